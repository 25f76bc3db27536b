"""
Whether an effect is added, and whether the model found is written: the judgement and the guard.

An effect is accepted on its held-out gain, its win over the axis's terms so
far fold by fold (`validation.paired`: the mean per-fold improvement at least
``significance`` standard errors, and better on a majority of the folds) and
its worst block (`judge`); a record effect that explains more than every live
one ends an axis's search (`record_cause`). The guard writes the model found
only when it beats the PX4-style cubic the same way, fold by fold, by the
margin on the pooled RMS, and is no worse under the scheme beside
(`choose_model`, `cubic_errors`).
"""

from dataclasses import dataclass, replace
import math
from typing import Optional

import numpy as np

from .data import HYSTERESIS_SPAN_SHARE, TIME_CONSTANTS_PER_RECORD, TIME_GRID_S, WIDTH_GRID_C
from .fits import AxisSpec, fitted_parameters, Score
from .folds import Folds
from .problem import DiagnosisProblem
from .results import Candidate, HeldOutError, ModelChoice
from .settings import DiagnosisSettings, RECORD_SEARCH
from ..fitting import cubic_instead, FORWARD, paired


@dataclass(frozen=True)
class Judgement:
    """
    An effect's trial judged against the axis's current terms (`judge`).

    ``gain`` is the relative held-out RMS reduction; the mean per-fold
    improvement and its standard error are in rad/s, ``wins`` the folds it
    improves of ``folds``; ``worst_block_change`` is the largest rise of a
    block's held-out RMS over the larger of that RMS and the axis's;
    ``reason`` says why the trial is refused ('' if it passes).
    """

    gain: float
    mean_improvement_rad_s: float
    standard_error_rad_s: float
    worst_block_change: float
    reason: str
    wins: int = 0
    folds: int = 0


@dataclass(frozen=True)
class Attempt:
    """An effect tried on an axis: the spec of its best trial and its judgement."""

    effect: str
    spec: AxisSpec
    judgement: Judgement


def unbounded(problem: DiagnosisProblem, effect: str, spec: AxisSpec) -> str:
    """
    Return why a time constant or play width found at the upper search bound is refused, or ''.

    There the record would take a longer (wider) one: a slow trend the
    record cannot tell from a drift, or a shape of the temperature over the
    record, which is the polynomial's (`DiagnosisProblem._bounds`).
    """
    if effect == 'hysteresis':
        _, high = problem.bounds['hysteresis_half_width_c']
        top = max((v for v in WIDTH_GRID_C if v <= high), default=math.inf)
        width = spec.get('hysteresis')
        return '' if width < top else (
            f'half width {width:.3g} C at the upper search bound ({HYSTERESIS_SPAN_SHARE:g} of '
            "the span wide): a shape of the temperature over the record, the polynomial's")
    if effect == 'thermal_lag':
        values = (abs(spec.thermal_lag_s),)
        _, high = problem.bounds['thermal_lag_s']
    elif effect in ('thermal_gradient', 'thermal_gradient_2'):
        values = spec.gradient_s
        _, high = problem.bounds['gradient_time_constant_s']
    else:
        return ''
    top = max((v for v in TIME_GRID_S if v <= high), default=math.inf)
    if max(values) < top:
        return ''
    return (f'time constant {max(values):.4g} s at the upper search bound (the diagnosed '
            f'part / {TIME_CONSTANTS_PER_RECORD:g}, or its thermal cycle): a slow trend this '
            'record cannot tell from a drift')


def judge(problem: DiagnosisProblem, base: Score, score: Score, folds: Folds) -> Judgement:
    """
    Judge a trial's score against the axis's current one, on the same folds (`Judgement`).

    A block's change is the rise of its held-out RMS, over the bins the folds
    count, over the larger of that RMS and the axis's overall held-out RMS;
    the worst is the largest.
    """
    settings = problem.settings
    gain = (base.rms - score.rms) / base.rms if base.rms > 0.0 else 0.0
    comparison = paired(base.fold_rms, score.fold_rms)
    before, after = (problem.block_rms(np.where(folds.scored, s.residual, math.nan))
                     for s in (base, score))
    # A block near zero cannot lose by a ratio: rises count against the axis's error too.
    # Block 0 is not judged: there every history state starts from an assumed equilibrium.
    change = (after - before) / np.maximum(before, base.rms)
    change[~np.isfinite(change)] = -math.inf  # blocks no fold predicts
    change[0] = -math.inf
    worst = int(np.argmax(change))
    if not score.rank_ok:
        reason = ('on the training blocks of some fold the term cannot be told from the '
                  'others (rank loss)')
    elif not math.isfinite(gain) or gain < settings.min_gain:
        reason = f'held-out gain {gain:.3f} below --min-gain {settings.min_gain:g}'
    elif not comparison.beats(settings.significance):
        reason = comparison.why_not(settings.significance)
    elif change[worst] > settings.block_tolerance:
        reason = (f'held-out block {worst} loses: {before[worst]:.3g} -> {after[worst]:.3g} '
                  f'rad/s, a rise of {change[worst]:.2f} x max(its RMS, the axis RMS '
                  f'{base.rms:.3g}); --block-tolerance {settings.block_tolerance:g}')
    else:
        reason = ''
    return Judgement(gain, comparison.mean_rad_s, comparison.standard_error_rad_s,
                     float(change[worst]), reason, comparison.wins, comparison.folds)


