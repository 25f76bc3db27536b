"""
Load a recording by its path: a rosbag2 bag, a flight-controller log or a CSV file.

`load_recording` picks the reader by the path's extension. Bags (sqlite3 or
mcap) are read with `bag_reader.RawBagReader`: ``sensor_msgs/Imu`` and
``sensor_msgs/Temperature`` messages are paired by exact header stamp; a
supply voltage (``sensor_msgs/BatteryState``), on stamps of its own, is held
as the compensation node holds it (`load_bag`). Flight-controller logs
(``.ulg`` PX4 ULog, ``.bin`` ArduPilot DataFlash) are read by `flightlog`:
one IMU instance becomes a recording of its still samples
(`load_flight_log`). CSV files are read by `csv_reader.load_csv`.
"""

from pathlib import Path
from typing import Optional, Union

import numpy as np

from .bag import absolute_topic, BagError, ImuRecord, RawTopics, SupplyVoltageRecord, \
    TemperatureRecord
from .bag_reader import RawBagReader
from .columns import column_preset, ColumnMap, parse_column_map
from .csv_reader import load_csv
from .flightlog import FlightLogError, instance_columns, is_flight_log, read_flight_log
from .recording import (AXES, PathLike, Recording, recording_from_columns, RecordingError,
                        SKIP_CORRUPT, SKIP_DUPLICATED_TIME, SKIP_IMU_UNPAIRED, SKIP_NO_SUPPLY,
                        SKIP_TEMPERATURE_UNPAIRED)
from ..core.series import zero_order_hold

BAG_SUFFIXES = ('.db3', '.mcap')
# The compensation node's default supply_voltage.max_age_s.
SUPPLY_MAX_AGE_NS = 5_000_000_000
_NS_PER_S = 1_000_000_000


def _bag_message(path: PathLike, err: BagError) -> str:
    text = str(err)
    return text if str(path) in text else f'bag {path}: {text}'


def _read_bag(bag: RawBagReader, path: Path, temperature_topic: str):
    """Give the IMU records in bag order, temperature and supply by stamp, skip counts."""
    imu = []
    temperatures = {}
    supply = {}
    skipped = {}
    for _, _, record in bag.records():
        if isinstance(record, ImuRecord):
            imu.append(record)
        elif isinstance(record, SupplyVoltageRecord):
            supply[record.stamp_ns] = record.voltage_v
        elif isinstance(record, TemperatureRecord):
            if record.stamp_ns in temperatures:
                skipped[SKIP_DUPLICATED_TIME] = skipped.get(SKIP_DUPLICATED_TIME, 0) + 1
            else:
                temperatures[record.stamp_ns] = record.temperature_c
    if bag.skipped:
        skipped[SKIP_CORRUPT] = bag.skipped
    if not temperatures:
        present = ', '.join(f'{t} ({m})' for t, m in bag.bag_topics.items())
        msg = (f'bag {path} has no message on temperature topic '
               f'{absolute_topic(temperature_topic)}; the bag has: {present}')
        raise RecordingError(msg)
    return imu, temperatures, supply, skipped


