"""
Bias effects beyond a temperature polynomial, and `EffectModel`, the model that runs them.

The package, by module: `history` (the history operators), `table` (the
effects and their bias terms), `model` (`AxisTerms`, `EffectModel`, the
``polynomial`` and ``linear_btc`` models, the stream). What callers use is
here.
"""

from .history import (DEFAULT_RATE_WINDOW_S, FirstOrderLag, play_state, PlayOperator,
                      temperature_rate_c_s, TemperatureSlope)
from .model import (AxisTerms, DEFAULT_SUPPLY_REFERENCE_V, EffectModel, EffectStream, LinearBtc,
                    MAX_GRADIENT_TERMS, MODEL_NAMES, polynomial_model)
from .table import (Effect, EFFECT_NAMES, EFFECTS, LIVE_EFFECTS, PARAMETER_DESCRIPTIONS,
                    RECORD_EFFECTS)

__all__ = ['AxisTerms', 'DEFAULT_RATE_WINDOW_S', 'DEFAULT_SUPPLY_REFERENCE_V', 'Effect',
           'EFFECT_NAMES', 'EffectModel', 'EFFECTS', 'EffectStream', 'FirstOrderLag',
           'LinearBtc', 'LIVE_EFFECTS', 'MAX_GRADIENT_TERMS', 'MODEL_NAMES',
           'PARAMETER_DESCRIPTIONS', 'play_state', 'PlayOperator', 'polynomial_model',
           'RECORD_EFFECTS', 'temperature_rate_c_s', 'TemperatureSlope']
