"""
The parameters of the package's nodes, their checks, and the model they build.

Each parameter is a `Spec`: name, default, description, range, choices, and
its type as rcl names it (``double``, ``string_array``, ...). rclpy enforces
type and range from the descriptors ``ros/params.py`` makes of the specs; the
checks here say the same for values read from a parameter file without a node
(`node_values`), and what a descriptor cannot say (choices, array lengths, a
model that must build) for both. They raise `ParameterError` naming the
parameter. Nothing here imports rclpy: the toolkit runs without ROS.
"""

from dataclasses import dataclass
import math
import os
from typing import Any, Optional

import numpy as np
import yaml

from .core.chain import (CalibrationChain, ChainModel,
                         PARAMETER_DESCRIPTIONS as CHAIN_DESCRIPTIONS)
from .core.compensation import table_compensation
from .core.conversion import Output, SensorTransfer
from .core.effects import (AxisTerms, EffectModel, LinearBtc, PARAMETER_DESCRIPTIONS,
                           polynomial_model)
from .core.errors import ConfigError
from .core.interpolation import Interpolation
from .core.model_error import ModelErrorTable, table_temperatures
from .core.model_interface import ModelInputs
from .core.models import AXIS_NAMES, EepromModel
from .core.recalibration import RecalibrationLimits
from .core.tracking_parameters import PARAMETERS as TRACKING_PARAMETERS, PREFIX as TRACKING
from .errors import MlxTempCompError
from .simulation.mlx90609 import Fault
from .simulation.physics import Effects


class ParameterError(MlxTempCompError):
    """A parameter value or parameter file is invalid; the message names it."""


@dataclass(frozen=True)
class NoDefault:
    """The default of a parameter declared with its type only (its value is then [])."""

    value_type: str


_SCALAR_TYPES = ((bool, 'bool'), (int, 'integer'), (float, 'double'), (str, 'string'))


def type_of(value) -> Optional[str]:
    """
    Give rcl's type name of a parameter value; None for a mixed list or another type.

    The rules of rclpy's ``Parameter.Type.from_parameter_value``: a bool is not an
    integer, a list takes the type its items share, an empty list is a byte array.
    """
    if value is None:
        return 'not_set'
    for kind, name in _SCALAR_TYPES:
        if isinstance(value, kind):
            return name
    if isinstance(value, (list, tuple)):
        for kind, name in ((bytes, 'byte'),) + _SCALAR_TYPES:
            if all(isinstance(item, kind) for item in value):
                return f'{name}_array'
    return None


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

    @property
    def value_type(self) -> str:
        """Give the parameter's type as rcl names it: double, string_array, ..."""
        if isinstance(self.default, NoDefault):
            return self.default.value_type
        return type_of(self.default)

    @property
    def initial_value(self):
        """Give the value a node holds when nothing sets the parameter: [] for no default."""
        return [] if isinstance(self.default, NoDefault) else self.default


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

DEVICES = ('mlx90609', 'adis16130', 'mpu6000')

