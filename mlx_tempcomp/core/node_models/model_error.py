"""
The model's own error as a function of temperature, for the covariance the node publishes.

The angular velocity covariance the node publishes per axis is the white
noise of one sample squared plus the model's error at the sample's
temperature squared. ``mlx-tempcomp diagnose`` and ``fit`` measure both on
the rows a model was not fitted on:

- the white noise of a sample per axis (`sample_noise_rad_s`): from the
  spread of the differences of consecutive samples, which the slow bias
  does not reach (a median, so steps do not count);
- the model's error per temperature bin (`bias_rms_rad_s`): the RMS of its
  held-out residual in that bin (`validation.error_by_temperature`), less
  the share the white noise has in it (noise^2 / samples per averaged
  value). That is a bias error, slow and correlated in time: the noise
  averages out of a mean over many samples, it does not.

`ModelErrorTable` holds the error: linear between its temperatures, held
at the edges. `normalised_error` judges a published covariance the way a
consumer meets it: the error of each sample over the published standard
deviation (RMS 1 when the covariance tells the truth), and the mean error
over windows over the standard deviation such a mean has (the bias part
whole, the noise over the window's samples).
"""

from dataclasses import dataclass
import math

import numpy as np

from ..errors import CalibrationError, ConfigError

# The windows `normalised_error` averages the error over besides single samples.
WINDOW_S = 60.0
# MAD to the standard deviation of a normal distribution.
MAD_SIGMA = 1.4826


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

    def variance(self, noise_rad_s, temperature_c) -> np.ndarray:
        """
        Give noise^2 + error(T)^2 (samples, axes): white noise plus the model's bias error.

        ``noise_rad_s``: one figure for every axis, or one per axis.
        """
        noise = np.asarray(noise_rad_s, dtype=np.float64)
        return np.square(noise) + np.square(self.error_at(temperature_c))


def sample_noise_rad_s(parts) -> np.ndarray:
    """
    Give the white noise of one sample per axis from runs of rows (samples, axes) each.

    The robust spread (MAD) of the differences of consecutive samples within
    each run, over sqrt(2): a difference holds two samples' noise, while the
    bias, slow, cancels out of it. CalibrationError when no run holds two rows.
    """
    differences = [np.diff(np.asarray(part, dtype=np.float64), axis=0) for part in parts]
    differences = [d.reshape(len(d), -1) for d in differences if len(d)]
    if not differences:
        raise CalibrationError('the white noise needs two consecutive samples')
    pooled = np.concatenate(differences)
    spread = MAD_SIGMA * np.median(np.abs(pooled - np.median(pooled, axis=0)), axis=0)
    return spread / math.sqrt(2.0)


def bias_rms_rad_s(errors, noise_rad_s) -> np.ndarray:
    """
    Give the bias part of a `validation.TemperatureErrors` table: (bins, axes), NaN if empty.

    A bin's mean square counts each averaged value with its rows as weight;
    white noise of ``noise_rad_s`` per sample (one per axis) puts noise^2 x
    count / weight into it (noise^2 / rows per value, weighted by rows). What
    is left, at least 0, is the bias error's mean square.
    """
    rms = np.array(errors.rms_rad_s, dtype=np.float64).reshape(len(errors.count), -1)
    count = np.array(errors.count, dtype=np.float64)
    weight = np.array(errors.weight, dtype=np.float64)
    with np.errstate(invalid='ignore', divide='ignore'):
        share = np.square(np.asarray(noise_rad_s, dtype=np.float64)) * (count / weight)[:, None]
    bias = np.sqrt(np.maximum(np.square(rms) - share, 0.0))
    bias[count == 0] = math.nan
    return bias


def larger_table(tables: tuple, noise_rad_s) -> ModelErrorTable:
    """
    Give the node's table from tables of held-out errors over the same temperature bins.

    Per bin and axis the largest bias part (`bias_rms_rad_s`) of the tables
    that hold the bin, at the mean temperature of the first of them that
    does. CalibrationError when no table holds a residual.
    """
    bias = np.array([bias_rms_rad_s(table, noise_rad_s) for table in tables])
    filled = [k for k in range(bias.shape[1]) if np.any(np.isfinite(bias[:, k, 0]))]
    if not filled:
        raise CalibrationError('no held-out residual to take the model error from')
    temperature = tuple(next(table.temperature_c[k] for table in tables if table.count[k])
                        for k in filled)
    largest = np.fmax.reduce(bias[:, filled, :], axis=0)
    return ModelErrorTable(temperature, tuple(tuple(float(v) for v in largest[:, axis])
                                              for axis in range(largest.shape[1])))


