"""
A fleet job on a Dask cluster: one task per unit, results stored as they arrive.

The cluster is an in-process `LocalCluster` (one single-threaded worker
process per core by default), or an existing one named by ``--scheduler`` or
``DASK_SCHEDULER_ADDRESS``, connected to (over TLS with the client's
certificates, `connection`) before anything is written. Only unit names and
options are sent; each worker opens its records itself and returns the
unit's files, which the client stores in ``OUT/units/<unit>/`` by renaming a
complete temporary folder into place, so a unit folder is whole or absent. A
unit whose ``unit.json`` says it finished with the same command, records and
options is skipped (unless ``force``): a rerun, or a run after Ctrl-C, picks
up where the last stopped. A worker lost mid-task costs nothing but time:
the scheduler runs the task again elsewhere (up to
``distributed.scheduler.allowed-failures``). Dask is imported inside the
functions, so importing this module loads none of it.
"""

from dataclasses import asdict, dataclass
import json
import logging
import os
from pathlib import Path
import shutil
import uuid

from .connection import check_local, scheduler_client, TlsOptions
from .unit import LOG_FILE, one_line, run_unit, UNIT_FILE, UnitJob
from ..toolkit.outputs import staged_outputs
from ..toolkit.progress import Progress
from ..toolkit.running import write_json

UNITS_FOLDER = 'units'
SCHEDULER_VARIABLE = 'DASK_SCHEDULER_ADDRESS'
# The local cluster's workers: Dask's statistical profiler (a stack sample every 10 ms) off,
# and the event loop's tick and monitors slowed, since each wake-up takes the interpreter
# lock from the unit's task (docs/fleet.md, "Where the fleet's time goes").
WORKER_SETTINGS = {
    'distributed.worker.profile.enabled': False,
    'distributed.admin.tick.interval': '1s',
    'distributed.worker.memory.monitor-interval': '1s',
    'distributed.admin.system-monitor.interval': '5s',
}


@dataclass(frozen=True)
class FleetRun:
    """What a run did: units done now, skipped as finished before, failed (unit, reason)."""

    done: tuple
    skipped: tuple
    failed: tuple
    interrupted: bool


def unit_entry(job: UnitJob, status: str, error=None) -> dict:
    """
    Give the content of a unit's unit.json.

    ``results``: the folder of each run of the command (`UnitJob.runs`) and
    the records it ran on: the unit's folder and all its records for
    ``diagnose``, ``record-K`` per record for ``fit`` on several.
    """
    return {'unit': job.unit.unit, 'status': status, 'error': error, 'command': job.command,
            'options': list(job.options),
            'records': [asdict(record) for record in job.unit.records],
            'results': [{'folder': job.run_folder(run),
                         'records': [job.unit.records[index].path for index in indices]}
                        for run, indices in enumerate(job.runs())],
            'log': LOG_FILE}


def finished(job: UnitJob) -> bool:
    """Say whether the unit's folder holds a finished run of this very job."""
    try:
        entry = json.loads((Path(job.folder) / UNIT_FILE).read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return False
    return entry == unit_entry(job, 'ok')


def store_unit(job: UnitJob, outcome: dict) -> None:
    """Put a unit's files (or its error entry) in its folder: a whole folder, renamed in."""
    with staged_outputs() as outputs:
        staging = outputs.folder(job.folder)
        for name, data in outcome['files'].items():
            target = staging / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        write_json(staging / UNIT_FILE, unit_entry(job, outcome['status'], outcome['error']))


def _clear_leftovers(units: Path) -> None:
    """Remove staging folders a killed client left behind (names starting with a dot)."""
    for path in units.glob('.*'):
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)


def connect(scheduler, workers, tls=TlsOptions()):
    """
    Connect to ``scheduler`` or start a LocalCluster; give (client, cluster or None).

    ``tls``: the client's certificates given as options (`connection`); a
    refused connection, a bad certificate or no answer is one UserError line.
    """
    import dask
    from dask.distributed import Client, LocalCluster
    address = scheduler or os.environ.get(SCHEDULER_VARIABLE)
    if address:
        return scheduler_client(address, tls), None
    check_local(tls)
    # One thread per worker process: the commands are numpy and Python, and a worker
    # process runs one unit at a time anyway (unit._ONE_AT_A_TIME). No dashboard; the
    # scheduler's HTTP server, started regardless, takes a free local port: on Dask's
    # default one, a job beside another Dask cluster warned that the port was in use.
    with dask.config.set(WORKER_SETTINGS):
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=None,
                               scheduler_kwargs={'dashboard_address': '127.0.0.1:0'},
                               silence_logs=logging.ERROR)
    return Client(cluster), cluster


def run_fleet(jobs: list, *, scheduler=None, workers=None, force=False, progress=None,
              tls=TlsOptions()) -> FleetRun:
    """
    Run ``jobs`` (UnitJobs) on a Dask cluster; store each unit as it completes.

    The cluster is connected to first: a refused connection (UserError)
    leaves nothing written. ``progress`` None shows the progress line when
    stderr is a terminal. Ctrl-C stops the run: what finished is kept, the
    rest is marked interrupted (rerun to resume).
    """
    from dask.distributed import as_completed
    skipped = tuple(job.unit.unit for job in jobs if not force and finished(job))
    pending = {job.unit.unit: job for job in jobs if job.unit.unit not in skipped}
    if not pending:
        return FleetRun((), skipped, (), False)
    client, cluster = connect(scheduler, workers, tls)
    done, failed = [], []
    label = 'fleet {command}: {done} done, {failed} failed, {remaining} remaining'
    interrupted = False
    try:
        Path(jobs[0].folder).parent.mkdir(parents=True, exist_ok=True)
        _clear_leftovers(Path(jobs[0].folder).parent)
        with Progress(len(pending), '', progress) as bar:
            def show() -> None:
                bar.label = label.format(command=jobs[0].command, done=len(done),
                                         failed=len(failed),
                                         remaining=len(pending) - len(done) - len(failed))
                bar.update(len(done) + len(failed))
            show()
            run_id = uuid.uuid4().hex[:8]
            futures = {client.submit(run_unit, job, key=f'fleet-{run_id}-{unit}', pure=False):
                       unit for unit, job in pending.items()}
            for future in as_completed(futures):
                unit = futures.pop(future)
                try:
                    outcome = future.result()
                except Exception as err:  # a task Dask gave up on (KilledWorker): this unit's
                    outcome = {'unit': unit, 'status': 'error', 'files': {},
                               'error': f'{type(err).__name__}: {one_line(err)}'}
                future.release()
                store_unit(pending[unit], outcome)
                if outcome['status'] == 'ok':
                    done.append(unit)
                else:
                    failed.append((unit, outcome['error']))
                show()
    except KeyboardInterrupt:
        interrupted = True
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return FleetRun(tuple(done), skipped, tuple(failed), interrupted)
