"""
The history operators: what the effects that depend on a temperature's past see of it.

`TemperatureSlope` (the windowed dT/dt of thermal lag and temperature rate),
`FirstOrderLag` (the negative thermal lag, the thermal gradients) and
`PlayOperator` (hysteresis) each have a batch form, vectorised over a whole
record, and a runner (`runner()`) that steps one sample at a time and gives
the same recursion. They start at the first sample a batch or runner sees:
slope 0, lag and play at the first temperature (the device in equilibrium at
power-up). `History` is what they give one axis, for the bias terms.
"""

import collections
from dataclasses import dataclass
import math
from typing import Any, NamedTuple

import numpy as np

from ..errors import ConfigError

DEFAULT_RATE_WINDOW_S = 60.0


@dataclass(frozen=True)
class TemperatureSlope:
    """
    Slope of temperature over the last ``window_s`` seconds, degC/s.

    At sample n: (T[n] - T(t[n] - window_s)) / (t[n] - max(t[n] - window_s, t[0])),
    T between samples by linear interpolation; 0 at the first sample.
    """

    window_s: float

    def batch(self, time_s, temperature_c) -> np.ndarray:
        """Return the slope at every sample; ``temperature_c`` (samples,) or (samples, k)."""
        time = np.asarray(time_s, dtype=np.float64)
        temperature = np.asarray(temperature_c, dtype=np.float64)
        columns = temperature.reshape(len(time), -1)
        start = np.maximum(time - self.window_s, time[0])
        rate = np.empty(columns.shape)
        span = time - start
        for column in range(columns.shape[1]):
            then = np.interp(start, time, columns[:, column])
            with np.errstate(invalid='ignore', divide='ignore'):
                rate[:, column] = np.where(span > 0.0, (columns[:, column] - then) / span, 0.0)
        return rate.reshape(temperature.shape)

    def runner(self) -> '_SlopeRunner':
        return _SlopeRunner(self.window_s)


class _SlopeRunner:
    """`TemperatureSlope` one sample at a time."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self.times_s = collections.deque()
        self.temperatures_c = collections.deque()

    def step(self, time_s: float, temperature_c: float) -> float:
        times, temperatures = self.times_s, self.temperatures_c
        times.append(time_s)
        temperatures.append(temperature_c)
        start_s = max(time_s - self.window_s, times[0])
        # Keep one sample at or before the window start, for the interpolation.
        while len(times) > 2 and times[1] <= start_s:
            times.popleft()
            temperatures.popleft()
        span = time_s - start_s
        if span <= 0.0:
            return 0.0
        t0, t1, v0, v1 = times[0], times[1], temperatures[0], temperatures[1]
        then = v0 if start_s <= t0 else v0 + (v1 - v0) / (t1 - t0) * (start_s - t0)
        return (temperature_c - then) / span


def temperature_rate_c_s(time_s, temperature_c, window_s: float) -> np.ndarray:
    """Return the slope of temperature over the last ``window_s`` seconds (`TemperatureSlope`)."""
    return TemperatureSlope(window_s).batch(time_s, temperature_c)


# Rows of one vectorised stretch of the first-order lag span at most this many time
# constants, so exp(span / tau) stays far from overflow.
_LAG_SPAN = 400.0


@dataclass(frozen=True)
class FirstOrderLag:
    """
    A first-order lag of time constant ``time_constant_s``: y' = (x - y) / tau.

    Discretised as y[n] = a y[n-1] + (1 - a) x[n], a = exp(-(t[n] - t[n-1]) / tau),
    y[0] = x[0]: exact for an input held at each sample's value since the one
    before, and the same recursion sample by sample and in a batch.
    """

    time_constant_s: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.time_constant_s) and self.time_constant_s > 0.0):
            msg = f'a first-order lag needs a positive time constant, got {self.time_constant_s}'
            raise ConfigError(msg)

    def batch(self, time_s, values) -> np.ndarray:
        """
        Return the lagged values, vectorised.

        Inside a stretch from row s: y[n] = A[n] (y[s] + sum over s < k <= n of
        (1 - a[k]) x[k] / A[k]), A[n] = exp(-(t[n] - t[s]) / tau); stretches are
        chained by the plain recursion.
        """
        time = np.asarray(time_s, dtype=np.float64)
        x = np.asarray(values, dtype=np.float64)
        lagged = np.empty(x.shape)
        if x.size == 0:
            return lagged
        elapsed = (time - time[0]) / self.time_constant_s
        weight = -np.expm1(-np.maximum(np.diff(elapsed), 0.0))   # 1 - a[k], k >= 1
        stretch = np.floor(elapsed / _LAG_SPAN).astype(np.int64)
        edges = np.flatnonzero(np.diff(stretch)) + 1
        previous = float(x[0])
        lagged[0] = previous
        for start, stop in zip(np.concatenate(([1], edges)), np.append(edges, x.size)):
            if start >= stop:
                continue
            first = previous + weight[start - 1] * (x[start] - previous)
            lagged[start] = first
            if stop - start > 1:
                decay = elapsed[start:stop] - elapsed[start]
                growth = np.exp(decay[1:])
                total = np.cumsum(weight[start:stop - 1] * x[start + 1:stop] * growth)
                lagged[start + 1:stop] = (first + total) / growth
            previous = float(lagged[stop - 1])
        return lagged

    def runner(self) -> '_LagRunner':
        return _LagRunner(self.time_constant_s)


class _LagRunner:
    """`FirstOrderLag` one sample at a time."""

    def __init__(self, time_constant_s: float):
        self.time_constant_s = time_constant_s
        self.time_s = None
        self.value = None

    def step(self, time_s: float, value: float) -> float:
        if self.value is None:
            self.value = value
        else:
            weight = -math.expm1(-max(time_s - self.time_s, 0.0) / self.time_constant_s)
            self.value += weight * (value - self.value)
        self.time_s = time_s
        return self.value


@dataclass(frozen=True)
class PlayOperator:
    """
    Play operator of half width ``half_width_c`` on temperature; state s in [-1, 1].

    y starts at the first temperature; y[n] = clip(y[n-1], T[n] - w, T[n] + w);
    s = (T - y) / w: +1 after heating by 2w, -1 after cooling by 2w.
    """

    half_width_c: float

    def batch(self, temperature_c) -> np.ndarray:
        return play_state(temperature_c, self.half_width_c)

    def runner(self) -> '_PlayRunner':
        return _PlayRunner(self.half_width_c)


class _PlayRunner:
    """`PlayOperator` one sample at a time."""

    def __init__(self, half_width_c: float):
        self.half_width_c = half_width_c
        self.played = None

    def step(self, temperature_c: float) -> float:
        width = self.half_width_c
        y = temperature_c if self.played is None else self.played
        if y < temperature_c - width:
            y = temperature_c - width
        elif y > temperature_c + width:
            y = temperature_c + width
        self.played = y
        return (temperature_c - y) / width


def play_state(temperature_c, half_width_c: float) -> np.ndarray:
    """
    Return the state s in [-1, 1] of a play operator of half width ``half_width_c``.

    See `PlayOperator`. ``temperature_c`` has shape (samples,). Vectorised:
    until y is pushed down, y[n] = max(y_start, running max of T - w), and the
    mirror image after, so numpy works run by run; when runs are short (T
    reverses by 2w every few samples) a plain loop finishes, which is then
    faster.
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


class History(NamedTuple):
    """What the history operators give one axis: columns of a block or one row's floats."""

    slope: Any        # None: not needed
    lagged: Any
    gradients: list
    play: Any


NO_HISTORY = History(slope=None, lagged=None, gradients=[], play=None)
