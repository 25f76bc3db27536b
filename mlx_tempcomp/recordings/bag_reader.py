"""
Read our raw topics from a rosbag2 bag (sqlite3 or mcap) in bag-time order, without rclpy.

`RawBagReader` checks the topics and their types when it opens the bag, and
decodes each message into the records of `bag` (a message that does not
deserialize, or an EEPROM message with a wrong layout, is skipped and counted).
"""

from pathlib import Path
import struct
from typing import Iterator, Optional, Sequence, Tuple

import numpy as np
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.serde import SerdeError

from .bag import (absolute_topic, BagError, EEPROM, EEPROM_TYPE, EepromRecord, IMU, IMU_TYPE,
                  ImuRecord, jazzy_typestore, PathLike, RawTopics, SUPPLY, SUPPLY_VOLTAGE_TYPE,
                  SupplyVoltageRecord, TEMPERATURE, TEMPERATURE_TYPE, TemperatureRecord,
                  wanted_topics)
from .eeprom_multiarray import eeprom_images_from_multiarray
from ..core.errors import EepromError

try:  # the sqlite3 back end of rosbags >= 0.10; its errors can surface mid-iteration
    from apsw import Error as SqliteError
except ImportError:  # pragma: no cover
    from sqlite3 import Error as SqliteError

_NS_PER_S = 1_000_000_000
# rosbags reading a corrupt file: besides its ReaderError, a flipped byte or a cut file
# surfaces as a bad UTF-8 name or a negative seek (ValueError), an unknown type or schema
# id (KeyError), or a length too large to allocate (found by test/recordings/test_fuzz_readers.py).
_CORRUPT_FILE_ERRORS = (ValueError, KeyError, MemoryError, OverflowError, struct.error)
_STORAGE_ERRORS = (ReaderError, OSError, SqliteError) + _CORRUPT_FILE_ERRORS


def _storage_problem(err: Exception) -> str:
    if isinstance(err, _CORRUPT_FILE_ERRORS):
        return f'the file is corrupt ({type(err).__name__}: {err})'
    return str(err)


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
    try:
        images = eeprom_images_from_multiarray(dims, msg.data, msg.layout.data_offset)
    except EepromError as err:
        raise BagError(str(err)) from None
    return EepromRecord(images)


def _decode_supply_voltage(msg) -> SupplyVoltageRecord:
    stamp_ns, frame_id = _decode_header(msg.header)
    return SupplyVoltageRecord(stamp_ns=stamp_ns, frame_id=frame_id, voltage_v=msg.voltage)


_EXPECTED_TYPES = {IMU: IMU_TYPE, TEMPERATURE: TEMPERATURE_TYPE, EEPROM: EEPROM_TYPE,
                   SUPPLY: SUPPLY_VOLTAGE_TYPE}
_DECODERS = {IMU: _decode_imu, TEMPERATURE: _decode_temperature, EEPROM: _decode_eeprom,
             SUPPLY: _decode_supply_voltage}
# Messages the driver replays (the EEPROM is published once, before the replay).
_STREAMED = (IMU, TEMPERATURE, SUPPLY)


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
        self._typestore = jazzy_typestore()
        self._wanted = wanted_topics(topics, extra_temperature_topics)
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
        if IMU not in counts:
            present = ', '.join(f'{c.topic} ({c.msgtype})' for c in self._reader.connections)
            msg = (f'no IMU topic {absolute_topic(self.topics.imu)} in {self.path}; '
                   f'the bag has: {present or "no topics"}')
            raise BagError(msg)
        if counts[IMU] == 0:
            msg = (f'bag {self.path} is empty: no message on IMU topic '
                   f'{absolute_topic(self.topics.imu)}')
            raise BagError(msg)
        self._message_count = sum(counts.get(kind, 0) for kind in _STREAMED)
        self._supply_voltage_messages = counts.get(SUPPLY, 0)
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
        connections = self._connections({EEPROM})
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
                self._connections({EEPROM, *_STREAMED})):
            topic = self._routes[connection.id][1]
            try:
                record = self._decode(connection, data)
            except BagError as err:
                self.skipped += 1
                self.last_skip_reason = f'{connection.topic} at {bag_time_ns} ns: {err}'
                continue
            yield bag_time_ns, topic, record
