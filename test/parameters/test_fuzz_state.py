"""
Property-based tests of the state-file loader: whatever is on disk, a checked state or a refusal.

Random bytes, random YAML documents and mutated valid files (truncated, bytes
flipped, a value replaced) go through `load_state` with the fields of the ZRO
state and of the MPU offsets, then, for the ZRO state, through the offset the
compensation node would apply. Each either loads, with every value of the
type, length and range its field says and a model whose output is finite, or
is refused: None, one ERROR naming the reason, the file moved aside. Never an
exception. The whole state file (``state``: the ZRO state and the bias
tracking's section) is fuzzed too: its section is checked apart
(`checked_section`), so a bad one is refused alone, and a file cut anywhere
either is refused or keeps the ZRO state whole. State files saved for a
polynomial and a linear_btc model before those became effect models keep
loading with their offset; so do ZRO state files written before the section.
"""

import logging
import math
import os
import tempfile

from fuzz import examples
from hypothesis import currently_in_test_context, event, example, given, settings, strategies as st
from mlx_tempcomp.core.effects import polynomial_model
from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.mlx90609.conversion import Output
from mlx_tempcomp.core.mlx90609.eeprom import EepromFields
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.core.mlx90609.table_compensation import table_compensation
from mlx_tempcomp.core.node_models.rate_models import EepromModel
from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.specs import axes_of
from mlx_tempcomp.parameters.state_file import load_state, StateFileError, write_state
from mlx_tempcomp.ros.compensation.bias_tracking import checked_section
from mlx_tempcomp.ros.compensation.zro_recalibration import (saved_offset_model, state_fields,
                                                             TRACKING_SECTION, zro_state_fields)
from mlx_tempcomp.ros.driver.mpu6000_stream import MPU_OFFSETS_FIELDS
import numpy as np
import pytest
import yaml

FULL_SCALE_RAD_S = math.radians(300.0)
ZRO_FIELDS = zro_state_fields(FULL_SCALE_RAD_S)
MODEL = polynomial_model(((0.02, 0.001), (0.0,), (-0.01, 0.0, 1e-5)), temperature_min_c=-40.0,
                         temperature_max_c=85.0)
ZRO_STATE = {'model': 'polynomial', 'fingerprint': MODEL.fingerprint(), 'axes': ['x', 'y', 'z'],
             'zro_offset': [0.0125, -0.5, 3.25e-4], 'offset_unit': 'rad/s',
             'zro_offset_rad_s': [0.0125, -0.5, 3.25e-4], 'temperature_c': 31.5, 'samples': 500,
             'time': '2026-11-25T12:00:00+00:00'}
MPU_STATE = {'variant': 'mpu6000', 'gyro_offset_lsb': [-269, -106, 265],
             'accel_bias_lsb': [-83, 13, 18], 'accel_registers': [1443, 2646, 2270],
             'residual_gyro_rad_s': [0.145, 0.0575, -0.143],
             'residual_acceleration_m_s2': [0.05, -0.008, -0.011], 'gravity_axis': '+z',
             'temperature_c': 25.0, 'samples': 201, 'time': '2026-11-25T12:00:00+00:00'}
SECTION = {'model': 'polynomial', 'fingerprint': MODEL.fingerprint(), 'axes': ['x', 'y', 'z'],
           'zro_offset': [0.0125, -0.5, 3.25e-4], 'offset_rad_s': [1.5e-4, -2.5e-4, 3.0e-5],
           'variance_rad2_s2': [1e-8, 2e-8, 3.5e-8], 'time_s': 1.0e9, 'updates': 12,
           'last_update_s': 1.0e9 - 5.0, 'saved': '2026-11-26T12:00:00+00:00'}
FULL_STATE = {**ZRO_STATE, TRACKING_SECTION: SECTION}
SCHEMAS = {'zro': (ZRO_FIELDS, ZRO_STATE), 'mpu': (MPU_OFFSETS_FIELDS, MPU_STATE),
           'state': (state_fields(FULL_SCALE_RAD_S), FULL_STATE)}
# A few seconds per test (the profile in conftest.py sets the rest).
FUZZ = settings(max_examples=examples(300))


class Log(logging.Handler):
    """Keep the records `load_state` logs."""

    def __init__(self):
        super().__init__()
        self.records = []

    def emit(self, record):
        self.records.append(record)


def load(data: bytes, schema: str):
    """Write ``data`` as a state file, load it; give (state, ERROR messages, folder names)."""
    fields, _ = SCHEMAS[schema]
    logger = logging.getLogger(f'fuzz.{schema}')
    log = Log()
    logger.addHandler(log)
    logger.propagate = False
    try:
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, 'state.yaml')
            with open(path, 'wb') as stream:
                stream.write(data)
            state = load_state(path, fields, logger, 'saved state')
            names = sorted(os.listdir(folder))
    finally:
        logger.removeHandler(log)
    errors = [r.getMessage() for r in log.records if r.levelno >= logging.ERROR]
    return state, errors, names


