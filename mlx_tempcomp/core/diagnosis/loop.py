"""The loop itself: step 0, the rounds that add effects, the guard, and the `Diagnosis`."""

from dataclasses import dataclass, replace
import math
from typing import Optional

import numpy as np

from .acceptance import (Attempt, choose_model, cubic_errors, judge, record_cause,
                         record_findings, to_candidate, unbounded)
from .data import TIME_CONSTANTS_PER_RECORD
from .fits import AxisSpec, fitted_parameters, Score, Trial
from .folds import Folds
from .held_out_part import (compare_test, diagnosed_rows, heating_bins, outside_fitted_range,
                            test_normalised_error, written_error_by_temperature)
from .problem import DiagnosisProblem, HeldOutRun
from .results import (AxisDiagnosis, BinnedResidual, Diagnosis, HeldOutError, ModelChoice,
                      RecordFit, Step)
from .settings import BASE_EFFECT, DiagnosisSettings, ProgressCallback, RECORD_SEARCH
from ..effects import EffectModel, EFFECTS
from ..fitting import join_records, one_standard_error, order_score, paired, PX4_ORDER
from ..node_models import INPUTS

# The record shows motion when the specific force turns by this much, or its
# magnitude moves by MOTION_M_S2 (1 s means, 1st to 99th percentile).
MOTION_DEG = 5.0
MOTION_M_S2 = 1.0


CUBIC = AxisSpec(PX4_ORDER, baseline=True)


def _order_scores(problem: DiagnosisProblem, axis: int, spec: AxisSpec) -> tuple:
    """Score every polynomial order with the other terms of ``spec`` fitted alongside."""
    scores = []
    for order in range(problem.settings.max_order + 1):
        score = problem.score_spec(axis, replace(spec, order=order))
        scores.append(order_score(order, score.fold_rms if score.rank_ok else
                                  np.full(score.fold_rms.shape, math.inf)))
    return tuple(scores)


def _paired_best(problem: DiagnosisProblem, axis: int, incumbent: AxisSpec,
                 challengers) -> AxisSpec:
    """
    Give the polynomial order that beats the incumbent fold by fold, else the incumbent.

    Each challenger is scored on the incumbent's folds beside it; one the
    training folds cannot support (rank loss) never wins. Of those that win,
    the lowest order whose mean fold RMS is within one standard error of the
    best's (`validation.one_standard_error`).
    """
    base = problem.score_spec(axis, incumbent)
    folds = problem.folds_for(incumbent)
    winners = []
    for challenger in challengers:
        score = problem.score_spec(axis, challenger, folds)
        if score.rank_ok and paired(base.fold_rms, score.fold_rms).beats(
                problem.settings.significance):
            winners.append((challenger, order_score(challenger.order, score.fold_rms)))
    if not winners:
        return incumbent
    order = one_standard_error([score for _, score in winners])
    return next(spec for spec, _ in winners if spec.order == order)


def _step_zero_order(problem: DiagnosisProblem, axis: int) -> AxisSpec:
    """Give the PX4-style cubic, unless another order beats it fold by fold."""
    orders = [AxisSpec(order) for order in range(problem.settings.max_order + 1)
              if order != PX4_ORDER]
    return _paired_best(problem, axis, CUBIC, orders)


def _rechosen_order(problem: DiagnosisProblem, axis: int, trial: AxisSpec) -> AxisSpec:
    """
    Raise the polynomial order beside an accepted effect if a higher one beats it fold by fold.

    Never lower: the polynomial keeps the temperature shape, and an effect
    does not stand in for it.
    """
    higher = [replace(trial, order=order)
              for order in range(trial.order + 1, problem.settings.max_order + 1)]
    return _paired_best(problem, axis, trial, higher)


