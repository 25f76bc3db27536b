"""
Bias tracking at standstill: the offset the temperature model leaves, followed while still.

`BiasTracking` takes the rate after the temperature model and gives it less the tracked
offset, the offset's standard deviation and whether the gyro is still, sample by sample.
Per axis, a scalar Kalman filter holds the offset relative to the model as a bounded
random walk (first-order Gauss-Markov): its variance grows by q dt at first (q =
``random_walk_rad_s_rt_s`` squared, the unit's own wander) and levels off at
``initial_std_rad_s`` squared (what is known without tracking: the model's own error),
as the offset fades back to the model, with the time constant 2 initial_std^2 / q; each
window the `StandstillDetector` says to learn from is a measurement of the offset on the
axes it does not hold, its mean, with the variance noise^2 / samples. In motion nothing
is learnt: the temperature model carries the shape, the offset stays (and fades).

- **Shifts.** When the gyro has just become still and its first window's innovation is
  beyond ``agreement_multiple`` standard deviations (a bias step, or the bias moved in a
  long motion), the variance is widened by the innovation squared so that the windows
  that agreed on the shift are taken at once: a step is followed within the
  ``enter_windows`` still windows.
- **Slow ramps.** Within a still run the offset measured may move from where the run
  began by ``agreement_multiple`` standard deviations of its random walk at most (per
  axis; with an accelerometer its part along gravity), else the run ends; and a shift a
  turn could explain (without an accelerometer any, with one its part along gravity) is
  provisional: undone unless the run holds it `CONFIRM_WINDOWS` windows more, or twice as
  long as the run before it held when that one drifted out. A ramp, which looks like a
  staircase of steps, is never followed past a provisional step.
- **Rest hints.** When the robot says it is at rest (`hint`, or a 0/1 column given to
  `process`; `core.standstill.rest_hints` says when a window counts as hinted), the detector holds
  no axis of a hinted window: an offset of any size is taken. A still run whose windows
  were all hinted begins with a shift that is not provisional: a turn cannot explain it.
  The spread, temperature, accelerometer and agreement tests still apply, and so does the
  drift guard (a run that drifts out starts again, and a hinted one shifts at once).
  What a hinted window taught becomes the offset's zero: in motion the offset fades back
  to it, not to the model (a hint says the offset is real, e.g. a supply's shift).
  ``zero_at_start`` counts every window as hinted until the first still run begins, as a
  flight controller zeroes its gyro at boot: a robot started while turning slowly takes
  the turn for its offset.

Every sample goes through the same steps whether it comes in a block (`process`, numpy)
or alone (`process_one`, plain floats): the offset changes only when a window closes,
the window sums are added in sample order, the decisions are plain floats. Any split
into blocks gives the same bits (``test/core/test_fuzz_bias_tracking.py``).

`seed` sets the offset and its variance (the ZRO recalibration's window); `state` gives
a plain dict for a state file and `tracking_state` checks one read back.

What a learner beside it reads (`core.learning`): ``learnt``, the windows the last closed
window made it learn from; ``runs``, the still runs begun, and `in_run`; `open_window` and
`advance`, which closes the open window before a sample that lies outside it, so a
correction taken off before the tracker can change exactly where a window starts.
"""

from dataclasses import dataclass, replace
import math
from typing import Optional

import numpy as np

from .detector import (per_axis, StandstillDetector, StandstillSettings, WindowStatistics,
                       WindowSums)
from .rest_hints import RestHints
from ..errors import CalibrationError, ConfigError


