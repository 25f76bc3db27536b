"""
The standstill detector and the bias tracker on known signals (core, no ROS).

The signals are built here: white noise of a known sigma at 50 Hz, an offset, turns
and steps at known times; the figures asserted are what the code computes from them.
"""

import math

from mlx_tempcomp.core.errors import CalibrationError, ConfigError
from mlx_tempcomp.core.standstill.bias_tracker import (BiasTracking, tracking_state,
                                                       TrackingSettings, TrackingState)
from mlx_tempcomp.core.standstill.detector import StandstillSettings
from mlx_tempcomp.parameters.tracking import (PREFIX, tracking_parameters, tracking_settings,
                                              TRACKING_SPECS)
import numpy as np
import pytest

RATE_HZ = 50.0
NOISE = 1e-3                         # rad/s per sample: a window mean is 6.3e-5 rad/s
WINDOW_S = 5.0
BOUND = math.radians(0.1)            # max_mean_rate_rad_s
GRAVITY = np.array([0.0, 0.0, -9.81])


def settings(axes=3, **changes) -> TrackingSettings:
    standstill = {'rate_noise_rad_s': (NOISE,) * axes, 'random_walk_rad_s_rt_s': (1e-6,),
                  'window_s': WINDOW_S, 'max_acceleration_spread_m_s2': 0.05,
                  **{k: v for k, v in changes.items() if k not in ('initial_std_rad_s',)}}
    return TrackingSettings(StandstillSettings(**standstill),
                            initial_std_rad_s=(changes.get('initial_std_rad_s', 2e-3),))


def record(duration_s: float, axes=3, seed=0) -> tuple:
    rng = np.random.default_rng(seed)
    time_s = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    noise = NOISE * rng.standard_normal((time_s.size, axes))
    temperature = np.full(time_s.size, 25.0)
    return time_s, noise, temperature


def learnt_windows(tracker) -> list:
    return [(start, end) for w in tracker.windows for start, end, _ in w.learnt]


def test_rest_is_still_after_two_windows_and_learns_the_offset():
    time_s, noise, temperature = record(60.0)
    offset = np.array([1e-3, -5e-4, 2e-4])
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    out = tracker.process(time_s, noise + offset, temperature)
    # Still from the close of the second window (t = 10 s) on; moving before.
    assert not out.still[time_s < 10.0].any() and out.still[time_s >= 10.0].all()
    # Each window is learnt when the next one agrees: the first at 10 s, then one a window.
    assert learnt_windows(tracker)[:2] == [(0.0, 5.0), (5.0, 10.0)]
    assert len(learnt_windows(tracker)) == 10        # every window but the last
    status = tracker.status()
    assert np.allclose(status.offset_rad_s, offset, atol=4 * NOISE / math.sqrt(RATE_HZ * 50))
    assert status.still and all(status.stable) and status.updates == 10
    # The output is the input less the offset in effect, which moves only at window ends.
    applied = (noise + offset) - out.rate_rad_s
    changes = np.flatnonzero(np.any(np.abs(np.diff(applied, axis=0)) > 1e-12, axis=1))
    assert set(time_s[changes + 1].round(9)) == {10.0 + 5.0 * k for k in range(10)}


def test_a_slow_constant_turn_is_never_learnt_without_an_accelerometer():
    time_s, noise, temperature = record(300.0)
    rate = noise.copy()
    rate[:, 2] += math.radians(0.2)             # the slowest turn of the issue, all along
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    out = tracker.process(time_s, rate, temperature)
    # z sees the turn and is held; x and y, which do not, go on learning their offsets.
    assert not out.still.any() and tracker.status().held == (False, False, True)
    assert tracker.status().offset_rad_s[2] == 0.0 and tracker.updates > 0
    assert all(axes == (0, 1) for w in tracker.windows for _, _, axes in w.learnt)
    assert {w.reason.split(' ')[0] for w in tracker.windows[1:]} == {'held:'}
    # Turning on every axis, nothing is learnt.
    rate[:, :2] += math.radians(0.2)
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    tracker.process(time_s, rate, temperature)
    assert tracker.updates == 0
    assert {w.reason.split(' ')[0] for w in tracker.windows} == {'mean'}


