"""
Property-based test of the effect model's per-row path: one row at a time gives the block's bits.

`EffectStream.correct_one` runs a row in plain floats, `correct_block` in numpy,
through the same formulas. Random models (every effect, coefficients from zero
and signed zero to overflowing, a scale factor that divides by zero) and random
rows (NaN, infinities, signed zeros, temperatures on and beyond the clamp,
times in any order) must give the same bits row by row as one block, signed
zeros included. A NaN is only compared as NaN: numpy itself gives NaNs of
either sign for the same row depending on the block's length.
"""

import itertools
import math

from fuzz import examples
from hypothesis import given, settings, strategies as st
from mlx_tempcomp.core.effects import AxisTerms, EFFECT_NAMES, EffectModel
from mlx_tempcomp.core.errors import ConfigError
from mlx_tempcomp.core.node_models.interface import ModelInputs
import numpy as np
import pytest

# A few seconds (the profile in conftest.py sets the rest).
FUZZ = settings(max_examples=examples(300))

SPECIAL = st.sampled_from([0.0, -0.0, math.nan, math.inf, -math.inf])
# Coefficients: mostly of a real model's size, sometimes any finite float (overflow).
COEFFICIENT = st.one_of(st.floats(-1.0, 1.0), st.sampled_from([0.0, -0.0, 1.0, -1.0]),
                        st.floats(allow_nan=False, allow_infinity=False))
POSITIVE = st.floats(1e-3, 1e3)
TEMPERATURE = st.one_of(st.floats(-60.0, 130.0), SPECIAL,
                        st.sampled_from([-20.0, 60.0, 25.0]), st.floats())
VALUE = st.one_of(st.floats(-10.0, 10.0), SPECIAL, st.floats())


# Signed zeros and ones only: sums of zeros keep or lose their sign on every operation.
SIGNS = st.sampled_from([0.0, -0.0, 1.0, -1.0])
TEMPERATURE_SIGNS = st.sampled_from([0.0, -0.0, 10.0, -10.0, math.nan])


def _coefficients(low: int, high: int, coefficient=COEFFICIENT):
    return st.lists(coefficient, min_size=low, max_size=high).map(tuple)


@st.composite
def axis_terms(draw, axis: int, axes: int, coefficient) -> AxisTerms:
    """Give one axis's terms: a few effects (often none or one), so signed zeros survive."""
    terms = {'bias': draw(_coefficients(1, 5, coefficient))}
    # An effect with shapes, signs or lengths to vary is drawn here; any other in its form of
    # one coefficient (ONE_EFFECT), the coefficient drawn.
    for name in draw(st.sets(st.sampled_from(sorted(EFFECT_NAMES)))):
        if name == 'thermal_lag':
            terms['thermal_lag_s'] = draw(st.one_of(POSITIVE, POSITIVE.map(lambda v: -v)))
        elif name.startswith('thermal_gradient'):
            count = 2 if name.endswith('_2') else 1
            terms['gradient_time_constants_s'] = tuple(
                draw(st.lists(POSITIVE, min_size=count, max_size=count)))
            terms['gradient_rad_s_per_c'] = draw(_coefficients(count, count, coefficient))
        elif name == 'hysteresis':
            terms['hysteresis_half_width_c'] = draw(POSITIVE)
            terms['hysteresis_rad_s'] = draw(coefficient)
        elif name == 'supply_voltage':
            terms['supply_voltage'] = draw(_coefficients(1, 3, coefficient))
        elif name == 'bias_step':
            terms['bias_steps'] = draw(st.lists(st.tuples(st.floats(-10.0, 100.0), coefficient),
                                                min_size=1, max_size=2).map(tuple))
        elif name == 'secondary_temperature':
            terms['secondary'] = draw(_coefficients(1, 3, coefficient))
        elif name == 'acceleration_sensitivity':
            terms['acceleration_rad_s_per_m_s2'] = draw(_coefficients(3, 3, coefficient))
        elif name == 'scale_factor_temperature':
            # (-1,): 1 + S(x) is 0, the quotient is inf or NaN.
            terms['scale'] = draw(st.one_of(_coefficients(1, 3, coefficient), st.just((-1.0,))))
        elif name == 'rate_nonlinearity':
            terms['nonlinearity'] = draw(_coefficients(1, 2, coefficient))
        elif name == 'cross_axis':
            if axes > 1:
                cross = list(draw(_coefficients(axes, axes, coefficient)))
                cross[axis] = 0.0
                terms['cross_axis'] = tuple(cross)
        elif name != 'temperature_polynomial':
            terms.update(ONE_EFFECT[name](draw(coefficient))[axis % 2])
    return AxisTerms(**terms)


