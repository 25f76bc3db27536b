"""
Recordings for the calibration toolkit: gyro rate and temperature from CSV, bags or FC logs.

A `Recording` holds clean float64 columns: time strictly increasing, every
value finite. Rows that cannot be used are dropped and counted by reason in
``Recording.skipped`` (the ``SKIP_*`` constants); anything that leaves no
usable row, or a file that cannot be read at all, raises `RecordingError`
with a message naming the file and what is wrong. Values no gyro recording
holds (`PLAUSIBLE_RANGES`: a glitch, a -999 sentinel, a time in ns read as s)
are skipped like non-finite ones, so nothing downstream overflows.

Time order: a row that repeats an earlier row exactly (same
time, same values) is dropped and counted. Rows out of time order are sorted
into place, and counted in ``Recording.sorted_rows``, when that is all they
are: whole blocks of rows in the wrong place, each backward jump of the time
explaining at most three more cuts of the file's row order (moving one block
cuts it three times). Two rows with the same time but different values, or
rows whose times fall between earlier rows far more often than the backward
jumps explain (a clock reset, two recordings joined), raise `RecordingError`
naming the first offending row: sorting would mix two time bases.

CSV files have one header row. Canonical columns: ``time`` (s),
``temperature`` (degC), any of ``gyro_x``, ``gyro_y``, ``gyro_z`` (rad/s);
optional ``ref_x|y|z`` (turntable reference rate, rad/s), ``acc_x|y|z``
(m/s^2), ``temperature_2`` (degC) and ``supply_voltage`` (V). A `ColumnMap`
names the file's column for each (`parse_column_map` reads the command-line
form); `PRESETS` holds the maps of known data sets. The delimiter (tab, comma or semicolon) is
detected from the header unless the map sets it.

Bags (sqlite3 or mcap) are read with `RawBagReader`: ``sensor_msgs/Imu``
and ``sensor_msgs/Temperature`` messages are paired by exact header stamp; a
supply voltage (``sensor_msgs/BatteryState``), on stamps of its own, is held
as the compensation node holds it.

Flight-controller logs (``.ulg`` PX4 ULog, ``.bin`` ArduPilot DataFlash) are
read by `sources.flightlog`: one IMU instance becomes a recording of its
still samples (`load_flight_log`).
"""

import csv
from dataclasses import dataclass, field, replace
import functools
import math
import operator
from pathlib import Path
from types import MappingProxyType
from typing import Dict, Mapping, Optional, Union

import numpy as np

from .bag import (absolute_topic, BagError, ImuRecord, RawBagReader, RawTopics,
                  SupplyVoltageRecord, TemperatureRecord)
from .errors import SourceError
from .flightlog import FlightLogError, instance_columns, is_flight_log, read_flight_log
from ..core.pairing import zero_order_hold

AXES = ('x', 'y', 'z')
BAG_SUFFIXES = ('.db3', '.mcap')

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
# The compensation node's default supply_voltage.max_age_s.
SUPPLY_MAX_AGE_NS = 5_000_000_000

# What a gyro recording can hold, by canonical column prefix; a row beyond is a glitch or a
# sentinel (e.g. -999) and is skipped. Temperatures: the node's reference-temperature range.
PLAUSIBLE_RANGES = MappingProxyType({
    'time': (-1e10, 1e10),                # s: ROS stamps end in 2038 (2.1e9 s)
    'temperature': (-100.0, 200.0),       # degC, temperature and temperature_2
    'gyro': (-1e3, 1e3), 'ref': (-1e3, 1e3),   # rad/s: 57,000 deg/s
    'acc': (-1e4, 1e4),                   # m/s^2: 1000 g
    'supply_voltage': (-1e3, 1e3),        # V
})

_GROUPS = (('gyro', 'gyro'), ('reference', 'ref'), ('acceleration', 'acc'))
CANONICAL_COLUMNS = (('time', 'temperature')
                     + tuple(f'{prefix}_{a}' for _, prefix in _GROUPS for a in AXES)
                     + ('temperature_2', 'supply_voltage'))