@pytest.mark.parametrize('ramp_s', [30.0, 120.0, 600.0])
def test_a_slow_ramp_after_a_rest_is_not_followed(ramp_s):
    """A turn ramping from 0 to 0.2 deg/s after a rest: the offset comes back from it."""
    time_s, noise, temperature = record(200.0 + ramp_s + 100.0)
    ramp = np.clip((time_s - 100.0) / ramp_s, 0.0, 1.0) * math.radians(0.2)
    rate = noise.copy()
    rate[:, 2] += ramp
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    out = tracker.process(time_s, rate, temperature)
    offset_z = rate[:, 2] - out.rate_rad_s[:, 2]
    # While the ramp is below the bound it may look like a bias step for a few windows;
    # once it goes on, that shift is undone, and the turn itself is never taken.
    turning = time_s >= 100.0 + ramp_s
    assert np.max(np.abs(offset_z[turning])) < 1e-4
    assert not out.still[turning].any() and tracker.status().held[2]
    assert np.max(np.abs(offset_z)) <= 1.1 * BOUND


def test_a_constant_turn_slower_than_the_bound_is_rest_to_the_tracker():
    """What a gyro alone cannot tell: a turn below max_mean_rate_rad_s is an offset to it."""
    time_s, noise, temperature = record(60.0)
    rate = noise.copy()
    rate[:, 2] += 0.5 * BOUND
    tracker = BiasTracking(settings(), ('x', 'y', 'z'))
    tracker.process(time_s, rate, temperature)
    assert tracker.still and tracker.status().offset_rad_s[2] == pytest.approx(0.5 * BOUND,
                                                                               abs=2e-4)


def test_a_bias_step_at_rest_is_followed_within_two_still_windows():
    time_s, noise, temperature = record(200.0)
    step = 0.5 * BOUND
    rate = noise.copy()
    rate[time_s >= 102.5, 0] += step            # in the middle of a window
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    out = tracker.process(time_s, rate, temperature)
    error = out.rate_rad_s[:, 0] - np.where(time_s >= 102.5, 0.0, 0.0) - noise[:, 0]
    # The window holding the step spreads (moving); 105-110 and 110-115 agree: still at
    # 115 s, and 105-110 learnt then. From there the offset holds the step.
    followed = time_s >= 115.0
    assert tracker.windows[20].reason.startswith('rate spread') or \
        tracker.windows[21].reason.startswith('offset moved')
    assert np.max(np.abs(error[followed])) < 0.1 * step
    assert np.max(np.abs(error[(time_s >= 102.5) & (time_s < 110.0)])) > 0.9 * step


def test_turns_about_a_horizontal_axis_show_in_the_accelerometer():
    """0.08 deg/s about x, below the gyro's bound: the specific force tilts, no update."""
    time_s, noise, temperature = record(300.0)
    rate = noise.copy()
    rate_x = math.radians(0.08)
    turning = time_s >= 100.0
    rate[turning, 0] += rate_x
    angle = np.where(turning, (time_s - 100.0) * rate_x, 0.0)
    acceleration = np.column_stack([np.zeros_like(angle), -9.81 * np.sin(angle),
                                    -9.81 * np.cos(angle)])
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    out = tracker.process(time_s, rate, temperature, acceleration)
    assert not out.still[time_s >= 105.0].any()
    assert all(end <= 100.0 for _, end in learnt_windows(tracker))
    assert any(w.reason.startswith('specific force turned') for w in tracker.windows)
    # The same turn about gravity (z, here vertical) is rest to the tracker.
    rate = noise.copy()
    rate[turning, 2] += rate_x
    tracker = BiasTracking(settings(), ('x', 'y', 'z'))
    tracker.process(time_s, rate, temperature, np.tile(GRAVITY, (time_s.size, 1)))
    assert tracker.still


def test_with_an_accelerometer_the_bound_applies_about_gravity():
    """
    An offset beyond the bound on a horizontal axis is learnt; on the vertical it is not.

    The horizontal axes go on learning while z is held: a turn about gravity of 1.5 x the
    bound moves them by 0.02 x that (GRAVITY_TILT_RAD), below their window noise.
    """
    time_s, noise, temperature = record(60.0)
    gravity = np.tile(GRAVITY, (time_s.size, 1))
    for axis, learnt in ((0, True), (2, False)):
        rate = noise.copy()
        rate[:, axis] += 1.5 * BOUND
        tracker = BiasTracking(settings(), ('x', 'y', 'z'))
        tracker.process(time_s, rate, temperature, gravity)
        status = tracker.status()
        assert (abs(status.offset_rad_s[axis] - 1.5 * BOUND) < 1e-4) == learnt
        assert status.held == (False, False, not learnt) and status.still == learnt
        assert status.updates > 0


