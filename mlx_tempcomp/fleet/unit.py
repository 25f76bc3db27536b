"""
One unit of a fleet job, as a Dask worker runs it: the single-record command on its records.

`run_unit` parses the same argument list ``mlx-tempcomp diagnose|fit`` would
get and calls that command's handler, so a unit's files are those of the
command on the same records (one code path): ``diagnose A B ...`` over all of
a unit's records at once (one model, each record its own history and bias
offset), ``fit`` once per record (it takes one). The records are opened here,
on the worker: a local or shared path as it is, an fsspec URL through a local
cache. The command writes into a temporary folder; its files come back as
bytes for the client to store under ``OUT/units/<unit>/`` (so the workers
need no view of OUT), with the temporary paths and cached copies in their
text replaced by where the files will live and the records' own names. A
record the command refuses gives the unit an error entry with the command's
one-line reason. Beside the command's files, `MOMENTS_FILE` summarises each
record for the fleet prior (`core.fitting.pooling.record_moments`), so the prior never
reads a record again. No Dask in here.
"""

import argparse
import contextlib
from dataclasses import dataclass
import io
import json
from pathlib import Path
import tempfile
import threading

from .manifest import is_url, OPTIONAL_COLUMNS, RecordSpec, UnitSpec
from ..core.fitting import record_moments
from ..errors import MlxTempCompError
from ..toolkit import diagnose, fit
from ..toolkit.loading import load, read_options, ReadOptions
from ..toolkit.running import run_handler

COMMANDS = ('diagnose', 'fit')
# The commands that fit one model over several records of a unit.
SEVERAL_RECORDS = frozenset({'diagnose'})
UNIT_FILE = 'unit.json'
LOG_FILE = 'log.txt'
MOMENTS_FILE = 'design_moments.json'
# Files whose text may name the temporary folder or the cached copy of a URL.
_TEXT_SUFFIXES = ('.yaml', '.md', '.txt', '.json')
# pyplot and redirected stdout are per process: a worker process runs one unit at a time.
_ONE_AT_A_TIME = threading.Lock()


class UnitError(MlxTempCompError):
    """A unit the command refused, or whose records cannot run as one; a one-line reason."""


@dataclass(frozen=True)
class UnitJob:
    """What a worker needs for one unit: names and options only, never record data."""

    command: str
    unit: UnitSpec
    options: tuple
    folder: str

    def runs(self) -> tuple:
        """
        Give the record indices of each run of the command on this unit.

        ``diagnose`` fits one model over all of a unit's records (one run),
        ``fit`` takes one record (a run per record).
        """
        indices = tuple(range(len(self.unit.records)))
        return (indices,) if self.command in SEVERAL_RECORDS else tuple((k,) for k in indices)

    def run_folder(self, run: int) -> str:
        """Give the sub-folder of run ``run`` ('' for a unit of one run, else record-K)."""
        return '' if len(self.runs()) == 1 else f'record-{run + 1}'


def single_record_parser() -> argparse.ArgumentParser:
    """Give a parser of ``diagnose`` and ``fit`` exactly as ``mlx-tempcomp`` adds them."""
    parser = argparse.ArgumentParser(prog='mlx-tempcomp')
    commands = parser.add_subparsers(dest='command', required=True)
    diagnose.add_parser(commands)
    fit.add_parser(commands)
    return parser


def command_argv(command: str, record_paths: list, out: str, record_options: list,
                 options) -> list:
    """Give the argument list of the single-record command on ``record_paths``."""
    target = out if command == 'diagnose' else str(Path(out) / 'params.yaml')
    return [command, *record_paths, '--out', target, *record_options, *options]


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


def _moments(options: ReadOptions, local: str) -> dict:
    """Give one record's design moments for the fleet prior, or why there are none."""
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            recording = load(local, options)
        return {'moments': record_moments(recording.time_s, recording.temperature_c,
                                          recording.rate_error_rad_s, recording.axes)}
    except MlxTempCompError as err:
        return {'error': one_line(err)}


def _read_option(record: RecordSpec, name: str) -> str:
    value = getattr(record, name)
    return f'{name} {value!r}' if value is not None else f'no {name}'


