"""
The ``mlx-tempcomp fit`` command: one compensation model fitted, written as a parameter file.

Each ``--model`` has a function that fits it to the recording, prints what
it fitted and returns the node parameters with a header; `fit_command`
refuses options of other models, then writes the file the compensation
node loads (atomically), with the ``bias_tracking`` section the record's
residual gives (`toolkit.tracking`). docs/toolkit-fit.md describes the models.
"""

import argparse
import contextlib
from dataclasses import dataclass
import io
import math
from typing import Optional

import numpy as np

from .errors import UserError
from .exports import (add_export_options, check_export_outputs, check_export_record,
                      export_request, write_exports)
from .fit_covariance import held_out_judgement, HeldOutJudgement
from .loading import load, read_options
from .options import (add_parameter_file_options, add_recording_options, add_validation_options,
                      finite_float, non_negative_int, positive_float, validation_settings)
from .running import check_output_file, write_node_parameters
from .tables import format_btc_table, format_order_table, format_stage_table
from .tracking import tracking_section
from .uncertainty import block_lines
from ..core.effects import LinearBtc
from ..core.errors import TempCompError
from ..core.fitting import (block_bounds, ChainSettings, DEFAULT_BLOCKS, DEFAULT_FOLDS,
                            DISTINCT_DECIMALS, find_plateaus, fit_chain, fit_linear_btc,
                            fit_polynomial, held_out_outside_range, relative_polynomial,
                            select_orders, split, table_step_c)
from ..core.node_models import AXIS_NAMES, ChainModel
from ..parameters.files import (chain_parameters, linear_btc_parameters, node_model,
                                polynomial_parameters)

DEFAULT_MAX_ORDER = 8
DEFAULT_CHAIN_ORDER = ChainSettings.nonlinearity_order
BTC_TABLE_ROWS = 6
# The documents the relative and chain models come from, as their output names them.
RELATIVE_SOURCE = '"Temperature Correction in MPU6000"'
CHAIN_SOURCE = 'the PSI 3-axis teslameter calibration paper'


@dataclass(frozen=True)
class _FitOptions:
    """
    What the model fits take from the command line; None where an option was not given.

    ``source`` names the record in messages and in the file's header;
    ``validation`` is `validation_settings`'.
    """

    source: str
    order: Optional[int]
    max_order: Optional[int]
    blocks: Optional[int]
    folds: Optional[int]
    validation: dict
    true_temperature: Optional[float]
    t3: Optional[float]
    table_step: Optional[float]
    full_scale_dps: Optional[float]
    reference_temperature: Optional[float]
    reference_temperature_2: Optional[float]


@dataclass(frozen=True)
class _Fitted:
    """A fitted model's node parameters and the header of their file."""

    parameters: dict
    header: str


def _rate_error(recording) -> tuple:
    """Return the rate error the bias is fitted to and how it was formed."""
    if recording.reference_rad_s is None:
        return recording.rate_error_rad_s, 'gyro rate (no reference: assumed at rest)'
    return recording.rate_error_rad_s, 'gyro rate minus the reference rate (ref columns)'


