"""
Where a record moved: samples a bias(T) fit must skip, found from the gyro and accelerometer.

A thermal calibration wants the sensor still; a flight-controller log often
holds a hop or a flight. A sample is moving when its rate is more than
`GYRO_MOTION_RAD_S` off the slow baseline of its axis (the median of the
`BASELINE_WINDOW_S` window it falls in, interpolated between windows, so a
bias drifting with temperature is not taken for motion), or when its
acceleration magnitude is more than `ACC_MOTION_M_S2` off its own
baseline (an accelerometer drifts with temperature too). Samples within
`MOTION_MARGIN_S` of a moving one are skipped too: the sensor settles after
a landing or a touch.
"""

import numpy as np

# 5.7 deg/s: far above the noise of a gyro sampled at 1 kHz (~0.01 rad/s), far below a turn.
GYRO_MOTION_RAD_S = 0.1
# 0.05 g: a hand or a take-off, not an accelerometer's thermal drift (a few mg).
ACC_MOTION_M_S2 = 0.5
# Thermal drift is slow beside this; a hop or a touch is short beside it.
BASELINE_WINDOW_S = 30.0
MOTION_MARGIN_S = 0.5


def _baseline(time_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Median of each BASELINE_WINDOW_S window, interpolated linearly between window middles."""
    window = np.floor((time_s - time_s[0]) / BASELINE_WINDOW_S).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, window[1:] != window[:-1]])
    ends = np.r_[starts[1:], time_s.size]
    centres = np.array([np.median(time_s[a:b]) for a, b in zip(starts, ends)])
    medians = np.array([np.median(values[a:b], axis=0) for a, b in zip(starts, ends)])
    return np.column_stack([np.interp(time_s, centres, medians[:, axis])
                            for axis in range(values.shape[1])])


def _off_baseline(time_s: np.ndarray, values: np.ndarray, tolerance: float) -> np.ndarray:
    """Flag rows (finite in every column) more than ``tolerance`` off the baseline."""
    finite = np.isfinite(values).all(axis=1)
    flagged = np.zeros(time_s.size, dtype=bool)
    if finite.any():
        kept = values[finite]
        flagged[finite] = np.any(np.abs(kept - _baseline(time_s[finite], kept)) > tolerance,
                                 axis=1)
    return flagged


def moving_samples(time_s, gyro_rad_s, acceleration_m_s2=None) -> np.ndarray:
    """
    Flag the samples of one sensor that moved (see the module notes).

    ``time_s`` (samples,) increasing, ``gyro_rad_s`` (samples, axes) and the
    optional ``acceleration_m_s2`` (samples, 3). A sample with a NaN value is
    judged on its other sensor, or not flagged (it is skipped for its NaN).
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    gyro = np.asarray(gyro_rad_s, dtype=np.float64).reshape(time_s.size, -1)
    moving = _off_baseline(time_s, gyro, GYRO_MOTION_RAD_S)
    if acceleration_m_s2 is not None:
        norm = np.linalg.norm(np.asarray(acceleration_m_s2, dtype=np.float64), axis=1)
        moving |= _off_baseline(time_s, norm[:, np.newaxis], ACC_MOTION_M_S2)
    return near(time_s, time_s[moving], MOTION_MARGIN_S)


def near(query_time_s, event_time_s, margin_s: float) -> np.ndarray:
    """Flag each query time within ``margin_s`` of an event time (both sorted)."""
    query = np.asarray(query_time_s, dtype=np.float64)
    events = np.asarray(event_time_s, dtype=np.float64)
    if not events.size:
        return np.zeros(query.shape, dtype=bool)
    after = np.clip(np.searchsorted(events, query), 0, events.size - 1)
    before = np.clip(after - 1, 0, events.size - 1)
    distance = np.minimum(np.abs(events[after] - query), np.abs(events[before] - query))
    return distance <= margin_s
