"""
The field learner on known signals (core, no ROS): its maths, its guard, its state, bad input.

The filter is checked against the batch least squares it must equal, its fading against
the prior it must return to, its extrapolation against the held edge; the guard on pairs
of known gains; the learner with the real tracker over records built here (rests and
turns, a temperature cycle, a bias whose shape the prior model does not hold) against
what it must do: renew the model and beat tracking alone, hold the prior where no rest
came, refuse a window with NaN or a temperature jump, survive a state file's round trip
and refuse a damaged one, keep its state's size flat.
"""

import json
import math
import re

from mlx_tempcomp.core.errors import CalibrationError, ConfigError
from mlx_tempcomp.core.learning import FieldLearner, LearningTracking
from mlx_tempcomp.core.learning.curve import CurveFilter, observation, prior_covariance
from mlx_tempcomp.core.learning.guard import Pairs, t_multiple, verdict
from mlx_tempcomp.core.learning.settings import MIN_FADING_S
from mlx_tempcomp.core.standstill.bias_tracker import BiasTracking, TrackingSettings
from mlx_tempcomp.core.standstill.detector import StandstillSettings, WindowStatistics
from mlx_tempcomp.parameters.learning import knots_of, learning_parameters, learning_settings
import numpy as np
import pytest
import yaml

AXES = ('x', 'y', 'z')
RATE_HZ = 2.0
NOISE = 1e-3
KNOTS = (-10.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0)


def tracking(**changes) -> TrackingSettings:
    standstill = {'rate_noise_rad_s': (NOISE,) * 3, 'random_walk_rad_s_rt_s': (1e-6,),
                  'window_s': 5.0, 'max_temperature_rate_c_s': 0.05, **changes}
    return TrackingSettings(StandstillSettings(**standstill), initial_std_rad_s=(1e-3,))


def settings(**values):
    given = {'learning.temperature_min_c': -10.0, 'learning.temperature_max_c': 50.0,
             'learning.knot_step_c': 10.0, **{f'learning.{k}': v for k, v in values.items()}}
    return learning_settings(given, tracking())


def shape(temperature) -> np.ndarray:
    """Give the bias the prior model does not hold: a bowl, 2e-3 rad/s at 0 C and 50 C."""
    return 2e-3 * ((np.asarray(temperature) - 25.0) / 25.0) ** 2


def record(hours: float = 4.0, seed: int = 0, turn_at=None) -> tuple:
    """
    Give (time, rate, temperature, None, true rate) of rests of 90 s every 5 min.

    No accelerometer: the gyro alone judges every axis, as an MLX90609's.

    The temperature cycles 0 to 50 C in two hours; the rate is the bowl, white noise and
    the turns between the rests (fast, about z; out and back about x). ``turn_at`` (start,
    end, rate): a slow turn about gravity (z) in that stretch of a rest.
    """
    rng = np.random.default_rng(seed)
    time_s = np.arange(0.0, hours * 3600.0, 1.0 / RATE_HZ)
    temperature = 25.0 - 25.0 * np.cos(2.0 * math.pi * time_s / 7200.0)
    truth = np.zeros((time_s.size, 3))
    phase = time_s % 300.0
    truth[(phase >= 90.0) & (phase < 195.0), 2] = 0.5
    truth[(phase >= 195.0) & (phase < 245.0), 0] = 0.3
    truth[(phase >= 245.0) & (phase < 295.0), 0] = -0.3
    if turn_at is not None:
        start, end, turn = turn_at
        truth[(time_s >= start) & (time_s < end), 2] += turn
    rate = truth + shape(temperature)[:, None] + NOISE * rng.standard_normal((time_s.size, 3))
    return time_s, rate, temperature, None, truth


def run(learning=None, stream=None, data=None, **values):
    """Run tracking and learning over ``data`` (a `record`); give (stream, its output)."""
    data = record() if data is None else data
    if stream is None:
        stream, error = LearningTracking.start(BiasTracking(tracking(), AXES),
                                               learning or settings(**values))
        assert error == ''
    return stream, stream.process(*data[:4])


