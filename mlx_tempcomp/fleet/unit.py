"""
One unit of a fleet job, as a Dask worker runs it: the single-record command on each record.

`run_unit` parses the same argument list ``mlx-tempcomp diagnose|fit`` would
get and calls that command's handler, so a unit's files are those of the
single-record command on the same record (one code path). The record is
opened here, on the worker: a local or shared path as it is, an fsspec URL
through a local cache. The command writes into a temporary folder; its files
come back as bytes for the client to store under ``OUT/units/<unit>/``
(so the workers need no view of OUT), with the temporary paths in their text
replaced by where the files will live. A record the command refuses gives the
unit an error entry with the command's one-line reason. Beside the command's
files, each record's `MOMENTS_FILE` summarises it for the fleet prior
(`core.pooling.record_moments`), so the prior never reads a record again. No
Dask in here.
"""

import argparse
import contextlib
from dataclasses import dataclass
import io
import json
from pathlib import Path
import tempfile
import threading

from .manifest import is_url, UnitSpec
from ..core.pooling import record_moments
from ..errors import MlxTempCompError
from ..toolkit import diagnose, fit
from ..toolkit.common import load

COMMANDS = ('diagnose', 'fit')
UNIT_FILE = 'unit.json'
LOG_FILE = 'log.txt'
MOMENTS_FILE = 'design_moments.json'
# Files whose text may name the temporary folder or the cached copy of a URL.
_TEXT_SUFFIXES = ('.yaml', '.md', '.txt', '.json')
# pyplot and redirected stdout are per process: a worker process runs one unit at a time.
_ONE_AT_A_TIME = threading.Lock()


class UnitError(MlxTempCompError):
    """A record of a unit the single-record command refused; its one-line reason."""


@dataclass(frozen=True)
class UnitJob:
    """What a worker needs for one unit: names and options only, never record data."""

    command: str
    unit: UnitSpec
    options: tuple
    folder: str

    def record_folder(self, index: int) -> str:
        """Give the sub-folder of the unit's record ``index`` ('' for a unit of one record)."""
        return '' if len(self.unit.records) == 1 else f'record-{index + 1}'


def single_record_parser() -> argparse.ArgumentParser:
    """Give a parser of ``diagnose`` and ``fit`` exactly as ``mlx-tempcomp`` adds them."""
    parser = argparse.ArgumentParser(prog='mlx-tempcomp')
    commands = parser.add_subparsers(dest='command', required=True)
    diagnose.add_parser(commands)
    fit.add_parser(commands)
    return parser


def command_argv(command: str, record_path: str, out: str, record_options: list,
                 options) -> list:
    """Give the argument list of the single-record command on one record."""
    target = out if command == 'diagnose' else str(Path(out) / 'params.yaml')
    return [command, record_path, '--out', target, *record_options, *options]


def parse_command(argv: list) -> argparse.Namespace:
    """Parse a single-record command line; UnitError carries argparse's message."""
    errors = io.StringIO()
    try:
        with contextlib.redirect_stderr(errors):
            return single_record_parser().parse_args(argv)
    except SystemExit:
        lines = errors.getvalue().strip().splitlines()
        message = lines[-1] if lines else 'cannot parse the options'
        raise UnitError(message.replace('mlx-tempcomp diagnose: error: ', '')
                        .replace('mlx-tempcomp fit: error: ', '')) from None


def _local_copy(record: str, cache: Path) -> str:
    """Give a local path of the record: itself, or an fsspec URL's cached copy."""
    if not is_url(record):
        return record
    import fsspec
    try:
        return fsspec.open_local(f'simplecache::{record}',
                                 simplecache={'cache_storage': str(cache)})
    except Exception as err:  # fsspec backends raise their own classes
        msg = f'{record}: cannot fetch: {one_line(err)}'
        raise UnitError(msg) from None


def one_line(err: BaseException) -> str:
    """Give the first line of an exception's message (its class name when empty)."""
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


def _moments(args: argparse.Namespace) -> dict:
    """Give the record's design moments for the fleet prior, or why there are none."""
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            recording = load(args)
        rate = recording.gyro_rad_s if recording.reference_rad_s is None else \
            recording.gyro_rad_s - recording.reference_rad_s
        return record_moments(recording.time_s, recording.temperature_c, rate, recording.axes)
    except MlxTempCompError as err:
        return {'error': one_line(err)}


def _run_record(job: UnitJob, index: int, work: Path, files: dict) -> None:
    """Run the command on record ``index`` in ``work``; add its files to ``files``."""
    record = job.unit.records[index]
    out = work / f'out-{index}'
    out.mkdir()
    local = _local_copy(record.path, work / 'cache')
    args = parse_command(command_argv(job.command, local, str(out), record.options(),
                                      job.options))
    folder = job.record_folder(index)
    destination = str(Path(job.folder) / folder)
    log = io.StringIO()
    try:
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            args.handler(args)
    except MlxTempCompError as err:
        msg = str(err).replace(str(out), destination).replace(local, record.path)
        raise UnitError(msg) from None
    (out / LOG_FILE).write_text(log.getvalue(), encoding='utf-8')
    (out / MOMENTS_FILE).write_text(json.dumps(_moments(args)), encoding='utf-8')
    for path in sorted(out.rglob('*')):
        if not path.is_file():
            continue
        data = path.read_bytes()
        if path.suffix in _TEXT_SUFFIXES:
            data = data.decode('utf-8').replace(str(out), destination) \
                .replace(local, record.path).encode('utf-8')
        files[str(Path(folder) / path.relative_to(out))] = data


def run_unit(job: UnitJob) -> dict:
    """
    Run every record of a unit through the single-record command; give its outcome.

    The outcome: ``unit``, ``status`` ('ok' or 'error'), ``error`` (one line,
    naming the record) and ``files`` ({path in the unit folder: bytes}, empty
    on error).
    """
    files = {}
    with _ONE_AT_A_TIME, tempfile.TemporaryDirectory(prefix='mlx-fleet-') as work:
        for index, record in enumerate(job.unit.records):
            try:
                _run_record(job, index, Path(work), files)
            except MlxTempCompError as err:
                error = str(err)
            except Exception as err:  # any failure is this unit's, not the fleet's
                error = f'{record.path}: {type(err).__name__}: {one_line(err)}'
            else:
                continue
            if not error.startswith(record.path):
                error = f'{record.path}: {error}'
            return {'unit': job.unit.unit, 'status': 'error', 'error': error, 'files': {}}
    return {'unit': job.unit.unit, 'status': 'ok', 'error': None, 'files': files}
