"""
Property-based test of tracking with field learning: any split into blocks gives the same bits.

The node will hand `LearningTracking` blocks of 1 to ``max_block`` samples (`process_one`
for a block of one), ``mlx-tempcomp evaluate --learn`` the whole record in one block.
Random records (rests and turns so the tracker learns and the learner renews its curve
often, a temperature that ramps, gaps, the clock going back, NaN and infinite values in
any column, an accelerometer or none) and random splits must give the same rates,
standard deviations, still flags and corrections as one block, and the same states.
"""

import math

from fuzz import examples
from hypothesis import given, settings, strategies as st
from mlx_tempcomp.core.learning import LearningTracking
from mlx_tempcomp.core.standstill.bias_tracker import BiasTracking, TrackingSettings
from mlx_tempcomp.core.standstill.detector import StandstillSettings
from mlx_tempcomp.parameters.learning import learning_settings
import numpy as np

FUZZ = settings(max_examples=examples(60), deadline=None)
SPECIAL = st.sampled_from([math.nan, math.inf, -math.inf, 1e300])


@st.composite
def streams(draw):
    """Give (tracking settings, learning settings, axes, time, rate, temperature, accel)."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    axes = draw(st.sampled_from([('z',), ('x', 'y', 'z')]))
    rows = draw(st.integers(1, 900))
    interval = draw(st.sampled_from([0.05, 0.1]))
    time_s = 500.0 + interval * np.arange(rows) + rng.uniform(0.0, 0.3 * interval, rows)
    for _ in range(draw(st.integers(0, 2))):
        at = draw(st.integers(0, rows - 1))
        time_s[at:] += draw(st.sampled_from([4.0, -30.0, -0.5 * interval]))
    temperature = 10.0 + 30.0 * np.arange(rows) / 900.0 + 0.01 * rng.standard_normal(rows)
    moving = np.repeat(rng.random(rows // 30 + 1) < 0.3, 30)[:rows]
    rate = 2e-4 * rng.standard_normal((rows, len(axes))) + \
        1e-4 * (temperature[:, None] - 25.0)
    rate[moving] += rng.choice([0.05, -0.5]) * rng.random(len(axes))
    acceleration = np.array([0.0, 0.0, -9.81]) + 0.01 * rng.standard_normal((rows, 3))
    acceleration[moving] += rng.random(3)
    for column in draw(st.lists(st.sampled_from(['rate', 'temperature', 'acceleration']),
                                max_size=3)):
        target = {'rate': rate, 'temperature': temperature, 'acceleration': acceleration}
        target[column].reshape(rows, -1)[draw(st.integers(0, rows - 1)), 0] = draw(SPECIAL)
    tracking = TrackingSettings(StandstillSettings(
        rate_noise_rad_s=(2e-4,) * len(axes), random_walk_rad_s_rt_s=(1e-4,),
        window_s=draw(st.sampled_from([0.5, 1.0])), max_temperature_rate_c_s=1.0,
        max_acceleration_spread_m_s2=0.05, enter_windows=draw(st.integers(1, 2))),
        initial_std_rad_s=(3e-3,))
    learning = learning_settings({'learning.temperature_min_c': 0.0,
                                  'learning.temperature_max_c': 50.0,
                                  'learning.knot_step_c': 10.0, 'learning.significance': 0.0,
                                  'learning.min_runs': 2, 'learning.min_windows': 2}, tracking)
    return tracking, learning, axes, time_s, rate, temperature, acceleration


def _start(tracking, learning, axes) -> LearningTracking:
    stream, error = LearningTracking.start(BiasTracking(tracking, axes), learning)
    assert error == ''
    return stream


def _same(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def _same_state(a: LearningTracking, b: LearningTracking) -> bool:
    return repr(a.learner.state()) == repr(b.learner.state()) and \
        repr(a.tracker.state()) == repr(b.tracker.state())


@FUZZ
@given(streams(), st.booleans(), st.data())
def test_any_split_gives_the_bits_of_one_block(stream, with_acceleration, data):
    tracking, learning, axes, time_s, rate, temperature, acceleration = stream
    acceleration = acceleration if with_acceleration else None
    whole_stream = _start(tracking, learning, axes)
    whole = whole_stream.process(time_s, rate, temperature, acceleration)
    split = _start(tracking, learning, axes)
    rows = time_s.size
    start = 0
    parts = []
    while start < rows:
        end = min(rows, start + data.draw(st.integers(1, 120)))
        if end - start == 1:
            out = split.process_one(float(time_s[start]), rate[start].tolist(),
                                    float(temperature[start]),
                                    None if acceleration is None else
                                    acceleration[start].tolist())
            # The rates in use: the prior model's less the correction, before the offset.
            assert _same(out[4], rate[start] - np.array(out[3]))
            parts.append(tuple(np.array([v]) for v in out[:4]))
        else:
            block = split.process(time_s[start:end], rate[start:end], temperature[start:end],
                                  None if acceleration is None else acceleration[start:end])
            parts.append((block.rate_rad_s, block.std_rad_s, block.still,
                          block.correction_rad_s))
        start = end
    for index, expected in enumerate((whole.rate_rad_s, whole.std_rad_s, whole.still,
                                      whole.correction_rad_s)):
        got = np.concatenate([np.reshape(part[index], (-1,) + expected.shape[1:])
                              for part in parts])
        assert _same(got, expected), index
    assert _same_state(whole_stream, split)


def test_the_fuzzed_records_renew_the_curve():
    """Make sure the property exercises renewals and swaps: one record that has them."""
    rng = np.random.default_rng(5)
    time_s = 0.1 * np.arange(3000)
    temperature = 10.0 + 0.01 * np.arange(3000)
    rate = 1e-4 * (temperature[:, None] - 25.0) + 2e-4 * rng.standard_normal((3000, 1))
    rate[(time_s % 20.0) < 5.0] += 0.5
    tracking = TrackingSettings(StandstillSettings(
        rate_noise_rad_s=(2e-4,), random_walk_rad_s_rt_s=(1e-4,), window_s=1.0,
        max_temperature_rate_c_s=1.0), initial_std_rad_s=(3e-3,))
    learning = learning_settings({'learning.temperature_min_c': 0.0,
                                  'learning.temperature_max_c': 50.0,
                                  'learning.knot_step_c': 10.0, 'learning.significance': 0.0,
                                  'learning.min_runs': 2, 'learning.min_windows': 2}, tracking)
    stream = _start(tracking, learning, ('z',))
    stream.process(time_s, rate, temperature)
    assert stream.learner.renewals[0] >= 1 and stream.learner.swaps >= 1