_ALWAYS_REQUIRED = ('time', 'temperature')
# Optional columns of one value per row, by canonical name.
_SINGLE_COLUMNS = ('temperature_2', 'supply_voltage')
_DELIMITER_NAMES = {'tab': '\t', 'comma': ',', 'semicolon': ';'}
_NS_PER_S = 1_000_000_000

PathLike = Union[str, Path]


class RecordingError(SourceError):
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


def _axis_columns(prefix: str) -> Dict[str, str]:
    return {a: f'{prefix}_{a}' for a in AXES}


def _column_name(value, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        msg = f'column map: {what} must be a non-empty column name, got {value!r}'
        raise RecordingError(msg)
    return value.strip()


@dataclass(frozen=True)
class ColumnMap:
    """
    Which CSV column feeds each canonical column, and how to parse the file.

    ``gyro``, ``reference`` and ``acceleration`` map axis names (x, y, z) to
    column names. Columns not in the file are left out unless they are
    ``required`` (canonical names such as ``'gyro_x'``); ``time`` and
    ``temperature`` always are, and at least one gyro column must be found.
    Reference columns, when present, must cover every gyro axis found;
    acceleration is read only as all three axes. ``time_scale`` multiplies
    the time column into seconds (1e-6 for microseconds). ``delimiter``
    None detects tab, comma or semicolon from the header. ``skip_rows`` data
    rows are dropped at the start (counted as ``SKIP_PRESET``).
    """

    time: str = 'time'
    time_scale: float = 1.0
    temperature: str = 'temperature'
    gyro: Mapping[str, str] = field(default_factory=functools.partial(_axis_columns, 'gyro'))
    reference: Mapping[str, str] = field(
        default_factory=functools.partial(_axis_columns, 'ref'))
    acceleration: Mapping[str, str] = field(
        default_factory=functools.partial(_axis_columns, 'acc'))
    temperature_2: Optional[str] = 'temperature_2'
    supply_voltage: Optional[str] = 'supply_voltage'
    delimiter: Optional[str] = None
    skip_rows: int = 0
    required: frozenset = frozenset()

    def __post_init__(self):
        object.__setattr__(self, 'time', _column_name(self.time, 'time'))
        object.__setattr__(self, 'temperature', _column_name(self.temperature, 'temperature'))
        for group, prefix in _GROUPS:
            given = dict(getattr(self, group))
            unknown = sorted(set(given) - set(AXES))
            if unknown:
                msg = f'column map: {group} axes must be x, y or z, got {unknown}'
                raise RecordingError(msg)
            columns = {a: _column_name(given[a], f'{prefix}_{a}') for a in AXES if a in given}
            object.__setattr__(self, group, MappingProxyType(columns))
        if not self.gyro:
            msg = 'column map: no gyro column (map at least one of gyro_x, gyro_y, gyro_z)'
            raise RecordingError(msg)
        for name in _SINGLE_COLUMNS:
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _column_name(getattr(self, name), name))
        try:
            time_scale = float(self.time_scale)
        except (TypeError, ValueError):
            time_scale = math.nan
        if not (math.isfinite(time_scale) and time_scale > 0):
            msg = f'column map: time scale must be a positive number, got {self.time_scale!r}'
            raise RecordingError(msg)
        object.__setattr__(self, 'time_scale', time_scale)
        if self.delimiter is not None and (not isinstance(self.delimiter, str)
                                           or len(self.delimiter) != 1
                                           or self.delimiter in '\r\n"'):
            msg = f'column map: the delimiter must be one character, got {self.delimiter!r}'
            raise RecordingError(msg)
        if not isinstance(self.skip_rows, int) or self.skip_rows < 0:
            msg = f'column map: skip_rows must be an integer >= 0, got {self.skip_rows!r}'
            raise RecordingError(msg)
        required = frozenset(self.required)
        unmapped = sorted(required - set(self.sources()))
        if unmapped:
            msg = f'column map: required columns not mapped: {", ".join(unmapped)}'
            raise RecordingError(msg)
        object.__setattr__(self, 'required', required | frozenset(_ALWAYS_REQUIRED))

    def sources(self) -> Dict[str, str]:
        """Map each canonical column in use (e.g. ``'gyro_x'``) to its column in the file."""
        sources = {'time': self.time, 'temperature': self.temperature}
        for group, prefix in _GROUPS:
            sources.update((f'{prefix}_{a}', name) for a, name in getattr(self, group).items())
        sources.update((name, getattr(self, name)) for name in _SINGLE_COLUMNS
                       if getattr(self, name) is not None)
        return sources


