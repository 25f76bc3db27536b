"""
The test part: where it starts, its re-zero, and the figures the written model rests on.

The test part is the rows after the diagnosed part (a fraction, the last
cycle or the last record), which no fit sees. Here it is judged as written
and, for a held-out record, after a re-zero; and the written model's
held-out error is tabled by temperature and the rows it runs clamped are
counted (the package docstring's last paragraph).
"""

import functools
from typing import Optional

import numpy as np

from .data import effective_temperature
from .folds import weighted_rms
from .problem import DiagnosisProblem
from .results import BinnedResidual, ErrorByTemperature, HeldOutError, METHODS, OutsideFittedRange
from .settings import DEFAULT_REZERO_S, DiagnosisSettings, REZERO_MIN_SAMPLES
from ..effects import EffectModel, temperature_rate_c_s
from ..errors import CalibrationError, ConfigError
from ..fitting import (error_by_temperature, FORWARD, held_out_outside_range, outside_range,
                       temperature_bin_edges)
from ..node_models import larger_table, normalised_error, NormalisedError, sample_noise_rad_s
from ..series import bin_means, bin_starts, last_cycle_start_row, test_start_row


def diagnosed_rows(recording, settings: DiagnosisSettings) -> int:
    """
    Return the first row of the test part: the last record, fraction or full cycle.

    Refuse what several records cannot do, and a held-out record too short
    to re-zero, before any work.
    """
    records = recording.count
    if records > 1 and settings.record_effects:
        msg = ("record-only effects run on one record's clock: with several records they "
               'are findings only (leave out --record-effects)')
        raise CalibrationError(msg)
    if settings.test_record:
        if records < 2:
            msg = (f'{recording.names[0]} is the only record: holding out the last record '
                   'needs two or more')
            raise CalibrationError(msg)
        rezero_window_rows(recording, records - 1, settings.rezero_s)
        return recording.starts[-2]
    if records > 1 and (settings.test_cycle or settings.test_fraction):
        msg = ('with several records, hold out a whole record (--test record or --test '
               'each), not a part of the last one')
        raise CalibrationError(msg)
    if not settings.test_cycle:
        return test_start_row(len(recording.time_s), settings.test_fraction)
    try:
        return last_cycle_start_row(recording.temperature_c)
    except ConfigError as err:
        raise CalibrationError(str(err)) from None


def heating_bins(problem: DiagnosisProblem, rows: slice, starts: np.ndarray) -> np.ndarray:
    slope = problem.each(functools.partial(temperature_rate_c_s,
                                           window_s=problem.settings.rate_window_s),
                         problem.full.time_s, problem.full.temperature_c)[rows]
    return np.add.reduceat(slope, starts) >= 0.0


def _errors(binned: np.ndarray, counts: np.ndarray) -> tuple:
    """Give the `HeldOutError` (RMS and peak) per axis of binned residuals (bins, axes)."""
    return tuple(HeldOutError(weighted_rms(binned[:, a], counts),
                              float(np.max(np.abs(binned[:, a]))))
                 for a in range(binned.shape[1]))


