"""
Property-based test of the bias tracker's stream: any split into blocks gives the same bits.

The node hands `BiasTracking` blocks of 1 to ``max_block`` samples (`process_one` for a
block of one), ``mlx-tempcomp evaluate --track-bias`` the whole record in one block. Random
records (rests and turns so the detector goes through its states, an offset that steps,
gaps, the clock going back, NaN and infinite values in any column, an accelerometer or
none, or one on some blocks only; rest hints as each sample's own, the offline twin's
column, and as messages between blocks, the node's) and random splits must give the same
rates, standard deviations and still flags as one block and as rows one by one, and the
same state.
"""

from dataclasses import replace
import math

from fuzz import examples
from hypothesis import given, settings, strategies as st
from mlx_tempcomp.core.standstill.bias_tracker import BiasTracking, TrackingSettings
from mlx_tempcomp.core.standstill.detector import StandstillSettings
import numpy as np

FUZZ = settings(max_examples=examples(150))
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
    run = draw(st.sampled_from([40, 150]))
    moving = np.repeat(rng.random(rows // run + 1) < 0.4, run)[:rows]
    # An offset within the mean-rate bound, or beyond it (only a hint lets that be learnt).
    offset = draw(st.sampled_from([2e-4, 5e-3, 5e-3]))
    rate = 1e-3 * rng.standard_normal((rows, len(axes))) + offset
    rate[moving] += rng.choice([3e-3, 0.3, -1.0]) * rng.random(len(axes))
    rate[rows // 2:] += draw(st.sampled_from([0.0, 5e-4, -1.5e-3]))
    temperature = 25.0 + 0.01 * rng.standard_normal(rows)
    # The robot's word: the truth, wrong in some runs.
    hint = ~moving ^ np.repeat(rng.random(rows // 60 + 1) < 0.15, 60)[:rows]
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
    tracking = TrackingSettings(standstill, initial_std_rad_s=(2e-3,),
                                rest_hint_max_age_s=draw(st.sampled_from([0.05, 0.3, 2.0])),
                                zero_at_start=draw(st.sampled_from([False, False, True])))
    return tracking, axes, time_s, rate, temperature, acceleration, hint


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
@given(streams(), st.booleans(), st.booleans(), st.data())
def test_any_split_gives_the_bits_of_one_block(stream, with_acceleration, with_hint, data):
    tracking, axes, time_s, rate, temperature, acceleration, hint = stream
    acceleration = acceleration if with_acceleration else None
    hint = hint if with_hint else None
    whole_tracker = BiasTracking(tracking, axes)
    whole = whole_tracker.process(time_s, rate, temperature, acceleration, hint)
    chunked_tracker = BiasTracking(tracking, axes)
    parts = []
    for start, end in _chunks(data.draw, len(time_s)):
        part = slice(start, end)
        if end - start == 1:
            out = chunked_tracker.process_one(
                float(time_s[start]), rate[start].tolist(), float(temperature[start]),
                None if acceleration is None else acceleration[start].tolist(),
                None if hint is None else bool(hint[start]))
            parts.append(([out[0]], [out[1]], [out[2]]))
        else:
            out = chunked_tracker.process(time_s[part], rate[part], temperature[part],
                                          None if acceleration is None else acceleration[part],
                                          None if hint is None else hint[part])
            parts.append((out.rate_rad_s, out.std_rad_s, out.still))
    for index, column in enumerate((whole.rate_rad_s, whole.std_rad_s, whole.still)):
        assert _same(np.concatenate([np.asarray(p[index]) for p in parts]), column)
    assert chunked_tracker.state() == whole_tracker.state()
    assert chunked_tracker.status() == whole_tracker.status()


@FUZZ
@given(streams(), st.data())
def test_an_accelerometer_on_some_blocks_gives_the_bits_of_its_rows(stream, data):
    """The node's Imu may lack acceleration on some messages: blocks and rows agree."""
    tracking, axes, time_s, rate, temperature, acceleration, _ = stream
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


@FUZZ
@given(streams(), st.booleans(), st.booleans(), st.data())
def test_hints_in_blocks_give_the_bits_of_rows(stream, with_acceleration, with_column, data):
    """
    Hints as each sample's own (the twin's column) and as messages between blocks, at any time.

    Blocks and rows one by one, given the same column and the same messages (late,
    early, stale, repeated) between the same samples, agree; hints that say "moving"
    change no bit of a tracker that has none.
    """
    tracking, axes, time_s, rate, temperature, acceleration, hint = stream
    tracking = replace(tracking, zero_at_start=False)
    acceleration = acceleration if with_acceleration else None
    hint = hint if with_column else None
    block_tracker, row_tracker = BiasTracking(tracking, axes), BiasTracking(tracking, axes)
    plain, moving = BiasTracking(tracking, axes), BiasTracking(tracking, axes)
    for start, end in _chunks(data.draw, len(time_s)):
        for _ in range(data.draw(st.integers(0, 2))):
            at = float(time_s[start]) + data.draw(st.sampled_from([-3.0, -0.2, 0.0, 0.1, 5.0]))
            rest = data.draw(st.booleans())
            block_tracker.hint(at, rest)
            row_tracker.hint(at, rest)
            moving.hint(at, False)
        part = slice(start, end)
        given = None if acceleration is None else acceleration[part]
        hints = [None] * (end - start) if hint is None else hint[part].tolist()
        out = block_tracker.process(time_s[part], rate[part], temperature[part], given,
                                    None if hint is None else hint[part])
        rows = [row_tracker.process_one(float(t), r, float(c), a, h)
                for t, r, c, a, h in zip(time_s[part], rate[part].tolist(), temperature[part],
                                         [None] * (end - start) if given is None else
                                         given.tolist(), hints)]
        assert _same(out.rate_rad_s, [r[0] for r in rows])
        assert _same(out.std_rad_s, [r[1] for r in rows])
        assert _same(out.still, [r[2] for r in rows])
        unhinted = plain.process(time_s[part], rate[part], temperature[part], given)
        denied = moving.process(time_s[part], rate[part], temperature[part], given,
                                None if hint is None else np.zeros(end - start, dtype=bool))
        assert _same(unhinted.rate_rad_s, denied.rate_rad_s)
        assert _same(unhinted.still, denied.still)
    assert block_tracker.state() == row_tracker.state()
    assert block_tracker.status() == row_tracker.status()
