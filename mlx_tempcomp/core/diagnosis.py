"""
The closed loop of ``mlx-tempcomp diagnose``: fit, test the effects the model lacks, add one.

Truth is the reference rate when the recording has one, else zero (taken at
rest); the residual is corrected minus truth. The error figure is the RMS
(and peak) of the residual averaged over consecutive bins of ``average_s``
seconds (0: per sample) on held-out rows: averaging keeps white noise from
hiding a bias. The record is cut into ``blocks`` contiguous blocks dealt to
folds by `validation.split`, the code path `fit` uses too: forward in time
by default (each block after the first ``min_past`` predicted by a fit on
the blocks before it, as a node runs a model fitted on the past), or
round-robin to ``folds`` folds; ``validation`` chooses which decides, and
the other's figures are reported beside. Bins never span two blocks.
Stateful inputs (temperature slope, lags, play state) are computed over the
whole record first, then rows are split, as the node does when it replays
the record from the start. A fold's model clamps the (effective)
temperature at the range of its training blocks, as the node clamps at its
fitted range: forward, a block hotter or colder than its past is predicted
at the edge of that past.

Step 0 fits the temperature polynomial, its order per axis chosen by the
one-standard-error rule over the folds. Each round, every effect an axis
lacks is fitted jointly with the terms so far (linear least squares on bin
means, which is exact for the binned error). Time constants, the hysteresis
width and the lag are found by a bounded 1-D search on a log grid, coarse
then fine, with the linear coefficients solved at every point; the step
time of a bias step by a CUSUM. The best candidate is accepted if its
relative held-out RMS reduction is at least ``min_gain``, its mean per-fold
improvement exceeds ``significance`` standard errors, and no held-out block
but the first (where the history states start from an assumed equilibrium)
gets worse by more than ``block_tolerance`` x the larger of its RMS and the
axis's held-out RMS. The loop stops when no axis
accepts anything. Every reported error of a step comes from
`EffectModel.correct`, the code the node runs, on fold models.

The PX4-style cubic (a cubic in T, clamped as the node runs it) is the
baseline every axis must beat: the model the loop found is written only
when its held-out RMS under the deciding validation is at least
``baseline_margin`` below the cubic's and, under the scheme reported beside,
not above it; otherwise the axis writes the cubic, and `ModelChoice` says
why.

Several records of one unit (`records.join_records`) are diagnosed as one:
each keeps its own history (every stateful input starts afresh at its
first row, and a fold model runs each record from its start), and each has
its own bias offset, a constant column per record beyond the first in
every fit (a power cycle or a re-mount shifts the bias). Blocks never span
two records, and a block is predicted only when its record has training
rows (`validation.split`). The model written carries the offset of the
last record diagnosed: the robot runs after it, on the same mount, and
the node's ZRO recalibration at rest absorbs whatever a new run shifts.
``test_record`` holds the last record out; it is judged as written and
after a re-zero: its own bias over its first ``rezero_s`` seconds taken
off, as ``imu/recalibrate_zro`` does on a node.

By default the loop searches only the effects a node can run on a live
stream (`LIVE_EFFECTS`); acceleration only when the record shows the sensor
moved. The effects tied to the record's clock (time drift, bias steps) are
judged too, each round, before any live effect is added: when one passes
and gains more than every live effect that passes, nothing live is added
to that axis (a live term would only stand in for it), the search of the
axis ends and the record effect is named its ``cause``. After the loop
they are tested on top of the final model and reported as findings. Unless
``record_effects`` puts them into the search, they are never added.

Last, what the figures rest on: `OutsideFittedRange` says how much of the
test part and of each forward held-out block lies outside the temperature
range the model predicting it was fitted on (where it ran clamped), and
`ErrorByTemperature` bins the written model's held-out residuals (and the
test part's) into ``error_bins`` temperature bins (`validation.
error_by_temperature`): the validated error as a function of T, which the
node can add to its covariance.
"""

from dataclasses import dataclass, field, replace
import functools
import math
from typing import Callable, Mapping, Optional

import numpy as np

from .effects import (AxisTerms, DEFAULT_RATE_WINDOW_S, EFFECT_NAMES, EffectModel, EFFECTS,
                      FirstOrderLag, LIVE_EFFECTS, play_state, temperature_rate_c_s)
from .errors import CalibrationError, ConfigError
from .fitting import MIN_SPAN_C
from .metrics import bin_means, bin_starts, last_cycle_start_row, test_start_row
from .model_interface import INPUTS, ModelInputs
from .recalibration import RecalibrationLimits
from .records import join_records
from .validation import (BASELINE_MARGIN, cubic_instead, DEFAULT_BLOCKS, DEFAULT_FOLDS,
                         DEFAULT_MIN_PAST, error_by_temperature, FORWARD,
                         held_out_outside_range, one_standard_error, order_score,
                         outside_range, OutsideRange, PX4_ORDER, record_block_bounds,
                         ROUND_ROBIN, split, temperature_bin_edges, TemperatureErrors,
                         training_sums)

BASE_EFFECT = 'temperature_polynomial'
SEARCH_EFFECTS = tuple(e for e in LIVE_EFFECTS if e != BASE_EFFECT)
RECORD_SEARCH = ('time_drift', 'bias_step')
METHODS = ('none', 'px4_cubic', 'temperature_polynomial', 'diagnosed')
# Log grids of the 1-D searches: ratio 2^(1/4) between neighbours. The coarse pass
# visits every COARSE-th point within the bounds, the fine pass the neighbours of the best.
GRID_RATIO = 2.0 ** 0.25
COARSE = 4
TIME_GRID_S = tuple(float(GRID_RATIO ** k) for k in range(0, 81))        # 1 s .. 1.05e6 s
WIDTH_GRID_C = tuple(float(0.25 * GRID_RATIO ** k) for k in range(0, 33))  # 0.25 .. 64 C
# A time constant must fit this many times into the diagnosed part, or it is a drift.
TIME_CONSTANTS_PER_RECORD = 4.0
# The thermal lag's shortest time constant, in median sample intervals.
MIN_LAG_SAMPLES = 2.0
# Two gradient time constants closer than this ratio are one.
MIN_GRADIENT_RATIO = 2.0
# The record shows motion when the specific force turns by this much, or its
# magnitude moves by MOTION_M_S2 (1 s means, 1st to 99th percentile).
MOTION_DEG = 5.0
MOTION_M_S2 = 1.0
# Singular values of the scaled normal matrix below this (relative) count as rank loss.
RANK_RCOND = 1e-12
SUPPLY_ORDERS = (1, 2)
SECONDARY_ORDERS = (1, 2, 3)
SCALE_ORDERS = (0, 1, 2)
NONLINEARITY_ORDERS = (2, 3)
# The node's imu/recalibrate_zro: its default window (recalibration.duration_s) and the
# fewest samples it accepts in it.
DEFAULT_REZERO_S = 5.0
REZERO_MIN_SAMPLES = RecalibrationLimits.min_samples

# Temperature bins of the error-by-temperature table (equal width over the diagnosed part).
DEFAULT_ERROR_BINS = 8

Progress = Optional[Callable[[int, int, str], None]]


