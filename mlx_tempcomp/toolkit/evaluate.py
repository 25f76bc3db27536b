"""
The ``mlx-tempcomp evaluate`` command: a parameter file's model run over a recording.

The model is built as ``compensation_node`` builds it: the node's parameter
defaults (`COMPENSATION_SPECS`), overridden by the node's section of the
parameter file (types and ranges checked as rcl would: `node_values`), then
`build_model`, all from `parameters`.
It runs over the whole recording in one batch, so stateful effects start at
the first sample as they do when the recording is replayed into the node; the
ZRO state file of the node is not applied. The error is the corrected rate
minus the truth: the reference rate when the recording has one, else 0 (at
rest). Statistics per axis cover every sample and averages over bins of
``--average-s`` (weighted by their sample counts), optionally only the last
``--test-fraction`` of the rows: the test part and bins `diagnose` reports.
``--track-bias`` then runs the node's bias tracking over the model's output
(`toolkit.tracking.offline_twin`) and reports the error with and without it;
``--rest-hint COLUMN`` gives it the robot's rest hint of each row (a 0/1 column).

The covariance the node would publish with each sample is judged too: the
standard deviation per axis, sqrt(noise^2 + model_error(T)^2) from the
file's ``model_error.*`` and noise (`parameters.compensation`), with
``--track-bias`` sqrt(noise^2 + the tracked offset's variance), as the node
builds it; the error over it, RMS per sample and of 60 s means
(`core.node_models.model_error.normalised_error`), over the rows evaluated. ``--out-csv``
writes it per sample (``std_*``).

``--learn`` runs the field learner with it (`core.learning`, the file's
``learning.*``) and ``--learned-params`` writes the model in use at the end
(`toolkit.learning`).
"""

import argparse
import csv
import json
from pathlib import Path
import sys

import numpy as np

from .errors import UserError
from .learning import learning_lines, learning_of, write_learned
from .loading import load, read_options
from .options import add_recording_options, float_type, positive_float
from .running import check_output_file
from .tracking import offline_twin, rest_hint_column, twin_lines
from ..core.errors import TempCompError
from ..core.mlx90609 import Output, sensor_tables
from ..core.node_models import INPUTS, ModelInputs, normalised_error
from ..core.series import bin_means, bin_starts, ErrorStatistics, test_start_row
from ..parameters.compensation import covariance_noise_of, model_error_of
from ..parameters.files import node_values
from ..parameters.models import build_model
from ..parameters.specs import axes_of, ParameterError, transfer_of
from ..recordings.bag import BagError, RawTopics
from ..recordings.bag_reader import RawBagReader


_fraction = float_type(lambda value: 0.0 < value <= 1.0, 'a fraction in (0, 1]')


def _eeprom_images(files, path: str, imu_topic: str) -> tuple:
    """Give the EEPROM images from ``files`` (--eeprom), else from the bag at ``path``."""
    if files:
        images = []
        for name in files:
            try:
                images.append(Path(name).read_bytes())
            except OSError as err:
                msg = f'cannot read EEPROM image {name}: {err.strerror}'
                raise UserError(msg) from None
        return tuple(images)
    if _is_bag(Path(path)):
        try:
            with RawBagReader(Path(path), RawTopics(imu=imu_topic)) as bag:
                if bag.eeprom is not None:
                    return bag.eeprom.images
        except BagError as err:
            raise UserError(str(err)) from None
    msg = ('the eeprom model needs the factory tables: give the EEPROM image of each chip '
           'with --eeprom IMAGE [IMAGE ...] (or a bag with an /imu/eeprom message)')
    raise UserError(msg)


def _is_bag(path: Path) -> bool:
    return path.is_dir() or path.suffix.lower() in ('.db3', '.mcap')


