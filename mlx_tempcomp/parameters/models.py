"""
The models the compensation node runs, by the name its ``model`` parameter gives.

`MODELS` is their table: per name, a `ModelKind` with the prefix of the
model's parameters (``polynomial.``, ...), their specs and the function that
builds the model from the node's parameter values. `build_model` builds the
model named and probes it before it runs (`check_output`). A model added to
the package is a row here: its specs join the compensation node's (in this
order), its name the choices of ``model``, its prefix the parameters whose
change rebuilds the model. Any model may carry a learned correction table
(``correction.*``, `CORRECTION_SPECS`, `correction_of`): `build_model` then gives
the `CorrectedModel` of the model less the table.
"""

from dataclasses import dataclass
import math
from types import MappingProxyType
from typing import Callable, Optional

import numpy as np

from .specs import axes_of, NoDefault, ParameterError, Spec, transfer_of
from ..core.effects import (AxisTerms, EffectModel, LinearBtc, PARAMETER_DESCRIPTIONS,
                            polynomial_model)
from ..core.errors import ConfigError
from ..core.mlx90609 import Interpolation, Output, table_compensation
from ..core.node_models import (AXIS_NAMES, CalibrationChain, ChainModel, CorrectedModel,
                                CorrectionTable, EepromModel, ModelInputs,
                                PARAMETER_DESCRIPTIONS as CHAIN_DESCRIPTIONS)


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


EEPROM_SPECS = (
    Spec('eeprom.interpolation', 'quadratic', 'interpolation of the factory table',
         choices=tuple(m.value for m in Interpolation)),
    Spec('eeprom.wait_s', 5.0,
         'the eeprom model waits this long (sensor time from the first Imu sample) for the '
         'factory tables on imu/eeprom, which only an MLX90609 driver sends; then the rate '
         'only, less the tracked offset, until they come', read_only=True, low=0.0,
         high=3600.0),
)
POLYNOMIAL_SPECS = (
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
)
LINEAR_BTC_SPECS = (
    Spec('linear_btc.pbc_rad_s', NoDefault('double_array'), 'PBC per axis, rad/s'),
    Spec('linear_btc.btc_rad_s_per_c', NoDefault('double_array'), 'BTC per axis, rad/s/C'),
    Spec('linear_btc.t3_c', 25.0, 'T3, the temperature of the PBC measurement',
         low=-100.0, high=200.0),
)
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


def _eeprom_model(values: dict, axes: tuple, tables: Optional[tuple],
                  full_scale_dps: float) -> Optional[EepromModel]:
    interpolation = Interpolation.parse(values['eeprom.interpolation'])
    if tables is None:
        return None
    if len(tables) != len(axes):
        msg = f'the sensor sent {len(tables)} EEPROM tables but axes has {len(axes)} entries'
        raise ParameterError(msg)
    transfer = transfer_of(values)
    compensation = table_compensation(tables, full_scale_dps, Output.DIGITAL, interpolation,
                                      transfer)
    return EepromModel(compensation=compensation, transfer=transfer)


def _polynomial_model(values: dict, axes: tuple, tables, full_scale_dps) -> EffectModel:
    bias = []
    for axis in axes:
        coefficients = values[f'polynomial.bias.{axis}']
        if not coefficients:
            msg = (f'invalid parameter polynomial.bias.{axis}: the polynomial model needs '
                   f'coefficients for every axis in {list(axes)}')
            raise ParameterError(msg)
        bias.append(coefficients)
    scale = [values[f'polynomial.scale.{axis}'] for axis in axes]
    if any(scale) and not all(scale):
        msg = ('invalid parameter polynomial.scale: give a scale polynomial for every axis or '
               'for none')
        raise ParameterError(msg)
    return polynomial_model(
        tuple(bias), reference_temperature_c=values['polynomial.reference_temperature_c'],
        temperature_scale_c=values['polynomial.temperature_scale_c'],
        scale_coefficients=tuple(scale) if all(scale) else (),
        temperature_min_c=values['polynomial.temperature_min_c'],
        temperature_max_c=values['polynomial.temperature_max_c'])


def _linear_btc_model(values: dict, axes: tuple, tables, full_scale_dps) -> EffectModel:
    pbc, btc = values['linear_btc.pbc_rad_s'], values['linear_btc.btc_rad_s_per_c']
    for key, array in (('linear_btc.pbc_rad_s', pbc), ('linear_btc.btc_rad_s_per_c', btc)):
        if len(array) != len(axes):
            msg = (f'invalid parameter {key}: needs {len(axes)} values (one per axis in '
                   f'{list(axes)}), got {len(array)}')
            raise ParameterError(msg)
    return LinearBtc(pbc_rad_s=tuple(pbc), btc_rad_s_per_c=tuple(btc),
                     t3_c=values['linear_btc.t3_c']).model()


def _model_parameters(values: dict, prefix: str, specs) -> dict:
    """Give a model's parameters without ``prefix``; unset ones are left out."""
    return {spec.name[len(prefix):]: values[spec.name] for spec in specs
            if values[spec.name] != []}


def _effect_model(values: dict, axes: tuple, tables, full_scale_dps) -> EffectModel:
    for axis in axes:
        if not values[f'effects.bias.{axis}']:
            msg = (f'invalid parameter effects.bias.{axis}: the effects model needs a bias '
                   f'polynomial for every axis in {list(axes)}')
            raise ParameterError(msg)
    return EffectModel.from_parameters(_model_parameters(values, 'effects.', EFFECT_SPECS), axes)


