"""
The parameter type of the nodes, its checks, and the parameters both nodes have.

Each parameter is a `Spec`: name, default, description, range, choices, and
its type as rcl names it (``double``, ``string_array``, ...). rclpy enforces
type and range from the descriptors ``ros/declare.py`` makes of the specs; the
checks here say the same for values read from a parameter file without a node
(`parameters.files.node_values`), and what a descriptor cannot say (choices)
for both. They raise `ParameterError` naming the parameter. Nothing here
imports rclpy: the toolkit runs without ROS.
"""

from dataclasses import dataclass
from typing import Any, Optional

from ..core.mlx90609 import SensorTransfer
from ..core.node_models import AXIS_NAMES
from ..errors import MlxTempCompError


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

# The parameters both nodes have.
COMMON_SPECS = SENSOR_SPECS + (
    Spec('axes', ['z'], "Imu axes the gyro measures, e.g. ['z'] or ['x', 'y', 'z'] (quoted)",
         read_only=True),
    Spec('rate_noise_rad_s', 0.0058,
         '1-sigma rate noise of one sample in rad/s; sets the angular velocity covariance '
         '(0 = unknown)', low=0.0, high=10.0),
)


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
    """Give the nominal transfer of ``sensor.*`` (full scale aside)."""
    return SensorTransfer(
        nominal_zro_mv=values['sensor.nominal_zro_mv'],
        output_swing_mv=values['sensor.output_swing_mv'],
        temperature_sensor_mv_at_25c=values['sensor.temperature_sensor_mv_at_25c'],
        temperature_sensor_mv_per_k=values['sensor.temperature_sensor_mv_per_k'],
        temperature_mv_per_lsb=values['sensor.temperature_mv_per_lsb'],
        temperature_offset_mv=values['sensor.temperature_offset_mv'])


@dataclass(frozen=True)
class SensorSettings:
    """The ``sensor.*`` parameters: the full scale (0 = the EEPROM's RANGE) and the transfer."""

    full_scale_dps: float
    transfer: SensorTransfer


def sensor_of(values: dict) -> SensorSettings:
    return SensorSettings(values['sensor.full_scale_dps'], transfer_of(values))
