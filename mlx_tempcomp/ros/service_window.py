"""
The window a service collects from a running stream, the await that gives up on a stall.

``imu/recalibrate_zro``, ``imu/calibrate_offsets`` and ``imu/run_bias_procedure``
are coroutines: the stream keeps flowing (and filling their window) while
they await its future. A timer asks the service's stall check meanwhile; a
stall resolves the future with the check's refusal instead. A node runs one
such call at a time (`ServiceGuard`): one that arrives meanwhile is refused
at once, saying which call runs and since when, never queued.
"""

from datetime import datetime, timezone
import time
from typing import Callable

import numpy as np
from rclpy.task import Future

# How often a service checks its stream for a stall (wall time).
POLL_S = 0.1
# A device's service window that gets no sample for this long (wall time) gives up.
STALL_TIMEOUT_S = 5.0


class ServiceGuard:
    """
    The one call of a node's services that change its calibration, while it runs.

    `begin` takes the node for a call (``what``: "a ZRO recalibration") and
    gives '', or the refusal naming the call running and since when; `end`
    frees it. Every such service of a node shares its guard.
    """

    def __init__(self):
        self.running = ''
        self.since = ''
        self.started = 0.0

    def begin(self, what: str) -> str:
        if self.running:
            return (f'refused: {self.running} is running since {self.since} '
                    f'({time.monotonic() - self.started:.1f} s); call again when it is done')
        self.running = what
        self.since = datetime.now(timezone.utc).isoformat(timespec='seconds')
        self.started = time.monotonic()
        return ''

    def end(self) -> None:
        self.running = ''


class SampleWindow:
    """Rows of values over ``duration_ns`` of stamps; its future resolves ('') when full."""

    def __init__(self, duration_ns: int):
        self.duration_ns = duration_ns
        self.start_ns = None
        self.rows = []
        self.future = Future()

    def add(self, stamp_ns: int, *values) -> None:
        if self.future.done():
            return
        if self.start_ns is None:
            self.start_ns = stamp_ns
        self.rows.append(values)
        if stamp_ns - self.start_ns >= self.duration_ns:
            self.future.set_result('')

    def columns(self) -> tuple:
        """Give each value of the rows as an array (samples first)."""
        return tuple(np.array(column) for column in zip(*self.rows))


async def await_window(node, future: Future, stalled: Callable[[], str],
                       period_s: float = POLL_S) -> str:
    """
    Await ``future`` while a timer of ``node`` calls ``stalled`` every ``period_s``.

    ``stalled`` gives the refusal when the stream stalled, else ''; a refusal
    resolves the future. The timer goes however the await ends.
    """
    def check() -> None:
        if future.done():
            return
        refusal = stalled()
        if refusal:
            future.set_result(refusal)

    timer = node.create_timer(period_s, check)
    try:
        return await future
    finally:
        node.destroy_timer(timer)
