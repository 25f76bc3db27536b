"""
Every subcommand with each optional package unimportable, as on a machine with the nodes' extra.

A fresh interpreter puts an import hook in front of the import system that
refuses the packages it is given (the package and every submodule), then
runs ``mlx-tempcomp`` commands in turn. `NEEDS` is this test's own account of
what each command imports beyond the nodes' packages. For every optional
package and every command:

- when the command needs it, refused alone it gives exit code 2 and one
  ``error:`` line naming the package and the extra to install, before any
  work (the command's output folder stays empty);
- when the command does not need it, the command runs (exit 0) with it
  refused together with every other optional package the command does not
  need.

The fleet commands that run start a local Dask cluster, whose worker
processes are new interpreters without the hook: those runs check the
client's side. The runs of commands that need an optional package are
marked slow; the commands that need none run in the quick tier with every
optional package refused at once.
"""

import json
from pathlib import Path
import shutil
import subprocess
import sys

from measured_data import FLIGHT_LOGS
from mlx_tempcomp.cli import main
from mlx_tempcomp.simulation.mlx90609 import factory_eeprom, FactoryMeasurement
from mlx_tempcomp.simulation.physics import GyroTruth
import numpy as np
import pytest

# Optional package -> the extra of setup.py that installs it (scipy comes with allantools).
EXTRA = {'matplotlib': 'toolkit', 'allantools': 'toolkit', 'scipy': 'toolkit',
         'pyulog': 'flightlogs', 'pymavlink': 'flightlogs', 'dask': 'fleet',
         'distributed': 'fleet', 'fsspec': 'fleet'}
ALLAN = {'allantools', 'scipy'}
FLEET = {'dask', 'distributed', 'matplotlib'}
ADIS = ['adis-bias', '--source', 'simulated', '--average-s', '10', '--self-heat-s', '60',
        '--settle-s', '60', '--pbc-s', '10', '--rate-hz', '20', '--out', '{out}/adis.yaml']
# Command -> (arguments, the optional packages it imports). {out} is a folder of its own.
NEEDS = {
    'inspect CSV': (['inspect', '{cycle}'], set()),
    'inspect ULog': (['inspect', '{ulog}'], {'pyulog'}),
    'inspect DataFlash': (['inspect', '{dataflash}'], {'pymavlink'}),
    'decode-eeprom': (['decode-eeprom', '{image}'], set()),
    'fit': (['fit', '{cycle}', '--out', '{out}/fit.yaml'], set()),
    'allan': (['allan', '{cycle}'], ALLAN),
    'allan --out': (['allan', '{cycle}', '--out', '{out}/allan'], ALLAN | {'matplotlib'}),
    'adis-bias': (ADIS + ['--allan-record-s', '60'], ALLAN),
    'adis-bias --allan-record-s 0': (ADIS + ['--allan-record-s', '0'], set()),
    'convert': (['convert', '{cycle}', '--out', '{out}/bag'], set()),
    'diagnose': (['diagnose', '{cycle}', '--out', '{out}/diagnose'], {'matplotlib'}),
    'diagnose --no-plots': (['diagnose', '{cycle}', '--out', '{out}/diagnose', '--no-plots'],
                            set()),
    'evaluate': (['evaluate', '{cycle}', '--params', '{params}', '--out-csv',
                  '{out}/corrected.csv'], set()),
    'simulate': (['simulate', '--out', '{out}/simulated.csv', '--duration-s', '20'], set()),
    'inject-motion': (['inject-motion', '{cycle}', '--out', '{out}/moved.csv'], set()),
    'fleet report': (['fleet', 'report', '--out', '{out}/fleet'], {'matplotlib'}),
    'fleet diagnose': (['fleet', 'diagnose', '--records', '{units}/{{unit}}/*.csv', '--out',
                        '{out}/fleet', '--workers', '1'], FLEET),
    'fleet fit on URLs': (['fleet', 'fit', '--records', 'file://{units}/{{unit}}/*.csv',
                           '--out', '{out}/fleet', '--workers', '1'], FLEET | {'fsspec'}),
}
# Groups of commands by what they need. The group that needs nothing runs with every optional
# package refused, as with the nodes' extra alone (make demo); the others are slow.
GROUPS = sorted({frozenset(needs) for _, needs in NEEDS.values()}, key=sorted)

