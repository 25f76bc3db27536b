"""
Time-series helpers: pairing streams by stamp, error figures, noise figures.

The package, by module: `pairing` (samples of several streams paired by stamp: exactly,
by holding the latest reading or by interpolating; `ReadingPairer` for the node, whose
temperature comes at its own rate and stamps), `metrics` (mean, 1 sigma, peak and RMS as
AN2 and the calibration papers report them; bins of a record by time, the temperature
branches of a cycle), `noise` (the overlapping Allan deviation of IEEE Std 952-1997,
annex C: angle random walk, bias instability, rate random walk; allantools computes it,
imported inside the function). None imports another room of core.
"""

from .metrics import (bin_means, bin_starts, ErrorStatistics, last_cycle_start_row,
                      temperature_branches, test_start_row)
from .noise import (allan_deviation, FLICKER_FLOOR_FACTOR, MAX_INTERVAL_SPREAD, MIN_CLUSTERS,
                    MIN_SAMPLES, NOISE_DENSITY_TAU_S, noise_lines, RANDOM_WALK_TAU_S)
from .pairing import ReadingPairer, StampPairer, zero_order_hold

__all__ = ['allan_deviation', 'bin_means', 'bin_starts', 'ErrorStatistics', 'FLICKER_FLOOR_FACTOR',
           'last_cycle_start_row', 'MAX_INTERVAL_SPREAD', 'MIN_CLUSTERS', 'MIN_SAMPLES',
           'NOISE_DENSITY_TAU_S', 'noise_lines', 'RANDOM_WALK_TAU_S', 'ReadingPairer',
           'StampPairer', 'temperature_branches', 'test_start_row', 'zero_order_hold']
