"""QoS profiles of the raw and compensated streams."""

from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)

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
