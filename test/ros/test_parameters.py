"""Parameters of the nodes: bad files stop them with a clear line, runtime changes are checked."""

from pathlib import Path

from mlx_tempcomp.ros import messages
import pytest
from rclpy.qos import ReliabilityPolicy
from ros_harness import by_stamp, first_line_with, reliable, simulated_driver_params

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0

# (node, parameters, text the fatal line must hold: it names the parameter)
INVALID = {
    'rate_not_a_number': ('driver_node', {'publish_rate_hz': 'fast'},
                          'invalid parameter publish_rate_hz: Trying to set parameter '
                          "'publish_rate_hz' to 'fast' of type 'STRING', expecting type 'DOUBLE'"),
    'sampling_below_publishing': ('driver_node', {'publish_rate_hz': 100.0,
                                                  'sample_rate_hz': 50.0},
                                  'invalid parameter sample_rate_hz: 50 Hz is below '
                                  'publish_rate_hz (100 Hz)'),
    'oversample_zero': ('driver_node', {'oversample': 0},
                        'invalid parameter oversample: Invalid parameter value (0) for parameter. '
                        'Reason: Parameter oversample out of range. Min: 1, Max: 256'),
    'source_usb': ('driver_node', {'source': 'usb'},
                   "invalid parameter source: 'usb' is not one of simulated, spidev, i2c, bag"),
    'axes_w': ('driver_node', {'axes': ['w']},
               "invalid parameter axes: ['w'], give 1 to 3 distinct of 'x', 'y', 'z'"),
    'model_cubic': ('compensation_node', {'model': 'cubic'},
                    "invalid parameter model: 'cubic' is not one of eeprom, polynomial, "
                    'linear_btc'),
    'polynomial_without_bias': ('compensation_node', {'model': 'polynomial'},
                                'invalid parameter polynomial.bias.z: the polynomial model '
                                "needs coefficients for every axis in ['z']"),
    'linear_btc_too_short': ('compensation_node',
                             {'model': 'linear_btc', 'axes': ['x', 'z'],
                              'linear_btc.pbc_rad_s': [0.0],
                              'linear_btc.btc_rad_s_per_c': [0.0, 0.0]},
                             'invalid parameter linear_btc.pbc_rad_s: needs 2 values'),
    'model_error_not_increasing': ('compensation_node',
                                   {'model_error.temperature_c': [20.0, 10.0],
                                    'model_error.z_rad_s': [1e-3, 2e-3]},
                                   'invalid parameter model_error.temperature_c: model error '
                                   'temperatures must be strictly increasing, got [20.0, 10.0]'),
    'qos_override_misspelt': ('compensation_node',
                              {'qos_overrides./imu/data_raw.subscription.reliability': 'relible'},
                              'invalid qos_overrides for imu/data_raw: Unexpected QoS override '
                              'for policy `reliability`: `relible` (history: keep_last or '
                              'keep_all; depth: an integer; reliability: reliable or '
                              'best_effort)'),
    'stale_timeout_negative': ('compensation_node', {'stale_timeout_s': -1.0},
                               'invalid parameter stale_timeout_s: Invalid parameter value '
                               '(-1.0) for parameter. Reason: Parameter stale_timeout_s out of '
                               'range'),
}


@pytest.mark.parametrize('case', sorted(INVALID))
def test_invalid_parameter_file_exits_1_naming_the_parameter(launcher, tmp_path, case):
    node, params, expected = INVALID[case]
    if node == 'compensation_node':
        params = {'recalibration.state_file': str(tmp_path / 'zro.yaml'), **params}
    process = launcher.start(node, node, params)
    assert process.wait(20.0) == 1
    output = process.output()
    assert 'Traceback' not in output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    assert lines[0].startswith('[FATAL] [') and f'[{node}]: ' in lines[0], lines[0]
    assert expected in lines[0], lines[0]
    assert not (tmp_path / 'zro.yaml').exists()


def test_parameter_file_rcl_cannot_parse_exits_1_without_traceback(launcher, tmp_path):
    # The natural spelling of three axes: YAML 1.1 (rcl's parser) reads a bare y as true.
    path = tmp_path / 'axes.yaml'
    path.write_text('driver_node:\n  ros__parameters:\n    axes: [x, y, z]\n')
    process = launcher.start('driver_node', 'driver_node',
                             extra_args=['--params-file', str(path)])
    assert process.wait(20.0) == 1
    output = process.output()
    assert 'Traceback' not in output
    fatal = [line for line in output.splitlines() if line.startswith('[FATAL]')]
    assert len(fatal) == 1, output
    assert '[driver_node]: cannot start: ' in fatal[0]
    assert f"Couldn't parse params file: '--params-file {path}'" in fatal[0]
    assert 'line_num 3' in fatal[0]
    assert ('YAML reads a bare y, n, yes, no, on or off as a boolean: quote it, '
            "e.g. axes: ['x', 'y', 'z']") in fatal[0]


