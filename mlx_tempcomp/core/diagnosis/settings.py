"""How ``mlx-tempcomp diagnose`` is set: what it searches, its defaults, `DiagnosisSettings`."""

from dataclasses import dataclass
import math
from typing import Callable, Optional

from .folds import INSIDE_ROWS, SCORING
from ..effects import DEFAULT_RATE_WINDOW_S, EFFECT_NAMES, LIVE_EFFECTS, RECORD_EFFECTS
from ..errors import CalibrationError
from ..fitting import (BASELINE_MARGIN, DEFAULT_BLOCKS, DEFAULT_FOLDS, DEFAULT_MIN_PAST,
                       DEFAULT_SIGNIFICANCE, DEFAULT_VALIDATION, FORWARD, PURGED, PX4_ORDER, split)
from ..standstill import RecalibrationLimits

BASE_EFFECT = 'temperature_polynomial'
SEARCH_EFFECTS = tuple(e for e in LIVE_EFFECTS if e != BASE_EFFECT)
RECORD_SEARCH = tuple(e for e in EFFECT_NAMES if e in RECORD_EFFECTS)
# The node's imu/recalibrate_zro: its default window (recalibration.duration_s) and the
# fewest samples it accepts in it.
DEFAULT_REZERO_S = 5.0
REZERO_MIN_SAMPLES = RecalibrationLimits.min_samples

# Temperature bins of the error-by-temperature table (equal width over the diagnosed part).
DEFAULT_ERROR_BINS = 8

ProgressCallback = Optional[Callable[[int, int, str], None]]


@dataclass(frozen=True)
class DiagnosisSettings:
    """How the diagnosis splits, averages and judges; see the package docstring."""

    folds: int = DEFAULT_FOLDS
    blocks: int = DEFAULT_BLOCKS
    average_s: float = 1.0
    max_order: int = 8
    min_gain: float = 0.1
    significance: float = DEFAULT_SIGNIFICANCE
    block_tolerance: float = 1.0
    test_fraction: float = 0.0
    test_cycle: bool = False
    test_record: bool = False
    rezero_s: float = DEFAULT_REZERO_S
    rate_window_s: float = DEFAULT_RATE_WINDOW_S
    record_effects: bool = False
    validation: str = DEFAULT_VALIDATION
    min_past: float = DEFAULT_MIN_PAST
    baseline_margin: float = BASELINE_MARGIN
    error_bins: int = DEFAULT_ERROR_BINS
    scoring: str = INSIDE_ROWS

    def __post_init__(self) -> None:
        checks = (
            (self.folds >= 2, f'folds must be at least 2, got {self.folds}'),
            (self.blocks >= self.folds,
             f'blocks ({self.blocks}) must be at least the folds ({self.folds})'),
            (math.isfinite(self.average_s) and self.average_s >= 0.0,
             f'average_s must be a non-negative number, got {self.average_s}'),
            # The PX4-style cubic is fitted beside every model: its order is the least.
            (self.max_order >= PX4_ORDER,
             f'max_order must be at least {PX4_ORDER} (the cubic), got {self.max_order}'),
            (math.isfinite(self.min_gain) and 0.0 <= self.min_gain < 1.0,
             f'min_gain must be in [0, 1), got {self.min_gain}'),
            (math.isfinite(self.significance) and self.significance >= 0.0,
             f'significance must be non-negative, got {self.significance}'),
            (math.isfinite(self.block_tolerance) and self.block_tolerance >= 0.0,
             f'block_tolerance must be non-negative, got {self.block_tolerance}'),
            (math.isfinite(self.test_fraction) and 0.0 <= self.test_fraction < 1.0,
             f'test_fraction must be in [0, 1), got {self.test_fraction}'),
            (sum((self.test_cycle, bool(self.test_fraction), self.test_record)) <= 1,
             'hold out one of the last cycle, a test fraction or the last record'),
            (math.isfinite(self.rezero_s) and self.rezero_s > 0.0,
             f'rezero_s must be positive, got {self.rezero_s}'),
            (math.isfinite(self.rate_window_s) and self.rate_window_s > 0.0,
             f'rate_window_s must be positive, got {self.rate_window_s}'),
            (math.isfinite(self.baseline_margin) and 0.0 <= self.baseline_margin < 1.0,
             f'baseline_margin must be in [0, 1), got {self.baseline_margin}'),
            (self.error_bins >= 1, f'error_bins must be at least 1, got {self.error_bins}'),
            (self.scoring in SCORING,
             f'scoring must be one of {", ".join(SCORING)}, got {self.scoring!r}'),
        )
        for ok, msg in checks:
            if not ok:
                raise CalibrationError(msg)
        self.split()

    def split(self, scheme: Optional[str] = None):
        """Deal the blocks to folds by ``scheme`` (default: the deciding one)."""
        return split(self.blocks, scheme or self.validation, self.folds, self.min_past)

    @property
    def other_validation(self) -> str:
        """Give the scheme reported beside the deciding one: forward, or purged beside it."""
        return PURGED if self.validation == FORWARD else FORWARD

    @property
    def effects(self) -> tuple:
        """Give the effects the loop searches, in the order it tries them."""
        return SEARCH_EFFECTS + (RECORD_SEARCH if self.record_effects else ())