def last_quarter_error(out_rate: np.ndarray, data) -> np.ndarray:
    """RMS of the 60 s means of the published rate less the true rate, last quarter."""
    time_s, truth = data[0], data[4]
    start = time_s.size * 3 // 4
    error = (out_rate - truth)[start:]
    index = ((time_s[start:] - time_s[start]) // 60.0).astype(int)
    means = np.array([np.bincount(index, error[:, i]) / np.bincount(index)
                      for i in range(3)]).T
    return np.sqrt(np.mean(means * means, axis=0))


# The filter's maths.

def test_the_prior_is_a_random_walk_out_from_the_middle_knot():
    prior = prior_covariance(KNOTS, (1e-3,) * len(KNOTS), 1e-2, 20.0)
    shape_part = prior[1:, 1:]
    assert np.min(np.linalg.eigvalsh(prior)) > -1e-18
    middle = len(KNOTS) // 2
    assert shape_part[middle, middle] == 0.0
    variance = np.diag(shape_part)
    # Each step of 10 C adds 2 sigma^2 10 / 20 = sigma^2; none is shared across the middle.
    assert variance[middle + 1:] == pytest.approx([1e-6, 2e-6, 3e-6])
    assert variance[:middle] == pytest.approx([3e-6, 2e-6, 1e-6])
    assert shape_part[0, -1] == 0.0 and shape_part[0, 1] == pytest.approx(2e-6)


def test_the_filter_equals_the_batch_least_squares():
    prior = prior_covariance(KNOTS, (2e-3,) * len(KNOTS), 2e-2, 20.0)
    rng = np.random.default_rng(3)
    temperature = rng.uniform(-5.0, 45.0, 40)
    values = shape(temperature) + 1e-4 * rng.standard_normal(40)
    f = CurveFilter(prior)
    for t, v in zip(temperature, values):
        f.update(observation(KNOTS, t), float(v), 1e-8, gate=1e9)
    h = np.array([observation(KNOTS, t) for t in temperature])
    gain = prior @ h.T @ np.linalg.inv(h @ prior @ h.T + 1e-8 * np.eye(40))
    assert np.allclose(f.mean, gain @ values, rtol=0, atol=1e-9)
    assert np.allclose(f.covariance, prior - gain @ h @ prior, rtol=0, atol=1e-12)


def test_fading_brings_the_shape_back_to_the_prior_and_the_level_walks():
    prior = prior_covariance(KNOTS, (2e-3,) * len(KNOTS), 2e-2, 20.0)
    f = CurveFilter(prior, time_s=0.0)
    for t in np.linspace(0.0, 40.0, 30):
        f.update(observation(KNOTS, t), float(shape(t)), 1e-10, gate=1e9)
    learnt = f.mean.copy()
    level_variance = f.covariance[0, 0]
    f.predict(100.0, 1e-5, fading_s=100.0)
    assert np.allclose(f.mean[1:], learnt[1:] * math.exp(-1.0))
    assert f.mean[0] == learnt[0]
    assert f.covariance[0, 0] == pytest.approx(level_variance + 1e-10 * 100.0)
    f.predict(100.0 + 1e5, 0.0, fading_s=100.0)
    assert np.allclose(f.mean[1:], 0.0, atol=1e-15)
    assert np.allclose(f.covariance[1:, 1:], prior[1:, 1:], rtol=1e-9, atol=1e-20)


def test_beyond_the_last_rest_the_curve_is_held_and_stays_uncertain():
    prior = prior_covariance(KNOTS, (2e-3,) * len(KNOTS), 2e-2, 20.0)
    f = CurveFilter(prior)
    for t in np.linspace(15.0, 25.0, 20):
        f.update(observation(KNOTS, t), float(5e-4 + 1e-4 * (t - 20.0)), 1e-10, gate=1e9)
    curve = f.curve()
    # Knots 20 and 30: the walk from the middle; beyond the last rest (25 C) no slope goes on.
    assert curve[-1] == pytest.approx(curve[-2], abs=1e-12)
    assert curve[0] == pytest.approx(curve[1], abs=1e-12)
    spread = np.sqrt(f.curve_variance())
    assert spread[-1] > 10 * spread[3] and spread[0] > 10 * spread[3]


def test_the_gate_bounds_the_pull_of_one_window():
    prior = prior_covariance(KNOTS, (1e-3,) * len(KNOTS), 1e-2, 20.0)
    f = CurveFilter(prior)
    h = observation(KNOTS, 20.0)
    spread = math.sqrt(float(h @ prior @ h) + 1e-8)
    weight = f.update(h, 1.0, 1e-8, gate=4.0)
    assert weight == pytest.approx(16.0 * spread * spread)   # (4 spread / 1.0)^2
    assert float(h @ f.mean) <= 4.0 * spread


# The guard.

def pairs_of(runs) -> Pairs:
    total = Pairs()
    for windows in runs:
        run_pairs = Pairs()
        for in_use, challenger, prior in windows:
            run_pairs.add(in_use, challenger, prior)
        total.fold_run(run_pairs)
    return total


def test_t_multiple_is_the_student_quantile_of_the_normal_tail():
    assert t_multiple(2.0, 2) == pytest.approx(13.97, abs=0.01)
    assert t_multiple(2.0, 5) == pytest.approx(2.869, abs=0.002)
    assert t_multiple(2.0, 10000) == pytest.approx(2.0, abs=0.002)


def test_the_guard_accepts_a_better_curve_refuses_a_worse_and_brings_the_prior_back():
    rng = np.random.default_rng(4)
    better = pairs_of([[(1e-3 + 1e-4 * rng.standard_normal(), 2e-4, 1e-3)
                        for _ in range(5)] for _ in range(6)])
    decision, reason = verdict(better, 2.0, prior_in_use=True)
    assert decision == 'accept' and 'held-out gain' in reason
    worse = pairs_of([[(2e-4, 1e-3 + 1e-4 * rng.standard_normal(), 2e-4)
                       for _ in range(5)] for _ in range(6)])
    assert verdict(worse, 2.0, prior_in_use=True)[0] == 'keep'
    assert 'not 2.65 standard errors' in verdict(worse, 2.0, prior_in_use=True)[1]
    prior_better = pairs_of([[(1e-3 + 1e-4 * rng.standard_normal(), 2e-3, 1e-4)
                              for _ in range(5)] for _ in range(6)])
    decision, reason = verdict(prior_better, 2.0, prior_in_use=False)
    assert decision == 'revert' and reason.startswith('back to the prior')
    assert verdict(prior_better, 2.0, prior_in_use=True)[0] == 'keep'


def test_one_run_of_many_windows_is_not_enough():
    lucky = pairs_of([[(1e-3, 1e-4, 1e-3)] * 50])
    assert verdict(lucky, 2.0, prior_in_use=True)[0] == 'keep'


# The learner with the tracker.

def test_the_learner_renews_the_model_and_beats_tracking_alone():
    data = record()
    alone = BiasTracking(tracking(), AXES).process(*data[:4])
    stream, out = run(data=data)
    learner = stream.learner
    assert all(count >= 1 for count in learner.renewals)
    assert learner.windows > 2000 and not learner.refused
    # A shift the tracker withdraws drops its run: a few, where the bowl is steep.
    assert learner.runs_dropped < learner.runs_committed / 10
    # The curve in use follows the bowl from 0 to 50 C (less a common offset the tracker
    # takes), where the rests were.
    knots = np.array(learner.settings.knots_c)
    for axis in range(3):
        curve = np.array(learner.accepted.values_rad_s[axis])
        change = (curve - curve[3]) - (shape(knots) - shape(20.0))
        assert np.max(np.abs(change[1:])) < 3e-4, axis     # 15 % of the bowl
    # Until the first renewal is taken off, the published rate is tracking alone's, bit
    # for bit.
    first = int(np.argmax(np.any(out.correction_rad_s != 0.0, axis=1)))
    assert first > 0 and np.array_equal(out.rate_rad_s[:first], alone.rate_rad_s[:first])
    with_learning = last_quarter_error(out.rate_rad_s, data)
    tracking_alone = last_quarter_error(alone.rate_rad_s, data)
    assert np.all(with_learning < 0.7 * tracking_alone)
    assert np.sum(with_learning) < 0.5 * np.sum(tracking_alone)


def test_where_no_rest_came_the_renewed_model_is_the_prior_moved_by_the_edge():
    data = record(hours=2.0)
    cool = data[2] < 30.0
    stream, _ = run(data=tuple(None if column is None else column[cool] for column in data))
    learner = stream.learner
    knots = learner.settings.knots_c
    for axis in range(3):
        curve = learner.accepted.values_rad_s[axis]
        assert any(curve)
        assert curve[knots.index(40.0)] == pytest.approx(curve[knots.index(50.0)], abs=1e-9)
    assert max(learner.coverage()[0][knots.index(50.0):]) < 0.2


def test_a_window_with_nan_and_a_temperature_jump_are_refused():
    learner = FieldLearner(settings(), AXES)
    table = learner.accepted
    learner.window(window(5.0, 20.0), {0, 1, 2}, table)
    before = [f.mean.copy() for f in learner.working]
    learner.window(window(10.0, 20.0, (math.nan, 1e-3, 1e-3)), {0, 1, 2}, table)
    learner.window(window(15.0, math.nan), {0, 1, 2}, table)
    assert learner.refused == {'not finite': 2}
    learner.window(window(20.0, 45.0), {0, 1, 2}, table)       # 25 C in 15 s: a jump
    assert learner.refused == {'not finite': 2, 'temperature jump': 1}
    assert all(np.array_equal(b, f.mean) for b, f in zip(before, learner.working))
    learner.window(window(25.0, 45.2), {0, 1, 2}, table)      # a lasting jump is taken on
    assert learner.windows == 2
    learner.window(window(30.0, 120.0), {0, 1, 2}, table)
    assert learner.refused['outside the knots'] == 1


def test_a_slow_turn_taken_for_rest_does_not_spoil_the_curve():
    """
    Take a slow turn for bias, as the tracker does, and keep the curve nearly as it was.

    A turn of 0.05 deg/s about z (gravity) for a whole rest is rest to the tracker (below
    its 0.1 deg/s bound): the learner takes it as bias at that temperature. Its pull on the
    curve is one run's: the level widens at a run's start, so the run moves the level
    more than the shape, and the curve in use at the end is within 3e-4 rad/s (a third
    of the turn) of the curve learnt without the turn, everywhere.
    """
    turn = math.radians(0.05)
    rest = (3 * 3600.0 + 600.0, 3 * 3600.0 + 690.0)
    clean, _ = run(data=record())
    turned, _ = run(data=record(turn_at=(*rest, turn)))
    a = np.array(clean.learner.accepted.values_rad_s[2])
    b = np.array(turned.learner.accepted.values_rad_s[2])
    assert turned.tracker.window_count == clean.tracker.window_count
    assert np.max(np.abs((b - b.mean()) - (a - a.mean()))) < 3e-4


def window(end_s, temperature, measured=(1e-3, 1e-3, 1e-3)) -> WindowStatistics:
    """Give a closed window of 50 samples measuring ``measured`` at ``temperature``."""
    return WindowStatistics(index=int(end_s // 5), start_s=end_s - 5.0, end_s=end_s,
                            samples=50, first_s=end_s - 5.0, last_s=end_s - 0.1,
                            offset_rad_s=(0.0,) * 3, mean_rad_s=measured,
                            spread_rad_s=(NOISE,) * 3, temperature_rate_c_s=0.0,
                            temperature_c=temperature)


def test_the_state_survives_a_round_trip_and_goes_on_to_the_same_bits():
    stream, _ = run(data=record(hours=2.0))
    saved = yaml.safe_load(yaml.safe_dump(stream.learner.state()))
    restored, error = LearningTracking.start(BiasTracking(tracking(), AXES), settings(), saved)
    assert error == '' and restored.learner.state() == stream.learner.state()
    end = stream.learner.committed[0].time_s
    for learner in (stream.learner, restored.learner):
        for k in range(20):
            learner.window(window(end + 5.0 * (k + 1), 20.0 + 0.05 * k,
                                  (1e-3, -2e-3, 5e-4)), {0, 1, 2}, learner.applied)
    assert restored.learner.state() == stream.learner.state()


@pytest.mark.parametrize('damage, message', [
    (lambda s: s.pop('committed'), 'damaged: committed missing'),
    (lambda s: s['accepted'][1].__setitem__(2, math.nan), r'accepted\[1\]\[2\] nan'),
    (lambda s: s['committed']['covariance'][0].__setitem__(0, -1.0), 'not a covariance'),
    (lambda s: s.__setitem__('knots_c', s['knots_c'][:-1]), 'knots_c must be a list of 7'),
    (lambda s: s['trial'][0].__setitem__(0, 1.5), r'trial\[0\].windows must be an integer'),
    (lambda s: s.__setitem__('axes', ['x', 'y']), r"axes \['x', 'y'\] are not"),
])
def test_a_damaged_state_gives_the_prior_and_one_error(damage, message):
    stream, _ = run(data=record(hours=1.0))
    state = json.loads(json.dumps(stream.learner.state()))
    damage(state)
    restored, error = LearningTracking.start(BiasTracking(tracking(), AXES), settings(), state)
    assert error.startswith('learning state unusable, starting from the prior model: ')
    assert '\n' not in error and re.search(message, error), error
    assert restored.learner.state() == FieldLearner(settings(), AXES).state()


def numbers(value) -> int:
    """Count the numbers in a state: its size whatever their digits."""
    if isinstance(value, dict):
        return sum(numbers(v) for v in value.values())
    if isinstance(value, list):
        return sum(numbers(v) for v in value)
    return int(isinstance(value, (int, float)) and not isinstance(value, bool))


@pytest.mark.slow
def test_the_state_size_is_flat():
    stream, _ = run(data=record(hours=4.0))
    windows, size = stream.learner.windows, numbers(stream.learner.state())
    time_s, *rest = record(hours=12.0, seed=1)
    run(stream=stream, data=(time_s + 4 * 3600.0, *rest))
    assert stream.learner.windows > 3 * windows
    assert numbers(stream.learner.state()) == size


# The parameters.

def test_the_settings_come_from_the_table_and_the_tracker():
    s = settings()
    assert s.knots_c == (-10.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0)
    assert s.prior_std_rad_s[0] == (1e-3,) * 7 and s.level_std_rad_s == (1e-2,) * 3
    assert s.fading_s == (2e6,) * 3     # 2 x 1e-3^2 / 1e-6^2: the tracker's own
    assert learning_settings({}, tracking(random_walk_rad_s_rt_s=(1e-4,))).fading_s[0] == \
        MIN_FADING_S                    # 200 s: a day at least
    assert knots_of({'learning.temperature_min_c': 0.0, 'learning.temperature_max_c': 12.0,
                     'learning.knot_step_c': 5.0}) == (0.0, 5.0, 10.0, 12.0)
    assert learning_parameters(significance=3)['learning']['significance'] == 3.0
    with pytest.raises(ConfigError, match='learning.knot_step_c: must be a number'):
        settings(knot_step_c=0.0)
    with pytest.raises(ConfigError, match='learning.prior_std_rad_s: give one value'):
        settings(prior_std_rad_s=[1e-3, 1e-3])
    with pytest.raises(ConfigError, match='unknown learning parameters: bogus'):
        learning_parameters(bogus=1)
    with pytest.raises(CalibrationError, match='3 axes'):
        FieldLearner(settings(), ('x', 'z'))
