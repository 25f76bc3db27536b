"""
Which records belong to which unit: a manifest CSV or a path pattern with ``{unit}``.

A manifest has the columns ``unit,path`` and optionally ``preset``,
``columns``, ``imu_topic``, ``temperature_topic`` (empty cells take the
command's defaults); a unit may have several rows, one per record. Relative
paths are taken from the manifest's folder. A pattern such as
``bags/{unit}/*.mcap`` is globbed (local paths, or fsspec URLs such as
``s3://bucket/{unit}/*.mcap``) and the unit id read from the matched path.
Only names travel: the records are opened later, by the worker that runs the
unit.
"""

import csv
from dataclasses import dataclass
import glob
from pathlib import Path
import re
from typing import Optional

from ..errors import MlxTempCompError

OPTIONAL_COLUMNS = ('preset', 'columns', 'imu_topic', 'temperature_topic')
UNIT_FIELD = '{unit}'
# A unit id names a folder under OUT/units/.
_UNIT_ID = re.compile(r'[A-Za-z0-9][A-Za-z0-9._-]*$')


class ManifestError(MlxTempCompError):
    """A manifest or records pattern that cannot be read; one line for the user."""


@dataclass(frozen=True)
class RecordSpec:
    """One record of a unit: its path or URL and how to read it (None: the default)."""

    path: str
    preset: Optional[str] = None
    columns: Optional[str] = None
    imu_topic: Optional[str] = None
    temperature_topic: Optional[str] = None

    def options(self) -> list:
        """Give the single-record command's options that read this record."""
        argv = []
        for name in OPTIONAL_COLUMNS:
            value = getattr(self, name)
            if value is not None:
                argv += ['--' + name.replace('_', '-'), value]
        return argv


@dataclass(frozen=True)
class UnitSpec:
    """A unit and its records, in manifest order."""

    unit: str
    records: tuple


def is_url(path: str) -> bool:
    """Say whether ``path`` is an fsspec URL (``s3://...``) rather than a local path."""
    return '://' in path


def _check_unit(unit: str, where: str) -> str:
    if not _UNIT_ID.match(unit):
        msg = (f'{where}: unit id {unit!r} must be letters, digits, ".", "_" or "-" '
               '(it names a folder)')
        raise ManifestError(msg)
    return unit


def _group(pairs) -> tuple:
    """Group (unit, RecordSpec) pairs into UnitSpecs, units in order of first appearance."""
    units = {}
    for unit, record in pairs:
        units.setdefault(unit, []).append(record)
    return tuple(UnitSpec(unit, tuple(records)) for unit, records in units.items())


def read_manifest(path) -> tuple:
    """Read a manifest CSV into UnitSpecs; ManifestError names the row at fault."""
    path = Path(path)
    try:
        with open(path, newline='', encoding='utf-8') as stream:
            rows = list(csv.DictReader(stream))
            header = rows[0].keys() if rows else ()
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        msg = f'--manifest {path}: {getattr(err, "strerror", None) or err}'
        raise ManifestError(msg) from None
    missing = [name for name in ('unit', 'path') if name not in header]
    if not rows or missing:
        msg = (f'--manifest {path}: needs a header with the columns unit,path and at least '
               'one row' + (f'; missing {", ".join(missing)}' if missing and rows else ''))
        raise ManifestError(msg)
    unknown = [name for name in header if name not in ('unit', 'path', *OPTIONAL_COLUMNS)]
    if unknown:
        msg = (f'--manifest {path}: unknown column {", ".join(map(repr, unknown))}; known: '
               f'unit, path, {", ".join(OPTIONAL_COLUMNS)}')
        raise ManifestError(msg)
    pairs = []
    for line, row in enumerate(rows, start=2):
        where = f'--manifest {path} line {line}'
        cells = {k: (v or '').strip() for k, v in row.items() if k is not None}
        if None in row or not cells['unit'] or not cells['path']:
            msg = f'{where}: needs a unit and a path, and no more cells than the header'
            raise ManifestError(msg)
        record = cells['path']
        if not is_url(record) and not Path(record).is_absolute():
            record = str(path.parent.resolve() / record)
        options = {name: cells.get(name) or None for name in OPTIONAL_COLUMNS}
        pairs.append((_check_unit(cells['unit'], where), RecordSpec(record, **options)))
    return _group(pairs)


def _pattern_regex(pattern: str) -> re.Pattern:
    """Turn a glob with one ``{unit}`` into a regex whose group ``unit`` is the unit id."""
    def part(text: str) -> str:
        return ''.join('[^/]*' if c == '*' else '[^/]' if c == '?' else re.escape(c)
                       for c in text)
    before, after = pattern.split(UNIT_FIELD)
    return re.compile(part(before) + '(?P<unit>[^/]+)' + part(after) + '$')


def find_records(pattern: str) -> tuple:
    """Glob a records pattern holding ``{unit}`` once; give the UnitSpecs it matches."""
    if pattern.count(UNIT_FIELD) != 1:
        msg = f"--records {pattern!r} must hold {UNIT_FIELD} once, e.g. 'bags/{UNIT_FIELD}/*.mcap'"
        raise ManifestError(msg)
    wildcard = pattern.replace(UNIT_FIELD, '*')
    if is_url(pattern):
        import fsspec
        filesystem, _ = fsspec.core.url_to_fs(wildcard)
        protocol = pattern.split('://', 1)[0]
        paths = [f'{protocol}://{p}' if not is_url(p) else p
                 for p in filesystem.glob(wildcard.split('://', 1)[1])]
    else:
        paths = glob.glob(wildcard)
    regex = _pattern_regex(pattern)
    pairs = []
    for found in sorted(paths):
        match = regex.match(found)
        if match:
            record = found if is_url(found) else str(Path(found).resolve())
            pairs.append((_check_unit(match['unit'], f'--records {found}'),
                          RecordSpec(record)))
    if not pairs:
        msg = f'--records {pattern!r}: no record matches'
        raise ManifestError(msg)
    return _group(pairs)
