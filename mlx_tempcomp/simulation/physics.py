"""
Physics of a simulated MLX90609: temperature, true ZRO(T) and SF(T), noise, effects.

Time is simulated seconds. The environment (`Scenario`) scripts what the
device experiences; `GyroTruth` is what one device really does; `GyroPhysics`
integrates the state (die temperature, sensor lag, hysteresis, bias
instability) and gives the analog outputs at any later time.
"""

from dataclasses import dataclass, field
import math
from typing import Optional

import numpy as np

from ..core.mlx90609 import Output, SensorTransfer

GRAVITY_M_S2 = 9.80665
NOMINAL_SUPPLY_V = 5.0


def _interp(times_s: tuple, values: tuple, t: float) -> float:
    """np.interp of one time; the ends and constant profiles (most calls) without numpy."""
    # The same values as np.interp, which costs about 3 us a call: a device sample makes
    # several of these calls.
    if len(times_s) == 1 or t >= times_s[-1]:
        return float(values[-1])
    if t <= times_s[0]:
        return float(values[0])
    return float(np.interp(t, times_s, values))


@dataclass(frozen=True)
class ThermalProfile:
    """
    Chamber temperature through waypoints; the die follows it.

    With ``time_constant_s`` = 0 the die temperature is the scripted one,
    otherwise it follows the chamber as a first-order lag.
    """

    times_s: tuple = (0.0,)
    temperatures_c: tuple = (25.0,)
    time_constant_s: float = 0.0

    @classmethod
    def sweep(cls, low_c: float = -40.0, high_c: float = 85.0, duration_s: float = 1800.0,
              soak_s: float = 60.0) -> 'ThermalProfile':
        """Soak at ``low_c``, ramp linearly to ``high_c``, soak again."""
        ramp_s = duration_s - 2.0 * soak_s
        return cls(times_s=(0.0, soak_s, soak_s + ramp_s, duration_s),
                   temperatures_c=(low_c, low_c, high_c, high_c))

    @classmethod
    def cycle(cls, temperatures_c: tuple, rate_c_per_min: float, start_c: float = 25.0,
              time_constant_s: float = 0.0, hold_s: float = 0.0) -> 'ThermalProfile':
        """Ramp at ``rate_c_per_min`` from ``start_c`` through each temperature, hold each."""
        times = [0.0]
        points = [start_c]
        for target in temperatures_c:
            times.append(times[-1] + abs(target - points[-1]) / rate_c_per_min * 60.0)
            points.append(target)
            if hold_s > 0.0:
                times.append(times[-1] + hold_s)
                points.append(target)
        return cls(times_s=tuple(times), temperatures_c=tuple(points),
                   time_constant_s=time_constant_s)

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1])

    def chamber_c(self, t: float) -> float:
        return _interp(self.times_s, self.temperatures_c, t)


@dataclass(frozen=True)
class Scenario:
    """What the device experiences: temperature, true rate, acceleration, supply."""

    thermal: ThermalProfile = ThermalProfile()
    # True rate about the gyro axis, deg/s, piecewise linear through waypoints.
    rate_times_s: tuple = (0.0,)
    rate_dps: tuple = (0.0,)
    # Specific force in the sensor frame, m/s^2 (the board lies flat).
    acceleration_m_s2: tuple = (0.0, 0.0, GRAVITY_M_S2)
    supply_times_s: tuple = (0.0,)
    supply_v: tuple = (NOMINAL_SUPPLY_V,)

    def true_rate_dps(self, t: float) -> float:
        return _interp(self.rate_times_s, self.rate_dps, t)

    def supply_voltage_v(self, t: float) -> float:
        return _interp(self.supply_times_s, self.supply_v, t)


@dataclass(frozen=True)
class Effects:
    """Optional effects beyond the factory table's reach; all off by default."""

    thermal_lag_s: float = 0.0              # temperature sensor lags the die (first order)
    hysteresis_dps: float = 0.0             # ZRO differs by this between heating and cooling
    hysteresis_width_c: float = 5.0         # temperature change that flips the branch
    zro_supply_dps_per_v: float = 0.0       # ZRO shift per volt off the nominal 5 V
    zro_dps_per_c_s: float = 0.0            # ZRO shift per degC/s of die temperature change
    # ZRO + g_k x (die - node_k), node_k a part of the package lagging the die by tau_k.
    gradient_time_constants_s: tuple = ()
    gradient_dps_per_c: tuple = ()
    bias_steps: tuple = ()                  # ((time_s, step_dps), ...)
    acceleration_dps_per_m_s2: tuple = (0.0, 0.0, 0.0)   # g-sensitivity per axis


