"""
`EffectModel`: the temperature polynomial and the effects of `table.EFFECTS`, per axis.

`AxisTerms` holds the coefficients of one axis, a field per coefficient of
an effect; `EffectModel` the axes and what they share (references, the
clamped range, the slope window, the ZRO offset). `EffectModel.correct` runs
a batch, each history operator over it whole; `EffectModel.stream` gives
the node's `EffectStream`, which gives the same numbers (to rounding). Both
correct through `EffectModel.correct_axes`. `to_parameters` and
`from_parameters` flatten the model into the compensation node's
``effects.*`` parameters and back.

The node's ``polynomial`` and ``linear_btc`` models are effect models too, of
a bias (and scale) polynomial only: `polynomial_model` and `LinearBtc.model`
build them, named so that their fingerprints hash the parameters of their
own name (the key of the ZRO state files saved for them).
"""

from dataclasses import dataclass, field, fields, replace
import functools
import math
from typing import Mapping, NamedTuple, Optional

import numpy as np

from .history import DEFAULT_RATE_WINDOW_S, FirstOrderLag, History, play_state, TemperatureSlope
from .stream import EffectStream
from .table import clip, EFFECTS, polyval, quotient, RECORD_EFFECTS, SLOPE_EFFECTS
from ..errors import ConfigError
from ..node_models import (AXIS_NAMES, CorrectedRate, finite_tuple, INPUTS, model_fingerprint,
                           ModelInputs, NO_INPUTS, OffsetModel, rate_temperature_columns)

MAX_GRADIENT_TERMS = 2

DEFAULT_SUPPLY_REFERENCE_V = 5.0


class CheckedBlock(NamedTuple):
    """A block checked against a model: rate and temperature (samples, axes), inputs as arrays."""

    rate_rad_s: np.ndarray
    temperature_c: np.ndarray
    inputs: ModelInputs


@dataclass(frozen=True)
class AxisTerms:
    """
    The bias terms of one axis; empty tuples and zeros mean the effect is absent.

    ``bias`` is the temperature polynomial in rad/s, lowest order first;
    ``gradient_time_constants_s`` and ``gradient_rad_s_per_c`` pair up (at
    most two: ``thermal_gradient`` and ``thermal_gradient_2``);
    ``supply_voltage`` starts at the power 1 of (V - V_ref) (rad/s per V^k);
    ``secondary`` at the power 1 of x2; ``nonlinearity`` at u^2 (rad/s per
    (rad/s)^k); ``cross_axis`` has one coefficient per model axis (its own 0);
    ``acceleration_rad_s_per_m_s2`` one per x, y, z of the specific force;
    ``bias_steps`` holds (time_s, rad_s) pairs.
    """

    bias: tuple
    thermal_lag_s: float = 0.0
    temperature_rate_rad_s_per_c_s: float = 0.0
    gradient_time_constants_s: tuple = ()
    gradient_rad_s_per_c: tuple = ()
    hysteresis_half_width_c: float = 0.0
    hysteresis_rad_s: float = 0.0
    supply_voltage: tuple = ()
    time_drift_rad_s_per_s: float = 0.0
    bias_steps: tuple = ()
    secondary: tuple = ()
    acceleration_rad_s_per_m_s2: tuple = ()
    scale: tuple = ()
    nonlinearity: tuple = ()
    cross_axis: tuple = ()

    def __post_init__(self) -> None:
        bias = finite_tuple('bias', self.bias)
        if not bias:
            raise ConfigError('bias needs at least one coefficient')
        object.__setattr__(self, 'bias', bias)
        for name in _AXIS_SCALARS:
            value = float(getattr(self, name))
            if not math.isfinite(value):
                msg = f'{name} must be finite, got {value}'
                raise ConfigError(msg)
            object.__setattr__(self, name, value)
        if self.hysteresis_half_width_c < 0.0:
            msg = ('hysteresis_half_width_c must not be negative, got '
                   f'{self.hysteresis_half_width_c}')
            raise ConfigError(msg)
        if self.hysteresis_rad_s and not self.hysteresis_half_width_c:
            raise ConfigError('hysteresis_rad_s needs a positive hysteresis_half_width_c')
        steps = tuple(finite_tuple('bias_steps', pair) for pair in self.bias_steps)
        if any(len(pair) != 2 for pair in steps):
            raise ConfigError('bias_steps must be (time_s, rad_s) pairs')
        object.__setattr__(self, 'bias_steps', steps)
        for name in _AXIS_LISTS:
            object.__setattr__(self, name, finite_tuple(name, getattr(self, name)))
        taus, gains = self.gradient_time_constants_s, self.gradient_rad_s_per_c
        if len(taus) != len(gains) or len(taus) > MAX_GRADIENT_TERMS:
            msg = (f'gradient_time_constants_s and gradient_rad_s_per_c need the same number '
                   f'of values, at most {MAX_GRADIENT_TERMS}; got {len(taus)} and {len(gains)}')
            raise ConfigError(msg)
        if any(tau <= 0.0 for tau in taus):
            msg = f'gradient_time_constants_s must be positive, got {list(taus)}'
            raise ConfigError(msg)
        if self.acceleration_rad_s_per_m_s2 and len(self.acceleration_rad_s_per_m_s2) != 3:
            msg = ('acceleration_rad_s_per_m_s2 needs 3 values (x, y, z), got '
                   f'{len(self.acceleration_rad_s_per_m_s2)}')
            raise ConfigError(msg)

    @property
    def effects(self) -> tuple:
        """Names of the effects these terms hold, in EFFECT_NAMES order."""
        return tuple(effect.name for effect in EFFECTS if effect.present(self))

    @property
    def needs_slope(self) -> bool:
        return self.thermal_lag_s > 0.0 or any(effect.present(self) for effect in SLOPE_EFFECTS)


