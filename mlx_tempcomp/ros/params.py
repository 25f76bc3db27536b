"""
Parameter schemas of the nodes, and their translation into core objects.

Each parameter is declared with a descriptor (type, description, range,
read-only for hardware settings); rclpy enforces those. What a descriptor
cannot say (choices, array lengths, a model that must build) is checked by
the functions here, which raise `ParameterError` naming the parameter.
"""

from dataclasses import dataclass
import math
import os
from typing import Any, Optional

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterUninitializedException)
from rclpy.parameter import Parameter

from ..core.compensation import table_compensation
from ..core.conversion import Output, SensorTransfer
from ..core.errors import ConfigError
from ..core.interpolation import Interpolation
from ..core.models import AXIS_NAMES, EepromModel, LinearBtcModel, PolynomialModel
from ..core.recalibration import RecalibrationLimits
from ..simulation.mlx90609 import Fault
from ..simulation.physics import Effects


class ParameterError(Exception):
    """A parameter value is invalid; the message names the parameter."""


@dataclass(frozen=True)
class Spec:
    """One parameter: name, default (its type), description and constraints."""

    name: str
    default: Any
    description: str
    read_only: bool = False
    low: Optional[float] = None
    high: Optional[float] = None
    choices: tuple = ()

    def descriptor(self) -> ParameterDescriptor:
        text = self.description
        if self.choices:
            text += f" (one of: {', '.join(self.choices)})"
        descriptor = ParameterDescriptor(description=text, read_only=self.read_only)
        if self.low is not None:
            if isinstance(self.default, bool) or not isinstance(self.default, (int, float)):
                raise TypeError(f'range on non-numeric parameter {self.name}')
            if isinstance(self.default, int):
                descriptor.integer_range = [IntegerRange(
                    from_value=int(self.low), to_value=int(self.high), step=1)]
            else:
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(self.low), to_value=float(self.high), step=0.0)]
        return descriptor


SENSOR_SPECS = (
    Spec('sensor.full_scale_dps', 0.0, 'full scale in deg/s; 0 = from the EEPROM RANGE field',
         read_only=True, low=0.0, high=10000.0),
    Spec('sensor.nominal_zro_mv', 2500.0, 'nominal zero-rate output in mV', read_only=True,
         low=0.0, high=5000.0),
    Spec('sensor.output_swing_mv', 2000.0,
         'full-scale output swing in mV (typical SF = swing / full scale); UNCONFIRMED',
         read_only=True, low=1.0, high=5000.0),
    Spec('sensor.temperature_sensor_mv_at_25c', 2500.0,
         'TEMPOUT at 25 C in mV, typical (only maps degC to TEMPOUT); UNCONFIRMED',
         read_only=True, low=0.0, high=5000.0),
    Spec('sensor.temperature_sensor_mv_per_k', 10.0,
         'TEMPOUT slope in mV/K, typical; UNCONFIRMED', read_only=True, low=0.1, high=100.0),
    Spec('sensor.temperature_mv_per_lsb', 25.0 / 16.0,
         'temperature channel mV per ADC LSB; UNCONFIRMED', read_only=True, low=0.01, high=100.0),
    Spec('sensor.temperature_offset_mv', 300.0,
         'temperature channel mV at code 0; UNCONFIRMED', read_only=True, low=-5000.0,
         high=5000.0),
)

COMMON_SPECS = SENSOR_SPECS + (
    Spec('axes', ['z'], "Imu axes the gyro measures, e.g. ['z'] or ['x', 'y', 'z'] (quoted)",
         read_only=True),
    Spec('rate_noise_rad_s', 0.0058,
         '1-sigma rate noise of one sample in rad/s; sets the angular velocity covariance '
         '(0 = unknown)', low=0.0, high=10.0),
)

