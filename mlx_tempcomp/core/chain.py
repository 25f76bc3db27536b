"""
Calibration chain of the PSI 3-axis teslameter paper, for a gyro on a rate table.

The teslameter calibration (nonlinearity, offset and sensitivity versus the probe
temperature, offset versus the electronics temperature, angular errors) transposed to a
gyro: magnetic field -> angular rate, NMR -> the table's reference rate, Hall-probe
temperature -> sensor temperature T, electronics temperature -> a second temperature T2.
Per axis, on the measured rate m in rad/s, with FS the full scale, dT = T - Tref and
dT2 = T2 - T2ref, the stages run in the paper's order:

1. nonlinearity  y1 = P(m / FS), order 5: measured -> reference at Tref (section 5.1)
2. offset        y2 = y1 - (b + g dT), from zero-rate plateaus (section 5.2.2)
3. sensitivity   y3 = y2 - (K(y2 / FS) dT + C(y2 / FS)), K cubic, C linear (5.2.3)
4. offset_2      y4 = y3 - (d + h dT2), from zero-rate plateaus (section 5.2.4)
5. misalignment  rate = M @ y4, M 3 x 3 over all plateaus (section 7, Equations 2-3)

Each stage is fitted on plateau means of the data corrected by the stages before it;
plateaus are first trimmed to the same number of samples, as the paper does. Fits run in
float64 on rate scaled by the full scale and temperature centred on the reference, so
order 5 stays well conditioned. For stage 3 the error line of each rate level versus dT
is reported (Figures 16-17), but K and C are fitted together on the plateau means,
evaluated at the stage input as the correction does: polynomials through the per-level
lines would bias C by about K'(x) K(x) mean(dT^2) / FS, since the instrument's rate moves
with T along a level. `CalibrationChain` holds plain floats only and corrects
new samples without a reference; `to_parameters` flattens it into ROS parameters.
"""

from dataclasses import dataclass
import math
from typing import Mapping, Optional

import numpy as np

from .errors import CalibrationError, ConfigError
from .metrics import ErrorStatistics
from .model_interface import CorrectedRate, ModelInputs, NO_INPUTS
from .models import AXIS_NAMES, model_fingerprint, OffsetModel, one_row

STAGE_NAMES = ('raw', 'nonlinearity', 'offset', 'sensitivity', 'offset_2', 'misalignment')

# The descriptions of the node's chain.* parameters, by key of `CalibrationChain.to_parameters`.
PARAMETER_DESCRIPTIONS = {
    'full_scale_rad_s': 'full scale; the polynomials run in x = rate / full scale',
    'reference_temperature_c': 'Tref of dT = T - Tref',
    'reference_temperature_2_c': 'T2ref of dT2 = T2 - T2ref',
    'nonlinearity_rad_s': 'stage 1, axis {axis}: measured -> reference rate P(x), rad/s',
    'offset_rad_s': 'stage 2: offset b of x, y, z, rad/s',
    'offset_gradient_rad_s_per_c': 'stage 2: offset gradient g of x, y, z, rad/s/C',
    'sensitivity_slope_rad_s_per_c': 'stage 3, axis {axis}: K(x), rad/s per degC',
    'sensitivity_intercept_rad_s': 'stage 3, axis {axis}: C(x), rad/s',
    'offset_2_rad_s': 'stage 4: offset d of x, y, z, rad/s',
    'offset_2_gradient_rad_s_per_c': 'stage 4: gradient h of x, y, z, rad/s per degC of T2',
    'misalignment': 'stage 5: 3 x 3 matrix M row by row, rate = M @ y4',
}

_SCALARS = ('full_scale_rad_s', 'reference_temperature_c', 'reference_temperature_2_c')
_POLYNOMIALS = ('nonlinearity_rad_s', 'sensitivity_slope_rad_s_per_c',
                'sensitivity_intercept_rad_s')
_VECTORS = ('offset_rad_s', 'offset_gradient_rad_s_per_c', 'offset_2_rad_s',
            'offset_2_gradient_rad_s_per_c')


def _polyval(x: np.ndarray, coefficients: tuple) -> np.ndarray:
    return np.polynomial.polynomial.polyval(x, coefficients)


def _polyfit(x: np.ndarray, y: np.ndarray, order: int) -> tuple:
    return tuple(float(c) for c in np.polynomial.polynomial.polyfit(x, y, order))


def _finite(name: str, value) -> float:
    value = float(value)
    if not math.isfinite(value):
        msg = f'chain {name} must be finite, got {value}'
        raise ConfigError(msg)
    return value