def _map_from_sources(sources: Dict[str, str], **options) -> ColumnMap:
    groups = {group: {a: sources[f'{prefix}_{a}'] for a in AXES if f'{prefix}_{a}' in sources}
              for group, prefix in _GROUPS}
    return ColumnMap(time=sources.get('time', ''), temperature=sources.get('temperature', ''),
                     **{name: sources.get(name) for name in _SINGLE_COLUMNS}, **groups,
                     **options)


PRESETS = MappingProxyType({
    # tofupilot/examples imu_thermal_calibration: tab-separated, microseconds, row 0 a glitch
    'tofupilot': _map_from_sources(
        {'time': 'timestamp', 'temperature': 'imu.temperature',
         **{f'gyro_{a}': f'imu.gyro.{a}' for a in AXES},
         **{f'acc_{a}': f'imu.acc.{a}' for a in AXES}},
        time_scale=1e-6, delimiter='\t', skip_rows=1,
        required=frozenset(f'{prefix}_{a}' for prefix in ('gyro', 'acc') for a in AXES)),
})


def column_preset(name: str) -> ColumnMap:
    """Give the column map of a known data set; RecordingError names the known ones."""
    if name not in PRESETS:
        msg = f'unknown column preset {name!r}; known presets: {", ".join(sorted(PRESETS))}'
        raise RecordingError(msg)
    return PRESETS[name]


def _time_source(value: str, item: str):
    name, colon, scale_text = value.rpartition(':')
    if not colon:
        return value, 1.0
    try:
        scale = float(scale_text)
    except ValueError:
        scale = math.nan
    if not (math.isfinite(scale) and scale > 0):
        msg = (f'column map {item!r}: the time scale after ":" must be a positive number '
               f'(seconds per unit, e.g. 1e-6 for microseconds)')
        raise RecordingError(msg)
    return name, scale


def _delimiter_option(value: str, item: str) -> str:
    delimiter = _DELIMITER_NAMES.get(value.lower(), value)
    if len(delimiter) != 1:
        msg = (f'column map {item!r}: delimiter must be tab, comma, semicolon or one '
               f'character')
        raise RecordingError(msg)
    return delimiter


def _skip_rows_option(value: str, item: str) -> int:
    if not value.isdigit():
        msg = f'column map {item!r}: skip_rows must be an integer >= 0'
        raise RecordingError(msg)
    return int(value)