@dataclass(frozen=True)
class Noise:
    """Datasheet-like noise (MLX90609: 0.03 deg/s/sqrt(Hz), 75 Hz bandwidth)."""

    density_dps_rt_hz: float = 0.03
    bandwidth_hz: float = 75.0
    bias_instability_dps: float = 0.01      # first-order Gauss-Markov, 1 sigma
    bias_correlation_s: float = 100.0
    rate_random_walk_dps_rt_s: float = 0.0  # bias random walk, deg/s per sqrt(s)
    temperature_noise_mv: float = 0.5

    @property
    def white_sigma_dps(self) -> float:
        # Equivalent noise bandwidth of a first-order roll-off: pi/2 x corner.
        return self.density_dps_rt_hz * math.sqrt(math.pi / 2.0 * self.bandwidth_hz)


@dataclass(frozen=True)
class GyroTruth:
    """
    The true behaviour of one device.

    ZRO(T) = nominal + S0 x zro_dps(T); SF(T) = S0 x (1 + sf_relative(T)), with
    polynomials in (T - 25 C) of the die temperature, lowest order first.
    """

    full_scale_dps: float = 75.0
    zro_dps_coefficients: tuple = (0.0,)
    sf_relative_coefficients: tuple = (0.0,)
    sensor_mv_at_25c: float = 2500.0
    sensor_mv_per_k: float = 10.0
    effects: Effects = Effects()
    noise: Noise = Noise()
    transfer: SensorTransfer = SensorTransfer()
    rail_low_mv: float = 250.0              # output clips here (UNCONFIRMED)
    rail_high_mv: float = 4750.0

    @classmethod
    def random(cls, rng: np.random.Generator, full_scale_dps: float = 75.0,
               effects: Effects = Effects(), noise: Noise = Noise()) -> 'GyroTruth':
        """Draw a device with datasheet-like spreads (AN2 figures 10 and 11)."""
        def spread(sigma: float) -> float:
            return float(np.clip(rng.normal(0.0, sigma), -2.0 * sigma, 2.0 * sigma))
        return cls(full_scale_dps=full_scale_dps,
                   zro_dps_coefficients=(spread(1.0), spread(0.02), spread(2e-4), spread(2e-6)),
                   sf_relative_coefficients=(spread(0.008), spread(1.5e-4), spread(2e-6)),
                   sensor_mv_at_25c=2500.0 + spread(15.0),
                   sensor_mv_per_k=10.0 * (1.0 + spread(0.02)),
                   effects=effects, noise=noise)

    @property
    def typical_sf_mv(self) -> float:
        return self.transfer.typical_sf(self.full_scale_dps, Output.ANALOG)

    def zro_dps(self, die_c: float) -> float:
        return float(np.polynomial.polynomial.polyval(die_c - 25.0, self.zro_dps_coefficients))

    def zro_mv(self, die_c: float) -> float:
        return self.transfer.nominal_zro_mv + self.typical_sf_mv * self.zro_dps(die_c)

    def sf_mv(self, die_c: float) -> float:
        relative = np.polynomial.polynomial.polyval(die_c - 25.0, self.sf_relative_coefficients)
        return self.typical_sf_mv * (1.0 + float(relative))

    def sensor_mv(self, sensor_c: float) -> float:
        return self.sensor_mv_at_25c + self.sensor_mv_per_k * (sensor_c - 25.0)


@dataclass
class GyroState:
    time_s: float
    die_c: float
    sensor_c: float
    hysteresis_dps: float
    bias_dps: float
    die_rate_c_s: float = 0.0
    walk_dps: float = 0.0
    nodes_c: list = field(default_factory=list)