def _vector(name: str, values) -> tuple:
    values = tuple(_finite(name, v) for v in np.ravel(values))
    if len(values) != 3:
        msg = f'chain {name} needs 3 values (x, y, z), got {len(values)}'
        raise ConfigError(msg)
    return values


def _polynomials(name: str, values) -> tuple:
    axes = tuple(tuple(_finite(name, c) for c in np.ravel(axis)) for axis in values)
    if len(axes) != 3 or not all(axes):
        msg = f'chain {name} needs non-empty coefficients for the 3 axes, got {len(axes)} axes'
        raise ConfigError(msg)
    return axes


def _rates(name: str, values, samples: Optional[int] = None) -> np.ndarray:
    rate = np.asarray(values, dtype=np.float64)
    if rate.ndim != 2 or rate.shape[1] != 3 or samples not in (None, rate.shape[0]):
        msg = f'{name} must have shape ({samples or "samples"}, 3), got {rate.shape}'
        raise ConfigError(msg)
    return rate


def _column(name: str, values, samples: int) -> np.ndarray:
    column = np.asarray(values, dtype=np.float64)
    if column.shape != (samples,):
        msg = f'{name} must have shape ({samples},), got {column.shape}'
        raise ConfigError(msg)
    return column


def _apply_nonlinearity(rate: np.ndarray, full_scale_rad_s: float,
                        coefficients: tuple) -> np.ndarray:
    x = rate / full_scale_rad_s
    return np.stack([_polyval(x[..., axis], coefficients[axis]) for axis in range(3)], axis=-1)


def _apply_offset(rate: np.ndarray, delta_c: np.ndarray, constant: tuple,
                  gradient: tuple) -> np.ndarray:
    return rate - (np.asarray(constant) + delta_c[..., None] * np.asarray(gradient))


def _apply_sensitivity(rate: np.ndarray, delta_c: np.ndarray, full_scale_rad_s: float,
                       slope: tuple, intercept: tuple) -> np.ndarray:
    x = rate / full_scale_rad_s
    error = np.stack([_polyval(x[..., axis], slope[axis]) * delta_c +
                      _polyval(x[..., axis], intercept[axis]) for axis in range(3)], axis=-1)
    return rate - error


