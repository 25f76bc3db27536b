"""
ADIS16130 SPI protocol: start-up sequence, RATEDATA/TEMPDATA reads, offset-binary codes.

Facts from Analog Devices AN-1042, "ADIS16130 quick start guide and bias
optimisation tips" (Japanese edition; Table 3 start-up sequence, read
commands 0x48/0x4A then 3 bytes, Tables 4 and 5 code formats) and
the fact sheet "MLX90609 and ADIS16130" section 2 (Linux IIO driver: register
map, one full-duplex transfer per read). A command byte is b6 = read, b5:0 =
register; the write of a register is that byte followed by the value byte.
Reading back the 8-bit set-up registers is UNCONFIRMED (AD773x-like layout),
so `verify_registers` can be switched off.
"""

from dataclasses import dataclass
import math

import numpy as np

from .errors import FaultCounters, HardwareError, ProtocolError, SilentBusError
from .transport import Transport

# Registers (sensor-facts.md section 2, from the kernel driver).
COM = 0x00
IOP = 0x01
RATEDATA = 0x08
TEMPDATA = 0x0A
RATECS = 0x28
TEMPCS = 0x2A
RATECONV = 0x30
TEMPCONV = 0x32
MODE = 0x38
READ = 0x40             # b6 of the command byte: 1 = read
ADDRESS_MASK = 0x3F
MODE_24_BIT = 0x02      # MODE b1: 1 = 24-bit conversions, 0 = 16-bit
CHANNEL_ENABLE = 0x08   # RATECS / TEMPCS b3

# AN-1042 Table 3: (byte on SDI, register it goes to). Each register write is
# a COM byte naming the register, then the value; MODE 0x22 starts continuous
# 24-bit conversions of RATEDATA and TEMPDATA.
START_UP_SEQUENCE = (
    (0x01, 'COM'), (0x38, 'IOP'),
    (0x28, 'COM'), (0x0A, 'RATECS'),
    (0x30, 'COM'), (0x05, 'RATECONV'),
    (0x2A, 'COM'), (0x0A, 'TEMPCS'),
    (0x32, 'COM'), (0x05, 'TEMPCONV'),
    (0x38, 'COM'), (0x22, 'MODE'),
)

RESOLUTIONS_BITS = (24, 16)
# Offset binary: mid-scale is zero rate and 25 C (Tables 4 and 5).
RATE_LSB_PER_DPS_24 = 23488          # (14,260,608 - 8,388,608) / 250 deg/s
TEMPERATURE_LSB_PER_C_24 = 14093     # (9,516,048 - 8,388,608) / 80 C
TEMPERATURE_AT_MID_SCALE_C = 25.0
RATE_RANGE_DPS = 250.0               # the outermost rows of Table 4


def check_resolution(bits: int) -> int:
    if bits not in RESOLUTIONS_BITS:
        msg = f'ADIS16130 resolution must be 24 or 16 bits, got {bits!r}'
        raise HardwareError(msg)
    return bits


def start_up_bytes(bits: int = 24) -> bytes:
    """
    Return the Table 3 bytes for ``bits``-bit conversions.

    For 24 bits this is Table 3 unchanged; for 16 bits only the MODE value
    differs (b1 cleared: 0x20).
    """
    sequence = bytes(byte for byte, _ in START_UP_SEQUENCE)
    if check_resolution(bits) == 24:
        return sequence
    return sequence[:-1] + bytes((sequence[-1] & ~MODE_24_BIT,))


def start_up_registers(bits: int = 24) -> dict:
    """Return the value each register holds after `start_up_bytes` (register -> byte)."""
    sequence = start_up_bytes(bits)
    pairs = zip(sequence[::2], sequence[1::2])
    return {command & ADDRESS_MASK: value for command, value in pairs}


def mid_scale(bits: int) -> int:
    return 1 << (check_resolution(bits) - 1)


def full_code(bits: int) -> int:
    return (1 << check_resolution(bits)) - 1