def _skipped(problem: DiagnosisProblem) -> dict:
    """Map each effect the data cannot support, or the settings leave out, to the reason."""
    reference = ', '.join(f'ref_{a}' for a in problem.axes)
    bounds = problem.bounds
    skipped = {}
    low, high = bounds['gradient_time_constant_s']
    if low > high:
        for effect in ('thermal_gradient', 'thermal_gradient_2'):
            skipped[effect] = (f'the diagnosed part ({problem.duration_s:.0f} s) is too short: '
                               f'time constants from {low:g} s (the rate window) must fit '
                               f'{TIME_CONSTANTS_PER_RECORD:g} times into it')
    lag_low, lag_high = bounds['thermal_lag_s']
    if lag_low > lag_high:
        skipped['thermal_lag'] = f'the diagnosed part ({problem.duration_s:.0f} s) is too short'
    for effect in EFFECTS:
        lacking = [column for name in sorted(effect.inputs)
                   if getattr(problem.inputs, name) is None for column in INPUTS[name].columns]
        if lacking:
            skipped[effect.name] = f'needs column{"s" * (len(lacking) > 1)} {", ".join(lacking)}'
    if 'supply_voltage' not in skipped and problem.supply_reference is None:
        skipped['supply_voltage'] = 'supply_voltage is constant'
    if 'secondary_temperature' not in skipped and problem.secondary is None:
        skipped['secondary_temperature'] = 'temperature_2 is constant'
    if 'acceleration_sensitivity' not in skipped:
        turn_deg, change_m_s2 = problem.motion()
        if turn_deg < MOTION_DEG and change_m_s2 < MOTION_M_S2:
            skipped['acceleration_sensitivity'] = (
                f'the sensor did not move: the specific force turns {turn_deg:.2g} deg and '
                f'its magnitude changes {change_m_s2:.2g} m/s^2 (needs {MOTION_DEG:g} deg or '
                f'{MOTION_M_S2:g} m/s^2); a term would only stand in for temperature')
    for effect in ('scale_factor_temperature', 'rate_nonlinearity', 'cross_axis'):
        if problem.reference is None:
            skipped[effect] = f'needs reference columns {reference}'
    if 'cross_axis' not in skipped and len(problem.axes) < 2:
        skipped['cross_axis'] = 'needs at least 2 gyro axes'
    if not problem.settings.record_effects:
        for effect in RECORD_SEARCH:
            skipped[effect] = ("tied to the record's clock, a live node cannot run it: tested "
                               'as a finding only (--record-effects adds it)')
    return skipped


@dataclass(frozen=True)
class _StepZero:
    """Step 0: each axis's polynomial (order by the folds) and the uncorrected errors."""

    scores: tuple
    specs: tuple
    none_errors: tuple
    run: HeldOutRun
    model: EffectModel


@dataclass
class _Rounds:
    """What the rounds have found so far: per axis its spec, steps, rejects and cause."""

    specs: list
    steps: list
    rejected: list
    causes: list
    run: HeldOutRun
    number: int = 0


@dataclass(frozen=True)
class _Written:
    """
    What the axes write after the guard, and the figures beside.

    ``found`` are the specs the rounds found, ``specs`` those written (the
    PX4-style cubic where ``choices`` say so); ``run`` is the written specs'
    held-out run under the deciding validation, ``other_run`` their run
    under ``other``, the scheme beside; ``cubic`` and ``other_cubic`` the
    cubic's errors under each.
    """

    found: tuple
    specs: tuple
    choices: tuple
    run: HeldOutRun
    other: Folds
    other_run: HeldOutRun
    cubic: tuple
    other_cubic: tuple

    @property
    def other_errors(self) -> tuple:
        return self.other_run.errors


def diagnose(recording, settings: DiagnosisSettings = DiagnosisSettings(),
             progress: ProgressCallback = None) -> Diagnosis:
    """
    Run the loop on a recording and return the `Diagnosis`.

    ``recording`` has time_s, temperature_c, axes, gyro_rad_s and optional
    reference_rad_s, acceleration_m_s2, temperature_2_c and supply_voltage_v
    (a `mlx_tempcomp.recordings.recording.Recording`). ``progress(done, total,
    label)`` is called as work advances. Raise `CalibrationError` when the
    data cannot support the diagnosis.
    """
    records = join_records(recording)
    problem = DiagnosisProblem(records, diagnosed_rows(records, settings), settings, progress)
    skipped = _skipped(problem)
    searched = tuple(e for e in settings.effects if e not in skipped)
    zero = _step_zero(problem)
    rounds = _search(problem, zero, searched)
    findings = tuple(() if settings.record_effects else
                     record_findings(problem, axis, spec, rounds.number)
                     for axis, spec in enumerate(rounds.specs))
    written = _guard(problem, tuple(rounds.specs), rounds.run)
    return _diagnosis(problem, skipped, zero, rounds, findings, written)


