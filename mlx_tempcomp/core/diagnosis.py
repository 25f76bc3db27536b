"""
The closed loop of ``mlx-tempcomp diagnose``: fit, test the effects the model lacks, add one.

Truth is the reference rate when the recording has one, else zero (taken at
rest); the residual is corrected minus truth. The error figure is the RMS
(and peak) of the residual averaged over consecutive bins of ``average_s``
seconds (0: per sample) on held-out rows: averaging keeps white noise from
hiding a bias. The record is cut into ``blocks`` contiguous blocks dealt
round-robin to ``folds`` folds, so training data surrounds every held-out
block and a single thermal cycle's extremes stay covered. Bins never span
two blocks. Stateful inputs (temperature slope, play state) are computed
over the whole record first, then rows are split, as the node does when it
replays the record from the start.

Step 0 fits the temperature polynomial, its order per axis chosen by the
one-standard-error rule over the folds. Each round, every effect an axis
lacks is fitted jointly with the terms so far (linear least squares on bin
means, which is exact for the binned error; nonlinear parameters such as
the thermal lag, the hysteresis width and the step time from a small grid
or a CUSUM, scored by the folds). The best candidate is accepted if its
relative held-out RMS reduction is at least ``min_gain`` and its mean
per-fold improvement exceeds ``significance`` standard errors. The loop
stops when no axis accepts anything. Every reported error of a step comes
from `EffectModel.correct`, the code the node runs, on fold models.
"""

from dataclasses import dataclass, field, replace
import math
from typing import Callable, Mapping, Optional

import numpy as np

from .effects import (AxisTerms, DEFAULT_RATE_WINDOW_S, EFFECT_NAMES, EffectModel, play_state,
                      temperature_rate_c_s)
from .errors import CalibrationError
from .fitting import MIN_SPAN_C, OrderScore
from .metrics import bin_means, bin_starts, test_start_row

BASE_EFFECT = 'temperature_polynomial'
METHODS = ('none', 'px4_cubic', 'temperature_polynomial', 'diagnosed')
PX4_ORDER = 3
LAG_GRID_S = (5.0, 10.0, 20.0, 40.0, 80.0, 150.0, 300.0, 600.0, 1000.0)
WIDTH_GRID_C = (0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0)
# Golden-section evaluations that refine the best grid value, in log |value|.
REFINE_EVALUATIONS = {'thermal_lag': 10, 'hysteresis': 6}
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
# Singular values of the scaled normal matrix below this (relative) count as rank loss.
RANK_RCOND = 1e-12
SECONDARY_ORDERS = (1, 2, 3)
SCALE_ORDERS = (0, 1, 2)
NONLINEARITY_ORDERS = (2, 3)

Progress = Optional[Callable[[int, int, str], None]]


@dataclass(frozen=True)
class DiagnosisSettings:
    """How the diagnosis splits, averages and judges; see the module docstring."""

    folds: int = 5
    blocks: int = 20
    average_s: float = 1.0
    max_order: int = 8
    min_gain: float = 0.05
    significance: float = 2.0
    test_fraction: float = 0.0
    rate_window_s: float = DEFAULT_RATE_WINDOW_S

    def __post_init__(self) -> None:
        checks = (
            (self.folds >= 2, f'folds must be at least 2, got {self.folds}'),
            (self.blocks >= self.folds,
             f'blocks ({self.blocks}) must be at least the folds ({self.folds})'),
            (math.isfinite(self.average_s) and self.average_s >= 0.0,
             f'average_s must be a non-negative number, got {self.average_s}'),
            (self.max_order >= 0, f'max_order must be non-negative, got {self.max_order}'),
            (math.isfinite(self.min_gain) and 0.0 <= self.min_gain < 1.0,
             f'min_gain must be in [0, 1), got {self.min_gain}'),
            (math.isfinite(self.significance) and self.significance >= 0.0,
             f'significance must be non-negative, got {self.significance}'),
            (math.isfinite(self.test_fraction) and 0.0 <= self.test_fraction < 1.0,
             f'test_fraction must be in [0, 1), got {self.test_fraction}'),
            (math.isfinite(self.rate_window_s) and self.rate_window_s > 0.0,
             f'rate_window_s must be positive, got {self.rate_window_s}'),
        )
        for ok, msg in checks:
            if not ok:
                raise CalibrationError(msg)


@dataclass(frozen=True)
class HeldOutError:
    """Error of binned residuals in rad/s: RMS, peak |.|, and RMS per fold (CV only)."""

    rms_rad_s: float
    peak_rad_s: float
    fold_rms_rad_s: tuple = ()


@dataclass(frozen=True)
class Step:
    """One effect added to an axis, with the held-out error before and after it."""

    effect: str
    parameters: Mapping
    before: HeldOutError
    after: HeldOutError
    round_number: int
    held_out_gain: Optional[float] = None