def compare_test(problem: DiagnosisProblem, base_model: EffectModel, model: EffectModel) -> tuple:
    """
    Return (errors per method on the test part, binned residual before/after, re-zero, residual).

    The errors map 'test' and, when the test part is a record, 'test_rezeroed'
    (each residual less its mean over the record's re-zero window) to the
    errors per method; re-zero maps each method to what the window took off
    per axis (empty without a test record); residual is the written model's
    per sample (rows, axes).
    """
    full = problem.full
    test = slice(problem.rows, len(full.time_s))
    rows = len(full.time_s) - problem.rows
    starts = bin_starts(full.time_s[test], problem.settings.average_s)
    shape = (rows, len(problem.axes))
    residuals = {method: np.empty(shape) for method in METHODS}
    truth = 0.0 if full.reference_rad_s is None else full.reference_rad_s[test]
    # The cubic as PX4 runs it: fitted on the diagnosed rows, the written (last) record's
    # offset, clamped at its fitted range (`baseline`).
    cubic = problem.cubics()[-1]
    residuals['px4_cubic'] = cubic.corrected(full.gyro_rad_s[test], full.temperature_c[test]) \
        - truth
    residuals['none'] = full.gyro_rad_s[test] - truth
    for axis in range(len(problem.axes)):
        residuals['temperature_polynomial'][:, axis] = problem.test_residual(base_model, axis)
        residuals['diagnosed'][:, axis] = problem.test_residual(model, axis)
    binned, scopes = {}, {'test': {}}
    for method, values in residuals.items():
        binned[method], counts = bin_means(values, starts)
        scopes['test'][method] = _errors(binned[method], counts)
    rezero = {}
    if problem.settings.test_record:
        window = rezero_window_rows(full, full.count - 1, problem.settings.rezero_s)
        rezero = {method: values[:window].mean(axis=0) for method, values in residuals.items()}
        scopes['test_rezeroed'] = {method: _errors(*bin_means(values - rezero[method], starts))
                                   for method, values in residuals.items()}
    counts = np.diff(np.append(starts, rows)).astype(np.float64)
    part = BinnedResidual(
        time_s=np.add.reduceat(full.time_s[test], starts) / counts,
        temperature_c=np.add.reduceat(full.temperature_c[test], starts) / counts,
        heating=heating_bins(problem, test, starts),
        before_rad_s=binned['temperature_polynomial'], after_rad_s=binned['diagnosed'],
        rows=counts, cubic_rad_s=binned['px4_cubic'])
    return scopes, part, {method: tuple(float(v) for v in offset)
                          for method, offset in rezero.items()}, residuals['diagnosed']


def default_rezero_s(records, held_out) -> float:
    """
    Give the re-zero window a node needs on the ``held_out`` records (indices).

    The node's default (DEFAULT_REZERO_S, its recalibration.duration_s), or,
    where the samples come slower, as long as it takes to hold the
    REZERO_MIN_SAMPLES the service needs (9 s at 1 Hz): a user at that rate
    sets recalibration.duration_s so, and the judgement should run as that node.
    """
    window_s = DEFAULT_REZERO_S
    for record in held_out:
        rows = records.rows(record)
        since = records.time_s[rows] - records.time_s[rows.start]
        if since.size >= REZERO_MIN_SAMPLES:
            window_s = max(window_s, float(since[REZERO_MIN_SAMPLES - 1]))
    return window_s


def rezero_window_rows(records, record: int, window_s: float) -> int:
    """
    Return how many first rows of a record the node's ZRO recalibration would average.

    ``imu/recalibrate_zro`` takes samples from the first until one lies
    ``window_s`` after it, and refuses fewer than REZERO_MIN_SAMPLES; the
    sensor must be at rest (a reference rate, if recorded, zero). Raise
    CalibrationError naming the record otherwise.
    """
    rows = records.rows(record)
    since = records.time_s[rows] - records.time_s[rows.start]
    name = records.names[record]
    if since[-1] < window_s:
        msg = (f'{name}: the record lasts {since[-1]:.3g} s, shorter than the re-zero window '
               f'of {window_s:g} s (--rezero-s)')
        raise CalibrationError(msg)
    count = int(np.searchsorted(since, window_s)) + 1
    if count < REZERO_MIN_SAMPLES:
        needed = since[min(REZERO_MIN_SAMPLES, since.size) - 1]
        msg = (f'{name}: its first {window_s:g} s hold {count} samples, and imu/recalibrate_zro '
               f'refuses fewer than {REZERO_MIN_SAMPLES}: give --rezero-s {needed:g} or more')
        raise CalibrationError(msg)
    reference = records.reference_rad_s
    if reference is not None and np.any(reference[rows][:count] != 0.0):
        msg = (f'{name}: the reference rate is not zero in its first {window_s:g} s: the '
               're-zero needs the sensor at rest there')
        raise CalibrationError(msg)
    return count


