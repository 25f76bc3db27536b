"""
The field learner's settings: what it needs per axis, derived from the tracker's where not given.

`LearningSettings` is what `FieldLearner` and `LearningTracking` run on;
`derive_settings` builds it from the tracker's `TrackingSettings` and the figures the
``learning.*`` parameters give (``parameters.learning`` reads and checks them, and says
what each means). Per axis, with the tracker's figures (``bias_tracking.*``) where a
given value is 0:

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

import numpy as np

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


def derive_settings(tracking, knots_c: tuple, prior_std_rad_s: tuple, fading_s: tuple,
                    correlation_c: float, model_error=None, **trial) -> LearningSettings:
    """
    Build the learner's settings (see the module notes); a 0 per axis takes the default.

    ``tracking`` is the tracker's `TrackingSettings`; ``prior_std_rad_s`` and ``fading_s``
    one value per axis; ``model_error`` the prior model's `ModelErrorTable` or None;
    ``trial`` the guard's ``significance``, ``min_runs`` and ``min_windows``.
    """
    standstill = tracking.standstill
    error = None if model_error is None else model_error.error_at(np.asarray(knots_c))
    prior = []
    for axis in range(standstill.axes):
        if prior_std_rad_s[axis] > 0.0:
            column = (prior_std_rad_s[axis],) * len(knots_c)
        elif error is not None:
            column = tuple(max(float(v), 1e-12) for v in error[:, axis])
        else:
            column = (tracking.initial_std_rad_s[axis],) * len(knots_c)
        prior.append(column)
    fading = []
    for axis, value in enumerate(fading_s):
        walk = standstill.random_walk_rad_s_rt_s[axis]
        cap = tracking.initial_std_rad_s[axis]
        fading.append(value if value > 0.0 else
                      max(2.0 * cap * cap / (walk * walk), MIN_FADING_S) if walk > 0.0
                      else math.inf)
    return LearningSettings(
        knots_c=knots_c, prior_std_rad_s=tuple(prior),
        level_std_rad_s=tuple(LEVEL_MULTIPLE * max(column) for column in prior),
        correlation_c=correlation_c, fading_s=tuple(fading),
        random_walk_rad_s_rt_s=standstill.random_walk_rad_s_rt_s,
        rate_noise_rad_s=standstill.rate_noise_rad_s,
        tracker_std_rad_s=tracking.initial_std_rad_s, window_s=standstill.window_s,
        agreement_multiple=standstill.agreement_multiple,
        max_temperature_rate_c_s=standstill.max_temperature_rate_c_s, **trial)
