"""
A simulated MPU-6000 / MPU-6050 / MPU-6500 that answers at the register level, on SPI or I2C.

Its SPI face speaks the frames of `mlx_tempcomp.hardware.mpu6000`: bit 7 of
the first byte selects read, the address auto-increments over the 128
registers. Its I2C face (`i2c_read`, `i2c_write`, on a
`mlx_tempcomp.simulation.i2c.SimulatedI2cBus` at ``i2c_address``) reads and
writes the same registers without a read flag; it stops acknowledging once
I2C_IF_DIS is set on a part that has SPI (the MPU-6050 has none: its SPI
face drives nothing, every byte reads 0xFF). The
outputs come from `MpuTruth` and pass through the offset registers as on the
part: the gyro offset adds offset x 0.031 deg/s (the note's +-1000 dps format),
the accelerometer offset adds (register & ~1) / 2048 g, where the factory
(OTP) value already cancels the factory error. At power-on (and after
DEVICE_RESET) the part sleeps, its outputs read 0, the gyro offsets are 0
and the accelerometer offsets hold the factory values.
"""

from dataclasses import dataclass
import errno
import os
from typing import Optional

import numpy as np

from .clock import SimClock
from .i2c import SimulatedI2cBus
from .physics import ThermalProfile
from ..core.procedures import ACCEL_OFFSET_LSB_PER_G, from_twos_complement, GYRO_OFFSET_DPS_PER_LSB
from ..hardware import mpu6000 as protocol
from ..hardware.transport import SmbusTransport

REGISTER_COUNT = 128
_DATA = range(protocol.ACCEL_XOUT_H, protocol.ACCEL_XOUT_H + protocol.DATA_BYTES)
_FULL_SCALES_DPS = (250, 500, 1000, 2000)
_FULL_SCALES_G = (2, 4, 8, 16)


@dataclass(frozen=True)
class MpuTruth:
    """
    What one simulated part really does, x, y, z.

    Biases are with the factory trim in place and no user offsets: what a
    rest record shows after power-on. Noise is white, 1 sigma per sample
    (datasheet-like: 0.005 deg/s/sqrt(Hz) and 400 ug/sqrt(Hz) at 100 Hz
    bandwidth).
    """

    gyro_bias_dps: tuple = (0.8, -1.3, 0.45)
    gyro_bias_dps_per_c: tuple = (0.0, 0.0, 0.0)
    reference_temperature_c: float = 25.0
    accel_bias_g: tuple = (0.03, -0.05, 0.08)
    factory_accel_lsb: tuple = (-1743, 2210, 1385)     # x and z odd: bit 0 set
    rate_dps: tuple = (0.0, 0.0, 0.0)
    acceleration_g: tuple = (0.0, 0.0, 1.0)             # lying face up
    gyro_noise_dps: float = 0.063
    accel_noise_g: float = 0.005
    thermal: ThermalProfile = ThermalProfile()

    @classmethod
    def random(cls, rng: np.random.Generator, **fixed) -> 'MpuTruth':
        """Draw biases within the datasheet tolerances (ZRO +-20 deg/s, zero-g +-80 mg)."""
        factory = rng.integers(-3000, 3000, 3)
        factory[0] |= 1
        drawn = {'gyro_bias_dps': tuple(rng.normal(0.0, 5.0, 3)),
                 'gyro_bias_dps_per_c': tuple(rng.normal(0.0, 0.03, 3)),
                 'accel_bias_g': tuple(rng.normal(0.0, (0.025, 0.025, 0.04))),
                 'factory_accel_lsb': tuple(int(v) for v in factory)}
        return cls(**{**drawn, **fixed})

    def temperature_c(self, time_s: float) -> float:
        return self.thermal.chamber_c(time_s)


