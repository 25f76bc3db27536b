"""The MPU-6000/6500 driver against the simulated part, frame by frame, and its offsets."""

# Nothing of the project is mocked: `Mpu6000` talks to `SimulatedMpu6000` through
# `SimulatedMpuTransport`. The wrappers below only record the frames or stand for a
# bad wire between the two.

import math

from mlx_tempcomp.core.procedures.mpu6000_offsets import (accel_offset_lsb,
                                                          GYRO_OFFSET_DPS_PER_LSB, gyro_offset_lsb,
                                                          rest_bias, STANDARD_GRAVITY_M_S2)
from mlx_tempcomp.hardware.errors import HardwareError, ProtocolError, SilentBusError
from mlx_tempcomp.hardware.mpu6000 import (
    ACCEL_CONFIG, GYRO_CONFIG, MPU6000, Mpu6000, MPU6500, PWR_MGMT_1, USER_CTRL, WHO_AM_I)
from mlx_tempcomp.simulation.mpu6000 import MpuTruth, SimulatedMpu6000
from mlx_tempcomp.simulation.physics import ThermalProfile
from mlx_tempcomp.sources.mpu6000 import SimulatedMpuSource
import numpy as np
import pytest

G = STANDARD_GRAVITY_M_S2
QUIET = MpuTruth(gyro_noise_dps=0.0, accel_noise_g=0.0)
# Bias bounds after the offsets: half a register step plus, for the accelerometer, the
# LSB an odd bias loses to bit 0, plus 4 sigma of the mean of the noise.
GYRO_RESIDUAL_DPS = GYRO_OFFSET_DPS_PER_LSB / 2 + 4 * 0.063 / math.sqrt(1000)
ACCEL_RESIDUAL_G = 1.5 / 2048 + 4 * 0.005 / math.sqrt(1000)


class Recorder:
    """A wire that remembers every MOSI frame."""

    def __init__(self, inner):
        self.inner = inner
        self.frames = []

    def transfer(self, tx):
        self.frames.append(bytes(tx))
        return self.inner.transfer(tx)

    def wait(self, seconds):
        self.inner.wait(seconds)

    def close(self):
        self.inner.close()


class DroppedWrites(Recorder):
    """A wire on which write frames never reach the part."""

    def transfer(self, tx):
        return bytes(len(tx)) if not tx[0] & 0x80 else self.inner.transfer(tx)


def started(truth=QUIET, variant=MPU6000, **options):
    device = SimulatedMpu6000(truth, variant)
    driver = Mpu6000(device.transport(), variant, **options)
    driver.start()
    return device, driver


def mean_bias(source, samples=1000):
    """Mean gyro deg/s and acceleration g of a rest record (gravity left in)."""
    record = source.record(samples, 0.005)
    return (np.degrees(record.gyro_rad_s.mean(axis=0)),
            record.acceleration_m_s2.mean(axis=0) / G)


def test_read_frames_set_bit_7_and_burst_reads_auto_increment():
    device = SimulatedMpu6000(variant=MPU6500)
    transport = device.transport()
    assert transport.transfer(bytes((WHO_AM_I | 0x80, 0))) == bytes((0, 0x70))
    # Writes without bit 7; a 4-byte burst write fills SMPLRT_DIV..ACCEL_CONFIG.
    transport.transfer(bytes((0x19, 7, 3, 0x18, 0x08)))
    assert transport.transfer(bytes((0x99, 0, 0, 0, 0))) == bytes((0, 7, 3, 0x18, 0x08))


def test_start_sequence_resets_wakes_and_configures():
    device = SimulatedMpu6000()
    wire = Recorder(device.transport())
    driver = Mpu6000(wire, gyro_full_scale_dps=2000, accel_full_scale_g=8, dlpf_config=2,
                     sample_rate_divider=9)
    driver.start()
    writes = [frame for frame in wire.frames if not frame[0] & 0x80]
    assert writes == [bytes((0x6B, 0x80)), bytes((0x68, 0x07)), bytes((0x6A, 0x10)),
                      bytes((0x6B, 0x01)), bytes((0x19, 9, 2, 0x18, 0x10))]
    assert wire.frames[0] == bytes((0xF5, 0))
    assert device.registers[PWR_MGMT_1] == 0x01 and device.registers[USER_CTRL] == 0x10
    assert (device.registers[GYRO_CONFIG], device.registers[ACCEL_CONFIG]) == (0x18, 0x10)
    assert driver.factory_accel_lsb == QUIET.factory_accel_lsb
    # Reset, signal path reset and wake each wait 0.1 s on the part's clock.
    assert 0.3 < device.clock.now_s < 0.31


@pytest.mark.parametrize('variant, temperature_c', [(MPU6000, 25.0 + 0.2 / 340),
                                                    (MPU6500, 21.0 + 1335 / 333.87)])