def _chip_temperatures(path: str, imu_topic: str, temperature_topic: str, axes: tuple,
                       time_s: np.ndarray):
    """
    Give each chip's temperature (samples, axes) from the bag at ``path``, as the node pairs them.

    With several chips and the eeprom model the node takes each chip's own
    temperature from ``<temperature topic>/<axis>``; None when the input has none.
    """
    if not _is_bag(Path(path)):
        return None
    chips = tuple(f'{temperature_topic.rstrip("/")}/{a}' for a in axes)
    by_topic = {topic: {} for topic in chips}
    try:
        with RawBagReader(Path(path), RawTopics(imu=imu_topic, temperature=temperature_topic),
                          extra_temperature_topics=chips) as bag:
            for _, topic, record in bag.records():
                if topic in by_topic:
                    by_topic[topic][record.stamp_ns] = record.temperature_c
    except BagError as err:
        raise UserError(str(err)) from None
    columns = []
    for topic in chips:
        if not by_topic[topic]:
            return None
        stamps = np.array(sorted(by_topic[topic]), dtype=np.int64)
        values = np.array([by_topic[topic][s] for s in stamps.tolist()])
        # Recording times are float seconds: match each to the nearest stamp within 1 us.
        wanted_ns = time_s * 1e9
        index = np.clip(np.searchsorted(stamps, wanted_ns), 1, len(stamps) - 1)
        index -= (wanted_ns - stamps[index - 1] < stamps[index] - wanted_ns).astype(int)
        if len(stamps) == 1:
            index = np.zeros(len(time_s), dtype=int)
        if np.any(np.abs(stamps[index] - wanted_ns) > 1e3):
            msg = f'{path}: {topic} lacks the stamps of some IMU samples'
            raise UserError(msg)
        columns.append(values[index])
    return np.column_stack(columns)


def _unknown_name(line: str, strict: bool) -> None:
    """Warn of a name of the parameter file no node has (``--strict``: refuse the file)."""
    if strict:
        raise UserError(f'{line}; --strict refuses the file')
    print(f'warning: {line}', file=sys.stderr)


def _node_values(params: str, node_name: str, strict: bool) -> tuple:
    """
    Give the node's parameter values in the file ``params`` and the axes they compensate.

    Names no node has are warned of (``strict``: refused), a misspelled name of the
    model refused, as `node_values` says.
    """
    try:
        values = node_values(params, node_name, lambda line: _unknown_name(line, strict))
    except ParameterError as err:
        raise UserError(str(err)) from None
    try:
        return values, axes_of(values)
    except ParameterError as err:
        raise UserError(f'{params}: {err}') from None


def _build(values: dict, params: str, eeprom_files, path: str, imu_topic: str):
    """
    Build the node's model from ``values`` (of the file ``params``).

    The eeprom model takes its tables from ``eeprom_files`` (--eeprom), else
    from the bag at ``path`` (`_eeprom_images`).
    """
    try:
        model = build_model(values)
        if model is None:
            tables = sensor_tables(_eeprom_images(eeprom_files, path, imu_topic), Output.DIGITAL,
                                   transfer_of(values), values['sensor.full_scale_dps'])
            model = build_model(values, tables.tables, tables.full_scale_dps)
    except ParameterError as err:
        raise UserError(f'{params}: {err}') from None
    except TempCompError as err:
        raise UserError(f'EEPROM: {err}') from None
    return model


def _statistics(error: np.ndarray, weights=None) -> dict:
    stats = ErrorStatistics.of(error, weights)
    return {'mean': stats.mean, 'sigma': stats.sigma, 'rms': stats.rms, 'peak': stats.peak,
            'samples': stats.samples}


def _write_corrected(path: str, staged, time_s: np.ndarray, temperature_c: np.ndarray,
                     axes: tuple, corrected: np.ndarray, std, twin=None) -> None:
    """
    Write time, temperature and corrected rate as a canonical CSV recording at ``staged``.

    ``path`` is its name (``staged`` its staging name, `outputs`).

    With the offline twin of bias tracking, ``gyro_*`` is tracked and ``still`` (0 or 1),
    ``offset_*`` and ``offset_std_*`` (rad/s) and ``learnt_*`` (1 in a window the axis
    learnt from) follow; with field learning, ``correction_*`` (rad/s, the learnt
    correction taken off before the offset). Last, ``std_*``: the standard deviation the
    node publishes with the rate (rad/s), when ``std`` (samples, axes) is given.
    """
    header = ['time', 'temperature'] + [f'gyro_{a}' for a in axes]
    columns = [corrected]
    if twin is not None:
        header += ['still'] + [f'{name}_{a}' for name in ('offset', 'offset_std', 'learnt')
                               for a in axes]
        columns = [twin.rate_rad_s, twin.still[:, None].astype(int), twin.offset_rad_s,
                   twin.offset_std_rad_s, twin.learnt.astype(int)]
        if twin.correction_rad_s is not None:
            header += [f'correction_{a}' for a in axes]
            columns.append(twin.correction_rad_s)
    if std is not None:
        header += [f'std_{a}' for a in axes]
        columns.append(std)
    try:
        with open(staged, 'w', newline='', encoding='utf-8') as stream:
            writer = csv.writer(stream)
            writer.writerow(header)
            for t, temperature, *row in zip(time_s.tolist(), temperature_c.tolist(),
                                            *(c.tolist() for c in columns)):
                writer.writerow([repr(t), repr(temperature)] + [repr(v) for part in row
                                                                for v in part])
    except OSError as err:
        msg = f'cannot write {path}: {err.strerror}'
        raise UserError(msg) from None


