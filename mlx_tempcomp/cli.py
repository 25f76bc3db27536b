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
import os
from pathlib import Path
import sys

import numpy as np

from .core.chain import ChainModel, ChainSettings, find_plateaus, fit_chain, format_stage_table
from .core.conversion import Output
from .core.eeprom import decode_eeprom, VOTED_FIELDS
from .core.errors import TempCompError
from .core.fitting import (DISTINCT_DECIMALS, fit_linear_btc, fit_polynomial, format_btc_table,
                           format_order_table, relative_polynomial, select_orders, table_step_c)
from .core.models import AXIS_NAMES
from .core.noise import allan_deviation
from .core.table import factory_table, TRIPLET_TEMPERATURES_C
from .model_params import (chain_parameters, linear_btc_parameters, parameter_file,
                           polynomial_parameters, write_parameter_file)
from .toolkit import adis_bias, convert, diagnose, evaluate, simulate
from .toolkit.common import (add_recording_options, check_output_file, check_output_folder,
                             EXIT_USER_ERROR, finite_float, load, non_negative_int,
                             positive_float, UserError)

# Each adds its subcommand with add_parser(commands).
_COMMAND_MODULES = (adis_bias, convert, diagnose, evaluate, simulate)

DEFAULT_MAX_ORDER = 8
DEFAULT_BLOCKS = 20
DEFAULT_FOLDS = 5
DEFAULT_CHAIN_ORDER = ChainSettings.nonlinearity_order
BTC_TABLE_ROWS = 6

SECONDS_PER_HOUR = 3600.0
# 128 + SIGPIPE, what a shell reports for a command killed by a broken pipe.
EXIT_BROKEN_PIPE = 141


def _read_image(path: str) -> bytes:
    try:
        with open(path, 'rb') as image_file:
            return image_file.read()
    except OSError as err:
        msg = f'cannot read EEPROM image {path}: {err.strerror}'
        raise UserError(msg) from None


def _outvoted_warnings(fields) -> list:
    """One line per voted field whose copies disagree: the copies and what won."""
    lines = []
    for name in VOTED_FIELDS:
        bits = fields.outvoted_bits[name]
        if bits:
            copies = ', '.join(str(value) for value in fields.voted_copies[name])
            won = _VOTED_VALUES[name](fields)
            lines.append(f'warning: {name}: {bits} bit{"s" if bits > 1 else ""} out-voted; '
                         f'copies {copies}; the majority {won} was used (wrong if two copies '
                         'of a bit went bad)')
    return lines


_VOTED_VALUES = {'RANGE': lambda fields: fields.range_code,
                 'VERSION': lambda fields: fields.version,
                 **{f'TC{i}': (lambda fields, i=i: fields.tc_mv[i]) for i in range(3)}}


def decode_eeprom_command(args: argparse.Namespace) -> int:
    output = Output(args.output)
    try:
        fields = decode_eeprom(_read_image(args.image))
        table = factory_table(fields, output, full_scale_dps=args.full_scale)
    except TempCompError as err:
        msg = f'{args.image}: {err}'
        raise UserError(msg) from None
    warnings = _outvoted_warnings(fields)
    for line in warnings:
        print(f'{args.image}: {line}', file=sys.stderr)
    if warnings and args.strict:
        names = ', '.join(name for name in VOTED_FIELDS if fields.outvoted_bits[name])
        msg = f'{args.image}: out-voted bits in {names}; --strict refuses the image'
        raise UserError(msg)
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
        'voted_copies': {name: list(copies) for name, copies in fields.voted_copies.items()},
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


def _rate_error(recording) -> tuple:
    """Return the rate error the bias is fitted to and how it was formed."""
    if recording.reference_rad_s is None:
        return recording.gyro_rad_s, 'gyro rate (no reference: assumed at rest)'
    return recording.gyro_rad_s - recording.reference_rad_s, \
        'gyro rate minus the reference rate (ref columns)'


def _fit_polynomial_bias(args: argparse.Namespace, recording, rate_rad_s):
    """Choose the orders (or take --order), fit, print the orders; return the model."""
    readings_c = np.unique(np.round(recording.temperature_c, DISTINCT_DECIMALS))
    if readings_c.size == 1:
        msg = (f'{args.input}: the temperature does not vary: every row reads '
               f'{readings_c[0]:.2f} C; a bias(T) fit needs a recording over a temperature '
               'range (heat or cool the sensor while recording)')
        raise UserError(msg)
    blocks = DEFAULT_BLOCKS if args.blocks is None else args.blocks
    folds = DEFAULT_FOLDS if args.folds is None else args.folds
    if args.order is None:
        max_order = DEFAULT_MAX_ORDER if args.max_order is None else args.max_order
        selections = select_orders(recording.temperature_c, rate_rad_s, axes=recording.axes,
                                   candidate_orders=range(max_order + 1), blocks=blocks,
                                   folds=folds)
        orders = tuple(selection.order for selection in selections)
        print(format_order_table(selections))
    else:
        orders = (args.order,) * len(recording.axes)
    model = fit_polynomial(recording.temperature_c, rate_rad_s, orders)
    how = 'given by --order' if args.order is not None else \
        f'chosen by {folds}-fold cross-validation over {blocks} blocks'
    chosen = ', '.join(f'{axis} {order}' for axis, order in zip(recording.axes, orders))
    print(f'orders ({how}): {chosen}')
    return model


