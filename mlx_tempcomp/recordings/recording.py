"""
The recording the calibration toolkit works on: gyro rate and temperature in clean columns.

A `Recording` holds clean float64 columns: time strictly increasing, every
value finite. Its readers (`load.load_recording` by the path's extension:
`csv_reader`, `load.load_bag`, `load.load_flight_log`) give the canonical
columns of their rows to `recording_from_columns`, which drops the rows that
cannot be used and counts them by reason in ``Recording.skipped`` (the
``SKIP_*`` constants); anything that leaves no usable row, or a file that
cannot be read at all, raises `RecordingError` with a message naming the file
and what is wrong. Values no gyro recording holds (`PLAUSIBLE_RANGES`: a
glitch, a -999 sentinel, a time in ns read as s) are skipped like non-finite
ones, so nothing downstream overflows.

Time order: a row that repeats an earlier row exactly (same
time, same values) is dropped and counted. Rows out of time order are sorted
into place, and counted in ``Recording.sorted_rows``, when that is all they
are: whole blocks of rows in the wrong place, each backward jump of the time
explaining at most three more cuts of the file's row order (moving one block
cuts it three times). Two rows with the same time but different values, or
rows whose times fall between earlier rows far more often than the backward
jumps explain (a clock reset, two recordings joined), raise `RecordingError`
naming the first offending row: sorting would mix two time bases.
"""

from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Dict, Mapping, Optional, Sequence, Union

import numpy as np

from .errors import RecordFileError

AXES = ('x', 'y', 'z')
SKIP_PRESET = 'dropped by preset'
SKIP_NON_NUMERIC = 'non-numeric values'
SKIP_NON_FINITE = 'non-finite values'
SKIP_OUT_OF_RANGE = 'values out of range'
SKIP_REPEATED_ROW = 'repeated rows'
SKIP_DUPLICATED_TIME = 'duplicated time'
SKIP_IMU_UNPAIRED = 'IMU without temperature'
SKIP_TEMPERATURE_UNPAIRED = 'temperature without IMU'
SKIP_CORRUPT = 'corrupt messages'
SKIP_NO_SUPPLY = 'IMU without a supply voltage within 5 s'

# What a gyro recording can hold, by canonical column prefix; a row beyond is a glitch or a
# sentinel (e.g. -999) and is skipped. Temperatures: the node's reference-temperature range.
PLAUSIBLE_RANGES = MappingProxyType({
    'time': (-1e10, 1e10),                # s: ROS stamps end in 2038 (2.1e9 s)
    'temperature': (-100.0, 200.0),       # degC, temperature and temperature_2
    'gyro': (-1e3, 1e3), 'ref': (-1e3, 1e3),   # rad/s: 57,000 deg/s
    'acc': (-1e4, 1e4),                   # m/s^2: 1000 g
    'supply_voltage': (-1e3, 1e3),        # V
})


PathLike = Union[str, Path]


class RecordingError(RecordFileError):
    """A recording cannot be read, or holds no usable row; the message names the file."""


