"""
The driver node's ``device`` parameter over DDS: ADIS16130 and MPU-6000 next to the MLX90609.

Each simulated part streams through the compensation node; the MPU's offset
registers are calibrated, saved and written again at the next start; the
ADIS16130 bias procedure runs as a service on the stream; the MPU's gyro
offsets follow a bias model fitted by the toolkit as the temperature ramps.
"""

import math
import re

from device_runs import gyro_mean_after_change_dps, mpu_truth, SEED, TIMEOUT_S
from diagnostic_msgs.msg import DiagnosticStatus
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.procedures.mpu6000_offsets import STANDARD_GRAVITY_M_S2
from mlx_tempcomp.parameters.driver import DEVICES
from mlx_tempcomp.parameters.state_file import write_state
from mlx_tempcomp.ros.driver.adis16130_stream import file_linear_btc
from mlx_tempcomp.ros.driver.mpu6000_stream import offsets_state
from mlx_tempcomp.ros.driver.node import STREAMS
from mlx_tempcomp.ros.qos import EEPROM_QOS, STATUS_QOS
from mlx_tempcomp.simulation.mpu6000 import MpuTruth
from mlx_tempcomp.simulation.physics import ThermalProfile
from mlx_tempcomp.sources.mpu6000 import SimulatedMpuSource
import numpy as np
import pytest
from ros_harness import (by_stamp, COMPENSATION_DIAGNOSTIC, DRIVER_DIAGNOSTIC, first_line_with,
                         rates, simulated_driver_params, start_pipeline, status_values)
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import String, UInt8MultiArray
from std_srvs.srv import Trigger
import yaml

pytestmark = pytest.mark.ros

MPU_AXES = ['x', 'y', 'z']


def mean_dps(msgs, index: int) -> float:
    return math.degrees(float(np.mean([rates(m)[index] for m in msgs])))


def start_recorded_pipeline(launcher, probe, driver: dict, compensation: dict,
                            axes=('z',)) -> dict:
    """Record the streams, the EEPROM and diagnostics; start both nodes (start_pipeline)."""
    for topic in ('imu/data_raw', 'imu/data'):
        probe.subscribe(Imu, topic)
    probe.subscribe(Temperature, 'imu/temperature_raw')
    probe.subscribe(UInt8MultiArray, 'imu/eeprom', EEPROM_QOS)
    probe.subscribe_diagnostics()
    return start_pipeline(launcher, probe, driver, compensation, axes, TIMEOUT_S)


def test_every_device_has_a_stream():
    # A device the parameter accepts but the driver cannot stream would fail only at start.
    assert sorted(STREAMS) == sorted(DEVICES)


def test_mlx90609_by_name_streams_with_its_eeprom(launcher, probe):
    statuses = start_recorded_pipeline(launcher, probe,
                                       {'device': 'mlx90609', 'simulation.seed': SEED}, {})
    data = probe.wait_count('imu/data', 200, TIMEOUT_S, launcher)
    assert statuses[DRIVER_DIAGNOSTIC].hardware_id == f'simulated MLX90609 x1 (seed {SEED})'
    assert statuses[COMPENSATION_DIAGNOSTIC].message == 'compensating (eeprom)'
    assert len(probe.received['imu/eeprom']) == 1
    assert abs(mean_dps(data, 2)) < 0.3


