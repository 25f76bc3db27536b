"""
Pair samples of several streams by stamp: exactly, by holding, or by interpolating.

`StampPairer` pairs streams that share stamps (a driver that stamps rate and
temperature alike). A slower input carries stamps of its own: `zero_order_hold`
gives each sample the latest value at or before its stamp (a battery monitor's
supply voltage), and `ReadingPairer` does so, or interpolates, for readings that
arrive as a stream while the samples do (a driver's temperature at 1 Hz beside its
rate at 100 Hz), deciding each sample as soon as its readings allow.
"""

import bisect
import collections
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np


class StampPairer:
    """
    Collect one value per stream for each stamp; emit a stamp once every stream has it.

    Streams arrive in stamp order but may lose messages, so a stamp still
    incomplete when a newer one completes can never complete: it is dropped and
    counted. At most ``capacity`` incomplete stamps are held.
    """

    def __init__(self, streams: Tuple[str, ...], capacity: int = 1000):
        self.streams = tuple(streams)
        self.capacity = capacity
        self._pending: Dict[int, dict] = {}
        self.dropped = 0
        self.paired = 0

    def add(self, stream: str, stamp_ns: int, value) -> List[Tuple[int, dict]]:
        """Add one value; return the (stamp, {stream: value}) samples now complete."""
        entry = self._pending.setdefault(stamp_ns, {})
        entry[stream] = value
        if len(entry) < len(self.streams):
            if len(self._pending) > self.capacity:
                oldest = min(self._pending)
                del self._pending[oldest]
                self.dropped += 1
            return []
        del self._pending[stamp_ns]
        stale = [s for s in self._pending if s < stamp_ns]
        for s in stale:
            del self._pending[s]
        self.dropped += len(stale)
        self.paired += 1
        return [(stamp_ns, entry)]

    def clear(self) -> None:
        self._pending.clear()


def zero_order_hold(sample_stamps_ns, stamps_ns, values, max_age_ns: int):
    """
    Give each sample the latest held value stamped at or before it (zero-order hold).

    A sample older than every held value takes the oldest one. A value more
    than ``max_age_ns`` from its sample's stamp (either way) is not usable.

    Parameters
    ----------
    sample_stamps_ns
        Stamps of the samples (int64 ns), any order.
    stamps_ns, values
        Stamps (ascending) and values of the slow input.
    max_age_ns
        Largest usable distance between a sample and its value.

    Returns
    -------
    values, usable
        float64 arrays over the samples; values are NaN where not usable.

    """
    samples = np.asarray(sample_stamps_ns, dtype=np.int64)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    held = np.full(samples.shape, np.nan)
    if stamps.size == 0:
        return held, np.zeros(samples.shape, dtype=bool)
    index = np.clip(np.searchsorted(stamps, samples, side='right') - 1, 0, stamps.size - 1)
    usable = np.abs(samples - stamps[index]) <= max_age_ns
    held[usable] = np.asarray(values, dtype=np.float64)[index[usable]]
    return held, usable


@dataclass(frozen=True)
class PairedReading:
    """What a sample got of one reading stream: the value, the reading, exact or not, the age."""

    value: float
    payload: object     # of the reading held (interpolated: of the one before)
    exact: bool         # the reading is stamped like the sample: value and payload are its own
    age_ns: int         # from the sample to the farthest reading used, either way


# A sample's verdicts besides its readings: they may still come; its own reading was lost.
WAIT = 'wait'
LOST = 'lost'
# How the streams stamp is read from the last samples decided: shared when at least 3 in 4
# found a reading of their own stamp (a best-effort stream on a loaded machine loses a run
# of them now and then), apart at half or less (a temperature at a tenth of the rate,
# stamped like every tenth sample).
_OUTCOMES = 100
_SHARED_SHARE, _APART_SHARE = 0.75, 0.5
# How the streams stamp: not known yet, alike (every sample has a reading of its stamp), apart.
PRESUMED, SHARED, APART = 'presumed', 'shared', 'apart'


