"""EffectModel: each effect's formula, batch against stream, parameters round trip, bad input."""

from dataclasses import fields, replace
import math
from pathlib import Path
import re

from mlx_tempcomp.core.effects import (AxisTerms, EFFECT_NAMES, EffectModel, EFFECTS,
                                       FirstOrderLag, LIVE_EFFECTS, PARAMETER_DESCRIPTIONS,
                                       play_state, PlayOperator, RECORD_EFFECTS, table,
                                       temperature_rate_c_s, TemperatureSlope)
from mlx_tempcomp.core.errors import ConfigError
from mlx_tempcomp.core.node_models.interface import ModelInputs
import numpy as np
import pytest


def _record(samples=2000, seed=3):
    rng = np.random.default_rng(seed)
    time_s = 500.0 + np.cumsum(rng.uniform(0.05, 0.15, samples))
    temperature_c = 25.0 + 20.0 * np.sin((time_s - 500.0) / 40.0) + rng.normal(0, 0.05, samples)
    return {
        'time_s': time_s,
        'temperature_c': temperature_c,
        'temperature_2_c': 30.0 + 5.0 * np.cos(time_s / 70.0),
        'acceleration_m_s2': rng.normal(0.0, 1.0, (samples, 3)),
        'supply_voltage_v': 5.0 + 0.2 * np.sin(time_s / 90.0),
        'rate_rad_s': rng.normal(0.0, 0.2, (samples, 3)),
    }


def _full_model():
    terms = (
        AxisTerms(bias=(0.01, 0.002, -0.001), thermal_lag_s=20.0, hysteresis_half_width_c=2.0,
                  hysteresis_rad_s=0.003, time_drift_rad_s_per_s=1e-6,
                  bias_steps=((600.0, 0.01),), secondary=(0.001, 0.0005),
                  acceleration_rad_s_per_m_s2=(1e-4, 0.0, 2e-4), scale=(0.01, 0.001),
                  nonlinearity=(0.01, 0.002), cross_axis=(0.0, 0.01, 0.02)),
        AxisTerms(bias=(0.02,), cross_axis=(0.01, 0.0, 0.0), temperature_rate_rad_s_per_c_s=0.01,
                  gradient_time_constants_s=(15.0, 120.0), gradient_rad_s_per_c=(2e-4, -1e-4),
                  supply_voltage=(0.003, -0.001)),
        AxisTerms(bias=(0.0, 0.001), thermal_lag_s=-10.0, hysteresis_half_width_c=1.0,
                  hysteresis_rad_s=-0.002, gradient_time_constants_s=(40.0,),
                  gradient_rad_s_per_c=(3e-4,)),
    )
    return EffectModel(terms=terms, reference_temperature_c=25.0, temperature_scale_c=20.0,
                       temperature_min_c=0.0, temperature_max_c=44.0,
                       temperature_rate_window_s=30.0, time_reference_s=500.0,
                       secondary_reference_c=30.0, secondary_scale_c=5.0,
                       supply_reference_v=5.1, zro_offset_rad_s=(0.001, 0.002, 0.003))


INPUTS = ('time_s', 'temperature_2_c', 'acceleration_m_s2', 'supply_voltage_v')


def _inputs(data: dict, rows=slice(None)) -> ModelInputs:
    return ModelInputs(**{name: data[name][rows] for name in INPUTS})


def _through_stream(model, data: dict, edges) -> tuple:
    """Run the record through a new stream in blocks cut at ``edges``."""
    stream = model.stream()
    rates, clamped = [], []
    for start, stop in zip(edges[:-1], edges[1:]):
        rows = slice(start, stop)
        result = stream.correct_block(data['rate_rad_s'][rows], data['temperature_c'][rows],
                                      _inputs(data, rows))
        rates.append(result.rate_rad_s)
        clamped.append(result.temperature_clamped)
    return np.concatenate(rates), np.concatenate(clamped)


