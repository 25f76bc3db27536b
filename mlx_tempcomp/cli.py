"""
The ``mlx-tempcomp`` command line.

User mistakes (a missing or malformed file, an unknown VERSION, data that
cannot support the fit asked for) print one line starting with ``error:``
and exit with code 2, never a traceback. Subcommands beyond decode-eeprom,
fit and allan live in `mlx_tempcomp.toolkit`, one module each.
"""

import argparse
import json
import math
from pathlib import Path
import sys

from .core.conversion import Output
from .core.eeprom import decode_eeprom, VOTED_FIELDS
from .core.errors import TempCompError
from .core.fitting import fit_polynomial, format_order_table, select_orders
from .core.noise import allan_deviation
from .core.table import factory_table, TRIPLET_TEMPERATURES_C
from .model_params import parameter_file, polynomial_parameters, write_parameter_file
from .toolkit.common import (add_recording_options, EXIT_USER_ERROR, load, non_negative_int,
                             UserError)

# Each adds its subcommand with add_parser(commands).
_COMMAND_MODULES = ()

DEFAULT_MAX_ORDER = 8
DEFAULT_BLOCKS = 5

SECONDS_PER_HOUR = 3600.0


def _read_image(path: str) -> bytes:
    try:
        with open(path, 'rb') as image_file:
            return image_file.read()
    except OSError as err:
        msg = f'cannot read EEPROM image {path}: {err.strerror}'
        raise UserError(msg) from None


def decode_eeprom_command(args: argparse.Namespace) -> int:
    output = Output(args.output)
    try:
        fields = decode_eeprom(_read_image(args.image))
        table = factory_table(fields, output, full_scale_dps=args.full_scale)
    except TempCompError as err:
        msg = f'{args.image}: {err}'
        raise UserError(msg) from None
    result = {
        'image': args.image,
        'range_code': fields.range_code,
        'full_scale_dps': fields.full_scale_dps,
        'version': fields.version,
        'has_table': table is not None,
        'tc_mv': list(fields.tc_mv),
        'ee_zro': list(fields.ee_zro),
        'ee_sf': list(fields.ee_sf),
        'outvoted_bits': dict(fields.outvoted_bits),
        'output': output.value,
    }
    if table is not None:
        result.update(tc=list(table.tc), zro=list(table.zro), sf=list(table.sf))
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f'{args.image}: VERSION {fields.version}, RANGE {fields.range_code} '
          f'(full scale {fields.full_scale_dps:g} deg/s)')
    if table is None:
        print('VERSION 0: the EEPROM holds no table; use the nominal ZRO and scale factor')
    else:
        unit = 'LSB' if output is Output.DIGITAL else 'mV'
        print(f'{output.value} output: TC in {unit} of TEMPOUT, ZRO in {unit}, '
              f'SF in {unit}/(deg/s)')
        print(f'{"triplet":<10}{"TC (mV)":>10}{"TC":>12}{"ZRO":>12}{"SF":>10}'
              f'{"EE_ZRO":>8}{"EE_SF":>7}')
        for i, temperature_c in enumerate(TRIPLET_TEMPERATURES_C):
            print(f'{f"{temperature_c:+.0f} C":<10}{fields.tc_mv[i]:>10d}{table.tc[i]:>12.3f}'
                  f'{table.zro[i]:>12.3f}{table.sf[i]:>10.4f}{fields.ee_zro[i]:>8d}'
                  f'{fields.ee_sf[i]:>7d}')
    counts = ', '.join(f'{name} {fields.outvoted_bits[name]}' for name in VOTED_FIELDS)
    print(f'out-voted bits: {counts} (total {fields.total_outvoted_bits})')
    return 0


