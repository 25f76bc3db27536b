"""
Which CSV column feeds each canonical column of a recording: column maps, presets, their text.

CSV files have one header row. Canonical columns: ``time`` (s),
``temperature`` (degC), any of ``gyro_x``, ``gyro_y``, ``gyro_z`` (rad/s);
optional ``ref_x|y|z`` (turntable reference rate, rad/s), ``acc_x|y|z``
(m/s^2), ``temperature_2`` (degC) and ``supply_voltage`` (V). A `ColumnMap`
names the file's column for each (`parse_column_map` reads the command-line
form); `PRESETS` holds the maps of known data sets (`column_preset`). The
delimiter (tab, comma or semicolon) is detected from the header unless the map
sets it. A map that is wrong raises `RecordingError` saying what is wrong.
"""

from dataclasses import dataclass, field
import functools
import math
from types import MappingProxyType
from typing import Dict, Mapping, Optional

from .recording import AXES, RecordingError

_GROUPS = (('gyro', 'gyro'), ('reference', 'ref'), ('acceleration', 'acc'))
CANONICAL_COLUMNS = (('time', 'temperature')
                     + tuple(f'{prefix}_{a}' for _, prefix in _GROUPS for a in AXES)
                     + ('temperature_2', 'supply_voltage'))
_ALWAYS_REQUIRED = ('time', 'temperature')
# Optional columns of one value per row, by canonical name.
_SINGLE_COLUMNS = ('temperature_2', 'supply_voltage')
_DELIMITER_NAMES = {'tab': '\t', 'comma': ',', 'semicolon': ';'}


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