def load_bag(path: PathLike, imu_topic: str = '/imu/data',
             temperature_topic: str = '/imu/temperature',
             supply_voltage_topic: str = '/imu/supply_voltage') -> Recording:
    """
    Load a rosbag2 recording (folder, or a bare .db3 or .mcap file).

    Parameters
    ----------
    path
        The bag.
    imu_topic, temperature_topic, supply_voltage_topic
        ``sensor_msgs/Imu``, ``sensor_msgs/Temperature`` and
        ``sensor_msgs/BatteryState`` topics; a leading slash is optional.

    Returns
    -------
    Recording
        Messages paired by exact header stamp; time from the stamps. Unpaired
        messages are counted in ``skipped``. Axes are those whose angular
        velocity is finite in some paired message (NaN marks an unmeasured
        axis). Acceleration is included unless a message flags it unreported
        (``linear_acceleration_covariance[0] == -1``). With messages on the
        supply-voltage topic, each sample has the latest voltage stamped at or
        before it (or the first one); samples more than 5 s from any voltage
        are skipped and counted.

    Raises
    ------
    RecordingError
        The bag cannot be read, lacks a topic, or nothing pairs.

    """
    path = Path(path)
    try:
        with RawBagReader(path, RawTopics(imu=imu_topic, temperature=temperature_topic,
                                          supply_voltage=supply_voltage_topic)) as bag:
            imu, temperatures, supply, skipped = _read_bag(bag, path, temperature_topic)
    except BagError as err:
        raise RecordingError(_bag_message(path, err)) from None
    topics = RawTopics(imu=absolute_topic(imu_topic),
                       temperature=absolute_topic(temperature_topic),
                       supply_voltage=absolute_topic(supply_voltage_topic))
    imu, stamps_ns, numbers = _paired_by_stamp(path, topics, imu, temperatures, skipped)
    supply_v = None
    if supply:
        imu, stamps_ns, numbers, supply_v = _held_supply(path, topics, imu, stamps_ns, numbers,
                                                         supply, skipped)
    columns = _bag_columns(path, topics, imu, stamps_ns, temperatures, supply_v)
    return recording_from_columns(str(path), columns, skipped, f'{topics.imu} message', numbers)


def _paired_by_stamp(path: Path, topics: RawTopics, imu: list, temperatures: dict,
                     skipped: dict) -> tuple:
    """Give the IMU records with a temperature of the same stamp, their stamps and numbers."""
    stamps_ns = np.array([record.stamp_ns for record in imu], dtype=np.int64)
    paired = np.array([stamp in temperatures for stamp in stamps_ns.tolist()], dtype=bool)
    if not paired.any():
        msg = (f'bag {path}: no message on {topics.imu} has a temperature on '
               f'{topics.temperature} with the same header stamp '
               f'({len(imu)} IMU and {len(temperatures)} temperature messages)')
        raise RecordingError(msg)
    used_stamps = set(stamps_ns[paired].tolist())
    unpaired = {SKIP_IMU_UNPAIRED: int(np.count_nonzero(~paired)),
                SKIP_TEMPERATURE_UNPAIRED: len(temperatures) - len(used_stamps)}
    skipped.update((reason, count) for reason, count in unpaired.items() if count)
    return ([record for record, used in zip(imu, paired) if used], stamps_ns[paired],
            np.flatnonzero(paired) + 1)


def _held_supply(path: Path, topics: RawTopics, imu: list, stamps_ns: np.ndarray,
                 numbers: np.ndarray, supply: dict, skipped: dict) -> tuple:
    """
    Give each IMU record the supply voltage the node would hold for it.

    Records further than 5 s from every voltage are left out and counted;
    returns the records, their stamps and numbers, and the voltages.
    """
    held = sorted(supply)
    supply_v, usable = zero_order_hold(stamps_ns, held, [supply[s] for s in held],
                                       SUPPLY_MAX_AGE_NS)
    if usable.all():
        return imu, stamps_ns, numbers, supply_v
    skipped[SKIP_NO_SUPPLY] = int(np.count_nonzero(~usable))
    imu = [record for record, used in zip(imu, usable) if used]
    if not imu:
        msg = (f'bag {path}: no IMU message within 5 s of a supply voltage on '
               f'{topics.supply_voltage}')
        raise RecordingError(msg)
    return imu, stamps_ns[usable], numbers[usable], supply_v[usable]


