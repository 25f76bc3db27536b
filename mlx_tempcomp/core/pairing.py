"""Pair samples of several streams (rate, temperature...) that carry the same stamp."""

from typing import Dict, List, Tuple


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