def parse_column_map(spec: str) -> ColumnMap:
    """
    Read a column map from its command-line form.

    Parameters
    ----------
    spec
        Comma-separated ``canonical=source`` pairs that override the default
        map, e.g. ``time=timestamp:1e-6,temperature=imu.temperature,gyro_z=gz``.
        Canonical names: time, temperature, gyro_x|y|z, ref_x|y|z, acc_x|y|z,
        temperature_2. Only time takes a scale after ``:`` (seconds per unit).
        An empty source (``acc_x=``) leaves an optional column out. Options:
        ``delimiter=tab|comma|semicolon|<char>`` and ``skip_rows=N``. Every
        column named in the spec must be in the file; a default mapping whose
        column the spec gives to another canonical column is dropped.

    Returns
    -------
    ColumnMap
        The map; RecordingError says what is wrong with a bad spec.

    """
    sources = ColumnMap().sources()
    options = {}
    named = set()
    parsers = {'delimiter': _delimiter_option, 'skip_rows': _skip_rows_option}
    items = [item.strip() for item in str(spec).split(',')]
    if not any(items):
        msg = 'column map is empty; expected canonical=source pairs such as time=t_us:1e-6'
        raise RecordingError(msg)
    for item in items:
        key, equals, value = (part.strip() for part in item.partition('='))
        if not equals or not key:
            msg = f'column map item {item!r} is not canonical=source'
            raise RecordingError(msg)
        if key in named:
            msg = f'column map names {key} twice'
            raise RecordingError(msg)
        named.add(key)
        if key in parsers:
            options[key] = parsers[key](value, item)
        elif key not in CANONICAL_COLUMNS:
            msg = (f'column map: unknown column {key!r}; use one of '
                   f'{", ".join(CANONICAL_COLUMNS + tuple(parsers))}')
            raise RecordingError(msg)
        elif not value:
            if key in _ALWAYS_REQUIRED:
                msg = f'column map item {item!r}: {key} needs a column name'
                raise RecordingError(msg)
            sources.pop(key, None)
            named.discard(key)
        elif key == 'time':
            sources['time'], options['time_scale'] = _time_source(value, item)
        else:
            sources[key] = value
    required = frozenset(named & set(CANONICAL_COLUMNS))
    claimed = {sources[key] for key in required}
    sources = {key: name for key, name in sources.items()
               if key in required or key in _ALWAYS_REQUIRED or name not in claimed}
    return _map_from_sources(sources, required=required, **options)


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


def _read_csv_rows(path: Path, delimiter: Optional[str]):
    """Give the header, the data rows (lists of cells) and their line numbers; skip blanks."""
    try:
        with path.open(newline='', encoding='utf-8-sig') as stream:
            line = stream.readline()
            header_line = 1
            while line and not line.strip():
                line = stream.readline()
                header_line += 1
            if not line:
                msg = f'{path} is empty'
                raise RecordingError(msg)
            if '\0' in line:
                msg = f'{path} is not a text CSV file (it holds NUL bytes)'
                raise RecordingError(msg)
            line = line.rstrip('\r\n')
            if delimiter is None:
                delimiter = max('\t,;', key=line.count)
            header = [name.strip() for name in next(csv.reader([line], delimiter=delimiter))]
            reader = csv.reader(stream, delimiter=delimiter)
            rows, lines = [], []
            for row in reader:
                if row:
                    rows.append(row)
                    lines.append(header_line + reader.line_num)
    except UnicodeDecodeError:
        msg = f'{path} is not a text CSV file (not UTF-8)'
        raise RecordingError(msg) from None
    except csv.Error as err:
        msg = f'{path} is not a readable CSV file: {err}'
        raise RecordingError(msg) from None
    except OSError as err:
        msg = f'cannot read {path}: {err.strerror or err}'
        raise RecordingError(msg) from None
    return header, rows, np.array(lines, dtype=np.int64)


def _pick_columns(path: Path, header: list, columns: ColumnMap) -> Dict[str, int]:
    """Map each canonical column found in the header to its index; check what is missing."""
    index = {}
    missing = []
    for canonical, name in columns.sources().items():
        positions = [i for i, column in enumerate(header) if column == name]
        if len(positions) > 1:
            msg = f'{path}: column {name!r} appears {len(positions)} times in the header'
            raise RecordingError(msg)
        if positions:
            index[canonical] = positions[0]
        elif canonical in columns.required:
            missing.append(repr(name))
    gyro_axes = [a for a in AXES if f'gyro_{a}' in index]
    if not gyro_axes:
        missing.append('one of ' + ', '.join(repr(n) for n in columns.gyro.values()))
    if missing:
        fitting = [name for name, preset in PRESETS.items()
                   if set(preset.sources().values()) <= set(header)]
        hint = f"; preset {', '.join(map(repr, fitting))} reads it" if fitting else ''
        msg = (f'{path}: missing columns {", ".join(missing)}; the file has '
               f'{", ".join(repr(n) for n in header)}{hint}')
        raise RecordingError(msg)
    reference_axes = [a for a in gyro_axes if f'ref_{a}' in index]
    if reference_axes and reference_axes != gyro_axes:
        absent = ', '.join(repr(columns.reference.get(a, f'ref_{a}'))
                           for a in gyro_axes if a not in reference_axes)
        msg = (f'{path}: reference columns cover gyro axes {", ".join(reference_axes)} but '
               f'not {absent}; a reference needs every gyro axis')
        raise RecordingError(msg)
    for a in AXES:
        if a not in gyro_axes:
            index.pop(f'ref_{a}', None)
    acceleration = [f'acc_{a}' for a in AXES if f'acc_{a}' in index]
    if 0 < len(acceleration) < len(AXES):
        msg = (f'{path}: acceleration needs acc_x, acc_y and acc_z; the file has only '
               f'{", ".join(repr(columns.acceleration[n[-1]]) for n in acceleration)}')
        raise RecordingError(msg)
    return index


