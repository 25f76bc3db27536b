"""
``mlx-tempcomp diagnose``: the loop finds an undeclared effect, adds nothing to clean data.

Data come from the project's simulator (`GyroPhysics` with `Effects`): three
-20..70 C cycles at 2 C/min sampled at 1 Hz, a cubic ZRO, white rate noise,
and one effect the diagnosis is not told about.
"""

import contextlib
import functools
import io
import json
import math

from mlx_tempcomp.cli import main
from mlx_tempcomp.core.diagnosis import diagnose, DiagnosisSettings
from mlx_tempcomp.core.effects import EffectModel
from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.simulation.physics import (Effects, GyroPhysics, GyroTruth, Noise, Scenario,
                                             ThermalProfile)
from mlx_tempcomp.sources.recording import Recording
import numpy as np
import pytest
import yaml

RATE_HZ = 1.0
NOISE_DPS = 0.02
TEMPERATURE_NOISE_C = 0.02
STEP_TIME_S = 9000.0
LAG_S = 200.0
EFFECTS = {
    'clean': Effects(),
    'thermal_lag': Effects(thermal_lag_s=LAG_S),
    'hysteresis': Effects(hysteresis_dps=0.2, hysteresis_width_c=5.0),
    'bias_step': Effects(bias_steps=((STEP_TIME_S, 0.2),)),
}
STEP_STRUCTURE = {'effect', 'parameters', 'rms_before', 'rms_after', 'peak_before',
                  'peak_after'}


@functools.lru_cache(maxsize=None)
def simulated(name: str, seed: int = 0) -> tuple:
    """Return (time s, sensor temperature C, rate rad/s) of the simulated device."""
    profile = ThermalProfile.cycle((70.0, -20.0) * 3, rate_c_per_min=2.0, start_c=25.0)
    truth = GyroTruth(zro_dps_coefficients=(0.5, 0.02, 2e-4, -2e-6), effects=EFFECTS[name],
                      noise=Noise(bias_instability_dps=0.0))
    physics = GyroPhysics(truth, Scenario(thermal=profile), seed=seed)
    time_s = np.arange(1, int(profile.duration_s * RATE_HZ) + 1) / RATE_HZ
    temperature_c = np.empty(time_s.size)
    zro_dps = np.empty(time_s.size)
    for i, t in enumerate(time_s):
        physics.advance(float(t))
        temperature_c[i] = physics.state.sensor_c
        zro_dps[i] = physics.zro_offset_dps()
    rng = np.random.default_rng(seed + 1)
    rate_rad_s = np.radians(zro_dps + rng.normal(0.0, NOISE_DPS, time_s.size))
    return time_s, temperature_c + rng.normal(0.0, TEMPERATURE_NOISE_C, time_s.size), rate_rad_s


def recording(name: str) -> Recording:
    time_s, temperature_c, rate_rad_s = simulated(name)
    return Recording(name, time_s, temperature_c, ('z',), rate_rad_s[:, None])


@pytest.mark.parametrize('effect', ['thermal_lag', 'hysteresis', 'bias_step'])
def test_diagnose_names_the_undeclared_effect_and_halves_the_error(effect):
    result = diagnose(recording(effect))
    steps = result.per_axis[0].steps
    assert [s.effect for s in steps[:2]] == ['temperature_polynomial', effect]
    assert steps[1].after.rms_rad_s <= 0.5 * steps[1].before.rms_rad_s
    # Held-out errors chain: each step starts where the one before ended.
    assert steps[1].before == steps[0].after
    parameters = steps[1].parameters
    if effect == 'thermal_lag':
        assert parameters['thermal_lag_s'] == pytest.approx(LAG_S, rel=0.15)
    elif effect == 'bias_step':
        assert parameters['time_s'] == pytest.approx(STEP_TIME_S, abs=5.0)
        assert parameters['step_rad_s'] == pytest.approx(math.radians(0.2), rel=0.1)
    else:
        assert parameters['hysteresis_rad_s'] > 0.0


def test_diagnose_adds_nothing_to_clean_data():
    result = diagnose(recording('clean'))
    axis = result.per_axis[0]
    assert axis.effects == ('temperature_polynomial',)
    assert axis.order == 3
    assert {c.effect for c in axis.rejected} == {'thermal_lag', 'hysteresis', 'time_drift',
                                                 'bias_step'}
    assert all(c.reason for c in axis.rejected)
    assert result.model.terms[0].effects == ('temperature_polynomial',)


