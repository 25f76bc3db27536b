"""
``mlx-tempcomp fleet``: every unit through the single-record command on a real Dask cluster.

Records are CSV files of a two-cycle -20..70 C chamber run, one axis, a
quadratic bias whose coefficients differ unit to unit; one unit's slope is ten
times the others' (the outlier the report must flag), two records are bad (a
missing file, a file that is no CSV). One fleet run on a LocalCluster of two
workers serves most tests; the kill test starts a real ``dask scheduler`` and
two ``dask worker`` processes and kills one while units run.
"""

import contextlib
import io
import json
from pathlib import Path
import signal
import subprocess
import sys
import time

from mlx_tempcomp.cli import main
import numpy as np
import pytest

GOOD_UNITS = ('a1', 'a2', 'a3', 'a4', 'a5', 'odd')
BAD_UNITS = {'gone': 'missing.csv', 'junk': 'junk.csv'}
SLOPE_RAD_S_PER_C = 2e-4
ROWS = 600
# A unit of two records: one row per record in the report (one model: issue 15 item 3).
PAIR = ('a1.csv', 'a2.csv')
DASK = Path(sys.executable).with_name('dask')


def write_record(path: Path, seed: int, slope_factor: float = 1.0) -> str:
    """Write a CSV record of one gyro: two -20..70 C cycles, bias(T) of this unit, noise."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(ROWS) * 12.0
    phase = (2.0 * np.arange(ROWS) / ROWS) % 1.0
    temperature_c = 25.0 + 45.0 * (1.0 - 4.0 * np.abs(phase - 0.5)) + \
        rng.normal(0.0, 0.02, ROWS)
    slope = SLOPE_RAD_S_PER_C * slope_factor * (1.0 + 0.1 * rng.standard_normal())
    bias = 0.01 * (1.0 + 0.2 * rng.standard_normal()) + slope * (temperature_c - 25.0) + \
        2e-6 * (1.0 + 0.2 * rng.standard_normal()) * (temperature_c - 25.0) ** 2
    rate = bias + rng.normal(0.0, 5e-4, ROWS)
    np.savetxt(path, np.column_stack([time_s, temperature_c, rate]), delimiter=',',
               header='time,temperature,gyro_z', comments='', fmt='%.17g')
    return str(path)


def run_cli(argv: list) -> tuple:
    """Run mlx-tempcomp in this process; give (exit code, stdout, stderr)."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main([str(arg) for arg in argv])
    return code, stdout.getvalue(), stderr.getvalue()


@pytest.fixture(scope='module')
def records(tmp_path_factory) -> Path:
    """Write the records and the manifest; give their folder."""
    folder = tmp_path_factory.mktemp('records')
    rows = ['unit,path']
    for seed, unit in enumerate(GOOD_UNITS):
        write_record(folder / f'{unit}.csv', seed, 10.0 if unit == 'odd' else 1.0)
        rows.append(f'{unit},{unit}.csv')
    (folder / 'junk.csv').write_text('this is not\na recording\n', encoding='utf-8')
    rows += [f'{unit},{name}' for unit, name in BAD_UNITS.items()]
    rows += [f'pair,{name}' for name in PAIR]
    (folder / 'units.csv').write_text('\n'.join(rows) + '\n', encoding='utf-8')
    return folder


@pytest.fixture(scope='module')
def fleet_run(records, tmp_path_factory) -> tuple:
    """Run fleet diagnose over the manifest on a local cluster of two workers."""
    out = tmp_path_factory.mktemp('fleet') / 'out'
    result = run_cli(['fleet', 'diagnose', '--manifest', records / 'units.csv', '--out', out,
                      '--workers', 2, '--progress'])
    return out, result


