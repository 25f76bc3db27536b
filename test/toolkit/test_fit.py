"""``mlx-tempcomp fit``: every model, what it prints, and the parameter file the node loads."""

import math

from cli_checks import assert_user_error, node_values
from measured_data import MEASURED_CSV
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.effects import LinearBtc, polynomial_model
from mlx_tempcomp.core.fitting.chain_fit import ChainSettings, fit_chain
from mlx_tempcomp.core.node_models.chain import ChainModel, STAGE_NAMES
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.ros import messages
from mlx_tempcomp.simulation.turntable import simulate_turntable
import numpy as np
from numpy.polynomial.polynomial import polyval
import pytest
from ros_harness import by_stamp
from sensor_msgs.msg import Imu
import yaml

TIMEOUT_S = 20.0
NOISE_RAD_S = 0.002
# True bias in x = (T - 22.5) / 62.5: cubic on gyro_x, quadratic on gyro_z (rad/s).
TRUE_BIAS = {'x': (0.01, 0.02, -0.005, 0.03), 'z': (-0.02, 0.01, 0.04)}


def true_bias_rad_s(axis, temperature_c):
    return np.polynomial.polynomial.polyval((np.asarray(temperature_c) - 22.5) / 62.5,
                                            TRUE_BIAS[axis])


def sweep_csv(tmp_path, samples=4000, seed=0):
    """Write two slow -40..85 C cycles with the true bias plus white noise; return the path."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(samples) * 0.5
    temperature_c = 22.5 - 62.5 * np.cos(2.0 * np.pi * 2.0 * np.arange(samples) / samples)
    columns = {'time': time_s, 'temperature': temperature_c}
    for axis in TRUE_BIAS:
        columns[f'gyro_{axis}'] = true_bias_rad_s(axis, temperature_c) + \
            rng.normal(0.0, NOISE_RAD_S, samples)
    path = tmp_path / 'sweep.csv'
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',',
               header=','.join(columns), comments='')
    return str(path)


def model_from_yaml(path, node_name='compensation_node'):
    """Build the polynomial model the parameter file describes; return (axes, model)."""
    with open(path) as stream:
        values = yaml.safe_load(stream)[node_name]['ros__parameters']
    polynomial = values['polynomial']
    model = polynomial_model(
        tuple(polynomial['bias'][axis] for axis in values['axes']),
        reference_temperature_c=polynomial['reference_temperature_c'],
        temperature_scale_c=polynomial['temperature_scale_c'],
        temperature_min_c=polynomial['temperature_min_c'],
        temperature_max_c=polynomial['temperature_max_c'])
    return tuple(values['axes']), model


@pytest.fixture
def fitted(tmp_path, capsys):
    """Fit the synthetic sweep, any order against the cubic; give (parameter file, output)."""
    out_path = tmp_path / 'params.yaml'
    assert main(['fit', sweep_csv(tmp_path), '--baseline-margin', '0', '--out',
                 str(out_path)]) == 0
    return out_path, capsys.readouterr().out


def test_fit_chooses_true_orders_and_reproduces_bias(fitted):
    """The sweep's x is a true cubic, z a quadratic: with no margin asked for, z beats it."""
    out_path, out = fitted
    assert ('orders (chosen on held-out blocks, round-robin: 20 blocks dealt to 5 folds): '
            'x 3, z 2') in out
    assert out.startswith(f'{out_path.parent / "sweep.csv"}: 4000 rows used; skipped: none\n')
    assert 'fitted temperature range: -40.00 to 85.00 C' in out
    text = out_path.read_text()
    assert "- 'x'" in text and "- 'z'" in text, 'axes must be quoted for rcl'
    axes, model = model_from_yaml(out_path)
    assert axes == ('x', 'z')
    assert [len(t.bias) for t in model.terms] == [4, 3]
    section = yaml.safe_load(text)['compensation_node']['ros__parameters']['polynomial']
    numbers = [section[k] for k in section if k != 'bias'] + \
        [c for coefficients in section['bias'].values() for c in coefficients]
    assert all(isinstance(v, float) for v in numbers), 'rcl refuses an int for a double'
    temperature_c = np.linspace(-40.0, 85.0, 200)
    bias = np.column_stack([true_bias_rad_s(axis, temperature_c) for axis in axes])
    residual = model.correct(bias, temperature_c).rate_rad_s
    assert np.max(np.abs(residual)) < NOISE_RAD_S / 4


