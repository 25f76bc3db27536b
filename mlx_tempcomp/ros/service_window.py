"""
The window a service collects from a running stream, the await that gives up on a stall.

``imu/recalibrate_zro``, ``imu/calibrate_offsets`` and ``imu/run_bias_procedure``
are coroutines: the stream keeps flowing (and filling their window) while
they await its future. A timer asks the service's stall check meanwhile; a
stall fails the future with the check's refusal instead. A node runs one
such call at a time (`ServiceGuard`): one that arrives meanwhile is refused
at once, saying which call runs and since when, never queued.

A call's answer is a value, `Outcome` (whether it changed the calibration, and
what it says), never text to parse: a refusal anywhere below the service is
`Refused`, which `guarded` turns into the failed outcome ``refused: <reason>``;
a change applied but not saved is an outcome that failed.
"""

from dataclasses import dataclass
from datetime import datetime, timezone
import time
from typing import Awaitable, Callable, Optional

import numpy as np
from rclpy.task import Future

from ..errors import MlxTempCompError

# How often a service checks its stream for a stall (wall time).
POLL_S = 0.1
# A device's service window that gets no sample for this long (wall time) gives up.
STALL_TIMEOUT_S = 5.0


class Refused(MlxTempCompError):
    """A calibration call refused, with its reason: nothing was changed."""

    def outcome(self) -> 'Outcome':
        return Outcome(False, f'refused: {self}')


@dataclass(frozen=True)
class Outcome:
    """What a calibration call did: ``success`` when it changed and kept it; ``message``."""

    success: bool
    message: str


class ServiceGuard:
    """
    The one call of a node's services that change its calibration, while it runs.

    `begin` takes the node for a call (``what``: "a ZRO recalibration"), or
    raises `Refused` naming the call running and since when; `end` frees it.
    Every such service of a node shares its guard (`guarded`).
    """

    def __init__(self):
        self.running = ''
        self.since = ''
        self.started = 0.0

    def begin(self, what: str) -> None:
        if self.running:
            raise Refused(f'{self.running} is running since {self.since} '
                          f'({time.monotonic() - self.started:.1f} s); call again when it is '
                          'done')
        self.running = what
        self.since = datetime.now(timezone.utc).isoformat(timespec='seconds')
        self.started = time.monotonic()

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


async def guarded(guard: ServiceGuard, what: str,
                  call: Callable[[], Awaitable[Outcome]]) -> Outcome:
    """Run ``call`` alone under ``guard`` (``what`` names it); a `Refused` is its outcome."""
    try:
        guard.begin(what)
    except Refused as refusal:
        return refusal.outcome()
    try:
        return await call()
    except Refused as refusal:
        return refusal.outcome()
    finally:
        guard.end()


async def await_window(node, future: Future, poll: Callable[[], Optional[object]],
                       period_s: float = POLL_S):
    """
    Await ``future`` while a timer of ``node`` calls ``poll`` every ``period_s``.

    ``poll`` raises `Refused` when the stream stalled (the await raises it), or
    gives what resolves the future (None: not yet). The timer goes however the
    await ends.
    """
    def check() -> None:
        if future.done():
            return
        try:
            result = poll()
        except Refused as refusal:
            future.set_exception(refusal)
            return
        if result is not None:
            future.set_result(result)

    timer = node.create_timer(period_s, check)
    try:
        return await future
    finally:
        node.destroy_timer(timer)
