"""
Rest hints in the core: when a window counts as hinted, and what a hinted window changes.

The signals are built here (white noise of a known sigma at 50 Hz, offsets, turns, shaking
at known times) as in test_core_bias_tracker.py; the hints are given as each sample's own
(the offline twin's column) or as messages at their own times (the node's).
"""

import math

from mlx_tempcomp.core.errors import CalibrationError, ConfigError
from mlx_tempcomp.core.standstill.bias_tracker import (BiasTracking, tracking_state,
                                                       TrackingSettings)
from mlx_tempcomp.core.standstill.detector import StandstillSettings
from mlx_tempcomp.core.standstill.rest_hints import RestHints
import numpy as np
import pytest

RATE_HZ = 50.0
NOISE = 1e-3
WINDOW_S = 5.0
AXES = ('x', 'y', 'z')
OFFSET = math.radians(0.3)             # the issue's: three times the mean-rate bound
GRAVITY = np.array([0.0, 0.0, -9.81])


def settings(**changes) -> TrackingSettings:
    tracking = {k: changes.pop(k) for k in ('rest_hint_max_age_s', 'zero_at_start')
                if k in changes}
    standstill = StandstillSettings(**{
        'rate_noise_rad_s': (NOISE,) * 3, 'random_walk_rad_s_rt_s': (1e-6,),
        'window_s': WINDOW_S, 'max_acceleration_spread_m_s2': 0.05, **changes})
    return TrackingSettings(standstill, initial_std_rad_s=(2e-3,), **tracking)


def record(duration_s: float, seed: int = 0) -> tuple:
    rng = np.random.default_rng(seed)
    time_s = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    return time_s, NOISE * rng.standard_normal((time_s.size, 3)), np.full(time_s.size, 25.0)


def learnt(tracker) -> list:
    return [(start, end) for w in tracker.windows for start, end, _ in w.learnt]


def test_covers_needs_rest_over_the_whole_span_within_the_age():
    hints = RestHints()
    for t in (0.0, 0.5, 1.0, 1.5, 2.0):
        hints.add(t, True)
    assert hints.covers(0.2, 2.9, max_age_s=1.0)
    assert not hints.covers(0.2, 3.1, max_age_s=1.0)        # stale before the last sample
    assert not hints.covers(-0.1, 1.0, max_age_s=1.0)       # nothing before the first
    hints.add(1.2, False)                                    # a late "moving" slots in
    assert not hints.covers(0.2, 1.3, 1.0) and hints.covers(1.5, 2.5, 1.0)
    assert hints.covers(0.0, 1.1, 1.0)                       # it counts from 1.2 on
    hints.add(1.5, False)                                    # two hints at one time
    assert not hints.covers(1.6, 1.9, 1.0)
    sparse = RestHints()
    sparse.add(0.0, True)
    sparse.add(3.0, True)
    assert not sparse.covers(0.5, 3.5, max_age_s=2.0)       # a gap longer than the age
    assert sparse.covers(0.5, 3.5, max_age_s=3.0)
    assert not sparse.covers(math.nan, 1.0, 3.0)
    sparse.forget_before(3.2)
    assert len(sparse) == 1 and sparse.latest(10.0) == (3.0, True)


@pytest.mark.parametrize('offset_dps', [0.3, 5.0])
def test_a_hinted_rest_re_zeroes_any_offset_within_two_still_windows(offset_dps):
    time_s, noise, temperature = record(60.0)
    offset = np.array([1.0, -1.0, 0.5]) * math.radians(offset_dps)
    plain = BiasTracking(settings(), AXES, keep_windows=True)
    plain.process(time_s, noise + offset, temperature)
    # Beyond the bound on every axis: a gyro alone takes it for a turn and learns nothing.
    assert plain.updates == 0 and plain.status().held == (True,) * 3
    tracker = BiasTracking(settings(), AXES, keep_windows=True)
    out = tracker.process(time_s, noise + offset, temperature,
                          rest_hint=np.ones(time_s.size, dtype=bool))
    # Still when the second window closes (10 s), the first learnt then, kept: no turn
    # can explain a shift the robot says it made at rest.
    assert learnt(tracker)[0] == (0.0, 5.0) and tracker.withdrawn == 0
    assert not out.still[time_s < 10.0].any() and out.still[time_s >= 10.0].all()
    after = time_s >= 10.0
    assert np.all(np.abs(out.rate_rad_s[after].mean(axis=0)) < 4 * NOISE / math.sqrt(250))
    assert np.allclose(tracker.status().offset_rad_s, offset, atol=4 * NOISE / math.sqrt(250))
    assert all(w.hinted for w in tracker.windows) and tracker.status().hinted


