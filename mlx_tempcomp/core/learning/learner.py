"""
The field learner: the still windows the tracker learns from, made into a renewed curve.

`FieldLearner` keeps, per axis, the `CurveFilter` of the correction c(T) to the prior
model (fixed size: a level and the shape at the knots, with its covariance), the curve in
use (``accepted``, a `CorrectionTable` relative to the prior model, zero at first: tracking
alone), and the guard's trial of the next candidate (`guard`). It is fed, window by window,
what the tracker learnt (`close`, after every closed window):

- A learnt window gives, per axis it was learnt on, the offset it measures relative to the
  prior model (the tracker's measured offset plus the correction that was taken off
  during it), its mean temperature, the variance of its mean and its gravity direction.
  It is refused (and counted) when a value is not finite, its temperature lies outside
  the knots, or its temperature jumped from the learnt window before by more than the
  tracker's temperature rate bound allows.
- The windows of a still run go into working filters and count for the guard only when
  the run ends: a run whose shift the tracker withdraws (`BiasTracking.withdrawn`: a
  shift a slow turn could explain that the run did not hold) is dropped, with its pairs.
- A turn of the gravity seen by more than `parameters.TURN_RAD` between learnt windows
  makes the level unknown again (g-sensitivity moves every bias); the shape stays.
- After each run the guard may accept the candidate (it becomes the curve in use), bring
  back the prior, or keep the curve in use and say why (``reason`` per axis).

``state`` gives a plain dict for a state file and `FieldLearner.restore` checks one read
back (CalibrationError naming the key: the caller starts from the prior and says so).
"""

import math

import numpy as np

from .curve import CurveFilter, observation, prior_covariance
from .guard import Pairs, verdict
from .settings import LearningSettings, TURN_RAD
from .state import learner_state, restore_state
from ..errors import CalibrationError
from ..node_models import CorrectionTable

# A held-out gain is reported up to this (a curve that predicted every window exactly).
MAX_GAIN = 1e6
# A trial not decided at min_runs that is ahead goes on for up to this many times as many
# runs; one behind starts afresh.
TRIAL_RUNS_MULTIPLE = 3


def _run_sums(sums, d: float, h: np.ndarray, time_s: float) -> tuple:
    """
    Add a window to a run's sums: (windows, sum of d, last time, sum of the knot weights).

    The knot weights (h without the level) give the sum of any curve over the run's
    windows: its values at the knots dotted with them.
    """
    if sums is None:
        return (1.0, d, time_s) + tuple(float(v) for v in h[1:])
    return (sums[0] + 1.0, sums[1] + d, time_s) + tuple(
        float(a + b) for a, b in zip(sums[3:], h[1:]))


def _decay(elapsed_s: float, walk: float, cap: float) -> float:
    """Give how much of an offset the tracker still holds after ``elapsed_s`` (its fading)."""
    if walk <= 0.0 or elapsed_s <= 0.0:
        return 1.0
    return math.exp(-elapsed_s * walk * walk / (2.0 * cap * cap))