SHIPPED_CONFIG = str(Path(__file__).resolve().parents[2] / 'config' / 'mlx_tempcomp.yaml')


def test_a_p_after_the_shipped_config_takes_effect(launcher, probe, tmp_path):
    # The bag source was chosen: it looks for the bag (before: the simulator streamed).
    bag = launcher.start('driver_node', 'driver_node', extra_args=[
        '--params-file', SHIPPED_CONFIG, '-p', 'source:=bag',
        '-p', f'bag.path:={tmp_path / "absent"}'])
    assert bag.wait(TIMEOUT_S) == 1
    assert f'[driver_node]: bag {tmp_path / "absent"} does not exist' in bag.output()
    state_file = tmp_path / 'zro.yaml'
    compensation = launcher.start('compensation_node', 'compensation_node', extra_args=[
        '--params-file', SHIPPED_CONFIG, '-p', f'recalibration.state_file:={state_file}',
        '-p', 'supply_voltage.pairing:=stamp', '-p', 'model:=linear_btc',
        '-p', 'linear_btc.pbc_rad_s:=[0.01]', '-p', 'linear_btc.btc_rad_s_per_c:=[0]'])
    values = probe.get_parameters('compensation_node', [
        'recalibration.state_file', 'supply_voltage.pairing', 'model',
        'linear_btc.btc_rad_s_per_c', 'max_block'])
    assert values == {'recalibration.state_file': str(state_file),
                      'supply_voltage.pairing': 'stamp', 'model': 'linear_btc',
                      'linear_btc.btc_rad_s_per_c': [0.0], 'max_block': 500}
    assert "model linear_btc on axes ['z']" in compensation.output()
    assert f'state file {state_file}: nothing saved yet' in compensation.output()


def test_a_p_a_node_section_outranks_refuses_the_start(launcher, tmp_path):
    # A /** section and a node's own one, as the shipped file had them: rcl puts a plain -p
    # into /**, below the node's section.
    path = tmp_path / 'own.yaml'
    path.write_text('/**:\n  ros__parameters:\n    frame_id: imu_link\n'
                    'driver_node:\n  ros__parameters:\n    source: simulated\n')
    refused = launcher.start('driver_node', 'driver_node', extra_args=[
        '--params-file', str(path), '-p', 'source:=bag'])
    assert refused.wait(TIMEOUT_S) == 1
    fatal = first_line_with(refused.output(), '[FATAL]')
    assert ("[driver_node]: -p source:=bag did not take effect (source is 'simulated'): a "
            "'driver_node:' section of a parameter file outranks a plain -p; give "
            '-p driver_node:source:=bag, or set it in a file after that one') in fatal
    assert 'Traceback' not in refused.output()
    # The way the message names does win over the section.
    qualified = launcher.start('driver_node', 'driver_node', extra_args=[
        '--params-file', str(path), '-p', 'driver_node:source:=bag',
        '-p', f'bag.path:={tmp_path / "absent"}'])
    assert qualified.wait(TIMEOUT_S) == 1
    assert 'does not exist' in first_line_with(qualified.output(), '[FATAL]')


def test_unknown_keys_warn_with_the_closest_known_one(launcher, probe, tmp_path):
    driver = launcher.driver({'publish_rate_hx': 50.0, **simulated_driver_params()})
    compensation = launcher.compensation({'modle': 'polynomial',
                                          'recalibration.state_file': str(tmp_path / 'z')})
    expected = {driver: 'unknown parameter publish_rate_hx ignored: no node of mlx_tempcomp '
                        'has it; did you mean publish_rate_hz?',
                compensation: 'unknown parameter modle ignored: no node of mlx_tempcomp has '
                              'it; did you mean model?'}
    for process, text in expected.items():
        probe.spin_until(lambda: text in process.output(), TIMEOUT_S, text, launcher)
        assert first_line_with(process.output(), text).startswith('[WARN]')
    # The node runs its default model.
    assert 'model eeprom on axes' in compensation.output()


