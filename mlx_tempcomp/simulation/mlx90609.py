"""
A simulated MLX90609 that answers at the SPI frame level.

It speaks the protocol of `mlx_tempcomp.hardware.mlx90609` (STATR, ADCC,
ADCR with EOC, EER, refusal answers) and is backed by `GyroPhysics`. Its
EEPROM holds a factory table measured from the device's own truth with
realistic errors and encoded by `encode_eeprom`. Faults can be switched on
at any time to exercise the driver.
"""

from dataclasses import dataclass
import enum
from typing import Optional

import numpy as np

from .clock import SimClock
from .physics import GyroPhysics, GyroTruth
from ..core.mlx90609 import (ADC_MAX_CODE, ee_from_sf, ee_from_zro, EEPROM_SIZE, EepromFields,
                             encode_eeprom, Output, TRIPLET_TEMPERATURES_C)
from ..hardware import mlx90609 as protocol


class Fault(str, enum.Enum):
    """Faults the simulated device can be switched into."""

    NONE = 'none'
    REFUSE = 'refuse'            # every instruction refused (BUSY)
    NO_EOC = 'no_eoc'            # conversions never end
    SILENT_HIGH = 'silent_high'  # MISO floats high: all ones
    SILENT_LOW = 'silent_low'    # MISO stuck low: all zeros


@dataclass(frozen=True)
class FactoryMeasurement:
    """How well the factory measured each triplet (1 sigma) and how it stored them."""

    version: int = 2
    zro_sigma_dps: float = 0.05
    sf_sigma_relative: float = 0.002
    tc_sigma_mv: float = 1.0


def factory_eeprom(truth: GyroTruth, rng: np.random.Generator,
                   measurement: FactoryMeasurement = FactoryMeasurement()) -> bytes:
    """
    Build the EEPROM image the factory would write for ``truth``.

    Unused bits and the user area hold random bytes, as on a real part.
    """
    fill = rng.integers(0, 256, EEPROM_SIZE, dtype=np.uint8).tobytes()
    range_code = int(round(truth.full_scale_dps / 5.0))
    if measurement.version == 0:
        fields = EepromFields(range_code=range_code, version=0, tc_mv=(0, 0, 0),
                              ee_zro=(0, 0, 0), ee_sf=(0, 0, 0))
        return encode_eeprom(fields, fill=fill)
    tc, ee_zro, ee_sf = [], [], []
    for temperature_c in TRIPLET_TEMPERATURES_C:
        tc.append(int(round(truth.sensor_mv(temperature_c)
                            + rng.normal(0.0, measurement.tc_sigma_mv))))
        zro_mv = truth.zro_mv(temperature_c) + truth.typical_sf_mv * rng.normal(
            0.0, measurement.zro_sigma_dps)
        sf_mv = truth.sf_mv(temperature_c) * (1.0 + rng.normal(
            0.0, measurement.sf_sigma_relative))
        ee_zro.append(ee_from_zro(measurement.version, zro_mv, Output.ANALOG))
        ee_sf.append(ee_from_sf(sf_mv, truth.typical_sf_mv))
    fields = EepromFields(range_code=range_code, version=measurement.version,
                          tc_mv=tuple(tc), ee_zro=tuple(ee_zro), ee_sf=tuple(ee_sf))
    return encode_eeprom(fields, fill=fill)


