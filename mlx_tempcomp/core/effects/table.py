"""
The table of effects: each effect's coefficients, node parameters, inputs and bias term.

Per axis, on raw rate r in rad/s, temperature T in degC, time t in s and
supply voltage V, `EffectModel` (`model.py`) corrects:

- ``temperature_polynomial``: P(x), x = (T_eff - reference) / scale, T_eff
  clamped to the fitted range;
- ``thermal_lag``: T_eff is the temperature of the sensing element when it
  and the temperature sensor are one first-order lag of time constant tau
  apart. lag > 0, the sensor lags the element: T_eff = T + lag x dT/dt, dT/dt
  the slope of T over the last ``window`` seconds; lag < 0, the element lags
  the sensor: T_eff = L_|lag|(T), the first-order lag of T;
- ``temperature_rate``: + c x dT/dt (the same windowed slope);
- ``thermal_gradient`` (and ``thermal_gradient_2``, a second time constant):
  + sum over k of g_k x (T - L_tau_k(T)), the bias following the temperature
  difference between the die and parts of the package that lag it by tau_k;
- ``hysteresis``: + h x s, s in [-1, 1] the state of a play operator of
  half width w on T: +1 after heating by 2w, -1 after cooling by 2w;
- ``supply_voltage``: + sum over k >= 1 of v_k (V - supply_reference)^k;
- ``secondary_temperature``: + Q(x2), x2 = (T2 - reference_2) / scale_2, no
  constant term;
- ``acceleration_sensitivity``: + g . a, a the specific force in m/s^2;
- ``time_drift``: + d x (t - time_reference);
- ``bias_step``: + the sum of the steps whose time has come;
- ``scale_factor_temperature``: u = (r - bias) / (1 + S(x));
- ``rate_nonlinearity``: v = u - (n2 u^2 + n3 u^3 + ...);
- ``cross_axis``: w = v - sum over the other axes j of m_j v_j;

and last the ZRO offset learned at rest: corrected = w - offset.

Each effect is one `Effect` of the table `EFFECTS`, in the order above: its
coefficient fields, the descriptions of its node parameters, the inputs it
needs, live or not, whether its bias term reads dT/dt, and its bias term;
the model, the diagnosis and the node parameters read it
(docs/architecture.md, "How to add an effect"). ``time_drift`` and ``bias_step`` are tied to the
clock of the record they were found in (`RECORD_EFFECTS`); every other
effect runs causally on a live stream (`LIVE_EFFECTS`).

A bias term's values are the columns of a block or one row's floats:
`polyval`, `clip` and `quotient` do the same operations on both, so a row
gives, bit for bit, what a block gives for it.
"""

from dataclasses import dataclass
from typing import Callable, Mapping, Optional

import numpy as np


@dataclass(frozen=True)
class Effect:
    """
    One effect: its coefficients, their descriptions, the inputs it needs, its bias term.

    ``fields`` are the `AxisTerms` fields it owns (node parameters
    ``effects.<field>.<axis>``), ``model_fields`` the `EffectModel` fields
    (``effects.<field>``); ``descriptions`` describe each of its node
    parameters, ``{axis}`` standing for the axis. It is present on an axis
    when its ``marker`` field (its first field unless given) is non-zero,
    or holds at least ``count`` values when ``count`` is given. ``inputs``
    are the `ModelInputs` fields it needs; ``live`` is False when it is tied
    to the clock of the record it was found in; ``slope`` says its bias term
    reads the windowed dT/dt (``history.slope``). ``bias(term, model, inputs,
    history, total)`` adds its term to the bias of an axis (None: the effect
    acts elsewhere in `EffectModel.correct_axes`); its values are columns of
    a block or one row's floats, with the same operations for both.
    """

    name: str
    fields: tuple
    descriptions: Mapping
    marker: str = ''
    model_fields: tuple = ()
    count: int = 0
    inputs: frozenset = frozenset()
    live: bool = True
    slope: bool = False
    bias: Optional[Callable] = None

    def __post_init__(self) -> None:
        if not self.marker:
            object.__setattr__(self, 'marker', self.fields[0])

    def present(self, term) -> bool:
        """Say whether ``term``, an `AxisTerms`, holds the effect."""
        value = getattr(term, self.marker)
        if self.count:
            return len(value) >= self.count
        return any(value) if isinstance(value, tuple) else value != 0.0