def test_an_integer_is_taken_where_a_double_is_meant(launcher, probe, tmp_path):
    launcher.driver(simulated_driver_params(**{'publish_rate_hz': 50, 'sample_rate_hz': 100,
                                               'simulation.rate_dps': [1]}))
    launcher.compensation({'stale_timeout_s': 2, 'polynomial.bias.z': [0, 1],
                           'recalibration.state_file': str(tmp_path / 'zro.yaml')})
    driver = probe.get_parameters('driver_node', ['publish_rate_hz', 'simulation.rate_dps'])
    assert driver == {'publish_rate_hz': 50.0, 'simulation.rate_dps': [1.0]}
    assert all(isinstance(v, float) for v in (driver['publish_rate_hz'],
                                              *driver['simulation.rate_dps']))
    compensation = probe.get_parameters('compensation_node',
                                        ['stale_timeout_s', 'polynomial.bias.z'])
    assert compensation == {'stale_timeout_s': 2.0, 'polynomial.bias.z': [0.0, 1.0]}
    assert isinstance(compensation['stale_timeout_s'], float)


def test_an_integer_set_at_run_time_is_taken_where_a_double_is_meant(launcher, probe,
                                                                     tmp_path):
    # What `ros2 param set /compensation_node bias_tracking.window_s 5` sends: an INTEGER,
    # which rclpy alone refuses for a DOUBLE parameter.
    launcher.driver(simulated_driver_params())
    launcher.compensation({'recalibration.state_file': str(tmp_path / 'zro.yaml'),
                           'model': 'polynomial', 'polynomial.bias.z': [0.0]})
    for node, values, expected in (
            ('compensation_node', {'bias_tracking.window_s': 5, 'polynomial.bias.z': [0, 1]},
             {'bias_tracking.window_s': 5.0, 'polynomial.bias.z': [0.0, 1.0]}),
            ('driver_node', {'simulation.supply_v': 4}, {'simulation.supply_v': 4.0})):
        results = probe.set_parameters(node, values)
        assert [r.successful for r in results] == [True] * len(values), \
            [r.reason for r in results]
        got = probe.get_parameters(node, list(values))
        assert got == expected
        assert all(isinstance(v, float) for value in got.values()
                   for v in (value if isinstance(value, list) else [value]))
    # Still checked: an integer out of range is refused, and so is a string.
    results = probe.set_parameters('compensation_node', {'stale_timeout_s': 0,
                                                         'bias_tracking.window_s': 'long'})
    assert [r.successful for r in results] == [False, False]
    assert 'stale_timeout_s out of range' in results[0].reason, results[0].reason
    assert probe.get_parameters('compensation_node', ['stale_timeout_s',
                                                      'bias_tracking.window_s']) == \
        {'stale_timeout_s': 1.0, 'bias_tracking.window_s': 5.0}


def test_qos_overrides_make_the_streams_reliable(launcher, probe, tmp_path):
    # The standard qos_overrides parameters: best effort by default (REP-2003), reliable
    # and deep where a replay must lose nothing.
    launcher.driver(simulated_driver_params(**reliable(['imu/data_raw'], 'publisher')))
    launcher.compensation({**reliable(['imu/data_raw'], 'subscription'),
                           'recalibration.state_file': str(tmp_path / 'zro.yaml')})

    def endpoint(kind, topic):
        found = getattr(probe.node, f'get_{kind}_info_by_topic')(topic)
        return found[0].qos_profile if found else None
    probe.spin_until(lambda: endpoint('publishers', '/imu/data_raw') and
                     endpoint('subscriptions', '/imu/data_raw') and
                     endpoint('publishers', '/imu/temperature_raw'), TIMEOUT_S,
                     'the raw streams', launcher)
    # (The graph reports reliability, not history or depth: those are read back below.)
    for kind in ('publishers', 'subscriptions'):
        assert endpoint(kind, '/imu/data_raw').reliability == ReliabilityPolicy.RELIABLE, kind
    # Not overridden: the sensor-data profile.
    qos = endpoint('publishers', '/imu/temperature_raw')
    assert qos.reliability == ReliabilityPolicy.BEST_EFFORT
    assert probe.get_parameters('driver_node', [
        'qos_overrides./imu/data_raw.publisher.reliability',
        'qos_overrides./imu/data_raw.publisher.depth']) == {
            'qos_overrides./imu/data_raw.publisher.reliability': 'reliable',
            'qos_overrides./imu/data_raw.publisher.depth': 5000}


