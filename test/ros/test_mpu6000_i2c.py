"""
The driver node reading the simulated MPU over I2C, over DDS; and what it refuses at start.

The same simulated part as on SPI answers through its I2C face: the driver streams it
through the compensation node, calibrates its offset registers with
``imu/calibrate_offsets`` over I2C, and names a bus that stops answering. The
parameter checks start the real executable (the absent /dev/i2c-N through smbus2).
"""

import math

from device_runs import gyro_mean_after_change_dps, mpu_truth, SEED
from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from ros_harness import (COMPENSATION_DIAGNOSTIC, DRIVER_DIAGNOSTIC, rates, start_pipeline,
                         status_values)
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import Trigger
import yaml

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
MPU_AXES = ['x', 'y', 'z']


def mean_dps(msgs) -> np.ndarray:
    return np.degrees(np.mean([rates(m) for m in msgs], axis=0))


def test_mpu6050_on_i2c_streams_calibrates_its_offsets_and_reports_a_silent_bus(
        launcher, probe, tmp_path):
    truth = mpu_truth()
    path = tmp_path / 'offsets.yaml'
    polynomial = {'model': 'polynomial', 'polynomial.reference_temperature_c': 25.0}
    for axis, bias_dps in zip(MPU_AXES, truth.gyro_bias_dps):
        polynomial[f'polynomial.bias.{axis}'] = [math.radians(bias_dps)]
    for topic in ('imu/data_raw', 'imu/data'):
        probe.subscribe(Imu, topic)
    probe.subscribe(Temperature, 'imu/temperature_raw')
    probe.subscribe_diagnostics()
    # AD0 high: the part and the driver at 0x69.
    statuses = start_pipeline(launcher, probe, {
        'device': 'mpu6000', 'mpu6000.variant': 'mpu6050', 'simulation.bus': 'i2c',
        'i2c.address': 0x69, 'simulation.seed': SEED, 'mpu6000.offsets_file': str(path),
        'mpu6000.calibration.duration_s': 2.0}, polynomial, MPU_AXES, TIMEOUT_S)
    assert statuses[DRIVER_DIAGNOSTIC].hardware_id == f'simulated MPU6050 on I2C at 0x69 ' \
                                                      f'(seed {SEED})'
    assert statuses[COMPENSATION_DIAGNOSTIC].message == 'compensating (polynomial)'
    data = list(probe.wait_count('imu/data', 300, TIMEOUT_S, launcher))
    before = mean_dps(probe.received['imu/data_raw'])
    print(f'MPU-6050 on I2C: bias {np.round(truth.gyro_bias_dps, 3)}, raw mean '
          f'{np.round(before, 3)}, compensated {np.round(mean_dps(data), 4)} deg/s')
    assert before == pytest.approx(truth.gyro_bias_dps, abs=0.02)
    assert np.all(np.abs(mean_dps(data)) < 0.02)

    response = probe.call(Trigger, 'imu/calibrate_offsets', Trigger.Request(), TIMEOUT_S)
    assert response.success, response.message
    print(response.message)
    state = yaml.safe_load(path.read_text())
    assert state['variant'] == 'mpu6050' and state['gravity_axis'] == '+z'
    expected_lsb = [-round(b / 0.031) for b in truth.gyro_bias_dps]
    assert all(abs(got - want) <= 1 for got, want in zip(state['gyro_offset_lsb'],
                                                         expected_lsb)), state
    after = gyro_mean_after_change_dps(launcher, probe, before)
    print(f'gyro mean after the offsets {np.round(after, 4)} deg/s')
    # Half a register step (0.031 deg/s) plus the noise of the two means (as on SPI).
    assert np.all(np.abs(after) < 0.035), after

    # SDA never pulled low to acknowledge: every read is a NACK, named as such.
    result, = probe.set_parameters('driver_node', {'simulation.fault': 'silent_high'})
    assert result.successful, result.reason
    failing = probe.wait_status(
        DRIVER_DIAGNOSTIC, lambda s: s.level == DiagnosticStatus.ERROR, TIMEOUT_S,
        'driver ERROR', launcher)
    assert failing.message.startswith(
        'I2C reads failing: no device acknowledged address 0x69 on the simulated I2C bus'), \
        failing.message
    assert int(status_values(failing)['silent_bus']) > 0


@pytest.mark.parametrize('params, named', [
    ({'source': 'i2c'},
     'invalid parameter source: the mlx90609 speaks SPI only; i2c is for the mpu6000'),
    ({'device': 'adis16130', 'simulation.bus': 'i2c'},
     'invalid parameter simulation.bus: the adis16130 speaks SPI only; i2c is for the mpu6000'),
    ({'device': 'mpu6000', 'axes': MPU_AXES, 'mpu6000.variant': 'mpu6050'},
     'invalid parameter simulation.bus: the mpu6050 speaks I2C only, give i2c'),
    ({'device': 'mpu6000', 'axes': MPU_AXES, 'source': 'spidev', 'mpu6000.variant': 'mpu6050'},
     'invalid parameter source: the mpu6050 speaks I2C only, give i2c'),
    ({'device': 'mpu6000', 'axes': MPU_AXES, 'simulation.bus': 'i2c', 'i2c.address': 0x50},
     'invalid parameter i2c.address: an MPU answers at 0x68 (104, AD0 low) or 0x69 (105, AD0 '
     'high), got 0x50 (80)'),
    ({'device': 'mpu6000', 'axes': MPU_AXES, 'source': 'i2c', 'i2c.bus': 250},
     'cannot open /dev/i2c-250: no such I2C bus (ls /dev/i2c-* lists those there are'),
], ids=['mlx90609 on i2c', 'adis16130 simulated on i2c', 'mpu6050 simulated on spi',
        'mpu6050 on spidev', 'address of no MPU', 'absent i2c bus'])
def test_bad_i2c_settings_exit_1_naming_the_parameter(launcher, params, named):
    driver = launcher.driver(params)
    assert driver.wait(TIMEOUT_S) == 1
    assert named in driver.output()
