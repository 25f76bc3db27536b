"""
Chamber records straight from the device physics: the bias a gyro at rest shows, sampled.

`GyroPhysics` integrates one device's state (die and sensor temperature,
hysteresis, gradients, bias instability, random walk); `chamber_run` samples
its zero-rate offset at a fixed rate, one device per axis, and adds white
rate and temperature noise, without the SPI frames and conversion of the
full simulated part (`mlx-tempcomp simulate`): thousands of rows a second,
for the diagnosis tests and the benches that judge it on many records.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from .physics import Effects, GyroPhysics, GyroTruth, Noise, Scenario, ThermalProfile

# The cubic ZRO of the chamber records, deg/s in powers of (T - 25 C).
CHAMBER_ZRO_DPS = (0.5, 0.02, 2e-4, -2e-6)


def chamber_profile(legs, start_c: float = 25.0, hold_s: float = 600.0) -> ThermalProfile:
    """Ramp to each (temperature C, rate C/min) of ``legs`` in turn and hold it ``hold_s``."""
    times, temperatures = [0.0], [start_c]
    for target_c, rate_c_per_min in legs:
        times.append(times[-1] + abs(target_c - temperatures[-1]) / rate_c_per_min * 60.0)
        temperatures.append(target_c)
        times.append(times[-1] + hold_s)
        temperatures.append(target_c)
    return ThermalProfile(times_s=tuple(times), temperatures_c=tuple(temperatures))


@dataclass(frozen=True)
class ChamberRun:
    """Rows of a chamber record: time, sensor temperature, rate (rows, axes), supply."""

    time_s: np.ndarray
    temperature_c: np.ndarray
    rate_rad_s: np.ndarray
    supply_v: np.ndarray


def device_offsets(truth: GyroTruth, scenario: Scenario, seed: int,
                   time_s: np.ndarray) -> tuple:
    """Return (sensor temperature C, zero-rate offset deg/s) of one device at ``time_s``."""
    physics = GyroPhysics(truth, scenario, seed=seed)
    temperature_c = np.empty(time_s.size)
    zro_dps = np.empty(time_s.size)
    for row, t in enumerate(time_s.tolist()):
        physics.advance(t)
        temperature_c[row] = physics.state.sensor_c
        zro_dps[row] = physics.zro_offset_dps()
    return temperature_c, zro_dps


def chamber_run(effects: Effects, noise: Noise, scenario: Scenario, seed: int,
                rate_noise_dps: float, temperature_noise_c: float, supply_noise_v: float = 0.0,
                axes: int = 1, zro_dps: Optional[tuple] = None,
                rate_hz: float = 1.0) -> ChamberRun:
    """
    Sample ``axes`` devices (seeds ``seed``, ``seed`` + 2, ...) at ``rate_hz`` through a scenario.

    Each axis's device has the cubic ZRO ``zro_dps`` (default CHAMBER_ZRO_DPS,
    the same on every axis) and the given effects and noise; the first
    device's sensor temperature is the recorded one. White noise (seeded
    ``seed`` + 1) is added to the rate, the temperature and the supply, which
    the scenario's waypoints give.
    """
    interval_s = 1.0 / rate_hz
    time_s = np.arange(interval_s, math.floor(scenario.thermal.duration_s) + interval_s / 2,
                       interval_s)
    truth = GyroTruth(zro_dps_coefficients=zro_dps or CHAMBER_ZRO_DPS, effects=effects,
                      noise=noise)
    runs = [device_offsets(truth, scenario, seed + 2 * axis, time_s) for axis in range(axes)]
    temperature_c = runs[0][0]
    rng = np.random.default_rng(seed + 1)
    rate_rad_s = np.column_stack([np.radians(zro + rng.normal(0.0, rate_noise_dps, time_s.size))
                                  for _, zro in runs])
    supply_v = np.interp(time_s, scenario.supply_times_s, scenario.supply_v)
    if supply_noise_v:
        supply_v = supply_v + rng.normal(0.0, supply_noise_v, time_s.size)
    temperature_c = temperature_c + rng.normal(0.0, temperature_noise_c, time_s.size)
    return ChamberRun(time_s, temperature_c, rate_rad_s, supply_v)
