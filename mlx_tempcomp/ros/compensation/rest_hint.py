"""
The robot's rest hint as a message: which types, what time each takes, when it says at rest.

``bias_tracking.rest_hint_type`` names one of `KINDS`. A twist (nav_msgs/Odometry's
``twist.twist``, geometry_msgs/Twist, geometry_msgs/TwistStamped's ``twist``) says at rest
when its linear speed is at most ``rest_hint_max_linear_m_s`` and its angular speed at most
``rest_hint_max_angular_rad_s`` (NaN: moving); std_msgs/Bool says at rest when true.
Odometry and TwistStamped carry their time in the header stamp, on the Imu's clock; Twist,
Bool and a zero stamp (never set) carry none, and take the time of the latest sample the
tracker has seen when they arrive (`core.standstill.rest_hints` says how hints count).
"""

from dataclasses import dataclass
import math
from typing import Callable, Optional

from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from std_msgs.msg import Bool

from .. import messages


@dataclass(frozen=True)
class HintKind:
    """One message type a rest hint may come as."""

    message_type: type
    stamp: Optional[Callable]      # message -> its header stamp; None: unstamped
    twist: Optional[Callable]      # message -> its Twist; None: a Bool


KINDS = {
    'nav_msgs/Odometry': HintKind(Odometry, lambda m: m.header.stamp, lambda m: m.twist.twist),
    'geometry_msgs/Twist': HintKind(Twist, None, lambda m: m),
    'geometry_msgs/TwistStamped': HintKind(TwistStamped, lambda m: m.header.stamp,
                                           lambda m: m.twist),
    'std_msgs/Bool': HintKind(Bool, None, None),
}


def _speed(vector) -> float:
    return math.sqrt(vector.x * vector.x + vector.y * vector.y + vector.z * vector.z)


def at_rest(kind: HintKind, msg, max_linear_m_s: float, max_angular_rad_s: float) -> bool:
    """Tell whether ``msg`` says the robot stands still."""
    if kind.twist is None:
        return bool(msg.data)
    twist = kind.twist(msg)
    # NaN compares false: a speed that is not a number is not rest.
    return _speed(twist.linear) <= max_linear_m_s and _speed(twist.angular) <= max_angular_rad_s


def stamp_ns(kind: HintKind, msg) -> Optional[int]:
    """Give the message's stamp in ns, None when it has none (or a zero one)."""
    if kind.stamp is None:
        return None
    stamp = messages.stamp_to_ns(kind.stamp(msg))
    return stamp or None