def test_fit_says_first_how_the_model_does_on_held_out_blocks_and_writes_its_covariance(
        fitted):
    """A true polynomial and white noise: the covariance is the noise, and says so."""
    out_path, out = fitted
    lines = out.splitlines()
    assert lines[1].startswith('forward held-out blocks (each predicted by a fit on the blocks '
                               'before it, as the node runs a model later in time): the model '
                               "written against PX4's cubic clamped at its range")
    assert lines[2].startswith('error left (RMS per sample): x ')
    covariance = next(line for line in lines if line.startswith('covariance (model_error.*'))
    values = yaml.safe_load(out_path.read_text())['compensation_node']['ros__parameters']
    error = values['model_error']
    assert error['rate_noise_rad_s'] == pytest.approx([NOISE_RAD_S] * 2, rel=0.05)
    # The polynomial is the truth: what the held-out blocks leave is the noise, which the
    # table does not count twice.
    for axis in ('x', 'z'):
        assert max(error[f'{axis}_rad_s']) < NOISE_RAD_S / 2
    per_sample = covariance.split('per sample ')[1].split(';')[0]
    for cell in per_sample.split(', '):
        assert 0.9 < float(cell.split()[1]) < 1.1, covariance
    assert '# model_error: the white noise of a sample per axis' in out_path.read_text()


def test_fit_writes_the_cubic_unless_an_order_beats_it_fold_by_fold(tmp_path, capsys):
    """The sweep's z is a true quadratic, as good as the cubic that holds it: the cubic."""
    assert main(['fit', sweep_csv(tmp_path), '--validation', 'forward', '--out',
                 str(tmp_path / 'p.yaml')]) == 0
    out = capsys.readouterr().out
    assert ('orders (chosen on held-out blocks, forward over 20 blocks: blocks 5 to 19 each '
            'predicted from the blocks before it): x 3, z 3') in out
    assert ('z: the PX4-style cubic unless another order beats it on held-out blocks, fold by '
            'fold and by the margin (forward over 20 blocks: blocks 5 to 19 each predicted '
            'from the blocks before it): no order does, so the cubic is written') in out


def test_fit_with_fixed_order_and_node_name(tmp_path, capsys):
    out_path = tmp_path / 'params.yaml'
    code = main(['fit', sweep_csv(tmp_path), '--order', '4', '--node-name', 'gyro_comp',
                 '--out', str(out_path)])
    assert code == 0
    assert 'orders (given by --order): x 4, z 4' in capsys.readouterr().out
    _, model = model_from_yaml(out_path, 'gyro_comp')
    assert [len(t.bias) for t in model.terms] == [5, 5]


