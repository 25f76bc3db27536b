"""
Pair samples of several streams by stamp: exactly (rate, temperature...) or by holding.

A slow input (a battery monitor's supply voltage) carries stamps of its own;
`zero_order_hold` gives each sample the latest value at or before its stamp.
"""

from typing import Dict, List, Tuple

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