class SimulatedMlx90609:
    """Frame-level model of the chip's SPI interface."""

    def __init__(self, physics: GyroPhysics, eeprom: bytes, clock: SimClock,
                 sclk_hz: float = 1e6, conversion_time_s: float = 115e-6):
        if len(eeprom) != EEPROM_SIZE:
            msg = f'EEPROM image must be {EEPROM_SIZE} bytes, got {len(eeprom)}'
            raise ValueError(msg)
        self.physics = physics
        self.eeprom = bytearray(eeprom)
        self.clock = clock
        self.bit_time_s = 1.0 / sclk_hz
        self.conversion_time_s = conversion_time_s
        self.fault = Fault.NONE
        self._channel = protocol.Channel.RATE
        self._adc_enabled = False
        self._conversion_end_s = float('inf')
        self._code = 0

    def flip_eeprom_bit(self, address: int, bit: int) -> None:
        """Simulate a worn cell or a bad read of one EEPROM bit."""
        self.eeprom[address] ^= 1 << bit

    def _status(self) -> int:
        eoc = self._adc_enabled and self.fault is not Fault.NO_EOC and \
            self.clock.now_s >= self._conversion_end_s
        return ((protocol.ANSWER_EOC if eoc else 0)
                | (protocol.ANSWER_CHAN if self._channel is protocol.Channel.TEMPERATURE else 0)
                | (protocol.ANSWER_ADEN if self._adc_enabled else 0))

    def _sample(self) -> int:
        """Convert the selected channel now (the ADC samples at conversion start)."""
        transfer = self.physics.truth.transfer
        now = self.clock.now_s
        if self._channel is protocol.Channel.RATE:
            code = transfer.rate_mv_to_lsb(self.physics.rate_output_mv(now))
        else:
            code = transfer.temperature_mv_to_lsb(self.physics.temperature_output_mv(now))
        return int(min(max(round(float(code)), 0), ADC_MAX_CODE))

    def frame(self, instruction: int) -> int:
        """Execute one 24-clock frame; the instruction runs after its 8th bit."""
        self.clock.advance(8 * self.bit_time_s)
        answer = self._execute(instruction)
        self.clock.advance(16 * self.bit_time_s)
        if self.fault is Fault.SILENT_HIGH:
            return 0xFFFF
        if self.fault is Fault.SILENT_LOW:
            return 0x0000
        return answer

    def _execute(self, instruction: int) -> int:
        if self.fault is Fault.REFUSE:
            return protocol.ANSWER_REFUSED | protocol.ANSWER_BUSY
        if instruction < EEPROM_SIZE:
            return self.eeprom[instruction]
        if instruction == protocol.STATR:
            return self._status()
        if instruction & 0xF3 == protocol.ADCC:
            self._channel = protocol.Channel(bool(instruction & protocol.ADCC_CHAN))
            self._adc_enabled = bool(instruction & protocol.ADCC_ADEN)
            if self._adc_enabled:
                self._code = self._sample()
                self._conversion_end_s = self.clock.now_s + self.conversion_time_s
            return self._status()
        if instruction == protocol.ADCR:
            status = self._status()
            if status & protocol.ANSWER_EOC:
                # ADCR answer (DS13 Table 10): b13 = EOC, b11..b1 = AD10..AD0, b0 = 0;
                # CHAN and ADEN are not echoed, their bit positions hold AD2 and AD1.
                return protocol.ANSWER_EOC | (self._code << 1)
            return status
        return protocol.ANSWER_REFUSED | protocol.ANSWER_OPC

    def transport(self) -> 'SimulatedTransport':
        return SimulatedTransport(self)


class SimulatedTransport:
    """`Transport` onto a `SimulatedMlx90609`: frames in, answers out, waits on its clock."""

    def __init__(self, device: SimulatedMlx90609):
        self.device = device

    def transfer(self, tx: bytes) -> bytes:
        if len(tx) != 3:
            msg = f'an MLX90609 frame is 3 bytes, got {len(tx)}'
            raise ValueError(msg)
        answer = self.device.frame(tx[0])
        return bytes((0, answer >> 8, answer & 0xFF))

    def wait(self, seconds: float) -> None:
        self.device.clock.advance(seconds)

    def close(self) -> None:
        """Nothing to release."""


def simulated_device(truth: GyroTruth, physics_scenario, seed: int,
                     clock: Optional[SimClock] = None,
                     measurement: FactoryMeasurement = FactoryMeasurement()
                     ) -> SimulatedMlx90609:
    """Build a device with its factory EEPROM; the same seed gives the same run."""
    rng = np.random.default_rng(seed)
    eeprom = factory_eeprom(truth, rng, measurement)
    physics = GyroPhysics(truth, physics_scenario, seed=int(rng.integers(2**31)))
    return SimulatedMlx90609(physics, eeprom, clock or SimClock())
