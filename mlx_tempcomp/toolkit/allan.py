"""
The ``mlx-tempcomp allan`` command: Allan deviation and noise figures of a recording.

Prints, per gyro axis, the angle random walk, the bias instability and the
compensation node's ``rate_noise_rad_s``, then per gyro and accelerometer
axis the two continuous-time densities visual-inertial tools take (`noise_lines`):
the noise density and the random walk. ``--kalibr-yaml FILE`` writes them as
Kalibr's ``imu.yaml``; ``--out DIR`` also writes allan.json (figures and
curves) and allan.png (log-log curves, gyro and accelerometer each on its own axes, with
the fitted lines and where each figure was read). matplotlib is imported only when the
plot is written.
"""

import argparse
import math
from pathlib import Path

import numpy as np

from .errors import UserError
from .loading import load, read_options
from .options import add_recording_options
from .running import check_output_file, check_output_folder, write_json, write_result
from ..core.errors import TempCompError
from ..core.series import (allan_deviation, FLICKER_FLOOR_FACTOR, MIN_CLUSTERS,
                           NOISE_DENSITY_TAU_S, noise_lines, RANDOM_WALK_TAU_S)
from ..recordings.recording import AXES

SECONDS_PER_HOUR = 3600.0
# The topic a visual-inertial tool reads: the compensation node's output.
KALIBR_TOPIC = '/imu/data'


def add_parser(commands) -> None:
    """Add the ``allan`` subcommand."""
    allan = commands.add_parser(
        'allan', help='Allan deviation and noise figures of a recording (Kalibr imu.yaml)',
        description='Compute the overlapping Allan deviation of each gyro and accelerometer '
                    'axis of a recording (CSV or rosbag2 bag) at octave-spaced taus and print '
                    'the angle random walk, bias instability and the rate_noise_rad_s '
                    'parameter of the compensation node, and the noise density and random '
                    "walk Kalibr's imu.yaml takes. Record the sensor still, at a steady "
                    'temperature.')
    add_recording_options(allan)
    allan.add_argument('--out', metavar='DIR',
                       help='also write allan.json and allan.png into this folder')
    allan.add_argument('--kalibr-yaml', metavar='FILE',
                       help="write the noise figures as Kalibr's imu.yaml (the largest of the "
                            'axes; accelerometer entries when the record has acceleration)')
    allan.add_argument('--kalibr-topic', default=KALIBR_TOPIC, metavar='TOPIC',
                       help='rostopic written into the imu.yaml (default: %(default)s, the '
                            "compensation node's output)")
    allan.set_defaults(handler=allan_command, needs=_needs)


def _needs(args: argparse.Namespace) -> list:
    """Give the optional packages allan will import (extras.require)."""
    return [('allantools', '')] + ([('matplotlib', '')] if args.out is not None else [])


def _axis_json(figures, lines, unit: str) -> dict:
    return {'axis': figures.axis,
            'angle_random_walk_rad_s_rt_hz': figures.angle_random_walk_rad_s_rt_hz,
            'bias_instability_rad_s': figures.bias_instability_rad_s,
            'bias_instability_tau_s': figures.bias_instability_tau_s,
            'rate_noise_rad_s': figures.rate_noise_rad_s,
            f'noise_density_{unit}_rt_hz': lines.noise_density,
            'noise_density_upper_bound': lines.noise_density_bound,
            f'random_walk_{unit}_s_rt_hz': lines.random_walk,
            'random_walk_upper_bound': lines.random_walk_bound,
            'taus_s': figures.taus_s.tolist(),
            'adev_rad_s': figures.adev_rad_s.tolist()}