def _read_options(job: UnitJob, indices: tuple) -> list:
    """
    Give the read options of the records of one run; UnitError when their rows differ.

    ``diagnose A B`` reads its records with one set of options; a unit whose
    manifest rows differ would need a run per record, which is not one model.
    """
    first = job.unit.records[indices[0]]
    for index in indices[1:]:
        other = job.unit.records[index]
        for name in OPTIONAL_COLUMNS:
            if getattr(other, name) != getattr(first, name):
                msg = (f'unit {job.unit.unit}: {other.path} has {_read_option(other, name)}, '
                       f'{first.path} {_read_option(first, name)}: {job.command} reads the '
                       f'records of a unit with one {name}; give its rows the same, or make '
                       'them units of their own')
                raise UnitError(msg)
    return first.options()


class _Names:
    """Replace the worker's temporary names (output folder, cached copies) in a text."""

    def __init__(self, names: dict):
        self.names = sorted(((old, new) for old, new in names.items() if old != new),
                            key=lambda pair: -len(pair[0]))

    def __call__(self, text: str) -> str:
        for old, new in self.names:
            text = text.replace(old, new)
        return text


def _run(job: UnitJob, run: int, work: Path, files: dict, moments: dict) -> None:
    """
    Run the command once on the records of run ``run``, in ``work``.

    Add its files to ``files`` and each record's design moments to
    ``moments`` (by record index).
    """
    indices = job.runs()[run]
    records = [job.unit.records[index] for index in indices]
    record_options = _read_options(job, indices)
    locals_ = [_local_copy(record.path, work / 'cache') for record in records]
    out = work / f'out-{run}'
    out.mkdir()
    args = parse_command(command_argv(job.command, locals_, str(out), record_options,
                                      job.options))
    folder = job.run_folder(run)
    named = _Names({str(out): str(Path(job.folder) / folder),
                    **{local: record.path for local, record in zip(locals_, records)}})
    log = io.StringIO()
    try:
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            run_handler(args)
    except MlxTempCompError as err:
        raise UnitError(named(str(err))) from None
    except Exception as err:  # a crash of the command is this unit's, in the user's names
        raise UnitError(named(f'{type(err).__name__}: {one_line(err)}')) from None
    (out / LOG_FILE).write_text(log.getvalue(), encoding='utf-8')
    for index, local in zip(indices, locals_):
        found = _moments(read_options(args), local)
        moments[index] = {key: named(value) if key == 'error' else value
                          for key, value in found.items()}
    for path in sorted(out.rglob('*')):
        if not path.is_file():
            continue
        data = path.read_bytes()
        if path.suffix in _TEXT_SUFFIXES:
            data = named(data.decode('utf-8')).encode('utf-8')
        files[str(Path(folder) / path.relative_to(out))] = data


def run_unit(job: UnitJob) -> dict:
    """
    Run the command on a unit's records (`UnitJob.runs`); give its outcome.

    The outcome: ``unit``, ``status`` ('ok' or 'error'), ``error`` (one line,
    naming the record, or the records of the run when it is about none in
    particular) and ``files`` ({path in the unit folder: bytes}, empty on
    error), among them `MOMENTS_FILE`: each record's design moments, in the
    unit's order.
    """
    files, moments = {}, {}
    with _ONE_AT_A_TIME, tempfile.TemporaryDirectory(prefix='mlx-fleet-') as work:
        for run, indices in enumerate(job.runs()):
            paths = [job.unit.records[index].path for index in indices]
            try:
                _run(job, run, Path(work), files, moments)
            except MlxTempCompError as err:
                error = str(err)
            except Exception as err:  # any failure is this unit's, not the fleet's
                error = f'{type(err).__name__}: {one_line(err)}'
            else:
                continue
            if not any(path in error for path in paths):
                error = f'{", ".join(paths)}: {error}'
            return {'unit': job.unit.unit, 'status': 'error', 'error': error, 'files': {}}
    files[MOMENTS_FILE] = json.dumps({'records': [
        {'path': record.path, **moments[index]}
        for index, record in enumerate(job.unit.records)]}).encode('utf-8')
    return {'unit': job.unit.unit, 'status': 'ok', 'error': None, 'files': files}