@dataclass(frozen=True)
class CalibrationChain:
    """
    The fitted chain: per-axis polynomials and offsets, then a 3 x 3 misalignment matrix.

    Polynomials are lowest order first in x = rate / full_scale_rad_s: the nonlinearity
    and C(x) give rad/s, K(x) gives rad/s per degC of (T - reference_temperature_c).
    ``misalignment`` holds the rows of M, reference = M @ corrected.
    """

    full_scale_rad_s: float
    reference_temperature_c: float
    reference_temperature_2_c: float
    nonlinearity_rad_s: tuple
    offset_rad_s: tuple
    offset_gradient_rad_s_per_c: tuple
    sensitivity_slope_rad_s_per_c: tuple
    sensitivity_intercept_rad_s: tuple
    offset_2_rad_s: tuple
    offset_2_gradient_rad_s_per_c: tuple
    misalignment: tuple

    def __post_init__(self) -> None:
        for name in _SCALARS:
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.full_scale_rad_s <= 0.0:
            msg = f'chain full_scale_rad_s must be positive, got {self.full_scale_rad_s}'
            raise ConfigError(msg)
        for name in _POLYNOMIALS:
            object.__setattr__(self, name, _polynomials(name, getattr(self, name)))
        for name in _VECTORS:
            object.__setattr__(self, name, _vector(name, getattr(self, name)))
        matrix = np.asarray(self.misalignment, dtype=np.float64)
        if matrix.shape != (3, 3):
            msg = f'chain misalignment must be 3 x 3, got shape {matrix.shape}'
            raise ConfigError(msg)
        object.__setattr__(self, 'misalignment',
                           tuple(_vector('misalignment', row) for row in matrix))

    def stages(self, rate_rad_s, temperature_c, temperature_2_c) -> tuple:
        """
        Return the rate after each of the five stages, in rad/s of shape (samples, 3).

        Parameters
        ----------
        rate_rad_s : array (samples, 3)
            Measured rate.
        temperature_c, temperature_2_c : array (samples,)
            Sensor temperature and second (electronics) temperature.

        """
        rate = _rates('rate_rad_s', rate_rad_s)
        delta_c = _column('temperature_c', temperature_c, len(rate)) - \
            self.reference_temperature_c
        delta_2_c = _column('temperature_2_c', temperature_2_c, len(rate)) - \
            self.reference_temperature_2_c
        linear = _apply_nonlinearity(rate, self.full_scale_rad_s, self.nonlinearity_rad_s)
        offset = _apply_offset(linear, delta_c, self.offset_rad_s,
                               self.offset_gradient_rad_s_per_c)
        sensitivity = _apply_sensitivity(offset, delta_c, self.full_scale_rad_s,
                                         self.sensitivity_slope_rad_s_per_c,
                                         self.sensitivity_intercept_rad_s)
        offset_2 = _apply_offset(sensitivity, delta_2_c, self.offset_2_rad_s,
                                 self.offset_2_gradient_rad_s_per_c)
        # Sums of products, not a matrix product: a block then gives, bit for bit, what
        # its rows give one at a time.
        aligned = np.column_stack([sum(offset_2[:, j] * m for j, m in enumerate(row))
                                   for row in self.misalignment])
        return linear, offset, sensitivity, offset_2, aligned

    def correct(self, rate_rad_s, temperature_c, temperature_2_c) -> np.ndarray:
        """Return the corrected rate in rad/s, shape (samples, 3); no reference needed."""
        return self.stages(rate_rad_s, temperature_c, temperature_2_c)[-1]

    def to_parameters(self) -> dict:
        """
        Flatten into ROS parameters: floats and flat float lists.

        Per-axis polynomials become ``<name>.x``, ``<name>.y``, ``<name>.z``; the
        misalignment matrix is 9 floats, row by row.
        """
        parameters = {name: getattr(self, name) for name in _SCALARS}
        for name in _POLYNOMIALS:
            for axis, coefficients in zip(AXIS_NAMES, getattr(self, name)):
                parameters[f'{name}.{axis}'] = list(coefficients)
        for name in _VECTORS:
            parameters[name] = list(getattr(self, name))
        parameters['misalignment'] = [c for row in self.misalignment for c in row]
        return parameters

    @classmethod
    def from_parameters(cls, parameters: Mapping) -> 'CalibrationChain':
        """Build the chain from `to_parameters` output; raise `ConfigError` if invalid."""
        def get(key: str):
            if key not in parameters:
                msg = f'chain parameter {key} is missing'
                raise ConfigError(msg)
            return parameters[key]

        fields = {name: get(name) for name in _SCALARS + _VECTORS}
        for name in _POLYNOMIALS:
            fields[name] = tuple(get(f'{name}.{axis}') for axis in AXIS_NAMES)
        matrix = np.ravel(get('misalignment'))
        if matrix.size != 9:
            msg = f'chain parameter misalignment needs 9 values (3 x 3), got {matrix.size}'
            raise ConfigError(msg)
        return cls(misalignment=matrix.reshape(3, 3), **fields)


