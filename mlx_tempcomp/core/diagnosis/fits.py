"""
What the loop can add to an axis: `AxisSpec`, and per effect how it is searched and fitted.

`FITS` holds, for every effect but the temperature polynomial, its trials
(a flag, a few orders, a 1-D grid search of a time constant or width, the
CUSUM of a bias step), its bin-mean design columns, its `AxisTerms` fields
from the fitted coefficients and its report. `best_trial` runs an effect's
trials on a `DiagnosisData` with a scoring function and keeps the best
scored; `design` gives an axis's design matrix.
"""

# `AxisSpec.with_choice` names its own class.
from __future__ import annotations

from dataclasses import dataclass, field, replace
import functools
import math
from typing import Callable, Optional

import numpy as np

from .data import DiagnosisData, TIME_GRID_S, WIDTH_GRID_C
from .settings import BASE_EFFECT
from ..effects import AxisTerms, EFFECT_NAMES, FirstOrderLag, play_state

# The coarse pass of a 1-D search visits every COARSE-th grid point (`data.TIME_GRID_S`,
# `data.WIDTH_GRID_C`) within the bounds, the fine pass the neighbours of the best.
COARSE = 4
# Two gradient time constants closer than this ratio are one.
MIN_GRADIENT_RATIO = 2.0
SUPPLY_ORDERS = (1, 2)
SECONDARY_ORDERS = (1, 2, 3)
SCALE_ORDERS = (0, 1, 2)
NONLINEARITY_ORDERS = (2, 3)


@dataclass(frozen=True)
class AxisSpec:
    """
    The effects of one axis: the polynomial order and each effect's choice.

    ``choices`` pairs an effect with what the search chose for it (a time
    constant, a width, an order, True), in EFFECT_NAMES order: the order of
    the design columns. ``thermal_gradient`` holds one or two time constants,
    the second being ``thermal_gradient_2``. ``baseline`` marks the PX4-style
    cubic itself (`core.fitting.baseline`: np.polyfit on the rows, clamped), order 3
    and no effects; adding an effect gives a polynomial fitted beside it.
    """

    order: int
    choices: tuple = ()
    baseline: bool = False

    def get(self, effect: str, default=None):
        return dict(self.choices).get(effect, default)

    def with_choice(self, effect: str, choice) -> AxisSpec:
        choices = dict(self.choices, **{effect: choice})
        return replace(self, baseline=False,
                       choices=tuple((e, choices[e]) for e in EFFECT_NAMES if e in choices))

    @property
    def thermal_lag_s(self) -> float:
        return self.get('thermal_lag', 0.0)

    @property
    def gradient_s(self) -> tuple:
        return self.get('thermal_gradient', ())

    @property
    def effects(self) -> set:
        present = {BASE_EFFECT} | {effect for effect, _ in self.choices}
        return present | ({'thermal_gradient_2'} if len(self.gradient_s) > 1 else set())

    def can_add(self, effect: str) -> bool:
        """Whether ``effect`` can be added to this spec this round."""
        if effect in self.effects:
            return False
        return effect != 'thermal_gradient_2' or len(self.gradient_s) == 1


def _step_time(data: DiagnosisData, axis: int, spec: AxisSpec) -> float:
    """
    Return the bias step time that least squares prefers, given the axis's other terms.

    The numerator is the CUSUM of the current (weighted) residual; it is
    divided by what a step at each bin start leaves unexplained by the other
    terms, which makes the peak the exact least-squares step location.
    """
    root = np.sqrt(data.counts)
    basis, _ = np.linalg.qr(design(data, axis, spec) * root[:, None])
    target = data.target[:, axis] * root
    residual = target - basis @ (basis.T @ target)
    # Sums from each bin to the end: a step starting at that bin.
    cusum = np.cumsum((residual * root)[::-1])[::-1]
    projected = np.cumsum((basis * root[:, None])[::-1], axis=0)[::-1]
    left = np.cumsum(data.counts[::-1])[::-1] - np.sum(np.square(projected), axis=1)
    usable = left > 1e-9 * np.sum(data.counts)
    usable[0] = False
    if not usable.any():
        return float(data.time[-1])
    gain = np.where(usable, np.square(cusum) / np.where(usable, left, 1.0), -1.0)
    return float(data.time[data.starts[int(np.argmax(gain))]])


def _grid_search(grid: tuple, low: float, high: float, evaluate) -> None:
    """
    Bounded 1-D search of ``evaluate`` over the grid points in [low, high].

    Every COARSE-th point first, then the neighbours of the best at half the
    stride, down to the grid's own spacing.
    """
    points = [value for value in grid if low <= value <= high]
    if not points:
        return
    seen = {}

    def rms(index: int) -> float:
        if index not in seen:
            seen[index] = evaluate(points[index])
        return seen[index]

    coarse = sorted(set(range(0, len(points), COARSE)) | {len(points) - 1})
    best = min(coarse, key=rms)
    stride = COARSE // 2
    while stride >= 1:
        for index in (best - stride, best + stride):
            if 0 <= index < len(points) and rms(index) < rms(best):
                best = index
        stride //= 2


