"""
Least-squares bias models of temperature, the polynomial order chosen by held-out blocks.

PX4 and ArduPilot fit a fixed cubic with ``np.polyfit`` on the temperature as
measured. Here the cubic is the incumbent and another order is taken only
when it beats the cubic fold by fold on held-out blocks; the fit runs in
float64 on x = (T - centre) / scale, scale the power of two at or above the
half span of the data's temperature range, so x lies in [-1, 1] and orders
well above 5 keep every term (the MPU-6000 note loses the terms above order 5
to single precision on raw temperature). Order 3 is PX4's cubic itself
(`baseline.fit_cubic`), to the bit.

Besides the plain polynomial: `relative_polynomial`, the MPU-6000 note's
correction rate - (p(T) - p(T_true)), and `fit_linear_btc`, the ADIS16130
note's first-order RBC = RATE + PBC + (TEMP - T3) x BTC.
"""

from dataclasses import dataclass, replace
import math
import operator

import numpy as np

from .baseline import cubic_scale_c, CubicSums, fit_cubic, PX4_ORDER, solve_cubic
from .validation import (BASELINE_MARGIN, block_bounds, cubic_instead, DEFAULT_BLOCKS,
                         DEFAULT_FOLDS, DEFAULT_MIN_PAST, DEFAULT_SIGNIFICANCE,
                         DEFAULT_VALIDATION, FORWARD,
                         one_standard_error, order_score, paired, split)
from ..effects import EffectModel, LinearBtc, polynomial_model
from ..errors import CalibrationError
from ..node_models import AXIS_NAMES

MIN_SPAN_C = 1.0
BASELINE_RULE = ('the PX4-style cubic unless another order beats it on held-out blocks, fold '
                 'by fold and by the margin')
DISTINCT_DECIMALS = 2
# Rows per chunk of the normal equations: 2^18 rows of an order-8 basis are 19 MB.
CHUNK_ROWS = 1 << 18
# Gram singular values this far below the largest are rounding, not data.
GRAM_RCOND = 1e-13


@dataclass(frozen=True)
class OrderSelection:
    """Order chosen for one axis, every score it was chosen from, and the rule used."""

    axis: str
    order: int
    scores: tuple
    rule: str


def contiguous_blocks(samples: int, count: int) -> tuple:
    """Split indices 0..samples-1 into `count` contiguous, near-equal index arrays."""
    bounds = block_bounds(samples, count)
    return tuple(np.arange(first, last) for first, last in zip(bounds[:-1], bounds[1:]))


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
    bad = (temperature.size - np.count_nonzero(np.isfinite(temperature))
           + rate.size - np.count_nonzero(np.isfinite(rate)))
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


@dataclass(frozen=True)
class _Moments:
    """
    Least-squares summary of some rows: all a fit of order <= the basis order needs.

    gram and moment are the normal equations of the Legendre basis
    P_0..P_order in x = (T - centre) / half_span, one x for every block of a
    record, so blocks add up. distinct holds the rows' temperatures rounded to
    DISTINCT_DECIMALS: all of them, or at least order + 1 (all support needs).
    """

    rows: int
    low_c: float
    high_c: float
    distinct: np.ndarray
    gram: np.ndarray
    moment: np.ndarray


def _scaling(low_c: float, high_c: float) -> tuple:
    """Return (centre, scale) of a temperature range: the scale a power of two (1 for a point)."""
    return 0.5 * (low_c + high_c), cubic_scale_c(low_c, high_c)


def _chunks(start: int, stop: int):
    for first in range(start, stop, CHUNK_ROWS):
        yield first, min(first + CHUNK_ROWS, stop)


def _moments(temperature, rate, rows: slice, scaling: tuple, order: int) -> _Moments:
    """Accumulate the `_Moments` of temperature[rows], CHUNK_ROWS rows at a time."""
    centre_c, half_span_c = scaling
    gram = np.zeros((order + 1, order + 1))
    moment = np.zeros((order + 1, rate.shape[1]))
    distinct = np.empty(0)
    for first, last in _chunks(rows.start, rows.stop):
        chunk_c = temperature[first:last]
        basis = np.polynomial.legendre.legvander((chunk_c - centre_c) / half_span_c, order)
        gram += basis.T @ basis
        moment += basis.T @ rate[first:last]
        # Support needs order + 1 distinct values at most: stop sorting once there are enough.
        if distinct.size <= order:
            distinct = np.union1d(distinct, np.round(chunk_c, DISTINCT_DECIMALS))
    return _Moments(rows=rows.stop - rows.start, low_c=float(np.min(temperature[rows])),
                    high_c=float(np.max(temperature[rows])), distinct=distinct, gram=gram,
                    moment=moment)