@dataclass(frozen=True)
class DiagnosisSettings:
    """How the diagnosis splits, averages and judges; see the module docstring."""

    folds: int = DEFAULT_FOLDS
    blocks: int = DEFAULT_BLOCKS
    average_s: float = 1.0
    max_order: int = 8
    min_gain: float = 0.1
    significance: float = 2.0
    block_tolerance: float = 1.0
    test_fraction: float = 0.0
    test_cycle: bool = False
    test_record: bool = False
    rezero_s: float = DEFAULT_REZERO_S
    rate_window_s: float = DEFAULT_RATE_WINDOW_S
    record_effects: bool = False
    validation: str = FORWARD
    min_past: float = DEFAULT_MIN_PAST
    baseline_margin: float = BASELINE_MARGIN
    error_bins: int = DEFAULT_ERROR_BINS

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
            (math.isfinite(self.block_tolerance) and self.block_tolerance >= 0.0,
             f'block_tolerance must be non-negative, got {self.block_tolerance}'),
            (math.isfinite(self.test_fraction) and 0.0 <= self.test_fraction < 1.0,
             f'test_fraction must be in [0, 1), got {self.test_fraction}'),
            (sum((self.test_cycle, bool(self.test_fraction), self.test_record)) <= 1,
             'hold out one of the last cycle, a test fraction or the last record'),
            (math.isfinite(self.rezero_s) and self.rezero_s > 0.0,
             f'rezero_s must be positive, got {self.rezero_s}'),
            (math.isfinite(self.rate_window_s) and self.rate_window_s > 0.0,
             f'rate_window_s must be positive, got {self.rate_window_s}'),
            (math.isfinite(self.baseline_margin) and 0.0 <= self.baseline_margin < 1.0,
             f'baseline_margin must be in [0, 1), got {self.baseline_margin}'),
            (self.error_bins >= 1, f'error_bins must be at least 1, got {self.error_bins}'),
        )
        for ok, msg in checks:
            if not ok:
                raise CalibrationError(msg)
        self.split()

    def split(self, scheme: Optional[str] = None):
        """Deal the blocks to folds by ``scheme`` (default: the deciding one)."""
        return split(self.blocks, scheme or self.validation, self.folds, self.min_past)

    @property
    def other_validation(self) -> str:
        """Give the scheme reported beside the deciding one."""
        return ROUND_ROBIN if self.validation == FORWARD else FORWARD

    @property
    def effects(self) -> tuple:
        """Give the effects the loop searches, in the order it tries them."""
        return SEARCH_EFFECTS + (RECORD_SEARCH if self.record_effects else ())


@dataclass(frozen=True)
class HeldOutError:
    """
    Error of binned residuals in rad/s: RMS, peak |.|, and RMS per fold and per block.

    Blocks no fold predicts (forward validation's first blocks) have NaN there.
    """

    rms_rad_s: float
    peak_rad_s: float
    fold_rms_rad_s: tuple = ()
    block_rms_rad_s: tuple = ()


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
    """An effect tried in a round and not added (or a record effect's finding)."""

    effect: str
    round_number: int
    parameters: Mapping
    held_out_gain: float
    fold_improvement_rad_s: float
    fold_improvement_se_rad_s: float
    reason: str
    worst_block_change: float = 0.0


@dataclass(frozen=True)
class ModelChoice:
    """
    The model an axis writes: the one the loop found, or the PX4-style cubic.

    ``found`` and ``cubic`` are their held-out errors under the deciding
    validation, ``other_found`` and ``other_cubic`` under the scheme reported
    beside. The found model is written when its RMS is at most (1 -
    ``margin``) x the cubic's under the first and at most the cubic's under
    the second, else ``reason`` says why the cubic is.
    """

    written: str
    found: HeldOutError
    cubic: HeldOutError
    margin: float
    other_found: HeldOutError
    other_cubic: HeldOutError
    reason: str = ''

    @property
    def ratio(self) -> float:
        """Give the found model's held-out RMS over the cubic's (deciding validation)."""
        return _ratio(self.found, self.cubic)

    @property
    def other_ratio(self) -> float:
        """Give the found model's held-out RMS over the cubic's (the scheme beside)."""
        return _ratio(self.other_found, self.other_cubic)


def _ratio(error: HeldOutError, baseline: HeldOutError) -> float:
    return error.rms_rad_s / baseline.rms_rad_s if baseline.rms_rad_s else math.inf


@dataclass(frozen=True)
class AxisDiagnosis:
    """
    What the loop found on one axis.

    ``findings`` holds the record effects (time drift, bias step) tested on
    top of the final model when the search left them out; one whose
    ``reason`` is empty passed every test. ``cause`` is the record effect
    that explained the residual better than every live effect and ended the
    search of the axis (None if none did). ``choice`` says which model the
    axis writes (`ModelChoice`).
    """

    axis: str
    order: int
    order_scores: tuple
    steps: tuple
    rejected: tuple
    findings: tuple = ()
    choice: Optional[ModelChoice] = None
    cause: Optional[Candidate] = None

    @property
    def effects(self) -> tuple:
        return tuple(step.effect for step in self.steps)


@dataclass(frozen=True)
class BinnedResidual:
    """Binned residuals (bins, axes) of the base and diagnosed models; rows per bin."""

    time_s: np.ndarray
    temperature_c: np.ndarray
    heating: np.ndarray
    before_rad_s: np.ndarray
    after_rad_s: np.ndarray
    rows: Optional[np.ndarray] = None


@dataclass(frozen=True)
class OutsideFittedRange:
    """
    Where the model runs outside the temperature range it was fitted on: it clamps there.

    Temperatures are the effective ones each axis's model clamps (T, or
    T_eff with a thermal lag), one column per axis; ``per_axis`` says whether
    they differ. ``blocks`` holds per block of the forward scheme the
    `OutsideRange` of its rows against the blocks before it (None: not
    predicted), ``test`` the test part's against the written model's range.
    """

    per_axis: bool
    blocks: tuple
    test: Optional[OutsideRange] = None


@dataclass(frozen=True)
class ErrorByTemperature:
    """
    The written model's held-out error per temperature bin (`TemperatureErrors`).

    ``held_out``: the residuals of the deciding validation's folds (the
    figure the node takes); ``test``: the written model on the test part.
    ``rows_per_bin`` is the mean number of samples per averaging bin.
    """

    validation: str
    held_out: TemperatureErrors
    rows_per_bin: float
    test: Optional[TemperatureErrors] = None


@dataclass(frozen=True)
class RecordFit:
    """
    One record of the input: its name and rows, and whether the diagnosis fitted it.

    ``offset_rad_s`` is its bias offset per axis against the written one
    (the last fitted record's), None for a held-out record.
    """

    name: str
    rows: int
    fitted: bool
    offset_rad_s: Optional[tuple]