@dataclass(frozen=True)
class Score:
    """A spec scored on the folds: RMS per fold and overall, full rank, the binned residual."""

    fold_rms: np.ndarray
    rms: float
    rank_ok: bool
    residual: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class Trial:
    """A spec tried on an axis and its score on the folds."""

    spec: AxisSpec
    score: Score


class _Search:
    """
    Keeps the best `Trial` of the trials of one effect.

    ``score`` scores a spec on the axis searched: a `Score`, or None when no
    fold can judge it (`problem.DiagnosisProblem.judge`).
    """

    def __init__(self, score: Callable[[AxisSpec], Optional[Score]]):
        self.score, self.best = score, None

    def __call__(self, spec: AxisSpec) -> float:
        score = self.score(spec)
        if score is None:
            return math.inf
        if self.best is None or score.rms < self.best.score.rms:
            self.best = Trial(spec, score)
        return score.rms


def best_trial(data: DiagnosisData, score: Callable[[AxisSpec], Optional[Score]], axis: int,
               spec: AxisSpec, effect: str) -> Optional[Trial]:
    """
    Return the best `Trial` of one effect, None if none fits the search bounds.

    The trials read ``data`` (its bounds, its features); ``score`` scores
    each spec on ``axis`` (see `_Search`).
    """
    search = _Search(score)
    FITS[effect].trials(search, data, axis, spec)
    return search.best


def design(data: DiagnosisData, axis: int, spec: AxisSpec) -> np.ndarray:
    """
    Return the bin-mean design matrix of an axis.

    Columns: the polynomial's, each effect's in ``spec.choices`` order
    (`FITS`), the records' offsets last.
    """
    blocks = [data.polynomial(spec.thermal_lag_s)[:, :spec.order + 1]]
    for effect, choice in spec.choices:
        columns = FITS[effect].columns
        if columns is not None:
            blocks.append(columns(data, axis, spec, choice))
    blocks.append(data.offset_columns())
    return np.column_stack(blocks)


@dataclass(frozen=True)
class EffectFit:
    """
    How the loop fits one effect on an axis.

    ``trials(search, data, axis, spec)`` scores each choice worth trying
    with `_Search`; ``columns(data, axis, spec, choice)`` gives the
    effect's bin-mean design columns (None: it moves the polynomial's x);
    ``terms(data, axis, choice, take)`` its `AxisTerms` fields, ``take(n)``
    giving its next n fitted coefficients (None: another effect holds its
    choice); ``report(terms, data)`` its fitted parameters in SI units.
    """

    trials: Callable
    report: Callable
    columns: Optional[Callable] = None
    terms: Optional[Callable] = None


def _flag(effect: str) -> Callable:
    """Trials of an effect without a choice: one, the effect in."""
    def trials(search: _Search, data: DiagnosisData, axis: int, spec: AxisSpec) -> None:
        search(spec.with_choice(effect, True))
    return trials


def _orders(effect: str, orders: tuple) -> Callable:
    """Trials of an effect whose choice is a polynomial order: each of ``orders``."""
    def trials(search: _Search, data: DiagnosisData, axis: int, spec: AxisSpec) -> None:
        for order in orders:
            search(spec.with_choice(effect, order))
    return trials


def _lag_trials(search: _Search, data: DiagnosisData, axis: int, spec: AxisSpec) -> None:
    low, high = data.bounds['thermal_lag_s']
    for sign in (1.0, -1.0):
        _grid_search(TIME_GRID_S, low, high,
                     lambda tau: search(spec.with_choice('thermal_lag', sign * tau)))


def _lag_report(terms: AxisTerms, data: DiagnosisData) -> dict:
    lag = terms.thermal_lag_s
    return {'thermal_lag_s': lag,
            'form': ('the sensor lags: T_eff = T + lag x dT/dt' if lag > 0.0 else
                     'the element lags: T_eff = first-order lag of T'),
            'temperature_rate_window_s': data.settings.rate_window_s}


def _rate_columns(data: DiagnosisData, axis: int, spec: AxisSpec, choice) -> np.ndarray:
    return data.cached('rate', lambda: data.mean(data.slope)[:, None])


def _gradient_trials(search: _Search, data: DiagnosisData, axis: int,
                     spec: AxisSpec) -> None:
    low, high = data.bounds['gradient_time_constant_s']
    _grid_search(TIME_GRID_S, low, high,
                 lambda tau: search(spec.with_choice('thermal_gradient', (tau,))))