def test_stream_gives_the_batch_result_in_any_blocks():
    data = _record()
    model = _full_model()
    batch = model.correct(data['rate_rad_s'], data['temperature_c'], _inputs(data))
    samples = len(data['time_s'])
    one_by_one, clamped = _through_stream(model, data, list(range(samples + 1)))
    rng = np.random.default_rng(4)
    edges = np.unique(np.concatenate([[0, samples], rng.integers(1, samples, 60)]))
    blocks, _ = _through_stream(model, data, edges)
    # Bit for bit, whatever the blocks: the node may take one message or many per call.
    np.testing.assert_array_equal(blocks, one_by_one)
    # The vectorised first-order lag sums in another order than the recursion: rounding.
    np.testing.assert_allclose(one_by_one, batch.rate_rad_s, rtol=0.0, atol=1e-13)
    np.testing.assert_array_equal(clamped, batch.temperature_clamped)
    clamped = clamped.any(axis=1).tolist()
    # The thermal lag pushes T_eff past the 44 C clamp on some samples: the flag is exercised.
    assert 0 < sum(clamped) < len(clamped)


def test_polynomial_only_model_is_the_polynomial():
    data = _record()
    model = EffectModel(terms=(AxisTerms(bias=(0.01, -0.02, 0.003)),),
                        reference_temperature_c=20.0, temperature_scale_c=10.0)
    corrected = model.correct(data['rate_rad_s'][:, :1], data['temperature_c']).rate_rad_s
    x = (data['temperature_c'] - 20.0) / 10.0
    expected = data['rate_rad_s'][:, 0] - (0.01 - 0.02 * x + 0.003 * x * x)
    np.testing.assert_allclose(corrected[:, 0], expected, atol=1e-15)


def test_temperature_rate_is_the_slope_over_the_window():
    time_s = np.arange(0.0, 100.0, 0.5)
    temperature_c = 10.0 + 0.1 * time_s
    rate = temperature_rate_c_s(time_s, temperature_c, 20.0)
    assert rate[0] == 0.0
    np.testing.assert_allclose(rate[1:], 0.1, rtol=1e-12)
    # Between samples the window start is interpolated: still the exact slope of a line.
    np.testing.assert_allclose(temperature_rate_c_s(time_s, temperature_c, 7.25)[1:], 0.1,
                               rtol=1e-12)


def test_thermal_lag_recovers_the_die_temperature_of_a_first_order_lag():
    # A sensor lagging the die by tau reads T_s with T_die = T_s + tau dT_s/dt.
    tau_s = 30.0
    time_s = np.arange(0.0, 2000.0, 0.5)
    die_c = 25.0 + 0.05 * time_s
    sensor_c = die_c - tau_s * 0.05 * (1.0 - np.exp(-time_s / tau_s))
    model = EffectModel(terms=(AxisTerms(bias=(0.0, 1.0), thermal_lag_s=tau_s),),
                        reference_temperature_c=0.0, temperature_scale_c=1.0,
                        temperature_rate_window_s=10.0)
    bias = -model.correct(np.zeros((time_s.size, 1)), sensor_c,
                          ModelInputs(time_s=time_s)).rate_rad_s[:, 0]
    settled = time_s > 300.0
    np.testing.assert_allclose(bias[settled], die_c[settled], atol=1e-3)


