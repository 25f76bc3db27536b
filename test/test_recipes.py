"""
docs/architecture.md's recipes, applied to a copy of the package: a toy effect and a toy part.

Each numbered step of "How to add an effect" and "How to add a sensor" is here as the text
edits it makes (`Edit`: a file, an anchor found there once, the text put after or before it),
under the step's number, and as the files a toy stands in for (`StandIn`).
`test_the_doc_lists_the_steps_the_edits_make` holds the doc and these tables in step: the files
each doc step names are those of its edits and stand-ins, and the names an edit goes by are
in its doc step. The other tests copy the package with config/, docs/, test/ and README.md
into a temporary folder, apply every edit, and run the copy (PYTHONPATH): the toy effect,
bias + k x |dT/dt|, simulated, named by ``mlx-tempcomp diagnose`` and written into
params.yaml, taken by ``mlx-tempcomp evaluate``, built and declared by the compensation
node; the toy part accepted by the driver's parameter checks, its stream picked by the driver
node. On the copy they run the tests that hold each list of effects or parts to the code, so
a place the recipe does not name fails here, in the code that refuses the toy or in one of
those tests.
"""

from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import textwrap

from mlx_tempcomp.parameters.files import flat_parameters
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
ARCHITECTURE = ROOT / 'docs' / 'architecture.md'
# What a copy holds: the package and what the steps touch or the copied tests read.
COPIED = ('mlx_tempcomp', 'config', 'docs', 'test', 'README.md', 'setup.cfg')
# Paths outside the package; a doc step names package files from inside mlx_tempcomp/.
OUTSIDE_PACKAGE = ('config/', 'docs/', 'test/', 'README.md')
TIMEOUT_S = 600.0


@dataclass(frozen=True)
class Edit:
    """
    One text edit of a step: ``text`` put just after ``anchor`` (before it with ``before``).

    ``anchor`` must be found exactly once in ``path``. ``names`` are the names the doc's step
    gives for what the edit adds or where (each in backquotes there).
    """

    path: str
    names: tuple
    anchor: str
    text: str
    before: bool = False


@dataclass(frozen=True)
class StandIn:
    """A file of a step that the toy does not write: it stands on an existing part's."""

    path: str


# The toy effect: bias + k x |dT/dt|, dT/dt the slope the temperature rate reads.
TOY = 'toy_rate_magnitude'
TOY_FIELD = 'toy_rate_magnitude_rad_s_per_c_s'
TOY_SIMULATED = 'toy_dps_per_abs_c_s'
TOY_DPS = 6.0          # deg/s per C/s: 0.2 deg/s on a 2 C/min ramp
# What the steps add for it, beyond one-line entries.
TOY_BIAS = f"""def _toy_bias(term, model, inputs, history, total):
    return total + term.{TOY_FIELD} * abs(history.slope)


"""
TOY_EFFECT = f"""    Effect('{TOY}', fields=('{TOY_FIELD}',), inputs=_TIME, slope=True,
           bias=_toy_bias, descriptions={{'{TOY_FIELD}': 'axis {{axis}}: bias + k x |dT/dt|'}}),
"""
TOY_FIT = f"""    '{TOY}': EffectFit(
        _flag('{TOY}'),
        lambda terms, problem: {{'rad_s_per_c_s': terms.{TOY_FIELD}}},
        lambda problem, axis, spec, choice: problem.cached(
            '{TOY}', lambda: problem.mean(np.abs(problem.slope))[:, None]),
        lambda problem, axis, choice, take: {{'{TOY_FIELD}': take(1)[0]}}),
"""
TOY_FORMULA_TEST = f"""

def test_toy_rate_magnitude_is_k_times_the_magnitude_of_the_slope():
    time_s = np.arange(0.0, 400.0, 0.5)
    temperature_c = np.where(time_s < 200.0, 20.0 + 0.1 * time_s,
                             60.0 - 0.05 * (time_s - 200.0))
    model = EffectModel(terms=(AxisTerms(bias=(0.0,), {TOY_FIELD}=0.5),),
                        temperature_rate_window_s=10.0)
    bias = -model.correct(np.zeros((time_s.size, 1)), temperature_c,
                          ModelInputs(time_s=time_s)).rate_rad_s[:, 0]
    slope = TemperatureSlope(10.0).batch(time_s, temperature_c)
    np.testing.assert_array_equal(bias, 0.5 * np.abs(slope))
    assert bias[100] == pytest.approx(0.05) and bias[-1] == pytest.approx(0.025)"""