DRIVER_SPECS = COMMON_SPECS + (
    Spec('source', 'simulated', 'where raw data comes from', read_only=True,
         choices=('simulated', 'spidev', 'bag')),
    Spec('frame_id', 'imu_link', 'frame_id of published messages (REP-145)'),
    Spec('rate_hz', 100.0, 'publish rate in Hz (simulated time for the simulated source)',
         read_only=True, low=0.1, high=10000.0),
    Spec('oversample', 1, 'conversions averaged per published sample', read_only=True,
         low=1, high=256),
    Spec('spi.bus', 0, 'spidev bus number', read_only=True, low=0, high=255),
    Spec('spi.chip_selects', [0], 'spidev chip select per axis, same order as axes',
         read_only=True),
    Spec('spi.speed_hz', 500000, 'SPI clock in Hz (maximum UNCONFIRMED)', read_only=True,
         low=1000, high=20000000),
    Spec('spi.mode', 3, 'SPI mode (0 or 3 work: data latched on the rising edge)',
         read_only=True, low=0, high=3),
    Spec('bag.path', '', 'rosbag2 folder (sqlite3 or mcap) to replay', read_only=True),
    Spec('bag.rate_factor', 1.0,
         'replay speed: 1 = recorded rate, 2 = twice as fast, 0 = as fast as the consumer '
         'takes it (paced by bag.pace_topic)',
         read_only=True, low=0.0, high=1000.0),
    Spec('bag.pace_topic', 'imu/data',
         'at rate factor 0: keep at most 100 samples ahead of the stamps seen here',
         read_only=True),
    Spec('bag.imu_topic', '/imu/data_raw', 'Imu topic in the bag', read_only=True),
    Spec('bag.temperature_topic', '/imu/temperature_raw', 'Temperature topic in the bag',
         read_only=True),
    Spec('bag.eeprom_topic', '/imu/eeprom', 'EEPROM topic in the bag', read_only=True),
    Spec('simulation.seed', 0, 'seed of the simulated chips and their noise', read_only=True,
         low=0, high=2**31 - 1),
    Spec('simulation.real_time_factor', 1.0,
         'simulated seconds per wall second (10 = ten times faster than real time)',
         read_only=True, low=0.001, high=10000.0),
    Spec('simulation.eeprom_version', 2, 'EEPROM VERSION the simulated factory writes',
         read_only=True, low=0, high=255),
    Spec('simulation.start_temperature_c', 25.0, 'chamber temperature at start',
         read_only=True, low=-60.0, high=125.0),
    Spec('simulation.cycle_temperatures_c', Parameter.Type.DOUBLE_ARRAY,
         'chamber temperatures to ramp through in turn (empty: constant)', read_only=True),
    Spec('simulation.ramp_c_per_min', 2.0, 'chamber ramp rate', read_only=True,
         low=0.001, high=1000.0),
    Spec('simulation.hold_s', 0.0, 'soak at each cycle temperature', read_only=True,
         low=0.0, high=1e6),
    Spec('simulation.die_time_constant_s', 0.0, 'die follows the chamber with this lag',
         read_only=True, low=0.0, high=1e5),
    Spec('simulation.rate_dps', [0.0], 'true rate in deg/s, one value or one per axis',
         read_only=True),
    Spec('simulation.supply_v', 5.0, 'supply voltage', read_only=True, low=0.0, high=10.0),
    Spec('simulation.thermal_lag_s', 0.0, 'effect: temperature sensor lags the die',
         read_only=True, low=0.0, high=1e5),
    Spec('simulation.hysteresis_dps', 0.0, 'effect: ZRO heating/cooling branch difference',
         read_only=True, low=-100.0, high=100.0),
    Spec('simulation.zro_supply_dps_per_v', 0.0, 'effect: ZRO shift per volt off 5 V',
         read_only=True, low=-1000.0, high=1000.0),
    Spec('simulation.fault', 'none', 'SPI fault of the simulated chips (settable at runtime)',
         choices=tuple(f.value for f in Fault)),
)

