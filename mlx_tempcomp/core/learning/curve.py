"""
The learnt correction of one axis: a Kalman filter on a level and a shape over temperature.

The correction to the prior model is c(T) = a + s(T): ``a`` a level common to every
temperature, s(T) a shape given at the knots T_k (cubic between them, held beyond the
ends: `core.node_models.correction.knot_weights`). The state is x = (a, s_0 .. s_n-1), a fixed size
whatever the running time, with its covariance P:

- **Prior.** x ~ N(0, P0): the prior model is right on average. The level is the
  correction at the middle knot, its standard deviation ``level_std_rad_s`` (ten times
  the model's own error: an offset seen at one temperature is an offset at all); the shape
  is a random walk in temperature from there (`prior_covariance`), its steps set by the
  model's own error (``prior_std_rad_s``) and the correlation length. Between two rests
  the renewed curve goes straight from one to the other; beyond the last one it is held
  (the prior's shape, moved by the offset learnt at the edge), as PX4 clamps its cubic.
- **Time.** Between windows the level walks as the tracker's offset does (variance q dt,
  q = ``random_walk_rad_s_rt_s`` squared: the bias wanders), and the shape fades back to
  the prior as a first-order Gauss-Markov process with the time constant ``fading_s``:
  s -> f s, P_ss -> f^2 P_ss + (1 - f^2) P0_ss, f = exp(-dt / fading_s). Old windows
  fade, so an ageing curve is followed; where nothing comes for long, it is the prior.
- **A window** is a measurement of c at its mean temperature: the offset it measures
  relative to the prior model, with the variance of its mean (noise^2 / samples) plus the
  random walk over one window. The windows of one still run share its wander: at its
  first window the level widens by that variance once more, so a run's level counts as
  no better known than one window's, however long the run. An innovation beyond
  ``gate`` standard deviations counts as if it were at the gate (Huber): no one window
  moves the curve by more than that.

Every operation is numpy on small arrays in a fixed order: the same windows in the same
order give the same bits, whether the samples came in blocks or one by one.
"""

import math
from typing import Optional

import numpy as np

from ..node_models import knot_weights


def prior_covariance(knots_c: tuple, prior_std_rad_s: tuple, level_std_rad_s: float,
                     correlation_c: float) -> np.ndarray:
    """
    Give P0 of one axis: the level (at the middle knot), then the shape at each knot.

    The shape is a random walk in temperature out from the middle knot (where it is 0):
    between two knots it moves with the variance 2 sigma^2 dT / correlation (sigma the
    prior's standard deviation there), so the model's error changes by about sigma
    sqrt(2) over the correlation length. Its covariance is then the variance two knots
    share on one side of the middle, none across it.
    """
    knots = np.asarray(knots_c, dtype=np.float64)
    std = np.asarray(prior_std_rad_s, dtype=np.float64)
    count = knots.size
    middle = count // 2
    step = 2.0 * (0.5 * (std[1:] + std[:-1])) ** 2 * np.diff(knots) / correlation_c
    spread = np.zeros(count)
    spread[middle + 1:] = np.cumsum(step[middle:])
    spread[:middle] = np.cumsum(step[:middle][::-1])[::-1]
    side = np.sign(np.arange(count) - middle)
    covariance = np.zeros((count + 1, count + 1))
    covariance[0, 0] = level_std_rad_s * level_std_rad_s
    covariance[1:, 1:] = np.where(side[:, None] * side[None, :] > 0,
                                  np.minimum(spread[:, None], spread[None, :]), 0.0)
    return covariance


def observation(knots_c: tuple, temperature_c: float) -> np.ndarray:
    """Give h with c(T) = h . x: 1 for the level, the table's weights at T for the shape."""
    h = np.zeros(len(knots_c) + 1)
    h[0] = 1.0
    for index, weight in knot_weights(knots_c, float(temperature_c)):
        h[1 + index] += weight
    return h


class CurveFilter:
    """The state (level, shape) of one axis and its covariance; see the module notes."""

    def __init__(self, prior: np.ndarray, mean: Optional[np.ndarray] = None,
                 covariance: Optional[np.ndarray] = None, time_s: Optional[float] = None):
        self.prior = prior
        self.mean = np.zeros(prior.shape[0]) if mean is None else np.array(mean, dtype=float)
        self.covariance = prior.copy() if covariance is None else \
            np.array(covariance, dtype=float)
        self.time_s = time_s

    def copy(self) -> 'CurveFilter':
        return CurveFilter(self.prior, self.mean.copy(), self.covariance.copy(), self.time_s)

    def curve(self) -> np.ndarray:
        """Give the correction at each knot: the level plus the shape there."""
        return self.mean[0] + self.mean[1:]

    def predict(self, time_s: float, random_walk_rad_s_rt_s: float, fading_s: float) -> None:
        """
        Carry the state to ``time_s``: the level walks, the shape fades to the prior.

        A time before the last (a clock that went back: a restart, a replay) is a new
        session: the level is unknown again (its prior variance added), the shape kept.
        """
        if self.time_s is None:
            self.time_s = time_s
            return
        elapsed = time_s - self.time_s
        if elapsed < 0.0:
            self.covariance[0, 0] += self.prior[0, 0]
            self.time_s = time_s
            return
        fade = math.exp(-elapsed / fading_s) if math.isfinite(fading_s) else 1.0
        if fade != 1.0:
            self.mean[1:] *= fade
            self.covariance[1:, 1:] = fade * fade * self.covariance[1:, 1:] + \
                (1.0 - fade * fade) * self.prior[1:, 1:]
            self.covariance[0, 1:] *= fade
            self.covariance[1:, 0] *= fade
        self.covariance[0, 0] += random_walk_rad_s_rt_s * random_walk_rad_s_rt_s * elapsed
        self.time_s = time_s

    def forget_level(self, variance: Optional[float] = None) -> None:
        """Widen the level by ``variance`` (None: its prior's, as if unknown again)."""
        self.covariance[0, 0] += self.prior[0, 0] if variance is None else variance

    def update(self, h: np.ndarray, value: float, variance: float, gate: float) -> float:
        """
        Take one measurement ``value`` = h . x + noise of ``variance``; give its weight.

        The weight is 1, or less when the innovation is beyond ``gate`` standard
        deviations (it then counts as one at the gate).
        """
        spread = self.covariance @ h
        predicted = float(h @ spread) + variance
        innovation = value - float(h @ self.mean)
        weight = 1.0
        if innovation * innovation > gate * gate * predicted:
            widened = innovation * innovation / (gate * gate)
            weight = predicted / widened
            predicted = widened
        gain = spread / predicted
        self.mean += gain * innovation
        self.covariance -= np.outer(gain, spread)
        self.covariance = 0.5 * (self.covariance + self.covariance.T)
        return weight

    def curve_variance(self, covariance: Optional[np.ndarray] = None) -> np.ndarray:
        """Give the variance of the correction (level plus shape) at each knot."""
        p = self.covariance if covariance is None else covariance
        return np.maximum(p[0, 0] + 2.0 * p[0, 1:] + np.diag(p)[1:], 0.0)
