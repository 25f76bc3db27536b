"""
Our raw topics in rosbag2 bags: records, topic names and message types (reader and writer).

The bags are read (`bag_reader.RawBagReader`) and written
(`bag_writer.RawBagWriter`) with the pure-Python ``rosbags`` package (0.11)
and its ROS 2 Jazzy message definitions, so a bag recorded by ``ros2 bag
record`` replays here and a bag written here plays with ``ros2 bag play``.
Both rosbag2 storage formats are supported for reading and writing: sqlite3
and mcap. Bags are written in rosbag2 format version 8, the version ROS 2
Jazzy writes.

The raw topics:

- IMU rate (``sensor_msgs/msg/Imu``, ``/imu/data_raw``),
- die temperature (``sensor_msgs/msg/Temperature``, ``/imu/temperature_raw``,
  plus any extra temperature topics, e.g. one per chip),
- the EEPROM images (``std_msgs/msg/UInt8MultiArray``, ``/imu/eeprom``) laid
  out as dims [axis: size A, stride 128 A] and [byte: size 128, stride 128],
- optionally the supply voltage (``sensor_msgs/msg/BatteryState``, its
  ``voltage``, ``/imu/supply_voltage``), for models with supply terms.

Topic names match with or without their leading slash; the writer always
records the absolute name (with the slash), as ROS does.
"""

from dataclasses import dataclass
import functools
import operator
from pathlib import Path
from typing import Union

import numpy as np
from rosbags.typesys import get_typestore, Stores

from .eeprom_multiarray import checked_images
from .errors import RecordFileError
from ..core.errors import EepromError

IMU_TYPE = 'sensor_msgs/msg/Imu'
TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'
EEPROM_TYPE = 'std_msgs/msg/UInt8MultiArray'
SUPPLY_VOLTAGE_TYPE = 'sensor_msgs/msg/BatteryState'

STORAGES = ('sqlite3', 'mcap')
BAG_VERSION = 8  # rosbag2 metadata version of ROS 2 Jazzy

# The kinds of raw topic, as messages name them.
IMU, TEMPERATURE, EEPROM, SUPPLY = 'imu', 'temperature', 'eeprom', 'supply voltage'

PathLike = Union[str, Path]


class BagError(RecordFileError):
    """A bag cannot be read or written, or a record does not fit its message."""


@functools.lru_cache(maxsize=None)
def jazzy_typestore():
    """Give the ROS 2 Jazzy message definitions (built once, about 0.1 s)."""
    return get_typestore(Stores.ROS2_JAZZY)


def checked_stamp_ns(value, what: str) -> int:
    """Give ``value`` as an integer number of nanoseconds; BagError naming ``what`` if not."""
    try:
        stamp_ns = operator.index(value)
    except TypeError:
        msg = f'{what} must be an integer number of nanoseconds, got {value!r}'
        raise BagError(msg) from None
    return stamp_ns