@dataclass(frozen=True)
class Candidate:
    """An effect tried in a round and not added, with its held-out gain."""

    effect: str
    round_number: int
    parameters: Mapping
    held_out_gain: float
    fold_improvement_rad_s: float
    fold_improvement_se_rad_s: float
    reason: str


@dataclass(frozen=True)
class AxisDiagnosis:
    """What the loop found on one axis."""

    axis: str
    order: int
    order_scores: tuple
    steps: tuple
    rejected: tuple

    @property
    def effects(self) -> tuple:
        return tuple(step.effect for step in self.steps)


@dataclass(frozen=True)
class BinnedResidual:
    """Binned residuals (bins, axes) of the base and diagnosed models, for plots."""

    time_s: np.ndarray
    temperature_c: np.ndarray
    heating: np.ndarray
    before_rad_s: np.ndarray
    after_rad_s: np.ndarray


@dataclass(frozen=True)
class Diagnosis:
    """
    The result: the model, the steps per axis, and the comparison with simpler models.

    ``comparison`` maps 'cross_validation' (and 'test' with a test fraction)
    to a mapping of each of METHODS to one `HeldOutError` per axis.
    """

    axes: tuple
    settings: DiagnosisSettings
    model: EffectModel
    base_model: EffectModel
    per_axis: tuple
    skipped: tuple
    comparison: Mapping
    rows: int
    test_rows: int
    bins: int
    truth: str
    held_out: BinnedResidual
    test: Optional[BinnedResidual] = None


@dataclass(frozen=True)
class _Spec:
    """The effects of one axis and their nonlinear parameters (-1 or None: absent)."""

    order: int
    thermal_lag_s: float = 0.0
    hysteresis_half_width_c: float = 0.0
    time_drift: bool = False
    bias_step_time_s: Optional[float] = None
    secondary_order: int = 0
    acceleration: bool = False
    scale_order: int = -1
    nonlinearity_order: int = 0
    cross_axis: bool = False

    @property
    def effects(self) -> set:
        present = {BASE_EFFECT,
                   'thermal_lag' if self.thermal_lag_s else '',
                   'hysteresis' if self.hysteresis_half_width_c else '',
                   'time_drift' if self.time_drift else '',
                   'bias_step' if self.bias_step_time_s is not None else '',
                   'secondary_temperature' if self.secondary_order else '',
                   'acceleration_sensitivity' if self.acceleration else '',
                   'scale_factor_temperature' if self.scale_order >= 0 else '',
                   'rate_nonlinearity' if self.nonlinearity_order else '',
                   'cross_axis' if self.cross_axis else ''}
        return present - {''}


@dataclass(frozen=True)
class _Score:
    fold_rms: np.ndarray
    rms: float
    rank_ok: bool
    residual: np.ndarray = field(repr=False)


def _rms(values, weights) -> float:
    total = float(np.sum(weights))
    return math.sqrt(float(np.sum(weights * np.square(values))) / total) if total else math.nan


def _solve(design: np.ndarray, target: np.ndarray, weights: np.ndarray) -> tuple:
    """Weighted least squares with column scaling; return (coefficients, full rank)."""
    root = np.sqrt(weights)[:, None]
    scaled = design * root
    norms = np.sqrt(np.sum(np.square(scaled), axis=0))
    norms[norms == 0.0] = 1.0
    solution, _, rank, _ = np.linalg.lstsq(scaled / norms, target * root[:, 0], rcond=None)
    return solution / norms, rank == design.shape[1]


def _solve_normal(gram: np.ndarray, moment: np.ndarray) -> tuple:
    """Solve normal equations scaled to a unit diagonal; return (coefficients, full rank)."""
    diagonal = np.sqrt(np.diag(gram))
    diagonal[diagonal == 0.0] = 1.0
    scaled = gram / np.outer(diagonal, diagonal)
    solution, _, rank, _ = np.linalg.lstsq(scaled, moment / diagonal, rcond=RANK_RCOND)
    return solution / diagonal, rank == gram.shape[0]


