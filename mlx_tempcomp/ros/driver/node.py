"""
Driver node: raw rate and temperature from a simulated, SPI or I2C gyro, or a bag.

``device`` picks the part's stream from `STREAMS` (a ``<part>_stream``
module each; only the MLX90609 has an EEPROM topic and a temperature per
chip, only the MPU-6000 linear acceleration); ``source`` ``bag`` replays a bag
instead (`bag_replay.BagStream`).

Publishes (REP-145): ``imu/data_raw`` (sensor_msgs/Imu, nominal conversion,
rad/s), ``imu/temperature_raw`` (sensor_msgs/Temperature, degC; with several
chips their mean, and each chip's on ``imu/temperature_raw/<axis>``),
``imu/eeprom`` (std_msgs/UInt8MultiArray, transient local: the chips' EEPROM
images, so the raw topics reproduce compensation exactly) and ``/diagnostics``;
a bag with a second temperature (``bag.temperature_2_topic``) also gives
``imu/temperature_2_raw``, one with a supply voltage (``bag.supply_voltage_topic``)
``imu/supply_voltage`` (sensor_msgs/BatteryState), and so does the simulated
MLX90609's supply monitor (``simulation.supply_monitor_hz``).
"""

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import UInt8MultiArray

from .adis16130_stream import AdisStream
from .bag_replay import BagStream
from .mlx90609_stream import Mlx90609Stream
from .mpu6000_stream import MpuStream
from .timed_stream import StreamPorts, TimedStream
from .. import messages
from ..declare import declare
from ..qos import EEPROM_QOS, stream_publisher
from ..runner import run
from ...parameters.driver import driver_settings, DRIVER_SPECS
from ...parameters.specs import check_choices, ParameterError

# The stream of each ``device``: a new sensor adds its row.
STREAMS = {'mlx90609': Mlx90609Stream, 'adis16130': AdisStream, 'mpu6000': MpuStream}


