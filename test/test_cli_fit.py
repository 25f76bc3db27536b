"""The ``mlx-tempcomp fit`` command: orders, coefficients, and the parameter file in the node."""

from pathlib import Path

from mlx_tempcomp.cli import main
from mlx_tempcomp.core.models import PolynomialModel
from mlx_tempcomp.ros import messages
from mlx_tempcomp.ros.qos import SENSOR_INPUT_QOS
import numpy as np
import pytest
from ros_harness import by_stamp
from sensor_msgs.msg import Imu, Temperature
import yaml

MEASURED_CSV = (Path(__file__).resolve().parents[2] / 'shared' / 'data'
                / 'tofupilot_imu_thermal_sweep' / 'imu_raw_data.csv')
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
    """Build the PolynomialModel the parameter file describes; return (axes, model)."""
    with open(path) as stream:
        values = yaml.safe_load(stream)[node_name]['ros__parameters']
    polynomial = values['polynomial']
    model = PolynomialModel(
        bias_coefficients=tuple(polynomial['bias'][axis] for axis in values['axes']),
        reference_temperature_c=polynomial['reference_temperature_c'],
        temperature_scale_c=polynomial['temperature_scale_c'],
        temperature_min_c=polynomial['temperature_min_c'],
        temperature_max_c=polynomial['temperature_max_c'])
    return tuple(values['axes']), model


def assert_user_error(code, capsys, needle):
    out, err = capsys.readouterr()
    assert code == 2
    assert err.startswith('error: ') and err.count('\n') == 1, err
    assert needle in err
    assert 'Traceback' not in err


@pytest.fixture
def fitted(tmp_path, capsys):
    """Fit the synthetic sweep; give (parameter file path, printed output)."""
    out_path = tmp_path / 'params.yaml'
    assert main(['fit', sweep_csv(tmp_path), '--out', str(out_path)]) == 0
    return out_path, capsys.readouterr().out


def test_fit_chooses_true_orders_and_reproduces_bias(fitted):
    out_path, out = fitted
    assert 'orders (chosen by 5-block cross-validation): x 3, z 2' in out
    assert 'rows used: 4000; skipped: none' in out
    assert 'fitted temperature range: -40.00 to 85.00 C' in out
    text = out_path.read_text()
    assert "- 'x'" in text and "- 'z'" in text, 'axes must be quoted for rcl'
    axes, model = model_from_yaml(out_path)
    assert axes == ('x', 'z')
    assert [len(c) for c in model.bias_coefficients] == [4, 3]
    section = yaml.safe_load(text)['compensation_node']['ros__parameters']['polynomial']
    numbers = [section[k] for k in section if k != 'bias'] + \
        [c for coefficients in section['bias'].values() for c in coefficients]
    assert all(isinstance(v, float) for v in numbers), 'rcl refuses an int for a double'
    temperature_c = np.linspace(-40.0, 85.0, 200)
    bias = np.column_stack([true_bias_rad_s(axis, temperature_c) for axis in axes])
    residual = model.correct(bias, temperature_c).rate_rad_s
    assert np.max(np.abs(residual)) < NOISE_RAD_S / 4


def test_fit_with_fixed_order_and_node_name(tmp_path, capsys):
    out_path = tmp_path / 'params.yaml'
    code = main(['fit', sweep_csv(tmp_path), '--order', '4', '--node-name', 'gyro_comp',
                 '--out', str(out_path)])
    assert code == 0
    assert 'orders (given by --order): x 4, z 4' in capsys.readouterr().out
    _, model = model_from_yaml(out_path, 'gyro_comp')
    assert [len(c) for c in model.bias_coefficients] == [5, 5]


@pytest.mark.ros
def test_compensation_node_loads_the_fitted_file(fitted, launcher, probe, tmp_path):
    out_path, _ = fitted
    axes, model = model_from_yaml(out_path)
    launcher.start('compensation_node', 'compensation_node', extra_args=[
        '--params-file', str(out_path),
        '-p', f'recalibration.state_file:={tmp_path / "zro_state.yaml"}'])
    received = probe.subscribe(Imu, 'imu/data')
    imu_publisher = probe.node.create_publisher(Imu, 'imu/data_raw', SENSOR_INPUT_QOS)
    temperature_publisher = probe.node.create_publisher(Temperature, 'imu/temperature_raw',
                                                        SENSOR_INPUT_QOS)
    probe.spin_until(lambda: imu_publisher.get_subscription_count() and
                     temperature_publisher.get_subscription_count() and
                     probe.node.count_publishers('imu/data'),
                     TIMEOUT_S, 'the compensation node', launcher)
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
    assert 'orders (chosen by 5-block cross-validation): x ' in out
    assert 'skipped: dropped by preset 1' in out
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
