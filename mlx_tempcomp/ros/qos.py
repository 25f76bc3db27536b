"""QoS profiles of the raw and compensated streams, and the streams' QoS overrides."""

import copy

from rclpy.exceptions import InvalidParameterTypeException
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions

from ..parameters.specs import ParameterError

# Streams: best effort, as REP-2003 asks for sensor data.
SENSOR_QOS = qos_profile_sensor_data
# Subscribers keep a deeper queue than the preset's 5, so a burst (a replayed bag, a busy
# moment) waits instead of being dropped. Best effort, so it matches any sensor publisher.
SENSOR_INPUT_QOS = QoSProfile(depth=200, history=HistoryPolicy.KEEP_LAST,
                              reliability=ReliabilityPolicy.BEST_EFFORT,
                              durability=DurabilityPolicy.VOLATILE)
# The EEPROM images: sent once, kept for late joiners.
EEPROM_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Progress of a long procedure: kept for late joiners, so a monitor that starts (or is
# discovered) after the call still reads every phase from the beginning.
STATUS_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _overridable(create, topic: str, qos: QoSProfile):
    """
    Create a stream entity that takes the standard QoS override parameters.

    ``qos_overrides.<topic>.<publisher|subscription>.<policy>`` may change its history,
    depth and reliability. A replay that must lose nothing (every raw sample changes a
    model's history state) sets reliability ``reliable`` and a deep history on both ends.
    """
    try:
        # A copy: rclpy writes the overrides into the profile it is given.
        return create(copy.copy(qos), QoSOverridingOptions.with_default_policies())
    except (InvalidParameterTypeException, InvalidQosOverridesError, RuntimeError) as err:
        raise ParameterError(f'invalid qos_overrides for {topic}: {err} (history: keep_last or '
                             'keep_all; depth: an integer; reliability: reliable or '
                             'best_effort)') from None


def stream_publisher(node, msg_type, topic: str):
    """Create a sensor-data publisher of ``topic`` that takes QoS overrides."""
    return _overridable(lambda qos, options: node.create_publisher(
        msg_type, topic, qos, qos_overriding_options=options), topic, SENSOR_QOS)


def stream_subscription(node, msg_type, topic: str, callback):
    """Create a deep-queued sensor-data subscription of ``topic`` that takes QoS overrides."""
    return _overridable(lambda qos, options: node.create_subscription(
        msg_type, topic, callback, qos, qos_overriding_options=options), topic,
        SENSOR_INPUT_QOS)
