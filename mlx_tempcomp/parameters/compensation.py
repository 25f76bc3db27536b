"""
The compensation node's parameters: its specs, and the settings read from their values.

`COMPENSATION_SPECS` are the parameters both nodes share (`specs.COMMON_SPECS`),
``model`` and each model's own (`models.MODELS`, in that order), the correction
table any model may carry (`models.CORRECTION_SPECS`), the model error table,
the ZRO recalibration, the inputs, and the bias tracking
(``bias_tracking.*``, `tracking.TRACKING_SPECS`) with its field learning
(``learning.*``, `learning.LEARNING_SPECS`). `model_error_of` and
`covariance_noise_of` read the settings the node and the toolkit build from the
values, raising `ParameterError` naming the parameter.

`compensation_settings` gives the node's settings of its values, `CompensationSettings`:
frozen, typed, one section per group of parameters (``temperature.*``,
``supply_voltage.*``, ``recalibration.*``, ``bias_tracking.*`` with the core's
`TrackingSettings`, ``learning.*`` as `learning.FieldLearning`), the model error table
and the covariance's noise, each checked by the builder the toolkit shares
(`model_error_of`, `tracking.tracking_settings`, `learning.field_learning`);
`ParameterError` names the parameter. The model's own parameters are not in it: the
node builds the model from the values (`models.build_model`), as ``evaluate`` does.
"""

from dataclasses import dataclass, replace
import math
import os
from typing import Optional

from .learning import field_learning, FieldLearning, LEARNING_SPECS, PREFIX as LEARNING
from .models import correction_of, CORRECTION_SPECS, MODELS
from .specs import (axes_of, COMMON_SPECS, NoDefault, ParameterError, sensor_of, SensorSettings,
                    Spec)
from .state_paths import state_path
from .tracking import PREFIX as TRACKING, tracking_settings, TRACKING_SPECS, UNIT_SPECS
from ..core.errors import ConfigError
from ..core.node_models import AXIS_NAMES, ModelErrorTable, table_temperatures
from ..core.standstill import RecalibrationLimits, TrackingSettings

# The node's own learning parameter (fit and diagnose do not write it).
LEARNED_MODEL_FILE = LEARNING + 'learned_model_file'

COMPENSATION_SPECS = COMMON_SPECS + (
    Spec('model', 'eeprom', 'compensation model', choices=tuple(MODELS)),
) + tuple(spec for kind in MODELS.values() for spec in kind.specs) \
    + CORRECTION_SPECS + (
    Spec('model_error.temperature_c', NoDefault('double_array'),
         'temperatures of the model error table, strictly increasing, degC (empty: no model '
         'error; mlx-tempcomp diagnose and fit write it)'),
    Spec('model_error.rate_noise_rad_s', NoDefault('double_array'),
         'white noise of one sample per axis (in the order of axes), rad/s: in the angular '
         'velocity covariance it takes the place of rate_noise_rad_s (empty: rate_noise_rad_s '
         'for every axis; mlx-tempcomp diagnose and fit write it, measured on the record)'),
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
         "ZRO and bias tracking state YAML ('' = $ROS_HOME/mlx_tempcomp/<namespace>/<node "
         'name>_zro.yaml, ROS_HOME defaulting to ~/.ros)', read_only=True),
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
    Spec('temperature.pairing', 'hold',
         'how imu/temperature_raw (and a second temperature) pairs with the Imu samples: '
         'hold = the latest reading stamped at or before each sample, at once (a driver that '
         'rates and stamps its temperature its own way; one that stamps both alike is paired '
         'exactly); interpolate = linear between the readings before and after, which waits '
         'for the one after; stamp = the reading with the same stamp only; none = the driver '
         'sends no temperature: the rate only, less the tracked offset',
         read_only=True, choices=('hold', 'interpolate', 'stamp', 'none')),
    Spec('temperature.max_age_s', 2.0,
         'hold, interpolate: a reading further than this from the sample stamp is not used; '
         'the sample is skipped and counted (a sample waits at most this long, in sensor '
         'time, for a reading)', read_only=True, low=0.0, high=3600.0),
    Spec('temperature.wait_s', 5.0,
         'Imu samples with no temperature at all this long after the first one (sensor '
         'time; ten times as long while a publisher of the temperature topic is matched) go '
         'on with the rate only, less the tracked offset, until a temperature comes',
         read_only=True, low=0.0, high=3600.0),
    Spec('rate_only.offset_std_rad_s', math.radians(1.0),
         'with the rate only (no temperature, or no factory tables for the eeprom model): '
         "the raw rate offset's standard deviation before the tracking learns it, and the "
         'most it grows to; its square goes into the Imu covariance', low=0.0, high=10.0),
) + TRACKING_SPECS + tuple(
    # Read at start: switched at run time, the tracked offset would need re-expressing.
    replace(spec, read_only=True) for spec in LEARNING_SPECS) + (
    # The node's own: where imu/save_learned_model writes the model in use.
    Spec(LEARNED_MODEL_FILE, '',
         "imu/save_learned_model writes the model in use here, a parameter file ('' = "
         '<node name>_learned.yaml beside the state file)', read_only=True),
)


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


