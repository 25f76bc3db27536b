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
The fit is `chain_fit`'s.
"""

from dataclasses import dataclass
import math
from typing import Mapping, Optional

import numpy as np

from .interface import CorrectedRate, ModelInputs, NO_INPUTS
from .rate_models import AXIS_NAMES, model_fingerprint, OffsetModel, one_row
from ..errors import ConfigError

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


def polyval(x: np.ndarray, coefficients: tuple) -> np.ndarray:
    """Evaluate a polynomial, lowest order first."""
    return np.polynomial.polynomial.polyval(x, coefficients)


def polyfit(x: np.ndarray, y: np.ndarray, order: int) -> tuple:
    """Fit a polynomial of ``order`` by least squares; its coefficients, lowest first."""
    return tuple(float(c) for c in np.polynomial.polynomial.polyfit(x, y, order))


def finite(name: str, value) -> float:
    """Give ``value`` as a float; ConfigError naming ``name`` unless it is finite."""
    value = float(value)
    if not math.isfinite(value):
        msg = f'chain {name} must be finite, got {value}'
        raise ConfigError(msg)
    return value


def _vector(name: str, values) -> tuple:
    values = tuple(finite(name, v) for v in np.ravel(values))
    if len(values) != 3:
        msg = f'chain {name} needs 3 values (x, y, z), got {len(values)}'
        raise ConfigError(msg)
    return values


def _polynomials(name: str, values) -> tuple:
    axes = tuple(tuple(finite(name, c) for c in np.ravel(axis)) for axis in values)
    if len(axes) != 3 or not all(axes):
        msg = f'chain {name} needs non-empty coefficients for the 3 axes, got {len(axes)} axes'
        raise ConfigError(msg)
    return axes


def checked_rates(name: str, values, samples: Optional[int] = None) -> np.ndarray:
    """Give rates x, y, z as float64 (samples, 3); ConfigError on another shape."""
    rate = np.asarray(values, dtype=np.float64)
    if rate.ndim != 2 or rate.shape[1] != 3 or samples not in (None, rate.shape[0]):
        msg = f'{name} must have shape ({samples or "samples"}, 3), got {rate.shape}'
        raise ConfigError(msg)
    return rate


def checked_column(name: str, values, samples: int) -> np.ndarray:
    """Give one value per sample as float64 (samples,); ConfigError on another shape."""
    column = np.asarray(values, dtype=np.float64)
    if column.shape != (samples,):
        msg = f'{name} must have shape ({samples},), got {column.shape}'
        raise ConfigError(msg)
    return column


def apply_nonlinearity(rate: np.ndarray, full_scale_rad_s: float,
                       coefficients: tuple) -> np.ndarray:
    """Stage 1: the reference rate P(m / FS) of each axis."""
    x = rate / full_scale_rad_s
    return np.stack([polyval(x[..., axis], coefficients[axis]) for axis in range(3)], axis=-1)


def apply_offset(rate: np.ndarray, delta_c: np.ndarray, constant: tuple,
                 gradient: tuple) -> np.ndarray:
    """Stages 2 and 4: take off the offset line constant + gradient x delta_c."""
    return rate - (np.asarray(constant) + delta_c[..., None] * np.asarray(gradient))


def apply_sensitivity(rate: np.ndarray, delta_c: np.ndarray, full_scale_rad_s: float,
                      slope: tuple, intercept: tuple) -> np.ndarray:
    """Stage 3: take off K(x) delta_c + C(x), x = rate / FS."""
    x = rate / full_scale_rad_s
    error = np.stack([polyval(x[..., axis], slope[axis]) * delta_c +
                      polyval(x[..., axis], intercept[axis]) for axis in range(3)], axis=-1)
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
            object.__setattr__(self, name, finite(name, getattr(self, name)))
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
        rate = checked_rates('rate_rad_s', rate_rad_s)
        delta_c = checked_column('temperature_c', temperature_c, len(rate)) - \
            self.reference_temperature_c
        delta_2_c = checked_column('temperature_2_c', temperature_2_c, len(rate)) - \
            self.reference_temperature_2_c
        linear = apply_nonlinearity(rate, self.full_scale_rad_s, self.nonlinearity_rad_s)
        offset = apply_offset(linear, delta_c, self.offset_rad_s,
                              self.offset_gradient_rad_s_per_c)
        sensitivity = apply_sensitivity(offset, delta_c, self.full_scale_rad_s,
                                        self.sensitivity_slope_rad_s_per_c,
                                        self.sensitivity_intercept_rad_s)
        offset_2 = apply_offset(sensitivity, delta_2_c, self.offset_2_rad_s,
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