def _parse_cells(cells: np.ndarray):
    """Give the float64 values of string cells and the mask of cells that are not numbers."""
    values = np.empty(cells.shape, dtype=np.float64)
    non_numeric = np.zeros(cells.shape, dtype=bool)
    for j in range(cells.shape[1]):
        try:
            values[:, j] = cells[:, j].astype(np.float64)
        except ValueError:
            for i, cell in enumerate(cells[:, j]):
                try:
                    values[i, j] = float(cell)
                except ValueError:
                    values[i, j] = math.nan
                    non_numeric[i, j] = True
    return values, non_numeric


def load_csv(path: PathLike, columns: ColumnMap = ColumnMap()) -> Recording:
    """
    Load a CSV recording (one header row, then one sample per row).

    Parameters
    ----------
    path
        The file.
    columns
        Which column feeds each canonical column, and parsing options.

    Returns
    -------
    Recording
        Rows with a non-numeric, NaN or inf cell in a used column, and rows
        whose time repeats or goes backwards, are dropped and counted.

    Raises
    ------
    RecordingError
        The file cannot be read, a required column is missing, or no row is
        usable.

    """
    path = Path(path)
    header, rows, lines = _read_csv_rows(path, columns.delimiter)
    if not rows:
        msg = f'{path} has a header but no data rows'
        raise RecordingError(msg)
    index = _pick_columns(path, header, columns)
    skipped = {}
    if columns.skip_rows:
        skipped[SKIP_PRESET] = min(columns.skip_rows, len(rows))
        rows, lines = rows[columns.skip_rows:], lines[columns.skip_rows:]
    positions = list(index.values())
    width = max(positions) + 1
    getter = operator.itemgetter(*positions)
    cells = np.array([getter(row) if len(row) >= width
                      else tuple(row[i] if i < len(row) else '' for i in positions)
                      for row in rows], dtype=str).reshape(len(rows), len(positions))
    values, non_numeric_cells = _parse_cells(cells)
    non_numeric = non_numeric_cells.any(axis=1)
    if rows and non_numeric.all():
        used = ', '.join(repr(header[i]) for i in positions)
        msg = (f'{path}: no row has numbers in every used column ({used}); '
               f'is the delimiter right and are the values plain numbers?')
        raise RecordingError(msg)
    data = dict(zip(index, values.T))
    data['time'] = data['time'] * columns.time_scale
    return _recording(str(path), data, non_numeric, skipped, _RowNames('line', lines))


def _bag_message(path: PathLike, err: BagError) -> str:
    text = str(err)
    return text if str(path) in text else f'bag {path}: {text}'


def _read_bag(bag: RawBagReader, path: Path, temperature_topic: str):
    """Give the IMU records in bag order, temperature and supply by stamp, skip counts."""
    imu = []
    temperatures = {}
    supply = {}
    skipped = {}
    for _, _, record in bag.records():
        if isinstance(record, ImuRecord):
            imu.append(record)
        elif isinstance(record, SupplyVoltageRecord):
            supply[record.stamp_ns] = record.voltage_v
        elif isinstance(record, TemperatureRecord):
            if record.stamp_ns in temperatures:
                skipped[SKIP_DUPLICATED_TIME] = skipped.get(SKIP_DUPLICATED_TIME, 0) + 1
            else:
                temperatures[record.stamp_ns] = record.temperature_c
    if bag.skipped:
        skipped[SKIP_CORRUPT] = bag.skipped
    if not temperatures:
        present = ', '.join(f'{t} ({m})' for t, m in bag.bag_topics.items())
        msg = (f'bag {path} has no message on temperature topic '
               f'{absolute_topic(temperature_topic)}; the bag has: {present}')
        raise RecordingError(msg)
    return imu, temperatures, supply, skipped