def _print_range(model) -> None:
    print(f'fitted temperature range: {model.temperature_min_c:.2f} to '
          f'{model.temperature_max_c:.2f} C (clamped outside)')


def _fit_polynomial_model(args: argparse.Namespace, recording) -> tuple:
    rate_rad_s, formed = _rate_error(recording)
    print(f'model polynomial: bias(T) fitted to the {formed}')
    model = _fit_polynomial_bias(args, recording, rate_rad_s)
    _print_range(model)
    return (polynomial_parameters(model, recording.axes),
            f'Bias polynomials fitted by mlx-tempcomp fit from {args.input}')


def _fit_relative_model(args: argparse.Namespace, recording) -> tuple:
    rate_rad_s, formed = _rate_error(recording)
    if args.true_temperature is None:
        true_c, how = float(np.mean(recording.temperature_c)), 'mean temperature of the data'
    else:
        true_c, how = args.true_temperature, 'given by --true-temperature'
    print(f'model relative (seed 002): rate - (p(T) - p(T_true)), p fitted to the {formed}')
    fitted = _fit_polynomial_bias(args, recording, rate_rad_s)
    model = relative_polynomial(fitted, true_c)
    _print_range(model)
    print(f'T_true = {true_c:.2f} C ({how})')
    x = (true_c - fitted.reference_temperature_c) / fitted.temperature_scale_c
    removed = ', '.join(f'{axis} {np.polynomial.polynomial.polyval(x, c):.3e}'
                        for axis, c in zip(recording.axes, fitted.bias_coefficients))
    print(f'p(T_true) taken off the constant terms (rad/s): {removed}')
    print("written as model 'polynomial' whose bias is zero at T_true; the compensation "
          'node runs it unchanged')
    return (polynomial_parameters(model, recording.axes),
            f'Relative bias correction rate - (p(T) - p({true_c:.2f} C)) (seed 002), written '
            f'as polynomials,\nfitted by mlx-tempcomp fit from {args.input}')


def _fit_linear_btc_model(args: argparse.Namespace, recording) -> tuple:
    rate_rad_s, formed = _rate_error(recording)
    model = fit_linear_btc(recording.temperature_c, rate_rad_s, args.t3)
    how = 'given by --t3' if args.t3 is not None else 'mean temperature of the data'
    print('model linear_btc (ADIS16130 AN-1042): RBC = RATE + PBC + (TEMP - T3) x BTC, '
          f'line fitted to the {formed}')
    print(f'T3 = {model.t3_c:.2f} C ({how})')
    corrected = model.correct(rate_rad_s, recording.temperature_c).rate_rad_s
    rms = np.sqrt(np.mean(np.square(corrected), axis=0))
    print(f'{"axis":<6}{"BTC":>12}{"PBC":>12}{"RMS after":>12}{"bias slope":>14}')
    print(f'{"":<6}{"rad/s/C":>12}{"rad/s":>12}{"rad/s":>12}{"deg/s/C":>14}')
    for i, axis in enumerate(recording.axes):
        btc = model.btc_rad_s_per_c[i]
        print(f'{axis:<6}{btc:>12.3e}{model.pbc_rad_s[i]:>12.3e}{rms[i]:>12.3e}'
              f'{math.degrees(-btc):>14.6g}')
    if args.table_step is None:
        extent_c = max(abs(float(np.min(recording.temperature_c)) - model.t3_c),
                       abs(float(np.max(recording.temperature_c)) - model.t3_c))
        step_c = table_step_c(extent_c, BTC_TABLE_ROWS)
    else:
        step_c = args.table_step
    print('correction factors (TEMP - T3) x BTC, as Table 6 of the note:')
    print(format_btc_table(model, recording.axes, step_c, BTC_TABLE_ROWS))
    return (linear_btc_parameters(model, recording.axes),
            f'ADIS16130 linear BTC/PBC correction fitted by mlx-tempcomp fit from {args.input}')