def to_candidate(problem: DiagnosisProblem, axis: int, attempt: Attempt, number: int,
                 reason: str) -> Candidate:
    """Describe an attempt of round ``number`` that is not added, for ``reason``."""
    judgement = attempt.judgement
    parameters = fitted_parameters(attempt.effect, problem.fit_terms(axis, attempt.spec),
                                   problem)
    return Candidate(attempt.effect, number, parameters, judgement.gain,
                     judgement.mean_improvement_rad_s, judgement.standard_error_rad_s, reason,
                     judgement.worst_block_change)


def record_findings(problem: DiagnosisProblem, axis: int, spec: AxisSpec, number: int) -> tuple:
    """
    Test the record effects on top of the final model of an axis; report, do not add.

    They are events on the record's clock (a step, a drift), judged forward
    in time whatever scheme decides: a fold with the step's neighbours on
    both sides would take any wander of the bias for one.
    """
    findings = []
    for effect in RECORD_SEARCH:
        trial = problem.best_trial(axis, spec, effect)  # always one trial
        folds = problem.folds_for(trial.spec, FORWARD)
        current = problem.score_spec(axis, spec, folds)
        judgement = judge(problem, current, problem.score_spec(axis, trial.spec, folds), folds)
        findings.append(to_candidate(problem, axis, Attempt(effect, trial.spec, judgement),
                                     number, judgement.reason))
    return tuple(findings)


def choose_model(settings: DiagnosisSettings, found: Score, cubic: Score,
                 other_found: HeldOutError, other_cubic: HeldOutError,
                 errors: tuple) -> ModelChoice:
    """
    Write the found model if it beats the cubic fold by fold and by the margin, else the cubic.

    ``found`` and ``cubic`` are scored on the same folds of the deciding
    validation, ``errors`` their `HeldOutError`; the found model must also
    be no worse than the cubic under the scheme beside (``other_found``,
    ``other_cubic``). The choice says why the cubic is written.
    """
    margin = settings.baseline_margin
    choice = ModelChoice('diagnosed', errors[0], errors[1], margin, other_found, other_cubic)
    deciding, beside = (scheme.replace('_', '-') for scheme in (settings.validation,
                                                                settings.other_validation))
    reason = cubic_instead(choice.found.rms_rad_s, choice.cubic.rms_rad_s, margin, deciding)
    comparison = paired(cubic.fold_rms, found.fold_rms)
    if not reason and not comparison.beats(settings.significance):
        reason = (f'against the PX4-style cubic, {deciding} fold by fold: '
                  f'{comparison.why_not(settings.significance)}')
    if not reason and choice.other_ratio > 1.0:
        reason = (f'the model found has {beside} held-out RMS '
                  f'{choice.other_found.rms_rad_s:.3e} rad/s, {choice.other_ratio:.2f}x the '
                  f"PX4-style cubic's {choice.other_cubic.rms_rad_s:.3e} rad/s: worse there")
    if not reason:
        return choice
    return replace(choice, written='px4_cubic',
                   reason=reason + ', so the simpler cubic is written')


def cubic_errors(problem: DiagnosisProblem, folds: Folds) -> tuple:
    """Return the held-out error of the PX4-style cubic per axis (`baseline_run`)."""
    return problem.baseline_run(folds).errors


def record_cause(record: tuple, tried: list) -> Optional[Candidate]:
    """
    Return the record effect that passes and gains more than every live effect that passes.

    ``record`` holds the record effects' candidates (`record_findings`),
    ``tried`` the live effects' `Attempt` of the same round.
    """
    passing = [candidate for candidate in record if not candidate.reason]
    if not passing:
        return None
    best = max(passing, key=lambda candidate: candidate.held_out_gain)
    live = max((attempt.judgement.gain for attempt in tried if not attempt.judgement.reason),
               default=-math.inf)
    return best if best.held_out_gain > live else None