def _bag_columns(path: Path, topics: RawTopics, imu: list, stamps_ns: np.ndarray,
                 temperatures: dict, supply_v: Optional[np.ndarray]) -> dict:
    """Give the canonical columns of the paired records (NaN marks an unmeasured axis)."""
    rate_rad_s = np.array([record.angular_velocity_rad_s for record in imu])
    axes = [i for i in range(3) if np.isfinite(rate_rad_s[:, i]).any()]
    if not axes:
        msg = f'bag {path}: no finite angular velocity on {topics.imu}'
        raise RecordingError(msg)
    seconds = (stamps_ns // _NS_PER_S).astype(np.float64)
    columns = {'time': seconds + (stamps_ns % _NS_PER_S) * 1e-9,
               'temperature': np.array([temperatures[s] for s in stamps_ns.tolist()])}
    columns.update((f'gyro_{AXES[i]}', rate_rad_s[:, i]) for i in axes)
    if all(record.linear_acceleration_covariance[0] != -1 for record in imu):
        acceleration = np.array([record.linear_acceleration_m_s2 for record in imu])
        columns.update((f'acc_{a}', acceleration[:, i]) for i, a in enumerate(AXES))
    if supply_v is not None:
        columns['supply_voltage'] = supply_v
    return columns


def load_recording(path: PathLike, *, columns: Union[ColumnMap, str, None] = None,
                   preset: Optional[str] = None, imu_topic: str = '/imu/data',
                   temperature_topic: str = '/imu/temperature',
                   supply_voltage_topic: str = '/imu/supply_voltage',
                   instance: Optional[int] = None) -> Recording:
    """
    Load a recording: a bag, a flight-controller log or a CSV file, by the path's extension.

    A folder, ``.db3`` or ``.mcap`` is a bag; ``.ulg`` or ``.bin`` a
    flight-controller log, of which IMU ``instance`` is read (default: the
    first usable one, see `load_flight_log`); anything else is CSV.

    ``columns`` (a ColumnMap or its command-line form) or ``preset`` (a name
    in PRESETS) say how to read a CSV file; the default map reads the
    canonical columns. They do not apply to bags, whose topics are given by
    ``imu_topic``, ``temperature_topic`` and ``supply_voltage_topic``.
    """
    path = Path(path)
    if is_flight_log(path) and not path.is_dir():
        if columns is not None or preset is not None:
            msg = f'{path} is a flight-controller log: a column map or preset applies to CSV'
            raise RecordingError(msg)
        return load_flight_log(path, instance)[0]
    if path.is_dir() or path.suffix.lower() in BAG_SUFFIXES:
        if columns is not None or preset is not None:
            msg = f'{path} is a rosbag2 bag: a column map or preset applies to CSV files only'
            raise RecordingError(msg)
        return load_bag(path, imu_topic, temperature_topic, supply_voltage_topic)
    if columns is not None and preset is not None:
        msg = f'{path}: give a column map or a preset, not both'
        raise RecordingError(msg)
    return load_csv(path, csv_column_map(columns, preset))


def is_csv(path: PathLike) -> bool:
    """Say whether `load_recording` reads ``path`` as a CSV file."""
    path = Path(path)
    return not (path.is_dir() or path.suffix.lower() in BAG_SUFFIXES or is_flight_log(path))


def csv_column_map(columns: Union[ColumnMap, str, None], preset: Optional[str]) -> ColumnMap:
    """Give the column map a CSV file is read with: ``preset``'s, ``columns`` or the default."""
    if preset is not None:
        return column_preset(preset)
    if isinstance(columns, str):
        return parse_column_map(columns)
    return ColumnMap() if columns is None else columns


def load_flight_log(path: PathLike, instance: Optional[int] = None) -> tuple:
    """
    Load one IMU instance of a PX4 ULog or ArduPilot DataFlash log as a Recording.

    Returns the Recording (the instance's still samples; moving ones and
    those without a temperature counted in ``skipped``), the whole
    `flightlog.FlightLog` and the `flightlog.ImuInstance` used. Raises
    RecordingError when the log cannot be read or the instance cannot be used.
    """
    try:
        log = read_flight_log(path)
        used, data, skipped = instance_columns(log, instance)
    except FlightLogError as err:
        raise RecordingError(str(err)) from None
    if not data['time'].size:
        msg = f'{path}: {used.label}: no still sample with a temperature'
        raise RecordingError(msg)
    source = f'{path} [{used.label}]'
    return recording_from_columns(source, data, skipped, f'{used.name} sample'), log, used