def rate_lsb_per_dps(bits: int) -> float:
    """23,488 LSB/(deg/s) at 24 bits; a 16-bit code is the top 16 bits: 91.75."""
    return RATE_LSB_PER_DPS_24 / (1 << (24 - check_resolution(bits)))


def temperature_lsb_per_c(bits: int) -> float:
    """14,093 LSB/C at 24 bits; 55.05 at 16 bits."""
    return TEMPERATURE_LSB_PER_C_24 / (1 << (24 - check_resolution(bits)))


def _code_error(code, bits: int) -> HardwareError:
    return HardwareError(f'{bits}-bit ADIS16130 codes are integers 0..{full_code(bits)}, '
                         f'got {code!r}')


def _decode(code, bits: int):
    """Return code - mid-scale as float (array for arrays); plain Python for one code."""
    if isinstance(code, (int, np.integer)):
        if not 0 <= code <= full_code(bits):
            raise _code_error(code, bits)
        return float(code - mid_scale(bits))
    codes = np.asarray(code)
    if not np.issubdtype(codes.dtype, np.integer) or np.any(codes < 0) or \
            np.any(codes > full_code(bits)):
        raise _code_error(code, bits)
    return codes.astype(np.float64) - mid_scale(bits)


def _encode(offset_lsb, bits: int):
    # Nearest code, ties away from mid-scale (Table 4 at 16 bits: +-10 and +-250 deg/s
    # fall on ties, +-917.5 and +-22,937.5 LSB); the ADC clips at its code limits.
    # One value (every simulated sample) in plain floats: numpy costs microseconds here.
    scalar = np.ndim(offset_lsb) == 0
    if not (math.isfinite(offset_lsb) if scalar else np.all(np.isfinite(offset_lsb))):
        msg = f'cannot encode a non-finite value as an ADIS16130 code: {offset_lsb!r}'
        raise HardwareError(msg)
    if scalar:
        rounded = math.copysign(math.floor(abs(offset_lsb) + 0.5), offset_lsb)
        return int(min(max(rounded + mid_scale(bits), 0), full_code(bits)))
    offset = np.asarray(offset_lsb, dtype=np.float64)
    rounded = np.sign(offset) * np.floor(np.abs(offset) + 0.5)
    return np.clip(rounded + mid_scale(bits), 0, full_code(bits)).astype(np.int64)


def rate_dps_from_code(code, bits: int = 24):
    """Convert RATEDATA codes (offset binary) to deg/s."""
    return _decode(code, bits) / rate_lsb_per_dps(bits)


def rate_code_from_dps(rate_dps, bits: int = 24):
    """Convert deg/s to the nearest RATEDATA code (inverse of `rate_dps_from_code`)."""
    return _encode(np.multiply(rate_dps, rate_lsb_per_dps(bits)), bits)


def temperature_c_from_code(code, bits: int = 24):
    """Convert TEMPDATA codes (offset binary, 25 C at mid-scale) to C."""
    return TEMPERATURE_AT_MID_SCALE_C + _decode(code, bits) / temperature_lsb_per_c(bits)


def temperature_code_from_c(temperature_c, bits: int = 24):
    """Convert C to the nearest TEMPDATA code (inverse of `temperature_c_from_code`)."""
    offset_c = np.subtract(temperature_c, TEMPERATURE_AT_MID_SCALE_C)
    return _encode(offset_c * temperature_lsb_per_c(bits), bits)


@dataclass(frozen=True)
class Adis16130Reading:
    """
    Rate and temperature (averaged when oversampled).

    ``saturated`` is set when a rate was beyond the rated range: it is then
    not trustworthy.
    """

    rate_dps: float
    temperature_c: float
    saturated: bool