@dataclass(frozen=True)
class ChainModel(OffsetModel):
    """
    A `CalibrationChain` as a compensation model: 3 axes, needs the second temperature.

    The chain's output minus the ZRO offset learned at rest; no temperature is clamped.
    """

    chain: CalibrationChain
    zro_offset_rad_s: tuple = (0.0, 0.0, 0.0)

    name = 'chain'
    axes = 3
    inputs = frozenset({'temperature_2_c'})

    def __post_init__(self) -> None:
        object.__setattr__(self, 'zro_offset_rad_s', _vector('zro_offset_rad_s',
                                                             self.zro_offset_rad_s))

    def fingerprint(self) -> str:
        return model_fingerprint(self.name, self.chain.to_parameters())

    def correct(self, rate_rad_s, temperature_c,
                inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        """Correct a batch; ``inputs.temperature_2_c`` (samples,) is required."""
        if inputs.temperature_2_c is None:
            raise ConfigError('the chain model needs temperature_2_c (offset_2 stage)')
        temperature = np.asarray(temperature_c, dtype=np.float64)
        if temperature.ndim == 2:
            temperature = temperature.mean(axis=1)
        corrected = self.chain.correct(rate_rad_s, temperature, inputs.temperature_2_c)
        return CorrectedRate(corrected - np.asarray(self.zro_offset_rad_s),
                             np.zeros(corrected.shape, dtype=bool))

    def stream(self) -> '_ChainStream':
        """Return the sample-by-sample runner; the chain keeps no state."""
        return _ChainStream(self)


class _ChainStream:
    def __init__(self, model: ChainModel):
        self.model = model

    def correct_block(self, rates_rad_s, temperatures_c,
                      inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        return self.model.correct(rates_rad_s, temperatures_c, inputs)

    def correct_one(self, *row) -> tuple:
        """Correct one row: (rad/s per axis as a list, any clamped); as `correct_block`."""
        return one_row(self, *row)


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
            _finite(name, getattr(self, name))
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
    reference = _rates('reference_rad_s', reference_rad_s)
    temperatures = np.column_stack([_column('temperature_c', temperature_c, len(reference)),
                                    _column('temperature_2_c', temperature_2_c,
                                            len(reference))])
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
    measured = _rates('measured_rad_s', measured_rad_s)
    reference = _rates('reference_rad_s', reference_rad_s, len(measured))
    outputs = (measured, *chain.stages(measured, temperature_c, temperature_2_c))
    rows = []
    for stage, output in zip(STAGE_NAMES, outputs):
        error = output - reference
        for axis, values in zip(AXIS_NAMES + ('all',), (*error.T, error)):
            rows.append(_statistics_row(stage, axis, values, chain.full_scale_rad_s))
    return tuple(rows)


def format_stage_table(rows) -> str:
    """Render `StageError` rows as text, in % of full scale and in rad/s."""
    lines = [f'{"stage":<13}{"axis":<5}{"mean %FS":>10}{"1 sigma":>10}{"peak":>10}'
             f'{"mean rad/s":>13}{"1 sigma":>11}{"peak":>11}{"RMS":>11}']
    for row in rows:
        lines.append(f'{row.stage:<13}{row.axis:<5}{row.mean_percent_fs:>10.4f}'
                     f'{row.sigma_percent_fs:>10.4f}{row.peak_percent_fs:>10.4f}'
                     f'{row.mean_rad_s:>13.3e}{row.sigma_rad_s:>11.3e}'
                     f'{row.peak_rad_s:>11.3e}{row.rms_rad_s:>11.3e}')
    return '\n'.join(lines)


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
    measured = _rates('measured_rad_s', measured_rad_s)
    reference = _rates('reference_rad_s', reference_rad_s, len(measured))
    temperature = _column('temperature_c', temperature_c, len(measured))
    temperature_2 = _column('temperature_2_c', temperature_2_c, len(measured))
    ids = np.asarray(plateau_id)
    if ids.shape != (len(measured),) or not np.issubdtype(ids.dtype, np.integer):
        msg = f'plateau_id must be integers of shape ({len(measured)},), got {ids.shape}'
        raise ConfigError(msg)
    finite = np.all(np.isfinite(np.column_stack(
        [measured, reference, temperature, temperature_2])), axis=1)
    index = _trimmed_plateaus(np.where(finite, ids, -1), settings.min_plateau_samples)

    s = settings
    fs = s.full_scale_rad_s
    rate = measured[index]
    reference_p = reference[index].mean(axis=1)
    temperature_p = temperature[index].mean(axis=1)
    temperature_2_p = temperature_2[index].mean(axis=1)
    moving = np.abs(reference_p) > s.zero_rate_rad_s
    zero = ~moving.any(axis=1)
    alone = moving & (np.count_nonzero(moving, axis=1) == 1)[:, None]
    steady_2 = np.abs(temperature_2_p - s.reference_temperature_2_c) <= s.reference_window_2_c
    at_reference = steady_2 & \
        (np.abs(temperature_p - s.reference_temperature_c) <= s.reference_window_c)

    # 1. Nonlinearity on the plateau means at the reference temperature (section 5.1).
    measured_p = rate.mean(axis=1)
    nonlinearity, orders = [], []
    used = np.zeros(len(index), dtype=bool)
    for axis, name in enumerate(AXIS_NAMES):
        select = at_reference & (zero | alone[:, axis])
        x, target = measured_p[select, axis] / fs, reference_p[select, axis]
        levels = _level_count(target, s.level_tolerance_rad_s)
        if levels < s.nonlinearity_order + 1:
            msg = (f'nonlinearity of axis {name}: {levels} rate levels within '
                   f'{s.reference_window_c:g} C of {s.reference_temperature_c:g} C, '
                   f'order {s.nonlinearity_order} needs {s.nonlinearity_order + 1}')
            raise CalibrationError(msg)
        nonlinearity.append(_polyfit(x, target, s.nonlinearity_order))
        residuals = [(None, measured_p[select, axis] - target)]
        residuals += [(order, _polyval(x, _polyfit(x, target, order)) - target)
                      for order in s.compared_orders if order < levels]
        orders += [OrderResidual(axis=name, order=order, peak_rad_s=float(np.max(np.abs(r))),
                                 rms_rad_s=float(np.sqrt(np.mean(r * r))),
                                 peak_percent_fs=float(np.max(np.abs(r))) * 100.0 / fs)
                   for order, r in residuals]
        used |= select
    reference_temperature_c = float(temperature_p[used].mean())
    reference_temperature_2_c = float(temperature_2_p[used].mean())
    delta_p = temperature_p - reference_temperature_c
    delta = temperature[index] - reference_temperature_c
    linear = _apply_nonlinearity(rate, fs, nonlinearity)

    # 2. Offset versus temperature at zero rate (section 5.2.2).
    select = zero & steady_2
    _require_span('offset', 'zero-rate plateaus', temperature_p[select],
                  s.min_temperature_span_c)
    error = linear.mean(axis=1) - reference_p
    lines = [_polyfit(delta_p[select], error[select, axis], 1) for axis in range(3)]
    offset = tuple(line[0] for line in lines)
    gradient = tuple(line[1] for line in lines)
    offset_corrected = _apply_offset(linear, delta, offset, gradient)

    # 3. Sensitivity: one error line per rate level, then K(rate) and C(rate) (5.2.3).
    stage_input = offset_corrected.mean(axis=1)
    error = stage_input - reference_p
    slope, intercept, points = [], [], []
    needed = max(s.sensitivity_slope_order, s.sensitivity_intercept_order) + 1
    for axis, name in enumerate(AXIS_NAMES):
        select = np.flatnonzero(steady_2 & (zero | alone[:, axis]))
        labels = _level_labels(reference_p[select, axis], s.level_tolerance_rad_s)
        axis_points, fitted_levels = [], []
        for level in range(labels.max(initial=-1) + 1):
            members = select[labels == level]
            span = float(np.ptp(temperature_p[members]))
            if span < s.min_temperature_span_c:
                continue
            c, k = _polyfit(delta_p[members], error[members, axis], 1)
            axis_points.append(SensitivityPoint(
                axis=name, rate_rad_s=float(reference_p[members, axis].mean()) + c,
                slope_rad_s_per_c=k, intercept_rad_s=c, temperature_span_c=span,
                plateaus=int(members.size)))
            fitted_levels.append(members)
        if len(axis_points) < needed:
            msg = (f'sensitivity of axis {name}: {len(axis_points)} rate levels span '
                   f'{s.min_temperature_span_c:g} C of temperature or more, K of order '
                   f'{s.sensitivity_slope_order} and C of order '
                   f'{s.sensitivity_intercept_order} need {needed}')
            raise CalibrationError(msg)
        fitted = np.concatenate(fitted_levels)
        x = stage_input[fitted, axis] / fs
        design = np.column_stack([
            np.polynomial.polynomial.polyvander(x, s.sensitivity_slope_order) *
            delta_p[fitted, None],
            np.polynomial.polynomial.polyvander(x, s.sensitivity_intercept_order)])
        solution = np.linalg.lstsq(design, error[fitted, axis], rcond=None)[0]
        slope.append(tuple(float(c) for c in solution[:s.sensitivity_slope_order + 1]))
        intercept.append(tuple(float(c) for c in solution[s.sensitivity_slope_order + 1:]))
        points += axis_points
    sensitivity_corrected = _apply_sensitivity(offset_corrected, delta, fs, slope, intercept)

    # 4. Offset versus the second temperature at zero rate (section 5.2.4).
    _require_span('offset_2', 'zero-rate plateaus', temperature_2_p[zero],
                  s.min_temperature_span_c)
    delta_2_p = temperature_2_p - reference_temperature_2_c
    error = sensitivity_corrected.mean(axis=1) - reference_p
    lines = [_polyfit(delta_2_p[zero], error[zero, axis], 1) for axis in range(3)]
    offset_2 = tuple(line[0] for line in lines)
    gradient_2 = tuple(line[1] for line in lines)
    offset_2_corrected = _apply_offset(sensitivity_corrected,
                                       temperature_2[index] - reference_temperature_2_c,
                                       offset_2, gradient_2)

    # 5. Misalignment: reference = M @ corrected over all plateaus (Equations 2-3); stage 1
    # needed a turning plateau on each axis alone, so the three columns are independent.
    solution = np.linalg.lstsq(offset_2_corrected.mean(axis=1) / fs, reference_p / fs,
                               rcond=None)[0]

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
