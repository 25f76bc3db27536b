"""Error figures: mean, 1 sigma, peak and RMS, as AN2 and the calibration papers report."""

from dataclasses import dataclass

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
    def of(cls, error) -> 'ErrorStatistics':
        error = np.asarray(error, dtype=np.float64).ravel()
        error = error[np.isfinite(error)]
        if error.size == 0:
            msg = 'no finite samples to take error statistics of'
            raise ConfigError(msg)
        return cls(mean=float(np.mean(error)), sigma=float(np.std(error)),
                   peak=float(np.max(np.abs(error))),
                   rms=float(np.sqrt(np.mean(np.square(error)))), samples=int(error.size))