TOY_RECOVERED = f"""    '{TOY}': lambda parameters, model: parameters['rad_s_per_c_s'] == (
        pytest.approx(math.radians({TOY_DPS}), rel=0.1)),
"""

# Per step of "How to add an effect", the edits that make it for the toy.
EFFECT_STEPS = {
    1: (Edit('mlx_tempcomp/core/effects/model.py', ('AxisTerms',),
             '    temperature_rate_rad_s_per_c_s: float = 0.0\n',
             f'    {TOY_FIELD}: float = 0.0\n'),),
    2: (Edit('mlx_tempcomp/core/effects/table.py', ('_rate_bias',), 'def _gradient_bias(',
             TOY_BIAS, before=True),
        Edit('mlx_tempcomp/core/effects/table.py', ('Effect', 'EFFECTS', 'slope=True'),
             "{'temperature_rate_rad_s_per_c_s': 'axis {axis}: bias + c x dT/dt'}),\n",
             TOY_EFFECT),
        Edit('mlx_tempcomp/core/effects/table.py', (),
             '- ``temperature_rate``: + c x dT/dt (the same windowed slope);\n',
             f'- ``{TOY}``: + k x |dT/dt| (the same slope);\n')),
    3: (Edit('mlx_tempcomp/core/diagnosis/fits.py', ('EffectFit', 'FITS', '_flag', 'take'),
             "    'thermal_gradient': EffectFit(\n", TOY_FIT, before=True),),
    4: (Edit('mlx_tempcomp/simulation/physics.py', ('Effects',),
             '    zro_dps_per_c_s: float = 0.0            # ZRO shift per degC/s of die '
             'temperature change\n',
             f'    {TOY_SIMULATED}: float = 0.0          # ZRO shift per degC/s of |die rate|\n'),
        Edit('mlx_tempcomp/simulation/physics.py', ('GyroPhysics.zro_offset_dps',),
             '        offset += effects.zro_dps_per_c_s * s.die_rate_c_s\n',
             f'        offset += effects.{TOY_SIMULATED} * abs(s.die_rate_c_s)\n')),
    5: (Edit('config/mlx_tempcomp.yaml', ('effects:',),
             '    #   gradient_time_constants_s, gradient_rad_s_per_c, supply_voltage, '
             'secondary,\n',
             f'    #   {TOY_FIELD}: {{<a>: 0.0}}\n', before=True),),
    6: (Edit('test/core/test_effects.py', ('_full_model',),
             '        AxisTerms(bias=(0.01, 0.002, -0.001), thermal_lag_s=20.0, '
             'hysteresis_half_width_c=2.0,\n',
             f'                  {TOY_FIELD}=0.004,\n'),
        Edit('test/core/test_effects.py', (),
             '\n\ndef test_polynomial_only_model_is_the_polynomial():', TOY_FORMULA_TEST,
             before=True),
        Edit('test/core/test_fuzz_effect_rows.py', ('ONE_EFFECT',),
             "    'temperature_rate': lambda c: ({'temperature_rate_rad_s_per_c_s': c},) * 2,\n",
             f"    '{TOY}': lambda c: ({{'{TOY_FIELD}': c}},) * 2,\n"),
        Edit('test/toolkit/test_diagnose.py', ('EFFECTS',),
             "    'temperature_rate': (Effects(zro_dps_per_c_s=4.0), QUIET),\n",
             f"    '{TOY}': (Effects({TOY_SIMULATED}={TOY_DPS}), QUIET),\n"),
        Edit('test/toolkit/test_diagnose.py', ('RECOVERED',), 'RECOVERED = {\n', TOY_RECOVERED)),
    7: (Edit('docs/diagnose.md', (), '| `temperature_rate` | ',
             f'| `{TOY}` | + k \\|dT/dt\\|, the same slope | live | k |\n', before=True),
        Edit('docs/ros.md', (), '| `effects.temperature_rate_rad_s_per_c_s.<a>` |',
             f'| `effects.{TOY_FIELD}.<a>` | + k x \\|dT/dt\\| (the same slope) |\n',
             before=True)),
}