def test_adis16130_streams_through_linear_btc(launcher, probe):
    bias_dps = 0.8
    statuses = start_recorded_pipeline(
        launcher, probe, {'device': 'adis16130', 'simulation.bias_dps': bias_dps},
        {'model': 'linear_btc', 'linear_btc.pbc_rad_s': [-math.radians(bias_dps)],
         'linear_btc.btc_rad_s_per_c': [0.0], 'linear_btc.t3_c': 25.0})
    data = list(probe.wait_count('imu/data', 300, TIMEOUT_S, launcher))
    raw = list(probe.received['imu/data_raw'])
    temperature = list(probe.received['imu/temperature_raw'])
    driver = statuses[DRIVER_DIAGNOSTIC]
    assert driver.hardware_id == 'simulated ADIS16130 (seed 0), 24-bit'
    assert status_values(driver)['device'] == 'adis16130'
    assert statuses[COMPENSATION_DIAGNOSTIC].message == 'compensating (linear_btc)'
    # One axis, no accelerometer, no EEPROM (the eeprom model would have no tables).
    for msg in raw:
        assert msg.linear_acceleration_covariance[0] == -1.0
        assert math.isnan(msg.angular_velocity.x) and math.isnan(msg.angular_velocity.y)
    assert probe.received['imu/eeprom'] == []
    assert np.mean([m.temperature for m in temperature]) == pytest.approx(25.0, abs=0.05)
    # 0.22 deg/s of white noise per sample: the mean of 300 is good to about 0.04.
    raw_mean, compensated_mean = mean_dps(raw, 2), mean_dps(data, 2)
    print(f'ADIS16130: bias {bias_dps} deg/s; raw mean {raw_mean:.4f}, compensated '
          f'{compensated_mean:.4f} deg/s ({len(raw)} / {len(data)} samples)')
    assert raw_mean == pytest.approx(bias_dps, abs=0.06)
    assert abs(compensated_mean) < 0.06
    # Runtime faults: the MLX90609's refusal is not the ADIS16130's; a stuck MISO is.
    result, = probe.set_parameters('driver_node', {'simulation.fault': 'refuse'})
    assert not result.successful and 'knows none, silent_high, silent_low' in result.reason
    result, = probe.set_parameters('driver_node', {'simulation.fault': 'silent_low'})
    assert result.successful, result.reason
    failing = probe.wait_status(
        DRIVER_DIAGNOSTIC, lambda s: s.level == DiagnosticStatus.ERROR, TIMEOUT_S,
        'driver ERROR', launcher)
    assert int(status_values(failing)['silent_bus']) > 0
    assert failing.message.startswith('SPI reads failing: '), failing.message


def test_mpu6000_streams_through_polynomial(launcher, probe, tmp_path):
    truth = mpu_truth()
    bias_rad_s = np.radians(truth.gyro_bias_dps)
    polynomial = {'model': 'polynomial', 'polynomial.reference_temperature_c': 25.0}
    for axis, bias in zip(MPU_AXES, bias_rad_s):
        polynomial[f'polynomial.bias.{axis}'] = [float(bias)]
    statuses = start_recorded_pipeline(
        launcher, probe, {'device': 'mpu6000', 'simulation.seed': SEED,
                          'mpu6000.offsets_file': str(tmp_path / 'offsets.yaml')},
        polynomial, axes=MPU_AXES)
    data = list(probe.wait_count('imu/data', 300, TIMEOUT_S, launcher))
    raw = list(probe.received['imu/data_raw'])
    driver = status_values(statuses[DRIVER_DIAGNOSTIC])
    assert statuses[DRIVER_DIAGNOSTIC].hardware_id == f'simulated MPU6000 (seed {SEED})'
    assert driver['offsets'] == 'none' and driver['gyro_offset_lsb'] == '[0, 0, 0]'
    assert probe.received['imu/eeprom'] == []
    for index in range(3):
        raw_mean, compensated_mean = mean_dps(raw, index), mean_dps(data, index)
        print(f'MPU axis {MPU_AXES[index]}: bias {truth.gyro_bias_dps[index]:.3f}, raw mean '
              f'{raw_mean:.3f}, compensated {compensated_mean:.4f} deg/s')
        assert raw_mean == pytest.approx(truth.gyro_bias_dps[index], abs=0.02)
        assert abs(compensated_mean) < 0.02
    # Linear acceleration: lying face up, the factory-trimmed bias on top, covariance set.
    acceleration_g = np.mean([[m.linear_acceleration.x, m.linear_acceleration.y,
                               m.linear_acceleration.z] for m in raw], axis=0) \
        / STANDARD_GRAVITY_M_S2
    expected_g = np.add(truth.acceleration_g, truth.accel_bias_g)
    assert acceleration_g == pytest.approx(expected_g, abs=0.003)
    assert list(raw[0].linear_acceleration_covariance) == pytest.approx(
        [0.049 ** 2, 0, 0, 0, 0.049 ** 2, 0, 0, 0, 0.049 ** 2])