class _Problem:
    """The rows, bins, folds and cached bin-mean features of one diagnosis."""

    def __init__(self, recording, settings: DiagnosisSettings, progress: Progress):
        self.settings = settings
        self.progress = progress
        self.axes = tuple(recording.axes)
        total = len(recording.time_s)
        self.rows = test_start_row(total, settings.test_fraction)
        self.full = recording
        rows = slice(0, self.rows)
        self.time = np.asarray(recording.time_s, dtype=np.float64)[rows]
        self.temperature = np.asarray(recording.temperature_c, dtype=np.float64)[rows]
        self.rate = np.asarray(recording.gyro_rad_s, dtype=np.float64)[rows]
        self.reference = None if recording.reference_rad_s is None else \
            np.asarray(recording.reference_rad_s, dtype=np.float64)[rows]
        self.temperature_2 = None if recording.temperature_2_c is None else \
            np.asarray(recording.temperature_2_c, dtype=np.float64)[rows]
        self.acceleration = None if recording.acceleration_m_s2 is None else \
            np.asarray(recording.acceleration_m_s2, dtype=np.float64)[rows]
        self._check_size()
        low, high = float(np.min(self.temperature)), float(np.max(self.temperature))
        if high - low < MIN_SPAN_C:
            msg = (f'the temperature spans {high - low:.3g} C ({low:.2f} to {high:.2f} C); '
                   f'diagnose needs at least {MIN_SPAN_C:g} C to fit any temperature term')
            raise CalibrationError(msg)
        self.centre_c = 0.5 * (low + high)
        self.half_span_c = 0.5 * (high - low)
        self.time_reference_s = float(self.time[0])
        self.duration_s = max(float(self.time[-1] - self.time[0]), 1.0)
        self.slope = temperature_rate_c_s(self.time, self.temperature, settings.rate_window_s)
        self._split()
        self.truth_is_reference = self.reference is not None
        error = self.rate if self.reference is None else self.rate - self.reference
        self.target = self.mean(error)
        self.secondary = None
        if self.temperature_2 is not None:
            low2, high2 = float(np.min(self.temperature_2)), float(np.max(self.temperature_2))
            if high2 > low2:
                self.secondary = (0.5 * (low2 + high2), 0.5 * (high2 - low2))
        self._cache = {}

    def _check_size(self) -> None:
        needed = 2 * self.settings.blocks
        if self.rows < needed:
            msg = (f'{self.rows} rows to diagnose (after the test fraction); '
                   f'{self.settings.blocks} blocks need at least {needed}')
            raise CalibrationError(msg)

    def _split(self) -> None:
        """Cut rows into blocks, bins inside blocks, and deal blocks to folds."""
        settings = self.settings
        edges = np.linspace(0, self.rows, settings.blocks + 1).astype(np.int64)
        block = np.repeat(np.arange(settings.blocks), np.diff(edges))
        self.row_fold = (block % settings.folds).astype(np.int8)
        boundary = np.zeros(self.rows, dtype=bool)
        boundary[edges[:-1]] = True
        if settings.average_s > 0.0:
            since = self.time - self.time[edges[:-1]][block]
            index = np.floor(since / settings.average_s).astype(np.int64)
            boundary[1:] |= index[1:] != index[:-1]
        else:
            boundary[:] = True
        self.starts = np.flatnonzero(boundary)
        self.counts = np.diff(np.append(self.starts, self.rows)).astype(np.float64)
        self.bin_fold = self.row_fold[self.starts]
        self.held = tuple(self.bin_fold == fold for fold in range(settings.folds))

    def mean(self, values: np.ndarray) -> np.ndarray:
        """Return the bin means of row values (rows,) or (rows, k)."""
        sums = np.add.reduceat(values, self.starts, axis=0)
        return sums / (self.counts if sums.ndim == 1 else self.counts[:, None])

    def _cached(self, key, build):
        if key not in self._cache:
            self._cache[key] = build()
        return self._cache[key]

    def x(self, lag_s: float) -> np.ndarray:
        effective = self.temperature + lag_s * self.slope if lag_s else self.temperature
        return (effective - self.centre_c) / self.half_span_c

    def _powers(self, values: np.ndarray, first: int, last: int) -> np.ndarray:
        columns = []
        power = values ** first
        for _ in range(first, last + 1):
            columns.append(self.mean(power))
            power = power * values
        return np.column_stack(columns)

    def polynomial(self, lag_s: float) -> np.ndarray:
        return self._cached(('poly', lag_s),
                            lambda: self._powers(self.x(lag_s), 0, self.settings.max_order))

    def raw_cubic(self) -> np.ndarray:
        return self._cached('cubic', lambda: self._powers(self.temperature, 0, PX4_ORDER))

    def play(self, width_c: float) -> np.ndarray:
        return self._cached(('play', width_c),
                            lambda: self.mean(play_state(self.temperature, width_c))[:, None])

    def drift(self) -> np.ndarray:
        return self._cached('drift', lambda: self.mean(
            (self.time - self.time_reference_s) / self.duration_s)[:, None])

    def step(self, time_s: float) -> np.ndarray:
        return self._cached(('step', time_s), lambda: self.mean(
            (self.time >= time_s).astype(np.float64))[:, None])

    def secondary_powers(self) -> np.ndarray:
        reference, scale = self.secondary
        return self._cached('secondary', lambda: self._powers(
            (self.temperature_2 - reference) / scale, 1, max(SECONDARY_ORDERS)))

    def acceleration_means(self) -> np.ndarray:
        return self._cached('acceleration', lambda: self.mean(self.acceleration))

    def scale(self, axis: int, lag_s: float) -> np.ndarray:
        def build():
            x = self.x(lag_s)
            truth = self.reference[:, axis]
            return np.column_stack([self.mean(truth * x ** k)
                                    for k in range(max(SCALE_ORDERS) + 1)])
        return self._cached(('scale', axis, lag_s), build)

    def nonlinearity(self, axis: int) -> np.ndarray:
        return self._cached(('nonlinearity', axis), lambda: self._powers(
            self.reference[:, axis], 2, max(NONLINEARITY_ORDERS)))

    def cross(self, axis: int) -> np.ndarray:
        others = [j for j in range(len(self.axes)) if j != axis]
        return self._cached(('cross', axis), lambda: self.mean(self.reference[:, others]))

    def design(self, axis: int, spec: _Spec) -> np.ndarray:
        """Return the bin-mean design matrix of an axis; columns in `_coefficients` order."""
        blocks = [self.polynomial(spec.thermal_lag_s)[:, :spec.order + 1]]
        if spec.hysteresis_half_width_c:
            blocks.append(self.play(spec.hysteresis_half_width_c))
        if spec.time_drift:
            blocks.append(self.drift())
        if spec.bias_step_time_s is not None:
            blocks.append(self.step(spec.bias_step_time_s))
        if spec.secondary_order:
            blocks.append(self.secondary_powers()[:, :spec.secondary_order])
        if spec.acceleration:
            blocks.append(self.acceleration_means())
        if spec.scale_order >= 0:
            blocks.append(self.scale(axis, spec.thermal_lag_s)[:, :spec.scale_order + 1])
        if spec.nonlinearity_order:
            blocks.append(self.nonlinearity(axis)[:, :spec.nonlinearity_order - 1])
        if spec.cross_axis:
            blocks.append(self.cross(axis))
        return np.column_stack(blocks)

    def score(self, design: np.ndarray, axis: int) -> _Score:
        """Fit on the training bins of each fold, predict the held-out bins."""
        target = self.target[:, axis]
        weighted = design * self.counts[:, None]
        grams = [(weighted[held].T @ design[held], weighted[held].T @ target[held])
                 for held in self.held]
        gram = sum(g for g, _ in grams)
        moment = sum(m for _, m in grams)
        residual = np.empty_like(target)
        fold_rms = np.empty(self.settings.folds)
        rank_ok = True
        for fold, held in enumerate(self.held):
            solution, full_rank = _solve_normal(gram - grams[fold][0], moment - grams[fold][1])
            rank_ok = rank_ok and full_rank
            residual[held] = target[held] - design[held] @ solution
            fold_rms[fold] = _rms(residual[held], self.counts[held])
        return _Score(fold_rms, _rms(residual, self.counts), rank_ok, residual)

    def fit_terms(self, axis: int, spec: _Spec, bins=None) -> AxisTerms:
        """Fit one axis on the given bins (all when None) and return its terms."""
        design = self.design(axis, spec)
        target = self.target[:, axis]
        if bins is not None:
            design, target = design[bins], target[bins]
        weights = self.counts if bins is None else self.counts[bins]
        solution, _ = _solve(design, target, weights)
        return self._terms(axis, spec, solution)

    def _terms(self, axis: int, spec: _Spec, solution: np.ndarray) -> AxisTerms:
        values = iter(float(v) for v in solution)

        def take(count: int) -> tuple:
            return tuple(next(values) for _ in range(count))

        terms = {'bias': take(spec.order + 1), 'thermal_lag_s': spec.thermal_lag_s}
        if spec.hysteresis_half_width_c:
            terms.update(hysteresis_half_width_c=spec.hysteresis_half_width_c,
                         hysteresis_rad_s=take(1)[0])
        if spec.time_drift:
            terms['time_drift_rad_s_per_s'] = take(1)[0] / self.duration_s
        if spec.bias_step_time_s is not None:
            terms['bias_steps'] = ((spec.bias_step_time_s, take(1)[0]),)
        if spec.secondary_order:
            terms['secondary'] = take(spec.secondary_order)
        if spec.acceleration:
            terms['acceleration_rad_s_per_m_s2'] = take(3)
        if spec.scale_order >= 0:
            terms['scale'] = take(spec.scale_order + 1)
        if spec.nonlinearity_order:
            terms['nonlinearity'] = take(spec.nonlinearity_order - 1)
        if spec.cross_axis:
            others = iter(take(len(self.axes) - 1))
            terms['cross_axis'] = tuple(0.0 if j == axis else next(others)
                                        for j in range(len(self.axes)))
        return AxisTerms(**terms)

    def model(self, specs: tuple, fold: Optional[int] = None) -> EffectModel:
        """Fit every axis on all bins, or on the training bins of ``fold``."""
        bins = None if fold is None else self.bin_fold != fold
        low, high = self.clamp_range(specs)
        secondary = self.secondary or (25.0, 1.0)
        return EffectModel(
            terms=tuple(self.fit_terms(axis, spec, bins) for axis, spec in enumerate(specs)),
            reference_temperature_c=self.centre_c, temperature_scale_c=self.half_span_c,
            temperature_min_c=low, temperature_max_c=high,
            temperature_rate_window_s=self.settings.rate_window_s,
            time_reference_s=self.time_reference_s, secondary_reference_c=secondary[0],
            secondary_scale_c=secondary[1])

    def clamp_range(self, specs: tuple) -> tuple:
        """
        Return the range of T_eff over all rows and axes, the clamp of every model.

        Fold models clamp there too (not at their training range), so the
        folds measure the fit where the deployed model applies.
        """
        key = ('clamp', tuple(spec.thermal_lag_s for spec in specs))
        if key not in self._cache:
            low, high = math.inf, -math.inf
            for lag_s in set(key[1]):
                effective = self.temperature + lag_s * self.slope
                low = min(low, float(np.min(effective)))
                high = max(high, float(np.max(effective)))
            self._cache[key] = (low, high)
        return self._cache[key]

    def residual(self, model: EffectModel, axis: int, stop: Optional[int] = None) -> np.ndarray:
        """
        Return corrected minus truth for one axis, the model run from the record start.

        Without cross-axis terms the axis runs alone: a third of the memory.
        """
        source = self.full
        span = slice(0, stop)
        column = axis
        rate = source.gyro_rad_s[span]
        if not any(any(term.cross_axis) for term in model.terms):
            model = replace(model, terms=(model.terms[axis],),
                            zro_offset_rad_s=(model.zro_offset_rad_s[axis],))
            rate = rate[:, axis:axis + 1]
            column = 0
        # Inputs only when needed: the model computes a temperature slope whenever given time.
        time_s = source.time_s[span] if model.needs_time else None
        temperature_2 = source.temperature_2_c[span] if model.needs_temperature_2 else None
        acceleration = source.acceleration_m_s2[span] if model.needs_acceleration else None
        corrected = model.correct(rate, source.temperature_c[span], time_s=time_s,
                                  temperature_2_c=temperature_2,
                                  acceleration_m_s2=acceleration).rate_rad_s[:, column]
        if source.reference_rad_s is not None:
            corrected = corrected - source.reference_rad_s[span, axis]
        return corrected

    def held_out(self, specs: tuple, label: str) -> tuple:
        """Return (binned held-out residual (bins, axes), HeldOutError per axis)."""
        residual = np.empty((len(self.starts), len(self.axes)))
        folds = self.settings.folds
        for fold in range(folds):
            self.report(fold, folds, label)
            model = self.model(specs, fold)
            held = self.bin_fold == fold
            for axis in range(len(self.axes)):
                residual[held, axis] = self.mean(self.residual(model, axis, self.rows))[held]
        self.report(folds, folds, label)
        return residual, tuple(self.error(residual[:, axis]) for axis in range(len(self.axes)))

    def error(self, residual: np.ndarray) -> HeldOutError:
        folds = tuple(_rms(residual[self.bin_fold == k], self.counts[self.bin_fold == k])
                      for k in range(self.settings.folds))
        return HeldOutError(_rms(residual, self.counts), float(np.max(np.abs(residual))), folds)

    def report(self, done: int, total: int, label: str) -> None:
        if self.progress is not None:
            self.progress(done, total, label)


