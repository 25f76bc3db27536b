"""
One diagnosis's data: `DiagnosisProblem` holds its rows, bins, folds and cached features.

It scores an `AxisSpec` on the held-out bins of each fold (least squares on
bin means, the polynomial clamped as each fold's model runs it), fits the
models the folds and the written file hold, and runs them over the record
as the node does. The PX4-style cubic (`core.baseline`) is fitted on each
fold's training rows as PX4 fits it and run clamped (`baseline_run`): the
incumbent every other model is compared with, fold by fold.
"""

from dataclasses import dataclass, field, replace
import functools
import math
from typing import Optional

import numpy as np

from .cubic import baseline_run, BaselineRun, cubic_bias
from .fits import AxisSpec, FITS, TIME_CONSTANTS_PER_RECORD, TIME_GRID_S, WIDTH_GRID_C
from .folds import cut_bins, Folds, weighted_rms
from .results import HeldOutError
from .settings import DiagnosisSettings, Progress
from ..baseline import cubic_scale_c, cubic_sums, fit_cubic, solve_cubic
from ..effects import (AxisTerms, EffectModel, FirstOrderLag, SLOPE_EFFECTS,
                       temperature_rate_c_s)
from ..errors import CalibrationError
from ..fitting import MIN_SPAN_C
from ..metrics import temperature_branches
from ..model_interface import INPUTS, ModelInputs
from ..validation import buffer_blocks, PURGED, split, training_sums

# The thermal lag's shortest time constant, in median sample intervals.
MIN_LAG_SAMPLES = 2.0
# A play operator's full width (twice its half width) spans at most this share of the
# temperature range: a wider one follows the temperature over the record, as the
# polynomial does, and would stand in for it.
HYSTERESIS_SPAN_SHARE = 0.25
# Singular values of the scaled normal matrix below this (relative) count as rank loss.
RANK_RCOND = 1e-12


@dataclass(frozen=True)
class Score:
    """A spec scored on the folds: RMS per fold and overall, full rank, the binned residual."""

    fold_rms: np.ndarray
    rms: float
    rank_ok: bool
    residual: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class HeldOutRun:
    """The fold models run as the node runs them: binned residual (bins, axes), errors per axis."""

    residual: np.ndarray
    errors: tuple


@dataclass(frozen=True)
class AxisFit:
    """One axis fitted: its terms, and each fitted record's offset to add to their constant."""

    terms: AxisTerms
    offsets_rad_s: tuple


@dataclass(frozen=True)
class Centring:
    """The centre and half span of an input column, which its terms are scaled by."""

    centre: float
    half_span: float


@dataclass(frozen=True)
class _LagFeatures:
    """Of one lag: bin means of x^0..x^max_order, and T_eff's lowest and highest per block."""

    powers: np.ndarray
    block_low_c: np.ndarray
    block_high_c: np.ndarray


def _solve_normal(gram: np.ndarray, moment: np.ndarray) -> tuple:
    """
    Solve normal equations scaled to a unit diagonal; return (coefficients, full rank).

    A column that is zero on every row (a bias step after the training
    blocks) gets coefficient 0 and does not count as rank loss: the past
    has nothing to say about it yet.
    """
    diagonal = np.sqrt(np.diag(gram))
    present = np.count_nonzero(diagonal)
    diagonal[diagonal == 0.0] = 1.0
    scaled = gram / np.outer(diagonal, diagonal)
    solution, _, rank, _ = np.linalg.lstsq(scaled, moment / diagonal, rcond=RANK_RCOND)
    return solution / diagonal, rank == present