class GyroPhysics:
    """Integrates one device's state over simulated time; seedable."""

    def __init__(self, truth: GyroTruth, scenario: Scenario, seed: Optional[int] = None):
        self.truth = truth
        self.scenario = scenario
        self.rng = np.random.default_rng(seed)
        start_c = scenario.thermal.chamber_c(0.0)
        noise = truth.noise
        self.state = GyroState(time_s=0.0, die_c=start_c, sensor_c=start_c,
                               hysteresis_dps=0.0,
                               bias_dps=self.rng.normal(0.0, noise.bias_instability_dps),
                               nodes_c=[start_c] * len(truth.effects.gradient_time_constants_s))

    def reseed(self, seed) -> None:
        """Draw the noise and the bias instability afresh from ``seed`` (another day)."""
        self.rng = np.random.default_rng(seed)
        self.state.bias_dps = self.rng.normal(0.0, self.truth.noise.bias_instability_dps)

    def advance(self, t: float) -> None:
        """Move the state to time ``t`` (never backwards)."""
        s = self.state
        dt = t - s.time_s
        if dt <= 0.0:
            return
        thermal = self.scenario.thermal
        chamber = thermal.chamber_c(t)
        die = chamber if thermal.time_constant_s <= 0.0 else \
            s.die_c + (chamber - s.die_c) * -math.expm1(-dt / thermal.time_constant_s)
        effects = self.truth.effects
        lag = effects.thermal_lag_s
        s.sensor_c = die if lag <= 0.0 else \
            s.sensor_c + (die - s.sensor_c) * -math.expm1(-dt / lag)
        if effects.hysteresis_dps:
            # Play-type hysteresis: the branch moves towards +h/2 when heating and
            # -h/2 when cooling, fully switched after a change of about the width.
            change = die - s.die_c
            target = math.copysign(0.5 * effects.hysteresis_dps, change) if change else \
                s.hysteresis_dps
            fraction = min(1.0, abs(change) / effects.hysteresis_width_c)
            s.hysteresis_dps += (target - s.hysteresis_dps) * fraction
        s.nodes_c = [node + (die - node) * -math.expm1(-dt / tau) for node, tau in
                     zip(s.nodes_c, effects.gradient_time_constants_s)]
        s.die_rate_c_s = (die - s.die_c) / dt
        noise = self.truth.noise
        if noise.rate_random_walk_dps_rt_s > 0.0:
            s.walk_dps += noise.rate_random_walk_dps_rt_s * math.sqrt(dt) * \
                self.rng.standard_normal()
        if noise.bias_instability_dps > 0.0:
            decay = math.exp(-dt / noise.bias_correlation_s)
            s.bias_dps = s.bias_dps * decay + noise.bias_instability_dps * \
                math.sqrt(1.0 - decay * decay) * self.rng.standard_normal()
        s.die_c = die
        s.time_s = t

    def zro_offset_dps(self) -> float:
        """Everything at zero rate beyond the nominal ZRO, in deg/s of equivalent rate."""
        s = self.state
        effects = self.truth.effects
        offset = self.truth.zro_dps(s.die_c) + s.hysteresis_dps + s.bias_dps + s.walk_dps
        offset += effects.zro_dps_per_c_s * s.die_rate_c_s
        offset += sum(g * (s.die_c - node)
                      for g, node in zip(effects.gradient_dps_per_c, s.nodes_c))
        offset += effects.zro_supply_dps_per_v * (
            self.scenario.supply_voltage_v(s.time_s) - NOMINAL_SUPPLY_V)
        offset += sum(step for when, step in effects.bias_steps if s.time_s >= when)
        offset += float(np.dot(effects.acceleration_dps_per_m_s2,
                               self.scenario.acceleration_m_s2))
        return offset

    def rate_output_mv(self, t: float) -> float:
        """Analog rate output at ``t``, noise included, clipped at the rails."""
        self.advance(t)
        truth = self.truth
        sf_mv = truth.sf_mv(self.state.die_c)
        rate = self.scenario.true_rate_dps(t) + truth.noise.white_sigma_dps * \
            self.rng.standard_normal()
        mv = truth.transfer.nominal_zro_mv + truth.typical_sf_mv * self.zro_offset_dps() + \
            sf_mv * rate
        return min(max(mv, truth.rail_low_mv), truth.rail_high_mv)

    def temperature_output_mv(self, t: float) -> float:
        self.advance(t)
        return self.truth.sensor_mv(self.state.sensor_c) + \
            self.truth.noise.temperature_noise_mv * self.rng.standard_normal()
