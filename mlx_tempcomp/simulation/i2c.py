"""
A simulated I2C adapter: parts at 7-bit addresses, answering smbus2's block calls.

`SimulatedI2cBus` offers what `mlx_tempcomp.hardware.transport.SmbusTransport`
calls of ``smbus2.SMBus``, with the same limits and failures, so the real
transport (block splitting, error mapping) runs against it unchanged: at most
32 bytes a call (ValueError beyond, as smbus2), and ``OSError`` ENXIO for an
address no part acknowledges, as i2c-dev gives. A part offers
``i2c_read(register, count)`` and ``i2c_write(register, data)`` and raises
``OSError`` itself when it does not answer. Each call takes 9 bit times a byte
(8 data bits and the acknowledge) on the shared `SimClock`.
"""

import errno
import os
from typing import Dict, List, Protocol, Sequence

from .clock import SimClock

SMBUS_BLOCK_MAX = 32
# Bytes of a register read besides its data: address + write, register, address + read.
_READ_OVERHEAD_BYTES = 3
# Of a register write: address + write, register.
_WRITE_OVERHEAD_BYTES = 2


class I2cPart(Protocol):
    """What a simulated part gives the bus: register reads and writes at its address."""

    def i2c_read(self, register: int, count: int) -> bytes:
        """Read ``count`` registers from ``register``; ``OSError`` if it does not answer."""

    def i2c_write(self, register: int, data: bytes) -> None:
        """Write ``data`` from ``register`` on; ``OSError`` if it does not answer."""


class SimulatedI2cBus:
    """An I2C adapter with simulated parts on it, driven through smbus2's block calls."""

    def __init__(self, clock: SimClock, scl_hz: float = 400e3):
        self.clock = clock
        self.bit_time_s = 1.0 / scl_hz
        self.parts: Dict[int, I2cPart] = {}

    def attach(self, address: int, part: I2cPart) -> None:
        if address in self.parts:
            msg = f'two parts at I2C address 0x{address:02X}'
            raise ValueError(msg)
        self.parts[address] = part

    def _part(self, address: int, size: int) -> I2cPart:
        self.clock.advance(9 * size * self.bit_time_s)
        try:
            return self.parts[address]
        except KeyError:
            raise OSError(errno.ENXIO, os.strerror(errno.ENXIO)) from None

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> List[int]:
        if length > SMBUS_BLOCK_MAX:
            msg = f'Desired block length over {SMBUS_BLOCK_MAX} bytes'
            raise ValueError(msg)
        part = self._part(i2c_addr, _READ_OVERHEAD_BYTES + length)
        return list(part.i2c_read(register, length))

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int]) -> None:
        if len(data) > SMBUS_BLOCK_MAX:
            msg = f'Data length cannot exceed {SMBUS_BLOCK_MAX} bytes'
            raise ValueError(msg)
        self._part(i2c_addr, _WRITE_OVERHEAD_BYTES + len(data)).i2c_write(register, bytes(data))

    def close(self) -> None:
        """Nothing to release."""
