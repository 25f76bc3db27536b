"""
Write our raw topics into a new rosbag2 bag (sqlite3 or mcap), without rclpy.

`RawBagWriter` turns the records of `bag` into their ROS 2 Jazzy messages
(rosbags' definitions) and writes them, or writes messages already
serialized (e.g. by rclpy's serialize_message).
"""

import math
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError

from .bag import (absolute_topic, BAG_VERSION, BagError, checked_stamp_ns, EEPROM_TYPE,
                  EepromRecord, IMU_TYPE, ImuRecord, jazzy_typestore, PathLike, RawTopics,
                  STORAGES, SUPPLY_VOLTAGE_TYPE, SupplyVoltageRecord, TEMPERATURE,
                  TEMPERATURE_TYPE, TemperatureRecord, wanted_topics)
from .eeprom_multiarray import eeprom_multiarray_from_images

try:  # the sqlite3 back end of rosbags >= 0.10; its errors can surface mid-iteration
    from apsw import Error as SqliteError
except ImportError:  # pragma: no cover
    from sqlite3 import Error as SqliteError

_NS_PER_S = 1_000_000_000
_INT32_MAX = 2**31 - 1
_INT64_MAX = 2**63 - 1
_STORAGE_PLUGINS = {'sqlite3': StoragePlugin.SQLITE3, 'mcap': StoragePlugin.MCAP}


def _header(typestore, stamp_ns: int, frame_id: str):
    sec, nanosec = divmod(stamp_ns, _NS_PER_S)
    if not -_INT32_MAX - 1 <= sec <= _INT32_MAX:
        msg = f'stamp {stamp_ns} ns does not fit a ROS time (int32 seconds)'
        raise BagError(msg)
    types = typestore.types
    return types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
        frame_id=frame_id)


def _imu_message(typestore, record: ImuRecord):
    types = typestore.types
    vector = types['geometry_msgs/msg/Vector3']
    return types[IMU_TYPE](
        header=_header(typestore, record.stamp_ns, record.frame_id),
        orientation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.array(record.orientation_covariance),
        angular_velocity=vector(*(float(v) for v in record.angular_velocity_rad_s)),
        angular_velocity_covariance=np.array(record.angular_velocity_covariance),
        linear_acceleration=vector(*(float(v) for v in record.linear_acceleration_m_s2)),
        linear_acceleration_covariance=np.array(record.linear_acceleration_covariance))


def _temperature_message(typestore, record: TemperatureRecord):
    return typestore.types[TEMPERATURE_TYPE](
        header=_header(typestore, record.stamp_ns, record.frame_id),
        temperature=record.temperature_c, variance=record.variance)


def _supply_voltage_message(typestore, record: SupplyVoltageRecord):
    types = typestore.types
    battery = types[SUPPLY_VOLTAGE_TYPE]
    # Only the voltage is measured: the rest is NaN or unknown, as the message defines.
    return battery(header=_header(typestore, record.stamp_ns, record.frame_id),
                   voltage=record.voltage_v, temperature=math.nan, current=math.nan,
                   charge=math.nan, capacity=math.nan, design_capacity=math.nan,
                   percentage=math.nan,
                   power_supply_status=battery.POWER_SUPPLY_STATUS_UNKNOWN,
                   power_supply_health=battery.POWER_SUPPLY_HEALTH_UNKNOWN,
                   power_supply_technology=battery.POWER_SUPPLY_TECHNOLOGY_UNKNOWN,
                   present=True, cell_voltage=np.array([], dtype=np.float32),
                   cell_temperature=np.array([], dtype=np.float32), location='',
                   serial_number='')


def _eeprom_message(typestore, record: EepromRecord):
    types = typestore.types
    dims, data = eeprom_multiarray_from_images(record.images)
    dimension = types['std_msgs/msg/MultiArrayDimension']
    layout = types['std_msgs/msg/MultiArrayLayout'](
        dim=[dimension(label=label, size=size, stride=stride) for label, size, stride in dims],
        data_offset=0)
    return types[EEPROM_TYPE](layout=layout, data=np.frombuffer(data, dtype=np.uint8))


def _check_record(record, record_type) -> None:
    if not isinstance(record, record_type):
        msg = f'expected a {record_type.__name__}, got {type(record).__name__}'
        raise BagError(msg)


