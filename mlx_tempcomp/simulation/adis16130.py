"""
A simulated ADIS16130 that answers at the SPI byte level.

It speaks the protocol of `mlx_tempcomp.hardware.adis16130`: a command byte
(b6 = read, b5:0 = register), then the value of a write or the bytes of a
read; set-up registers keep what was written, and once MODE starts
continuous conversions RATEDATA and TEMPDATA are refreshed at the update
rate with offset-binary codes in the MODE resolution. The rate and
temperature come from `GyroPhysics` with a known bias temperature
coefficient. Chip select does not reset the byte state, so the note's one
byte per frame and the Linux driver's 4-byte frame both work.
"""

from dataclasses import dataclass
import enum
import math
from typing import Optional

from .clock import SimClock
from .physics import Effects, GyroPhysics, GyroTruth, Noise, Scenario, ThermalProfile
from ..hardware import adis16130 as protocol

# Typical figures, UNCONFIRMED by a datasheet. The bandwidth follows AN-1042's
# tip that 50 Hz halves the noise (so about 200 Hz without the capacitor).
ADIS16130_NOISE = Noise(density_dps_rt_hz=0.0125, bandwidth_hz=200.0,
                        bias_instability_dps=0.0016, bias_correlation_s=100.0,
                        temperature_noise_mv=0.0)
UPDATE_RATE_HZ = 5700.0                  # AN-1042: RATE and TEMP refresh at 5.7 kHz
SUPPLY_DPS_PER_V = 0.2                   # AN-1042: 0.0002 deg/s per mV of supply
MODE_CONTINUOUS = 0x20                   # MODE b7:5 = 001, as in Table 3 (AD773x-like)
MODE_OPERATION_MASK = 0xE0
# Power-on contents of every register: UNCONFIRMED (taken as zero, so nothing converts).
POWER_ON_VALUE = 0x00


class Fault(str, enum.Enum):
    """Faults the simulated device can be switched into."""

    NONE = 'none'
    SILENT_HIGH = 'silent_high'  # MISO floats high: all ones
    SILENT_LOW = 'silent_low'    # MISO stuck low: all zeros


@dataclass(frozen=True)
class Adis16130Truth:
    """
    What one simulated device really does.

    bias(T) = bias_dps + bias_dps_per_c x (T - 25 C) of the die temperature;
    the rate is scaled by 1 + sensitivity_error + sensitivity_error_per_c x
    (T - 25 C). The temperature output reads the (lagged) sensor temperature
    plus ``temperature_error_c`` and white noise.
    """

    bias_dps: float = 0.0
    bias_dps_per_c: float = 0.0
    sensitivity_error: float = 0.0
    sensitivity_error_per_c: float = 0.0
    temperature_error_c: float = 0.0
    temperature_noise_c: float = 0.005   # UNCONFIRMED
    effects: Effects = Effects(zro_supply_dps_per_v=SUPPLY_DPS_PER_V)
    noise: Noise = ADIS16130_NOISE

    def gyro_truth(self) -> GyroTruth:
        """Return the bias part as a `GyroTruth` for `GyroPhysics` (its mV terms are unused)."""
        return GyroTruth(full_scale_dps=protocol.RATE_RANGE_DPS,
                         zro_dps_coefficients=(self.bias_dps, self.bias_dps_per_c),
                         effects=self.effects, noise=self.noise)


class Adis16130Physics:
    """Rate in deg/s and temperature in C over simulated time; seedable."""

    def __init__(self, truth: Adis16130Truth, scenario: Scenario, seed: Optional[int] = None):
        self.truth = truth
        self.gyro = GyroPhysics(truth.gyro_truth(), scenario, seed)

    def rate_dps(self, t: float) -> float:
        gyro = self.gyro
        gyro.advance(t)
        truth = self.truth
        sensitivity = 1.0 + truth.sensitivity_error + truth.sensitivity_error_per_c * (
            gyro.state.die_c - 25.0)
        noise = truth.noise.white_sigma_dps * gyro.rng.standard_normal()
        return sensitivity * gyro.scenario.true_rate_dps(t) + noise + gyro.zro_offset_dps()

    def temperature_c(self, t: float) -> float:
        self.gyro.advance(t)
        return (self.gyro.state.sensor_c + self.truth.temperature_error_c
                + self.truth.temperature_noise_c * self.gyro.rng.standard_normal())