@dataclass(frozen=True)
class NormalisedError:
    """
    Error over the published standard deviation, RMS per axis (1: the covariance is true).

    ``per_sample``: each sample's error over the square root of its published
    variance; ``window_means``: the mean error of each window of ``window_s``
    over the standard deviation of that mean (the bias part of the variance
    whole, the noise part over the window's samples), weighted by samples.
    """

    per_sample: tuple
    window_means: tuple
    window_s: float
    samples: int
    windows: int


def normalised_error(time_s, error_rad_s, variance_rad2_s2, noise_rad_s,
                     window_s: float = WINDOW_S) -> NormalisedError:
    """
    Judge a published variance (samples, axes) against the error (samples, axes).

    ``noise_rad_s`` (per axis) is the white-noise part of the variance; the
    rest is a bias that does not average out of a window's mean.
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    error = np.asarray(error_rad_s, dtype=np.float64).reshape(len(time_s), -1)
    variance = np.broadcast_to(np.asarray(variance_rad2_s2, dtype=np.float64), error.shape)
    noise2 = np.broadcast_to(np.square(np.asarray(noise_rad_s, dtype=np.float64)),
                             (error.shape[1],))
    with np.errstate(invalid='ignore', divide='ignore'):
        per_sample = np.sqrt(np.mean(np.square(error) / variance, axis=0))
        index = np.floor((time_s - time_s[0]) / window_s).astype(np.int64)
        starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
        rows = np.diff(np.append(starts, len(time_s))).astype(np.float64)[:, None]
        means = np.add.reduceat(error, starts, axis=0) / rows
        bias2 = np.add.reduceat(variance - noise2, starts, axis=0) / rows
        ratio2 = np.square(means) / (np.maximum(bias2, 0.0) + noise2 / rows)
        windows = np.sqrt(np.sum(rows * ratio2, axis=0) / np.sum(rows))
    return NormalisedError(tuple(float(v) for v in per_sample),
                           tuple(float(v) for v in windows), float(window_s), len(time_s),
                           len(starts))


class StillWindows:
    """
    The node's check of its covariance at rest: `normalised_error`'s window means, live.

    Fed the rate it published while its bias tracking says the gyro is still
    (the truth there is 0), with the tracked offset's standard deviation (the
    bias part of the published variance) and the white noise per axis. Each
    window of ``window_s`` seconds of consecutive still samples gives per axis
    its mean over sqrt(bias std^2 mean + noise^2 / samples); a sample that is
    not still drops the open window. Plain floats: it runs per published sample.
    """

    def __init__(self, window_s: float = WINDOW_S):
        self.window_s = window_s
        self.windows = 0
        self._squares = None
        self._open = None

    def add(self, time_s: float, rates, stds, noise_rad_s, still: bool) -> None:
        """Take one published sample: its stamp, rate, bias std and noise per axis."""
        if not still:
            self._open = None
            return
        if self._open is not None and time_s >= self._open[0] + self.window_s:
            self._close(noise_rad_s)
        if self._open is None:
            self._open = [time_s, 0, [0.0] * len(rates), [0.0] * len(rates)]
        window = self._open
        window[1] += 1
        for axis, (rate, std) in enumerate(zip(rates, stds)):
            window[2][axis] += rate
            window[3][axis] += std * std

    def _close(self, noise_rad_s) -> None:
        _, samples, sums, variances = self._open
        self._open = None
        ratios = []
        for total, variance, noise in zip(sums, variances, noise_rad_s):
            spread = variance / samples + noise * noise / samples
            if spread <= 0.0:
                return
            ratios.append((total / samples) ** 2 / spread)
        self._squares = ratios if self._squares is None else \
            [a + b for a, b in zip(self._squares, ratios)]
        self.windows += 1

    def rms(self) -> list:
        """Give the RMS per axis over the windows closed so far ([] before the first)."""
        if not self.windows:
            return []
        return [math.sqrt(total / self.windows) for total in self._squares]