def _combined(parts) -> _Moments:
    """Return the `_Moments` of the union of disjoint row sets sharing one basis."""
    return _Moments(rows=sum(part.rows for part in parts),
                    low_c=min(part.low_c for part in parts),
                    high_c=max(part.high_c for part in parts),
                    distinct=np.unique(np.concatenate([part.distinct for part in parts])),
                    gram=sum(part.gram for part in parts),
                    moment=sum(part.moment for part in parts))


def _support_problem(moments: _Moments, order: int) -> str:
    """Return why the rows cannot support a polynomial of this order, '' if they can."""
    distinct = moments.distinct.size
    if distinct < order + 1:
        return (f'order {order} needs at least {order + 1} distinct temperatures '
                f'(rounded to 0.01 C), the data has {distinct}')
    span_c = moments.high_c - moments.low_c
    if order >= 1 and span_c < MIN_SPAN_C:
        return (f'order {order} needs a temperature span of at least {MIN_SPAN_C} C, '
                f'the data spans {span_c:.3g} C ({moments.low_c:.2f} to {moments.high_c:.2f} C)')
    if span_c == 0.0:
        return (f'all temperatures equal {moments.low_c:.2f} C; the model needs '
                'temperature_min_c below temperature_max_c')
    return ''


def _legendre_solution(moments: _Moments, order: int) -> tuple:
    """
    Solve the normal equations up to ``order``: (coefficients (order + 1, axes), rank).

    The Gram matrix is scaled to a unit diagonal and solved by SVD; singular
    values below GRAM_RCOND of the largest count as zero (the rank).
    """
    size = order + 1
    gram = moments.gram[:size, :size]
    diagonal = np.diag(gram)
    scale = 1.0 / np.sqrt(np.where(diagonal > 0.0, diagonal, 1.0))
    solution, _, rank, _ = np.linalg.lstsq(gram * np.outer(scale, scale),
                                           moments.moment[:size] * scale[:, None],
                                           rcond=GRAM_RCOND)
    return solution * scale[:, None], int(rank)


def _power_coefficients(legendre: np.ndarray) -> tuple:
    """Convert Legendre coefficients to powers of the same x, keeping their count."""
    power = np.polynomial.legendre.leg2poly(legendre)
    # leg2poly drops trailing exact zeros; the model keeps one coefficient per power.
    return tuple(float(c) for c in np.pad(power, (0, legendre.size - power.size)))


def fit_polynomial(temperature_c, rate_rad_s, orders) -> EffectModel:
    """
    Fit a bias polynomial per axis by least squares in float64: a ``polynomial`` model.

    temperature_c has shape (samples,), rate_rad_s (samples,) or (samples, axes),
    orders is one int for every axis or one per axis. The model works in
    x = (T - centre) / scale over the data's temperature range and clamps to
    that range. Raise CalibrationError when the data cannot support an order.

    The fit never holds a design matrix: it accumulates the normal equations
    of Legendre polynomials in x CHUNK_ROWS rows at a time (well conditioned
    on [-1, 1]), solves them and converts the solution to powers of x. An
    axis of order 3 is PX4's cubic (`baseline.fit_cubic`): the node runs it
    as the firmware's formula, to the bit.
    """
    temperature, rate = _fit_inputs(temperature_c, rate_rad_s)
    axis_orders = _axis_orders(orders, rate.shape[1])
    highest = max(axis_orders)
    low_c = float(np.min(temperature))
    high_c = float(np.max(temperature))
    scaling = _scaling(low_c, high_c)
    moments = _moments(temperature, rate, slice(0, temperature.size), scaling, highest)
    problem = _support_problem(moments, highest)
    if problem:
        raise CalibrationError(problem)
    coefficients = []
    cubic = None
    for axis, order in enumerate(axis_orders):
        if order == PX4_ORDER:
            cubic = cubic or fit_cubic(temperature, rate)[0].effect_model()
            coefficients.append(cubic.terms[axis].bias)
            continue
        solution, rank = _legendre_solution(moments, order)
        if rank < order + 1:
            msg = (f'axis {AXIS_NAMES[axis]}: the temperatures cannot determine an order '
                   f'{order} polynomial (design matrix rank {rank})')
            raise CalibrationError(msg)
        coefficients.append(_power_coefficients(solution[:, axis]))
    centre_c, scale_c = scaling
    return polynomial_model(tuple(coefficients), reference_temperature_c=centre_c,
                            temperature_scale_c=scale_c, temperature_min_c=low_c,
                            temperature_max_c=high_c)


