"""
Where ``mlx-tempcomp fleet diagnose`` spends its time beyond the units' own work, on a small fleet.

``mlx-tempcomp simulate --fleet N`` (bench_fleet.py's units), then in this
process a sequential loop of ``mlx-tempcomp diagnose`` over them, then
``mlx-tempcomp fleet diagnose --workers W`` with the fleet's public steps
wrapped to time them: `run_unit` on the worker (its wall and CPU time, the
CPU of its own thread, the single-record command's handler, the design
moments for the prior, the parsing), `store_unit` on the client, the fleet
report and the fleet prior. CPU times are what a loaded machine cannot blur:
the process CPU of a task beyond its thread's is the worker's other threads
(event loop, heartbeats, monitors; Dask's statistical profiler when on).
Nothing is asserted: the figures are printed.

    .venv/bin/python bench/profile_fleet.py [--units 20] [--workers 1]
"""

import argparse
import contextlib
import csv
import io
import os
from pathlib import Path
import resource
import subprocess
import sys
import tempfile
import time

from mlx_tempcomp.cli import main as cli_main
import mlx_tempcomp.fleet.command as command
import mlx_tempcomp.fleet.run as run


def timed_run_unit(job):
    """Run a unit as the fleet does; add how its time was spent to the outcome."""
    import mlx_tempcomp.fleet.unit as unit
    spent = {'handler': 0.0, 'moments': 0.0, 'parse': 0.0}

    def timed(name, function):
        def call(*args):
            start = time.perf_counter()
            try:
                return function(*args)
            finally:
                spent[name] += time.perf_counter() - start
        return call

    parse, load, moments = unit.parse_command, unit.load, unit.record_moments

    def parse_and_time_handler(argv):
        args = timed('parse', parse)(argv)
        args.handler = timed('handler', args.handler)
        return args

    # The moments read the record again (load) and summarise it (record_moments).
    unit.parse_command = parse_and_time_handler
    unit.load, unit.record_moments = timed('moments', load), timed('moments', moments)
    spent['start'] = time.time()
    wall, cpu, thread = time.perf_counter(), time.process_time(), time.thread_time()
    try:
        outcome = unit.run_unit(job)
    finally:
        unit.parse_command, unit.load, unit.record_moments = parse, load, moments
    spent.update(task=time.perf_counter() - wall, task_cpu=time.process_time() - cpu,
                 thread_cpu=time.thread_time() - thread, pid=os.getpid(),
                 bytes=sum(len(data) for data in outcome['files'].values()))
    outcome['timing'] = spent
    return outcome


def sequential(manifest: Path, out: Path) -> tuple:
    """Diagnose every unit in turn here; give (first unit s, then s and CPU s per unit)."""
    out.mkdir()
    times = []
    for row in csv.DictReader(manifest.open()):
        wall, cpu = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(io.StringIO()):
            code = cli_main(['diagnose', str(manifest.parent / row['path']), '--out',
                             str(out / row['unit'])])
        if code:
            sys.exit(f'diagnose {row["path"]}: exit code {code}')
        times.append((time.perf_counter() - wall, time.process_time() - cpu))
    rest = times[1:]
    return (times[0][0], sum(t for t, _ in rest) / len(rest),
            sum(c for _, c in rest) / len(rest))


def profile_fleet(manifest: Path, out: Path, workers: int) -> None:
    """Run fleet diagnose with its steps timed; print where the time went."""
    timings, stores, marks = [], [], {}
    store, report, prior = run.store_unit, command.write_fleet_report, command.write_fleet_prior

    def timed_store(job, outcome):
        start = time.perf_counter()
        store(job, outcome)
        stores.append(time.perf_counter() - start)
        timings.append(outcome['timing'])

    def timed(name, function):
        def call(*args):
            start = time.perf_counter()
            result = function(*args)
            marks[name] = time.perf_counter() - start
            return result
        return call

    run.run_unit, run.store_unit = timed_run_unit, timed_store
    command.write_fleet_report = timed('report', report)
    command.write_fleet_prior = timed('prior', prior)
    before = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    start_wall, start_clock, start_thread = time.perf_counter(), time.time(), time.thread_time()
    with contextlib.redirect_stdout(io.StringIO()):
        code = cli_main(['fleet', 'diagnose', '--manifest', str(manifest), '--out', str(out),
                         '--workers', str(workers)])
    wall = time.perf_counter() - start_wall
    after = resource.getrusage(resource.RUSAGE_SELF)
    after_children = resource.getrusage(resource.RUSAGE_CHILDREN)
    client_cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    workers_cpu = after_children.ru_utime + after_children.ru_stime - \
        children.ru_utime - children.ru_stime
    n = len(timings)
    first = {}
    for timing in sorted(timings, key=lambda t: t['start']):
        first.setdefault(timing['pid'], timing)
    steady = [t for t in timings if all(t is not f for f in first.values())]

    def mean(key: str) -> float:
        return sum(t[key] for t in steady) / len(steady)
    print(f'fleet diagnose, {workers} worker(s): exit code {code}, {n} units in {wall:.1f} s; '
          f'CPU: client {client_cpu:.1f} s (main thread {time.thread_time() - start_thread:.1f}'
          f' s), workers and nannies {workers_cpu:.1f} s')
    started = min(t['start'] for t in timings) - start_clock
    print(f'  cluster start to the first task: {started:.2f} s; first task of each worker: '
          + ', '.join(f'{t["task"]:.2f} s (handler {t["handler"]:.2f} s)'
                      for t in first.values()))
    rest = mean('task') - mean('handler') - mean('moments') - mean('parse')
    print(f'  per unit on a worker after its first: {mean("task"):.3f} s wall, CPU '
          f'{mean("task_cpu"):.3f} s of the process, {mean("thread_cpu"):.3f} s of the task '
          f'thread; handler {mean("handler"):.3f} s, design moments (the record read again) '
          f'{mean("moments") * 1e3:.1f} ms, parse {mean("parse") * 1e3:.1f} ms, the rest '
          f'(temporary folder, files back) {rest * 1e3:.1f} ms; {mean("bytes") / 1e3:.0f} kB '
          'of files')
    print(f'  client: store_unit {sum(stores) / n * 1e3:.1f} ms per unit; fleet report '
          f'{marks["report"]:.2f} s; fleet prior {marks["prior"]:.2f} s')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--units', type=int, default=20)
    parser.add_argument('--workers', type=int, default=1)
    args = parser.parse_args()
    print(f'load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores')
    with tempfile.TemporaryDirectory(prefix='profile-fleet-') as folder:
        folder = Path(folder)
        subprocess.run([sys.executable, '-m', 'mlx_tempcomp.cli', 'simulate', '--fleet',
                        str(args.units), '--out', str(folder / 'fleet'), '--axes', 'z',
                        '--cycle-c', '70', '-20', '--ramp-c-per-min', '3', '--rate-hz', '0.5',
                        '--thermal-lag-s', '60'], check=True, stdout=subprocess.DEVNULL)
        manifest = folder / 'fleet' / 'units.csv'
        first, per_unit, cpu = sequential(manifest, folder / 'sequential')
        print(f'sequential diagnose loop: first unit {first:.2f} s (imports), then '
              f'{per_unit:.3f} s per unit, CPU {cpu:.3f} s per unit')
        profile_fleet(manifest, folder / 'fleet-out', args.workers)
    print(f'load average {os.getloadavg()[0]:.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
