"""
MPU-6000 / MPU-6050 / MPU-6500 protocol over SPI or I2C: register map, start-up, data, offsets.

The register map is the same on both buses. One SPI frame is an address byte
then data bytes, MSB first; bit 7 of the address byte set means read. On I2C
(a `RegisterTransport`) the register address has no read flag: the bus's own
read bit does that; the part answers at 0x68 (AD0 low) or 0x69 (AD0 high).
Either way the register address auto-increments, so one transfer reads a
whole block (burst read) or writes several registers. The MPU-6050 has no
SPI; over SPI the I2C interface is disabled at start (I2C_IF_DIS), over I2C
it is not.

Register map and scales: MPU-6000/6050 and MPU-6500 register maps (SPI mode 0
or 3, at most 1 MHz for configuration registers; I2C at most 400 kHz). The offset registers and
their formats are those of the application note "Using Hardware Offset Registers for
Calibration": gyro
XG/YG/ZG_OFFS_USR at 0x13..0x18 on both variants, accelerometer
XA/YA/ZA_OFFS_USR at 0x06..0x0B (MPU-6000/6050) or 0x77/0x7A/0x7D (MPU-6500;
the note's 0x0E for ZA_OFFS_USRL is a typo for 0x7E, its own code reads two
bytes from 0x7D). Temperature conversions are UNCONFIRMED (datasheets, not
the seed): MPU-6000/6050 T = raw / 340 + 36.53, MPU-6500 T = raw / 333.87 + 21.
"""

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple, Union

import numpy as np

from .errors import FaultCounters, HardwareError, NackError, ProtocolError, SilentBusError
from .transport import RegisterTransport, Transport
from ..core.errors import CalibrationError
from ..core.procedures import from_twos_complement, merge_preserving_bit0, STANDARD_GRAVITY_M_S2

READ_FLAG = 0x80
# 7-bit I2C addresses: AD0 low, AD0 high.
I2C_ADDRESSES = (0x68, 0x69)

# Registers.
XG_OFFS_USRH = 0x13            # then YG at 0x15, ZG at 0x17 (high byte first)
SMPLRT_DIV = 0x19
CONFIG = 0x1A                  # DLPF_CFG in bits 2..0
GYRO_CONFIG = 0x1B             # FS_SEL in bits 4..3
ACCEL_CONFIG = 0x1C            # AFS_SEL in bits 4..3
ACCEL_XOUT_H = 0x3B            # accel x, y, z, temperature, gyro x, y, z: 14 bytes
TEMP_OUT_H = 0x41
GYRO_XOUT_H = 0x43
DATA_BYTES = 14
SIGNAL_PATH_RESET = 0x68
USER_CTRL = 0x6A
PWR_MGMT_1 = 0x6B
WHO_AM_I = 0x75

GYRO_OFFSET_REGISTERS = (XG_OFFS_USRH, XG_OFFS_USRH + 2, XG_OFFS_USRH + 4)

# Bits.
DEVICE_RESET = 0x80            # PWR_MGMT_1; self-clearing
SLEEP = 0x40                   # PWR_MGMT_1; set at power-on
CLKSEL_PLL_X = 0x01            # PWR_MGMT_1: PLL on the X gyro, the recommended clock
SIGNAL_PATH_RESET_ALL = 0x07   # gyro, accel and temperature signal paths
I2C_IF_DIS = 0x10              # USER_CTRL: SPI only

# Full-scale settings (FS_SEL / AFS_SEL 0..3) and their datasheet sensitivities.
GYRO_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
ACCEL_LSB_PER_G = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}
_FULL_SCALE_CODE = {250: 0, 500: 1, 1000: 2, 2000: 3, 2: 0, 4: 1, 8: 2, 16: 3}

INT16_LIMITS = (-32768, 32767)


@dataclass(frozen=True)
class Variant:
    """What differs between the parts this protocol drives."""

    name: str
    who_am_i: int
    accel_offset_registers: Tuple[int, int, int]    # high byte of XA, YA, ZA_OFFS_USR
    temperature_lsb_per_c: float
    temperature_offset_c: float
    spi: bool = True                                # the MPU-6050 speaks I2C only

    def temperature_c(self, raw: int) -> float:
        return raw / self.temperature_lsb_per_c + self.temperature_offset_c


