"""
The compensation node's ``bias_tracking.*`` parameters: their specs and the settings they make.

`UNIT_SPECS` are the unit's parameters, those ``mlx-tempcomp fit`` and ``diagnose``
write (`tracking_parameters`, with the values `core.standstill.tracking_bounds` derives);
`NODE_SPECS` the robot's, which its configuration sets (the rest hints, the start-up
zeroing, how often the offset is saved); `TRACKING_SPECS` both, as the compensation
node declares them (`compensation.COMPENSATION_SPECS`), so the node, the shipped
config and ``mlx-tempcomp evaluate`` share one table. `tracking_settings` turns the
node's values into `TrackingSettings` (None when tracking is off), checking what a
descriptor cannot say: per-axis lists of one value or one per axis, each in its range;
a ConfigError names the parameter.
"""

import math
from typing import Optional

from .specs import Spec
from ..core.errors import ConfigError
from ..core.standstill import StandstillSettings, TrackingSettings

PREFIX = 'bias_tracking.'
# The messages a rest hint may come as (`ros/compensation/rest_hint.py` reads each).
REST_HINT_TYPES = ('nav_msgs/Odometry', 'geometry_msgs/Twist', 'geometry_msgs/TwistStamped',
                   'std_msgs/Bool')

UNIT_SPECS = (
    Spec(PREFIX + 'enabled', True,
         'follow the offset the temperature model leaves while the gyro is still '
         '(false: the model alone)'),
    Spec(PREFIX + 'window_s', 5.0, 'window the standstill is judged on, s of sensor time',
         low=0.1, high=3600.0),
    Spec(PREFIX + 'rate_noise_rad_s', [0.0],
         '1-sigma noise of one sample, rad/s: one value for every axis or one per axis '
         'of axes; 0 = rate_noise_rad_s'),
    Spec(PREFIX + 'noise_multiple', 3.0,
         'a window whose rate spreads more than this x its noise on an axis moves',
         low=1.0, high=1000.0),
    Spec(PREFIX + 'max_mean_rate_rad_s', math.radians(0.1),
         'a window whose mean rate less the offset exceeds this moves (with an '
         'accelerometer: its part about gravity); a slower constant turn is rest to the '
         'tracker, rad/s', low=1e-6, high=10.0),
    Spec(PREFIX + 'agreement_multiple', 4.0,
         'consecutive still windows agree within this many standard deviations (their '
         'noise and the random walk between them)', low=1.0, high=1000.0),
    Spec(PREFIX + 'max_temperature_rate_c_s', 0.2,
         'a window whose temperature changes faster than this is not learnt from, C/s',
         low=1e-4, high=100.0),
    Spec(PREFIX + 'max_acceleration_spread_m_s2', 0.2,
         'with an accelerometer: a window whose specific force spreads more than this '
         'on an axis moves, m/s^2', low=1e-6, high=1000.0),
    Spec(PREFIX + 'max_tilt_rate_rad_s', math.radians(0.05),
         'with an accelerometer: the specific force turning faster than this between '
         'two windows is motion, rad/s', low=1e-7, high=10.0),
    Spec(PREFIX + 'enter_windows', 2,
         'quiet windows in a row, each agreeing with the one before, that make the gyro '
         'still', low=1, high=100),
    Spec(PREFIX + 'leave_windows', 1, 'windows out of the still run that make it moving',
         low=1, high=100),
    Spec(PREFIX + 'random_walk_rad_s_rt_s', [1e-5],
         'how fast the offset wanders, rad/s per sqrt(s), one value or one per axis: its '
         "square is the filter's process noise"),
    Spec(PREFIX + 'initial_std_rad_s', [math.radians(0.1)],
         "the offset's standard deviation before anything is learnt and the most it "
         'grows to in motion, rad/s, one value or one per axis'),
    Spec(PREFIX + 'stable_std_rad_s', math.radians(0.05),
         "an axis's offset is stable while its standard deviation is at most this, "
         'rad/s', low=1e-9, high=10.0),
)

NODE_SPECS = (
    Spec(PREFIX + 'rest_hint_max_age_s', 1.0,
         'a rest hint says at rest or moving for this long at most (sensor time, s): a '
         'window is hinted when the hints said at rest over all of it', low=1e-3, high=3600.0),
    Spec(PREFIX + 'zero_at_start', False,
         'take the first still run after the start as at rest, whatever its mean rate '
         '(as a flight controller zeroes its gyro at boot): a robot started while turning '
         'slowly takes the turn for its offset'),
    Spec(PREFIX + 'save_period_s', 60.0,
         'the tracked offset is written to the state file at most once per this many '
         'seconds of sensor time, when it learnt since the last write, and at a clean stop',
         low=0.0, high=86400.0),
    Spec(PREFIX + 'rest_hint_topic', '',
         "the robot's word that it stands still, e.g. odom or cmd_vel ('' = none): while it "
         'says so over a whole window, the mean-rate bound is lifted', read_only=True),
    Spec(PREFIX + 'rest_hint_type', REST_HINT_TYPES[0],
         'the message type of rest_hint_topic: Odometry and TwistStamped by their stamps, '
         'Twist and Bool (true = at rest) at the latest sample tracked', read_only=True,
         choices=REST_HINT_TYPES),
    Spec(PREFIX + 'rest_hint_max_linear_m_s', 0.001,
         'a twist (odometry, velocity command) is at rest when its linear speed is at most '
         'this, m/s', low=0.0, high=100.0),
    Spec(PREFIX + 'rest_hint_max_angular_rad_s', 0.001,
         'and its angular speed at most this, rad/s (0.057 deg/s: far below a slow turn)',
         low=0.0, high=100.0),
)

TRACKING_SPECS = UNIT_SPECS + NODE_SPECS


def _short(spec: Spec) -> str:
    """Give a spec's name without the prefix, as a parameter file's section holds it."""
    return spec.name[len(PREFIX):]


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
    scalar = {_short(spec): values[spec.name] for spec in UNIT_SPECS
              if spec.low is not None and spec.name != PREFIX + 'stable_std_rad_s'}
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
    unknown = sorted(set(given) - {_short(spec) for spec in UNIT_SPECS})
    if unknown:
        raise ConfigError(f'unknown bias_tracking parameters: {", ".join(unknown)}')
    section = {}
    for spec in UNIT_SPECS:
        value = given.get(_short(spec), spec.default)
        if isinstance(spec.default, list):
            value = [float(v) for v in value]
        elif isinstance(spec.default, float):
            value = float(value)
        section[_short(spec)] = value
    return {'bias_tracking': section}
