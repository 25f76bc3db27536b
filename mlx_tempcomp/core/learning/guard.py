"""
The guard: a renewed curve replaces the one in use only if it predicts later rests better.

Each still run is predicted, beside the curve in use and the prior (no correction), by the
learner's curve as it was when the run began: held out from it, never used to make it
(prequential). A window is predicted as the tracker would meet it: the mean residual of
the last still run before it (its anchor, what the tracker held at that run's end),
faded as the tracker fades it, carried to the window by the curve:

    p = (d - c(T)) - decay (anchor under c)

with d the offset the window measures relative to the prior model. For the prior p is
the error of tracking alone; for a curve, the error of tracking on top of it. Each window
is a pair: how much smaller |p| is with the learner's curve than with the curve in use.
The learner's curve (as it is now, every run learnt) replaces it when the pairs beat it
by `validation.Paired`'s rule, the rule of diagnose's guard (the mean gain
``significance`` standard errors, and a majority of the pairs won), the standard error
taken over the still runs (the windows of one run share its anchor and its wander, so
they are not independent), and worth as much as a normal test's with the runs' degrees
of freedom (`t_multiple`). When it does not, and the prior beats the curve in use by the
same rule, the prior comes back: learning never stays worse than tracking alone. A trial
is judged when it holds ``min_runs`` runs and ``min_windows`` windows; one ahead but not
yet significant goes on (up to three times as many runs), one behind starts afresh.
"""

from dataclasses import dataclass, fields
import math

import numpy as np

from ..fitting import Paired


@dataclass
class Pairs:
    """
    The sums of a set of pairs, per still run folded in for the clustered standard error.

    Per challenger (``challenger`` against the curve in use, ``prior`` against it):
    the windows and the runs, sum of the gains (|p in use| - |p challenger|), their
    per-run sums squared, sum of n_run x run sum, sum of n_run^2, the wins, and the sums
    of p^2 of the three curves.
    """

    windows: int = 0
    runs: int = 0
    gain: float = 0.0
    run_gain2: float = 0.0
    run_cross: float = 0.0
    run_count2: float = 0.0
    wins: int = 0
    prior_gain: float = 0.0
    prior_run_gain2: float = 0.0
    prior_run_cross: float = 0.0
    prior_wins: int = 0
    square_in_use: float = 0.0
    square_challenger: float = 0.0
    square_prior: float = 0.0

    def add(self, in_use: float, challenger: float, prior: float) -> None:
        """Add one window's errors p under the curve in use, the challenger and the prior."""
        self.windows += 1
        gain = abs(in_use) - abs(challenger)
        prior_gain = abs(in_use) - abs(prior)
        self.gain += gain
        self.prior_gain += prior_gain
        self.wins += gain > 0.0
        self.prior_wins += prior_gain > 0.0
        self.square_in_use += in_use * in_use
        self.square_challenger += challenger * challenger
        self.square_prior += prior * prior

    def fold_run(self, run: 'Pairs') -> None:
        """Add the pairs of one still run (a cluster)."""
        if not run.windows:
            return
        self.runs += 1
        self.run_gain2 += run.gain * run.gain
        self.run_cross += run.windows * run.gain
        self.prior_run_gain2 += run.prior_gain * run.prior_gain
        self.prior_run_cross += run.windows * run.prior_gain
        self.run_count2 += run.windows * run.windows
        for name in ('windows', 'gain', 'wins', 'prior_gain', 'prior_wins', 'square_in_use',
                     'square_challenger', 'square_prior'):
            setattr(self, name, getattr(self, name) + getattr(run, name))

    def paired(self, prior: bool = False) -> Paired:
        """Give the challenger (or the prior) against the curve in use, clustered by run."""
        n = self.windows
        total = self.prior_gain if prior else self.gain
        if n < 2 or self.runs < 2:
            return Paired(math.nan, math.nan, self.prior_wins if prior else self.wins, n)
        mean = total / n
        square = self.prior_run_gain2 if prior else self.run_gain2
        cross = self.prior_run_cross if prior else self.run_cross
        spread = max(square - 2.0 * mean * cross + mean * mean * self.run_count2, 0.0)
        error = math.sqrt(self.runs / (self.runs - 1.0) * spread) / n
        return Paired(mean, error, self.prior_wins if prior else self.wins, n)

    def gain_ratio(self, prior: bool = False) -> float:
        """Give RMS p in use / RMS p of the challenger (of the prior): > 1 is a gain."""
        other = self.square_prior if prior else self.square_challenger
        return math.sqrt(self.square_in_use / other) if other > 0.0 else math.inf

    def to_list(self) -> list:
        return [getattr(self, f.name) for f in fields(self)]

    @classmethod
    def from_list(cls, values: list) -> 'Pairs':
        return cls(*values)


