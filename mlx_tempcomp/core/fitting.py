"""
Least-squares bias models of temperature, the polynomial order chosen by cross-validation.

PX4 and ArduPilot fit a fixed cubic with ``np.polyfit`` on the temperature as
measured. Here the order is chosen from the data, and the fit runs in float64
on x = (T - centre) / half_span of the data's temperature range, so x lies in
[-1, 1] and orders well above 5 keep every term (the MPU-6000 note loses the
terms above order 5 to single precision on raw temperature).

Besides the plain polynomial: `relative_polynomial`, the MPU-6000 note's
correction rate - (p(T) - p(T_true)), and `fit_linear_btc`, the ADIS16130
note's first-order RBC = RATE + PBC + (TEMP - T3) x BTC.
"""

from dataclasses import dataclass, replace
import math
import operator

import numpy as np

from .errors import CalibrationError
from .models import AXIS_NAMES, LinearBtcModel, PolynomialModel

MIN_SPAN_C = 1.0
DISTINCT_DECIMALS = 2
ONE_SE_RULE = 'one-standard-error'


@dataclass(frozen=True)
class OrderScore:
    """Held-out RMS residual of one polynomial order, per block and summarised."""

    order: int
    block_rms_rad_s: tuple
    mean_rms_rad_s: float
    standard_error_rad_s: float


@dataclass(frozen=True)
class OrderSelection:
    """Order chosen for one axis, every score it was chosen from, and the rule used."""

    axis: str
    order: int
    scores: tuple
    rule: str


def contiguous_blocks(samples: int, count: int) -> tuple:
    """Split indices 0..samples-1 into `count` contiguous, near-equal index arrays."""
    samples = operator.index(samples)
    count = operator.index(count)
    if count < 2:
        msg = f'cross-validation needs at least 2 blocks, got {count}'
        raise CalibrationError(msg)
    if samples < count:
        msg = f'cannot split {samples} samples into {count} blocks'
        raise CalibrationError(msg)
    return tuple(np.array_split(np.arange(samples), count))


def _fit_inputs(temperature_c, rate_rad_s) -> tuple:
    temperature = np.asarray(temperature_c, dtype=np.float64)
    rate = np.asarray(rate_rad_s, dtype=np.float64)
    if rate.ndim == 1:
        rate = rate[:, None]
    if temperature.ndim != 1 or rate.ndim != 2 or rate.shape[0] != temperature.shape[0]:
        msg = (f'temperature must have shape (samples,) and rate (samples,) or '
               f'(samples, axes); got {np.shape(temperature_c)} and {np.shape(rate_rad_s)}')
        raise CalibrationError(msg)
    if not 1 <= rate.shape[1] <= len(AXIS_NAMES):
        msg = f'rate must have 1 to {len(AXIS_NAMES)} axes, got {rate.shape[1]}'
        raise CalibrationError(msg)
    if temperature.size == 0:
        msg = 'no samples to fit'
        raise CalibrationError(msg)
    bad = np.count_nonzero(~np.isfinite(temperature)) + np.count_nonzero(~np.isfinite(rate))
    if bad:
        msg = f'calibration data has {bad} non-finite temperature or rate values'
        raise CalibrationError(msg)
    return temperature, rate


def _axis_orders(orders, axes: int) -> tuple:
    values = (orders,) * axes if np.ndim(orders) == 0 else tuple(orders)
    if len(values) != axes:
        msg = f'orders needs one value per axis ({axes}), got {len(values)}'
        raise CalibrationError(msg)
    try:
        values = tuple(operator.index(order) for order in values)
    except TypeError:
        msg = f'polynomial orders must be integers, got {orders!r}'
        raise CalibrationError(msg) from None
    if min(values) < 0:
        msg = f'polynomial orders must be non-negative, got {list(values)}'
        raise CalibrationError(msg)
    return values


