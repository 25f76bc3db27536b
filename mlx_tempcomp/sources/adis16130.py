"""
One ADIS16130 read as a one-axis sensor (its z axis), over spidev or simulated.

Unlike the MLX90609 there is no factory table to apply: the part's codes
convert to deg/s and C by the fixed offset-binary formats, so a sample is
already in rad/s and C, with the time it was taken.
"""

from dataclasses import dataclass
import math
import time

import numpy as np

from ..hardware.adis16130 import Adis16130
from ..hardware.errors import HardwareError
from ..hardware.transport import SpidevTransport
from ..simulation.adis16130 import Adis16130Truth, Fault, simulated_device, UPDATE_RATE_HZ
from ..simulation.clock import SimClock
from ..simulation.physics import Scenario, ThermalProfile

AXES = ('z',)
DEFAULT_SPEED_HZ = 1_000_000   # ADI's BF537-STAMP board file (sensor-facts.md section 2)
SPI_MODE = 3                   # AN-1042 Table 2: CPOL = 1, CPHA = 1


@dataclass(frozen=True)
class Sample:
    """One reading: rate and temperature per axis, when it was taken, saturation."""

    time_s: float
    rate_rad_s: np.ndarray
    temperature_c: np.ndarray
    saturated: bool


@dataclass(frozen=True)
class Record:
    """Samples taken at a fixed rate; saturated readings are left out and counted."""

    time_s: np.ndarray
    rate_rad_s: np.ndarray        # (n, 1)
    temperature_c: np.ndarray     # (n,)
    saturated: int


class WallClock:
    """Seconds since construction on the monotonic clock; `advance` sleeps."""

    def __init__(self):
        self._start = time.monotonic()

    @property
    def now_s(self) -> float:
        return time.monotonic() - self._start

    def advance(self, seconds: float) -> None:
        if seconds > 0.0:
            time.sleep(seconds)


class Adis16130Sensor:
    """A started `Adis16130` and the clock its samples are stamped with."""

    axes = AXES

    def __init__(self, driver: Adis16130, clock):
        self.driver = driver
        self.clock = clock
        driver.start()

    def read(self, oversample: int = 1) -> Sample:
        reading = self.driver.read(oversample)
        return Sample(time_s=self.clock.now_s,
                      rate_rad_s=np.array([math.radians(reading.rate_dps)]),
                      temperature_c=np.array([reading.temperature_c]),
                      saturated=reading.saturated)

    def record(self, duration_s: float, rate_hz: float, oversample: int = 1) -> Record:
        """Read at ``rate_hz`` for ``duration_s`` (on real hardware, as fast as it keeps up)."""
        if not duration_s > 0.0 or not rate_hz > 0.0:
            msg = f'record needs a positive duration and rate, got {duration_s} s, {rate_hz} Hz'
            raise HardwareError(msg)
        start_s = self.clock.now_s
        samples = []
        saturated = 0
        for index in range(int(math.floor(duration_s * rate_hz + 1e-9))):
            self.clock.advance(start_s + index / rate_hz - self.clock.now_s)
            sample = self.read(oversample)
            if sample.saturated:
                saturated += 1
            else:
                samples.append(sample)
        return Record(time_s=np.array([s.time_s for s in samples]),
                      rate_rad_s=np.array([s.rate_rad_s for s in samples]).reshape(-1, 1),
                      temperature_c=np.array([s.temperature_c[0] for s in samples]),
                      saturated=saturated)

    @property
    def counters(self) -> dict:
        return self.driver.counters.as_dict()

    def close(self) -> None:
        self.driver.transport.close()


def spidev_sensor(bus: int, chip_select: int, speed_hz: int = DEFAULT_SPEED_HZ,
                  mode: int = SPI_MODE, resolution_bits: int = 24,
                  verify_registers: bool = True) -> Adis16130Sensor:
    """Start the part on ``/dev/spidev<bus>.<chip_select>``."""
    transport = SpidevTransport(bus, chip_select, speed_hz, mode)
    try:
        return Adis16130Sensor(Adis16130(transport, resolution_bits=resolution_bits,
                                         verify_registers=verify_registers), WallClock())
    except HardwareError:
        transport.close()
        raise


@dataclass(frozen=True)
class SimulationConfig:
    """What the simulated part experiences and how it behaves."""

    seed: int = 0
    resolution_bits: int = 24
    truth: Adis16130Truth = Adis16130Truth()
    thermal: ThermalProfile = ThermalProfile()
    rate_dps: float = 0.0
    supply_v: float = 5.0
    update_rate_hz: float = UPDATE_RATE_HZ
    sclk_hz: float = float(DEFAULT_SPEED_HZ)


class SimulatedSensor(Adis16130Sensor):
    """A simulated part on a simulated clock, started through the real protocol."""

    def __init__(self, config: SimulationConfig = SimulationConfig()):
        scenario = Scenario(thermal=config.thermal, rate_dps=(config.rate_dps,),
                            supply_v=(config.supply_v,))
        self.device = simulated_device(config.truth, scenario, config.seed, SimClock(),
                                       config.sclk_hz, config.update_rate_hz)
        driver = Adis16130(self.device.transport(), resolution_bits=config.resolution_bits)
        super().__init__(driver, self.device.clock)

    @property
    def fault(self) -> Fault:
        return self.device.fault

    @fault.setter
    def fault(self, fault: Fault) -> None:
        self.device.fault = fault

    def advance_to(self, time_s: float) -> None:
        """Let simulated time pass up to ``time_s`` (never backwards)."""
        self.clock.advance(time_s - self.clock.now_s)
