"""
``mlx-tempcomp inspect FILE``: what a recording holds for calibration, like ``ros2 bag info``.

For a CSV file or a bag, the recording as the other commands load it; for a
PX4 ULog or ArduPilot DataFlash log, each IMU instance (or the one
``--instance`` names). Per instance: samples, rate, duration from the
stamps, temperature range and its rate of change, how many samples moved
(`core.standstill.moving_samples`), gaps in the stamps, and which commands it can feed and why
not. ``--json`` prints the same as one JSON document (``feeds`` maps each
command to null when the instance can feed it, else to the reason).
"""

import argparse
import json
import math
from pathlib import Path

import numpy as np

from .errors import UserError
from .loading import load, read_options, ReadOptions
from .options import add_recording_options
from ..core.diagnosis import DiagnosisSettings
from ..core.series import MAX_INTERVAL_SPREAD, MIN_SAMPLES
from ..core.standstill import moving_samples
from ..recordings.flightlog import FlightLogError, is_flight_log, read_flight_log, sample_rate_hz
from ..recordings.load import BAG_SUFFIXES

# A thermal calibration wants the temperature to move this much: ArduPilot's onboard
# learning waits for a 10 C rise (AP_InertialSensor_tempcal.cpp).
THERMAL_SPAN_C = 10.0
# The rate of change is taken over windows this long (or the whole record if shorter).
RATE_WINDOW_S = 60.0
# An interval this many times the median one is a gap.
GAP_FACTOR = 3.0


def add_parser(commands) -> None:
    """Add the ``inspect`` subcommand."""
    parser = commands.add_parser(
        'inspect', help='say what a recording or flight log holds for calibration',
        description='Say what a CSV file, rosbag2 bag, PX4 ULog or ArduPilot DataFlash log '
                    'holds for calibration: per IMU instance its rate, duration (from the '
                    'stamps), temperature range and rate of change, whether it moved, gaps, '
                    'and which mlx-tempcomp commands it can feed.')
    add_recording_options(parser)
    parser.add_argument('--json', action='store_true', help='print JSON')
    parser.set_defaults(handler=inspect_command, per_instance=False)


def _rate_of_change_c_min(time_s: np.ndarray, temperature_c: np.ndarray) -> tuple:
    """Give the mean and the peak |dT/dt| over RATE_WINDOW_S windows, in C/min."""
    duration_s = float(time_s[-1] - time_s[0]) if time_s.size else 0.0
    if time_s.size < 2 or duration_s <= 0.0:
        return math.nan, math.nan
    mean = (temperature_c[-1] - temperature_c[0]) / duration_s
    window_s = min(RATE_WINDOW_S, duration_s)
    starts = time_s[:max(1, int(np.searchsorted(time_s, time_s[-1] - window_s, 'right')))]
    later = np.interp(starts + window_s, time_s, temperature_c)
    peak = np.max(np.abs(later - np.interp(starts, time_s, temperature_c))) / window_s
    return 60.0 * float(mean), 60.0 * float(peak)


def _gaps(time_s: np.ndarray) -> dict:
    if time_s.size < 3:
        return {'count': 0, 'longest_s': 0.0}
    interval_s = np.diff(time_s)
    gap = interval_s > GAP_FACTOR * np.median(interval_s)
    return {'count': int(np.count_nonzero(gap)),
            'longest_s': float(interval_s[gap].max()) if gap.any() else 0.0}


def _feeds(problem: str, kept_time_s: np.ndarray, kept_temperature_c: np.ndarray) -> dict:
    """Say for each command whether the still, valid samples can feed it, and why not."""
    if problem:
        return dict.fromkeys(('fit', 'diagnose', 'allan', 'evaluate', 'convert'), problem)
    span_c = float(np.ptp(kept_temperature_c)) if kept_temperature_c.size else 0.0
    # Only the still samples with a temperature are fitted: the span counts those alone.
    if not kept_temperature_c.size:
        thermal = 'no still sample with a temperature (moving samples are left out)'
    elif span_c < THERMAL_SPAN_C:
        thermal = (f'the {kept_temperature_c.size} still samples span {span_c:.2f} C (moving '
                   f'ones are left out); a thermal calibration wants {THERMAL_SPAN_C:g} C')
    else:
        thermal = ''
    blocks = DiagnosisSettings().blocks
    diagnose = thermal or ('' if kept_time_s.size >= 2 * blocks else
                           f'{kept_time_s.size} samples; {blocks} blocks need {2 * blocks}')
    allan = ''
    if kept_time_s.size < MIN_SAMPLES:
        allan = f'{kept_time_s.size} samples; an Allan deviation needs {MIN_SAMPLES}'
    else:
        interval_s = np.diff(kept_time_s)
        spread = float(np.ptp(interval_s) / np.median(interval_s))
        if spread > MAX_INTERVAL_SPREAD:
            allan = (f'irregular sampling: intervals spread {100 * spread:.0f} % of the median '
                     f'(at most {100 * MAX_INTERVAL_SPREAD:.0f} %)')
    return {'fit': thermal, 'diagnose': diagnose, 'allan': allan, 'evaluate': '',
            'convert': ''}