def _step_zero(problem: DiagnosisProblem) -> _StepZero:
    """Fit each axis's temperature polynomial: the PX4-style cubic unless an order beats it."""
    axes = range(len(problem.axes))
    scores = tuple(_order_scores(problem, axis, AxisSpec(0)) for axis in axes)
    specs = tuple(_step_zero_order(problem, axis) for axis in axes)
    none_errors = tuple(problem.error(problem.target[:, a]) for a in axes)
    run = problem.held_out(specs, 'held-out check of step 0')
    return _StepZero(scores, specs, none_errors, run, problem.model(specs))


def _search(problem: DiagnosisProblem, zero: _StepZero, searched: tuple) -> _Rounds:
    """Add effects round by round, from step 0, until no axis accepts one."""
    axes = range(len(problem.axes))
    steps = [[Step(BASE_EFFECT, fitted_parameters(BASE_EFFECT, zero.model.terms[a], problem),
                   zero.none_errors[a], zero.run.errors[a], 0)] for a in axes]
    rounds = _Rounds(list(zero.specs), steps, [[] for _ in axes], [None for _ in axes],
                     zero.run)
    active = set(axes)
    while active:
        rounds.number += 1
        accepted = _round(problem, rounds, searched, active)
        if not accepted:
            break
        _add(problem, rounds, accepted)
        active = set(accepted)
    return rounds


def _round(problem: DiagnosisProblem, rounds: _Rounds, searched: tuple, active: set) -> dict:
    """Try every effect each active axis lacks; give {axis: the `Attempt` it adds}."""
    work = sum(1 for a in active for e in searched if rounds.specs[a].can_add(e))
    done = 0
    accepted = {}
    for axis in sorted(active):
        spec = rounds.specs[axis]
        tried = []
        for effect in searched:
            if not spec.can_add(effect):
                continue
            trial = problem.best_trial(axis, spec, effect)
            done += 1
            problem.report(done, work, f'round {rounds.number}: candidate effects')
            if trial is not None:
                tried.append(_attempt(problem, axis, effect, trial, spec))
        tried.sort(key=lambda attempt: (bool(attempt.judgement.reason),
                                        -attempt.judgement.gain))
        if not problem.settings.record_effects:
            record = record_findings(problem, axis, spec, rounds.number)
            rounds.causes[axis] = record_cause(record, tried)
        chosen = _choose(problem, rounds, axis, tried)
        if chosen is not None:
            accepted[axis] = chosen
    return accepted


def _attempt(problem: DiagnosisProblem, axis: int, effect: str, trial: Trial,
             spec: AxisSpec) -> Attempt:
    """Judge an effect's best trial against the axis's terms on its folds; a bound refuses."""
    folds = problem.folds_for(trial.spec)
    current = problem.score_spec(axis, spec, folds)
    judgement = judge(problem, current, trial.score, folds)
    bound = unbounded(problem, effect, trial.spec)
    if bound and not judgement.reason:
        judgement = replace(judgement, reason=bound)
    return Attempt(effect, trial.spec, judgement)


def _choose(problem: DiagnosisProblem, rounds: _Rounds, axis: int,
            tried: list) -> Optional[Attempt]:
    """Give what an axis adds this round (the best attempt, if it passes); file the rest."""
    cause = rounds.causes[axis]
    chosen = None
    for rank, attempt in enumerate(tried):
        reason = attempt.judgement.reason
        if not reason and cause is not None:
            reason = (f'the record-only {cause.effect} explains more (held-out '
                      f'gain {cause.held_out_gain:.3f}): not a live stand-in')
        if rank == 0 and not reason:
            chosen = attempt
            continue
        reason = reason or 'significant, but another effect gained more this round'
        rounds.rejected[axis].append(to_candidate(problem, axis, attempt, rounds.number,
                                                  reason))
    return chosen