@st.composite
def models(draw, coefficient=COEFFICIENT) -> EffectModel:
    axes = draw(st.integers(1, 3))
    return EffectModel(
        terms=tuple(draw(axis_terms(axis, axes, coefficient)) for axis in range(axes)),
        reference_temperature_c=draw(st.one_of(st.floats(-40.0, 80.0), st.just(-0.0))),
        temperature_scale_c=draw(POSITIVE),
        temperature_min_c=draw(st.one_of(st.floats(-50.0, 20.0),
                                         st.sampled_from([-math.inf, 0.0, -0.0]))),
        temperature_max_c=draw(st.one_of(st.floats(25.0, 90.0), st.just(math.inf))),
        temperature_rate_window_s=draw(POSITIVE), time_reference_s=draw(st.floats(-10.0, 10.0)),
        secondary_reference_c=draw(st.floats(-40.0, 80.0)), secondary_scale_c=draw(POSITIVE),
        supply_reference_v=draw(st.floats(0.0, 10.0)),
        zro_offset_rad_s=draw(_coefficients(axes, axes, coefficient)))


def _rows(draw, count: int, width: int, values) -> list:
    return draw(st.lists(st.lists(values, min_size=width, max_size=width),
                         min_size=count, max_size=count))


@FUZZ
@given(signs=st.booleans(), data=st.data())
def test_rows_one_at_a_time_give_the_bits_of_one_block(signs, data):
    model = data.draw(models(SIGNS if signs else COEFFICIENT))
    value, temperature = (SIGNS, TEMPERATURE_SIGNS) if signs else (VALUE, TEMPERATURE)
    count = data.draw(st.integers(1, 20))
    rates = _rows(data.draw, count, model.axes, value)
    temperatures = _rows(data.draw, count, data.draw(st.sampled_from([1, model.axes])),
                         temperature)
    time_s = data.draw(st.lists(st.floats(0.0, 200.0), min_size=count, max_size=count))
    if data.draw(st.booleans()):
        time_s.sort()   # as a stream's stamps; unsorted too, the runners take any
    columns = {'time_s': time_s,
               'temperature_2_c': [row[0] for row in _rows(data.draw, count, 1, temperature)],
               'acceleration_m_s2': _rows(data.draw, count, 3, value),
               'supply_voltage_v': [row[0] for row in _rows(data.draw, count, 1, value)]}
    with np.errstate(all='ignore'):
        stream = model.stream()
        rows = [stream.correct_one(rates[i], temperatures[i], ModelInputs(
            **{name: column[i] for name, column in columns.items()})) for i in range(count)]
        block = model.stream().correct_block(rates, temperatures, ModelInputs(
            **{name: np.array(column) for name, column in columns.items()}))
    _assert_same_bits(rows, block)


def _assert_same_bits(rows: list, block) -> None:
    """Rows of `correct_one` against a block: every bit but a NaN's sign, and the flags."""
    got = np.array([rate for rate, _ in rows], dtype=np.float64)
    assert all(type(value) is float for rate, _ in rows for value in rate)
    nan = np.isnan(block.rate_rad_s)
    np.testing.assert_array_equal(np.isnan(got), nan)
    np.testing.assert_array_equal(got.view(np.uint64)[~nan],
                                  block.rate_rad_s.view(np.uint64)[~nan])
    assert [clamped for _, clamped in rows] == block.temperature_clamped.any(axis=1).tolist()


# Each effect alone with its coefficients set to one value: terms of axis 0 and axis 1.
ONE_EFFECT = {
    'thermal_lag': lambda c: ({'thermal_lag_s': 5.0}, {'thermal_lag_s': -5.0}),
    'temperature_rate': lambda c: ({'temperature_rate_rad_s_per_c_s': c},) * 2,
    'thermal_gradient': lambda c: ({'gradient_time_constants_s': (5.0,),
                                    'gradient_rad_s_per_c': (c,)},) * 2,
    'thermal_gradient_2': lambda c: ({'gradient_time_constants_s': (5.0, 50.0),
                                      'gradient_rad_s_per_c': (c, c)},) * 2,
    'hysteresis': lambda c: ({'hysteresis_half_width_c': 0.5, 'hysteresis_rad_s': c},) * 2,
    'supply_voltage': lambda c: ({'supply_voltage': (c, c)},) * 2,
    'secondary_temperature': lambda c: ({'secondary': (c, c)},) * 2,
    'acceleration_sensitivity': lambda c: ({'acceleration_rad_s_per_m_s2': (c, c, c)},) * 2,
    'scale_factor_temperature': lambda c: ({'scale': (c,)}, {'scale': (c, c)}),
    'rate_nonlinearity': lambda c: ({'nonlinearity': (c,)},) * 2,
    'cross_axis': lambda c: ({'cross_axis': (0.0, c)}, {'cross_axis': (c, 0.0)}),
    'time_drift': lambda c: ({'time_drift_rad_s_per_s': c},) * 2,
    'bias_step': lambda c: ({'bias_steps': ((1.0, c),)},) * 2,
}


