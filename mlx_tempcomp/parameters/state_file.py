"""
Calibration state on disk: written atomically, checked when read back at start.

A write (`atomic_write`, the one writer of every file the package keeps as
state or writes as a result) goes to a temporary file ``.<name>.<random>.tmp``
in the same folder, is given mode `FILE_MODE`, flushed and fsynced, then
renamed over the old file (rename is atomic on POSIX), and the folder is
fsynced. A crash at any point leaves either the old or the new file, whole; a
kill before the rename also leaves the temporary file, which `load_state`
removes at the next start. The rename replaces whatever has the name: a
symbolic link planted there is replaced by the new file, never followed (the
file it points to is left as it is).

`load_state` is what every user of a state file calls at start: it removes
those leftovers, reads the file and checks each of its `Field` s (type,
finite, within bounds, list lengths). A file that fails is logged at ERROR
with the reason and moved aside to ``<file>.bad-<UTC stamp>`` (never over an
earlier one), and the caller runs without it; its next save writes a fresh
file. A damaged file (not YAML, not a mapping, a key missing: what a
truncation leaves) and a wrong value are told apart in the log; whether a
whole, valid file belongs to the running model is the caller's question.
"""

import contextlib
from dataclasses import dataclass
from datetime import datetime, timezone
import glob
import math
import os
import reprlib
import tempfile
from typing import Optional, Tuple, Union

import yaml

from ..errors import MlxTempCompError


# libyaml's emitter where PyYAML has it: the same text, a third of the time (the field
# learner's section holds some 3000 numbers, written while the stream waits).
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


class StateFileError(MlxTempCompError):
    """The state file cannot be read or written, or holds what its user cannot use."""


@dataclass(frozen=True)
class Field:
    """
    One key of a state file and what its value must be.

    ``kind`` is 'text', 'integer' or 'number' (finite; an integer is taken), or
    'section' (any value: a nested section its user checks, so that a bad one is
    refused apart from the rest of the file). ``length`` makes it a list: of
    that many items, of (fewest, most), or as long as the list under the key it
    names (an earlier field). Numbers must lie in [``low``, ``high``]; text, if
    ``choices`` are given, be one of them. Fields of one ``group`` are there
    together or not at all: a file may hold a section it did not need yet (a
    file written before the section existed still loads); a field without a
    group must be there.
    """

    key: str
    kind: str
    length: Union[int, Tuple[int, int], str, None] = None
    low: float = -math.inf
    high: float = math.inf
    choices: Tuple[str, ...] = ()
    group: str = ''


# rw-r--r--: the owner (the node's user) alone may change a calibration; anyone may read it
# (calibration numbers are no secret, and a diagnostics account or a technician reads them).
# Set explicitly, whatever the umask: the docs (docs/ros.md) promise this mode.
FILE_MODE = 0o644


def atomic_write(path, text: str, mode: int = FILE_MODE) -> None:
    """
    Replace the file at ``path`` with ``text``, atomically; OSError on failure.

    The new file has permissions ``mode`` whatever the umask, from its first
    byte on. A symbolic link at ``path`` is replaced, not followed. The
    temporary file is removed on every exception, interruptions included.
    """
    path = os.path.abspath(path)
    folder = os.path.dirname(path)
    descriptor, temporary = tempfile.mkstemp(prefix='.' + os.path.basename(path) + '.',
                                             suffix='.tmp', dir=folder)
    try:
        try:
            os.fchmod(descriptor, mode)
            data = text.encode()
            while data:
                data = data[os.write(descriptor, data):]
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    folder_descriptor = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(folder_descriptor)
    finally:
        os.close(folder_descriptor)


def write_state(path: str, state: dict) -> None:
    """Replace the YAML file at ``path`` with ``state``, atomically; StateFileError."""
    try:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        atomic_write(path, yaml.dump(state, Dumper=_DUMPER, sort_keys=False))
    except OSError as err:
        msg = f'cannot write state file {path}: {err.strerror}'
        raise StateFileError(msg) from None


def parse_state(data: bytes) -> dict:
    """Return the mapping in a state file's ``data``; StateFileError saying how it is damaged."""
    try:
        state = yaml.safe_load(data.decode('utf-8'))
    except UnicodeDecodeError:
        raise StateFileError('damaged: not UTF-8 text') from None
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = f' at line {mark.line + 1}' if mark is not None else ''
        problem = getattr(err, 'problem', None) or type(err).__name__
        raise StateFileError(f'damaged: not valid YAML{where} ({problem})') from None
    except (ValueError, OverflowError) as err:
        # A tagged or implicit value its constructor refuses: a date 2026-13-45, !!int abc.
        raise StateFileError(f'damaged: not valid YAML ({err})') from None
    except RecursionError:
        raise StateFileError('damaged: not valid YAML (nested too deeply)') from None
    if not isinstance(state, dict):
        kind = 'empty' if state is None else f'a {type(state).__name__}, not a mapping'
        raise StateFileError(f'damaged: {kind}')
    return state


def _read_bytes(path: str):
    """Return the bytes of ``path``, None when there is no such file; StateFileError."""
    try:
        with open(path, 'rb') as state_file:
            return state_file.read()
    except FileNotFoundError:
        return None
    except OSError as err:
        msg = f'cannot read state file {path}: {err.strerror}'
        raise StateFileError(msg) from None


