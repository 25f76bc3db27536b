"""
The MPU-6000 family over I2C: the same protocol class and the same simulated part as on SPI.

Nothing of the project is mocked: `Mpu6000` talks through the real `SmbusTransport` to
`SimulatedMpu6000`'s I2C face on a `SimulatedI2cBus`, which answers smbus2's block calls
with smbus2's limits and i2c-dev's errors. The buses below only record the calls or stand
for what the kernel answers (a driver holding the address, a NACK code of another adapter).
The last test reads a real part on /dev/i2c-* and is skipped without one.
"""

import errno
import glob
import math
import os

from mlx_tempcomp.core.procedures.mpu6000_offsets import (GYRO_OFFSET_DPS_PER_LSB,
                                                          STANDARD_GRAVITY_M_S2)
from mlx_tempcomp.hardware.errors import (HardwareError, NackError, ProtocolError,
                                          SilentBusError, TransportError)
from mlx_tempcomp.hardware.mpu6000 import (
    ACCEL_XOUT_H, I2C_IF_DIS, MPU6000, Mpu6000, MPU6050, MPU6500, PWR_MGMT_1, USER_CTRL,
    WHO_AM_I)
from mlx_tempcomp.hardware.transport import open_i2c, SmbusTransport
from mlx_tempcomp.simulation.i2c import SimulatedI2cBus
from mlx_tempcomp.simulation.mpu6000 import MpuTruth, SimulatedMpu6000
from mlx_tempcomp.sources.mpu6000 import i2c_mpu, SimulatedMpuSource
import numpy as np
import pytest

G = STANDARD_GRAVITY_M_S2
QUIET = MpuTruth(gyro_noise_dps=0.0, accel_noise_g=0.0)


class RecordingBus:
    """A simulated bus that remembers every block call: (read|write, address, register, n)."""

    def __init__(self, inner: SimulatedI2cBus):
        self.inner = inner
        self.calls = []

    def read_i2c_block_data(self, address, register, length):
        self.calls.append(('read', address, register, length))
        return self.inner.read_i2c_block_data(address, register, length)

    def write_i2c_block_data(self, address, register, data):
        self.calls.append(('write', address, register, list(data)))
        self.inner.write_i2c_block_data(address, register, data)

    def close(self):
        self.inner.close()


class KernelBus:
    """A bus whose every call fails as the kernel fails it, with ``code``."""

    def __init__(self, code: int):
        self.code = code

    def read_i2c_block_data(self, address, register, length):
        raise OSError(self.code, os.strerror(self.code))

    def close(self):
        """Nothing to release."""


def on_i2c(variant=MPU6000, truth=QUIET, part_address=0x68, address=None):
    """Give a part on a recorded simulated bus, and the driver's transport to ``address``."""
    device = SimulatedMpu6000(truth, variant, i2c_address=part_address)
    bus = RecordingBus(SimulatedI2cBus(device.clock))
    bus.inner.attach(part_address, device)
    transport = SmbusTransport(bus, part_address if address is None else address, 'bus 1',
                               device.clock.advance)
    return device, bus, transport


def test_register_reads_carry_no_read_flag_and_split_into_32_byte_blocks():
    device, bus, transport = on_i2c(MPU6500)
    assert transport.read_registers(WHO_AM_I, 1) == bytes((0x70,))
    assert bus.calls == [('read', 0x68, 0x75, 1)]
    # 80 registers: blocks of 32, 32 and 16 from 0x00, 0x20 and 0x40, auto-incrementing.
    bus.calls.clear()
    assert transport.read_registers(0x00, 80) == bytes(device.registers[:80])
    assert bus.calls == [('read', 0x68, 0x00, 32), ('read', 0x68, 0x20, 32),
                         ('read', 0x68, 0x40, 16)]
    bus.calls.clear()
    transport.write_registers(0x19, bytes((7, 3, 0x18, 0x08)))
    assert bus.calls == [('write', 0x68, 0x19, [7, 3, 0x18, 0x08])]
    assert transport.read_registers(0x19, 4) == bytes((7, 3, 0x18, 0x08))
    # smbus2's limit holds on the simulated bus too: the transport never asks for more.
    with pytest.raises(ValueError, match='over 32 bytes'):
        bus.inner.read_i2c_block_data(0x68, 0x00, 33)