def _order_scores(problem: _Problem, axis: int, spec: _Spec) -> tuple:
    """Score every polynomial order with the other terms of ``spec`` fitted alongside."""
    scores = []
    for order in range(problem.settings.max_order + 1):
        score = problem.score(problem.design(axis, replace(spec, order=order)), axis)
        folds = tuple(float(v) for v in score.fold_rms)
        if not score.rank_ok:
            scores.append(OrderScore(order, folds, math.inf, math.inf))
            continue
        error = float(np.std(score.fold_rms, ddof=1) / math.sqrt(score.fold_rms.size))
        scores.append(OrderScore(order, folds, float(np.mean(score.fold_rms)), error))
    return tuple(scores)


def _choose_order(axis_name: str, scores: tuple) -> int:
    best = min(scores, key=lambda s: s.mean_rms_rad_s)
    if not math.isfinite(best.mean_rms_rad_s):
        msg = f'axis {axis_name}: the training folds cannot support any polynomial order'
        raise CalibrationError(msg)
    threshold = best.mean_rms_rad_s + best.standard_error_rad_s
    return next(s.order for s in scores if s.mean_rms_rad_s <= threshold)


def _skipped(problem: _Problem) -> dict:
    """Map each effect the data cannot support to the reason."""
    reference = ', '.join(f'ref_{a}' for a in problem.axes)
    skipped = {}
    if problem.temperature_2 is None:
        skipped['secondary_temperature'] = 'needs column temperature_2'
    elif problem.secondary is None:
        skipped['secondary_temperature'] = 'temperature_2 is constant'
    if problem.acceleration is None:
        skipped['acceleration_sensitivity'] = 'needs columns acc_x, acc_y, acc_z'
    for effect in ('scale_factor_temperature', 'rate_nonlinearity', 'cross_axis'):
        if problem.reference is None:
            skipped[effect] = f'needs reference columns {reference}'
    if 'cross_axis' not in skipped and len(problem.axes) < 2:
        skipped['cross_axis'] = 'needs at least 2 gyro axes'
    return skipped