def outside_fitted_range(problem: DiagnosisProblem, specs: tuple,
                         model: EffectModel) -> OutsideFittedRange:
    """
    Measure which rows the written model and the folds' models run clamped.

    Each axis's effective temperature over the whole record (history states
    from its start, as the node runs them), against the range of the blocks
    before each forward block, of each deciding fold's training blocks, and
    against the written model's range.
    """
    full = problem.full
    slope = problem.each(functools.partial(temperature_rate_c_s,
                                           window_s=problem.settings.rate_window_s),
                         full.time_s, full.temperature_c)
    lags = [spec.thermal_lag_s for spec in specs]
    effective = np.column_stack([effective_temperature(problem.records, full.time_s,
                                                       full.temperature_c, slope, lag)
                                 for lag in lags])
    blocks = held_out_outside_range(effective[:problem.rows], problem.block_edges,
                                    problem.folds_of(FORWARD).split)
    test = outside_range(effective[problem.rows:], model.temperature_min_c,
                         model.temperature_max_c) if problem.test_rows else None
    deciding = problem.settings.validation
    deciding_blocks = None if deciding == FORWARD else held_out_outside_range(
        effective[:problem.rows], problem.block_edges, problem.folds.split)
    return OutsideFittedRange(len(set(lags)) > 1, blocks, test, deciding, deciding_blocks)


def written_error_by_temperature(problem: DiagnosisProblem, held_out: BinnedResidual,
                                 other: np.ndarray, test: Optional[BinnedResidual]
                                 ) -> ErrorByTemperature:
    """
    Bin the written model's held-out (and test) residuals by temperature; build its table.

    The held-out bins of each scheme are those its folds count (inside their
    training range with scoring 'inside'): the bins' mean squares add up to
    the held-out RMS. ``other`` holds the binned residuals of the scheme
    beside the deciding one. The table takes per bin the larger bias part of
    the two (`model_error.larger_table`): one of them is forward, the model
    run later in time than it was fitted, which is how the node runs it; the
    white noise of the diagnosed rows (`model_error.sample_noise_rad_s`) is
    taken out of both, as the node adds it apart.
    """
    temperature = problem.temperature
    edges = temperature_bin_edges(float(np.min(temperature)), float(np.max(temperature)),
                                  problem.settings.error_bins)
    scheme = problem.settings.other_validation
    tables = []
    for folds, residual in ((problem.folds, held_out.after_rad_s),
                            (problem.folds_of(scheme), other)):
        counted = np.where(folds.scored[:, None], residual, np.nan)
        tables.append(error_by_temperature(held_out.temperature_c, counted, held_out.rows,
                                           edges))
    test_table = None if test is None else error_by_temperature(
        test.temperature_c, test.after_rad_s, test.rows, edges)
    reference = held_out if test is None else test
    cubic = None if reference.cubic_rad_s is None else error_by_temperature(
        reference.temperature_c, reference.cubic_rad_s, reference.rows, edges)
    noise = sample_noise_rad_s([problem.error_rows[rows]
                                for rows in problem.records.segments(problem.rows)])
    try:
        table = larger_table(tuple(tables), noise)
    except CalibrationError:
        table = None
    return ErrorByTemperature(problem.settings.validation, tables[0],
                              float(np.mean(problem.counts)), test_table, scheme, tables[1],
                              tuple(float(v) for v in noise), table, cubic)


def test_normalised_error(problem: DiagnosisProblem, errors: ErrorByTemperature,
                          residual: np.ndarray) -> Optional[NormalisedError]:
    """Judge the covariance the written file publishes on the test part (as written)."""
    if errors.table is None:
        return None
    full = problem.full
    test = slice(problem.rows, len(full.time_s))
    variance = errors.table.variance(errors.noise_rad_s, full.temperature_c[test])
    return normalised_error(full.time_s[test], residual, variance, errors.noise_rad_s)
