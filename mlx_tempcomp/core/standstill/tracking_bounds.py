"""
The ``bias_tracking.*`` bounds of a unit, derived from a record of it at rest and its model.

`derive_bounds` takes the residual the written model leaves on each record (time, rate
less the model and the reference, temperature, specific force or None) and gives the
values ``mlx-tempcomp fit`` and ``diagnose`` write beside the model:

- ``rate_noise_rad_s`` per axis: the white noise of one sample, from the spread of the
  differences of consecutive samples (a median, so steps and turns do not count):
  sqrt(2) x the noise for white noise, as ``allan``'s ``rate_noise_rad_s`` reads it;
- ``max_mean_rate_rad_s`` stays 0.1 deg/s, half the slowest turn the issue asks to
  reject, unless the noise needs more; ``window_s`` is the shortest window (at least
  5 s) whose mean noise is a fifth of that bound, so noise alone never reads as a turn;
- ``random_walk_rad_s_rt_s`` per axis: how far the residual's window means move from
  one window to the next beyond their noise, q = (mean square change - 2 noise^2 / n) / W;
- ``initial_std_rad_s`` per axis: the RMS of the residual's window means, what the
  model leaves without tracking;
- ``noise_multiple``, ``max_temperature_rate_c_s``, ``max_acceleration_spread_m_s2``
  and ``max_tilt_rate_rad_s``: the record's own window statistics (99th percentile)
  with a margin, so that the record itself, at rest, reads as still;
- ``stable_std_rad_s``: half the mean-rate bound.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from .detector import MIN_WINDOW_SAMPLES
from ..errors import CalibrationError
from ..node_models import sample_noise_rad_s

MEAN_RATE_BOUND_RAD_S = math.radians(0.1)
MIN_WINDOW_S = 5.0
MAX_WINDOW_S = 60.0
# A window's mean noise is at most this fraction of the mean-rate bound.
NOISE_MARGIN = 5.0
# The record's own 99th percentiles are widened by this much.
PERCENTILE_MARGIN = 1.5
MIN_NOISE_MULTIPLE = 3.0
MIN_TEMPERATURE_RATE_C_S = 0.01
MIN_ACCELERATION_SPREAD_M_S2 = 0.01
MIN_TILT_RATE_RAD_S = 1e-4
# Floor of the random walk: the filter never stops forgetting.
MIN_RANDOM_WALK_RAD_S_RT_S = 1e-7


@dataclass(frozen=True)
class RestRecord:
    """One record's residual at rest: rate less the model (and the reference), per axis."""

    time_s: np.ndarray
    residual_rad_s: np.ndarray
    temperature_c: np.ndarray
    acceleration_m_s2: Optional[np.ndarray] = None


def _noise(records: list) -> np.ndarray:
    """Give the white noise of one sample per axis, from consecutive differences (pooled)."""
    return sample_noise_rad_s([r.residual_rad_s for r in records])


def _windows(record: RestRecord, window_s: float) -> list:
    """Give each window's rows (at least the detector's minimum), by sample time."""
    index = np.floor((record.time_s - record.time_s[0]) / window_s).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
    ends = np.r_[starts[1:], index.size]
    return [(int(index[a]), slice(a, b)) for a, b in zip(starts, ends)
            if b - a >= MIN_WINDOW_SAMPLES]


def _slope(time_s: np.ndarray, values: np.ndarray) -> float:
    time_s = time_s - time_s.mean()
    return float(np.dot(time_s, values - values.mean()) / np.dot(time_s, time_s))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b)))


