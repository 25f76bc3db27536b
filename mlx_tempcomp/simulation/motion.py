"""
Known motion injected into a record taken at rest: the truth is known and the bias is real.

A `MotionSchedule` is a list of segments, each a rest or a turn about one axis whose rate
goes linearly from ``rate_start_rad_s`` to ``rate_end_rad_s`` (a constant turn, a ramp, or
a piece of a trapezoid). The axis is ``x``, ``y`` or ``z`` of the sensor frame, or
``gravity``: the vertical as the sensor sees it when the turn starts, which the
accelerometer cannot see a turn about. `motion_schedule` draws one from a seed
(`ScheduleSettings`: `ScheduleSettings.mixed` mixes rests of 10 s to 10 min with slow turns
of 0.2 to 2 deg/s, constant and ramped, fast turns and turns about the gravity axis;
`ScheduleSettings.cycle` rests 90 s every 5 min and fills the rest with turns about every
axis).

`inject_motion` adds the schedule's rate to the gyro columns of a record (the record's own
noise and bias stay) and gives it as the reference (``ref_x|y|z``). When the record has an
accelerometer, the attitude is integrated segment by segment (each turns about a fixed
axis, so the rotation of a segment is exact) and the recorded specific force is turned
with it: ``f + R(t)^T f0 - f0``, f0 the record's mean specific force, so the
accelerometer's noise and drift stay too. What injection cannot give: the gyro's
scale-factor error and g-sensitivity during the turns, and vibration; a rate table or a
robot has them, the tracker ignores moving windows anyway.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from ..core.errors import ConfigError

TURN_AXES = ('x', 'y', 'z', 'gravity')
REST = 'rest'
# Kinds of segment, as the schedule labels them.
KINDS = (REST, 'slow', 'ramped', 'fast')
_AXIS_VECTORS = {'x': (1.0, 0.0, 0.0), 'y': (0.0, 1.0, 0.0), 'z': (0.0, 0.0, 1.0)}
# A fast turn ramps up and down in this long (a robot's or a table's acceleration).
FAST_RAMP_S = 0.5


@dataclass(frozen=True)
class Segment:
    """One piece of a schedule: from ``start_s`` to ``end_s`` about ``axis`` (rest: none)."""

    start_s: float
    end_s: float
    kind: str
    axis: str = ''
    rate_start_rad_s: float = 0.0
    rate_end_rad_s: float = 0.0
    # The turn this segment belongs to (a ramped or fast turn spans several segments).
    turn: int = -1


@dataclass(frozen=True)
class MotionSchedule:
    """Segments end to end from time 0 (the record's first sample); rest after the last."""

    segments: tuple

    @property
    def duration_s(self) -> float:
        """Give the time the schedule covers."""
        return self.segments[-1].end_s if self.segments else 0.0

    @property
    def still_share(self) -> float:
        """Give the share of the schedule at rest."""
        rest = sum(s.end_s - s.start_s for s in self.segments if s.kind == REST)
        return rest / self.duration_s if self.duration_s else 1.0

    def rests(self) -> list:
        """Give the (start_s, end_s) of each rest."""
        return [(s.start_s, s.end_s) for s in self.segments if s.kind == REST]

    def to_json(self) -> list:
        """Give the segments as plain dicts (for a truth file)."""
        return [dict(vars(s)) for s in self.segments]


@dataclass(frozen=True)
class ScheduleSettings:
    """
    What `motion_schedule` draws. Rates in deg/s, times in s.

    ``rest_period_s`` > 0: one rest of ``rest_s[1]`` at the start of every period, turns
    filling the rest of it (`cycle`); 0: rests of ``rest_s[0]`` to ``rest_s[1]``
    (log-uniform) between stretches of turns of ``moving_s[0]`` to ``moving_s[1]``
    (`mixed`). A stretch is turns one after the other, each ``turn_s`` long (a fast one
    ``fast_turn_s``), of kind slow (constant), ramped (a trapezoid up to its rate and
    down) or fast, about ``axes`` in turn. With ``level_rests`` (the default) a turn
    about one of ``level_axes`` (the horizontal ones: x and y of a sensor lying flat)
    goes out and back, as a robot's tilts do, so every rest is at the starting attitude;
    without, the sensor rests at whatever attitude its turns leave.
    """

    rest_period_s: float = 0.0
    rest_s: tuple = (10.0, 600.0)
    moving_s: tuple = (20.0, 300.0)
    turn_s: tuple = (15.0, 60.0)
    fast_turn_s: tuple = (2.0, 8.0)
    slow_dps: tuple = (0.2, 2.0)
    fast_dps: tuple = (10.0, 90.0)
    kinds: tuple = ('slow', 'ramped', 'fast')
    axes: tuple = TURN_AXES
    level_rests: bool = True
    level_axes: tuple = ('x', 'y')

    def __post_init__(self) -> None:
        for name in ('rest_s', 'moving_s', 'turn_s', 'fast_turn_s', 'slow_dps', 'fast_dps'):
            low, high = getattr(self, name)
            if not 0.0 < low <= high < math.inf:
                msg = f'schedule {name} must be 0 < low <= high, got {(low, high)}'
                raise ConfigError(msg)
        if not (math.isfinite(self.rest_period_s) and self.rest_period_s >= 0.0):
            msg = f'schedule rest_period_s must be >= 0, got {self.rest_period_s}'
            raise ConfigError(msg)
        if self.rest_period_s and self.rest_period_s <= self.rest_s[1]:
            msg = 'schedule rest_period_s must be longer than its rest'
            raise ConfigError(msg)
        if not self.kinds or not set(self.kinds) <= set(KINDS[1:]):
            msg = f'schedule kinds must be some of {", ".join(KINDS[1:])}, got {self.kinds}'
            raise ConfigError(msg)
        if not self.axes or not set(self.axes) <= set(TURN_AXES):
            msg = f'schedule axes must be some of {", ".join(TURN_AXES)}, got {self.axes}'
            raise ConfigError(msg)

    @classmethod
    def mixed(cls, **changes) -> 'ScheduleSettings':
        """Rests of 10 s to 10 min between stretches of every kind of turn about every axis."""
        return cls(**changes)

    @classmethod
    def cycle(cls, **changes) -> 'ScheduleSettings':
        """Still 30 % of the time: a rest of 90 s every 5 min, turns about every axis between."""
        return cls(**{'rest_period_s': 300.0, 'rest_s': (90.0, 90.0), **changes})


def _profile(rng: np.random.Generator, settings: ScheduleSettings, kind: str,
             length: float) -> tuple:
    """Give the (time, rate) knots of one turn of ``length`` s (a random sign and rate)."""
    sign = float(rng.choice((-1.0, 1.0)))
    if kind == 'fast':
        rate = sign * math.radians(float(rng.uniform(*settings.fast_dps)))
        ramp = min(FAST_RAMP_S, length / 2.0)
        return ((0.0, 0.0), (ramp, rate), (length - ramp, rate), (length, 0.0))
    rate = sign * math.radians(float(rng.uniform(*settings.slow_dps)))
    if kind == 'slow':
        return ((0.0, rate), (length, rate))
    up, down = (rng.uniform(0.2, 0.5, 2) * length).tolist()
    return ((0.0, 0.0), (up, rate), (length - down, rate), (length, 0.0))


def _turns(rng: np.random.Generator, settings: ScheduleSettings, start_s: float,
           end_s: float, first_turn: int) -> list:
    """
    Fill ``start_s`` to ``end_s`` with turns; the kinds and axes go round in turn.

    With ``level_rests`` a turn about a level axis is a tilt and its return (the same profile,
    the other way), so the sensor rests where it started.
    """
    segments = []
    t, turn = start_s, first_turn
    while end_s - t > 1e-9:
        kind = settings.kinds[turn % len(settings.kinds)]
        axis = settings.axes[(turn // len(settings.kinds)) % len(settings.axes)]
        span = settings.fast_turn_s if kind == 'fast' else settings.turn_s
        length = min(float(rng.uniform(*span)), end_s - t)
        knots = _profile(rng, settings, kind, length)
        if settings.level_rests and axis in settings.level_axes:
            half = length / 2.0
            knots = _profile(rng, settings, kind, half)
            knots += tuple((half + k, -rate) for k, rate in knots)
        for (a_s, a_rate), (b_s, b_rate) in zip(knots[:-1], knots[1:]):
            if b_s > a_s:
                segments.append(Segment(t + a_s, t + b_s, kind, axis, a_rate, b_rate, turn))
        t += length
        turn += 1
    return segments


def motion_schedule(duration_s: float, settings: ScheduleSettings = ScheduleSettings(),
                    seed: int = 0) -> MotionSchedule:
    """Draw a schedule of ``duration_s`` (see `ScheduleSettings`); it starts with a rest."""
    if not (math.isfinite(duration_s) and duration_s > 0.0):
        msg = f'a schedule needs a positive duration, got {duration_s}'
        raise ConfigError(msg)
    rng = np.random.default_rng(seed)
    segments, t, turn = [], 0.0, 0
    while duration_s - t > 1e-9:
        if settings.rest_period_s:
            rest = settings.rest_s[1]
            moving = settings.rest_period_s - rest
        else:
            rest = math.exp(float(rng.uniform(*np.log(settings.rest_s))))
            moving = float(rng.uniform(*settings.moving_s))
        rest = min(rest, duration_s - t)
        segments.append(Segment(t, t + rest, REST))
        t += rest
        moving = min(moving, duration_s - t)
        if moving > 1e-9:
            turns = _turns(rng, settings, t, t + moving, turn)
            turn = turns[-1].turn + 1
            segments += turns
            t += moving
    return MotionSchedule(tuple(segments))


def _rotation(axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Give the rotation matrices (n, 3, 3) by ``angle_rad`` (n,) about the unit ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angle_rad)[:, None, None], np.cos(angle_rad)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


@dataclass(frozen=True)
class InjectedMotion:
    """A record with motion: the gyro with the schedule's rate added, and that rate."""

    gyro_rad_s: np.ndarray
    reference_rad_s: np.ndarray
    acceleration_m_s2: Optional[np.ndarray]
    # Per sample: the index of its segment in the schedule, -1 after the schedule.
    segment: np.ndarray


def inject_motion(time_s, gyro_rad_s, axes, schedule: MotionSchedule,
                  acceleration_m_s2=None) -> InjectedMotion:
    """
    Add ``schedule`` (time 0 = the first sample) to a record's gyro; see the module notes.

    ``gyro_rad_s`` (samples, len(axes)) for the record's ``axes`` (of x, y, z);
    ``acceleration_m_s2`` (samples, 3) or None. The gravity axis is the mean specific
    force's direction turned with the sensor; without an accelerometer, the sensor's z
    at the start turned with it.
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    gyro = np.asarray(gyro_rad_s, dtype=np.float64)
    columns = ['xyz'.index(a) for a in axes]
    elapsed = time_s - time_s[0]
    rate = np.zeros((time_s.size, 3))
    segment_of = np.full(time_s.size, -1)
    accel = None if acceleration_m_s2 is None else \
        np.array(acceleration_m_s2, dtype=np.float64)
    f0 = np.array([0.0, 0.0, 1.0]) if accel is None else accel.mean(axis=0)
    if not np.linalg.norm(f0) > 0.0:
        msg = 'the mean specific force is zero: no gravity axis to turn about'
        raise ConfigError(msg)
    attitude = np.eye(3)     # sensor to the record's start frame
    for index, seg in enumerate(schedule.segments):
        rows = np.flatnonzero((elapsed >= seg.start_s) & (elapsed < seg.end_s))
        segment_of[rows] = index
        if seg.kind == REST:
            if accel is not None:
                accel[rows] += attitude.T @ f0 - f0
            continue
        if seg.axis == 'gravity':
            vertical = attitude.T @ f0
            axis = vertical / np.linalg.norm(vertical)
        else:
            axis = np.array(_AXIS_VECTORS[seg.axis])
        length = seg.end_s - seg.start_s
        slope = (seg.rate_end_rad_s - seg.rate_start_rad_s) / length

        def angle(dt):
            return seg.rate_start_rad_s * dt + 0.5 * slope * dt * dt

        dt = elapsed[rows] - seg.start_s
        rate[rows] = (seg.rate_start_rad_s + slope * dt)[:, None] * axis
        if accel is not None and rows.size:
            turned = attitude @ _rotation(axis, angle(dt))
            accel[rows] += np.einsum('nji,j->ni', turned, f0) - f0
        attitude = attitude @ _rotation(axis, np.array([angle(length)]))[0]
    if accel is not None:
        accel[segment_of < 0] += attitude.T @ f0 - f0
    reference = rate[:, columns]
    return InjectedMotion(gyro_rad_s=gyro + reference, reference_rad_s=reference,
                          acceleration_m_s2=accel, segment=segment_of)
