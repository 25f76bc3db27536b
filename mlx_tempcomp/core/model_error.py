"""
The model's own error as a function of temperature, for the covariance the node publishes.

``mlx-tempcomp diagnose`` measures, per axis, the RMS of the held-out
residual of the model it writes in temperature bins (`validation.
error_by_temperature`): how far off the compensated rate was, forward in
time, at each temperature. That is a bias error, slow and correlated in
time, not white noise; the node adds its square to the white noise
variance of the sensor in the Imu covariance, so that a consumer is not
told the compensated rate is better than the model was shown to be.
`ModelErrorTable` holds it: linear between its temperatures, held at the
edges.
"""

from dataclasses import dataclass
import math

import numpy as np

from .errors import ConfigError


def table_temperatures(values) -> tuple:
    """Give the temperatures of a table as floats; ConfigError unless finite and increasing."""
    temperature = tuple(float(t) for t in values)
    if not temperature or not all(math.isfinite(t) for t in temperature):
        msg = f'the model error table needs finite temperatures, got {list(temperature)}'
        raise ConfigError(msg)
    if any(b <= a for a, b in zip(temperature, temperature[1:])):
        msg = f'model error temperatures must be strictly increasing, got {list(temperature)}'
        raise ConfigError(msg)
    return temperature


@dataclass(frozen=True)
class ModelErrorTable:
    """
    Model error (1-sigma, rad/s) per axis at each of ``temperature_c``.

    ``temperature_c`` strictly increasing, degC; ``error_rad_s`` one tuple
    per axis, a non-negative value per temperature.
    """

    temperature_c: tuple
    error_rad_s: tuple

    def __post_init__(self) -> None:
        temperature = table_temperatures(self.temperature_c)
        errors = tuple(tuple(float(v) for v in axis) for axis in self.error_rad_s)
        if not errors:
            raise ConfigError('the model error table needs the error of at least one axis')
        for axis, values in enumerate(errors):
            if len(values) != len(temperature):
                msg = (f'model error of axis {axis} needs {len(temperature)} values (one per '
                       f'temperature), got {len(values)}')
                raise ConfigError(msg)
            if not all(math.isfinite(v) and v >= 0.0 for v in values):
                msg = f'model error of axis {axis} must be finite and >= 0, got {list(values)}'
                raise ConfigError(msg)
        object.__setattr__(self, 'temperature_c', temperature)
        object.__setattr__(self, 'error_rad_s', errors)

    @property
    def axes(self) -> int:
        return len(self.error_rad_s)

    def error_at(self, temperature_c) -> np.ndarray:
        """
        Give the model error (samples, axes) at temperatures (samples,) or (samples, axes).

        Linear between the table's temperatures, held beyond its first and
        last; an unknown (NaN) temperature gets the largest error of the axis.
        """
        temperature = np.asarray(temperature_c, dtype=np.float64)
        temperature = temperature.reshape(len(temperature), -1)
        temperature = np.broadcast_to(temperature, (len(temperature), self.axes))
        out = np.empty(temperature.shape)
        for axis, values in enumerate(self.error_rad_s):
            column = temperature[:, axis]
            out[:, axis] = np.where(np.isnan(column), max(values),
                                    np.interp(column, self.temperature_c, values))
        return out

    def variance(self, noise_rad_s: float, temperature_c) -> np.ndarray:
        """Give noise^2 + error(T)^2 (samples, axes): white noise plus the model's bias error."""
        return noise_rad_s ** 2 + np.square(self.error_at(temperature_c))