def test_temperature_shaking_gaps_and_bad_samples_stop_the_learning():
    time_s, noise, temperature = record(100.0)
    cases = {
        'temperature rate': (noise, temperature + 0.5 * time_s, None),
        'acceleration spread': (noise, temperature, GRAVITY + np.random.default_rng(1)
                                .normal(0.0, 0.3, (time_s.size, 3))),
        'fewer than': (noise[::70], temperature[::70], None),
    }
    for expected, (rate, temps, acceleration) in cases.items():
        tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
        step = 70 if expected == 'fewer than' else 1
        tracker.process(time_s[::step], rate, temps, acceleration)
        assert tracker.updates == 0, expected
        assert all(expected.split(' ')[-1] in w.reason for w in tracker.windows), expected
    # A NaN spoils its window only; a gap of a window breaks the run.
    rate = noise.copy()
    rate[260, 1] = math.nan
    keep = (time_s < 40.0) | (time_s >= 50.0)
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    out = tracker.process(time_s[keep], rate[keep], temperature[keep])
    assert math.isnan(out.rate_rad_s[260, 1])
    assert tracker.windows[1].reason.startswith('rate spread nan')
    learnt = learnt_windows(tracker)
    assert (0.0, 5.0) not in learnt and (5.0, 10.0) not in learnt and (10.0, 15.0) in learnt
    assert (35.0, 40.0) not in learnt and (50.0, 55.0) in learnt


def test_leave_windows_keeps_the_flag_through_one_bad_window():
    time_s, noise, temperature = record(60.0)
    rate = noise.copy()
    shaking = (time_s >= 30.0) & (time_s < 35.0)              # one window of motion
    rate[shaking] += 0.05 * np.sin(2.0 * np.pi * time_s[shaking])[:, None]
    for leave, still_after in ((1, False), (2, True)):
        tracker = BiasTracking(settings(leave_windows=leave), ('x', 'y', 'z'))
        out = tracker.process(time_s, rate, temperature)
        assert out.still[(time_s >= 35.0) & (time_s < 40.0)].all() == still_after
        assert not np.any(np.abs(np.array(tracker.status().offset_rad_s)) > 1e-3)


def test_the_clock_going_back_starts_a_new_grid():
    time_s, noise, temperature = record(40.0)
    tracker = BiasTracking(settings(), ('x', 'y', 'z'), keep_windows=True)
    tracker.process(time_s, noise + 1e-3, temperature)
    out = tracker.process(time_s[:300], noise[:300] + 1e-3, temperature[:300])
    # The window open when the clock went back closes; then moving until two agree again.
    assert not out.still[1:].any() and len(tracker.windows) == 9
    assert tracker.windows[-1].start_s == 0.0 and tracker.windows[-2].start_s == 35.0


def test_the_state_round_trips_and_survives_a_restart():
    time_s, noise, temperature = record(60.0)
    tracker = BiasTracking(settings(), ('x', 'y', 'z'))
    tracker.process(time_s, noise + 1e-3, temperature)
    state = tracker.state()
    restored = BiasTracking(settings(), ('x', 'y', 'z'), state=tracking_state(state, 3))
    assert restored.state() == state
    assert restored.status().offset_rad_s == tracker.status().offset_rad_s
    assert restored.status().std_rad_s == tracker.status().std_rad_s
    assert not restored.still                      # a restart starts moving
    # A restart 100 s later grows the variance by q dt at the first window.
    restored.process(time_s + 160.0, noise + 1e-3, temperature)
    assert restored.updates > state['updates']
    fresh = BiasTracking(settings(), ('x', 'y', 'z'))
    assert fresh.state()['updates'] == 0 and fresh.state()['time_s'] is None
    assert tracking_state(fresh.state(), 3).time_s is None


