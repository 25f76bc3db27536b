"""
The baseline every model is judged against: PX4's thermal cubic, as PX4 fits and runs it.

PX4's ``Tools/process_sensor_caldata.py`` fits ``np.polyfit(T - TREF, rate, 3)``
per axis, TREF the middle of the fitted range TMIN..TMAX; the firmware
subtracts sum X_k (clamp(T, TMIN, TMAX) - TREF)^k from the raw rate. `fit_cubic`
is that fit, `ClampedCubic` that correction, and every place that compares
with the cubic or writes it (the validation folds, the test part, the report,
``fit``, the PX4 and ArduPilot exports, the fleet) goes through them.

A written cubic is an `EffectModel` (`ClampedCubic.effect_model`) whose
reference temperature is TREF and whose scale is a power of two: x = (clamp(T)
- TREF) / 2^k and the coefficients X_k 2^(jk) are then exact, and so is every
step of the polynomial's evaluation, so the node's output is, bit for bit,
the firmware's formula in float64 (`cubic_scale_c`).

Several records of one unit fit one cubic with a bias offset per record after
the first (a power cycle or a re-mount shifts the bias): the same least
squares with an indicator column per such record; `fit_cubic` gives the cubic
of each record.

Held-out folds fit the cubic on many unions of contiguous blocks: `cubic_sums`
sums each block's normal equations once (in Legendre polynomials of a common
x, well conditioned) and `solve_cubic` solves the same least squares for any
union of them, without a pass over the rows.
"""

from dataclasses import dataclass, replace
import math
from typing import Optional

import numpy as np
from numpy.polynomial import legendre as legendre_series, polynomial as power_series

from ..effects import EffectModel, polynomial_model
from ..errors import CalibrationError

PX4_ORDER = 3


def cubic_scale_c(low_c: float, high_c: float) -> float:
    """Give the power of two at or above the half span: x = (T - TREF) / scale in [-1, 1]."""
    half_span = 0.5 * (high_c - low_c)
    return 2.0 ** math.ceil(math.log2(half_span)) if half_span > 0.0 else 1.0


@dataclass(frozen=True)
class ClampedCubic:
    """
    PX4's cubic per axis: X0..X3 (lowest first) of (clamp(T, low, high) - TREF), rad/s.

    TREF is the middle of [``low_c``, ``high_c``], the fitted range.
    """

    low_c: float
    high_c: float
    coefficients: tuple

    @property
    def reference_c(self) -> float:
        return 0.5 * (self.low_c + self.high_c)

    def offset_rad_s(self, temperature_c) -> np.ndarray:
        """Give the cubic of each axis at each temperature, clamped: (rows, axes)."""
        relative = np.clip(np.asarray(temperature_c, dtype=np.float64), self.low_c,
                           self.high_c) - self.reference_c
        return np.column_stack([np.polyval(axis[::-1], relative) for axis in self.coefficients])

    def corrected(self, rate_rad_s, temperature_c) -> np.ndarray:
        """Give the raw rate (rows, axes) less the cubic, as the firmware corrects it."""
        return np.asarray(rate_rad_s, dtype=np.float64) - self.offset_rad_s(temperature_c)

    def effect_model(self) -> EffectModel:
        """Give the cubic as the node's polynomial model, the same numbers to the bit."""
        scale = cubic_scale_c(self.low_c, self.high_c)
        bias = tuple(tuple(c * scale ** k for k, c in enumerate(axis))
                     for axis in self.coefficients)
        return polynomial_model(bias, reference_temperature_c=self.reference_c,
                                temperature_scale_c=scale, temperature_min_c=self.low_c,
                                temperature_max_c=self.high_c)

    def shifted(self, offsets_rad_s) -> 'ClampedCubic':
        """Give the cubic with ``offsets_rad_s`` (one per axis) added to X0."""
        return replace(self, coefficients=tuple(
            (axis[0] + float(offset),) + axis[1:]
            for axis, offset in zip(self.coefficients, offsets_rad_s)))


@dataclass(frozen=True)
class CubicSums:
    """
    The normal equations of the cubic per block: Legendre P0..P3 of x = (T - centre) / scale.

    ``gram`` (blocks, 4, 4) and ``moment`` (blocks, 4, axes) sum each block's
    rows; ``low_c`` and ``high_c`` are each block's temperature range,
    ``record`` its record.
    """

    centre_c: float
    scale_c: float
    gram: np.ndarray
    moment: np.ndarray
    low_c: np.ndarray
    high_c: np.ndarray
    record: np.ndarray


def cubic_sums(temperature_c, values, bounds, centre_c: float, scale_c: float,
               record_of_block=None) -> CubicSums:
    """Sum the normal equations of each block of rows (``bounds``: block starts and the end)."""
    temperature = np.asarray(temperature_c, dtype=np.float64)
    data = np.asarray(values, dtype=np.float64)
    data = data.reshape(len(data), -1)
    grams, moments = [], []
    for first, last in zip(bounds[:-1], bounds[1:]):
        basis = np.polynomial.legendre.legvander((temperature[first:last] - centre_c) / scale_c,
                                                 PX4_ORDER)
        grams.append(basis.T @ basis)
        moments.append(basis.T @ data[first:last])
    starts = np.asarray(bounds[:-1])
    blocks = len(starts)
    return CubicSums(centre_c, scale_c, np.array(grams), np.array(moments),
                     np.minimum.reduceat(temperature, starts),
                     np.maximum.reduceat(temperature, starts),
                     np.zeros(blocks, dtype=np.int64) if record_of_block is None
                     else np.asarray(record_of_block))


