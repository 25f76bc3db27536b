"""The loop itself: step 0, the rounds that add effects, the guard, and the `Diagnosis`."""

from dataclasses import replace
import math

import numpy as np

from .acceptance import (choose_model, cubic_errors, judge, record_cause, record_findings,
                         to_candidate, unbounded)
from .fits import AxisSpec, best_trial, fitted_parameters, TIME_CONSTANTS_PER_RECORD
from .held_out_part import (compare_test, diagnosed_rows, heating_bins, outside_fitted_range,
                            written_error_by_temperature)
from .problem import DiagnosisProblem
from .results import AxisDiagnosis, BinnedResidual, Diagnosis, RecordFit, Step
from .settings import BASE_EFFECT, DiagnosisSettings, Progress, RECORD_SEARCH
from ..effects import EFFECTS
from ..errors import CalibrationError
from ..model_interface import INPUTS
from ..records import join_records
from ..validation import one_standard_error, order_score, PX4_ORDER

# The record shows motion when the specific force turns by this much, or its
# magnitude moves by MOTION_M_S2 (1 s means, 1st to 99th percentile).
MOTION_DEG = 5.0
MOTION_M_S2 = 1.0


def _order_scores(problem: DiagnosisProblem, axis: int, spec: AxisSpec) -> tuple:
    """Score every polynomial order with the other terms of ``spec`` fitted alongside."""
    scores = []
    for order in range(problem.settings.max_order + 1):
        score = problem.score_spec(axis, replace(spec, order=order))
        scores.append(order_score(order, score.fold_rms if score.rank_ok else
                                  np.full(score.fold_rms.shape, math.inf)))
    return tuple(scores)


def _choose_order(axis_name: str, scores: tuple) -> int:
    try:
        return one_standard_error(scores)
    except CalibrationError as err:
        msg = f'axis {axis_name}: {err}'
        raise CalibrationError(msg) from None


def _rechosen_order(problem: DiagnosisProblem, axis: int, trial: AxisSpec) -> AxisSpec:
    """
    Choose the polynomial order again beside an accepted effect.

    The new term may take over what a higher order did, or free one up; the
    order the effect was judged with stays when the rule's choice has a
    higher held-out RMS (the rule allows one standard error of the mean fold
    RMS, which forward folds make wide).
    """
    chosen = replace(trial, order=_choose_order(problem.axes[axis],
                                                _order_scores(problem, axis, trial)))
    better = problem.score_spec(axis, chosen).rms <= problem.score_spec(axis, trial).rms
    return chosen if better else trial


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
    if bounds['thermal_lag_s'][0] > bounds['thermal_lag_s'][1]:
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