def unit_files(folder: Path) -> dict:
    """Give {relative path: bytes} of a unit folder."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob('*'))
            if p.is_file()}


def test_fleet_unit_is_the_single_record_command(records, fleet_run, tmp_path):
    out, (code, _, _) = fleet_run
    single = tmp_path / 'single'
    assert run_cli(['diagnose', records / 'a1.csv', '--out', single])[0] == 0
    unit = out / 'units' / 'a1'
    fleet, alone = unit_files(unit), unit_files(single)
    assert set(fleet) == set(alone) | {'unit.json', 'log.txt'}
    assert json.loads(fleet['report.json']) == json.loads(alone['report.json'])
    for name in ('params.yaml', 'report.md'):
        assert fleet[name].decode() == alone[name].decode().replace(str(single), str(unit))
    assert fleet['residual_vs_temperature.png'] == alone['residual_vs_temperature.png']


def test_fleet_fit_is_the_single_record_command(records, tmp_path):
    out = tmp_path / 'out'
    # fsspec URLs: globbed by the client, fetched by the workers.
    url = f'file://{records}/{{unit}}.csv'
    code, stdout, stderr = run_cli(['fleet', 'fit', '--records', url, '--out', out,
                                    '--workers', 1, '--options=--max-order 3'])
    assert code == 1, 'junk.csv matches the pattern and fails'
    assert 'failed: junk: ' in stderr and 'junk.csv' in stderr
    single = tmp_path / 'a2.yaml'
    assert run_cli(['fit', records / 'a2.csv', '--out', single, '--max-order', 3])[0] == 0
    fleet = (out / 'units' / 'a2' / 'params.yaml').read_text()
    assert f'from file://{records}/a2.csv' in fleet
    assert fleet.replace('file://', '') == \
        single.read_text().replace(str(single), str(out / 'units/a2/params.yaml'))
    assert 'orders (chosen on held-out blocks' in (out / 'units' / 'a2' / 'log.txt').read_text()


def test_a_bad_record_is_its_units_error_and_the_rest_complete(fleet_run):
    out, (code, stdout, stderr) = fleet_run
    assert code == 1
    assert '9 units: 7 done, 0 finished before (skipped), 2 failed' in stdout
    assert '7 done, 2 failed, 0 remaining' in stderr, 'the progress line'
    assert 'failed: junk: ' in stderr
    fleet = json.loads((out / 'fleet.json').read_text())
    failed = {f['unit']: f['error'] for f in fleet['failed']}
    assert set(failed) == set(BAD_UNITS)
    for unit, name in BAD_UNITS.items():
        assert '\n' not in failed[unit] and name in failed[unit], failed[unit]
        entry = json.loads((out / 'units' / unit / 'unit.json').read_text())
        assert entry['status'] == 'error' and entry['error'] == failed[unit]
    assert 'No such file' in failed['gone'] or 'does not exist' in failed['gone']
    for unit in GOOD_UNITS:
        assert json.loads((out / 'units' / unit / 'unit.json').read_text())['status'] == 'ok'
        assert (out / 'units' / unit / 'params.yaml').exists()
    assert not [p for p in (out / 'units').iterdir() if p.name.startswith('.')]


def test_the_report_has_a_row_per_unit_and_flags_the_outlier(fleet_run):
    out = fleet_run[0]
    fleet = json.loads((out / 'fleet.json').read_text())
    assert [(r['unit'], r['record']) for r in fleet['records']] == \
        [(u, '') for u in GOOD_UNITS] + [('pair', 'record-1'), ('pair', 'record-2')]
    pair = out / 'units' / 'pair'
    for k, name in enumerate(PAIR, start=1):
        assert (pair / f'record-{k}' / 'report.json').read_text() == \
            (out / 'units' / name[:2] / 'report.json').read_text()
    for row in fleet['records']:
        assert row['held_out_rms_rad_s']['z'] > 0.0 and row['gain_over_cubic']['z'] > 0.0
        assert isinstance(row['effects']['z'], list)
    slopes = fleet['coefficients']['z']['slope_rad_s_per_c']
    assert slopes['units'] == len(GOOD_UNITS) + len(PAIR)
    assert 0.8 * SLOPE_RAD_S_PER_C < slopes['median'] < 1.3 * SLOPE_RAD_S_PER_C
    flagged = {(o['unit'], o['metric']) for o in fleet['outliers']}
    assert ('odd', 'slope_rad_s_per_c') in flagged
    assert {unit for unit, _ in flagged} == {'odd'}, fleet['outliers']
    markdown = (out / 'fleet.md').read_text()
    assert '| odd |' in markdown and 'slope_rad_s_per_c' in markdown
    assert 'issue 15 item 3' in markdown
    assert (out / 'fleet_coefficients.png').read_bytes()[:4] == b'\x89PNG'
    (out / 'fleet.json').unlink()
    assert run_cli(['fleet', 'report', '--out', out])[0] == 0
    assert json.loads((out / 'fleet.json').read_text()) == fleet


def test_a_rerun_skips_finished_units_and_force_redoes_them(records, fleet_run):
    out = fleet_run[0]
    manifest = records / 'units.csv'
    inode = {unit: (out / 'units' / unit / 'unit.json').stat().st_ino for unit in GOOD_UNITS}
    code, stdout, _ = run_cli(['fleet', 'diagnose', '--manifest', manifest, '--out', out])
    assert code == 1 and f'0 done, {len(GOOD_UNITS) + 1} finished before (skipped), 2 failed' \
        in stdout
    assert inode == {unit: (out / 'units' / unit / 'unit.json').stat().st_ino
                     for unit in GOOD_UNITS}
    one = records / 'a1_only.csv'
    one.write_text('unit,path\na1,a1.csv\n', encoding='utf-8')
    code, stdout, _ = run_cli(['fleet', 'diagnose', '--manifest', one, '--out', out,
                               '--workers', 1, '--force'])
    assert code == 0 and '1 units: 1 done, 0 finished before (skipped), 0 failed' in stdout
    assert (out / 'units' / 'a1' / 'unit.json').stat().st_ino != inode['a1']


def test_ctrl_c_keeps_what_finished_and_a_rerun_resumes(records, tmp_path):
    manifest = tmp_path / 'good.csv'
    manifest.write_text('unit,path\n' + ''.join(f'{u},{records / u}.csv\n' for u in GOOD_UNITS),
                        encoding='utf-8')
    out = tmp_path / 'out'
    run = subprocess.Popen([sys.executable, '-m', 'mlx_tempcomp.cli', 'fleet', 'diagnose',
                            '--manifest', manifest, '--out', out, '--workers', '1'],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Not a staging folder (.a1.xxxx): a Ctrl-C before its rename removes it.
        _wait_for(lambda: list(out.glob('units/[!.]*/unit.json')), 120.0, 'the first unit')
        run.send_signal(signal.SIGINT)
        stdout, stderr = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait(30)
    assert run.returncode == 130, stderr
    assert 'interrupted: rerun the same command to resume' in stdout
    finished = len(list(out.glob('units/[!.]*/unit.json')))
    assert 1 <= finished < len(GOOD_UNITS)
    code, stdout, _ = run_cli(['fleet', 'diagnose', '--manifest', manifest, '--out', out,
                               '--workers', 2])
    assert code == 0
    assert f'{len(GOOD_UNITS) - finished} done, {finished} finished before (skipped)' in stdout
    assert len(json.loads((out / 'fleet.json').read_text())['records']) == len(GOOD_UNITS)


def test_mistakes_are_one_line_errors(records, tmp_path):
    for argv, expected in (
            (['--manifest', tmp_path / 'none.csv'], 'none.csv: No such file'),
            (['--records', 'no_unit_field/*.csv'], 'must hold {unit} once'),
            (['--records', f'{tmp_path}/{{unit}}.csv'], 'no record matches'),
            (['--manifest', records / 'units.csv', '--options=--folds x'],
             "--folds: expected a non-negative integer, got 'x'"),
            (['--manifest', records / 'units.csv', '--options=--out here'],
             'belong to the fleet command')):
        code, _, stderr = run_cli(['fleet', 'diagnose', '--out', tmp_path / 'out', *argv])
        assert code == 2 and stderr.startswith('error: ') and expected in stderr, stderr
        assert stderr.count('\n') == 1
    code, _, stderr = run_cli(['fleet', 'report', '--out', tmp_path])
    assert code == 2 and stderr == f'error: --out {tmp_path}: no units/ folder; run ' \
        'mlx-tempcomp fleet diagnose or fit first\n'


def test_simulate_fleet_writes_units_a_manifest_and_the_truth(tmp_path):
    out = tmp_path / 'fleet'
    code, stdout, _ = run_cli(['simulate', '--fleet', 4, '--fleet-outliers', 1, '--out', out,
                               '--duration-s', 20, '--rate-hz', 2, '--axes', 'z',
                               '--thermal-lag-s', 60])
    assert code == 0 and 'wrote 4 units' in stdout
    truth = json.loads((out / 'fleet_truth.json').read_text())
    assert [u['unit'] for u in truth['units']] == [f'unit-00{k}' for k in range(4)]
    assert sum(u['outlier'] for u in truth['units']) == 1
    lags = [u['effects']['thermal_lag_s'] for u in truth['units']]
    assert len(set(lags)) == 4 and all(30.0 <= lag <= 90.0 for lag in lags)
    slopes = [json.loads((out / u['truth']).read_text())['devices']['z']
              ['zro_dps_coefficients'][1] for u in truth['units']]
    outlier = [s for s, u in zip(slopes, truth['units']) if u['outlier']][0]
    assert all(abs(outlier) > 0.1 > abs(s) for s, u in zip(slopes, truth['units'])
               if not u['outlier'])
    manifest = (out / 'units.csv').read_text().splitlines()
    assert manifest[0] == 'unit,path' and len(manifest) == 5


def _wait_for(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.1)


def test_a_killed_worker_costs_nothing(records, fleet_run, tmp_path):
    """A real scheduler and two workers; one is killed mid-run; the results are identical."""
    manifest = tmp_path / 'good.csv'
    manifest.write_text('unit,path\n' + ''.join(f'{u},{records / u}.csv\n' for u in GOOD_UNITS),
                        encoding='utf-8')
    scheduler_file = tmp_path / 'scheduler.json'
    started = []
    try:
        started.append(subprocess.Popen(
            [DASK, 'scheduler', '--host', '127.0.0.1', '--port', '0', '--no-dashboard',
             '--scheduler-file', scheduler_file], stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL))
        _wait_for(scheduler_file.exists, 60.0, 'the scheduler file')
        for name in ('w1', 'w2'):
            started.append(subprocess.Popen(
                [DASK, 'worker', '--scheduler-file', scheduler_file, '--nthreads', '1',
                 '--no-nanny', '--no-dashboard', '--name', name], stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL))
        address = json.loads(scheduler_file.read_text())['address']
        out = tmp_path / 'out'
        fleet = subprocess.Popen(
            [sys.executable, '-m', 'mlx_tempcomp.cli', 'fleet', 'diagnose', '--manifest',
             manifest, '--out', out, '--scheduler', address], stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True)
        started.append(fleet)
        _wait_for(lambda: len(list(out.glob('units/*/unit.json'))) >= 1, 120.0,
                  'the first unit')
        assert fleet.poll() is None, 'the run must still be going when the worker dies'
        started[1].send_signal(signal.SIGKILL)
        stdout, stderr = fleet.communicate(timeout=180)
        assert fleet.returncode == 0, stderr
        assert started[1].wait(10) == -signal.SIGKILL
        assert f'{len(GOOD_UNITS)} done' in stdout
        local = fleet_run[0] / 'units'
        for unit in GOOD_UNITS:
            here, there = unit_files(out / 'units' / unit), unit_files(local / unit)
            assert set(here) == set(there)
            for name, data in here.items():
                assert data.replace(str(out).encode(), b'') == \
                    there[name].replace(str(fleet_run[0]).encode(), b''), (unit, name)
    finally:
        for process in reversed(started):
            if process.poll() is None:
                process.kill()
            process.wait(30)