class SimulatedMpu6000:
    """Register-level model of the part's SPI and I2C interfaces."""

    def __init__(self, truth: MpuTruth = MpuTruth(), variant: protocol.Variant = protocol.MPU6000,
                 clock: Optional[SimClock] = None, seed: int = 0, sclk_hz: float = 1e6,
                 gyro_offset_dps_per_lsb: float = GYRO_OFFSET_DPS_PER_LSB,
                 i2c_address: int = protocol.I2C_ADDRESSES[0]):
        if truth.thermal.time_constant_s != 0.0:
            msg = 'the simulated MPU follows its thermal profile directly (time_constant_s 0)'
            raise ValueError(msg)
        self.truth = truth
        self.variant = variant
        self.clock = clock or SimClock()
        self.bit_time_s = 1.0 / sclk_hz
        self.gyro_offset_dps_per_lsb = gyro_offset_dps_per_lsb
        self.i2c_address = i2c_address              # the AD0 pin: 0x68 low, 0x69 high
        # 0x00 or 0xFF: the data line stuck (MISO; on I2C, SDA: held low, or never pulled
        # low to acknowledge).
        self.stuck_miso: Optional[int] = None
        self._rng = np.random.default_rng(seed)
        self.registers = bytearray(REGISTER_COUNT)
        self._data = bytes(protocol.DATA_BYTES)
        self.power_cycle()

    def power_cycle(self) -> None:
        """Power off and on: every register back to its power-on value, outputs 0."""
        self.registers[:] = bytes(REGISTER_COUNT)
        self.registers[protocol.PWR_MGMT_1] = protocol.SLEEP
        self.registers[protocol.WHO_AM_I] = self.variant.who_am_i
        for address, value in zip(self.variant.accel_offset_registers,
                                  self.truth.factory_accel_lsb):
            self.registers[address:address + 2] = protocol.word_bytes(value)
        self._data = bytes(protocol.DATA_BYTES)

    def _word(self, address: int) -> int:
        return from_twos_complement((self.registers[address] << 8) | self.registers[address + 1])

    def _sample(self) -> bytes:
        """Latch the 14 output bytes now (a burst read sees one consistent sample)."""
        truth = self.truth
        temperature_c = truth.temperature_c(self.clock.now_s)
        gyro_offsets = [self._word(a) for a in protocol.GYRO_OFFSET_REGISTERS]
        gyro_dps = (np.array(truth.rate_dps) + truth.gyro_bias_dps
                    + np.multiply(truth.gyro_bias_dps_per_c,
                                  temperature_c - truth.reference_temperature_c)
                    + np.multiply(gyro_offsets, self.gyro_offset_dps_per_lsb)
                    + self._rng.normal(0.0, truth.gyro_noise_dps, 3))
        accel_offsets = [self._word(a) & ~1 for a in self.variant.accel_offset_registers]
        factory = [value & ~1 for value in truth.factory_accel_lsb]
        accel_g = (np.array(truth.acceleration_g) + truth.accel_bias_g
                   + (np.array(accel_offsets) - factory) / ACCEL_OFFSET_LSB_PER_G
                   + self._rng.normal(0.0, truth.accel_noise_g, 3))
        gyro_scale = protocol.GYRO_LSB_PER_DPS[
            _FULL_SCALES_DPS[self.registers[protocol.GYRO_CONFIG] >> 3 & 3]]
        accel_scale = protocol.ACCEL_LSB_PER_G[
            _FULL_SCALES_G[self.registers[protocol.ACCEL_CONFIG] >> 3 & 3]]
        temperature = (temperature_c - self.variant.temperature_offset_c) \
            * self.variant.temperature_lsb_per_c
        counts = np.concatenate((accel_g * accel_scale, [temperature], gyro_dps * gyro_scale))
        low, high = protocol.INT16_LIMITS
        return b''.join(protocol.word_bytes(int(v))
                        for v in np.clip(np.round(counts), low, high))

    def _latch(self, address: int, count: int) -> range:
        """Give the registers an access spans; a span over the outputs takes a new sample."""
        span = range(address, address + count)
        if not self.registers[protocol.PWR_MGMT_1] & protocol.SLEEP and \
                any(a in _DATA for a in span):
            self._data = self._sample()
        return span

    def frame(self, tx: bytes) -> bytes:
        """Execute one SPI frame, an address byte then data; return the MISO bytes."""
        if not self.variant.spi:
            return b'\xff' * len(tx)                # no SPI pins: nothing drives MISO
        address = tx[0] & 0x7F
        span = self._latch(address, len(tx) - 1)
        self.clock.advance(8 * len(tx) * self.bit_time_s)
        if tx[0] & protocol.READ_FLAG:
            rx = bytes((0,)) + bytes(self._read(a % REGISTER_COUNT) for a in span)
        else:
            self._write_block(address, tx[1:])
            rx = bytes(len(tx))
        if self.stuck_miso is not None:
            return bytes((self.stuck_miso,)) * len(tx)
        return rx

    def _i2c_answers(self) -> None:
        """Raise the ``OSError`` i2c-dev gives when the part does not take part in a transfer."""
        if self.stuck_miso == 0x00:
            raise OSError(errno.ETIMEDOUT, os.strerror(errno.ETIMEDOUT))
        if self.stuck_miso == 0xFF or (self.variant.spi and self.registers[protocol.USER_CTRL]
                                       & protocol.I2C_IF_DIS):
            raise OSError(errno.ENXIO, os.strerror(errno.ENXIO))

    def i2c_read(self, register: int, count: int) -> bytes:
        """Execute one I2C register read: the register address, then ``count`` bytes."""
        self._i2c_answers()
        return bytes(self._read(a % REGISTER_COUNT) for a in self._latch(register, count))

    def i2c_write(self, register: int, data: bytes) -> None:
        """Execute one I2C register write: the register address, then ``data``."""
        self._i2c_answers()
        self._latch(register, len(data))
        self._write_block(register, data)

    def _write_block(self, address: int, data: bytes) -> None:
        for offset, value in enumerate(data):
            self._write((address + offset) % REGISTER_COUNT, value)

    def _read(self, address: int) -> int:
        if address in _DATA:
            return self._data[address - protocol.ACCEL_XOUT_H]
        return self.registers[address]

    def _write(self, address: int, value: int) -> None:
        if address in _DATA or address == protocol.WHO_AM_I:
            return
        if address == protocol.PWR_MGMT_1 and value & protocol.DEVICE_RESET:
            self.power_cycle()
        elif address == protocol.SIGNAL_PATH_RESET:
            self.registers[address] = 0              # self-clearing
        else:
            self.registers[address] = value

    def transport(self) -> 'SimulatedMpuTransport':
        return SimulatedMpuTransport(self)

    def i2c_transport(self, address: Optional[int] = None) -> SmbusTransport:
        """Give the I2C transport to ``address`` (default: this part's) on a bus of its own."""
        bus = SimulatedI2cBus(self.clock)
        bus.attach(self.i2c_address, self)
        return SmbusTransport(bus, self.i2c_address if address is None else address,
                              'the simulated I2C bus', self.clock.advance)


class SimulatedMpuTransport:
    """`Transport` onto a `SimulatedMpu6000`: frames in, MISO bytes out, waits on its clock."""

    def __init__(self, device: SimulatedMpu6000):
        self.device = device

    def transfer(self, tx: bytes) -> bytes:
        if not tx:
            msg = 'an SPI frame needs at least the address byte'
            raise ValueError(msg)
        return self.device.frame(bytes(tx))

    def wait(self, seconds: float) -> None:
        self.device.clock.advance(seconds)

    def close(self) -> None:
        """Nothing to release."""