DRIVER_SPECS = COMMON_SPECS + (
    Spec('device', 'mlx90609', 'sensor read by the simulated and spidev sources', read_only=True,
         choices=DEVICES),
    Spec('source', 'simulated', 'where raw data comes from', read_only=True,
         choices=('simulated', 'spidev', 'bag')),
    Spec('frame_id', 'imu_link', 'frame_id of published messages (REP-145)'),
    Spec('publish_rate_hz', 100.0, 'publish rate in Hz (simulated time for the simulated '
         'source); each message is the mean of the device samples of its interval',
         read_only=True, low=0.1, high=10000.0),
    Spec('sample_rate_hz', 0.0, 'device sample rate in Hz, at least publish_rate_hz; 0 = the '
         "part's natural rate (MLX90609 1000, UNCONFIRMED; ADIS16130 5700; MPU-6000 its gyro "
         'output rate over 1 + SMPLRT_DIV)', read_only=True, low=0.0, high=100000.0),
    Spec('oversample', 1, 'conversions averaged per device sample', read_only=True,
         low=1, high=256),
    Spec('spi.bus', 0, 'spidev bus number', read_only=True, low=0, high=255),
    Spec('spi.chip_selects', [0], 'spidev chip select per axis, same order as axes',
         read_only=True),
    Spec('spi.speed_hz', 0,
         'SPI clock in Hz; 0 = the device default (MLX90609 500 kHz, its maximum UNCONFIRMED; '
         'ADIS16130 1 MHz; MPU-6000/6500 1 MHz, the limit for configuration registers)',
         read_only=True, low=0, high=20000000),
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
    Spec('bag.pace_timeout_s', 1.0,
         'at rate factor 0: after this long without progress on bag.pace_topic the replay '
         'goes on anyway (a replay nobody consumes still ends)',
         read_only=True, low=0.001, high=3600.0),
    Spec('bag.on_end', 'stop', 'at the end of the bag: stop (log a summary, exit 0), loop '
         '(start over, stamps shifted to keep increasing) or hold (stay up, publish nothing)',
         read_only=True, choices=('stop', 'loop', 'hold')),
    Spec('bag.imu_topic', '/imu/data_raw', 'Imu topic in the bag', read_only=True),
    Spec('bag.temperature_topic', '/imu/temperature_raw', 'Temperature topic in the bag',
         read_only=True),
    Spec('bag.eeprom_topic', '/imu/eeprom', 'EEPROM topic in the bag', read_only=True),
    Spec('bag.supply_voltage_topic', '/imu/supply_voltage',
         'supply-voltage topic in the bag (sensor_msgs/BatteryState), replayed as '
         'imu/supply_voltage when the bag has it', read_only=True),
    Spec('bag.temperature_2_topic', '',
         "second-temperature topic in the bag, replayed as imu/temperature_2_raw ('' = none)",
         read_only=True),
    Spec('simulation.seed', 0, 'seed of the simulated chips and their noise', read_only=True,
         low=0, high=2**31 - 1),
    Spec('simulation.real_time_factor', 1.0,
         'simulated seconds per wall second (10 = ten times faster than real time)',
         read_only=True, low=0.001, high=10000.0),
    Spec('simulation.lossless', False,
         'read every sample: a driver that falls behind lets the simulated clock lag wall '
         'time instead of skipping samples as missed reads (for tests)', read_only=True),
    Spec('simulation.wait_for_subscriber', False,
         'hold the simulated clock at 0 until imu/data_raw has a subscriber (or a '
         'compensation node in the same process), so a late listener misses nothing',
         read_only=True),
    Spec('simulation.eeprom_version', 2, 'EEPROM VERSION the simulated factory writes',
         read_only=True, low=0, high=255),
    Spec('simulation.start_temperature_c', 25.0, 'chamber temperature at start',
         read_only=True, low=-60.0, high=125.0),
    Spec('simulation.cycle_temperatures_c', NoDefault('double_array'),
         'chamber temperatures to ramp through in turn (empty: constant)', read_only=True),
    Spec('simulation.ramp_c_per_min', 2.0, 'chamber ramp rate', read_only=True,
         low=0.001, high=1000.0),
    Spec('simulation.hold_s', 0.0, 'soak at each cycle temperature', read_only=True,
         low=0.0, high=1e6),
    Spec('simulation.die_time_constant_s', 0.0, 'die follows the chamber with this lag',
         read_only=True, low=0.0, high=1e5),
    Spec('simulation.rate_dps', [0.0], 'true rate in deg/s, one value or one per axis',
         read_only=True),
    Spec('simulation.supply_v', 5.0,
         'supply voltage (settable at runtime on the MLX90609: a step from the next sample)',
         low=0.0, high=10.0),
    Spec('simulation.supply_monitor_hz', 0.0,
         'MLX90609: publish the simulated supply on imu/supply_voltage (BatteryState) at this '
         'rate, on stamps of its own, as a board supply monitor would (0 = none)',
         read_only=True, low=0.0, high=1000.0),
    Spec('simulation.thermal_lag_s', 0.0, 'effect: temperature sensor lags the die',
         read_only=True, low=0.0, high=1e5),
    Spec('simulation.hysteresis_dps', 0.0, 'effect: ZRO heating/cooling branch difference',
         read_only=True, low=-100.0, high=100.0),
    Spec('simulation.zro_supply_dps_per_v', 0.0, 'effect: ZRO shift per volt off 5 V',
         read_only=True, low=-1000.0, high=1000.0),
    Spec('simulation.fault', 'none',
         'SPI fault of the simulated chips (settable at runtime; adis16130 and mpu6000: none, '
         'silent_high, silent_low)', choices=tuple(f.value for f in Fault)),
    Spec('simulation.bias_dps', 0.0, 'adis16130: bias at 25 C in deg/s', read_only=True,
         low=-1000.0, high=1000.0),
    Spec('simulation.bias_dps_per_c', 0.0,
         'adis16130: bias temperature slope in deg/s/C (mpu6000: drawn from the seed)',
         read_only=True, low=-100.0, high=100.0),
    Spec('adis16130.resolution_bits', 24, 'conversion resolution, 24 or 16 (MODE b1)',
         read_only=True, low=16, high=24),
    Spec('adis16130.verify_registers', True,
         'read the start-up registers back (read-back UNCONFIRMED on real parts)',
         read_only=True),
    Spec('adis16130.bias_procedure.average_s', 10.0, 'window of each point (the note: 10 s)',
         low=0.01, high=3600.0),
    Spec('adis16130.bias_procedure.self_heat_s', 600.0,
         'wait between the points while the part warms itself (the note: 600 s)',
         low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.settle_s', 2400.0,
         'wait before the PBC window, the rest record included (the note: 2400 s)',
         low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.pbc_s', 150.0,
         'PBC window (the note: 150 s); 0 = the averaging time the rest record advises',
         low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.allan_record_s', 1200.0,
         'rest record at the end of the settle wait for the Allan deviation (0 = none: no '
         'noise figures, motion check against rate_noise_rad_s)', low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.min_temperature_change_c', 0.5,
         'smallest T2 - T1 a BTC is computed from', low=0.001, high=100.0),
    Spec('adis16130.bias_procedure.output_file', '',
         "linear_btc parameter file ('' = ~/.ros/mlx_tempcomp/<node name>_linear_btc.yaml)"),
    Spec('adis16130.bias_procedure.node_name', 'compensation_node',
         'node section of the parameter file'),
    Spec('mpu6000.variant', 'mpu6000', 'part: MPU-6000 (or 6050 register map) or MPU-6500',
         read_only=True, choices=('mpu6000', 'mpu6500')),
    Spec('mpu6000.gyro_full_scale_dps', 250, 'gyro range: 250, 500, 1000 or 2000 deg/s',
         read_only=True, low=250, high=2000),
    Spec('mpu6000.accel_full_scale_g', 2, 'accelerometer range: 2, 4, 8 or 16 g',
         read_only=True, low=2, high=16),
    Spec('mpu6000.dlpf_config', 3, 'DLPF_CFG (CONFIG bits 2..0)', read_only=True, low=0,
         high=6),
    Spec('mpu6000.sample_rate_divider', 0, 'SMPLRT_DIV', read_only=True, low=0, high=255),
    Spec('mpu6000.accel_noise_m_s2', 0.049,
         '1-sigma accelerometer noise of one sample in m/s^2 (datasheet 400 ug/sqrt(Hz) at '
         '100 Hz: 0.005 g); sets the linear acceleration covariance (0 = unknown)',
         low=0.0, high=100.0),
    Spec('mpu6000.offsets_file', '',
         "offset register state YAML ('' = ~/.ros/mlx_tempcomp/<node name>_offsets.yaml)",
         read_only=True),
    Spec('mpu6000.calibration.duration_s', 1.0,
         'averaging window of imu/calibrate_offsets (sensor time; the note: 200 samples)',
         low=0.01, high=3600.0),
    Spec('mpu6000.calibration.noise_multiple', 3.0,
         'a gyro rate spread above this x rate_noise_rad_s means the board moves',
         low=0.1, high=1000.0),
    Spec('mpu6000.offset_model_file', '',
         'parameter file of a polynomial bias model of gyro x, y, z (mlx-tempcomp fit): '
         "refresh the gyro offset registers from it as the temperature moves ('' = off)",
         read_only=True),
    Spec('mpu6000.offset_model_node', 'compensation_node',
         'node section of mpu6000.offset_model_file', read_only=True),
    Spec('mpu6000.offset_refresh_c', 0.5,
         'rewrite the gyro offset registers when the temperature moved this much since the '
         'last write', read_only=True, low=0.001, high=100.0),
)


