"""
Bias effects beyond a temperature polynomial, and `EffectModel`, the model that runs them.

`mlx-tempcomp diagnose` adds these effects one by one; the compensation node
runs the result sample by sample through `EffectModel.stream`, which gives the
same numbers as the batch `EffectModel.correct` (to rounding). Per axis, on
raw rate r in rad/s, temperature T in degC and time t in s:

- ``temperature_polynomial``: P(x), x = (T_eff - reference) / scale, T_eff
  clamped to the fitted range;
- ``thermal_lag``: T_eff = T + lag x dT/dt, the die temperature when the
  sensor lags it by a first-order lag (negative: the bias follows a lagged
  temperature); dT/dt is the slope of T over the last ``window`` seconds;
- ``hysteresis``: + h x s, s in [-1, 1] the state of a play operator of
  half width w on T: +1 after heating by 2w, -1 after cooling by 2w;
- ``time_drift``: + d x (t - time_reference);
- ``bias_step``: + the sum of the steps whose time has come;
- ``secondary_temperature``: + Q(x2), x2 = (T2 - reference_2) / scale_2, no
  constant term;
- ``acceleration_sensitivity``: + g . a, a the specific force in m/s^2;
- ``scale_factor_temperature``: u = (r - bias) / (1 + S(x));
- ``rate_nonlinearity``: v = u - (n2 u^2 + n3 u^3 + ...);
- ``cross_axis``: w = v - sum over the other axes j of m_j v_j;

and last the ZRO offset learned at rest: corrected = w - offset.

Stateful inputs (the temperature slope and the play state) start at the first
sample a batch or stream sees, with dT/dt = 0 and s = 0.
"""

import collections
from dataclasses import dataclass, field, fields, replace
import functools
import math
from typing import Mapping, Optional

import numpy as np

from .errors import ConfigError
from .models import _columns, _fingerprint, _finite_tuple, _OffsetModel, CorrectedRate

EFFECT_NAMES = ('temperature_polynomial', 'thermal_lag', 'hysteresis',
                'scale_factor_temperature', 'rate_nonlinearity', 'cross_axis',
                'acceleration_sensitivity', 'time_drift', 'bias_step', 'secondary_temperature')

DEFAULT_RATE_WINDOW_S = 60.0


def temperature_rate_c_s(time_s, temperature_c, window_s: float) -> np.ndarray:
    """
    Return the slope of temperature over the last ``window_s`` seconds, degC/s.

    At sample n: (T[n] - T(t[n] - window_s)) / (t[n] - max(t[n] - window_s, t[0])),
    T between samples by linear interpolation; 0 at the first sample.
    ``temperature_c`` has shape (samples,) or (samples, columns).
    """
    time = np.asarray(time_s, dtype=np.float64)
    temperature = np.asarray(temperature_c, dtype=np.float64)
    columns = temperature.reshape(len(time), -1)
    start = np.maximum(time - window_s, time[0])
    rate = np.empty(columns.shape)
    span = time - start
    for column in range(columns.shape[1]):
        then = np.interp(start, time, columns[:, column])
        with np.errstate(invalid='ignore', divide='ignore'):
            rate[:, column] = np.where(span > 0.0, (columns[:, column] - then) / span, 0.0)
    return rate.reshape(temperature.shape)