COMPENSATION_SPECS = COMMON_SPECS + (
    Spec('model', 'eeprom', 'compensation model',
         choices=('eeprom', 'polynomial', 'linear_btc')),
    Spec('eeprom.interpolation', 'quadratic', 'interpolation of the factory table',
         choices=tuple(m.value for m in Interpolation)),
    Spec('polynomial.reference_temperature_c', 25.0, 'Tref of x = (T - Tref) / scale',
         low=-100.0, high=200.0),
    Spec('polynomial.temperature_scale_c', 1.0, 'scale of x = (T - Tref) / scale',
         low=1e-6, high=1000.0),
    Spec('polynomial.temperature_min_c', -1000.0, 'temperatures below are clamped',
         low=-1000.0, high=1000.0),
    Spec('polynomial.temperature_max_c', 1000.0, 'temperatures above are clamped',
         low=-1000.0, high=1000.0),
) + tuple(
    Spec(f'polynomial.bias.{axis}', Parameter.Type.DOUBLE_ARRAY,
         f'bias polynomial of axis {axis} in rad/s, lowest order first') for axis in AXIS_NAMES
) + tuple(
    Spec(f'polynomial.scale.{axis}', Parameter.Type.DOUBLE_ARRAY,
         f'relative scale-factor polynomial of axis {axis} (empty: none)') for axis in AXIS_NAMES
) + (
    Spec('linear_btc.pbc_rad_s', Parameter.Type.DOUBLE_ARRAY, 'PBC per axis, rad/s'),
    Spec('linear_btc.btc_rad_s_per_c', Parameter.Type.DOUBLE_ARRAY, 'BTC per axis, rad/s/C'),
    Spec('linear_btc.t3_c', 25.0, 'T3, the temperature of the PBC measurement',
         low=-100.0, high=200.0),
    Spec('recalibration.duration_s', 5.0, 'averaging window (sensor time)', low=0.05,
         high=3600.0),
    Spec('recalibration.noise_multiple', 3.0, 'rate spread above this x noise means motion',
         low=0.1, high=1000.0),
    Spec('recalibration.max_mean_rate_rad_s', math.radians(2.0),
         'mean residual rate above this means motion', low=1e-6, high=10.0),
    Spec('recalibration.max_temperature_change_c', 0.5,
         'temperature change within the window above this is refused', low=1e-3, high=100.0),
    Spec('recalibration.state_file', '',
         "ZRO state YAML ('' = ~/.ros/mlx_tempcomp/<node name>_zro.yaml)", read_only=True),
    Spec('stale_timeout_s', 1.0, 'no input for this long is reported as stale', low=0.01,
         high=3600.0),
)


def declare(node, specs) -> dict:
    """Declare ``specs`` on ``node``; return their values. Raise `ParameterError`."""
    values = {}
    for spec in specs:
        try:
            parameter = node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except (InvalidParameterTypeException, InvalidParameterValueException) as err:
            msg = f'invalid parameter {spec.name}: {err}'
            raise ParameterError(msg) from None
        values[spec.name] = value_of(parameter)
    check_choices(specs, values)
    return values


def value_of(parameter):
    try:
        value = parameter.value
    except ParameterUninitializedException:
        value = None
    return [] if value is None else value


def check_choices(specs, values: dict) -> None:
    for spec in specs:
        if spec.choices and spec.name in values and values[spec.name] not in spec.choices:
            choices = ', '.join(spec.choices)
            msg = (f'invalid parameter {spec.name}: {values[spec.name]!r} is not one of '
                   f'{choices}')
            raise ParameterError(msg)


def axes_of(values: dict) -> tuple:
    axes = tuple(values['axes'])
    if not 1 <= len(axes) <= 3 or len(set(axes)) != len(axes) or \
            not set(axes) <= set(AXIS_NAMES):
        msg = f"invalid parameter axes: {list(axes)}, give 1 to 3 distinct of 'x', 'y', 'z'"
        raise ParameterError(msg)
    return axes


def transfer_of(values: dict) -> SensorTransfer:
    return SensorTransfer(
        nominal_zro_mv=values['sensor.nominal_zro_mv'],
        output_swing_mv=values['sensor.output_swing_mv'],
        temperature_sensor_mv_at_25c=values['sensor.temperature_sensor_mv_at_25c'],
        temperature_sensor_mv_per_k=values['sensor.temperature_sensor_mv_per_k'],
        temperature_mv_per_lsb=values['sensor.temperature_mv_per_lsb'],
        temperature_offset_mv=values['sensor.temperature_offset_mv'])


