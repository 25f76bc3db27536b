"""
Error figures: mean, 1 sigma, peak and RMS, as AN2 and the calibration papers report.

Also the two definitions `diagnose` and `evaluate` share, so their figures agree: the
test part of a record (`test_start_row`) and its residual averaged over time bins
(`bin_starts`, `bin_means`; figures of bin means are weighted by their sample counts).
"""

from dataclasses import dataclass
import math

import numpy as np

from ..errors import ConfigError


@dataclass(frozen=True)
class ErrorStatistics:
    """Statistics of an error signal (same unit as the signal)."""

    mean: float
    sigma: float
    peak: float
    rms: float
    samples: int

    @classmethod
    def of(cls, error, weights=None) -> 'ErrorStatistics':
        """Take the statistics of ``error``, each value weighted by ``weights`` if given."""
        error = np.asarray(error, dtype=np.float64).ravel()
        weights = np.ones(error.shape) if weights is None else \
            np.broadcast_to(np.asarray(weights, dtype=np.float64).ravel(), error.shape)
        finite = np.isfinite(error)
        error, weights = error[finite], weights[finite]
        if error.size == 0:
            msg = 'no finite samples to take error statistics of'
            raise ConfigError(msg)
        mean = float(np.average(error, weights=weights))
        return cls(mean=mean,
                   sigma=math.sqrt(float(np.average(np.square(error - mean), weights=weights))),
                   peak=float(np.max(np.abs(error))),
                   rms=math.sqrt(float(np.average(np.square(error), weights=weights))),
                   samples=int(error.size))


def test_start_row(samples: int, fraction: float) -> int:
    """Return the first row of the test part: the last floor(fraction x samples) rows."""
    return samples - int(math.floor(fraction * samples))


def bin_starts(time_s, average_s: float) -> np.ndarray:
    """
    Give the first row of each time bin of ``average_s`` seconds, counted from time_s[0].

    With ``average_s`` = 0 every row is its own bin.
    """
    time = np.asarray(time_s, dtype=np.float64)
    if average_s <= 0.0:
        return np.arange(time.size)
    index = np.floor((time - time[0]) / average_s).astype(np.int64)
    return np.flatnonzero(np.concatenate(([True], index[1:] != index[:-1])))


def bin_means(values, starts) -> tuple:
    """Return (mean of ``values`` rows over each bin, sample count of each bin)."""
    values = np.asarray(values, dtype=np.float64)
    counts = np.diff(np.append(starts, values.shape[0])).astype(np.float64)
    sums = np.add.reduceat(values, starts, axis=0)
    return sums / (counts[:, None] if sums.ndim == 2 else counts), counts


# A temperature branch (heating or cooling) must span this fraction of the record's range.
BRANCH_FRACTION = 0.25
# Branches are found on at most this many evenly spaced rows: temperature moves slowly.
_BRANCH_ROWS = 200000


def temperature_branches(temperature_c) -> np.ndarray:
    """
    Return the first row of each heating or cooling branch of a record.

    A branch ends where the temperature turns back by BRANCH_FRACTION of the
    record's range from its extreme; the first branch starts at row 0. A
    last stretch smaller than that belongs to the branch before it.
    """
    temperature = np.asarray(temperature_c, dtype=np.float64)
    if temperature.size == 0:
        return np.zeros(0, dtype=np.int64)
    every = max(1, temperature.size // _BRANCH_ROWS)
    values = temperature[::every].tolist()
    threshold = BRANCH_FRACTION * (max(values) - min(values))
    starts = [0]
    if threshold <= 0.0:
        return np.array(starts)
    direction = 0
    high = low = 0
    for i, value in enumerate(values):
        if value > values[high]:
            high = i
        if value < values[low]:
            low = i
        if direction >= 0 and values[high] - value >= threshold:
            if direction > 0:
                starts.append(high)
            direction, low = -1, i
        elif direction <= 0 and value - values[low] >= threshold:
            if direction < 0:
                starts.append(low)
            direction, high = 1, i
    return np.array(starts, dtype=np.int64) * every


def last_cycle_start_row(temperature_c) -> int:
    """
    Return the first row of the record's last full heating/cooling cycle (its last two branches).

    Raise `ConfigError` unless the record holds at least two full cycles
    (four branches), so that a full cycle is left to learn from.
    """
    starts = temperature_branches(temperature_c)
    if len(starts) < 4:
        msg = (f'the record holds {len(starts)} heating/cooling branches (each spanning '
               f'{BRANCH_FRACTION:g} of its temperature range); holding out the last full '
               'cycle needs at least two cycles (4 branches)')
        raise ConfigError(msg)
    return int(starts[-2])
