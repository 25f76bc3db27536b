"""
Property-based test of the bias tracker's stream: any split into blocks gives the same bits.

The node hands `BiasTracking` blocks of 1 to ``max_block`` samples (`process_one` for a
block of one), ``mlx-tempcomp evaluate --track-bias`` the whole record in one block. Random
records (rests and turns so the detector goes through its states, an offset that steps,
gaps, the clock going back, NaN and infinite values in any column, an accelerometer or
none, or one on some blocks only) and random splits must give the same rates, standard
deviations and still flags as one block and as rows one by one, and the same state.
"""

import math

from hypothesis import given, settings, strategies as st
from mlx_tempcomp.core.bias_tracker import BiasTracking, TrackingSettings
from mlx_tempcomp.core.standstill import StandstillSettings
import numpy as np

FUZZ = settings(max_examples=150)
SPECIAL = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e300])


@st.composite
def streams(draw):
    """Give (settings, axes, time, rate, temperature, acceleration) of a random record."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    axes = draw(st.sampled_from([('z',), ('x', 'z'), ('x', 'y', 'z')]))
    rows = draw(st.integers(1, 600))
    interval = draw(st.sampled_from([0.01, 0.05, 0.1]))
    time_s = 1000.0 + interval * np.arange(rows) + rng.uniform(0.0, 0.3 * interval, rows)
    for _ in range(draw(st.integers(0, 2))):        # gaps and the clock going back
        at = draw(st.integers(0, rows - 1))
        time_s[at:] += draw(st.sampled_from([3.0, 17.5, -40.0, -0.5 * interval]))
    moving = np.repeat(rng.random(rows // 40 + 1) < 0.4, 40)[:rows]
    rate = 1e-3 * rng.standard_normal((rows, len(axes))) + 2e-4
    rate[moving] += rng.choice([3e-3, 0.3, -1.0]) * rng.random(len(axes))
    rate[rows // 2:] += draw(st.sampled_from([0.0, 5e-4, -1.5e-3]))
    temperature = 25.0 + 0.01 * rng.standard_normal(rows)
    acceleration = np.array([0.0, 0.0, -9.81]) + 0.01 * rng.standard_normal((rows, 3))
    acceleration[moving] += rng.random(3)
    for column in draw(st.lists(st.sampled_from(['rate', 'temperature', 'acceleration']),
                                max_size=3)):
        at = draw(st.integers(0, rows - 1))
        target = {'rate': rate, 'temperature': temperature,
                  'acceleration': acceleration}[column]
        target.reshape(rows, -1)[at, 0] = draw(SPECIAL)
    standstill = StandstillSettings(
        rate_noise_rad_s=(1e-3,) * len(axes), random_walk_rad_s_rt_s=(1e-5,),
        window_s=draw(st.sampled_from([0.25, 1.0, 2.5])),
        max_acceleration_spread_m_s2=0.05,
        enter_windows=draw(st.integers(1, 3)), leave_windows=draw(st.integers(1, 2)))
    tracking = TrackingSettings(standstill, initial_std_rad_s=(2e-3,))
    return tracking, axes, time_s, rate, temperature, acceleration


def _chunks(draw, rows: int) -> list:
    sizes = draw(st.lists(st.integers(1, 50), min_size=1, max_size=rows))
    bounds, start = [], 0
    for size in sizes:
        if start >= rows:
            break
        bounds.append((start, min(start + size, rows)))
        start += size
    if start < rows:
        bounds.append((start, rows))
    return bounds


def _same(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


@FUZZ
@given(streams(), st.booleans(), st.data())
def test_any_split_gives_the_bits_of_one_block(stream, with_acceleration, data):
    tracking, axes, time_s, rate, temperature, acceleration = stream
    acceleration = acceleration if with_acceleration else None
    whole_tracker = BiasTracking(tracking, axes)
    whole = whole_tracker.process(time_s, rate, temperature, acceleration)
    chunked_tracker = BiasTracking(tracking, axes)
    parts = []
    for start, end in _chunks(data.draw, len(time_s)):
        part = slice(start, end)
        if end - start == 1:
            out = chunked_tracker.process_one(
                float(time_s[start]), rate[start].tolist(), float(temperature[start]),
                None if acceleration is None else acceleration[start].tolist())
            parts.append(([out[0]], [out[1]], [out[2]]))
        else:
            out = chunked_tracker.process(time_s[part], rate[part], temperature[part],
                                          None if acceleration is None else acceleration[part])
            parts.append((out.rate_rad_s, out.std_rad_s, out.still))
    for index, column in enumerate((whole.rate_rad_s, whole.std_rad_s, whole.still)):
        assert _same(np.concatenate([np.asarray(p[index]) for p in parts]), column)
    assert chunked_tracker.state() == whole_tracker.state()
    assert chunked_tracker.status() == whole_tracker.status()


@FUZZ
@given(streams(), st.data())
def test_an_accelerometer_on_some_blocks_gives_the_bits_of_its_rows(stream, data):
    """The node's Imu may lack acceleration on some messages: blocks and rows agree."""
    tracking, axes, time_s, rate, temperature, acceleration = stream
    block_tracker, row_tracker = BiasTracking(tracking, axes), BiasTracking(tracking, axes)
    for start, end in _chunks(data.draw, len(time_s)):
        given_acceleration = data.draw(st.booleans())
        part = slice(start, end)
        out = block_tracker.process(time_s[part], rate[part], temperature[part],
                                    acceleration[part] if given_acceleration else None)
        rows = [row_tracker.process_one(float(t), r, float(c),
                                        a if given_acceleration else None)
                for t, r, c, a in zip(time_s[part], rate[part].tolist(),
                                      temperature[part], acceleration[part].tolist())]
        assert _same(out.rate_rad_s, [r[0] for r in rows])
        assert _same(out.std_rad_s, [r[1] for r in rows])
        assert _same(out.still, [r[2] for r in rows])
    assert block_tracker.state() == row_tracker.state()