@dataclass(frozen=True)
class Diagnosis:
    """
    The result: the model, the steps per axis, and the comparison with simpler models.

    ``comparison`` maps each validation scheme, the deciding one first (and
    'test' with a test part), to a mapping of each of METHODS to one
    `HeldOutError` per axis.
    ``skipped`` lists (effect, reason) for effects the data cannot support
    or the settings leave out. ``records`` describes each record
    (`RecordFit`); with a held-out record, 'test_rezeroed' in ``comparison``
    holds the errors after its re-zero, and ``rezero_rad_s`` maps each of
    METHODS to what the re-zero took off per axis. ``outside_range`` and
    ``error_by_temperature`` are the module docstring's last paragraph.
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
    bounds: Mapping = field(default_factory=dict)
    records: tuple = ()
    rezero_rad_s: Mapping = field(default_factory=dict)
    first_blocks: tuple = (0,)
    outside_range: Optional[OutsideFittedRange] = None
    error_by_temperature: Optional[ErrorByTemperature] = None

    def split(self, scheme: Optional[str] = None):
        """Give the blocks as a scheme (default: the deciding one) dealt them, records and all."""
        settings = self.settings
        return split(settings.blocks, scheme or settings.validation, settings.folds,
                     settings.min_past, self.first_blocks)


@dataclass(frozen=True)
class _Spec:
    """
    The effects of one axis: the polynomial order and each effect's choice.

    ``choices`` pairs an effect with what the search chose for it (a time
    constant, a width, an order, True), in EFFECT_NAMES order: the order of
    the design columns. ``thermal_gradient`` holds one or two time constants,
    the second being ``thermal_gradient_2``.
    """

    order: int
    choices: tuple = ()

    def get(self, effect: str, default=None):
        return dict(self.choices).get(effect, default)

    def with_choice(self, effect: str, choice) -> '_Spec':
        choices = dict(self.choices, **{effect: choice})
        return replace(self, choices=tuple((e, choices[e]) for e in EFFECT_NAMES if e in choices))

    @property
    def thermal_lag_s(self) -> float:
        return self.get('thermal_lag', 0.0)

    @property
    def gradient_s(self) -> tuple:
        return self.get('thermal_gradient', ())

    @property
    def effects(self) -> set:
        present = {BASE_EFFECT} | {effect for effect, _ in self.choices}
        return present | ({'thermal_gradient_2'} if len(self.gradient_s) > 1 else set())


@dataclass(frozen=True)
class _Score:
    fold_rms: np.ndarray
    rms: float
    rank_ok: bool
    residual: np.ndarray = field(repr=False)


def _rms(values, weights) -> float:
    total = float(np.sum(weights))
    return math.sqrt(float(np.sum(weights * np.square(values))) / total) if total else math.nan


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


class _Folds:
    """The bins each fold of a `validation.Split` fits on and predicts."""

    def __init__(self, split_, bin_block: np.ndarray, block_rows: np.ndarray):
        self.split = split_
        self.train = tuple(used[bin_block] for used in split_.training)
        self.held = tuple(used[bin_block] for used in split_.held)
        # The fold predicting each block, -1 for blocks no fold predicts.
        self.block_fold = np.where(split_.predicted, np.argmax(split_.held, axis=0), -1)
        self.scored = split_.predicted[bin_block]
        # A fold's model runs from the record start to the end of its last held block.
        self.stop = tuple(int(block_rows[np.flatnonzero(used)[-1] + 1])
                          for used in split_.held)


class _Problem:
    """The rows, bins, folds and cached bin-mean features of one diagnosis."""

    def __init__(self, recording, settings: DiagnosisSettings, progress: Progress):
        self.settings = settings
        self.progress = progress
        recording = self.records = join_records(recording)
        self.axes = tuple(recording.axes)
        total = len(recording.time_s)
        self.rows = _test_start(recording, settings)
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
        self.time_reference_s = float(self.time[0])
        # The longest record: a time constant must fit into one (histories restart).
        self.duration_s = max(max(float(self.time[rows.stop - 1] - self.time[rows.start])
                                  for rows in recording.segments(self.rows)), 1.0)
        self.slope = self.each(functools.partial(temperature_rate_c_s,
                                                 window_s=settings.rate_window_s),
                               self.time, self.temperature)
        self._split()
        self.truth_is_reference = self.reference is not None
        error = self.rate if self.reference is None else self.rate - self.reference
        self.target = self.mean(error)
        self.secondary = _centre_and_half_span(self.inputs.temperature_2_c)
        self.supply_reference = _centre_and_half_span(self.inputs.supply_voltage_v)
        self.bounds = self._bounds()
        self._cache = {}

    def _check_size(self) -> None:
        needed = 2 * self.settings.blocks
        if self.rows < needed:
            msg = (f'{self.rows} rows to diagnose (after the test part); '
                   f'{self.settings.blocks} blocks need at least {needed}')
            raise CalibrationError(msg)

    def _bounds(self) -> dict:
        """Give the search ranges of the nonlinear parameters (record length and span)."""
        interval = float(np.median(np.diff(self.time)))
        longest = self.duration_s / TIME_CONSTANTS_PER_RECORD
        return {'thermal_lag_s': (max(MIN_LAG_SAMPLES * interval, TIME_GRID_S[0]), longest),
                'gradient_time_constant_s': (self.settings.rate_window_s, longest),
                'hysteresis_half_width_c': (WIDTH_GRID_C[0], self.half_span_c)}

    def each(self, operator, *columns) -> np.ndarray:
        """Run a history operator over each record's rows of ``columns`` (`Records.each`)."""
        return self.records.each(operator, *columns)

    def _split(self) -> None:
        """Cut rows into blocks (none spanning two records), bins inside blocks; deal blocks."""
        settings = self.settings
        rows = [part.stop - part.start for part in self.records.segments(self.rows)]
        edges, self.first_blocks = record_block_bounds(rows, settings.blocks)
        self.block_edges = edges
        block = np.repeat(np.arange(settings.blocks), np.diff(edges))
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
        self.bin_block = block[self.starts]
        self.folds = self.folds_of(settings.validation)

    def folds_of(self, scheme: str) -> _Folds:
        """Return the folds of a validation scheme over this problem's bins."""
        settings = self.settings
        return _Folds(split(settings.blocks, scheme, settings.folds, settings.min_past,
                            self.first_blocks), self.bin_block, self.block_edges)

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
        return _effective(self.records, self.time, self.temperature, self.slope, lag_s)

    def x(self, lag_s: float) -> np.ndarray:
        return (self.effective(lag_s) - self.centre_c) / self.half_span_c

    def powers(self, values: np.ndarray, first: int, last: int) -> np.ndarray:
        columns = []
        power = values ** first
        for _ in range(first, last + 1):
            columns.append(self.mean(power))
            power = power * values
        return np.column_stack(columns)

    def _lag_features(self, lag_s: float) -> tuple:
        """Return (bin means of x^0..x^max_order, lowest and highest T_eff per block) of a lag."""
        def build():
            effective = self.effective(lag_s)
            x = (effective - self.centre_c) / self.half_span_c
            starts = self.block_edges[:-1]
            return (self.powers(x, 0, self.settings.max_order),
                    np.minimum.reduceat(effective, starts), np.maximum.reduceat(effective, starts))
        return self.cached(('lag', lag_s), build)

    def polynomial(self, lag_s: float) -> np.ndarray:
        return self._lag_features(lag_s)[0]

    def predicted_polynomial(self, lag_s: float, folds: _Folds) -> np.ndarray:
        """Return `polynomial` as the folds predict it: T_eff clamped at their training range."""
        def build():
            powers, block_low, block_high = self._lag_features(lag_s)
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
                x = (np.clip(effective[rows], low, high) - self.centre_c) / self.half_span_c
                starts = self.starts[bins] - rows.start
                predicted[bins] = (np.add.reduceat(np.polynomial.polynomial.polyvander(
                    x, self.settings.max_order), starts, axis=0) / self.counts[bins][:, None])
            return predicted
        return self.cached(('predicted', lag_s, folds.split.scheme), build)

    def acceleration_means(self) -> np.ndarray:
        return self.cached('acceleration', lambda: self.mean(self.inputs.acceleration_m_s2))

    def design(self, axis: int, spec: _Spec) -> np.ndarray:
        """Return the bin-mean design matrix of an axis; columns in `_terms` order."""
        blocks = [self.polynomial(spec.thermal_lag_s)[:, :spec.order + 1]]
        for effect, choice in spec.choices:
            columns = _FITS[effect].columns
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

    def score_spec(self, axis: int, spec: _Spec, folds: Optional[_Folds] = None) -> _Score:
        """Score the terms of ``spec`` on an axis, the polynomial clamped as the folds run it."""
        folds = folds or self.folds
        design = self.design(axis, spec)
        predict = design.copy()
        # The polynomial's columns come first (`design`).
        width = spec.order + 1
        predict[:, :width] = self.predicted_polynomial(spec.thermal_lag_s, folds)[:, :width]
        return self.score(design, predict, axis, folds)

    def score(self, design: np.ndarray, predict: np.ndarray, axis: int,
              folds: _Folds) -> _Score:
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
        for fold, held in enumerate(folds.held):
            solution, full_rank = _solve_normal(grams[fold], moments[fold])
            rank_ok = rank_ok and full_rank
            residual[held] = target[held] - predict[held] @ solution
            fold_rms[fold] = _rms(residual[held], self.counts[held])
        scored = folds.scored
        return _Score(fold_rms, _rms(residual[scored], self.counts[scored]), rank_ok, residual)

    def fit_terms(self, axis: int, spec: _Spec, bins=None) -> AxisTerms:
        """Fit one axis on the given bins (all when None); its terms with the written offset."""
        terms, offsets = self.fit_offsets(axis, spec, bins)
        return _shifted(terms, offsets[-1])

    def fit_offsets(self, axis: int, spec: _Spec, bins=None) -> tuple:
        """
        Fit one axis on the given bins (all when None).

        Return (its terms, each fitted record's offset to add to their constant:
        0 for the first).
        """
        design = self.design(axis, spec)
        target = self.target[:, axis]
        if bins is not None:
            design, target = design[bins], target[bins]
        weights = self.counts if bins is None else self.counts[bins]
        # The solver `score` uses: a fold's model is the one its score was judged on.
        weighted = design * weights[:, None]
        solution, _ = _solve_normal(weighted.T @ design, weighted.T @ target)
        offsets = self.fitted_records - 1
        return (self._terms(axis, spec, solution[:solution.size - offsets]),
                (0.0,) + tuple(float(v) for v in solution[solution.size - offsets:]))

    def _terms(self, axis: int, spec: _Spec, solution: np.ndarray) -> AxisTerms:
        values = iter(float(v) for v in solution)

        def take(count: int) -> tuple:
            return tuple(next(values) for _ in range(count))

        terms = {'bias': take(spec.order + 1)}
        for effect, choice in spec.choices:
            terms.update(_FITS[effect].terms(self, axis, choice, take))
        return AxisTerms(**terms)

    def model(self, specs: tuple, fold: Optional[int] = None,
              folds: Optional[_Folds] = None) -> EffectModel:
        """Fit every axis on all bins, or on the training bins of ``fold``; written offset."""
        return self.record_models(specs, fold, folds)[-1]

    def record_models(self, specs: tuple, fold: Optional[int] = None,
                      folds: Optional[_Folds] = None) -> tuple:
        """
        Fit every axis on all bins, or on the training bins of ``fold``: one model per record.

        Each fitted record's model has its own offset; a record after them
        (the test record) runs the last one's, the written offset.
        """
        folds = folds or self.folds
        bins = None if fold is None else folds.train[fold]
        low, high = self.clamp_range(specs, None if fold is None else
                                     folds.split.training[fold])
        secondary = self.secondary or (25.0, 1.0)
        supply = self.supply_reference or (EffectModel.supply_reference_v, 1.0)
        fits = [self.fit_offsets(axis, spec, bins) for axis, spec in enumerate(specs)]
        model = EffectModel(
            terms=tuple(terms for terms, _ in fits),
            reference_temperature_c=self.centre_c, temperature_scale_c=self.half_span_c,
            temperature_min_c=low, temperature_max_c=high,
            temperature_rate_window_s=self.settings.rate_window_s,
            time_reference_s=self.time_reference_s, secondary_reference_c=secondary[0],
            secondary_scale_c=secondary[1], supply_reference_v=supply[0])
        models = tuple(replace(model, terms=tuple(_shifted(terms, offsets[record])
                                                  for terms, offsets in fits))
                       for record in range(self.fitted_records))
        return models + models[-1:] * (self.records.count - self.fitted_records)

    def record_offsets(self, specs: tuple) -> np.ndarray:
        """Give each fitted record's bias offset (records, axes) against the written one."""
        offsets = np.array([self.fit_offsets(axis, spec)[1] for axis, spec in enumerate(specs)])
        return (offsets - offsets[:, -1:]).T

    def clamp_range(self, specs: tuple, blocks: Optional[np.ndarray] = None) -> tuple:
        """Return the range of T_eff over the given blocks (all when None) and all axes."""
        used = slice(None) if blocks is None else blocks
        ranges = [self._lag_features(spec.thermal_lag_s)[1:] for spec in specs]
        return (float(min(np.min(low[used]) for low, _ in ranges)),
                float(max(np.max(high[used]) for _, high in ranges)))

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

    def held_out(self, specs: tuple, label: str, folds: Optional[_Folds] = None,
                 axes: Optional[tuple] = None) -> tuple:
        """
        Return (binned held-out residual (bins, axes), HeldOutError per axis).

        Only ``axes`` (default: all) are run; the others' columns stay NaN.
        """
        folds = folds or self.folds
        axes = range(len(self.axes)) if axes is None else axes
        residual = np.full((len(self.starts), len(self.axes)), math.nan)
        count = folds.split.folds
        for fold, held in enumerate(folds.held):
            self.report(fold, count, label)
            model = self.record_models(specs, fold, folds)
            for axis in axes:
                binned = self.mean(self.residual(model, axis, folds.stop[fold]))
                residual[:binned.size, axis][held[:binned.size]] = binned[held[:binned.size]]
        self.report(count, count, label)
        return residual, tuple(self.error(residual[:, axis], folds) if axis in axes else None
                               for axis in range(len(self.axes)))

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

    def error(self, residual: np.ndarray, folds: Optional[_Folds] = None) -> HeldOutError:
        """Return the `HeldOutError` of binned residuals on the bins the folds predict."""
        folds = folds or self.folds
        scored = folds.scored
        per_fold = tuple(_rms(residual[held], self.counts[held]) for held in folds.held)
        return HeldOutError(_rms(residual[scored], self.counts[scored]),
                            float(np.max(np.abs(residual[scored]))), per_fold,
                            tuple(float(v) for v in self.block_rms(residual)))

    def motion(self) -> tuple:
        """Return (turn of the specific force in deg, change of its magnitude in m/s^2)."""
        means = self.acceleration_means()
        magnitude = np.linalg.norm(means, axis=1)
        usable = magnitude > 0.0
        if not usable.any():
            return 0.0, 0.0
        direction = means[usable] / magnitude[usable, None]
        centre = np.median(direction, axis=0)
        centre /= np.linalg.norm(centre)
        angle = np.degrees(np.arccos(np.clip(direction @ centre, -1.0, 1.0)))
        low, high = np.percentile(magnitude[usable], (1.0, 99.0))
        return float(np.percentile(angle, 99.0)), float(high - low)

    def report(self, done: int, total: int, label: str) -> None:
        if self.progress is not None:
            self.progress(done, total, label)


