"""
Bias tracking in the toolkit: the section ``fit`` and ``diagnose`` write, and the offline twin.

`tracking_section` derives the ``bias_tracking.*`` values of a unit from its records and
the model a command writes (`core.standstill.tracking_bounds`): the written model is built from its
parameters as the node builds it and run over each record, and the residual it leaves
gives the noise, the random walk and the bounds.

`offline_twin` is ``mlx-tempcomp evaluate --track-bias``: the `BiasTracking` the node runs,
built from the parameter file's ``bias_tracking.*`` by the same `tracking_settings`, over
the model's output of the whole record in one block (the node gets blocks of 1 to
``max_block`` samples: the same bits, ``test/core/test_fuzz_bias_tracking.py``). Its report
compares the error with and without tracking, at rest and in motion when the record has
a reference (moving: any reference rate not zero). ``--rest-hint COLUMN`` gives each sample
the hint of its row, a 0/1 column of a CSV record (1: the robot said it was at rest;
`rest_hint_column`), as the node takes the robot's messages (`core.standstill.rest_hints`). With
``--learn`` the field learner rides on the tracker (`core.learning.LearningTracking`, the
same bits for any split too).
"""

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Optional

import numpy as np

from .errors import UserError
from .tables import bounds_lines
from ..core.errors import TempCompError
from ..core.learning import FieldLearner, LearningTracking
from ..core.node_models import ModelInputs
from ..core.series import bin_means, bin_starts, ErrorStatistics
from ..core.standstill import BiasTracking, derive_bounds, RestRecord
from ..parameters.files import node_model
from ..parameters.tracking import tracking_parameters, tracking_settings
from ..recordings.columns import column_preset, parse_column_map
from ..recordings.csv_reader import load_csv_column
from ..recordings.flightlog import is_flight_log
from ..recordings.load import BAG_SUFFIXES
from ..recordings.recording import RecordingError


def model_residual(model, recording, axes) -> np.ndarray:
    """Give the rate the model leaves on ``recording`` less its reference (rows, axes)."""
    columns = [recording.axes.index(a) for a in axes]
    inputs = ModelInputs(**{name: getattr(recording, name) for name in model.inputs})
    corrected = model.correct(recording.gyro_rad_s[:, columns], recording.temperature_c,
                              inputs).rate_rad_s
    if recording.reference_rad_s is not None:
        corrected = corrected - recording.reference_rad_s[:, columns]
    return corrected


def _rest_records(model, recording, axes) -> list:
    """Give the record's parts at rest (all of it without a reference) with their residual."""
    residual = model_residual(model, recording, axes)
    if recording.reference_rad_s is None:
        runs = [(0, len(recording))]
    else:
        runs = _runs(~np.any(recording.reference_rad_s != 0.0, axis=1))
    acceleration = recording.acceleration_m_s2
    return [RestRecord(recording.time_s[a:b], residual[a:b], recording.temperature_c[a:b],
                       None if acceleration is None else acceleration[a:b])
            for a, b in runs if b - a > 2]


def tracking_section(recordings: list, parameters: dict) -> tuple:
    """
    Give (``bias_tracking`` section, console lines) for the model ``parameters`` describe.

    The bounds come from the records at rest: with a reference, the rows where it is zero.
    An empty section and a line saying why when the records cannot give the bounds.
    """
    model = node_model(parameters)
    axes = tuple(parameters['axes'])
    records = [part for r in recordings for part in _rest_records(model, r, axes)]
    try:
        values, notes = derive_bounds(records)
    except TempCompError as err:
        return {}, [f'bias tracking: not derived ({err}); the node uses its defaults']
    return tracking_parameters(**values), bounds_lines(values, axes, notes)


