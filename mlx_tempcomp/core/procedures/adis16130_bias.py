"""
The ADIS16130 bias procedure of AN-1042, fed one sample at a time.

The note's steps: average RATE and TEMP for 10 s -> (T1, B1); wait 10 min
while the part warms itself; average again -> (T2, B2); BTC = -(B2 - B1) /
(T2 - T1); wait 40 min; average RATE for 150 s, PBC = -mean; read TEMP ->
T3. The correction is RBC = RATE + PBC + (TEMP - T3) x BTC (`LinearBtc`;
Table 6: a +0.04 deg/s/C bias slope gives BTC = -0.04 deg/s/C).

`BiasProcedure` runs the steps on sensor time from ``add(time_s, rate_rad_s,
temperature_c)``, so a command line loop or a ROS node can drive it from its
stream. The last ``allan_record_s`` of the 40-minute wait, when the part is
thermally settled, are kept as a rest record: their Allan deviation (computed
by the ``noise_figures`` function the caller passes, e.g. the one of
`mlx_tempcomp.core.series.noise`, which keeps this module numpy-only) gives the
per-sample rate noise, the expected uncertainty of each averaging window and,
unless the PBC window is fixed, its length (`averaging_time_s`). The noise
figure also drives the motion check: a window whose rate spread exceeds
``motion_noise_multiple`` times it is refused.
"""

from dataclasses import dataclass
import enum
import math
from typing import Callable, Optional

import numpy as np

from ..effects import EffectModel, LinearBtc
from ..errors import CalibrationError, ConfigError
from ..series import MIN_SAMPLES

# The note's timings (AN-1042 steps 3 to 8).
NOTE_AVERAGE_S = 10.0
NOTE_SELF_HEAT_S = 600.0
NOTE_SETTLE_S = 2400.0
NOTE_PBC_S = 150.0
# Below this change between the two points the BTC is mostly noise: at the
# simulated part's 0.0016 deg/s bias instability a 0.5 C change already gives
# about 0.005 deg/s/C (1 sigma), an eighth of the note's 0.04 deg/s/C example.
MIN_TEMPERATURE_CHANGE_C = 0.5
# A window at rest has a sample standard deviation of about the white noise
# figure (at most it, when sampling faster than the bandwidth); twice it means
# an extra, motion-like spread of sqrt(3) times the noise.
MOTION_NOISE_MULTIPLE = 2.0
MIN_WINDOW_SAMPLES = 10
# Taus beyond a tenth of the rest record rest on fewer than ten clusters
# (the limit `mlx_tempcomp.core.series.noise` applies to its bias-instability search).
RECORD_FRACTION = 10.0


class Phase(str, enum.Enum):
    """Steps of the procedure, in order."""

    POINT_1 = 'point_1'
    SELF_HEAT = 'self_heat'
    POINT_2 = 'point_2'
    SETTLE = 'settle'
    REST_RECORD = 'rest_record'
    PBC = 'pbc'
    DONE = 'done'

    @property
    def is_wait(self) -> bool:
        """Tell whether the samples of this phase are not used (self-heat and settle waits)."""
        return self in (Phase.SELF_HEAT, Phase.SETTLE)


_ORDER = tuple(Phase)


@dataclass(frozen=True)
class BiasPoint:
    """Mean temperature and rate of one averaging window."""

    temperature_c: float
    bias_rad_s: float
    samples: int
    duration_s: float


def btc_rad_s_per_c(point_1: BiasPoint, point_2: BiasPoint,
                    min_change_c: float = MIN_TEMPERATURE_CHANGE_C) -> float:
    """
    Return the note's BTC = -(B2 - B1) / (T2 - T1) in rad/s/C.

    Raise CalibrationError naming T1 and T2 when they differ by less than
    ``min_change_c``: the part did not warm between the points.
    """
    change_c = point_2.temperature_c - point_1.temperature_c
    if not abs(change_c) >= min_change_c:
        msg = (f'T1 {point_1.temperature_c:.3f} C and T2 {point_2.temperature_c:.3f} C differ '
               f'by {abs(change_c):.3f} C, less than {min_change_c:g} C: the part did not '
               'warm itself between the two points (self-heating wait too short, or the part '
               'was already warm at the start); a BTC from them would be mostly noise')
        raise CalibrationError(msg)
    return -(point_2.bias_rad_s - point_1.bias_rad_s) / change_c