def gyro_mean_dps(launcher, probe, samples: int = 200) -> np.ndarray:
    """Return the mean raw rate of the next ``samples`` samples, deg/s per axis."""
    probe.clear()
    raw = probe.wait_count('imu/data_raw', samples, TIMEOUT_S, launcher)
    return np.array([mean_dps(raw[:samples], i) for i in range(3)])


def start_mpu(launcher, probe, path, label: str):
    params = simulated_driver_params(device='mpu6000', axes=MPU_AXES, **{
        'simulation.seed': SEED, 'mpu6000.calibration.duration_s': 2.0,
        'mpu6000.offsets_file': str(path)})
    driver = launcher.driver(params, label=label)
    probe.wait_streaming(['imu/data_raw'], TIMEOUT_S, launcher)
    return driver


@pytest.mark.slow
def test_mpu6000_offsets_calibrate_persist_and_return_at_start(launcher, probe, tmp_path):
    truth = mpu_truth()
    path = tmp_path / 'state' / 'offsets.yaml'
    probe.subscribe(Imu, 'imu/data_raw')
    driver = start_mpu(launcher, probe, path, 'first')
    assert 'no saved offsets in' in driver.output()
    before = gyro_mean_dps(launcher, probe)
    assert before == pytest.approx(truth.gyro_bias_dps, abs=0.02)

    # A noise figure far below the real spread: the check sees motion and refuses.
    probe.set_parameters('driver_node', {'rate_noise_rad_s': 1e-5})
    response = probe.call(Trigger, 'imu/calibrate_offsets', Trigger.Request(), TIMEOUT_S)
    assert not response.success
    assert response.message.startswith('refused: the board moves: the '), response.message
    assert not path.exists()

    probe.set_parameters('driver_node', {'rate_noise_rad_s': 0.0058})
    response = probe.call(Trigger, 'imu/calibrate_offsets', Trigger.Request(), TIMEOUT_S)
    assert response.success, response.message
    print(response.message)
    assert 'gravity on +z' in response.message and str(path) in response.message
    # What changed, from what to what: the registers were at their power-on values.
    state = yaml.safe_load(path.read_text())
    assert f'gyro offsets from [0, 0, 0] to {state["gyro_offset_lsb"]} LSB, accel offset ' \
        f'registers from ' in response.message, response.message
    assert f'offset calibration: {response.message}' in driver.output()
    state = yaml.safe_load(path.read_text())
    # The note's conversion: register = -round(bias / 0.031 deg/s).
    expected_lsb = [-round(b / 0.031) for b in truth.gyro_bias_dps]
    assert all(abs(got - want) <= 1 for got, want in zip(state['gyro_offset_lsb'],
                                                         expected_lsb)), state
    assert state['variant'] == 'mpu6000' and len(state['accel_bias_lsb']) == 3
    after = gyro_mean_after_change_dps(launcher, probe, before)
    print(f'gyro mean before {np.round(before, 4)}, after {np.round(after, 4)} deg/s')
    # One register step is 0.031 deg/s: the residual is at most half of it, plus the noise
    # of the two 200-sample means (0.063 deg/s per sample: 3 sigma of their sum 0.019).
    assert np.all(np.abs(after) < 0.035)

    # Power off and on: the registers clear, the driver writes the saved ones again.
    driver.stop()
    probe.wait_quiet(['imu/data_raw'], 0.3, TIMEOUT_S, launcher)
    restarted = start_mpu(launcher, probe, path, 'second')
    assert 'wrote the saved offsets from' in restarted.output()
    again = gyro_mean_dps(launcher, probe)
    assert np.all(np.abs(again) < 0.035), again

    # A damaged file, then one with a value no register holds: each logged at ERROR and
    # moved aside, the driver starts without offsets (the bias is back).
    restarted.stop()
    for label, content, reason in (
            ('third', 'gyro_offset_lsb: [1, 2\n', 'damaged: not valid YAML at line 2'),
            ('fourth', yaml.safe_dump({**state, 'gyro_offset_lsb': [40000, 0, 0]}),
             'gyro_offset_lsb[0] 40000 is outside -32768 to 32767')):
        probe.wait_quiet(['imu/data_raw'], 0.3, TIMEOUT_S, launcher)
        path.write_text(content)
        driver = start_mpu(launcher, probe, path, label)
        line = first_line_with(driver.output(), f'saved offsets in {path} unusable: {reason}')
        assert line.startswith('[ERROR]') and 'moved aside to' in line, driver.output()
        assert not path.exists()
        assert gyro_mean_dps(launcher, probe) == pytest.approx(truth.gyro_bias_dps, abs=0.02)
        driver.stop()
    assert len(list(path.parent.glob('offsets.yaml.bad-*'))) == 2