def _second_gradient(search: _Search, data: DiagnosisData, axis: int,
                     spec: AxisSpec) -> None:
    """Search a second gradient time constant, then the first again beside it."""
    bounds = data.bounds['gradient_time_constant_s']
    (first,) = spec.gradient_s

    def pair(kept: float, tau: float) -> float:
        if max(kept, tau) < MIN_GRADIENT_RATIO * min(kept, tau):
            return math.inf
        return search(spec.with_choice('thermal_gradient', tuple(sorted((kept, tau)))))

    _grid_search(TIME_GRID_S, *bounds, lambda tau: pair(first, tau))
    if search.best is not None:
        second = next(t for t in search.best.spec.gradient_s if t != first)
        _grid_search(TIME_GRID_S, *bounds, lambda tau: pair(second, tau))


def _gradient_columns(data: DiagnosisData, axis: int,
                      spec: AxisSpec, taus: tuple) -> np.ndarray:
    def difference(tau: float) -> np.ndarray:
        lagged = data.each(FirstOrderLag(tau).batch, data.time, data.temperature)
        return data.mean(data.temperature - lagged)
    return np.column_stack([data.cached(('gradient', tau), functools.partial(difference, tau))
                            for tau in taus])


def _gradient_report(terms: AxisTerms, data: DiagnosisData) -> dict:
    return {'time_constants_s': list(terms.gradient_time_constants_s),
            'rad_s_per_c': list(terms.gradient_rad_s_per_c)}


def _hysteresis_trials(search: _Search, data: DiagnosisData, axis: int,
                       spec: AxisSpec) -> None:
    low, high = data.bounds['hysteresis_half_width_c']
    _grid_search(WIDTH_GRID_C, low, high,
                 lambda width: search(spec.with_choice('hysteresis', width)))


def _play_columns(data: DiagnosisData, axis: int,
                  spec: AxisSpec, width_c: float) -> np.ndarray:
    return data.cached(('play', width_c), lambda: data.mean(data.each(
        functools.partial(play_state, half_width_c=width_c), data.temperature))[:, None])


def _supply_columns(data: DiagnosisData, axis: int,
                    spec: AxisSpec, order: int) -> np.ndarray:
    reference = data.supply_reference.centre
    return data.cached('supply', lambda: data.powers(
        data.inputs.supply_voltage_v - reference, 1, max(SUPPLY_ORDERS)))[:, :order]


def _secondary_columns(data: DiagnosisData, axis: int,
                       spec: AxisSpec, order: int) -> np.ndarray:
    reference, scale = data.secondary.centre, data.secondary.half_span
    return data.cached('secondary', lambda: data.powers(
        (data.inputs.temperature_2_c - reference) / scale, 1, max(SECONDARY_ORDERS)))[:, :order]


def _scale_columns(data: DiagnosisData, axis: int, spec: AxisSpec, order: int) -> np.ndarray:
    lag_s = spec.thermal_lag_s

    def build():
        x = data.x(lag_s)
        truth = data.reference[:, axis]
        return np.column_stack([data.mean(truth * x ** k)
                                for k in range(max(SCALE_ORDERS) + 1)])
    return data.cached(('scale', axis, lag_s), build)[:, :order + 1]


def _nonlinearity_columns(data: DiagnosisData, axis: int,
                          spec: AxisSpec, order: int) -> np.ndarray:
    return data.cached(('nonlinearity', axis), lambda: data.powers(
        data.reference[:, axis], 2, max(NONLINEARITY_ORDERS)))[:, :order - 1]


def _cross_columns(data: DiagnosisData, axis: int, spec: AxisSpec, choice) -> np.ndarray:
    others = [j for j in range(len(data.axes)) if j != axis]
    return data.cached(('cross', axis), lambda: data.mean(data.reference[:, others]))


def _cross_terms(data: DiagnosisData, axis: int, choice, take) -> dict:
    others = iter(take(len(data.axes) - 1))
    return {'cross_axis': tuple(0.0 if j == axis else next(others)
                                for j in range(len(data.axes)))}


def _drift_columns(data: DiagnosisData, axis: int, spec: AxisSpec, choice) -> np.ndarray:
    return data.cached('drift', lambda: data.mean(
        (data.time - data.time_reference_s) / data.duration_s)[:, None])


def _step_trials(search: _Search, data: DiagnosisData, axis: int, spec: AxisSpec) -> None:
    search(spec.with_choice('bias_step', _step_time(data, axis, spec)))


def _step_columns(data: DiagnosisData, axis: int,
                  spec: AxisSpec, time_s: float) -> np.ndarray:
    return data.cached(('step', time_s), lambda: data.mean(
        (data.time >= time_s).astype(np.float64))[:, None])


