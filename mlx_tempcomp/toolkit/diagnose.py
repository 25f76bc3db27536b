"""
``mlx-tempcomp diagnose``: the closed loop, its report, plots and a parameter file.

Runs `mlx_tempcomp.core.diagnosis.diagnose` on a recording, or on several
records of one unit fitted as one, and writes into ``--out DIR``:
report.md, report.json (per axis the ordered steps with their held-out error
before and after, per fold and per block, the rejected and skipped
candidates, the findings of the record-only effects; each record's offset;
a held-out record's errors as written and after a re-zero),
residual_vs_temperature.png, residual_vs_time.png, error_per_step.png,
error_by_temperature.png and params.yaml, which compensation_node loads:
live-runnable effects only, unless --record-effects put time drift and bias
steps into the search, and the held-out error by temperature
(``model_error.*``, for the Imu covariance) and the bias tracking's bounds
(``bias_tracking.*``, `toolkit.tracking`). The report says how much of the
test set and of each forward held-out block lies outside the temperature
range the model predicting it was fitted on (`uncertainty`).
``--test each`` diagnoses once per record with that record held out, then
once over all records for params.yaml.
"""

import argparse
import dataclasses
import math
from pathlib import Path

from .common import (add_recording_options, add_validation_options, check_output_folder,
                     fraction, load_records, node_name, non_negative_float, non_negative_int,
                     positive_float, UserError, validation_settings, write_json, write_result)
from .exports import (add_export_options, check_export_outputs, check_export_record,
                      write_exports)
from .progress import add_progress_option, Progress
from .tracking import tracking_section
from .uncertainty import (console_lines, error_by_temperature_json, error_lines,
                          outside_lines, outside_range_json, params_model_error,
                          plot_error_by_temperature)
from ..core.diagnosis import (DEFAULT_REZERO_S, default_rezero_s, diagnose as run_diagnosis,
                              DiagnosisSettings, METHODS, RECORD_SEARCH, rezero_window_rows,
                              SCORING, SEARCH_EFFECTS)
from ..core.effects import RECORD_EFFECTS
from ..core.errors import TempCompError
from ..core.records import join_records
from ..core.validation import FORWARD
from ..parameters.files import effect_parameters, parameter_file, write_parameter_file

PLOTS = ('residual_vs_temperature.png', 'residual_vs_time.png', 'error_per_step.png',
         'error_by_temperature.png')
CUBIC_ORDER = 3
# The other files of --out, which diagnose replaces as a whole.
OWN_FILES = ('report.md', 'report.json', 'params.yaml')
# Plots draw at most this many bins per axis (every k-th bin beyond).
MAX_PLOT_POINTS = 20000
METRIC = ('RMS and peak |.| of the residual (corrected - truth) averaged over bins of '
          '{average} on held-out rows, rad/s; averaging keeps white noise from hiding the '
          'bias')


TEST_RECORD = 'record'
TEST_EACH = 'each'
WRITTEN_OFFSET = ('the last record fitted: the robot runs after it, on that mount and '
                  'power-up; on a new run, recalibrate the ZRO at rest (imu/recalibrate_zro) '
                  "to take up that run's own offset")


def _max_order(text: str) -> int:
    """Parse --max-order: the cubic the written model is judged against needs order 3."""
    order = non_negative_int(text)
    if order < CUBIC_ORDER:
        msg = (f'expected an order of at least {CUBIC_ORDER} (the PX4-style cubic is fitted '
               f'beside every model), got {text!r}')
        raise argparse.ArgumentTypeError(msg)
    return order


def _test_part(text: str):
    """Parse --test: 'cycle', 'record', 'each' or a fraction in [0, 1) (argparse type)."""
    return text if text in ('cycle', TEST_RECORD, TEST_EACH) else fraction(text)


