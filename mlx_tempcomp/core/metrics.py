"""
Error figures: mean, 1 sigma, peak and RMS, as AN2 and the calibration papers report.

Also the two definitions `diagnose` and `evaluate` share, so their figures agree: the
test part of a record (`test_start_row`) and its residual averaged over time bins
(`bin_starts`, `bin_means`; figures of bin means are weighted by their sample counts).
"""

from dataclasses import dataclass
import math

import numpy as np

from .errors import ConfigError


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