@pytest.mark.parametrize('change, message', [
    ({'offset_rad_s': [0.0, 'abc', 0.0]}, "offset_rad_s\\[1\\] must be a number, got 'abc'"),
    ({'offset_rad_s': [0.0, 0.0]}, 'offset_rad_s must be a list of 3 values'),
    ({'variance_rad2_s2': [0.0, -1.0, 0.0]}, 'variance_rad2_s2\\[1\\] -1.0 is outside 0 to'),
    ({'offset_rad_s': [1e300, 0.0, 0.0]}, 'offset_rad_s\\[0\\] 1e\\+300 is outside -34.9'),
    ({'time_s': math.nan}, 'time_s nan is outside'),
    ({'updates': 1.5}, 'updates must be an integer, got 1.5'),
    ({'updates': True}, 'updates must be an integer'),
    ({'updates': None}, 'updates must be an integer'),
])
def test_bad_states_are_refused_naming_the_field(change, message):
    state = {'offset_rad_s': [0.0] * 3, 'variance_rad2_s2': [1e-8] * 3, 'time_s': 10.0,
             'updates': 3, 'last_update_s': 5.0, **change}
    with pytest.raises(CalibrationError, match=message):
        tracking_state(state, 3, max_offset_rad_s=math.radians(2000.0))
    with pytest.raises(CalibrationError, match='updates, last_update_s missing'):
        tracking_state({'offset_rad_s': [0.0] * 3, 'variance_rad2_s2': [0.0] * 3,
                        'time_s': 1.0}, 3)
    one_axis = TrackingState((0.0,), (0.0,), None, 0, None)
    with pytest.raises(CalibrationError, match='has 1 axes, not 3'):
        BiasTracking(settings(), ('x', 'y', 'z'), state=one_axis)


def test_a_seed_sets_the_offset_and_its_variance():
    tracker = BiasTracking(settings(), ('x', 'y', 'z'))
    assert tracker.status().stable == (False,) * 3
    tracker.seed([1e-3, 0.0, -1e-3], [1e-10] * 3, time_s=5.0)
    status = tracker.status()
    assert status.offset_rad_s == (1e-3, 0.0, -1e-3) and all(status.stable)
    out = tracker.process_one(6.0, [1e-3, 0.0, 0.0], 25.0)
    assert out[0] == [0.0, 0.0, 1e-3] and out[1] == [1e-5] * 3 and out[2] is False
    with pytest.raises(CalibrationError, match='finite offsets and variances >= 0'):
        tracker.seed([math.nan, 0.0, 0.0], [0.0] * 3)


def test_settings_are_checked_naming_the_setting():
    with pytest.raises(ConfigError, match='random_walk_rad_s_rt_s needs one value or one per '
                                          'axis \\(3\\), got 2'):
        settings(random_walk_rad_s_rt_s=(1e-6, 1e-6))
    with pytest.raises(ConfigError, match='window_s must be a positive number'):
        settings(window_s=0.0)
    with pytest.raises(ConfigError, match='enter_windows must be an integer >= 1'):
        settings(enter_windows=0)
    with pytest.raises(ConfigError, match='initial_std_rad_s must be finite and > 0'):
        settings(initial_std_rad_s=0.0)


def node_values(**given) -> dict:
    values = {spec.name: spec.default for spec in TRACKING_SPECS}
    values.update({PREFIX + k: v for k, v in given.items()})
    return values


def test_node_values_make_the_settings_or_name_the_parameter():
    built = tracking_settings(node_values(), ('z',), rate_noise_rad_s=0.0058)
    assert built.standstill.rate_noise_rad_s == (0.0058,)
    assert built.standstill.window_s == 5.0 and built.standstill.enter_windows == 2
    assert tracking_settings(node_values(enabled=False), ('z',), 0.0058) is None
    built = tracking_settings(node_values(rate_noise_rad_s=[1e-3, 0.0]), ('x', 'z'), 0.0058)
    assert built.standstill.rate_noise_rad_s == (1e-3, 0.0058)
    with pytest.raises(ConfigError, match='invalid parameter bias_tracking.rate_noise_rad_s: '
                                          'bias tracking needs the noise'):
        tracking_settings(node_values(), ('z',), rate_noise_rad_s=0.0)
    with pytest.raises(ConfigError, match='invalid parameter bias_tracking.initial_std_rad_s: '
                                          'give one value or one per axis \\(2\\)'):
        tracking_settings(node_values(initial_std_rad_s=[1e-3] * 3), ('x', 'z'), 0.0058)
    with pytest.raises(ConfigError, match='random_walk_rad_s_rt_s: give one value .* got '
                                          '\\[-1.0\\]'):
        tracking_settings(node_values(random_walk_rad_s_rt_s=[-1.0]), ('z',), 0.0058)
    section = tracking_parameters(window_s=10, rate_noise_rad_s=[1, 2])['bias_tracking']
    assert section['window_s'] == 10.0 and section['rate_noise_rad_s'] == [1.0, 2.0]
    assert section['enabled'] is True and section['enter_windows'] == 2
    with pytest.raises(ConfigError, match='unknown bias_tracking parameters: windows'):
        tracking_parameters(windows=3)
