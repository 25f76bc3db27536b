"""
The driver's bag source: the raw topics of a rosbag2 folder replayed as the live driver sends them.

``source: bag`` (``bag.*``): the Imu, temperature (one per chip too), second temperature,
supply voltage and EEPROM records of our raw topics (`recordings.bag_reader`), published on
the driver's topics with their recorded stamps, at the recorded rate scaled by
``bag.rate_factor``, or at rate factor 0 as fast as the consumer on ``bag.pace_topic`` takes
them (``PACE_WINDOW`` samples ahead at most). The replay starts with its first subscriber,
once the temperature topics are matched and the EEPROM message delivered; a compensation
node in the same process (bringup) takes the messages directly. At the end of the bag
(``bag.on_end``) the driver stops, holds, or loops with its stamps shifted.
"""

import collections
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.duration import Duration
from sensor_msgs.msg import BatteryState, Imu, Temperature

from .timed_stream import refuse_fault
from .. import messages
from ..qos import SENSOR_INPUT_QOS, stream_publisher
from ...parameters.specs import ParameterError
from ...recordings.bag import (absolute_topic, ImuRecord, RawTopics, SupplyVoltageRecord,
                               TemperatureRecord)
from ...recordings.bag_reader import RawBagReader

# Most bag messages published by one timer tick: a replay catching up after a stall sends
# short bursts, so the executor (and subscriber queues) keep up.
MAX_SAMPLES_PER_TICK = 20
ACK_TIMEOUT = Duration(seconds=1.0)
# bag.on_end stop: how long the last status waits for its readers' acknowledgement (a busy
# reader takes longer than the EEPROM's 1 s; past it the driver exits regardless).
LAST_STATUS_ACK_TIMEOUT = Duration(seconds=5.0)
# A bag replayed at rate factor 0 stays this many samples ahead of its consumer; without
# progress for bag.pace_timeout_s it goes on anyway (nobody may be consuming).
PACE_WINDOW = 100
MATCH_GRACE_S = 2.0
# bag.on_end stop: the last messages are on their way before the process exits.
STOP_LINGER_S = 0.2