class Adis16130:
    """
    One ADIS16130 behind a `Transport` (SPI mode 3, MSB first, 8-bit words).

    `start` writes the Table 3 sequence, one byte per chip-select frame as
    AN-1042 asks; each read is one full-duplex frame, the command byte then
    3 (24-bit) or 2 (16-bit) data bytes, as the Linux driver does. Every fault
    becomes a typed `HardwareError` and is counted.
    """

    def __init__(self, transport: Transport, *, resolution_bits: int = 24,
                 verify_registers: bool = True, rate_range_dps: float = RATE_RANGE_DPS):
        self.transport = transport
        self.resolution_bits = check_resolution(resolution_bits)
        self.verify_registers = verify_registers
        self.rate_range_dps = rate_range_dps
        self.counters = FaultCounters()

    def _transfer(self, tx: bytes) -> bytes:
        rx = self.transport.transfer(tx)
        if len(rx) != len(tx):
            self.counters.protocol_errors += 1
            msg = f'SPI frame returned {len(rx)} bytes, expected {len(tx)}'
            raise ProtocolError(msg)
        return rx

    def start(self) -> None:
        """Send the start-up sequence, then (optionally) read the registers back."""
        for byte in start_up_bytes(self.resolution_bits):
            self._transfer(bytes((byte,)))
        if self.verify_registers:
            self.verify_configuration()

    def read_register(self, register: int) -> int:
        """Read one 8-bit set-up register (read-back is UNCONFIRMED on real parts)."""
        return self._transfer(bytes((READ | register, 0)))[1]

    def verify_configuration(self) -> None:
        """Raise unless every register written by `start` reads back as written."""
        expected = start_up_registers(self.resolution_bits)
        found = {register: self.read_register(register) for register in expected}
        if set(found.values()) <= {0x00} or set(found.values()) <= {0xFF}:
            self.counters.silent_bus += 1
            msg = (f'ADIS16130 set-up registers all read 0x{found[MODE]:02X}: bus silent, '
                   'part absent, or part reset to its power-on values')
            raise SilentBusError(msg)
        wrong = [f'0x{r:02X} = 0x{found[r]:02X} (wrote 0x{v:02X})'
                 for r, v in expected.items() if found[r] != v]
        if wrong:
            self.counters.protocol_errors += 1
            msg = (f'ADIS16130 registers do not read back as written: {", ".join(wrong)} '
                   '(parts that cannot read back need verify_registers off)')
            raise ProtocolError(msg)

    def read_code(self, register: int) -> int:
        """Read a data register (0x40 | register, then 3 or 2 bytes); return its code."""
        count = self.resolution_bits // 8
        rx = self._transfer(bytes((READ | register,)) + bytes(count))
        code = int.from_bytes(rx[1:], 'big')
        # The code limits lie far outside the rated range (+-357 deg/s, -570..+620 C):
        # an all-ones or all-zeros word is a silent bus, a part not started, or an ADC
        # pinned at its limit; none of them is a number to pass on.
        if code in (0, full_code(self.resolution_bits)):
            self.counters.silent_bus += 1
            level = 'high' if code else 'low'
            msg = (f'read 0x{READ | register:02X} gave 0x{code:0{2 * count}X}: MISO stuck '
                   f'{level} (bus silent, part not started, or ADC at its limit)')
            raise SilentBusError(msg)
        return code

    def read_rate_dps(self) -> float:
        """Read RATEDATA (command 0x48) and convert it to deg/s."""
        return float(rate_dps_from_code(self.read_code(RATEDATA), self.resolution_bits))

    def read_temperature_c(self) -> float:
        """Read TEMPDATA (command 0x4A) and convert it to C."""
        return float(temperature_c_from_code(self.read_code(TEMPDATA), self.resolution_bits))

    def read(self, oversample: int = 1) -> Adis16130Reading:
        """Read rate and temperature ``oversample`` times and average them."""
        if oversample < 1:
            msg = f'oversample must be at least 1, got {oversample}'
            raise HardwareError(msg)
        rate_sum = temperature_sum = 0.0
        saturated = False
        for _ in range(oversample):
            rate = self.read_rate_dps()
            temperature_sum += self.read_temperature_c()
            saturated = saturated or abs(rate) > self.rate_range_dps
            rate_sum += rate
        if saturated:
            self.counters.saturated += 1
        return Adis16130Reading(rate_dps=rate_sum / oversample,
                                temperature_c=temperature_sum / oversample, saturated=saturated)