@dataclass(frozen=True)
class TrackingSettings:
    """
    The detector's settings, the offset's prior and when it counts as stable.

    ``initial_std_rad_s`` (one per axis): the offset's standard deviation before any
    window, and the most its variance grows to in motion. ``stable_std_rad_s``: an
    axis's estimate is stable while its standard deviation is at most this and it has
    learnt from a window or a seed. ``rest_hint_max_age_s``: how long a rest hint says
    what it says (`core.standstill.rest_hints`); ``zero_at_start``: every window counts as hinted
    until the first still run begins.
    """

    standstill: StandstillSettings
    initial_std_rad_s: tuple
    stable_std_rad_s: float = math.radians(0.05)
    rest_hint_max_age_s: float = 1.0
    zero_at_start: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, 'initial_std_rad_s', per_axis(
            'initial_std_rad_s', self.initial_std_rad_s, self.standstill.axes))
        if not (math.isfinite(self.stable_std_rad_s) and self.stable_std_rad_s > 0.0):
            msg = f'stable_std_rad_s must be a positive number, got {self.stable_std_rad_s!r}'
            raise ConfigError(msg)
        age = self.rest_hint_max_age_s
        if isinstance(age, bool) or not isinstance(age, (int, float)) or \
                not (math.isfinite(age) and age > 0.0):
            msg = f'rest_hint_max_age_s must be a positive number, got {age!r}'
            raise ConfigError(msg)
        if not isinstance(self.zero_at_start, bool):
            msg = f'zero_at_start must be true or false, got {self.zero_at_start!r}'
            raise ConfigError(msg)


@dataclass(frozen=True)
class TrackedBlock:
    """Per sample: the rate less the offset, the offset's standard deviation, still or not."""

    rate_rad_s: np.ndarray
    std_rad_s: np.ndarray
    still: np.ndarray


@dataclass(frozen=True)
class TrackingStatus:
    """What the tracker holds now (for /diagnostics and the bias topic)."""

    still: bool
    offset_rad_s: tuple
    std_rad_s: tuple
    stable: tuple
    updates: int
    last_update_s: Optional[float]
    windows: int
    reason: str
    # Per axis: its mean was beyond the bound in the last window (a turn it may see).
    held: tuple
    # The last window was hinted (the robot said at rest over all of it).
    hinted: bool = False


@dataclass(frozen=True)
class WindowRecord:
    """One closed window as the tracker judged it (kept with ``keep_windows``)."""

    start_s: float
    end_s: float
    samples: int
    quiet: bool
    still: bool
    # The (start_s, end_s, axes) of each window learnt when this one closed.
    learnt: tuple
    reason: str
    offset_rad_s: tuple
    hinted: bool = False


# A still run that began with a shift must hold it this many windows more (at least), or
# the shift is undone.
CONFIRM_WINDOWS = 4


@dataclass
class _StillRun:
    """Where a still run began: the offset and variance after its first windows."""

    offset_rad_s: tuple
    variance: tuple
    time_s: float
    # The filter before a shift the run began with (None: no shift), and how many more
    # windows must agree with it before it stays.
    before: Optional[tuple]
    unconfirmed: int
    windows: int


STATE_KEYS = ('offset_rad_s', 'variance_rad2_s2', 'time_s', 'updates', 'last_update_s')


@dataclass(frozen=True)
class TrackingState:
    """The filter's state, as a state file holds it (see `BiasTracking.state`)."""

    offset_rad_s: tuple
    variance_rad2_s2: tuple
    time_s: Optional[float]
    updates: int
    last_update_s: Optional[float]
    # What the offset fades to (set by a hinted window); None: the model (0).
    zero_rad_s: Optional[tuple] = None


def _number(state: dict, key: str, index=None, low=-math.inf, high=math.inf,
            integer=False):
    value = state[key] if index is None else state[key][index]
    name = key if index is None else f'{key}[{index}]'
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (integer and not isinstance(value, int)):
        kind = 'an integer' if integer else 'a number'
        raise CalibrationError(f'{name} must be {kind}, got {value!r}')
    if not math.isfinite(value) or not low <= value <= high:
        raise CalibrationError(f'{name} {value!r} is outside {low:g} to {high:g}')
    return value if integer else float(value)