class BagStream:
    """
    Replays the raw topics of a rosbag2 folder at the recorded rate, scaled, or at once.

    At the end (``bag.on_end``) it stops the driver, holds, or loops: pass p
    (from 0) carries the recorded stamps plus p x the shift, the bag's stamp
    span plus its mean Imu interval, so stamps keep increasing.
    """

    def __init__(self, node):
        """Open the bag ``bag.path`` names for ``node``, the driver (`node.DriverNode`)."""
        self.node = node
        self.simulated = False
        bag = node.settings.bag
        path = bag.path
        temperature_topic = bag.temperature_topic
        axis_topics = tuple(f'{temperature_topic.rstrip("/")}/{axis}' for axis in node.axes) \
            if len(node.axes) > 1 else ()
        temperature_2_topic = bag.temperature_2_topic
        extra_topics = axis_topics + ((temperature_2_topic,) if temperature_2_topic else ())
        if temperature_2_topic and absolute_topic(temperature_2_topic) in \
                {absolute_topic(t) for t in (temperature_topic,) + axis_topics}:
            msg = (f'invalid parameter bag.temperature_2_topic: {temperature_2_topic} is '
                   'already the temperature topic')
            raise ParameterError(msg)
        self.reader = RawBagReader(
            path, RawTopics(imu=bag.imu_topic, temperature=temperature_topic,
                            eeprom=bag.eeprom_topic, supply_voltage=bag.supply_voltage_topic),
            extra_temperature_topics=extra_topics)
        # Topic (without slashes) -> (publisher, pairer stream of the compensation node); the
        # main temperature topic is the default.
        self.publishers = {topic.strip('/'): (publisher, f'temperature_{axis}') for
                           topic, publisher, axis in zip(axis_topics,
                                                         node.axis_temperature_publishers,
                                                         node.axes)}
        if temperature_2_topic:
            if absolute_topic(temperature_2_topic) not in \
                    {absolute_topic(t) for t in self.reader.bag_topics}:
                self.reader.close()
                msg = (f'invalid parameter bag.temperature_2_topic: no topic '
                       f'{absolute_topic(temperature_2_topic)} in {path}')
                raise ParameterError(msg)
            self.publishers[temperature_2_topic.strip('/')] = (stream_publisher(
                node, Temperature, 'imu/temperature_2_raw'), 'temperature_2')
        self.temperature_topic = temperature_topic.strip('/')
        self.supply_publisher = stream_publisher(
            node, BatteryState, 'imu/supply_voltage') if self.reader.has_supply_voltage \
            else None
        if self.reader.eeprom is not None:
            node.eeprom_publisher.publish(messages.eeprom_message(self.reader.eeprom.images))
        self.rate_factor = bag.rate_factor
        self.on_end = bag.on_end
        self.hardware_id = f'bag {path}'
        self.records = self.reader.records()
        self.next_record = next(self.records, None)
        self.first_bag_ns = None if self.next_record is None else self.next_record[0]
        self.start_wall = None
        self.first_subscriber = None
        self.published = 0
        self.passes = 0
        self.shift_ns = 0
        # Stamps of the first pass: the loop shift.
        self.stamp_span_ns = [None, None]
        self.imu_count = 0
        self.finished = self.next_record is None
        self.finished_wall = None
        self.in_flight = collections.deque()
        self.last_progress = time.monotonic()
        self.pace_timeouts = 0
        self.pace_timeout_s = bag.pace_timeout_s
        if self.rate_factor == 0.0:
            node.create_subscription(Imu, bag.pace_topic, self.on_consumed,
                                     SENSOR_INPUT_QOS)
        self.timer = node.create_timer(0.002, self.tick)
        node.get_logger().info(f'{self.reader.message_count} messages in {path}, rate factor '
                               f'{self.rate_factor:g}: waiting for a subscriber')

    def check_fault(self, value: str) -> None:
        refuse_fault()

    def tick(self) -> None:
        if self.start_wall is None:
            # A replay nobody hears is lost: start with the first subscriber of the rate,
            # once the temperature topics are matched too (or after a grace period: some
            # consumers want the rate only) and the EEPROM message is delivered.
            # A compensation node in this process (bringup) takes the messages directly.
            if not self.node.has_consumer():
                return
            local = bool(self.node.local_consumers)
            if self.first_subscriber is None:
                self.first_subscriber = time.monotonic()
            publishers = [self.node.temperature_publisher] + \
                [publisher for publisher, _ in self.publishers.values()] + \
                ([self.supply_publisher] if self.supply_publisher else [])
            if not local and any(p.get_subscription_count() == 0 for p in publishers) and \
                    time.monotonic() - self.first_subscriber < MATCH_GRACE_S:
                return
            self.node.eeprom_publisher.wait_for_all_acked(ACK_TIMEOUT)
            self.start_wall = time.monotonic()
            self.node.get_logger().info('subscriber present: replay starts')
        self._replay((time.monotonic() - self.start_wall) * 1e9 * self.rate_factor)
        self.node.hand_off()

    def _replay(self, elapsed_ns: float) -> None:
        """Publish the messages due after ``elapsed_ns`` of replay, a burst at most."""
        if self.finished:
            self._stop_when_delivered()
            return
        for _ in range(MAX_SAMPLES_PER_TICK):
            if self.next_record is None:
                self._end_of_bag()
                return
            bag_ns, topic, record = self.next_record
            if self.rate_factor > 0.0 and bag_ns - self.first_bag_ns > elapsed_ns:
                return
            if self.rate_factor == 0.0 and isinstance(record, ImuRecord) and self._ahead():
                return
            self._publish(topic, record)
            self.next_record = next(self.records, None)

    def _end_of_bag(self) -> None:
        self.passes += 1
        logger = self.node.get_logger()
        text = (f'bag replay finished: {self.published} messages, {self.reader.skipped} '
                'skipped')
        if self.on_end == 'loop':
            first_ns, last_ns = self.stamp_span_ns
            step_ns = (last_ns - first_ns) // (self.imu_count - 1) if self.imu_count > 1 \
                else 1_000_000_000
            self.shift_ns = self.passes * (last_ns - first_ns + step_ns)
            logger.info(f'{text} (pass {self.passes}); bag.on_end loop: starting over, '
                        f'stamps shifted by {self.shift_ns / 1e9:.9f} s')
            self.records = self.reader.records()
            self.next_record = next(self.records, None)
            self.start_wall = time.monotonic()
            return
        self.finished = True
        self.finished_wall = time.monotonic()
        if self.on_end == 'hold':
            logger.info(f'{text}; bag.on_end hold: publishing nothing until stopped')
            self.timer.cancel()
        else:
            logger.info(f'{text}; bag.on_end stop: the driver exits')

    def _stop_when_delivered(self) -> None:
        """bag.on_end stop: exit once the consumer caught up (rate factor 0) and a linger."""
        now = time.monotonic()
        if now - self.finished_wall < STOP_LINGER_S or (
                self.in_flight and now - self.last_progress < self.pace_timeout_s):
            return
        self.timer.cancel()
        # The last status says 'finished'; it is reliable: wait until its readers have it.
        self.node.publish_diagnostics()
        self.node.diagnostics_publisher.wait_for_all_acked(LAST_STATUS_ACK_TIMEOUT)
        # Out of the executor's spin with the context still up: the runner destroys the
        # nodes as after a stop signal, and the process exits 0.
        raise SystemExit(0)

    def on_consumed(self, msg: Imu) -> None:
        stamp_ns = messages.stamp_to_ns(msg.header.stamp)
        while self.in_flight and self.in_flight[0] <= stamp_ns:
            self.in_flight.popleft()
        self.last_progress = time.monotonic()

    def _ahead(self) -> bool:
        """Tell whether the replay must wait for its consumer before the next sample."""
        if len(self.in_flight) < PACE_WINDOW:
            return False
        if time.monotonic() - self.last_progress < self.pace_timeout_s:
            return True
        self.pace_timeouts += 1
        self.in_flight.clear()
        return False

    def _publish(self, topic: str, record) -> None:
        if not isinstance(record, (ImuRecord, TemperatureRecord, SupplyVoltageRecord)):
            return      # the EEPROM: published once at start
        stamp_ns = record.stamp_ns + self.shift_ns
        if self.passes == 0:
            first_ns, last_ns = self.stamp_span_ns
            self.stamp_span_ns = [stamp_ns if first_ns is None else min(first_ns, stamp_ns),
                                  stamp_ns if last_ns is None else max(last_ns, stamp_ns)]
        stamp = messages.ns_to_stamp(stamp_ns)
        if isinstance(record, ImuRecord):
            msg = Imu()
            msg.header.stamp = stamp
            msg.header.frame_id = record.frame_id
            msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = \
                (float(v) for v in record.angular_velocity_rad_s)
            msg.angular_velocity_covariance = [float(v) for v in
                                               record.angular_velocity_covariance]
            msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = \
                (float(v) for v in record.linear_acceleration_m_s2)
            msg.linear_acceleration_covariance = [float(v) for v in
                                                  record.linear_acceleration_covariance]
            msg.orientation_covariance = [float(v) for v in record.orientation_covariance]
            self.node.send(self.node.imu_publisher, 'imu', msg)
            self.imu_count += self.passes == 0
            if self.rate_factor == 0.0:
                self.in_flight.append(stamp_ns)
        elif isinstance(record, TemperatureRecord):
            msg = messages.temperature_message(stamp, record.frame_id, record.temperature_c,
                                               record.variance)
            publisher, stream = self.publishers.get(topic.strip('/'),
                                                    (self.node.temperature_publisher,
                                                     'temperature'))
            self.node.send(publisher, stream, msg)
        else:
            self.node.send(self.supply_publisher, 'supply_voltage',
                           messages.supply_voltage_message(stamp, record.frame_id,
                                                           record.voltage_v))
        self.published += 1

    def status(self) -> tuple:
        state = 'finished' if self.finished else \
            'waiting for a subscriber' if self.start_wall is None else 'replaying'
        values = {'state': state,
                  'published': self.published, 'messages': self.reader.message_count,
                  'skipped': self.reader.skipped, 'rate_factor': self.rate_factor,
                  'pace_timeouts': self.pace_timeouts, 'on_end': self.on_end,
                  'passes': self.passes, 'stamp_shift_ns': self.shift_ns}
        if self.reader.skipped:
            return DiagnosticStatus.WARN, f'{self.reader.skipped} bag messages skipped', values
        return DiagnosticStatus.OK, state, values

    def close(self) -> None:
        self.reader.close()