@dataclass(frozen=True)
class EffectModel(OffsetModel):
    """
    Temperature polynomial plus diagnosed effects, per axis; see the module docstring.

    ``terms`` holds one `AxisTerms` per axis. Temperatures (T_eff) outside
    [temperature_min_c, temperature_max_c] are clamped and flagged. ``name``
    is the node's ``model`` parameter that gives it: 'effects', or
    'polynomial' and 'linear_btc' for a model that holds no more than their
    parameters (`polynomial_model`, `LinearBtc`).
    """

    terms: tuple
    reference_temperature_c: float = 25.0
    temperature_scale_c: float = 1.0
    temperature_min_c: float = -math.inf
    temperature_max_c: float = math.inf
    temperature_rate_window_s: float = DEFAULT_RATE_WINDOW_S
    time_reference_s: float = 0.0
    secondary_reference_c: float = 25.0
    secondary_scale_c: float = 1.0
    supply_reference_v: float = DEFAULT_SUPPLY_REFERENCE_V
    zro_offset_rad_s: tuple = field(default=())
    name: str = 'effects'

    def __post_init__(self) -> None:
        terms = tuple(self.terms)
        if not 1 <= len(terms) <= 3 or not all(isinstance(t, AxisTerms) for t in terms):
            msg = f'effects model needs AxisTerms for 1 to 3 axes, got {len(terms)}'
            raise ConfigError(msg)
        object.__setattr__(self, 'terms', terms)
        for name in ('reference_temperature_c', 'temperature_scale_c',
                     'temperature_rate_window_s', 'time_reference_s', 'secondary_reference_c',
                     'secondary_scale_c', 'supply_reference_v'):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                msg = f'{name} must be finite, got {value}'
                raise ConfigError(msg)
            object.__setattr__(self, name, value)
        for name in ('temperature_scale_c', 'temperature_rate_window_s', 'secondary_scale_c'):
            if getattr(self, name) <= 0.0:
                msg = f'{name} must be positive, got {getattr(self, name)}'
                raise ConfigError(msg)
        object.__setattr__(self, 'temperature_min_c', float(self.temperature_min_c))
        object.__setattr__(self, 'temperature_max_c', float(self.temperature_max_c))
        if not self.temperature_min_c < self.temperature_max_c:
            msg = (f'temperature_min_c ({self.temperature_min_c}) must be below '
                   f'temperature_max_c ({self.temperature_max_c})')
            raise ConfigError(msg)
        for axis, term in enumerate(terms):
            if term.cross_axis and len(term.cross_axis) != len(terms):
                msg = (f'cross_axis of axis {axis} needs {len(terms)} values (one per model '
                       f'axis), got {len(term.cross_axis)}')
                raise ConfigError(msg)
            if term.cross_axis and term.cross_axis[axis] != 0.0:
                msg = f'cross_axis of axis {axis} must have 0 for the axis itself'
                raise ConfigError(msg)
        offset = self.zro_offset_rad_s or (0.0,) * len(terms)
        object.__setattr__(self, 'zro_offset_rad_s',
                           finite_tuple('zro_offset_rad_s', offset, len(terms)))
        self._check_name()

    def _check_name(self) -> None:
        """Refuse a polynomial or linear_btc model holding what their parameters cannot."""
        if self.name == 'effects':
            return
        if self.name not in MODEL_NAMES:
            msg = f'an effect model is named one of {list(MODEL_NAMES)}, got {self.name!r}'
            raise ConfigError(msg)
        held = {name for term in self.terms for name in term.effects}
        extra = held - {'temperature_polynomial', 'scale_factor_temperature'}
        if self.name == 'linear_btc':
            extra |= held & {'scale_factor_temperature'}
        if extra:
            msg = f'a {self.name} model holds no {", ".join(sorted(extra))}'
            raise ConfigError(msg)
        if self.name == 'linear_btc' and (
                any(len(term.bias) != 2 for term in self.terms) or self.temperature_scale_c != 1.0
                or math.isfinite(self.temperature_min_c) or math.isfinite(self.temperature_max_c)):
            raise ConfigError('a linear_btc model is a line in T - T3 per axis, not clamped')

    @property
    def axes(self) -> int:
        return len(self.terms)

    # Cached (the model is frozen): the stream asks for these on every block.
    @functools.cached_property
    def inputs(self) -> frozenset:
        """Give the `ModelInputs` fields the effects of any axis need."""
        return frozenset().union(*(effect.inputs for effect in EFFECTS for term in self.terms
                                   if effect.present(term)))

    @functools.cached_property
    def _biases(self) -> tuple:
        """Give the effects with a bias term present on each axis."""
        return tuple(tuple(e for e in _BIAS_EFFECTS if e.present(term)) for term in self.terms)

    @functools.cached_property
    def has_cross_axis(self) -> bool:
        return any(any(t.cross_axis) for t in self.terms)

    @functools.cached_property
    def record_effects(self) -> tuple:
        """Give the effects of RECORD_EFFECTS the model holds (tied to its record's clock)."""
        return tuple(sorted({e for t in self.terms for e in t.effects} & RECORD_EFFECTS))

    def fingerprint(self) -> str:
        """Hash the parameters of the model's name, the ZRO offset left out."""
        if self.name == 'polynomial':
            scale = tuple(term.scale for term in self.terms)
            content = {'bias': tuple(term.bias for term in self.terms),
                       'scale': scale if any(scale) else (),
                       'tref': self.reference_temperature_c, 'tscale': self.temperature_scale_c,
                       'range': [self.temperature_min_c, self.temperature_max_c]}
        elif self.name == 'linear_btc':
            line = LinearBtc.of(self)
            content = {'pbc': line.pbc_rad_s, 'btc': line.btc_rad_s_per_c, 't3': line.t3_c}
        else:
            content = {name: getattr(self, name) for name in _SCALARS}
            content['terms'] = [{f.name: getattr(t, f.name) for f in fields(t)}
                                for t in self.terms]
        return model_fingerprint(self.name, content)

    def correct(self, rate_rad_s, temperature_c,
                inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        """
        Correct a batch; stateful inputs start at its first sample.

        rate (samples, axes) rad/s; temperature (samples,) or (samples, axes)
        degC; ``inputs`` holds what the effects need (`Effect.inputs`).
        """
        block = self.checked_block(rate_rad_s, temperature_c, inputs)
        histories = [self._history(term, block.inputs.time_s, block.temperature_c[:, axis])
                     for axis, term in enumerate(self.terms)]
        return self.correct_checked(block, histories)

    def _history(self, term: AxisTerms, time: Optional[np.ndarray],
                 measured: np.ndarray) -> History:
        """Run the history operators ``term`` needs over a whole batch."""
        return History(
            slope=TemperatureSlope(self.temperature_rate_window_s).batch(time, measured)
            if term.needs_slope else None,
            lagged=FirstOrderLag(-term.thermal_lag_s).batch(time, measured)
            if term.thermal_lag_s < 0.0 else None,
            gradients=[measured - FirstOrderLag(tau).batch(time, measured)
                       for tau in term.gradient_time_constants_s],
            play=play_state(measured, term.hysteresis_half_width_c)
            if term.hysteresis_rad_s else None)

    def checked_block(self, rate_rad_s, temperature_c, inputs: ModelInputs) -> CheckedBlock:
        """Check and convert a block's arguments (as `correct` takes them) into arrays."""
        rate, temperature = rate_temperature_columns(rate_rad_s, temperature_c, self.axes)
        samples = rate.shape[0]
        return CheckedBlock(rate, temperature, ModelInputs(**{
            name: self._input(name, getattr(inputs, name), (samples,) + spec.shape)
            for name, spec in INPUTS.items()}))

    def correct_checked(self, block: CheckedBlock, histories: list) -> CorrectedRate:
        """Correct a checked block from the history operators' outputs per axis."""
        inputs = block.inputs
        if inputs.acceleration_m_s2 is not None:
            inputs = replace(inputs, acceleration_m_s2=inputs.acceleration_m_s2.T)
        corrected, clamped = self.correct_axes(list(block.rate_rad_s.T),
                                               list(block.temperature_c.T), inputs, histories)
        return CorrectedRate(np.stack(corrected, axis=1), np.stack(clamped, axis=1))

    def correct_axes(self, rates: list, temperatures: list, inputs: ModelInputs,
                     histories: list) -> tuple:
        """
        Correct each axis from its rate, measured temperature and history: (corrected, clamped).

        The values are the columns of a block or the floats of one row
        (acceleration by component first); element by element only, with the
        same operations for both, so a row gives, bit for bit, what a block
        gives for it.
        """
        corrected, clamped = [], []
        for term, rate, measured, history, biases in zip(self.terms, rates, temperatures,
                                                         histories, self._biases):
            effective = measured
            if term.thermal_lag_s > 0.0:
                effective = measured + term.thermal_lag_s * history.slope
            elif term.thermal_lag_s < 0.0:
                effective = history.lagged
            limited = clip(effective, self.temperature_min_c, self.temperature_max_c)
            clamped.append((measured != measured) | (limited != effective))   # NaN or clamped
            x = (limited - self.reference_temperature_c) / self.temperature_scale_c
            total = polyval(x, term.bias)
            for effect in biases:
                total = effect.bias(term, self, inputs, history, total)
            u = rate - total
            if any(term.scale):
                u = quotient(u, 1.0 + polyval(x, term.scale))
            if any(term.nonlinearity):
                u = u - u * u * polyval(u, term.nonlinearity)
            corrected.append(u)
        if self.has_cross_axis:
            before = corrected
            corrected = []
            for term, v in zip(self.terms, before):
                for gain, other in zip(term.cross_axis, before):
                    v = v - gain * other
                corrected.append(v)
        return [w - offset for w, offset in zip(corrected, self.zro_offset_rad_s)], clamped

    def _input(self, name: str, value, shape: tuple) -> Optional[np.ndarray]:
        if value is None:
            if name in self.inputs:
                msg = f'the effects model needs {name} for its effects'
                raise ConfigError(msg)
            return None
        array = np.asarray(value, dtype=np.float64)
        if array.shape != shape:
            msg = f'{name} must have shape {shape}, got {array.shape}'
            raise ConfigError(msg)
        return array

    def stream(self) -> EffectStream:
        """Return a sample-by-sample runner whose state starts empty."""
        return EffectStream(self)

    def to_parameters(self, axis_names) -> dict:
        """
        Flatten into ROS parameters of the compensation node, without the ``effects.`` prefix.

        ``axis_names`` names the Imu axis of each term. Scalars are floats,
        per-axis values float lists keyed ``<name>.<axis>``; bias steps become
        ``bias_step_time_s.<axis>`` and ``bias_step_rad_s.<axis>``.
        """
        names = tuple(axis_names)
        if len(names) != self.axes:
            msg = f'{len(names)} axis names for {self.axes} axes'
            raise ConfigError(msg)
        parameters = {name: float(getattr(self, name)) for name in _SCALARS}
        for axis, term in zip(names, self.terms):
            for name in _AXIS_SCALARS:
                parameters[f'{name}.{axis}'] = float(getattr(term, name))
            for name in _AXIS_LISTS:
                parameters[f'{name}.{axis}'] = [float(v) for v in getattr(term, name)]
            parameters[f'bias_step_time_s.{axis}'] = [float(time_s)
                                                      for time_s, _ in term.bias_steps]
            parameters[f'bias_step_rad_s.{axis}'] = [float(step_rad_s)
                                                     for _, step_rad_s in term.bias_steps]
        return parameters

    @classmethod
    def from_parameters(cls, parameters: Mapping, axis_names) -> 'EffectModel':
        """Build the model from `to_parameters` output; raise `ConfigError` naming a bad key."""
        def get(key: str, default=None):
            if key in parameters:
                return parameters[key]
            if default is None:
                msg = f'effects parameter {key} is missing'
                raise ConfigError(msg)
            return default

        terms = []
        for axis in axis_names:
            times = list(get(f'bias_step_time_s.{axis}', []))
            steps = list(get(f'bias_step_rad_s.{axis}', []))
            if len(times) != len(steps):
                msg = (f'effects parameters bias_step_time_s.{axis} and bias_step_rad_s.{axis} '
                       f'differ in length ({len(times)} and {len(steps)})')
                raise ConfigError(msg)
            values = {name: get(f'{name}.{axis}', 0.0) for name in _AXIS_SCALARS}
            values.update({name: tuple(get(f'{name}.{axis}', [])) for name in _AXIS_LISTS})
            values['bias'] = tuple(get(f'bias.{axis}'))
            try:
                terms.append(AxisTerms(bias_steps=tuple(zip(times, steps)), **values))
            except ConfigError as err:
                msg = f'effects parameters of axis {axis}: {err}'
                raise ConfigError(msg) from None
        scalars = {name: get(name, _SCALAR_DEFAULTS.get(name)) for name in _SCALARS}
        return cls(terms=tuple(terms), **scalars)

    def with_terms(self, axis: int, **changes) -> 'EffectModel':
        """Return a copy whose terms of ``axis`` (an index) have ``changes``."""
        terms = list(self.terms)
        terms[axis] = replace(terms[axis], **changes)
        return replace(self, terms=tuple(terms))

    def live(self) -> 'EffectModel':
        """Return the model without its RECORD_EFFECTS (time drift, bias steps)."""
        absent = {f.name: f.default for f in fields(AxisTerms)
                  if any(f.name in e.fields for e in EFFECTS if not e.live)}
        return replace(self, terms=tuple(replace(t, **absent) for t in self.terms))


# The parameters of `to_parameters`, in field order: float fields are scalars, tuples
# lists; bias_steps, (time, step) pairs, becomes two lists.
_SCALARS = tuple(f.name for f in fields(EffectModel)
                 if f.name not in ('terms', 'zro_offset_rad_s', 'name'))
# Scalars a parameter file written before they existed may lack.
_SCALAR_DEFAULTS = {'supply_reference_v': DEFAULT_SUPPLY_REFERENCE_V}
_AXIS_SCALARS = tuple(f.name for f in fields(AxisTerms) if f.type is float)
_AXIS_LISTS = tuple(f.name for f in fields(AxisTerms)
                    if f.type is tuple and f.name != 'bias_steps')
_BIAS_EFFECTS = tuple(effect for effect in EFFECTS if effect.bias is not None)
# The node's model parameters that give an effect model.
MODEL_NAMES = ('effects', 'polynomial', 'linear_btc')


def polynomial_model(bias_coefficients, reference_temperature_c: float = 25.0,
                     temperature_scale_c: float = 1.0, scale_coefficients=(),
                     temperature_min_c: float = -math.inf,
                     temperature_max_c: float = math.inf) -> EffectModel:
    """
    Give the ``polynomial`` model: a bias polynomial per axis, optional scale-factor polynomials.

    corrected = (raw - bias(x)) / (1 + sf(x)) - offset, x = (T - Tref) / scale;
    coefficients lowest order first, bias in rad/s, sf relative (0 = nominal),
    scale-factor polynomials for every axis or none. Temperatures outside
    [min, max] are clamped and flagged, as PX4 and ArduPilot do.
    """
    bias = tuple(tuple(float(c) for c in axis) for axis in bias_coefficients)
    if not 1 <= len(bias) <= 3:
        msg = f'polynomial needs bias coefficients for 1 to 3 axes, got {len(bias)}'
        raise ConfigError(msg)
    for axis, coefficients in zip(AXIS_NAMES, bias):
        if not coefficients or not all(math.isfinite(c) for c in coefficients):
            msg = f'polynomial bias coefficients of axis {axis} must be finite and non-empty'
            raise ConfigError(msg)
    scale = tuple(tuple(float(c) for c in axis) for axis in scale_coefficients)
    if scale and len(scale) != len(bias):
        msg = f'polynomial scale coefficients given for {len(scale)} axes, bias for {len(bias)}'
        raise ConfigError(msg)
    if not all(math.isfinite(c) for axis in scale for c in axis):
        raise ConfigError('polynomial scale coefficients must be finite')
    terms = tuple(AxisTerms(bias=b, scale=s) for b, s in zip(bias, scale or ((),) * len(bias)))
    return EffectModel(terms=terms, reference_temperature_c=reference_temperature_c,
                       temperature_scale_c=temperature_scale_c,
                       temperature_min_c=temperature_min_c, temperature_max_c=temperature_max_c,
                       name='polynomial')


@dataclass(frozen=True)
class LinearBtc:
    """
    The ADIS16130 first-order bias correction: RBC = RATE + PBC + (TEMP - T3) x BTC.

    PBC is minus the bias at T3 (rad/s), BTC minus the bias slope (rad/s/degC),
    as the note's Table 6 shows (+0.12 C at a 0.04 deg/s/C slope gives -0.0048 deg/s).
    `model` runs it as the ``linear_btc`` effect model: the bias polynomial
    (-PBC, -BTC) in x = T - T3, which `of` reads back exactly.
    """

    pbc_rad_s: tuple
    btc_rad_s_per_c: tuple
    t3_c: float

    def __post_init__(self) -> None:
        pbc = tuple(float(v) for v in self.pbc_rad_s)
        if not 1 <= len(pbc) <= 3:
            msg = f'linear_btc needs PBC for 1 to 3 axes, got {len(pbc)}'
            raise ConfigError(msg)
        object.__setattr__(self, 'pbc_rad_s', finite_tuple('linear_btc.pbc', pbc, len(pbc)))
        object.__setattr__(self, 'btc_rad_s_per_c',
                           finite_tuple('linear_btc.btc', self.btc_rad_s_per_c, len(pbc)))
        if not math.isfinite(self.t3_c):
            msg = f'linear_btc.t3_c must be finite, got {self.t3_c}'
            raise ConfigError(msg)

    def model(self) -> EffectModel:
        return EffectModel(terms=tuple(AxisTerms(bias=(-pbc, -btc)) for pbc, btc in
                                       zip(self.pbc_rad_s, self.btc_rad_s_per_c)),
                           reference_temperature_c=self.t3_c, name='linear_btc')

    @classmethod
    def of(cls, model: EffectModel) -> 'LinearBtc':
        """Give the coefficients of a ``linear_btc`` model."""
        if model.name != 'linear_btc':
            msg = f'a {model.name} model has no PBC and BTC'
            raise ConfigError(msg)
        return cls(pbc_rad_s=tuple(-term.bias[0] for term in model.terms),
                   btc_rad_s_per_c=tuple(-term.bias[1] for term in model.terms),
                   t3_c=model.reference_temperature_c)