def test_hints_as_messages_at_their_own_times_give_the_bits_of_each_sample_s_own():
    time_s, noise, temperature = record(60.0)
    rate = noise + OFFSET
    column = BiasTracking(settings(), AXES)
    expected = column.process(time_s, rate, temperature, rest_hint=np.ones(time_s.size, bool))
    # An odometry at 2 Hz, each stamped a little before the sample it arrives with.
    messages = BiasTracking(settings(), AXES)
    rows = []
    for t, r in zip(time_s.tolist(), rate.tolist()):
        if round(t * RATE_HZ) % 25 == 0:
            messages.hint(t - 0.01, True)
        rows.append(messages.process_one(t, r, 25.0))
    assert np.array_equal([r[0] for r in rows], expected.rate_rad_s)
    assert messages.state() == column.state()
    # One per 2 s with a 1 s age leaves every window uncovered: nothing learnt.
    stale = BiasTracking(settings(), AXES)
    for t, r in zip(time_s.tolist(), rate.tolist()):
        if round(t * RATE_HZ) % 100 == 0:
            stale.hint(t, True)
        stale.process_one(t, r, 25.0)
    assert stale.updates == 0


def test_a_hint_never_makes_a_shaking_or_warming_robot_still():
    time_s, noise, temperature = record(60.0)
    hint = np.ones(time_s.size, dtype=bool)
    rng = np.random.default_rng(1)
    shaking = noise + OFFSET + 10 * NOISE * rng.standard_normal(noise.shape)
    tracker = BiasTracking(settings(), AXES, keep_windows=True)
    out = tracker.process(time_s, shaking, temperature, rest_hint=hint)
    assert tracker.updates == 0 and not out.still.any()
    assert all(w.reason.startswith('rate spread') and w.hinted for w in tracker.windows)
    # The accelerometer's spread, and a temperature moving faster than the bound, likewise.
    acceleration = GRAVITY + 0.5 * rng.standard_normal((time_s.size, 3))
    tracker = BiasTracking(settings(), AXES, keep_windows=True)
    tracker.process(time_s, noise + OFFSET, temperature, acceleration, rest_hint=hint)
    assert tracker.updates == 0
    assert all(w.reason.startswith('acceleration spread') for w in tracker.windows)
    tracker = BiasTracking(settings(), AXES)
    tracker.process(time_s, noise + OFFSET, 25.0 + 0.5 * time_s, rest_hint=hint)
    assert tracker.updates == 0


def test_a_hint_that_ends_mid_window_leaves_that_window_to_the_gyro():
    time_s, noise, temperature = record(60.0)
    rate = noise + OFFSET
    # The robot says at rest until 12.5 s, then starts a slow turn of 0.15 deg/s about z.
    hint = time_s < 12.5
    rate[~hint, 2] += math.radians(0.15)
    tracker = BiasTracking(settings(), AXES, keep_windows=True)
    tracker.process(time_s, rate, temperature, rest_hint=hint)
    assert [w.hinted for w in tracker.windows[:3]] == [True, True, False]
    # The first window is learnt (the second agreed with it); the second would be learnt
    # when the third agreed, which the turn starting in it does not: nothing more on z.
    assert learnt(tracker)[0] == (0.0, 5.0)
    assert all(2 not in axes for w in tracker.windows[2:] for _, _, axes in w.learnt)
    assert tracker.status().offset_rad_s[2] == pytest.approx(OFFSET, abs=4e-4)


def test_a_hinted_shift_is_kept_where_an_unhinted_one_is_withdrawn():
    time_s, noise, temperature = record(60.0)
    # A step within the bound after a rest, then shaking two windows later: unhinted, the
    # step could be the start of a slow turn, so it is withdrawn; hinted, it stays.
    rate = noise.copy()
    rate[time_s >= 20.0] += math.radians(0.05)
    rate[time_s >= 35.0] += 20 * NOISE * np.random.default_rng(2).standard_normal(
        (np.count_nonzero(time_s >= 35.0), 3))
    moving = time_s >= 35.0
    results = {}
    for hinted in (False, True):
        tracker = BiasTracking(settings(), AXES, keep_windows=True)
        tracker.process(time_s, rate, temperature,
                        rest_hint=~moving if hinted else None)
        results[hinted] = tracker
    assert results[False].withdrawn == 1 and results[True].withdrawn == 0
    assert max(map(abs, results[False].status().offset_rad_s)) < 2e-4
    assert results[True].status().offset_rad_s == pytest.approx(
        [math.radians(0.05)] * 3, abs=2e-4)