def _model_specs(prefix: str, parameters: dict, descriptions: dict, required: bool) -> tuple:
    """Give a Spec per key of a model's ``to_parameters``; lists become arrays."""
    specs = []
    for key, value in parameters.items():
        name, _, axis = key.partition('.')
        if isinstance(value, list):
            default = NoDefault('double_array')
        else:
            default = NoDefault('double') if required else float(value)
        specs.append(Spec(prefix + key, default, descriptions[name].format(axis=axis)))
    return tuple(specs)


# Scalars default to the model's own defaults; unset lists mean an absent effect.
EFFECT_SPECS = _model_specs(
    'effects.', EffectModel((AxisTerms(bias=(0.0,)),) * 3).to_parameters(AXIS_NAMES),
    PARAMETER_DESCRIPTIONS, required=False)
# A chain has no neutral default: every parameter must be given.
_ZEROS, _POLYNOMIALS = (0.0, 0.0, 0.0), ((0.0,),) * 3
CHAIN_SPECS = _model_specs('chain.', CalibrationChain(
    full_scale_rad_s=1.0, reference_temperature_c=25.0, reference_temperature_2_c=25.0,
    nonlinearity_rad_s=_POLYNOMIALS, offset_rad_s=_ZEROS, offset_gradient_rad_s_per_c=_ZEROS,
    sensitivity_slope_rad_s_per_c=_POLYNOMIALS, sensitivity_intercept_rad_s=_POLYNOMIALS,
    offset_2_rad_s=_ZEROS, offset_2_gradient_rad_s_per_c=_ZEROS,
    misalignment=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))).to_parameters(),
    CHAIN_DESCRIPTIONS, required=True)