def add_parser(commands) -> None:
    """Add the ``diagnose`` subcommand."""
    defaults = DiagnosisSettings()
    parser = commands.add_parser(
        'diagnose', help='find the effects a temperature polynomial misses, add them, report',
        description='Fit a temperature polynomial (order by held-out blocks), then test '
                    f'each effect it lacks ({", ".join(SEARCH_EFFECTS + RECORD_SEARCH)}) on '
                    'held-out blocks and add the best significant one, until '
                    'none helps. Blocks are judged forward in time by default (each predicted '
                    'by a fit on the blocks before it). Several records of one unit are '
                    'fitted as one, each with its own history and bias offset (params.yaml '
                    "carries the last record's). Writes report.md, report.json, PNG plots and "
                    'params.yaml for the compensation node into --out.')
    add_recording_options(parser, several=True)
    parser.add_argument('--out', required=True, metavar='DIR',
                        help='folder for the report, plots and parameter file (created)')
    add_validation_options(parser)
    parser.add_argument('--folds', type=non_negative_int, default=defaults.folds, metavar='N',
                        help='round-robin folds (default: %(default)s)')
    parser.add_argument('--blocks', type=non_negative_int, default=defaults.blocks,
                        metavar='N', help='contiguous blocks the diagnosed part is cut into '
                                          '(default: %(default)s)')
    parser.add_argument('--average-s', type=non_negative_float, default=defaults.average_s,
                        metavar='S', help='bin length the residual is averaged over, 0 per '
                                          'sample (default: %(default)s)')
    parser.add_argument('--max-order', type=_max_order, default=defaults.max_order,
                        metavar='N', help='highest polynomial order tried, at least 3: the '
                                          'PX4-style cubic is fitted beside every model '
                                          '(default: %(default)s)')
    parser.add_argument('--min-gain', type=fraction, default=defaults.min_gain, metavar='F',
                        help='smallest relative held-out RMS reduction that adds an effect '
                             '(default: %(default)s)')
    parser.add_argument('--scoring', choices=SCORING, default=defaults.scoring,
                        help="which held-out rows a fold's score counts: all, or only those "
                             "inside the temperature range of the fold's training blocks (the "
                             'rest, extrapolation, reported apart) (default: %(default)s)')
    parser.add_argument('--block-tolerance', type=non_negative_float,
                        default=defaults.block_tolerance, metavar='F',
                        help='refuse an effect when a held-out block gets worse by more than F '
                             'x the larger of its RMS and the axis RMS (default: %(default)s)')
    test = parser.add_mutually_exclusive_group()
    test.add_argument('--test', type=_test_part, metavar='F|cycle|record|each',
                      help="keep a final test set: the last F of the record, 'cycle' for "
                           'the last full heating/cooling cycle (the record needs two); of '
                           "several records, 'record' holds out the last, 'each' each in "
                           'turn (leave one record out)')
    test.add_argument('--test-fraction', type=fraction, metavar='F',
                      help='same as --test F')
    parser.add_argument('--rezero-s', type=positive_float, metavar='S',
                        help='a held-out record is judged as written and after a re-zero: its '
                             'mean residual over its first S seconds taken off, as '
                             'imu/recalibrate_zro (recalibration.duration_s) does (default: the '
                             f"node's {DEFAULT_REZERO_S:g} s, longer where that holds fewer "
                             'samples than the service needs)')
    parser.add_argument('--error-bins', type=non_negative_int, default=defaults.error_bins,
                        metavar='N', help='temperature bins of the error-by-temperature table '
                                          '(equal width over the diagnosed part; params.yaml '
                                          'model_error.*) (default: %(default)s)')
    parser.add_argument('--record-effects', action='store_true',
                        help='also search time drift and bias steps, which are tied to the '
                             "record's clock, and write them into params.yaml (default: "
                             'report them as findings only)')
    parser.add_argument('--node-name', type=node_name, default='compensation_node',
                        metavar='NAME', help='node section of params.yaml (default: '
                                             '%(default)s)')
    parser.add_argument('--no-plots', action='store_true',
                        help='write the report and params.yaml without the PNG plots (and '
                             'without matplotlib)')
    add_progress_option(parser)
    add_export_options(parser)
    parser.set_defaults(handler=diagnose_command, needs=_needs)


def _needs(args: argparse.Namespace) -> list:
    """Give the optional packages diagnose will import (extras.require): the plots'."""
    return [] if args.no_plots else [('matplotlib', 'give --no-plots')]


class _Bars:
    """One progress bar per phase the diagnosis reports."""

    def __init__(self, enabled):
        self.enabled = enabled
        self.bar = None
        self.label = None
        self.run = ''

    def __call__(self, done: int, total: int, label: str) -> None:
        label = f'{self.run}{label}'
        if label != self.label:
            self.close()
            self.bar = Progress(total, f'diagnose: {label}', self.enabled)
            self.label = label
        self.bar.total = max(int(total), 1)
        self.bar.update(done)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar = None


def _check_records(args: argparse.Namespace, test) -> None:
    """Refuse what several records (or one, with --test record|each) cannot do, before work."""
    records = args.records
    twice = sorted({record for record in records if records.count(record) > 1})
    if twice:
        msg = f'{twice[0]} is given twice: give each record of the unit once'
        raise UserError(msg)
    if test in (TEST_RECORD, TEST_EACH) and len(records) < 2:
        msg = (f'{records[0]}: --test {test} holds out whole records: give two or more '
               'records of the unit, or --test F')
        raise UserError(msg)
    if len(records) > 1 and (args.px4_params or args.ardupilot_parm):
        msg = ('--px4-params and --ardupilot-parm export the cubic of one record: give one '
               f'record, not {len(records)}')
        raise UserError(msg)


def _error_text(records: list, err: Exception) -> str:
    """Name the record a diagnosis error is about, or every record when it is all of them."""
    text = str(err)
    if any(text.startswith(f'{record}:') for record in records):
        return text
    return f'{", ".join(records)}: {text}'


def _diagnoses(args: argparse.Namespace, recordings: list, settings: DiagnosisSettings,
               bars: '_Bars') -> tuple:
    """
    Return (the diagnosis written, those with a record held out).

    --test each first diagnoses with each record held out in turn (the
    others in the order given), then over all records for params.yaml.
    """
    if settings.test_record and args.test == TEST_EACH:
        records = join_records(recordings)
        for record in range(len(recordings)):  # refuse a short record before any work
            rezero_window_rows(records, record, settings.rezero_s)
        held_out = []
        for record, recording in enumerate(recordings):
            bars.run = f'record {record + 1} of {len(recordings)} held out: '
            others = recordings[:record] + recordings[record + 1:]
            held_out.append(run_diagnosis(others + [recording], settings, progress=bars))
        bars.run = 'all records: '
        written = run_diagnosis(recordings, dataclasses.replace(settings, test_record=False),
                                progress=bars)
        return written, tuple(held_out)
    diagnosis = run_diagnosis(recordings, settings, progress=bars)
    return diagnosis, (diagnosis,) if settings.test_record else ()