def _rate_bias(term, model, inputs, history, total):
    return total + term.temperature_rate_rad_s_per_c_s * history.slope


def _gradient_bias(term, model, inputs, history, total):
    for gain, difference in zip(term.gradient_rad_s_per_c, history.gradients):
        total = total + gain * difference
    return total


def _hysteresis_bias(term, model, inputs, history, total):
    return total + term.hysteresis_rad_s * history.play


def _supply_bias(term, model, inputs, history, total):
    dv = inputs.supply_voltage_v - model.supply_reference_v
    return total + dv * polyval(dv, term.supply_voltage)


def _secondary_bias(term, model, inputs, history, total):
    x2 = (inputs.temperature_2_c - model.secondary_reference_c) / model.secondary_scale_c
    return total + x2 * polyval(x2, term.secondary)


def _acceleration_bias(term, model, inputs, history, total):
    # Acceleration by component first: a column of the block, or a float of the row.
    for component, gain in enumerate(term.acceleration_rad_s_per_m_s2):
        total = total + gain * inputs.acceleration_m_s2[component]
    return total


def _drift_bias(term, model, inputs, history, total):
    return total + term.time_drift_rad_s_per_s * (inputs.time_s - model.time_reference_s)


def _step_bias(term, model, inputs, history, total):
    time_s = inputs.time_s
    for when_s, step_rad_s in term.bias_steps:
        if isinstance(time_s, np.ndarray):
            total = total + np.where(time_s >= when_s, step_rad_s, 0.0)
        else:
            total = total + (step_rad_s if time_s >= when_s else 0.0)
    return total


def polyval(x, coefficients: tuple):
    """
    Give the polynomial (lowest order first) at x, a column or a float.

    numpy's polyval's operations in its order: a float gives, bit for bit, the
    element of a column.
    """
    total = coefficients[-1] + x * 0.0
    for coefficient in coefficients[-2::-1]:
        total = coefficient + total * x
    return total


def clip(value, low: float, high: float):
    """Give np.clip of a column, or of a float by comparisons: NaN passes, a tie keeps it."""
    if isinstance(value, np.ndarray):
        return np.clip(value, low, high)
    return low if value < low else high if value > high else value


def quotient(numerator, denominator):
    """Give numerator / denominator; a float divided by zero as numpy does (inf or NaN)."""
    try:
        return numerator / denominator
    except ZeroDivisionError:
        return float(np.float64(numerator) / denominator)