def tracking_state(state, axes: int, max_offset_rad_s: float = math.inf) -> TrackingState:
    """
    Check a state dict read back (`BiasTracking.state`); CalibrationError names the key.

    Offsets within +-``max_offset_rad_s`` (the full scale), variances >= 0, times
    finite (``time_s`` and ``last_update_s`` may be null: never), ``updates`` >= 0;
    ``zero_rad_s`` (written once a hint taught the tracker) like the offsets, or absent.
    """
    if not isinstance(state, dict):
        raise CalibrationError(f'the tracking state must be a mapping, got {state!r}')
    missing = [key for key in STATE_KEYS if key not in state]
    if missing:
        raise CalibrationError(f'damaged: {", ".join(missing)} missing (truncated?)')
    lists = ('offset_rad_s', 'variance_rad2_s2') + (('zero_rad_s',) if 'zero_rad_s' in state
                                                    else ())
    for key in lists:
        if not isinstance(state[key], list) or len(state[key]) != axes:
            raise CalibrationError(f'{key} must be a list of {axes} values, got {state[key]!r}')
    offset = tuple(_number(state, 'offset_rad_s', i, -max_offset_rad_s, max_offset_rad_s)
                   for i in range(axes))
    variance = tuple(_number(state, 'variance_rad2_s2', i, 0.0) for i in range(axes))
    times = [None if state[key] is None else _number(state, key)
             for key in ('time_s', 'last_update_s')]
    zero = tuple(_number(state, 'zero_rad_s', i, -max_offset_rad_s, max_offset_rad_s)
                 for i in range(axes)) if 'zero_rad_s' in state else None
    return TrackingState(offset_rad_s=offset, variance_rad2_s2=variance, time_s=times[0],
                         updates=_number(state, 'updates', low=0, integer=True),
                         last_update_s=times[1], zero_rad_s=zero)


