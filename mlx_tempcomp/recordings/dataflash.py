"""
ArduPilot DataFlash (``.bin``) logs read with pymavlink's DFReader: one IMU instance per IMU.

Only the IMU, PARM and MSG messages are decoded (DFReader's type filter; the
file is memory-mapped). Modern logs have one ``IMU`` type with an instance
column ``I``; older ones have ``IMU``, ``IMU2``, ``IMU3`` and no ``I``.
Device ids are the ``INS_GYRn_ID`` parameters (``INSn_GYR_ID`` from IMU 4 on).
Units come from the log's FMTU/UNIT/MULT messages when it has them (rad/s
or deg/s, m/s/s, degC); without them, those LogStructure.h documents (rad/s,
m/s/s, degC) are assumed and a note says so. Time is ``TimeUS``
(microseconds since boot). Motion is found on each instance's own samples.

The ``IMU`` rates and accelerations are in the vehicle's frame: ArduPilot
rotates each sample by ``AHRS_ORIENTATION`` after its offsets and thermal
corrections (``AP_InertialSensor_Backend::_rotate_and_correct_gyro``), so the
INS_TCAL coefficients act in the sensor frame before that rotation.
`board_rotation` gives that rotation from ArduPilot's table.
"""

import contextlib
import io
import math
import os
import re
import sys
import tempfile

import numpy as np

from .flightlog import FlightLog, FlightLogError, ImuInstance, register
from ..core.standstill import moving_samples

IMU_TYPES = ('IMU', 'IMU2', 'IMU3')
MESSAGES = IMU_TYPES + ('PARM', 'MSG')
_FIELDS = ('GyrX', 'GyrY', 'GyrZ', 'AccX', 'AccY', 'AccZ', 'T')
# Each unit a log may declare for a field, and its factor to SI.
UNIT_FACTORS = {
    'gyro': {'rad/s': 1.0, 'deg/s': math.pi / 180.0, 'mrad/s': 1e-3},
    'acceleration': {'m/s/s': 1.0, 'm/s^2': 1.0, 'mm/s/s': 1e-3},
    'temperature': {'degC': 1.0, 'cdegC': 0.01},
}
_KIND = {'GyrX': 'gyro', 'GyrY': 'gyro', 'GyrZ': 'gyro', 'AccX': 'acceleration',
         'AccY': 'acceleration', 'AccZ': 'acceleration', 'T': 'temperature'}
_FIRMWARE = re.compile(r'^(Ardu\w+|APM:\w+)\s+V\S+')
# AHRS_ORIENTATION values as (roll, pitch, yaw) in degrees, AP_Math/rotations.h order:
# the rotation is Matrix3::from_euler(roll, pitch, yaw). 38 (ROLL_90_PITCH_68_YAW_293) is
# the matrix vector3.cpp spells out, which is from_euler(90, 68.8, 293.3). Values 42 on
# (ROLL_45, ROLL_315, the custom ones) are past tempcal_IMU.py's table (pymavlink rotmat).
BOARD_ROTATIONS_DEG = (
    (0, 0, 0), (0, 0, 45), (0, 0, 90), (0, 0, 135), (0, 0, 180), (0, 0, 225), (0, 0, 270),
    (0, 0, 315), (180, 0, 0), (180, 0, 45), (180, 0, 90), (180, 0, 135), (0, 180, 0),
    (180, 0, 225), (180, 0, 270), (180, 0, 315), (90, 0, 0), (90, 0, 45), (90, 0, 90),
    (90, 0, 135), (270, 0, 0), (270, 0, 45), (270, 0, 90), (270, 0, 135), (0, 90, 0),
    (0, 270, 0), (0, 180, 90), (0, 180, 270), (90, 90, 0), (180, 90, 0), (270, 90, 0),
    (90, 180, 0), (270, 180, 0), (90, 270, 0), (180, 270, 0), (270, 270, 0), (90, 180, 90),
    (90, 0, 270), (90, 68.8, 293.3), (0, 315, 0), (90, 315, 0), (0, 7, 0),
)


def board_rotation(orientation: int) -> np.ndarray:
    """
    Give the matrix ArduPilot rotates IMU samples by for ``AHRS_ORIENTATION`` = orientation.

    A logged sample is R @ v with v in the sensor frame, so R.T @ logged is v.
    Raise FlightLogError for a value tempcal_IMU.py cannot undo (42 on, custom).
    """
    if not 0 <= orientation < len(BOARD_ROTATIONS_DEG):
        msg = (f'AHRS_ORIENTATION {orientation} is not one that tempcal_IMU.py (ArduPilot) can '
               f'undo (it knows 0 to {len(BOARD_ROTATIONS_DEG) - 1}; custom rotations and '
               'ROLL_45/ROLL_315 are beyond its table)')
        raise FlightLogError(msg)
    roll, pitch, yaw = np.radians(BOARD_ROTATIONS_DEG[orientation])
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def device_id_parameter(kind: str, index: int) -> str:
    """Name the device id parameter of ``kind`` GYR or ACC of IMU instance ``index`` (0-based)."""
    if index >= 3:
        return f'INS{index + 1}_{kind}_ID'
    return f'INS_{kind}{index + 1 if index else ""}_ID'


