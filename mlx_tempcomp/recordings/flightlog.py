"""
Flight-controller logs (PX4 ULog, ArduPilot DataFlash): their IMU instances, and one as columns.

`read_flight_log` picks the reader by extension: each reader registers the
suffix of its logs here (`register`: ``.ulg`` `ulog`, ``.bin`` `dataflash`,
which the package's ``__init__`` imports, so neither this module nor they
import each other back). Each loads only the messages it needs and gives a
`FlightLog`: one `ImuInstance` per IMU, with its raw samples in SI
units (rad/s, m/s^2, degC, time in s from the log's own stamps), the
samples the vehicle moved in (`core.standstill.moving_samples`), the log's parameters and
notes on how it was read (units assumed, a file cut short). `instance_columns`
gives the still samples of one instance as the canonical columns of a
recording; an instance whose temperature is NaN throughout, or constant,
or that never sits still is refused with `FlightLogError` naming it.
"""

from dataclasses import dataclass, field
import math
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Mapping, Optional

import numpy as np

from .errors import RecordFileError

SKIP_MOVING = 'moving (vehicle moved)'
SKIP_NO_TEMPERATURE = 'no temperature (NaN)'
# Temperatures that agree to this many decimals are one reading (a sensor without one
# reports a fixed value, e.g. 32.0 C).
TEMPERATURE_DECIMALS = 6


class FlightLogError(RecordFileError):
    """A flight-controller log cannot be read, or the IMU instance asked for cannot be used."""


def _read_only(array) -> Optional[np.ndarray]:
    if array is None:
        return None
    array = np.array(array, dtype=np.float64)
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class ImuInstance:
    """
    One IMU of a log: its samples as the log holds them (NaN kept), in SI units.

    ``index`` is the log's instance number (PX4 multi_id, ArduPilot ``I`` or
    IMU/IMU2/IMU3 order), ``name`` where the samples come from,
    ``device_id`` the gyro driver's id when the log has one,
    ``accel_device_id`` the accelerometer's (it may differ: two chips). ``moving``
    flags the samples taken while the vehicle moved.
    """

    index: int
    name: str
    device_id: Optional[int]
    time_s: np.ndarray
    temperature_c: np.ndarray
    gyro_rad_s: np.ndarray
    acceleration_m_s2: Optional[np.ndarray]
    moving: np.ndarray
    accel_device_id: Optional[int] = None

    def __post_init__(self):
        for name in ('time_s', 'temperature_c', 'gyro_rad_s', 'acceleration_m_s2'):
            object.__setattr__(self, name, _read_only(getattr(self, name)))
        moving = np.array(self.moving, dtype=bool)
        moving.flags.writeable = False
        object.__setattr__(self, 'moving', moving)

    def __len__(self) -> int:
        return int(self.time_s.size)

    @property
    def label(self) -> str:
        """Name the instance in messages: number, source and device id."""
        device = f', device id {self.device_id}' if self.device_id is not None else ''
        return f'IMU instance {self.index} ({self.name}{device})'

    def problem(self) -> str:
        """Say why a bias(T) fit cannot use this instance; empty when it can."""
        if not len(self):
            return 'no samples'
        finite = self.temperature_c[np.isfinite(self.temperature_c)]
        if not finite.size:
            return f'temperature is NaN in all {len(self)} samples (the sensor reports none)'
        readings = np.unique(np.round(finite, TEMPERATURE_DECIMALS))
        if readings.size == 1:
            return (f'temperature is constant at {readings[0]:.2f} C in all {finite.size} '
                    'samples (a fixed value, not a measurement)')
        if self.moving.all():
            return f'the vehicle moved during all {len(self)} samples'
        return ''