_TIME = frozenset({'time_s'})
# The effects in the order diagnose tries them and reports them; biases add up in it.
EFFECTS = (
    Effect('temperature_polynomial', fields=('bias',), count=1,
           model_fields=('reference_temperature_c', 'temperature_scale_c', 'temperature_min_c',
                         'temperature_max_c'),
           descriptions={
               'bias': 'axis {axis}: bias polynomial in x, rad/s, lowest order first',
               'reference_temperature_c': 'Tref of x = (T_eff - Tref) / scale',
               'temperature_scale_c': 'scale of x = (T_eff - Tref) / scale',
               'temperature_min_c': 'effective temperatures below are clamped',
               'temperature_max_c': 'effective temperatures above are clamped'}),
    Effect('thermal_lag', fields=('thermal_lag_s',), inputs=_TIME,
           model_fields=('temperature_rate_window_s',),
           descriptions={
               'thermal_lag_s': 'axis {axis}: thermal lag; > 0: T_eff = T + lag x dT/dt, < 0: '
                                'T_eff = first-order lag of T with time constant |lag|',
               'temperature_rate_window_s': 'dT/dt of thermal lag and temperature rate: the '
                                            'slope over this window (s)'}),
    Effect('temperature_rate', fields=('temperature_rate_rad_s_per_c_s',), inputs=_TIME,
           slope=True, bias=_rate_bias,
           descriptions={'temperature_rate_rad_s_per_c_s': 'axis {axis}: bias + c x dT/dt'}),
    Effect('thermal_gradient', fields=('gradient_time_constants_s', 'gradient_rad_s_per_c'),
           count=1, inputs=_TIME, bias=_gradient_bias,
           descriptions={
               'gradient_time_constants_s': 'axis {axis}: thermal gradient time constants (at '
                                            'most 2)',
               'gradient_rad_s_per_c': 'axis {axis}: bias + g_k x (T - lag_k(T)), one per time '
                                       'constant'}),
    # The second term in thermal_gradient's fields, summed there.
    Effect('thermal_gradient_2', fields=(), marker='gradient_time_constants_s', count=2,
           inputs=_TIME, descriptions={}),
    Effect('hysteresis', fields=('hysteresis_half_width_c', 'hysteresis_rad_s'),
           marker='hysteresis_rad_s', bias=_hysteresis_bias,
           descriptions={
               'hysteresis_half_width_c': 'axis {axis}: half width of the hysteresis play '
                                          'operator',
               'hysteresis_rad_s': 'axis {axis}: hysteresis, bias + h x play state'}),
    Effect('supply_voltage', fields=('supply_voltage',), model_fields=('supply_reference_v',),
           inputs=frozenset({'supply_voltage_v'}), bias=_supply_bias,
           descriptions={
               'supply_voltage': 'axis {axis}: supply voltage polynomial in V - Vref from power '
                                 '1, rad/s',
               'supply_reference_v': 'Vref of the supply voltage terms, in (V - Vref)^k'}),
    Effect('secondary_temperature', fields=('secondary',),
           model_fields=('secondary_reference_c', 'secondary_scale_c'),
           inputs=frozenset({'temperature_2_c'}), bias=_secondary_bias,
           descriptions={
               'secondary': 'axis {axis}: second-temperature polynomial in x2 from power 1, '
                            'rad/s',
               'secondary_reference_c': 'T2ref of x2 = (T2 - T2ref) / scale_2',
               'secondary_scale_c': 'scale_2 of x2 = (T2 - T2ref) / scale_2'}),
    Effect('acceleration_sensitivity', fields=('acceleration_rad_s_per_m_s2',),
           inputs=frozenset({'acceleration_m_s2'}), bias=_acceleration_bias,
           descriptions={'acceleration_rad_s_per_m_s2': 'axis {axis}: bias per m/s^2 of x, y, '
                                                        'z acceleration'}),
    Effect('scale_factor_temperature', fields=('scale',), descriptions={
        'scale': 'axis {axis}: relative scale-factor polynomial in x (empty: none)'}),
    Effect('rate_nonlinearity', fields=('nonlinearity',), descriptions={
        'nonlinearity': 'axis {axis}: rate nonlinearity from u^2, v = u - u^2 poly(u)'}),
    Effect('cross_axis', fields=('cross_axis',), descriptions={
        'cross_axis': 'axis {axis}: cross-axis coefficients, one per model axis (own: 0)'}),
    Effect('time_drift', fields=('time_drift_rad_s_per_s',), model_fields=('time_reference_s',),
           inputs=_TIME, live=False, bias=_drift_bias,
           descriptions={
               'time_drift_rad_s_per_s': 'axis {axis}: bias drift per second since '
                                         'time_reference_s',
               'time_reference_s': 'time drift is zero at this stamp (s)'}),
    Effect('bias_step', fields=('bias_steps',), inputs=_TIME, live=False, bias=_step_bias,
           descriptions={
               'bias_step_time_s': 'axis {axis}: stamps of the bias steps (s)',
               'bias_step_rad_s': 'axis {axis}: bias steps in rad/s, one per bias_step_time_s'}),
)
EFFECT_NAMES = tuple(effect.name for effect in EFFECTS)
# Effects that need the clock of the record they were fitted on: not for a live node.
RECORD_EFFECTS = frozenset(effect.name for effect in EFFECTS if not effect.live)
LIVE_EFFECTS = tuple(effect.name for effect in EFFECTS if effect.live)
# Effects whose bias term reads the windowed dT/dt (the thermal lag's T_eff reads it too).
SLOPE_EFFECTS = tuple(effect for effect in EFFECTS if effect.slope)
# The description of every effects.* node parameter, by its name without the axis.
PARAMETER_DESCRIPTIONS = {name: text for effect in EFFECTS
                          for name, text in effect.descriptions.items()}