def averaging_time_s(figures, default_s: float, record_s: float) -> float:
    """
    Return the averaging time the Allan deviation of a rest record advises.

    It is the tau of the Allan minimum (the bias-instability floor,
    ``figures.bias_instability_tau_s``), at most a tenth of the record
    length ``record_s`` and at least the note's ``default_s``.
    """
    return max(float(default_s), min(float(figures.bias_instability_tau_s),
                                     float(record_s) / RECORD_FRACTION))


def adev_at_rad_s(figures, tau_s: float) -> tuple:
    """
    Return (Allan deviation at ``tau_s``, whether tau lies within the curve).

    Read by log-log interpolation of ``figures.taus_s`` / ``adev_rad_s``;
    outside the curve, white noise (slope -1/2) below it and the last value
    above it, flagged False.
    """
    taus = np.asarray(figures.taus_s, dtype=np.float64)
    adev = np.asarray(figures.adev_rad_s, dtype=np.float64)
    if tau_s < taus[0]:
        return float(adev[0] * math.sqrt(taus[0] / tau_s)), False
    if tau_s > taus[-1]:
        return float(adev[-1]), False
    return float(np.exp(np.interp(math.log(tau_s), np.log(taus), np.log(adev)))), True


def short_window(rate_hz: float, average_s: float, pbc_s: Optional[float],
                 allan_record_s: float) -> Optional[tuple]:
    """
    Give (setting, seconds, why) for the first window too short at ``rate_hz``, or None.

    The averaging windows (``average_s``, ``pbc_s``; None: advised later) need
    MIN_WINDOW_SAMPLES samples; the rest record (``allan_record_s``, 0 skips it)
    the MIN_SAMPLES of an Allan deviation. The caller names the setting its way.
    """
    for name, seconds in (('average_s', average_s), ('pbc_s', pbc_s)):
        if seconds is not None and seconds * rate_hz < MIN_WINDOW_SAMPLES:
            return name, seconds, f'gives fewer than {MIN_WINDOW_SAMPLES} samples'
    if 0.0 < allan_record_s * rate_hz < MIN_SAMPLES:
        return ('allan_record_s', allan_record_s,
                f'gives fewer than the {MIN_SAMPLES} samples an Allan deviation needs '
                '(0 skips it)')
    return None


@dataclass(frozen=True)
class ProcedureSettings:
    """Durations (sensor seconds) and limits of the procedure; None PBC = advised by Allan."""

    average_s: float = NOTE_AVERAGE_S
    self_heat_s: float = NOTE_SELF_HEAT_S
    settle_s: float = NOTE_SETTLE_S
    pbc_s: Optional[float] = None
    allan_record_s: float = 0.0
    min_temperature_change_c: float = MIN_TEMPERATURE_CHANGE_C
    motion_noise_multiple: float = MOTION_NOISE_MULTIPLE
    rate_noise_rad_s: Optional[float] = None

    def __post_init__(self) -> None:
        for name in ('average_s', 'min_temperature_change_c', 'motion_noise_multiple'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f'{name} must be positive, got {value}')
        for name in ('self_heat_s', 'settle_s', 'allan_record_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f'{name} must be >= 0, got {value}')
        for name in ('pbc_s', 'rate_noise_rad_s'):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f'{name} must be positive or None, got {value}')

    def pbc_window_s(self, figures) -> float:
        """Return the PBC window: as given, else the Allan advice, else the note's 150 s."""
        if self.pbc_s is not None:
            return self.pbc_s
        if figures is None:
            return NOTE_PBC_S
        return averaging_time_s(figures, NOTE_PBC_S, self.allan_record_s)