# Run by a fresh interpreter: argv[1] is JSON {refused, runs: [[name, argv], ...]}.
_DRIVER = r"""
import contextlib, io, json, sys, traceback

class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in REFUSED:
            raise ModuleNotFoundError(f'No module named {name!r}', name=name)
        return None

job = json.loads(sys.argv[1])
REFUSED = set(job['refused'])
sys.meta_path.insert(0, Refuse())
from mlx_tempcomp.cli import main
results = {}
for name, argv in job['runs']:
    out, err, code = io.StringIO(), io.StringIO(), None
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as end:
            code = end.code
        except BaseException:
            traceback.print_exc()
    results[name] = [code, out.getvalue(), err.getvalue()]
print(json.dumps(results))
"""


@pytest.fixture(scope='module')
def inputs(tmp_path_factory):
    """Give the paths the commands read: a thermal cycle, its parameter file, an image, logs."""
    folder = tmp_path_factory.mktemp('extras')
    cycle = folder / 'cycle.csv'
    assert main(['simulate', '--out', str(cycle), '--cycle-c', '60', '-20', '25',
                 '--ramp-c-per-min', '8', '--rate-hz', '1', '--axes', 'z', '--seed', '1']) == 0
    params = folder / 'params.yaml'
    assert main(['fit', str(cycle), '--out', str(params)]) == 0
    image = folder / 'eeprom.bin'
    truth = GyroTruth.random(np.random.default_rng(0))
    image.write_bytes(factory_eeprom(truth, np.random.default_rng(0), FactoryMeasurement()))
    units = folder / 'units'
    (units / 'unit-a').mkdir(parents=True)
    shutil.copy(cycle, units / 'unit-a' / 'cycle.csv')
    return {'cycle': str(cycle), 'params': str(params), 'image': str(image),
            'units': str(units), 'ulog': str(FLIGHT_LOGS / 'px4_robologs_test.ulg'),
            'dataflash': str(FLIGHT_LOGS / 'ardupilot_pymavlink_test.BIN')}


def _run(inputs: dict, out: Path, refused, names) -> dict:
    """Run the commands ``names`` with ``refused`` unimportable; give name -> (code, out, err)."""
    (out / 'fleet' / 'units').mkdir(parents=True)  # what fleet report reads
    runs = []
    for name in names:
        argv, _ = NEEDS[name]
        for path in (inputs['ulog'], inputs['dataflash']):
            if ('{ulog}' in argv or '{dataflash}' in argv) and not Path(path).is_file():
                pytest.skip(f'flight log not present: {path} (set MLX_TEMPCOMP_SHARED)')
        runs.append([name, [part.format(out=out, **inputs) for part in argv]])
    job = json.dumps({'refused': sorted(refused), 'runs': runs})
    done = subprocess.run([sys.executable, '-c', _DRIVER, job], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize('package', sorted(EXTRA))
def test_a_command_that_needs_the_package_names_its_extra_before_any_work(
        inputs, tmp_path, package):
    names = [name for name, (_, needs) in NEEDS.items() if package in needs]
    assert names
    results = _run(inputs, tmp_path, {package}, names)
    for name, (code, _, err) in results.items():
        assert code == 2, (name, err)
        assert err.startswith('error: ') and err.count('\n') == 1, (name, err)
        assert package in err and f"pip install 'mlx_tempcomp[{EXTRA[package]}]'" in err, err
        assert 'Traceback' not in err
    written = sorted(str(path.relative_to(tmp_path)) for path in tmp_path.rglob('*')
                     if path.is_file())
    assert written == [], written


@pytest.mark.parametrize('needs', [
    pytest.param(group, id='+'.join(sorted(group)) or 'none',
                 marks=[pytest.mark.slow] if group else [])
    for group in GROUPS])
def test_a_command_runs_without_every_package_it_does_not_need(inputs, tmp_path, needs):
    names = [name for name, (_, wanted) in NEEDS.items() if frozenset(wanted) == needs]
    results = _run(inputs, tmp_path, set(EXTRA) - needs, names)
    for name, (code, out, err) in results.items():
        assert code == 0, (name, out, err)
        assert 'Traceback' not in err, (name, err)
    if 'diagnose --no-plots' in results:
        assert 'no plots (--no-plots)' in results['diagnose --no-plots'][1]
        assert not list((tmp_path / 'diagnose').glob('*.png'))
        assert 'none (--no-plots)' in (tmp_path / 'diagnose' / 'report.md').read_text()