def diagnose(recording, settings: DiagnosisSettings = DiagnosisSettings(),
             progress: Progress = None) -> Diagnosis:
    """
    Run the loop on a recording and return the `Diagnosis`.

    ``recording`` has time_s, temperature_c, axes, gyro_rad_s and optional
    reference_rad_s, acceleration_m_s2, temperature_2_c and supply_voltage_v
    (a `mlx_tempcomp.sources.recording.Recording`). ``progress(done, total,
    label)`` is called as work advances. Raise `CalibrationError` when the
    data cannot support the diagnosis.
    """
    records = join_records(recording)
    problem = DiagnosisProblem(records, diagnosed_rows(records, settings), settings, progress)
    axes = problem.axes
    skipped = _skipped(problem)
    searched = tuple(e for e in settings.effects if e not in skipped)
    scores = tuple(_order_scores(problem, axis, AxisSpec(0)) for axis in range(len(axes)))
    specs = [AxisSpec(_choose_order(name, s)) for name, s in zip(axes, scores)]
    none_errors = tuple(problem.error(problem.target[:, a]) for a in range(len(axes)))
    residual, errors = problem.held_out(tuple(specs), 'held-out check of step 0')
    base_residual = residual
    base_specs = tuple(specs)
    base_model = problem.model(base_specs)
    steps = [[Step(BASE_EFFECT, fitted_parameters(BASE_EFFECT, base_model.terms[a], problem),
                   none_errors[a], errors[a], 0)] for a in range(len(axes))]
    rejected = [[] for _ in axes]
    causes = [None for _ in axes]
    active = set(range(len(axes)))
    number = 0
    while active:
        number += 1
        accepted = {}
        work = sum(1 for a in active for e in searched if specs[a].can_add(e))
        done = 0
        for axis in sorted(active):
            current = problem.score_spec(axis, specs[axis])
            tried = []
            for effect in searched:
                if not specs[axis].can_add(effect):
                    continue
                best = best_trial(problem, axis, specs[axis], effect)
                done += 1
                problem.report(done, work, f'round {number}: candidate effects')
                if best is None:
                    continue
                trial, score = best
                judged = judge(problem, current, score)
                bound = unbounded(problem, effect, trial)
                if bound and not judged[4]:
                    judged = judged[:4] + (bound,)
                tried.append((effect, trial, judged))
            tried.sort(key=lambda item: (bool(item[2][4]), -item[2][0]))
            if not settings.record_effects:
                causes[axis] = record_cause(record_findings(problem, axis, specs[axis], number),
                                            tried)
            for rank, (effect, trial, judged) in enumerate(tried):
                reason = judged[4]
                if not reason and causes[axis] is not None:
                    reason = (f'the record-only {causes[axis].effect} explains more (held-out '
                              f'gain {causes[axis].held_out_gain:.3f}): not a live stand-in')
                if rank == 0 and not reason:
                    accepted[axis] = (effect, trial, judged[0])
                    continue
                reason = reason or 'significant, but another effect gained more this round'
                rejected[axis].append(to_candidate(problem, axis, effect, trial, judged, number,
                                                   reason))
        if not accepted:
            break
        for axis, (effect, trial, gain) in accepted.items():
            specs[axis] = _rechosen_order(problem, axis, trial)
        new_residual, new_errors = problem.held_out(tuple(specs),
                                                    f'held-out check of round {number}')
        model = problem.model(tuple(specs))
        for axis, (effect, trial, gain) in accepted.items():
            parameters = fitted_parameters(effect, model.terms[axis], problem)
            parameters['polynomial_order'] = specs[axis].order
            steps[axis].append(Step(effect, parameters, errors[axis], new_errors[axis], number,
                                    gain))
        residual, errors = new_residual, new_errors
        active = set(accepted)
    findings = [() if settings.record_effects else record_findings(problem, a, specs[a], number)
                for a in range(len(axes))]
    found = tuple(specs)
    other = problem.folds_of(settings.other_validation)
    cubic = cubic_errors(problem, problem.folds)
    other_cubic = cubic_errors(problem, other)
    other_errors = problem.held_out(found, 'the other validation', other)[1]
    choices = tuple(choose_model(settings, (errors[a], other_errors[a]),
                                 (cubic[a], other_cubic[a])) for a in range(len(axes)))
    cubic_axes = tuple(a for a, choice in enumerate(choices) if choice.written == 'px4_cubic')
    if cubic_axes:
        specs = [AxisSpec(PX4_ORDER) if a in cubic_axes else spec for a, spec in enumerate(found)]
        # The models clamp at the range of every axis's T_eff: with the same lags, the axes
        # that keep their model keep their figures.
        same = {s.thermal_lag_s for s in specs} == {s.thermal_lag_s for s in found}
        run = cubic_axes if same else None
        new_residual, new_errors = problem.held_out(tuple(specs), 'held-out check of the cubic',
                                                    axes=run)
        new_other = problem.held_out(tuple(specs), 'the other validation', other, run)[1]
        changed = list(run or range(len(axes)))
        residual = residual.copy()  # step 0's may be the same array
        residual[:, changed] = new_residual[:, changed]
        errors = tuple(new_errors[a] if a in changed else errors[a] for a in range(len(axes)))
        other_errors = tuple(new_other[a] if a in changed else other_errors[a]
                             for a in range(len(axes)))
    model = problem.model(tuple(specs))
    comparison = {settings.validation: {
        'none': none_errors, 'px4_cubic': cubic,
        'temperature_polynomial': tuple(axis_steps[0].after for axis_steps in steps),
        'diagnosed': errors}, settings.other_validation: {
        'none': tuple(problem.error(problem.target[:, a], other) for a in range(len(axes))),
        'px4_cubic': other_cubic,
        'temperature_polynomial': problem.held_out(base_specs, 'the other validation',
                                                   other)[1],
        'diagnosed': other_errors}}
    held_rows = slice(0, problem.rows)
    held_out = BinnedResidual(
        time_s=problem.mean(problem.time), temperature_c=problem.mean(problem.temperature),
        heating=heating_bins(problem, held_rows, problem.starts), before_rad_s=base_residual,
        after_rad_s=residual, rows=problem.counts)
    test, rezero = None, {}
    if problem.test_rows:
        scopes, test, rezero = compare_test(problem, base_model, model)
        comparison.update(scopes)
    per_axis = tuple(AxisDiagnosis(name, found[a].order, scores[a], tuple(steps[a]),
                                   tuple(rejected[a]), findings[a], choices[a], causes[a])
                     for a, name in enumerate(axes))
    return Diagnosis(axes=axes, settings=settings, model=model, base_model=base_model,
                     per_axis=per_axis, skipped=tuple(sorted(skipped.items())),
                     comparison=comparison, rows=problem.rows, test_rows=problem.test_rows,
                     bins=len(problem.starts),
                     truth='reference' if problem.truth_is_reference else 'zero (at rest)',
                     held_out=held_out, test=test, bounds=problem.bounds,
                     records=_record_fits(problem, tuple(specs)), rezero_rad_s=rezero,
                     first_blocks=problem.first_blocks,
                     outside_range=outside_fitted_range(problem, tuple(specs), model),
                     error_by_temperature=written_error_by_temperature(problem, held_out, test))


def _record_fits(problem: DiagnosisProblem, specs: tuple) -> tuple:
    """Describe each record: its name, rows, role and fitted offset against the written one."""
    offsets = problem.record_offsets(specs)
    records = problem.records
    return tuple(RecordFit(name, records.starts[k + 1] - records.starts[k],
                           k < problem.fitted_records,
                           tuple(float(v) for v in offsets[k]) if k < problem.fitted_records
                           else None)
                 for k, name in enumerate(records.names))
