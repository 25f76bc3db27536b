"""
Several records of one unit laid end to end: what `diagnosis.diagnose` runs on.

A user calibrates a unit from a few runs, and each run starts with a power
cycle or a re-mount. `join_records` lays the runs end to end on one clock:
each record's stamps are shifted so that it starts one of its own sample
intervals after the record before it ends (the time column stays strictly
increasing), and the row where each record starts is kept. Every history
state (the temperature slope's window, lags, play operators) starts fresh
there, as on a node restarted for each run: `Records.each` runs a batch
operator record by record. One record is itself, unshifted and not copied.
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..errors import CalibrationError
from ..node_models import INPUTS

# Columns beside time_s, temperature_c and gyro_rad_s a record may hold.
OPTIONAL_COLUMNS = ('reference_rad_s',) + tuple(name for name in INPUTS if name != 'time_s')


@dataclass(frozen=True, eq=False)
class Records:
    """
    Records of one unit end to end; the attributes of a recording, over all rows.

    ``starts`` holds the first row of each record, then the number of rows;
    ``shifts_s`` what was added to each record's stamps.
    """

    names: tuple
    starts: tuple
    shifts_s: tuple
    axes: tuple
    time_s: np.ndarray
    temperature_c: np.ndarray
    gyro_rad_s: np.ndarray
    reference_rad_s: Optional[np.ndarray] = None
    acceleration_m_s2: Optional[np.ndarray] = None
    temperature_2_c: Optional[np.ndarray] = None
    supply_voltage_v: Optional[np.ndarray] = None

    @property
    def count(self) -> int:
        """Give the number of records."""
        return len(self.names)

    def __len__(self) -> int:
        return self.starts[-1]

    def rows(self, record: int) -> slice:
        """Give the rows of one record."""
        return slice(self.starts[record], self.starts[record + 1])

    def segments(self, stop: Optional[int] = None) -> tuple:
        """Give the rows of each record up to row ``stop`` (all when None); none empty."""
        stop = len(self) if stop is None else stop
        return tuple(slice(first, min(last, stop))
                     for first, last in zip(self.starts[:-1], self.starts[1:]) if first < stop)

    def each(self, operator, *columns) -> np.ndarray:
        """
        Run ``operator(*parts)`` on each record's part of ``columns``, joined.

        The columns may stop short of the last row (the diagnosed part); a
        history operator then starts afresh at each record's first row.
        """
        if self.count == 1:
            return operator(*columns)
        return np.concatenate([operator(*(column[rows] for column in columns))
                               for rows in self.segments(len(columns[0]))])

    def record_of(self, row: int) -> int:
        """Give the record a row belongs to."""
        return int(np.searchsorted(self.starts, row, side='right')) - 1

    def own_time_s(self, time_s: float) -> tuple:
        """Give (record, stamp on that record's own clock) of a time on the joined clock."""
        record = self.record_of(int(np.searchsorted(self.time_s, time_s)))
        record = min(max(record, 0), self.count - 1)
        return record, float(time_s - self.shifts_s[record])


def _median_interval_s(time_s: np.ndarray) -> float:
    return float(np.median(np.diff(time_s))) if len(time_s) > 1 else 1.0


def _check_like(first, other) -> None:
    """Raise CalibrationError naming ``other`` when its axes or columns differ from the first's."""
    if tuple(other.axes) != tuple(first.axes):
        msg = (f'{other.source}: gyro axes {", ".join(other.axes)}, but {first.source} has '
               f'{", ".join(first.axes)}: the records of one unit need the same axes')
        raise CalibrationError(msg)
    for name in OPTIONAL_COLUMNS:
        has, had = getattr(other, name) is not None, getattr(first, name) is not None
        if has != had:
            columns = ('ref_' + ', ref_'.join(first.axes) if name == 'reference_rad_s' else
                       ', '.join(INPUTS[name].columns))
            msg = (f'{other.source}: {"has" if has else "lacks"} {columns}, which '
                   f'{first.source} {"lacks" if has else "has"}: the records of one unit need '
                   'the same columns')
            raise CalibrationError(msg)


def join_records(recordings) -> Records:
    """
    Lay recordings of one unit end to end (see the module docstring).

    Each has ``source``, ``axes``, ``time_s``, ``temperature_c``,
    ``gyro_rad_s`` and the optional columns (None when absent), like
    `mlx_tempcomp.recordings.recording.Recording`; one recording stands for
    itself alone, a `Records` is returned as it is. Raise CalibrationError
    naming a record whose axes or columns differ from the first's.
    """
    if isinstance(recordings, Records):
        return recordings
    recordings = (recordings,) if hasattr(recordings, 'time_s') else tuple(recordings)
    if not recordings:
        raise CalibrationError('no record given')
    first = recordings[0]
    for other in recordings[1:]:
        _check_like(first, other)
    shifts, end = [], None
    for recording in recordings:
        time_s = np.asarray(recording.time_s, dtype=np.float64)
        shift = 0.0 if end is None else end + _median_interval_s(time_s) - float(time_s[0])
        shifts.append(shift)
        end = float(time_s[-1]) + shift
    lengths = [len(recording.time_s) for recording in recordings]

    def joined(name: str, shift: bool = False):
        if getattr(first, name) is None:
            return None
        if len(recordings) == 1:
            return np.asarray(getattr(first, name), dtype=np.float64)
        return np.concatenate([np.asarray(getattr(r, name), dtype=np.float64) + (s if shift
                                                                                 else 0.0)
                               for r, s in zip(recordings, shifts)])

    return Records(names=tuple(str(r.source) for r in recordings),
                   starts=tuple(int(v) for v in np.concatenate(([0], np.cumsum(lengths)))),
                   shifts_s=tuple(shifts), axes=tuple(first.axes),
                   time_s=joined('time_s', shift=True), temperature_c=joined('temperature_c'),
                   gyro_rad_s=joined('gyro_rad_s'),
                   **{name: joined(name) for name in OPTIONAL_COLUMNS})
