"""
Fitting the calibration chain (`chain.CalibrationChain`) on a rate-table record.

The plateaus of the record (`find_plateaus`) are trimmed to the same number
of samples, as the PSI teslameter paper does; each stage is fitted on the
plateau means of the data corrected by the stages before it (`fit_chain`),
and the error after each stage tabulated (`stage_errors`, the paper's Tables
2 and 3). `chain`'s docstring has the stages and their formulas.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from ..errors import CalibrationError, ConfigError
from ..node_models import (apply_nonlinearity, apply_offset, apply_sensitivity, AXIS_NAMES,
                           CalibrationChain, checked_column, checked_rates, finite, polyfit,
                           polyval, STAGE_NAMES)
from ..series import ErrorStatistics


@dataclass(frozen=True)
class ChainSettings:
    """
    How to fit the chain.

    The nonlinearity is fitted on the plateaus within ``reference_window_c`` of
    ``reference_temperature_c``; the chain's reference temperatures are the mean
    temperatures of those plateaus, where the nonlinearity holds. Stages 1 to 3 use
    plateaus within ``reference_window_2_c`` of ``reference_temperature_2_c`` only, the
    electronics temperature being the subject of stage 4. A plateau is at zero rate when
    every axis of its reference is within ``zero_rate_rad_s``; plateaus whose reference
    differs by less than ``level_tolerance_rad_s`` are the same rate level.
    """

    full_scale_rad_s: float
    reference_temperature_c: float
    reference_temperature_2_c: float
    nonlinearity_order: int = 5
    compared_orders: tuple = (1, 2, 3, 4, 5, 6)
    sensitivity_slope_order: int = 3
    sensitivity_intercept_order: int = 1
    reference_window_c: float = 2.0
    reference_window_2_c: float = 2.0
    zero_rate_rad_s: float = math.radians(0.1)
    level_tolerance_rad_s: float = math.radians(0.5)
    min_temperature_span_c: float = 2.0
    min_plateau_samples: int = 10

    def __post_init__(self) -> None:
        for name in ('full_scale_rad_s', 'reference_window_c', 'reference_window_2_c',
                     'zero_rate_rad_s', 'level_tolerance_rad_s', 'min_temperature_span_c'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f'chain settings {name} must be positive, got {value}'
                raise ConfigError(msg)
        for name in ('reference_temperature_c', 'reference_temperature_2_c'):
            finite(name, getattr(self, name))
        orders = (self.nonlinearity_order, self.sensitivity_slope_order,
                  self.sensitivity_intercept_order, *self.compared_orders)
        if not all(isinstance(order, int) and order >= 0 for order in orders):
            msg = f'chain settings polynomial orders must be integers >= 0, got {orders}'
            raise ConfigError(msg)
        if self.nonlinearity_order < 1:
            msg = f'chain settings nonlinearity_order must be >= 1, got {self.nonlinearity_order}'
            raise ConfigError(msg)
        if self.min_plateau_samples < 1:
            msg = ('chain settings min_plateau_samples must be >= 1, '
                   f'got {self.min_plateau_samples}')
            raise ConfigError(msg)


@dataclass(frozen=True)
class StageError:
    """One row of the paper's Tables 2 and 3: error (output - reference) after a stage."""

    stage: str
    axis: str
    mean_rad_s: float
    sigma_rad_s: float
    peak_rad_s: float
    rms_rad_s: float
    mean_percent_fs: float
    sigma_percent_fs: float
    peak_percent_fs: float
    samples: int


@dataclass(frozen=True)
class OrderResidual:
    """Figure 5 and Table 1: nonlinearity residual of one order (None: uncompensated)."""

    axis: str
    order: Optional[int]
    peak_rad_s: float
    rms_rad_s: float
    peak_percent_fs: float


@dataclass(frozen=True)
class SensitivityPoint:
    """Figures 16 and 17: the error line of one rate level versus (T - Tref)."""

    axis: str
    rate_rad_s: float
    slope_rad_s_per_c: float
    intercept_rad_s: float
    temperature_span_c: float
    plateaus: int


@dataclass(frozen=True)
class ChainFit:
    """The fitted chain and what the paper reports about its fit."""

    chain: CalibrationChain
    stage_errors: tuple
    nonlinearity_orders: tuple
    sensitivity_points: tuple