MPU6000 = Variant('mpu6000', 0x68, (0x06, 0x08, 0x0A), 340.0, 36.53)
MPU6050 = Variant('mpu6050', 0x68, (0x06, 0x08, 0x0A), 340.0, 36.53, spi=False)
MPU6500 = Variant('mpu6500', 0x70, (0x77, 0x7A, 0x7D), 333.87, 21.0)
VARIANTS = {variant.name: variant for variant in (MPU6000, MPU6050, MPU6500)}


def variant_named(name: str) -> Variant:
    try:
        return VARIANTS[name]
    except KeyError:
        msg = f'unknown MPU variant {name!r}; known: {", ".join(sorted(VARIANTS))}'
        raise HardwareError(msg) from None


def signed16(high: int, low: int) -> int:
    return from_twos_complement((high << 8) | low)


def word_bytes(value: int) -> bytes:
    """Two's complement bytes, high first, of a signed 16-bit value."""
    if not INT16_LIMITS[0] <= value <= INT16_LIMITS[1]:
        msg = f'{value} does not fit a 16-bit register'
        raise HardwareError(msg)
    return (int(value) & 0xFFFF).to_bytes(2, 'big')


@dataclass(frozen=True)
class RawReading:
    """Signed output registers of one burst read."""

    accel: Tuple[int, int, int]
    temperature: int
    gyro: Tuple[int, int, int]


@dataclass(frozen=True)
class MpuReading:
    """
    One sample in SI units.

    ``saturated`` is set when a gyro or accelerometer output reached an
    int16 limit: that axis is not trustworthy.
    """

    gyro_rad_s: np.ndarray
    acceleration_m_s2: np.ndarray
    temperature_c: float
    saturated: bool


@dataclass(frozen=True)
class Offsets:
    """Signed contents of the offset registers, x, y, z."""

    gyro_lsb: Tuple[int, int, int]
    accel_lsb: Tuple[int, int, int]


def _three_ints(values: Sequence[int], what: str) -> Tuple[int, int, int]:
    if len(values) != 3 or any(int(v) != v for v in values):
        msg = f'{what} needs 3 integers, got {values!r}'
        raise HardwareError(msg)
    return tuple(int(v) for v in values)


