"""Motion schedules and their injection into a record at rest (simulation.motion)."""

import math

from mlx_tempcomp.core.errors import ConfigError
from mlx_tempcomp.simulation.motion import (inject_motion, motion_schedule, MotionSchedule,
                                            REST, ScheduleSettings, Segment)
import numpy as np
import pytest


def test_the_cycle_schedule_rests_90_s_every_5_min_and_turns_about_every_axis():
    schedule = motion_schedule(3000.0, ScheduleSettings.cycle(), seed=3)
    assert schedule.duration_s == pytest.approx(3000.0)
    assert schedule.rests() == [(300.0 * k, 300.0 * k + 90.0) for k in range(10)]
    assert schedule.still_share == pytest.approx(0.3)
    turns = [s for s in schedule.segments if s.kind != REST]
    assert {s.axis for s in turns} == {'x', 'y', 'z', 'gravity'}
    assert {s.kind for s in turns} == {'slow', 'ramped', 'fast'}
    # Segments end to end, no gap.
    ends = [s.end_s for s in schedule.segments[:-1]]
    assert ends == pytest.approx([s.start_s for s in schedule.segments[1:]])


def test_the_mixed_schedule_draws_within_its_ranges():
    schedule = motion_schedule(20000.0, ScheduleSettings.mixed(), seed=5)
    rests = [end - start for start, end in schedule.rests()]
    assert min(rests[:-1]) >= 10.0 and max(rests) <= 600.0
    for s in schedule.segments:
        peak = math.degrees(max(abs(s.rate_start_rad_s), abs(s.rate_end_rad_s)))
        if s.kind in ('slow', 'ramped'):
            assert peak <= 2.0 and (s.kind == 'ramped' or peak >= 0.2)
        elif s.kind == 'fast':
            assert peak <= 90.0
    slow = [s for s in schedule.segments if s.kind == 'slow']
    assert all(s.rate_start_rad_s == s.rate_end_rad_s for s in slow)
    assert motion_schedule(20000.0, ScheduleSettings.mixed(), seed=5) == schedule
    assert motion_schedule(20000.0, ScheduleSettings.mixed(), seed=6) != schedule


def test_level_rests_bring_every_tilt_back():
    schedule = motion_schedule(3000.0, ScheduleSettings.cycle(), seed=1)
    for turn in {s.turn for s in schedule.segments if s.axis in ('x', 'y')}:
        angle = sum(0.5 * (s.rate_start_rad_s + s.rate_end_rad_s) * (s.end_s - s.start_s)
                    for s in schedule.segments if s.turn == turn)
        assert angle == pytest.approx(0.0, abs=1e-12)


def test_injection_adds_the_rate_and_turns_the_specific_force():
    schedule = MotionSchedule((
        Segment(0.0, 10.0, REST), Segment(10.0, 20.0, 'slow', 'x', math.pi / 20, math.pi / 20),
        Segment(20.0, 30.0, REST), Segment(30.0, 40.0, 'slow', 'gravity', 0.3, 0.3),
        Segment(40.0, 50.0, 'ramped', 'z', 0.0, 0.1)))
    time_s = 100.0 + np.arange(0.0, 60.0, 0.5)
    gyro = np.full((time_s.size, 2), 1e-3)
    acceleration = np.tile([0.0, 0.0, -9.8], (time_s.size, 1)) + 1e-3
    injected = inject_motion(time_s, gyro, ('x', 'z'), schedule, acceleration)
    at = {t: i for i, t in enumerate((time_s - 100.0).tolist())}
    assert np.allclose(injected.gyro_rad_s - gyro, injected.reference_rad_s, rtol=0, atol=1e-15)
    assert injected.reference_rad_s[at[15.0]] == pytest.approx([math.pi / 20, 0.0])
    assert injected.reference_rad_s[at[45.0]] == pytest.approx([0.0, 0.05])
    # A quarter turn about x: the mean specific force f0 (-z) turns to -y.
    f0 = acceleration.mean(axis=0)
    turned = np.array([f0[0], f0[2], -f0[1]])
    assert injected.acceleration_m_s2[at[25.0]] == pytest.approx(acceleration[0] + turned - f0)
    assert turned == pytest.approx([1e-3, -9.799, -1e-3])
    # About gravity (now about -y): nearly all the rate is on y, which is not measured.
    vertical = turned / np.linalg.norm(turned)
    assert injected.reference_rad_s[at[35.0]] == pytest.approx(0.3 * vertical[[0, 2]])
    assert injected.acceleration_m_s2[at[35.0]] == pytest.approx(acceleration[0] + turned - f0)
    assert injected.segment[at[5.0]] == 0 and injected.segment[at[55.0]] == -1
    # After the schedule the sensor stays where the last turn (0.5 rad about z) left it.
    c, s = math.cos(0.5), math.sin(0.5)
    last = np.array([c * turned[0] + s * turned[1], -s * turned[0] + c * turned[1], turned[2]])
    assert injected.acceleration_m_s2[at[55.0]] == pytest.approx(acceleration[0] + last - f0)
    without = inject_motion(time_s, gyro, ('x', 'z'), schedule)
    assert without.acceleration_m_s2 is None
    # Without an accelerometer the gravity axis is z at the start: after the quarter turn
    # about x, the sensor's y.
    assert without.reference_rad_s[at[35.0]] == pytest.approx([0.0, 0.0], abs=1e-12)


def test_bad_schedules_are_refused_naming_the_setting():
    with pytest.raises(ConfigError, match='schedule slow_dps must be 0 < low <= high'):
        ScheduleSettings(slow_dps=(2.0, 0.2))
    with pytest.raises(ConfigError, match='schedule axes must be some of x, y, z, gravity'):
        ScheduleSettings(axes=('w',))
    with pytest.raises(ConfigError, match='rest_period_s must be longer than its rest'):
        ScheduleSettings.cycle(rest_period_s=60.0)
    with pytest.raises(ConfigError, match='a schedule needs a positive duration'):
        motion_schedule(0.0)
