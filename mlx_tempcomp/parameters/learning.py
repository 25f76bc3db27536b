"""
The compensation node's ``learning.*`` parameters: their specs and the learner's settings.

`LEARNING_SPECS` lists each, as `tracking.TRACKING_SPECS` lists ``bias_tracking.*``:
the compensation node declares them (`compensation.COMPENSATION_SPECS`) and ``mlx-tempcomp
evaluate --learn`` reads them from a parameter file's node section. `field_learning`
turns the values (defaults where absent) into `FieldLearning`, checking what a
descriptor cannot say (a ConfigError names the parameter); its `settings` adds the
tracking settings and the prior model's error table and gives
`core.learning.LearningSettings` (``core/learning/settings.py`` gives the maths of what
a 0 stands for). `learning_settings` does both for ``evaluate``, whose prior model is
read with the values. `learning_parameters` gives the section of a parameter file.
"""

from dataclasses import dataclass
import math
from typing import Optional

from .specs import Spec
from ..core.errors import ConfigError
from ..core.learning import derive_settings, LearningSettings

PREFIX = 'learning.'

LEARNING_SPECS = (
    Spec(PREFIX + 'enabled', True,
         'renew the temperature model from the still windows the bias tracking learns '
         'from (false: tracking alone)'),
    Spec(PREFIX + 'temperature_min_c', -40.0, 'first knot of the learnt correction table, degC',
         low=-100.0, high=200.0),
    Spec(PREFIX + 'temperature_max_c', 85.0,
         'last knot of the learnt correction table, degC (held beyond both ends)',
         low=-100.0, high=200.0),
    Spec(PREFIX + 'knot_step_c', 5.0, 'temperature between the knots of the correction table, '
         'degC', low=0.5, high=100.0),
    Spec(PREFIX + 'correlation_c', 20.0,
         'how far in temperature the shape learnt at one temperature carries, degC',
         low=0.5, high=1000.0),
    Spec(PREFIX + 'prior_std_rad_s', [0.0],
         "the prior model's own error, rad/s, one value or one per axis; 0 = its "
         'model_error table, else bias_tracking.initial_std_rad_s'),
    Spec(PREFIX + 'fading_s', [0.0],
         'time constant over which the shape learnt fades back to the prior, s of sensor '
         "time, one value or one per axis; 0 = the tracker's own, 2 initial_std^2 / "
         'random_walk^2, at least a day'),
    Spec(PREFIX + 'significance', 2.0,
         'a renewed model replaces the one in use when its mean gain on later still '
         'windows is this many standard errors (and it wins on most of them)',
         low=0.0, high=100.0),
    Spec(PREFIX + 'min_runs', 3, 'held-out still runs a renewed model is judged on, at least (a '
         'trial not decided then goes on for up to three times as many)', low=2, high=1000),
    Spec(PREFIX + 'min_windows', 10,
         'held-out still windows a renewed model is judged on, at least', low=2, high=100000),
)
_BY_NAME = {spec.name[len(PREFIX):]: spec for spec in LEARNING_SPECS}


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
    spec = _BY_NAME[name]
    value = values.get(PREFIX + name, spec.default)
    integer = isinstance(spec.default, int) and not isinstance(spec.default, bool)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (integer and not isinstance(value, int)) or not math.isfinite(value) or \
            not spec.low <= value <= spec.high:
        kind = 'an integer' if integer else 'a number'
        msg = (f'invalid parameter {PREFIX}{name}: must be {kind} from {spec.low:g} to '
               f'{spec.high:g}, got {value!r}')
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


@dataclass(frozen=True)
class FieldLearning:
    """
    The ``learning.*`` values, checked, per axis where they may be: what the learner starts from.

    ``knots_c`` are those of ``temperature_min_c`` to ``_max_c`` by ``knot_step_c``
    (None when not asked for: the prior model's table gives them).
    """

    knots_c: Optional[tuple]
    prior_std_rad_s: tuple
    fading_s: tuple
    correlation_c: float
    significance: float
    min_runs: int
    min_windows: int

    def settings(self, tracking, model_error=None, knots_c=None) -> LearningSettings:
        """
        Give the learner's settings with the tracker's `TrackingSettings` ``tracking``.

        ``model_error`` is the prior model's `ModelErrorTable` or None; ``knots_c`` the
        knots of the correction the prior model carries already (the learnt one adds to
        it), else those of the values.
        """
        knots = tuple(knots_c) if knots_c is not None else self.knots_c
        return derive_settings(
            tracking, knots, self.prior_std_rad_s, self.fading_s, self.correlation_c,
            model_error, significance=self.significance, min_runs=self.min_runs,
            min_windows=self.min_windows)


def field_learning(values: dict, axes: int, knots: bool = True) -> FieldLearning:
    """
    Give the checked ``learning.*`` ``values`` (defaults where absent) of ``axes`` axes.

    ``knots``: check and give the knots of the values (else None: the prior model's).
    """
    return FieldLearning(
        knots_c=knots_of(values) if knots else None,
        prior_std_rad_s=_axis_values(values, 'prior_std_rad_s', axes),
        fading_s=_axis_values(values, 'fading_s', axes),
        correlation_c=_scalar(values, 'correlation_c'),
        significance=_scalar(values, 'significance'), min_runs=_scalar(values, 'min_runs'),
        min_windows=_scalar(values, 'min_windows'))


def learning_settings(values: dict, tracking, model_error=None, knots_c=None
                      ) -> LearningSettings:
    """
    Build the learner's settings from ``learning.*`` ``values`` (defaults where absent).

    ``tracking`` is the tracker's `TrackingSettings`; ``model_error`` and ``knots_c`` as
    `FieldLearning.settings` takes them (the values' knots are not read with ``knots_c``).
    """
    return field_learning(values, tracking.standstill.axes, knots_c is None).settings(
        tracking, model_error, knots_c)


def learning_parameters(**given) -> dict:
    """Give the ``learning`` section of a parameter file: the defaults, updated by ``given``."""
    unknown = sorted(set(given) - set(_BY_NAME))
    if unknown:
        raise ConfigError(f'unknown learning parameters: {", ".join(unknown)}')
    section = {}
    for name, spec in _BY_NAME.items():
        value = given.get(name, spec.default)
        if isinstance(spec.default, list):
            value = [float(v) for v in value]
        elif isinstance(spec.default, float):
            value = float(value)
        section[name] = value
    return {'learning': section}


def renewal_lines(learner, axes: tuple) -> list:
    """Say per axis how often the learner renewed, when last and its gain (a file header)."""
    lines = []
    for i, axis in enumerate(axes):
        status = learner.last_renewal[i]
        when = 'never renewed' if status is None else \
            f'last renewed at {status[0]:.1f} s, held-out gain {status[1]:.2f}x'
        lines.append(f'axis {axis}: {learner.renewals[i]} renewals, {when}; '
                     f'{learner.reason[i]}')
    return lines


def largest_correction_rad_s(learner) -> float:
    """Give the largest learnt correction in use, any axis and temperature, rad/s."""
    return max((abs(v) for column in learner.accepted.values_rad_s for v in column),
               default=0.0)
