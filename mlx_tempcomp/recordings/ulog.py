"""
PX4 ULog (``.ulg``) logs read with pyulog: one IMU instance per ``sensor_gyro`` multi_id.

Only ``sensor_gyro``, ``sensor_accel`` and ``sensor_combined`` are loaded
(pyulog's message_name_filter_list), so memory follows those topics, not the
log. Units are those msg/SensorGyro.msg and SensorAccel.msg declare: x, y, z
in rad/s (m/s^2), temperature in degC; ``timestamp`` in microseconds since
boot. ``sensor_gyro`` holds raw rates, before the CAL_GYROn offsets. The
vehicle's motion is found on ``sensor_combined`` (about 200 Hz), which sees
a hop that the 1 Hz ``sensor_gyro`` samples of the default log profile miss;
without it, on the instance's own samples.

A file cut inside a message is said to be cut (`file_end`): the ULog spec
has readers drop that message, and pyulog does so without a word. A file cut
exactly between two messages cannot be told from a whole one: ULog declares
no length and has no end marker (its sync messages are for resynchronising
after corruption); only appended data the flag-bits header declares past the
end shows a cut there.
"""

import contextlib
import io
import mmap
import os
import struct

import numpy as np

from .flightlog import FlightLog, FlightLogError, ImuInstance, register
from ..core.standstill import MOTION_MARGIN_S, moving_samples, near

TOPICS = ('sensor_gyro', 'sensor_accel', 'sensor_combined')
UNITS_NOTE = 'units as PX4 msg/SensorGyro.msg declares them: rad/s, m/s^2, degC'
# An accel sample pairs with a gyro sample of the same instance stamped this close.
PAIR_TOLERANCE_S = 0.1
_US = 1e-6
# The file header (magic, version, timestamp), then messages: uint16 size, uint8 type, data.
FILE_HEADER_BYTES = 16
MESSAGE_HEADER = struct.Struct('<HB')
# The flag-bits message ('B', first after the header): compat[8], incompat[8], offsets[3].
FLAG_BITS = ord('B')
FLAG_BITS_BODY = struct.Struct('<8B8B3Q')
DATA_APPENDED = 0x1


def _release(value) -> str:
    """Give PX4's release number, ver_sw_release = 0xMMmmppTT, as vMM.mm.pp."""
    try:
        number = int(value)
    except (TypeError, ValueError):
        return '?'
    return f'v{number >> 24 & 0xFF}.{number >> 16 & 0xFF}.{number >> 8 & 0xFF}'


def _columns(data, names) -> np.ndarray:
    return np.column_stack([np.asarray(data[name], dtype=np.float64) for name in names])


def _paired_accel(gyro_time_s: np.ndarray, accel) -> np.ndarray:
    """Give the accel sample nearest each gyro sample (NaN where none is close)."""
    paired = np.full((gyro_time_s.size, 3), np.nan)
    if accel is None or not accel['timestamp'].size:
        return paired
    time_s = accel['timestamp'] * _US
    values = _columns(accel, ('x', 'y', 'z'))
    after = np.clip(np.searchsorted(time_s, gyro_time_s), 0, time_s.size - 1)
    before = np.clip(after - 1, 0, time_s.size - 1)
    nearest = np.where(np.abs(time_s[before] - gyro_time_s) < np.abs(time_s[after] - gyro_time_s),
                       before, after)
    close = np.abs(time_s[nearest] - gyro_time_s) <= PAIR_TOLERANCE_S
    paired[close] = values[nearest[close]]
    return paired


def _device_id(data):
    """Give a topic's device_id, or None when it has none or several."""
    ids = np.unique(data['device_id']) if 'device_id' in data else ()
    return int(ids[0]) if len(ids) == 1 else None


def _motion_times(combined):
    """Give the stamps of sensor_combined's moving samples, or None without the topic."""
    if combined is None or combined['timestamp'].size < 2:
        return None
    time_s = combined['timestamp'] * _US
    moving = moving_samples(time_s, _columns(combined, [f'gyro_rad[{i}]' for i in range(3)]),
                            _columns(combined, [f'accelerometer_m_s2[{i}]' for i in range(3)]))
    return time_s[moving]


