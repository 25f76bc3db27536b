"""
The ``mlx-tempcomp convert`` command: a CSV recording to a rosbag2 bag on the raw topics.

The bag holds what `driver_node` publishes, so ``driver_node`` with
``source: bag`` replays it into ``compensation_node``: ``sensor_msgs/Imu`` on
``/imu/data_raw`` (unmeasured axes NaN, acceleration flagged unreported with
covariance[0] = -1 when the recording has none) and ``sensor_msgs/Temperature``
on ``/imu/temperature_raw``; a second temperature goes to
``/imu/temperature_2_raw``, a supply voltage to ``/imu/supply_voltage``
(``sensor_msgs/BatteryState``). Header stamps and bag times are the recording's
time, which must not be negative.
"""

import argparse
import math

import numpy as np

from .errors import UserError
from .loading import load, read_options
from .options import add_recording_options
from .progress import add_progress_option, Progress
from .running import check_output_folder
from ..recordings.bag import (BagError, EepromRecord, ImuRecord, RawTopics, STORAGES,
                              SupplyVoltageRecord, TemperatureRecord)
from ..recordings.bag_writer import RawBagWriter
from ..recordings.recording import AXES, Recording

TEMPERATURE_2_TOPIC = '/imu/temperature_2_raw'
FRAME_ID = 'imu_link'

_UNREPORTED = np.array([-1.0] + [0.0] * 8)
_UNKNOWN = np.zeros(9)


def stamps_ns(time_s: np.ndarray, source: str) -> np.ndarray:
    """Give the ROS stamps of ``time_s`` in ns; UserError for a negative or colliding time."""
    time_s = np.asarray(time_s, dtype=np.float64)
    negative = np.flatnonzero(time_s < 0.0)
    if negative.size:
        msg = (f'{source}: time must be >= 0 s to become ROS stamps; row {negative[0]} has '
               f'{time_s[negative[0]]:g} s')
        raise UserError(msg)
    seconds = np.floor(time_s)
    stamps = seconds.astype(np.int64) * 1_000_000_000 + \
        np.round((time_s - seconds) * 1e9).astype(np.int64)
    if np.any(np.diff(stamps) <= 0):
        msg = f'{source}: samples less than 1 ns apart cannot become distinct ROS stamps'
        raise UserError(msg)
    return stamps


def write_raw_bag(path, storage: str, recording: Recording, axis_temperatures_c=None,
                  eeprom_images=None, progress_enabled=None, name=None) -> int:
    """
    Write ``recording`` on the raw topics into a new bag folder; return the messages written.

    ``axis_temperatures_c`` (samples, axes) adds ``/imu/temperature_raw/<axis>``
    per chip (the driver publishes those with several chips) and
    ``eeprom_images`` an ``/imu/eeprom`` message at the first stamp. ``name``
    is the bag's name on the console when ``path`` is its staging name.
    """
    stamps = stamps_ns(recording.time_s, recording.source)
    per_axis = axis_temperatures_c is not None and len(recording.axes) > 1
    axis_topics = tuple(f'/imu/temperature_raw/{a}' for a in recording.axes) if per_axis else ()
    extra = axis_topics + ((TEMPERATURE_2_TOPIC,) if recording.temperature_2_c is not None
                           else ())
    rates = np.full((len(recording), 3), math.nan)
    rates[:, [AXES.index(a) for a in recording.axes]] = recording.gyro_rad_s
    acceleration = recording.acceleration_m_s2
    supply_v = recording.supply_voltage_v
    written = 0
    try:
        with RawBagWriter(path, storage, RawTopics(), extra) as bag, \
                Progress(len(recording), f'writing {name or path}',
                         progress_enabled) as progress:
            if eeprom_images is not None:
                bag.write_eeprom(int(stamps[0]), EepromRecord(tuple(eeprom_images)))
                written += 1
            for row, stamp in enumerate(stamps.tolist()):
                # Temperatures first, as the driver does: a stamp pairer completes on the Imu.
                if per_axis:
                    for topic, value in zip(axis_topics, axis_temperatures_c[row]):
                        bag.write_temperature(stamp, TemperatureRecord(stamp, FRAME_ID, value,
                                                                       0.0), topic)
                if recording.temperature_2_c is not None:
                    bag.write_temperature(stamp, TemperatureRecord(
                        stamp, FRAME_ID, recording.temperature_2_c[row], 0.0),
                        TEMPERATURE_2_TOPIC)
                if supply_v is not None:
                    bag.write_supply_voltage(stamp, SupplyVoltageRecord(stamp, FRAME_ID,
                                                                        supply_v[row]))
                    written += 1
                bag.write_temperature(stamp, TemperatureRecord(
                    stamp, FRAME_ID, recording.temperature_c[row], 0.0))
                bag.write_imu(stamp, ImuRecord(
                    stamp_ns=stamp, frame_id=FRAME_ID, angular_velocity_rad_s=rates[row],
                    angular_velocity_covariance=_UNKNOWN,
                    linear_acceleration_m_s2=np.zeros(3) if acceleration is None
                    else acceleration[row],
                    linear_acceleration_covariance=_UNREPORTED if acceleration is None
                    else _UNKNOWN,
                    orientation_covariance=_UNREPORTED))
                written += 2 + len(extra)
                progress.update(row + 1)
    except BagError as err:
        raise UserError(str(err).replace(str(path), str(name or path))) from None
    return written


def convert_command(args: argparse.Namespace) -> int:
    check_output_folder(args.out, '--out', new=True)
    recording = load(args.input, read_options(args, at_rest=False))
    messages = write_raw_bag(args.outputs.folder(args.out, create=False, replace=False),
                             args.storage, recording, progress_enabled=args.progress or None,
                             name=args.out)
    print(f'{args.input}: axes {", ".join(recording.axes)}, {recording.duration_s:.1f} s')
    topics = ['/imu/data_raw', '/imu/temperature_raw']
    if recording.temperature_2_c is not None:
        topics.append(TEMPERATURE_2_TOPIC)
    if recording.supply_voltage_v is not None:
        topics.append(RawTopics.supply_voltage)
    print(f'wrote {args.out} ({args.storage}): {messages} messages on {", ".join(topics)}')
    print(f'replay: driver_node --ros-args -p source:=bag -p bag.path:={args.out} '
          f"-p bag.rate_factor:=0.0 -p \"axes:=[{', '.join(repr(a) for a in recording.axes)}]\""
          + (f' -p bag.temperature_2_topic:={TEMPERATURE_2_TOPIC}'
             if recording.temperature_2_c is not None else ''))
    return 0


def add_parser(commands) -> None:
    """Add the ``convert`` subcommand."""
    convert = commands.add_parser(
        'convert', help='write a CSV recording as a rosbag2 bag on the raw topics',
        description='Write a recording (CSV with the usual column options) as a rosbag2 '
                    'bag on the raw topics /imu/data_raw and /imu/temperature_raw (and '
                    '/imu/temperature_2_raw, /imu/supply_voltage from the temperature_2 and '
                    'supply_voltage columns), so '
                    'driver_node (source bag) replays it through compensation_node. '
                    'Stamps are the recording time, which must be >= 0.')
    add_recording_options(convert)
    convert.add_argument('--out', required=True, metavar='BAG',
                         help='bag folder to create (must not exist)')
    convert.add_argument('--storage', choices=STORAGES, default='sqlite3',
                         help='rosbag2 storage (default: %(default)s)')
    add_progress_option(convert)
    convert.set_defaults(handler=convert_command)