def fold_rows(samples: int, blocks: int, folds: int = DEFAULT_FOLDS, scheme: str = FORWARD,
              min_past: float = DEFAULT_MIN_PAST) -> tuple:
    """Give the held-out rows of each fold of `validation.split` over ``samples`` rows."""
    bounds = block_bounds(samples, blocks)
    return tuple(np.concatenate([np.arange(bounds[block], bounds[block + 1])
                                 for block in np.flatnonzero(held)])
                 for held in split(blocks, scheme, folds, min_past).held)


def _held_out_rms_rad_s(temperature, rate, bounds, orders, folds) -> dict:
    """
    Return per order the held-out RMS per fold (rows) and axis (columns), inf if unsupported.

    Each fold's polynomial is the least-squares fit on its training blocks
    (the sum of their normal equations), clamped to their temperature range;
    it is evaluated, clamped so, in the Legendre basis it was solved in (the
    same polynomial as the fitted model would evaluate in powers of
    the training x). Order 3 is PX4's cubic, fitted on the training rows and
    run clamped (`baseline.fit_cubic`).
    """
    highest = orders[-1]
    scaling = _scaling(float(np.min(temperature)), float(np.max(temperature)))
    centre_c, scale_c = scaling
    parts = [_moments(temperature, rate, slice(first, last), scaling, highest)
             for first, last in zip(bounds[:-1], bounds[1:])]
    rms = {order: np.full((folds.folds, rate.shape[1]), math.inf) for order in orders}
    for fold in range(folds.folds):
        held_out = np.flatnonzero(folds.held[fold])
        training = _combined([part for part, used in zip(parts, folds.training[fold]) if used])
        solutions = {}
        for order in orders:
            if not _support_problem(training, order):
                solution, rank = _legendre_solution(training, order)
                if rank == order + 1:
                    solutions[order] = solution
        if not solutions:
            continue
        cubic = _fold_cubic(parts, scaling, folds.training[fold]) \
            if PX4_ORDER in solutions else None
        squares = {order: np.zeros(rate.shape[1]) for order in solutions}
        for block in held_out:
            for first, last in _chunks(bounds[block], bounds[block + 1]):
                clamped_c = np.clip(temperature[first:last], training.low_c, training.high_c)
                basis = np.polynomial.legendre.legvander(
                    (clamped_c - centre_c) / scale_c, max(solutions))
                for order, solution in solutions.items():
                    residual = rate[first:last] - basis[:, :order + 1] @ solution \
                        if order != PX4_ORDER else \
                        cubic.corrected(rate[first:last], temperature[first:last])
                    squares[order] += np.einsum('ij,ij->j', residual, residual)
        rows = sum(parts[block].rows for block in held_out)
        for order, total in squares.items():
            rms[order][fold] = np.sqrt(total / rows)
    return rms


def _fold_cubic(parts: list, scaling: tuple, training: np.ndarray):
    """PX4's cubic fitted on a fold's training blocks (`baseline.solve_cubic`, their sums)."""
    size = PX4_ORDER + 1
    sums = CubicSums(scaling[0], scaling[1], np.array([part.gram[:size, :size] for part in parts]),
                     np.array([part.moment[:size] for part in parts]),
                     np.array([part.low_c for part in parts]),
                     np.array([part.high_c for part in parts]), np.zeros(len(parts), dtype=int))
    return solve_cubic(sums, training)[0]