def _instance_report(index, name, device_id, time_s, temperature_c, moving, problem) -> dict:
    finite = np.isfinite(temperature_c)
    kept = ~moving & finite
    mean_c_min, peak_c_min = _rate_of_change_c_min(time_s[finite], temperature_c[finite])
    return {
        'instance': index, 'name': name, 'device_id': device_id,
        'samples': int(time_s.size),
        'rate_hz': sample_rate_hz(time_s),
        'start_s': float(time_s[0]) if time_s.size else math.nan,
        'duration_s': float(time_s[-1] - time_s[0]) if time_s.size else 0.0,
        'temperature_min_c': float(temperature_c[finite].min()) if finite.any() else math.nan,
        'temperature_max_c': float(temperature_c[finite].max()) if finite.any() else math.nan,
        'temperature_nan_samples': int(np.count_nonzero(~finite)),
        'temperature_rate_mean_c_min': mean_c_min,
        'temperature_rate_peak_c_min': peak_c_min,
        'moving_samples': int(np.count_nonzero(moving)),
        'kept_samples': int(np.count_nonzero(kept)),
        'gaps': _gaps(time_s),
        'usable': not problem, 'problem': problem,
        'feeds': {command: why or None for command, why in
                  _feeds(problem, time_s[kept], temperature_c[kept]).items()},
    }


def _flight_log_report(path: str, instance) -> dict:
    """Describe the IMU instances of a flight log: ``instance`` ('all' or None: every one)."""
    try:
        log = read_flight_log(path)
    except FlightLogError as err:
        raise UserError(str(err)) from None
    wanted = list(log.instances)
    if instance not in (None, 'all'):
        wanted = [i for i in log.instances if i.index == instance]
        if not wanted:
            known = ', '.join(str(i.index) for i in log.instances) or 'none'
            msg = f'{path}: no IMU instance {instance}; the log has {known}'
            raise UserError(msg)
    thermal = {name: value for name, value in sorted(log.parameters.items())
               if name.startswith(('TC_G', 'INS_TCAL', 'INS4_TCAL', 'INS5_TCAL'))
               or name.endswith('_CALTEMP')}
    return {'file': str(path), 'format': log.log_format, 'system': log.system,
            'notes': list(log.notes), 'thermal_parameters': thermal,
            'instances': [_instance_report(i.index, i.name, i.device_id, i.time_s,
                                           i.temperature_c, i.moving, i.problem())
                          for i in wanted]}


def _recording_report(path: str, options: ReadOptions, to_stderr: bool) -> dict:
    """Describe a CSV file or bag as one IMU instance (`load` prints on stderr: ``to_stderr``)."""
    recording = load(path, options, to_stderr)
    moving = moving_samples(recording.time_s, recording.gyro_rad_s,
                            recording.acceleration_m_s2)
    bag = Path(path).is_dir() or Path(path).suffix.lower() in BAG_SUFFIXES
    return {'file': str(path), 'format': 'rosbag2 bag' if bag else 'CSV', 'system': '',
            'notes': [], 'skipped': dict(recording.skipped),
            'thermal_parameters': {},
            'instances': [_instance_report(0, 'recording', None, recording.time_s,
                                           recording.temperature_c, moving, '')]}


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _text(report: dict) -> str:
    lines = [f'{report["file"]}: {report["format"]}' + (f', {report["system"]}'
                                                        if report['system'] else '')]
    lines += [f'  {note}' for note in report['notes']]
    if report['thermal_parameters']:
        lines.append('thermal parameters in the log: ' + ', '.join(
            f'{k}={v:g}' for k, v in report['thermal_parameters'].items()))
    if not report['instances']:
        lines.append('no IMU samples')
    for item in report['instances']:
        device = f', device id {item["device_id"]}' if item['device_id'] is not None else ''
        lines.append(f'instance {item["instance"]} ({item["name"]}{device}):')
        lines.append(f'  samples {item["samples"]} at {item["rate_hz"]:.4g} Hz over '
                     f'{item["duration_s"]:.2f} s (stamps from {item["start_s"]:.3f} s)')
        if math.isfinite(item['temperature_min_c']):
            lines.append(f'  temperature {item["temperature_min_c"]:.2f} to '
                         f'{item["temperature_max_c"]:.2f} C over every sample; rate of change '
                         f'mean {item["temperature_rate_mean_c_min"]:+.3g} C/min, peak '
                         f'{item["temperature_rate_peak_c_min"]:.3g} C/min'
                         + (f'; {item["temperature_nan_samples"]} samples NaN'
                            if item['temperature_nan_samples'] else ''))
        else:
            lines.append('  temperature NaN in every sample')
        lines.append(f'  moved: {item["moving_samples"]} of {item["samples"]} samples; '
                     f'{item["kept_samples"]} still samples with a temperature kept')
        gaps = item['gaps']
        lines.append(f'  gaps (> {GAP_FACTOR:g} x the median interval): {gaps["count"]}'
                     + (f', longest {gaps["longest_s"]:.3f} s' if gaps['count'] else ''))
        feeds = item['feeds']
        can = [c for c, why in feeds.items() if not why]
        lines.append(f'  can feed: {", ".join(can) or "nothing"}')
        lines += [f'  not {command}: {why}' for command, why in feeds.items() if why]
    return '\n'.join(lines)


def inspect_command(args: argparse.Namespace) -> int:
    if is_flight_log(args.input):
        report = _flight_log_report(args.input, args.instance)
    else:
        if args.instance is not None:
            msg = f'--instance applies to .ulg and .bin logs, not {args.input}'
            raise UserError(msg)
        report = _recording_report(args.input, read_options(args), args.json)
    if args.json:
        print(json.dumps(_plain(report), indent=2))
    else:
        print(_text(report))
    return 0
