"""
Whether a recording's columns hold what they claim: seconds, a part's temperature, a still gyro.

Loading skips single rows beyond `recording.PLAUSIBLE_RANGES` (a glitch, a
sentinel). A column read in the wrong unit, or the wrong column read, passes
that row by row and still gives a wrong fit with exit code 0: an accelerometer
column taken as a gyro at rest "fits" a bias of -554 deg/s, a time in ns read
as µs a thermal sweep of 80 C in 4 s. `implausible_columns` looks at whole
columns against what any gyro record holds (the bounds below, each with its
reason) and gives one line per column that does not, naming the column and the
likely fix (``map time=timestamp:1e-6``). The toolkit prints them as warnings,
or refuses the record with ``--strict`` (`toolkit.loading.load`).
"""

import math
from typing import Optional

import numpy as np

from .columns import ColumnMap
from .recording import Recording

# A sample interval outside this is no gyro record's. The fastest MEMS gyros output 32 kHz
# (ICM-42688), 3.1e-5 s; a thermal logger samples at least once a minute, else its samples
# would be degrees of temperature apart.
MIN_SAMPLE_INTERVAL_S = 1e-5
MAX_SAMPLE_INTERVAL_S = 60.0
# Where a time unit is guessed, the interval of a usual gyro record (100 Hz).
TYPICAL_SAMPLE_INTERVAL_S = 0.01
# A part's temperature cannot change faster: a die following a 165 C thermal-shock step with
# the 20 s time constant of a part on a board slews 8 C/s at most; a climatic chamber ramps
# 0.25 C/s, self-heating at power-up a few C in tens of seconds.
MAX_TEMPERATURE_SLEW_C_S = 10.0
# The slew is read between medians of windows this long (shorter in a short record, a quarter
# of it), so a sensor's quantization noise and a glitch row move no window.
SLEW_WINDOW_S = 10.0
_MIN_SLEW_WINDOWS = 4
_MAX_SLEW_WINDOWS = 10_000
# A gyro at rest reads its offset. MEMS datasheets give a few deg/s; the widest, the
# MPU-6000's, +-20 deg/s at 25 C and +-20 deg/s more over -40 to 85 C. Beyond 50 deg/s
# the column is not a still gyro in rad/s: gravity on an accelerometer reads 562 deg/s, a
# deg/s column with an offset above 0.87 deg/s reads more than 50.
MAX_REST_OFFSET_DPS = 50.0
STANDARD_GRAVITY_M_S2 = 9.80665
# A column whose mean is this near 1 g is taken for an accelerometer in the hint.
_GRAVITY_BAND = (0.7, 1.3)
RAD_S_PER_DPS = math.pi / 180.0
# Time units a column may be in, seconds per unit, for the hint.
_TIME_UNITS = (('ns', 1e-9), ('µs', 1e-6), ('ms', 1e-3), ('s', 1.0))


def median_interval_s(time_s: np.ndarray) -> float:
    """Give the median of the sample intervals (NaN with one sample)."""
    return float(np.median(np.diff(time_s))) if time_s.size > 1 else math.nan


def temperature_slew(time_s: np.ndarray, temperature_c: np.ndarray) -> Optional[tuple]:
    """
    Give the steepest temperature change between adjacent windows, or None if too short.

    Windows of `SLEW_WINDOW_S` (a quarter of a shorter record; three sample
    intervals at least); each reads as its median time and temperature. Returns
    (slew C/s, from C, to C, over s).
    """
    if time_s.size < 2 * _MIN_SLEW_WINDOWS:
        return None
    duration_s = float(time_s[-1] - time_s[0])
    window_s = max(min(SLEW_WINDOW_S, duration_s / _MIN_SLEW_WINDOWS),
                   3.0 * median_interval_s(time_s), duration_s / _MAX_SLEW_WINDOWS)
    index = np.floor((time_s - time_s[0]) / window_s).astype(np.int64)
    starts = np.flatnonzero(np.diff(index, prepend=-1))
    if starts.size < 2:
        return None
    ends = np.append(starts[1:], time_s.size)
    times = np.array([np.median(time_s[a:b]) for a, b in zip(starts, ends)])
    temperatures = np.array([np.median(temperature_c[a:b]) for a, b in zip(starts, ends)])
    slews = np.abs(np.diff(temperatures)) / np.diff(times)
    steepest = int(np.argmax(slews))
    return (float(slews[steepest]), float(temperatures[steepest]),
            float(temperatures[steepest + 1]), float(times[steepest + 1] - times[steepest]))


def _source(columns: Optional[ColumnMap], canonical: str) -> str:
    """Name a column in a message: its canonical name, and the file's column if it differs."""
    if columns is None:
        return canonical
    name = columns.sources()[canonical]
    return canonical if name == canonical else f'{canonical} (column {name})'


def _mapping(columns: Optional[ColumnMap], canonical: str, factor: Optional[float]) -> str:
    """Give the --columns item that reads ``canonical`` ``factor`` times as large, or ''."""
    if columns is None:
        return ''
    name = columns.sources()[canonical]
    if factor is None:
        return f' map {canonical}=COLUMN:SCALE (--columns)'
    return f' map {canonical}={name}:{columns.scale(canonical) * factor:.6g} (--columns)'