def test_start_over_i2c_leaves_the_i2c_interface_on():
    device, bus, transport = on_i2c()
    driver = Mpu6000(transport, gyro_full_scale_dps=2000, accel_full_scale_g=8,
                     dlpf_config=2, sample_rate_divider=9)
    driver.start()
    assert driver.bus == 'i2c'
    assert bus.calls[0] == ('read', 0x68, WHO_AM_I, 1)
    writes = [call[2:] for call in bus.calls if call[0] == 'write']
    # As on SPI, but without USER_CTRL = I2C_IF_DIS, which would cut this bus.
    assert writes == [(0x6B, [0x80]), (0x68, [0x07]), (0x6B, [0x01]), (0x19, [9, 2, 0x18, 0x10])]
    assert device.registers[PWR_MGMT_1] == 0x01 and device.registers[USER_CTRL] == 0
    assert driver.factory_accel_lsb == QUIET.factory_accel_lsb
    # The 14 output bytes are one block read.
    bus.calls.clear()
    driver.read()
    assert bus.calls == [('read', 0x68, ACCEL_XOUT_H, 14)]
    # The three 0.1 s waits, plus each call's bytes at 400 kHz (9 bits a byte).
    assert 0.3 < device.clock.now_s < 0.302


def test_i2c_if_dis_set_over_i2c_cuts_the_part_off():
    _, _, transport = on_i2c()
    transport.write_registers(USER_CTRL, bytes((I2C_IF_DIS,)))
    with pytest.raises(NackError, match='no device acknowledged address 0x68 on bus 1'):
        transport.read_registers(WHO_AM_I, 1)


@pytest.mark.parametrize('variant', [MPU6000, MPU6050, MPU6500], ids=lambda v: v.name)
def test_i2c_reads_what_spi_reads(variant):
    _, _, transport = on_i2c(variant)
    over_i2c = Mpu6000(transport, variant)
    over_i2c.start()
    spi_variant = MPU6000 if variant is MPU6050 else variant
    over_spi = Mpu6000(SimulatedMpu6000(QUIET, spi_variant).transport(), spi_variant)
    over_spi.start()
    assert over_i2c.read_raw() == over_spi.read_raw()
    reading = over_i2c.read()
    assert reading.temperature_c == pytest.approx(over_spi.read().temperature_c)
    np.testing.assert_allclose(np.degrees(reading.gyro_rad_s), (0.8, -1.3, 0.45),
                               atol=0.5 / 131)
    assert over_i2c.counters.as_dict() == {'silent_bus': 0, 'protocol_errors': 0,
                                           'saturated': 0}


def test_a_part_at_another_address_is_a_nack_naming_ad0():
    _, _, transport = on_i2c(address=0x69)
    driver = Mpu6000(transport)
    with pytest.raises(NackError) as raised:
        driver.start()
    assert str(raised.value) == (
        'WHO_AM_I: no device acknowledged address 0x69 on bus 1 (No such device or address): '
        'nothing answers there (wiring, supply, or another address); an MPU answers at 0x68 '
        'with AD0 low, 0x69 with AD0 high')
    assert isinstance(raised.value, SilentBusError)
    assert driver.counters.silent_bus == 1
    # With AD0 high the part answers at 0x69.
    _, _, transport = on_i2c(part_address=0x69)
    Mpu6000(transport).start()


@pytest.mark.parametrize('part, expected, hint', [
    (MPU6500, MPU6050, r'read 0x70, expected 0x68 for mpu6050 \(an mpu6500\?\)'),
    (MPU6050, MPU6500, r'read 0x68, expected 0x70 for mpu6500 \(an mpu6000 or mpu6050\?\)'),
], ids=['mpu6500 for a 6050', 'mpu6050 for a 6500'])
def test_a_wrong_who_am_i_over_i2c_names_the_part_it_looks_like(part, expected, hint):
    _, _, transport = on_i2c(part)
    driver = Mpu6000(transport, expected)
    with pytest.raises(ProtocolError, match=f'^WHO_AM_I {hint}$'):
        driver.start()
    assert driver.counters.protocol_errors == 1


def test_a_stuck_data_line_over_i2c_is_a_nack_or_a_bus_error():
    device, _, transport = on_i2c()
    driver = Mpu6000(transport)
    driver.start()
    device.stuck_miso = 0xFF              # SDA never pulled low: no acknowledge
    with pytest.raises(NackError, match='^no device acknowledged address 0x68 on bus 1'):
        driver.read()
    device.stuck_miso = 0x00              # SDA held low: the adapter times out
    with pytest.raises(TransportError, match=r'^I2C block read at register 0x3B of 0x68 on '
                                             r'bus 1 failed: \[Errno 110\] Connection timed'):
        driver.read()
    assert driver.counters.silent_bus == 1
    device.stuck_miso = None
    assert not driver.read().saturated


