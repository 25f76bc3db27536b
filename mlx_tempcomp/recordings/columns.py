"""
Which CSV column feeds each canonical column of a recording: column maps, presets, their text.

CSV files have one header row. Canonical columns: ``time`` (s),
``temperature`` (degC), any of ``gyro_x``, ``gyro_y``, ``gyro_z`` (rad/s);
optional ``ref_x|y|z`` (turntable reference rate, rad/s), ``acc_x|y|z``
(m/s^2), ``temperature_2`` (degC) and ``supply_voltage`` (V). A `ColumnMap`
names the file's column for each, and the factor that brings it to the canonical
unit (`parse_column_map` reads the command-line form, ``gyro_z=gz:0.0174533``
for a column in deg/s); `PRESETS` holds the maps of known data sets (`column_preset`). The
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


def _scale(name, value) -> float:
    """Check a column's scale: finite and non-zero, positive for the time."""
    if name not in CANONICAL_COLUMNS:
        msg = f'column map: a scale for unknown column {name!r}'
        raise RecordingError(msg)
    try:
        scale = float(value)
    except (TypeError, ValueError):
        scale = math.nan
    if not (math.isfinite(scale) and (scale > 0 if name == 'time' else scale != 0)):
        what = 'a positive number' if name == 'time' else 'a non-zero number'
        msg = f'column map: the scale of {name} must be {what}, got {value!r}'
        raise RecordingError(msg)
    return scale


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
    acceleration is read only as all three axes. ``scales`` multiplies a
    column into its canonical unit, by canonical name: ``{'time': 1e-6}`` for
    microseconds, ``{'gyro_z': 0.0174533}`` for deg/s, -1 to flip an axis; a
    column not named is taken as it is (``time_scale`` is the time's). ``delimiter``
    None detects tab, comma or semicolon from the header. ``skip_rows`` data
    rows are dropped at the start (counted as ``SKIP_PRESET``).
    """

    time: str = 'time'
    scales: Mapping[str, float] = field(default_factory=dict)
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
        object.__setattr__(self, 'scales', MappingProxyType(
            {name: _scale(name, value) for name, value in dict(self.scales).items()}))
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
        unscaled = sorted(set(self.scales) - set(self.sources()))
        if unscaled:
            msg = f'column map: a scale for columns not mapped: {", ".join(unscaled)}'
            raise RecordingError(msg)

    @property
    def time_scale(self) -> float:
        """Give the factor from the time column to seconds."""
        return self.scale('time')

    def scale(self, canonical: str) -> float:
        """Give the factor from the file's column of ``canonical`` to its canonical unit."""
        return self.scales.get(canonical, 1.0)

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
        scales={'time': 1e-6}, delimiter='\t', skip_rows=1,
        required=frozenset(f'{prefix}_{a}' for prefix in ('gyro', 'acc') for a in AXES)),
})


def column_preset(name: str) -> ColumnMap:
    """Give the column map of a known data set; RecordingError names the known ones."""
    if name not in PRESETS:
        msg = f'unknown column preset {name!r}; known presets: {", ".join(sorted(PRESETS))}'
        raise RecordingError(msg)
    return PRESETS[name]


# What a scale after ":" brings each column to, for the messages.
_UNITS = {'time': 'seconds per unit, e.g. 1e-6 for microseconds',
          'temperature': 'degC per unit', 'temperature_2': 'degC per unit',
          'gyro': 'rad/s per unit, e.g. 0.0174533 for deg/s',
          'ref': 'rad/s per unit, e.g. 0.0174533 for deg/s',
          'acc': 'm/s^2 per unit, e.g. 9.80665 for g', 'supply_voltage': 'V per unit'}


def _scaled_source(key: str, value: str, item: str) -> tuple:
    """Give the column name and scale of ``name[:scale]`` (scale None when not given)."""
    name, colon, scale_text = value.rpartition(':')
    if not colon:
        return value, None
    try:
        scale = float(scale_text)
    except ValueError:
        scale = math.nan
    if not name:
        msg = f'column map {item!r}: {key} needs a column name before ":"'
        raise RecordingError(msg)
    positive = key == 'time'
    if not (math.isfinite(scale) and (scale > 0 if positive else scale != 0)):
        unit = _UNITS.get(key, _UNITS.get(key.rsplit('_', 1)[0]))
        msg = (f'column map {item!r}: the {key} scale after ":" must be a '
               f'{"positive" if positive else "non-zero"} number ({unit})')
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
        temperature_2, supply_voltage. Each takes a scale after ``:``, the
        factor to its canonical unit: seconds, degC, rad/s (``gyro_z=gz:0.0174533``
        for deg/s, ``gyro_y=gy:-1`` to flip an axis), m/s^2, V; the time's must
        be positive, the others non-zero.
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
    scales = {}
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
        else:
            sources[key], scale = _scaled_source(key, value, item)
            if scale is not None:
                scales[key] = scale
    required = frozenset(named & set(CANONICAL_COLUMNS))
    claimed = {sources[key] for key in required}
    sources = {key: name for key, name in sources.items()
               if key in required or key in _ALWAYS_REQUIRED or name not in claimed}
    return _map_from_sources(sources, required=required, scales=scales, **options)