# The toy part: its device name, one setting of its own; the ADIS16130's modules stand in
# for its protocol, simulation, source and stream.
PART = 'toygyro'
PART_SETTING = f'{PART}.bandwidth_hz'
PART_SECTION = 'ToygyroSettings'
SENSOR_STEPS = {
    1: (StandIn('mlx_tempcomp/hardware/<part>.py'), StandIn('test/hardware/test_<part>.py')),
    2: (StandIn('mlx_tempcomp/simulation/<part>.py'),),
    3: (StandIn('mlx_tempcomp/sources/<part>.py'),
        Edit('test/sources/test_protocol.py', ('SOURCES',),
             "    'adis16130': lambda: adis16130.SimulatedSensor(),\n",
             f"    '{PART}': lambda: adis16130.SimulatedSensor(),\n")),
    4: (StandIn('mlx_tempcomp/ros/driver/<part>_stream.py'), StandIn('test/ros/test_devices.py')),
    5: (Edit('mlx_tempcomp/ros/driver/node.py', ('STREAMS',), "'mpu6000': MpuStream",
             f", '{PART}': AdisStream"),),
    6: (Edit('mlx_tempcomp/parameters/driver.py', ('DEVICES',), "'adis16130', 'mpu6000'",
             f", '{PART}'"),
        Edit('mlx_tempcomp/parameters/driver.py', ('DRIVER_SPECS',),
             "    Spec('mpu6000.variant',",
             f"    Spec('{PART_SETTING}', 50.0, 'toy part: bandwidth', read_only=True, low=1.0,"
             ' high=1000.0),\n', before=True),
        Edit('mlx_tempcomp/parameters/driver.py', ('DriverSettings',),
             '@dataclass(frozen=True)\nclass DriverSettings:',
             f'@dataclass(frozen=True)\nclass {PART_SECTION}:\n'
             f'    """``{PART}.*``: the toy part\'s bandwidth."""\n\n'
             '    bandwidth_hz: float\n\n\n',
             before=True),
        Edit('mlx_tempcomp/parameters/driver.py', ('DriverSettings',),
             '    mpu6000: Mpu6000Settings\n', f'    {PART}: {PART_SECTION}\n'),
        Edit('mlx_tempcomp/parameters/driver.py', ('driver_settings',), '        mpu6000=mpu6000',
             f",\n        {PART}=_section({PART_SECTION}, values, '{PART}.')"),
        Edit('mlx_tempcomp/parameters/driver.py', ('sample_rate_hz',),
             'output rate over 1 + SMPLRT_DIV', f'; {PART} 5700'),
        Edit('mlx_tempcomp/parameters/driver.py', ('spi.speed_hz',),
             'the limit for configuration registers', f'; {PART} 1 MHz')),
    7: (Edit('config/mlx_tempcomp.yaml', ('device:',), 'mpu6000 (x, y, z + accel)',
             f' | {PART}'),
        Edit('config/mlx_tempcomp.yaml', ('sample_rate_hz',),
             'MPU-6000 gyro rate / (1 + SMPLRT_DIV)', f', {PART} 5700'),
        Edit('config/mlx_tempcomp.yaml', ('speed_hz',), 'ADIS16130 1 MHz, MPU-6000/6500 1 MHz',
             f', {PART} 1 MHz'),
        Edit('config/mlx_tempcomp.yaml', ('<part>:',), '    mpu6000:\n',
             f'    {PART}:\n      bandwidth_hz: 50.0\n', before=True)),
    8: (Edit('README.md', (), 'InvenSense\nMPU-6000/6500', f', a {PART}'),
        Edit('README.md', ('device',),
             '`mpu6000` (3 axes and accelerometer; on SPI or I2C, the MPU-6050 too)',
             f', `{PART}` (one axis)'),
        Edit('README.md', (), '| [`docs/mlx90609.md`](docs/mlx90609.md), ',
             f'[`docs/{PART}.md`](docs/{PART}.md), '),
        Edit('docs/ros.md', ('device',), '| `mpu6000` | x, y, z measured;',
             f'| `{PART}` | exactly one | `imu/data_raw`, `imu/temperature_raw` | none |\n',
             before=True),
        Edit('docs/ros.md', (), 'Per device: ', f'`{PART_SETTING}` (its bandwidth); '),
        StandIn('docs/<part>.md')),
}