def evaluate_command(args: argparse.Namespace) -> int:
    if args.rest_hint is not None and not args.track_bias:
        raise UserError("--rest-hint is the bias tracking's input: give --track-bias with it")
    if args.learn and not args.track_bias:
        raise UserError('--learn runs with the bias tracking: give --track-bias too')
    if args.learned_params is not None and not args.learn:
        raise UserError('--learned-params writes what --learn learnt: give --learn too')
    for path, option in ((args.out_csv, '--out-csv'), (args.learned_params, '--learned-params')):
        if path is not None:
            check_output_file(path, option)
    values, axes = _node_values(args.params, args.node_name, args.strict)
    model = _build(values, args.params, args.eeprom, args.input, args.imu_topic)
    learning = learning_of(args.params, args.node_name, values, model) if args.learn else None
    recording = load(args.input, read_options(args), to_stderr=args.json)
    columns = _columns(recording, axes, model, args.params, args.input)
    inputs = ModelInputs(**{name: getattr(recording, name) for name in model.inputs})
    temperature_c = recording.temperature_c
    if model.name == 'eeprom' and len(axes) > 1:
        chips = _chip_temperatures(args.input, args.imu_topic, args.temperature_topic, axes,
                                   recording.time_s)
        if chips is None:
            print(f'note: {args.input} has no per-chip temperatures '
                  f'({args.temperature_topic}/<axis>): every chip gets the mean temperature',
                  file=sys.stderr)
        else:
            temperature_c = chips
    try:
        result = model.correct(recording.gyro_rad_s[:, columns], temperature_c, inputs)
    except TempCompError as err:
        raise UserError(f'{args.params}: the {model.name} model cannot run: {err}') from None
    corrected = result.rate_rad_s
    truth = np.zeros_like(corrected) if recording.reference_rad_s is None else \
        recording.reference_rad_s[:, columns]
    error = corrected - truth
    # The test part and bins as diagnose defines them, so the figures compare.
    part = slice(test_start_row(len(recording), args.test_fraction), len(recording))
    averaged, counts = bin_means(error[part], bin_starts(recording.time_s[part], args.average_s))
    report = {
        'input': args.input, 'params': args.params, 'model': model.name, 'axes': list(axes),
        'truth': 'reference' if recording.reference_rad_s is not None else 'zero (at rest)',
        'rows': len(recording), 'skipped': dict(recording.skipped),
        'sorted_rows': recording.sorted_rows,
        'test_fraction': args.test_fraction,
        'evaluated_from_s': float(recording.time_s[part][0]),
        'evaluated_to_s': float(recording.time_s[-1]),
        'average_s': args.average_s,
        'temperature_clamped_samples': int(np.count_nonzero(result.temperature_clamped[part]
                                                            .any(axis=1))),
        'unit': 'rad/s',
        'per_sample': {a: _statistics(error[part, i]) for i, a in enumerate(axes)},
        'averaged': {a: _statistics(averaged[:, i], counts) for i, a in enumerate(axes)},
    }
    hint = None if args.rest_hint is None else \
        (args.rest_hint, rest_hint_column(args.input, args.rest_hint, read_options(args),
                                          recording))
    twin = offline_twin(values, axes, recording, corrected, part, args.params,
                        args.average_s, hint, learning) if args.track_bias else None
    if twin:
        report['bias_tracking'] = twin.report
    noise, variance = _published_variance(values, args.params, temperature_c, twin)
    report['covariance'] = _covariance_report(noise, variance, axes, recording.time_s[part],
                                              (twin.rate_rad_s - truth)[part] if twin else
                                              error[part], variance is not None and
                                              variance[part], bool(twin))
    if args.out_csv is not None:
        _write_corrected(args.out_csv, args.outputs.file(args.out_csv), recording.time_s,
                         recording.temperature_c, axes, corrected,
                         None if variance is None else np.sqrt(variance), twin)
    written = None
    if args.learned_params is not None:
        written = write_learned(args.learned_params, args.outputs, args.params, args.node_name,
                                args.input, model, twin.learner, axes)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print('\n'.join(_text_lines(report, part.start, twin)))
    for path, line in ((args.out_csv, f'wrote {args.out_csv}'), (written, written)):
        if path is not None:
            print(line)
    return 0