def _window_figures(records: list, window_s: float) -> dict:
    """Window means, spreads and their changes between adjacent windows, pooled."""
    figures = {name: [] for name in ('means', 'changes', 'samples', 'spreads',
                                     'temperature_rates', 'acceleration_spreads', 'tilts')}
    for record in records:
        previous = None
        for index, rows in _windows(record, window_s):
            mean = record.residual_rad_s[rows].mean(axis=0)
            figures['means'].append(mean)
            figures['samples'].append(rows.stop - rows.start)
            figures['spreads'].append(record.residual_rad_s[rows].std(axis=0))
            figures['temperature_rates'].append(
                abs(_slope(record.time_s[rows], record.temperature_c[rows])))
            force = None
            if record.acceleration_m_s2 is not None:
                force = record.acceleration_m_s2[rows].mean(axis=0)
                figures['acceleration_spreads'].append(
                    float(record.acceleration_m_s2[rows].std(axis=0).max()))
            if previous is not None and previous[0] == index - 1:
                figures['changes'].append(mean - previous[1])
                if force is not None:
                    figures['tilts'].append(_angle(previous[2], force) / window_s)
            previous = (index, mean, force)
    return {name: np.array(values) for name, values in figures.items()}


def _percentile(values: np.ndarray, floor: float) -> float:
    return max(PERCENTILE_MARGIN * float(np.percentile(values, 99)), floor) if values.size \
        else floor


def derive_bounds(records: list) -> tuple:
    """
    Give (values, notes): the ``bias_tracking`` values of the records and how each came.

    ``records`` are `RestRecord` s of one unit (their axes alike). CalibrationError
    when they are too short for two adjacent windows.
    """
    records = [r for r in records if r.time_s.size > 2]
    rows = sum(r.time_s.size for r in records)
    if not records:
        raise CalibrationError('no part of the records at rest holds three samples')
    interval_s = float(np.median(np.concatenate([np.diff(r.time_s) for r in records])))
    noise = np.maximum(_noise(records), 1e-12)
    bound = MEAN_RATE_BOUND_RAD_S
    needed_s = (NOISE_MARGIN * float(noise.max()) / bound) ** 2 * interval_s
    # Half seconds up: a window holds at least twice the detector's fewest samples.
    window_s = float(np.clip(math.ceil(2.0 * max(needed_s, 2 * MIN_WINDOW_SAMPLES * interval_s))
                             / 2.0, MIN_WINDOW_S, MAX_WINDOW_S))
    notes = {}
    if needed_s > MAX_WINDOW_S:
        bound = NOISE_MARGIN * float(noise.max()) / math.sqrt(MAX_WINDOW_S / interval_s)
        notes['max_mean_rate_rad_s'] = (
            f'raised from 0.1 deg/s: a {MAX_WINDOW_S:g} s window of this noise needs it')
    figures = _window_figures(records, window_s)
    if figures['changes'].size == 0:
        msg = (f'{rows} samples give no two adjacent windows of {window_s:g} s with '
               f'{MIN_WINDOW_SAMPLES} samples each: too short to derive the bias tracking')
        raise CalibrationError(msg)
    samples = float(np.mean(figures['samples']))
    excess = np.mean(figures['changes'] ** 2, axis=0) - 2.0 * noise ** 2 / samples
    random_walk = np.maximum(np.sqrt(np.maximum(excess, 0.0) / window_s),
                             MIN_RANDOM_WALK_RAD_S_RT_S)
    initial = np.maximum(np.sqrt(np.mean(figures['means'] ** 2, axis=0)),
                         noise / math.sqrt(samples))
    values = {
        'window_s': window_s,
        'rate_noise_rad_s': noise.tolist(),
        'noise_multiple': max(MIN_NOISE_MULTIPLE, PERCENTILE_MARGIN * float(
            np.percentile(figures['spreads'] / noise, 99))),
        'max_mean_rate_rad_s': bound,
        'max_temperature_rate_c_s': _percentile(figures['temperature_rates'],
                                                MIN_TEMPERATURE_RATE_C_S),
        'random_walk_rad_s_rt_s': random_walk.tolist(),
        'initial_std_rad_s': initial.tolist(),
        'stable_std_rad_s': bound / 2.0,
    }
    if figures['acceleration_spreads'].size:
        values['max_acceleration_spread_m_s2'] = _percentile(
            figures['acceleration_spreads'], MIN_ACCELERATION_SPREAD_M_S2)
        values['max_tilt_rate_rad_s'] = min(
            _percentile(figures['tilts'], MIN_TILT_RATE_RAD_S), bound)
    return values, notes