def _doc_steps(heading: str) -> dict:
    """Give the numbered steps of a section of docs/architecture.md: number -> text."""
    section = ARCHITECTURE.read_text(encoding='utf-8').partition(f'\n## {heading}\n')[2]
    section = section.partition('\n## ')[0]
    steps = {}
    for match in re.finditer(r'^(\d+)\. (.*?)(?=^\d+\. |^\S|\Z)', section, re.M | re.S):
        steps[int(match.group(1))] = match.group(2)
    return steps


def _doc_files(text: str) -> set:
    """Give the files a doc step names in backquotes, from the repository's root."""
    files = set()
    for name in re.findall(r'`([^`\s]+\.(?:py|yaml|md))`', text):
        files.add(name if name.startswith(OUTSIDE_PACKAGE) else f'mlx_tempcomp/{name}')
    return files


@pytest.mark.parametrize('heading, steps', [('How to add an effect', EFFECT_STEPS),
                                            ('How to add a sensor', SENSOR_STEPS)],
                         ids=['effect', 'sensor'])
def test_the_doc_lists_the_steps_the_edits_make(heading, steps):
    documented = _doc_steps(heading)
    assert sorted(documented) == sorted(steps), f'{heading}: the doc has other steps'
    for number, items in steps.items():
        text = ' '.join(documented[number].split())
        assert _doc_files(text) == {item.path for item in items}, f'{heading}, step {number}'
        quoted = re.findall(r'`([^`]+)`', text)
        for item in items:
            for name in getattr(item, 'names', ()):
                assert any(name in span for span in quoted), \
                    f'{heading}, step {number}: {name} is not named'


def _copy_with(folder: Path, steps: dict) -> Path:
    """Copy the package and what the steps touch into ``folder``; apply every edit there."""
    for name in COPIED:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, folder / name,
                            ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
        else:
            shutil.copy2(source, folder / name)
    for number, items in steps.items():
        for edit in items:
            if not isinstance(edit, Edit):
                continue
            path = folder / edit.path
            text = path.read_text(encoding='utf-8')
            found = text.count(edit.anchor)
            assert found == 1, f'step {number}: {edit.anchor!r} is in {edit.path} {found} times'
            at = text.index(edit.anchor) + (0 if edit.before else len(edit.anchor))
            path.write_text(text[:at] + edit.text + text[at:], encoding='utf-8')
    return folder


def _run(copy: Path, *args, cwd: Path = None) -> str:
    """Run Python on the copy (its package first on the path); give stdout, fail on an error."""
    done = subprocess.run([sys.executable, *args], cwd=cwd or copy, capture_output=True,
                          text=True, timeout=TIMEOUT_S,
                          env=dict(os.environ, PYTHONPATH=str(copy),
                                   PYTHONDONTWRITEBYTECODE='1'))
    assert done.returncode == 0, f'{args} exit {done.returncode}\n{done.stdout}\n{done.stderr}'
    return done.stdout


def _command(copy: Path, *args, cwd: Path) -> str:
    """Run ``mlx-tempcomp ARGS`` from the copy."""
    return _run(copy, '-c', 'import sys; from mlx_tempcomp.cli import main; '
                'sys.exit(main(sys.argv[1:]))', *args, cwd=cwd)


def _pytest(copy: Path, *args) -> str:
    """Run the copy's tests (its setup.cfg, conftest.py and package); give the report."""
    return _run(copy, '-m', 'pytest', '-p', 'no:cacheprovider', '-q', '-rA', *args)


@pytest.fixture(scope='module')
def effect_copy(tmp_path_factory) -> Path:
    return _copy_with(tmp_path_factory.mktemp('effect'), EFFECT_STEPS)


@pytest.fixture(scope='module')
def sensor_copy(tmp_path_factory) -> Path:
    return _copy_with(tmp_path_factory.mktemp('sensor'), SENSOR_STEPS)