def play_state(temperature_c, half_width_c: float) -> np.ndarray:
    """
    Return the state s in [-1, 1] of a play operator of half width ``half_width_c``.

    y starts at the first temperature; y[n] = clip(y[n-1], T[n] - w, T[n] + w);
    s = (T - y) / w. ``temperature_c`` has shape (samples,). Vectorised: until
    y is pushed down, y[n] = max(y_start, running max of T - w), and the mirror
    image after, so numpy works run by run; when runs are short (T reverses by
    2w every few samples) a plain loop finishes, which is then faster.
    """
    temperature = np.asarray(temperature_c, dtype=np.float64)
    played = np.empty(temperature.shape)
    if temperature.size == 0:
        return played
    width = float(half_width_c)
    y = float(temperature[0])
    rising = True
    start = 0
    chunk = _PLAY_CHUNK
    turns = 0
    while start < temperature.size:
        if turns > _PLAY_MIN_RUN and start < _PLAY_MIN_RUN * turns:
            _play_loop(temperature, width, y, start, played)
            break
        segment = temperature[start:start + chunk]
        if rising:
            level = np.maximum(np.maximum.accumulate(segment - width), y)
            turned = np.flatnonzero(segment + width < level)
        else:
            level = np.minimum(np.minimum.accumulate(segment + width), y)
            turned = np.flatnonzero(segment - width > level)
        end = int(turned[0]) if turned.size else segment.size
        played[start:start + end] = level[:end]
        if end:
            y = float(level[end - 1])
        start += end
        if turned.size:
            rising = not rising
            turns += 1
            chunk = _PLAY_CHUNK
        else:
            chunk = min(2 * chunk, _PLAY_CHUNK_MAX)
    return (temperature - played) / width


_PLAY_CHUNK = 64
_PLAY_CHUNK_MAX = 1 << 20
_PLAY_MIN_RUN = 64


def _play_loop(temperature: np.ndarray, width: float, y: float, start: int,
               played: np.ndarray) -> None:
    """Run the play operator sample by sample from ``start`` into ``played``."""
    values = temperature[start:].tolist()
    out = [0.0] * len(values)
    for i, value in enumerate(values):
        if y < value - width:
            y = value - width
        elif y > value + width:
            y = value + width
        out[i] = y
    played[start:] = out


def _polynomial(name: str, values) -> tuple:
    values = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in values):
        msg = f'{name} must be finite, got {list(values)}'
        raise ConfigError(msg)
    return values


@dataclass(frozen=True)
class AxisTerms:
    """
    The bias terms of one axis; empty tuples and zeros mean the effect is absent.

    ``bias`` is the temperature polynomial in rad/s, lowest order first;
    ``secondary`` starts at the power 1 of x2; ``nonlinearity`` at u^2 (rad/s
    per (rad/s)^k); ``cross_axis`` has one coefficient per model axis (its
    own 0); ``acceleration_rad_s_per_m_s2`` one per x, y, z of the specific
    force; ``bias_steps`` holds (time_s, rad_s) pairs.
    """

    bias: tuple
    thermal_lag_s: float = 0.0
    hysteresis_half_width_c: float = 0.0
    hysteresis_rad_s: float = 0.0
    time_drift_rad_s_per_s: float = 0.0
    bias_steps: tuple = ()
    secondary: tuple = ()
    acceleration_rad_s_per_m_s2: tuple = ()
    scale: tuple = ()
    nonlinearity: tuple = ()
    cross_axis: tuple = ()

    def __post_init__(self) -> None:
        bias = _polynomial('bias', self.bias)
        if not bias:
            raise ConfigError('bias needs at least one coefficient')
        object.__setattr__(self, 'bias', bias)
        for name in ('thermal_lag_s', 'hysteresis_half_width_c', 'hysteresis_rad_s',
                     'time_drift_rad_s_per_s'):
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
        steps = tuple(_polynomial('bias_steps', pair) for pair in self.bias_steps)
        if any(len(pair) != 2 for pair in steps):
            raise ConfigError('bias_steps must be (time_s, rad_s) pairs')
        object.__setattr__(self, 'bias_steps', steps)
        for name in ('secondary', 'scale', 'nonlinearity', 'cross_axis',
                     'acceleration_rad_s_per_m_s2'):
            object.__setattr__(self, name, _polynomial(name, getattr(self, name)))
        if self.acceleration_rad_s_per_m_s2 and len(self.acceleration_rad_s_per_m_s2) != 3:
            msg = ('acceleration_rad_s_per_m_s2 needs 3 values (x, y, z), got '
                   f'{len(self.acceleration_rad_s_per_m_s2)}')
            raise ConfigError(msg)

    @property
    def effects(self) -> tuple:
        """Names of the effects these terms hold, in EFFECT_NAMES order."""
        present = {
            'temperature_polynomial': True,
            'thermal_lag': self.thermal_lag_s != 0.0,
            'hysteresis': self.hysteresis_rad_s != 0.0,
            'scale_factor_temperature': any(self.scale),
            'rate_nonlinearity': any(self.nonlinearity),
            'cross_axis': any(self.cross_axis),
            'acceleration_sensitivity': any(self.acceleration_rad_s_per_m_s2),
            'time_drift': self.time_drift_rad_s_per_s != 0.0,
            'bias_step': bool(self.bias_steps),
            'secondary_temperature': any(self.secondary),
        }
        return tuple(name for name in EFFECT_NAMES if present[name])