def _step_report(terms: AxisTerms, data: DiagnosisData) -> dict:
    (time_s, step_rad_s), = terms.bias_steps
    records = data.records
    if records.count == 1:
        return {'time_s': time_s, 'step_rad_s': step_rad_s,
                'after_start_s': time_s - data.time_reference_s}
    # Several records: the stamp on the clock of the record the step lies in.
    record, own_s = records.own_time_s(time_s)
    return {'time_s': own_s, 'step_rad_s': step_rad_s,
            'after_start_s': float(time_s - records.time_s[records.starts[record]]),
            'record': records.names[record]}


# Every effect but BASE_EFFECT; the design columns come in EFFECT_NAMES order.
FITS = {
    'thermal_lag': EffectFit(_lag_trials, _lag_report,
                             terms=lambda data, axis, lag_s, take: {'thermal_lag_s': lag_s}),
    'temperature_rate': EffectFit(
        _flag('temperature_rate'),
        lambda terms, data: {'rad_s_per_c_s': terms.temperature_rate_rad_s_per_c_s,
                             'temperature_rate_window_s': data.settings.rate_window_s},
        _rate_columns,
        lambda data, axis, choice, take: {'temperature_rate_rad_s_per_c_s': take(1)[0]}),
    'thermal_gradient': EffectFit(
        _gradient_trials, _gradient_report, _gradient_columns,
        lambda data, axis, taus, take: {'gradient_time_constants_s': taus,
                                        'gradient_rad_s_per_c': take(len(taus))}),
    'thermal_gradient_2': EffectFit(_second_gradient, _gradient_report),
    'hysteresis': EffectFit(
        _hysteresis_trials,
        lambda terms, data: {'half_width_c': terms.hysteresis_half_width_c,
                             'hysteresis_rad_s': terms.hysteresis_rad_s},
        _play_columns,
        lambda data, axis, width_c, take: {'hysteresis_half_width_c': width_c,
                                           'hysteresis_rad_s': take(1)[0]}),
    'supply_voltage': EffectFit(
        _orders('supply_voltage', SUPPLY_ORDERS),
        lambda terms, data: {'rad_s_per_v_k': list(terms.supply_voltage),
                             'supply_reference_v': data.supply_reference.centre},
        _supply_columns, lambda data, axis, order, take: {'supply_voltage': take(order)}),
    'secondary_temperature': EffectFit(
        _orders('secondary_temperature', SECONDARY_ORDERS),
        lambda terms, data: {'coefficients_rad_s': list(terms.secondary)},
        _secondary_columns, lambda data, axis, order, take: {'secondary': take(order)}),
    'acceleration_sensitivity': EffectFit(
        _flag('acceleration_sensitivity'),
        lambda terms, data: {'rad_s_per_m_s2': list(terms.acceleration_rad_s_per_m_s2)},
        lambda data, axis, spec, choice: data.acceleration_means(),
        lambda data, axis, choice, take: {'acceleration_rad_s_per_m_s2': take(3)}),
    'scale_factor_temperature': EffectFit(
        _orders('scale_factor_temperature', SCALE_ORDERS),
        lambda terms, data: {'relative_coefficients': list(terms.scale)},
        _scale_columns, lambda data, axis, order, take: {'scale': take(order + 1)}),
    'rate_nonlinearity': EffectFit(
        _orders('rate_nonlinearity', NONLINEARITY_ORDERS),
        lambda terms, data: {'coefficients': list(terms.nonlinearity)},
        _nonlinearity_columns,
        lambda data, axis, order, take: {'nonlinearity': take(order - 1)}),
    'cross_axis': EffectFit(_flag('cross_axis'),
                            lambda terms, data: {'coefficients': list(terms.cross_axis)},
                            _cross_columns, _cross_terms),
    'time_drift': EffectFit(
        _flag('time_drift'),
        lambda terms, data: {'rad_s_per_s': terms.time_drift_rad_s_per_s,
                             'time_reference_s': data.time_reference_s},
        _drift_columns,
        lambda data, axis, choice, take: {
            'time_drift_rad_s_per_s': take(1)[0] / data.duration_s}),
    'bias_step': EffectFit(_step_trials, _step_report, _step_columns,
                           lambda data, axis, time_s, take: {
                               'bias_steps': ((time_s, take(1)[0]),)}),
}


def fitted_parameters(effect: str, terms: AxisTerms, data: DiagnosisData) -> dict:
    """Return the fitted parameters of one effect of an axis, in SI units."""
    if effect == BASE_EFFECT:
        return {'order': len(terms.bias) - 1, 'bias_rad_s': list(terms.bias),
                'reference_temperature_c': data.centre_c,
                'temperature_scale_c': data.scale_c}
    return FITS[effect].report(terms, data)