def _rezero_s(args: argparse.Namespace, recordings: list, test) -> float:
    """Give --rezero-s, or the window a node needs on the records held out (`default_rezero_s`)."""
    if args.rezero_s is not None:
        return args.rezero_s
    if test == TEST_EACH:
        held_out = range(len(recordings))
    elif test == TEST_RECORD:
        held_out = (len(recordings) - 1,)
    else:
        return DEFAULT_REZERO_S
    return default_rezero_s(join_records(recordings), held_out)


def diagnose_command(args: argparse.Namespace) -> int:
    exports = {Path(p).name for p in (args.px4_params, args.ardupilot_parm)
               if p is not None and Path(p).resolve().parent == Path(args.out).resolve()}
    check_output_folder(args.out, '--out', owns={*OWN_FILES, *PLOTS, *exports})
    test = args.test if args.test is not None else args.test_fraction or 0.0
    _check_records(args, test)
    check_export_outputs(args)
    try:   # the settings are checked before the records are read
        settings = DiagnosisSettings(
            folds=args.folds, blocks=args.blocks, average_s=args.average_s,
            max_order=args.max_order, min_gain=args.min_gain,
            block_tolerance=args.block_tolerance, scoring=args.scoring,
            error_bins=args.error_bins,
            test_cycle=test == 'cycle', test_record=test in (TEST_RECORD, TEST_EACH),
            test_fraction=test if isinstance(test, float) else 0.0,
            rezero_s=args.rezero_s or DEFAULT_REZERO_S,
            record_effects=args.record_effects, **validation_settings(args))
    except TempCompError as err:
        raise UserError(str(err)) from None
    recordings = load_records(args)
    check_export_record(args, recordings[0])
    bars = _Bars(True if args.progress else None)
    try:
        settings = dataclasses.replace(settings, rezero_s=_rezero_s(args, recordings, test))
        diagnosis, held_out = _diagnoses(args, recordings, settings, bars)
    except TempCompError as err:
        raise UserError(_error_text(args.records, err)) from None
    finally:
        bars.close()
    out = Path(args.out)
    source = ', '.join(args.records)
    report = _report(source, recordings, diagnosis, held_out)
    plots = () if args.no_plots else PLOTS
    try:
        folder = args.outputs.folder(out)   # replaces --out when the command is done
        write_json(folder / 'report.json', report)
        write_result(folder / 'report.md', _markdown(report, plots))
        if not args.no_plots:
            _plots(folder, diagnosis)
        model_error, _ = params_model_error(diagnosis.error_by_temperature, diagnosis.axes,
                                            diagnosis.settings.average_s)
        parameters = effect_parameters(diagnosis.model, diagnosis.axes)
        tracking, tracking_lines = tracking_section(recordings, parameters)
        content = parameter_file(args.node_name, {**parameters, **model_error, **tracking})
        record = diagnosis.model.record_effects
        header = (f'Effects model diagnosed by mlx-tempcomp diagnose from {source}\n'
                  + (f'Holds record-only effects ({", ".join(record)}): they use the stamps '
                     'of that record\n' if record else 'Live-runnable effects only\n')
                  + (f'Bias offset of {report["written_offset"]["record"]}, '
                     + WRITTEN_OFFSET.replace(': ', ':\n', 1) + '\n'
                     if len(recordings) > 1 else '')
                  + ('model_error: held-out RMS by temperature (a bias error), added to the '
                     'Imu covariance\n' if model_error else '')
                  + f'Use: compensation_node --ros-args --params-file {out / "params.yaml"}')
        write_parameter_file(folder / 'params.yaml', content, header)
    except OSError as err:
        msg = f'cannot write to {out}: {err.strerror}'
        raise UserError(msg) from None
    print(_summary(report))
    print('\n'.join(tracking_lines))
    if len(recordings) == 1:
        held = diagnosis.test_rows
        write_exports(args, recordings[0], lambda part: diagnosis.model,
                      start=len(recordings[0]) - held if held else None,
                      full_saw_held_out=not held)
    print(f'wrote {out / "report.md"}, report.json, params.yaml and '
          + (f'{len(plots)} plots' if plots else 'no plots (--no-plots)'))
    print('\n'.join(_held_out_lines(report) + _written_lines(report)))
    return 0


def _number(value):
    return float(value) if math.isfinite(value) else None


def _numbers(values) -> list:
    return [_number(v) for v in values]


def _error(error) -> dict:
    return {'rms': _number(error.rms_rad_s), 'peak': _number(error.peak_rad_s),
            'fold_rms': _numbers(error.fold_rms_rad_s)}


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, float):
        return _number(value)
    return value


def _record_effect_text(finding) -> str:
    """Say what a record-only effect is: its size and, for a step, when."""
    parameters = finding.parameters
    if finding.effect == 'bias_step':
        record = f' of {parameters["record"]}' if 'record' in parameters else ''
        return (f'a step of {parameters["step_rad_s"]:.3g} rad/s '
                f'{parameters["after_start_s"]:.1f} s after the record start{record} (stamp '
                f'{parameters["time_s"]:.1f} s)')
    return f'a drift of {3600.0 * parameters["rad_s_per_s"]:.3g} rad/s per hour'


def _cause_text(cause) -> str:
    """One sentence on the record effect that ended an axis's search."""
    return (f'{cause.effect}, {_record_effect_text(cause)}, explains the residual better '
            f'than any live effect (held-out gain {cause.held_out_gain:.3f}, round '
            f'{cause.round_number}), so no live effect stands in for it; it is tied to '
            "this record's clock: on a live node, recalibrate the ZRO at rest "
            '(imu/recalibrate_zro) after such a change')


