"""
The ``learning.*`` parameters: their table and the settings of the field learner they make.

`PARAMETERS` lists each (name without the prefix, default, description, range of a
scalar), as ``core.tracking_parameters`` lists ``bias_tracking.*``: ``mlx-tempcomp
evaluate --learn`` reads them from a parameter file's node section, and the compensation
node will declare them from the same table. `learning_settings` turns the values, the
tracking settings and the prior model's error table into `LearningSettings`, checking
what a descriptor cannot say; a ConfigError names the parameter.

Per axis, with the tracker's figures (``bias_tracking.*``) where a value is 0:

- the prior's standard deviation at each knot: ``prior_std_rad_s``, else the model's own
  error table (``model_error.*``, what diagnose measured held out), else the tracker's
  ``initial_std_rad_s`` (the offset it expects the model to leave);
- the fading time constant of the shape: ``fading_s``, else the tracker's own, 2
  initial_std^2 / q (q = ``random_walk_rad_s_rt_s`` squared: the time over which the
  offset the model leaves is no longer known), but at least `MIN_FADING_S`, a day: what
  wanders within a day is the offset (the level walks with q, as the tracker's offset
  does); the shape of bias(T) is the part's own and ages over days.
"""

from dataclasses import dataclass
import math
from typing import Any, Optional

import numpy as np

from ..errors import ConfigError

PREFIX = 'learning.'


@dataclass(frozen=True)
class Parameter:
    """One ``learning.*`` parameter; ``low``/``high`` bound a scalar (None: a list or a bool)."""

    name: str
    default: Any
    description: str
    low: Optional[float] = None
    high: Optional[float] = None


PARAMETERS = (
    Parameter('enabled', True,
              'renew the temperature model from the still windows the bias tracking learns '
              'from (false: tracking alone)'),
    Parameter('temperature_min_c', -40.0, 'first knot of the learnt correction table, degC',
              -100.0, 200.0),
    Parameter('temperature_max_c', 85.0,
              'last knot of the learnt correction table, degC (held beyond both ends)',
              -100.0, 200.0),
    Parameter('knot_step_c', 5.0, 'temperature between the knots of the correction table, '
              'degC', 0.5, 100.0),
    Parameter('correlation_c', 20.0,
              'how far in temperature the shape learnt at one temperature carries, degC',
              0.5, 1000.0),
    Parameter('prior_std_rad_s', [0.0],
              "the prior model's own error, rad/s, one value or one per axis; 0 = its "
              'model_error table, else bias_tracking.initial_std_rad_s'),
    Parameter('fading_s', [0.0],
              'time constant over which the shape learnt fades back to the prior, s of sensor '
              "time, one value or one per axis; 0 = the tracker's own, 2 initial_std^2 / "
              'random_walk^2, at least a day'),
    Parameter('significance', 2.0,
              'a renewed model replaces the one in use when its mean gain on later still '
              'windows is this many standard errors (and it wins on most of them)',
              0.0, 100.0),
    Parameter('min_runs', 3, 'held-out still runs a renewed model is judged on, at least (a '
              'trial not decided then goes on for up to three times as many)', 2, 1000),
    Parameter('min_windows', 10, 'held-out still windows a renewed model is judged on, at least',
              2, 100000),
)
_BY_NAME = {p.name: p for p in PARAMETERS}
# The level (an offset common to every temperature) is known this many times less well than
# the shape before anything is learnt: an offset seen at one temperature carries to all.
LEVEL_MULTIPLE = 10.0
# The shape fades over a day at least (see the module notes).
MIN_FADING_S = 86400.0
# A turn of the gravity seen by more than this between learnt windows (rad) moves the biases
# of a g-sensitive gyro: the level is unknown again.
TURN_RAD = 0.1


@dataclass(frozen=True)
class LearningSettings:
    """
    What the field learner needs, per axis where a tuple (see the module notes).

    ``knots_c``: the correction table's temperatures; ``prior_std_rad_s``: one tuple per
    axis, a value per knot; ``level_std_rad_s``, ``random_walk_rad_s_rt_s``,
    ``fading_s`` (inf: none), ``rate_noise_rad_s``: per axis; ``window_s``,
    ``agreement_multiple``, ``max_temperature_rate_c_s`` and ``tracker_std_rad_s`` (the
    tracker's initial_std, its fading cap) as the tracker has them.
    """

    knots_c: tuple
    prior_std_rad_s: tuple
    level_std_rad_s: tuple
    correlation_c: float
    fading_s: tuple
    random_walk_rad_s_rt_s: tuple
    rate_noise_rad_s: tuple
    tracker_std_rad_s: tuple
    window_s: float
    agreement_multiple: float
    max_temperature_rate_c_s: float
    significance: float = 2.0
    min_runs: int = 3
    min_windows: int = 10

    @property
    def axes(self) -> int:
        return len(self.prior_std_rad_s)