def _step_time(problem: _Problem, axis: int, spec: _Spec) -> float:
    """
    Return the bias step time that least squares prefers, given the axis's other terms.

    The numerator is the CUSUM of the current (weighted) residual; it is
    divided by what a step at each bin start leaves unexplained by the other
    terms, which makes the peak the exact least-squares step location.
    """
    root = np.sqrt(problem.counts)
    basis, _ = np.linalg.qr(problem.design(axis, spec) * root[:, None])
    target = problem.target[:, axis] * root
    residual = target - basis @ (basis.T @ target)
    # Sums from each bin to the end: a step starting at that bin.
    cusum = np.cumsum((residual * root)[::-1])[::-1]
    projected = np.cumsum((basis * root[:, None])[::-1], axis=0)[::-1]
    left = np.cumsum(problem.counts[::-1])[::-1] - np.sum(np.square(projected), axis=1)
    usable = left > 1e-9 * np.sum(problem.counts)
    usable[0] = False
    if not usable.any():
        return float(problem.time[-1])
    gain = np.where(usable, np.square(cusum) / np.where(usable, left, 1.0), -1.0)
    return float(problem.time[problem.starts[int(np.argmax(gain))]])


def _trials(problem: _Problem, axis: int, spec: _Spec, effect: str):
    """Yield the specs to try for one effect (a generator: grids refine on results)."""
    if effect == 'thermal_lag':
        yield from (replace(spec, thermal_lag_s=s * v) for s in (1.0, -1.0) for v in LAG_GRID_S)
    elif effect == 'hysteresis':
        yield from (replace(spec, hysteresis_half_width_c=w) for w in WIDTH_GRID_C)
    elif effect == 'time_drift':
        yield replace(spec, time_drift=True)
    elif effect == 'bias_step':
        yield replace(spec, bias_step_time_s=_step_time(problem, axis, spec))
    elif effect == 'secondary_temperature':
        yield from (replace(spec, secondary_order=k) for k in SECONDARY_ORDERS)
    elif effect == 'acceleration_sensitivity':
        yield replace(spec, acceleration=True)
    elif effect == 'scale_factor_temperature':
        yield from (replace(spec, scale_order=k) for k in SCALE_ORDERS)
    elif effect == 'rate_nonlinearity':
        yield from (replace(spec, nonlinearity_order=k) for k in NONLINEARITY_ORDERS)
    elif effect == 'cross_axis':
        yield replace(spec, cross_axis=True)


