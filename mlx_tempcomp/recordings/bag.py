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
from typing import Sequence, Tuple, Union

import numpy as np
from rosbags.typesys import get_typestore, Stores

from .errors import RecordFileError
from ..core.eeprom import EEPROM_SIZE

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


def _image_bytes(image, index: int) -> bytes:
    if not isinstance(image, (bytes, bytearray, memoryview)):
        msg = f'EEPROM image {index}: expected bytes, got {type(image).__name__}'
        raise BagError(msg)
    image = bytes(image)
    if len(image) != EEPROM_SIZE:
        msg = f'EEPROM image {index}: expected {EEPROM_SIZE} bytes, got {len(image)}'
        raise BagError(msg)
    return image


@dataclass(frozen=True)
class EepromRecord:
    """The EEPROM images of every axis, 128 bytes each, in axis order."""

    images: tuple

    def __post_init__(self):
        if isinstance(self.images, (bytes, bytearray, memoryview, str)):
            msg = 'EepromRecord.images: expected a sequence of images, got one bytes object'
            raise BagError(msg)
        images = tuple(_image_bytes(image, i) for i, image in enumerate(self.images))
        if not images:
            msg = 'EepromRecord.images: no image'
            raise BagError(msg)
        object.__setattr__(self, 'images', images)


LayoutDim = Tuple[str, int, int]


def _data_bytes(data) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    array = np.asarray(data)
    if array.ndim != 1 or (array.size and array.dtype.kind not in 'iu'):
        msg = f'EEPROM data must be a flat sequence of bytes, got {type(data).__name__}'
        raise BagError(msg)
    if array.size and (array.min() < 0 or array.max() > 255):
        msg = 'EEPROM data holds values outside 0..255'
        raise BagError(msg)
    return array.astype(np.uint8).tobytes()


def eeprom_images_from_multiarray(layout_dims: Sequence[LayoutDim], data,
                                  data_offset: int = 0) -> Tuple[bytes, ...]:
    """
    Check a UInt8MultiArray EEPROM layout and split its data into images.

    Plain values only, so the ROS node and the bag reader share this check.

    Parameters
    ----------
    layout_dims
        ``(label, size, stride)`` of each ``layout.dim`` entry; expected
        ``[('axis', A, 128 A), ('byte', 128, 128)]`` with A >= 1.
    data
        The concatenated images: bytes, bytearray, memoryview, array.array
        or a sequence of ints in 0..255.
    data_offset
        ``layout.data_offset``; the images start there.

    Returns
    -------
    tuple of bytes
        One 128-byte image per axis.

    Raises
    ------
    BagError
        Naming the first thing that does not fit.

    """
    dims = [tuple(dim) for dim in layout_dims]
    if len(dims) != 2 or any(len(dim) != 3 for dim in dims):
        msg = (f'EEPROM layout must have 2 dims (label, size, stride): axis and byte; '
               f'got {dims}')
        raise BagError(msg)
    (axis_label, axes, axis_stride), (byte_label, byte_size, byte_stride) = dims
    if (axis_label, byte_label) != ('axis', 'byte'):
        msg = f"EEPROM layout labels must be 'axis' and 'byte', got {axis_label!r} and " \
              f'{byte_label!r}'
        raise BagError(msg)
    if byte_size != EEPROM_SIZE or byte_stride != EEPROM_SIZE:
        msg = (f'EEPROM byte dim must have size and stride {EEPROM_SIZE}, got size '
               f'{byte_size} and stride {byte_stride}')
        raise BagError(msg)
    if axes < 1:
        msg = f'EEPROM axis dim must have size >= 1, got {axes}'
        raise BagError(msg)
    if axis_stride != axes * EEPROM_SIZE:
        msg = (f'EEPROM axis dim stride must be {axes} x {EEPROM_SIZE} = '
               f'{axes * EEPROM_SIZE}, got {axis_stride}')
        raise BagError(msg)
    if data_offset < 0:
        msg = f'EEPROM data_offset must be >= 0, got {data_offset}'
        raise BagError(msg)
    raw = _data_bytes(data)
    expected = data_offset + axes * EEPROM_SIZE
    if len(raw) != expected:
        msg = (f'EEPROM data has {len(raw)} bytes; the layout ({axes} axes x {EEPROM_SIZE} '
               f'bytes + offset {data_offset}) needs {expected}')
        raise BagError(msg)
    return tuple(raw[data_offset + i * EEPROM_SIZE:data_offset + (i + 1) * EEPROM_SIZE]
                 for i in range(axes))


def eeprom_multiarray_from_images(images: Sequence[bytes]) -> Tuple[list, bytes]:
    """Give the ``(layout_dims, data)`` of a UInt8MultiArray carrying the images."""
    images = EepromRecord(tuple(images)).images
    axes = len(images)
    dims = [('axis', axes, axes * EEPROM_SIZE), ('byte', EEPROM_SIZE, EEPROM_SIZE)]
    return dims, b''.join(images)


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
