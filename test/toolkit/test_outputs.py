"""
Outputs are all or nothing: a run that fails or is interrupted at any step leaves the old ones.

Each command writes its outputs under staging names beside them and renames
them in when it is done (`mlx_tempcomp.toolkit.outputs`). Here each step of
``diagnose``, ``fit``, ``evaluate --out-csv``, ``convert`` and ``simulate``
is made to fail in turn, through the real command in a subprocess: Ctrl-C
(SIGINT) once the step shows on the console, a write refused by the file-size
limit (RLIMIT_FSIZE, which binds root too) at the first output larger than
the limit, matplotlib's pyplot refused by an import hook in the plots step,
and a record whose exports cannot be fitted after the rest was written.
Each time the previous outputs are there byte for byte (or none, where there
were none) and no staging name is left behind.
"""

import json
import os
from pathlib import Path
import resource
import shutil
import signal
import subprocess
import sys

from mlx_tempcomp.cli import main
from mlx_tempcomp.toolkit.outputs import staged_outputs
import numpy as np
import pytest

ENV = {**os.environ, 'PYTHONUNBUFFERED': '1', 'PYTHONDONTWRITEBYTECODE': '1'}
# Refuses matplotlib.pyplot only: matplotlib itself imports, so diagnose's start-up check
# passes and the plots step fails, after report.json and report.md.
_WITHOUT_PYPLOT = r"""
import sys
class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name == 'matplotlib.pyplot':
            raise ModuleNotFoundError('No module named matplotlib.pyplot', name=name)
sys.meta_path.insert(0, Refuse())
from mlx_tempcomp.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _snapshot(folder: Path) -> dict:
    """Give {relative path: bytes} of every file under ``folder`` (hidden ones included)."""
    return {str(path.relative_to(folder)): path.read_bytes()
            for path in sorted(folder.rglob('*')) if path.is_file()}


def _cli(argv, limit_bytes=None, script=None):
    """Run mlx-tempcomp in a subprocess, file sizes limited to ``limit_bytes``; give it done."""
    def limit():
        if limit_bytes is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # a write past it fails: EFBIG
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    command = [sys.executable, '-c', script] if script else \
        [sys.executable, '-m', 'mlx_tempcomp.cli']
    return subprocess.run([*command, *map(str, argv)], capture_output=True, text=True,
                          env=ENV, preexec_fn=limit, timeout=300)


def _interrupted(argv, marker: str):
    """Run mlx-tempcomp with --progress, Ctrl-C once ``marker`` shows on stderr; give it."""
    process = subprocess.Popen(
        [sys.executable, '-m', 'mlx_tempcomp.cli', *map(str, argv), '--progress'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV,
        # As from a terminal: a suite started in the background of a script inherits SIGINT
        # ignored, and Python then installs no KeyboardInterrupt for it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        seen = b''
        while marker.encode() not in seen:
            chunk = os.read(process.stderr.fileno(), 4096)
            assert chunk, f'ended before {marker!r}: {seen.decode()}'
            seen += chunk
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=60)
    finally:
        process.kill()
    return process.returncode, (seen + err).decode()


def _assert_failed(done, folder: Path, before: dict) -> None:
    assert done.returncode != 0, done.stdout
    assert _snapshot(folder) == before, sorted(set(_snapshot(folder)) ^ set(before))


@pytest.fixture(scope='module')
def records(tmp_path_factory):
    """Give a thermal cycle, a long record and one whose exports fail after the rest."""
    folder = tmp_path_factory.mktemp('records')
    cycle = folder / 'cycle.csv'
    assert main(['simulate', '--out', str(cycle), '--cycle-c', '60', '-20', '25',
                 '--ramp-c-per-min', '8', '--rate-hz', '1', '--seed', '3']) == 0
    rng = np.random.default_rng(3)
    time_s = np.arange(20000) * 0.01
    long = folder / 'long.csv'
    np.savetxt(long, np.column_stack([time_s, 25.0 + 10.0 * np.sin(time_s / 50.0),
                                      rng.normal(0.0, 0.003, time_s.size)]),
               delimiter=',', header='time,temperature,gyro_z', comments='', fmt='%.9g')
    # Three temperatures in the first 80 % of the rows, a ramp in the rest: every model
    # fits the whole record, but the exports' cubic, fitted to the rows before the held-out
    # part, finds three temperatures where it needs four.
    rows = 2000
    first = int(0.8 * rows)
    temperature_c = np.concatenate([25.0 + np.floor(np.arange(first) / (first / 3)),
                                    27.0 + np.arange(1, rows - first + 1) * 33.0 / (rows - first)])
    gyro = 0.001 * (temperature_c - 25.0) + rng.normal(0.0, 0.003, (3, rows))
    late = folder / 'late.csv'
    np.savetxt(late, np.column_stack([np.arange(rows, dtype=float), temperature_c, *gyro]),
               delimiter=',', header='time,temperature,gyro_x,gyro_y,gyro_z', comments='',
               fmt='%.9g')
    return {'cycle': cycle, 'long': long, 'late': late}


@pytest.fixture(scope='module')
def earlier_diagnosis(records, tmp_path_factory) -> Path:
    """Give the --out folder of a diagnose run on the cycle, once for the module."""
    out = tmp_path_factory.mktemp('earlier') / 'diagnosis'
    assert main(['diagnose', str(records['cycle']), '--out', str(out)]) == 0
    return out


@pytest.fixture
def diagnosed(earlier_diagnosis, tmp_path):
    """Give a folder holding a diagnose --out folder from an earlier run, and its files."""
    out = tmp_path / 'diagnosis'
    shutil.copytree(earlier_diagnosis, out)   # a copy each: a test may not touch the others'
    return out, _snapshot(tmp_path)


@pytest.mark.slow
def test_diagnose_interrupted_while_diagnosing(records, diagnosed, tmp_path):
    out, before = diagnosed
    # The long record: its diagnosis lasts seconds after the first progress bar shows.
    code, err = _interrupted(['diagnose', records['long'], '--out', out], 'diagnose:')
    assert code == 130, err
    assert err.rstrip().endswith('interrupted: no output of this run was written')
    assert _snapshot(tmp_path) == before


@pytest.mark.slow
def test_diagnose_failing_to_write_its_report(records, diagnosed, tmp_path):
    out, before = diagnosed
    done = _cli(['diagnose', records['cycle'], '--out', out], limit_bytes=4096)
    _assert_failed(done, tmp_path, before)
    assert 'File too large' in done.stderr and done.stderr.startswith('error: ')


def test_diagnose_failing_in_the_plots(records, diagnosed, tmp_path):
    out, before = diagnosed
    done = _cli(['diagnose', records['cycle'], '--out', out], script=_WITHOUT_PYPLOT)
    _assert_failed(done, tmp_path, before)
    assert "cannot import name 'pyplot'" in done.stderr


@pytest.mark.slow
def test_diagnose_failing_in_the_exports_after_the_folder(records, tmp_path):
    out = tmp_path / 'diagnosis'
    # --min-past 0.5: the forward blocks are predicted from rows that span the ramp.
    assert main(['diagnose', str(records['late']), '--out', str(out), '--min-past', '0.5']) == 0
    before = _snapshot(tmp_path)
    done = _cli(['diagnose', records['late'], '--out', out, '--min-past', '0.5',
                 '--px4-params', out / 'px4.params', '--px4-device-id', '1',
                 '--ardupilot-parm', tmp_path / 'imu.parm'])
    _assert_failed(done, tmp_path, before)
    assert 'rows diagnosed in' in done.stdout   # the diagnosis was done
    assert 'the exported cubic' in done.stderr and done.stderr.count('\n') == 1


def test_fit_failing_in_the_exports_or_the_parameter_file(records, tmp_path):
    outputs = ['--order', '1', '--out', tmp_path / 'fit.yaml', '--ardupilot-parm',
               tmp_path / 'imu.parm', '--px4-params', tmp_path / 'px4.params',
               '--px4-device-id', '1']
    assert _cli(['fit', records['cycle'], *outputs]).returncode == 0
    before = _snapshot(tmp_path)
    done = _cli(['fit', records['late'], *outputs])   # fitted, then the exports fail
    _assert_failed(done, tmp_path, before)
    assert 'fitted temperature range' in done.stdout and 'the exported cubic' in done.stderr
    done = _cli(['fit', records['cycle'], '--out', tmp_path / 'fit.yaml'], limit_bytes=200)
    _assert_failed(done, tmp_path, before)
    assert 'File too large' in done.stderr and done.stderr.count('\n') == 1


def test_evaluate_failing_to_write_its_csv(records, tmp_path):
    params = tmp_path / 'fit.yaml'
    assert main(['fit', str(records['long']), '--out', str(params)]) == 0
    argv = ['evaluate', records['long'], '--params', params, '--out-csv', tmp_path / 'out.csv']
    assert _cli(argv).returncode == 0
    before = _snapshot(tmp_path)
    done = _cli(argv, limit_bytes=100_000)   # the CSV is larger: cut in the middle
    _assert_failed(done, tmp_path, before)
    assert 'File too large' in done.stderr and done.stderr.count('\n') == 1


@pytest.mark.slow
def test_convert_interrupted_or_failing_while_writing_the_bag(records, tmp_path):
    code, err = _interrupted(['convert', records['long'], '--out', tmp_path / 'bag'],
                             'writing')
    assert code == 130, err
    assert _snapshot(tmp_path) == {}
    done = _cli(['convert', records['long'], '--out', tmp_path / 'bag', '--storage', 'mcap'],
                limit_bytes=100_000)
    _assert_failed(done, tmp_path, {})


@pytest.mark.slow
def test_simulate_interrupted_or_failing_at_each_output(tmp_path):
    code, err = _interrupted(['simulate', '--out', tmp_path / 'run.csv', '--duration-s', '3000'],
                             'simulating')
    assert code == 130, err
    code, err = _interrupted(['simulate', '--out', tmp_path / 'fleet', '--fleet', '50',
                              '--duration-s', '20'], 'simulating')
    assert code == 130, err
    assert _snapshot(tmp_path) == {} and list(tmp_path.iterdir()) == []
    # The CSV (about 1.5 kB) is written, its truth (about 3.7 kB) is not: neither stays.
    short = ['simulate', '--out', tmp_path / 'run.csv', '--duration-s', '2']
    _assert_failed(_cli(short, limit_bytes=2500), tmp_path, {})
    _assert_failed(_cli(short[:3] + ['bag', '--duration-s', '60'], limit_bytes=20_000),
                   tmp_path, {})
    assert _cli(short).returncode == 0
    assert sorted(_snapshot(tmp_path)) == ['run.csv', 'run.truth.json']


def test_outputs_replace_all_targets_or_none(tmp_path):
    """The helper itself: a failure after each staged output, and a rename that fails."""
    old = {'a.txt': b'old a', 'b/c.txt': b'old c'}
    for name, data in old.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_bytes(data)
    for failing_after in range(3):
        with pytest.raises(KeyboardInterrupt):
            with staged_outputs() as outputs:
                for step, write in enumerate([
                        lambda: outputs.file(tmp_path / 'a.txt').write_bytes(b'new a'),
                        lambda: (outputs.folder(tmp_path / 'b') / 'c.txt').write_bytes(b'c')]):
                    if step == failing_after:
                        raise KeyboardInterrupt
                    write()
                raise KeyboardInterrupt
        assert _snapshot(tmp_path) == old
    # The second target cannot be replaced (a folder in the way of a file): the first is undone.
    (tmp_path / 'd.txt').mkdir()
    (tmp_path / 'd.txt' / 'keep').write_bytes(b'k')
    with pytest.raises(OSError):
        with staged_outputs() as outputs:
            outputs.file(tmp_path / 'a.txt').write_bytes(b'new a')
            outputs.file(tmp_path / 'd.txt').write_bytes(b'new d')
    assert _snapshot(tmp_path) == {**old, 'd.txt/keep': b'k'}
    shutil.rmtree(tmp_path / 'd.txt')
    with staged_outputs() as outputs:
        outputs.file(tmp_path / 'a.txt').write_bytes(b'new a')
        (outputs.folder(tmp_path / 'b') / 'e.txt').write_bytes(b'e')
    assert _snapshot(tmp_path) == {'a.txt': b'new a', 'b/e.txt': b'e'}
    assert json.dumps(sorted(p.name for p in tmp_path.iterdir())) == '["a.txt", "b"]'