def fit_polynomial(temperature_c, rate_rad_s, orders) -> PolynomialModel:
    """
    Fit a bias polynomial per axis by least squares in float64.

    temperature_c has shape (samples,), rate_rad_s (samples,) or (samples, axes),
    orders is one int for every axis or one per axis. The model works in
    x = (T - centre) / half_span of the data's temperature range and clamps to
    that range. Raise CalibrationError when the data cannot support an order.
    """
    temperature, rate = _fit_inputs(temperature_c, rate_rad_s)
    axis_orders = _axis_orders(orders, rate.shape[1])
    highest = max(axis_orders)
    distinct = np.unique(np.round(temperature, DISTINCT_DECIMALS)).size
    if distinct < highest + 1:
        msg = (f'order {highest} needs at least {highest + 1} distinct temperatures '
               f'(rounded to 0.01 C), the data has {distinct}')
        raise CalibrationError(msg)
    low_c = float(np.min(temperature))
    high_c = float(np.max(temperature))
    span_c = high_c - low_c
    if highest >= 1 and span_c < MIN_SPAN_C:
        msg = (f'order {highest} needs a temperature span of at least {MIN_SPAN_C} C, '
               f'the data spans {span_c:.3g} C ({low_c:.2f} to {high_c:.2f} C)')
        raise CalibrationError(msg)
    if span_c == 0.0:
        msg = (f'all temperatures equal {low_c:.2f} C; the model needs '
               'temperature_min_c below temperature_max_c')
        raise CalibrationError(msg)
    centre_c = 0.5 * (low_c + high_c)
    half_span_c = 0.5 * span_c
    vandermonde = np.polynomial.polynomial.polyvander((temperature - centre_c) / half_span_c,
                                                      highest)
    coefficients = []
    for axis, order in enumerate(axis_orders):
        solution, _, rank, _ = np.linalg.lstsq(vandermonde[:, :order + 1], rate[:, axis],
                                               rcond=None)
        if rank < order + 1:
            msg = (f'axis {AXIS_NAMES[axis]}: the temperatures cannot determine an order '
                   f'{order} polynomial (design matrix rank {rank})')
            raise CalibrationError(msg)
        coefficients.append(tuple(solution))
    return PolynomialModel(bias_coefficients=tuple(coefficients),
                           reference_temperature_c=centre_c, temperature_scale_c=half_span_c,
                           temperature_min_c=low_c, temperature_max_c=high_c)


def fold_rows(samples: int, blocks: int, folds: int) -> tuple:
    """
    Give the held-out rows of each fold: contiguous blocks dealt round-robin to folds.

    Fold k holds out blocks k, k + folds, k + 2 folds, ... With more blocks
    than folds, training data surrounds every held-out block, so a single
    thermal cycle's extremes are not extrapolated.
    """
    if not 2 <= folds <= blocks:
        msg = f'cross-validation needs 2 <= folds <= blocks, got {folds} folds, {blocks} blocks'
        raise CalibrationError(msg)
    splits = contiguous_blocks(samples, blocks)
    return tuple(np.concatenate(splits[fold::folds]) for fold in range(folds))


def _held_out_rms_rad_s(temperature, rate, held_out: tuple, order: int) -> np.ndarray:
    """Return the held-out RMS per fold (rows) and axis (columns), inf if unsupported."""
    rms = np.full((len(held_out), rate.shape[1]), math.inf)
    for index, block in enumerate(held_out):
        train = np.setdiff1d(np.arange(temperature.size), block, assume_unique=True)
        try:
            model = fit_polynomial(temperature[train], rate[train], order)
        except CalibrationError:
            continue
        residual = model.correct(rate[block], temperature[block]).rate_rad_s
        rms[index] = np.sqrt(np.mean(np.square(residual), axis=0))
    return rms