class FieldLearner:
    """The learner of every axis; see the module notes. ``axes`` names the gyro axes."""

    def __init__(self, settings: LearningSettings, axes: tuple):
        self.settings = settings
        self.axes = tuple(axes)
        if len(self.axes) != settings.axes:
            msg = f'learning settings of {settings.axes} axes for axes {list(self.axes)}'
            raise CalibrationError(msg)
        knots = settings.knots_c
        self.priors = [prior_covariance(knots, settings.prior_std_rad_s[i],
                                        settings.level_std_rad_s[i], settings.correlation_c)
                       for i in range(len(self.axes))]
        self.committed = [CurveFilter(prior) for prior in self.priors]
        self.working = [f.copy() for f in self.committed]
        self.accepted = CorrectionTable.zero(knots, len(self.axes))
        # The curve taken off now, and the one before the last swap with the time it
        # stopped (for a window learnt after the swap that was corrected before it).
        self.applied = self.accepted
        self.before = None
        self.swaps = 0
        count = len(self.axes)
        # (T, time) of the last window the tracker learnt from, per axis: its offset's anchor.
        self.tracker_anchor = [None] * count
        self.candidate = [None] * count        # knot values of the frozen candidate
        self.trial = [Pairs() for _ in range(count)]
        self.run_pairs = [Pairs() for _ in range(count)]
        # Per axis, the sums of the last committed run and of the run going on (`_run_sums`).
        self.anchor = [None] * count
        self.run_last = [None] * count
        self.pending = False                   # a run's windows not committed yet
        self.last_window = None                # (T, time) of the last learnt window seen
        self.gravity = None
        self.windows = 0                       # windows used (per window, any axis)
        self.refused = {}
        self.runs_committed = 0
        self.runs_dropped = 0
        self.renewals = [0] * count
        self.last_renewal = [None] * count     # (time, gain)
        self.reason = ['nothing learnt yet'] * count
        self.seen_runs = 0
        self.seen_withdrawn = 0

    # The windows.

    def close(self, tracker) -> None:
        """
        Take what ``tracker`` did when its last window closed; renew the curve taken off.

        Call it after `BiasTracking.advance` closed a window, before the next sample is
        corrected: a curve accepted while no still run goes on is taken off (``applied``)
        from that sample on, and the tracker's offset re-expressed against it (`swap`).
        """
        if tracker.withdrawn != self.seen_withdrawn:
            self._drop()
        elif self.pending and (tracker.runs != self.seen_runs or not tracker.in_run):
            self._commit()
        self.seen_runs, self.seen_withdrawn = tracker.runs, tracker.withdrawn
        for window, axes in tracker.learnt:
            if math.isfinite(window.temperature_c):
                for i in axes:
                    self.tracker_anchor[i] = (window.temperature_c, window.end_s)
            during = self.before[0] if self.before is not None and \
                window.end_s <= self.before[1] else self.applied
            self.window(window, axes, during)
        if self.pending and not tracker.in_run:
            self._commit()
        if self.accepted != self.applied and not tracker.in_run:
            self.swap(tracker)

    def swap(self, tracker) -> None:
        """
        Take the accepted curve off from now on; re-express the tracker's offset against it.

        The tracker's offset o of an axis was learnt at its last learnt window (temperature
        T*) relative to the curve applied then, and has faded since as the tracker fades it;
        against the new curve it is o - decay (c_new(T*) - c_old(T*)). Nothing is counted
        twice: the rate published at T* is the same before and after, and away from T* it
        moves by the change of shape the new curve learnt.
        """
        state = tracker.state()
        offsets = list(state['offset_rad_s'])
        s = self.settings
        for i in range(len(self.axes)):
            anchor = self.tracker_anchor[i]
            if anchor is None or state['time_s'] is None:
                continue
            temperature, time_s = anchor
            change = self.accepted.at(i, temperature) - self.applied.at(i, temperature)
            offsets[i] -= _decay(state['time_s'] - time_s, s.random_walk_rad_s_rt_s[i],
                                 s.tracker_std_rad_s[i]) * change
        tracker.seed(offsets, state['variance_rad2_s2'])
        window = tracker.open_window
        self.before = (self.applied, -math.inf if window is None else window[0])
        self.applied = self.accepted
        self.swaps += 1

    def _refuse(self, reason: str) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + 1

    def window(self, w, axes, applied: CorrectionTable) -> None:
        """Learn from one window on ``axes`` (indices); see the module notes."""
        s = self.settings
        temperature = w.temperature_c
        axes = sorted(axes)
        measured = [w.measured_rad_s[i] for i in axes]
        if not (w.samples > 0 and math.isfinite(temperature) and math.isfinite(w.end_s)
                and all(math.isfinite(v) for v in measured)):
            self._refuse('not finite')
            return
        previous, self.last_window = self.last_window, (temperature, w.end_s)
        if not s.knots_c[0] <= temperature <= s.knots_c[-1]:
            self._refuse('outside the knots')
            return
        if previous is not None:
            allowed = s.max_temperature_rate_c_s * (abs(w.end_s - previous[1]) + s.window_s)
            if not abs(temperature - previous[0]) <= allowed:
                self._refuse('temperature jump')
                return
        if w.acceleration_m_s2 is not None:
            self._gravity(w.acceleration_m_s2)
        h = observation(s.knots_c, temperature)
        for i, value in zip(axes, measured):
            d = value + applied.at(i, temperature)
            noise = s.rate_noise_rad_s[i]
            walk = s.random_walk_rad_s_rt_s[i]
            variance = noise * noise / w.samples + walk * walk * s.window_s
            self._score(i, d, h, w.end_s)
            working = self.working[i]
            working.predict(w.end_s, walk, s.fading_s[i])
            if self.run_last[i] is None:
                working.forget_level(variance)
            working.update(h, d, variance, s.agreement_multiple)
            self.run_last[i] = _run_sums(self.run_last[i], d, h, w.end_s)
        self.windows += 1
        self.pending = True

    def _gravity(self, acceleration) -> None:
        norm = math.sqrt(sum(a * a for a in acceleration))
        if not (math.isfinite(norm) and norm > 0.0):
            return
        up = tuple(a / norm for a in acceleration)
        if self.gravity is not None:
            cosine = sum(a * b for a, b in zip(up, self.gravity))
            if math.acos(max(-1.0, min(1.0, cosine))) > TURN_RAD:
                for working in self.working:
                    working.forget_level()
        self.gravity = up

    def _score(self, i: int, d: float, h: np.ndarray, time_s: float) -> None:
        """
        Add the window's errors under the three curves to the run's pairs (`guard`).

        The anchor is the mean residual of the last committed run under each curve (what
        the tracker held at its end), faded as the tracker fades it.
        """
        candidate, anchor = self.candidate[i], self.anchor[i]
        if candidate is None or anchor is None:
            return
        s = self.settings
        count, total, anchor_s = anchor[:3]
        weights = np.asarray(anchor[3:])
        decay = _decay(time_s - anchor_s, s.random_walk_rad_s_rt_s[i], s.tracker_std_rad_s[i])

        def error(values) -> float:
            values = np.asarray(values)
            return (d - float(h[1:] @ values)) - decay * (total - float(weights @ values)) / count

        self.run_pairs[i].add(error(self.accepted.values_rad_s[i]), error(candidate),
                              error(np.zeros(len(s.knots_c))))

    # The runs.

    def _drop(self) -> None:
        """Forget the run going on: its shift was withdrawn (a slow turn may have made it)."""
        if self.pending:
            self.runs_dropped += 1
        self.working = [f.copy() for f in self.committed]
        self.run_pairs = [Pairs() for _ in self.axes]
        self.run_last = [None] * len(self.axes)
        self.pending = False

    def _commit(self) -> None:
        """Keep the run's windows; fold its pairs into the trials; judge the trials."""
        self.committed = [f.copy() for f in self.working]
        self.runs_committed += 1
        self.pending = False
        for i in range(len(self.axes)):
            self.trial[i].fold_run(self.run_pairs[i])
            self.run_pairs[i] = Pairs()
            if self.run_last[i] is not None:
                self.anchor[i] = self.run_last[i]
                self.run_last[i] = None
            self._judge(i)

    def _judge(self, i: int) -> None:
        """
        Judge the trial when it holds enough runs; take the learner's curve as the candidate.

        Every run is predicted by the curve as it was when the run began (held out from
        it); the trial sums how that always-renewed curve did against the curve in use
        since the last decision. Accepted, the curve now (all the runs) is taken in use.
        """
        s = self.settings
        trial = self.trial[i]
        fresh = tuple(float(v) for v in self.committed[i].curve())
        if self.candidate[i] is None:
            if self.runs_committed < s.min_runs:
                self.reason[i] = f'{self.runs_committed} still runs learnt; the learnt curve ' \
                                 f'is tried from {s.min_runs} on'
                return
            self.reason[i] = 'the learnt curve is tried on the still runs to come'
        elif trial.runs >= s.min_runs and trial.windows >= s.min_windows:
            prior_in_use = not any(self.accepted.values_rad_s[i])
            decision, reason = verdict(trial, s.significance, prior_in_use)
            if decision == 'keep' and trial.gain > 0.0 and \
                    trial.runs < TRIAL_RUNS_MULTIPLE * s.min_runs:
                reason += '; ahead, the trial goes on'
            else:
                time_s = self.committed[i].time_s
                if decision == 'accept':
                    self.accepted = self.accepted.with_axis(i, fresh)
                    self.last_renewal[i] = (time_s, min(trial.gain_ratio(), MAX_GAIN))
                elif decision == 'revert':
                    self.accepted = self.accepted.with_axis(i, (0.0,) * len(s.knots_c))
                    self.last_renewal[i] = (time_s,
                                            min(trial.gain_ratio(prior=True), MAX_GAIN))
                self.renewals[i] += decision != 'keep'
                self.trial[i] = Pairs()
            self.reason[i] = reason
        self.candidate[i] = fresh

    # What it holds.

    def coverage(self) -> list:
        """
        Give per axis, per knot, how well the curve is known there, from 0 to 1.

        One less its variance over the prior model's own error squared: 0 where it is no
        better known than the prior model, 1 where it is known exactly.
        """
        shares = []
        for i, f in enumerate(self.committed):
            prior = np.square(self.settings.prior_std_rad_s[i])
            shares.append([float(v) for v in np.clip(1.0 - f.curve_variance() / prior, 0.0,
                                                     1.0)])
        return shares

    def status(self) -> dict:
        """Give what the learner holds, per axis, for diagnostics and reports."""
        return {
            'windows': self.windows, 'runs': self.runs_committed,
            'runs_dropped': self.runs_dropped, 'refused': dict(self.refused),
            'axes': {a: {'renewals': self.renewals[i], 'last_renewal': self.last_renewal[i],
                         'reason': self.reason[i],
                         'trial_windows': self.trial[i].windows, 'trial_runs': self.trial[i].runs,
                         'correction_rad_s': list(self.accepted.values_rad_s[i])}
                     for i, a in enumerate(self.axes)},
            'knots_c': list(self.settings.knots_c), 'coverage': self.coverage()}

    def state(self) -> dict:
        """Give the state as plain YAML-safe values (`restore` checks it back)."""
        return learner_state(self)

    @classmethod
    def restore(cls, settings: LearningSettings, axes: tuple, state) -> 'FieldLearner':
        """Give the learner a state dict holds; CalibrationError naming the first wrong key."""
        learner = cls(settings, axes)
        restore_state(learner, state)
        return learner
