"""
A simulated unit from one day to the next: its bias(T) moves as real parts' does.

Day 1 is the unit as `GyroTruth.random` drew it (what ``mlx-tempcomp simulate`` gives
without ``--day``). Each later day, drawn from the unit's seed alone (the same unit and
day give the same change, whatever else is asked):

- **repeatability**: an offset of the zero-rate output, drawn afresh each day (1 sigma
  ``repeatability_dps``): a power cycle does not come back to the same bias;
- **ageing**: the slope, curvature and cubic term of ZRO(T) walk a step a day (1 sigma
  ``ageing_dps_per_c``, ``_c2``, ``_c3``): the shape of the curve moves, and an offset
  cannot follow a shape;
- **a turn**: the unit is mounted on another face each day (one of six, the first on day
  1), so gravity falls on other axes; with g-sensitivity (``acceleration_dps_per_m_s2``)
  each axis's bias changes with it;
- the noise and the bias instability are drawn afresh each day.
"""

from dataclasses import dataclass

import numpy as np

# The faces a unit can lie on, in `toolkit.simulate`'s order (z up first).
FACES = 6
_DAY_STREAM = 0x5EED_DA7


@dataclass(frozen=True)
class DayToDay:
    """The 1-sigma change of one day, per axis (see the module notes); deg/s and degC."""

    repeatability_dps: float = 0.1
    ageing_dps_per_c: float = 0.005
    ageing_dps_per_c2: float = 5e-5
    ageing_dps_per_c3: float = 5e-7


@dataclass(frozen=True)
class DayChange:
    """What day ``day`` changes: per axis the ZRO coefficients added, and the face it lies on."""

    day: int
    zro_dps_coefficients: tuple
    face: int


def day_change(seed: int, axes: int, day: int, spread: DayToDay = DayToDay()) -> DayChange:
    """
    Give the change of ``day`` (1: none) of the unit of ``seed`` with ``axes`` chips.

    The ZRO change of an axis is today's repeatability offset plus the ageing steps of
    every day since day 1, lowest order first, in (die temperature - 25 C).
    """
    if day < 1:
        raise ValueError(f'days count from 1, got {day}')
    if day == 1:
        return DayChange(1, ((0.0,) * 4,) * axes, 0)
    change = []
    steps = np.array([spread.ageing_dps_per_c, spread.ageing_dps_per_c2,
                      spread.ageing_dps_per_c3])
    for axis in range(axes):
        rng = np.random.default_rng([_DAY_STREAM, seed, axis])
        # Every day's draws, in order, so day N's are the same whatever day is asked.
        draws = rng.standard_normal((day - 1, 4))
        ageing = (draws[:, 1:] * steps).sum(axis=0)
        change.append((float(draws[-1, 0] * spread.repeatability_dps),)
                      + tuple(float(v) for v in ageing))
    face = int(np.random.default_rng([_DAY_STREAM, seed, day]).integers(FACES))
    return DayChange(day, tuple(change), face)


def noise_seed(seed: int, axis: int, day: int) -> list:
    """Give the seed of one chip's noise on ``day`` (day 1: None, the unit's own)."""
    return None if day == 1 else [_DAY_STREAM, seed, axis, day, 1]