@pytest.mark.parametrize('effect', sorted(ONE_EFFECT))
def test_signed_zeros_keep_their_sign_through_each_effect_row_by_row(effect):
    """Every sign of zero a row can meet in one effect, exhaustively: -0.0 + 0.0 is 0.0."""
    assert set(ONE_EFFECT) == set(EFFECT_NAMES) - {'temperature_polynomial'}
    # Rows: rate and acceleration of either sign of zero, x = -0.25, +-0 and 0.25 (the
    # reference), the second temperature and supply at their references, time across the step.
    grid = list(itertools.product((0.0, 2.0), (0.0, -0.0), (20.0, 25.0, 30.0), (0.0, -0.0)))
    rates = [[rate, -rate] for _, rate, _, _ in grid]
    temperatures = [[temperature] for _, _, temperature, _ in grid]
    columns = {'time_s': [start + 0.01 * row for row, (start, _, _, _) in enumerate(grid)],
               'temperature_2_c': [25.0] * len(grid),
               'acceleration_m_s2': [[zero, -zero, zero] for _, _, _, zero in grid],
               'supply_voltage_v': [5.0] * len(grid)}
    signs = itertools.product((0.0, -0.0, 1.0, -1.0), (0.0, -0.0), (0.0, -0.0))
    for coefficient, bias, offset in signs:
        model = EffectModel(
            terms=tuple(AxisTerms(bias=(bias,) * order, **terms)
                        for order, terms in zip((1, 2), ONE_EFFECT[effect](coefficient))),
            reference_temperature_c=25.0, temperature_scale_c=20.0, secondary_reference_c=25.0,
            supply_reference_v=5.0, zro_offset_rad_s=(offset, -offset))
        with np.errstate(all='ignore'):
            stream = model.stream()
            rows = [stream.correct_one(rates[i], temperatures[i], ModelInputs(
                **{name: column[i] for name, column in columns.items()}))
                for i in range(len(grid))]
            block = model.stream().correct_block(rates, temperatures, ModelInputs(
                **{name: np.array(column) for name, column in columns.items()}))
        _assert_same_bits(rows, block)


def test_rows_of_numpy_values_or_integers_give_the_float_rows():
    model = EffectModel(terms=(AxisTerms(bias=(0.01, 0.002), acceleration_rad_s_per_m_s2=(
        1e-4, 0.0, 2e-4), thermal_lag_s=-10.0),) * 2)
    inputs = ModelInputs(time_s=3.0, acceleration_m_s2=[0.0, 1.0, 9.0])
    expected = model.stream().correct_one([0.5, 1.0], [30.0], inputs)
    given = [([np.float32(0.5), 1], np.array([30.0]),
              ModelInputs(time_s=np.float64(3.0), acceleration_m_s2=np.array([0, 1, 9]))),
             (np.array([0.5, 1.0]), (30,), ModelInputs(time_s=3, acceleration_m_s2=(0, 1.0, 9)))]
    for rates, temperatures, row_inputs in given:
        rate, clamped = model.stream().correct_one(rates, temperatures, row_inputs)
        assert (rate, clamped) == expected
        assert all(type(value) is float for value in rate)


@pytest.mark.parametrize('rates, temperatures, inputs, message', [
    ([0.1], [25.0], ModelInputs(time_s=0.0), r'rate must have shape \(samples, 2\)'),
    ([0.1, 0.2], [25.0, 25.0, 25.0], ModelInputs(time_s=0.0), 'temperature shape'),
    ([0.1, 0.2], [25.0], ModelInputs(), 'needs time_s'),
    ([0.1, 0.2], [25.0], ModelInputs(time_s=[0.0, 1.0]), r'time_s must have shape \(1,\)'),
    ([0.1, 0.2], [25.0], ModelInputs(time_s=0.0, acceleration_m_s2=[0.0, 9.8]),
     r'acceleration_m_s2 must have shape \(1, 3\)'),
])
def test_a_row_of_the_wrong_shape_is_named_and_leaves_the_stream_as_it_was(
        rates, temperatures, inputs, message):
    model = EffectModel(terms=(AxisTerms(bias=(0.01,), thermal_lag_s=5.0),) * 2)
    stream, fresh = model.stream(), model.stream()
    with pytest.raises(ConfigError, match=message):
        stream.correct_one(rates, temperatures, inputs)
    row = ([0.1, 0.2], [25.0], ModelInputs(time_s=1.0))
    assert stream.correct_one(*row) == fresh.correct_one(*row)