def _shifted(terms: AxisTerms, offset_rad_s: float) -> AxisTerms:
    """Give the terms with ``offset_rad_s`` added to the polynomial's constant."""
    if not offset_rad_s:
        return terms
    return replace(terms, bias=(terms.bias[0] + offset_rad_s,) + terms.bias[1:])


def _effective(records, time_s: np.ndarray, temperature_c: np.ndarray, slope_c_s: np.ndarray,
               lag_s: float) -> np.ndarray:
    """
    T_eff of a thermal lag (`EffectModel`), row by row; ``slope_c_s`` the windowed dT/dt.

    A lag filter starts afresh at each record's first row (`Records.each`).
    """
    if lag_s > 0.0:
        return temperature_c + lag_s * slope_c_s
    if lag_s < 0.0:
        return records.each(FirstOrderLag(-lag_s).batch, time_s, temperature_c)
    return temperature_c


def _centre_and_half_span(values) -> Optional[tuple]:
    """Return (centre, half span) of a column, None when absent or constant."""
    if values is None:
        return None
    low, high = float(np.min(values)), float(np.max(values))
    return (0.5 * (low + high), 0.5 * (high - low)) if high > low else None


def _test_start(recording, settings: DiagnosisSettings) -> int:
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


def _order_scores(problem: _Problem, axis: int, spec: _Spec) -> tuple:
    """Score every polynomial order with the other terms of ``spec`` fitted alongside."""
    scores = []
    for order in range(problem.settings.max_order + 1):
        score = problem.score_spec(axis, replace(spec, order=order))
        scores.append(order_score(order, score.fold_rms if score.rank_ok else
                                  np.full(score.fold_rms.shape, math.inf)))
    return tuple(scores)


def _choose_order(axis_name: str, scores: tuple) -> int:
    try:
        return one_standard_error(scores)
    except CalibrationError as err:
        msg = f'axis {axis_name}: {err}'
        raise CalibrationError(msg) from None


def _rechosen_order(problem: _Problem, axis: int, trial: _Spec) -> _Spec:
    """
    Choose the polynomial order again beside an accepted effect.

    The new term may take over what a higher order did, or free one up; the
    order the effect was judged with stays when the rule's choice has a
    higher held-out RMS (the rule allows one standard error of the mean fold
    RMS, which forward folds make wide).
    """
    chosen = replace(trial, order=_choose_order(problem.axes[axis],
                                                _order_scores(problem, axis, trial)))
    better = problem.score_spec(axis, chosen).rms <= problem.score_spec(axis, trial).rms
    return chosen if better else trial


