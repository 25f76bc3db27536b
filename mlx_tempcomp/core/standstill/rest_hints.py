"""
Rest hints: the robot saying it stands still, on the sensor's time line.

A hint is (time_s, at_rest): at ``time_s`` the robot said it was at rest (True) or moving.
What it said holds until the next hint, for ``max_age_s`` at most. A window of samples
(its first to its last sample) is **hinted** when the hints said "at rest" at every
instant of it:

- the latest hint at or before its first sample says at rest, and is at most
  ``max_age_s`` old there;
- every hint after it, up to the window's last sample, says at rest;
- no two of those hints are more than ``max_age_s`` apart, and the last is at most
  ``max_age_s`` before the window's last sample.

So a hint that ends mid-window, a "moving" inside it, or hints gone stale leave the
window unhinted. A window is judged when it closes (the first sample of a later window
arrives), with the hints known then: a hint that arrives after that does not count for it.
``max_age_s`` is also the transport's allowance: the last hint need only be that young at
the window's last sample.

The core takes times only (seconds of the samples' own clock). The node gives a stamped
message its header stamp and an unstamped one the time of the latest sample it has
tracked (`ros/compensation/bias_tracking.py`); the offline twin gives each sample the hint of
its row (``evaluate --rest-hint COLUMN``). Hints are kept in time order (a late one slots
in) from the latest at or before the open window's start; a clock going back forgets them.
"""

import bisect
import math

import numpy as np

# Hints kept at most (a stream stamped far in the future must not grow without end).
MAX_HINTS = 1_000_000


class RestHints:
    """The hints known, in time order; `covers` says whether they hint a span."""

    def __init__(self):
        self._times = []
        self._rest = []
        self.received = 0

    def __len__(self) -> int:
        return len(self._times)

    def add(self, time_s: float, at_rest: bool) -> None:
        """Keep one hint; a non-finite time is ignored (it says nothing about any window)."""
        if not math.isfinite(time_s):
            return
        self.received += 1
        times = self._times
        if not times or time_s >= times[-1]:
            times.append(time_s)
            self._rest.append(bool(at_rest))
        else:
            index = bisect.bisect_right(times, time_s)
            times.insert(index, time_s)
            self._rest.insert(index, bool(at_rest))
        self._cap()

    def add_block(self, time_s: np.ndarray, at_rest: np.ndarray) -> None:
        """Keep one hint per row (the offline twin: each sample's own); the same as `add` each."""
        finite = np.isfinite(time_s)
        times = time_s[finite]
        if not times.size:
            return
        rest = np.asarray(at_rest, dtype=bool)[finite]
        if (not self._times or times[0] >= self._times[-1]) and np.all(np.diff(times) >= 0):
            self._times.extend(times.tolist())
            self._rest.extend(rest.tolist())
            self.received += times.size
            self._cap()
            return
        for t, r in zip(times.tolist(), rest.tolist()):
            self.add(t, r)

    def _cap(self) -> None:
        if len(self._times) > MAX_HINTS:
            del self._times[:-MAX_HINTS]
            del self._rest[:-MAX_HINTS]

    def clear(self) -> None:
        """Forget every hint (the clock went back: they belong to another time line)."""
        self._times.clear()
        self._rest.clear()

    def forget_before(self, time_s: float) -> None:
        """Drop the hints before the latest at or before ``time_s`` (no window needs them)."""
        times = self._times
        index = bisect.bisect_right(times, time_s) - 1
        while index > 0 and times[index - 1] == times[index]:
            index -= 1
        if index > 0:
            del times[:index]
            del self._rest[:index]

    def latest(self, time_s: float):
        """Give (time, at rest) of the latest hint at or before ``time_s``, None without one."""
        index = bisect.bisect_right(self._times, time_s) - 1
        return None if index < 0 else (self._times[index], self._rest[index])

    def covers(self, first_s: float, last_s: float, max_age_s: float) -> bool:
        """Tell whether the hints said at rest from ``first_s`` to ``last_s`` (module notes)."""
        if not (math.isfinite(first_s) and math.isfinite(last_s)):
            return False
        times, rest = self._times, self._rest
        start = bisect.bisect_right(times, first_s) - 1
        if start < 0 or first_s - times[start] > max_age_s:
            return False
        # Several hints at that very time: each must say at rest.
        while start > 0 and times[start - 1] == times[start]:
            start -= 1
        end = bisect.bisect_right(times, last_s)
        previous = times[start]
        for index in range(start, end):
            if not rest[index] or times[index] - previous > max_age_s:
                return False
            previous = times[index]
        return last_s - previous <= max_age_s
