"""
One to three MLX90609 chips read as one sensor, over spidev or simulated.

An MLX90609 measures one axis, so an N-axis gyro is N chips, each with its
own chip select, EEPROM table and temperature sensor.
"""

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from ..hardware.errors import HardwareError
from ..hardware.mlx90609 import ErrorCounters, Mlx90609
from ..hardware.transport import SpidevTransport
from ..simulation.clock import SimClock
from ..simulation.mlx90609 import FactoryMeasurement, Fault, simulated_device
from ..simulation.physics import Effects, GyroTruth, Noise, Scenario, ThermalProfile


@dataclass(frozen=True)
class RawSample:
    """Codes of every axis from one reading, and whether any was saturated."""

    rate_code: np.ndarray
    temperature_code: np.ndarray
    saturated: bool


class Mlx90609Array:
    """Read 1-3 chips in turn; their EEPROMs give the factory tables."""

    def __init__(self, drivers: Sequence[Mlx90609]):
        if not 1 <= len(drivers) <= 3:
            msg = f'one to three MLX90609 chips are supported, got {len(drivers)}'
            raise HardwareError(msg)
        self.drivers = tuple(drivers)

    @property
    def axes(self) -> int:
        return len(self.drivers)

    def read_eeproms(self) -> tuple:
        """Read every chip's EEPROM image (address 0 first)."""
        return tuple(driver.read_eeprom() for driver in self.drivers)

    def read(self, oversample: int = 1) -> RawSample:
        readings = [driver.read(oversample) for driver in self.drivers]
        return RawSample(rate_code=np.array([r.rate_code for r in readings]),
                         temperature_code=np.array([r.temperature_code for r in readings]),
                         saturated=any(r.saturated for r in readings))

    @property
    def counters(self) -> dict:
        total = ErrorCounters().as_dict()
        for driver in self.drivers:
            for name, count in driver.counters.as_dict().items():
                total[name] += count
        return total

    def close(self) -> None:
        for driver in self.drivers:
            driver.transport.close()


def spidev_array(bus: int, chip_selects: Sequence[int], speed_hz: int,
                 mode: int) -> Mlx90609Array:
    """Chips on ``/dev/spidev<bus>.<cs>``, one chip select per axis."""
    transports = []
    try:
        for chip_select in chip_selects:
            transports.append(SpidevTransport(bus, chip_select, speed_hz, mode))
    except HardwareError:
        for transport in transports:
            transport.close()
        raise
    return Mlx90609Array([Mlx90609(t) for t in transports])


@dataclass(frozen=True)
class SimulationConfig:
    """What the simulated chips experience and which optional effects they have."""

    seed: int = 0
    full_scale_dps: float = 75.0
    eeprom_version: int = 2
    start_temperature_c: float = 25.0
    cycle_temperatures_c: tuple = ()          # empty: constant temperature
    ramp_c_per_min: float = 2.0
    hold_s: float = 0.0                        # soak at each cycle temperature
    die_time_constant_s: float = 0.0
    rate_dps: tuple = (0.0,)                   # true rate per axis (one value: all axes)
    supply_v: float = 5.0
    effects: Effects = Effects()
    noise: Noise = Noise()

    def thermal_profile(self) -> ThermalProfile:
        return ThermalProfile.cycle(self.cycle_temperatures_c, self.ramp_c_per_min,
                                    self.start_temperature_c, self.die_time_constant_s,
                                    self.hold_s)

    def true_rate_dps(self, axis: int) -> float:
        return self.rate_dps[axis] if len(self.rate_dps) > 1 else self.rate_dps[0]


class SimulatedArray(Mlx90609Array):
    """Simulated chips sharing one simulated clock; faults switch all chips at once."""

    def __init__(self, config: SimulationConfig, axes: int = 1):
        if not 1 <= axes <= 3:
            msg = f'one to three simulated axes are supported, got {axes}'
            raise HardwareError(msg)
        if len(config.rate_dps) not in (1, axes):
            msg = f'simulation rate_dps needs 1 or {axes} values, got {len(config.rate_dps)}'
            raise HardwareError(msg)
        self.clock = SimClock()
        thermal = config.thermal_profile()
        self.devices = []
        for axis in range(axes):
            seed = config.seed * 10 + axis
            truth = GyroTruth.random(np.random.default_rng(seed), config.full_scale_dps,
                                     config.effects, config.noise)
            scenario = Scenario(thermal=thermal, rate_dps=(config.true_rate_dps(axis),),
                                supply_v=(config.supply_v,))
            device = simulated_device(truth, scenario, seed, self.clock,
                                      FactoryMeasurement(version=config.eeprom_version))
            self.devices.append(device)
        super().__init__([Mlx90609(d.transport()) for d in self.devices])

    @property
    def fault(self) -> Fault:
        return self.devices[0].fault

    @fault.setter
    def fault(self, fault: Fault) -> None:
        for device in self.devices:
            device.fault = fault

    @property
    def supply_v(self) -> float:
        """Give the chips' supply voltage now."""
        return self.devices[0].physics.scenario.supply_voltage_v(self.clock.now_s)

    @supply_v.setter
    def supply_v(self, volts: float) -> None:
        """Switch every chip's supply to ``volts`` from now on (a step)."""
        for device in self.devices:
            device.physics.scenario = replace(device.physics.scenario, supply_times_s=(0.0,),
                                              supply_v=(float(volts),))

    def advance_to(self, time_s: float) -> None:
        """Let simulated time pass up to ``time_s`` (never backwards)."""
        self.clock.advance(time_s - self.clock.now_s)