class Mpu6000:
    """
    One MPU-6000, MPU-6050 or MPU-6500 behind a `Transport` (SPI) or `RegisterTransport` (I2C).

    `start` resets and configures the part and reads the factory accelerometer
    offsets; `read` gives gyro rad/s, acceleration m/s^2 and temperature.
    Faults become a typed `HardwareError` (and are counted) or, for a
    saturated output, a flag on the reading.
    """

    def __init__(self, transport: Union[Transport, RegisterTransport],
                 variant: Variant = MPU6000, *,
                 gyro_full_scale_dps: int = 250, accel_full_scale_g: int = 2,
                 dlpf_config: int = 3, sample_rate_divider: int = 0, settle_s: float = 0.1):
        if gyro_full_scale_dps not in GYRO_LSB_PER_DPS:
            msg = (f'gyro full scale must be one of {sorted(GYRO_LSB_PER_DPS)} deg/s, '
                   f'got {gyro_full_scale_dps}')
            raise HardwareError(msg)
        if accel_full_scale_g not in ACCEL_LSB_PER_G:
            msg = (f'accelerometer full scale must be one of {sorted(ACCEL_LSB_PER_G)} g, '
                   f'got {accel_full_scale_g}')
            raise HardwareError(msg)
        if not 0 <= dlpf_config <= 6:
            msg = f'dlpf_config must be 0..6, got {dlpf_config}'
            raise HardwareError(msg)
        if not 0 <= sample_rate_divider <= 255:
            msg = f'sample_rate_divider must be 0..255, got {sample_rate_divider}'
            raise HardwareError(msg)
        self.bus = 'i2c' if isinstance(transport, RegisterTransport) else 'spi'
        if self.bus == 'spi' and not variant.spi:
            msg = f'the {variant.name} has no SPI interface: read it over I2C'
            raise HardwareError(msg)
        self.transport = transport
        self.variant = variant
        self.gyro_full_scale_dps = gyro_full_scale_dps
        self.accel_full_scale_g = accel_full_scale_g
        self.dlpf_config = dlpf_config
        self.sample_rate_divider = sample_rate_divider
        self.settle_s = settle_s
        self.counters = FaultCounters()
        self.factory_accel_lsb: Optional[Tuple[int, int, int]] = None

    def read_registers(self, address: int, count: int) -> bytes:
        """Burst-read ``count`` registers from ``address`` (one SPI frame, I2C block reads)."""
        if self.bus == 'spi':
            rx = self.transport.transfer(bytes((address | READ_FLAG,)) + bytes(count))
            what, data, expected = 'SPI frame', rx[1:], count + 1
        else:
            try:
                rx = data = self.transport.read_registers(address, count)
            except NackError:
                self.counters.silent_bus += 1
                raise
            what, expected = 'I2C block read', count
        if len(rx) != expected:
            self.counters.protocol_errors += 1
            msg = f'{what} returned {len(rx)} bytes, expected {expected}'
            raise ProtocolError(msg)
        return data

    def write_registers(self, address: int, data: bytes) -> None:
        """Write ``data`` to consecutive registers from ``address`` (one frame, or block)."""
        if self.bus == 'spi':
            self.transport.transfer(bytes((address & 0x7F,)) + bytes(data))
            return
        try:
            self.transport.write_registers(address, bytes(data))
        except NackError:
            self.counters.silent_bus += 1
            raise

    def _write_checked(self, address: int, data: bytes) -> None:
        self.write_registers(address, data)
        back = self.read_registers(address, len(data))
        if back != bytes(data):
            self.counters.protocol_errors += 1
            msg = (f'register 0x{address:02X}: wrote {bytes(data).hex()}, '
                   f'read back {back.hex()}')
            raise ProtocolError(msg)

    def who_am_i(self) -> int:
        try:
            return self.read_registers(WHO_AM_I, 1)[0]
        except NackError as err:
            msg = (f'WHO_AM_I: {err}; an MPU answers at 0x{I2C_ADDRESSES[0]:02X} with AD0 low, '
                   f'0x{I2C_ADDRESSES[1]:02X} with AD0 high')
            raise NackError(msg) from None

    def start(self) -> None:
        """
        Identify, reset and configure the part; read the factory accel offsets.

        Sequence: WHO_AM_I; DEVICE_RESET, wait; SIGNAL_PATH_RESET, wait (the
        register map asks for both over SPI); I2C_IF_DIS (SPI only: over I2C it
        would cut the bus it speaks on); wake on the X gyro PLL, wait; DLPF,
        sample rate divider and full-scale ranges, each read back. The reset
        clears the user offset registers: write them after.
        """
        identity = self.who_am_i()
        if identity in (0x00, 0xFF):
            self.counters.silent_bus += 1
            msg = f'WHO_AM_I read 0x{identity:02X}: bus silent or part absent'
            raise SilentBusError(msg)
        if identity != self.variant.who_am_i:
            self.counters.protocol_errors += 1
            others = [v.name for v in VARIANTS.values() if v.who_am_i == identity]
            hint = f' (an {" or ".join(others)}?)' if others else ''
            msg = (f'WHO_AM_I read 0x{identity:02X}, expected 0x{self.variant.who_am_i:02X} '
                   f'for {self.variant.name}{hint}')
            raise ProtocolError(msg)
        self.write_registers(PWR_MGMT_1, bytes((DEVICE_RESET,)))
        self.transport.wait(self.settle_s)
        self.write_registers(SIGNAL_PATH_RESET, bytes((SIGNAL_PATH_RESET_ALL,)))
        self.transport.wait(self.settle_s)
        if self.bus == 'spi':
            self._write_checked(USER_CTRL, bytes((I2C_IF_DIS,)))
        self._write_checked(PWR_MGMT_1, bytes((CLKSEL_PLL_X,)))
        self.transport.wait(self.settle_s)
        # SMPLRT_DIV, CONFIG, GYRO_CONFIG, ACCEL_CONFIG are consecutive: one burst write.
        config = (self.sample_rate_divider, self.dlpf_config,
                  _FULL_SCALE_CODE[self.gyro_full_scale_dps] << 3,
                  _FULL_SCALE_CODE[self.accel_full_scale_g] << 3)
        self._write_checked(SMPLRT_DIV, bytes(config))
        self.factory_accel_lsb = self.read_offsets().accel_lsb

    def read_raw(self) -> RawReading:
        """Burst-read the 14 output bytes (accel, temperature, gyro) of one sample."""
        data = self.read_registers(ACCEL_XOUT_H, DATA_BYTES)
        if data in (bytes(DATA_BYTES), b'\xff' * DATA_BYTES):
            self.counters.silent_bus += 1
            msg = (f'all output registers read 0x{data[0]:02X}: bus silent, or the part is '
                   f'asleep after a reset')
            raise SilentBusError(msg)
        values = [signed16(data[i], data[i + 1]) for i in range(0, DATA_BYTES, 2)]
        return RawReading(accel=tuple(values[0:3]), temperature=values[3],
                          gyro=tuple(values[4:7]))

    def read(self) -> MpuReading:
        raw = self.read_raw()
        saturated = any(v in INT16_LIMITS for v in raw.accel + raw.gyro)
        if saturated:
            self.counters.saturated += 1
        gyro_dps = np.array(raw.gyro, dtype=np.float64) / GYRO_LSB_PER_DPS[
            self.gyro_full_scale_dps]
        accel_g = np.array(raw.accel, dtype=np.float64) / ACCEL_LSB_PER_G[
            self.accel_full_scale_g]
        return MpuReading(gyro_rad_s=np.radians(gyro_dps),
                          acceleration_m_s2=accel_g * STANDARD_GRAVITY_M_S2,
                          temperature_c=self.variant.temperature_c(raw.temperature),
                          saturated=saturated)

    def _read_words(self, addresses: Sequence[int]) -> Tuple[int, int, int]:
        return tuple(signed16(*self.read_registers(a, 2)) for a in addresses)

    def read_offsets(self) -> Offsets:
        """Read the gyro and accelerometer offset registers (signed)."""
        return Offsets(gyro_lsb=self._read_words(GYRO_OFFSET_REGISTERS),
                       accel_lsb=self._read_words(self.variant.accel_offset_registers))

    def write_gyro_offsets(self, lsb: Sequence[int]) -> None:
        """Write XG/YG/ZG_OFFS_USR (signed, +-1000 dps format) and read them back."""
        for address, value in zip(GYRO_OFFSET_REGISTERS, _three_ints(lsb, 'gyro offsets')):
            self._write_checked(address, word_bytes(value))

    def write_accel_offsets(self, bias_lsb: Sequence[int],
                            factory_lsb: Optional[Sequence[int]] = None
                            ) -> Tuple[int, int, int]:
        """
        Subtract ``bias_lsb`` (+-16 g format) from the factory values, keeping bit 0.

        The factory values are ``factory_lsb`` if given, else those `start`
        read after the reset, else the registers now (the note's
        read-modify-write). Merging onto the factory values, not the current
        contents, makes a second call replace the first instead of adding to
        it. Returns the values written.
        """
        bias = _three_ints(bias_lsb, 'accelerometer offsets')
        if factory_lsb is not None:
            factory = _three_ints(factory_lsb, 'factory accelerometer offsets')
        else:
            if self.factory_accel_lsb is None:
                self.factory_accel_lsb = self.read_offsets().accel_lsb
            factory = self.factory_accel_lsb
        try:
            merged = tuple(merge_preserving_bit0(f, b) for f, b in zip(factory, bias))
        except CalibrationError as err:
            msg = f'accelerometer offsets: {err}'
            raise HardwareError(msg) from None
        for address, value in zip(self.variant.accel_offset_registers, merged):
            self._write_checked(address, word_bytes(value))
        return merged