def _published_variance(values: dict, params: str, temperature_c: np.ndarray, twin) -> tuple:
    """
    Give (noise per axis, the variance the node publishes per sample (samples, axes) or None).

    noise^2 + the model error's square at the temperature (`ModelErrorTable`),
    or + the tracked offset's variance with the twin; None when the noise is
    unknown (0: the node publishes a covariance of 0).
    """
    try:
        noise = np.array(covariance_noise_of(values))
        table = model_error_of(values)
    except ParameterError as err:
        raise UserError(f'{params}: {err}') from None
    if not noise.any():
        return noise, None
    if twin is not None:
        return noise, np.square(noise) + np.square(twin.offset_std_rad_s)
    temperature = np.asarray(temperature_c, dtype=np.float64)
    if table is None:
        return noise, np.broadcast_to(np.square(noise), (len(temperature), noise.size))
    return noise, table.variance(noise, temperature)


def _covariance_report(noise: np.ndarray, variance, axes: tuple, time_s: np.ndarray,
                       error: np.ndarray, part_variance, tracked: bool) -> dict:
    """Give report's ``covariance``: what the node publishes, judged on the rows evaluated."""
    section = {'noise_rad_s': dict(zip(axes, noise.tolist())), 'tracked': tracked}
    if variance is None:
        section['normalised'] = None
        return section
    judged = normalised_error(time_s, error, part_variance, noise)
    section['normalised'] = {'per_sample': dict(zip(axes, judged.per_sample)),
                             'window_means': dict(zip(axes, judged.window_means)),
                             'window_s': judged.window_s, 'windows': judged.windows}
    section['mean_std_rad_s'] = dict(zip(axes, np.mean(np.sqrt(part_variance), axis=0)
                                         .tolist()))
    return section


def _columns(recording, axes: tuple, model, params: str, path: str) -> list:
    """Give the recording's column of each axis the model compensates; refuse missing inputs."""
    missing = [a for a in axes if a not in recording.axes]
    if missing:
        msg = (f'{path} has no gyro_{", gyro_".join(missing)} but the parameter file '
               f'compensates axes {", ".join(axes)}')
        raise UserError(msg)
    for name in INPUTS:
        if name in model.inputs and getattr(recording, name) is None:
            *others, last = INPUTS[name].columns
            what = f'{", ".join(others)} and {last} columns' if others else f'a {last} column'
            msg = f'the {model.name} model of {params} needs {what}; {path} has none'
            raise UserError(msg)
    return [recording.axes.index(a) for a in axes]