def _plausible_time(time_s: np.ndarray, temperature_c: np.ndarray) -> bool:
    interval_s = median_interval_s(time_s)
    slew = temperature_slew(time_s, temperature_c)
    return (MIN_SAMPLE_INTERVAL_S <= interval_s <= MAX_SAMPLE_INTERVAL_S
            and (slew is None or slew[0] <= MAX_TEMPERATURE_SLEW_C_S))


def _time_unit(recording: Recording, columns: Optional[ColumnMap]) -> Optional[tuple]:
    """Give the time unit (name, factor to apply) that makes the record plausible, if one."""
    current = 1.0 if columns is None else columns.time_scale
    interval_s = median_interval_s(recording.time_s)
    found = []
    for unit, seconds in _TIME_UNITS:
        factor = seconds / current
        if not math.isclose(factor, 1.0) and \
                _plausible_time(recording.time_s * factor, recording.temperature_c):
            found.append((abs(math.log(interval_s * factor / TYPICAL_SAMPLE_INTERVAL_S)),
                          unit, factor))
    return min(found)[1:] if found else None


def _time_hint(recording: Recording, columns: Optional[ColumnMap]) -> str:
    unit = _time_unit(recording, columns)
    if unit is None:
        return ''
    return f'; is the time in {unit[0]}?' + _mapping(columns, 'time', unit[1])


def _interval_line(recording: Recording, columns: Optional[ColumnMap]) -> Optional[str]:
    interval_s = median_interval_s(recording.time_s)
    if not math.isfinite(interval_s) or \
            MIN_SAMPLE_INTERVAL_S <= interval_s <= MAX_SAMPLE_INTERVAL_S:
        return None
    return (f'{_source(columns, "time")}: median sample interval {interval_s:.3g} s, where a '
            f'gyro record samples every {MIN_SAMPLE_INTERVAL_S:g} to '
            f'{MAX_SAMPLE_INTERVAL_S:g} s' + _time_hint(recording, columns))


def _slew_line(recording: Recording, columns: Optional[ColumnMap]) -> Optional[str]:
    slew = temperature_slew(recording.time_s, recording.temperature_c)
    if slew is None or slew[0] <= MAX_TEMPERATURE_SLEW_C_S:
        return None
    rate, start_c, end_c, over_s = slew
    hint = _time_hint(recording, columns) or \
        ('; is the column in degC, and the time in s?'
         + _mapping(columns, 'temperature', None))
    return (f'{_source(columns, "temperature")}: changes {rate:.3g} C/s ({start_c:.1f} to '
            f'{end_c:.1f} C in {over_s:.3g} s), where no part' "'s temperature changes "
            f'faster than {MAX_TEMPERATURE_SLEW_C_S:g} C/s' + hint)


def _rest_hint(mean: float, columns: Optional[ColumnMap], canonical: str) -> str:
    low, high = (STANDARD_GRAVITY_M_S2 * bound for bound in _GRAVITY_BAND)
    if low <= abs(mean) <= high:
        return (f'; is it an accelerometer column (gravity reads {STANDARD_GRAVITY_M_S2} '
                f'm/s^2)?' + ('' if columns is None else
                              f' map {canonical}=<the gyro column> (--columns)'))
    if abs(mean) <= MAX_REST_OFFSET_DPS:
        return '; is it in deg/s?' + _mapping(columns, canonical, RAD_S_PER_DPS)
    return '; is it in raw counts?' + _mapping(columns, canonical, None)


def _rest_lines(recording: Recording, columns: Optional[ColumnMap]) -> list:
    if recording.reference_rad_s is not None:
        return []
    lines = []
    for axis, mean in zip(recording.axes, np.mean(recording.gyro_rad_s, axis=0).tolist()):
        if abs(mean) <= math.radians(MAX_REST_OFFSET_DPS):
            continue
        canonical = f'gyro_{axis}'
        lines.append(f'{_source(columns, canonical)}: mean {mean:.4g} rad/s '
                     f'({math.degrees(mean):.4g} deg/s) at rest (no ref_{axis} column) is '
                     f"beyond any gyro's offset ({MAX_REST_OFFSET_DPS:g} deg/s)"
                     + _rest_hint(mean, columns, canonical))
    return lines


def implausible_columns(recording: Recording, at_rest: bool = True,
                        columns: Optional[ColumnMap] = None) -> list:
    """
    Give a line per column that holds what no gyro record does, with the likely fix.

    The time's median sample interval, the temperature's steepest change
    (`temperature_slew`) and, when ``at_rest`` (the command takes a record
    without a reference as still: a bias fit, its evaluation), each gyro axis's
    mean. ``columns``, the map a CSV file was read with, names the file's
    columns and the ``--columns`` item that would read them right.
    """
    lines = [_interval_line(recording, columns), _slew_line(recording, columns)]
    if at_rest:
        lines += _rest_lines(recording, columns)
    return [f'{recording.source}: {line}' for line in lines if line]