def covariance_noise_of(values: dict) -> tuple:
    """
    Give the white noise of one sample per measured axis the covariance takes, rad/s.

    ``model_error.rate_noise_rad_s`` when given (one per axis), else
    ``rate_noise_rad_s`` for every axis; `ParameterError` naming the
    parameter when it is not one finite figure >= 0 per axis.
    """
    axes = axes_of(values)
    given = values['model_error.rate_noise_rad_s']
    if not given:
        return (values['rate_noise_rad_s'],) * len(axes)
    if len(given) != len(axes) or not all(math.isfinite(v) and v >= 0.0 for v in given):
        msg = (f'invalid parameter model_error.rate_noise_rad_s: needs one finite noise >= 0 '
               f'per axis ({len(axes)}: {", ".join(axes)}), got {list(given)}')
        raise ParameterError(msg)
    return tuple(float(v) for v in given)


def unit_values(values: dict) -> dict:
    """
    Give the node's values that describe the unit's model, as ``fit`` writes them (flat).

    ``model``, ``axes``, the running model's own parameters, ``correction.*``,
    ``model_error.*``, ``rate_noise_rad_s``, the unit's ``bias_tracking.*`` and
    ``learning.*`` (not the node's own: state files, topics, periods); unset ones left out.
    """
    prefixes = (MODELS[values['model']].prefix, 'correction.', 'model_error.')
    unit = {'model', 'axes', 'rate_noise_rad_s'} | \
        {spec.name for spec in UNIT_SPECS + LEARNING_SPECS}
    return {key: value for key, value in values.items()
            if (key in unit or key.startswith(prefixes)) and value != []}


@dataclass(frozen=True)
class TemperatureSettings:
    """``temperature.*``: how the temperature pairs with the samples, and how long it waits."""

    pairing: str                 # hold, interpolate, stamp or none
    max_age_s: float
    wait_s: float


@dataclass(frozen=True)
class SupplyVoltageSettings:
    """``supply_voltage.*``: how the supply voltage pairs with the samples."""

    pairing: str                 # hold or stamp
    max_age_s: float


@dataclass(frozen=True)
class RecalibrationSettings:
    """``recalibration.*``: the ZRO recalibration's window, its rest limits, the state file."""

    duration_s: float
    noise_multiple: float
    max_mean_rate_rad_s: float
    max_temperature_change_c: float
    state_file: str              # '' = under ROS_HOME (`state_file_of`)


@dataclass(frozen=True)
class RestHintSettings:
    """``bias_tracking.rest_hint_*`` but its age: the robot's word that it stands still."""

    topic: str                   # '' = none
    message_type: str
    max_linear_m_s: float
    max_angular_rad_s: float


@dataclass(frozen=True)
class BiasTrackingSettings:
    """``bias_tracking.*``: the tracker's settings (None: off) and what the node adds."""

    tracker: Optional[TrackingSettings]
    zero_at_start: bool
    save_period_s: float
    rest_hint: RestHintSettings


