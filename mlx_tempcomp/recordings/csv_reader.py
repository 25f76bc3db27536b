"""CSV recordings: one header row, then one sample per row, read through a `ColumnMap`."""

import csv
import math
import operator
from pathlib import Path
from typing import Dict, Optional

import numpy as np

from .columns import ColumnMap, PRESETS
from .recording import (AXES, PathLike, Recording, recording_from_columns, RecordingError,
                        SKIP_PRESET)


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
    data = {name: column * columns.scale(name) if name in columns.scales else column
            for name, column in zip(index, values.T)}
    return recording_from_columns(str(path), data, skipped, 'line', lines, non_numeric)


def load_csv_column(path: PathLike, name: str, columns: ColumnMap = ColumnMap()) -> tuple:
    """
    Read one more column of a CSV recording, beside its time: (time_s, cells, line numbers).

    The file is read as `load_csv` reads it (delimiter, ``skip_rows``, the time column and
    its scale); ``cells`` are the column's text. `RecordingError` names a missing column.
    """
    path = Path(path)
    header, rows, lines = _read_csv_rows(path, columns.delimiter)
    wanted = {}
    for canonical, column in (('time', columns.time), ('extra', name)):
        positions = [i for i, cell in enumerate(header) if cell == column]
        if len(positions) != 1:
            what = 'appears more than once in' if positions else 'is not in'
            msg = (f'{path}: column {column!r} {what} the header '
                   f'({", ".join(repr(n) for n in header)})')
            raise RecordingError(msg)
        wanted[canonical] = positions[0]
    rows, lines = rows[columns.skip_rows:], lines[columns.skip_rows:]
    cells = np.array([[row[i] if i < len(row) else '' for i in wanted.values()] for row in rows],
                     dtype=str).reshape(len(rows), 2)
    time_s, non_numeric = _parse_cells(cells[:, :1])
    time_s = np.where(non_numeric[:, 0], math.nan, time_s[:, 0] * columns.time_scale)
    return time_s, cells[:, 1], lines
