"""
Property-based tests of the parameter loaders: a parameter file gives a model or a user error.

The files are what the toolkit writes (`parameters.files`: ``fit``, the ADIS16130 bias
procedure) and reads back the way ``mlx-tempcomp evaluate``, the MPU offset refresh and
the compensation node do: `node_values` (the node's defaults overridden by the file's
section, types and ranges checked as rcl would), then `build_model`. Valid models
round-trip to the same fingerprint; random bytes, random YAML and valid files with a
value replaced give a `ParameterError` (the one ``error:`` line of the CLI, the
node's fatal line), or a model whose output is finite for every input a gyro
can give: rate within +-2000 deg/s, temperature from -40 to 125 C.
"""

import math
import os
import tempfile

from fuzz import examples
from hypothesis import (currently_in_test_context, event, example, given, settings,
                        strategies as st)
from mlx_tempcomp.core.effects import LinearBtc, polynomial_model
from mlx_tempcomp.core.node_models.interface import ModelInputs
from mlx_tempcomp.parameters.files import (linear_btc_parameters, node_values, parameter_file,
                                           polynomial_parameters, write_parameter_file)
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.specs import ParameterError
import numpy as np
import pytest
import yaml

NODE = 'compensation_node'
# A few seconds per test (the profile in conftest.py sets the rest).
FUZZ = settings(max_examples=examples(300))
FULL_SCALE_RAD_S = math.radians(2000.0)
RATES = np.linspace(-FULL_SCALE_RAD_S, FULL_SCALE_RAD_S, 5)
TEMPERATURES_C = np.linspace(-40.0, 125.0, 34)

finite = st.floats(-1e3, 1e3, allow_nan=False)
axes_sets = st.sampled_from([('z',), ('x',), ('x', 'y'), ('x', 'y', 'z'), ('z', 'x')])


@st.composite
def polynomial_models(draw):
    axes = draw(axes_sets)
    low = draw(st.floats(-60.0, 20.0))
    high = low + draw(st.floats(1.0, 120.0))
    reference = draw(st.floats(-20.0, 60.0))
    # As fit writes them: x = (T - Tref) / scale within +-1 over the clamped range.
    model = polynomial_model(
        tuple(draw(st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=9)) for _ in axes),
        reference_temperature_c=reference,
        temperature_scale_c=max(abs(low - reference), abs(high - reference)) *
        draw(st.floats(1.0, 2.0)),
        temperature_min_c=low, temperature_max_c=high)
    return model, axes


@st.composite
def linear_btc_models(draw):
    axes = draw(axes_sets)
    model = LinearBtc(
        pbc_rad_s=tuple(draw(st.floats(-1.0, 1.0)) for _ in axes),
        btc_rad_s_per_c=tuple(draw(st.floats(-0.01, 0.01)) for _ in axes),
        t3_c=draw(st.floats(-40.0, 125.0))).model()
    return model, axes


def parameters_of(model, axes) -> dict:
    if model.name == 'polynomial':
        return polynomial_parameters(model, axes)
    return linear_btc_parameters(model, axes)


def load_text(text: str):
    """Write ``text`` as a parameter file; give the model or the user error it makes."""
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, 'params.yaml')
        with open(path, 'w', encoding='utf-8') as stream:
            stream.write(text)
        return load_file(path)


def load_file(path: str):
    try:
        values = node_values(path, NODE)
        model = build_model(values)
    except ParameterError as err:
        message = str(err)
        assert message and '\n' not in message, message
        count(f'refused: {type(err).__name__}')
        return err
    count('no model yet (eeprom)' if model is None else f'built: {model.name}')
    if model is not None:
        assert_finite_output(model)
    return model


def assert_finite_output(model) -> None:
    """Run ``model`` over the rates and temperatures a gyro gives, every extra input given."""
    rates, temperatures = np.meshgrid(RATES, TEMPERATURES_C)
    samples = rates.size
    rate = np.repeat(rates.reshape(-1, 1), model.axes, axis=1)
    result = model.stream().correct_block(rate, temperatures.reshape(-1), ModelInputs(
        time_s=np.arange(samples) * 0.01, temperature_2_c=temperatures.reshape(-1),
        acceleration_m_s2=np.tile([0.0, 0.0, 9.81], (samples, 1)),
        supply_voltage_v=np.full(samples, 5.0)))
    assert np.all(np.isfinite(result.rate_rad_s)), model


def count(outcome: str) -> None:
    """Count ``outcome`` in the statistics of a property (--hypothesis-show-statistics)."""
    if currently_in_test_context():
        event(outcome)


def dump(parameters: dict) -> str:
    return yaml.safe_dump(parameter_file(NODE, parameters), sort_keys=False)


@FUZZ
@given(case=st.one_of(polynomial_models(), linear_btc_models()))
def test_written_models_load_back_the_same(case):
    model, axes = case
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, 'params.yaml')
        write_parameter_file(path, parameter_file(NODE, parameters_of(model, axes)), 'fitted')
        loaded = load_file(path)
    assert not isinstance(loaded, Exception), loaded
    assert loaded.name == model.name and loaded.fingerprint() == model.fingerprint()