@pytest.mark.parametrize('code, error, text', [
    (errno.EREMOTEIO, NackError, 'no device acknowledged address 0x68 on bus 1 (Remote I/O '
                                 'error)'),
    (errno.EBUSY, TransportError, 'address 0x68 on bus 1 is held by a kernel driver (Device or '
                                  'resource busy): unbind it (for an MPU, inv-mpu6050)'),
], ids=['EREMOTEIO', 'EBUSY'])
def test_kernel_error_codes_become_typed_errors(code, error, text):
    transport = SmbusTransport(KernelBus(code), 0x68, 'bus 1')
    with pytest.raises(error) as raised:
        transport.read_registers(WHO_AM_I, 1)
    assert str(raised.value).startswith(text)


def test_bad_buses_addresses_and_variants_are_refused():
    with pytest.raises(TransportError, match=r'^cannot open /dev/i2c-250: no such I2C bus '
                                             r'\(ls /dev/i2c-\* lists those there are'):
        open_i2c(250, 0x68)
    with pytest.raises(TransportError, match='cannot open /dev/i2c-250'):
        i2c_mpu(250, 0x68, 'mpu6050')
    with pytest.raises(TransportError, match='0x80 is outside the 7-bit device range'):
        SmbusTransport(SimulatedI2cBus(SimulatedMpu6000().clock), 0x80, 'bus 1')
    # The MPU-6050 has no SPI: refused by the protocol; its SPI face drives nothing.
    device = SimulatedMpu6000(variant=MPU6050)
    with pytest.raises(HardwareError, match='^the mpu6050 has no SPI interface: read it over '
                                            'I2C$'):
        Mpu6000(device.transport(), MPU6050)
    assert device.transport().transfer(bytes((WHO_AM_I | 0x80, 0))) == b'\xff\xff'
    with pytest.raises(HardwareError, match='the mpu6050 has no SPI interface'):
        SimulatedMpuSource(variant='mpu6050')
    with pytest.raises(HardwareError, match="bus must be spi or i2c, got 'usb'"):
        SimulatedMpuSource(bus='usb')


@pytest.mark.parametrize('variant', ['mpu6050', 'mpu6500'])
def test_offsets_calibrated_over_i2c_zero_the_bias_as_over_spi(variant):
    results = {}
    for bus in ('spi', 'i2c') if variant != 'mpu6050' else ('i2c',):
        source = SimulatedMpuSource(variant=variant, seed=3, bus=bus)
        source.start()
        calibration = source.calibrate_offsets()
        after = source.record(1000, 0.005)
        results[bus] = calibration
        gyro_dps = np.degrees(after.gyro_rad_s.mean(axis=0))
        accel_g = after.acceleration_m_s2.mean(axis=0) / G
        assert np.all(np.abs(gyro_dps) < GYRO_OFFSET_DPS_PER_LSB / 2 + 4 * 0.063 / math.sqrt(
            1000) + 4 * 0.063 / math.sqrt(200)), gyro_dps
        np.testing.assert_allclose(accel_g, (0.0, 0.0, 1.0), atol=0.002)
        assert source.device.read_offsets().gyro_lsb == calibration.gyro_lsb
    if 'spi' in results:
        # One protocol: the same part and seed give the same registers on both buses.
        assert results['spi'].gyro_lsb == results['i2c'].gyro_lsb
        assert results['spi'].accel_registers == results['i2c'].accel_registers


@pytest.mark.hardware(devices='/dev/i2c-*')
def test_a_real_part_on_i2c_answers_and_reads_gravity_at_rest():
    """A part lying still on MLX_TEMPCOMP_I2C_BUS (default 1) at MLX_TEMPCOMP_I2C_ADDRESS."""
    bus = int(os.environ.get('MLX_TEMPCOMP_I2C_BUS', '1'))
    if not glob.glob(f'/dev/i2c-{bus}'):
        pytest.skip(f'no /dev/i2c-{bus} (set MLX_TEMPCOMP_I2C_BUS)')
    address = int(os.environ.get('MLX_TEMPCOMP_I2C_ADDRESS', '0x68'), 0)
    source = i2c_mpu(bus, address, os.environ.get('MLX_TEMPCOMP_MPU_VARIANT', 'mpu6050'))
    try:
        source.start()
        record = source.record(100, 0.005)
    finally:
        source.close()
    gravity_g = np.linalg.norm(record.acceleration_m_s2.mean(axis=0)) / G
    assert gravity_g == pytest.approx(1.0, abs=0.15)
    # The datasheets' zero-rate tolerance is +-20 deg/s; the die sits between -40 and 85 C.
    assert np.all(np.abs(np.degrees(record.gyro_rad_s.mean(axis=0))) < 20.0)
    assert -40.0 < record.temperature_c.mean() < 85.0