def assert_loaded_or_refused(data: bytes, schema: str):
    """Assert the property; give the state (None when refused)."""
    fields, _ = SCHEMAS[schema]
    state, errors, names = load(data, schema)
    count('refused' if state is None else 'loaded')
    if state is None:
        assert len(errors) == 1 and ' unusable: ' in errors[0], errors
        assert errors[0].endswith('; starting without it')
        assert len(names) == 1 and names[0].startswith('state.yaml.bad-'), names
        return None
    assert errors == [] and names == ['state.yaml']
    for field in fields:
        if field.key not in state:
            # A group the file does not hold, whole: the ZRO state or the section.
            assert field.group and not any(f.key in state for f in fields
                                           if f.group == field.group)
            continue
        if field.kind == 'section':
            assert_section_checked(state[field.key])
            continue
        value = state[field.key]
        items = value if field.length is not None else [value]
        if field.length is not None:
            assert isinstance(value, list)
        for item in items:
            if field.kind == 'text':
                assert isinstance(item, str)
                assert not field.choices or item in field.choices
            else:
                assert isinstance(item, int if field.kind == 'integer' else float)
                assert not isinstance(item, bool)
                assert math.isfinite(item) and field.low <= item <= field.high
    if schema in ('zro', 'state') and 'axes' in state:
        assert len(state['zro_offset']) == len(state['axes'])
        assert len(state['zro_offset_rad_s']) == len(state['axes'])
        assert_applies_finite(state)
    return state


def assert_section_checked(section) -> bool:
    """Assert a section is checked whole or refused in one line; tell whether it was taken."""
    try:
        checked = checked_section(section, FULL_SCALE_RAD_S)
    except (StateFileError, CalibrationError) as err:
        assert str(err) and '\n' not in str(err)
        count('section refused')
        return False
    count('section taken')
    state = checked['state']
    axes = len(checked['axes'])
    assert len(checked['zro_offset']) == axes
    assert len(state.offset_rad_s) == len(state.variance_rad2_s2) == axes
    assert all(math.isfinite(v) and abs(v) <= FULL_SCALE_RAD_S for v in state.offset_rad_s)
    assert all(math.isfinite(v) and v >= 0.0 for v in state.variance_rad2_s2)
    assert isinstance(state.updates, int) and state.updates >= 0
    return True


def assert_applies_finite(state: dict) -> None:
    """Assert what the node applies from a checked state: a refusal or a finite output."""
    if tuple(state['axes']) != ('x', 'y', 'z') or state['fingerprint'] != MODEL.fingerprint():
        return   # learned on another model: the node does not apply it
    try:
        model = saved_offset_model(MODEL, state, FULL_SCALE_RAD_S)
    except StateFileError as err:
        assert 'beyond the full scale' in str(err)
        return
    assert np.all(np.abs(model.zro_offset_rad_s) <= FULL_SCALE_RAD_S)
    rate = model.correct(np.full((4, 3), FULL_SCALE_RAD_S), [-40.0, 0.0, 25.0, 85.0])
    assert np.all(np.isfinite(rate.rate_rad_s))


def count(outcome: str) -> None:
    """Count ``outcome`` in the statistics of a property (--hypothesis-show-statistics)."""
    if currently_in_test_context():
        event(outcome)


def dump(state) -> bytes:
    return yaml.safe_dump(state, sort_keys=False).encode()


def test_the_valid_files_load_as_written(tmp_path):
    for schema, (_, state) in SCHEMAS.items():
        assert assert_loaded_or_refused(dump(state), schema) == state
    # As the writers write them.
    path = tmp_path / 'zro.yaml'
    write_state(str(path), ZRO_STATE)
    assert assert_loaded_or_refused(path.read_bytes(), 'zro') == ZRO_STATE


# Found by hand beside the fuzzing, kept as examples: nested beyond Python's recursion limit,
# values YAML's constructors refuse with ValueError, an alias bomb (9^9 leaves).
BOMB = b''.join(b'%s: &%s [%s]\n' % (level, level, b', '.join([b'*' + previous] * 9))
                for previous, level in zip([b'l0'] + [b'l%d' % i for i in range(1, 9)],
                                           [b'l%d' % i for i in range(1, 10)]))


@pytest.mark.slow
@FUZZ
@given(data=st.binary(max_size=400), schema=st.sampled_from(sorted(SCHEMAS)))
@example(data=b'[' * 100000, schema='zro')
@example(data=b'zro_offset: ' + b'[' * 100000, schema='zro')
@example(data=dump(ZRO_STATE).replace(b"'2026-11-25T12:00:00+00:00'", b'2026-13-45'),
         schema='zro')