@dataclass(frozen=True)
class EffectModel(_OffsetModel):
    """
    Temperature polynomial plus diagnosed effects, per axis; see the module docstring.

    ``terms`` holds one `AxisTerms` per axis. Temperatures (T_eff) outside
    [temperature_min_c, temperature_max_c] are clamped and flagged.
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
    zro_offset_rad_s: tuple = field(default=())

    name = 'effects'

    def __post_init__(self) -> None:
        terms = tuple(self.terms)
        if not 1 <= len(terms) <= 3 or not all(isinstance(t, AxisTerms) for t in terms):
            msg = f'effects model needs AxisTerms for 1 to 3 axes, got {len(terms)}'
            raise ConfigError(msg)
        object.__setattr__(self, 'terms', terms)
        for name in ('reference_temperature_c', 'temperature_scale_c',
                     'temperature_rate_window_s', 'time_reference_s', 'secondary_reference_c',
                     'secondary_scale_c'):
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
                           _finite_tuple('zro_offset_rad_s', offset, len(terms)))

    @property
    def axes(self) -> int:
        return len(self.terms)

    # Cached (the model is frozen): the stream asks for these on every sample.
    @functools.cached_property
    def needs_time(self) -> bool:
        return any(t.thermal_lag_s or t.time_drift_rad_s_per_s or t.bias_steps
                   for t in self.terms)

    @functools.cached_property
    def needs_temperature_2(self) -> bool:
        return any(any(t.secondary) for t in self.terms)

    @functools.cached_property
    def needs_acceleration(self) -> bool:
        return any(any(t.acceleration_rad_s_per_m_s2) for t in self.terms)

    @functools.cached_property
    def has_cross_axis(self) -> bool:
        return any(any(t.cross_axis) for t in self.terms)

    def fingerprint(self) -> str:
        content = {f.name: getattr(self, f.name) for f in fields(self)
                   if f.name not in ('terms', 'zro_offset_rad_s')}
        content['terms'] = [{f.name: getattr(t, f.name) for f in fields(t)} for t in self.terms]
        return _fingerprint(self.name, content)

    def correct(self, rate_rad_s, temperature_c, time_s=None, temperature_2_c=None,
                acceleration_m_s2=None) -> CorrectedRate:
        """
        Correct a batch; stateful inputs start at its first sample.

        rate (samples, axes) rad/s; temperature (samples,) or (samples, axes)
        degC; time (samples,) s, needed by thermal_lag, time_drift and
        bias_step; temperature_2 (samples,) by secondary_temperature;
        acceleration (samples, 3) m/s^2 by acceleration_sensitivity.
        """
        rate, temperature = _columns(rate_rad_s, temperature_c, self.axes)
        samples = rate.shape[0]
        time = self._input('time_s', time_s, (samples,), self.needs_time)
        temperature_2 = self._input('temperature_2_c', temperature_2_c, (samples,),
                                    self.needs_temperature_2)
        acceleration = self._input('acceleration_m_s2', acceleration_m_s2, (samples, 3),
                                   self.needs_acceleration)
        slope = None if time is None else \
            temperature_rate_c_s(time, temperature, self.temperature_rate_window_s)
        bias = np.empty(rate.shape)
        x = np.empty(rate.shape)
        clamped = np.isnan(temperature)
        for axis, term in enumerate(self.terms):
            effective = temperature[:, axis]
            if term.thermal_lag_s:
                effective = effective + term.thermal_lag_s * slope[:, axis]
            limited = np.clip(effective, self.temperature_min_c, self.temperature_max_c)
            clamped[:, axis] |= limited != effective
            x[:, axis] = (limited - self.reference_temperature_c) / self.temperature_scale_c
            total = np.polynomial.polynomial.polyval(x[:, axis], term.bias)
            if term.hysteresis_rad_s:
                total = total + term.hysteresis_rad_s * play_state(
                    temperature[:, axis], term.hysteresis_half_width_c)
            if term.time_drift_rad_s_per_s:
                total = total + term.time_drift_rad_s_per_s * (time - self.time_reference_s)
            for when_s, step_rad_s in term.bias_steps:
                total = total + np.where(time >= when_s, step_rad_s, 0.0)
            if any(term.secondary):
                x2 = (temperature_2 - self.secondary_reference_c) / self.secondary_scale_c
                total = total + x2 * np.polynomial.polynomial.polyval(x2, term.secondary)
            if any(term.acceleration_rad_s_per_m_s2):
                total = total + acceleration @ np.asarray(term.acceleration_rad_s_per_m_s2)
            bias[:, axis] = total
        corrected = rate - bias
        for axis, term in enumerate(self.terms):
            if any(term.scale):
                scale = np.polynomial.polynomial.polyval(x[:, axis], term.scale)
                corrected[:, axis] /= 1.0 + scale
            if any(term.nonlinearity):
                u = corrected[:, axis]
                corrected[:, axis] = u - u * u * np.polynomial.polynomial.polyval(
                    u, term.nonlinearity)
        if self.has_cross_axis:
            matrix = np.array([t.cross_axis or (0.0,) * self.axes for t in self.terms])
            corrected = corrected - corrected @ matrix.T
        return CorrectedRate(corrected - np.asarray(self.zro_offset_rad_s), clamped)

    @staticmethod
    def _input(name: str, value, shape: tuple, needed: bool) -> Optional[np.ndarray]:
        if value is None:
            if needed:
                msg = f'the effects model needs {name} for its effects'
                raise ConfigError(msg)
            return None
        array = np.asarray(value, dtype=np.float64)
        if array.shape != shape:
            msg = f'{name} must have shape {shape}, got {array.shape}'
            raise ConfigError(msg)
        return array

    def stream(self) -> 'EffectStream':
        """Return a sample-by-sample runner whose state starts empty."""
        return EffectStream(self)

    def correct_sample(self, rates_rad_s, temperatures_c, time_s=None, temperature_2_c=None,
                       acceleration_m_s2=None) -> tuple:
        """Refuse: this model has state; use `stream` to correct sample by sample."""
        raise ConfigError('the effects model keeps state: correct samples through stream()')

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
            parameters[f'bias_step_time_s.{axis}'] = [float(s[0]) for s in term.bias_steps]
            parameters[f'bias_step_rad_s.{axis}'] = [float(s[1]) for s in term.bias_steps]
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
        return cls(terms=tuple(terms), **{name: get(name) for name in _SCALARS})

    def with_terms(self, axis: int, **changes) -> 'EffectModel':
        """Return a copy whose terms of ``axis`` (an index) have ``changes``."""
        terms = list(self.terms)
        terms[axis] = replace(terms[axis], **changes)
        return replace(self, terms=tuple(terms))


_SCALARS = ('reference_temperature_c', 'temperature_scale_c', 'temperature_min_c',
            'temperature_max_c', 'temperature_rate_window_s', 'time_reference_s',
            'secondary_reference_c', 'secondary_scale_c')
_AXIS_SCALARS = ('thermal_lag_s', 'hysteresis_half_width_c', 'hysteresis_rad_s',
                 'time_drift_rad_s_per_s')
_AXIS_LISTS = ('bias', 'secondary', 'acceleration_rad_s_per_m_s2', 'scale', 'nonlinearity',
               'cross_axis')


class EffectStream:
    """
    Runs an `EffectModel` one sample at a time, keeping the temperature history and play state.

    Gives what `EffectModel.correct` gives on the same samples as one batch.
    """

    def __init__(self, model: EffectModel):
        self.model = model
        self.history = [collections.deque() for _ in model.terms]
        self.played = [None] * model.axes

    def _slope(self, axis: int, time_s: float, temperature_c: float) -> float:
        history = self.history[axis]
        history.append((time_s, temperature_c))
        first_s = history[0][0]
        start_s = max(time_s - self.model.temperature_rate_window_s, first_s)
        # Keep one sample at or before the window start, for the interpolation.
        while len(history) > 2 and history[1][0] <= start_s:
            history.popleft()
        span = time_s - start_s
        if span <= 0.0:
            return 0.0
        (t0, v0), (t1, v1) = history[0], history[1]
        then = v0 if start_s <= t0 else v0 + (v1 - v0) / (t1 - t0) * (start_s - t0)
        return (temperature_c - then) / span

    def correct_sample(self, rates_rad_s, temperatures_c, time_s=None, temperature_2_c=None,
                       acceleration_m_s2=None) -> tuple:
        """
        Return (corrected rad/s per axis as a list, whether a temperature was clamped).

        ``temperatures_c`` holds one temperature, or one per axis.
        """
        model = self.model
        axes = model.axes
        if len(rates_rad_s) != axes:
            msg = f'{len(rates_rad_s)} rates for {axes} axes'
            raise ConfigError(msg)
        temperatures = list(temperatures_c) if len(temperatures_c) == axes else \
            [temperatures_c[0]] * axes
        for name, value, needed in (('time_s', time_s, model.needs_time),
                                    ('temperature_2_c', temperature_2_c,
                                     model.needs_temperature_2),
                                    ('acceleration_m_s2', acceleration_m_s2,
                                     model.needs_acceleration)):
            if needed and value is None:
                msg = f'the effects model needs {name} for its effects'
                raise ConfigError(msg)
        corrected = []
        xs = []
        clamped = False
        for axis, term in enumerate(model.terms):
            temperature = float(temperatures[axis])
            effective = temperature
            if term.thermal_lag_s:
                effective += term.thermal_lag_s * self._slope(axis, float(time_s), temperature)
            limited = min(max(effective, model.temperature_min_c), model.temperature_max_c)
            clamped = clamped or limited != effective or math.isnan(temperature)
            x = (limited - model.reference_temperature_c) / model.temperature_scale_c
            xs.append(x)
            bias = float(np.polynomial.polynomial.polyval(x, term.bias))
            if term.hysteresis_rad_s:
                bias += term.hysteresis_rad_s * self._play(axis, temperature,
                                                           term.hysteresis_half_width_c)
            if term.time_drift_rad_s_per_s:
                bias += term.time_drift_rad_s_per_s * (time_s - model.time_reference_s)
            for when_s, step_rad_s in term.bias_steps:
                if time_s >= when_s:
                    bias += step_rad_s
            if any(term.secondary):
                x2 = (temperature_2_c - model.secondary_reference_c) / model.secondary_scale_c
                bias += x2 * float(np.polynomial.polynomial.polyval(x2, term.secondary))
            if any(term.acceleration_rad_s_per_m_s2):
                bias += sum(g * a for g, a in zip(term.acceleration_rad_s_per_m_s2,
                                                  acceleration_m_s2))
            corrected.append(float(rates_rad_s[axis]) - bias)
        for axis, term in enumerate(model.terms):
            if any(term.scale):
                corrected[axis] /= 1.0 + float(np.polynomial.polynomial.polyval(xs[axis],
                                                                                term.scale))
            if any(term.nonlinearity):
                u = corrected[axis]
                corrected[axis] = u - u * u * float(np.polynomial.polynomial.polyval(
                    u, term.nonlinearity))
        if model.has_cross_axis:
            before = list(corrected)
            for axis, term in enumerate(model.terms):
                if term.cross_axis:
                    corrected[axis] = before[axis] - sum(m * v for m, v in
                                                         zip(term.cross_axis, before))
        return [v - o for v, o in zip(corrected, model.zro_offset_rad_s)], clamped

    def _play(self, axis: int, temperature_c: float, half_width_c: float) -> float:
        y = self.played[axis]
        if y is None:
            y = temperature_c
        if y < temperature_c - half_width_c:
            y = temperature_c - half_width_c
        elif y > temperature_c + half_width_c:
            y = temperature_c + half_width_c
        self.played[axis] = y
        return (temperature_c - y) / half_width_c