def _add(problem: DiagnosisProblem, rounds: _Rounds, accepted: dict) -> None:
    """Add the accepted effects (each axis's order chosen again) and run the folds on them."""
    for axis, attempt in accepted.items():
        rounds.specs[axis] = _rechosen_order(problem, axis, attempt.spec)
    specs = tuple(rounds.specs)
    run = problem.held_out(specs, f'held-out check of round {rounds.number}')
    model = problem.model(specs)
    for axis, attempt in accepted.items():
        parameters = fitted_parameters(attempt.effect, model.terms[axis], problem)
        parameters['polynomial_order'] = specs[axis].order
        rounds.steps[axis].append(Step(attempt.effect, parameters, rounds.run.errors[axis],
                                       run.errors[axis], rounds.number,
                                       attempt.judgement.gain))
    rounds.run = run


def _guard(problem: DiagnosisProblem, found: tuple, run: HeldOutRun) -> _Written:
    """Choose per axis the model found or the PX4-style cubic (`choose_model`)."""
    settings = problem.settings
    other = problem.folds_of(settings.other_validation)
    cubic = cubic_errors(problem, problem.folds)
    other_cubic = cubic_errors(problem, other)
    other_run = problem.held_out(found, 'the other validation', other)
    choices = tuple(_choice(problem, axis, spec, run, other_run.errors[axis], other_cubic[axis])
                    for axis, spec in enumerate(found))
    cubic_axes = tuple(a for a, choice in enumerate(choices) if choice.written == 'px4_cubic')
    specs = found
    if cubic_axes:
        specs, run, other_run = _write_cubic(problem, found, cubic_axes, run, other_run, other)
    return _Written(found, specs, choices, run, other, other_run, cubic, other_cubic)


def _choice(problem: DiagnosisProblem, axis: int, spec: AxisSpec, run: HeldOutRun,
            other_found: HeldOutError, other_cubic: HeldOutError):
    """
    Judge an axis's model found against the cubic, fold by fold, on the found model's folds.

    The found model's folds run as the node runs them (`held_out`): the
    rounds' run where its folds are the deciding scheme's own, else (purged,
    a buffer of its memory) run again on its folds.
    """
    if spec.baseline:
        error = run.errors[axis]
        return ModelChoice('px4_cubic', error, error, problem.settings.baseline_margin,
                           other_found, other_cubic,
                           'the model found is the PX4-style cubic: no other order or effect '
                           'beats it fold by fold')
    folds = problem.folds_for(spec)
    if folds is not problem.folds:
        specs = tuple(spec if a == axis else CUBIC for a in range(len(problem.axes)))
        run = problem.held_out(specs, 'the guard', folds, axes=(axis,))
    error = run.errors[axis]
    own = Score(np.array(error.fold_rms_rad_s), error.rms_rad_s, True, run.residual[:, axis])
    cubic = problem.score_spec(axis, CUBIC, folds)
    return choose_model(problem.settings, own, cubic, other_found, other_cubic,
                        (error, problem.baseline_run(folds).errors[axis]))


def _write_cubic(problem: DiagnosisProblem, found: tuple, cubic_axes: tuple, run: HeldOutRun,
                 other_run: HeldOutRun, other: Folds) -> tuple:
    """Give (the specs with the cubic on ``cubic_axes``, their run, their run beside)."""
    specs = tuple(CUBIC if a in cubic_axes else spec for a, spec in enumerate(found))
    # The models clamp at the range of every axis's T_eff: with the same lags, the axes
    # that keep their model keep their figures.
    same = {s.thermal_lag_s for s in specs} == {s.thermal_lag_s for s in found}
    axes = cubic_axes if same else None
    changed = list(axes or range(len(found)))
    new = problem.held_out(specs, 'held-out check of the cubic', axes=axes)
    new_other = problem.held_out(specs, 'the other validation', other, axes)
    return specs, _merged(run, new, changed), _merged(other_run, new_other, changed)