COMPENSATION_SPECS = COMMON_SPECS + (
    Spec('model', 'eeprom', 'compensation model',
         choices=('eeprom', 'polynomial', 'linear_btc', 'effects', 'chain')),
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
    Spec(f'polynomial.bias.{axis}', NoDefault('double_array'),
         f'bias polynomial of axis {axis} in rad/s, lowest order first') for axis in AXIS_NAMES
) + tuple(
    Spec(f'polynomial.scale.{axis}', NoDefault('double_array'),
         f'relative scale-factor polynomial of axis {axis} (empty: none)') for axis in AXIS_NAMES
) + (
    Spec('linear_btc.pbc_rad_s', NoDefault('double_array'), 'PBC per axis, rad/s'),
    Spec('linear_btc.btc_rad_s_per_c', NoDefault('double_array'), 'BTC per axis, rad/s/C'),
    Spec('linear_btc.t3_c', 25.0, 'T3, the temperature of the PBC measurement',
         low=-100.0, high=200.0),
) + EFFECT_SPECS + CHAIN_SPECS + (
    Spec('model_error.temperature_c', NoDefault('double_array'),
         'temperatures of the model error table, strictly increasing, degC (empty: no model '
         'error; mlx-tempcomp diagnose writes it)'),
) + tuple(
    Spec(f'model_error.{axis}_rad_s', NoDefault('double_array'),
         f'axis {axis}: held-out RMS error of the model at each model_error.temperature_c, '
         'rad/s; its square, linear in T between them and held beyond, is added to '
         'rate_noise_rad_s^2 in the angular velocity covariance') for axis in AXIS_NAMES
) + (
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
    Spec('max_block', 500, 'input messages taken per wake-up at most and compensated as one '
         'block (1: one message per callback)', read_only=True, low=1, high=100000),
    Spec('supply_voltage.pairing', 'hold',
         'how a model with supply terms pairs imu/supply_voltage with the samples: hold = '
         'the latest voltage stamped at or before each sample (a battery monitor at its own '
         'rate), stamp = the voltage with the same stamp (a driver or bag that stamps it '
         'with the sample)', read_only=True, choices=('hold', 'stamp')),
    Spec('supply_voltage.max_age_s', 5.0,
         'hold: a voltage further than this from the sample stamp is not used; the sample '
         'is skipped and counted', low=0.0, high=3600.0),
) + tuple(Spec(TRACKING + p.name, p.default, p.description, low=p.low, high=p.high)
          for p in TRACKING_PARAMETERS)


# Every parameter of the package's nodes: a /** section gives both nodes all of them.
KNOWN_NAMES = frozenset(spec.name for spec in DRIVER_SPECS + COMPENSATION_SPECS)


def widen_integers(spec: Spec, value):
    """
    Give an integer (or list of integers) meant for a double parameter as float(s).

    YAML reads ``stale_timeout_s: 2`` as an integer; the nodes take it as 2.0, and so does
    every reader of their files.
    """
    if spec.value_type == 'double' and type_of(value) == 'integer':
        return float(value)
    if spec.value_type == 'double_array' and type_of(value) == 'integer_array':
        return [float(v) for v in value]
    return value


def check_value(spec: Spec, value) -> None:
    """Raise `ParameterError` unless ``value`` has the type and range rcl takes for ``spec``."""
    given = type_of(value)
    if value == [] and spec.value_type.endswith('_array'):
        given = spec.value_type
    if given != spec.value_type:
        kind = 'a mixed or unsupported value' if given is None else given
        msg = (f'invalid parameter {spec.name}: expected {spec.value_type}, got {kind} '
               f'({value!r})')
        raise ParameterError(msg)
    if spec.low is not None and not spec.low <= value <= spec.high:
        msg = (f'invalid parameter {spec.name}: {value!r} is outside {spec.low:g} to '
               f'{spec.high:g}')
        raise ParameterError(msg)