@pytest.mark.ros
def test_compensation_node_loads_the_fitted_file(fitted, launcher, probe, tmp_path):
    out_path, _ = fitted
    axes, model = model_from_yaml(out_path)
    launcher.start('compensation_node', 'compensation_node', extra_args=[
        '--params-file', str(out_path),
        '-p', f'recalibration.state_file:={tmp_path / "zro_state.yaml"}'])
    received = probe.subscribe(Imu, 'imu/data')
    imu_publisher, temperature_publisher = probe.raw_publishers(TIMEOUT_S, launcher)
    rng = np.random.default_rng(1)
    indices = messages.axis_indices(axes)
    inputs = {}   # stamp in ns -> (raw rates in rad/s, temperature in degC)

    def publish_pair():
        """Publish one raw pair, temperatures sweeping -50..95 C (beyond the fit: clamped)."""
        stamp_ns = 1_000_000_000 + len(inputs) * 10_000_000
        stamp = messages.ns_to_stamp(stamp_ns)
        raw_rad_s = rng.normal(0.0, 0.1, len(axes))
        temperature_c = -50.0 + 145.0 * (len(inputs) % 30) / 29
        imu_publisher.publish(messages.imu_message(stamp, 'imu_link', indices, raw_rad_s,
                                                   [0.0] * 9))
        temperature_publisher.publish(messages.temperature_message(stamp, 'imu_link',
                                                                   temperature_c))
        inputs[stamp_ns] = (raw_rad_s, temperature_c)
        probe.spin_once(0.02)
        return len(received) >= 30

    # Keep publishing until the node answers: it may match the publishers after the probe.
    probe.spin_until(publish_pair, TIMEOUT_S, 'compensated samples', launcher)
    probe.drain()
    outputs = by_stamp(received)
    assert set(outputs) <= set(inputs)
    stamps = sorted(outputs)
    raw_rad_s = np.array([inputs[s][0] for s in stamps])
    temperature_c = np.array([inputs[s][1] for s in stamps])
    expected = model.correct(raw_rad_s, temperature_c).rate_rad_s
    got = np.array([messages.imu_rates(outputs[s], indices) for s in stamps])
    assert np.max(np.abs(got - expected)) <= 1e-12
    assert np.mean(np.abs(got - raw_rad_s)) > 0.01, 'the correction is not the identity'
    assert min(temperature_c) < model.temperature_min_c, 'clamping exercised'


def test_measured_sweep_with_tofupilot_preset(tmp_path, capsys):
    if not MEASURED_CSV.is_file():
        pytest.skip(f'measured data not present: {MEASURED_CSV}')
    out_path = tmp_path / 'measured.yaml'
    assert main(['fit', str(MEASURED_CSV), '--preset', 'tofupilot', '--out',
                 str(out_path)]) == 0
    out = capsys.readouterr().out
    assert ('orders (chosen on held-out blocks, round-robin: 20 blocks dealt to 5 folds): '
            'x 3, y 3, z 3') in out
    assert 'skipped: dropped by preset 1' in out
    # Round-robin, the coldest block (6) and the hottest (14) reach beyond every other
    # fold's blocks, so their folds' polynomials run clamped there.
    assert 'held-out rows outside the temperature range of their training blocks (clamped): ' \
        in out
    assert '  block 6: 70% of 420 rows outside -16.33 .. 73.97 C' in out
    axes, model = model_from_yaml(out_path)
    assert axes == ('x', 'y', 'z')
    assert model.temperature_min_c < model.temperature_max_c