def effects_of(values: dict) -> Effects:
    return Effects(thermal_lag_s=values['simulation.thermal_lag_s'],
                   hysteresis_dps=values['simulation.hysteresis_dps'],
                   zro_supply_dps_per_v=values['simulation.zro_supply_dps_per_v'])


def limits_of(values: dict) -> RecalibrationLimits:
    noise = values['rate_noise_rad_s']
    if noise <= 0.0:
        msg = 'invalid parameter rate_noise_rad_s: recalibration needs a positive noise figure'
        raise ParameterError(msg)
    return RecalibrationLimits(
        rate_noise_rad_s=noise, noise_multiple=values['recalibration.noise_multiple'],
        max_mean_rate_rad_s=values['recalibration.max_mean_rate_rad_s'],
        max_temperature_change_c=values['recalibration.max_temperature_change_c'])


def state_file_of(values: dict, node_name: str) -> str:
    path = values['recalibration.state_file']
    if not path:
        path = os.path.join('~', '.ros', 'mlx_tempcomp', f'{node_name}_zro.yaml')
    return os.path.expanduser(path)


def build_model(values: dict, tables: Optional[tuple] = None, full_scale_dps: float = 0.0):
    """
    Build the model named by ``model`` from parameter values.

    ``tables`` are the factory tables from the sensor's EEPROM and
    ``full_scale_dps`` the full scale they were decoded with (None while the
    EEPROM has not arrived: the eeprom model is then None).
    """
    axes = axes_of(values)
    name = values['model']
    try:
        if name == 'polynomial':
            bias = []
            for axis in axes:
                coefficients = values[f'polynomial.bias.{axis}']
                if not coefficients:
                    msg = (f'invalid parameter polynomial.bias.{axis}: the polynomial model '
                           f'needs coefficients for every axis in {list(axes)}')
                    raise ParameterError(msg)
                bias.append(coefficients)
            scale = [values[f'polynomial.scale.{axis}'] for axis in axes]
            if any(scale) and not all(scale):
                msg = ('invalid parameter polynomial.scale: give a scale polynomial for every '
                       'axis or for none')
                raise ParameterError(msg)
            return PolynomialModel(
                bias_coefficients=tuple(bias),
                reference_temperature_c=values['polynomial.reference_temperature_c'],
                temperature_scale_c=values['polynomial.temperature_scale_c'],
                scale_coefficients=tuple(scale) if all(scale) else (),
                temperature_min_c=values['polynomial.temperature_min_c'],
                temperature_max_c=values['polynomial.temperature_max_c'])
        if name == 'linear_btc':
            pbc, btc = values['linear_btc.pbc_rad_s'], values['linear_btc.btc_rad_s_per_c']
            for key, array in (('linear_btc.pbc_rad_s', pbc), ('linear_btc.btc_rad_s_per_c', btc)):
                if len(array) != len(axes):
                    msg = (f'invalid parameter {key}: needs {len(axes)} values (one per axis '
                           f'in {list(axes)}), got {len(array)}')
                    raise ParameterError(msg)
            return LinearBtcModel(pbc_rad_s=tuple(pbc), btc_rad_s_per_c=tuple(btc),
                                  t3_c=values['linear_btc.t3_c'])
        interpolation = Interpolation.parse(values['eeprom.interpolation'])
        if tables is None:
            return None
        if len(tables) != len(axes):
            msg = (f'the sensor sent {len(tables)} EEPROM tables but axes has {len(axes)} '
                   'entries')
            raise ParameterError(msg)
        transfer = transfer_of(values)
        compensation = table_compensation(tables, full_scale_dps, Output.DIGITAL,
                                          interpolation, transfer)
        return EepromModel(compensation=compensation, transfer=transfer)
    except ConfigError as err:
        msg = f'invalid {name} model parameters: {err}'
        raise ParameterError(msg) from None
