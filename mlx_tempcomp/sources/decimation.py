"""
Device-rate sampling, published at a lower rate: device samples averaged over each interval.

Device sample k is taken at k / sample_rate_hz; publish interval j covers
[j / publish_rate_hz, (j + 1) / publish_rate_hz). `Decimator` groups the
samples read into their intervals and hands back each interval once it is
complete, with the mean of its samples (`mean_sample`) and the mean of their
times, which is where that mean belongs. Samples never read (missed, failed,
saturated) are simply absent from their interval's mean. No rclpy here.
"""

from dataclasses import dataclass, fields, replace
import math
from typing import List, Optional

import numpy as np

# Sample times within this many periods of an interval edge count as on it (rounding).
_EDGE = 1e-9


@dataclass(frozen=True)
class Interval:
    """A complete publish interval: its number, its mean sample and what went into it."""

    number: int
    mean: object
    time_s: float
    samples: int
    first_index: int
    last_index: int


def mean_sample(samples: list):
    """
    Average samples of one dataclass type field by field.

    Arrays and numbers are averaged; flags (bools) are or-ed.
    """
    first = samples[0]
    if len(samples) == 1:
        return first
    values = {}
    for field in fields(first):
        column = [getattr(s, field.name) for s in samples]
        if isinstance(column[0], (bool, np.bool_)):
            values[field.name] = any(column)
        else:
            values[field.name] = np.mean(np.asarray(column, dtype=np.float64), axis=0)
    return replace(first, **values)


class Decimator:
    """Group device samples (index k, sample) into publish intervals; see the module docstring."""

    def __init__(self, sample_rate_hz: float, publish_rate_hz: float):
        if not (math.isfinite(sample_rate_hz) and math.isfinite(publish_rate_hz)
                and sample_rate_hz >= publish_rate_hz > 0.0):
            msg = (f'the sample rate ({sample_rate_hz} Hz) must be at least the publish rate '
                   f'({publish_rate_hz} Hz), both positive')
            raise ValueError(msg)
        self.sample_rate_hz = float(sample_rate_hz)
        self.publish_rate_hz = float(publish_rate_hz)
        self.number: Optional[int] = None
        self.pending: list = []
        self.indices: List[int] = []

    def interval_of(self, index: int) -> int:
        """Return the publish interval of device sample ``index``."""
        return int(math.floor(index * self.publish_rate_hz / self.sample_rate_hz + _EDGE))

    def add(self, index: int, sample) -> Optional[Interval]:
        """Add sample ``index`` (increasing); return the interval it closes, if any."""
        number = self.interval_of(index)
        closed = self._close() if self.number is not None and number != self.number else None
        self.number = number
        self.pending.append(sample)
        self.indices.append(index)
        return closed

    def close_before(self, index: int) -> Optional[Interval]:
        """Return the open interval if sample ``index`` (not read yet) lies past it."""
        if self.number is None or self.interval_of(index) == self.number:
            return None
        return self._close()

    def _close(self) -> Interval:
        indices = self.indices
        interval = Interval(number=self.number, mean=mean_sample(self.pending),
                            time_s=sum(indices) / len(indices) / self.sample_rate_hz,
                            samples=len(indices), first_index=indices[0],
                            last_index=indices[-1])
        self.number, self.pending, self.indices = None, [], []
        return interval
