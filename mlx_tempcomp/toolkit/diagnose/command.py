"""The ``mlx-tempcomp diagnose`` command: its options, the run and the files it writes."""

import argparse
import dataclasses
from pathlib import Path

from .plots import PLOTS, write_plots
from .report import build_report, WRITTEN_OFFSET
from .runs import (Bars, check_records, diagnoses, error_text, held_out_rezero_s, TEST_EACH,
                   TEST_RECORD)
from .text import held_out_lines, markdown, summary, written_lines
from ..errors import UserError
from ..exports import (add_export_options, check_export_outputs, check_export_record,
                       export_request, write_exports)
from ..loading import load_records, read_options
from ..options import (add_recording_options, add_validation_options, fraction, node_name,
                       non_negative_float, non_negative_int, positive_float, validation_settings)
from ..progress import add_progress_option
from ..running import check_output_folder, write_json, write_result
from ..tracking import tracking_section
from ..uncertainty import params_model_error
from ...core.diagnosis import (DEFAULT_REZERO_S, DiagnosisSettings, RECORD_SEARCH, SCORING,
                               SEARCH_EFFECTS)
from ...core.errors import TempCompError
from ...parameters.files import effect_parameters, parameter_file, write_parameter_file

CUBIC_ORDER = 3
# The other files of --out, which diagnose replaces as a whole.
OWN_FILES = ('report.md', 'report.json', 'params.yaml')


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
                    'none helps. By default each block is predicted by a fit on the others '
                    "(round-robin), scoring only the rows inside their fit's temperature "
                    'range (extrapolation reported apart). Several records of one unit are '
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


def diagnose_command(args: argparse.Namespace) -> int:
    inside = {Path(p).name for p in (args.px4_params, args.ardupilot_parm)
              if p is not None and Path(p).resolve().parent == Path(args.out).resolve()}
    check_output_folder(args.out, '--out', owns={*OWN_FILES, *PLOTS, *inside})
    test = args.test if args.test is not None else args.test_fraction or 0.0
    check_records(args.records, test, exporting=bool(args.px4_params or args.ardupilot_parm))
    exports = export_request(args)
    check_export_outputs(exports, folder=args.out)
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
    recordings = load_records(args.records, read_options(args))
    check_export_record(exports, recordings[0])
    diagnosis, held_out = _run(recordings, settings, test, args.rezero_s, args.records,
                               args.progress)
    out = Path(args.out)
    report = build_report(', '.join(args.records), recordings, diagnosis, held_out)
    plots = () if args.no_plots else PLOTS
    try:
        folder = args.outputs.folder(out)   # replaces --out when the command is done
        write_json(folder / 'report.json', report)
        write_result(folder / 'report.md', markdown(report, plots))
        if plots:
            write_plots(folder, diagnosis)
        tracking_lines = _write_parameters(folder / 'params.yaml', out / 'params.yaml',
                                           args.node_name, report, diagnosis, recordings)
    except OSError as err:
        msg = f'cannot write to {out}: {err.strerror}'
        raise UserError(msg) from None
    print(summary(report))
    print('\n'.join(tracking_lines))
    if len(recordings) == 1:
        held = diagnosis.test_rows
        write_exports(exports, args.outputs, recordings[0], lambda part: diagnosis.model,
                      start=len(recordings[0]) - held if held else None,
                      full_saw_held_out=not held)
    print(f'wrote {out / "report.md"}, report.json, params.yaml and '
          + (f'{len(plots)} plots' if plots else 'no plots (--no-plots)'))
    print('\n'.join(held_out_lines(report) + written_lines(report)))
    return 0


def _run(recordings: list, settings: DiagnosisSettings, test, given_rezero_s, records: list,
         progress: bool) -> tuple:
    """Run the diagnoses (`runs.diagnoses`) with progress bars; a TempCompError is the user's."""
    bars = Bars(True if progress else None)
    try:
        window_s = held_out_rezero_s(given_rezero_s, recordings, test)
        settings = dataclasses.replace(settings, rezero_s=window_s)
        return diagnoses(recordings, settings, test, bars)
    except TempCompError as err:
        raise UserError(error_text(records, err)) from None
    finally:
        bars.close()


def _write_parameters(path: Path, named: Path, node_name: str, report: dict, diagnosis,
                      recordings: list) -> list:
    """
    Write params.yaml at ``path`` (its staging name; ``named`` its own); give the tracking's lines.

    It holds the diagnosed model, its error by temperature (``model_error.*``)
    and the bias tracking's bounds (``bias_tracking.*``).
    """
    model_error, _ = params_model_error(diagnosis.error_by_temperature, diagnosis.axes)
    parameters = effect_parameters(diagnosis.model, diagnosis.axes)
    tracking, tracking_lines = tracking_section(recordings, parameters)
    content = parameter_file(node_name, {**parameters, **model_error, **tracking})
    record = diagnosis.model.record_effects
    header = (f'Effects model diagnosed by mlx-tempcomp diagnose from {report["source"]}\n'
              + (f'Holds record-only effects ({", ".join(record)}): they use the stamps '
                 'of that record\n' if record else 'Live-runnable effects only\n')
              + (f'Bias offset of {report["written_offset"]["record"]}, '
                 + WRITTEN_OFFSET.replace(': ', ':\n', 1) + '\n'
                 if len(recordings) > 1 else '')
              + ('model_error: the white noise of a sample per axis and the held-out error '
                 'by temperature\n(a bias error) the Imu covariance adds up\n'
                 if model_error else '')
              + f'Use: compensation_node --ros-args --params-file {named}')
    write_parameter_file(path, content, header)
    return tracking_lines