def _factors(path, reader, name: str) -> tuple:
    """Give the SI factor of each of _FIELDS for message ``name``, and whether units were read."""
    fmt = reader.formats.get(reader.name_to_id.get(name))
    if fmt is None or fmt.units is None:
        return tuple(1.0 for _ in _FIELDS), False
    factors = []
    for column in _FIELDS:
        unit = fmt.get_unit(column)
        table = UNIT_FACTORS[_KIND[column]]
        if unit not in table:
            msg = (f'{path}: {name}.{column} is in {unit!r}; expected one of '
                   f'{", ".join(table)}')
            raise FlightLogError(msg)
        factors.append(table[unit])
    return tuple(factors), True


def _scan(path, reader):
    """Decode the IMU, PARM and MSG messages: rows per instance, parameters, firmware."""
    rows = {}
    parameters = {}
    firmware = ''
    while True:
        message = reader.recv_match(type=list(MESSAGES))
        if message is None:
            break
        kind = message.get_type()
        if kind == 'PARM':
            parameters.setdefault(message.Name, float(message.Value))
        elif kind == 'MSG':
            match = _FIRMWARE.match(str(message.Message))
            if match and not firmware:
                firmware = str(message.Message)
        else:
            fields = message.get_fieldnames()
            index = int(message.I) if 'I' in fields else IMU_TYPES.index(kind)
            time_us = message.TimeUS if 'TimeUS' in fields else message.TimeMS * 1000.0
            label = f'IMU I={index}' if 'I' in fields else kind
            rows.setdefault((index, kind, label), []).append(
                [float(time_us)] + [float(getattr(message, f)) for f in _FIELDS])
    return rows, parameters, firmware


def _unindexed_tail(reader) -> int:
    """
    Give the bytes at the end that are no whole message, from DFReader's index.

    The index holds the offset of every message, a last one cut short too; the
    reading itself jumps from one wanted message to the next, so it cannot tell.
    """
    offsets = reader.offsets
    last = max(((found[-1], kind) for kind, found in enumerate(offsets) if found),
               default=None)
    if last is None or last[1] not in reader.formats:
        return 0
    end = last[0] + reader.formats[last[1]].len
    return reader.data_len - (last[0] if end > reader.data_len else end)


@contextlib.contextmanager
def _captured_output(chatter: io.StringIO):
    """Send what Python and the C indexer print (stdout, stderr) into ``chatter``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile(mode='w+b') as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
                yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            sink.seek(0)
            chatter.write(sink.read().decode('utf-8', 'replace'))


def read_dataflash(path) -> FlightLog:
    """Read the IMU instances of a DataFlash log; FlightLogError when DFReader cannot."""
    from pymavlink import DFReader
    chatter = io.StringIO()
    try:
        # DFReader and its C indexer print what they skip; it becomes a note, not stray output.
        with _captured_output(chatter):
            reader = DFReader.DFReader_binary(str(path), zero_time_base=False)
            try:
                if len(reader.formats) <= 1:
                    msg = (f'{path}: not a DataFlash log, or cut before its first message format '
                           '(no FMT message in it)')
                    raise FlightLogError(msg)
                rows, parameters, firmware = _scan(path, reader)
                unread = max(int(reader.data_len - reader.offset), _unindexed_tail(reader))
                factors = {kind: _factors(path, reader, kind) for _, kind, _ in rows}
            finally:
                reader.close()
    except FlightLogError:
        raise
    except Exception as err:  # noqa: B902 - DFReader raises any type on a damaged file
        msg = f'{path}: not a readable DataFlash log ({type(err).__name__}: {err})'
        raise FlightLogError(msg) from None
    instances = []
    # The IMU ids are parameters: INS_GYR_ID, INS_GYR2_ID, ..., INS4_GYR_ID (0 when unset).
    ids = {(i, kind): int(parameters.get(device_id_parameter(kind, i), 0))
           for i, _, _ in rows for kind in ('GYR', 'ACC')}
    for (index, kind, label), values in sorted(rows.items()):
        scale, _ = factors[kind]
        values = np.array(values) * np.r_[1e-6, scale]
        values = values[np.argsort(values[:, 0], kind='stable')]
        instances.append(ImuInstance(
            index=index, name=label, device_id=ids[index, 'GYR'] or None,
            accel_device_id=ids[index, 'ACC'] or None, time_s=values[:, 0],
            temperature_c=values[:, 7], gyro_rad_s=values[:, 1:4],
            acceleration_m_s2=values[:, 4:7],
            moving=moving_samples(values[:, 0], values[:, 1:4], values[:, 4:7])))
    notes = []
    if any(not declared for _, declared in factors.values()):
        notes.append('no FMTU units in the log: LogStructure.h units assumed (rad/s, m/s/s, '
                     'degC)')
    elif factors:
        notes.append('units as the log declares them (FMTU)')
    if unread > 0:
        notes.append(f'file cut short or damaged: {unread} bytes at the end not read')
    said = ' '.join(chatter.getvalue().split())
    if said:
        notes.append(f'DFReader: {said[:200]}')
    return FlightLog(source=str(path), log_format='ArduPilot DataFlash',
                     system=firmware or 'ArduPilot (no version message)', instances=instances,
                     parameters=parameters, notes=notes)


register('.bin', read_dataflash)