def _skipped(problem: _Problem) -> dict:
    """Map each effect the data cannot support, or the settings leave out, to the reason."""
    reference = ', '.join(f'ref_{a}' for a in problem.axes)
    bounds = problem.bounds
    skipped = {}
    low, high = bounds['gradient_time_constant_s']
    if low > high:
        for effect in ('thermal_gradient', 'thermal_gradient_2'):
            skipped[effect] = (f'the diagnosed part ({problem.duration_s:.0f} s) is too short: '
                               f'time constants from {low:g} s (the rate window) must fit '
                               f'{TIME_CONSTANTS_PER_RECORD:g} times into it')
    if bounds['thermal_lag_s'][0] > bounds['thermal_lag_s'][1]:
        skipped['thermal_lag'] = f'the diagnosed part ({problem.duration_s:.0f} s) is too short'
    for effect in EFFECTS:
        lacking = [column for name in sorted(effect.inputs)
                   if getattr(problem.inputs, name) is None for column in INPUTS[name].columns]
        if lacking:
            skipped[effect.name] = f'needs column{"s" * (len(lacking) > 1)} {", ".join(lacking)}'
    if 'supply_voltage' not in skipped and problem.supply_reference is None:
        skipped['supply_voltage'] = 'supply_voltage is constant'
    if 'secondary_temperature' not in skipped and problem.secondary is None:
        skipped['secondary_temperature'] = 'temperature_2 is constant'
    if 'acceleration_sensitivity' not in skipped:
        turn_deg, change_m_s2 = problem.motion()
        if turn_deg < MOTION_DEG and change_m_s2 < MOTION_M_S2:
            skipped['acceleration_sensitivity'] = (
                f'the sensor did not move: the specific force turns {turn_deg:.2g} deg and '
                f'its magnitude changes {change_m_s2:.2g} m/s^2 (needs {MOTION_DEG:g} deg or '
                f'{MOTION_M_S2:g} m/s^2); a term would only stand in for temperature')
    for effect in ('scale_factor_temperature', 'rate_nonlinearity', 'cross_axis'):
        if problem.reference is None:
            skipped[effect] = f'needs reference columns {reference}'
    if 'cross_axis' not in skipped and len(problem.axes) < 2:
        skipped['cross_axis'] = 'needs at least 2 gyro axes'
    if not problem.settings.record_effects:
        for effect in RECORD_SEARCH:
            skipped[effect] = ("tied to the record's clock, a live node cannot run it: tested "
                               'as a finding only (--record-effects adds it)')
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


def _grid_search(grid: tuple, low: float, high: float, evaluate) -> None:
    """
    Bounded 1-D search of ``evaluate`` over the grid points in [low, high].

    Every COARSE-th point first, then the neighbours of the best at half the
    stride, down to the grid's own spacing.
    """
    points = [value for value in grid if low <= value <= high]
    if not points:
        return
    seen = {}

    def rms(index: int) -> float:
        if index not in seen:
            seen[index] = evaluate(points[index])
        return seen[index]

    coarse = sorted(set(range(0, len(points), COARSE)) | {len(points) - 1})
    best = min(coarse, key=rms)
    stride = COARSE // 2
    while stride >= 1:
        for index in (best - stride, best + stride):
            if 0 <= index < len(points) and rms(index) < rms(best):
                best = index
        stride //= 2


class _Search:
    """Keeps the best (spec, score) of the trials of one effect."""

    def __init__(self, problem: _Problem, axis: int):
        self.problem, self.axis, self.best = problem, axis, None

    def __call__(self, spec: _Spec) -> float:
        score = self.problem.score_spec(self.axis, spec)
        if self.best is None or score.rms < self.best[1].rms:
            self.best = (spec, score)
        return score.rms


def _available(effect: str, spec: _Spec) -> bool:
    """Whether ``effect`` can be added to ``spec`` this round."""
    if effect in spec.effects:
        return False
    return effect != 'thermal_gradient_2' or len(spec.gradient_s) == 1


def _best_trial(problem: _Problem, axis: int, spec: _Spec, effect: str) -> Optional[tuple]:
    """Return (best spec, its score) for one effect, None if none fits the search bounds."""
    search = _Search(problem, axis)
    _FITS[effect].trials(search, problem, axis, spec)
    return search.best


@dataclass(frozen=True)
class _Fit:
    """
    How the loop fits one effect on an axis.

    ``trials(search, problem, axis, spec)`` scores each choice worth trying
    with `_Search`; ``columns(problem, axis, spec, choice)`` gives the
    effect's bin-mean design columns (None: it moves the polynomial's x);
    ``terms(problem, axis, choice, take)`` its `AxisTerms` fields, ``take(n)``
    giving its next n fitted coefficients (None: another effect holds its
    choice); ``report(terms, problem)`` its fitted parameters in SI units.
    """

    trials: Callable
    report: Callable
    columns: Optional[Callable] = None
    terms: Optional[Callable] = None


def _flag(effect: str) -> Callable:
    """Trials of an effect without a choice: one, the effect in."""
    def trials(search: _Search, problem: _Problem, axis: int, spec: _Spec) -> None:
        search(spec.with_choice(effect, True))
    return trials


def _orders(effect: str, orders: tuple) -> Callable:
    """Trials of an effect whose choice is a polynomial order: each of ``orders``."""
    def trials(search: _Search, problem: _Problem, axis: int, spec: _Spec) -> None:
        for order in orders:
            search(spec.with_choice(effect, order))
    return trials


def _lag_trials(search: _Search, problem: _Problem, axis: int, spec: _Spec) -> None:
    low, high = problem.bounds['thermal_lag_s']
    for sign in (1.0, -1.0):
        _grid_search(TIME_GRID_S, low, high,
                     lambda tau: search(spec.with_choice('thermal_lag', sign * tau)))


def _lag_report(terms: AxisTerms, problem: _Problem) -> dict:
    lag = terms.thermal_lag_s
    return {'thermal_lag_s': lag,
            'form': ('the sensor lags: T_eff = T + lag x dT/dt' if lag > 0.0 else
                     'the element lags: T_eff = first-order lag of T'),
            'temperature_rate_window_s': problem.settings.rate_window_s}


def _rate_columns(problem: _Problem, axis: int, spec: _Spec, choice) -> np.ndarray:
    return problem.cached('rate', lambda: problem.mean(problem.slope)[:, None])


def _gradient_trials(search: _Search, problem: _Problem, axis: int, spec: _Spec) -> None:
    low, high = problem.bounds['gradient_time_constant_s']
    _grid_search(TIME_GRID_S, low, high,
                 lambda tau: search(spec.with_choice('thermal_gradient', (tau,))))


def _second_gradient(search: _Search, problem: _Problem, axis: int, spec: _Spec) -> None:
    """Search a second gradient time constant, then the first again beside it."""
    bounds = problem.bounds['gradient_time_constant_s']
    (first,) = spec.gradient_s

    def pair(kept: float, tau: float) -> float:
        if max(kept, tau) < MIN_GRADIENT_RATIO * min(kept, tau):
            return math.inf
        return search(spec.with_choice('thermal_gradient', tuple(sorted((kept, tau)))))

    _grid_search(TIME_GRID_S, *bounds, lambda tau: pair(first, tau))
    if search.best is not None:
        second = next(t for t in search.best[0].gradient_s if t != first)
        _grid_search(TIME_GRID_S, *bounds, lambda tau: pair(second, tau))


def _gradient_columns(problem: _Problem, axis: int, spec: _Spec, taus: tuple) -> np.ndarray:
    def difference(tau: float) -> np.ndarray:
        lagged = problem.each(FirstOrderLag(tau).batch, problem.time, problem.temperature)
        return problem.mean(problem.temperature - lagged)
    return np.column_stack([problem.cached(('gradient', tau), functools.partial(difference, tau))
                            for tau in taus])


def _gradient_report(terms: AxisTerms, problem: _Problem) -> dict:
    return {'time_constants_s': list(terms.gradient_time_constants_s),
            'rad_s_per_c': list(terms.gradient_rad_s_per_c)}


def _hysteresis_trials(search: _Search, problem: _Problem, axis: int, spec: _Spec) -> None:
    low, high = problem.bounds['hysteresis_half_width_c']
    _grid_search(WIDTH_GRID_C, low, high,
                 lambda width: search(spec.with_choice('hysteresis', width)))


def _play_columns(problem: _Problem, axis: int, spec: _Spec, width_c: float) -> np.ndarray:
    return problem.cached(('play', width_c), lambda: problem.mean(problem.each(
        functools.partial(play_state, half_width_c=width_c), problem.temperature))[:, None])


def _supply_columns(problem: _Problem, axis: int, spec: _Spec, order: int) -> np.ndarray:
    reference, _ = problem.supply_reference
    return problem.cached('supply', lambda: problem.powers(
        problem.inputs.supply_voltage_v - reference, 1, max(SUPPLY_ORDERS)))[:, :order]


def _secondary_columns(problem: _Problem, axis: int, spec: _Spec, order: int) -> np.ndarray:
    reference, scale = problem.secondary
    return problem.cached('secondary', lambda: problem.powers(
        (problem.inputs.temperature_2_c - reference) / scale, 1, max(SECONDARY_ORDERS)))[:, :order]


