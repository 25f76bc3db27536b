"""
Transports: SPI (one full-duplex frame at a time) and I2C (register block reads and writes).

An SPI part gets a `Transport`; an I2C part a `RegisterTransport`, whose
register address carries no read flag (the bus's own read bit does that).
`SmbusTransport` speaks to one slave address through anything with smbus2's
block calls: ``smbus2.SMBus`` on Linux i2c-dev (`open_i2c`), or a simulated
bus (`mlx_tempcomp.simulation.i2c.SimulatedI2cBus`).
"""

import errno
import time
from typing import Callable, Protocol, runtime_checkable

from .errors import NackError, TransportError

# Most bytes one SMBus I2C block read or write moves (smbus2 refuses more): longer ones are
# split, the part's register address auto-incrementing across them.
I2C_BLOCK_BYTES = 32
# What the kernel's adapters give when nothing acknowledges the address (the kernel's
# fault-codes.rst: ENXIO; many adapters give EREMOTEIO or EIO).
_NO_ACKNOWLEDGE = {errno.ENXIO, errno.EREMOTEIO, errno.EIO}


class Transport(Protocol):
    """What a device protocol needs from a bus."""

    def transfer(self, tx: bytes) -> bytes:
        """Clock ``tx`` out and return the bytes clocked in (same length)."""

    def wait(self, seconds: float) -> None:
        """Let ``seconds`` pass on the device's clock."""

    def close(self) -> None:
        """Release the bus."""


@runtime_checkable
class RegisterTransport(Protocol):
    """What a register device needs from an I2C bus: block reads and writes at its address."""

    name: str

    def read_registers(self, register: int, count: int) -> bytes:
        """Read ``count`` registers from ``register`` on (auto-increment)."""

    def write_registers(self, register: int, data: bytes) -> None:
        """Write ``data`` to consecutive registers from ``register`` on."""

    def wait(self, seconds: float) -> None:
        """Let ``seconds`` pass on the device's clock."""

    def close(self) -> None:
        """Release the bus."""


class SpidevTransport:
    """Linux spidev (``/dev/spidev<bus>.<device>``) through the ``spidev`` package."""

    def __init__(self, bus: int, device: int, speed_hz: int = 500_000, mode: int = 3):
        try:
            import spidev
        except ImportError as err:
            msg = f'the spidev package is not installed: {err}'
            raise TransportError(msg) from None
        self._spi = spidev.SpiDev()
        try:
            self._spi.open(bus, device)
            self._spi.max_speed_hz = int(speed_hz)
            self._spi.mode = int(mode)
            self._spi.bits_per_word = 8
        except (OSError, ValueError, TypeError) as err:
            self._spi.close()
            msg = f'cannot open /dev/spidev{bus}.{device} (mode {mode}, {speed_hz} Hz): {err}'
            raise TransportError(msg) from None
        self.name = f'/dev/spidev{bus}.{device}'

    def transfer(self, tx: bytes) -> bytes:
        try:
            return bytes(self._spi.xfer2(list(tx)))
        except OSError as err:
            msg = f'SPI transfer on {self.name} failed: {err}'
            raise TransportError(msg) from None

    def wait(self, seconds: float) -> None:
        if seconds > 0.0:
            time.sleep(seconds)

    def close(self) -> None:
        self._spi.close()


class SmbusTransport:
    """
    One 7-bit slave address on an smbus2-style bus, as a `RegisterTransport`.

    ``bus`` offers smbus2's ``read_i2c_block_data``, ``write_i2c_block_data``
    and ``close``; ``name`` names it in errors; ``sleep`` lets time pass
    (``time.sleep`` on hardware, the simulated clock otherwise). An address
    nobody acknowledges raises `NackError`, any other bus failure
    `TransportError`.
    """

    def __init__(self, bus, address: int, name: str,
                 sleep: Callable[[float], None] = time.sleep):
        if not 0x08 <= address <= 0x77:
            msg = f'I2C address 0x{address:02X} is outside the 7-bit device range 0x08-0x77'
            raise TransportError(msg)
        self._bus = bus
        self.address = address
        self.name = name
        self._sleep = sleep

    def read_registers(self, register: int, count: int) -> bytes:
        data = bytearray()
        for start in range(0, count, I2C_BLOCK_BYTES):
            length = min(I2C_BLOCK_BYTES, count - start)
            data += bytes(self._call('read', self._bus.read_i2c_block_data,
                                     register + start, length))
        return bytes(data)

    def write_registers(self, register: int, data: bytes) -> None:
        for start in range(0, len(data), I2C_BLOCK_BYTES):
            self._call('write', self._bus.write_i2c_block_data, register + start,
                       list(data[start:start + I2C_BLOCK_BYTES]))

    def _call(self, what: str, block_call, register: int, argument):
        try:
            return block_call(self.address, register, argument)
        except OSError as err:
            where = f'0x{self.address:02X} on {self.name}'
            if err.errno in _NO_ACKNOWLEDGE:
                msg = (f'no device acknowledged address {where} ({err.strerror}): nothing '
                       'answers there (wiring, supply, or another address)')
                raise NackError(msg) from None
            if err.errno == errno.EBUSY:
                msg = (f'address {where} is held by a kernel driver ({err.strerror}): unbind '
                       'it (for an MPU, inv-mpu6050) to read the part from here')
                raise TransportError(msg) from None
            msg = f'I2C block {what} at register 0x{register:02X} of {where} failed: {err}'
            raise TransportError(msg) from None

    def wait(self, seconds: float) -> None:
        if seconds > 0.0:
            self._sleep(seconds)

    def close(self) -> None:
        self._bus.close()


def open_i2c(bus: int, address: int) -> SmbusTransport:
    """Open ``/dev/i2c-<bus>`` through smbus2 for the part at ``address``."""
    try:
        import smbus2
    except ImportError as err:
        msg = f'the smbus2 package is not installed: {err}'
        raise TransportError(msg) from None
    path = f'/dev/i2c-{bus}'
    try:
        handle = smbus2.SMBus(bus)
    except FileNotFoundError:
        msg = (f'cannot open {path}: no such I2C bus (ls /dev/i2c-* lists those there are; '
               'enable the bus and load the i2c-dev module)')
        raise TransportError(msg) from None
    except PermissionError:
        msg = f'cannot open {path}: permission denied (add the user to the i2c group)'
        raise TransportError(msg) from None
    except OSError as err:
        msg = f'cannot open {path}: {err}'
        raise TransportError(msg) from None
    needed = smbus2.I2cFunc.SMBUS_READ_I2C_BLOCK | smbus2.I2cFunc.SMBUS_WRITE_I2C_BLOCK
    if handle.funcs & needed != needed:
        handle.close()
        msg = f'{path} cannot do I2C block reads and writes (its adapter lacks them)'
        raise TransportError(msg)
    try:
        return SmbusTransport(handle, address, path)
    except TransportError:
        handle.close()
        raise