def test_an_offset_calibration_call_while_one_runs_is_refused(launcher, probe, tmp_path):
    path = tmp_path / 'offsets.yaml'
    params = simulated_driver_params(device='mpu6000', axes=MPU_AXES, **{
        'mpu6000.calibration.duration_s': 600.0, 'mpu6000.offsets_file': str(path)})
    driver = launcher.driver(params)
    probe.subscribe(Imu, 'imu/data_raw')
    probe.wait_streaming(['imu/data_raw'], TIMEOUT_S, launcher)
    # 600 s of sensor time (120 s of wall time at 5 x): the first runs, whatever the speed.
    first = probe.call_async(Trigger, 'imu/calibrate_offsets', Trigger.Request(), TIMEOUT_S)
    second = probe.call(Trigger, 'imu/calibrate_offsets', Trigger.Request(), TIMEOUT_S)
    assert not first.done()
    assert not second.success
    assert re.fullmatch(r'refused: an offset calibration is running since \S+ \(\d+\.\d s\); '
                        r'call again when it is done', second.message), second.message
    assert f'offset calibration: {second.message}' in driver.output()
    assert not path.exists()


@pytest.mark.parametrize('params, named', [
    ({'device': 'adis'}, "invalid parameter device: 'adis' is not one of mlx90609, adis16130, "
                         'mpu6000'),
    ({'device': 'adis16130', 'axes': ['x', 'z']},
     "invalid parameter axes: the adis16130 measures one axis, got ['x', 'z']"),
    ({'device': 'mpu6000', 'axes': MPU_AXES, 'mpu6000.offset_model_file': '/absent/bias.yaml'},
     'invalid parameter mpu6000.offset_model_file (/absent/bias.yaml): cannot read parameter '
     'file /absent/bias.yaml'),
], ids=['unknown device', 'adis16130 on two axes', 'mpu6000 offset model file absent'])
def test_bad_device_parameters_exit_1_naming_the_parameter(launcher, params, named):
    driver = launcher.driver(params)
    assert driver.wait(TIMEOUT_S) == 1
    assert named in driver.output()