def fit_command(args: argparse.Namespace) -> int:
    recording = load(args)
    try:
        if args.order is None:
            selections = select_orders(recording.temperature_c, recording.gyro_rad_s,
                                       axes=recording.axes,
                                       candidate_orders=range(args.max_order + 1),
                                       blocks=args.blocks)
            orders = tuple(selection.order for selection in selections)
            print(format_order_table(selections))
        else:
            orders = (args.order,) * len(recording.axes)
        model = fit_polynomial(recording.temperature_c, recording.gyro_rad_s, orders)
    except TempCompError as err:
        msg = f'{args.input}: {err}'
        raise UserError(msg) from None
    how = 'given by --order' if args.order is not None else \
        f'chosen by {args.blocks}-block cross-validation'
    chosen = ', '.join(f'{axis} {order}' for axis, order in zip(recording.axes, orders))
    print(f'orders ({how}): {chosen}')
    skipped = ', '.join(f'{reason} {count}' for reason, count in recording.skipped.items()
                        if count)
    print(f'rows used: {len(recording)}; skipped: {skipped or "none"}')
    print(f'fitted temperature range: {model.temperature_min_c:.2f} to '
          f'{model.temperature_max_c:.2f} C (clamped outside)')
    content = parameter_file(args.node_name, polynomial_parameters(model, recording.axes))
    header = (f'Bias polynomials fitted by mlx-tempcomp fit from {args.input}\n'
              f'Use: compensation_node --ros-args --params-file {args.out}')
    try:
        write_parameter_file(args.out, content, header)
    except OSError as err:
        msg = f'cannot write {args.out}: {err.strerror}'
        raise UserError(msg) from None
    print(f'wrote {args.out}')
    return 0


def _write_allan_files(out_dir: str, source: str, figures: tuple) -> None:
    """Write allan.json (figures and curves) and allan.png (log-log curves) into out_dir."""
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
        (Path(out_dir) / 'allan.json').write_text(json.dumps(result, indent=2) + '\n')
        figure.savefig(Path(out_dir) / 'allan.png', dpi=100)
    except OSError as err:
        msg = f'cannot write to {out_dir}: {err.strerror}'
        raise UserError(msg) from None
    finally:
        pyplot.close(figure)


def allan_command(args: argparse.Namespace) -> int:
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
        _write_allan_files(args.out, args.input, figures)
        print(f'wrote {Path(args.out) / "allan.json"} and {Path(args.out) / "allan.png"}')
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='mlx-tempcomp',
        description='MLX90609 temperature compensation toolkit.')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    decode = commands.add_parser(
        'decode-eeprom', help='decode a 128-byte MLX90609 EEPROM image',
        description='Decode the factory table of a 128-byte MLX90609 EEPROM image '
                    '(Melexis AN2 sections 3.1-3.4) and count out-voted bits.')
    decode.add_argument('image', help='binary file of 128 bytes, address 0 first')
    decode.add_argument('--output', choices=[o.value for o in Output],
                        default=Output.DIGITAL.value,
                        help='express the table for the digital (LSB) or analog (mV) output')
    decode.add_argument('--full-scale', type=float, metavar='DPS',
                        help='full scale in deg/s, overriding 5 x RANGE')
    decode.add_argument('--json', action='store_true', help='print JSON')
    decode.set_defaults(handler=decode_eeprom_command)
    fit = commands.add_parser(
        'fit', help='fit bias polynomials to a recording and write a parameter file',
        description='Fit a bias polynomial per gyro axis to a recording (CSV or rosbag2 '
                    'bag), the order chosen per axis by contiguous-block cross-validation '
                    'with the one-standard-error rule, and write a ROS 2 parameter file '
                    'for the compensation node.')
    add_recording_options(fit)
    orders = fit.add_mutually_exclusive_group()
    orders.add_argument('--order', type=non_negative_int, metavar='N',
                        help='fit this order on every axis instead of choosing it')
    orders.add_argument('--max-order', type=non_negative_int, default=DEFAULT_MAX_ORDER,
                        metavar='N', help='highest order tried (default: %(default)s)')
    fit.add_argument('--blocks', type=int, default=DEFAULT_BLOCKS, metavar='N',
                     help='contiguous cross-validation blocks (default: %(default)s)')
    fit.add_argument('--out', required=True, metavar='PARAMS.yaml',
                     help='parameter file to write (replaced atomically)')
    fit.add_argument('--node-name', default='compensation_node', metavar='NAME',
                     help='node section of the parameter file (default: %(default)s)')
    fit.set_defaults(handler=fit_command)
    allan = commands.add_parser(
        'allan', help='Allan deviation and noise figures of a recording',
        description='Compute the overlapping Allan deviation of each gyro axis of a '
                    'recording (CSV or rosbag2 bag) at octave-spaced taus and print the '
                    'angle random walk, bias instability and the rate_noise_rad_s '
                    'parameter of the compensation node.')
    add_recording_options(allan)
    allan.add_argument('--out', metavar='DIR',
                       help='also write allan.json and allan.png into this folder')
    allan.set_defaults(handler=allan_command)
    for module in _COMMAND_MODULES:
        module.add_parser(commands)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except UserError as err:
        print(f'error: {err}', file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == '__main__':
    sys.exit(main())
