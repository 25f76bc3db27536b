"""
The rclpy-free parameter schema against rclpy: the same type names and the same descriptors.

`parameters` checks a parameter file's values without a node (``evaluate``, the MPU
offset refresh); the nodes declare the same specs through rclpy. Both must agree on every
value a YAML file can give.
"""

import math
from pathlib import Path

from hypothesis import given, strategies as st
from mlx_tempcomp.core.node_models.model_error import ModelErrorTable
from mlx_tempcomp.parameters.compensation import (compensation_settings, COMPENSATION_SPECS,
                                                  covariance_noise_of, model_error_of)
from mlx_tempcomp.parameters.driver import DEVICES, DRIVER_SPECS
from mlx_tempcomp.parameters.files import flat_parameters, node_values
from mlx_tempcomp.parameters.models import build_model, MODELS
from mlx_tempcomp.parameters.specs import NoDefault, ParameterError, type_of
from mlx_tempcomp.ros.declare import descriptor
import pytest
from rclpy.parameter import Parameter
import yaml

scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=5),
                    st.binary(max_size=2), st.dates())
yaml_values = st.one_of(scalars, st.lists(scalars, max_size=4),
                        st.lists(st.sampled_from([True, 1, 1.0, 'a', b'b']), max_size=4))


def rclpy_type(value):
    try:
        return Parameter.Type.from_parameter_value(value).name.lower()
    except TypeError:
        return None


@given(yaml_values)
def test_type_of_names_the_type_rclpy_gives(value):
    assert type_of(value) == rclpy_type(value)


@pytest.mark.parametrize('spec', COMPENSATION_SPECS + DRIVER_SPECS, ids=lambda spec: spec.name)
def test_each_spec_has_an_rcl_type_and_its_descriptor(spec):
    declared = Parameter.Type[spec.value_type.upper()] if isinstance(spec.default, NoDefault) \
        else Parameter.Type.from_parameter_value(spec.default)
    assert declared.name.lower() == spec.value_type
    result = descriptor(spec)
    assert result.read_only == spec.read_only
    assert result.description.startswith(spec.description)
    ranges = list(result.integer_range) + list(result.floating_point_range)
    if spec.low is None:
        assert ranges == []
    else:
        assert [(r.from_value, r.to_value) for r in ranges] == [(spec.low, spec.high)]


def test_the_shipped_config_lists_every_parameter():
    """config/mlx_tempcomp.yaml says it lists every parameter: hold it to that."""
    config = Path(__file__).resolve().parents[2] / 'config' / 'mlx_tempcomp.yaml'
    text = config.read_text()
    listed = set(flat_parameters(yaml.safe_load(text)['/**']['ros__parameters']))
    specs = {spec.name: spec for spec in DRIVER_SPECS + COMPENSATION_SPECS}
    assert sorted(listed - specs.keys()) == []
    # Coefficients a fit writes (effects, chain) and arrays with no default are given in
    # comments; every other parameter is a key with its default.
    commented = {name for name, spec in specs.items() if name.startswith(('effects.', 'chain.'))
                 or isinstance(spec.default, NoDefault) or spec.default == []}
    assert sorted(specs.keys() - listed - commented) == []
    for name in commented - listed:
        key = name.removesuffix('.x').removesuffix('.y').removesuffix('.z').split('.')[-1]
        assert key in text.replace('#', ''), name


def test_every_device_is_listed_where_a_user_looks():
    """The config's device line, the README's device row and docs/ros.md's device table."""
    root = Path(__file__).resolve().parents[2]
    config = (root / 'config' / 'mlx_tempcomp.yaml').read_text()
    (device_line,) = [line for line in config.splitlines() if line.strip().startswith('device:')]
    readme = (root / 'README.md').read_text()
    (readme_row,) = [line for line in readme.splitlines() if line.startswith('| `device` |')]
    ros = (root / 'docs' / 'ros.md').read_text().partition('## Devices (`device`)')[2]
    for device in DEVICES:
        assert device in device_line.partition('#')[2], device
        assert f'`{device}`' in readme_row, device
        assert f'\n| `{device}`' in ros.partition('\n## ')[0], device


def test_a_file_s_integer_for_a_double_is_read_as_the_nodes_take_it(tmp_path):
    """The toolkit reads ``2`` where a double is meant as 2.0, as the nodes do."""
    path = tmp_path / 'ints.yaml'
    path.write_text('compensation_node:\n  ros__parameters:\n    stale_timeout_s: 2\n'
                    '    model: polynomial\n    polynomial:\n      bias:\n        z: [0, 1]\n')
    values = node_values(str(path), 'compensation_node')
    assert values['stale_timeout_s'] == 2.0 and isinstance(values['stale_timeout_s'], float)
    assert values['polynomial.bias.z'] == [0.0, 1.0]
    assert all(isinstance(v, float) for v in values['polynomial.bias.z'])
    # An integer where an integer is meant stays one; a string is still refused.
    path.write_text('compensation_node:\n  ros__parameters:\n    stale_timeout_s: two\n')
    with pytest.raises(ParameterError, match='invalid parameter stale_timeout_s: expected '
                                             "double, got string \\('two'\\)"):
        node_values(str(path), 'compensation_node')


NODE_FILE = 'compensation_node:\n  ros__parameters:\n{}'