class BiasTracking:
    """
    The standstill detector and the offset filter over a stream; see the module notes.

    ``axes`` names the gyro axes (x, y, z: which specific force axis is which);
    ``state`` a checked `TrackingState` to start from; ``keep_windows`` keeps a
    `WindowRecord` of every closed window in ``windows`` (the offline twin's report);
    ``hints`` the `RestHints` to judge windows with (the node keeps one across trackers;
    None: made at the first hint). ``zeroing`` is true until the start-up zeroing is done
    (``zero_at_start``; the node clears it for a tracker rebuilt after its start).
    """

    def __init__(self, settings: TrackingSettings, axes: tuple,
                 state: Optional[TrackingState] = None, keep_windows: bool = False,
                 hints: Optional[RestHints] = None):
        self.settings = settings
        self.hints = hints
        self.zeroing = settings.zero_at_start
        self.axes = tuple(axes)
        self._detector = StandstillDetector(settings.standstill, self.axes)
        standstill = settings.standstill
        self._q = [w * w for w in standstill.random_walk_rad_s_rt_s]
        self._noise2 = [s * s for s in standstill.rate_noise_rad_s]
        self._cap = [s * s for s in settings.initial_std_rad_s]
        self._offset = [0.0] * len(self.axes)
        self._variance = list(self._cap)
        self._time_s = None
        self._zero = None
        self.updates = 0
        self.last_update_s = None
        if state is not None:
            self._restore(state)
        self._std = [math.sqrt(v) for v in self._variance]
        self._window = None
        self._origin_s = None
        self.window_count = 0
        self.held = (False,) * len(self.axes)
        self.hinted = False
        self._still = False
        self.withdrawn = 0
        self._run = None
        self._drifted_windows = 0
        self.reason = 'no window yet'
        self.windows = [] if keep_windows else None
        # (WindowStatistics, axes) learnt when the last window closed; still runs begun.
        self.learnt = ()
        self.runs = 0

    def _restore(self, state: TrackingState) -> None:
        if len(state.offset_rad_s) != len(self.axes):
            msg = f'the tracking state has {len(state.offset_rad_s)} axes, not {len(self.axes)}'
            raise CalibrationError(msg)
        self._offset = list(state.offset_rad_s)
        self._variance = list(state.variance_rad2_s2)
        self._time_s = state.time_s
        self._zero = None if state.zero_rad_s is None else list(state.zero_rad_s)
        self.updates = state.updates
        self.last_update_s = state.last_update_s

    @property
    def still(self) -> bool:
        """Tell whether the gyro is still now: in a still run, no axis held."""
        return self._still

    @property
    def in_run(self) -> bool:
        """Tell whether a still run is going on (its windows learnt, not yet ended)."""
        return self._run is not None

    @property
    def open_window(self) -> Optional[tuple]:
        """Give the (start_s, end_s) of the open window; None before the first sample."""
        return None if self._window is None else (self._window.start_s, self._window.end_s)

    def advance(self, time_s: float) -> bool:
        """
        Close the open window if a sample at ``time_s`` lies outside it, as that sample would.

        Tell whether it closed. The sample itself is then given to `process` or
        `process_one` as usual (its window is open).
        """
        window = self._window
        if window is None or not math.isfinite(time_s) or \
                window.start_s <= time_s < window.end_s:
            return False
        self._roll(time_s)
        return True

    def seed(self, offset_rad_s, variance_rad2_s2, time_s: Optional[float] = None) -> None:
        """Set the offset and its variance (a ZRO recalibration's mean and noise^2 / n)."""
        offset = [float(v) for v in offset_rad_s]
        variance = [float(v) for v in variance_rad2_s2]
        if len(offset) != len(self.axes) or len(variance) != len(self.axes) or \
                not all(math.isfinite(v) for v in offset) or \
                not all(math.isfinite(v) and v >= 0.0 for v in variance):
            msg = (f'a seed needs {len(self.axes)} finite offsets and variances >= 0, got '
                   f'{offset} and {variance}')
            raise CalibrationError(msg)
        self._offset, self._variance = offset, variance
        self._std = [math.sqrt(v) for v in variance]
        self._run = None
        self._zero = None
        # An operator's re-zero is the start-up zeroing's job done.
        self.zeroing = False
        if time_s is not None:
            self._time_s = float(time_s)

    def state(self) -> dict:
        """Give the state as plain YAML-safe values (`tracking_state` checks it back)."""
        state = {'offset_rad_s': list(self._offset), 'variance_rad2_s2': list(self._variance),
                 'time_s': self._time_s, 'updates': self.updates,
                 'last_update_s': self.last_update_s}
        if self._zero is not None:
            state['zero_rad_s'] = list(self._zero)
        return state

    def status(self) -> TrackingStatus:
        """Give what the tracker holds now."""
        learnt = self.updates > 0 or self._variance != self._cap
        return TrackingStatus(
            still=self.still, offset_rad_s=tuple(self._offset), std_rad_s=tuple(self._std),
            stable=tuple(learnt and s <= self.settings.stable_std_rad_s for s in self._std),
            updates=self.updates, last_update_s=self.last_update_s, windows=self.window_count,
            reason=self.reason, held=self.held, hinted=self.hinted)

    def hint(self, time_s: float, at_rest: bool) -> None:
        """Take a rest hint at ``time_s`` (sample time, s): at rest or moving from then on."""
        if self.hints is None:
            self.hints = RestHints()
        self.hints.add(time_s, at_rest)

    # The stream.

    def process(self, time_s, rate_rad_s, temperature_c, acceleration_m_s2=None,
                rest_hint=None) -> TrackedBlock:
        """
        Track over a block of samples in time order; give them less the offset.

        ``time_s`` (n,), ``rate_rad_s`` (n, axes) after the temperature model,
        ``temperature_c`` (n,), ``acceleration_m_s2`` (n, 3) or None (no accelerometer),
        ``rest_hint`` (n,) booleans or None: each sample's own hint (the offline twin).
        """
        time_s = np.asarray(time_s, dtype=np.float64).reshape(-1)
        rows = time_s.size
        rate = np.asarray(rate_rad_s, dtype=np.float64).reshape(rows, len(self.axes))
        temperature = np.asarray(temperature_c, dtype=np.float64).reshape(rows)
        acceleration = None if acceleration_m_s2 is None else \
            np.asarray(acceleration_m_s2, dtype=np.float64).reshape(rows, 3)
        hint = None if rest_hint is None else np.asarray(rest_hint, dtype=bool).reshape(rows)
        if hint is not None and self.hints is None:
            self.hints = RestHints()
        out = np.empty_like(rate)
        std = np.empty_like(rate)
        still = np.empty(rows, dtype=bool)
        first = 0
        while first < rows:
            if self._window is None:
                self._open(float(time_s[first]))
            times = time_s[first:]
            outside = ((times >= self._window.end_s) | (times < self._window.start_s)) & \
                np.isfinite(times)
            end = first + int(np.argmax(outside)) if outside.any() else rows
            if end == first:
                self._roll(float(time_s[first]))
                continue
            part = slice(first, end)
            if hint is not None:
                self.hints.add_block(time_s[part], hint[part])
            out[part] = rate[part] - self._offset
            std[part] = self._std
            still[part] = self._still
            self._window.add_block(time_s[part], out[part], temperature[part],
                                   None if acceleration is None else acceleration[part])
            first = end
        return TrackedBlock(rate_rad_s=out, std_rad_s=std, still=still)

    def process_one(self, time_s: float, rate_rad_s, temperature_c: float,
                    acceleration_m_s2=None, rest_hint: Optional[bool] = None) -> tuple:
        """
        Track one sample in plain floats; give (rates less the offset, stds, still).

        ``rest_hint``: the sample's own hint, as a row of `process`'s (None: none).
        """
        if self._window is None:
            self._open(time_s)
        elif (time_s >= self._window.end_s or time_s < self._window.start_s) and \
                math.isfinite(time_s):
            self._roll(time_s)
        if rest_hint is not None:
            self.hint(time_s, rest_hint)
        out = [r - o for r, o in zip(rate_rad_s, self._offset)]
        self._window.add_row(time_s, out, temperature_c, acceleration_m_s2)
        return out, list(self._std), self._still

    def _open(self, time_s: float) -> None:
        """Start the window grid at ``time_s`` (a finite stamp) and its first window."""
        if not math.isfinite(time_s):
            msg = f'the first sample of a tracked stream needs a finite time, got {time_s}'
            raise CalibrationError(msg)
        self._origin_s = time_s
        self._start_window(0)

    def _start_window(self, index: int) -> None:
        width = self.settings.standstill.window_s
        self._window = WindowSums(index, self._origin_s + index * width,
                                  self._origin_s + (index + 1) * width, tuple(self._offset),
                                  len(self.axes))
        if self.hints is not None:
            self.hints.forget_before(self._window.start_s)

    def _roll(self, time_s: float) -> None:
        """Close the window and start the one that holds ``time_s``."""
        window = self._window
        self._close(window.statistics())
        if time_s < window.start_s:
            # The clock went back (a replay restarted): a new grid, nothing carried over.
            self._detector.reset()
            self._end_run()
            self._still = False
            if self.hints is not None:
                self.hints.clear()
            self._open(time_s)
            return
        width = self.settings.standstill.window_s
        index = math.floor((time_s - self._origin_s) / width)
        if self._origin_s + index * width > time_s:
            index -= 1
        elif self._origin_s + (index + 1) * width <= time_s:
            index += 1
        self._start_window(index)

    def _hinted(self, w: WindowStatistics) -> WindowStatistics:
        """Give ``w`` marked hinted when the hints (or the start-up zeroing) cover it."""
        if self.zeroing or self.hints is not None and self.hints.covers(
                w.first_s, w.last_s, self.settings.rest_hint_max_age_s):
            return replace(w, hinted=True)
        return w

    def _close(self, w: WindowStatistics) -> None:
        w = self._hinted(w)
        verdict = self._detector.judge(w)
        self.window_count += 1
        self.held = tuple(i in verdict.held for i in range(len(self.axes)))
        self.hinted = w.hinted
        self._predict(w.end_s)
        reason, learnt = verdict.reason, ()
        if verdict.entered:
            hinted = w.hinted and all(v.hinted for v, _ in verdict.learn)
            self._begin_run(verdict.learn, w.end_s, hinted)
            if hinted:
                self._re_zero(frozenset().union(*(axes for _, axes in verdict.learn)))
            learnt = verdict.learn
        elif verdict.learn:
            ((window, axes),) = verdict.learn
            drift = self._drift(window, axes)
            if drift:
                reason = drift
                self._detector.interrupt(w, verdict.held)
                self._end_run(drifted=True)
            else:
                self._learn(window, axes, shift=False)
                if window.hinted and w.hinted:
                    self._re_zero(axes)
                learnt = verdict.learn
                self._run.windows += 1
                self._run.unconfirmed = max(self._run.unconfirmed - 1, 0)
        elif not verdict.still:
            self._end_run()
        self._still = self._detector.still and not verdict.held
        self.reason = reason or ('still' if self._still else 'moving')
        self._std = [math.sqrt(v) for v in self._variance]
        self.learnt = learnt
        if self.windows is not None:
            self.windows.append(WindowRecord(
                start_s=w.start_s, end_s=w.end_s, samples=w.samples, quiet=verdict.quiet,
                still=self._still,
                learnt=tuple((v.start_s, v.end_s, tuple(sorted(axes))) for v, axes in learnt),
                reason=reason, offset_rad_s=tuple(self._offset), hinted=w.hinted))

    def _begin_run(self, learn: tuple, time_s: float, hinted: bool = False) -> None:
        """
        Learn the windows that made the gyro still; a shift a turn could explain is provisional.

        Without an accelerometer any shift could be a slow turn; with one, only its part
        about gravity (a turn about another axis tilts the specific force). In a run
        whose every window was hinted no turn explains it: the shift stays.
        """
        self.zeroing = False
        if self._run is not None:
            self._end_run()
        self.runs += 1
        before = (list(self._offset), list(self._variance))
        shifted = False
        for order, (window, axes) in enumerate(learn):
            shifted |= self._learn(window, axes, shift=order == 0)
        last = learn[-1][0] if learn else None
        vertical = None if last is None or last.acceleration_m_s2 is None else \
            self._detector.vertical(last.acceleration_m_s2)
        if hinted:
            shifted = False
        elif shifted and vertical is not None:
            gate = self.settings.standstill.agreement_multiple
            change = sum(u * (x - b) for u, x, b in zip(vertical, self._offset, before[0]))
            spread = sum(u * u * (v + n / last.samples)
                         for u, v, n in zip(vertical, before[1], self._noise2))
            shifted = not change * change <= gate * gate * spread
        # A slow ramp shows as a still run that drifts out, then shifts, drifts out again:
        # a shift after a drift must hold twice as long as the run it ended held.
        unconfirmed = max(CONFIRM_WINDOWS, 2 * self._drifted_windows) if shifted else 0
        self._run = _StillRun(offset_rad_s=tuple(self._offset),
                              variance=tuple(self._variance),
                              time_s=last.end_s if last else time_s,
                              before=before + (vertical,) if shifted else None,
                              unconfirmed=unconfirmed, windows=len(learn))

    def _end_run(self, drifted: bool = False) -> None:
        """End the still run; a shift it has not confirmed yet is undone (about gravity)."""
        run, self._run = self._run, None
        self._drifted_windows = run.windows if drifted and run is not None else 0
        if run is None or not run.unconfirmed:
            return
        offset, variance, vertical = run.before
        if vertical is None:
            self._offset = offset
        else:
            change = [x - b for x, b in zip(self._offset, offset)]
            along = sum(u * c for u, c in zip(vertical, change)) / sum(u * u for u in vertical)
            self._offset = [x - u * along for x, u in zip(self._offset, vertical)]
        self._variance = [max(v, b) for v, b in zip(self._variance, variance)]
        self.withdrawn += 1

    def _drift(self, w: WindowStatistics, axes: frozenset) -> str:
        """
        Give how ``w`` drifted on ``axes`` from where its still run began beyond the walk.

        Per axis without an accelerometer; with one, only the drift about gravity (the
        accelerometer sees a turn about any other axis tilt the specific force).
        """
        run = self._run
        if run is None:
            return ''
        gate = self.settings.standstill.agreement_multiple
        axes = sorted(axes)
        moved = [w.measured_rad_s[i] - run.offset_rad_s[i] for i in axes]
        variance = [run.variance[i] + self._noise2[i] / w.samples +
                    self._q[i] * (w.end_s - run.time_s) for i in axes]
        if w.acceleration_m_s2 is not None:
            vertical = self._detector.vertical(w.acceleration_m_s2)
            up = [vertical[i] for i in axes]
            moved = [sum(m * u for m, u in zip(moved, up))]
            variance = [sum(v * u * u for v, u in zip(variance, up))]
        for i, (drift, var) in enumerate(zip(moved, variance)):
            if not drift * drift <= gate * gate * var:
                where = 'about gravity' if w.acceleration_m_s2 is not None else \
                    f'on axis {axes[i]}'
                return f'offset drifted {drift:.3g} rad/s {where} since the still run began'
        return ''

    def _re_zero(self, axes) -> None:
        """Make the offset of ``axes`` their zero: what a hinted window taught stays."""
        if self._zero is None:
            self._zero = [0.0] * len(self.axes)
        for i in axes:
            self._zero[i] = self._offset[i]

    def _predict(self, time_s: float) -> None:
        """
        Carry the offsets from the last time to ``time_s``: a first-order Gauss-Markov process.

        Its standard deviation is ``initial_std_rad_s`` (the model's own error: the offset
        stays within it) and its variance grows at first by q dt (the random walk), so its
        time constant is 2 initial_std^2 / q: the offset fades back to the model (or to
        the zero a hint set) over it, and its variance grows back to initial_std^2.
        """
        if self._time_s is not None and time_s > self._time_s:
            elapsed = time_s - self._time_s
            zero = self._zero
            for i, (q, cap) in enumerate(zip(self._q, self._cap)):
                if q > 0.0:
                    decay = math.exp(-elapsed * q / (2.0 * cap))
                    if zero is None:
                        self._offset[i] *= decay
                    else:
                        self._offset[i] = zero[i] + (self._offset[i] - zero[i]) * decay
                    self._variance[i] = decay * decay * self._variance[i] + \
                        cap * (1.0 - decay * decay)
        if self._time_s is None or time_s > self._time_s:
            self._time_s = time_s

    def _learn(self, w: WindowStatistics, axes: frozenset, shift: bool) -> bool:
        """Update ``axes`` with the offsets the window measures; tell whether one shifted."""
        gate = self.settings.standstill.agreement_multiple
        shifted = False
        for i in sorted(axes):
            measured = w.measured_rad_s[i]
            noise = self._noise2[i] / w.samples
            variance = self._variance[i]
            innovation = measured - self._offset[i]
            if shift and innovation * innovation > gate * gate * (variance + noise):
                variance += innovation * innovation
                shifted = True
            gain = variance / (variance + noise)
            self._offset[i] += gain * innovation
            self._variance[i] = (1.0 - gain) * variance
        self.updates += 1
        self.last_update_s = w.end_s
        return shifted
