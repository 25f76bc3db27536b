"""
The nodes' settings: every parameter reaches one, and the parameters that do not go together.

`driver_settings` and `compensation_settings` turn a node's values into its settings;
each parameter must reach a field: changed alone to another value it takes (on one
of a few bases: the defaults, a part or table it belongs to), the settings differ.
A parameter added to the specs and forgotten in the settings fails here, by name; the
compensation node's model parameters are the one exception, named: the node builds its
model from the values (`build_model`).
"""

import dataclasses

from mlx_tempcomp.parameters.compensation import compensation_settings, COMPENSATION_SPECS
from mlx_tempcomp.parameters.driver import driver_settings, DRIVER_SPECS
from mlx_tempcomp.parameters.models import CORRECTION_SPECS, MODELS
from mlx_tempcomp.parameters.specs import check_value, ParameterError, Spec
import pytest

MPU_AXES = ['x', 'y', 'z']


def defaults(specs, **given) -> dict:
    """Give every value of ``specs``: the defaults, with ``given``."""
    values = {spec.name: spec.initial_value for spec in specs}
    values.update(given)
    return values


def alternatives(spec) -> list:
    """Give values of ``spec`` other than its default, of its type and in its range."""
    default = spec.initial_value
    kind = spec.value_type
    if spec.choices:
        candidates = list(spec.choices)
    elif kind == 'bool':
        candidates = [not default]
    elif kind in ('integer', 'double'):
        given = 0 if default == [] else default     # a double declared without a default
        candidates = [given + 1, given * 2 + 1] if spec.low is None else \
            [spec.high, spec.low, (spec.low + spec.high) / 2]
        candidates = [int(v) if kind == 'integer' else float(v) for v in candidates]
    elif kind == 'string':
        candidates = ['other', '/other']
    else:
        item = {'double_array': 2e-3, 'integer_array': 1, 'string_array': 'x'}[kind]
        candidates = [[item], [item] * 3, [item] * 2]
    valid = []
    for value in candidates:
        try:
            check_value(spec, value)
        except ParameterError:
            continue
        if value != default:
            valid.append(value)
    return valid


def unreached(build, specs, bases) -> list:
    """Give the names of ``specs`` no change of which (on any base) changes ``build``'s result."""
    missing = []
    for spec in specs:
        reached = False
        for base in bases:
            settings = build(base)
            for value in alternatives(spec):
                try:
                    changed = build({**base, spec.name: value})
                except ParameterError:
                    continue
                if changed != settings:
                    reached = True
                    break
            if reached:
                break
        if not reached:
            missing.append(spec.name)
    return missing


DRIVER_BASES = (
    defaults(DRIVER_SPECS),
    # simulation.bus i2c is the MPU's.
    defaults(DRIVER_SPECS, device='mpu6000', axes=MPU_AXES),
)


def test_every_driver_parameter_reaches_a_setting():
    assert unreached(driver_settings, DRIVER_SPECS, DRIVER_BASES) == []


def test_a_parameter_forgotten_by_the_settings_is_named():
    forgotten = Spec('forgotten.bandwidth_hz', 50.0, 'declared, read by nothing', low=1.0,
                     high=1000.0)
    assert unreached(driver_settings, DRIVER_SPECS + (forgotten,), DRIVER_BASES) == \
        ['forgotten.bandwidth_hz']


def test_the_driver_settings_are_frozen_and_hold_no_list():
    settings = driver_settings(DRIVER_BASES[0])
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.frame_id = 'other'
    hash(settings)   # every part frozen, lists as tuples
    assert settings.spi.chip_selects == (0,) and settings.simulation.rate_dps == (0.0,)


DRIVER_REFUSED = {
    'adis16130 on two axes': (
        {'device': 'adis16130', 'axes': ['x', 'z']},
        "invalid parameter axes: the adis16130 measures one axis, got ['x', 'z']"),
    'adis16130 simulated at two rates': (
        {'device': 'adis16130', 'simulation.rate_dps': [1.0, 2.0]},
        'invalid parameter simulation.rate_dps: the adis16130 measures one axis, give one '
        'value, got 2'),
    'mlx90609 on i2c': (
        {'source': 'i2c'},
        'invalid parameter source: the mlx90609 speaks SPI only; i2c is for the mpu6000'),
    'supply monitor of a real part': (
        {'source': 'spidev', 'simulation.supply_monitor_hz': 1.0},
        'invalid parameter simulation.supply_monitor_hz: the supply monitor belongs to the '
        'simulated MLX90609 (device mlx90609, source simulated)'),
    'bag without a path': (
        {'source': 'bag'}, 'invalid parameter bag.path: the bag source needs a path'),
    'three axes on one chip select': (
        {'source': 'spidev', 'axes': MPU_AXES},
        'invalid parameter spi.chip_selects: 1 chip selects for 3 axes'),
    'mpu6000 on two chip selects': (
        {'device': 'mpu6000', 'axes': MPU_AXES, 'source': 'spidev', 'spi.chip_selects': [0, 1]},
        'invalid parameter spi.chip_selects: the mpu6000 is one part on one chip select, got 2'),
    'mpu6000 oversampled': (
        {'device': 'mpu6000', 'axes': MPU_AXES, 'oversample': 4},
        'invalid parameter oversample: the mpu6000 averages in its DLPF, not in the driver; '
        'give 1, got 4'),
    'mpu6000 simulated with a die lag': (
        {'device': 'mpu6000', 'axes': MPU_AXES, 'simulation.die_time_constant_s': 10.0},
        'invalid parameter simulation.die_time_constant_s: the simulated mpu6000 follows its '
        'thermal profile directly, give 0'),
    'no frame_id': ({'frame_id': ''}, 'invalid parameter frame_id: must not be empty'),
}


