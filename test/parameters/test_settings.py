"""
The nodes' settings: every parameter reaches one, and the parameters that do not go together.

`driver_settings` turns the driver's values into `DriverSettings`; each parameter
must reach a field: changed alone to another value it takes (on one of a few
bases: the defaults, a part it belongs to), the settings differ. A parameter added
to the specs and forgotten in the settings fails here, by name.
"""

import dataclasses

from mlx_tempcomp.parameters.driver import driver_settings, DRIVER_SPECS
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
        candidates = [default + 1, default * 2 + 1] if spec.low is None else \
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