_WILDCARDS = ('/**', '**')


def flat_parameters(tree: dict, prefix: str = '') -> dict:
    """Turn ``{'a': {'b': v}}`` into ``{'a.b': v}``: the names rcl gives a file's keys."""
    flat = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(flat_parameters(value, name + '.'))
        else:
            flat[name] = value
    return flat


def _read_overrides(path: str, node_name: str) -> dict:
    """Give the flat parameters of ``node_name`` in a ROS 2 parameter file (wildcards first)."""
    try:
        with open(path, encoding='utf-8') as stream:
            document = yaml.safe_load(stream)
    except OSError as err:
        msg = f'cannot read parameter file {path}: {err.strerror}'
        raise ParameterError(msg) from None
    except (yaml.YAMLError, ValueError, RecursionError) as err:
        # ValueError: not UTF-8, or a value YAML's constructors refuse (2026-13-45, !!int a).
        mark = getattr(err, 'problem_mark', None)
        where = f' (line {mark.line + 1})' if mark is not None else ''
        problem = getattr(err, 'problem', None) or str(err).split('\n')[0] or type(err).__name__
        msg = f'parameter file {path} is not YAML{where}: {problem}'
        raise ParameterError(msg) from None
    if not isinstance(document, dict):
        msg = f'parameter file {path} is not a mapping of node sections'
        raise ParameterError(msg)
    names = [key for key in _WILDCARDS if key in document] + \
        [key for key in (node_name, '/' + node_name.lstrip('/')) if key in document]
    if not names:
        sections = ', '.join(repr(str(key)) for key in document) or 'none'
        msg = f'parameter file {path} has no section for node {node_name!r} (sections: ' \
              f'{sections}); see --node-name'
        raise ParameterError(msg)
    overrides = {}
    for name in names:
        section = document[name]
        parameters = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(parameters, dict):
            msg = f'parameter file {path}: section {name!r} has no ros__parameters mapping'
            raise ParameterError(msg)
        overrides.update(flat_parameters(parameters))
    return overrides


def node_values(path: str, node_name: str) -> dict:
    """
    Give every compensation-node parameter value with ``node_name``'s section of a file.

    The node's defaults, overridden by the file's ``/**`` and ``node_name`` sections,
    type and range checked as rcl checks them, then the choices. Raise `ParameterError`
    (the message starts with ``path``) where the node would refuse to start.
    """
    overrides = _read_overrides(path, node_name)
    values = {}
    for spec in COMPENSATION_SPECS:
        if spec.name not in overrides:
            values[spec.name] = spec.initial_value
            continue
        value = widen_integers(spec, overrides[spec.name])
        try:
            check_value(spec, value)
        except ParameterError as err:
            raise ParameterError(f'{path}: {err}') from None
        values[spec.name] = value
    try:
        check_choices(COMPENSATION_SPECS, values)
    except ParameterError as err:
        raise ParameterError(f'{path}: {err}') from None
    return values


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


