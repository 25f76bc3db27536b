"""
The compensation node's ``bias_tracking.*`` parameters: their table and the settings they make.

`PARAMETERS` lists each parameter (name without the prefix, default, description,
range of a scalar); ``parameters.compensation`` makes the node's specs of it, so the node, the
shipped config and ``mlx-tempcomp evaluate`` share one table. `tracking_settings` turns
the node's values into `TrackingSettings` (None when tracking is off), checking what a
descriptor cannot say: per-axis lists of one value or one per axis, each in its range;
a ConfigError names the parameter. `tracking_parameters` gives the section
``mlx-tempcomp fit`` and ``diagnose`` write (`core.tracking_bounds` derives its values):
the unit's parameters, not the robot's (``unit`` false: the rest hints' age and the
start-up zeroing, which the robot's configuration sets).
"""

from dataclasses import dataclass
import math
from typing import Any, Optional

from .bias_tracker import TrackingSettings
from .errors import ConfigError
from .standstill import StandstillSettings

PREFIX = 'bias_tracking.'


@dataclass(frozen=True)
class Parameter:
    """
    One ``bias_tracking.*`` parameter; ``low``/``high`` bound a scalar (None: a list).

    ``unit``: the unit's, written by ``fit`` and ``diagnose``; false: the robot's.
    """

    name: str
    default: Any
    description: str
    low: Optional[float] = None
    high: Optional[float] = None
    unit: bool = True


PARAMETERS = (
    Parameter('enabled', True,
              'follow the offset the temperature model leaves while the gyro is still '
              '(false: the model alone)'),
    Parameter('window_s', 5.0, 'window the standstill is judged on, s of sensor time',
              0.1, 3600.0),
    Parameter('rate_noise_rad_s', [0.0],
              '1-sigma noise of one sample, rad/s: one value for every axis or one per axis '
              'of axes; 0 = rate_noise_rad_s'),
    Parameter('noise_multiple', 3.0,
              'a window whose rate spreads more than this x its noise on an axis moves',
              1.0, 1000.0),
    Parameter('max_mean_rate_rad_s', math.radians(0.1),
              'a window whose mean rate less the offset exceeds this moves (with an '
              'accelerometer: its part about gravity); a slower constant turn is rest to the '
              'tracker, rad/s', 1e-6, 10.0),
    Parameter('agreement_multiple', 4.0,
              'consecutive still windows agree within this many standard deviations (their '
              'noise and the random walk between them)', 1.0, 1000.0),
    Parameter('max_temperature_rate_c_s', 0.2,
              'a window whose temperature changes faster than this is not learnt from, C/s',
              1e-4, 100.0),
    Parameter('max_acceleration_spread_m_s2', 0.2,
              'with an accelerometer: a window whose specific force spreads more than this '
              'on an axis moves, m/s^2', 1e-6, 1000.0),
    Parameter('max_tilt_rate_rad_s', math.radians(0.05),
              'with an accelerometer: the specific force turning faster than this between '
              'two windows is motion, rad/s', 1e-7, 10.0),
    Parameter('enter_windows', 2,
              'quiet windows in a row, each agreeing with the one before, that make the gyro '
              'still', 1, 100),
    Parameter('leave_windows', 1, 'windows out of the still run that make it moving', 1, 100),
    Parameter('random_walk_rad_s_rt_s', [1e-5],
              'how fast the offset wanders, rad/s per sqrt(s), one value or one per axis: its '
              "square is the filter's process noise"),
    Parameter('initial_std_rad_s', [math.radians(0.1)],
              "the offset's standard deviation before anything is learnt and the most it "
              'grows to in motion, rad/s, one value or one per axis'),
    Parameter('stable_std_rad_s', math.radians(0.05),
              "an axis's offset is stable while its standard deviation is at most this, "
              'rad/s', 1e-9, 10.0),
    Parameter('rest_hint_max_age_s', 1.0,
              'a rest hint says at rest or moving for this long at most (sensor time, s): a '
              'window is hinted when the hints said at rest over all of it', 1e-3, 3600.0,
              unit=False),
    Parameter('zero_at_start', False,
              'take the first still run after the start as at rest, whatever its mean rate '
              '(as a flight controller zeroes its gyro at boot): a robot started while turning '
              'slowly takes the turn for its offset', unit=False),
)


def _axis_values(values: dict, name: str, axes: int, zero: bool) -> tuple:
    given = values[PREFIX + name]
    if len(given) not in (1, axes) or not all(
            math.isfinite(v) and (v > 0.0 or zero and v == 0.0) for v in given):
        relation = '>= 0' if zero else '> 0'
        msg = (f'invalid parameter {PREFIX}{name}: give one value or one per axis ({axes}), '
               f'each finite and {relation}; got {list(given)}')
        raise ConfigError(msg)
    return tuple(given) * (axes if len(given) == 1 else 1)


def tracking_settings(values: dict, axes: tuple, rate_noise_rad_s: float
                      ) -> Optional[TrackingSettings]:
    """
    Build the tracking settings from the node's values; None when ``enabled`` is false.

    ``values`` holds the node's flat parameters (``bias_tracking.window_s``, ...);
    ``rate_noise_rad_s`` the node's own noise figure, the one a 0 in
    ``bias_tracking.rate_noise_rad_s`` stands for.
    """
    if not values[PREFIX + 'enabled']:
        return None
    count = len(axes)
    noise = _axis_values(values, 'rate_noise_rad_s', count, zero=True)
    if any(v == 0.0 for v in noise):
        if not rate_noise_rad_s > 0.0:
            msg = (f'invalid parameter {PREFIX}rate_noise_rad_s: bias tracking needs the '
                   'noise of a sample; give it here or in rate_noise_rad_s (both are 0)')
            raise ConfigError(msg)
        noise = tuple(v or rate_noise_rad_s for v in noise)
    scalar = {p.name: values[PREFIX + p.name] for p in PARAMETERS
              if p.low is not None and p.unit and p.name != 'stable_std_rad_s'}
    standstill = StandstillSettings(
        rate_noise_rad_s=noise,
        random_walk_rad_s_rt_s=_axis_values(values, 'random_walk_rad_s_rt_s', count, zero=True),
        **scalar)
    return TrackingSettings(
        standstill=standstill,
        initial_std_rad_s=_axis_values(values, 'initial_std_rad_s', count, zero=False),
        stable_std_rad_s=values[PREFIX + 'stable_std_rad_s'],
        rest_hint_max_age_s=values[PREFIX + 'rest_hint_max_age_s'],
        zero_at_start=values[PREFIX + 'zero_at_start'])


def tracking_parameters(**given) -> dict:
    """
    Give the ``bias_tracking`` section of a parameter file: the defaults, updated by ``given``.

    Values are plain floats (and the two integers, ``enabled``), lists for the per-axis
    parameters; an unknown name is a ConfigError. The unit's parameters only.
    """
    unknown = sorted(set(given) - {p.name for p in PARAMETERS if p.unit})
    if unknown:
        raise ConfigError(f'unknown bias_tracking parameters: {", ".join(unknown)}')
    section = {}
    for p in (p for p in PARAMETERS if p.unit):
        value = given.get(p.name, p.default)
        if isinstance(p.default, list):
            value = [float(v) for v in value]
        elif isinstance(p.default, float):
            value = float(value)
        section[p.name] = value
    return {'bias_tracking': section}