@dataclass(frozen=True, eq=False)
class FlightLog:
    """What `read_flight_log` found: the log's IMU instances, parameters and reading notes."""

    source: str
    log_format: str
    system: str
    instances: tuple
    parameters: Mapping[str, float] = field(default_factory=dict)
    notes: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, 'instances', tuple(self.instances))
        object.__setattr__(self, 'parameters', MappingProxyType(dict(self.parameters)))
        object.__setattr__(self, 'notes', tuple(self.notes))

    def instance(self, index: Optional[int] = None) -> ImuInstance:
        """
        Give instance ``index``, or the first usable one when None.

        Raise FlightLogError naming the instance when it is absent or cannot
        be used (see `ImuInstance.problem`).
        """
        if not self.instances:
            msg = f'{self.source}: no IMU samples in this {self.log_format} log'
            raise FlightLogError(msg)
        if index is None:
            for candidate in self.instances:
                if not candidate.problem():
                    return candidate
            reasons = '; '.join(f'{i.label}: {i.problem()}' for i in self.instances)
            msg = f'{self.source}: no IMU instance can be used: {reasons}'
            raise FlightLogError(msg)
        found = [i for i in self.instances if i.index == index]
        if not found:
            known = ', '.join(str(i.index) for i in self.instances)
            msg = f'{self.source}: no IMU instance {index}; the log has instances {known}'
            raise FlightLogError(msg)
        problem = found[0].problem()
        if problem:
            msg = f'{self.source}: {found[0].label}: {problem}'
            raise FlightLogError(msg)
        return found[0]


# The suffix of each kind of log (lower case, with its dot) -> its reader.
_READERS = {}


def register(suffix: str, reader: Callable[[Path], FlightLog]) -> None:
    """Make ``reader`` read the logs whose name ends in ``suffix`` (lower case, with its dot)."""
    _READERS[suffix] = reader


def is_flight_log(path) -> bool:
    """Tell whether ``path`` is read as a flight-controller log (by its extension)."""
    return Path(path).suffix.lower() in _READERS


def read_flight_log(path) -> FlightLog:
    """Read a ``.ulg`` (PX4 ULog) or ``.bin`` (ArduPilot DataFlash) log; FlightLogError if not."""
    path = Path(path)
    if not path.is_file():
        msg = f'cannot read {path}: no such file' if not path.exists() else \
            f'cannot read {path}: not a file'
        raise FlightLogError(msg)
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        msg = f'{path} is not a flight-controller log: its name ends in none of ' \
              f'{", ".join(_READERS)}'
        raise FlightLogError(msg)
    return reader(path)


def instance_columns(log: FlightLog, index: Optional[int] = None) -> tuple:
    """
    Give one instance's still samples as canonical recording columns.

    Returns the instance, the columns (time, temperature, gyro_x|y|z and,
    when every sample has one, acc_x|y|z) and the counts of the samples
    left out by reason: moving ones, and those without a temperature.
    """
    instance = log.instance(index)
    keep = ~instance.moving & np.isfinite(instance.temperature_c)
    skipped = {SKIP_MOVING: int(np.count_nonzero(instance.moving)),
               SKIP_NO_TEMPERATURE: int(np.count_nonzero(
                   ~instance.moving & ~np.isfinite(instance.temperature_c)))}
    columns = {'time': instance.time_s[keep], 'temperature': instance.temperature_c[keep]}
    columns.update((f'gyro_{a}', instance.gyro_rad_s[keep, i]) for i, a in enumerate('xyz'))
    if instance.acceleration_m_s2 is not None:
        acceleration = instance.acceleration_m_s2[keep]
        if np.isfinite(acceleration).all():
            columns.update((f'acc_{a}', acceleration[:, i]) for i, a in enumerate('xyz'))
    return instance, columns, {reason: count for reason, count in skipped.items() if count}


def sample_rate_hz(time_s: np.ndarray) -> float:
    """Give the median sample rate of increasing stamps (NaN with fewer than two)."""
    if np.size(time_s) < 2:
        return math.nan
    return float(1.0 / np.median(np.diff(time_s)))