def _scale_columns(problem: _Problem, axis: int, spec: _Spec, order: int) -> np.ndarray:
    lag_s = spec.thermal_lag_s

    def build():
        x = problem.x(lag_s)
        truth = problem.reference[:, axis]
        return np.column_stack([problem.mean(truth * x ** k)
                                for k in range(max(SCALE_ORDERS) + 1)])
    return problem.cached(('scale', axis, lag_s), build)[:, :order + 1]


def _nonlinearity_columns(problem: _Problem, axis: int, spec: _Spec, order: int) -> np.ndarray:
    return problem.cached(('nonlinearity', axis), lambda: problem.powers(
        problem.reference[:, axis], 2, max(NONLINEARITY_ORDERS)))[:, :order - 1]


def _cross_columns(problem: _Problem, axis: int, spec: _Spec, choice) -> np.ndarray:
    others = [j for j in range(len(problem.axes)) if j != axis]
    return problem.cached(('cross', axis), lambda: problem.mean(problem.reference[:, others]))


def _cross_terms(problem: _Problem, axis: int, choice, take) -> dict:
    others = iter(take(len(problem.axes) - 1))
    return {'cross_axis': tuple(0.0 if j == axis else next(others)
                                for j in range(len(problem.axes)))}


def _drift_columns(problem: _Problem, axis: int, spec: _Spec, choice) -> np.ndarray:
    return problem.cached('drift', lambda: problem.mean(
        (problem.time - problem.time_reference_s) / problem.duration_s)[:, None])


def _step_trials(search: _Search, problem: _Problem, axis: int, spec: _Spec) -> None:
    search(spec.with_choice('bias_step', _step_time(problem, axis, spec)))


def _step_columns(problem: _Problem, axis: int, spec: _Spec, time_s: float) -> np.ndarray:
    return problem.cached(('step', time_s), lambda: problem.mean(
        (problem.time >= time_s).astype(np.float64))[:, None])


def _step_report(terms: AxisTerms, problem: _Problem) -> dict:
    (time_s, step_rad_s), = terms.bias_steps
    records = problem.records
    if records.count == 1:
        return {'time_s': time_s, 'step_rad_s': step_rad_s,
                'after_start_s': time_s - problem.time_reference_s}
    # Several records: the stamp on the clock of the record the step lies in.
    record, own_s = records.own_time_s(time_s)
    return {'time_s': own_s, 'step_rad_s': step_rad_s,
            'after_start_s': float(time_s - records.time_s[records.starts[record]]),
            'record': records.names[record]}


# Every effect but BASE_EFFECT; the design columns come in EFFECT_NAMES order.
_FITS = {
    'thermal_lag': _Fit(_lag_trials, _lag_report,
                        terms=lambda problem, axis, lag_s, take: {'thermal_lag_s': lag_s}),
    'temperature_rate': _Fit(
        _flag('temperature_rate'),
        lambda terms, problem: {'rad_s_per_c_s': terms.temperature_rate_rad_s_per_c_s,
                                'temperature_rate_window_s': problem.settings.rate_window_s},
        _rate_columns,
        lambda problem, axis, choice, take: {'temperature_rate_rad_s_per_c_s': take(1)[0]}),
    'thermal_gradient': _Fit(
        _gradient_trials, _gradient_report, _gradient_columns,
        lambda problem, axis, taus, take: {'gradient_time_constants_s': taus,
                                           'gradient_rad_s_per_c': take(len(taus))}),
    'thermal_gradient_2': _Fit(_second_gradient, _gradient_report),
    'hysteresis': _Fit(
        _hysteresis_trials,
        lambda terms, problem: {'half_width_c': terms.hysteresis_half_width_c,
                                'hysteresis_rad_s': terms.hysteresis_rad_s},
        _play_columns,
        lambda problem, axis, width_c, take: {'hysteresis_half_width_c': width_c,
                                              'hysteresis_rad_s': take(1)[0]}),
    'supply_voltage': _Fit(
        _orders('supply_voltage', SUPPLY_ORDERS),
        lambda terms, problem: {'rad_s_per_v_k': list(terms.supply_voltage),
                                'supply_reference_v': problem.supply_reference[0]},
        _supply_columns, lambda problem, axis, order, take: {'supply_voltage': take(order)}),
    'secondary_temperature': _Fit(
        _orders('secondary_temperature', SECONDARY_ORDERS),
        lambda terms, problem: {'coefficients_rad_s': list(terms.secondary)},
        _secondary_columns, lambda problem, axis, order, take: {'secondary': take(order)}),
    'acceleration_sensitivity': _Fit(
        _flag('acceleration_sensitivity'),
        lambda terms, problem: {'rad_s_per_m_s2': list(terms.acceleration_rad_s_per_m_s2)},
        lambda problem, axis, spec, choice: problem.acceleration_means(),
        lambda problem, axis, choice, take: {'acceleration_rad_s_per_m_s2': take(3)}),
    'scale_factor_temperature': _Fit(
        _orders('scale_factor_temperature', SCALE_ORDERS),
        lambda terms, problem: {'relative_coefficients': list(terms.scale)},
        _scale_columns, lambda problem, axis, order, take: {'scale': take(order + 1)}),
    'rate_nonlinearity': _Fit(
        _orders('rate_nonlinearity', NONLINEARITY_ORDERS),
        lambda terms, problem: {'coefficients': list(terms.nonlinearity)},
        _nonlinearity_columns,
        lambda problem, axis, order, take: {'nonlinearity': take(order - 1)}),
    'cross_axis': _Fit(_flag('cross_axis'),
                       lambda terms, problem: {'coefficients': list(terms.cross_axis)},
                       _cross_columns, _cross_terms),
    'time_drift': _Fit(
        _flag('time_drift'),
        lambda terms, problem: {'rad_s_per_s': terms.time_drift_rad_s_per_s,
                                'time_reference_s': problem.time_reference_s},
        _drift_columns,
        lambda problem, axis, choice, take: {
            'time_drift_rad_s_per_s': take(1)[0] / problem.duration_s}),
    'bias_step': _Fit(_step_trials, _step_report, _step_columns,
                      lambda problem, axis, time_s, take: {
                          'bias_steps': ((time_s, take(1)[0]),)}),
}


def _unbounded(problem: _Problem, effect: str, spec: _Spec) -> str:
    """
    Return why a time constant found at the upper search bound is refused, or ''.

    There the record would take a longer one: a slow trend the record cannot
    tell from a drift.
    """
    if effect == 'thermal_lag':
        values, high = (abs(spec.thermal_lag_s),), problem.bounds['thermal_lag_s'][1]
    elif effect in ('thermal_gradient', 'thermal_gradient_2'):
        values, high = spec.gradient_s, problem.bounds['gradient_time_constant_s'][1]
    else:
        return ''
    top = max(v for v in TIME_GRID_S if v <= high)
    if max(values) < top:
        return ''
    return (f'time constant {max(values):.4g} s at the upper search bound (the diagnosed '
            f'part / {TIME_CONSTANTS_PER_RECORD:g}): a slow trend this record cannot tell '
            'from a drift')


def _parameters(effect: str, terms: AxisTerms, problem: _Problem) -> dict:
    """Return the fitted parameters of one effect of an axis, in SI units."""
    if effect == BASE_EFFECT:
        return {'order': len(terms.bias) - 1, 'bias_rad_s': list(terms.bias),
                'reference_temperature_c': problem.centre_c,
                'temperature_scale_c': problem.half_span_c}
    return _FITS[effect].report(terms, problem)


def _judge(problem: _Problem, base: _Score, score: _Score) -> tuple:
    """
    Return (relative gain, mean fold improvement, its SE, worst block change, why rejected).

    A block's change is the rise of its held-out RMS over the larger of that
    RMS and the axis's overall held-out RMS; the worst is the largest.
    """
    settings = problem.settings
    gain = (base.rms - score.rms) / base.rms if base.rms > 0.0 else 0.0
    improvement = base.fold_rms - score.fold_rms
    mean = float(np.mean(improvement))
    error = float(np.std(improvement, ddof=1) / math.sqrt(improvement.size))
    before, after = problem.block_rms(base.residual), problem.block_rms(score.residual)
    # A block near zero cannot lose by a ratio: rises count against the axis's error too.
    # Block 0 is not judged: there every history state starts from an assumed equilibrium.
    change = (after - before) / np.maximum(before, base.rms)
    change[~np.isfinite(change)] = -math.inf  # blocks no fold predicts
    change[0] = -math.inf
    worst = int(np.argmax(change))
    if not score.rank_ok:
        reason = ('on the training blocks of some fold the term cannot be told from the '
                  'others (rank loss)')
    elif not math.isfinite(gain) or gain < settings.min_gain:
        reason = f'held-out gain {gain:.3f} below --min-gain {settings.min_gain:g}'
    elif not mean > settings.significance * error:
        reason = (f'mean fold improvement {mean:.3g} rad/s not above '
                  f'{settings.significance:g} standard errors ({error:.3g} rad/s)')
    elif change[worst] > settings.block_tolerance:
        reason = (f'held-out block {worst} loses: {before[worst]:.3g} -> {after[worst]:.3g} '
                  f'rad/s, a rise of {change[worst]:.2f} x max(its RMS, the axis RMS '
                  f'{base.rms:.3g}); --block-tolerance {settings.block_tolerance:g}')
    else:
        reason = ''
    return gain, mean, error, float(change[worst]), reason