def _missing_chain_columns(recording) -> list:
    missing = [f'gyro_{axis}' for axis in AXIS_NAMES if axis not in recording.axes]
    if recording.reference_rad_s is None:
        missing += [f'ref_{axis}' for axis in AXIS_NAMES]
    else:
        missing += [f'ref_{axis}' for axis in AXIS_NAMES if axis not in recording.axes]
    if recording.temperature_2_c is None:
        missing.append('temperature_2')
    return missing


def _fit_chain_model(args: argparse.Namespace, recording) -> tuple:
    missing = _missing_chain_columns(recording)
    if missing:
        msg = (f'{args.input}: --model chain needs the columns gyro_x|y|z, ref_x|y|z and '
               f'temperature_2; missing {", ".join(missing)}')
        raise UserError(msg)
    reference = recording.reference_rad_s
    plateau_id = find_plateaus(reference, recording.temperature_c, recording.temperature_2_c)
    on_plateau = plateau_id >= 0
    if not on_plateau.any():
        msg = (f'{args.input}: no plateau: the reference rate and temperatures never hold '
               'steady for 10 samples')
        raise UserError(msg)
    if args.full_scale_dps is None:
        full_scale_rad_s = float(np.max(np.abs(reference)))
        how = 'largest reference rate'
        if full_scale_rad_s == 0.0:
            msg = f'{args.input}: the reference rate is zero throughout; the chain needs rates'
            raise UserError(msg)
    else:
        full_scale_rad_s, how = math.radians(args.full_scale_dps), 'given by --full-scale-dps'

    def reference_temperature(value, column, option):
        if value is not None:
            return value, f'given by {option}'
        return float(np.mean(column[on_plateau])), 'mean over the plateaus'

    temperature_c, how_t = reference_temperature(args.reference_temperature,
                                                 recording.temperature_c,
                                                 '--reference-temperature')
    temperature_2_c, how_t2 = reference_temperature(args.reference_temperature_2,
                                                    recording.temperature_2_c,
                                                    '--reference-temperature-2')
    settings = ChainSettings(
        full_scale_rad_s=full_scale_rad_s, reference_temperature_c=temperature_c,
        reference_temperature_2_c=temperature_2_c,
        nonlinearity_order=DEFAULT_CHAIN_ORDER if args.order is None else args.order)
    result = fit_chain(reference, recording.gyro_rad_s, recording.temperature_c,
                       recording.temperature_2_c, plateau_id, settings)
    chain = result.chain
    print('model chain (seed 004): nonlinearity, offset(T), sensitivity K(rate) C(rate), '
          'offset(T2), misalignment')
    print(f'plateaus found: {int(plateau_id.max(initial=-1)) + 1} '
          f'({np.count_nonzero(on_plateau)} of {len(recording)} rows)')
    print(f'full scale: {math.degrees(full_scale_rad_s):.6g} deg/s ({how}); nonlinearity '
          f'order {settings.nonlinearity_order}')
    print(f'reference temperatures asked: T {temperature_c:.2f} C ({how_t}), '
          f'T2 {temperature_2_c:.2f} C ({how_t2})')
    print(f'reference temperatures of the chain (mean of the nonlinearity plateaus): '
          f'T {chain.reference_temperature_c:.2f} C, T2 {chain.reference_temperature_2_c:.2f} C')
    print(f'{"axis":<6}{"offset":>12}{"dOffset/dT":>14}{"offset_2":>12}{"dOffset_2/dT2":>15}'
          f'{"misalignment row":>34}')
    print(f'{"":<6}{"rad/s":>12}{"rad/s/C":>14}{"rad/s":>12}{"rad/s/C":>15}')
    for i, axis in enumerate(AXIS_NAMES):
        row = ' '.join(f'{v:+.6f}' for v in chain.misalignment[i])
        print(f'{axis:<6}{chain.offset_rad_s[i]:>12.4e}'
              f'{chain.offset_gradient_rad_s_per_c[i]:>14.4e}{chain.offset_2_rad_s[i]:>12.4e}'
              f'{chain.offset_2_gradient_rad_s_per_c[i]:>15.4e}  {row}')
    print(f'error (output - reference) after each stage on the trimmed calibration plateaus '
          f'({result.stage_errors[0].samples} samples per axis):')
    print(format_stage_table(result.stage_errors))
    return (chain_parameters(ChainModel(chain)),
            f'Seed-004 calibration chain fitted by mlx-tempcomp fit from {args.input}\n'
            'The node needs the second temperature (temperature_2) for the offset_2 stage')