PAIR_FIELDS = tuple(f.name for f in fields(Pairs))
INTEGER_PAIR_FIELDS = ('windows', 'runs', 'wins', 'prior_wins')


def t_multiple(significance: float, runs: int) -> float:
    """
    Give the multiple of a clustered standard error worth ``significance`` normal ones.

    The standard error over ``runs`` clusters has runs - 1 degrees of freedom: the
    Student t quantile of the normal tail beyond ``significance`` (found by bisection on
    the t distribution's integral), larger than it for few runs.
    """
    freedom = runs - 1
    if freedom < 1 or significance <= 0.0:
        return significance
    tail = 0.5 * math.erfc(significance / math.sqrt(2.0))
    scale = math.lgamma(0.5 * (freedom + 1)) - math.lgamma(0.5 * freedom) - \
        0.5 * math.log(freedom * math.pi)

    def beyond(t: float) -> float:
        # The tail beyond t, x = tan(theta) mapping it onto a finite interval: midpoints.
        start = math.atan(t)
        step = (0.5 * math.pi - start) / 4000
        x = np.tan(start + step * (np.arange(4000) + 0.5))
        density = np.exp(scale - 0.5 * (freedom + 1) * np.log1p(x * x / freedom))
        return float(np.sum(density * (1.0 + x * x)) * step)

    low, high = significance, significance
    while beyond(high) > tail:
        high *= 2.0
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if beyond(middle) > tail else (low, middle)
    return high


def verdict(pairs: Pairs, significance: float, prior_in_use: bool) -> tuple:
    """
    Judge a finished trial: ('accept' | 'revert' | 'keep', reason).

    ``prior_in_use``: the curve in use is the prior (no reverting to it then). The
    significance asked is that of a normal test: over few runs it takes more standard
    errors (`t_multiple`).
    """
    significance = t_multiple(significance, pairs.runs)
    challenger = pairs.paired()
    if challenger.beats(significance):
        return 'accept', (f'renewed: better on {challenger.wins} of {challenger.folds} later '
                          f'still windows, held-out gain {pairs.gain_ratio():.2f}x')
    reason = _why_not(challenger, significance, 'the renewed curve')
    if not prior_in_use:
        prior = pairs.paired(prior=True)
        if prior.beats(significance):
            return 'revert', (f'back to the prior: it was better on {prior.wins} of '
                              f'{prior.folds} later still windows, '
                              f'{pairs.gain_ratio(prior=True):.2f}x')
    return 'keep', reason


def _why_not(paired: Paired, significance: float, what: str) -> str:
    if not (paired.mean_rad_s > 0.0
            and paired.mean_rad_s >= significance * paired.standard_error_rad_s):
        return (f'{what} kept out: mean gain {paired.mean_rad_s:.3g} rad/s over '
                f'{paired.folds} later still windows, not {significance:.3g} standard errors '
                f'({paired.standard_error_rad_s:.3g} rad/s)')
    return f'{what} kept out: better on {paired.wins} of {paired.folds} windows, not most'