def _text_lines(report: dict, start: int, twin) -> list:
    """Give the report as text: the rows evaluated (from row ``start``), the error per axis."""
    fraction = report['test_fraction']
    lines = [f'model {report["model"]} from {report["params"]}; truth: {report["truth"]}']
    which = 'every row' if start == 0 else \
        f'the last {fraction:.0%} of the rows, --test-fraction {fraction:g}'
    lines.append(f'evaluated {report["rows"] - start} samples from '
                 f'{report["evaluated_from_s"]:.1f} to {report["evaluated_to_s"]:.1f} s '
                 f'({which}); {report["temperature_clamped_samples"]} with temperature clamped')
    lines.append(f'{"axis":<6}{"":<14}{"mean":>12}{"sigma":>12}{"rms":>12}{"peak":>12}   rad/s')
    for a in report['axes']:
        for label, key in (('per sample', 'per_sample'), (f'{report["average_s"]:g} s mean',
                                                          'averaged')):
            s = report[key][a]
            lines.append(f'{a:<6}{label:<14}{s["mean"]:>12.3e}{s["sigma"]:>12.3e}'
                         f'{s["rms"]:>12.3e}{s["peak"]:>12.3e}')
    if twin:
        lines += twin_lines(twin.report, tuple(report['axes']))
        if 'learning' in twin.report:
            lines += learning_lines(twin.report['learning'], tuple(report['axes']))
    return lines + [_covariance_line(report['covariance'])]


def _covariance_line(section: dict) -> str:
    """Say how the covariance the node publishes compares with the error (1: honest)."""
    what = 'tracked' if section['tracked'] else 'model'
    judged = section['normalised']
    if judged is None:
        return 'covariance: not judged: the noise is 0 (unknown), so the node publishes 0'

    def cells(values):
        return ', '.join(f'{axis} {value:.2f}' for axis, value in values.items())
    stds = ', '.join(f'{axis} {value:.3e}' for axis, value in section['mean_std_rad_s'].items())
    return (f'covariance ({what}): mean published std {stds} rad/s; error / std (RMS, 1 = '
            f'honest, above 1 = too confident) per sample {cells(judged["per_sample"])}, '
            f'{judged["window_s"]:g} s means {cells(judged["window_means"])}')


def add_parser(commands) -> None:
    """Add the ``evaluate`` subcommand."""
    evaluate = commands.add_parser(
        'evaluate', help="run a parameter file's model over a recording and report its error",
        description='Build the compensation model from a ROS 2 parameter file as '
                    'compensation_node does, run it over the whole recording, and print per '
                    'axis the mean, sigma, RMS and peak of corrected minus true rate (the '
                    'reference columns, else 0 at rest), per sample and averaged.')
    add_recording_options(evaluate)
    evaluate.add_argument('--params', required=True, metavar='FILE',
                          help='ROS 2 parameter file (e.g. written by fit or diagnose)')
    evaluate.add_argument('--node-name', default='compensation_node', metavar='NAME',
                          help='node section to read (default: %(default)s; /** applies too)')
    evaluate.add_argument('--average-s', type=positive_float, default=1.0, metavar='S',
                          help='bin width of the averaged statistics (default: %(default)s)')
    evaluate.add_argument('--test-fraction', type=_fraction, default=1.0, metavar='F',
                          help='statistics over the last F of the rows only, the test part '
                               'of diagnose --test-fraction (default: 1)')
    evaluate.add_argument('--eeprom', nargs='+', metavar='IMAGE',
                          help='EEPROM images (128 bytes, one per axis) for the eeprom model')
    evaluate.add_argument('--json', action='store_true', help='print JSON')
    evaluate.add_argument('--out-csv', metavar='FILE',
                          help='write time, temperature and corrected rate of every sample '
                               '(with --track-bias: tracked, and the still flag and offset), '
                               'and the standard deviation the node publishes with it')
    evaluate.add_argument('--track-bias', action='store_true',
                          help="then run the node's bias tracking (bias_tracking.* of the "
                               "file) over the model's output, as the node does, and report "
                               'the error with and without it')
    evaluate.add_argument('--rest-hint', metavar='COLUMN',
                          help="with --track-bias: the robot's rest hint of each row, a 0/1 "
                               'column of the CSV record (1: at rest; inject-motion writes '
                               'rest_hint), as the node takes bias_tracking.rest_hint_topic')
    evaluate.add_argument('--learn', action='store_true',
                          help="with --track-bias: run the node's field learner too (learning.* "
                               'of the file, whatever learning.enabled says): it renews the model '
                               'from the still windows the tracker learns from')
    evaluate.add_argument('--learned-params', metavar='FILE',
                          help='with --learn: write the model in use at the end as a parameter '
                               'file (the given one with the learnt correction table)')
    evaluate.set_defaults(handler=evaluate_command)
