"""
Bias effects beyond a temperature polynomial, and `EffectModel`, the model that runs them.

`mlx-tempcomp diagnose` adds these effects one by one; the compensation node
runs the result sample by sample through `EffectModel.stream`, which gives
the same numbers as the batch `EffectModel.correct` (to rounding). Each
effect, its formula and its bias term are one entry of the table
`EFFECTS`; the model, the diagnosis and the node parameters read it.

The package, by module, each importing only those above it: `history` (the
history operators: temperature slope, first-order lag, play operator, in a
batch and one sample at a time), `table` (`Effect`, `EFFECTS` and the names
derived from it, the bias terms and the arithmetic they share between a
block and a row), `stream` (`EffectStream`, the node's runner), `model`
(`AxisTerms`, `EffectModel`, its node parameters, the ``polynomial`` and
``linear_btc`` models). What callers use is here.
"""

from .history import (DEFAULT_RATE_WINDOW_S, FirstOrderLag, play_state, PlayOperator,
                      temperature_rate_c_s, TemperatureSlope)
from .model import (AxisTerms, DEFAULT_SUPPLY_REFERENCE_V, EffectModel, LinearBtc,
                    MAX_GRADIENT_TERMS, MODEL_NAMES, polynomial_model)
from .stream import EffectStream
from .table import (Effect, EFFECT_NAMES, EFFECTS, LIVE_EFFECTS, PARAMETER_DESCRIPTIONS,
                    RECORD_EFFECTS, SLOPE_EFFECTS)

__all__ = ['AxisTerms', 'DEFAULT_RATE_WINDOW_S', 'DEFAULT_SUPPLY_REFERENCE_V', 'Effect',
           'EFFECT_NAMES', 'EffectModel', 'EFFECTS', 'EffectStream', 'FirstOrderLag',
           'LinearBtc', 'LIVE_EFFECTS', 'MAX_GRADIENT_TERMS', 'MODEL_NAMES',
           'PARAMETER_DESCRIPTIONS', 'play_state', 'PlayOperator', 'polynomial_model',
           'RECORD_EFFECTS', 'SLOPE_EFFECTS', 'temperature_rate_c_s', 'TemperatureSlope']