def _instance(gyro, accel, motion_times) -> ImuInstance:
    data = gyro.data
    order = np.argsort(data['timestamp'], kind='stable')
    time_s = data['timestamp'][order] * _US
    rate = _columns(data, ('x', 'y', 'z'))[order]
    acceleration = _paired_accel(time_s, None if accel is None else accel.data)
    if motion_times is None:
        moving = moving_samples(time_s, rate, acceleration)
    else:
        moving = near(time_s, motion_times, MOTION_MARGIN_S)
    return ImuInstance(
        index=int(gyro.multi_id), name=f'sensor_gyro[{gyro.multi_id}]',
        device_id=_device_id(data),
        accel_device_id=None if accel is None else _device_id(accel.data), time_s=time_s,
        temperature_c=np.asarray(data['temperature'], dtype=np.float64)[order],
        gyro_rad_s=rate,
        acceleration_m_s2=None if np.isnan(acceleration).all() else acceleration,
        moving=moving)


def file_end(path) -> str:
    """
    Say how a ULog file is cut short; '' when it ends where a message ends.

    Walks the message headers (memory-mapped, nothing kept): the file is cut
    when its last message runs past the end, or when the flag-bits message
    declares data appended at an offset past the end.
    """
    with open(path, 'rb') as handle:
        size = os.fstat(handle.fileno()).st_size
        if size <= FILE_HEADER_BYTES:
            return ''
        with mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as data:
            start = FILE_HEADER_BYTES
            body = start + MESSAGE_HEADER.size
            length, kind = MESSAGE_HEADER.unpack_from(data, start)
            if kind == FLAG_BITS and length >= FLAG_BITS_BODY.size \
                    and size >= body + FLAG_BITS_BODY.size:
                fields = FLAG_BITS_BODY.unpack_from(data, body)
                offsets = [offset for offset in fields[16:] if offset]
                if fields[8] & DATA_APPENDED and offsets:
                    if max(offsets) > size:
                        return (f'its header declares data appended at byte {max(offsets)}; '
                                f'the file ends at byte {size}')
                    # What comes before an appended part may end inside a message.
                    start = max(start, *offsets)
            position = start
            while position + MESSAGE_HEADER.size <= size:
                length, _ = MESSAGE_HEADER.unpack_from(data, position)
                if position + MESSAGE_HEADER.size + length > size:
                    break
                position += MESSAGE_HEADER.size + length
    if position == size:
        return ''
    return (f'the last {size - position} bytes (from byte {position}) are a message cut off, '
            'not read')


def read_ulog(path) -> FlightLog:
    """Read the IMU instances of a ULog file; FlightLogError when pyulog cannot."""
    from pyulog import ULog
    chatter = io.StringIO()
    try:
        # pyulog prints what it finds wrong; it becomes a note, not stray output.
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            ulog = ULog(str(path), message_name_filter_list=list(TOPICS))
    except Exception as err:  # noqa: B902 - pyulog raises any type on a damaged file
        msg = f'{path}: not a readable ULog file ({type(err).__name__}: {err})'
        raise FlightLogError(msg) from None
    topics = {(d.name, d.multi_id): d for d in ulog.data_list}
    combined = topics.get(('sensor_combined', 0))
    motion_times = _motion_times(None if combined is None else combined.data)
    try:
        instances = [_instance(d, topics.get(('sensor_accel', multi_id)), motion_times)
                     for (name, multi_id), d in sorted(topics.items()) if name == 'sensor_gyro']
    except (KeyError, ValueError) as err:
        msg = f'{path}: sensor_gyro lacks a field PX4 logs ({err})'
        raise FlightLogError(msg) from None
    info = ulog.msg_info_dict
    notes = [UNITS_NOTE]
    if motion_times is not None:
        notes.append('motion found on sensor_combined')
    if ulog.file_corruption or chatter.getvalue().strip():
        said = ' '.join(chatter.getvalue().split())[:200]
        notes.append(f'file damaged or cut short: read what pyulog could ({said or "corrupt"})')
    else:
        cut = file_end(path)
        if cut:
            notes.append(f'file cut short: {cut}')
    if ulog.dropouts:
        lost_ms = sum(d.duration for d in ulog.dropouts)
        notes.append(f'{len(ulog.dropouts)} logger dropouts, {lost_ms} ms in all')
    system = f'PX4 {_release(info.get("ver_sw_release"))}, {info.get("ver_hw", "board ?")}'
    return FlightLog(source=str(path), log_format='PX4 ULog', system=system,
                     instances=instances, parameters=dict(ulog.initial_parameters),
                     notes=notes)


register('.ulg', read_ulog)