@pytest.mark.parametrize('key, message', [
    ('modle: polynomial', 'unknown parameter modle: no node of mlx_tempcomp has it, and the '
                          'model would be built without it; did you mean model?'),
    ("axis: ['x']", 'unknown parameter axis: no node of mlx_tempcomp has it, and the model '
                    'would be built without it; did you mean axes?'),
    ('polynomial: {bais: {z: [0.01]}}',
     'unknown parameter polynomial.bais.z: no node of mlx_tempcomp has it, and the model '
     'would be built without it; did you mean polynomial.bias.z?'),
    ('sensor: {full_scale: 300.0}',
     'unknown parameter sensor.full_scale: no node of mlx_tempcomp has it, and the model '
     'would be built without it; did you mean sensor.full_scale_dps?'),
])
def test_a_misspelled_name_of_the_model_is_refused_naming_it(tmp_path, key, message):
    path = tmp_path / 'typo.yaml'
    path.write_text(NODE_FILE.format(f'    {key}\n'))
    with pytest.raises(ParameterError) as raised:
        node_values(str(path), 'compensation_node')
    assert str(raised.value) == f'{path}: {message}'


def test_other_unknown_names_are_warned_of_as_the_node_does(tmp_path):
    path = tmp_path / 'typo.yaml'
    path.write_text(NODE_FILE.format(
        '    bias_tracking: {temperature_rate_windows_s: 30.0, window_s: 20.0}\n'
        '    stale_timout_s: 2.0\n    publish_rate_hz: 50.0\n    use_sim_time: true\n'
        '    qos_overrides: {/imu/data_raw: {subscription: {depth: 10}}}\n'))
    warnings = []
    values = node_values(str(path), 'compensation_node', warnings.append)
    assert warnings == [
        f'{path}: unknown parameter bias_tracking.temperature_rate_windows_s ignored: no node '
        'of mlx_tempcomp has it; did you mean bias_tracking.max_temperature_rate_c_s?',
        f'{path}: unknown parameter stale_timout_s ignored: no node of mlx_tempcomp has it; '
        'did you mean stale_timeout_s?']
    # The known ones are read; the driver's (a /** section serves both) and rclpy's are known.
    assert values['bias_tracking.window_s'] == 20.0
    assert node_values(str(path), 'compensation_node') == values


def model_error_values(**given) -> dict:
    values = {spec.name: spec.initial_value for spec in COMPENSATION_SPECS}
    values.update({'axes': ['x', 'z'], **given})
    return values


def test_model_error_of_builds_the_table_of_the_measured_axes():
    assert model_error_of(model_error_values()) is None
    table = model_error_of(model_error_values(**{
        'model_error.temperature_c': [0.0, 30.0], 'model_error.x_rad_s': [1e-3, 2e-3],
        'model_error.z_rad_s': [3e-3, 0.0], 'model_error.y_rad_s': [9.0]}))
    # y is not measured: its values are not used, as polynomial.bias.y would not be.
    assert table == ModelErrorTable((0.0, 30.0), ((1e-3, 2e-3), (3e-3, 0.0)))
    # The sensor-noise limits of a ZRO recalibration do not take the model error.
    assert compensation_settings(model_error_values()).recalibration_limits().rate_noise_rad_s == \
        0.0058


@pytest.mark.parametrize('given, message', [
    ({'model_error.x_rad_s': [1e-3]},
     'invalid parameter model_error.temperature_c: unset, but model_error.x_rad_s is given; '
     'the table needs its temperatures'),
    ({'model_error.temperature_c': [0.0, 30.0], 'model_error.x_rad_s': [1e-3, 1e-3]},
     'invalid parameter model_error.z_rad_s: needs 2 values (one per '
     'model_error.temperature_c), got 0'),
    ({'model_error.temperature_c': [30.0, 0.0], 'model_error.x_rad_s': [1e-3, 1e-3],
      'model_error.z_rad_s': [1e-3, 1e-3]},
     'invalid parameter model_error.temperature_c: model error temperatures must be '
     'strictly increasing, got [30.0, 0.0]'),
    ({'model_error.temperature_c': [0.0], 'model_error.x_rad_s': [-1e-3],
      'model_error.z_rad_s': [1e-3]},
     'invalid parameter model_error.x_rad_s: an error must be finite and >= 0, got [-0.001]'),
])
def test_model_error_of_names_what_is_wrong(given, message):
    with pytest.raises(ParameterError) as raised:
        model_error_of(model_error_values(**given))
    assert str(raised.value) == message


def test_the_model_table_gives_the_choices_and_refuses_a_name_it_lacks():
    """``model`` offers the table's names; a name outside it is refused, not built as another."""
    spec = next(spec for spec in COMPENSATION_SPECS if spec.name == 'model')
    assert spec.choices == tuple(MODELS) == ('eeprom', 'polynomial', 'linear_btc', 'effects',
                                             'chain')
    values = {spec.name: spec.initial_value for spec in COMPENSATION_SPECS}
    with pytest.raises(ParameterError, match="invalid parameter model: 'cubic' is not one of "
                                             'eeprom, polynomial, linear_btc, effects, chain'):
        build_model({**values, 'model': 'cubic'})


def test_the_covariance_takes_the_noise_of_each_axis_when_given():
    assert covariance_noise_of(model_error_values()) == (0.0058, 0.0058)
    per_axis = model_error_values(**{'model_error.rate_noise_rad_s': [2e-4, 3e-4]})
    assert covariance_noise_of(per_axis) == (2e-4, 3e-4)
    # The recalibration's motion check keeps rate_noise_rad_s.
    assert compensation_settings(per_axis).recalibration_limits().rate_noise_rad_s == 0.0058
    for wrong in ([2e-4], [2e-4, -1.0], [2e-4, math.nan]):
        with pytest.raises(ParameterError, match='invalid parameter model_error.rate_noise_rad_s: '
                                                 r'needs one finite noise >= 0 per axis \(2: x, '
                                                 r'z\)'):
            covariance_noise_of(model_error_values(**{'model_error.rate_noise_rad_s': wrong}))