def _finding_text(finding) -> str:
    """One sentence on a record-only effect tested on top of the final model."""
    what = _record_effect_text(finding)
    if finding.reason:
        return f'{what} would not pass: {finding.reason}'
    return (f'{what}, held-out gain {finding.held_out_gain:.3f}; ZRO recalibration at rest '
            '(imu/recalibrate_zro) covers it on a live node')


def _written(axis, terms) -> dict:
    """Return what an axis writes into params.yaml, with the figures it was chosen on."""
    choice = axis.choice
    return {'model': choice.written, 'effects': list(terms.effects),
            'polynomial_order': len(terms.bias) - 1,
            'held_out_rms': _number(choice.found.rms_rad_s),
            'cubic_held_out_rms': _number(choice.cubic.rms_rad_s),
            'ratio': _number(choice.ratio), 'margin': choice.margin,
            'other_ratio': _number(choice.other_ratio), 'reason': choice.reason}


def _gains(methods: dict) -> dict:
    """Give the PX4-style cubic's RMS over the diagnosed model's per axis (above 1: better)."""
    return {axis: _number(methods['px4_cubic'][axis].rms_rad_s / error.rms_rad_s)
            if error.rms_rad_s else None for axis, error in methods['diagnosed'].items()}


def _held_out_record(diagnosis) -> dict:
    """Describe how the model fitted on the other records does on the held-out one."""
    held = diagnosis.records[-1]
    scopes = {scope: {method: dict(zip(diagnosis.axes, errors))
                      for method, errors in diagnosis.comparison[scope].items()}
              for scope in ('test', 'test_rezeroed')}
    return {'record': held.name, 'rows': held.rows,
            'fitted_on': [r.name for r in diagnosis.records if r.fitted],
            'gain_as_written': _gains(scopes['test']),
            'gain_after_rezero': _gains(scopes['test_rezeroed']),
            'as_written': {m: {a: _error(e) for a, e in errors.items()}
                           for m, errors in scopes['test'].items()},
            'after_rezero': {m: {a: _error(e) for a, e in errors.items()}
                             for m, errors in scopes['test_rezeroed'].items()},
            'rezero_rad_s': {m: dict(zip(diagnosis.axes, offset))
                             for m, offset in diagnosis.rezero_rad_s.items()},
            'written': {axis.axis: axis.choice.written for axis in diagnosis.per_axis}}


def _geometric_mean(values) -> float:
    values = [v for v in values if v]
    return math.exp(sum(math.log(v) for v in values) / len(values)) if values else None


def _records(recordings: list, diagnosis, held_out: tuple) -> dict:
    """Return the records part of report.json: each record, the written offset, held out."""
    fits = {fit.name: fit for fit in diagnosis.records}
    written = [fit for fit in diagnosis.records if fit.fitted][-1]
    entries = [{'record': r.source, 'rows': len(r), 'duration_s': r.duration_s,
                'fitted': fits[r.source].fitted,
                'offset_rad_s': None if fits[r.source].offset_rad_s is None else
                dict(zip(diagnosis.axes, fits[r.source].offset_rad_s))} for r in recordings]
    records = [_held_out_record(d) for d in held_out]
    summary = {kind: {axis: _number(_geometric_mean(r[kind][axis] for r in records))
                      for axis in diagnosis.axes}
               for kind in ('gain_as_written', 'gain_after_rezero')} if records else None
    return {'records': entries,
            'written_offset': {'record': written.name, 'why': WRITTEN_OFFSET},
            'held_out_records': records, 'held_out_summary': summary}