def read_state(path: str):
    """Return the state dict at ``path``, or None when there is no file yet."""
    data = _read_bytes(path)
    if data is None:
        return None
    try:
        return parse_state(data)
    except StateFileError as err:
        raise StateFileError(f'state file {path} is {err}') from None


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_item(field: Field, name: str, value):
    if field.kind == 'section':
        return value
    if field.kind == 'text':
        if not isinstance(value, str):
            raise StateFileError(f'{name} must be text, got {reprlib.repr(value)}')
        if field.choices and value not in field.choices:
            raise StateFileError(f'{name} must be one of {", ".join(field.choices)}, got '
                                 f'{reprlib.repr(value)}')
        return value
    if field.kind == 'integer' and not (isinstance(value, int) and not isinstance(value, bool)):
        raise StateFileError(f'{name} must be an integer, got {reprlib.repr(value)}')
    if not _is_number(value):
        raise StateFileError(f'{name} must be a number, got {reprlib.repr(value)}')
    if not math.isfinite(value):
        raise StateFileError(f'{name} must be finite, got {reprlib.repr(value)}')
    if not field.low <= value <= field.high:
        raise StateFileError(f'{name} {reprlib.repr(value)} is outside {field.low:g} to '
                             f'{field.high:g}')
    return value if field.kind == 'integer' else float(value)


def check_state(state: dict, fields) -> dict:
    """
    Return the values of ``fields`` in ``state``; StateFileError naming the first wrong one.

    A missing key says "missing" (a truncated or hand-cut file), and so does a
    file with none of the fields; keys beyond ``fields`` are left out, and so are
    the fields of a group the file does not hold.
    """
    groups = {field.group for field in fields if field.group and field.key in state}
    held = [field for field in fields if not field.group or field.group in groups]
    missing = [field.key for field in held if field.key not in state] if held else \
        [field.key for field in fields]
    fields = held
    if missing:
        msg = f'damaged: {", ".join(missing)} missing (truncated?)'
        raise StateFileError(msg)
    values = {}
    for field in fields:
        value = state[field.key]
        if field.length is None:
            values[field.key] = _check_item(field, field.key, value)
            continue
        fewest = most = field.length if isinstance(field.length, int) else \
            len(values[field.length]) if isinstance(field.length, str) else None
        if fewest is None:
            fewest, most = field.length
        if not isinstance(value, list) or not fewest <= len(value) <= most:
            count = fewest if fewest == most else f'{fewest} to {most}'
            msg = f'{field.key} must be a list of {count} values, got {reprlib.repr(value)}'
            raise StateFileError(msg)
        values[field.key] = [_check_item(field, f'{field.key}[{index}]', item)
                             for index, item in enumerate(value)]
    return values


def remove_leftovers(path: str) -> list:
    """Remove the temporary files an interrupted write of ``path`` left; return their paths."""
    folder, name = os.path.split(os.path.abspath(path))
    removed = []
    for leftover in sorted(glob.glob(os.path.join(glob.escape(folder),
                                                  '.' + glob.escape(name) + '.*.tmp'))):
        try:
            os.unlink(leftover)
        except FileNotFoundError:
            continue
        removed.append(leftover)
    return removed


def move_aside(path: str, keep: bool = False) -> str:
    """
    Rename ``path`` to ``<path>.bad-<UTC stamp>``, never over an earlier one; return it.

    A hard link then an unlink: the link fails rather than replace a file of
    the same name (rename would replace it), and the file always has a name.
    With ``keep`` the file keeps its name too (a copy for the record, while
    the part of it still in use stays; the next atomic write replaces the name,
    not the copy).
    """
    stamp = datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')
    for attempt in range(1000):
        target = f'{path}.bad-{stamp}' + (f'-{attempt}' if attempt else '')
        try:
            os.link(path, target)
        except FileExistsError:
            continue
        if not keep:
            os.unlink(path)
        return target
    raise FileExistsError(f'{path}.bad-{stamp}-*')


def reject_state(path: str, reason: str, logger, what: str) -> None:
    """Log at ERROR why the state file at ``path`` is unusable and move it aside."""
    try:
        where = f'moved aside to {move_aside(path)}'
    except OSError as err:
        where = f'cannot move it aside ({err.strerror or err}), left in place'
    logger.error(f'{what} in {path} unusable: {reason}; {where}; starting without it')


def load_state(path: str, fields, logger, what: str) -> Optional[dict]:
    """
    Give the checked ``fields`` of the state file at ``path``; None when there is none usable.

    Removes leftover temporary files of ``path`` first (a WARN names them).
    No file is no state, not logged here; a file that cannot be used is
    logged at ERROR with the reason and moved aside (`reject_state`).
    ``what`` names the state in the log ("saved ZRO offset"); ``logger``
    needs warning and error (rclpy's and Python's have them).
    """
    try:
        removed = remove_leftovers(path)
    except OSError as err:
        logger.warning(f'cannot remove temporary files an interrupted save of {path} left: '
                       f'{err}')
        removed = []
    if removed:
        logger.warning(f'removed {len(removed)} temporary file(s) an interrupted save of '
                       f'{path} left: {", ".join(os.path.basename(p) for p in removed)}')
    try:
        data = _read_bytes(path)
    except StateFileError as err:
        logger.error(f'{err}; starting without {what}')
        return None
    if data is None:
        return None
    try:
        return check_state(parse_state(data), fields)
    except StateFileError as err:
        reject_state(path, str(err), logger, what)
        return None