def _write_allan_files(out_dir: str, source: str, outputs, gyro: tuple, accel: tuple) -> None:
    """Write allan.json (figures and curves) and allan.png (`allan_figure`) into ``out_dir``."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot

    result = {'source': source, 'axes': [_axis_json(f, lines, 'rad_s') for f, lines in gyro]}
    if accel:
        # The accelerometer's curve is in m/s^2, under the same keys as the gyro's.
        result['accelerometer_axes'] = [_axis_json(f, lines, 'm_s2') for f, lines in accel]
    figure = allan_figure(pyplot, source, gyro, accel)
    try:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        write_json(outputs.file(Path(out_dir) / 'allan.json'), result)
        figure.savefig(outputs.file(Path(out_dir) / 'allan.png'), dpi=100, format='png')
    except OSError as err:
        msg = f'cannot write to {out_dir}: {err.strerror}'
        raise UserError(msg) from None
    finally:
        pyplot.close(figure)


def _sensor_panel(plot, pairs: tuple, sensor: str, unit: str) -> None:
    """
    Draw one sensor's curves, the lines its figures come from, and where each was read.

    Per axis: the Allan deviation; the white-noise line N / sqrt(tau) (dashed) and
    the random-walk line K sqrt(tau / 3) (dotted) over the trusted taus, unless the
    figure is a bound; a square where N is read (tau = 1 s), a triangle where K is
    (3 s), a downward triangle at the floor the bias instability is read from.
    """
    for k, (f, lines) in enumerate(pairs):
        colour = f'C{k}'
        plot.loglog(f.taus_s, f.adev_rad_s, marker='.', color=colour, label=f'{sensor} {f.axis}')
        taus = f.taus_s[f.taus_s <= max(f.duration_s / MIN_CLUSTERS, f.taus_s[0])]
        if not lines.noise_density_bound:
            plot.loglog(taus, lines.noise_density / np.sqrt(taus), '--', color=colour, lw=1)
        if not lines.random_walk_bound:
            plot.loglog(taus, lines.random_walk * np.sqrt(taus / 3.0), ':', color=colour, lw=1)
        plot.loglog([NOISE_DENSITY_TAU_S], [lines.noise_density / NOISE_DENSITY_TAU_S ** 0.5],
                    's', color=colour, mfc='none', ms=8)
        plot.loglog([RANDOM_WALK_TAU_S], [lines.random_walk], '^', color=colour, mfc='none',
                    ms=8)
        plot.loglog([f.bias_instability_tau_s],
                    [f.bias_instability_rad_s * FLICKER_FLOOR_FACTOR], 'v', color=colour, ms=8)
    plot.set_xlabel('tau (s)')
    plot.set_ylabel(f'Allan deviation ({unit})')
    plot.set_title(sensor)
    plot.grid(True, which='both', alpha=0.3)


def allan_figure(pyplot, source: str, gyro: tuple, accel: tuple):
    """
    Give allan.png's figure: gyro and accelerometer each on axes of their own (`_sensor_panel`).

    One legend below the panels names the axes and what each mark means.
    """
    from matplotlib.lines import Line2D

    panels = 2 if accel else 1
    figure, grid = pyplot.subplots(1, panels, figsize=(6.0 * panels, 5.5), squeeze=False,
                                   layout='constrained')
    _sensor_panel(grid[0][0], gyro, 'gyro', 'rad/s')
    if accel:
        _sensor_panel(grid[0][1], accel, 'accelerometer', 'm/s^2')
    figure.suptitle(f'Overlapping Allan deviation: {Path(source).name}')
    grey = {'color': '0.3'}
    marks = [Line2D([], [], ls='--', **grey, label='white-noise line N / sqrt(tau)'),
             Line2D([], [], ls=':', **grey, label='random-walk line K sqrt(tau / 3)'),
             Line2D([], [], ls='', marker='s', mfc='none', **grey,
                    label=f'N read at tau = {NOISE_DENSITY_TAU_S:g} s'),
             Line2D([], [], ls='', marker='^', mfc='none', **grey,
                    label=f'K read at tau = {RANDOM_WALK_TAU_S:g} s'),
             Line2D([], [], ls='', marker='v', **grey,
                    label='floor (bias instability = floor / 0.664)')]
    axes = [Line2D([], [], marker='.', color=f'C{k}', label=f'axis {f.axis}')
            for k, (f, _) in enumerate(gyro if len(gyro) >= len(accel) else accel)]
    figure.legend(handles=axes + marks, loc='outside lower center', ncol=4, fontsize='small')
    return figure


def _largest(pairs: tuple) -> tuple:
    """Give the largest noise density and random walk over the axes, and whether each bounds."""
    density = max((lines for _, lines in pairs), key=lambda lines: lines.noise_density)
    walk = max((lines for _, lines in pairs), key=lambda lines: lines.random_walk)
    return (density.noise_density, density.noise_density_bound, walk.random_walk,
            walk.random_walk_bound)


def kalibr_yaml(gyro: tuple, accel: tuple, topic: str, rate_hz: float, source: str) -> str:
    """
    Give the text of Kalibr's imu.yaml for (NoiseFigures, NoiseLines) pairs per axis.

    Kalibr takes one noise density and one random walk per sensor: the
    largest of the axes is written (a filter told too little noise trusts
    the sensor too much), the axes' own values in comments beside.
    """
    def entries(name: str, pairs: tuple, units: tuple) -> list:
        density, density_bound, walk, walk_bound = _largest(pairs)
        axes = ', '.join(f'{f.axis} {lines.noise_density:.3e} / {lines.random_walk:.3e}'
                         for f, lines in pairs)
        return [f'# {name} axes (noise density / random walk): {axes}',
                f'{name}_noise_density: {density:.6e}  # {units[0]}'
                + (', an upper bound: no white-noise line in the record' if density_bound
                   else ''),
                f'{name}_random_walk: {walk:.6e}  # {units[1]}'
                + (', an upper bound: the record shows no random walk' if walk_bound else '')]

    lines = [f'# IMU noise model for Kalibr, by mlx-tempcomp allan from {source}',
             '# Continuous-time densities from the overlapping Allan deviation: the noise '
             f'density is the white-noise line (slope -1/2) at tau = {NOISE_DENSITY_TAU_S:g} s,',
             '# the random walk the random-walk line (slope +1/2) at tau = '
             f'{RANDOM_WALK_TAU_S:g} s; the largest of the axes.']
    if accel:
        lines += entries('accelerometer', accel, ('m/s^2/sqrt(Hz)', 'm/s^3/sqrt(Hz)'))
    else:
        lines.append('# no accelerometer in the record: accelerometer_* left out')
    lines += entries('gyroscope', gyro, ('rad/s/sqrt(Hz)', 'rad/s^2/sqrt(Hz)'))
    rate = float(f'{rate_hz:.6g}')
    lines += [f'rostopic: {topic}', f"update_rate: {rate!r}  # Hz, the record's"]
    return '\n'.join(lines) + '\n'


def _figures(source: str, recording) -> tuple:
    """Give ((NoiseFigures, NoiseLines) per gyro axis, the same per accelerometer axis)."""
    try:
        gyro = allan_deviation(recording.time_s, recording.gyro_rad_s, recording.axes)
        accel = () if recording.acceleration_m_s2 is None else \
            allan_deviation(recording.time_s, recording.acceleration_m_s2, AXES)
        return (tuple((f, noise_lines(f)) for f in gyro),
                tuple((f, noise_lines(f)) for f in accel))
    except TempCompError as err:
        msg = f'{source}: {err}'
        raise UserError(msg) from None


def _bound(flag: bool) -> str:
    return ' <' if flag else ''


def allan_command(args: argparse.Namespace) -> int:
    if args.out is not None:
        check_output_folder(args.out, '--out')
    if args.kalibr_yaml is not None:
        check_output_file(args.kalibr_yaml, '--kalibr-yaml')
    recording = load(args.input, read_options(args))
    gyro, accel = _figures(args.input, recording)
    print(f'{args.input}: {len(recording)} samples over {recording.duration_s:.1f} s')
    print(f'{"axis":<6}{"ARW":>12}{"ARW":>14}{"bias inst.":>12}{"bias inst.":>12}'
          f'{"at tau":>10}{"rate_noise":>12}')
    print(f'{"":<6}{"deg/sqrt(h)":>12}{"rad/s/rt(Hz)":>14}{"deg/h":>12}{"rad/s":>12}'
          f'{"s":>10}{"rad/s":>12}')
    for f, _ in gyro:
        arw_deg_rt_h = math.degrees(f.angle_random_walk_rad_s_rt_hz) * SECONDS_PER_HOUR ** 0.5
        bias_deg_h = math.degrees(f.bias_instability_rad_s) * SECONDS_PER_HOUR
        print(f'{f.axis:<6}{arw_deg_rt_h:>12.4g}{f.angle_random_walk_rad_s_rt_hz:>14.4g}'
              f'{bias_deg_h:>12.4g}{f.bias_instability_rad_s:>12.4g}'
              f'{f.bias_instability_tau_s:>10.4g}{f.rate_noise_rad_s:>12.4g}')
    print('ARW read at tau = 1 s; bias instability = ADEV minimum / 0.664; '
          'rate_noise is the compensation node parameter')
    print(f'{"sensor":<16}{"noise density":>16}{"random walk":>16}   (Kalibr imu.yaml)')
    for sensor, pairs, units in (('gyro', gyro, 'rad/s, rad/s^2'),
                                 ('accelerometer', accel, 'm/s^2, m/s^3')):
        for f, lines in pairs:
            print(f'{sensor + " " + f.axis:<16}{lines.noise_density:>14.4e}'
                  f'{_bound(lines.noise_density_bound):<2}{lines.random_walk:>14.4e}'
                  f'{_bound(lines.random_walk_bound):<2} {units} /sqrt(Hz)')
    print(f'noise density: white-noise line at tau = {NOISE_DENSITY_TAU_S:g} s; random walk: '
          f'+1/2 line at tau = {RANDOM_WALK_TAU_S:g} s; < an upper bound (the record holds no '
          'such term)' + ('' if accel else '; no accelerometer in the record'))
    if args.kalibr_yaml is not None:
        rate_hz = 1.0 / float(np.median(np.diff(recording.time_s)))   # as the figures take it
        text = kalibr_yaml(gyro, accel, args.kalibr_topic, rate_hz, args.input)
        try:
            write_result(args.outputs.file(args.kalibr_yaml), text)
        except OSError as err:
            msg = f'cannot write {args.kalibr_yaml}: {err.strerror}'
            raise UserError(msg) from None
        print(f'wrote {args.kalibr_yaml} (Kalibr imu.yaml, rostopic {args.kalibr_topic}, '
              f'update_rate {rate_hz:.6g} Hz)')
    if args.out is not None:
        _write_allan_files(args.out, args.input, args.outputs, gyro, accel)
        print(f'wrote {Path(args.out) / "allan.json"} and {Path(args.out) / "allan.png"}')
    return 0