def test_read_converts_counts_to_si_units(variant, temperature_c):
    # Quiet part face up at 25 C: gyro = bias, accel = (0.03, -0.05, 1 + 0.08) g.
    # MPU-6000: (25 - 36.53) x 340 = -3920.2 -> -3920; MPU-6500: 4 x 333.87 = 1335.48 -> 1335.
    _, driver = started(variant=variant)
    raw = driver.read_raw()
    assert raw.gyro == (105, -170, 59)                  # round(bias x 131)
    assert raw.accel == (492, -819, 17695)              # round(g x 16384)
    reading = driver.read()
    np.testing.assert_allclose(reading.gyro_rad_s, np.radians(np.array(raw.gyro) / 131.0))
    np.testing.assert_allclose(reading.acceleration_m_s2, np.array(raw.accel) / 16384.0 * G)
    assert reading.temperature_c == pytest.approx(temperature_c, abs=1e-12)
    assert not reading.saturated


def test_full_scale_and_saturation():
    truth = MpuTruth(gyro_noise_dps=0.0, accel_noise_g=0.0, rate_dps=(100.0, 300.0, 0.0))
    _, driver = started(truth, gyro_full_scale_dps=2000, accel_full_scale_g=16)
    assert driver.read_raw().gyro == (round(100.8 * 16.4), round(298.7 * 16.4), 7)
    _, narrow = started(truth)
    reading = narrow.read()
    assert reading.saturated and narrow.counters.saturated == 1
    assert narrow.read_raw().gyro[1] == 32767


def test_temperature_follows_the_profile():
    truth = MpuTruth(gyro_noise_dps=0.0, accel_noise_g=0.0, gyro_bias_dps_per_c=(0.1, 0, 0),
                     thermal=ThermalProfile(times_s=(0.0, 100.0), temperatures_c=(25.0, 45.0)))
    device, driver = started(truth)
    device.clock.advance(50.0 - device.clock.now_s)
    reading = driver.read()
    assert reading.temperature_c == pytest.approx(35.0, abs=1.0 / 340)
    assert np.degrees(reading.gyro_rad_s[0]) == pytest.approx(0.8 + 1.0, abs=0.5 / 131)


def test_silent_bus_wrong_part_and_sleeping_part_are_errors():
    device = SimulatedMpu6000()
    driver = Mpu6000(device.transport())
    for stuck in (0xFF, 0x00):
        device.stuck_miso = stuck
        with pytest.raises(SilentBusError, match=f'WHO_AM_I read 0x{stuck:02X}'):
            driver.start()
    device.stuck_miso = None
    with pytest.raises(SilentBusError, match='asleep'):
        driver.read()                                   # never started: outputs read 0
    assert driver.counters.as_dict() == {'silent_bus': 3, 'protocol_errors': 0, 'saturated': 0}
    wrong = Mpu6000(SimulatedMpu6000(variant=MPU6500).transport(), MPU6000)
    with pytest.raises(ProtocolError, match=r'read 0x70, expected 0x68 for mpu6000 \(an mpu6500'):
        wrong.start()


def test_a_write_that_does_not_land_is_detected():
    driver = Mpu6000(DroppedWrites(SimulatedMpu6000().transport()))
    with pytest.raises(ProtocolError, match='register 0x6A: wrote 10, read back 00'):
        driver.start()
    assert driver.counters.protocol_errors == 1


def test_bad_settings_are_refused():
    transport = SimulatedMpu6000().transport()
    with pytest.raises(HardwareError, match=r'gyro full scale must be one of \[250, 500'):
        Mpu6000(transport, gyro_full_scale_dps=300)
    with pytest.raises(HardwareError, match='dlpf_config must be 0..6'):
        Mpu6000(transport, dlpf_config=7)
    _, driver = started()
    with pytest.raises(HardwareError, match='40000 does not fit'):
        driver.write_gyro_offsets((0, 40000, 0))
    with pytest.raises(HardwareError, match='needs 3 integers'):
        driver.write_gyro_offsets((0, 1.5, 0))
    with pytest.raises(HardwareError, match='accelerometer offsets: factory -1743 - offset 31500'):
        driver.write_accel_offsets((31500, 0, 0))


def test_negative_gyro_offsets_are_written_as_twos_complement():
    device, driver = started()
    driver.write_gyro_offsets((-26, 42, -1))
    assert bytes(device.registers[0x13:0x19]) == bytes((0xFF, 0xE6, 0x00, 0x2A, 0xFF, 0xFF))
    assert driver.read_offsets().gyro_lsb == (-26, 42, -1)


@pytest.mark.parametrize('variant, addresses', [(MPU6000, (0x06, 0x08, 0x0A)),
                                                (MPU6500, (0x77, 0x7A, 0x7D))])