_FIT_MODELS = {
    'polynomial': (_fit_polynomial_model, ('order', 'max_order', 'blocks', 'folds')),
    'relative': (_fit_relative_model, ('order', 'max_order', 'blocks', 'folds',
                                       'true_temperature')),
    'linear_btc': (_fit_linear_btc_model, ('t3', 'table_step')),
    'chain': (_fit_chain_model, ('order', 'full_scale_dps', 'reference_temperature',
                                 'reference_temperature_2')),
}

# Options of some models only: refused with another instead of silently ignored.
_FIT_MODEL_OPTIONS = tuple(dict.fromkeys(name for _, names in _FIT_MODELS.values()
                                         for name in names))


def fit_command(args: argparse.Namespace) -> int:
    fit, allowed = _FIT_MODELS[args.model]
    given = [name for name in _FIT_MODEL_OPTIONS
             if getattr(args, name) is not None and name not in allowed]
    if given:
        options = ', '.join('--' + name.replace('_', '-') for name in given)
        msg = f'{options} {"does" if len(given) == 1 else "do"} not apply to --model {args.model}'
        raise UserError(msg)
    check_output_file(args.out, '--out')
    recording = load(args)
    try:
        parameters, header = fit(args, recording)
    except TempCompError as err:
        msg = f'{args.input}: {err}'
        raise UserError(msg) from None
    content = parameter_file(args.node_name, parameters)
    header += f'\nUse: compensation_node --ros-args --params-file {args.out}'
    try:
        write_parameter_file(args.out, content, header)
    except OSError as err:
        msg = f'cannot write {args.out}: {err.strerror}'
        raise UserError(msg) from None
    print(f'wrote {args.out} (model {parameters["model"]})')
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
    decode.add_argument('--strict', action='store_true',
                        help='exit with code 2 when any voted field has out-voted bits (the '
                             'warnings name them)')
    decode.set_defaults(handler=decode_eeprom_command)
    fit = commands.add_parser(
        'fit', help='fit a compensation model to a recording and write a parameter file',
        description='Fit a compensation model to a recording (CSV or rosbag2 bag) and write '
                    'a ROS 2 parameter file the compensation node loads. polynomial: a bias '
                    'polynomial per axis, the order chosen by contiguous-block '
                    'cross-validation with the one-standard-error rule; relative: the same '
                    'polynomial made zero at a true temperature (seed 002); linear_btc: the '
                    'ADIS16130 line, BTC and PBC at T3; chain: the seed-004 calibration chain '
                    '(needs ref_x|y|z and temperature_2). The bias is fitted to gyro minus '
                    'ref when the recording has a reference, else to gyro (at rest).')
    add_recording_options(fit)
    fit.add_argument('--model', choices=tuple(_FIT_MODELS), default='polynomial',
                     help='model to fit (default: %(default)s)')
    orders = fit.add_mutually_exclusive_group()
    orders.add_argument('--order', type=non_negative_int, metavar='N',
                        help='polynomial, relative: fit this order on every axis instead of '
                             'choosing it; chain: nonlinearity order (default '
                             f'{DEFAULT_CHAIN_ORDER})')
    orders.add_argument('--max-order', type=non_negative_int, metavar='N',
                        help=f'highest order tried (default: {DEFAULT_MAX_ORDER})')
    fit.add_argument('--blocks', type=int, metavar='N',
                     help='contiguous blocks, dealt round-robin to the folds (default: '
                          f'{DEFAULT_BLOCKS})')
    fit.add_argument('--folds', type=int, metavar='N',
                     help=f'cross-validation folds (default: {DEFAULT_FOLDS})')
    fit.add_argument('--true-temperature', type=finite_float, metavar='C',
                     help='relative: temperature at which no bias is introduced '
                          '(default: the mean temperature of the data)')
    fit.add_argument('--t3', type=finite_float, metavar='C',
                     help='linear_btc: T3, where PBC holds (default: the mean temperature of '
                          'the data)')
    fit.add_argument('--table-step', type=positive_float, metavar='C',
                     help='linear_btc: temperature step of the printed correction table '
                          '(default: a 1-2-5 step covering the data in 6 rows each side)')
    fit.add_argument('--full-scale-dps', type=positive_float, metavar='DPS',
                     help='chain: full scale in deg/s (default: the largest reference rate)')
    fit.add_argument('--reference-temperature', type=finite_float, metavar='C',
                     help='chain: temperature of the nonlinearity fit (default: the mean '
                          'temperature over the plateaus)')
    fit.add_argument('--reference-temperature-2', type=finite_float, metavar='C',
                     help='chain: second temperature of stages 1-3 (default: the mean '
                          'second temperature over the plateaus)')
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
    except BrokenPipeError:
        # The reader went away (e.g. `| head`): stop quietly, as Unix tools do.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


if __name__ == '__main__':
    sys.exit(main())