def _fit_polynomial_bias(options: _FitOptions, recording, rate_rad_s):
    """Choose the orders (or take --order), fit, print the orders; return the model."""
    readings_c = np.unique(np.round(recording.temperature_c, DISTINCT_DECIMALS))
    if readings_c.size == 1:
        msg = (f'{options.source}: the temperature does not vary: every row reads '
               f'{readings_c[0]:.2f} C; a bias(T) fit needs a recording over a temperature '
               'range (heat or cool the sensor while recording)')
        raise UserError(msg)
    blocks = DEFAULT_BLOCKS if options.blocks is None else options.blocks
    folds = DEFAULT_FOLDS if options.folds is None else options.folds
    if options.order is None:
        max_order = DEFAULT_MAX_ORDER if options.max_order is None else options.max_order
        validation = options.validation
        selections = select_orders(recording.temperature_c, rate_rad_s, axes=recording.axes,
                                   candidate_orders=range(max_order + 1), blocks=blocks,
                                   folds=folds, **validation)
        orders = tuple(selection.order for selection in selections)
        print(format_order_table(selections))
        dealt = split(blocks, validation['validation'], folds, validation['min_past'])
        how = f'chosen on held-out blocks, {dealt.describe()}'
        outside = held_out_outside_range(recording.temperature_c,
                                         block_bounds(len(recording.temperature_c), blocks),
                                         dealt)
        print('\n'.join(block_lines(outside, dealt.describe())))
    else:
        orders = (options.order,) * len(recording.axes)
        how = 'given by --order'
    model = fit_polynomial(recording.temperature_c, rate_rad_s, orders)
    chosen = ', '.join(f'{axis} {order}' for axis, order in zip(recording.axes, orders))
    print(f'orders ({how}): {chosen}')
    return model


def _print_range(model) -> None:
    print(f'fitted temperature range: {model.temperature_min_c:.2f} to '
          f'{model.temperature_max_c:.2f} C (clamped outside)')


def _fit_polynomial_model(options: _FitOptions, recording) -> tuple:
    rate_rad_s, formed = _rate_error(recording)
    print(f'model polynomial: bias(T) fitted to the {formed}')
    model = _fit_polynomial_bias(options, recording, rate_rad_s)
    _print_range(model)
    return _Fitted(polynomial_parameters(model, recording.axes),
                   f'Bias polynomials fitted by mlx-tempcomp fit from {options.source}')


def _fit_relative_model(options: _FitOptions, recording) -> tuple:
    rate_rad_s, formed = _rate_error(recording)
    if options.true_temperature is None:
        true_c, how = float(np.mean(recording.temperature_c)), 'mean temperature of the data'
    else:
        true_c, how = options.true_temperature, 'given by --true-temperature'
    print(f'model relative ({RELATIVE_SOURCE}): rate - (p(T) - p(T_true)), p fitted to the '
          f'{formed}')
    fitted = _fit_polynomial_bias(options, recording, rate_rad_s)
    model = relative_polynomial(fitted, true_c)
    _print_range(model)
    print(f'T_true = {true_c:.2f} C ({how})')
    x = (true_c - fitted.reference_temperature_c) / fitted.temperature_scale_c
    removed = ', '.join(f'{axis} {np.polynomial.polynomial.polyval(x, term.bias):.3e}'
                        for axis, term in zip(recording.axes, fitted.terms))
    print(f'p(T_true) taken off the constant terms (rad/s): {removed}')
    print("written as model 'polynomial' whose bias is zero at T_true; the compensation "
          'node runs it unchanged')
    return _Fitted(polynomial_parameters(model, recording.axes),
                   f'Relative bias correction rate - (p(T) - p({true_c:.2f} C)) of '
                   f'{RELATIVE_SOURCE}, written as polynomials,\nfitted by mlx-tempcomp fit '
                   f'from {options.source}')