def solve_cubic(sums: CubicSums, blocks: np.ndarray, records: int = 1) -> tuple:
    """
    Fit the cubic on the given blocks (a mask) from their sums; one `ClampedCubic` per record.

    The least squares `fit_cubic` solves on those rows, with an offset column
    per record after the first; its range is the blocks'. A record with no
    block among them gets offset 0.
    """
    used = np.asarray(blocks, dtype=bool)
    size = PX4_ORDER + 1
    gram = np.zeros((size + records - 1,) * 2)
    moment = np.zeros((size + records - 1, sums.moment.shape[2]))
    for block in np.flatnonzero(used):
        g, m, record = sums.gram[block], sums.moment[block], int(sums.record[block])
        gram[:size, :size] += g
        moment[:size] += m
        if record:
            column = size + record - 1
            # The record's indicator is 1 = P0 on its rows: its sums are P0's.
            gram[column, :size] += g[0]
            gram[:size, column] += g[0]
            gram[column, column] += g[0, 0]
            moment[column] += m[0]
    diagonal = np.sqrt(np.diag(gram))
    diagonal[diagonal == 0.0] = 1.0
    solution = np.linalg.lstsq(gram / np.outer(diagonal, diagonal), moment / diagonal[:, None],
                               rcond=1e-13)[0] / diagonal[:, None]
    low, high = float(np.min(sums.low_c[used])), float(np.max(sums.high_c[used]))
    cubic = ClampedCubic(low, high, tuple(
        _about_reference(solution[:size, axis], sums.centre_c, sums.scale_c, 0.5 * (low + high))
        for axis in range(solution.shape[1])))
    offsets = np.vstack([np.zeros(solution.shape[1]), solution[size:]])
    return tuple(cubic.shifted(offset) for offset in offsets)


def _about_reference(legendre: np.ndarray, centre_c: float, scale_c: float,
                     reference_c: float) -> tuple:
    """
    Give Legendre coefficients in x = (T - centre) / scale as powers of (T - reference).

    The steps of ``Polynomial(leg2poly(legendre))(Polynomial((a, b)))`` in numpy's own
    series functions, so the bits are its; without the Polynomial objects, whose
    construction cost the held-out folds' thousands of calls half their time.
    """
    powers = legendre_series.leg2poly(legendre)
    # Polynomial.__call__ maps the line through the default domain and window first.
    line = power_series.polyadd(0.0, power_series.polymul(
        1.0, ((reference_c - centre_c) / scale_c, 1.0 / scale_c)))
    shifted = power_series.polyadd(powers[-1], power_series.polymul(line, 0))   # Horner
    for index in range(2, len(powers) + 1):
        shifted = power_series.polyadd(powers[-index], power_series.polymul(shifted, line))
    return tuple(float(c) for c in np.pad(shifted, (0, PX4_ORDER + 1 - shifted.size)))


def fit_cubic(temperature_c, values, record: Optional[np.ndarray] = None,
              records: int = 1) -> tuple:
    """
    Fit PX4's cubic to ``values`` (rows,) or (rows, axes); give one `ClampedCubic` per record.

    ``record`` gives each row's record (0 .. ``records`` - 1); with one record
    the fit is ``np.polyfit(T - TREF, values[:, axis], 3)``, axis by axis, as
    PX4's script does. With several, each record after the first has an
    offset column beside the cubic's; the cubics of the records differ in X0.
    Raise CalibrationError when the temperatures are not finite or do not move.
    """
    temperature = np.asarray(temperature_c, dtype=np.float64)
    data = np.asarray(values, dtype=np.float64)
    data = data.reshape(len(data), -1)
    if temperature.size == 0 or not np.all(np.isfinite(temperature)):
        msg = 'the PX4-style cubic needs finite temperatures'
        raise CalibrationError(msg)
    low, high = float(np.min(temperature)), float(np.max(temperature))
    if high <= low:
        msg = f'the PX4-style cubic needs the temperature to move, all rows are at {low:.2f} C'
        raise CalibrationError(msg)
    relative = temperature - 0.5 * (low + high)
    if records == 1:
        # full=True: the same solution, without the RankWarning a fold whose rows hold few
        # temperatures raises (the cubic there is what PX4's script would fit, as poor).
        coefficients = tuple(
            tuple(float(c) for c in np.polyfit(relative, data[:, axis], PX4_ORDER,
                                               full=True)[0][::-1])
            for axis in range(data.shape[1]))
        return (ClampedCubic(low, high, coefficients),)
    return _with_offsets(relative, data, np.asarray(record), records, low, high)


def _with_offsets(relative: np.ndarray, data: np.ndarray, record: np.ndarray, records: int,
                  low: float, high: float) -> tuple:
    """np.polyfit's least squares (columns scaled to unit norm) with a column per record > 0."""
    design = np.column_stack([np.vander(relative, PX4_ORDER + 1),
                              (record[:, None] == np.arange(1, records)[None, :])])
    design = design.astype(np.float64)
    norms = np.sqrt(np.sum(design * design, axis=0))
    norms[norms == 0.0] = 1.0
    solution = np.linalg.lstsq(design / norms, data, rcond=len(relative) *
                               np.finfo(np.float64).eps)[0] / norms[:, None]
    cubic = ClampedCubic(low, high, tuple(tuple(float(c) for c in solution[PX4_ORDER::-1, axis])
                                          for axis in range(data.shape[1])))
    offsets = np.vstack([np.zeros(data.shape[1]), solution[PX4_ORDER + 1:]])
    return tuple(cubic.shifted(offset) for offset in offsets)