def test_accel_read_modify_write_keeps_bit_0_of_the_factory_value(variant, addresses):
    device, driver = started(variant=variant)
    factory = QUIET.factory_accel_lsb                  # (-1743, 2210, 1385): x, z odd
    assert driver.read_offsets().accel_lsb == factory
    written = driver.write_accel_offsets((62, -103, 164))
    # -1743 - 62, 2210 - (-103 & ~1 = -104), 1385 - 164; bit 0 as in the factory value.
    assert written == (-1805, 2314, 1221)
    assert [device.registers[a + 1] & 1 for a in addresses] == [1, 0, 1]
    assert driver.read_offsets().accel_lsb == written
    # A second write replaces the first; it does not subtract again.
    assert driver.write_accel_offsets((0, 0, 165)) == (-1743, 2210, 1221)


def test_offsets_from_a_rest_record_zero_the_simulated_bias():
    # Face down, so gravity is -1 g on z and the z bias must keep its sign.
    source = SimulatedMpuSource(MpuTruth(acceleration_g=(0.0, 0.0, -1.0)), seed=3)
    source.start()
    record = source.record(1000, 0.005)
    bias = rest_bias(record.gyro_rad_s, record.acceleration_m_s2)
    assert (bias.gravity_axis, bias.gravity_sign) == (2, -1)
    np.testing.assert_allclose(np.array(bias.acceleration_m_s2) / G, (0.03, -0.05, 0.08),
                               atol=0.001)
    gyro_before, accel_before = mean_bias(source)
    np.testing.assert_allclose(gyro_before, (0.8, -1.3, 0.45), atol=0.01)
    source.write_offsets(gyro_offset_lsb(bias.gyro_rad_s), accel_offset_lsb(
        bias.acceleration_m_s2))
    gyro_after, accel_after = mean_bias(source)
    assert np.all(np.abs(gyro_after) < GYRO_RESIDUAL_DPS)
    assert np.all(np.abs(accel_after - (0.0, 0.0, -1.0)) < ACCEL_RESIDUAL_G)


def test_calibrate_offsets_on_an_mpu6500_lying_on_its_side():
    truth = MpuTruth.random(np.random.default_rng(7), acceleration_g=(0.0, 1.0, 0.0))
    source = SimulatedMpuSource(truth, variant='mpu6500', seed=7)
    source.start()
    calibration = source.calibrate_offsets(samples=1000)
    assert (calibration.bias.gravity_axis, calibration.bias.gravity_sign) == (1, 1)
    np.testing.assert_allclose(np.degrees(calibration.bias.gyro_rad_s), truth.gyro_bias_dps,
                               atol=0.01)
    gyro_after, accel_after = mean_bias(source)
    assert np.all(np.abs(gyro_after) < GYRO_RESIDUAL_DPS)
    assert np.all(np.abs(accel_after - (0.0, 1.0, 0.0)) < ACCEL_RESIDUAL_G)
    # Calibrating again starts from the bare part, so it finds the same offsets.
    again = source.calibrate_offsets(samples=1000)
    assert np.all(np.abs(np.subtract(again.gyro_lsb, calibration.gyro_lsb)) <= 1)
    assert np.all(np.abs(np.subtract(again.accel_registers, calibration.accel_registers)) <= 2)


def test_power_cycle_clears_the_offsets_and_rewriting_restores_them():
    source = SimulatedMpuSource(seed=5)
    source.start()
    calibration = source.calibrate_offsets(samples=1000)
    source.simulated.power_cycle()
    with pytest.raises(SilentBusError, match='asleep'):
        source.read()
    source.start()
    assert source.device.read_offsets().gyro_lsb == (0, 0, 0)
    assert source.device.read_offsets().accel_lsb == MpuTruth().factory_accel_lsb
    gyro_bare, accel_bare = mean_bias(source)
    np.testing.assert_allclose(gyro_bare, (0.8, -1.3, 0.45), atol=0.01)
    np.testing.assert_allclose(accel_bare, (0.03, -0.05, 1.08), atol=0.001)
    # What the state file would hold: the gyro registers and the accel bias in LSB.
    written = source.write_offsets(calibration.gyro_lsb, calibration.accel_bias_lsb)
    assert written == calibration.accel_registers
    gyro_after, accel_after = mean_bias(source)
    assert np.all(np.abs(gyro_after) < GYRO_RESIDUAL_DPS)
    assert np.all(np.abs(accel_after - (0.0, 0.0, 1.0)) < ACCEL_RESIDUAL_G)
    # start() resets the part, which clears the offsets just as a power cycle does.
    source.start()
    assert source.device.read_offsets().gyro_lsb == (0, 0, 0)


def test_source_stamps_samples_on_the_simulated_clock():
    source = SimulatedMpuSource(seed=1)
    source.start()
    source.advance_to(10.0)
    first = source.read()
    source.advance_to(10.5)
    second = source.read()
    assert first.time_s == 10.0 and second.time_s == 10.5
    assert first.gyro_rad_s.shape == first.acceleration_m_s2.shape == (3,)
    assert source.axes == ('x', 'y', 'z')
    with pytest.raises(HardwareError, match="unknown MPU variant 'mpu9250'"):
        SimulatedMpuSource(variant='mpu9250')