def _fit_linear_btc_model(options: _FitOptions, recording) -> tuple:
    rate_rad_s, formed = _rate_error(recording)
    model = fit_linear_btc(recording.temperature_c, rate_rad_s, options.t3)
    line = LinearBtc.of(model)
    how = 'given by --t3' if options.t3 is not None else 'mean temperature of the data'
    print('model linear_btc (ADIS16130 AN-1042): RBC = RATE + PBC + (TEMP - T3) x BTC, '
          f'line fitted to the {formed}')
    print(f'T3 = {line.t3_c:.2f} C ({how})')
    corrected = model.correct(rate_rad_s, recording.temperature_c).rate_rad_s
    rms = np.sqrt(np.mean(np.square(corrected), axis=0))
    print(f'{"axis":<6}{"BTC":>12}{"PBC":>12}{"RMS after":>12}{"bias slope":>14}')
    print(f'{"":<6}{"rad/s/C":>12}{"rad/s":>12}{"rad/s":>12}{"deg/s/C":>14}')
    for i, axis in enumerate(recording.axes):
        btc = line.btc_rad_s_per_c[i]
        print(f'{axis:<6}{btc:>12.3e}{line.pbc_rad_s[i]:>12.3e}{rms[i]:>12.3e}'
              f'{math.degrees(-btc):>14.6g}')
    if options.table_step is None:
        extent_c = max(abs(float(np.min(recording.temperature_c)) - line.t3_c),
                       abs(float(np.max(recording.temperature_c)) - line.t3_c))
        step_c = table_step_c(extent_c, BTC_TABLE_ROWS)
    else:
        step_c = options.table_step
    print('correction factors (TEMP - T3) x BTC, as Table 6 of the note:')
    print(format_btc_table(model, recording.axes, step_c, BTC_TABLE_ROWS))
    return _Fitted(linear_btc_parameters(model, recording.axes),
                   'ADIS16130 linear BTC/PBC correction fitted by mlx-tempcomp fit from '
                   f'{options.source}')


def _check_chain_columns(options: _FitOptions, recording) -> None:
    missing = [f'gyro_{axis}' for axis in AXIS_NAMES if axis not in recording.axes]
    if recording.reference_rad_s is None:
        missing += [f'ref_{axis}' for axis in AXIS_NAMES]
    else:
        missing += [f'ref_{axis}' for axis in AXIS_NAMES if axis not in recording.axes]
    if recording.temperature_2_c is None:
        missing.append('temperature_2')
    if missing:
        msg = (f'{options.source}: --model chain needs the columns gyro_x|y|z, ref_x|y|z and '
               f'temperature_2; missing {", ".join(missing)}')
        raise UserError(msg)


def _chain_plateaus(options: _FitOptions, recording) -> np.ndarray:
    """Give each row's plateau number (-1 off the plateaus); refuse a record without one."""
    plateau_id = find_plateaus(recording.reference_rad_s, recording.temperature_c,
                               recording.temperature_2_c)
    if not (plateau_id >= 0).any():
        msg = (f'{options.source}: no plateau: the reference rate and temperatures never hold '
               'steady for 10 samples')
        raise UserError(msg)
    return plateau_id


def _chain_full_scale(options: _FitOptions, recording) -> tuple:
    """Give the full scale in rad/s and where it came from."""
    if options.full_scale_dps is not None:
        return math.radians(options.full_scale_dps), 'given by --full-scale-dps'
    full_scale_rad_s = float(np.max(np.abs(recording.reference_rad_s)))
    if full_scale_rad_s == 0.0:
        msg = f'{options.source}: the reference rate is zero throughout; the chain needs rates'
        raise UserError(msg)
    return full_scale_rad_s, 'largest reference rate'


def _chain_temperature(value, column: np.ndarray, on_plateau: np.ndarray, option: str) -> tuple:
    """Give a reference temperature (the option's, else the plateaus' mean) and its origin."""
    if value is not None:
        return value, f'given by {option}'
    return float(np.mean(column[on_plateau])), 'mean over the plateaus'


def _print_chain(recording, plateau_id: np.ndarray, settings: ChainSettings, hows: dict,
                 result) -> None:
    """Print the plateaus, the settings asked, the fitted stages and their errors."""
    chain = result.chain
    print(f'model chain (calibration chain of {CHAIN_SOURCE}): nonlinearity, offset(T), '
          'sensitivity K(rate) C(rate), offset(T2), misalignment')
    print(f'plateaus found: {int(plateau_id.max(initial=-1)) + 1} '
          f'({np.count_nonzero(plateau_id >= 0)} of {len(recording)} rows)')
    print(f'full scale: {math.degrees(settings.full_scale_rad_s):.6g} deg/s '
          f'({hows["full_scale"]}); nonlinearity order {settings.nonlinearity_order}')
    print(f'reference temperatures asked: T {settings.reference_temperature_c:.2f} C '
          f'({hows["temperature"]}), T2 {settings.reference_temperature_2_c:.2f} C '
          f'({hows["temperature_2"]})')
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