def _report(source: str, recordings: list, diagnosis, held_out: tuple = ()) -> dict:
    """Return the content of report.json (all errors in rad/s)."""
    settings = diagnosis.settings
    average = f'{settings.average_s:g} s' if settings.average_s else 'one sample'
    skipped = [{'effect': effect, 'reason': reason} for effect, reason in diagnosis.skipped]
    axes = {}
    for axis, terms in zip(diagnosis.per_axis, diagnosis.model.terms):
        axes[axis.axis] = {
            'written': _written(axis, terms),
            'cause': None if axis.cause is None else {
                'effect': axis.cause.effect, 'round': axis.cause.round_number,
                'parameters': _plain(dict(axis.cause.parameters)),
                'held_out_gain': _number(axis.cause.held_out_gain),
                'text': _cause_text(axis.cause)},
            'steps': [{'effect': s.effect, 'live': s.effect not in RECORD_EFFECTS,
                       'parameters': _plain(dict(s.parameters)),
                       'rms_before': _number(s.before.rms_rad_s),
                       'rms_after': _number(s.after.rms_rad_s),
                       'peak_before': _number(s.before.peak_rad_s),
                       'peak_after': _number(s.after.peak_rad_s),
                       'fold_rms_before': _numbers(s.before.fold_rms_rad_s),
                       'fold_rms_after': _numbers(s.after.fold_rms_rad_s),
                       'block_rms_before': _numbers(s.before.block_rms_rad_s),
                       'block_rms_after': _numbers(s.after.block_rms_rad_s),
                       'round': s.round_number,
                       'held_out_gain': None if s.held_out_gain is None else
                       _number(s.held_out_gain)} for s in axis.steps],
            'rejected': [{'effect': c.effect, 'round': c.round_number,
                          'parameters': _plain(dict(c.parameters)),
                          'held_out_gain': _number(c.held_out_gain),
                          'mean_fold_improvement': _number(c.fold_improvement_rad_s),
                          'fold_improvement_standard_error':
                              _number(c.fold_improvement_se_rad_s),
                          'worst_block_change': _number(c.worst_block_change),
                          'reason': c.reason} for c in axis.rejected],
            'findings': [{'effect': f.effect, 'parameters': _plain(dict(f.parameters)),
                          'held_out_gain': _number(f.held_out_gain),
                          'passes': not f.reason, 'text': _finding_text(f)}
                         for f in axis.findings],
            'skipped': skipped,
            'polynomial_order': axis.order,
            'order_scores': [{'order': s.order, 'mean_fold_rms': _number(s.mean_rms_rad_s),
                              'standard_error': _number(s.standard_error_rad_s),
                              'fold_rms': _numbers(s.block_rms_rad_s)}
                             for s in axis.order_scores],
        }
    comparison = {scope: {method: {name: _error(error) for name, error in
                                   zip(diagnosis.axes, errors)}
                          for method, errors in methods.items()}
                  for scope, methods in diagnosis.comparison.items()}
    return {
        'source': source,
        'unit': 'rad/s',
        'metric': METRIC.format(average=average),
        'truth': diagnosis.truth,
        'rows': {'diagnosed': diagnosis.rows, 'test': diagnosis.test_rows,
                 'bins': diagnosis.bins,
                 'skipped_while_loading': _skipped_while_loading(recordings),
                 'sorted_while_loading': sum(r.sorted_rows for r in recordings)},
        'settings': {'validation': settings.validation,
                     'other_validation': settings.other_validation,
                     'min_past': settings.min_past,
                     'held_out_scheme': diagnosis.split().describe(),
                     'other_scheme': diagnosis.split(settings.other_validation).describe(),
                     'folds': settings.folds, 'blocks': settings.blocks,
                     'average_s': settings.average_s, 'max_order': settings.max_order,
                     'min_gain': settings.min_gain, 'significance': settings.significance,
                     'block_tolerance': settings.block_tolerance,
                     'baseline_margin': settings.baseline_margin,
                     'test': (('each' if held_out and not settings.test_record else 'record')
                              if held_out else 'cycle' if settings.test_cycle
                              else settings.test_fraction),
                     'rezero_s': settings.rezero_s,
                     'record_effects': settings.record_effects,
                     'temperature_rate_window_s': settings.rate_window_s},
        'effects': {'searched': list(settings.effects),
                    'record_only': sorted(RECORD_EFFECTS),
                    'in_params_yaml': sorted({e for t in diagnosis.model.terms
                                              for e in t.effects})},
        'search_bounds': {name: [float(low), float(high)]
                          for name, (low, high) in diagnosis.bounds.items()},
        'axes': axes,
        'skipped': skipped,
        'comparison': comparison,
        **_records(recordings, diagnosis, held_out),
        'outside_fitted_range': outside_range_json(diagnosis.outside_range, diagnosis.axes,
                                                   diagnosis.split(FORWARD).describe()),
        'error_by_temperature': error_by_temperature_json(diagnosis.error_by_temperature,
                                                          diagnosis.axes, settings.average_s),
    }


def _skipped_while_loading(recordings: list) -> dict:
    """Add up the rows each record skipped while loading, by reason."""
    total = {}
    for recording in recordings:
        for reason, count in recording.skipped.items():
            total[reason] = total.get(reason, 0) + count
    return total


def _e(value) -> str:
    return '-' if value is None else f'{value:.3e}'


def _table(header: tuple, rows: list) -> list:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines.extend('| ' + ' | '.join(str(cell) for cell in row) + ' |' for row in rows)
    return lines


def _parameter_text(parameters: dict) -> str:
    def show(value):
        if isinstance(value, list):
            return '[' + ', '.join(show(v) for v in value) + ']'
        if isinstance(value, float):
            return f'{value:.4g}'
        return str(value)
    return ', '.join(f'{key} {show(value)}' for key, value in parameters.items())


_METHOD_TEXT = {'none': 'no compensation', 'px4_cubic': 'PX4-style cubic in raw T',
                'temperature_polynomial': 'temperature polynomial (step 0)',
                'diagnosed': 'diagnosed model'}


def _comparison_lines(report: dict) -> list:
    lines = []
    names = list(report['axes'])
    header = ('method', *(f'{a} RMS' for a in names), *(f'{a} peak' for a in names))
    settings = report['settings']
    test = settings['test']
    held = report['held_out_records'][-1]['record'] if report['held_out_records'] else None
    scopes = {settings['validation']: f'Held-out blocks, {settings["held_out_scheme"]} '
                                      '(decides)',
              settings['other_validation']: f'Held-out blocks, {settings["other_scheme"]} '
                                            '(reported beside)',
              'test': (f'Test record {held}, as written (the written offset: its own is '
                       'unknown), never seen by the diagnosis' if held else
                       'Test set (' + ('the last full heating/cooling cycle' if test == 'cycle'
                                       else f'the last {test:g} of the record')
                       + ', never seen by the diagnosis)'),
              'test_rezeroed': f'Test record {held}, after a re-zero (its mean residual over '
                               f'its first {settings["rezero_s"]:g} s taken off, as '
                               'imu/recalibrate_zro does at rest)'}
    for scope, methods in report['comparison'].items():
        lines += ['', f'### {scopes[scope]}', '']
        rows = [(_METHOD_TEXT[m], *(_e(methods[m][a]['rms']) for a in names),
                 *(_e(methods[m][a]['peak']) for a in names)) for m in METHODS]
        lines += _table(header, rows)
        cubic, diagnosed = methods['px4_cubic'], methods['diagnosed']
        lines += ['', 'Diagnosed / PX4-style cubic, RMS: ' + ', '.join(
            f'{a} {diagnosed[a]["rms"] / cubic[a]["rms"]:.2f}x' for a in names
            if cubic[a]['rms'])]
    lines += ['', 'The cubic on held-out blocks is least squares of T^0..T^3 (raw '
                  'temperature) on the same bins; on the test set it is np.polyfit(T, rate, '
                  '3) on every row of the diagnosed part, as the PX4 script does'
              + ('; over several records each record has its own offset beside it, in the '
                 'cubic as in the diagnosed model, and both write the last one.'
                 if len(report['records']) > 1 else '.')]
    return lines