def select_orders(temperature_c, rate_rad_s, axes=None, candidate_orders=range(0, 9),
                  blocks: int = DEFAULT_BLOCKS, folds: int = DEFAULT_FOLDS,
                  validation: str = DEFAULT_VALIDATION, min_past: float = DEFAULT_MIN_PAST,
                  baseline_margin: float = BASELINE_MARGIN,
                  significance: float = DEFAULT_SIGNIFICANCE) -> tuple:
    """
    Choose the bias polynomial order per axis on held-out contiguous blocks.

    The record is cut into ``blocks`` contiguous blocks and dealt to folds by
    ``validation`` (`validation.split`: forward in time by default,
    round-robin to ``folds`` folds, or purged). Each candidate order is
    fitted on a fold's training blocks and scored by the RMS of the corrected
    rate on its held-out blocks. Blocks are contiguous because neighbouring
    samples are correlated. The cubic (PX4's model, order 3) is the
    incumbent: another order is chosen only when it beats the cubic fold by
    fold (`validation.paired`: its mean per-fold gain at least
    ``significance`` standard errors and a win on most folds) and its mean
    held-out RMS is ``baseline_margin`` below the cubic's; of those, the one
    with the largest mean gain. Orders the training data cannot support
    score inf and are never chosen. Each block is summarised once (normal
    equations up to the highest order), so the cost hardly grows with the
    number of orders and folds.
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
    orders = sorted(set(_axis_orders(candidates, len(candidates))) | {PX4_ORDER})
    dealt = split(blocks, validation, folds, min_past)
    bounds = block_bounds(temperature.size, blocks)
    fold_rms = _held_out_rms_rad_s(temperature, rate, bounds, orders, dealt)
    selections = []
    for axis, name in enumerate(names):
        scores = tuple(order_score(order, fold_rms[order][:, axis]) for order in orders)
        selections.append(_against_cubic(name, scores, dealt, baseline_margin, significance))
    return tuple(selections)


def _against_cubic(name: str, scores: tuple, dealt, margin: float,
                   significance: float) -> OrderSelection:
    """
    Take the cubic unless orders beat it fold by fold and by the margin.

    Of those that do, the lowest order whose mean held-out RMS is within one
    standard error of the best's.
    """
    cubic = next(s for s in scores if s.order == PX4_ORDER)
    if not math.isfinite(cubic.mean_rms_rad_s):
        return _without_cubic(name, scores, dealt)
    scheme = dealt.scheme.replace('_', '-')
    winners = [score for score in scores
               if score is not cubic and math.isfinite(score.mean_rms_rad_s)
               and paired(cubic.block_rms_rad_s, score.block_rms_rad_s).beats(significance)
               and not cubic_instead(score.mean_rms_rad_s, cubic.mean_rms_rad_s, margin, scheme)]
    chosen = one_standard_error(winners) if winners else PX4_ORDER
    rule = (f'{BASELINE_RULE} ({dealt.describe()}): '
            + (f'order {chosen} does (of those that do, the lowest within one standard error '
               'of the best)' if winners else 'no order does, so the cubic is written'))
    return OrderSelection(axis=name, order=chosen, scores=scores, rule=rule)


def _without_cubic(name: str, scores: tuple, dealt) -> OrderSelection:
    """Where the folds cannot support a cubic: the lowest order within one SE of the best."""
    try:
        chosen = one_standard_error(scores)
    except CalibrationError:
        msg = (f'axis {name}: the data cannot support any of the orders '
               f'{[s.order for s in scores]} ({dealt.describe()})')
        raise CalibrationError(msg) from None
    rule = (f'the training folds cannot support the PX4-style cubic ({dealt.describe()}): the '
            f'lowest order within one standard error of the best, order {chosen}')
    return OrderSelection(axis=name, order=chosen, scores=scores, rule=rule)


def relative_polynomial(model: EffectModel, true_temperature_c: float) -> EffectModel:
    """
    Shift each bias polynomial so that it is zero at ``true_temperature_c``.

    The note "Temperature Correction in MPU6000" corrects
    gyro - (p(T) - p(T_true)), T_true being the temperature at which no bias
    is introduced. That is a polynomial model whose constant term is lowered
    by p(T_true), so the compensation node runs it as it runs any polynomial.
    Raise CalibrationError when T_true lies outside the fitted temperature
    range (p would be extrapolated there).
    """
    true_c = float(true_temperature_c)
    if not model.temperature_min_c <= true_c <= model.temperature_max_c:
        msg = (f'true temperature {true_c:g} C is outside the fitted range '
               f'{model.temperature_min_c:.2f} to {model.temperature_max_c:.2f} C, '
               'where the polynomial would be extrapolated')
        raise CalibrationError(msg)
    x = (true_c - model.reference_temperature_c) / model.temperature_scale_c
    return replace(model, terms=tuple(
        replace(term, bias=(term.bias[0] - np.polynomial.polynomial.polyval(x, term.bias),)
                + term.bias[1:]) for term in model.terms))


def fit_linear_btc(temperature_c, rate_rad_s, t3_c=None) -> EffectModel:
    """
    Fit the ADIS16130 note's first-order bias correction per axis: a ``linear_btc`` model.

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
    return LinearBtc(pbc_rad_s=tuple(-solution[0]),
                     btc_rad_s_per_c=tuple(-solution[1] / half_span_c), t3_c=t3).model()


def table_step_c(extent_c: float, rows_each_side: int) -> float:
    """Return the smallest 1, 2 or 5 x 10^k step that reaches ``extent_c`` in so many rows."""
    if not (math.isfinite(extent_c) and extent_c > 0.0) or rows_each_side < 1:
        msg = f'a table needs a positive extent and rows, got {extent_c} C, {rows_each_side}'
        raise CalibrationError(msg)
    raw = extent_c / rows_each_side
    decade = 10.0 ** math.floor(math.log10(raw))
    return next(m * decade for m in (1.0, 2.0, 5.0, 10.0) if m * decade >= raw * (1 - 1e-12))
