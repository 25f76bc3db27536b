"""
Standstill: is the gyro still, judged window by window from its own output.

Samples are cut into windows of ``window_s`` on their own time stamps (window k holds
the samples from t0 + k W to t0 + (k + 1) W, t0 the first stamp), so the windows do not
depend on how the samples arrive. `WindowSums` accumulates a window's sums in sample
order, by plain addition (numpy's ``cumsum`` on a block, float ``+=`` on a row), so a
block and its rows one by one give the same bits. A closed window gives its
`WindowStatistics`; the `StandstillDetector` judges each:

- **quiet**: enough samples; on every axis the rate spread (standard deviation) within
  ``noise_multiple`` x the axis's per-sample noise; the temperature's slope over the
  window within ``max_temperature_rate_c_s``; with an accelerometer, its spread within
  ``max_acceleration_spread_m_s2`` on every axis;
- **held axes**: the mean rate, relative to the tracker's current offset, beyond
  ``max_mean_rate_rad_s`` may be a constant turn. Without an accelerometer each axis
  beyond it is held; with one, the mean's part along gravity (the mean specific force)
  is the turn it cannot see, and beyond the bound every axis that turn would move by
  more than its window mean's noise is held (the gravity seen counted up to
  `GRAVITY_TILT_RAD` off the true vertical). A held axis learns nothing from the
  window; a window whose every axis is held is not quiet. A **hinted** window (the robot
  said it was at rest over the whole window, `core.standstill.rest_hints`) holds no axis: its mean
  is an offset, whatever its size; the other tests still apply;
- **agrees** with the window before it (adjacent and quiet): the offsets they measure
  (the offset in effect plus the window's mean) differ on no axis held in neither by
  more than ``agreement_multiple`` x their standard deviation (the noise of both means
  and the bias's own random walk between them); with an accelerometer, the specific
  force turned by no more than ``max_tilt_rate_rad_s`` x the time between them.

A run of ``enter_windows`` quiet windows, each agreeing with the one before, makes the
gyro still; ``leave_windows`` windows out of the run make it moving again. The tracker
learns from a window of a still run once the next window agrees with it (on the axes
held in neither), so the last window before a motion (which may hold the slow start of
a ramp) is never learnt.

What a gyro alone cannot tell: a constant turn is a bias to it. A turn whose rate, less
the current offset, stays within ``max_mean_rate_rad_s`` is rest to the detector (without
an accelerometer about any axis, with one about gravity); a turn that starts slower than
that and speeds up by less than the agreement allows between two windows (a slow ramp)
is taken for rest until it does (the tracker's drift guard ends such a run). An
accelerometer sees every turn about a horizontal axis (the specific force tilts) and
every shaking; it cannot see a turn about gravity.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from ..errors import ConfigError

# A window needs this many samples for its spread to mean anything.
MIN_WINDOW_SAMPLES = 5
# How far the gravity an accelerometer sees may be off the true vertical, rad: its offset
# (20 mg of a MEMS part over temperature) tilts it. A turn about gravity moves an axis by
# up to (its cosine to the vertical seen + this) x the rate.
GRAVITY_TILT_RAD = 0.02
AXIS_NAMES = ('x', 'y', 'z')


def per_axis(name: str, values, axes: int, zero: bool = False) -> tuple:
    """Give ``values`` (one, or one per axis) as a float per axis, finite and > 0 (or >= 0)."""
    values = tuple(float(v) for v in values)
    if len(values) == 1:
        values *= axes
    if len(values) != axes:
        msg = f'{name} needs one value or one per axis ({axes}), got {len(values)}'
        raise ConfigError(msg)
    if not all(math.isfinite(v) and (v > 0.0 or zero and v == 0.0) for v in values):
        msg = f'{name} must be finite and {">=" if zero else ">"} 0, got {list(values)}'
        raise ConfigError(msg)
    return values


@dataclass(frozen=True)
class StandstillSettings:
    """
    When a window is still (see the module notes). Rates in rad/s, one per axis.

    ``rate_noise_rad_s``: the 1-sigma noise of one sample per axis (``allan``'s
    ``rate_noise_rad_s``); ``random_walk_rad_s_rt_s``: how fast the bias wanders, in
    rad/s per sqrt(s) (consecutive still windows may differ by it beyond their noise;
    the tracker's process noise is its square).
    """

    rate_noise_rad_s: tuple
    random_walk_rad_s_rt_s: tuple
    window_s: float = 5.0
    noise_multiple: float = 3.0
    max_mean_rate_rad_s: float = math.radians(0.1)
    agreement_multiple: float = 4.0
    max_temperature_rate_c_s: float = 0.2
    max_acceleration_spread_m_s2: float = 0.2
    max_tilt_rate_rad_s: float = math.radians(0.05)
    enter_windows: int = 2
    leave_windows: int = 1

    def __post_init__(self) -> None:
        noise = tuple(float(v) for v in self.rate_noise_rad_s)
        object.__setattr__(self, 'rate_noise_rad_s', noise)
        object.__setattr__(self, 'random_walk_rad_s_rt_s', per_axis(
            'random_walk_rad_s_rt_s', self.random_walk_rad_s_rt_s, len(noise), zero=True))
        per_axis('rate_noise_rad_s', noise, len(noise))
        if not 1 <= len(noise) <= 3:
            msg = f'rate_noise_rad_s needs 1 to 3 axes, got {len(noise)}'
            raise ConfigError(msg)
        for name in ('window_s', 'noise_multiple', 'max_mean_rate_rad_s', 'agreement_multiple',
                     'max_temperature_rate_c_s', 'max_acceleration_spread_m_s2',
                     'max_tilt_rate_rad_s'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                msg = f'{name} must be a positive number, got {value!r}'
                raise ConfigError(msg)
        for name in ('enter_windows', 'leave_windows'):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
                msg = f'{name} must be an integer >= 1, got {value!r}'
                raise ConfigError(msg)

    @property
    def axes(self) -> int:
        """Give the number of gyro axes."""
        return len(self.rate_noise_rad_s)


@dataclass(frozen=True)
class WindowStatistics:
    """
    What one closed window holds; rates per axis.

    ``offset_rad_s`` is the tracker's offset in effect during the window and
    ``mean_rad_s`` the mean of the rate less that offset, so ``measured_rad_s``
    (their sum) is the offset the window measures. ``temperature_c`` is the mean
    temperature. ``acceleration_m_s2`` is None without an accelerometer;
    ``acceleration_partial`` when only some samples had one.
    """

    index: int
    start_s: float
    end_s: float
    samples: int
    first_s: float
    last_s: float
    offset_rad_s: tuple
    mean_rad_s: tuple
    spread_rad_s: tuple
    temperature_rate_c_s: float
    acceleration_m_s2: Optional[tuple] = None
    acceleration_spread_m_s2: Optional[tuple] = None
    acceleration_partial: bool = False
    # The robot said it was at rest over the whole window (set by the tracker at its close).
    hinted: bool = False
    temperature_c: float = math.nan

    @property
    def measured_rad_s(self) -> tuple:
        """Give the offset this window measures: the offset in effect plus the mean left."""
        return tuple(o + m for o, m in zip(self.offset_rad_s, self.mean_rad_s))

    @property
    def centre_s(self) -> float:
        """Give the middle of the samples' times."""
        return 0.5 * (self.first_s + self.last_s)


class WindowSums:
    """
    The running sums of one window, added in sample order (block or row: the same bits).

    Per axis the rate (less the offset in effect) and its square; the time since the
    window's start and its square, the temperature less the window's first, and their
    product (the temperature's least-squares slope); the specific force less the
    window's first and its square.
    """

    def __init__(self, index: int, start_s: float, end_s: float, offset_rad_s: tuple,
                 axes: int):
        self.index, self.start_s, self.end_s = index, start_s, end_s
        self.offset_rad_s = tuple(offset_rad_s)
        self.axes = axes
        self.samples = 0
        self.first_s = self.last_s = math.nan
        self.temperature_ref_c = math.nan
        self.sums = [0.0] * (2 * axes + 4)
        self.acceleration_samples = 0
        self.acceleration_ref = None
        self.acceleration_sums = [0.0] * 6

    def add_block(self, time_s: np.ndarray, corrected: np.ndarray, temperature_c: np.ndarray,
                  acceleration: Optional[np.ndarray]) -> None:
        """Add rows (all in this window); ``corrected`` is the rate less the offset."""
        # NaN and infinities are expected: they spoil their window, which is then not quiet.
        with np.errstate(all='ignore'):
            self._add_block(time_s, corrected, temperature_c, acceleration)

    def _add_block(self, time_s, corrected, temperature_c, acceleration) -> None:
        if not self.samples:
            self.first_s, self.temperature_ref_c = float(time_s[0]), float(temperature_c[0])
        self.last_s = float(time_s[-1])
        self.samples += time_s.size
        dt = time_s - self.start_s
        d_temperature = temperature_c - self.temperature_ref_c
        columns = np.column_stack((corrected, corrected * corrected, dt, dt * dt,
                                   d_temperature, dt * d_temperature))
        self.sums = _carried_sum(self.sums, columns)
        if acceleration is not None:
            if self.acceleration_ref is None:
                self.acceleration_ref = acceleration[0].tolist()
            delta = acceleration - self.acceleration_ref
            self.acceleration_sums = _carried_sum(self.acceleration_sums,
                                                  np.column_stack((delta, delta * delta)))
            self.acceleration_samples += time_s.size

    def add_row(self, time_s: float, corrected: list, temperature_c: float,
                acceleration) -> None:
        """Add one row in plain floats: the same operations in the same order as a block."""
        if not self.samples:
            self.first_s, self.temperature_ref_c = time_s, temperature_c
        self.last_s = time_s
        self.samples += 1
        dt = time_s - self.start_s
        d_temperature = temperature_c - self.temperature_ref_c
        sums, axes = self.sums, self.axes
        for i, value in enumerate(corrected):
            sums[i] += value
            sums[axes + i] += value * value
        base = 2 * axes
        sums[base] += dt
        sums[base + 1] += dt * dt
        sums[base + 2] += d_temperature
        sums[base + 3] += dt * d_temperature
        if acceleration is not None:
            if self.acceleration_ref is None:
                self.acceleration_ref = [float(a) for a in acceleration]
            sums = self.acceleration_sums
            for i, (value, ref) in enumerate(zip(acceleration, self.acceleration_ref)):
                delta = value - ref
                sums[i] += delta
                sums[3 + i] += delta * delta
            self.acceleration_samples += 1

    def statistics(self) -> WindowStatistics:
        """Give what the closed window holds (NaN where a non-finite input went in)."""
        n, axes, sums = self.samples, self.axes, self.sums
        mean = [s / n for s in sums[:axes]]
        spread = [math.sqrt(max(ss / n - m * m, 0.0)) if ss == ss else math.nan
                  for ss, m in zip(sums[axes:2 * axes], mean)]
        st, stt, s_temp, st_temp = sums[2 * axes:]
        denominator = n * stt - st * st
        slope = (n * st_temp - st * s_temp) / denominator if denominator > 0.0 else \
            (0.0 if denominator == 0.0 else math.nan)
        acceleration = spread_a = None
        if self.acceleration_samples:
            mean_a = [s / n for s in self.acceleration_sums[:3]]
            spread_a = tuple(math.sqrt(max(ss / n - m * m, 0.0)) if ss == ss else math.nan
                             for ss, m in zip(self.acceleration_sums[3:], mean_a))
            acceleration = tuple(r + m for r, m in zip(self.acceleration_ref, mean_a))
        return WindowStatistics(
            index=self.index, start_s=self.start_s, end_s=self.end_s, samples=n,
            first_s=self.first_s, last_s=self.last_s, offset_rad_s=self.offset_rad_s,
            mean_rad_s=tuple(mean), spread_rad_s=tuple(spread), temperature_rate_c_s=slope,
            acceleration_m_s2=acceleration, acceleration_spread_m_s2=spread_a,
            acceleration_partial=0 < self.acceleration_samples < n,
            temperature_c=self.temperature_ref_c + s_temp / n)


def _carried_sum(carried: list, columns: np.ndarray) -> list:
    """Add ``columns`` row by row to ``carried``: numpy's cumsum adds in order, as += does."""
    stacked = np.empty((columns.shape[0] + 1, columns.shape[1]))
    stacked[0] = carried
    stacked[1:] = columns
    return np.cumsum(stacked, axis=0)[-1].tolist()


@dataclass(frozen=True)
class Verdict:
    """
    The detector's judgement of one window.

    ``reason`` says why the window is not part of a still run ('' when it is);
    ``held`` the axes whose mean rate this window is beyond the bound on (a turn they
    see may be going on), which learn nothing from it. ``learn`` are the windows the
    tracker learns from now, each confirmed by the one after it, as (window, axes) pairs
    (the axes held in neither): the run but its newest window when the gyro has just
    become still (``entered``), the window before this one while it stays still.
    """

    quiet: bool
    agrees: bool
    still: bool
    entered: bool
    reason: str
    held: frozenset
    learn: tuple


class StandstillDetector:
    """Judge closed windows in order; see the module notes. ``axes`` names the gyro axes."""

    def __init__(self, settings: StandstillSettings, axes: tuple):
        if len(axes) != settings.axes or not set(axes) <= set(AXIS_NAMES):
            msg = f'axes {list(axes)} must be {settings.axes} of x, y, z'
            raise ConfigError(msg)
        self.settings = settings
        self.axis_index = tuple(AXIS_NAMES.index(a) for a in axes)
        self._all = frozenset(range(len(axes)))
        self.reset()

    def reset(self) -> None:
        """Forget the windows seen: moving, no run (a gap or a clock going back)."""
        self.still = False
        self._previous = None
        self._run = []          # (window, held axes), oldest first
        self._run_length = 0
        self._misses = 0

    def vertical(self, acceleration_m_s2: tuple) -> tuple:
        """Give the gravity direction's component on each gyro axis (NaN without gravity)."""
        norm = math.sqrt(sum(a * a for a in acceleration_m_s2))
        if not norm > 0.0:
            return (math.nan,) * len(self.axis_index)
        return tuple(acceleration_m_s2[k] / norm for k in self.axis_index)

    def interrupt(self, w: WindowStatistics, held: frozenset) -> None:
        """Break the still run at ``w`` (its offset drifted): moving, ``w`` starts a new run."""
        self.still, self._misses = False, 0
        self._run, self._run_length = [(w, held)], 1

    def _quiet_reason(self, w: WindowStatistics) -> str:
        """Give why the window is not quiet, '' when it is (NaN fails every test)."""
        s = self.settings
        if w.samples < MIN_WINDOW_SAMPLES:
            return f'{w.samples} samples, fewer than {MIN_WINDOW_SAMPLES}'
        if w.acceleration_partial:
            return 'acceleration missing on some samples'
        for i, spread in enumerate(w.spread_rad_s):
            if not spread <= s.noise_multiple * s.rate_noise_rad_s[i]:
                return f'rate spread {spread:.3g} rad/s on axis {i} (noise ' \
                       f'{s.rate_noise_rad_s[i]:.3g})'
        if not abs(w.temperature_rate_c_s) <= s.max_temperature_rate_c_s:
            return f'temperature rate {w.temperature_rate_c_s:.3g} C/s'
        if w.acceleration_m_s2 is not None and \
                not max(w.acceleration_spread_m_s2) <= s.max_acceleration_spread_m_s2:
            return f'acceleration spread {max(w.acceleration_spread_m_s2):.3g} m/s^2'
        return ''

    def _held(self, w: WindowStatistics) -> tuple:
        """
        Give (held axes, reason): the axes a turn within the window's mean could move.

        None in a hinted window: the robot says it does not turn.
        Without an accelerometer, each axis whose mean (less the offset) is beyond the
        bound. With one, the mean's part about gravity is the turn it cannot see: beyond
        the bound, every axis that turn would move by more than the noise of its window
        mean (so an axis learns from it at most what its noise hides).
        """
        s = self.settings
        if w.hinted:
            return frozenset(), ''
        if w.acceleration_m_s2 is None:
            held = frozenset(i for i, m in enumerate(w.mean_rad_s)
                             if not abs(m) <= s.max_mean_rate_rad_s)
            worst = max(held, key=lambda i: abs(w.mean_rad_s[i]), default=None)
            return held, '' if worst is None else \
                f'mean rate {w.mean_rad_s[worst]:.3g} rad/s on axis {worst}'
        up = self.vertical(w.acceleration_m_s2)
        turn = sum(m * u for m, u in zip(w.mean_rad_s, up))
        if abs(turn) <= s.max_mean_rate_rad_s:
            return frozenset(), ''
        held = frozenset(i for i, u in enumerate(up) if not (abs(u) + GRAVITY_TILT_RAD) *
                         abs(turn) <= s.rate_noise_rad_s[i] / math.sqrt(w.samples))
        return held, f'mean rate about gravity {turn:.3g} rad/s'

    def _disagreement(self, before: WindowStatistics, w: WindowStatistics, axes) -> str:
        """Give why ``w`` does not agree with the quiet ``before`` on ``axes`` ('' if it does)."""
        s = self.settings
        elapsed = w.centre_s - before.centre_s
        for i in sorted(axes):
            a, b = before.measured_rad_s[i], w.measured_rad_s[i]
            variance = s.rate_noise_rad_s[i] ** 2 * (1.0 / before.samples + 1.0 / w.samples) \
                + s.random_walk_rad_s_rt_s[i] ** 2 * elapsed
            if not abs(b - a) <= s.agreement_multiple * math.sqrt(variance):
                return f'offset moved {b - a:.3g} rad/s on axis {i} since the window before'
        if before.acceleration_m_s2 is not None and w.acceleration_m_s2 is not None:
            tilt = _angle(before.acceleration_m_s2, w.acceleration_m_s2)
            if not tilt <= s.max_tilt_rate_rad_s * elapsed:
                return f'specific force turned {tilt:.3g} rad since the window before'
        return ''

    def judge(self, w: WindowStatistics) -> Verdict:
        """Judge the next closed window; windows must come in order of their index."""
        previous, self._previous = self._previous, w
        reason = self._quiet_reason(w)
        held, held_reason = (frozenset(), '') if reason else self._held(w)
        if held == self._all:
            reason = held_reason
        quiet = not reason
        agrees = False
        if quiet:
            if self._run and self._run[-1][0] is previous and previous.index == w.index - 1:
                axes = self._all - held - self._run[-1][1]
                reason = self._disagreement(previous, w, axes) if axes else \
                    'no axis free in both windows'
                agrees = not reason
            if agrees:
                self._run.append((w, held))
                self._run_length += 1
            else:
                self._run, self._run_length = [(w, held)], 1
            self._run = self._run[-max(self.settings.enter_windows, 2):]
        else:
            self._run, self._run_length = [], 0
        entered = False
        learn = ()
        if self._run_length >= self.settings.enter_windows:
            # A window is learnt once the next one agrees with it: the start of a slow
            # ramp at the end of a rest shows in the window after it, not in its own.
            entered = not self.still
            pairs = list(zip(self._run[:-1], self._run[1:]))
            learn = tuple((a, self._all - a_held - b_held)
                          for (a, a_held), (_, b_held) in (pairs if entered else pairs[-1:]))
            self.still, self._misses = True, 0
        elif self.still:
            self._misses += 1
            self.still = self._misses < self.settings.leave_windows
        if self.still and quiet and (agrees or entered):
            reason = f'held: {held_reason}' if held else ''
        else:
            reason = reason or 'run too short'
        return Verdict(quiet=quiet, agrees=agrees, still=self.still, entered=entered,
                       reason=reason, held=held, learn=learn)


def _angle(a: tuple, b: tuple) -> float:
    """Give the angle between two vectors in rad (NaN for a zero or non-finite one)."""
    dot = sum(x * y for x, y in zip(a, b))
    cross = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    return math.atan2(math.sqrt(sum(c * c for c in cross)), dot)