def find_plateaus(reference_rad_s, temperature_c, temperature_2_c,
                  tolerance_rad_s: float = math.radians(0.01), temperature_step_c: float = 1.0,
                  min_samples: int = 10) -> np.ndarray:
    """
    Give each plateau of a recording a number; samples outside any plateau get -1.

    A plateau is a run of at least ``min_samples`` samples whose reference changes by at
    most ``tolerance_rad_s`` and whose temperatures change by at most
    ``temperature_step_c`` from one sample to the next (a jump means a new session).
    """
    reference = checked_rates('reference_rad_s', reference_rad_s)
    temperatures = np.column_stack([
        checked_column('temperature_c', temperature_c, len(reference)),
        checked_column('temperature_2_c', temperature_2_c, len(reference))])
    breaks = np.any(np.abs(np.diff(reference, axis=0)) > tolerance_rad_s, axis=1) | \
        np.any(np.abs(np.diff(temperatures, axis=0)) > temperature_step_c, axis=1)
    run = np.concatenate(([0], np.cumsum(breaks)))[:len(reference)]
    counts = np.bincount(run)
    long_enough = counts >= min_samples
    numbers = np.where(long_enough, np.cumsum(long_enough) - 1, -1)
    return numbers[run]


def _trimmed_plateaus(plateau_id: np.ndarray, min_samples: int) -> np.ndarray:
    """Return sample indices (plateaus, samples): each plateau cut to its central part."""
    in_plateau = np.flatnonzero(plateau_id >= 0)
    _, group, counts = np.unique(plateau_id[in_plateau], return_inverse=True,
                                 return_counts=True)
    kept = counts >= min_samples
    if not kept.any():
        msg = f'no plateau has {min_samples} valid samples or more'
        raise CalibrationError(msg)
    length = int(counts[kept].min())
    order = np.argsort(group, kind='stable')
    group = group[order]
    position = np.arange(order.size) - (np.cumsum(counts) - counts)[group]
    first = ((counts - length) // 2)[group]
    take = kept[group] & (position >= first) & (position < first + length)
    return in_plateau[order[take]].reshape(-1, length)


def _level_labels(values: np.ndarray, tolerance: float) -> np.ndarray:
    """Label values into levels: sorted values closer than ``tolerance`` share one."""
    order = np.argsort(values)
    labels = np.empty(values.size, dtype=int)
    labels[order] = np.cumsum(np.diff(values[order], prepend=-np.inf) > tolerance) - 1
    return labels


def _level_count(values: np.ndarray, tolerance: float) -> int:
    return int(_level_labels(values, tolerance).max() + 1) if values.size else 0


def _require_span(stage: str, what: str, temperatures_c: np.ndarray, span_c: float) -> None:
    if temperatures_c.size == 0:
        msg = f'{stage}: no {what} to fit a temperature gradient on'
        raise CalibrationError(msg)
    if np.ptp(temperatures_c) < span_c:
        msg = (f'{stage}: the {what} span {np.ptp(temperatures_c):.3g} C of temperature, '
               f'a gradient needs at least {span_c:g} C')
        raise CalibrationError(msg)


def _statistics_row(stage: str, axis: str, error: np.ndarray,
                    full_scale_rad_s: float) -> StageError:
    stats = ErrorStatistics.of(error)
    percent = 100.0 / full_scale_rad_s
    return StageError(stage=stage, axis=axis, mean_rad_s=stats.mean, sigma_rad_s=stats.sigma,
                      peak_rad_s=stats.peak, rms_rad_s=stats.rms,
                      mean_percent_fs=stats.mean * percent,
                      sigma_percent_fs=stats.sigma * percent,
                      peak_percent_fs=stats.peak * percent, samples=stats.samples)


def stage_errors(chain: CalibrationChain, reference_rad_s, measured_rad_s, temperature_c,
                 temperature_2_c) -> tuple:
    """
    Tabulate mean, 1 sigma, peak and RMS of (output - reference) after each stage.

    Returns one `StageError` per stage of `STAGE_NAMES` (raw first) and per axis x, y, z
    and 'all' (the three axes pooled): the paper's Tables 2 and 3, for calibration or
    verification data.
    """
    measured = checked_rates('measured_rad_s', measured_rad_s)
    reference = checked_rates('reference_rad_s', reference_rad_s, len(measured))
    outputs = (measured, *chain.stages(measured, temperature_c, temperature_2_c))
    rows = []
    for stage, output in zip(STAGE_NAMES, outputs):
        error = output - reference
        for axis, values in zip(AXIS_NAMES + ('all',), (*error.T, error)):
            rows.append(_statistics_row(stage, axis, values, chain.full_scale_rad_s))
    return tuple(rows)


def fit_chain(reference_rad_s, measured_rad_s, temperature_c, temperature_2_c, plateau_id,
              settings: ChainSettings) -> ChainFit:
    """
    Fit the five stages in order, each on the output of the stages before it.

    Parameters
    ----------
    reference_rad_s, measured_rad_s : array (samples, 3)
        Reference rate of the table and rate measured by the gyro.
    temperature_c, temperature_2_c : array (samples,)
        Sensor temperature and second (electronics) temperature.
    plateau_id : array (samples,) of int
        Plateau number of each sample, -1 outside plateaus (see `find_plateaus`).
    settings : ChainSettings
        Orders, reference temperatures and the limits of what counts as a plateau.

    Returns
    -------
    ChainFit
        The chain, the per-stage error table on the trimmed plateaus, the nonlinearity
        residual of each compared order and the per-level sensitivity lines.

    Raises
    ------
    CalibrationError
        When the data cannot support a stage: too few rate levels at the reference
        temperature for the order, no zero-rate plateau, or a temperature span below
        ``min_temperature_span_c``.

    """
    measured = checked_rates('measured_rad_s', measured_rad_s)
    reference = checked_rates('reference_rad_s', reference_rad_s, len(measured))
    temperature = checked_column('temperature_c', temperature_c, len(measured))
    temperature_2 = checked_column('temperature_2_c', temperature_2_c, len(measured))
    index = _plateau_index(plateau_id, np.column_stack(
        [measured, reference, temperature, temperature_2]), settings.min_plateau_samples)
    plateaus = _Plateaus.of(index, measured, reference, temperature, temperature_2, settings)
    fs = settings.full_scale_rad_s
    # 1. Nonlinearity at the reference temperature; the chain's references are where it holds.
    nonlinearity, orders, used = _fit_nonlinearity(plateaus, settings)
    reference_temperature_c = float(plateaus.temperature_c[used].mean())
    reference_temperature_2_c = float(plateaus.temperature_2_c[used].mean())
    delta_p = plateaus.temperature_c - reference_temperature_c
    delta = temperature[index] - reference_temperature_c
    linear = apply_nonlinearity(plateaus.rate_rad_s, fs, nonlinearity)
    # 2. Offset versus temperature at zero rate (section 5.2.2).
    offset, gradient = _fit_offset_line(
        'offset', linear, plateaus, plateaus.zero & plateaus.steady_2, plateaus.temperature_c,
        reference_temperature_c, settings.min_temperature_span_c)
    offset_corrected = apply_offset(linear, delta, offset, gradient)
    # 3. Sensitivity: K(rate) dT + C(rate) on the plateau means (section 5.2.3).
    slope, intercept, points = _fit_sensitivity(plateaus, offset_corrected.mean(axis=1),
                                                delta_p, settings)
    sensitivity_corrected = apply_sensitivity(offset_corrected, delta, fs, slope, intercept)
    # 4. Offset versus the second temperature at zero rate (section 5.2.4).
    offset_2, gradient_2 = _fit_offset_line(
        'offset_2', sensitivity_corrected, plateaus, plateaus.zero, plateaus.temperature_2_c,
        reference_temperature_2_c, settings.min_temperature_span_c)
    offset_2_corrected = apply_offset(sensitivity_corrected,
                                      temperature_2[index] - reference_temperature_2_c,
                                      offset_2, gradient_2)
    # 5. Misalignment: reference = M @ corrected over all plateaus (Equations 2-3); stage 1
    # needed a turning plateau on each axis alone, so the three columns are independent.
    solution = np.linalg.lstsq(offset_2_corrected.mean(axis=1) / fs,
                               plateaus.reference_rad_s / fs, rcond=None)[0]
    chain = CalibrationChain(
        full_scale_rad_s=fs, reference_temperature_c=reference_temperature_c,
        reference_temperature_2_c=reference_temperature_2_c,
        nonlinearity_rad_s=tuple(nonlinearity), offset_rad_s=offset,
        offset_gradient_rad_s_per_c=gradient, sensitivity_slope_rad_s_per_c=tuple(slope),
        sensitivity_intercept_rad_s=tuple(intercept), offset_2_rad_s=offset_2,
        offset_2_gradient_rad_s_per_c=gradient_2, misalignment=solution.T)
    flat = index.ravel()
    table = stage_errors(chain, reference[flat], measured[flat], temperature[flat],
                         temperature_2[flat])
    return ChainFit(chain=chain, stage_errors=table, nonlinearity_orders=tuple(orders),
                    sensitivity_points=tuple(points))


def _plateau_index(plateau_id, columns: np.ndarray, min_samples: int) -> np.ndarray:
    """Give the samples the chain is fitted on (`_trimmed_plateaus`), ``columns`` all finite."""
    ids = np.asarray(plateau_id)
    if ids.shape != (len(columns),) or not np.issubdtype(ids.dtype, np.integer):
        msg = f'plateau_id must be integers of shape ({len(columns)},), got {ids.shape}'
        raise ConfigError(msg)
    finite = np.all(np.isfinite(columns), axis=1)
    return _trimmed_plateaus(np.where(finite, ids, -1), min_samples)


@dataclass(frozen=True)
class _Plateaus:
    """The trimmed plateaus a chain is fitted on: their samples, their means, their kind."""

    rate_rad_s: np.ndarray         # the measured rate of their samples (plateaus, samples, 3)
    reference_rad_s: np.ndarray    # the mean reference of each (plateaus, 3), likewise below
    temperature_c: np.ndarray
    temperature_2_c: np.ndarray
    zero: np.ndarray               # no axis turns
    alone: np.ndarray              # (plateaus, 3): the axis turns, and no other
    steady_2: np.ndarray           # the second temperature within its reference window
    at_reference: np.ndarray       # both temperatures within their reference windows

    @classmethod
    def of(cls, index: np.ndarray, measured: np.ndarray, reference: np.ndarray,
           temperature: np.ndarray, temperature_2: np.ndarray, settings: ChainSettings):
        """Gather the samples ``index`` (plateaus, samples) picks and classify each plateau."""
        s = settings
        reference_p = reference[index].mean(axis=1)
        temperature_p = temperature[index].mean(axis=1)
        temperature_2_p = temperature_2[index].mean(axis=1)
        moving = np.abs(reference_p) > s.zero_rate_rad_s
        steady_2 = np.abs(temperature_2_p - s.reference_temperature_2_c) <= \
            s.reference_window_2_c
        at_reference = steady_2 & \
            (np.abs(temperature_p - s.reference_temperature_c) <= s.reference_window_c)
        return cls(rate_rad_s=measured[index], reference_rad_s=reference_p,
                   temperature_c=temperature_p, temperature_2_c=temperature_2_p,
                   zero=~moving.any(axis=1),
                   alone=moving & (np.count_nonzero(moving, axis=1) == 1)[:, None],
                   steady_2=steady_2, at_reference=at_reference)


def _fit_nonlinearity(plateaus: _Plateaus, settings: ChainSettings) -> tuple:
    """
    Stage 1: the nonlinearity on the plateau means at the reference temperature (section 5.1).

    Returns (its polynomial per axis, the residual of each compared order,
    the plateaus it was fitted on).
    """
    s = settings
    fs = s.full_scale_rad_s
    measured_p = plateaus.rate_rad_s.mean(axis=1)
    reference_p = plateaus.reference_rad_s
    nonlinearity, orders = [], []
    used = np.zeros(len(reference_p), dtype=bool)
    for axis, name in enumerate(AXIS_NAMES):
        select = plateaus.at_reference & (plateaus.zero | plateaus.alone[:, axis])
        x, target = measured_p[select, axis] / fs, reference_p[select, axis]
        levels = _level_count(target, s.level_tolerance_rad_s)
        if levels < s.nonlinearity_order + 1:
            msg = (f'nonlinearity of axis {name}: {levels} rate levels within '
                   f'{s.reference_window_c:g} C of {s.reference_temperature_c:g} C, '
                   f'order {s.nonlinearity_order} needs {s.nonlinearity_order + 1}')
            raise CalibrationError(msg)
        nonlinearity.append(polyfit(x, target, s.nonlinearity_order))
        residuals = [(None, measured_p[select, axis] - target)]
        residuals += [(order, polyval(x, polyfit(x, target, order)) - target)
                      for order in s.compared_orders if order < levels]
        orders += [OrderResidual(axis=name, order=order, peak_rad_s=float(np.max(np.abs(r))),
                                 rms_rad_s=float(np.sqrt(np.mean(r * r))),
                                 peak_percent_fs=float(np.max(np.abs(r))) * 100.0 / fs)
                   for order, r in residuals]
        used |= select
    return nonlinearity, orders, used


def _fit_offset_line(stage: str, corrected: np.ndarray, plateaus: _Plateaus,
                     select: np.ndarray, temperature_p: np.ndarray, reference_c: float,
                     span_c: float) -> tuple:
    """
    Stages 2 and 4: an offset line in a temperature on the plateaus ``select`` (zero rate).

    ``corrected`` is the output of the stages before it on the plateaus'
    samples; ``temperature_p`` the plateaus' mean of the temperature the line
    runs in, ``reference_c`` its reference. Returns (offsets, gradients) of x, y, z.
    """
    _require_span(stage, 'zero-rate plateaus', temperature_p[select], span_c)
    delta_p = temperature_p - reference_c
    error = corrected.mean(axis=1) - plateaus.reference_rad_s
    lines = [polyfit(delta_p[select], error[select, axis], 1) for axis in range(3)]
    return tuple(line[0] for line in lines), tuple(line[1] for line in lines)


def _fit_sensitivity(plateaus: _Plateaus, stage_input: np.ndarray, delta_p: np.ndarray,
                     settings: ChainSettings) -> tuple:
    """
    Stage 3: one error line per rate level, then K(rate) and C(rate) (section 5.2.3).

    ``stage_input`` is the plateau means after stage 2, ``delta_p`` their
    temperature less the reference. Returns (K per axis, C per axis, the
    per-level lines).
    """
    s = settings
    error = stage_input - plateaus.reference_rad_s
    slope, intercept, points = [], [], []
    needed = max(s.sensitivity_slope_order, s.sensitivity_intercept_order) + 1
    for axis, name in enumerate(AXIS_NAMES):
        axis_points, fitted_levels = _sensitivity_levels(plateaus, error, delta_p, axis, s)
        if len(axis_points) < needed:
            msg = (f'sensitivity of axis {name}: {len(axis_points)} rate levels span '
                   f'{s.min_temperature_span_c:g} C of temperature or more, K of order '
                   f'{s.sensitivity_slope_order} and C of order '
                   f'{s.sensitivity_intercept_order} need {needed}')
            raise CalibrationError(msg)
        fitted = np.concatenate(fitted_levels)
        x = stage_input[fitted, axis] / s.full_scale_rad_s
        design = np.column_stack([
            np.polynomial.polynomial.polyvander(x, s.sensitivity_slope_order) *
            delta_p[fitted, None],
            np.polynomial.polynomial.polyvander(x, s.sensitivity_intercept_order)])
        solution = np.linalg.lstsq(design, error[fitted, axis], rcond=None)[0]
        slope.append(tuple(float(c) for c in solution[:s.sensitivity_slope_order + 1]))
        intercept.append(tuple(float(c) for c in solution[s.sensitivity_slope_order + 1:]))
        points += axis_points
    return slope, intercept, points


def _sensitivity_levels(plateaus: _Plateaus, error: np.ndarray, delta_p: np.ndarray,
                        axis: int, settings: ChainSettings) -> tuple:
    """
    Fit the error line of each rate level of ``axis`` that spans enough temperature.

    Returns (a `SensitivityPoint` per such level, the plateaus of each).
    """
    s = settings
    select = np.flatnonzero(plateaus.steady_2 & (plateaus.zero | plateaus.alone[:, axis]))
    labels = _level_labels(plateaus.reference_rad_s[select, axis], s.level_tolerance_rad_s)
    points, levels = [], []
    for level in range(labels.max(initial=-1) + 1):
        members = select[labels == level]
        span = float(np.ptp(plateaus.temperature_c[members]))
        if span < s.min_temperature_span_c:
            continue
        c, k = polyfit(delta_p[members], error[members, axis], 1)
        points.append(SensitivityPoint(
            axis=AXIS_NAMES[axis],
            rate_rad_s=float(plateaus.reference_rad_s[members, axis].mean()) + c,
            slope_rad_s_per_c=k, intercept_rad_s=c, temperature_span_c=span,
            plateaus=int(members.size)))
        levels.append(members)
    return points, levels