def _float_array(value, size: int, name: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        msg = f'{name}: not an array of numbers ({err})'
        raise BagError(msg) from None
    if array.shape != (size,):
        msg = f'{name}: expected shape ({size},), got {array.shape}'
        raise BagError(msg)
    array.flags.writeable = False
    return array


def _same_arrays(a: np.ndarray, b: np.ndarray) -> bool:
    return np.array_equal(a, b, equal_nan=True)


@dataclass(frozen=True, eq=False)
class ImuRecord:
    """
    One raw IMU message: rates and accelerations with their covariances.

    Arrays are float64 copies, read-only. NaN marks an axis that is not
    measured (e.g. a single-axis gyro). Equality compares values, NaN equal
    to NaN.
    """

    stamp_ns: int
    frame_id: str
    angular_velocity_rad_s: np.ndarray
    angular_velocity_covariance: np.ndarray
    linear_acceleration_m_s2: np.ndarray
    linear_acceleration_covariance: np.ndarray
    orientation_covariance: np.ndarray

    _ARRAYS = (('angular_velocity_rad_s', 3), ('angular_velocity_covariance', 9),
               ('linear_acceleration_m_s2', 3), ('linear_acceleration_covariance', 9),
               ('orientation_covariance', 9))

    def __post_init__(self):
        object.__setattr__(self, 'stamp_ns',
                           checked_stamp_ns(self.stamp_ns, 'ImuRecord.stamp_ns'))
        object.__setattr__(self, 'frame_id', str(self.frame_id))
        for name, size in self._ARRAYS:
            array = _float_array(getattr(self, name), size, f'ImuRecord.{name}')
            object.__setattr__(self, name, array)

    def __eq__(self, other):
        if not isinstance(other, ImuRecord):
            return NotImplemented
        return (self.stamp_ns == other.stamp_ns and self.frame_id == other.frame_id
                and all(_same_arrays(getattr(self, name), getattr(other, name))
                        for name, _ in self._ARRAYS))


@dataclass(frozen=True)
class TemperatureRecord:
    """One raw temperature message (degrees Celsius, variance in C^2)."""

    stamp_ns: int
    frame_id: str
    temperature_c: float
    variance: float

    def __post_init__(self):
        object.__setattr__(self, 'stamp_ns',
                           checked_stamp_ns(self.stamp_ns, 'TemperatureRecord.stamp_ns'))
        object.__setattr__(self, 'frame_id', str(self.frame_id))
        object.__setattr__(self, 'temperature_c', float(self.temperature_c))
        object.__setattr__(self, 'variance', float(self.variance))


@dataclass(frozen=True)
class SupplyVoltageRecord:
    """
    One supply-voltage message: the voltage of a sensor_msgs/BatteryState.

    The message holds it as a float32, so volts come back rounded to float32
    (about 0.5 uV at 5 V).
    """

    stamp_ns: int
    frame_id: str
    voltage_v: float

    def __post_init__(self):
        object.__setattr__(self, 'stamp_ns',
                           checked_stamp_ns(self.stamp_ns, 'SupplyVoltageRecord.stamp_ns'))
        object.__setattr__(self, 'frame_id', str(self.frame_id))
        object.__setattr__(self, 'voltage_v', float(self.voltage_v))


@dataclass(frozen=True)
class EepromRecord:
    """The EEPROM images of every axis, 128 bytes each, in axis order."""

    images: tuple

    def __post_init__(self):
        try:
            images = checked_images(self.images)
        except EepromError as err:
            raise BagError(f'EepromRecord.images: {err}') from None
        object.__setattr__(self, 'images', images)


@dataclass(frozen=True)
class RawTopics:
    """Names of the raw topics; a leading slash is optional."""

    imu: str = '/imu/data_raw'
    temperature: str = '/imu/temperature_raw'
    eeprom: str = '/imu/eeprom'
    supply_voltage: str = '/imu/supply_voltage'


def absolute_topic(topic: str) -> str:
    """Give the topic name with exactly one leading slash."""
    return '/' + str(topic).lstrip('/')


def wanted_topics(topics: RawTopics, extra_temperature_topics) -> dict:
    """Map absolute topic name -> (kind, the caller's spelling)."""
    if isinstance(extra_temperature_topics, str):
        extra_temperature_topics = (extra_temperature_topics,)
    wanted = {}
    entries = [(topics.imu, IMU), (topics.temperature, TEMPERATURE), (topics.eeprom, EEPROM),
               (topics.supply_voltage, SUPPLY)]
    entries += [(topic, TEMPERATURE) for topic in extra_temperature_topics]
    for topic, kind in entries:
        name = absolute_topic(topic)
        if name in wanted and wanted[name][0] != kind:
            msg = f'topic {name} is configured both as {wanted[name][0]} and as {kind}'
            raise BagError(msg)
        wanted.setdefault(name, (kind, topic))
    return wanted