class DriverNode(Node):
    """Reads the configured source and publishes the raw topics."""

    def __init__(self, **kwargs):
        super().__init__('driver_node', **kwargs)
        # The values build the candidate settings of a change; the node reads the settings.
        self.values = declare(self, DRIVER_SPECS)
        self.settings = driver_settings(self.values)
        settings = self.settings
        self.device = settings.device
        self.axes = settings.axes
        self.indices = messages.axis_indices(self.axes)
        self.covariance = messages.rate_covariance(self.indices, settings.rate_noise_rad_s)
        self.imu_publisher = stream_publisher(self, Imu, 'imu/data_raw')
        self.temperature_publisher = stream_publisher(self, Temperature,
                                                      'imu/temperature_raw')
        # One temperature per chip, and the EEPROM, are MLX90609 things (a bag may hold them).
        mlx = self.device == 'mlx90609' or settings.source == 'bag'
        self.axis_temperature_publishers = [
            stream_publisher(self, Temperature, f'imu/temperature_raw/{axis}')
            for axis in self.axes] if len(self.axes) > 1 and mlx else []
        self.eeprom_publisher = self.create_publisher(UInt8MultiArray, 'imu/eeprom',
                                                      EEPROM_QOS) if mlx else None
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # In one process with the compensation node (bringup) the raw messages are also
        # handed to it directly, once per timer tick: (pairer stream, message) pairs.
        self.local_consumers = []
        self.handoff = []
        if settings.source == 'bag':
            self.stream = BagStream(self)
        else:
            self.stream = STREAMS[self.device](StreamPorts(
                node=self, settings=lambda: self.settings, publish_raw=self.publish_raw,
                hand_off=self.hand_off, has_consumer=self.has_consumer,
                eeprom_publisher=self.eeprom_publisher))
        self.create_timer(1.0, self.publish_diagnostics)
        self.add_on_set_parameters_callback(self.validate_parameters)
        self.add_post_set_parameters_callback(self.apply_parameters)
        outputs = [p.topic_name for p in self.publishers
                   if p.topic_name not in ('/rosout', '/parameter_events')]
        services = [self.resolve_service_name(s.srv_name) for s in self.services
                    if 'imu/' in s.srv_name]
        self.get_logger().info(
            f'device {self.device}, source {settings.source}, axes {list(self.axes)}: '
            f'{self.stream.hardware_id}; publishes {", ".join(outputs)}'
            + (f'; services {", ".join(services)}' if services else ''))

    def validate_parameters(self, parameters) -> SetParametersResult:
        """Refuse a change whose candidate settings do not build, or the stream cannot take."""
        changed = {p.name for p in parameters}
        candidate = {**self.values, **{p.name: p.value for p in parameters}}
        try:
            check_choices(DRIVER_SPECS, candidate)
            settings = driver_settings(candidate)
            if 'simulation.fault' in changed:
                self.stream.check_fault(settings.simulation.fault)
            if 'simulation.supply_v' in changed and not settings.simulated_mlx90609:
                raise ParameterError('simulation.supply_v changes at runtime on the simulated '
                                     'MLX90609 only')
        except ParameterError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def apply_parameters(self, parameters) -> None:
        """Swap in the settings of the values set (validated): the next message takes them."""
        for parameter in parameters:
            self.values[parameter.name] = parameter.value
        self.settings = settings = driver_settings(self.values)
        self.covariance = messages.rate_covariance(self.indices, settings.rate_noise_rad_s)
        if self.stream.simulated:
            self.stream.set_fault(settings.simulation.fault)
        if settings.simulated_mlx90609:
            self.stream.array.supply_v = settings.simulation.supply_v

    def publish_raw(self, stamp_ns: int, rate_rad_s, temperatures_c, acceleration_m_s2=None,
                    acceleration_covariance=None) -> None:
        stamp = messages.ns_to_stamp(stamp_ns)
        frame_id = self.settings.frame_id
        # Temperature first: a subscriber pairing by stamp then completes on the Imu.
        for axis, publisher, temperature in zip(self.axes, self.axis_temperature_publishers,
                                                temperatures_c):
            self.send(publisher, f'temperature_{axis}',
                      messages.temperature_message(stamp, frame_id, temperature))
        self.send(self.temperature_publisher, 'temperature', messages.temperature_message(
            stamp, frame_id, sum(temperatures_c) / len(temperatures_c)))
        self.send(self.imu_publisher, 'imu', messages.imu_message(
            stamp, frame_id, self.indices, rate_rad_s, self.covariance, acceleration_m_s2,
            acceleration_covariance))

    def send(self, publisher, stream: str, msg) -> None:
        """Publish ``msg``; keep it for the local consumers too, if any."""
        publisher.publish(msg)
        if self.local_consumers:
            self.handoff.append((stream, msg))

    def has_consumer(self) -> bool:
        """Tell whether someone takes imu/data_raw: a subscriber, or a node in this process."""
        return bool(self.local_consumers) or self.imu_publisher.get_subscription_count() > 0

    def hand_off(self) -> None:
        """Give the local consumers what this tick sent (called at the end of every tick)."""
        if not self.handoff:
            return
        handoff, self.handoff = self.handoff, []
        for consumer in self.local_consumers:
            consumer(handoff)

    def publish_diagnostics(self) -> None:
        level, message, values = self.stream.status()
        status = messages.diagnostic_status(f'{self.get_name()}: {self.settings.source}',
                                            self.stream.hardware_id, level, message, values)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_publisher.publish(array)

    def destroy_node(self):
        if isinstance(self.stream, TimedStream):
            self.get_logger().info(f'{self.get_name()} {self.stream.summary()}')
        self.stream.close()
        return super().destroy_node()


def main(args=None) -> int:
    return run([DriverNode], args, 'driver_node')


if __name__ == '__main__':
    raise SystemExit(main())
