"""
Simulated rate-table calibration of a 3-axis gyro, the data the calibration chain is fitted on.

The table holds reference-rate plateaus on each axis in turn and on all three at once, at
several chamber temperatures; then, at zero rate and the reference die temperature, the
electronics temperature steps through a range (the paper's Figure 18 test). The gyro is
the exact inverse of a `CalibrationChain` (`TurntableTruth.chain`), so the fit can be
checked against the truth; white noise is added to the measured rate. Output columns are
in the canonical units: s, rad/s, degC.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from ..core.errors import ConfigError
from ..core.node_models import CalibrationChain

_RATE_LEVELS_RAD_S = tuple(math.radians(dps) for dps in range(-300, 301, 25))
_CROSS_LEVELS_RAD_S = tuple(math.radians(dps) for dps in (-300.0, -150.0, 150.0, 300.0))


def _spread(rng: np.random.Generator, scale: float, size: int) -> np.ndarray:
    """Draw magnitudes between 0.5 and 1 x ``scale`` with random signs."""
    return scale * rng.uniform(0.5, 1.0, size) * rng.choice((-1.0, 1.0), size)


@dataclass(frozen=True)
class TurntableTruth:
    """
    The true behaviour of one gyro, in the functional forms of the chain.

    ``nonlinearity_rad_s`` maps measured to reference rate at the reference temperatures
    (its constant term is the zero-rate offset there), per axis, in x = rate / full
    scale; ``sensitivity_slope_rad_s_per_c`` is K(x), cubic with K(0) = 0;
    ``sensitivity_matrix`` S (unit diagonal: the scale factor is in the nonlinearity)
    turns the true rate into the rate each axis senses, so the chain's misalignment is
    inv(S). The offsets at the reference temperatures and C(x) are zero: the sequential
    fit puts anything there into the nonlinearity, fitted at the reference (a linear
    C(x) leaves (1 - c1) P(x) - c0, still a polynomial of the same order), so only this
    form of the truth is identifiable.
    """

    full_scale_rad_s: float
    reference_temperature_c: float
    reference_temperature_2_c: float
    nonlinearity_rad_s: tuple
    offset_gradient_rad_s_per_c: tuple
    sensitivity_slope_rad_s_per_c: tuple
    offset_2_gradient_rad_s_per_c: tuple
    sensitivity_matrix: tuple

    @classmethod
    def random(cls, rng: np.random.Generator, full_scale_rad_s: float = math.radians(300.0),
               reference_temperature_c: float = 20.0,
               reference_temperature_2_c: float = 25.0) -> 'TurntableTruth':
        """
        Draw a gyro: offset 0.5 deg/s, scale +-1.5 %, odd nonlinearity up to 1.5 % FS.

        Offset drift 0.02 deg/s/C, scale-factor drift up to 300 ppm/C with a cubic
        rate dependence, electronics offset drift 0.05 deg/s/C, axis misalignment
        (off-diagonal S) up to 1e-2.
        """
        fs = full_scale_rad_s
        nonlinearity = np.column_stack([
            _spread(rng, math.radians(0.5), 3), fs * (1.0 + _spread(rng, 0.015, 3)),
            fs * _spread(rng, 0.002, 3), fs * _spread(rng, 0.01, 3),
            fs * _spread(rng, 0.005, 3), fs * _spread(rng, 0.015, 3)])
        slope = np.column_stack([np.zeros(3), fs * _spread(rng, 3e-4, 3),
                                 fs * _spread(rng, 3e-5, 3), fs * _spread(rng, 6e-5, 3)])
        matrix = np.eye(3) + _spread(rng, 1e-2, 9).reshape(3, 3) * (1.0 - np.eye(3))
        return cls(full_scale_rad_s=fs, reference_temperature_c=reference_temperature_c,
                   reference_temperature_2_c=reference_temperature_2_c,
                   nonlinearity_rad_s=tuple(map(tuple, nonlinearity.tolist())),
                   offset_gradient_rad_s_per_c=tuple(_spread(rng, math.radians(0.02), 3)),
                   sensitivity_slope_rad_s_per_c=tuple(map(tuple, slope.tolist())),
                   offset_2_gradient_rad_s_per_c=tuple(_spread(rng, math.radians(0.05), 3)),
                   sensitivity_matrix=tuple(map(tuple, matrix.tolist())))

    def chain(self) -> CalibrationChain:
        """Return the chain that corrects this gyro exactly."""
        zeros = (0.0, 0.0, 0.0)
        return CalibrationChain(
            full_scale_rad_s=self.full_scale_rad_s,
            reference_temperature_c=self.reference_temperature_c,
            reference_temperature_2_c=self.reference_temperature_2_c,
            nonlinearity_rad_s=self.nonlinearity_rad_s, offset_rad_s=zeros,
            offset_gradient_rad_s_per_c=self.offset_gradient_rad_s_per_c,
            sensitivity_slope_rad_s_per_c=self.sensitivity_slope_rad_s_per_c,
            sensitivity_intercept_rad_s=((0.0, 0.0),) * 3, offset_2_rad_s=zeros,
            offset_2_gradient_rad_s_per_c=self.offset_2_gradient_rad_s_per_c,
            misalignment=np.linalg.inv(self.sensitivity_matrix))


@dataclass(frozen=True)
class TurntableProtocol:
    """
    What the table, the chamber and the electronics do, and the gyro's noise.

    Each chamber session holds every level of ``rate_levels_rad_s`` on x, then y, then
    z, then every level of ``cross_axis_levels_rad_s`` on all three axes, ramping at
    ``acceleration_rad_s2`` between plateaus; sessions are ``soak_s`` apart (not
    recorded). Meanwhile the electronics temperature drifts by
    ``temperature_2_drift_c`` around the reference. The last session holds zero rate at
    the reference temperature while the electronics temperature steps through
    ``electronics_temperatures_c``.
    """

    rate_levels_rad_s: tuple = _RATE_LEVELS_RAD_S
    cross_axis_levels_rad_s: tuple = _CROSS_LEVELS_RAD_S
    chamber_temperatures_c: tuple = (-20.0, 0.0, 20.0, 40.0, 60.0)
    electronics_temperatures_c: tuple = (10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)
    hold_s: float = 4.0
    electronics_hold_s: float = 30.0
    sample_rate_hz: float = 10.0
    acceleration_rad_s2: float = math.radians(200.0)
    soak_s: float = 3600.0
    temperature_noise_c: float = 0.05
    temperature_2_drift_c: float = 0.2
    temperature_2_period_s: float = 1000.0
    noise_rad_s: float = math.radians(0.05)


@dataclass(frozen=True)
class TurntableSession:
    """A recorded session: arrays of one row per sample, and the truth behind them."""

    time_s: np.ndarray
    reference_rad_s: np.ndarray
    measured_rad_s: np.ndarray
    temperature_c: np.ndarray
    temperature_2_c: np.ndarray
    plateau_id: np.ndarray
    truth: TurntableTruth


def _table_motion(targets: np.ndarray, hold: int, step_rad_s: float) -> tuple:
    """Return the reference (samples, 3) and plateau number (-1 on ramps) through ``targets``."""
    references, plateaus = [], []
    current = np.zeros(3)
    for number, target in enumerate(np.vstack([targets, np.zeros(3)])):
        steps = math.ceil(np.max(np.abs(target - current)) / step_rad_s)
        fractions = np.arange(1, steps) / steps
        references += [current + fractions[:, None] * (target - current)]
        plateaus += [np.full(fractions.size, -1)]
        if number < len(targets):
            references += [np.tile(target, (hold, 1))]
            plateaus += [np.full(hold, number)]
        current = target
    return np.concatenate(references), np.concatenate(plateaus)


def _newton(value, slope, target: np.ndarray, start: np.ndarray, scale: float) -> np.ndarray:
    """Solve value(x) = target element-wise, to 1e-13 x ``scale``."""
    x = start
    for _ in range(50):
        step = (value(x) - target) / slope(x)
        x = x - step
        if np.max(np.abs(step), initial=0.0) <= 1e-13 * scale:
            return x
    msg = 'the truth cannot be inverted: is its nonlinearity monotonic over the range?'
    raise ConfigError(msg)


def _measured_rate(chain: CalibrationChain, reference_rad_s: np.ndarray,
                   temperature_c: np.ndarray, temperature_2_c: np.ndarray) -> np.ndarray:
    """Run the chain backwards: the noiseless rate that it corrects to the reference."""
    fs = chain.full_scale_rad_s
    polynomial = np.polynomial.polynomial
    delta = temperature_c - chain.reference_temperature_c
    delta_2 = temperature_2_c - chain.reference_temperature_2_c
    sensed = np.linalg.solve(np.asarray(chain.misalignment), reference_rad_s.T).T
    sensed += np.asarray(chain.offset_2_rad_s) + \
        delta_2[:, None] * np.asarray(chain.offset_2_gradient_rad_s_per_c)
    measured = np.empty_like(sensed)
    for axis in range(3):
        k = chain.sensitivity_slope_rad_s_per_c[axis]
        c = chain.sensitivity_intercept_rad_s[axis]
        dk, dc = polynomial.polyder(k), polynomial.polyder(c)
        linear = _newton(
            lambda y: y - polynomial.polyval(y / fs, k) * delta - polynomial.polyval(y / fs, c),
            lambda y: 1.0 - (polynomial.polyval(y / fs, dk) * delta +
                             polynomial.polyval(y / fs, dc)) / fs,
            sensed[:, axis], sensed[:, axis], fs)
        linear += chain.offset_rad_s[axis] + chain.offset_gradient_rad_s_per_c[axis] * delta
        p = chain.nonlinearity_rad_s[axis]
        dp = polynomial.polyder(p)
        measured[:, axis] = _newton(lambda m: polynomial.polyval(m / fs, p),
                                    lambda m: polynomial.polyval(m / fs, dp) / fs,
                                    linear, linear, fs)
    return measured


def simulate_turntable(protocol: TurntableProtocol = TurntableProtocol(),
                       truth: Optional[TurntableTruth] = None,
                       seed: Optional[int] = None) -> TurntableSession:
    """
    Simulate a calibration session; ``truth`` is drawn from ``seed`` when not given.

    Die temperature is the chamber set point plus white noise of
    ``temperature_noise_c`` (the gyro sees the temperature it reports).
    """
    rng = np.random.default_rng(seed)
    truth = TurntableTruth.random(rng) if truth is None else truth
    rate = protocol.sample_rate_hz
    eye = np.eye(3)
    targets = np.array([eye[axis] * level for axis in range(3)
                        for level in protocol.rate_levels_rad_s] +
                       [np.ones(3) * level for level in protocol.cross_axis_levels_rad_s])
    reference, plateau = _table_motion(targets, round(protocol.hold_s * rate),
                                       protocol.acceleration_rad_s2 / rate)
    hold = round(protocol.electronics_hold_s * rate)
    steps = len(protocol.electronics_temperatures_c)
    sessions = [(reference, plateau, np.full(len(reference), chamber_c), None)
                for chamber_c in protocol.chamber_temperatures_c]
    sessions.append((np.zeros((steps * hold, 3)), np.repeat(np.arange(steps), hold),
                     np.full(steps * hold, truth.reference_temperature_c),
                     np.repeat(protocol.electronics_temperatures_c, hold)))

    times, references, plateaus, chambers, electronics = [], [], [], [], []
    start_s, first_plateau = 0.0, 0
    for reference, plateau, chamber_c, electronics_c in sessions:
        time_s = start_s + np.arange(len(reference)) / rate
        if electronics_c is None:
            electronics_c = truth.reference_temperature_2_c + protocol.temperature_2_drift_c * \
                np.sin(2.0 * math.pi * time_s / protocol.temperature_2_period_s)
        times.append(time_s)
        references.append(reference)
        plateaus.append(np.where(plateau >= 0, plateau + first_plateau, -1))
        chambers.append(chamber_c)
        electronics.append(electronics_c)
        start_s = time_s[-1] + protocol.soak_s
        first_plateau += plateau.max() + 1

    reference = np.concatenate(references)
    samples = len(reference)
    temperature = np.concatenate(chambers) + \
        protocol.temperature_noise_c * rng.standard_normal(samples)
    temperature_2 = np.concatenate(electronics) + \
        protocol.temperature_noise_c * rng.standard_normal(samples)
    measured = _measured_rate(truth.chain(), reference, temperature, temperature_2) + \
        protocol.noise_rad_s * rng.standard_normal((samples, 3))
    return TurntableSession(time_s=np.concatenate(times), reference_rad_s=reference,
                            measured_rad_s=measured, temperature_c=temperature,
                            temperature_2_c=temperature_2, plateau_id=np.concatenate(plateaus),
                            truth=truth)
