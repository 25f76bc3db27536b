"""
Interpolation of ZRO(TEMPOUT) and SF(TEMPOUT) between three calibration triplets.

AN2 section 4 names step, linear, piecewise-linear and second-order polynomial
interpolation and gives the polynomial in closed form, formulas (3)-(13).
"""

import enum

import numpy as np

from ..errors import ConfigError


class Interpolation(str, enum.Enum):
    """How a value is interpolated between the triplets TC0..TC2."""

    QUADRATIC = 'quadratic'                # AN2 formulas (3)-(13)
    PIECEWISE_LINEAR = 'piecewise_linear'  # straight segments through all three triplets
    LINEAR = 'linear'                      # one line through the outer triplets (TC0, TC2)
    STEP = 'step'                          # value of the nearest triplet

    @classmethod
    def parse(cls, value: str) -> 'Interpolation':
        try:
            return cls(value)
        except ValueError:
            names = ', '.join(m.value for m in cls)
            msg = f'interpolation must be one of {names}, got {value!r}'
            raise ConfigError(msg) from None


def check_triplets(tc, values) -> tuple:
    """Validate and return (tc, values) as float arrays of three distinct abscissae."""
    tc = np.asarray(tc, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if tc.shape != (3,) or values.shape != (3,):
        msg = f'need three triplets, got TC of shape {tc.shape} and values of {values.shape}'
        raise ConfigError(msg)
    if not (np.all(np.isfinite(tc)) and np.all(np.isfinite(values))):
        msg = f'triplets must be finite, got TC={tc.tolist()} values={values.tolist()}'
        raise ConfigError(msg)
    if not (tc[0] < tc[1] < tc[2]):
        msg = f'TC0 < TC1 < TC2 is required, got TC={tc.tolist()}'
        raise ConfigError(msg)
    return tc, values


def quadratic_coefficients(tc, values) -> tuple:
    """
    Return (A, B, C) of value(x) = A x^2 + B x + C through the three triplets.

    AN2 formulas (5)-(13), with T0 = TC2 - TC1, T1 = TC0 - TC2, T2 = TC1 - TC0.
    """
    (tc0, tc1, tc2), (v0, v1, v2) = check_triplets(tc, values)
    t0 = tc2 - tc1
    t1 = tc0 - tc2
    t2 = tc1 - tc0
    denominator = t0 * t1 * t2
    a = -(v0 * t0 + v1 * t1 + v2 * t2) / denominator
    b = (v0 * t0 * (tc1 + tc2) + v1 * t1 * (tc0 + tc2) + v2 * t2 * (tc1 + tc0)) / denominator
    c = -(v0 * t0 * tc1 * tc2 + v1 * t1 * tc0 * tc2 + v2 * t2 * tc0 * tc1) / denominator
    return a, b, c


def interpolate(method: Interpolation, tc, values, x) -> np.ndarray:
    """
    Evaluate the interpolation of ``values`` over ``tc`` at ``x``.

    ``x`` is used as given: clamping to [TC0, TC2] is the caller's decision.
    """
    tc, values = check_triplets(tc, values)
    x = np.asarray(x, dtype=np.float64)
    if method is Interpolation.QUADRATIC:
        a, b, c = quadratic_coefficients(tc, values)
        return (a * x + b) * x + c
    if method is Interpolation.PIECEWISE_LINEAR:
        slopes = np.diff(values) / np.diff(tc)
        segment = (x > tc[1]).astype(np.intp)
        return values[segment] + slopes[segment] * (x - tc[segment])
    if method is Interpolation.LINEAR:
        slope = (values[2] - values[0]) / (tc[2] - tc[0])
        return values[0] + slope * (x - tc[0])
    if method is Interpolation.STEP:
        boundaries = 0.5 * (tc[:-1] + tc[1:])
        return values[np.searchsorted(boundaries, x, side='right')]
    msg = f'unknown interpolation {method!r}'
    raise ConfigError(msg)