@dataclass(frozen=True)
class BiasResult:
    """The two points, BTC, the PBC window and T3, and the noise of the rest record."""

    point_1: BiasPoint
    point_2: BiasPoint
    btc_rad_s_per_c: float
    pbc_point: BiasPoint
    noise: object  # the figures of the rest record, or None without one

    @property
    def pbc_rad_s(self) -> float:
        return -self.pbc_point.bias_rad_s

    @property
    def t3_c(self) -> float:
        return self.pbc_point.temperature_c

    @property
    def btc_uncertainty_rad_s_per_c(self) -> Optional[float]:
        """Return the expected 1-sigma error of BTC from the rest record's noise, or None."""
        if self.noise is None:
            return None
        change_c = abs(self.point_2.temperature_c - self.point_1.temperature_c)
        adev_1_rad_s, _ = adev_at_rad_s(self.noise, self.point_1.duration_s)
        adev_2_rad_s, _ = adev_at_rad_s(self.noise, self.point_2.duration_s)
        return math.hypot(adev_1_rad_s, adev_2_rad_s) / change_c

    @property
    def model(self) -> EffectModel:
        return LinearBtc(pbc_rad_s=(self.pbc_rad_s,), btc_rad_s_per_c=(self.btc_rad_s_per_c,),
                         t3_c=self.t3_c).model()


class _Window:
    """Running sums of one averaging window (rate shifted by its first value for precision)."""

    def __init__(self):
        self.samples = 0
        self.first_s = self.last_s = math.nan
        self._shift = 0.0
        self._rate = self._rate_sq = self._temperature = 0.0

    def add(self, time_s: float, rate_rad_s: float, temperature_c: float) -> None:
        if self.samples == 0:
            self.first_s = time_s
            self._shift = rate_rad_s
        self.last_s = time_s
        self.samples += 1
        delta = rate_rad_s - self._shift
        self._rate += delta
        self._rate_sq += delta * delta
        self._temperature += temperature_c

    def point(self, name: str, duration_s: float) -> BiasPoint:
        if self.samples < MIN_WINDOW_SAMPLES:
            msg = (f'the {name} window of {duration_s:g} s got {self.samples} samples, fewer '
                   f'than {MIN_WINDOW_SAMPLES}: the stream is too slow or stalled')
            raise CalibrationError(msg)
        return BiasPoint(temperature_c=self._temperature / self.samples,
                         bias_rad_s=self._shift + self._rate / self.samples,
                         samples=self.samples, duration_s=duration_s)

    @property
    def spread_rad_s(self) -> float:
        """Sample standard deviation of the rate."""
        mean = self._rate / self.samples
        return math.sqrt(max(self._rate_sq / self.samples - mean * mean, 0.0)
                         * self.samples / max(self.samples - 1, 1))