@pytest.mark.slow
def test_adis16130_bias_procedure_writes_linear_btc(launcher, probe, tmp_path):
    slope_dps_per_c = 0.3
    out = tmp_path / 'btc' / 'adis.yaml'
    prefix = 'adis16130.bias_procedure.'
    # The temperature ramps 2 C/min: 3.1 C between the points, 0.93 deg/s of bias change
    # against 0.05 deg/s of noise in the difference of two 2 s means at 20 Hz (the BTC's
    # 1 sigma about 5 %; with 45 s of self-heating it was 11 %, and CI once drew +31 %).
    launcher.driver(simulated_driver_params(**{
        'device': 'adis16130', 'publish_rate_hz': 20.0, 'sample_rate_hz': 20.0,
        'simulation.real_time_factor': 20.0,
        'simulation.bias_dps_per_c': slope_dps_per_c,
        'simulation.cycle_temperatures_c': [60.0], 'simulation.ramp_c_per_min': 2.0,
        prefix + 'average_s': 2.0, prefix + 'self_heat_s': 90.0, prefix + 'settle_s': 12.0,
        prefix + 'allan_record_s': 10.0, prefix + 'pbc_s': 2.0,
        prefix + 'output_file': str(out)}))
    # Transient local: every status since the call, even if the probe is matched late.
    status = probe.subscribe(String, 'imu/bias_procedure/status', STATUS_QOS)
    response = probe.call(Trigger, 'imu/run_bias_procedure', Trigger.Request(), TIMEOUT_S)
    assert response.success, response.message
    print(response.message)
    for name in ('T1', 'B1', 'T2', 'B2', 'BTC', 'PBC', 'T3'):
        assert f'{name} ' in response.message
    # What changed, from what to what: no file before.
    assert 'linear_btc of compensation_node from none (no file) to PBC [' in response.message
    probe.drain()
    texts = [m.data for m in status]
    for phase in ('point_1', 'self_heat', 'point_2', 'settle', 'rest_record', 'pbc'):
        assert any(t.startswith(f'phase {phase}: ') for t in texts), (phase, texts)
    assert texts[-1].startswith('done: ')
    section = yaml.safe_load(out.read_text())['compensation_node']['ros__parameters']
    assert section['model'] == 'linear_btc' and section['axes'] == ['z']
    btc_dps_per_c = math.degrees(section['linear_btc']['btc_rad_s_per_c'][0])
    # Table 6: a positive bias slope gives a negative BTC.
    assert btc_dps_per_c == pytest.approx(-slope_dps_per_c, rel=0.3)
    assert section['rate_noise_rad_s'] > 0.0


def test_the_bias_procedure_says_what_the_file_held_before(tmp_path):
    path = tmp_path / 'btc.yaml'
    assert file_linear_btc(str(path), 'compensation_node') == 'none (no file)'
    path.write_text(yaml.safe_dump({'compensation_node': {'ros__parameters': {
        'model': 'linear_btc', 'linear_btc': {'pbc_rad_s': [0.0125], 'btc_rad_s_per_c':
                                              [-0.0002], 't3_c': 31.5}}}}))
    assert file_linear_btc(str(path), 'compensation_node') == \
        'PBC [0.0125] rad/s, BTC [-0.0002] rad/s/C, T3 31.5000 C'
    assert file_linear_btc(str(path), 'other_node') == \
        'a file without a linear_btc section for other_node'
    path.write_text('compensation_node: [unclosed\n')
    assert file_linear_btc(str(path), 'compensation_node') == 'an unreadable file (ParserError)'


def drift_dps(temperature_c, gyro_rad_s, span_c: float) -> np.ndarray:
    """Return the rate change over ``span_c`` of a line fitted to rate(T), deg/s per axis."""
    slopes = np.polyfit(temperature_c, np.degrees(gyro_rad_s), 1)[0]
    return slopes * span_c