def _ratio_text(gains: dict) -> str:
    return ', '.join(f'{axis} {_gain(gain)}' for axis, gain in gains.items())


def _gain(gain) -> str:
    return '-' if gain is None else f'{gain:.2f}x'


def _held_out_lines(report: dict) -> list:
    """Per held-out record, the gain over the cubic as written and after a re-zero; summary."""
    rezero = report['settings']['rezero_s']
    lines = []
    for record in report['held_out_records']:
        lines.append(f'held out {record["record"]}: gain over the PX4-style cubic (its RMS / '
                     "the model's) as written "
                     f'{_ratio_text(record["gain_as_written"])}; '
                     f'after a re-zero over its first {rezero:g} s '
                     f'{_ratio_text(record["gain_after_rezero"])}')
    if rezero != DEFAULT_REZERO_S:
        lines.append(f'the re-zero judged here averages the first {rezero:g} s of a record; '
                     'a node re-zeroes so with recalibration.duration_s: '
                     f'{rezero:g} (its default {DEFAULT_REZERO_S:g} s)')
    summary = report['held_out_summary']
    if summary and len(report['held_out_records']) > 1:
        lines.append('leave one record out, geometric mean of the gains over the cubic: as '
                     f'written {_ratio_text(summary["gain_as_written"])}; after a re-zero '
                     f'{_ratio_text(summary["gain_after_rezero"])}')
    return lines


def _records_lines(report: dict) -> list:
    """Describe the records of a unit: rows, role, offset; the written offset; held out."""
    axes = list(report['axes'])
    lines = ['## Records', '',
             f'{len(report["records"])} records of one unit, each with its own history '
             '(lags, play operators and the rate window start at its first row) and its own '
             'bias offset (a constant per record in every fit). params.yaml carries the '
             f'offset of {report["written_offset"]["record"]}, '
             f'{report["written_offset"]["why"]}.', '']
    lines += _table(('record', 'rows', 'duration (s)', 'role',
                     *(f'{a} offset vs written (rad/s)' for a in axes)),
                    [(r['record'], r['rows'], f'{r["duration_s"]:.0f}',
                      'fitted' if r['fitted'] else 'held out',
                      *(_e(r['offset_rad_s'][a]) if r['offset_rad_s'] else '-' for a in axes))
                     for r in report['records']])
    held = report['held_out_records']
    if held:
        lines += ['', '### Held-out records', '',
                  'Each fitted on the other records, run on the held-out one from its start; '
                  "gain = the PX4-style cubic's RMS / the diagnosed model's (above 1: "
                  "better), as written and after a re-zero over the record's first "
                  f'{report["settings"]["rezero_s"]:g} s.', '']
        lines += _table(('held-out record', *(f'{a} as written' for a in axes),
                         *(f'{a} after re-zero' for a in axes), 'writes'),
                        [(r['record'], *(_gain(r['gain_as_written'][a]) for a in axes),
                          *(_gain(r['gain_after_rezero'][a]) for a in axes),
                          ', '.join(f'{a} {w}' for a, w in r['written'].items()))
                         for r in held])
        summary = report['held_out_summary']
        if len(held) > 1:
            lines += ['', 'Geometric mean over the held-out records: as written '
                      f'{_ratio_text(summary["gain_as_written"])}; after a re-zero '
                      f'{_ratio_text(summary["gain_after_rezero"])}.']
    return lines + ['']