@pytest.mark.parametrize('case', sorted(DRIVER_REFUSED))
def test_driver_parameters_that_do_not_go_together_are_refused_naming_one(case):
    given, message = DRIVER_REFUSED[case]
    with pytest.raises(ParameterError) as raised:
        driver_settings(defaults(DRIVER_SPECS, **given))
    assert str(raised.value).startswith(message)


# Read from the values by build_model, as evaluate reads them: not settings of the node.
MODEL_PARAMETERS = {spec.name for kind in MODELS.values() for spec in kind.specs} | \
    {spec.name for spec in CORRECTION_SPECS}
COMPENSATION_BASES = (
    defaults(COMPENSATION_SPECS),
    # A model error table of three axes: each column is read.
    defaults(COMPENSATION_SPECS, **{
        'axes': MPU_AXES, 'model_error.temperature_c': [0.0], 'model_error.x_rad_s': [1e-3],
        'model_error.y_rad_s': [1e-3], 'model_error.z_rad_s': [1e-3]}),
)


def test_every_compensation_parameter_reaches_a_setting_but_the_model_s():
    missing = unreached(compensation_settings, COMPENSATION_SPECS, COMPENSATION_BASES)
    # The eeprom model's wait is the node's: how long the samples wait for the tables.
    assert sorted(missing) == sorted(MODEL_PARAMETERS - {'eeprom.wait_s'})


def test_the_compensation_settings_are_frozen_and_hold_no_list():
    settings = compensation_settings(COMPENSATION_BASES[1])
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.model = 'polynomial'
    hash(settings)
    assert settings.model_error.temperature_c == (0.0,)
    assert settings.covariance_noise_rad_s == (0.0058,) * 3


COMPENSATION_REFUSED = {
    'model error without temperatures': (
        {'model_error.z_rad_s': [1e-3]},
        'invalid parameter model_error.temperature_c: unset, but model_error.z_rad_s is given'),
    'covariance noise of another axis count': (
        {'model_error.rate_noise_rad_s': [1e-3, 1e-3]},
        'invalid parameter model_error.rate_noise_rad_s: needs one finite noise >= 0 per axis '
        '(1: z)'),
    'tracking without a noise figure': (
        {'rate_noise_rad_s': 0.0},
        'invalid parameter bias_tracking.rate_noise_rad_s: bias tracking needs the noise of a '
        'sample; give it here or in rate_noise_rad_s (both are 0)'),
    'tracking std per axis of another count': (
        {'axes': ['x', 'z'], 'bias_tracking.initial_std_rad_s': [1e-3] * 3},
        'invalid parameter bias_tracking.initial_std_rad_s: give one value or one per axis (2)'),
    'learning knots upside down': (
        {'learning.temperature_min_c': 50.0, 'learning.temperature_max_c': 10.0},
        'invalid parameter learning.temperature_max_c: must be above temperature_min_c (50), '
        'got 10'),
    'learning prior per axis of another count': (
        {'learning.prior_std_rad_s': [1e-3, 1e-3]},
        'invalid parameter learning.prior_std_rad_s: give one value or one per axis (1)'),
}


@pytest.mark.parametrize('case', sorted(COMPENSATION_REFUSED))
def test_compensation_parameters_that_do_not_go_together_are_refused_naming_one(case):
    given, message = COMPENSATION_REFUSED[case]
    with pytest.raises(ParameterError) as raised:
        compensation_settings(defaults(COMPENSATION_SPECS, **given))
    assert str(raised.value).startswith(message)


def test_what_is_not_used_is_not_checked_and_the_recalibration_refuses_without_a_noise():
    # Tracking off: its values are not used (a change turning it on checks them).
    off = compensation_settings(defaults(COMPENSATION_SPECS, **{
        'bias_tracking.enabled': False, 'learning.enabled': False, 'rate_noise_rad_s': 0.0,
        'learning.temperature_min_c': 50.0, 'learning.temperature_max_c': 10.0}))
    assert off.tracking.tracker is None and off.learning is None
    # A model with a correction table: the learnt table takes its knots, not learning.*'s.
    corrected = compensation_settings(defaults(COMPENSATION_SPECS, **{
        'correction.temperature_c': [0.0, 40.0], 'correction.z_rad_s': [0.0, 1e-3],
        'learning.temperature_min_c': 50.0, 'learning.temperature_max_c': 10.0}))
    assert corrected.learning.knots_c is None
    with pytest.raises(ParameterError, match='invalid parameter rate_noise_rad_s: recalibration '
                                             'needs a positive noise figure'):
        off.recalibration_limits()