_GRID_SIZES = {'thermal_lag': 2 * len(LAG_GRID_S) + REFINE_EVALUATIONS['thermal_lag'],
               'hysteresis': len(WIDTH_GRID_C) + REFINE_EVALUATIONS['hysteresis'],
               'secondary_temperature': len(SECONDARY_ORDERS),
               'scale_factor_temperature': len(SCALE_ORDERS),
               'rate_nonlinearity': len(NONLINEARITY_ORDERS)}


class _Counter:
    """Count candidate fits and report them as progress."""

    def __init__(self, problem: _Problem, total: int, label: str):
        self.problem, self.total, self.label, self.done = problem, total, label, 0

    def __call__(self) -> None:
        self.done += 1
        self.problem.report(self.done, self.total, self.label)


def _best_trial(problem: _Problem, axis: int, spec: _Spec, effect: str, tick) -> tuple:
    """Return (best spec, its score) for one effect; thermal lag and hysteresis refined."""
    best = None
    for trial in _trials(problem, axis, spec, effect):
        best = _better(best, trial, problem.score(problem.design(axis, trial), axis))
        tick()
    if effect in REFINE_EVALUATIONS:
        name = 'thermal_lag_s' if effect == 'thermal_lag' else 'hysteresis_half_width_c'
        grid = LAG_GRID_S if effect == 'thermal_lag' else WIDTH_GRID_C
        value = getattr(best[0], name)
        index = grid.index(abs(value))
        # Bracket by the neighbours; past the grid's ends by one more grid ratio.
        low = grid[index - 1] if index else grid[0] * grid[0] / grid[1]
        high = grid[index + 1] if index + 1 < len(grid) else grid[-1] * grid[-1] / grid[-2]

        def evaluate(magnitude: float) -> float:
            nonlocal best
            trial = replace(spec, **{name: math.copysign(magnitude, value)})
            score = problem.score(problem.design(axis, trial), axis)
            best = _better(best, trial, score)
            tick()
            return score.rms

        _golden(evaluate, low, high, REFINE_EVALUATIONS[effect])
    return best


def _golden(evaluate, low: float, high: float, evaluations: int) -> None:
    """Golden-section search of ``evaluate`` over [low, high] > 0 in log scale."""
    a, b = math.log(low), math.log(high)
    c, d = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
    fc, fd = evaluate(math.exp(c)), evaluate(math.exp(d))
    for _ in range(evaluations - 2):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - GOLDEN * (b - a)
            fc = evaluate(math.exp(c))
        else:
            a, c, fc = c, d, fd
            d = a + GOLDEN * (b - a)
            fd = evaluate(math.exp(d))