def model_error_of(values: dict) -> Optional[ModelErrorTable]:
    """
    Build the model error table of the measured axes; None when model_error.* is unset.

    Raise `ParameterError` naming the parameter when the table is given in part
    or is not a table (temperatures not increasing, lengths that differ).
    """
    axes = axes_of(values)
    temperature = values['model_error.temperature_c']
    errors = [values[f'model_error.{axis}_rad_s'] for axis in axes]
    if not temperature and not any(errors):
        return None
    if not temperature:
        given = next(axis for axis, values in zip(axes, errors) if values)
        msg = (f'invalid parameter model_error.temperature_c: unset, but '
               f'model_error.{given}_rad_s is given; the table needs its temperatures')
        raise ParameterError(msg)
    try:
        table_temperatures(temperature)
    except ConfigError as err:
        raise ParameterError(f'invalid parameter model_error.temperature_c: {err}') from None
    for axis, column in zip(axes, errors):
        if len(column) != len(temperature):
            msg = (f'invalid parameter model_error.{axis}_rad_s: needs {len(temperature)} '
                   f'values (one per model_error.temperature_c), got {len(column)}')
            raise ParameterError(msg)
        if not all(math.isfinite(v) and v >= 0.0 for v in column):
            msg = (f'invalid parameter model_error.{axis}_rad_s: an error must be finite and '
                   f'>= 0, got {list(column)}')
            raise ParameterError(msg)
    return ModelErrorTable(tuple(temperature), tuple(tuple(column) for column in errors))


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
    EEPROM has not arrived: the eeprom model is then None). A model whose
    output over what a gyro gives is not finite or not plausible is refused
    (`_check_output`).
    """
    model = _build_model(values, tables, full_scale_dps)
    if model is not None:
        _check_output(model, values['model'], axes_of(values))
    return model


# A model is probed before it runs: rates of -1, 0 and 1 rad/s (any gyro's range), die
# temperatures -40 to 125 C rising 0.05 C/s (every extra input given). Coefficients that
# overflow there, or put the compensated rate beyond ten times +-2000 deg/s (the widest range
# of the parts the driver reads), are a typo or a unit mix-up, never a gyro.
_PROBE_RATE, _PROBE_TEMPERATURE = (a.reshape(-1) for a in np.meshgrid(
    [-1.0, 0.0, 1.0], np.arange(-40.0, 125.5, 0.5)))
_PROBE_TIME_S = 10.0 * np.arange(_PROBE_RATE.size)
MAX_COMPENSATED_RATE_RAD_S = 10.0 * math.radians(2000.0)


def _check_output(model, name: str, axes: tuple) -> None:
    samples = _PROBE_RATE.size
    with np.errstate(all='ignore'):
        corrected = model.stream().correct_block(
            np.repeat(_PROBE_RATE[:, None], model.axes, axis=1), _PROBE_TEMPERATURE, ModelInputs(
                time_s=getattr(model, 'time_reference_s', 0.0) + _PROBE_TIME_S,
                temperature_2_c=_PROBE_TEMPERATURE,
                acceleration_m_s2=np.tile([0.0, 0.0, 9.81], (samples, 1)),
                supply_voltage_v=np.full(samples, 5.0))).rate_rad_s
    beyond = ~(np.abs(corrected) <= MAX_COMPENSATED_RATE_RAD_S)   # NaN included
    if beyond.any():
        row, axis = np.argwhere(beyond)[0]
        msg = (f'invalid {name} model parameters: axis {axes[axis]} gives '
               f'{corrected[row, axis]:.4g} rad/s at {_PROBE_TEMPERATURE[row]:g} C and a raw '
               f'rate of {_PROBE_RATE[row]:g} rad/s, beyond +-{MAX_COMPENSATED_RATE_RAD_S:.4g} '
               'rad/s; check the coefficients and their units')
        raise ParameterError(msg)


def _build_model(values: dict, tables: Optional[tuple], full_scale_dps: float):
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
            return polynomial_model(
                tuple(bias), reference_temperature_c=values['polynomial.reference_temperature_c'],
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
            return LinearBtc(pbc_rad_s=tuple(pbc), btc_rad_s_per_c=tuple(btc),
                             t3_c=values['linear_btc.t3_c']).model()
        if name == 'effects':
            return _effect_model(values, axes)
        if name == 'chain':
            return _chain_model(values, axes)
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


def _model_parameters(values: dict, prefix: str, specs) -> dict:
    """Give a model's parameters without ``prefix``; unset ones are left out."""
    return {spec.name[len(prefix):]: values[spec.name] for spec in specs
            if values[spec.name] != []}


def _effect_model(values: dict, axes: tuple) -> EffectModel:
    for axis in axes:
        if not values[f'effects.bias.{axis}']:
            msg = (f'invalid parameter effects.bias.{axis}: the effects model needs a bias '
                   f'polynomial for every axis in {list(axes)}')
            raise ParameterError(msg)
    return EffectModel.from_parameters(_model_parameters(values, 'effects.', EFFECT_SPECS), axes)


def _chain_model(values: dict, axes: tuple) -> ChainModel:
    if axes != AXIS_NAMES:
        msg = f"invalid parameter axes: the chain model needs ['x', 'y', 'z'], got {list(axes)}"
        raise ParameterError(msg)
    missing = [spec.name for spec in CHAIN_SPECS if values[spec.name] == []]
    if missing:
        msg = (f'invalid parameter {missing[0]}: unset; the chain model needs every chain.* '
               f'parameter ({len(missing)} unset)')
        raise ParameterError(msg)
    return ChainModel(CalibrationChain.from_parameters(
        _model_parameters(values, 'chain.', CHAIN_SPECS)))