class RawBagWriter:
    """
    Write our raw topics into a new rosbag2 folder (sqlite3 or mcap) with rosbags.

    The folder is created on construction. A connection is registered on the
    first message of each topic. Leaving the ``with`` block closes the bag
    and writes its metadata, also when an exception ends the block, so an
    interrupted recording keeps what it holds.
    """

    def __init__(self, path: PathLike, storage: str = 'sqlite3',
                 topics: RawTopics = RawTopics(), extra_temperature_topics: Sequence[str] = ()):
        self.path = Path(path)
        self.topics = topics
        self._wanted = wanted_topics(topics, extra_temperature_topics)
        self._typestore = jazzy_typestore()
        self._connections = {}
        if storage not in _STORAGE_PLUGINS:
            msg = f'unknown bag storage {storage!r}; use one of {", ".join(STORAGES)}'
            raise BagError(msg)
        self.storage = storage
        if self.path.exists():
            msg = f'{self.path} exists already; a bag is written into a new folder'
            raise BagError(msg)
        try:
            writer = Writer(self.path, version=BAG_VERSION,
                            storage_plugin=_STORAGE_PLUGINS[storage])
            writer.open()
        except (WriterError, OSError) as err:
            msg = f'cannot create bag {self.path}: {err}'
            raise BagError(msg) from None
        self._writer: Optional[Writer] = writer

    def __enter__(self) -> 'RawBagWriter':
        return self

    def __exit__(self, exc_type, exc_value, traceback) -> None:
        self.close()

    def close(self) -> None:
        """Finish the bag (write its metadata); safe to call twice."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            writer.close()
        except (WriterError, OSError) as err:
            msg = f'cannot finish bag {self.path}: {err}'
            raise BagError(msg) from None

    def _connection(self, topic: str, msgtype: str):
        if self._writer is None:
            msg = f'bag {self.path} is closed'
            raise BagError(msg)
        name = absolute_topic(topic)
        if name in self._connections:
            registered_type, connection = self._connections[name]
            if registered_type != msgtype:
                msg = f'topic {name} already holds {registered_type}, not {msgtype}'
                raise BagError(msg)
            return connection
        if msgtype not in self._typestore.types:
            msg = f'unknown message type {msgtype!r} for topic {name}'
            raise BagError(msg)
        try:
            connection = self._writer.add_connection(name, msgtype, typestore=self._typestore)
        except WriterError as err:
            msg = f'cannot add topic {name} to bag {self.path}: {err}'
            raise BagError(msg) from None
        self._connections[name] = (msgtype, connection)
        return connection

    def write_raw(self, bag_time_ns: int, topic: str, msgtype: str, cdr_bytes) -> None:
        """Write one already serialized (CDR) message, e.g. from rclpy's serialize_message."""
        bag_time_ns = checked_stamp_ns(bag_time_ns, 'bag_time_ns')
        if not 0 <= bag_time_ns <= _INT64_MAX:
            msg = f'bag_time_ns must be in 0..2^63-1, got {bag_time_ns}'
            raise BagError(msg)
        if not isinstance(cdr_bytes, (bytes, bytearray, memoryview)):
            msg = f'CDR data must be bytes, got {type(cdr_bytes).__name__}'
            raise BagError(msg)
        connection = self._connection(topic, msgtype)
        try:
            self._writer.write(connection, bag_time_ns, bytes(cdr_bytes))
        except (WriterError, OSError, SqliteError) as err:
            msg = f'cannot write to bag {self.path}: {err}'
            raise BagError(msg) from None

    def _write_message(self, bag_time_ns: int, topic: str, msgtype: str, message) -> None:
        try:
            data = self._typestore.serialize_cdr(message, msgtype)
        except SerdeError as err:
            msg = f'cannot serialize {msgtype} for {topic}: {err}'
            raise BagError(msg) from None
        self.write_raw(bag_time_ns, topic, msgtype, data)

    def write_imu(self, bag_time_ns: int, record: ImuRecord) -> None:
        """Write one IMU record on the IMU topic."""
        _check_record(record, ImuRecord)
        self._write_message(bag_time_ns, self.topics.imu, IMU_TYPE,
                            _imu_message(self._typestore, record))

    def write_temperature(self, bag_time_ns: int, record: TemperatureRecord,
                          topic: Optional[str] = None) -> None:
        """Write one temperature record on the temperature topic or an extra one."""
        _check_record(record, TemperatureRecord)
        topic = self.topics.temperature if topic is None else topic
        if self._wanted.get(absolute_topic(topic), (None,))[0] != TEMPERATURE:
            names = sorted(n for n, (kind, _) in self._wanted.items() if kind == TEMPERATURE)
            msg = f'{topic} is not a temperature topic of this bag ({", ".join(names)})'
            raise BagError(msg)
        self._write_message(bag_time_ns, topic, TEMPERATURE_TYPE,
                            _temperature_message(self._typestore, record))

    def write_supply_voltage(self, bag_time_ns: int, record: SupplyVoltageRecord) -> None:
        """Write one supply-voltage record on the supply-voltage topic."""
        _check_record(record, SupplyVoltageRecord)
        self._write_message(bag_time_ns, self.topics.supply_voltage, SUPPLY_VOLTAGE_TYPE,
                            _supply_voltage_message(self._typestore, record))

    def write_eeprom(self, bag_time_ns: int, record: EepromRecord) -> None:
        """Write the EEPROM images on the EEPROM topic."""
        _check_record(record, EepromRecord)
        self._write_message(bag_time_ns, self.topics.eeprom, EEPROM_TYPE,
                            _eeprom_message(self._typestore, record))
