"""
MLX90609 SPI protocol: instruction set, answer words, conversions, EEPROM reads.

One frame is an 8-bit instruction followed by a 16-bit answer, MSB first
(24 clocks). Facts from the fact sheet "MLX90609 and ADIS16130" (datasheet
pages 9 and 13); EER is UNCONFIRMED there and follows Colin O'Flynn's library.
"""

from dataclasses import dataclass
import enum

from .errors import (EocTimeoutError, FaultCounters, HardwareError, ProtocolError, RefusalError,
                     SilentBusError)
from .transport import Transport

EEPROM_SIZE = 128

# Instructions.
STATR = 0x88
ADCR = 0x80
ADCC = 0x90
ADCC_CHAN = 0x08     # 1 = temperature channel
ADCC_ADEN = 0x04     # 1 = ADC enabled
# EER is 0AAAAAAA: the address itself.

# Answer bits.
ANSWER_REFUSED = 1 << 15
ANSWER_OPC = 1 << 14
ANSWER_EOC = 1 << 13
ANSWER_BUSY = 1 << 10
ANSWER_CHAN = 1 << 3
ANSWER_ADEN = 1 << 2
# Extra refusal bits, UNCONFIRMED (O'Flynn's library).
ANSWER_EEDIS = 1 << 9
ANSWER_ECRC = 1 << 6
ANSWER_EPLL = 1 << 5
ANSWER_EDRV = 1 << 4

_REFUSAL_BITS = (('OPC', ANSWER_OPC), ('EOC', ANSWER_EOC), ('BUSY', ANSWER_BUSY),
                 ('EEDIS', ANSWER_EEDIS), ('ECRC', ANSWER_ECRC), ('EPLL', ANSWER_EPLL),
                 ('EDRV', ANSWER_EDRV))


class Channel(enum.IntEnum):
    RATE = 0
    TEMPERATURE = 1


def adcc_instruction(channel: Channel, enable: bool = True) -> int:
    return (ADCC | (ADCC_CHAN if channel is Channel.TEMPERATURE else 0)
            | (ADCC_ADEN if enable else 0))


def adc_code(answer: int) -> int:
    """Extract the 11-bit code AD10..AD0 of an ADCR answer (bits 11..1)."""
    return (answer >> 1) & 0x7FF


def describe_refusal(answer: int) -> str:
    flags = [name for name, bit in _REFUSAL_BITS if answer & bit]
    return f'0x{answer:04X} ({", ".join(flags) if flags else "no flag set"})'


@dataclass
class ErrorCounters(FaultCounters):
    """The common fault counters plus the MLX90609's refusals and EOC time-outs."""

    refusals: int = 0
    eoc_timeouts: int = 0


@dataclass(frozen=True)
class Mlx90609Reading:
    """
    Rate and temperature ADC codes (averaged when oversampled).

    ``saturated`` is set when a code reached a limit: the rate or
    temperature is then not trustworthy.
    """

    rate_code: float
    temperature_code: float
    saturated: bool


class Mlx90609:
    """
    One MLX90609 behind a `Transport`.

    Every fault becomes a typed `HardwareError` (and is counted) or, for a
    saturated code, a flag on the `Mlx90609Reading`; no method returns a silently
    wrong number.
    """

    def __init__(self, transport: Transport, *, conversion_wait_s: float = 120e-6,
                 eoc_poll_interval_s: float = 20e-6, eoc_max_polls: int = 20,
                 saturation_low_code: int = 0, saturation_high_code: int = 2047):
        self.transport = transport
        self.conversion_wait_s = conversion_wait_s
        self.eoc_poll_interval_s = eoc_poll_interval_s
        self.eoc_max_polls = eoc_max_polls
        self.saturation_low_code = saturation_low_code
        self.saturation_high_code = saturation_high_code
        self.counters = ErrorCounters()

    def _frame(self, instruction: int) -> int:
        rx = self.transport.transfer(bytes((instruction, 0, 0)))
        if len(rx) != 3:
            self.counters.protocol_errors += 1
            msg = f'SPI frame returned {len(rx)} bytes, expected 3'
            raise ProtocolError(msg)
        return (rx[1] << 8) | rx[2]

    def command(self, instruction: int) -> int:
        """Send one instruction; return its answer, or raise on a silent bus or refusal."""
        answer = self._frame(instruction)
        if answer == 0xFFFF:
            self.counters.silent_bus += 1
            msg = f'instruction 0x{instruction:02X} answered 0xFFFF: MISO stuck high, bus silent'
            raise SilentBusError(msg)
        if answer & ANSWER_REFUSED:
            self.counters.refusals += 1
            msg = f'instruction 0x{instruction:02X} refused: {describe_refusal(answer)}'
            raise RefusalError(msg, answer)
        return answer

    def status(self) -> int:
        return self.command(STATR)

    def start_conversion(self, channel: Channel) -> None:
        instruction = adcc_instruction(channel)
        answer = self.command(instruction)
        if answer == 0x0000:
            self.counters.silent_bus += 1
            msg = f'ADCC 0x{instruction:02X} answered 0x0000: MISO stuck low, bus silent'
            raise SilentBusError(msg)
        echo = answer & (ANSWER_CHAN | ANSWER_ADEN)
        if echo != instruction & (ADCC_CHAN | ADCC_ADEN):
            self.counters.protocol_errors += 1
            msg = f'ADCC 0x{instruction:02X} answered 0x{answer:04X}: wrong CHAN/ADEN echo'
            raise ProtocolError(msg)

    def convert(self, channel: Channel) -> int:
        """Start a conversion, wait, poll ADCR until EOC; return the 11-bit code."""
        self.start_conversion(channel)
        self.transport.wait(self.conversion_wait_s)
        for _ in range(self.eoc_max_polls):
            answer = self.command(ADCR)
            if answer & ANSWER_EOC:
                return adc_code(answer)
            self.transport.wait(self.eoc_poll_interval_s)
        self.counters.eoc_timeouts += 1
        msg = (f'{Channel(channel).name.lower()} conversion: no EOC after '
               f'{self.eoc_max_polls} ADCR polls')
        raise EocTimeoutError(msg)

    def _saturated(self, code: int) -> bool:
        return code <= self.saturation_low_code or code >= self.saturation_high_code

    def read(self, oversample: int = 1) -> Mlx90609Reading:
        """Read rate and temperature ``oversample`` times and average the codes."""
        if oversample < 1:
            msg = f'oversample must be at least 1, got {oversample}'
            raise HardwareError(msg)
        rate_sum = temperature_sum = 0
        saturated = False
        for _ in range(oversample):
            rate = self.convert(Channel.RATE)
            temperature = self.convert(Channel.TEMPERATURE)
            saturated = saturated or self._saturated(rate) or self._saturated(temperature)
            rate_sum += rate
            temperature_sum += temperature
        if saturated:
            self.counters.saturated += 1
        return Mlx90609Reading(rate_code=rate_sum / oversample,
                               temperature_code=temperature_sum / oversample,
                               saturated=saturated)

    def read_eeprom(self) -> bytes:
        """Read all 128 EEPROM bytes with EER (0AAAAAAA), the byte in the answer's low byte."""
        image = bytes(self.command(address) & 0xFF for address in range(EEPROM_SIZE))
        if image in (bytes(EEPROM_SIZE), b'\xff' * EEPROM_SIZE):
            self.counters.silent_bus += 1
            msg = f'EEPROM read gave 128 bytes of 0x{image[0]:02X}: bus silent or part absent'
            raise SilentBusError(msg)
        return image