LINEAR_BTC = {'model': 'linear_btc', 'linear_btc.pbc_rad_s': [0.01],
              'linear_btc.btc_rad_s_per_c': [0.0002], 'linear_btc.t3_c': 25.0}


def linear_btc(raw_rad_s: float, temperature_c: float, pbc: float) -> float:
    return raw_rad_s + pbc + (temperature_c - 25.0) * 0.0002


@pytest.mark.slow
def test_runtime_coefficient_changes_are_checked_and_applied(launcher, probe, tmp_path):
    probe.subscribe_pipeline()
    launcher.driver(simulated_driver_params())
    launcher.compensation({'recalibration.state_file': str(tmp_path / 'zro.yaml'),
                           **LINEAR_BTC})
    probe.wait_streaming(['imu/data_raw', 'imu/data'], TIMEOUT_S, launcher)

    results = probe.set_parameters('compensation_node', {'linear_btc.pbc_rad_s': [0.5, 0.5]})
    assert [r.successful for r in results] == [False]
    assert results[0].reason == ('invalid parameter linear_btc.pbc_rad_s: needs 1 values '
                                 "(one per axis in ['z']), got 2")
    values = probe.get_parameters('compensation_node', ['linear_btc.pbc_rad_s'])
    assert values == {'linear_btc.pbc_rad_s': [0.01]}
    # The stream goes on, with the old coefficients. The waits are on what is asserted:
    # samples the probe heard with their raw inputs (a loaded machine drops some of a
    # best-effort stream).
    probe.clear()
    probe.spin_until(lambda: pbcs_heard(probe).count(0.01) >= 50, TIMEOUT_S,
                     '50 samples with the first PBC', launcher)

    results = probe.set_parameters('compensation_node', {'linear_btc.pbc_rad_s': [-0.04]})
    assert [r.successful for r in results] == [True], results[0].reason
    probe.spin_until(lambda: pbcs_heard(probe).count(-0.04) >= 250, TIMEOUT_S,
                     '250 samples with the new PBC', launcher)
    launcher.stop_all()
    probe.drain()

    # Every compensated sample is raw + PBC + (T - T3) x BTC with the old PBC up to one
    # stamp and the new one from there on: the output shifts by exactly -0.05 rad/s.
    pbcs = pbcs_heard(probe)
    switch = pbcs.index(-0.04)
    assert pbcs[:switch] == [0.01] * switch and pbcs[switch:] == [-0.04] * (len(pbcs) - switch)
    assert switch >= 50 and len(pbcs) - switch >= 250


def pbcs_heard(probe) -> list:
    """Give the PBC each compensated sample heard with its raw inputs was made with."""
    raw = by_stamp(probe.received['imu/data_raw'])
    temperature = by_stamp(probe.received['imu/temperature_raw'])
    pbcs = []
    for msg in probe.received['imu/data']:
        stamp = messages.stamp_to_ns(msg.header.stamp)
        if stamp not in raw or stamp not in temperature:
            continue
        z, t = raw[stamp].angular_velocity.z, temperature[stamp].temperature
        for pbc in (0.01, -0.04):
            if abs(msg.angular_velocity.z - linear_btc(z, t, pbc)) < 1e-12:
                pbcs.append(pbc)
                break
        else:
            pytest.fail(f'sample at {stamp} fits neither PBC: raw {z}, T {t}, '
                        f'compensated {msg.angular_velocity.z}')
    return pbcs


def test_read_only_parameters_cannot_change_at_runtime(launcher, probe, tmp_path):
    launcher.driver(simulated_driver_params())
    launcher.compensation({'recalibration.state_file': str(tmp_path / 'zro.yaml')})
    for node, name, value in (('driver_node', 'source', 'bag'),
                              ('driver_node', 'publish_rate_hz', 10.0),
                              ('compensation_node', 'axes', ['x', 'y', 'z']),
                              ('compensation_node', 'recalibration.state_file', '/tmp/x')):
        before = probe.get_parameters(node, [name])
        results = probe.set_parameters(node, {name: value})
        assert [r.successful for r in results] == [False], f'{node} {name}'
        assert 'read-only' in results[0].reason, results[0].reason
        assert probe.get_parameters(node, [name]) == before
    # A writable one goes through.
    results = probe.set_parameters('driver_node', {'frame_id': 'gyro_link'})
    assert [r.successful for r in results] == [True]
    assert probe.get_parameters('driver_node', ['frame_id']) == {'frame_id': 'gyro_link'}