@example(data=b'samples: !!int abc', schema='mpu')
@example(data=b'time: 2026-02-30 25:00:00', schema='mpu')
@example(data=b'l0: &l0 [1]\n' + BOMB + dump({**ZRO_STATE, 'zro_offset': 'bomb'}).replace(
    b'zro_offset: bomb', b'zro_offset: *l9'), schema='zro')
def test_random_bytes(data, schema):
    assert_loaded_or_refused(data, schema)


scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                    st.text(max_size=12), st.sampled_from(['x', 'y', 'z', 'rad/s', 'LSB',
                                                           'polynomial', 'mpu6000', '+z']))
documents = st.recursive(scalars, lambda children: st.one_of(
    st.lists(children, max_size=4),
    st.dictionaries(st.text(max_size=8), children, max_size=4)), max_leaves=12)


@FUZZ
@given(document=documents, schema=st.sampled_from(sorted(SCHEMAS)))
def test_random_yaml_documents(document, schema):
    assert_loaded_or_refused(dump(document), schema)


@FUZZ
@given(schema=st.sampled_from(sorted(SCHEMAS)), data=st.data())
def test_valid_files_truncated_anywhere_are_refused_or_whole(schema, data):
    text = dump(SCHEMAS[schema][1])
    # Cut anywhere but in the last line's newline: that one loses nothing.
    cut = data.draw(st.integers(0, len(text) - 2), label='cut')
    state = assert_loaded_or_refused(text[:cut], schema)
    # A truncation never loads as a different state: every key is required and the last
    # (time, saved) is quoted, so a cut inside it is not YAML. The whole file keeps its ZRO
    # state when the cut falls in the section that follows it, and refuses that section.
    if schema == 'state' and state is not None:
        assert {k: v for k, v in state.items() if k != TRACKING_SECTION} == ZRO_STATE
        assert TRACKING_SECTION not in state or \
            not assert_section_checked(state[TRACKING_SECTION])
    else:
        assert state is None


@FUZZ
@given(schema=st.sampled_from(sorted(SCHEMAS)), data=st.data())
def test_valid_files_with_bytes_flipped(schema, data):
    text = bytearray(dump(SCHEMAS[schema][1]))
    for _ in range(data.draw(st.integers(1, 4), label='flips')):
        position = data.draw(st.integers(0, len(text) - 1), label='position')
        text[position] ^= data.draw(st.integers(1, 255), label='mask')
    assert_loaded_or_refused(bytes(text), schema)


replacements = st.one_of(
    st.text(max_size=8), st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300, 1e308,
                                          -1.0, -(2**40), 2**64, 0, True, None, 'abc', '',
                                          '1e300', '.nan']),
    st.floats(), st.integers(), st.lists(st.floats(), max_size=5),
    st.lists(st.integers(-2**17, 2**17), max_size=5), st.lists(st.text(max_size=3), max_size=4),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))


@FUZZ
@given(schema=st.sampled_from(sorted(SCHEMAS)), data=st.data())
def test_valid_files_with_a_value_replaced(schema, data):
    fields, state = SCHEMAS[schema]
    # The keys the valid file holds (the learner's section is fuzzed in core/test_learning.py).
    key = data.draw(st.sampled_from([field.key for field in fields if field.key in state]),
                    label='key')
    value = data.draw(replacements, label='value')
    changed = {**state, key: value}
    if isinstance(state[key], list) and data.draw(st.booleans(), label='one item'):
        index = data.draw(st.integers(0, len(state[key]) - 1), label='index')
        changed[key] = [value if i == index else v for i, v in enumerate(state[key])]
    assert_loaded_or_refused(dump(changed), schema)


@FUZZ
@given(data=st.data())
def test_a_section_with_a_value_replaced_is_refused_alone(data):
    key = data.draw(st.sampled_from(sorted(SECTION)), label='key')
    value = data.draw(replacements, label='value')
    changed = {**SECTION, key: value}
    if isinstance(SECTION[key], list) and data.draw(st.booleans(), label='one item'):
        index = data.draw(st.integers(0, len(SECTION[key]) - 1), label='index')
        changed[key] = [value if i == index else v for i, v in enumerate(SECTION[key])]
    state = assert_loaded_or_refused(dump({**ZRO_STATE, TRACKING_SECTION: changed}), 'state')
    # The ZRO state loads whatever the section holds.
    assert {k: v for k, v in state.items() if k != TRACKING_SECTION} == ZRO_STATE