def _axis_lines(name: str, axis: dict) -> list:
    lines = [f'## Axis {name}', '']
    if axis['cause']:
        lines += ['### Cause: a record-only effect', '', axis['cause']['text'] + '.', '']
    lines += ['### Effects added', '']
    lines += _table(('round', 'effect', 'runs on', 'fitted constants', 'RMS before',
                     'RMS after', 'peak before', 'peak after'),
                    [(s['round'], s['effect'], 'live node' if s['live'] else 'this record',
                      _parameter_text({k: v for k, v in s['parameters'].items()
                                       if k != 'bias_rad_s'}),
                      _e(s['rms_before']), _e(s['rms_after']), _e(s['peak_before']),
                      _e(s['peak_after'])) for s in axis['steps']])
    first, last = axis['steps'][0], axis['steps'][-1]
    lines += ['', '### Held-out RMS per block (step 0 -> final model)', '']
    lines += _table(('block', 'step 0', 'final', 'change'),
                    [(k, _e(before), _e(after),
                      f'{(after - before) / before:+.0%}' if before else '-')
                     for k, (before, after) in enumerate(zip(first['block_rms_after'],
                                                             last['block_rms_after']))
                     if before is not None])
    lines += ['', '### Candidates rejected', '']
    lines += _table(('round', 'effect', 'held-out gain', 'why'),
                    [(c['round'], c['effect'], f'{c["held_out_gain"]:.3f}'
                      if c['held_out_gain'] is not None else '-', c['reason'])
                     for c in axis['rejected']]) if axis['rejected'] else ['none']
    if axis['findings']:
        lines += ['', "### Record-only effects (the record's clock; not in params.yaml)", '']
        lines += [f'- {f["effect"]}: {f["text"]}' for f in axis['findings']]
    lines += ['', '### Polynomial order (step 0, one-standard-error rule)', '']
    lines += _table(('order', 'mean fold RMS', 'standard error', 'chosen'),
                    [(s['order'], _e(s['mean_fold_rms']), _e(s['standard_error']),
                      '*' if s['order'] == first['parameters']['order'] else '')
                     for s in axis['order_scores']])
    return lines + ['']


def _model_text(written: dict) -> str:
    """Name a written model: the cubic, or the polynomial order and the effects beside it."""
    if written['model'] == 'px4_cubic':
        return 'the PX4-style cubic'
    added = [e for e in written['effects'] if e != 'temperature_polynomial']
    return (f'polynomial order {written["polynomial_order"]}'
            + (' + ' + ', '.join(added) if added else ''))


def _written_lines(report: dict) -> list:
    """One line per axis: the model written, its held-out error and the cubic's."""
    scheme = report['settings']['validation'].replace('_', '-')
    lines = []
    for name, axis in report['axes'].items():
        written = axis['written']
        cubic = f'{_e(written["cubic_held_out_rms"])} rad/s'
        if written['model'] == 'px4_cubic':
            lines.append(f'axis {name}: writes the PX4-style cubic, {scheme}-validated RMS '
                         f'{cubic}; {written["reason"]}')
        else:
            lines.append(f'axis {name}: writes {_model_text(written)}, {scheme}-validated RMS '
                         f'{_e(written["held_out_rms"])} rad/s; the cubic {cubic} '
                         f'({written["ratio"]:.2f}x)')
    return lines


def _markdown(report: dict, plots=PLOTS) -> str:
    rows = report['rows']
    settings = report['settings']
    effects = report['effects']
    bounds = report['search_bounds']
    lines = [f'# Diagnosis of {report["source"]}', '',
             f'- rows diagnosed: {rows["diagnosed"]} ({rows["bins"]} bins); test rows: '
             f'{rows["test"]}; skipped while loading: '
             + (', '.join(f'{k} {v}' for k, v in rows['skipped_while_loading'].items() if v)
                or 'none')
             + (f'; rows out of time order sorted into place: {rows["sorted_while_loading"]}'
                if rows['sorted_while_loading'] else ''),
             f'- truth: {report["truth"]}; error figure: {report["metric"]}.',
             f'- held-out scheme (decides): {settings["held_out_scheme"]}; reported beside: '
             f'{settings["other_scheme"]}; stateful inputs (temperature slope over '
             f'{settings["temperature_rate_window_s"]:g} s, lags, play state) are computed '
             + ('over each record from its start' if len(report['records']) > 1 else
                'over the whole record') + ' before rows are split.',
             f'- an effect is added when its relative held-out RMS reduction is at least '
             f'{settings["min_gain"]:g}, its mean per-fold improvement exceeds '
             f'{settings["significance"]:g} standard errors and no held-out block but the '
             f'first gets worse by more than {settings["block_tolerance"]:g} x the larger of '
             'its RMS and the axis RMS; the candidate with the largest gain wins the round; '
             'the polynomial order is then chosen again.',
             '- effects searched (all run causally on a live node): '
             + ', '.join(effects['searched']) + "; record-only (tied to the record's clock): "
             + ', '.join(effects['record_only'])
             + (' -- searched too (--record-effects)' if settings['record_effects'] else
                ' -- tested as findings, not added'),
             '- search bounds: ' + '; '.join(f'{name} {low:.3g} .. {high:.3g}'
                                             for name, (low, high) in bounds.items()),
             '- step errors come from EffectModel.correct (the code the node runs) on fold '
             'models; all values in rad/s.', '']
    lines += ['## Model written (params.yaml)', '',
              f'Each axis writes the model the loop found when its held-out RMS '
              f'({settings["validation"].replace("_", "-")}) is at least '
              f'{settings["baseline_margin"]:.0%} below the PX4-style cubic\'s and, '
              f'{settings["other_validation"].replace("_", "-")}, not above it; else the '
              'cubic.', '']
    lines += [f'- {line}' for line in _written_lines(report)]
    lines.append('')
    if len(report['records']) > 1:
        lines += _records_lines(report)
    if report['skipped']:
        lines += ['## Skipped candidates', '']
        lines += [f'- {s["effect"]}: {s["reason"]}' for s in report['skipped']]
        lines.append('')
    for name, axis in report['axes'].items():
        lines += _axis_lines(name, axis)
    lines += outside_lines(report['outside_fitted_range'])
    lines += error_lines(report['error_by_temperature'], list(report['axes']))
    lines += ['## Comparison']
    lines += _comparison_lines(report)
    lines += ['', '## Plots', '']
    lines += [f'- ![{name}]({name})' for name in plots] or ['none (--no-plots)']
    return '\n'.join(lines) + '\n'


