"""
Gyro noise figures from the overlapping Allan deviation (IEEE Std 952-1997, annex C).

`allan_deviation` computes, per gyro axis, the overlapping Allan deviation
of a rate record at octave-spaced averaging times and reads from it the
angle random walk, the bias instability and the per-sample white rate noise
that the compensation node's ``rate_noise_rad_s`` parameter expects.
"""

from dataclasses import dataclass

import numpy as np

from .errors import CalibrationError

MIN_SAMPLES = 100
MAX_INTERVAL_SPREAD = 0.10
ARW_TAU_S = 1.0
# The bias instability floor is searched only at taus the record holds this
# many times: beyond, the deviation rests on too few clusters to be trusted.
MIN_CLUSTERS = 10
# Ratio of the flat floor of the Allan deviation to the bias instability
# coefficient B of flicker (1/f) rate noise: sqrt(2 ln 2 / pi) (IEEE 952, C.1.4).
FLICKER_FLOOR_FACTOR = 0.664


@dataclass(frozen=True)
class NoiseFigures:
    """
    Allan deviation of one gyro axis and the noise figures read from it.

    ``taus_s`` are the averaging times, ``adev_rad_s`` the overlapping Allan
    deviation at each. ``angle_random_walk_rad_s_rt_hz`` is
    ``sigma(tau) * sqrt(tau)`` read (not fitted) at tau = 1 s by log-log
    interpolation between the neighbouring octaves, where white rate noise
    (slope -1/2) normally dominates; if 1 s lies outside the curve, it is
    read at the nearest end. ``bias_instability_rad_s`` is the minimum of
    the curve divided by 0.664 (the flicker floor factor of IEEE 952) and
    ``bias_instability_tau_s`` where that minimum lies, searched only up to
    a tenth of the record (longer taus rest on too few clusters); when the
    curve still falls there the record is too short to reach the floor and
    the figure is an upper bound. ``rate_noise_rad_s`` is the
    1-sigma white noise of one sample implied by the angle random walk at
    the sample rate, ``ARW * sqrt(rate_hz)``.
    """

    axis: str
    taus_s: np.ndarray
    adev_rad_s: np.ndarray
    angle_random_walk_rad_s_rt_hz: float
    bias_instability_rad_s: float
    bias_instability_tau_s: float
    rate_noise_rad_s: float


def _sample_rate_hz(time_s: np.ndarray) -> float:
    """Give the sample rate from the median interval, refusing short or irregular records."""
    if time_s.shape[0] < MIN_SAMPLES:
        msg = f'an Allan deviation needs at least {MIN_SAMPLES} samples, got {time_s.shape[0]}'
        raise CalibrationError(msg)
    interval_s = np.diff(time_s)
    median_s = float(np.median(interval_s))
    if not median_s > 0:
        msg = f'time must increase; the median sample interval is {median_s:g} s'
        raise CalibrationError(msg)
    spread = float((interval_s.max() - interval_s.min()) / median_s)
    if spread > MAX_INTERVAL_SPREAD:
        msg = (f'irregular sampling: intervals span {interval_s.min():.6g} to '
               f'{interval_s.max():.6g} s, a spread of {100 * spread:.1f} % of the median '
               f'{median_s:.6g} s (at most {100 * MAX_INTERVAL_SPREAD:.0f} %); '
               'cut the record at its gaps')
        raise CalibrationError(msg)
    return 1.0 / median_s


def _figures(axis: str, rate_rad_s: np.ndarray, rate_hz: float) -> NoiseFigures:
    # Imported here: only the noise figures need it, and it brings scipy (about 1.4 s to
    # import, 110 MB), which the nodes' environment of `make demo` does not install.
    try:
        import allantools
    except ImportError:
        msg = ('the Allan deviation needs the allantools package: '
               "pip install allantools (or the package's toolkit extra)")
        raise CalibrationError(msg) from None
    taus_s, adev_rad_s, _, _ = allantools.oadev(rate_rad_s, rate=rate_hz, data_type='freq',
                                                taus='octave')
    taus_s = np.asarray(taus_s, dtype=np.float64)
    adev_rad_s = np.asarray(adev_rad_s, dtype=np.float64)
    read_tau_s = float(np.clip(ARW_TAU_S, taus_s[0], taus_s[-1]))
    log_adev = np.interp(np.log(read_tau_s), np.log(taus_s), np.log(adev_rad_s))
    arw_rad_s_rt_hz = float(np.exp(log_adev) * np.sqrt(read_tau_s))
    duration_s = rate_rad_s.shape[0] / rate_hz
    trusted = taus_s <= max(duration_s / MIN_CLUSTERS, taus_s[0])
    floor = int(np.argmin(np.where(trusted, adev_rad_s, np.inf)))
    return NoiseFigures(axis=axis, taus_s=taus_s, adev_rad_s=adev_rad_s,
                        angle_random_walk_rad_s_rt_hz=arw_rad_s_rt_hz,
                        bias_instability_rad_s=float(adev_rad_s[floor] / FLICKER_FLOOR_FACTOR),
                        bias_instability_tau_s=float(taus_s[floor]),
                        rate_noise_rad_s=arw_rad_s_rt_hz * float(np.sqrt(rate_hz)))


def allan_deviation(time_s, rate_rad_s, axes) -> tuple[NoiseFigures, ...]:
    """
    Compute the overlapping Allan deviation and noise figures of each gyro axis.

    Parameters
    ----------
    time_s
        Sample times, one per row, regularly spaced: the sample rate is the
        inverse of the median interval.
    rate_rad_s
        Gyro rate, one row per sample and one column per axis.
    axes
        Axis names, one per column of ``rate_rad_s``.

    Returns
    -------
    tuple of NoiseFigures
        One per axis, in the order of ``axes``.

    Raises
    ------
    CalibrationError
        Fewer than 100 samples, arrays of mismatched shapes or non-finite
        values, or irregular sampling: the spread of the sample intervals
        (largest minus smallest) exceeds 10 % of the median interval.

    """
    time_s = np.asarray(time_s, dtype=np.float64)
    rate_rad_s = np.asarray(rate_rad_s, dtype=np.float64)
    axes = tuple(axes)
    if time_s.ndim != 1 or rate_rad_s.shape != (time_s.shape[0], len(axes)):
        msg = (f'need time of shape (rows,) and rate of shape (rows, {len(axes)}), got '
               f'{time_s.shape} and {rate_rad_s.shape}')
        raise CalibrationError(msg)
    if not (np.isfinite(time_s).all() and np.isfinite(rate_rad_s).all()):
        msg = 'time and rate must be finite'
        raise CalibrationError(msg)
    rate_hz = _sample_rate_hz(time_s)
    return tuple(_figures(axis, rate_rad_s[:, i], rate_hz) for i, axis in enumerate(axes))