def _chain_model(values: dict, axes: tuple, tables, full_scale_dps) -> ChainModel:
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


@dataclass(frozen=True)
class ModelKind:
    """
    A model the node runs: its parameters and how it is built from them.

    ``build(values, axes, tables, full_scale_dps)`` gives the model from the
    node's parameter values and measured axes; ``tables`` and
    ``full_scale_dps`` are the factory tables of the sensor's EEPROM, which
    only the eeprom model takes (None while they have not arrived: the model
    is then None).
    """

    prefix: str
    specs: tuple
    build: Callable


MODELS = MappingProxyType({
    'eeprom': ModelKind('eeprom.', EEPROM_SPECS, _eeprom_model),
    'polynomial': ModelKind('polynomial.', POLYNOMIAL_SPECS, _polynomial_model),
    'linear_btc': ModelKind('linear_btc.', LINEAR_BTC_SPECS, _linear_btc_model),
    'effects': ModelKind('effects.', EFFECT_SPECS, _effect_model),
    'chain': ModelKind('chain.', CHAIN_SPECS, _chain_model),
})
CORRECTION_PREFIX = 'correction.'
CORRECTION_SPECS = (
    Spec('correction.temperature_c', NoDefault('double_array'),
         'knots of the correction table taken off after any model (mlx-tempcomp evaluate '
         '--learned-params writes it), strictly increasing, degC (empty: none)'),
) + tuple(
    Spec(f'correction.{axis}_rad_s', NoDefault('double_array'),
         f'axis {axis}: correction at each correction.temperature_c, rad/s; cubic between '
         'them (Catmull-Rom), held beyond the ends') for axis in AXIS_NAMES
)
# Parameters whose change rebuilds the model: ``model`` and those under these prefixes.
MODEL_PREFIXES = tuple(kind.prefix for kind in MODELS.values()) + (CORRECTION_PREFIX,)


def correction_of(values: dict) -> Optional[CorrectionTable]:
    """
    Give the correction table of the measured axes; None when ``correction.*`` is unset.

    Raise `ParameterError` naming the parameter when it is given in part or is not a
    table (temperatures not increasing, lengths that differ, values not finite).
    """
    axes = axes_of(values)
    temperature = values['correction.temperature_c']
    columns = [values[f'correction.{axis}_rad_s'] for axis in axes]
    if not temperature and not any(columns):
        return None
    missing = [axis for axis, column in zip(axes, columns) if not column]
    if not temperature or missing:
        name = 'temperature_c' if not temperature else f'{missing[0]}_rad_s'
        msg = (f'invalid parameter correction.{name}: unset, but the correction table of '
               f'axes {list(axes)} is given in part; give its temperatures and every axis')
        raise ParameterError(msg)
    for axis, column in zip(axes, columns):
        if len(column) != len(temperature):
            msg = (f'invalid parameter correction.{axis}_rad_s: needs {len(temperature)} values '
                   f'(one per correction.temperature_c), got {len(column)}')
            raise ParameterError(msg)
    try:
        return CorrectionTable(tuple(temperature), tuple(tuple(c) for c in columns))
    except ConfigError as err:
        raise ParameterError(f'invalid parameter correction: {err}') from None


def build_model(values: dict, tables: Optional[tuple] = None, full_scale_dps: float = 0.0):
    """
    Build the model named by ``model`` from parameter values.

    ``tables`` are the factory tables from the sensor's EEPROM and
    ``full_scale_dps`` the full scale they were decoded with (None while the
    EEPROM has not arrived: the eeprom model is then None). A model whose
    output over what a gyro gives is not finite or not plausible is refused
    (`check_output`).
    """
    axes = axes_of(values)
    name = values['model']
    if name not in MODELS:
        msg = f'invalid parameter model: {name!r} is not one of {", ".join(MODELS)}'
        raise ParameterError(msg)
    try:
        model = MODELS[name].build(values, axes, tables, full_scale_dps)
    except ConfigError as err:
        msg = f'invalid {name} model parameters: {err}'
        raise ParameterError(msg) from None
    table = correction_of(values)
    if model is not None and table is not None:
        model = CorrectedModel(model, table)
    if model is not None:
        check_output(model, name, axes)
    return model


# A model is probed before it runs: rates of -1, 0 and 1 rad/s (any gyro's range), die
# temperatures -40 to 125 C rising 0.05 C/s (every extra input given). Coefficients that
# overflow there, or put the compensated rate beyond ten times +-2000 deg/s (the widest range
# of the parts the driver reads), are a typo or a unit mix-up, never a gyro.
_PROBE_RATE, _PROBE_TEMPERATURE = (a.reshape(-1) for a in np.meshgrid(
    [-1.0, 0.0, 1.0], np.arange(-40.0, 125.5, 0.5)))
_PROBE_TIME_S = 10.0 * np.arange(_PROBE_RATE.size)
MAX_COMPENSATED_RATE_RAD_S = 10.0 * math.radians(2000.0)


def check_output(model, name: str, axes: tuple) -> None:
    """Raise `ParameterError` if ``model`` gives a rate no gyro gives over the probe."""
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