def select_orders(temperature_c, rate_rad_s, axes=None, candidate_orders=range(0, 9),
                  blocks: int = 20, folds: int = 5) -> tuple:
    """
    Choose the bias polynomial order per axis by contiguous-block cross-validation.

    The record is cut into ``blocks`` contiguous blocks dealt round-robin to
    ``folds`` folds (`fold_rows`). Each candidate order is fitted on all folds
    but one and scored by the RMS of the corrected rate (through
    PolynomialModel.correct, so clamping acts as in the node) on the held-out
    fold. Blocks are contiguous because neighbouring samples are correlated.
    The chosen order is the lowest whose mean held-out RMS is within one
    standard error of the best; orders the training data cannot support
    score inf and are never chosen.
    """
    temperature, rate = _fit_inputs(temperature_c, rate_rad_s)
    names = AXIS_NAMES[:rate.shape[1]] if axes is None else tuple(axes)
    if len(names) != rate.shape[1]:
        msg = f'{len(names)} axis names given for {rate.shape[1]} rate columns'
        raise CalibrationError(msg)
    candidates = tuple(candidate_orders)
    if not candidates:
        msg = 'no candidate orders given'
        raise CalibrationError(msg)
    orders = sorted(set(_axis_orders(candidates, len(candidates))))
    held_out = fold_rows(temperature.size, blocks, folds)
    block_rms = {order: _held_out_rms_rad_s(temperature, rate, held_out, order)
                 for order in orders}
    selections = []
    for axis, name in enumerate(names):
        scores = tuple(_score(order, block_rms[order][:, axis]) for order in orders)
        best = min(scores, key=lambda score: score.mean_rms_rad_s)
        if not math.isfinite(best.mean_rms_rad_s):
            msg = (f'axis {name}: the data cannot support any of the orders {orders} '
                   f'in {folds}-fold cross-validation')
            raise CalibrationError(msg)
        threshold = best.mean_rms_rad_s + best.standard_error_rad_s
        chosen = next(score.order for score in scores if score.mean_rms_rad_s <= threshold)
        rule = (f'{ONE_SE_RULE}: lowest order whose mean held-out RMS over {folds} '
                f'folds of {blocks} contiguous blocks is within one standard error of the '
                f'best (order {best.order})')
        selections.append(OrderSelection(axis=name, order=chosen, scores=scores, rule=rule))
    return tuple(selections)


def _score(order: int, block_rms_rad_s: np.ndarray) -> OrderScore:
    if not np.all(np.isfinite(block_rms_rad_s)):
        return OrderScore(order, tuple(float(v) for v in block_rms_rad_s), math.inf, math.inf)
    standard_error = np.std(block_rms_rad_s, ddof=1) / math.sqrt(block_rms_rad_s.size)
    return OrderScore(order, tuple(float(v) for v in block_rms_rad_s),
                      float(np.mean(block_rms_rad_s)), float(standard_error))


def format_order_table(selections) -> str:
    """Return a table of every order's held-out RMS per axis, the chosen order marked."""
    header = ('axis', 'order', 'mean held-out RMS (deg/s)', 'standard error (deg/s)', 'chosen')
    rows = []
    for selection in selections:
        for score in selection.scores:
            if math.isfinite(score.mean_rms_rad_s):
                mean_text = f'{math.degrees(score.mean_rms_rad_s):.4e}'
                error_text = f'{math.degrees(score.standard_error_rad_s):.2e}'
            else:
                mean_text = 'unsupported'
                error_text = '-'
            rows.append((selection.axis, str(score.order), mean_text, error_text,
                         '*' if score.order == selection.order else ''))
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    lines = ['  '.join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip()
             for row in (header, *rows)]
    lines.extend(f'{selection.axis}: {selection.rule}' for selection in selections)
    return '\n'.join(lines)