def self_heating_profile(start_c: float = 25.0, rise_c: float = 5.0,
                         time_constant_s: float = 120.0) -> ThermalProfile:
    """Die at ``start_c`` at power-up, settling ``rise_c`` higher (first order)."""
    return ThermalProfile(times_s=(0.0, 1e-6), temperatures_c=(start_c, start_c + rise_c),
                          time_constant_s=time_constant_s)


class SimulatedAdis16130:
    """Byte-level model of the part's SPI interface."""

    def __init__(self, physics: Adis16130Physics, clock: SimClock, sclk_hz: float = 1e6,
                 update_rate_hz: float = UPDATE_RATE_HZ):
        self.physics = physics
        self.clock = clock
        self.bit_time_s = 1.0 / sclk_hz
        self.update_rate_hz = update_rate_hz
        self.fault = Fault.NONE
        self.power_cycle()

    def power_cycle(self) -> None:
        """Lose every setting, as after a supply drop: registers back to power-on values."""
        self.registers = {register: POWER_ON_VALUE
                          for register in protocol.start_up_registers()}
        self.data = {protocol.RATEDATA: 0, protocol.TEMPDATA: 0}
        self._conversion = {protocol.RATEDATA: -1, protocol.TEMPDATA: -1}
        self._write_register = None
        self._out = []

    @property
    def resolution_bits(self) -> int:
        return 24 if self.registers[protocol.MODE] & protocol.MODE_24_BIT else 16

    def _converting(self, register: int) -> bool:
        select = protocol.RATECS if register == protocol.RATEDATA else protocol.TEMPCS
        return (self.registers[protocol.MODE] & MODE_OPERATION_MASK == MODE_CONTINUOUS
                and bool(self.registers[select] & protocol.CHANNEL_ENABLE))

    def _refresh(self, register: int) -> None:
        """Bring a data register to the latest conversion (sampled at its own instant)."""
        if not self._converting(register):
            return
        index = math.floor(self.clock.now_s * self.update_rate_hz)
        if index == self._conversion[register]:
            return
        self._conversion[register] = index
        t = index / self.update_rate_hz
        bits = self.resolution_bits
        if register == protocol.RATEDATA:
            self.data[register] = protocol.rate_code_from_dps(self.physics.rate_dps(t), bits)
        else:
            self.data[register] = protocol.temperature_code_from_c(
                self.physics.temperature_c(t), bits)

    def _read_bytes(self, register: int) -> list:
        if register in self.data:
            self._refresh(register)
            count = self.resolution_bits // 8
            return list(int(self.data[register]).to_bytes(count, 'big'))
        return [self.registers.get(register, POWER_ON_VALUE)]

    def exchange(self, mosi: int) -> int:
        """Clock one byte in on MOSI; return the byte clocked out on MISO."""
        self.clock.advance(8 * self.bit_time_s)
        miso = self._step(mosi)
        if self.fault is Fault.SILENT_HIGH:
            return 0xFF
        if self.fault is Fault.SILENT_LOW:
            return 0x00
        return miso

    def _step(self, mosi: int) -> int:
        if self._out:
            return self._out.pop(0)
        if self._write_register is not None:
            if self._write_register in self.registers:
                self.registers[self._write_register] = mosi
            self._write_register = None
            return 0x00
        register = mosi & protocol.ADDRESS_MASK
        if mosi & protocol.READ:
            self._out = self._read_bytes(register)
        elif register != protocol.COM:
            # A write to COM itself (0x00, also the dummy byte of a read) leaves the
            # next byte a command.
            self._write_register = register
        return 0x00

    def transport(self) -> 'SimulatedTransport':
        return SimulatedTransport(self)


class SimulatedTransport:
    """`Transport` onto a `SimulatedAdis16130`: bytes in, bytes out, waits on its clock."""

    def __init__(self, device: SimulatedAdis16130):
        self.device = device

    def transfer(self, tx: bytes) -> bytes:
        return bytes(self.device.exchange(byte) for byte in tx)

    def wait(self, seconds: float) -> None:
        self.device.clock.advance(seconds)

    def close(self) -> None:
        """Nothing to release."""


def simulated_device(truth: Adis16130Truth, scenario: Scenario, seed: int,
                     clock: Optional[SimClock] = None, sclk_hz: float = 1e6,
                     update_rate_hz: float = UPDATE_RATE_HZ) -> SimulatedAdis16130:
    """Build a device; the same seed gives the same run."""
    physics = Adis16130Physics(truth, scenario, seed=seed)
    return SimulatedAdis16130(physics, clock or SimClock(), sclk_hz, update_rate_hz)
