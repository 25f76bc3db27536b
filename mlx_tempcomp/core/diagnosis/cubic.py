"""
The PX4-style cubic in the diagnosis: each fold's, run on its held-out bins, and the written one.

Each fold fits the cubic on its training blocks (`baseline.solve_cubic`, from
the blocks' normal equations) and runs it clamped at their range, as PX4
runs it, on the blocks it holds out: `baseline_run`, the incumbent every
other model is compared with fold by fold. The cubic an axis writes is
`baseline.fit_cubic` on every diagnosed row, carried in the problem's x
(`cubic_bias`).
"""

from dataclasses import dataclass
import math

import numpy as np

from .data import DiagnosisData
from .folds import Folds, weighted_rms
from ..fitting import PX4_ORDER


@dataclass(frozen=True)
class BaselineRun:
    """
    The PX4-style cubic of each fold, fitted on its training blocks and run clamped.

    ``residual`` (bins, axes) holds the held-out bins, NaN elsewhere;
    ``fold_rms`` (folds, axes) each fold's RMS over the bins it counts.
    """

    residual: np.ndarray
    fold_rms: np.ndarray
    errors: tuple


def baseline_run(data: DiagnosisData, folds: Folds) -> BaselineRun:
    """Fit the cubic on each fold's training blocks, run it on its held blocks (`BaselineRun`)."""
    axes = len(data.axes)
    residual = np.full((len(data.starts), axes), math.nan)
    fold_rms = np.full((folds.split.folds, axes), math.nan)
    for fold, (held, counted) in enumerate(zip(folds.split.held, folds.counted)):
        cubics = data.fold_cubics(folds.split.training[fold])
        for block in np.flatnonzero(held):
            residual[data.bin_block == block] = _block_residual(data, cubics, block)
        fold_rms[fold] = [weighted_rms(residual[counted, a], data.counts[counted])
                          for a in range(axes)]
    return BaselineRun(residual, fold_rms, tuple(data.error(residual[:, a], folds)
                                                 for a in range(axes)))


def _block_residual(data: DiagnosisData, cubics: tuple, block: int) -> np.ndarray:
    """Give the bin means of a block's residual under the cubics (its record's)."""
    rows = slice(data.block_edges[block], data.block_edges[block + 1])
    cubic = cubics[data.records.record_of(rows.start)]
    corrected = cubic.corrected(data.rate[rows], data.temperature[rows])
    if data.reference is not None:
        corrected = corrected - data.reference[rows]
    bins = data.bin_block == block
    return np.add.reduceat(corrected, data.starts[bins] - rows.start, axis=0) / \
        data.counts[bins][:, None]


def cubic_bias(cubic, axis: int, centre_c: float, scale_c: float) -> tuple:
    """
    Give a cubic's coefficients in x = (T - centre) / scale, lowest first.

    Exact where the centre is the cubic's TREF (scale a power of two): the
    written cubic; a fold's, fitted on part of the range, is re-expanded.
    """
    coefficients = cubic.coefficients[axis]
    if cubic.reference_c == centre_c:
        return tuple(c * scale_c ** k for k, c in enumerate(coefficients))
    polynomial = np.polynomial.Polynomial
    shifted = polynomial(coefficients)(polynomial((centre_c - cubic.reference_c, scale_c))).coef
    return tuple(float(c) for c in np.pad(shifted, (0, PX4_ORDER + 1 - shifted.size)))