def _candidate(problem: _Problem, axis: int, effect: str, trial: _Spec, judged: tuple,
               number: int, reason: str) -> Candidate:
    gain, mean, error, worst, _ = judged
    parameters = _parameters(effect, problem.fit_terms(axis, trial), problem)
    return Candidate(effect, number, parameters, gain, mean, error, reason, worst)


def _findings(problem: _Problem, axis: int, spec: _Spec, number: int) -> tuple:
    """Test the record effects on top of the final model of an axis; report, do not add."""
    current = problem.score_spec(axis, spec)
    findings = []
    for effect in RECORD_SEARCH:
        trial, score = _best_trial(problem, axis, spec, effect)  # always one trial
        judged = _judge(problem, current, score)
        findings.append(_candidate(problem, axis, effect, trial, judged, number, judged[4]))
    return tuple(findings)


def _choose_model(settings: DiagnosisSettings, found: tuple, cubic: tuple) -> ModelChoice:
    """
    Write the found model if it beats the cubic (`cubic_instead`) and loses beside, else the cubic.

    ``found`` and ``cubic`` are (deciding, beside) held-out errors.
    """
    margin = settings.baseline_margin
    choice = ModelChoice('diagnosed', found[0], cubic[0], margin, found[1], cubic[1])
    deciding, beside = (scheme.replace('_', '-') for scheme in (settings.validation,
                                                                settings.other_validation))
    reason = cubic_instead(choice.found.rms_rad_s, choice.cubic.rms_rad_s, margin, deciding)
    if not reason and choice.other_ratio > 1.0:
        reason = (f'the model found has {beside} held-out RMS '
                  f'{choice.other_found.rms_rad_s:.3e} rad/s, {choice.other_ratio:.2f}x the '
                  f"PX4-style cubic's {choice.other_cubic.rms_rad_s:.3e} rad/s: worse there")
    if not reason:
        return choice
    return replace(choice, written='px4_cubic',
                   reason=reason + ', so the simpler cubic is written')


def _cubic_errors(problem: _Problem, folds: _Folds) -> tuple:
    """
    Return the held-out error of the PX4-style cubic per axis.

    A cubic in raw T spans what a cubic in x does: the same least squares,
    clamped as the node runs it.
    """
    return tuple(problem.error(problem.score_spec(a, _Spec(PX4_ORDER), folds).residual, folds)
                 for a in range(len(problem.axes)))


def _cause(record: tuple, tried: list) -> Optional[Candidate]:
    """
    Return the record effect that passes and gains more than every live effect that passes.

    ``record`` holds the record effects' candidates (`_findings`), ``tried``
    the live ones as (effect, trial, judged) of the same round.
    """
    passing = [candidate for candidate in record if not candidate.reason]
    if not passing:
        return None
    best = max(passing, key=lambda candidate: candidate.held_out_gain)
    live = max((judged[0] for _, _, judged in tried if not judged[4]), default=-math.inf)
    return best if best.held_out_gain > live else None


def _heating(problem: _Problem, rows: slice, starts: np.ndarray) -> np.ndarray:
    slope = problem.each(functools.partial(temperature_rate_c_s,
                                           window_s=problem.settings.rate_window_s),
                         problem.full.time_s, problem.full.temperature_c)[rows]
    return np.add.reduceat(slope, starts) >= 0.0


def _binned_error(residual: np.ndarray, starts: np.ndarray) -> tuple:
    binned, counts = bin_means(residual, starts)
    errors = tuple(HeldOutError(_rms(binned[:, a], counts), float(np.max(np.abs(binned[:, a]))))
                   for a in range(residual.shape[1]))
    return binned, errors


def _cubic_trend(problem: _Problem, error: np.ndarray, temperature_c: np.ndarray
                 ) -> np.ndarray:
    """
    Return the PX4-style cubic fitted to ``error`` on the diagnosed rows, at ``temperature_c``.

    np.polyfit(T, rate, 3), as the PX4 script does; over several records
    with each record's offset beside it, the last one's written (the same
    treatment as the diagnosed model).
    """
    if problem.fitted_records == 1:
        return np.polyval(np.polyfit(problem.temperature, error[:problem.rows], PX4_ORDER),
                          temperature_c)

    def powers(values):
        return np.polynomial.polynomial.polyvander(
            (values - problem.centre_c) / problem.half_span_c, PX4_ORDER)

    record = np.searchsorted(problem.records.starts, np.arange(problem.rows), side='right') - 1
    offsets = (record[:, None] == np.arange(1, problem.fitted_records)[None, :])
    solution = np.linalg.lstsq(np.column_stack([powers(problem.temperature), offsets]),
                               error[:problem.rows], rcond=None)[0]
    return powers(temperature_c) @ solution[:PX4_ORDER + 1] + solution[-1]


def _compare_test(problem: _Problem, base_model: EffectModel, model: EffectModel) -> tuple:
    """
    Return (errors per method on the test part, binned residual before/after, re-zero).

    The errors map 'test' and, when the test part is a record, 'test_rezeroed'
    (each residual less its mean over the record's re-zero window) to the
    errors per method; re-zero maps each method to what the window took off
    per axis (empty without a test record).
    """
    full = problem.full
    test = slice(problem.rows, len(full.time_s))
    rows = len(full.time_s) - problem.rows
    starts = bin_starts(full.time_s[test], problem.settings.average_s)
    shape = (rows, len(problem.axes))
    residuals = {method: np.empty(shape) for method in METHODS}
    for axis in range(len(problem.axes)):
        truth = 0.0 if full.reference_rad_s is None else full.reference_rad_s[:, axis]
        error = full.gyro_rad_s[:, axis] - truth
        residuals['none'][:, axis] = error[test]
        residuals['px4_cubic'][:, axis] = error[test] - _cubic_trend(
            problem, error, full.temperature_c[test])
        residuals['temperature_polynomial'][:, axis] = problem.test_residual(base_model, axis)
        residuals['diagnosed'][:, axis] = problem.test_residual(model, axis)
    binned = {method: _binned_error(values, starts) for method, values in residuals.items()}
    scopes = {'test': {method: errors for method, (_, errors) in binned.items()}}
    rezero = {}
    if problem.settings.test_record:
        window = rezero_window_rows(full, full.count - 1, problem.settings.rezero_s)
        rezero = {method: values[:window].mean(axis=0) for method, values in residuals.items()}
        scopes['test_rezeroed'] = {method: _binned_error(values - rezero[method], starts)[1]
                                   for method, values in residuals.items()}
    counts = np.diff(np.append(starts, rows)).astype(np.float64)
    part = BinnedResidual(
        time_s=np.add.reduceat(full.time_s[test], starts) / counts,
        temperature_c=np.add.reduceat(full.temperature_c[test], starts) / counts,
        heating=_heating(problem, test, starts),
        before_rad_s=binned['temperature_polynomial'][0], after_rad_s=binned['diagnosed'][0],
        rows=counts)
    return scopes, part, {method: tuple(float(v) for v in offset)
                          for method, offset in rezero.items()}


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