def _column(source: str, name: str, value, shape: tuple) -> np.ndarray:
    """Give a read-only float64 copy of one column, checked for shape and finiteness."""
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        msg = f'{source}: {name} is not an array of numbers ({err})'
        raise RecordingError(msg) from None
    if array.shape != shape:
        msg = f'{source}: {name} must have shape {shape}, got {array.shape}'
        raise RecordingError(msg)
    if not np.isfinite(array).all():
        msg = f'{source}: {name} holds NaN or inf'
        raise RecordingError(msg)
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class Recording:
    """
    Gyro rate and temperature sampled together, ready for fitting.

    Arrays are read-only float64 copies with one row per sample; ``time_s``
    is strictly increasing and starts wherever the data starts. ``axes``
    names the gyro axes present, in x, y, z order, and orders the columns
    of ``gyro_rad_s`` and ``reference_rad_s``. ``skipped`` counts the rows
    dropped while loading, by reason; ``sorted_rows`` the rows that were out
    of time order in the source and were sorted into place.
    """

    source: str
    time_s: np.ndarray
    temperature_c: np.ndarray
    axes: tuple
    gyro_rad_s: np.ndarray
    reference_rad_s: Optional[np.ndarray] = None
    acceleration_m_s2: Optional[np.ndarray] = None
    temperature_2_c: Optional[np.ndarray] = None
    supply_voltage_v: Optional[np.ndarray] = None
    skipped: Mapping[str, int] = field(default_factory=dict)
    sorted_rows: int = 0

    def __post_init__(self):
        source = str(self.source)
        object.__setattr__(self, 'source', source)
        axes = tuple(self.axes)
        if not axes or axes != tuple(a for a in AXES if a in axes):
            msg = f'{source}: axes must be some of x, y, z, in that order; got {axes}'
            raise RecordingError(msg)
        object.__setattr__(self, 'axes', axes)
        rows = np.shape(self.time_s)[0] if np.ndim(self.time_s) == 1 else None
        if not rows:
            msg = f'{source}: a recording needs time_s of one or more rows, got ' \
                  f'shape {np.shape(self.time_s)}'
            raise RecordingError(msg)
        time_s = _column(source, 'time_s', self.time_s, (rows,))
        if not np.all(np.diff(time_s) > 0):
            msg = f'{source}: time_s must be strictly increasing'
            raise RecordingError(msg)
        object.__setattr__(self, 'time_s', time_s)
        shapes = (('temperature_c', (rows,)), ('gyro_rad_s', (rows, len(axes))),
                  ('reference_rad_s', (rows, len(axes))), ('acceleration_m_s2', (rows, 3)),
                  ('temperature_2_c', (rows,)), ('supply_voltage_v', (rows,)))
        for name, shape in shapes:
            value = getattr(self, name)
            if value is not None or name in ('temperature_c', 'gyro_rad_s'):
                object.__setattr__(self, name, _column(source, name, value, shape))
        skipped = {str(reason): int(count) for reason, count in dict(self.skipped).items()}
        object.__setattr__(self, 'skipped', MappingProxyType(skipped))
        if int(self.sorted_rows) < 0:
            msg = f'{source}: sorted_rows must be >= 0, got {self.sorted_rows!r}'
            raise RecordingError(msg)
        object.__setattr__(self, 'sorted_rows', int(self.sorted_rows))

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def rate_error_rad_s(self) -> np.ndarray:
        """Give the rate error a bias is fitted to: gyro minus reference, or the gyro at rest."""
        if self.reference_rad_s is None:
            return self.gyro_rad_s
        return self.gyro_rad_s - self.reference_rad_s

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample."""
        return float(self.time_s[-1] - self.time_s[0])

    def slice(self, rows) -> 'Recording':  # noqa: A003 - the toolkit's agreed name
        """
        Give a Recording of some rows, e.g. a train or test part.

        Parameters
        ----------
        rows
            A boolean mask of ``len(self)`` rows, increasing row indices or a
            ``slice``. At least one row must be selected.

        Returns
        -------
        Recording
            The selected rows, same source, axes, ``skipped`` and
            ``sorted_rows`` counts (they describe how the source was loaded).

        """
        try:
            index = np.atleast_1d(np.arange(len(self))[rows])
        except (IndexError, TypeError, ValueError) as err:
            msg = f'{self.source}: cannot select rows {rows!r}: {err}'
            raise RecordingError(msg) from None

        def take(array):
            return None if array is None else array[index]

        return replace(self, time_s=self.time_s[index], temperature_c=self.temperature_c[index],
                       gyro_rad_s=self.gyro_rad_s[index],
                       reference_rad_s=take(self.reference_rad_s),
                       acceleration_m_s2=take(self.acceleration_m_s2),
                       temperature_2_c=take(self.temperature_2_c),
                       supply_voltage_v=take(self.supply_voltage_v))


# Moving one block of rows elsewhere cuts the file's row order in three places.
CUTS_PER_BACKWARD_JUMP = 3


@dataclass(frozen=True)
class _RowNames:
    """Names rows in messages: ``noun`` and the 1-based number of each row in the source."""

    noun: str
    numbers: np.ndarray

    def __call__(self, row: int) -> str:
        return f'{self.noun} {int(self.numbers[row])}'


def _count(skipped: Dict[str, int], reason: str, count) -> None:
    if count:
        skipped[reason] = skipped.get(reason, 0) + int(count)


def _drop_repeats(source: str, time_s: np.ndarray, values: np.ndarray, rows: np.ndarray,
                  names: _RowNames, skipped: Dict[str, int]) -> np.ndarray:
    """Drop rows that repeat an earlier row exactly; refuse a time shared by other values."""
    if np.all(np.diff(time_s[rows]) > 0):
        return rows  # in time order already: no time can repeat (and no sort is paid)
    order = np.argsort(time_s[rows], kind='stable')
    same = np.flatnonzero(np.diff(time_s[rows[order]]) == 0)
    if not same.size:
        return rows
    first, later = rows[order[same]], rows[order[same + 1]]
    repeated = np.all(values[first] == values[later], axis=1)
    if not repeated.all():
        clash = np.flatnonzero(~repeated)
        pick = clash[np.argmin(later[clash])]
        msg = (f'{source}: {names(later[pick])} has time {float(time_s[later[pick]])!r} s '
               f'like {names(first[pick])} but other values; two samples cannot share a time '
               '(a clock reset or two recordings joined?): fix the times or split the file')
        raise RecordingError(msg)
    _count(skipped, SKIP_REPEATED_ROW, later.size)
    return np.setdiff1d(rows, later, assume_unique=True)


def _time_ordered_rows(source: str, time_s: np.ndarray, values: np.ndarray, bounds: tuple,
                       non_numeric: np.ndarray, names: _RowNames,
                       skipped: Dict[str, int]) -> tuple:
    """
    Give the usable rows in time order and how many were out of order.

    Rows with a non-numeric, non-finite or implausible value (outside ``bounds``,
    the low and high of each column) and exact repeats are counted in
    ``skipped``; see the module notes for when rows are sorted or refused.
    """
    finite = np.isfinite(values).all(axis=1)
    low, high = bounds
    with np.errstate(invalid='ignore'):
        plausible = ((values >= low) & (values <= high)).all(axis=1)
    _count(skipped, SKIP_NON_NUMERIC, np.count_nonzero(non_numeric))
    _count(skipped, SKIP_NON_FINITE, np.count_nonzero(~non_numeric & ~finite))
    _count(skipped, SKIP_OUT_OF_RANGE, np.count_nonzero(~non_numeric & finite & ~plausible))
    rows = _drop_repeats(source, time_s, values, np.flatnonzero(~non_numeric & plausible),
                         names, skipped)
    times = time_s[rows]
    backward = np.flatnonzero(np.diff(times) < 0)
    if not backward.size:
        return rows, 0
    order = np.argsort(times, kind='stable')
    cuts = int(np.count_nonzero(np.diff(order) != 1))
    if cuts > CUTS_PER_BACKWARD_JUMP * backward.size:
        before, after = rows[backward[0]], rows[backward[0] + 1]
        msg = (f'{source}: time goes back at {names(after)} ({float(time_s[after])!r} s '
               f'after {float(time_s[before])!r} s at {names(before)}) and later rows fall '
               f'between earlier ones: in time order the rows come in {cuts + 1} pieces for '
               f'{backward.size} backward jump(s), not whole blocks out of place (a clock '
               'reset or two recordings joined?); sorting would mix them: fix the times or '
               'split the file')
        raise RecordingError(msg)
    previous = np.maximum.accumulate(times)[:-1]
    return rows[order], int(np.count_nonzero(times[1:] < previous))


def _skip_summary(skipped: Mapping[str, int]) -> str:
    return ', '.join(f'{reason} {count}' for reason, count in skipped.items())


def _recording(source: str, columns: Dict[str, np.ndarray], non_numeric: np.ndarray,
               skipped: Dict[str, int], names: _RowNames) -> Recording:
    """Drop unusable rows of canonical columns (each of N rows), order them, build it."""
    values = np.column_stack(list(columns.values()))
    bounds = np.array([PLAUSIBLE_RANGES[name if name in PLAUSIBLE_RANGES
                                        else name.rsplit('_', 1)[0]] for name in columns]).T
    keep, sorted_rows = _time_ordered_rows(source, columns['time'], values, bounds,
                                           non_numeric, names, skipped)
    if not keep.size:
        msg = (f'{source}: no usable row; all {sum(skipped.values())} rows skipped '
               f'({_skip_summary(skipped)})')
        raise RecordingError(msg)
    axes = tuple(a for a in AXES if f'gyro_{a}' in columns)

    def stack(prefix: str, group_axes: tuple) -> Optional[np.ndarray]:
        if f'{prefix}_{group_axes[0]}' not in columns:
            return None
        return np.column_stack([columns[f'{prefix}_{a}'][keep] for a in group_axes])

    def single(name: str) -> Optional[np.ndarray]:
        return None if name not in columns else columns[name][keep]

    return Recording(source=source, time_s=columns['time'][keep],
                     temperature_c=columns['temperature'][keep], axes=axes,
                     gyro_rad_s=stack('gyro', axes), reference_rad_s=stack('ref', axes),
                     acceleration_m_s2=stack('acc', AXES),
                     temperature_2_c=single('temperature_2'),
                     supply_voltage_v=single('supply_voltage'), skipped=skipped,
                     sorted_rows=sorted_rows)


def recording_from_columns(source: str, columns: Dict[str, np.ndarray],
                           skipped: Mapping[str, int], noun: str,
                           row_numbers: Optional[Sequence[int]] = None,
                           non_numeric: Optional[np.ndarray] = None) -> Recording:
    """
    Build a Recording from canonical columns of one row per sample, as the loaders do.

    Rows with a non-finite or implausible value, or marked in ``non_numeric``
    (a cell that is not a number), are dropped and counted on top of
    ``skipped``. ``noun`` and ``row_numbers`` name a row in messages (e.g.
    'line 12', 'IMU sample 3'); the numbers are 1-based, in the source's order
    (default: 1 to N).
    """
    rows = len(columns['time'])
    numbers = np.arange(1, rows + 1) if row_numbers is None else row_numbers
    marked = np.zeros(rows, dtype=bool) if non_numeric is None else non_numeric
    return _recording(source, dict(columns), marked, dict(skipped), _RowNames(noun, numbers))