def _summary(report: dict) -> str:
    rows = report['rows']
    lines = [f'{report["source"]}: {rows["diagnosed"]} rows diagnosed in {rows["bins"]} bins'
             + (f', last {rows["test"]} rows kept as the test set' if rows['test'] else '')
             + f'; truth {report["truth"]}; errors in rad/s']
    if len(report['records']) > 1:
        lines.append(f'{len(report["records"])} records, each with its own history and bias '
                     f'offset; params.yaml carries the offset of '
                     f'{report["written_offset"]["record"]} (the last record fitted)')
    for skipped in report['skipped']:
        lines.append(f'skipped {skipped["effect"]}: {skipped["reason"]}')
    for name, axis in report['axes'].items():
        steps = axis['steps']
        chain = ' -> '.join([_e(steps[0]['rms_before'])]
                            + [f'{s["effect"]} {_e(s["rms_after"])}' for s in steps])
        lines.append(f'axis {name}: held-out RMS {chain}')
        if axis['cause']:
            lines.append(f'axis {name}: cause: {axis["cause"]["text"]}')
        lines.extend(f'axis {name}: record-only finding {f["effect"]}: {f["text"]}'
                     for f in axis['findings'] if f['passes'])
    for scope, methods in report['comparison'].items():
        for method in METHODS:
            values = ', '.join(f'{a} {_e(e["rms"])}' for a, e in methods[method].items())
            lines.append(f'{scope:<16} {method:<22} {values}')
    lines += console_lines(report)
    not_written = report['error_by_temperature']['not_written']
    if not_written:
        lines.append(not_written)
    return '\n'.join(lines)


def _every(count: int) -> slice:
    return slice(None, None, max(1, math.ceil(count / MAX_PLOT_POINTS)))


_BRANCHES = ((True, 'tab:red', 'heating'), (False, 'tab:blue', 'cooling'))


def _residual_panels(grid, axes, parts, titles, x_of) -> None:
    """Scatter each part's residuals against ``x_of(part)``, heating and cooling coloured."""
    for row, name in enumerate(axes):
        for column, (title, values) in enumerate(titles):
            plot = grid[row][column]
            for part, label, marker in parts:
                pick = _every(len(part.time_s))
                x = x_of(part)[pick]
                for heating, colour, branch in _BRANCHES:
                    mask = part.heating[pick] == heating
                    plot.scatter(x[mask], getattr(part, values)[pick, row][mask], s=3, c=colour,
                                 marker=marker, label=f'{branch}, {label}')
            plot.set_title(f'{name}: {title}')
            plot.set_ylabel('residual (rad/s)')
            plot.grid(True, alpha=0.3)
        grid[row][0].legend(markerscale=3, fontsize='small')


def _plots(out: Path, diagnosis) -> None:
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot
    from matplotlib.ticker import MaxNLocator

    axes = diagnosis.axes
    parts = [(diagnosis.held_out, 'held-out folds', 'o')]
    if diagnosis.test is not None:
        parts.append((diagnosis.test, 'test set', 'x'))
    titles = (('temperature polynomial', 'before_rad_s'), ('diagnosed', 'after_rad_s'))
    figure, grid = pyplot.subplots(len(axes), 2, figsize=(11.0, 3.2 * len(axes)),
                                   squeeze=False, sharex=True)
    _residual_panels(grid, axes, parts, titles, lambda part: part.temperature_c)
    for plot in grid[-1]:
        plot.set_xlabel('temperature (C)')
    _save(pyplot, figure, out / PLOTS[0])
    figure, grid = pyplot.subplots(len(axes), 2, figsize=(13.0, 3.0 * len(axes)),
                                   squeeze=False, sharex=True, sharey='row')
    start_s = diagnosis.held_out.time_s[0]
    if diagnosis.test is not None:
        for plot in grid.flat:
            plot.axvspan(diagnosis.test.time_s[0] - start_s,
                         diagnosis.test.time_s[-1] - start_s, color='0.9', zorder=0,
                         label='test set')
    _residual_panels(grid, axes, parts, titles, lambda part: part.time_s - start_s)
    for plot in grid[-1]:
        plot.set_xlabel('time since start (s)')
    _save(pyplot, figure, out / PLOTS[1])
    figure, plot = pyplot.subplots(figsize=(8.0, 4.5))
    for row, axis in enumerate(diagnosis.per_axis):
        values = [axis.steps[0].before.rms_rad_s] + [s.after.rms_rad_s for s in axis.steps]
        labels = ['none'] + [s.effect for s in axis.steps]
        plot.semilogy(range(len(values)), values, marker='o', label=f'axis {axis.axis}')
        for index, label in enumerate(labels):
            plot.annotate(label, (index, values[index]), fontsize=7, rotation=20,
                          textcoords='offset points', xytext=(3, 3))
    plot.set_xlabel('step')
    plot.xaxis.set_major_locator(MaxNLocator(integer=True))
    plot.set_ylabel('held-out RMS (rad/s)')
    plot.set_title('Held-out error per step')
    plot.grid(True, which='both', alpha=0.3)
    plot.legend()
    _save(pyplot, figure, out / PLOTS[2])
    plot_error_by_temperature(out / PLOTS[3], diagnosis, _save)


def _save(pyplot, figure, path: Path) -> None:
    try:
        figure.tight_layout()
        figure.savefig(path, dpi=100)
    finally:
        pyplot.close(figure)