def _fit_chain_model(options: _FitOptions, recording) -> tuple:
    _check_chain_columns(options, recording)
    plateau_id = _chain_plateaus(options, recording)
    on_plateau = plateau_id >= 0
    full_scale_rad_s, how_full_scale = _chain_full_scale(options, recording)
    temperature_c, how_t = _chain_temperature(options.reference_temperature,
                                              recording.temperature_c, on_plateau,
                                              '--reference-temperature')
    temperature_2_c, how_t2 = _chain_temperature(options.reference_temperature_2,
                                                 recording.temperature_2_c, on_plateau,
                                                 '--reference-temperature-2')
    settings = ChainSettings(
        full_scale_rad_s=full_scale_rad_s, reference_temperature_c=temperature_c,
        reference_temperature_2_c=temperature_2_c,
        nonlinearity_order=DEFAULT_CHAIN_ORDER if options.order is None else options.order)
    result = fit_chain(recording.reference_rad_s, recording.gyro_rad_s,
                       recording.temperature_c, recording.temperature_2_c, plateau_id, settings)
    _print_chain(recording, plateau_id, settings,
                 {'full_scale': how_full_scale, 'temperature': how_t, 'temperature_2': how_t2},
                 result)
    return _Fitted(chain_parameters(ChainModel(result.chain)),
                   f'Calibration chain of {CHAIN_SOURCE},\nfitted by mlx-tempcomp fit from '
                   f'{options.source}\nThe node needs the second temperature (temperature_2) '
                   'for the offset_2 stage')


_FIT_MODELS = {
    'polynomial': (_fit_polynomial_model, ('order', 'max_order', 'blocks', 'folds',
                                           'validation', 'min_past', 'baseline_margin')),
    'relative': (_fit_relative_model, ('order', 'max_order', 'blocks', 'folds', 'validation',
                                       'min_past', 'baseline_margin', 'true_temperature')),
    'linear_btc': (_fit_linear_btc_model, ('t3', 'table_step')),
    'chain': (_fit_chain_model, ('order', 'full_scale_dps', 'reference_temperature',
                                 'reference_temperature_2')),
}

# Options of some models only: refused with another instead of silently ignored.
_FIT_MODEL_OPTIONS = tuple(dict.fromkeys(name for _, names in _FIT_MODELS.values()
                                         for name in names))


def add_parser(commands) -> None:
    """Add the ``fit`` subcommand."""
    fit = commands.add_parser(
        'fit', help='fit a compensation model to a recording and write a parameter file',
        description='Fit a compensation model to a recording (CSV or rosbag2 bag) and write '
                    'a ROS 2 parameter file the compensation node loads. polynomial: a bias '
                    'polynomial per axis, the order chosen by contiguous-block '
                    'cross-validation with the one-standard-error rule; relative: the same '
                    f'polynomial made zero at a true temperature ({RELATIVE_SOURCE}); '
                    'linear_btc: the ADIS16130 line, BTC and PBC at T3; chain: the calibration '
                    f'chain of {CHAIN_SOURCE} (needs ref_x|y|z and temperature_2). The bias is '
                    'fitted to gyro minus ref when the recording has a reference, else to '
                    'gyro (at rest).')
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
    fit.add_argument('--blocks', type=non_negative_int, metavar='N',
                     help='polynomial, relative: contiguous blocks the record is cut into '
                          f'(default: {DEFAULT_BLOCKS})')
    fit.add_argument('--folds', type=non_negative_int, metavar='N',
                     help=f'polynomial, relative: round-robin folds (default: {DEFAULT_FOLDS})')
    add_validation_options(fit, 'polynomial, relative: ')
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
    add_parameter_file_options(fit)
    add_export_options(fit)
    fit.set_defaults(handler=fit_command)


