"""Simulated time shared by the simulated parts, optionally paced against the wall clock."""

import time
from typing import Optional


class SimClock:
    """
    Simulated time, optionally paced against the wall clock.

    ``real_time_factor`` None runs as fast as possible; 1.0 is real time;
    10.0 runs ten times faster than real time.
    """

    def __init__(self, real_time_factor: Optional[float] = None):
        if real_time_factor is not None and real_time_factor <= 0.0:
            msg = f'real_time_factor must be positive, got {real_time_factor}'
            raise ValueError(msg)
        self.real_time_factor = real_time_factor
        self.now_s = 0.0
        self._wall_start = time.monotonic()

    def advance(self, seconds: float) -> None:
        if seconds <= 0.0:
            return
        self.now_s += seconds
        if self.real_time_factor is not None:
            lag = self._wall_start + self.now_s / self.real_time_factor - time.monotonic()
            if lag > 0.0:
                time.sleep(lag)