@dataclass(frozen=True)
class CompensationSettings:
    """The compensation node's parameters, checked, but the model's own (`build_model`)."""

    axes: tuple
    sensor: SensorSettings
    rate_noise_rad_s: float
    model: str
    eeprom_wait_s: float
    model_error: Optional[ModelErrorTable]
    covariance_noise_rad_s: tuple        # per axis (`covariance_noise_of`)
    recalibration: RecalibrationSettings
    stale_timeout_s: float
    max_block: int
    supply_voltage: SupplyVoltageSettings
    temperature: TemperatureSettings
    rate_only_offset_std_rad_s: float
    tracking: BiasTrackingSettings
    learning: Optional[FieldLearning]    # None: learning.enabled false
    learned_model_file: str              # '' = beside the state file (`learned_model_file_of`)

    def recalibration_limits(self) -> RecalibrationLimits:
        """Give when a recalibration window is at rest; `ParameterError` without a noise figure."""
        if self.rate_noise_rad_s <= 0.0:
            msg = ('invalid parameter rate_noise_rad_s: recalibration needs a positive noise '
                   'figure')
            raise ParameterError(msg)
        given = self.recalibration
        return RecalibrationLimits(
            rate_noise_rad_s=self.rate_noise_rad_s, noise_multiple=given.noise_multiple,
            max_mean_rate_rad_s=given.max_mean_rate_rad_s,
            max_temperature_change_c=given.max_temperature_change_c)


def compensation_settings(values: dict) -> CompensationSettings:
    """
    Give the node's settings of its parameter values; `ParameterError` names what is wrong.

    The values are those `ros.declare.declare` gives (types, ranges and choices checked).
    The field learning's are checked while it is on, whether tracking runs or not
    (``bias_tracking.enabled`` may change at run time, ``learning.*`` may not); its knots
    unless the model carries a correction table, whose knots the learnt one takes.
    """
    axes = axes_of(values)
    model_error = model_error_of(values)
    try:
        tracker = tracking_settings(values, axes, values['rate_noise_rad_s'])
        learning = field_learning(values, len(axes), knots=correction_of(values) is None) \
            if values[LEARNING + 'enabled'] else None
    except ConfigError as err:
        raise ParameterError(str(err)) from None
    return CompensationSettings(
        axes=axes, sensor=sensor_of(values), rate_noise_rad_s=values['rate_noise_rad_s'],
        model=values['model'], eeprom_wait_s=values['eeprom.wait_s'], model_error=model_error,
        covariance_noise_rad_s=covariance_noise_of(values),
        recalibration=RecalibrationSettings(
            duration_s=values['recalibration.duration_s'],
            noise_multiple=values['recalibration.noise_multiple'],
            max_mean_rate_rad_s=values['recalibration.max_mean_rate_rad_s'],
            max_temperature_change_c=values['recalibration.max_temperature_change_c'],
            state_file=values['recalibration.state_file']),
        stale_timeout_s=values['stale_timeout_s'], max_block=values['max_block'],
        supply_voltage=SupplyVoltageSettings(values['supply_voltage.pairing'],
                                             values['supply_voltage.max_age_s']),
        temperature=TemperatureSettings(values['temperature.pairing'],
                                        values['temperature.max_age_s'],
                                        values['temperature.wait_s']),
        rate_only_offset_std_rad_s=values['rate_only.offset_std_rad_s'],
        tracking=BiasTrackingSettings(
            tracker=tracker, zero_at_start=values[TRACKING + 'zero_at_start'],
            save_period_s=values[TRACKING + 'save_period_s'],
            rest_hint=RestHintSettings(
                topic=values[TRACKING + 'rest_hint_topic'],
                message_type=values[TRACKING + 'rest_hint_type'],
                max_linear_m_s=values[TRACKING + 'rest_hint_max_linear_m_s'],
                max_angular_rad_s=values[TRACKING + 'rest_hint_max_angular_rad_s'])),
        learning=learning, learned_model_file=values[LEARNED_MODEL_FILE])


def state_file_of(settings: CompensationSettings, fully_qualified_name: str, log) -> str:
    """Give the node's state file: the parameter, else its default (`state_paths.state_path`)."""
    return state_path(settings.recalibration.state_file, fully_qualified_name, '_zro.yaml', log)


def learned_model_file_of(settings: CompensationSettings, state_file: str,
                          node_name: str) -> str:
    """Give where imu/save_learned_model writes: the parameter, else beside the state file."""
    path = settings.learned_model_file
    if not path:
        path = os.path.join(os.path.dirname(os.path.abspath(state_file)),
                            f'{node_name}_learned.yaml')
    return os.path.expanduser(path)