def _outside_range(problem: _Problem, specs: tuple, model: EffectModel) -> OutsideFittedRange:
    """
    Measure which rows the written model and the forward folds' models run clamped.

    Each axis's effective temperature over the whole record (history states
    from its start, as the node runs them), against the range of the blocks
    before each forward block and against the written model's range.
    """
    full = problem.full
    slope = problem.each(functools.partial(temperature_rate_c_s,
                                           window_s=problem.settings.rate_window_s),
                         full.time_s, full.temperature_c)
    lags = [spec.thermal_lag_s for spec in specs]
    effective = np.column_stack([_effective(problem.records, full.time_s, full.temperature_c,
                                            slope, lag) for lag in lags])
    blocks = held_out_outside_range(effective[:problem.rows], problem.block_edges,
                                    problem.folds_of(FORWARD).split)
    test = outside_range(effective[problem.rows:], model.temperature_min_c,
                         model.temperature_max_c) if problem.test_rows else None
    return OutsideFittedRange(len(set(lags)) > 1, blocks, test)


def _error_by_temperature(problem: _Problem, held_out: BinnedResidual,
                          test: Optional[BinnedResidual]) -> ErrorByTemperature:
    """Bin the written model's held-out (and test) residuals by temperature."""
    temperature = problem.temperature
    edges = temperature_bin_edges(float(np.min(temperature)), float(np.max(temperature)),
                                  problem.settings.error_bins)
    tables = [None if part is None else error_by_temperature(
        part.temperature_c, part.after_rad_s, part.rows, edges) for part in (held_out, test)]
    return ErrorByTemperature(problem.settings.validation, tables[0],
                              float(np.mean(problem.counts)), tables[1])


def diagnose(recording, settings: DiagnosisSettings = DiagnosisSettings(),
             progress: Progress = None) -> Diagnosis:
    """
    Run the loop on a recording and return the `Diagnosis`.

    ``recording`` has time_s, temperature_c, axes, gyro_rad_s and optional
    reference_rad_s, acceleration_m_s2, temperature_2_c and supply_voltage_v
    (a `mlx_tempcomp.sources.recording.Recording`). ``progress(done, total,
    label)`` is called as work advances. Raise `CalibrationError` when the
    data cannot support the diagnosis.
    """
    problem = _Problem(recording, settings, progress)
    axes = problem.axes
    skipped = _skipped(problem)
    searched = tuple(e for e in settings.effects if e not in skipped)
    scores = tuple(_order_scores(problem, axis, _Spec(0)) for axis in range(len(axes)))
    specs = [_Spec(_choose_order(name, s)) for name, s in zip(axes, scores)]
    none_errors = tuple(problem.error(problem.target[:, a]) for a in range(len(axes)))
    residual, errors = problem.held_out(tuple(specs), 'held-out check of step 0')
    base_residual = residual
    base_specs = tuple(specs)
    base_model = problem.model(base_specs)
    steps = [[Step(BASE_EFFECT, _parameters(BASE_EFFECT, base_model.terms[a], problem),
                   none_errors[a], errors[a], 0)] for a in range(len(axes))]
    rejected = [[] for _ in axes]
    causes = [None for _ in axes]
    active = set(range(len(axes)))
    number = 0
    while active:
        number += 1
        accepted = {}
        work = sum(1 for a in active for e in searched if _available(e, specs[a]))
        done = 0
        for axis in sorted(active):
            current = problem.score_spec(axis, specs[axis])
            tried = []
            for effect in searched:
                if not _available(effect, specs[axis]):
                    continue
                best = _best_trial(problem, axis, specs[axis], effect)
                done += 1
                problem.report(done, work, f'round {number}: candidate effects')
                if best is None:
                    continue
                trial, score = best
                judged = _judge(problem, current, score)
                bound = _unbounded(problem, effect, trial)
                if bound and not judged[4]:
                    judged = judged[:4] + (bound,)
                tried.append((effect, trial, judged))
            tried.sort(key=lambda item: (bool(item[2][4]), -item[2][0]))
            if not settings.record_effects:
                causes[axis] = _cause(_findings(problem, axis, specs[axis], number), tried)
            for rank, (effect, trial, judged) in enumerate(tried):
                reason = judged[4]
                if not reason and causes[axis] is not None:
                    reason = (f'the record-only {causes[axis].effect} explains more (held-out '
                              f'gain {causes[axis].held_out_gain:.3f}): not a live stand-in')
                if rank == 0 and not reason:
                    accepted[axis] = (effect, trial, judged[0])
                    continue
                reason = reason or 'significant, but another effect gained more this round'
                rejected[axis].append(_candidate(problem, axis, effect, trial, judged, number,
                                                 reason))
        if not accepted:
            break
        for axis, (effect, trial, gain) in accepted.items():
            specs[axis] = _rechosen_order(problem, axis, trial)
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
    findings = [() if settings.record_effects else _findings(problem, a, specs[a], number)
                for a in range(len(axes))]
    found = tuple(specs)
    other = problem.folds_of(settings.other_validation)
    cubic = _cubic_errors(problem, problem.folds)
    other_cubic = _cubic_errors(problem, other)
    other_errors = problem.held_out(found, 'the other validation', other)[1]
    choices = tuple(_choose_model(settings, (errors[a], other_errors[a]),
                                  (cubic[a], other_cubic[a])) for a in range(len(axes)))
    cubic_axes = tuple(a for a, choice in enumerate(choices) if choice.written == 'px4_cubic')
    if cubic_axes:
        specs = [_Spec(PX4_ORDER) if a in cubic_axes else spec for a, spec in enumerate(found)]
        # The models clamp at the range of every axis's T_eff: with the same lags, the axes
        # that keep their model keep their figures.
        same = {s.thermal_lag_s for s in specs} == {s.thermal_lag_s for s in found}
        run = cubic_axes if same else None
        new_residual, new_errors = problem.held_out(tuple(specs), 'held-out check of the cubic',
                                                    axes=run)
        new_other = problem.held_out(tuple(specs), 'the other validation', other, run)[1]
        changed = list(run or range(len(axes)))
        residual = residual.copy()  # step 0's may be the same array
        residual[:, changed] = new_residual[:, changed]
        errors = tuple(new_errors[a] if a in changed else errors[a] for a in range(len(axes)))
        other_errors = tuple(new_other[a] if a in changed else other_errors[a]
                             for a in range(len(axes)))
    model = problem.model(tuple(specs))
    comparison = {settings.validation: {
        'none': none_errors, 'px4_cubic': cubic,
        'temperature_polynomial': tuple(axis_steps[0].after for axis_steps in steps),
        'diagnosed': errors}, settings.other_validation: {
        'none': tuple(problem.error(problem.target[:, a], other) for a in range(len(axes))),
        'px4_cubic': other_cubic,
        'temperature_polynomial': problem.held_out(base_specs, 'the other validation',
                                                   other)[1],
        'diagnosed': other_errors}}
    held_rows = slice(0, problem.rows)
    held_out = BinnedResidual(
        time_s=problem.mean(problem.time), temperature_c=problem.mean(problem.temperature),
        heating=_heating(problem, held_rows, problem.starts), before_rad_s=base_residual,
        after_rad_s=residual, rows=problem.counts)
    test, rezero = None, {}
    if problem.test_rows:
        scopes, test, rezero = _compare_test(problem, base_model, model)
        comparison.update(scopes)
    per_axis = tuple(AxisDiagnosis(name, found[a].order, scores[a], tuple(steps[a]),
                                   tuple(rejected[a]), findings[a], choices[a], causes[a])
                     for a, name in enumerate(axes))
    return Diagnosis(axes=axes, settings=settings, model=model, base_model=base_model,
                     per_axis=per_axis, skipped=tuple(sorted(skipped.items())),
                     comparison=comparison, rows=problem.rows, test_rows=problem.test_rows,
                     bins=len(problem.starts),
                     truth='reference' if problem.truth_is_reference else 'zero (at rest)',
                     held_out=held_out, test=test, bounds=problem.bounds,
                     records=_record_fits(problem, tuple(specs)), rezero_rad_s=rezero,
                     first_blocks=problem.first_blocks,
                     outside_range=_outside_range(problem, tuple(specs), model),
                     error_by_temperature=_error_by_temperature(problem, held_out, test))


def _record_fits(problem: _Problem, specs: tuple) -> tuple:
    """Describe each record: its name, rows, role and fitted offset against the written one."""
    offsets = problem.record_offsets(specs)
    records = problem.records
    return tuple(RecordFit(name, records.starts[k + 1] - records.starts[k],
                           k < problem.fitted_records,
                           tuple(float(v) for v in offsets[k]) if k < problem.fitted_records
                           else None)
                 for k, name in enumerate(records.names))
