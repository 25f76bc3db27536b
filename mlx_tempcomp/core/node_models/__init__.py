"""
The models the compensation node runs, beside the effect model (`core.effects`).

The package, by module, each importing only those above it: `interface` (what every model
offers the node and the toolkit, `CompensationModel`, and the inputs beyond rate and
temperature it may need, `ModelInputs`), `rate_models` (the EEPROM table's model and the
ZRO offset on top of any model, the rate alone without a temperature; the fingerprint
a state file keys on), `model_error` (the model's own error by temperature, which the node
adds to its covariance), `correction` (a bias table in temperature taken off after any
model: what the field learner renews), `chain` (the rate-table calibration chain of the
SwissFEL teslameter paper). The node builds each by name (`parameters.models.MODELS`).
"""

from .chain import (apply_nonlinearity, apply_offset, apply_sensitivity, CalibrationChain,
                    ChainModel, checked_column, checked_rates, finite, PARAMETER_DESCRIPTIONS,
                    polyfit, polyval, STAGE_NAMES)
from .correction import CorrectedModel, CorrectionTable, knot_weights
from .interface import CorrectedRate, INPUTS, ModelInputs, NO_INPUTS
from .model_error import (bias_rms_rad_s, larger_table, ModelErrorTable, normalised_error,
                          NormalisedError, sample_noise_rad_s, StillWindows, table_temperatures)
from .rate_models import (AXIS_NAMES, EepromModel, finite_tuple, model_fingerprint, OffsetModel,
                          one_row, rate_temperature_columns, RateOnlyModel)

__all__ = ['apply_nonlinearity', 'apply_offset', 'apply_sensitivity', 'AXIS_NAMES',
           'bias_rms_rad_s', 'CalibrationChain', 'ChainModel', 'checked_column', 'checked_rates',
           'CorrectedModel', 'CorrectedRate', 'CorrectionTable', 'EepromModel', 'finite',
           'finite_tuple', 'INPUTS', 'knot_weights', 'larger_table', 'model_fingerprint',
           'ModelErrorTable', 'ModelInputs', 'NO_INPUTS', 'normalised_error', 'NormalisedError',
           'OffsetModel', 'one_row', 'PARAMETER_DESCRIPTIONS', 'polyfit', 'polyval',
           'rate_temperature_columns', 'RateOnlyModel', 'sample_noise_rad_s', 'STAGE_NAMES',
           'StillWindows', 'table_temperatures']
