"""
Read and write our raw topics in rosbag2 folders, without rclpy.

Uses the pure-Python ``rosbags`` package (0.11) and its ROS 2 Jazzy message
definitions, so a bag recorded by ``ros2 bag record`` replays here and a bag
written here plays with ``ros2 bag play``. Both rosbag2 storage formats are
supported for reading and writing: sqlite3 and mcap. Bags are written in
rosbag2 format version 8, the version ROS 2 Jazzy writes.

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
import math
import operator
from pathlib import Path
import struct
from typing import Iterator, Optional, Sequence, Tuple, Union

import numpy as np
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import get_typestore, Stores

from .errors import SourceError
from ..core.eeprom import EEPROM_SIZE

try:  # the sqlite3 back end of rosbags >= 0.10; its errors can surface mid-iteration
    from apsw import Error as _SqliteError
except ImportError:  # pragma: no cover
    from sqlite3 import Error as _SqliteError

IMU_TYPE = 'sensor_msgs/msg/Imu'
TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'
EEPROM_TYPE = 'std_msgs/msg/UInt8MultiArray'
SUPPLY_VOLTAGE_TYPE = 'sensor_msgs/msg/BatteryState'

STORAGES = ('sqlite3', 'mcap')
BAG_VERSION = 8  # rosbag2 metadata version of ROS 2 Jazzy

_NS_PER_S = 1_000_000_000
_INT32_MAX = 2**31 - 1
_INT64_MAX = 2**63 - 1
# rosbags reading a corrupt file: besides its ReaderError, a flipped byte or a cut file
# surfaces as a bad UTF-8 name or a negative seek (ValueError), an unknown type or schema
# id (KeyError), or a length too large to allocate (found by test/test_fuzz_readers.py).
_CORRUPT_FILE_ERRORS = (ValueError, KeyError, MemoryError, OverflowError, struct.error)
_STORAGE_ERRORS = (ReaderError, OSError, _SqliteError) + _CORRUPT_FILE_ERRORS
_STORAGE_PLUGINS = {'sqlite3': StoragePlugin.SQLITE3, 'mcap': StoragePlugin.MCAP}

PathLike = Union[str, Path]


class BagError(SourceError):
    """A bag cannot be read or written, or a record does not fit its message."""


def _storage_problem(err: Exception) -> str:
    if isinstance(err, _CORRUPT_FILE_ERRORS):
        return f'the file is corrupt ({type(err).__name__}: {err})'
    return str(err)


@functools.lru_cache(maxsize=None)
def _typestore():
    """Give the ROS 2 Jazzy message definitions (built once, about 0.1 s)."""
    return get_typestore(Stores.ROS2_JAZZY)


def _stamp_ns(value, what: str) -> int:
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
        object.__setattr__(self, 'stamp_ns', _stamp_ns(self.stamp_ns, 'ImuRecord.stamp_ns'))
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
                           _stamp_ns(self.stamp_ns, 'TemperatureRecord.stamp_ns'))
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
                           _stamp_ns(self.stamp_ns, 'SupplyVoltageRecord.stamp_ns'))
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


def _decode_header(header) -> Tuple[int, str]:
    return header.stamp.sec * _NS_PER_S + header.stamp.nanosec, header.frame_id


def _vector(vector) -> np.ndarray:
    return np.array([vector.x, vector.y, vector.z], dtype=np.float64)


def _decode_imu(msg) -> ImuRecord:
    stamp_ns, frame_id = _decode_header(msg.header)
    return ImuRecord(stamp_ns=stamp_ns, frame_id=frame_id,
                     angular_velocity_rad_s=_vector(msg.angular_velocity),
                     angular_velocity_covariance=msg.angular_velocity_covariance,
                     linear_acceleration_m_s2=_vector(msg.linear_acceleration),
                     linear_acceleration_covariance=msg.linear_acceleration_covariance,
                     orientation_covariance=msg.orientation_covariance)


def _decode_temperature(msg) -> TemperatureRecord:
    stamp_ns, frame_id = _decode_header(msg.header)
    return TemperatureRecord(stamp_ns=stamp_ns, frame_id=frame_id,
                             temperature_c=msg.temperature, variance=msg.variance)


def _decode_eeprom(msg) -> EepromRecord:
    dims = [(dim.label, dim.size, dim.stride) for dim in msg.layout.dim]
    return EepromRecord(eeprom_images_from_multiarray(dims, msg.data, msg.layout.data_offset))


def _decode_supply_voltage(msg) -> SupplyVoltageRecord:
    stamp_ns, frame_id = _decode_header(msg.header)
    return SupplyVoltageRecord(stamp_ns=stamp_ns, frame_id=frame_id, voltage_v=msg.voltage)


_IMU, _TEMPERATURE, _EEPROM, _SUPPLY = 'imu', 'temperature', 'eeprom', 'supply voltage'
_EXPECTED_TYPES = {_IMU: IMU_TYPE, _TEMPERATURE: TEMPERATURE_TYPE, _EEPROM: EEPROM_TYPE,
                   _SUPPLY: SUPPLY_VOLTAGE_TYPE}
_DECODERS = {_IMU: _decode_imu, _TEMPERATURE: _decode_temperature, _EEPROM: _decode_eeprom,
             _SUPPLY: _decode_supply_voltage}
# Messages the driver replays (the EEPROM is published once, before the replay).
_STREAMED = (_IMU, _TEMPERATURE, _SUPPLY)


def _wanted_topics(topics: RawTopics, extra_temperature_topics) -> dict:
    """Map absolute topic name -> (kind, the caller's spelling)."""
    if isinstance(extra_temperature_topics, str):
        extra_temperature_topics = (extra_temperature_topics,)
    wanted = {}
    entries = [(topics.imu, _IMU), (topics.temperature, _TEMPERATURE), (topics.eeprom, _EEPROM),
               (topics.supply_voltage, _SUPPLY)]
    entries += [(topic, _TEMPERATURE) for topic in extra_temperature_topics]
    for topic, kind in entries:
        name = absolute_topic(topic)
        if name in wanted and wanted[name][0] != kind:
            msg = f'topic {name} is configured both as {wanted[name][0]} and as {kind}'
            raise BagError(msg)
        wanted.setdefault(name, (kind, topic))
    return wanted


class RawBagReader:
    """
    Open a rosbag2 folder (sqlite3 or mcap) and iterate our raw topics in bag-time order.

    The bag is opened and checked on construction: it must hold the IMU topic
    with at least one message, and every raw topic it holds must have the
    expected message type. The temperature, EEPROM and supply-voltage topics
    are optional.
    A bare ``.db3`` or ``.mcap`` file is accepted too.

    ``records()`` yields ``(bag_time_ns, topic, record)`` where ``topic`` is
    spelled as configured (in ``topics`` or ``extra_temperature_topics``)
    whatever the bag's spelling. A message that does not deserialize, or an
    EEPROM message with a wrong layout, is skipped: ``skipped`` counts them
    in the current (latest) pass and ``last_skip_reason`` says why.
    """

    def __init__(self, path: PathLike, topics: RawTopics = RawTopics(),
                 extra_temperature_topics: Sequence[str] = ()):
        self.path = Path(path)
        self.topics = topics
        self.skipped = 0
        self.last_skip_reason: Optional[str] = None
        self._typestore = _typestore()
        self._wanted = _wanted_topics(topics, extra_temperature_topics)
        self._eeprom: Optional[EepromRecord] = None
        self._eeprom_read = False
        self._reader = self._open_reader()
        try:
            self._routes = self._check_connections()
        except BagError:
            self.close()
            raise

    def _open_reader(self) -> Reader:
        if not self.path.exists():
            msg = f'bag {self.path} does not exist'
            raise BagError(msg)
        if self.path.is_dir() and not (self.path / 'metadata.yaml').is_file():
            msg = f'{self.path} is not a rosbag2 folder: it has no metadata.yaml'
            raise BagError(msg)
        try:
            reader = Reader(self.path)
            reader.open()
        except _STORAGE_ERRORS as err:
            msg = f'cannot open bag {self.path}: {_storage_problem(err)}'
            raise BagError(msg) from None
        return reader

    def _check_connections(self) -> dict:
        """Check topics and types; map connection id -> (kind, caller's topic)."""
        routes = {}
        counts = {}
        for connection in self._reader.connections:
            name = absolute_topic(connection.topic)
            if name not in self._wanted:
                continue
            kind, topic = self._wanted[name]
            if connection.msgtype != _EXPECTED_TYPES[kind]:
                msg = (f'topic {connection.topic} in {self.path} has type '
                       f'{connection.msgtype}, expected {_EXPECTED_TYPES[kind]}')
                raise BagError(msg)
            routes[connection.id] = (kind, topic)
            counts[kind] = counts.get(kind, 0) + connection.msgcount
        if _IMU not in counts:
            present = ', '.join(f'{c.topic} ({c.msgtype})' for c in self._reader.connections)
            msg = (f'no IMU topic {absolute_topic(self.topics.imu)} in {self.path}; '
                   f'the bag has: {present or "no topics"}')
            raise BagError(msg)
        if counts[_IMU] == 0:
            msg = (f'bag {self.path} is empty: no message on IMU topic '
                   f'{absolute_topic(self.topics.imu)}')
            raise BagError(msg)
        self._message_count = sum(counts.get(kind, 0) for kind in _STREAMED)
        self._supply_voltage_messages = counts.get(_SUPPLY, 0)
        return routes

    def __enter__(self) -> 'RawBagReader':
        return self

    def __exit__(self, exc_type, exc_value, traceback) -> None:
        self.close()

    def close(self) -> None:
        """Close the bag; safe to call twice."""
        reader, self._reader = self._reader, None
        if reader is not None and reader.is_open:
            reader.close()

    def _open(self) -> Reader:
        if self._reader is None:
            msg = f'bag {self.path} is closed'
            raise BagError(msg)
        return self._reader

    @property
    def bag_topics(self) -> dict:
        """Every topic in the bag (as spelled there) with its message type."""
        return {c.topic: c.msgtype for c in self._open().connections}

    @property
    def message_count(self) -> int:
        """Messages on the IMU, temperature and supply-voltage topics, from the metadata."""
        return self._message_count

    @property
    def has_supply_voltage(self) -> bool:
        """Tell whether the bag holds supply-voltage messages."""
        return self._supply_voltage_messages > 0

    def _connections(self, kinds) -> list:
        return [c for c in self._open().connections
                if c.id in self._routes and self._routes[c.id][0] in kinds]

    def _messages(self, connections) -> Iterator[tuple]:
        if not connections:
            return
        try:
            yield from self._open().messages(connections=connections)
        except _STORAGE_ERRORS as err:
            msg = f'cannot read bag {self.path}: {_storage_problem(err)}'
            raise BagError(msg) from None

    def _decode(self, connection, data):
        """Give the record of one message; raise BagError if it is corrupt."""
        kind = self._routes[connection.id][0]
        try:
            msg = self._typestore.deserialize_cdr(data, connection.msgtype)
        except SerdeError as err:
            raise BagError(str(err)) from None
        return _DECODERS[kind](msg)

    @property
    def eeprom(self) -> Optional[EepromRecord]:
        """
        Give the first valid EEPROM message in the bag, or None without any.

        Reads only the EEPROM topic, once. Raises BagError when the bag has
        EEPROM messages but none of them is valid.
        """
        if self._eeprom_read:
            return self._eeprom
        connections = self._connections({_EEPROM})
        first_error = None
        messages = self._messages(connections)
        try:
            for connection, bag_time_ns, data in messages:
                try:
                    self._eeprom = self._decode(connection, data)
                    break
                except BagError as err:
                    first_error = first_error or f'at {bag_time_ns} ns: {err}'
        finally:
            messages.close()
        if self._eeprom is None and first_error is not None:
            msg = (f'no valid EEPROM message on {absolute_topic(self.topics.eeprom)} in '
                   f'{self.path}; the first fails {first_error}')
            raise BagError(msg)
        self._eeprom_read = True
        return self._eeprom

    def records(self) -> Iterator[Tuple[int, str, object]]:
        """
        Yield ``(bag_time_ns, topic, record)`` of every raw message in bag-time order.

        ``record`` is an ImuRecord, TemperatureRecord, SupplyVoltageRecord or
        EepromRecord. Corrupt messages are skipped and counted in ``skipped``.
        """
        self.skipped = 0
        self.last_skip_reason = None
        for connection, bag_time_ns, data in self._messages(
                self._connections({_EEPROM, *_STREAMED})):
            topic = self._routes[connection.id][1]
            try:
                record = self._decode(connection, data)
            except BagError as err:
                self.skipped += 1
                self.last_skip_reason = f'{connection.topic} at {bag_time_ns} ns: {err}'
                continue
            yield bag_time_ns, topic, record


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
        self._wanted = _wanted_topics(topics, extra_temperature_topics)
        self._typestore = _typestore()
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
        bag_time_ns = _stamp_ns(bag_time_ns, 'bag_time_ns')
        if not 0 <= bag_time_ns <= _INT64_MAX:
            msg = f'bag_time_ns must be in 0..2^63-1, got {bag_time_ns}'
            raise BagError(msg)
        if not isinstance(cdr_bytes, (bytes, bytearray, memoryview)):
            msg = f'CDR data must be bytes, got {type(cdr_bytes).__name__}'
            raise BagError(msg)
        connection = self._connection(topic, msgtype)
        try:
            self._writer.write(connection, bag_time_ns, bytes(cdr_bytes))
        except (WriterError, OSError, _SqliteError) as err:
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
        if self._wanted.get(absolute_topic(topic), (None,))[0] != _TEMPERATURE:
            names = sorted(n for n, (kind, _) in self._wanted.items() if kind == _TEMPERATURE)
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
