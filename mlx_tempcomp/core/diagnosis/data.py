"""
One diagnosis's data: `DiagnosisData` holds its rows, bins, folds, cached features and bounds.

The bottom of the diagnosis: the diagnosed rows of the records laid end to
end, cut into blocks and bins (`folds.cut_bins`) and dealt to folds; the
bin-mean features the trials share, computed once (`cached`); the search
ranges of the nonlinear parameters (`bounds`); the PX4-style cubic's normal
equations per block; and the held-out error of a binned residual. It scores
nothing: `problem.DiagnosisProblem`, above `fits` and `cubic`, scores and
fits on it.
"""

from dataclasses import dataclass
import functools
import math
from typing import Optional

import numpy as np

from .folds import cut_bins, Folds, weighted_rms
from .results import HeldOutError
from .settings import DiagnosisSettings, ProgressCallback
from ..effects import FirstOrderLag, temperature_rate_c_s
from ..errors import CalibrationError
from ..fitting import cubic_scale_c, cubic_sums, fit_cubic, MIN_SPAN_C, solve_cubic, split
from ..node_models import INPUTS, ModelInputs
from ..series import temperature_branches

# Log grids of the 1-D searches (`fits`): ratio 2^(1/4) between neighbours.
GRID_RATIO = 2.0 ** 0.25
TIME_GRID_S = tuple(float(GRID_RATIO ** k) for k in range(0, 81))        # 1 s .. 1.05e6 s
WIDTH_GRID_C = tuple(float(0.25 * GRID_RATIO ** k) for k in range(0, 33))  # 0.25 .. 64 C
# A time constant must fit this many times into the diagnosed part, or it is a drift.
TIME_CONSTANTS_PER_RECORD = 4.0
# The thermal lag's shortest time constant, in median sample intervals.
MIN_LAG_SAMPLES = 2.0
# A play operator's full width (twice its half width) spans at most this share of the
# temperature range: a wider one follows the temperature over the record, as the
# polynomial does, and would stand in for it.
HYSTERESIS_SPAN_SHARE = 0.25


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


class DiagnosisData:
    """
    The rows, bins, folds and cached bin-mean features of one diagnosis.

    ``records`` are the recordings laid end to end (`records.join_records`):
    their first ``rows`` are diagnosed, the rows after them are the test part
    (`held_out_part.diagnosed_rows`).
    """

    def __init__(self, records, rows: int, settings: DiagnosisSettings,
                 progress: ProgressCallback):
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
        """Return the folds of a validation scheme over the bins (cached)."""
        settings = self.settings

        def build():
            dealt = split(settings.blocks, scheme, settings.folds, settings.min_past,
                          self.first_blocks, buffer)
            return Folds(dealt, self.bin_block, self.block_edges, self.bin_range,
                         self.block_range, settings.scoring)
        return self.cached(('folds', scheme, buffer), build)

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

    def offset_columns(self) -> np.ndarray:
        """
        Give the bias offset columns of the records after the first (none for one record).

        Last in every design: 1 on the bins of its record. The offsets are the
        records' bias against the first's; a record with no training bins in
        a fold has a zero column there, coefficient 0 (the solver of `problem`).
        """
        def build():
            record = np.searchsorted(self.records.starts, self.starts, side='right') - 1
            return (record[:, None] == np.arange(1, self.fitted_records)[None, :]).astype(
                np.float64)
        return self.cached('offsets', build)

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

    def blocks_of(self, bins: np.ndarray) -> np.ndarray:
        """Give the blocks (a mask) the given bins lie in."""
        return np.bincount(self.bin_block[bins], minlength=self.settings.blocks) > 0

    def clamp_range(self, specs: tuple, blocks: Optional[np.ndarray] = None) -> tuple:
        """Return the range of T_eff over the given blocks (all when None) and all axes."""
        used = slice(None) if blocks is None else blocks
        features = [self._lag_features(spec.thermal_lag_s) for spec in specs]
        return (float(min(np.min(f.block_low_c[used]) for f in features)),
                float(max(np.max(f.block_high_c[used]) for f in features)))

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