def test_diagnose_with_a_reference_rate_finds_scale_cross_axis_and_nonlinearity():
    """Rate plateaus with a reference: x has a scale factor in T and sees y; y is nonlinear."""
    rng = np.random.default_rng(3)
    samples = 20000
    time_s = np.arange(samples, dtype=np.float64)
    temperature_c = 25.0 + 40.0 * np.sin(2.0 * np.pi * time_s / (samples / 3))
    x = (temperature_c - 25.0) / 40.0
    reference = np.repeat(rng.choice([-2.0, -1.0, 0.0, 1.0, 2.0], size=(samples // 50, 2)),
                          50, axis=0)
    gyro = np.column_stack([
        reference[:, 0] * (1.0 + 0.01 * x) + 0.01 + 0.005 * x + 0.003 * reference[:, 1],
        reference[:, 1] + 0.002 * reference[:, 1] ** 2 - 0.003 * x ** 2])
    noise_rad_s = 0.001
    gyro += rng.normal(0.0, noise_rad_s, gyro.shape)
    result = diagnose(Recording('table', time_s, temperature_c, ('x', 'y'), gyro,
                                reference_rad_s=reference))
    x_axis, y_axis = result.per_axis
    assert x_axis.effects == ('temperature_polynomial', 'scale_factor_temperature',
                              'cross_axis')
    assert y_axis.effects == ('temperature_polynomial', 'rate_nonlinearity')
    assert result.model.terms[0].scale == pytest.approx((0.0, 0.01), abs=5e-4)
    assert result.model.terms[0].cross_axis == pytest.approx((0.0, 0.003), abs=2e-4)
    assert result.model.terms[1].nonlinearity == pytest.approx((0.002,), abs=2e-4)
    for axis in result.per_axis:  # down to the white noise (one sample per 1 s bin)
        assert axis.steps[-1].after.rms_rad_s < 1.2 * noise_rad_s


def test_diagnose_refuses_data_it_cannot_judge():
    time_s, temperature_c, rate_rad_s = simulated('clean')
    few = Recording('few', time_s[:30], temperature_c[:30], ('z',), rate_rad_s[:30, None])
    with pytest.raises(CalibrationError, match='30 rows to diagnose'):
        diagnose(few)
    flat = Recording('flat', time_s, np.full(time_s.size, 25.0), ('z',), rate_rad_s[:, None])
    with pytest.raises(CalibrationError, match='temperature spans 0 C'):
        diagnose(flat)


def write_csv(tmp_path, rows=None) -> str:
    """Write gyro_x with a thermal lag and gyro_z clean (a cubic of the same temperature)."""
    time_s, temperature_c, rate_x = simulated('thermal_lag')
    rng = np.random.default_rng(7)
    rate_z = np.radians(np.polynomial.polynomial.polyval(temperature_c - 25.0,
                                                         (-0.3, 0.01, -1e-4, 3e-6))
                        + rng.normal(0.0, NOISE_DPS, time_s.size))
    columns = {'time': time_s, 'temperature': temperature_c, 'gyro_x': rate_x,
               'gyro_z': rate_z}
    table = np.column_stack(list(columns.values()))[slice(rows)]
    path = tmp_path / 'sweep.csv'
    np.savetxt(path, table, delimiter=',', header=','.join(columns), comments='',
               fmt='%.17g')
    return str(path)


@pytest.fixture(scope='module')
def cli_run(tmp_path_factory):
    """Run diagnose on the CSV with a test fraction; give (csv, out dir, stdout, stderr)."""
    tmp_path = tmp_path_factory.mktemp('diagnose')
    path = write_csv(tmp_path)
    out = tmp_path / 'out'
    # capsys is per test; this run is shared by the module.
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(['diagnose', path, '--out', str(out), '--test-fraction', '0.25',
                     '--progress'])
    assert code == 0, stderr.getvalue()
    return path, out, stdout.getvalue(), stderr.getvalue()


def test_cli_writes_report_plots_and_parameters(cli_run):
    _, out, stdout, stderr = cli_run
    for name in ('report.md', 'report.json', 'params.yaml', 'residual_vs_temperature.png',
                 'residual_vs_time.png', 'error_per_step.png'):
        assert (out / name).stat().st_size > 0, name
    assert (out / 'error_per_step.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'axis x: held-out RMS' in stdout and 'thermal_lag' in stdout
    assert 'skipped acceleration_sensitivity: needs columns acc_x, acc_y, acc_z' in stdout
    assert 'diagnose: round 1' in stderr, 'the progress bar was asked for'
    report_md = (out / 'report.md').read_text()
    assert '## Axis x' in report_md and '### Test set' in report_md


def test_cli_report_json_schema(cli_run):
    _, out, _, _ = cli_run
    report = json.loads((out / 'report.json').read_text())
    assert set(report['axes']) == {'x', 'z'}
    x, z = report['axes']['x'], report['axes']['z']
    for axis in (x, z):
        assert axis['steps'][0]['effect'] == 'temperature_polynomial'
        for step in axis['steps']:
            assert STEP_STRUCTURE <= set(step)
            numbers = STEP_STRUCTURE - {'effect', 'parameters'}
            assert all(isinstance(step[key], float) for key in numbers)
        for candidate in axis['rejected']:
            assert {'effect', 'round', 'held_out_gain', 'reason'} <= set(candidate)
        skipped = {s['effect']: s['reason'] for s in axis['skipped']}
        assert skipped['secondary_temperature'] == 'needs column temperature_2'
        assert skipped['cross_axis'] == 'needs reference columns ref_x, ref_z'
    assert [s['effect'] for s in x['steps']][:2] == ['temperature_polynomial', 'thermal_lag']
    assert [s['effect'] for s in z['steps']] == ['temperature_polynomial']
    for scope in ('cross_validation', 'test'):
        methods = report['comparison'][scope]
        assert set(methods) == {'none', 'px4_cubic', 'temperature_polynomial', 'diagnosed'}
        assert methods['diagnosed']['x']['rms'] < 0.5 * methods['px4_cubic']['x']['rms']


def flat_parameters(tree: dict, prefix: str = '') -> dict:
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(flat_parameters(value, f'{prefix}{key}.'))
        else:
            flat[f'{prefix}{key}'] = value
    return flat


def test_cli_parameter_file_round_trips_and_reproduces_the_test_error(cli_run):
    path, out, _, _ = cli_run
    values = yaml.safe_load((out / 'params.yaml').read_text())['compensation_node'][
        'ros__parameters']
    assert values['model'] == 'effects' and values['axes'] == ['x', 'z']
    model = EffectModel.from_parameters(flat_parameters(values['effects']), values['axes'])
    table = np.genfromtxt(path, delimiter=',', names=True)
    rows = len(table)
    recording = Recording('csv', table['time'], table['temperature'], ('x', 'z'),
                          np.column_stack([table['gyro_x'], table['gyro_z']]))
    expected = diagnose(recording, DiagnosisSettings(test_fraction=0.25))
    assert model == expected.model
    # The node-side model, run from the record's start, gives the reported test error.
    corrected = model.correct(recording.gyro_rad_s, recording.temperature_c,
                              time_s=recording.time_s).rate_rad_s
    test = slice(rows - int(math.floor(0.25 * rows)), rows)
    seconds = np.floor(recording.time_s[test] - recording.time_s[test][0])
    starts = np.flatnonzero(np.concatenate(([True], seconds[1:] != seconds[:-1])))
    counts = np.diff(np.append(starts, seconds.size))
    binned = np.add.reduceat(corrected[test], starts) / counts[:, None]
    rms = np.sqrt(np.sum(counts[:, None] * binned ** 2, axis=0) / counts.sum())
    report = json.loads((out / 'report.json').read_text())
    reported = report['comparison']['test']['diagnosed']
    assert rms == pytest.approx([reported['x']['rms'], reported['z']['rms']], rel=1e-9)


def assert_user_error(code, capsys, needle):
    _, err = capsys.readouterr()
    assert code == 2
    assert err.startswith('error: ') and err.count('\n') == 1, err
    assert needle in err and 'Traceback' not in err


def test_cli_bad_input_exits_2(tmp_path, capsys):
    out = str(tmp_path / 'out')
    assert_user_error(main(['diagnose', str(tmp_path / 'missing.csv'), '--out', out]),
                      capsys, 'missing.csv')
    no_temperature = tmp_path / 'no_temperature.csv'
    no_temperature.write_text('time,gyro_x\n0,0.1\n1,0.2\n')
    assert_user_error(main(['diagnose', str(no_temperature), '--out', out]), capsys,
                      'temperature')
    short = write_csv(tmp_path, rows=25)
    assert_user_error(main(['diagnose', short, '--out', out]), capsys,
                      '25 rows to diagnose')
    assert not (tmp_path / 'out').exists()