def _merged(run: HeldOutRun, new: HeldOutRun, changed: list) -> HeldOutRun:
    """Give ``run`` with the residual and errors of the ``changed`` axes from ``new``."""
    residual = run.residual.copy()  # step 0's may be the same array
    residual[:, changed] = new.residual[:, changed]
    return HeldOutRun(residual, tuple(new.errors[a] if a in changed else error
                                      for a, error in enumerate(run.errors)))


def _comparison(problem: DiagnosisProblem, zero: _StepZero, rounds: _Rounds,
                written: _Written) -> dict:
    """Map the deciding scheme and the one beside to each of METHODS' errors per axis."""
    settings = problem.settings
    other = written.other
    return {settings.validation: {
        'none': zero.none_errors, 'px4_cubic': written.cubic,
        'temperature_polynomial': tuple(axis_steps[0].after for axis_steps in rounds.steps),
        'diagnosed': written.run.errors}, settings.other_validation: {
        'none': tuple(problem.error(problem.target[:, a], other)
                      for a in range(len(problem.axes))),
        'px4_cubic': written.other_cubic,
        'temperature_polynomial': problem.held_out(zero.specs, 'the other validation',
                                                   other).errors,
        'diagnosed': written.other_errors}}


def _diagnosis(problem: DiagnosisProblem, skipped: dict, zero: _StepZero, rounds: _Rounds,
               findings: tuple, written: _Written) -> Diagnosis:
    """Fit the written model and gather the figures into the `Diagnosis`."""
    model = problem.model(written.specs)
    comparison = _comparison(problem, zero, rounds, written)
    held_out = BinnedResidual(
        time_s=problem.mean(problem.time), temperature_c=problem.mean(problem.temperature),
        heating=heating_bins(problem, slice(0, problem.rows), problem.starts),
        before_rad_s=zero.run.residual, after_rad_s=written.run.residual, rows=problem.counts,
        cubic_rad_s=np.where(problem.folds.scored[:, None],
                             problem.baseline_run(problem.folds).residual, np.nan))
    test, rezero, residual = None, {}, None
    if problem.test_rows:
        scopes, test, rezero, residual = compare_test(problem, zero.model, model)
        comparison.update(scopes)
    errors = written_error_by_temperature(problem, held_out, written.other_run.residual, test)
    per_axis = tuple(AxisDiagnosis(name, written.found[a].order, zero.scores[a],
                                   tuple(rounds.steps[a]), tuple(rounds.rejected[a]),
                                   findings[a], written.choices[a], rounds.causes[a])
                     for a, name in enumerate(problem.axes))
    return Diagnosis(axes=problem.axes, settings=problem.settings, model=model,
                     base_model=zero.model, per_axis=per_axis,
                     skipped=tuple(sorted(skipped.items())), comparison=comparison,
                     rows=problem.rows, test_rows=problem.test_rows, bins=len(problem.starts),
                     truth='reference' if problem.truth_is_reference else 'zero (at rest)',
                     held_out=held_out, test=test, bounds=problem.bounds,
                     records=_record_fits(problem, written.specs), rezero_rad_s=rezero,
                     first_blocks=problem.first_blocks,
                     outside_range=outside_fitted_range(problem, written.specs, model),
                     error_by_temperature=errors,
                     normalised=None if residual is None else
                     test_normalised_error(problem, errors, residual))


def _record_fits(problem: DiagnosisProblem, specs: tuple) -> tuple:
    """Describe each record: its name, rows, role and fitted offset against the written one."""
    offsets = problem.record_offsets(specs)
    records = problem.records
    return tuple(RecordFit(name, records.starts[k + 1] - records.starts[k],
                           k < problem.fitted_records,
                           tuple(float(v) for v in offsets[k]) if k < problem.fitted_records
                           else None)
                 for k, name in enumerate(records.names))