class DiagnosisProblem:
    """
    The rows, bins, folds and cached bin-mean features of one diagnosis.

    ``records`` are the recordings laid end to end (`records.join_records`):
    their first ``rows`` are diagnosed, the rows after them are the test part
    (`held_out_part.diagnosed_rows`).
    """

    def __init__(self, records, rows: int, settings: DiagnosisSettings, progress: Progress):
        self.settings = settings
        self.progress = progress
        recording = self.records = records
        self.axes = tuple(recording.axes)
        total = len(recording.time_s)
        self.rows = rows
        # The records the diagnosis fits; the last of them gives the written offset.
        self.fitted_records = recording.record_of(self.rows - 1) + 1
        self.full = recording
        rows = slice(0, self.rows)

        def head(values):
            return None if values is None else np.asarray(values, dtype=np.float64)[rows]

        self.time = head(recording.time_s)
        self.temperature = head(recording.temperature_c)
        self.rate = head(recording.gyro_rad_s)
        self.reference = head(recording.reference_rad_s)
        # The model inputs the record has (None: not recorded).
        self.inputs = ModelInputs(**{name: head(getattr(recording, name)) for name in INPUTS})
        self.test_rows = total - self.rows
        self._check_size()
        low, high = float(np.min(self.temperature)), float(np.max(self.temperature))
        if high - low < MIN_SPAN_C:
            msg = (f'the temperature spans {high - low:.3g} C ({low:.2f} to {high:.2f} C); '
                   f'diagnose needs at least {MIN_SPAN_C:g} C to fit any temperature term')
            raise CalibrationError(msg)
        self.centre_c = 0.5 * (low + high)
        self.half_span_c = 0.5 * (high - low)
        # x = (T - centre) / scale: a power of two, so that the PX4-style cubic the guard
        # writes is its own formula to the bit (`baseline.cubic_scale_c`).
        self.scale_c = cubic_scale_c(low, high)
        self.time_reference_s = float(self.time[0])
        # The longest record: a time constant must fit into one (histories restart).
        self.duration_s = max(max(float(self.time[rows.stop - 1] - self.time[rows.start])
                                  for rows in recording.segments(self.rows)), 1.0)
        self.slope = self.each(functools.partial(temperature_rate_c_s,
                                                 window_s=settings.rate_window_s),
                               self.time, self.temperature)
        self.truth_is_reference = self.reference is not None
        self.error_rows = self.rate if self.reference is None else self.rate - self.reference
        self._cache = {}
        self._split()
        self.target = self.mean(self.error_rows)
        self.secondary = _centring(self.inputs.temperature_2_c)
        self.supply_reference = _centring(self.inputs.supply_voltage_v)
        self.bounds = self._bounds()

    def _check_size(self) -> None:
        needed = 2 * self.settings.blocks
        if self.rows < needed:
            msg = (f'{self.rows} rows to diagnose (after the test part); '
                   f'{self.settings.blocks} blocks need at least {needed}')
            raise CalibrationError(msg)

    def _bounds(self) -> dict:
        """
        Give the search ranges of the nonlinear parameters (record length, cycle and span).

        A time constant fits TIME_CONSTANTS_PER_RECORD times into the longest
        record and no longer than its thermal cycle; a play operator is at
        most HYSTERESIS_SPAN_SHARE of the span wide. Beyond, their shape
        over the record is a function of temperature: the polynomial's.
        """
        interval = float(np.median(np.diff(self.time)))
        longest = min(self.duration_s / TIME_CONSTANTS_PER_RECORD, self.thermal_cycle_s())
        widest = HYSTERESIS_SPAN_SHARE * self.half_span_c
        return {'thermal_lag_s': (max(MIN_LAG_SAMPLES * interval, TIME_GRID_S[0]), longest),
                'gradient_time_constant_s': (self.settings.rate_window_s, longest),
                'hysteresis_half_width_c': (WIDTH_GRID_C[0], widest)}

    def thermal_cycle_s(self) -> float:
        """
        Give the record's thermal cycle: twice its median heating or cooling branch.

        Branches are `metrics.temperature_branches` of each record; a record
        of one branch (a single ramp) has no cycle shorter than itself.
        """
        durations = []
        for rows in self.records.segments(self.rows):
            time_s = self.time[rows]
            starts = temperature_branches(self.temperature[rows])
            durations += np.diff(np.append(time_s[starts], time_s[-1])).tolist()
        if len(durations) < 2:
            return self.duration_s
        return 2.0 * float(np.median(durations))

    def each(self, operator, *columns) -> np.ndarray:
        """Run a history operator over each record's rows of ``columns`` (`Records.each`)."""
        return self.records.each(operator, *columns)

    def _split(self) -> None:
        """Cut rows into blocks and bins (`folds.cut_bins`); deal the blocks to folds."""
        settings = self.settings
        rows = [part.stop - part.start for part in self.records.segments(self.rows)]
        bins = cut_bins(self.time, rows, settings.blocks, settings.average_s)
        self.block_edges, self.first_blocks = bins.block_edges, bins.first_blocks
        self.starts, self.counts, self.bin_block = bins.starts, bins.counts, bins.bin_block
        self.record_of_bin = np.searchsorted(self.records.starts, self.starts, side='right') - 1
        self.bin_range = (np.minimum.reduceat(self.temperature, self.starts),
                          np.maximum.reduceat(self.temperature, self.starts))
        edges = self.block_edges[:-1]
        self.block_range = (np.minimum.reduceat(self.temperature, edges),
                            np.maximum.reduceat(self.temperature, edges))
        self.block_s = float(np.median(np.diff(self.time[self.block_edges[:-1]]))) \
            if settings.blocks > 1 else self.duration_s
        self.folds = self.folds_of(settings.validation)

    def folds_of(self, scheme: str, buffer: int = 1) -> Folds:
        """Return the folds of a validation scheme over this problem's bins (cached)."""
        settings = self.settings

        def build():
            dealt = split(settings.blocks, scheme, settings.folds, settings.min_past,
                          self.first_blocks, buffer)
            return Folds(dealt, self.bin_block, self.block_edges, self.bin_range,
                         self.block_range, settings.scoring)
        return self.cached(('folds', scheme, buffer), build)

    def memory_s(self, spec: AxisSpec) -> float:
        """Give how far back the spec's history states reach: its longest time constant."""
        memory = [abs(spec.thermal_lag_s), *spec.gradient_s]
        if spec.thermal_lag_s > 0.0 or any(spec.get(effect.name) for effect in SLOPE_EFFECTS):
            memory.append(self.settings.rate_window_s)
        return max(memory)

    def folds_for(self, spec: AxisSpec, scheme: Optional[str] = None) -> Optional[Folds]:
        """
        Give the folds a spec is judged on: purged, a buffer of 3 x its memory.

        None when the buffer leaves no fold to judge it on: the record is too
        short for a model that remembers that long.
        """
        scheme = scheme or self.settings.validation
        if scheme != PURGED:
            return self.folds_of(scheme)
        try:
            return self.folds_of(scheme, buffer_blocks(self.memory_s(spec), self.block_s))
        except CalibrationError:
            return None

    def mean(self, values: np.ndarray) -> np.ndarray:
        """Return the bin means of row values (rows,) or (rows, k), or of their first rows."""
        bins = np.searchsorted(self.starts, len(values))
        sums = np.add.reduceat(values, self.starts[:bins], axis=0)
        counts = self.counts[:bins]
        return sums / (counts if sums.ndim == 1 else counts[:, None])

    def cached(self, key, build):
        """Give ``build()``, computed once per ``key``: the features the trials share."""
        if key not in self._cache:
            self._cache[key] = build()
        return self._cache[key]

    def effective(self, lag_s: float) -> np.ndarray:
        """T_eff of a thermal lag (`EffectModel`), row by row."""
        return effective_temperature(self.records, self.time, self.temperature, self.slope, lag_s)

    def x(self, lag_s: float) -> np.ndarray:
        return (self.effective(lag_s) - self.centre_c) / self.scale_c

    def powers(self, values: np.ndarray, first: int, last: int) -> np.ndarray:
        columns = []
        power = values ** first
        for _ in range(first, last + 1):
            columns.append(self.mean(power))
            power = power * values
        return np.column_stack(columns)

    def _lag_features(self, lag_s: float) -> _LagFeatures:
        """Give the polynomial's bin-mean columns and T_eff's range per block of a lag."""
        def build():
            effective = self.effective(lag_s)
            x = (effective - self.centre_c) / self.scale_c
            starts = self.block_edges[:-1]
            return _LagFeatures(self.powers(x, 0, self.settings.max_order),
                                np.minimum.reduceat(effective, starts),
                                np.maximum.reduceat(effective, starts))
        return self.cached(('lag', lag_s), build)

    def polynomial(self, lag_s: float) -> np.ndarray:
        return self._lag_features(lag_s).powers

    def predicted_polynomial(self, lag_s: float, folds: Folds) -> np.ndarray:
        """Return `polynomial` as the folds predict it: T_eff clamped at their training range."""
        def build():
            features = self._lag_features(lag_s)
            powers, block_low, block_high = (features.powers, features.block_low_c,
                                             features.block_high_c)
            predicted = powers
            effective = None
            for block, fold in enumerate(folds.block_fold):
                if fold < 0:
                    continue
                used = folds.split.training[fold]
                low, high = np.min(block_low[used]), np.max(block_high[used])
                if low <= block_low[block] and block_high[block] <= high:
                    continue
                # Only the blocks that leave their past's range are computed again.
                if effective is None:
                    effective, predicted = self.effective(lag_s), powers.copy()
                rows = slice(self.block_edges[block], self.block_edges[block + 1])
                bins = self.bin_block == block
                x = (np.clip(effective[rows], low, high) - self.centre_c) / self.scale_c
                starts = self.starts[bins] - rows.start
                predicted[bins] = (np.add.reduceat(np.polynomial.polynomial.polyvander(
                    x, self.settings.max_order), starts, axis=0) / self.counts[bins][:, None])
            return predicted
        return self.cached(('predicted', lag_s, folds.key), build)

    def acceleration_means(self) -> np.ndarray:
        return self.cached('acceleration', lambda: self.mean(self.inputs.acceleration_m_s2))

    def design(self, axis: int, spec: AxisSpec) -> np.ndarray:
        """Return the bin-mean design matrix of an axis; columns in `_terms` order."""
        blocks = [self.polynomial(spec.thermal_lag_s)[:, :spec.order + 1]]
        for effect, choice in spec.choices:
            columns = FITS[effect].columns
            if columns is not None:
                blocks.append(columns(self, axis, spec, choice))
        blocks.append(self.offset_columns())
        return np.column_stack(blocks)

    def offset_columns(self) -> np.ndarray:
        """
        Give the bias offset columns of the records after the first (none for one record).

        Last in every design: 1 on the bins of its record. The offsets are the
        records' bias against the first's; a record with no training bins in
        a fold has a zero column there, coefficient 0 (`_solve_normal`).
        """
        def build():
            record = np.searchsorted(self.records.starts, self.starts, side='right') - 1
            return (record[:, None] == np.arange(1, self.fitted_records)[None, :]).astype(
                np.float64)
        return self.cached('offsets', build)

    def score_spec(self, axis: int, spec: AxisSpec, folds: Optional[Folds] = None) -> Score:
        """
        Score the terms of ``spec`` on an axis, the polynomial clamped as the folds run it.

        The folds default to the spec's own (`folds_for`); the PX4-style cubic
        scores as PX4 fits and runs it (`baseline_run`).
        """
        folds = folds or self.folds_for(spec)
        if spec.baseline:
            run = self.baseline_run(folds)
            return Score(run.fold_rms[:, axis], run.errors[axis].rms_rad_s, True,
                         run.residual[:, axis])
        design = self.design(axis, spec)
        predict = design.copy()
        # The polynomial's columns come first (`design`).
        width = spec.order + 1
        predict[:, :width] = self.predicted_polynomial(spec.thermal_lag_s, folds)[:, :width]
        return self.score(design, predict, axis, folds)

    def score(self, design: np.ndarray, predict: np.ndarray, axis: int,
              folds: Folds) -> Score:
        """
        Fit on the training bins of each fold, predict the held-out bins (NaN elsewhere).

        ``predict`` is the design the held-out bins are predicted from.
        """
        target = self.target[:, axis]
        weighted = design * self.counts[:, None]
        edges = np.searchsorted(self.bin_block, np.arange(self.settings.blocks + 1))
        blocks = [slice(first, last) for first, last in zip(edges[:-1], edges[1:])]
        grams = training_sums(folds.split, np.array([weighted[b].T @ design[b] for b in blocks]))
        moments = training_sums(folds.split, np.array([weighted[b].T @ target[b]
                                                       for b in blocks]))
        residual = np.full_like(target, math.nan)
        fold_rms = np.empty(folds.split.folds)
        rank_ok = True
        for fold, (held, counted) in enumerate(zip(folds.held, folds.counted)):
            solution, full_rank = _solve_normal(grams[fold], moments[fold])
            rank_ok = rank_ok and full_rank
            residual[held] = target[held] - predict[held] @ solution
            fold_rms[fold] = weighted_rms(residual[counted], self.counts[counted])
        scored = folds.scored
        return Score(fold_rms, weighted_rms(residual[scored], self.counts[scored]), rank_ok,
                     residual)

    def baseline_run(self, folds: Optional[Folds] = None) -> BaselineRun:
        """Give the PX4-style cubic of each fold run on its held bins (`cubic.baseline_run`)."""
        folds = folds or self.folds
        return self.cached(('baseline', folds.key), lambda: baseline_run(self, folds))

    def fold_cubics(self, blocks: np.ndarray) -> tuple:
        """Give the PX4-style cubic of the given training blocks: a `ClampedCubic` per record."""
        sums = self.cached('cubic sums', lambda: cubic_sums(
            self.temperature, self.error_rows, self.block_edges, self.centre_c, self.scale_c,
            np.searchsorted(self.records.starts, self.block_edges[:-1], side='right') - 1))
        return solve_cubic(sums, blocks, self.fitted_records)

    def cubics(self) -> tuple:
        """Fit the PX4-style cubic on every diagnosed row (`baseline.fit_cubic`): per record."""
        def build():
            record = np.searchsorted(self.records.starts, np.arange(self.rows), side='right') - 1
            return fit_cubic(self.temperature, self.error_rows, record, self.fitted_records)
        return self.cached('cubics', build)

    def fit_terms(self, axis: int, spec: AxisSpec, bins=None) -> AxisTerms:
        """Fit one axis on the given bins (all when None); its terms with the written offset."""
        fit = self.fit_offsets(axis, spec, bins)
        return _shifted(fit.terms, fit.offsets_rad_s[-1])

    def fit_offsets(self, axis: int, spec: AxisSpec, bins=None) -> AxisFit:
        """
        Fit one axis on the given bins (all when None): its terms, and each record's offset.

        The offsets add to the terms' constant: the first record's is 0. The
        PX4-style cubic is fitted on the bins' rows (`baseline.fit_cubic`) and
        its terms are the last record's, whose offset is 0: written, it is its
        own formula to the bit (x's scale is a power of two).
        """
        if spec.baseline:
            return self._cubic_fit(axis, None if bins is None else self.blocks_of(bins))
        design = self.design(axis, spec)
        target = self.target[:, axis]
        if bins is not None:
            design, target = design[bins], target[bins]
        weights = self.counts if bins is None else self.counts[bins]
        # The solver `score` uses: a fold's model is the one its score was judged on.
        weighted = design * weights[:, None]
        solution, _ = _solve_normal(weighted.T @ design, weighted.T @ target)
        offsets = self.fitted_records - 1
        return AxisFit(self._terms(axis, spec, solution[:solution.size - offsets]),
                       (0.0,) + tuple(float(v) for v in solution[solution.size - offsets:]))

    def _cubic_fit(self, axis: int, blocks: Optional[np.ndarray]) -> AxisFit:
        """Give the PX4-style cubic as an `AxisFit` in x: its terms are the last record's."""
        cubics = self.cubics() if blocks is None else self.fold_cubics(blocks)
        biases = [cubic_bias(cubic, axis, self.centre_c, self.scale_c) for cubic in cubics]
        return AxisFit(AxisTerms(bias=biases[-1]), tuple(b[0] - biases[-1][0] for b in biases))

    def blocks_of(self, bins: np.ndarray) -> np.ndarray:
        """Give the blocks (a mask) the given bins lie in."""
        return np.bincount(self.bin_block[bins], minlength=self.settings.blocks) > 0

    def _terms(self, axis: int, spec: AxisSpec, solution: np.ndarray) -> AxisTerms:
        values = iter(float(v) for v in solution)

        def take(count: int) -> tuple:
            return tuple(next(values) for _ in range(count))

        terms = {'bias': take(spec.order + 1)}
        for effect, choice in spec.choices:
            terms.update(FITS[effect].terms(self, axis, choice, take))
        return AxisTerms(**terms)

    def model(self, specs: tuple, fold: Optional[int] = None,
              folds: Optional[Folds] = None) -> EffectModel:
        """Fit every axis on all bins, or on the training bins of ``fold``; written offset."""
        return self.record_models(specs, fold, folds)[-1]

    def record_models(self, specs: tuple, fold: Optional[int] = None,
                      folds: Optional[Folds] = None) -> tuple:
        """
        Fit every axis on all bins, or on the training bins of ``fold``: one model per record.

        Each fitted record's model has its own offset; a record after them
        (the test record) runs the last one's, the written offset.
        """
        folds = folds or self.folds
        bins = None if fold is None else folds.train[fold]
        low, high = self.clamp_range(specs, None if fold is None else
                                     folds.split.training[fold])
        secondary = self.secondary or Centring(25.0, 1.0)
        supply = self.supply_reference or Centring(EffectModel.supply_reference_v, 1.0)
        fits = [self.fit_offsets(axis, spec, bins) for axis, spec in enumerate(specs)]
        model = EffectModel(
            terms=tuple(fit.terms for fit in fits),
            reference_temperature_c=self.centre_c, temperature_scale_c=self.scale_c,
            temperature_min_c=low, temperature_max_c=high,
            temperature_rate_window_s=self.settings.rate_window_s,
            time_reference_s=self.time_reference_s, secondary_reference_c=secondary.centre,
            secondary_scale_c=secondary.half_span, supply_reference_v=supply.centre)
        models = tuple(replace(model, terms=tuple(_shifted(fit.terms, fit.offsets_rad_s[record])
                                                  for fit in fits))
                       for record in range(self.fitted_records))
        return models + models[-1:] * (self.records.count - self.fitted_records)

    def record_offsets(self, specs: tuple) -> np.ndarray:
        """Give each fitted record's bias offset (records, axes) against the written one."""
        offsets = np.array([self.fit_offsets(axis, spec).offsets_rad_s
                            for axis, spec in enumerate(specs)])
        return (offsets - offsets[:, -1:]).T

    def clamp_range(self, specs: tuple, blocks: Optional[np.ndarray] = None) -> tuple:
        """Return the range of T_eff over the given blocks (all when None) and all axes."""
        used = slice(None) if blocks is None else blocks
        features = [self._lag_features(spec.thermal_lag_s) for spec in specs]
        return (float(min(np.min(f.block_low_c[used]) for f in features)),
                float(max(np.max(f.block_high_c[used]) for f in features)))

    def residual(self, model, axis: int, stop: Optional[int] = None) -> np.ndarray:
        """
        Return corrected minus truth for one axis up to row ``stop``.

        ``model`` is one `EffectModel`, or one per record (`record_models`);
        each record runs from its own start, its history fresh.
        """
        models = model if isinstance(model, tuple) else (model,) * self.records.count
        parts = [self._run(models[record], axis, rows)
                 for record, rows in enumerate(self.records.segments(stop))]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _run(self, model: EffectModel, axis: int, span: slice) -> np.ndarray:
        """
        Return corrected minus truth for one axis on the rows of ``span``, from its start.

        Without cross-axis terms the axis runs alone: a third of the memory.
        """
        source = self.full
        column = axis
        rate = source.gyro_rad_s[span]
        if not model.has_cross_axis:
            model = replace(model, terms=(model.terms[axis],),
                            zro_offset_rad_s=(model.zro_offset_rad_s[axis],))
            rate = rate[:, axis:axis + 1]
            column = 0

        inputs = ModelInputs(**{name: getattr(source, name)[span] for name in model.inputs})
        corrected = model.correct(rate, source.temperature_c[span],
                                  inputs).rate_rad_s[:, column]
        if source.reference_rad_s is not None:
            corrected = corrected - source.reference_rad_s[span, axis]
        return corrected

    def test_residual(self, model: EffectModel, axis: int) -> np.ndarray:
        """Return corrected minus truth on the test rows, run from their record's start."""
        first = self.records.starts[self.records.record_of(self.rows)]
        return self._run(model, axis, slice(first, len(self.full)))[self.rows - first:]

    def held_out(self, specs: tuple, label: str, folds: Optional[Folds] = None,
                 axes: Optional[tuple] = None) -> HeldOutRun:
        """
        Run each fold's models on the bins it predicts; give the `HeldOutRun`.

        Only ``axes`` (default: all) are run; the others' columns stay NaN,
        their errors None. An axis that is the PX4-style cubic takes the
        cubic's own fold runs (`baseline_run`).
        """
        folds = folds or self.folds
        axes = range(len(self.axes)) if axes is None else axes
        residual = np.full((len(self.starts), len(self.axes)), math.nan)
        cubic = [axis for axis in axes if specs[axis].baseline]
        if cubic:
            residual[:, cubic] = self.baseline_run(folds).residual[:, cubic]
        run = [axis for axis in axes if not specs[axis].baseline]
        count = folds.split.folds
        for fold, held in enumerate(folds.held):
            if not run:
                break
            self.report(fold, count, label)
            model = self.record_models(specs, fold, folds)
            for axis in run:
                binned = self.mean(self.residual(model, axis, folds.stop[fold]))
                residual[:binned.size, axis][held[:binned.size]] = binned[held[:binned.size]]
        self.report(count, count, label)
        return HeldOutRun(residual, tuple(self.error(residual[:, axis], folds) if axis in axes
                                          else None for axis in range(len(self.axes))))

    def block_rms(self, residual: np.ndarray) -> np.ndarray:
        """RMS of binned residuals per block, NaN for a block no fold predicts."""
        known = np.isfinite(residual)
        weights = np.where(known, self.counts, 0.0)
        totals = np.bincount(self.bin_block, weights=weights * np.square(np.where(known,
                                                                                  residual, 0.0)),
                             minlength=self.settings.blocks)
        counts = np.bincount(self.bin_block, weights=weights, minlength=self.settings.blocks)
        return np.sqrt(np.divide(totals, counts, out=np.full(totals.shape, math.nan),
                                 where=counts > 0))

    def error(self, residual: np.ndarray, folds: Optional[Folds] = None) -> HeldOutError:
        """
        Return the `HeldOutError` of binned residuals on the bins the folds count.

        The held-out bins beyond their fold's training temperatures are
        measured apart: their RMS and their share of the held-out rows.
        """
        folds = folds or self.folds
        scored = folds.scored
        per_fold = tuple(weighted_rms(residual[counted], self.counts[counted])
                         for counted in folds.counted)
        held = np.any(folds.held, axis=0)
        outside = folds.extrapolated
        return HeldOutError(weighted_rms(residual[scored], self.counts[scored]),
                            float(np.max(np.abs(residual[scored]), initial=0.0)), per_fold,
                            tuple(float(v) for v in self.block_rms(residual)),
                            weighted_rms(residual[outside], self.counts[outside]),
                            float(np.sum(self.counts[outside]) / np.sum(self.counts[held])))

    def motion(self) -> tuple:
        """
        Return (turn of the specific force in deg, change of its magnitude in m/s^2).

        The turn is measured from the median direction; where the directions
        cancel out (a board turned through all six faces), it turned 180 deg.
        """
        means = self.acceleration_means()
        magnitude = np.linalg.norm(means, axis=1)
        usable = magnitude > 0.0
        if not usable.any():
            return 0.0, 0.0
        direction = means[usable] / magnitude[usable, None]
        low, high = np.percentile(magnitude[usable], (1.0, 99.0))
        centre = np.median(direction, axis=0)
        if np.linalg.norm(centre) < 1e-6:
            return 180.0, float(high - low)
        centre /= np.linalg.norm(centre)
        angle = np.degrees(np.arccos(np.clip(direction @ centre, -1.0, 1.0)))
        return float(np.percentile(angle, 99.0)), float(high - low)

    def report(self, done: int, total: int, label: str) -> None:
        if self.progress is not None:
            self.progress(done, total, label)


def _shifted(terms: AxisTerms, offset_rad_s: float) -> AxisTerms:
    """Give the terms with ``offset_rad_s`` added to the polynomial's constant."""
    if not offset_rad_s:
        return terms
    return replace(terms, bias=(terms.bias[0] + offset_rad_s,) + terms.bias[1:])


def effective_temperature(records, time_s: np.ndarray, temperature_c: np.ndarray,
                          slope_c_s: np.ndarray, lag_s: float) -> np.ndarray:
    """
    T_eff of a thermal lag (`EffectModel`), row by row; ``slope_c_s`` the windowed dT/dt.

    A lag filter starts afresh at each record's first row (`Records.each`).
    """
    if lag_s > 0.0:
        return temperature_c + lag_s * slope_c_s
    if lag_s < 0.0:
        return records.each(FirstOrderLag(-lag_s).batch, time_s, temperature_c)
    return temperature_c


def _centring(values) -> Optional[Centring]:
    """Give the centre and half span of a column, None when absent or constant."""
    if values is None:
        return None
    low, high = float(np.min(values)), float(np.max(values))
    return Centring(0.5 * (low + high), 0.5 * (high - low)) if high > low else None