def test_missing_file_is_a_user_error(tmp_path, capsys):
    code = main(['fit', str(tmp_path / 'absent.csv'), '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, 'absent.csv')
    assert not (tmp_path / 'p.yaml').exists()


def test_narrow_span_for_the_order_is_a_user_error(tmp_path, capsys):
    path = tmp_path / 'narrow.csv'
    rows = [f'{i * 0.1},{25.0 + i * 0.005},{0.001 * i}' for i in range(100)]
    path.write_text('time,temperature,gyro_z\n' + '\n'.join(rows) + '\n')
    code = main(['fit', str(path), '--order', '6', '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, 'temperature span')
    assert not (tmp_path / 'p.yaml').exists()


def test_unknown_preset_is_a_user_error(tmp_path, capsys):
    code = main(['fit', sweep_csv(tmp_path), '--preset', 'nope', '--out',
                 str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, "unknown column preset 'nope'")


def test_bad_column_spec_is_a_user_error(tmp_path, capsys):
    code = main(['fit', sweep_csv(tmp_path), '--columns', 'bogus=gz', '--out',
                 str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, 'bogus')


def write_csv(path, columns):
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',',
               header=','.join(columns), comments='', fmt='%.17g')
    return str(path)


def test_polynomial_on_turntable_data_fits_gyro_minus_reference(tmp_path, capsys):
    temperature_c = np.linspace(-20.0, 60.0, 400)
    reference = np.where(np.arange(400) % 50 < 25, 0.5, -0.3)
    bias = 0.01 + 2e-4 * (temperature_c - 20.0)
    path = write_csv(tmp_path / 'table.csv', {
        'time': np.arange(400) * 0.1, 'temperature': temperature_c,
        'gyro_z': reference + bias, 'ref_z': reference})
    out_path = tmp_path / 'p.yaml'
    assert main(['fit', path, '--order', '1', '--out', str(out_path)]) == 0
    assert 'fitted to the gyro rate minus the reference rate' in capsys.readouterr().out
    model = build_model(node_values(out_path))
    residual = model.correct((reference + bias)[:, None], temperature_c).rate_rad_s[:, 0]
    np.testing.assert_allclose(residual, reference, rtol=0.0, atol=1e-12)


def test_relative_model_is_the_seed_002_correction(tmp_path, capsys):
    path = sweep_csv(tmp_path)
    out_path = tmp_path / 'relative.yaml'
    assert main(['fit', path, '--model', 'relative', '--order', '3', '--true-temperature',
                 '30', '--out', str(out_path)]) == 0
    out = capsys.readouterr().out
    assert 'T_true = 30.00 C (given by --true-temperature)' in out
    assert "written as model 'polynomial' whose bias is zero at T_true" in out
    values = node_values(out_path)
    assert values['model'] == 'polynomial'
    model = build_model(values)
    data = np.loadtxt(path, delimiter=',', skiprows=1)
    temperature_c, rate_rad_s = data[:, 1], data[:, 2:]
    corrected = model.correct(rate_rad_s, temperature_c).rate_rad_s
    for axis in range(2):
        # The note's own formula, p fitted on the measured temperature (float64).
        p = np.polyfit(temperature_c, rate_rad_s[:, axis], 3)
        expected = rate_rad_s[:, axis] - (np.polyval(p, temperature_c) - np.polyval(p, 30.0))
        np.testing.assert_allclose(corrected[:, axis], expected, rtol=0.0, atol=1e-12)


def test_relative_true_temperature_defaults_to_the_mean(tmp_path, capsys):
    path = sweep_csv(tmp_path)
    out_path = tmp_path / 'relative.yaml'
    assert main(['fit', path, '--model', 'relative', '--baseline-margin', '0', '--out',
                 str(out_path)]) == 0
    out = capsys.readouterr().out
    mean_c = np.mean(np.loadtxt(path, delimiter=',', skiprows=1)[:, 1])
    assert f'T_true = {mean_c:.2f} C (mean temperature of the data)' in out
    assert ('orders (chosen on held-out blocks, round-robin: 20 blocks dealt to 5 folds): '
            'x 3, z 2') in out
    model = build_model(node_values(out_path))
    np.testing.assert_allclose(model.correct([[0.1, -0.2]], [mean_c]).rate_rad_s,
                               [[0.1, -0.2]], rtol=0.0, atol=1e-15)


def test_relative_true_temperature_outside_the_data_is_a_user_error(tmp_path, capsys):
    code = main(['fit', sweep_csv(tmp_path), '--model', 'relative', '--true-temperature',
                 '90', '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, 'true temperature 90 C is outside the fitted range')
    assert not (tmp_path / 'p.yaml').exists()


def test_linear_btc_recovers_the_slope_and_prints_table_6(tmp_path, capsys):
    rng = np.random.default_rng(3)
    temperature_c = 25.0 + 10.0 * np.sin(np.linspace(0.0, 4.0 * np.pi, 3000))
    slope_rad_s_per_c = math.radians(0.04)   # the bias slope of the note's Table 6
    gyro_z = 0.02 + slope_rad_s_per_c * (temperature_c - 25.0) + \
        rng.normal(0.0, NOISE_RAD_S, 3000)
    path = write_csv(tmp_path / 'btc.csv', {'time': np.arange(3000) * 0.01,
                                            'temperature': temperature_c, 'gyro_z': gyro_z})
    out_path = tmp_path / 'btc.yaml'
    assert main(['fit', path, '--model', 'linear_btc', '--t3', '25', '--table-step', '0.02',
                 '--out', str(out_path)]) == 0
    out = capsys.readouterr().out
    assert 'T3 = 25.00 C (given by --t3)' in out
    rows = {line.split()[0]: line.split()[1:] for line in out.splitlines()
            if line.split() and line.split()[0] in ('+0.12', '0', '-0.12')}
    assert set(rows) == {'+0.12', '0', '-0.12'} and rows['0'] == ['0', '0']
    # Slope error: noise / (sqrt(3000) x 7.1 C) = 5e-6 rad/s/C; BTC is minus the slope.
    tolerance_rad_s_per_c = 2.5e-5
    for offset, correction_dps in (('+0.12', -0.0048), ('-0.12', 0.0048)):
        rad_s, dps = (float(cell) for cell in rows[offset])
        assert rad_s == pytest.approx(math.radians(correction_dps),
                                      abs=0.12 * tolerance_rad_s_per_c)
        assert dps == pytest.approx(correction_dps, abs=0.12 * math.degrees(tolerance_rad_s_per_c))
    model = build_model(node_values(out_path))
    assert model.name == 'linear_btc'
    line = LinearBtc.of(model)
    assert line.btc_rad_s_per_c[0] == pytest.approx(-slope_rad_s_per_c,
                                                    abs=tolerance_rad_s_per_c)
    assert line.pbc_rad_s[0] == pytest.approx(-0.02, abs=2e-4)
    corrected = model.correct(gyro_z, temperature_c).rate_rad_s
    assert np.std(corrected) == pytest.approx(NOISE_RAD_S, rel=0.1)


@pytest.fixture(scope='module')
def turntable():
    return simulate_turntable(seed=4)


def turntable_csv(path, session, drop=()):
    columns = {'time': session.time_s, 'temperature': session.temperature_c,
               'temperature_2': session.temperature_2_c}
    columns.update((f'gyro_{a}', session.measured_rad_s[:, i]) for i, a in enumerate('xyz'))
    columns.update((f'ref_{a}', session.reference_rad_s[:, i]) for i, a in enumerate('xyz'))
    return write_csv(path, {k: v for k, v in columns.items() if k not in drop})


def test_chain_fit_from_csv_recovers_the_truth(tmp_path, capsys, turntable):
    out_path = tmp_path / 'chain.yaml'
    assert main(['fit', turntable_csv(tmp_path / 'table.csv', turntable), '--model', 'chain',
                 '--out', str(out_path)]) == 0
    out = capsys.readouterr().out
    assert 'full scale: 300 deg/s (largest reference rate); nonlinearity order 5' in out
    assert 'T 20.00 C (mean over the plateaus), T2 25.03 C (mean over the plateaus)' in out
    rms = {}
    for line in out.splitlines():
        fields = line.split()
        if len(fields) == 9 and fields[1] == 'all':
            rms[fields[0]] = float(fields[8])
    assert list(rms) == list(STAGE_NAMES)
    assert all(after < before for before, after in zip(rms.values(), list(rms.values())[1:]))
    values = node_values(out_path)
    model = build_model(values)
    assert isinstance(model, ChainModel)
    chain, truth = model.chain, turntable.truth.chain()
    # Tolerances of test_core_chain.py (same seed and protocol); see its noise budget.
    x = np.linspace(-1.0, 1.0, 201)
    for axis in range(3):
        assert np.max(np.abs(polyval(x, chain.nonlinearity_rad_s[axis]) -
                             polyval(x, truth.nonlinearity_rad_s[axis]))) < 8e-4
        assert np.max(np.abs(polyval(x, chain.sensitivity_slope_rad_s_per_c[axis]) -
                             polyval(x, truth.sensitivity_slope_rad_s_per_c[axis]))) < 1.2e-5
    np.testing.assert_allclose(chain.offset_gradient_rad_s_per_c,
                               truth.offset_gradient_rad_s_per_c, rtol=0.0, atol=1.2e-5)
    np.testing.assert_allclose(chain.offset_2_gradient_rad_s_per_c,
                               truth.offset_2_gradient_rad_s_per_c, rtol=0.0, atol=3e-5)
    np.testing.assert_allclose(chain.misalignment, truth.misalignment, rtol=0.0, atol=2.5e-5)
    # The file holds exactly the chain fit_chain gives with the documented defaults.
    on = turntable.plateau_id >= 0
    expected = fit_chain(turntable.reference_rad_s, turntable.measured_rad_s,
                         turntable.temperature_c, turntable.temperature_2_c,
                         turntable.plateau_id, ChainSettings(
                             full_scale_rad_s=np.max(np.abs(turntable.reference_rad_s)),
                             reference_temperature_c=np.mean(turntable.temperature_c[on]),
                             reference_temperature_2_c=np.mean(
                                 turntable.temperature_2_c[on]))).chain
    assert chain == expected


@pytest.mark.parametrize('drop, needle', [
    (('temperature_2',), 'missing temperature_2'),
    (('ref_x', 'ref_y', 'ref_z'), 'missing ref_x, ref_y, ref_z'),
    (('gyro_y', 'ref_y', 'temperature_2'), 'missing gyro_y, ref_y, temperature_2'),
])
def test_chain_missing_columns_are_a_user_error(tmp_path, capsys, turntable, drop, needle):
    path = turntable_csv(tmp_path / 'table.csv', turntable, drop)
    code = main(['fit', path, '--model', 'chain', '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, '--model chain needs the columns gyro_x|y|z, ref_x|y|z '
                                    f'and temperature_2; {needle}')
    assert not (tmp_path / 'p.yaml').exists()


def test_chain_data_that_cannot_support_a_stage_is_a_user_error(tmp_path, capsys, turntable):
    code = main(['fit', turntable_csv(tmp_path / 'table.csv', turntable), '--model', 'chain',
                 '--reference-temperature', '30', '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, 'nonlinearity of axis x: 0 rate levels within 2 C of 30 C')


@pytest.mark.parametrize('args, needle', [
    (['--t3', '20'], '--t3 does not apply to --model polynomial'),
    (['--model', 'linear_btc', '--order', '2'], '--order does not apply to --model linear_btc'),
    (['--model', 'chain', '--max-order', '3', '--blocks', '4'],
     '--max-order, --blocks do not apply to --model chain'),
    (['--model', 'relative', '--full-scale-dps', '300'],
     '--full-scale-dps does not apply to --model relative'),
])
def test_options_of_another_model_are_a_user_error(tmp_path, capsys, args, needle):
    code = main(['fit', sweep_csv(tmp_path), *args, '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, needle)


def test_linear_btc_narrow_span_is_a_user_error(tmp_path, capsys):
    path = tmp_path / 'narrow.csv'
    rows = [f'{i * 0.1},{25.0 + i * 0.005},{0.001 * i}' for i in range(100)]
    path.write_text('time,temperature,gyro_z\n' + '\n'.join(rows) + '\n')
    code = main(['fit', str(path), '--model', 'linear_btc', '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, 'a bias slope needs a temperature span of at least 1.0 C')


def test_chain_without_plateaus_is_a_user_error(tmp_path, capsys):
    ramp = np.linspace(-1.0, 1.0, 200)
    columns = {'time': np.arange(200) * 0.1, 'temperature': np.full(200, 20.0),
               'temperature_2': np.full(200, 25.0)}
    columns.update((f'gyro_{a}', ramp) for a in 'xyz')
    columns.update((f'ref_{a}', ramp) for a in 'xyz')
    code = main(['fit', write_csv(tmp_path / 'ramp.csv', columns), '--model', 'chain',
                 '--out', str(tmp_path / 'p.yaml')])
    assert_user_error(code, capsys, 'no plateau: the reference rate and temperatures never '
                                    'hold steady for 10 samples')