@pytest.mark.slow
def test_mpu6000_gyro_offsets_follow_a_fitted_bias_model(launcher, probe, tmp_path):
    # Seed 6 draws bias slopes of 0.041, 0.020, 0.045 deg/s/C: 1 to 2.2 deg/s over the ramp.
    seed, start_c, end_c, ramp_c_per_min = 6, 20.0, 70.0, 300.0
    thermal = ThermalProfile.cycle((end_c,), ramp_c_per_min, start_c)
    # The part the driver simulates, recorded in-process along the same ramp, no offsets.
    source = SimulatedMpuSource(MpuTruth.random(np.random.default_rng(seed), thermal=thermal),
                                seed=seed)
    source.start()
    record = source.record(1100, 0.01)
    csv_path = tmp_path / 'ramp.csv'
    np.savetxt(csv_path, np.column_stack((record.time_s, record.temperature_c,
                                          record.gyro_rad_s)),
               delimiter=',', header='time,temperature,gyro_x,gyro_y,gyro_z', comments='')
    model_path = tmp_path / 'bias.yaml'
    assert main(['fit', str(csv_path), '--order', '1', '--out', str(model_path)]) == 0
    # Offsets calibrated at a steady 25 C and saved as the service saves them.
    steady = SimulatedMpuSource(MpuTruth.random(np.random.default_rng(seed)), seed=seed)
    steady.start()
    calibration = steady.calibrate_offsets()
    offsets_path = tmp_path / 'offsets.yaml'
    write_state(str(offsets_path), offsets_state(
        'mpu6000', calibration.gyro_lsb, calibration.accel_bias_lsb,
        calibration.accel_registers, calibration.bias, calibration.temperature_c))

    imu = probe.subscribe(Imu, 'imu/data_raw')
    temperature = probe.subscribe(Temperature, 'imu/temperature_raw')
    probe.subscribe_diagnostics()
    driver = launcher.driver(simulated_driver_params(device='mpu6000', axes=MPU_AXES, **{
        'simulation.seed': seed, 'simulation.real_time_factor': 4.0,
        # The simulated clock starts when the probe subscribes (a loaded machine once took
        # longer to discover it than the whole ramp), then a hold near the start (inside
        # the model's fitted range) lets the temperature topic match too.
        'simulation.wait_for_subscriber': True,
        'simulation.start_temperature_c': start_c,
        'simulation.cycle_temperatures_c': [start_c + 2.0, end_c], 'simulation.hold_s': 8.0,
        'simulation.ramp_c_per_min': ramp_c_per_min,
        'mpu6000.offsets_file': str(offsets_path),
        'mpu6000.offset_model_file': str(model_path)}))
    probe.spin_until(lambda: temperature and temperature[-1].temperature >= end_c - 0.1,
                     TIMEOUT_S, f'the ramp to {end_c} C', launcher)
    status = probe.wait_status(DRIVER_DIAGNOSTIC, lambda s: True, TIMEOUT_S, 'driver status',
                               launcher)
    probe.drain()
    assert 'gyro offset refresh from' in driver.output()
    by_time = by_stamp(temperature)
    pairs = [(by_time[t].temperature, rates(m)) for t, m in by_stamp(imu).items()
             if t in by_time and by_time[t].temperature < end_c - 0.1]
    published_c = np.array([p[0] for p in pairs])
    published = np.array([p[1] for p in pairs])
    span_c = end_c - start_c
    before = drift_dps(record.temperature_c, record.gyro_rad_s, span_c)
    after = drift_dps(published_c, published, span_c)
    mean_after = np.degrees(published.mean(axis=0))
    values = status_values(status)
    print(f'{len(pairs)} samples from {published_c.min():.2f} to {published_c.max():.2f} C; '
          f'drift over {span_c:g} C without the refresh {np.round(before, 4)}, with '
          f'{np.round(after, 4)} deg/s; mean with {np.round(mean_after, 4)} deg/s; '
          f'{values["offset_refresh_writes"]} refresh writes, last at '
          f'{values["offset_refresh_temperature_c"]} C, registers {values["gyro_offset_lsb"]}')
    assert published_c.min() < start_c + 5.0 and len(pairs) > 500
    assert np.all(np.abs(after) * 3.0 <= np.abs(before)), (before, after)
    # Saved offsets plus the model's change since 25 C: nothing counted twice (12.8 deg/s
    # of bias on x would show).
    assert np.all(np.abs(mean_after) < 0.05), mean_after
    # One write at start, then one per 0.5 C of the 50 C ramp.
    assert int(values['offset_refresh_writes']) >= 90
    assert values['offset_refresh_failures'] == '0'
    assert float(values['offset_refresh_base_temperature_c']) == pytest.approx(25.0, abs=0.01)
    assert float(values['offset_refresh_temperature_c']) > end_c - 1.0