def load_bag(path: PathLike, imu_topic: str = '/imu/data',
             temperature_topic: str = '/imu/temperature',
             supply_voltage_topic: str = '/imu/supply_voltage') -> Recording:
    """
    Load a rosbag2 recording (folder, or a bare .db3 or .mcap file).

    Parameters
    ----------
    path
        The bag.
    imu_topic, temperature_topic, supply_voltage_topic
        ``sensor_msgs/Imu``, ``sensor_msgs/Temperature`` and
        ``sensor_msgs/BatteryState`` topics; a leading slash is optional.

    Returns
    -------
    Recording
        Messages paired by exact header stamp; time from the stamps. Unpaired
        messages are counted in ``skipped``. Axes are those whose angular
        velocity is finite in some paired message (NaN marks an unmeasured
        axis). Acceleration is included unless a message flags it unreported
        (``linear_acceleration_covariance[0] == -1``). With messages on the
        supply-voltage topic, each sample has the latest voltage stamped at or
        before it (or the first one); samples more than 5 s from any voltage
        are skipped and counted.

    Raises
    ------
    RecordingError
        The bag cannot be read, lacks a topic, or nothing pairs.

    """
    path = Path(path)
    try:
        with RawBagReader(path, RawTopics(imu=imu_topic, temperature=temperature_topic,
                                          supply_voltage=supply_voltage_topic)) as bag:
            imu, temperatures, supply, skipped = _read_bag(bag, path, temperature_topic)
    except BagError as err:
        raise RecordingError(_bag_message(path, err)) from None
    stamps_ns = np.array([record.stamp_ns for record in imu], dtype=np.int64)
    paired = np.array([stamp in temperatures for stamp in stamps_ns.tolist()], dtype=bool)
    if not paired.any():
        msg = (f'bag {path}: no message on {absolute_topic(imu_topic)} has a temperature on '
               f'{absolute_topic(temperature_topic)} with the same header stamp '
               f'({len(imu)} IMU and {len(temperatures)} temperature messages)')
        raise RecordingError(msg)
    imu = [record for record, used in zip(imu, paired) if used]
    stamps_ns = stamps_ns[paired]
    imu_numbers = np.flatnonzero(paired) + 1
    used_stamps = set(stamps_ns.tolist())
    unpaired = {SKIP_IMU_UNPAIRED: int(np.count_nonzero(~paired)),
                SKIP_TEMPERATURE_UNPAIRED: len(temperatures) - len(used_stamps)}
    skipped.update((reason, count) for reason, count in unpaired.items() if count)
    supply_v = None
    if supply:
        held = sorted(supply)
        supply_v, usable = zero_order_hold(stamps_ns, held, [supply[s] for s in held],
                                           SUPPLY_MAX_AGE_NS)
        if not usable.all():
            skipped[SKIP_NO_SUPPLY] = int(np.count_nonzero(~usable))
            imu = [record for record, used in zip(imu, usable) if used]
            imu_numbers = imu_numbers[usable]
            stamps_ns, supply_v = stamps_ns[usable], supply_v[usable]
            if not imu:
                msg = (f'bag {path}: no IMU message within 5 s of a supply voltage on '
                       f'{absolute_topic(supply_voltage_topic)}')
                raise RecordingError(msg)
    rate_rad_s = np.array([record.angular_velocity_rad_s for record in imu])
    axes = [i for i in range(3) if np.isfinite(rate_rad_s[:, i]).any()]
    if not axes:
        msg = f'bag {path}: no finite angular velocity on {absolute_topic(imu_topic)}'
        raise RecordingError(msg)
    seconds = (stamps_ns // _NS_PER_S).astype(np.float64)
    columns = {'time': seconds + (stamps_ns % _NS_PER_S) * 1e-9,
               'temperature': np.array([temperatures[s] for s in stamps_ns.tolist()])}
    columns.update((f'gyro_{AXES[i]}', rate_rad_s[:, i]) for i in axes)
    if all(record.linear_acceleration_covariance[0] != -1 for record in imu):
        acceleration = np.array([record.linear_acceleration_m_s2 for record in imu])
        columns.update((f'acc_{a}', acceleration[:, i]) for i, a in enumerate(AXES))
    if supply_v is not None:
        columns['supply_voltage'] = supply_v
    return _recording(str(path), columns, np.zeros(len(imu), dtype=bool), skipped,
                      _RowNames(f'{absolute_topic(imu_topic)} message', imu_numbers))


def recording_from_columns(source: str, columns: Dict[str, np.ndarray],
                           skipped: Mapping[str, int], noun: str) -> Recording:
    """
    Build a Recording from canonical columns of one row per sample, as the loaders do.

    Rows with a non-finite or implausible value are dropped and counted on top
    of ``skipped``; ``noun`` names a row in messages (e.g. 'IMU sample').
    """
    rows = len(columns['time'])
    return _recording(source, dict(columns), np.zeros(rows, dtype=bool), dict(skipped),
                      _RowNames(noun, np.arange(1, rows + 1)))


def load_recording(path: PathLike, *, columns: Union[ColumnMap, str, None] = None,
                   preset: Optional[str] = None, imu_topic: str = '/imu/data',
                   temperature_topic: str = '/imu/temperature',
                   supply_voltage_topic: str = '/imu/supply_voltage',
                   instance: Optional[int] = None) -> Recording:
    """
    Load a recording: a bag, a flight-controller log or a CSV file, by the path's extension.

    A folder, ``.db3`` or ``.mcap`` is a bag; ``.ulg`` or ``.bin`` a
    flight-controller log, of which IMU ``instance`` is read (default: the
    first usable one, see `load_flight_log`); anything else is CSV.

    ``columns`` (a ColumnMap or its command-line form) or ``preset`` (a name
    in PRESETS) say how to read a CSV file; the default map reads the
    canonical columns. They do not apply to bags, whose topics are given by
    ``imu_topic``, ``temperature_topic`` and ``supply_voltage_topic``.
    """
    path = Path(path)
    if is_flight_log(path) and not path.is_dir():
        if columns is not None or preset is not None:
            msg = f'{path} is a flight-controller log: a column map or preset applies to CSV'
            raise RecordingError(msg)
        return load_flight_log(path, instance)[0]
    if path.is_dir() or path.suffix.lower() in BAG_SUFFIXES:
        if columns is not None or preset is not None:
            msg = f'{path} is a rosbag2 bag: a column map or preset applies to CSV files only'
            raise RecordingError(msg)
        return load_bag(path, imu_topic, temperature_topic, supply_voltage_topic)
    if columns is not None and preset is not None:
        msg = f'{path}: give a column map or a preset, not both'
        raise RecordingError(msg)
    if preset is not None:
        columns = column_preset(preset)
    elif isinstance(columns, str):
        columns = parse_column_map(columns)
    return load_csv(path, ColumnMap() if columns is None else columns)


def load_flight_log(path: PathLike, instance: Optional[int] = None) -> tuple:
    """
    Load one IMU instance of a PX4 ULog or ArduPilot DataFlash log as a Recording.

    Returns the Recording (the instance's still samples; moving ones and
    those without a temperature counted in ``skipped``), the whole
    `flightlog.FlightLog` and the `flightlog.ImuInstance` used. Raises
    RecordingError when the log cannot be read or the instance cannot be used.
    """
    try:
        log = read_flight_log(path)
        used, data, skipped = instance_columns(log, instance)
    except FlightLogError as err:
        raise RecordingError(str(err)) from None
    if not data['time'].size:
        msg = f'{path}: {used.label}: no still sample with a temperature'
        raise RecordingError(msg)
    source = f'{path} [{used.label}]'
    return recording_from_columns(source, data, skipped, f'{used.name} sample'), log, used
