"""
The fleet job on Dask against a sequential loop of the single-record command, same run.

``mlx-tempcomp simulate --fleet N`` writes N units (one axis, one -20..70 C
cycle at 3 C/min sampled at 0.5 Hz, a 60 s thermal lag varying unit to
unit; about 1350 rows each). Then, each in a fresh interpreter:

- ``sequential``: one process calls ``mlx-tempcomp diagnose`` (cli.main) on
  every unit in turn: the shell loop the fleet job replaces;
- ``fleet 1 worker`` and ``fleet 2 workers``: ``mlx-tempcomp fleet diagnose
  --workers W`` on the manifest (a LocalCluster: start-up, scheduling, files
  back through the client, and the fleet report are all in the time).

Per-unit overhead is (fleet 1 worker - sequential) / N against the sequential
time per unit: everything the fleet machinery adds, fixed costs included.
Client peak RSS (VmHWM of the client process; the workers are other
processes) is measured with ``fleet fit --options='--order 2'`` (cheap units,
so the client's own cost shows) at --rss-units counts, the records reused
under distinct unit ids. Targets (issue 16): overhead under 5 %; 2 workers
at least 1.8x one worker on a 2-core machine; client peak RSS within 20 %
from 50 to 500 units. Nothing is asserted: the figures are printed.

    .venv/bin/python bench/bench_fleet.py [--units 200] [--rss-units 50 500]
"""

import argparse
from pathlib import Path
import subprocess
import sys
import tempfile
import time

TARGET_OVERHEAD = 0.05
TARGET_SPEEDUP = 1.8
TARGET_RSS_GROWTH = 0.20

SEQUENTIAL = r"""
import contextlib, csv, io, sys
from pathlib import Path
from mlx_tempcomp.cli import main
manifest, out = Path(sys.argv[1]), Path(sys.argv[2])
out.mkdir()
for row in csv.DictReader(open(manifest)):
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(['diagnose', str(manifest.parent / row['path']), '--out',
                     str(out / row['unit'])])
    assert code == 0, row
"""

CLIENT_RSS = r"""
import contextlib, io, sys
from mlx_tempcomp.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    code = main(sys.argv[1:])
assert code == 0, code
status = open('/proc/self/status').read()
print(int(status.split('VmHWM:')[1].split()[0]) / 1024.0)
"""


def timed(argv: list) -> float:
    """Run ``argv`` to completion (output discarded); give its wall time in seconds."""
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def verdict(met: bool) -> str:
    return 'met' if met else 'NOT met'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--units', type=int, default=200)
    parser.add_argument('--rss-units', type=int, nargs=2, default=(50, 500))
    args = parser.parse_args()
    python = sys.executable
    cli = [python, '-m', 'mlx_tempcomp.cli']
    with tempfile.TemporaryDirectory(prefix='bench-fleet-') as folder:
        folder = Path(folder)
        fleet = folder / 'fleet'
        seconds = timed([*cli, 'simulate', '--fleet', str(args.units), '--out', str(fleet),
                         '--axes', 'z', '--cycle-c', '70', '-20', '--ramp-c-per-min', '3',
                         '--rate-hz', '0.5', '--thermal-lag-s', '60'])
        print(f'simulated {args.units} units in {seconds:.1f} s')
        manifest = fleet / 'units.csv'
        sequential = timed([python, '-c', SEQUENTIAL, str(manifest), str(folder / 'seq')])
        one = timed([*cli, 'fleet', 'diagnose', '--manifest', str(manifest), '--out',
                     str(folder / 'w1'), '--workers', '1'])
        two = timed([*cli, 'fleet', 'diagnose', '--manifest', str(manifest), '--out',
                     str(folder / 'w2'), '--workers', '2'])
        per_unit = sequential / args.units
        overhead = (one - sequential) / args.units
        print(f'  sequential diagnose loop  {sequential:8.1f} s  ({per_unit:.3f} s per unit)')
        print(f'  fleet, 1 worker           {one:8.1f} s')
        print(f'  fleet, 2 workers          {two:8.1f} s')
        print(f'  per-unit overhead (1 worker - sequential) / units: {overhead:+.3f} s = '
              f'{overhead / per_unit:+.1%} of a unit (target < {TARGET_OVERHEAD:.0%}: '
              f'{verdict(overhead / per_unit < TARGET_OVERHEAD)})')
        print(f'  2 workers / 1 worker speed-up: {one / two:.2f}x (target >= '
              f'{TARGET_SPEEDUP}x: {verdict(one / two >= TARGET_SPEEDUP)})')
        records = [line.split(',')[1] for line in manifest.read_text().splitlines()[1:]]
        peaks = []
        for count in args.rss_units:
            rss_manifest = folder / f'rss-{count}.csv'
            rss_manifest.write_text('unit,path\n' + ''.join(
                f'u{k:04d},{fleet / records[k % len(records)]}\n' for k in range(count)))
            start = time.perf_counter()
            done = subprocess.run(
                [python, '-c', CLIENT_RSS, 'fleet', 'fit', '--manifest', str(rss_manifest),
                 '--out', str(folder / f'rss-{count}'), '--workers', '2',
                 '--options=--order 2'], check=True, capture_output=True, text=True)
            peaks.append(float(done.stdout.split()[-1]))
            print(f'  client peak RSS, fleet fit of {count:4d} units: {peaks[-1]:7.1f} MB '
                  f'({time.perf_counter() - start:.1f} s)')
        growth = peaks[-1] / peaks[0] - 1.0
        print(f'  client peak RSS growth {args.rss_units[0]} -> {args.rss_units[1]} units: '
              f'{growth:+.1%} (target within {TARGET_RSS_GROWTH:.0%}: '
              f'{verdict(abs(growth) <= TARGET_RSS_GROWTH)})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