def _better(best, trial: _Spec, score: _Score):
    if best is None or score.rms < best[1].rms:
        return trial, score
    return best


def _parameters(effect: str, terms: AxisTerms, problem: _Problem) -> dict:
    """Return the fitted parameters of one effect of an axis, in SI units."""
    if effect == BASE_EFFECT:
        return {'order': len(terms.bias) - 1, 'bias_rad_s': list(terms.bias),
                'reference_temperature_c': problem.centre_c,
                'temperature_scale_c': problem.half_span_c}
    if effect == 'thermal_lag':
        return {'thermal_lag_s': terms.thermal_lag_s,
                'temperature_rate_window_s': problem.settings.rate_window_s}
    if effect == 'hysteresis':
        return {'half_width_c': terms.hysteresis_half_width_c,
                'hysteresis_rad_s': terms.hysteresis_rad_s}
    if effect == 'time_drift':
        return {'rad_s_per_s': terms.time_drift_rad_s_per_s,
                'time_reference_s': problem.time_reference_s}
    if effect == 'bias_step':
        return {'time_s': terms.bias_steps[0][0], 'step_rad_s': terms.bias_steps[0][1]}
    if effect == 'secondary_temperature':
        return {'coefficients_rad_s': list(terms.secondary)}
    if effect == 'acceleration_sensitivity':
        return {'rad_s_per_m_s2': list(terms.acceleration_rad_s_per_m_s2)}
    if effect == 'scale_factor_temperature':
        return {'relative_coefficients': list(terms.scale)}
    if effect == 'rate_nonlinearity':
        return {'coefficients': list(terms.nonlinearity)}
    return {'coefficients': list(terms.cross_axis)}


def _judge(settings: DiagnosisSettings, base: _Score, score: _Score) -> tuple:
    """Return (relative gain, mean fold improvement, its standard error, why rejected)."""
    gain = (base.rms - score.rms) / base.rms if base.rms > 0.0 else 0.0
    improvement = base.fold_rms - score.fold_rms
    mean = float(np.mean(improvement))
    error = float(np.std(improvement, ddof=1) / math.sqrt(improvement.size))
    if not math.isfinite(gain) or gain < settings.min_gain:
        reason = f'held-out gain {gain:.3f} below --min-gain {settings.min_gain:g}'
    elif not mean > settings.significance * error:
        reason = (f'mean fold improvement {mean:.3g} rad/s not above '
                  f'{settings.significance:g} standard errors ({error:.3g} rad/s)')
    else:
        reason = ''
    return gain, mean, error, reason


def _heating(problem: _Problem, rows: slice, starts: np.ndarray) -> np.ndarray:
    slope = temperature_rate_c_s(problem.full.time_s, problem.full.temperature_c,
                                 problem.settings.rate_window_s)[rows]
    return np.add.reduceat(slope, starts) >= 0.0


def _test_bins(problem: _Problem) -> np.ndarray:
    """Bin starts of the test part (relative to its first row)."""
    return bin_starts(problem.full.time_s[problem.rows:], problem.settings.average_s)


def _binned_error(residual: np.ndarray, starts: np.ndarray) -> tuple:
    binned, counts = bin_means(residual, starts)
    errors = tuple(HeldOutError(_rms(binned[:, a], counts), float(np.max(np.abs(binned[:, a]))))
                   for a in range(residual.shape[1]))
    return binned, errors


def _compare_test(problem: _Problem, base_model: EffectModel, model: EffectModel) -> tuple:
    """Return (errors per method on the test part, binned residual before/after)."""
    full = problem.full
    test = slice(problem.rows, len(full.time_s))
    rows = len(full.time_s) - problem.rows
    starts = _test_bins(problem)
    shape = (rows, len(problem.axes))
    none, cubic, before, after = (np.empty(shape) for _ in range(4))
    for axis in range(len(problem.axes)):
        truth = 0.0 if full.reference_rad_s is None else full.reference_rad_s[:, axis]
        error = full.gyro_rad_s[:, axis] - truth
        none[:, axis] = error[test]
        trend = np.polyfit(problem.temperature, error[:problem.rows], PX4_ORDER)
        cubic[:, axis] = error[test] - np.polyval(trend, full.temperature_c[test])
        before[:, axis] = problem.residual(base_model, axis)[test]
        after[:, axis] = problem.residual(model, axis)[test]
    before, before_errors = _binned_error(before, starts)
    after, after_errors = _binned_error(after, starts)
    comparison = {'none': _binned_error(none, starts)[1],
                  'px4_cubic': _binned_error(cubic, starts)[1],
                  'temperature_polynomial': before_errors, 'diagnosed': after_errors}
    counts = np.diff(np.append(starts, rows)).astype(np.float64)
    binned = BinnedResidual(
        time_s=np.add.reduceat(full.time_s[test], starts) / counts,
        temperature_c=np.add.reduceat(full.temperature_c[test], starts) / counts,
        heating=_heating(problem, test, starts), before_rad_s=before, after_rad_s=after)
    return comparison, binned


