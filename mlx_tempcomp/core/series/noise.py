"""
Gyro noise figures from the overlapping Allan deviation (IEEE Std 952-1997, annex C).

`allan_deviation` computes, per gyro axis, the overlapping Allan deviation
of a rate record at octave-spaced averaging times and reads from it the
angle random walk, the bias instability and the per-sample white rate noise
that the compensation node's ``rate_noise_rad_s`` parameter expects, and the
two continuous-time densities Kalibr's ``imu.yaml`` takes (`noise_lines`).
It takes an accelerometer's record the same way (m/s^2 for rad/s).
"""

from dataclasses import dataclass
import itertools

import numpy as np

from ..errors import CalibrationError

MIN_SAMPLES = 100
MAX_INTERVAL_SPREAD = 0.10
ARW_TAU_S = 1.0
# The bias instability floor is searched only at taus the record holds this
# many times: beyond, the deviation rests on too few clusters to be trusted.
MIN_CLUSTERS = 10
# Ratio of the flat floor of the Allan deviation to the bias instability
# coefficient B of flicker (1/f) rate noise: sqrt(2 ln 2 / pi) (IEEE 952, C.1.4).
FLICKER_FLOOR_FACTOR = 0.664
# Where Kalibr's noise figures are read: the white-noise line (slope -1/2) at 1 s gives the
# noise density N (sigma = N / sqrt(tau)), the random-walk line (slope +1/2) at 3 s the random
# walk K (sigma = K sqrt(tau / 3)).
NOISE_DENSITY_TAU_S = 1.0
RANDOM_WALK_TAU_S = 3.0
# The powers of tau of the Allan variance terms of IEEE 952, annex C: quantization
# (3 Q^2 / tau^2), white noise (N^2 / tau), the flicker floor (constant), random walk
# (K^2 tau / 3) and rate ramp (R^2 tau^2 / 2).
_TERM_POWERS = (-2.0, -1.0, 0.0, 1.0, 2.0)
_WHITE, _WALK = 1, 3


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
    the sample rate, ``ARW * sqrt(rate_hz)``. ``duration_s`` is the record's
    length (samples / rate).
    """

    axis: str
    taus_s: np.ndarray
    adev_rad_s: np.ndarray
    angle_random_walk_rad_s_rt_hz: float
    bias_instability_rad_s: float
    bias_instability_tau_s: float
    rate_noise_rad_s: float
    duration_s: float


@dataclass(frozen=True)
class NoiseLines:
    """
    The white-noise and random-walk lines of an Allan deviation: Kalibr's two densities.

    In the record's unit U (rad/s for a gyro, m/s^2 for an accelerometer):
    ``noise_density`` N in U/sqrt(Hz), the line sigma = N / sqrt(tau) read at
    tau = 1 s; ``random_walk`` K in U/s/sqrt(Hz), the line sigma = K
    sqrt(tau / 3) read at tau = 3 s. Each ``*_bound`` is True when the
    curve holds no such term within the trusted taus (too short a record,
    or a floor above it): the value is then the largest the curve allows,
    an upper bound.
    """

    noise_density: float
    noise_density_bound: bool
    random_walk: float
    random_walk_bound: bool


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


def _figures(axis: str, rate_rad_s: np.ndarray, rate_hz: float, taus) -> NoiseFigures:
    # Imported here: only the noise figures need it, and it brings scipy (about 1.4 s to
    # import, 110 MB), which the nodes' environment of `make demo` does not install.
    try:
        import allantools
    except ImportError:
        msg = ('the Allan deviation needs the allantools package: '
               "pip install allantools (or the package's toolkit extra)")
        raise CalibrationError(msg) from None
    taus_s, adev_rad_s, _, _ = allantools.oadev(rate_rad_s, rate=rate_hz, data_type='freq',
                                                taus=taus)
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
                        rate_noise_rad_s=arw_rad_s_rt_hz * float(np.sqrt(rate_hz)),
                        duration_s=duration_s)


def _term_fit(taus_s: np.ndarray, avar: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """
    Fit the Allan variance with non-negative terms c_i tau^p_i (`_TERM_POWERS`).

    Least squares of the relative misfit, each tau weighted by ``weights``;
    the non-negative solution is the best of those on every subset of terms
    (five terms: 31 subsets, each an ordinary least-squares problem).
    """
    design = taus_s[:, None] ** np.asarray(_TERM_POWERS)[None, :] / avar[:, None]
    design, target = design * weights[:, None], weights
    best, coefficients = np.inf, np.zeros(len(_TERM_POWERS))
    for size in range(1, min(len(_TERM_POWERS), taus_s.size) + 1):
        for terms in itertools.combinations(range(len(_TERM_POWERS)), size):
            solution, *_ = np.linalg.lstsq(design[:, terms], target, rcond=None)
            if np.all(solution >= 0.0):
                misfit = float(np.sum((design[:, terms] @ solution - target) ** 2))
                if misfit < best:
                    best = misfit
                    coefficients = np.zeros(len(_TERM_POWERS))
                    coefficients[list(terms)] = solution
    return coefficients


def noise_lines(figures: NoiseFigures) -> NoiseLines:
    """
    Give the white-noise and random-walk lines of an axis's Allan deviation (Kalibr's figures).

    The Allan variance at the trusted taus (those the record holds at least
    `MIN_CLUSTERS` times) is fitted with the non-negative terms of IEEE 952,
    annex C (quantization, white noise, flicker floor, random walk, rate
    ramp), each tau weighted by the square root of its number of clusters,
    its estimate's precision. N is the white-noise term's line read at
    tau = 1 s, K the random-walk term's at tau = 3 s: the asymptotes the
    curve follows at slope -1/2 and +1/2, found without picking the taus
    where either alone holds. A term the fit finds zero is replaced by the
    largest value the curve allows (its minimum of sigma sqrt(tau) for N, of
    sigma sqrt(3 / tau) for K), flagged as a bound.
    """
    taus_s, adev = figures.taus_s, figures.adev_rad_s
    trusted = taus_s <= max(figures.duration_s / MIN_CLUSTERS, taus_s[0])
    taus_s, adev = taus_s[trusted], adev[trusted]
    coefficients = _term_fit(taus_s, adev ** 2, np.sqrt(figures.duration_s / taus_s))
    white, walk = coefficients[_WHITE], coefficients[_WALK]
    density = float(np.sqrt(white)) if white > 0.0 else float(np.min(adev * np.sqrt(taus_s)))
    random_walk = float(np.sqrt(3.0 * walk)) if walk > 0.0 else \
        float(np.min(adev * np.sqrt(3.0 / taus_s)))
    return NoiseLines(noise_density=density, noise_density_bound=not white > 0.0,
                      random_walk=random_walk, random_walk_bound=not walk > 0.0)


def allan_deviation(time_s, rate_rad_s, axes, taus='octave') -> tuple[NoiseFigures, ...]:
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
    taus
        The averaging times, as allantools takes them: 'octave' (1, 2, 4, ...
        sample intervals), 'decade' or a list in seconds.

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
    return tuple(_figures(axis, rate_rad_s[:, i], rate_hz, taus) for i, axis in enumerate(axes))
