"""Errors raised by transports and device protocols, and the counters of the faults seen."""

from dataclasses import dataclass, fields

from ..errors import MlxTempCompError


class HardwareError(MlxTempCompError):
    """Base class of every error the hardware layer raises."""


class TransportError(HardwareError):
    """The bus itself failed (device node missing, permission, I/O error)."""


class SilentBusError(HardwareError):
    """Nothing answers: every SPI answer bit the same (no part drives MISO), or no I2C ACK."""


class NackError(SilentBusError):
    """No device acknowledged its I2C address: absent, unpowered, or at another address."""


class RefusalError(HardwareError):
    """The device answered with a refusal word (bit 15 set)."""

    def __init__(self, message: str, answer: int):
        super().__init__(message)
        self.answer = answer


class EocTimeoutError(HardwareError):
    """A conversion did not signal end of conversion within the poll limit."""


class ProtocolError(HardwareError):
    """An answer is not what the protocol allows (for example a wrong channel echo)."""


@dataclass
class FaultCounters:
    """How often each fault every device protocol can meet was seen since the driver started."""

    silent_bus: int = 0
    protocol_errors: int = 0
    saturated: int = 0

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}