@dataclass(frozen=True)
class TwinResult:
    """
    What the offline twin gives: the tracked rate, per sample, and its report.

    With field learning, ``correction_rad_s`` is the learnt correction taken off each
    sample (before the tracker's offset) and ``learner`` the `FieldLearner` at the end.
    """

    rate_rad_s: np.ndarray
    offset_rad_s: np.ndarray
    offset_std_rad_s: np.ndarray
    still: np.ndarray
    learnt: np.ndarray
    report: dict
    correction_rad_s: Optional[np.ndarray] = None
    learner: Optional[FieldLearner] = None


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else math.nan


def _runs(mask: np.ndarray) -> list:
    """Give (start, end) rows of each run of True."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _statistics(error: np.ndarray) -> dict:
    stats = ErrorStatistics.of(error)
    return {'mean': stats.mean, 'sigma': stats.sigma, 'rms': stats.rms, 'peak': stats.peak,
            'samples': stats.samples}


def _gain(without: np.ndarray, with_: np.ndarray) -> float:
    return _rms(without) / _rms(with_) if _rms(with_) > 0.0 else math.inf


def _axis_report(without: np.ndarray, with_: np.ndarray, moving, starts) -> dict:
    (averaged_without, _), (averaged_with, _) = (bin_means(error, starts)
                                                 for error in (without, with_))
    report = {'without': _statistics(without), 'with': _statistics(with_),
              'gain': _gain(without, with_),
              'averaged_rms': {'without': _rms(averaged_without),
                               'with': _rms(averaged_with)},
              'averaged_gain': _gain(averaged_without, averaged_with)}
    if moving is not None:
        report['still_rms'] = {'without': _rms(without[~moving]), 'with': _rms(with_[~moving])}
        report['moving_rms'] = {'without': _rms(without[moving]), 'with': _rms(with_[moving])}
        ratios = [(_rms(with_[a:b]) / _rms(without[a:b]), a, b) for a, b in _runs(moving)
                  if _rms(without[a:b]) > 0.0]
        report['worst_moving_segment'] = None
        if ratios:
            ratio, first, end = max(ratios)
            report['worst_moving_segment'] = {'ratio': ratio, 'rows': [first, end]}
    return report


def learnt_mask(tracker: BiasTracking, time_s: np.ndarray) -> np.ndarray:
    """Give per sample and axis whether the tracker learnt from the window holding it."""
    mask = np.zeros((time_s.size, len(tracker.axes)), dtype=bool)
    for record in tracker.windows:
        for start_s, end_s, axes in record.learnt:
            rows = (time_s >= start_s) & (time_s < end_s)
            mask[np.ix_(rows, list(axes))] = True
    return mask


def _learnt_in_motion(tracker: BiasTracking, learnt: np.ndarray, time_s: np.ndarray,
                      reference: np.ndarray) -> dict:
    """
    Say how much the reference moved where the tracker learnt, on the axes it learnt.

    Samples learnt from while the reference was not zero; the largest reference rate
    there; the largest mean reference over a learnt window (what it could have taken).
    """
    largest_mean = np.zeros(reference.shape[1])
    for record in tracker.windows:
        for start_s, end_s, axes in record.learnt:
            rows = (time_s >= start_s) & (time_s < end_s)
            if rows.any():
                means = np.abs(reference[rows].mean(axis=0))
                for axis in axes:
                    largest_mean[axis] = max(largest_mean[axis], means[axis])
    moving = learnt & (reference != 0.0)
    return {'samples': int(np.count_nonzero(moving.any(axis=1))),
            'largest_reference_rad_s': np.max(np.abs(np.where(learnt, reference, 0.0)),
                                              axis=0, initial=0.0).tolist(),
            'largest_mean_reference_rad_s': largest_mean.tolist()}


def rest_hint_column(path: str, name: str, options, recording) -> np.ndarray:
    """
    Give the 0/1 column ``name`` of the CSV record at ``path`` for each row of ``recording``.

    The file is read with the recording's column map (``options``: --preset or --columns)
    and each row of the recording takes the value of the file's row with its time; a
    value other than 0 or 1 on such a row is a UserError naming the column and the line.
    """
    where = Path(path)
    if where.is_dir() or where.suffix.lower() in BAG_SUFFIXES or is_flight_log(where):
        msg = f'--rest-hint reads a 0/1 column of a CSV record; {path} is not one'
        raise UserError(msg)
    try:
        columns = column_preset(options.preset) if options.preset is not None else \
            parse_column_map(options.columns) if options.columns is not None else None
        time_s, cells, lines = load_csv_column(path, name, *([columns] if columns else []))
    except RecordingError as err:
        raise UserError(f'--rest-hint {name}: {err}') from None
    order = np.argsort(time_s, kind='stable')
    rows = order[np.clip(np.searchsorted(time_s[order], recording.time_s), 0, order.size - 1)]
    if not np.array_equal(time_s[rows], recording.time_s):
        msg = f'{path}: --rest-hint {name}: the rows of the record were not found by their time'
        raise UserError(msg)
    values = cells[rows]
    good = np.isin(np.char.strip(values), ('0', '1', '0.0', '1.0'))
    if not good.all():
        bad = int(np.flatnonzero(~good)[0])
        msg = (f'{path}: line {lines[rows[bad]]}: --rest-hint column {name!r} holds '
               f'{str(values[bad])!r}; it takes 0 (moving) or 1 (at rest)')
        raise UserError(msg)
    return np.char.strip(values).astype(float) == 1.0


def offline_twin(values: dict, axes: tuple, recording, corrected: np.ndarray, part: slice,
                 source: str, average_s: float, rest_hint=None, learning=None) -> TwinResult:
    """
    Track ``corrected`` (the model's output of every row) as the node would; see above.

    Figures over the rows of ``part``, per sample and of means over ``average_s`` bins.
    ``rest_hint``: (name, each row's hint) or None.
    ``learning(tracking settings)`` gives the `LearningSettings` of field learning, run
    with the tracker (`core.learning.LearningTracking`); None: tracking alone.
    """
    try:
        settings = tracking_settings(values, axes, values['rate_noise_rad_s'])
        if settings is None:
            msg = f'{source} turns bias tracking off (bias_tracking.enabled: false)'
            raise UserError(msg)
        tracker = BiasTracking(settings, axes, keep_windows=True)
        stream = None if learning is None else \
            LearningTracking(tracker, FieldLearner(learning(settings), axes))
    except TempCompError as err:
        raise UserError(f'{source}: {err}') from None
    hint = None if rest_hint is None else rest_hint[1]
    out = (tracker if stream is None else stream).process(
        recording.time_s, corrected, recording.temperature_c, recording.acceleration_m_s2, hint)
    correction = None if stream is None else out.correction_rad_s
    columns = [recording.axes.index(a) for a in axes]
    truth = 0.0 if recording.reference_rad_s is None else \
        recording.reference_rad_s[:, columns]
    moving = None if recording.reference_rad_s is None else \
        np.any(recording.reference_rad_s[part] != 0.0, axis=1)
    without, with_ = (corrected - truth)[part], (out.rate_rad_s - truth)[part]
    status = tracker.status()
    starts = bin_starts(recording.time_s[part], average_s)
    report = {
        'axes': {a: _axis_report(without[:, i], with_[:, i], moving, starts)
                 for i, a in enumerate(axes)},
        'average_s': average_s,
        'windows': tracker.window_count,
        'learnt_windows': sum(len(w.learnt) for w in tracker.windows),
        'updates': tracker.updates, 'shifts_withdrawn': tracker.withdrawn,
        'still_share_found': float(np.mean(out.still[part])),
        'final': {'offset_rad_s': list(status.offset_rad_s),
                  'std_rad_s': list(status.std_rad_s), 'stable': list(status.stable)},
        'settings': {'window_s': settings.standstill.window_s,
                     'max_mean_rate_rad_s': settings.standstill.max_mean_rate_rad_s,
                     'rest_hint_max_age_s': settings.rest_hint_max_age_s,
                     'zero_at_start': settings.zero_at_start},
        'hinted_windows': sum(w.hinted for w in tracker.windows),
    }
    if rest_hint is not None:
        report['rest_hint'] = {'column': rest_hint[0],
                               'at_rest_share': float(np.mean(rest_hint[1][part]))}
    learnt = learnt_mask(tracker, recording.time_s)
    if moving is not None:
        report['still_share_true'] = float(np.mean(~moving))
        report['learnt_while_moving'] = _learnt_in_motion(
            tracker, learnt[part], recording.time_s[part],
            recording.reference_rad_s[part][:, columns])
    offset = corrected - out.rate_rad_s
    if stream is not None:
        offset = offset - correction
        report['learning'] = {**stream.learner.status(), 'swaps': stream.learner.swaps}
    return TwinResult(rate_rad_s=out.rate_rad_s, offset_rad_s=offset,
                      offset_std_rad_s=out.std_rad_s, still=out.still, learnt=learnt,
                      report=report, correction_rad_s=correction,
                      learner=None if stream is None else stream.learner)


def twin_lines(report: dict, axes: tuple) -> list:
    """Print the offline twin's figures per axis (RMS, rad/s)."""
    lines = [f'bias tracking: {report["windows"]} windows, {report["learnt_windows"]} learnt '
             f'({report["shifts_withdrawn"]} shifts withdrawn); still '
             f'{100 * report["still_share_found"]:.1f} % of the samples'
             + (f' (truly {100 * report["still_share_true"]:.1f} %)'
                if 'still_share_true' in report else '')]
    if 'rest_hint' in report:
        lines.append(f'rest hint {report["rest_hint"]["column"]}: at rest '
                     f'{100 * report["rest_hint"]["at_rest_share"]:.1f} % of the samples; '
                     f'{report["hinted_windows"]} windows hinted (the mean-rate bound lifted)')
    elif report['settings']['zero_at_start']:
        lines.append(f'zero at start: {report["hinted_windows"]} windows taken as at rest '
                     'before the first still run')
    moving = 'still_share_true' in report
    header = f'{"axis":<6}{"without":>12}{"with":>12}{"gain":>8}{"mean gain":>10}'
    if moving:
        header += f'{"still w/o":>12}{"still with":>12}{"moving w/o":>12}' \
                  f'{"moving with":>12}{"worst seg":>10}'
    lines.append(header + '   RMS rad/s per sample; mean gain: of the '
                 f'{report["average_s"]:g} s means; worst seg: RMS with / without')
    for a in axes:
        s = report['axes'][a]
        line = (f'{a:<6}{s["without"]["rms"]:>12.3e}{s["with"]["rms"]:>12.3e}{s["gain"]:>8.2f}'
                f'{s["averaged_gain"]:>10.2f}')
        if moving:
            worst = s['worst_moving_segment']
            line += (f'{s["still_rms"]["without"]:>12.3e}{s["still_rms"]["with"]:>12.3e}'
                     f'{s["moving_rms"]["without"]:>12.3e}{s["moving_rms"]["with"]:>12.3e}'
                     f'{worst["ratio"] if worst else math.nan:>10.2f}')
        lines.append(line)
    if moving:
        learnt = report['learnt_while_moving']
        largest = ', '.join(f'{a} {v:.2e}' for a, v in
                            zip(axes, learnt['largest_reference_rad_s']))
        mean = ', '.join(f'{a} {v:.2e}' for a, v in
                         zip(axes, learnt['largest_mean_reference_rad_s']))
        lines.append(f'samples learnt from while the reference moved on a learnt axis: '
                     f'{learnt["samples"]}; the largest reference rate there {largest}, over a '
                     f'learnt window {mean} rad/s')
    return lines