def _axis_values(values: dict, name: str, axes: int) -> tuple:
    given = values.get(PREFIX + name, _BY_NAME[name].default)
    if not isinstance(given, (list, tuple)) or len(given) not in (1, axes) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            and v >= 0.0 for v in given):
        msg = (f'invalid parameter {PREFIX}{name}: give one value or one per axis ({axes}), '
               f'each finite and >= 0; got {given!r}')
        raise ConfigError(msg)
    return tuple(float(v) for v in given) * (axes if len(given) == 1 else 1)


def _scalar(values: dict, name: str):
    parameter = _BY_NAME[name]
    value = values.get(PREFIX + name, parameter.default)
    integer = isinstance(parameter.default, int) and not isinstance(parameter.default, bool)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (integer and not isinstance(value, int)) or not math.isfinite(value) or \
            not parameter.low <= value <= parameter.high:
        kind = 'an integer' if integer else 'a number'
        msg = (f'invalid parameter {PREFIX}{name}: must be {kind} from {parameter.low:g} to '
               f'{parameter.high:g}, got {value!r}')
        raise ConfigError(msg)
    return value if integer else float(value)


def knots_of(values: dict) -> tuple:
    """Give the knots of ``learning.temperature_min_c`` to ``_max_c`` by ``knot_step_c``."""
    low, high = _scalar(values, 'temperature_min_c'), _scalar(values, 'temperature_max_c')
    step = _scalar(values, 'knot_step_c')
    if not low < high:
        msg = (f'invalid parameter {PREFIX}temperature_max_c: must be above temperature_min_c '
               f'({low:g}), got {high:g}')
        raise ConfigError(msg)
    count = int(math.ceil((high - low) / step - 1e-9)) + 1
    return tuple(float(low + step * k) for k in range(count - 1)) + (float(high),)


def learning_settings(values: dict, tracking, model_error=None, knots_c=None
                      ) -> LearningSettings:
    """
    Build the learner's settings from ``learning.*`` ``values`` (defaults where absent).

    ``tracking`` is the tracker's `TrackingSettings`; ``model_error`` the prior model's
    `ModelErrorTable` or None; ``knots_c`` the knots of the correction the prior model
    carries already (the learnt one adds to it), else those of the values.
    """
    standstill = tracking.standstill
    axes = standstill.axes
    knots = tuple(knots_c) if knots_c is not None else knots_of(values)
    given = _axis_values(values, 'prior_std_rad_s', axes)
    error = None if model_error is None else model_error.error_at(np.asarray(knots))
    prior = []
    for axis in range(axes):
        if given[axis] > 0.0:
            column = (given[axis],) * len(knots)
        elif error is not None:
            column = tuple(max(float(v), 1e-12) for v in error[:, axis])
        else:
            column = (tracking.initial_std_rad_s[axis],) * len(knots)
        prior.append(column)
    fading = []
    for axis, value in enumerate(_axis_values(values, 'fading_s', axes)):
        walk = standstill.random_walk_rad_s_rt_s[axis]
        cap = tracking.initial_std_rad_s[axis]
        fading.append(value if value > 0.0 else
                      max(2.0 * cap * cap / (walk * walk), MIN_FADING_S) if walk > 0.0
                      else math.inf)
    return LearningSettings(
        knots_c=knots, prior_std_rad_s=tuple(prior),
        level_std_rad_s=tuple(LEVEL_MULTIPLE * max(column) for column in prior),
        correlation_c=_scalar(values, 'correlation_c'), fading_s=tuple(fading),
        random_walk_rad_s_rt_s=standstill.random_walk_rad_s_rt_s,
        rate_noise_rad_s=standstill.rate_noise_rad_s,
        tracker_std_rad_s=tracking.initial_std_rad_s, window_s=standstill.window_s,
        agreement_multiple=standstill.agreement_multiple,
        max_temperature_rate_c_s=standstill.max_temperature_rate_c_s,
        significance=_scalar(values, 'significance'), min_runs=_scalar(values, 'min_runs'),
        min_windows=_scalar(values, 'min_windows'))


def learning_parameters(**given) -> dict:
    """Give the ``learning`` section of a parameter file: the defaults, updated by ``given``."""
    unknown = sorted(set(given) - set(_BY_NAME))
    if unknown:
        raise ConfigError(f'unknown learning parameters: {", ".join(unknown)}')
    section = {}
    for p in PARAMETERS:
        value = given.get(p.name, p.default)
        if isinstance(p.default, list):
            value = [float(v) for v in value]
        elif isinstance(p.default, float):
            value = float(value)
        section[p.name] = value
    return {'learning': section}