def test_a_zro_state_file_written_before_the_section_loads(tmp_path):
    # As the node wrote it before bias tracking, byte for byte.
    text = (f'model: polynomial\nfingerprint: {MODEL.fingerprint()}\naxes:\n- x\n- y\n- z\n'
            'zro_offset:\n- 0.0125\n- -0.5\n- 0.000325\noffset_unit: rad/s\n'
            'zro_offset_rad_s:\n- 0.0125\n- -0.5\n- 0.000325\ntemperature_c: 31.5\n'
            "samples: 500\ntime: '2026-11-25T12:00:00+00:00'\n")
    assert assert_loaded_or_refused(text.encode(), 'state') == ZRO_STATE
    # And the section alone, before any recalibration.
    assert assert_loaded_or_refused(dump({TRACKING_SECTION: SECTION}), 'state') == \
        {TRACKING_SECTION: SECTION}


def test_an_eeprom_offset_in_lsb_is_held_to_the_full_scale_as_a_rate():
    fields = EepromFields(range_code=15, version=2, tc_mv=(1854, 2508, 3114),
                          ee_zro=(132, 133, 145), ee_sf=(120, 145, 133))
    model = EepromModel(table_compensation([factory_table(fields, Output.DIGITAL)], 75.0,
                                           Output.DIGITAL))
    state = {**ZRO_STATE, 'model': 'eeprom', 'fingerprint': model.fingerprint(),
             'axes': ['z'], 'offset_unit': 'LSB', 'zro_offset_rad_s': [0.01]}
    full_scale = math.radians(75.0)
    # 12.8 LSB is about 1 deg/s here: applied.
    applied = saved_offset_model(model, {**state, 'zro_offset': [12.8]}, full_scale)
    assert applied.zro_offset == (12.8,)
    # 1e300 LSB, beside a sane rad/s copy: refused, in LSB and as a rate.
    with pytest.raises(StateFileError, match=r'^zro_offset \[1e\+300\] LSB \(\[\S+\] rad/s at '
                                             r'31.5 C\) is beyond the full scale \+-1.309 '
                                             r'rad/s \(75 deg/s\)$'):
        saved_offset_model(model, {**state, 'zro_offset': [1e300]}, full_scale)


# ZRO state files as the compensation node saved them after a recalibration at rest when the
# polynomial and linear_btc models had classes of their own (commit 3765585), each beside the
# parameter file it ran: the fingerprint hashes those parameters.
SAVED_BEFORE_EFFECT_MODELS = {
    'polynomial': ("""\
compensation_node:
  ros__parameters:
    model: 'polynomial'
    axes: ['z']
    polynomial:
      reference_temperature_c: 30.0
      temperature_scale_c: 20.0
      temperature_min_c: -20.0
      temperature_max_c: 80.0
      bias: {'z': [0.02, 0.001, -3.0e-05]}
      scale: {'z': [0.01, 0.0001]}
""", """\
model: polynomial
fingerprint: 9d82dede89918148
axes:
- z
zro_offset:
- 0.011502152120795053
offset_unit: rad/s
zro_offset_rad_s:
- 0.011502152120795053
temperature_c: 26.802705223880597
samples: 201
time: '2026-11-26T13:22:07+00:00'
"""),
    'linear_btc': ("""\
compensation_node:
  ros__parameters:
    model: 'linear_btc'
    axes: ['z']
    linear_btc: {pbc_rad_s: [-0.03], btc_rad_s_per_c: [-0.0007], t3_c: 22.5}
""", """\
model: linear_btc
fingerprint: dcfb8ddcc4088374
axes:
- z
zro_offset:
- -0.0018279750799985478
offset_unit: rad/s
zro_offset_rad_s:
- -0.0018279750799985478
temperature_c: 26.804259950248756
samples: 201
time: '2026-11-26T13:22:09+00:00'
"""),
}


@pytest.mark.parametrize('name', sorted(SAVED_BEFORE_EFFECT_MODELS))
def test_a_state_saved_before_the_model_became_an_effect_model_keeps_its_offset(tmp_path, name):
    parameters, saved = SAVED_BEFORE_EFFECT_MODELS[name]
    (tmp_path / 'params.yaml').write_text(parameters)
    values = node_values(str(tmp_path / 'params.yaml'), 'compensation_node')
    model = build_model(values)
    state, errors, _ = load(saved.encode(), 'zro')
    assert state is not None and not errors
    # What the node compares before it applies a saved offset (_with_saved_offset).
    assert (model.name, model.fingerprint(), axes_of(values)) == \
        (state['model'], state['fingerprint'], tuple(state['axes']))
    applied = saved_offset_model(model, state, FULL_SCALE_RAD_S)
    assert applied.zro_offset == tuple(state['zro_offset'])
    rate = np.linspace(-1.0, 1.0, 7)[:, None]
    temperature = np.linspace(-30.0, 90.0, 7)
    np.testing.assert_allclose(applied.correct(rate, temperature).rate_rad_s,
                               model.correct(rate, temperature).rate_rad_s
                               - state['zro_offset'][0], rtol=0.0, atol=1e-15)
