"""
Whether an effect is added, and whether the model found is written: the judgement and the guard.

An effect is accepted on its held-out gain, the significance of its per-fold
improvement and its worst block (`judge`); a record effect that explains
more than every live one ends an axis's search (`record_cause`). The guard
writes the model found only when it beats the PX4-style cubic
(`choose_model`, `cubic_errors`).
"""

from dataclasses import dataclass, replace
import math
from typing import Optional

import numpy as np

from .fits import AxisSpec, best_trial, fitted_parameters, TIME_CONSTANTS_PER_RECORD, TIME_GRID_S
from .folds import Folds
from .problem import DiagnosisProblem, Score
from .results import Candidate, HeldOutError, ModelChoice
from .settings import DiagnosisSettings, RECORD_SEARCH
from ..validation import cubic_instead, PX4_ORDER


@dataclass(frozen=True)
class Judgement:
    """
    An effect's trial judged against the axis's current terms (`judge`).

    ``gain`` is the relative held-out RMS reduction; the mean per-fold
    improvement and its standard error are in rad/s; ``worst_block_change``
    is the largest rise of a block's held-out RMS over the larger of that
    RMS and the axis's; ``reason`` says why the trial is refused ('' if it
    passes).
    """

    gain: float
    mean_improvement_rad_s: float
    standard_error_rad_s: float
    worst_block_change: float
    reason: str


@dataclass(frozen=True)
class Attempt:
    """An effect tried on an axis: the spec of its best trial and its judgement."""

    effect: str
    spec: AxisSpec
    judgement: Judgement


def unbounded(problem: DiagnosisProblem, effect: str, spec: AxisSpec) -> str:
    """
    Return why a time constant found at the upper search bound is refused, or ''.

    There the record would take a longer one: a slow trend the record cannot
    tell from a drift.
    """
    if effect == 'thermal_lag':
        values = (abs(spec.thermal_lag_s),)
        _, high = problem.bounds['thermal_lag_s']
    elif effect in ('thermal_gradient', 'thermal_gradient_2'):
        values = spec.gradient_s
        _, high = problem.bounds['gradient_time_constant_s']
    else:
        return ''
    top = max(v for v in TIME_GRID_S if v <= high)
    if max(values) < top:
        return ''
    return (f'time constant {max(values):.4g} s at the upper search bound (the diagnosed '
            f'part / {TIME_CONSTANTS_PER_RECORD:g}): a slow trend this record cannot tell '
            'from a drift')


def judge(problem: DiagnosisProblem, base: Score, score: Score) -> Judgement:
    """
    Judge a trial's score against the axis's current one (`Judgement`).

    A block's change is the rise of its held-out RMS over the larger of that
    RMS and the axis's overall held-out RMS; the worst is the largest.
    """
    settings = problem.settings
    gain = (base.rms - score.rms) / base.rms if base.rms > 0.0 else 0.0
    improvement = base.fold_rms - score.fold_rms
    mean = float(np.mean(improvement))
    error = float(np.std(improvement, ddof=1) / math.sqrt(improvement.size))
    before, after = problem.block_rms(base.residual), problem.block_rms(score.residual)
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
    elif not mean > settings.significance * error:
        reason = (f'mean fold improvement {mean:.3g} rad/s not above '
                  f'{settings.significance:g} standard errors ({error:.3g} rad/s)')
    elif change[worst] > settings.block_tolerance:
        reason = (f'held-out block {worst} loses: {before[worst]:.3g} -> {after[worst]:.3g} '
                  f'rad/s, a rise of {change[worst]:.2f} x max(its RMS, the axis RMS '
                  f'{base.rms:.3g}); --block-tolerance {settings.block_tolerance:g}')
    else:
        reason = ''
    return Judgement(gain, mean, error, float(change[worst]), reason)


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
    """Test the record effects on top of the final model of an axis; report, do not add."""
    current = problem.score_spec(axis, spec)
    findings = []
    for effect in RECORD_SEARCH:
        trial = best_trial(problem, axis, spec, effect)  # always one trial
        judgement = judge(problem, current, trial.score)
        findings.append(to_candidate(problem, axis, Attempt(effect, trial.spec, judgement),
                                     number, judgement.reason))
    return tuple(findings)


def choose_model(settings: DiagnosisSettings, found: HeldOutError, cubic: HeldOutError,
                 other_found: HeldOutError, other_cubic: HeldOutError) -> ModelChoice:
    """
    Write the found model if it beats the cubic (`cubic_instead`) and is no worse beside.

    ``found`` and ``cubic`` are the held-out errors under the deciding
    validation, ``other_found`` and ``other_cubic`` under the scheme beside.
    Else the cubic is written, and the choice says why.
    """
    margin = settings.baseline_margin
    choice = ModelChoice('diagnosed', found, cubic, margin, other_found, other_cubic)
    deciding, beside = (scheme.replace('_', '-') for scheme in (settings.validation,
                                                                settings.other_validation))
    reason = cubic_instead(choice.found.rms_rad_s, choice.cubic.rms_rad_s, margin, deciding)
    if not reason and choice.other_ratio > 1.0:
        reason = (f'the model found has {beside} held-out RMS '
                  f'{choice.other_found.rms_rad_s:.3e} rad/s, {choice.other_ratio:.2f}x the '
                  f"PX4-style cubic's {choice.other_cubic.rms_rad_s:.3e} rad/s: worse there")
    if not reason:
        return choice
    return replace(choice, written='px4_cubic',
                   reason=reason + ', so the simpler cubic is written')


def cubic_errors(problem: DiagnosisProblem, folds: Folds) -> tuple:
    """
    Return the held-out error of the PX4-style cubic per axis.

    A cubic in raw T spans what a cubic in x does: the same least squares,
    clamped as the node runs it.
    """
    return tuple(problem.error(problem.score_spec(a, AxisSpec(PX4_ORDER), folds).residual, folds)
                 for a in range(len(problem.axes)))


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