@FUZZ
@given(data=st.binary(max_size=300))
@example(data=b'[' * 100000)
@example(data=b'compensation_node: {ros__parameters: {model: 2026-13-45}}')
@example(data=b'compensation_node: {ros__parameters: {axes: !!int abc}}')
def test_random_bytes(data):
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, 'params.yaml')
        with open(path, 'wb') as stream:
            stream.write(data)
        result = load_file(path)
    assert isinstance(result, Exception) or result.name == 'polynomial' or result is None


# Any float, plain ones, and those that break arithmetic: -1 (a scale factor of zero), huge.
numbers = st.one_of(st.floats(), st.floats(-1e3, 1e3),
                    st.sampled_from([-1.0, 1e300, -1e300, 1e308, -1e308, 5e-324]))
scalars = st.one_of(st.none(), st.booleans(), st.integers(), numbers, st.text(max_size=8))
values = st.one_of(
    scalars, st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300, 1e308, -1.0, 0.0,
                              2**63, 'x', 'y', 'z', 'polynomial', 'linear_btc', 'effects',
                              'chain', 'eeprom', '']),
    st.lists(numbers, max_size=10),
    st.lists(st.integers(-10, 10), max_size=4), st.lists(st.text(max_size=2), max_size=4),
    st.lists(st.sampled_from(['x', 'y', 'z']), max_size=4),
    st.dictionaries(st.sampled_from(['x', 'y', 'z', 'bias', 'q']),
                    st.lists(numbers, max_size=4), max_size=3))


def leaves(tree: dict, prefix=()) -> list:
    """Give the key paths of ``tree``'s values, the mappings included."""
    found = []
    for key, value in tree.items():
        found.append(prefix + (key,))
        if isinstance(value, dict):
            found += leaves(value, prefix + (key,))
    return found


# More examples here: an overflow takes a huge number in the right place (300 missed the one
# 3000 found: a bias of 1.8e308 rad/s).
@pytest.mark.slow
@settings(FUZZ, max_examples=examples(800))
@given(case=st.one_of(polynomial_models(), linear_btc_models()), data=st.data())
def test_written_files_with_values_replaced(case, data):
    tree = parameters_of(*case)
    for _ in range(data.draw(st.integers(1, 3), label='replacements')):
        keys = data.draw(st.sampled_from(leaves(tree) + [('new',), ('polynomial', 'scale')]),
                         label='key')
        node = tree
        for key in keys[:-1]:
            if not isinstance(node.get(key), dict):
                node[key] = {}
            node = node[key]
        old = node.get(keys[-1])
        if isinstance(old, list) and all(isinstance(v, float) for v in old) and \
                data.draw(st.booleans(), label='same type'):
            # Numbers where numbers belong: only their values can be wrong.
            node[keys[-1]] = data.draw(st.lists(
                numbers, min_size=max(len(old) - 1, 0), max_size=len(old) + 1), label='value')
        elif isinstance(old, float) and data.draw(st.booleans(), label='same type'):
            node[keys[-1]] = data.draw(numbers, label='value')
        else:
            node[keys[-1]] = data.draw(values, label='value')
    load_text(dump(tree))


@FUZZ
@given(document=st.recursive(scalars, lambda children: st.one_of(
    st.lists(children, max_size=3),
    st.dictionaries(st.sampled_from([NODE, '/**', 'ros__parameters', 'model', 'axes',
                                     'polynomial', 'bias', 'z', 'linear_btc']),
                    children, max_size=3)), max_leaves=10))
def test_random_yaml_documents(document):
    load_text(yaml.safe_dump(document))


@pytest.mark.parametrize('parameters, message', [
    ({'model': 'polynomial', 'polynomial': {'bias': {'z': [0.0]}, 'scale': {'z': [-1.0]}}},
     'invalid polynomial model parameters: axis z gives -inf rad/s at -40 C and a raw rate of '
     '-1 rad/s, beyond +-349.1 rad/s; check the coefficients and their units'),
    ({'model': 'polynomial', 'polynomial': {'bias': {'z': [0.0, 0.0, 0.0, 0.0, 1e300]}}},
     'invalid polynomial model parameters: axis z gives -1.785e+307 rad/s at -40 C'),
    ({'model': 'linear_btc', 'linear_btc': {'pbc_rad_s': [0.0], 'btc_rad_s_per_c': [1e308]}},
     'invalid linear_btc model parameters: axis z gives -inf rad/s at -40 C'),
    ({'model': 'linear_btc', 'linear_btc': {'pbc_rad_s': [500.0], 'btc_rad_s_per_c': [0.0]}},
     'invalid linear_btc model parameters: axis z gives 499 rad/s at -40 C'),
    ({'model': 'effects', 'effects': {'bias': {'z': [0.0, 0.0, 0.0, 1e300]}}},
     'invalid effects model parameters: axis z gives 2.746e+305 rad/s at -40 C'),
])
def test_coefficients_beyond_any_gyro_are_refused(parameters, message):
    result = load_text(dump({'axes': ['z'], **parameters}))
    assert isinstance(result, ParameterError), result
    assert str(result).startswith(message), str(result)