# A chamber cycle at 1 Hz, ramps of 1 to 3 C/min with holds (the effect is the ramp's speed),
# through the copy's simulator with the toy effect, written as a record.
SIMULATE = textwrap.dedent(f"""
    import numpy as np
    from mlx_tempcomp.simulation.physics import (Effects, GyroPhysics, GyroTruth, Noise,
                                                 Scenario, ThermalProfile)
    times, temperatures = [0.0], [25.0]
    for target_c, rate_c_per_min in ((70.0, 2.0), (-20.0, 1.0), (70.0, 3.0), (-20.0, 2.0)):
        times.append(times[-1] + abs(target_c - temperatures[-1]) / rate_c_per_min * 60.0)
        times.append(times[-1] + 600.0)
        temperatures += [target_c, target_c]
    truth = GyroTruth(zro_dps_coefficients=(0.5, 0.02, 2e-4, -2e-6),
                      effects=Effects({TOY_SIMULATED}={TOY_DPS}),
                      noise=Noise(bias_instability_dps=0.0))
    physics = GyroPhysics(truth, Scenario(thermal=ThermalProfile(tuple(times),
                                                                 tuple(temperatures))), seed=0)
    time_s = np.arange(1.0, times[-1])
    rows = []
    for t in time_s:
        physics.advance(float(t))
        rows.append((physics.state.sensor_c, physics.zro_offset_dps()))
    temperature_c, zro_dps = np.array(rows).T
    rng = np.random.default_rng(1)
    rate_rad_s = np.radians(zro_dps + rng.normal(0.0, 0.02, time_s.size))
    np.savetxt('toy.csv', np.column_stack([time_s, temperature_c + rng.normal(
        0.0, 0.02, time_s.size), rate_rad_s]), fmt='%.12g', delimiter=',',
        header='time,temperature,gyro_z', comments='')
""")


@pytest.fixture(scope='module')
def diagnosed(effect_copy, tmp_path_factory) -> Path:
    """Give a folder with the toy record (toy.csv) and its diagnosis (diag/)."""
    work = tmp_path_factory.mktemp('toy')
    _run(effect_copy, '-c', SIMULATE, cwd=work)
    _command(effect_copy, 'diagnose', 'toy.csv', '--out', 'diag', '--no-plots', cwd=work)
    return work


def test_a_toy_effect_is_diagnosed_written_and_evaluated(effect_copy, diagnosed):
    report = json.loads((diagnosed / 'diag' / 'report.json').read_text())
    axis = report['axes']['z']
    assert [step['effect'] for step in axis['steps']][:2] == ['temperature_polynomial', TOY]
    assert TOY in axis['written']['effects']
    assert TOY in report['effects']['searched']
    params = yaml.safe_load((diagnosed / 'diag' / 'params.yaml').read_text())
    flat = flat_parameters(params['compensation_node']['ros__parameters'])
    assert flat['model'] == 'effects'
    assert flat[f'effects.{TOY_FIELD}.z'] == pytest.approx(math.radians(TOY_DPS), rel=0.1)
    # evaluate takes the file; the toy's term is what makes its error small.
    params['compensation_node']['ros__parameters']['effects'][TOY_FIELD]['z'] = 0.0
    (diagnosed / 'without.yaml').write_text(yaml.safe_dump(params))
    errors = {}
    for name in ('diag/params.yaml', 'without.yaml'):
        out = _command(effect_copy, 'evaluate', '--params', name, 'toy.csv', '--json',
                       cwd=diagnosed)
        errors[name] = json.loads(out)['per_sample']['z']['rms']
    assert errors['diag/params.yaml'] < 0.5 * errors['without.yaml'], errors
    # The node's model, as it builds it from the file (build_model, the probe included).
    built = _run(effect_copy, '-c', textwrap.dedent("""
        from mlx_tempcomp.parameters.files import node_values
        from mlx_tempcomp.parameters.models import build_model
        model = build_model(node_values('diag/params.yaml', 'compensation_node'))
        print(' '.join(model.terms[0].effects))
    """), cwd=diagnosed)
    assert TOY in built.split()