class BiasProcedure:
    """
    AN-1042's bias procedure as a state machine on sensor time.

    Feed every sample with `add`; `phase`, `progress` and `phase_end_s`
    say where it stands, `point_1`, `point_2`, `btc_rad_s_per_c`, `noise`
    fill in as the phases close and `result` is set once the phase is DONE.
    ``noise_figures(time_s, rate_rad_s)`` (1-D arrays) returns the noise
    figures of the rest record (attributes ``rate_noise_rad_s``, ``taus_s``,
    ``adev_rad_s``, ``bias_instability_tau_s``); it is required when
    ``settings.allan_record_s`` > 0. `add` raises CalibrationError when a
    window moved, the temperature did not change between the points, or the
    stream stalled.
    """

    def __init__(self, settings: ProcedureSettings = ProcedureSettings(),
                 noise_figures: Optional[Callable] = None):
        if settings.allan_record_s > 0.0 and noise_figures is None:
            raise ConfigError('a rest record (allan_record_s > 0) needs a noise_figures function')
        self.settings = settings
        self._noise_figures = noise_figures
        self.phase = Phase.POINT_1
        self.phase_start_s = None
        self.point_1 = self.point_2 = None
        self.btc_rad_s_per_c = None
        self.noise = None
        self.result = None
        self.skipped = {'non-finite': 0, 'time not increasing': 0}
        self._last_s = -math.inf
        self._window = _Window()
        self._spreads = {}
        self._rest_time = []
        self._rest_rate = []

    @property
    def rate_noise_rad_s(self) -> Optional[float]:
        """Return the noise figure of the motion check: the rest record's, else the setting."""
        if self.noise is not None:
            return float(self.noise.rate_noise_rad_s)
        return self.settings.rate_noise_rad_s

    def phase_duration_s(self, phase: Phase) -> float:
        """Return how long ``phase`` lasts in sensor seconds (the PBC once the noise is known)."""
        s = self.settings
        durations = {
            Phase.POINT_1: s.average_s, Phase.SELF_HEAT: s.self_heat_s,
            Phase.POINT_2: s.average_s, Phase.SETTLE: max(s.settle_s - s.allan_record_s, 0.0),
            Phase.REST_RECORD: s.allan_record_s, Phase.PBC: s.pbc_window_s(self.noise),
            Phase.DONE: 0.0}
        return durations[phase]

    @property
    def phase_end_s(self) -> Optional[float]:
        """Return the sensor time the current phase ends at (None before the first sample)."""
        if self.phase_start_s is None or self.phase is Phase.DONE:
            return None
        return self.phase_start_s + self.phase_duration_s(self.phase)

    @property
    def progress(self) -> float:
        """Return the fraction of the current phase done, 0 to 1."""
        if self.phase is Phase.DONE:
            return 1.0
        if self.phase_start_s is None:
            return 0.0
        duration_s = self.phase_duration_s(self.phase)
        return min(max((self._last_s - self.phase_start_s) / duration_s, 0.0), 1.0)

    def add(self, time_s: float, rate_rad_s: float, temperature_c: float) -> Phase:
        """Take one sample (sensor time); return the phase it fell into."""
        time_s, rate_rad_s, temperature_c = float(time_s), float(rate_rad_s), \
            float(temperature_c)
        if not all(math.isfinite(v) for v in (time_s, rate_rad_s, temperature_c)):
            self.skipped['non-finite'] += 1
            return self.phase
        if time_s <= self._last_s:
            self.skipped['time not increasing'] += 1
            return self.phase
        self._last_s = time_s
        if self.phase_start_s is None:
            self.phase_start_s = time_s
        while self.phase is not Phase.DONE and time_s >= self.phase_end_s:
            self._close_phase()
        if self.phase in (Phase.POINT_1, Phase.POINT_2, Phase.PBC):
            self._window.add(time_s, rate_rad_s, temperature_c)
        elif self.phase is Phase.REST_RECORD:
            self._rest_time.append(time_s)
            self._rest_rate.append(rate_rad_s)
        return self.phase

    def _close_phase(self) -> None:
        phase = self.phase
        duration_s = self.phase_duration_s(phase)
        if phase in (Phase.POINT_1, Phase.POINT_2, Phase.PBC):
            point = self._window.point(phase.value, duration_s)
            self._spreads[phase] = self._window.spread_rad_s
            self._check_motion((phase,))
            self._window = _Window()
            if phase is Phase.POINT_1:
                self.point_1 = point
            elif phase is Phase.POINT_2:
                self.point_2 = point
                self.btc_rad_s_per_c = btc_rad_s_per_c(
                    self.point_1, point, self.settings.min_temperature_change_c)
            else:
                self.result = BiasResult(point_1=self.point_1, point_2=self.point_2,
                                         btc_rad_s_per_c=self.btc_rad_s_per_c,
                                         pbc_point=point, noise=self.noise)
        elif phase is Phase.REST_RECORD and self.settings.allan_record_s > 0.0:
            self.noise = self._noise_figures(np.array(self._rest_time),
                                             np.array(self._rest_rate))
            self._rest_time, self._rest_rate = [], []
            # The points were taken before any noise figure was known.
            self._check_motion((Phase.POINT_1, Phase.POINT_2))
        self.phase_start_s += duration_s
        self.phase = _ORDER[_ORDER.index(phase) + 1]

    def _check_motion(self, phases) -> None:
        noise_rad_s = self.rate_noise_rad_s
        if noise_rad_s is None:
            return
        limit = self.settings.motion_noise_multiple
        for phase in phases:
            spread_rad_s = self._spreads[phase]
            if spread_rad_s > limit * noise_rad_s:
                msg = (f'the part moved during the {phase.value} window: its rate spread '
                       f'(standard deviation) {spread_rad_s:.4g} rad/s is '
                       f'{spread_rad_s / noise_rad_s:.3g} x the rest noise rate_noise_rad_s '
                       f'{noise_rad_s:.4g} rad/s, above the motion_noise_multiple {limit:g}; '
                       'mount it on a fixed platform and start again')
                raise CalibrationError(msg)