class ReadingPairer:
    """
    Give each sample the readings of slower streams: held or interpolated, within an age.

    Samples (``add_sample``: the rate) and readings (``add_reading``: each
    temperature stream) come in any order; `pop` gives the samples now decided,
    in stamp order, each with a `PairedReading` per stream, or as unpaired:

    - a reading stamped like the sample is its own (exact, whatever the mode);
    - ``hold``: else the latest reading stamped before it, within ``max_age_ns``.
      It is decided at once with what has come: a sample does not wait for a
      slower stream.
    - ``interpolate``: linear between the readings before and after it, both
      within the age; a sample waits for the reading after it, at most until
      samples stamped ``max_age_ns`` later have come (then it is unpaired).

    How the streams stamp is read from the share of the last samples (2 to 100)
    paired exactly: SHARED at 3 in 4 (a driver that stamps both alike), APART at
    half or less, PRESUMED before. While SHARED, a sample pairs as by stamp: it
    waits for its own reading, so the choice does not depend on which topic came
    first, and one whose reading was lost (a reading stamped after it came first,
    or ``shared_wait_ns`` of later samples: a loaded machine may hold one topic
    back for seconds of a fast driver's stamps) is unpaired and counted
    (``lost``), as pairing by stamp drops it. While PRESUMED (at start) a sample
    waits for its own too, and is held when a later reading comes first.

    Before the first reading of a stream, samples wait, at most ``max_age_ns`` of
    later samples (a late reading may still come for them); those that expire, and
    those stamped before the first reading (nothing was measured before them: a
    driver's temperature began later, or its topic was matched later), are
    unpaired and counted apart (`before_first`). At most ``capacity`` samples wait
    (the oldest then goes unpaired) and ``history`` readings per stream are kept.
    """

    def __init__(self, streams: Tuple[str, ...], interpolate: bool, max_age_ns: int,
                 capacity: int = 20000, history: int = 1024,
                 shared_wait_ns: int = 10 * 10 ** 9):
        self.streams = tuple(streams)
        self.interpolate = interpolate
        self.max_age_ns = int(max_age_ns)
        self.shared_wait_ns = max(int(shared_wait_ns), self.max_age_ns)
        self.capacity = capacity
        self.history = history
        self._stamps: Dict[str, list] = {s: [] for s in self.streams}
        self._readings: Dict[str, list] = {s: [] for s in self.streams}
        self._pending: list = []         # (stamp_ns, arrival, sample), ascending
        self._arrivals = 0
        self.newest_sample_ns: Optional[int] = None
        self.stamps = PRESUMED
        self._outcomes = collections.deque(maxlen=_OUTCOMES)   # exact or not, the last
        self.paired = 0
        self.unpaired = 0
        self.before_first = 0
        self.lost = 0

    @property
    def waiting(self) -> int:
        return len(self._pending)

    @property
    def waiting_ns(self) -> int:
        """Give how long in stamps the oldest sample waiting has waited (0: none waits)."""
        return self.newest_sample_ns - self._pending[0][0] if self._pending else 0

    def add_reading(self, stream: str, stamp_ns: int, value: float, payload=None) -> None:
        """Keep a reading: a late one slots in by stamp, a repeated stamp replaces."""
        stamps, readings = self._stamps[stream], self._readings[stream]
        index = bisect.bisect_left(stamps, stamp_ns)
        if index < len(stamps) and stamps[index] == stamp_ns:
            readings[index] = (float(value), payload)
            return
        stamps.insert(index, stamp_ns)
        readings.insert(index, (float(value), payload))
        if len(stamps) > 2 * self.history:   # trimmed now and then, not at every reading
            del stamps[:-self.history]
            del readings[:-self.history]

    def add_sample(self, stamp_ns: int, sample) -> None:
        """Queue a sample to pair; `pop` gives it once decided."""
        self._arrivals += 1
        entry = (stamp_ns, self._arrivals, sample)
        if not self._pending or self._pending[-1][0] <= stamp_ns:
            self._pending.append(entry)
        else:
            bisect.insort(self._pending, entry, key=lambda e: (e[0], e[1]))
        if self.newest_sample_ns is None or stamp_ns > self.newest_sample_ns:
            self.newest_sample_ns = stamp_ns

    def pop(self) -> Tuple[list, list]:
        """
        Give (paired, unpaired) samples decided now, each in stamp order.

        ``paired``: (stamp_ns, sample, {stream: `PairedReading`}); ``unpaired``:
        (stamp_ns, sample) with no usable reading within the age.
        """
        paired, unpaired = [], []
        pending = self._pending
        decided = 0
        while decided < len(pending):
            stamp, _, sample = pending[decided]
            readings = self._decide(stamp, len(pending) - decided > self.capacity)
            if readings is WAIT:
                break
            decided += 1
            if readings is None or readings is LOST:
                self.unpaired += 1
                unpaired.append((stamp, sample))
                if readings is LOST:
                    self.lost += 1
                    self._follow(False)
                continue
            self.paired += 1
            paired.append((stamp, sample, readings))
            self._follow(all(r.exact for r in readings.values()))
        del pending[:decided]
        return paired, unpaired

    def _follow(self, exact: bool) -> None:
        """Tell how the streams stamp from the last samples' pairing."""
        outcomes = self._outcomes
        outcomes.append(exact)
        if len(outcomes) < 2:
            return
        share = sum(outcomes) / len(outcomes)
        if share >= _SHARED_SHARE:
            self.stamps = SHARED
        elif share <= _APART_SHARE:
            self.stamps = APART

    def _decide(self, stamp: int, overflow: bool):
        """Give the sample's {stream: PairedReading}; None when it cannot be paired, WAIT, LOST."""
        newer_ns = self.newest_sample_ns - stamp
        expired = overflow or newer_ns > self.max_age_ns
        late = overflow or newer_ns > self.shared_wait_ns
        readings = {}
        for stream in self.streams:
            stamps = self._stamps[stream]
            if not stamps and not expired:
                return WAIT
            if not stamps or stamp < stamps[0]:
                if stamps and self.stamps == SHARED and not self.interpolate:
                    return LOST   # its own was lost, as by stamp
                self.before_first += 1
                return None
            reading = self._reading(stream, stamp, expired, late)
            if reading is WAIT or reading is None or reading is LOST:
                return reading
            readings[stream] = reading
        return readings

    def _reading(self, stream: str, stamp: int, expired: bool, late: bool):
        """Give one stream's `PairedReading` at ``stamp``; None (none usable), WAIT, LOST."""
        stamps, readings = self._stamps[stream], self._readings[stream]
        index = bisect.bisect_right(stamps, stamp) - 1
        if index >= 0 and stamps[index] == stamp:
            value, payload = readings[index]
            return PairedReading(value, payload, True, 0)
        if self.stamps == SHARED and not self.interpolate:
            # As by stamp: its own reading, or none (one stamped after it came first).
            return LOST if index + 1 < len(stamps) or late else WAIT
        before = stamp - stamps[index]
        if index + 1 < len(stamps):
            if not self.interpolate:
                return PairedReading(*readings[index], False, before) \
                    if before <= self.max_age_ns else None
            after = stamps[index + 1] - stamp
            if max(before, after) > self.max_age_ns:
                return None
            (low, payload), high = readings[index], readings[index + 1][0]
            return PairedReading(low + (high - low) * (before / (before + after)), payload,
                                 False, max(before, after))
        if not expired and (self.interpolate or self.stamps != APART):
            return WAIT
        if self.interpolate or before > self.max_age_ns:
            return None
        return PairedReading(*readings[index], False, before)

    def has_readings(self, streams=None) -> bool:
        """Tell whether each of ``streams`` (default: all) gave a reading."""
        return all(self._stamps[s] for s in (self.streams if streams is None else streams))

    def set_streams(self, streams: Tuple[str, ...]) -> None:
        """Pair with ``streams`` from now on: the readings of those kept stay."""
        self._stamps = {s: self._stamps.get(s, []) for s in streams}
        self._readings = {s: self._readings.get(s, []) for s in streams}
        self.streams = tuple(streams)

    def take_waiting(self) -> list:
        """Give the samples waiting, (stamp_ns, sample) in stamp order, and forget them."""
        waiting = [(stamp, sample) for stamp, _, sample in self._pending]
        self._pending = []
        return waiting
