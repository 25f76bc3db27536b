"""
Checks of a window of rates taken at rest: was the sensor still and the temperature steady.

The ZRO recalibration's window holds the rate corrected by the running model
(offset included), so its mean is the residual the recalibration would remove;
the MPU-6000 offset calibration's holds the raw rate, and checks only its spread.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from ..errors import CalibrationError, ConfigError

# How `check_window` words a window that moved: ``axis`` is the axis's index, ``axis_name``
# its x, y or z.
SENSOR_MOVED = ('sensor moved: rate spread {spread_rad_s:.4g} rad/s on axis {axis} > '
                '{noise_multiple:g} x noise {rate_noise_rad_s:.4g}')


@dataclass(frozen=True)
class RecalibrationLimits:
    """
    When a window counts as 'at rest'.

    ``max_mean_rate_rad_s`` and ``max_temperature_change_c`` may be inf: no
    limit. ``spread_ddof`` 1 takes the spread as the sample standard deviation.
    """

    rate_noise_rad_s: float          # 1-sigma noise of one sample
    noise_multiple: float = 3.0      # spread above multiple x noise means motion
    max_mean_rate_rad_s: float = math.radians(2.0)
    max_temperature_change_c: float = 0.5
    min_samples: int = 10
    spread_ddof: int = 0

    def __post_init__(self) -> None:
        for name in ('rate_noise_rad_s', 'noise_multiple', 'max_mean_rate_rad_s',
                     'max_temperature_change_c'):
            value = getattr(self, name)
            unlimited = name.startswith('max_') and value == math.inf
            if not (math.isfinite(value) and value > 0.0 or unlimited):
                msg = f'recalibration {name} must be positive, got {value}'
                raise ConfigError(msg)
        if self.min_samples < 2:
            msg = f'recalibration min_samples must be at least 2, got {self.min_samples}'
            raise ConfigError(msg)


@dataclass(frozen=True)
class RecalibrationWindow:
    samples: int
    mean_rate_rad_s: np.ndarray
    spread_rad_s: np.ndarray
    temperature_c: float
    temperature_change_c: float


def rate_spread_rad_s(rate_rad_s, ddof: int = 0) -> np.ndarray:
    """
    Give the standard deviation of each axis of a window of rates (samples, axes).

    ``ddof`` 1 gives the sample standard deviation; a window of ``ddof`` samples
    or fewer has no spread (zeros).
    """
    rate = np.asarray(rate_rad_s, dtype=np.float64)
    if len(rate) <= ddof:
        return np.zeros(rate.shape[1])
    return rate.std(axis=0, ddof=ddof)


def moving_axis(spread_rad_s, rate_noise_rad_s: float, noise_multiple: float
                ) -> Optional[int]:
    """
    Give the axis that moved, or None when the window is at rest.

    Motion shows as a rate spread above ``noise_multiple`` x the 1-sigma noise of
    one sample; of the axes above it, the one that spreads most is named.
    """
    worst = int(np.argmax(spread_rad_s))
    return worst if spread_rad_s[worst] > noise_multiple * rate_noise_rad_s else None


def check_window(corrected_rate_rad_s, temperature_c, limits: RecalibrationLimits,
                 moved: str = SENSOR_MOVED) -> RecalibrationWindow:
    """
    Return the window's statistics, or raise `CalibrationError` saying why it is refused.

    Motion shows as a spread above ``noise_multiple`` x the sample noise on any axis
    (worded by ``moved``, a format of the fields of `SENSOR_MOVED`), or a mean rate
    above ``max_mean_rate_rad_s``; a drifting temperature as a change (max - min)
    above ``max_temperature_change_c``.
    """
    rate = np.asarray(corrected_rate_rad_s, dtype=np.float64)
    rate = rate[:, None] if rate.ndim == 1 else rate
    temperature = np.asarray(temperature_c, dtype=np.float64).ravel()
    finite = np.all(np.isfinite(rate), axis=1) & np.isfinite(temperature[:len(rate)])
    if np.count_nonzero(finite) < limits.min_samples:
        msg = (f'only {np.count_nonzero(finite)} valid samples in the window, '
               f'{limits.min_samples} needed: is the sensor streaming?')
        raise CalibrationError(msg)
    rate = rate[finite]
    temperature = temperature[:len(finite)][finite]
    stats = RecalibrationWindow(samples=len(rate), mean_rate_rad_s=rate.mean(axis=0),
                                spread_rad_s=rate_spread_rad_s(rate, limits.spread_ddof),
                                temperature_c=float(temperature.mean()),
                                temperature_change_c=float(np.ptp(temperature)))
    worst = moving_axis(stats.spread_rad_s, limits.rate_noise_rad_s, limits.noise_multiple)
    if worst is not None:
        raise CalibrationError(moved.format(
            axis=worst, axis_name='xyz'[worst], spread_rad_s=stats.spread_rad_s[worst],
            noise_multiple=limits.noise_multiple, rate_noise_rad_s=limits.rate_noise_rad_s))
    worst = int(np.argmax(np.abs(stats.mean_rate_rad_s)))
    if abs(stats.mean_rate_rad_s[worst]) > limits.max_mean_rate_rad_s:
        msg = (f'sensor moved: mean rate {stats.mean_rate_rad_s[worst]:.4g} rad/s on axis '
               f'{worst} exceeds {limits.max_mean_rate_rad_s:.4g}')
        raise CalibrationError(msg)
    if stats.temperature_change_c > limits.max_temperature_change_c:
        msg = (f'temperature drifted {stats.temperature_change_c:.3g} C during the window '
               f'(limit {limits.max_temperature_change_c:g} C)')
        raise CalibrationError(msg)
    return stats