def test_moving_hints_give_the_bits_of_no_hints():
    time_s, noise, temperature = record(120.0)
    rate = noise.copy()
    rate[time_s >= 40.0, 2] += math.radians(0.05)
    without = BiasTracking(settings(), AXES).process(time_s, rate, temperature)
    tracker = BiasTracking(settings(), AXES)
    moving = tracker.process(time_s, rate, temperature,
                             rest_hint=np.zeros(time_s.size, dtype=bool))
    assert np.array_equal(without.rate_rad_s, moving.rate_rad_s)
    assert np.array_equal(without.std_rad_s, moving.std_rad_s)
    assert np.array_equal(without.still, moving.still) and tracker.updates > 0


def test_zero_at_start_takes_the_first_still_run_whatever_its_rate():
    time_s, noise, temperature = record(60.0)
    tracker = BiasTracking(settings(zero_at_start=True), AXES, keep_windows=True)
    out = tracker.process(time_s, noise + OFFSET, temperature)
    assert learnt(tracker)[0] == (0.0, 5.0) and not tracker.zeroing
    assert np.all(np.abs(out.rate_rad_s[time_s >= 10.0].mean(axis=0)) < 3e-4)
    # Its risk: started on a turntable turning at 0.2 deg/s about z, which stops at 30 s.
    rate = noise.copy()
    rate[time_s < 30.0, 2] += math.radians(0.2)
    tracker = BiasTracking(settings(zero_at_start=True), AXES)
    out = tracker.process(time_s, rate, temperature)
    # The turn is taken for the offset; once it stops, z is off by the turn and held.
    assert tracker.status().offset_rad_s[2] == pytest.approx(math.radians(0.2), abs=3e-4)
    assert tracker.status().held == (False, False, True)
    assert out.rate_rad_s[time_s >= 40.0, 2].mean() == pytest.approx(-math.radians(0.2),
                                                                     abs=3e-4)


def test_the_hint_settings_are_checked():
    with pytest.raises(ConfigError, match='rest_hint_max_age_s must be a positive number'):
        settings(rest_hint_max_age_s=0.0)
    with pytest.raises(ConfigError, match='zero_at_start must be true or false'):
        settings(zero_at_start=1)


def test_what_a_hint_taught_is_the_zero_the_offset_fades_to_and_survives_a_restart():
    # A random walk of 1e-4 rad/s/sqrt(s) and an initial std of 2e-3: in motion the offset
    # fades to its zero with a time constant of 2 x 2e-3^2 / 1e-8 = 800 s.
    time_s, noise, temperature = record(1200.0)
    rate = noise + OFFSET
    moving = time_s >= 30.0
    rate[moving] += 50 * NOISE * np.random.default_rng(3).standard_normal(
        (np.count_nonzero(moving), 3))
    tracker = BiasTracking(settings(random_walk_rad_s_rt_s=(1e-4,)), AXES)
    tracker.process(time_s, rate, temperature, rest_hint=~moving)
    state = tracker.state()
    assert state['zero_rad_s'] == pytest.approx([OFFSET] * 3, abs=4e-4)
    # 1170 s of motion later the offset is still the hinted one, not faded toward 0.
    assert tracker.status().offset_rad_s == pytest.approx(state['zero_rad_s'], abs=1e-12)
    restored = BiasTracking(tracker.settings, AXES,
                            state=tracking_state(state, 3, max_offset_rad_s=1.0))
    assert restored.state() == state
    # A re-zero by the operator (a seed) forgets it: the model is its zero again.
    restored.seed([0.0] * 3, [1e-8] * 3)
    assert 'zero_rad_s' not in restored.state()
    with pytest.raises(CalibrationError, match=r'zero_rad_s\[0\] 2.0 is outside -1 to 1'):
        tracking_state({**state, 'zero_rad_s': [2.0, 0.0, 0.0]}, 3, max_offset_rad_s=1.0)