def diagnose(recording, settings: DiagnosisSettings = DiagnosisSettings(),
             progress: Progress = None) -> Diagnosis:
    """
    Run the loop on a recording and return the `Diagnosis`.

    ``recording`` has time_s, temperature_c, axes, gyro_rad_s and optional
    reference_rad_s, acceleration_m_s2 and temperature_2_c (a
    `mlx_tempcomp.sources.recording.Recording`). ``progress(done, total,
    label)`` is called as work advances. Raise `CalibrationError` when the
    data cannot support the diagnosis.
    """
    problem = _Problem(recording, settings, progress)
    axes = problem.axes
    skipped = _skipped(problem)
    scores = tuple(_order_scores(problem, axis, _Spec(0)) for axis in range(len(axes)))
    specs = [_Spec(_choose_order(name, s)) for name, s in zip(axes, scores)]
    none_errors = tuple(problem.error(problem.target[:, a]) for a in range(len(axes)))
    residual, errors = problem.held_out(tuple(specs), 'held-out check of step 0')
    base_residual = residual
    base_model = problem.model(tuple(specs))
    steps = [[Step(BASE_EFFECT, _parameters(BASE_EFFECT, base_model.terms[a], problem),
                   none_errors[a], errors[a], 0)] for a in range(len(axes))]
    rejected = [[] for _ in axes]
    active = set(range(len(axes)))
    for number in range(1, len(EFFECT_NAMES)):
        if not active:
            break
        accepted = {}
        work = sum(_GRID_SIZES.get(e, 1) for a in active for e in EFFECT_NAMES
                   if e not in specs[a].effects and e not in skipped)
        tick = _Counter(problem, work, f'round {number}: candidate effects')
        for axis in sorted(active):
            current = problem.score(problem.design(axis, specs[axis]), axis)
            tried = []
            for effect in EFFECT_NAMES:
                if effect in specs[axis].effects or effect in skipped:
                    continue
                trial, score = _best_trial(problem, axis, specs[axis], effect, tick)
                tried.append((effect, trial, score, _judge(settings, current, score)))
            tried.sort(key=lambda item: (bool(item[3][3]), -item[3][0]))
            for rank, (effect, trial, score, (gain, mean, error, reason)) in enumerate(tried):
                if rank == 0 and not reason:
                    accepted[axis] = (effect, trial, gain)
                    continue
                if not reason:
                    reason = 'significant, but another effect gained more this round'
                parameters = _parameters(effect, problem.fit_terms(axis, trial), problem)
                rejected[axis].append(Candidate(effect, number, parameters, gain, mean, error,
                                                reason))
        if not accepted:
            break
        for axis, (effect, trial, gain) in accepted.items():
            # The new term may take over what a higher order did, or free one up.
            specs[axis] = replace(trial, order=_choose_order(
                axes[axis], _order_scores(problem, axis, trial)))
        new_residual, new_errors = problem.held_out(tuple(specs),
                                                    f'held-out check of round {number}')
        model = problem.model(tuple(specs))
        for axis, (effect, trial, gain) in accepted.items():
            parameters = _parameters(effect, model.terms[axis], problem)
            parameters['polynomial_order'] = specs[axis].order
            steps[axis].append(Step(effect, parameters, errors[axis], new_errors[axis], number,
                                    gain))
        residual, errors = new_residual, new_errors
        active = set(accepted)
    model = problem.model(tuple(specs))
    cubic = [problem.score(problem.raw_cubic(), a).residual for a in range(len(axes))]
    comparison = {'cross_validation': {
        'none': none_errors,
        'px4_cubic': tuple(problem.error(r) for r in cubic),
        'temperature_polynomial': tuple(axis_steps[0].after for axis_steps in steps),
        'diagnosed': errors}}
    held_rows = slice(0, problem.rows)
    held_out = BinnedResidual(
        time_s=problem.mean(problem.time), temperature_c=problem.mean(problem.temperature),
        heating=_heating(problem, held_rows, problem.starts), before_rad_s=base_residual,
        after_rad_s=residual)
    test = None
    if problem.rows < len(recording.time_s):
        comparison['test'], test = _compare_test(problem, base_model, model)
    per_axis = tuple(AxisDiagnosis(name, specs[a].order, scores[a], tuple(steps[a]),
                                   tuple(rejected[a])) for a, name in enumerate(axes))
    return Diagnosis(axes=axes, settings=settings, model=model, base_model=base_model,
                     per_axis=per_axis, skipped=tuple(sorted(skipped.items())),
                     comparison=comparison, rows=problem.rows,
                     test_rows=len(recording.time_s) - problem.rows, bins=len(problem.starts),
                     truth='reference' if problem.truth_is_reference else 'zero (at rest)',
                     held_out=held_out, test=test)