@pytest.mark.slow
def test_the_tests_that_hold_effects_to_the_table_pass_on_the_copy(effect_copy):
    report = _pytest(effect_copy, 'test/core/test_effects.py',
                     'test/core/test_fuzz_effect_rows.py',
                     'test/parameters/test_specs.py::'
                     'test_the_shipped_config_lists_every_parameter',
                     'test/toolkit/test_diagnose.py', '-k',
                     f'not test_diagnose or {TOY} or adds_nothing')
    for test in ('test_toy_rate_magnitude_is_k_times_the_magnitude_of_the_slope',
                 f'test_signed_zeros_keep_their_sign_through_each_effect_row_by_row[{TOY}]',
                 f'test_diagnose_names_the_undeclared_effect_and_halves_the_error[{TOY}]',
                 'test_diagnose_adds_nothing_without_an_undeclared_effect[clean]',
                 'test_the_effect_table_owns_every_coefficient_once_and_describes_every_'
                 'parameter', 'test_every_effect_and_parameter_is_documented'):
        assert re.search(rf'^PASSED \S+::{re.escape(test)}$', report, re.M), test


# The node as it starts, from the copy: its parameters declared from the specs (rclpy
# descriptors), the model built from the file.
START_COMPENSATION = textwrap.dedent(f"""
    import json
    import rclpy
    from mlx_tempcomp.ros.compensation.node import CompensationNode
    rclpy.init(args=['--ros-args', '--params-file', 'diag/params.yaml', '-p',
                     'recalibration.state_file:=zro.yaml'])
    node = CompensationNode()
    name = 'effects.{TOY_FIELD}.z'
    (described,) = node.describe_parameters([name])
    print(json.dumps({{'value': node.get_parameter(name).value,
                      'description': described.description,
                      'effects': list(node.model.terms[0].effects)}}))
    node.destroy_node()
    rclpy.shutdown()
""")


@pytest.mark.ros
def test_the_compensation_node_declares_and_builds_the_toy_effect(effect_copy, diagnosed):
    node = json.loads(_run(effect_copy, '-c', START_COMPENSATION, cwd=diagnosed).splitlines()[-1])
    assert node['value'] == pytest.approx(math.radians(TOY_DPS), rel=0.1)
    assert node['description'] == 'axis z: bias + k x |dT/dt|'
    assert TOY in node['effects']


CHECK_PART = textwrap.dedent(f"""
    from mlx_tempcomp.parameters.driver import DEVICES, DRIVER_SPECS
    from mlx_tempcomp.parameters.specs import check_choices, check_value, ParameterError
    specs = {{spec.name: spec for spec in DRIVER_SPECS}}
    values = {{'device': '{PART}', '{PART_SETTING}': 200.0}}
    for name, value in values.items():
        check_value(specs[name], value)
    check_choices(DRIVER_SPECS, values)
    try:
        check_value(specs['{PART_SETTING}'], 5000.0)
    except ParameterError as err:
        print(err)
    print(' '.join(DEVICES))
""")


def test_a_toy_part_is_accepted_by_the_driver_s_parameters_and_listed(sensor_copy):
    refused, devices = _run(sensor_copy, '-c', CHECK_PART).splitlines()
    assert refused == f'invalid parameter {PART_SETTING}: 5000.0 is outside 1 to 1000'
    assert PART in devices.split()
    report = _pytest(sensor_copy, 'test/parameters/test_specs.py', 'test/sources/test_protocol.py',
                     'test/parameters/test_settings.py', '-k',
                     'config or device or source or driver_parameter')
    for test in ('test_the_shipped_config_lists_every_parameter',
                 'test_every_device_is_listed_where_a_user_looks',
                 'test_every_driver_parameter_reaches_a_setting',
                 'test_every_device_has_its_simulated_source_here',
                 f'test_simulated_sources_satisfy_the_protocol[{PART}]'):
        assert re.search(rf'^PASSED \S+::{re.escape(test)}$', report, re.M), test


START_DRIVER = textwrap.dedent(f"""
    import rclpy
    from mlx_tempcomp.ros.driver.node import DriverNode
    rclpy.init(args=['--ros-args', '-p', 'device:={PART}', '-p', '{PART_SETTING}:=200.0'])
    node = DriverNode()
    print(type(node.stream).__name__, node.get_parameter('{PART_SETTING}').value)
    node.destroy_node()
    rclpy.shutdown()
""")


@pytest.mark.ros
def test_the_driver_node_picks_the_toy_part_s_stream(sensor_copy):
    assert _run(sensor_copy, '-c', START_DRIVER).split()[-2:] == ['AdisStream', '200.0']
    report = _pytest(sensor_copy, 'test/ros/test_devices.py::test_every_device_has_a_stream')
    assert re.search(r'^PASSED \S+::test_every_device_has_a_stream$', report, re.M)