def test_first_order_lag_is_exact_for_held_input_and_matches_its_runner():
    tau_s = 7.0
    rng = np.random.default_rng(1)
    # Uneven steps, a gap of many time constants: stretches of the batch start anew.
    time_s = np.concatenate([np.cumsum(rng.uniform(0.1, 0.9, 3000)), [9000.0, 9000.5]])
    values = np.where(time_s < 500.0, 10.0, 30.0)
    lag = FirstOrderLag(tau_s)
    batch = lag.batch(time_s, values)
    # A step from 10 to 30 at the first sample past 500 s: 30 - 20 exp(-(t - t_step) / tau).
    step = np.flatnonzero(time_s >= 500.0)[0]
    after = time_s >= 500.0
    expected = 30.0 - 20.0 * np.exp(-(time_s[after] - time_s[step - 1]) / tau_s)
    np.testing.assert_allclose(batch[after], expected, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(batch[~after], 10.0, rtol=1e-14)
    runner = lag.runner()
    np.testing.assert_allclose([runner.step(t, v) for t, v in zip(time_s, values)], batch,
                               rtol=0.0, atol=1e-12)
    with pytest.raises(ConfigError, match='positive time constant'):
        FirstOrderLag(0.0)


def test_operator_runners_give_their_batch_results():
    data = _record()
    time_s, temperature_c = data['time_s'], data['temperature_c']
    slope, play = TemperatureSlope(20.0), PlayOperator(1.5)
    slope_runner, play_runner = slope.runner(), play.runner()
    assert [slope_runner.step(t, v) for t, v in zip(time_s, temperature_c)] == \
        slope.batch(time_s, temperature_c).tolist()
    assert [play_runner.step(v) for v in temperature_c] == play.batch(temperature_c).tolist()


def test_thermal_gradient_follows_the_lagging_node():
    # bias = g (T - L_tau(T)): on a steady ramp r it settles at g tau r.
    tau_s, ramp_c_s, gain = 50.0, 0.05, 1e-3
    time_s = np.arange(0.0, 1000.0, 0.5)
    model = EffectModel(terms=(AxisTerms(bias=(0.0,), gradient_time_constants_s=(tau_s,),
                                         gradient_rad_s_per_c=(gain,)),))
    bias = -model.correct(np.zeros((time_s.size, 1)), 20.0 + ramp_c_s * time_s,
                          ModelInputs(time_s=time_s)).rate_rad_s[:, 0]
    assert bias[0] == 0.0
    # Less half a sample: the input is held at each sample's value since the one before.
    np.testing.assert_allclose(bias[time_s > 500.0], gain * (tau_s - 0.25) * ramp_c_s, rtol=1e-4)


def test_play_state_follows_heating_and_cooling():
    temperature_c = np.concatenate([np.linspace(20, 40, 201), np.linspace(40, 20, 201)])
    state = play_state(temperature_c, 2.0)
    assert state[0] == 0.0
    assert np.all(np.abs(state) <= 1.0 + 1e-12)
    assert state[200] == pytest.approx(1.0)
    assert state[-1] == pytest.approx(-1.0)
    # After turning at 40 C the state falls linearly, -1 once it has cooled by 2 x 2 C.
    assert state[201 + 10] == pytest.approx(0.5)
    assert state[201 + 40] == pytest.approx(-1.0)


def test_parameters_round_trip_and_fingerprint_ignores_the_offset():
    model = _full_model()
    parameters = model.to_parameters(('x', 'y', 'z'))
    assert all(isinstance(v, (float, list)) for v in parameters.values())
    rebuilt = EffectModel.from_parameters(parameters, ('x', 'y', 'z'))
    assert rebuilt.with_zro_offset(model.zro_offset_rad_s) == model
    assert rebuilt.fingerprint() == model.fingerprint()
    assert model.with_terms(1, bias=(0.03,)).fingerprint() != model.fingerprint()


@pytest.mark.parametrize('change, message', [
    ({'bias': ()}, 'bias needs at least one coefficient'),
    ({'hysteresis_rad_s': 0.1}, 'needs a positive hysteresis_half_width_c'),
    ({'acceleration_rad_s_per_m_s2': (1.0, 2.0)}, 'needs 3 values'),
    ({'thermal_lag_s': math.nan}, 'thermal_lag_s must be finite'),
    ({'gradient_time_constants_s': (10.0,)}, 'the same number of values'),
    ({'gradient_time_constants_s': (1.0, 2.0, 3.0), 'gradient_rad_s_per_c': (1.0, 1.0, 1.0)},
     'at most 2'),
    ({'gradient_time_constants_s': (-1.0,), 'gradient_rad_s_per_c': (1.0,)}, 'must be positive'),
])
def test_invalid_terms_are_refused_with_the_field_named(change, message):
    with pytest.raises(ConfigError, match=message):
        AxisTerms(**{'bias': (0.0,), **change})


def test_missing_inputs_and_parameters_are_named():
    data = _record(50)
    model = _full_model()
    with pytest.raises(ConfigError, match='needs time_s'):
        model.correct(data['rate_rad_s'], data['temperature_c'])
    with pytest.raises(ConfigError, match='needs temperature_2_c'):
        model.stream().correct_block([[0.0] * 3], [25.0], ModelInputs(
            time_s=[1.0], acceleration_m_s2=[[0.0] * 3], supply_voltage_v=[5.0]))
    with pytest.raises(ConfigError, match='needs supply_voltage_v'):
        model.stream().correct_block([[0.0] * 3], [25.0], ModelInputs(
            time_s=[1.0], temperature_2_c=[30.0], acceleration_m_s2=[[0.0] * 3]))
    parameters = model.to_parameters(('x', 'y', 'z'))
    del parameters['bias.y']
    with pytest.raises(ConfigError, match='bias.y is missing'):
        EffectModel.from_parameters(parameters, ('x', 'y', 'z'))
    with pytest.raises(ConfigError, match='cross_axis of axis 0 needs 2 values'):
        EffectModel(terms=(AxisTerms(bias=(0.0,), cross_axis=(0.0, 0.1, 0.2)),
                           AxisTerms(bias=(0.0,))))


def test_the_effect_table_owns_every_coefficient_once_and_describes_every_parameter():
    owners = [name for effect in EFFECTS for name in effect.fields + effect.model_fields]
    assert len(owners) == len(set(owners))
    model_fields = {f.name for f in fields(EffectModel)} - {'terms', 'zro_offset_rad_s', 'name'}
    assert set(owners) == {f.name for f in fields(AxisTerms)} | model_fields
    parameters = {key.partition('.')[0] for key in _full_model().to_parameters(('x', 'y', 'z'))}
    assert set(PARAMETER_DESCRIPTIONS) == parameters
    assert set(EFFECT_NAMES) == set(LIVE_EFFECTS) | RECORD_EFFECTS


def test_each_effect_is_present_and_needs_its_inputs_when_its_coefficients_are_set():
    terms = _full_model().terms
    assert set(terms[0].effects) | set(terms[1].effects) | set(terms[2].effects) == \
        set(EFFECT_NAMES)
    assert terms[1].effects == ('temperature_polynomial', 'temperature_rate', 'thermal_gradient',
                                'thermal_gradient_2', 'supply_voltage', 'cross_axis')
    for effect in EFFECTS:
        holding = next(t for t in terms if effect.present(t))
        model = EffectModel(terms=(replace(holding, cross_axis=()),))
        assert effect.inputs <= model.inputs
    assert EffectModel(terms=(AxisTerms(bias=(1.0,), hysteresis_half_width_c=1.0,
                                        hysteresis_rad_s=0.1),)).inputs == frozenset()
    assert _full_model().live().record_effects == ()
    assert set(_full_model().record_effects) == RECORD_EFFECTS


def test_every_effect_and_parameter_is_documented():
    """The table's docstring and docs/diagnose.md give each effect, docs/ros.md each parameter."""
    docs = Path(__file__).resolve().parents[2] / 'docs'
    effects = (docs / 'diagnose.md').read_text().partition('\n## Effects\n')[2].partition(
        '\n## ')[0]
    for name in EFFECT_NAMES:
        assert f'``{name}``' in table.__doc__, name
        assert f'`{name}`' in effects, name
    parameters = (docs / 'ros.md').read_text().partition('\n### `effects` and `chain`\n')[2]
    for name in PARAMETER_DESCRIPTIONS:
        assert re.search(rf'`effects\.{name}(\.<a>)?`', parameters), name
