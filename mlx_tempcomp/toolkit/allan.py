"""
The ``mlx-tempcomp allan`` command: Allan deviation and noise figures of a recording.

Prints, per gyro axis, the angle random walk, the bias instability and the
compensation node's ``rate_noise_rad_s``; ``--out DIR`` also writes
allan.json (figures and curves) and allan.png (log-log curves). matplotlib
is imported only when the plot is written.
"""

import argparse
import math
from pathlib import Path

from .common import add_recording_options, check_output_folder, load, UserError, write_json
from ..core.errors import TempCompError
from ..core.noise import allan_deviation

SECONDS_PER_HOUR = 3600.0


def add_parser(commands) -> None:
    """Add the ``allan`` subcommand."""
    allan = commands.add_parser(
        'allan', help='Allan deviation and noise figures of a recording',
        description='Compute the overlapping Allan deviation of each gyro axis of a '
                    'recording (CSV or rosbag2 bag) at octave-spaced taus and print the '
                    'angle random walk, bias instability and the rate_noise_rad_s '
                    'parameter of the compensation node.')
    add_recording_options(allan)
    allan.add_argument('--out', metavar='DIR',
                       help='also write allan.json and allan.png into this folder')
    allan.set_defaults(handler=allan_command, needs=_needs)


def _needs(args: argparse.Namespace) -> list:
    """Give the optional packages allan will import (extras.require)."""
    return [('allantools', '')] + ([('matplotlib', '')] if args.out is not None else [])


def _write_allan_files(args: argparse.Namespace, figures: tuple) -> None:
    """Write allan.json (figures and curves) and allan.png (log-log curves) into --out."""
    out_dir, source = args.out, args.input
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot

    result = {
        'source': source,
        'axes': [{
            'axis': f.axis,
            'angle_random_walk_rad_s_rt_hz': f.angle_random_walk_rad_s_rt_hz,
            'bias_instability_rad_s': f.bias_instability_rad_s,
            'bias_instability_tau_s': f.bias_instability_tau_s,
            'rate_noise_rad_s': f.rate_noise_rad_s,
            'taus_s': f.taus_s.tolist(),
            'adev_rad_s': f.adev_rad_s.tolist(),
        } for f in figures],
    }
    figure, axes = pyplot.subplots(figsize=(7.0, 5.0))
    for f in figures:
        axes.loglog(f.taus_s, f.adev_rad_s, marker='.', label=f'gyro {f.axis}')
    axes.set_xlabel('tau (s)')
    axes.set_ylabel('Allan deviation (rad/s)')
    axes.set_title(f'Overlapping Allan deviation: {Path(source).name}')
    axes.grid(True, which='both', alpha=0.3)
    axes.legend()
    try:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        write_json(args.outputs.file(Path(out_dir) / 'allan.json'), result)
        figure.savefig(args.outputs.file(Path(out_dir) / 'allan.png'), dpi=100, format='png')
    except OSError as err:
        msg = f'cannot write to {out_dir}: {err.strerror}'
        raise UserError(msg) from None
    finally:
        pyplot.close(figure)


def allan_command(args: argparse.Namespace) -> int:
    if args.out is not None:
        check_output_folder(args.out, '--out')
    recording = load(args)
    try:
        figures = allan_deviation(recording.time_s, recording.gyro_rad_s, recording.axes)
    except TempCompError as err:
        msg = f'{args.input}: {err}'
        raise UserError(msg) from None
    print(f'{args.input}: {len(recording)} samples over {recording.duration_s:.1f} s')
    print(f'{"axis":<6}{"ARW":>12}{"ARW":>14}{"bias inst.":>12}{"bias inst.":>12}'
          f'{"at tau":>10}{"rate_noise":>12}')
    print(f'{"":<6}{"deg/sqrt(h)":>12}{"rad/s/rt(Hz)":>14}{"deg/h":>12}{"rad/s":>12}'
          f'{"s":>10}{"rad/s":>12}')
    for f in figures:
        arw_deg_rt_h = math.degrees(f.angle_random_walk_rad_s_rt_hz) * SECONDS_PER_HOUR ** 0.5
        bias_deg_h = math.degrees(f.bias_instability_rad_s) * SECONDS_PER_HOUR
        print(f'{f.axis:<6}{arw_deg_rt_h:>12.4g}{f.angle_random_walk_rad_s_rt_hz:>14.4g}'
              f'{bias_deg_h:>12.4g}{f.bias_instability_rad_s:>12.4g}'
              f'{f.bias_instability_tau_s:>10.4g}{f.rate_noise_rad_s:>12.4g}')
    print('ARW read at tau = 1 s; bias instability = ADEV minimum / 0.664; '
          'rate_noise is the compensation node parameter')
    if args.out is not None:
        _write_allan_files(args, figures)
        print(f'wrote {Path(args.out) / "allan.json"} and {Path(args.out) / "allan.png"}')
    return 0