def relative_polynomial(model: PolynomialModel, true_temperature_c: float) -> PolynomialModel:
    """
    Shift each bias polynomial so that it is zero at ``true_temperature_c`` (seed 002).

    The MPU-6000 note corrects gyro - (p(T) - p(T_true)), T_true being the
    temperature at which no bias is introduced. That is a polynomial model whose
    constant term is lowered by p(T_true), so the compensation node runs it as
    it runs any polynomial. Raise CalibrationError when T_true lies outside the
    fitted temperature range (p would be extrapolated there).
    """
    true_c = float(true_temperature_c)
    if not model.temperature_min_c <= true_c <= model.temperature_max_c:
        msg = (f'true temperature {true_c:g} C is outside the fitted range '
               f'{model.temperature_min_c:.2f} to {model.temperature_max_c:.2f} C, '
               'where the polynomial would be extrapolated')
        raise CalibrationError(msg)
    x = (true_c - model.reference_temperature_c) / model.temperature_scale_c
    shifted = tuple((c[0] - np.polynomial.polynomial.polyval(x, c),) + c[1:]
                    for c in model.bias_coefficients)
    return replace(model, bias_coefficients=shifted)


def fit_linear_btc(temperature_c, rate_rad_s, t3_c=None) -> LinearBtcModel:
    """
    Fit the ADIS16130 note's first-order bias correction per axis by least squares.

    The line bias(T) = B3 + slope (T - T3) is fitted in float64 on
    (T - T3) / half_span; BTC = -slope and PBC = -B3, the signs of the note's
    Table 6 (RBC = RATE + PBC + (TEMP - T3) x BTC). T3 defaults to the mean
    temperature of the data. Raise CalibrationError when the temperatures
    span less than MIN_SPAN_C.
    """
    temperature, rate = _fit_inputs(temperature_c, rate_rad_s)
    t3 = float(np.mean(temperature)) if t3_c is None else float(t3_c)
    if not math.isfinite(t3):
        msg = f'T3 must be finite, got {t3}'
        raise CalibrationError(msg)
    low_c = float(np.min(temperature))
    high_c = float(np.max(temperature))
    if high_c - low_c < MIN_SPAN_C:
        msg = (f'a bias slope needs a temperature span of at least {MIN_SPAN_C} C, the data '
               f'spans {high_c - low_c:.3g} C ({low_c:.2f} to {high_c:.2f} C)')
        raise CalibrationError(msg)
    half_span_c = 0.5 * (high_c - low_c)
    design = np.polynomial.polynomial.polyvander((temperature - t3) / half_span_c, 1)
    solution = np.linalg.lstsq(design, rate, rcond=None)[0]
    return LinearBtcModel(pbc_rad_s=tuple(-solution[0]),
                          btc_rad_s_per_c=tuple(-solution[1] / half_span_c), t3_c=t3)


def table_step_c(extent_c: float, rows_each_side: int) -> float:
    """Return the smallest 1, 2 or 5 x 10^k step that reaches ``extent_c`` in so many rows."""
    if not (math.isfinite(extent_c) and extent_c > 0.0) or rows_each_side < 1:
        msg = f'a table needs a positive extent and rows, got {extent_c} C, {rows_each_side}'
        raise CalibrationError(msg)
    raw = extent_c / rows_each_side
    decade = 10.0 ** math.floor(math.log10(raw))
    return next(m * decade for m in (1.0, 2.0, 5.0, 10.0) if m * decade >= raw * (1 - 1e-12))


def format_btc_table(model: LinearBtcModel, axes, step_c: float, rows_each_side: int = 6) -> str:
    """
    Return the ADIS16130 note's Table 6 for the model: (TEMP - T3) and (TEMP - T3) x BTC.

    Rows run from +rows_each_side to -rows_each_side steps of ``step_c``; the
    columns after the first give the correction in deg/s per axis, as the note
    prints it.
    """
    def text(value: float, digits: int) -> str:
        return '0' if value == 0.0 else f'{value:+.{digits}g}'

    header = ('TEMP - T3 (C)', *(f'{axis} (deg/s)' for axis in axes))
    rows = []
    for k in range(rows_each_side, -rows_each_side - 1, -1):
        offset_c = k * step_c
        rows.append((text(offset_c, 6), *(text(math.degrees(offset_c * btc), 4)
                                          for btc in model.btc_rad_s_per_c)))
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    return '\n'.join('  '.join(cell.rjust(width) for cell, width in zip(row, widths))
                     for row in (header, *rows))
