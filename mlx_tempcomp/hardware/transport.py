"""SPI transports: one full-duplex frame at a time."""

import time
from typing import Protocol

from .errors import TransportError


class Transport(Protocol):
    """What a device protocol needs from a bus."""

    def transfer(self, tx: bytes) -> bytes:
        """Clock ``tx`` out and return the bytes clocked in (same length)."""

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