def fit_command(args: argparse.Namespace) -> int:
    fit, allowed = _FIT_MODELS[args.model]
    given = [name for name in _FIT_MODEL_OPTIONS
             if getattr(args, name) is not None and name not in allowed]
    if given:
        names = ', '.join('--' + name.replace('_', '-') for name in given)
        msg = f'{names} {"does" if len(given) == 1 else "do"} not apply to --model {args.model}'
        raise UserError(msg)
    check_output_file(args.out, '--out')
    if args.model == 'chain' and (args.px4_params or args.ardupilot_parm):
        msg = ('--px4-params and --ardupilot-parm export a bias cubic; --model chain corrects '
               'rate-dependent errors no firmware cubic holds')
        raise UserError(msg)
    exports = export_request(args)
    check_export_outputs(exports)
    options = _FitOptions(
        source=args.input, order=args.order, max_order=args.max_order, blocks=args.blocks,
        folds=args.folds, validation=validation_settings(args),
        true_temperature=args.true_temperature, t3=args.t3, table_step=args.table_step,
        full_scale_dps=args.full_scale_dps, reference_temperature=args.reference_temperature,
        reference_temperature_2=args.reference_temperature_2)
    if args.model in ('polynomial', 'relative') and args.order is None:
        try:   # the held-out blocks the order is chosen on, before the record is read
            split(DEFAULT_BLOCKS if args.blocks is None else args.blocks,
                  options.validation['validation'],
                  DEFAULT_FOLDS if args.folds is None else args.folds,
                  options.validation['min_past'])
        except TempCompError as err:
            raise UserError(str(err)) from None
    recording = load(args.input, read_options(args))
    check_export_record(exports, recording)
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            fitted = fit(options, recording)
        judgement = _judgement(args, options, fit, recording)
        tracking, lines = tracking_section([recording], fitted.parameters)
    except TempCompError as err:
        msg = f'{args.input}: {err}'
        raise UserError(msg) from None
    # The judgement first: what a user reads before the fit's own tables.
    print('\n'.join(judgement.lines[:-1] + (printed.getvalue().rstrip('\n'),)
                    + judgement.lines[-1:]))
    print('\n'.join(lines))
    write_exports(exports, args.outputs, recording, lambda part: _refit(options, fit, part))
    header = fitted.header + ('\nmodel_error: the white noise of a sample per axis and the '
                              'held-out error by temperature\n(a bias error) the Imu '
                              'covariance adds up' if judgement.parameters else '')
    write_node_parameters(args.out, args.node_name, args.outputs,
                          {**fitted.parameters, **judgement.parameters, **tracking}, header)
    print(f'wrote {args.out} (model {fitted.parameters["model"]})')
    return 0


def _judgement(args: argparse.Namespace, options: _FitOptions, fit,
               recording) -> HeldOutJudgement:
    """Judge the model on held-out blocks, refitted as it was fitted (`fit_covariance`)."""
    if args.model == 'chain':
        return HeldOutJudgement({}, ('model_error not written: the chain is fitted on the '
                                     "plateaus of a rate table, not on a thermal record's "
                                     'blocks',))
    blocks = DEFAULT_BLOCKS if options.blocks is None else options.blocks
    folds = DEFAULT_FOLDS if options.folds is None else options.folds
    return held_out_judgement(recording, lambda part: _refit(options, fit, part),
                              tuple(recording.axes), blocks, folds,
                              options.validation['validation'], options.validation['min_past'])


def _refit(options: _FitOptions, fit, part):
    """Fit the same model to a part of the recording, quietly, for the exports' comparison."""
    with contextlib.redirect_stdout(io.StringIO()):
        return node_model(fit(options, part).parameters)
