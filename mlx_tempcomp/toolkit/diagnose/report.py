"""
report.json of ``mlx-tempcomp diagnose``: the diagnosis as plain JSON values (`build_report`).

Per axis the ordered steps with their held-out error before and after, per
fold and per block, the rejected and skipped candidates, the findings of
the record-only effects; the comparison with the PX4-style cubic; each
record's offset and a held-out record's errors as written and after a
re-zero; the rows outside the fitted range and the error by temperature
(`toolkit.uncertainty`). Every error is in rad/s; a non-finite number is
null.
"""

import math

import numpy as np

from ..uncertainty import error_by_temperature_json, normalised_json, outside_range_json
from ...core.effects import RECORD_EFFECTS
from ...core.fitting import FORWARD

METRIC = ('RMS and peak |.| of the residual (corrected - truth) averaged over bins of '
          '{average} on held-out rows, rad/s; averaging keeps white noise from hiding the '
          'bias')
WRITTEN_OFFSET = ('the last record fitted: the robot runs after it, on that mount and '
                  'power-up; on a new run, recalibrate the ZRO at rest (imu/recalibrate_zro) '
                  "to take up that run's own offset")


def _number(value):
    return float(value) if math.isfinite(value) else None


def _numbers(values) -> list:
    return [_number(v) for v in values]


def _error(error) -> dict:
    return {'rms': _number(error.rms_rad_s), 'peak': _number(error.peak_rad_s),
            'fold_rms': _numbers(error.fold_rms_rad_s)}


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, float):
        return _number(value)
    return value


def _record_effect_text(finding) -> str:
    """Say what a record-only effect is: its size and, for a step, when."""
    parameters = finding.parameters
    if finding.effect == 'bias_step':
        record = f' of {parameters["record"]}' if 'record' in parameters else ''
        return (f'a step of {parameters["step_rad_s"]:.3g} rad/s '
                f'{parameters["after_start_s"]:.1f} s after the record start{record} (stamp '
                f'{parameters["time_s"]:.1f} s)')
    return f'a drift of {3600.0 * parameters["rad_s_per_s"]:.3g} rad/s per hour'


def _short_effect_text(finding) -> str:
    """Name a record-only effect in a few words: a step's size and time, a drift's rate."""
    parameters = finding.parameters
    if finding.effect == 'bias_step':
        return (f'a bias step of {parameters["step_rad_s"]:+.2e} rad/s '
                f'{parameters["after_start_s"]:.0f} s after the start')
    return f'a drift of {3600.0 * parameters["rad_s_per_s"]:+.2e} rad/s per hour'


def _cause_text(cause) -> str:
    """One sentence on the record effect that ended an axis's search."""
    return (f'{cause.effect}, {_record_effect_text(cause)}, explains the residual better '
            f'than any live effect (held-out gain {cause.held_out_gain:.3f}, round '
            f'{cause.round_number}), so no live effect stands in for it; it is tied to '
            "this record's clock: on a live node, recalibrate the ZRO at rest "
            '(imu/recalibrate_zro) after such a change')


def _finding_text(finding) -> str:
    """One sentence on a record-only effect tested on top of the final model."""
    what = _record_effect_text(finding)
    if finding.reason:
        return f'{what} would not pass: {finding.reason}'
    return (f'{what}, held-out gain {finding.held_out_gain:.3f}; ZRO recalibration at rest '
            '(imu/recalibrate_zro) covers it on a live node')


def _written(axis, terms) -> dict:
    """Return what an axis writes into params.yaml, with the figures it was chosen on."""
    choice = axis.choice
    return {'model': choice.written, 'effects': list(terms.effects),
            'polynomial_order': len(terms.bias) - 1,
            'held_out_rms': _number(choice.found.rms_rad_s),
            'cubic_held_out_rms': _number(choice.cubic.rms_rad_s),
            'ratio': _number(choice.ratio), 'margin': choice.margin,
            'other_ratio': _number(choice.other_ratio), 'reason': choice.reason}


def _gains(methods: dict) -> dict:
    """Give the PX4-style cubic's RMS over the diagnosed model's per axis (above 1: better)."""
    return {axis: _number(methods['px4_cubic'][axis].rms_rad_s / error.rms_rad_s)
            if error.rms_rad_s else None for axis, error in methods['diagnosed'].items()}


def _held_out_record(diagnosis) -> dict:
    """Describe how the model fitted on the other records does on the held-out one."""
    held = diagnosis.records[-1]
    scopes = {scope: {method: dict(zip(diagnosis.axes, errors))
                      for method, errors in diagnosis.comparison[scope].items()}
              for scope in ('test', 'test_rezeroed')}
    return {'record': held.name, 'rows': held.rows,
            'fitted_on': [r.name for r in diagnosis.records if r.fitted],
            'gain_as_written': _gains(scopes['test']),
            'gain_after_rezero': _gains(scopes['test_rezeroed']),
            'as_written': {m: {a: _error(e) for a, e in errors.items()}
                           for m, errors in scopes['test'].items()},
            'after_rezero': {m: {a: _error(e) for a, e in errors.items()}
                             for m, errors in scopes['test_rezeroed'].items()},
            'rezero_rad_s': {m: dict(zip(diagnosis.axes, offset))
                             for m, offset in diagnosis.rezero_rad_s.items()},
            'written': {axis.axis: axis.choice.written for axis in diagnosis.per_axis}}


def _geometric_mean(values) -> float:
    values = [v for v in values if v]
    return math.exp(sum(math.log(v) for v in values) / len(values)) if values else None


def _records(recordings: list, diagnosis, held_out: tuple) -> dict:
    """Return the records part of report.json: each record, the written offset, held out."""
    fits = {fit.name: fit for fit in diagnosis.records}
    written = [fit for fit in diagnosis.records if fit.fitted][-1]
    entries = [{'record': r.source, 'rows': len(r), 'duration_s': r.duration_s,
                'fitted': fits[r.source].fitted,
                'offset_rad_s': None if fits[r.source].offset_rad_s is None else
                dict(zip(diagnosis.axes, fits[r.source].offset_rad_s))} for r in recordings]
    records = [_held_out_record(d) for d in held_out]
    summary = {kind: {axis: _number(_geometric_mean(r[kind][axis] for r in records))
                      for axis in diagnosis.axes}
               for kind in ('gain_as_written', 'gain_after_rezero')} if records else None
    return {'records': entries,
            'written_offset': {'record': written.name, 'why': WRITTEN_OFFSET},
            'held_out_records': records, 'held_out_summary': summary}


def build_report(source: str, recordings: list, diagnosis, held_out: tuple = ()) -> dict:
    """Return the content of report.json (all errors in rad/s)."""
    settings = diagnosis.settings
    average = f'{settings.average_s:g} s' if settings.average_s else 'one sample'
    skipped = [{'effect': effect, 'reason': reason} for effect, reason in diagnosis.skipped]
    return {
        'source': source,
        'unit': 'rad/s',
        'metric': METRIC.format(average=average),
        'truth': diagnosis.truth,
        'rows': {'diagnosed': diagnosis.rows, 'test': diagnosis.test_rows,
                 'bins': diagnosis.bins,
                 'skipped_while_loading': _skipped_while_loading(recordings),
                 'sorted_while_loading': sum(r.sorted_rows for r in recordings)},
        'settings': _settings(diagnosis, held_out),
        'effects': {'searched': list(settings.effects),
                    'record_only': sorted(RECORD_EFFECTS),
                    'in_params_yaml': sorted({e for t in diagnosis.model.terms
                                              for e in t.effects})},
        'search_bounds': {name: [float(low), float(high)]
                          for name, (low, high) in diagnosis.bounds.items()},
        'axes': {axis.axis: _axis(axis, terms, skipped)
                 for axis, terms in zip(diagnosis.per_axis, diagnosis.model.terms)},
        'skipped': skipped,
        'comparison': {scope: {method: {name: _error(error) for name, error in
                                        zip(diagnosis.axes, errors)}
                               for method, errors in methods.items()}
                       for scope, methods in diagnosis.comparison.items()},
        **_records(recordings, diagnosis, held_out),
        'outside_fitted_range': outside_range_json(diagnosis.outside_range, diagnosis.axes,
                                                   diagnosis.split(FORWARD).describe()),
        'error_by_temperature': error_by_temperature_json(diagnosis.error_by_temperature,
                                                          diagnosis.axes),
        'covariance': normalised_json(diagnosis.normalised, diagnosis.axes),
        'headline': _headline(diagnosis),
    }


def _headline(diagnosis) -> dict:
    """
    Give what the report says first: the gain over the clamped cubic, the error, what is left.

    On the test part when there is one (as written), else on the deciding
    scheme's held-out blocks; the gain is the cubic's RMS over the model's
    (the benches' direction: above 1, better). What is left per axis: the
    test part's mean (an offset, which a re-zero takes out) and the record-only
    effect (`_record_effect_text`) with the largest held-out gain, if any gains.
    """
    settings = diagnosis.settings
    scope = 'test' if 'test' in diagnosis.comparison else settings.validation
    methods = diagnosis.comparison[scope]
    gains = _gains({method: dict(zip(diagnosis.axes, errors))
                    for method, errors in methods.items()})
    test = diagnosis.test
    mean = None if test is None else np.average(test.after_rad_s, axis=0, weights=test.rows)
    left = {}
    for k, axis in enumerate(diagnosis.per_axis):
        found = axis.cause or max(axis.findings, key=lambda f: f.held_out_gain, default=None)
        left[axis.axis] = {
            'test_mean_rad_s': None if mean is None else float(mean[k]),
            'effect': None if found is None or not found.held_out_gain > 0.0 else {
                'effect': found.effect, 'text': _short_effect_text(found),
                'held_out_gain': _number(found.held_out_gain), 'passes': not found.reason}}
    return {'scope': scope, 'gain': gains,
            'rms_rad_s': {a: _number(e.rms_rad_s) for a, e in
                          zip(diagnosis.axes, methods['diagnosed'])},
            'cubic_rms_rad_s': {a: _number(e.rms_rad_s) for a, e in
                                zip(diagnosis.axes, methods['px4_cubic'])},
            'left': left}


def _settings(diagnosis, held_out: tuple) -> dict:
    """Give the settings the diagnosis ran with, its held-out schemes described."""
    settings = diagnosis.settings
    return {'validation': settings.validation,
            'other_validation': settings.other_validation,
            'min_past': settings.min_past,
            'held_out_scheme': diagnosis.split().describe(),
            'other_scheme': diagnosis.split(settings.other_validation).describe(),
            'folds': settings.folds, 'blocks': settings.blocks,
            'average_s': settings.average_s, 'max_order': settings.max_order,
            'min_gain': settings.min_gain, 'significance': settings.significance,
            'block_tolerance': settings.block_tolerance,
            'baseline_margin': settings.baseline_margin,
            'test': (('each' if held_out and not settings.test_record else 'record')
                     if held_out else 'cycle' if settings.test_cycle
                     else settings.test_fraction),
            'rezero_s': settings.rezero_s,
            'record_effects': settings.record_effects,
            'temperature_rate_window_s': settings.rate_window_s}


def _axis(axis, terms, skipped: list) -> dict:
    """Give an axis's part of report.json: what it writes, its steps, what it refused."""
    return {
        'written': _written(axis, terms),
        'cause': None if axis.cause is None else {
            'effect': axis.cause.effect, 'round': axis.cause.round_number,
            'parameters': _plain(dict(axis.cause.parameters)),
            'held_out_gain': _number(axis.cause.held_out_gain),
            'text': _cause_text(axis.cause)},
        'steps': [_step(s) for s in axis.steps],
        'rejected': [_rejected(c) for c in axis.rejected],
        'findings': [{'effect': f.effect, 'parameters': _plain(dict(f.parameters)),
                      'held_out_gain': _number(f.held_out_gain),
                      'passes': not f.reason, 'text': _finding_text(f)}
                     for f in axis.findings],
        'skipped': skipped,
        'polynomial_order': axis.order,
        'order_scores': [{'order': s.order, 'mean_fold_rms': _number(s.mean_rms_rad_s),
                          'standard_error': _number(s.standard_error_rad_s),
                          'fold_rms': _numbers(s.block_rms_rad_s)}
                         for s in axis.order_scores],
    }


def _step(step) -> dict:
    """Give an effect added: its parameters, its held-out error before and after."""
    return {'effect': step.effect, 'live': step.effect not in RECORD_EFFECTS,
            'parameters': _plain(dict(step.parameters)),
            'rms_before': _number(step.before.rms_rad_s),
            'rms_after': _number(step.after.rms_rad_s),
            'peak_before': _number(step.before.peak_rad_s),
            'peak_after': _number(step.after.peak_rad_s),
            'fold_rms_before': _numbers(step.before.fold_rms_rad_s),
            'fold_rms_after': _numbers(step.after.fold_rms_rad_s),
            'block_rms_before': _numbers(step.before.block_rms_rad_s),
            'block_rms_after': _numbers(step.after.block_rms_rad_s),
            'round': step.round_number,
            'held_out_gain': None if step.held_out_gain is None else
            _number(step.held_out_gain)}


def _rejected(candidate) -> dict:
    """Give a candidate refused: its gain, its fold-by-fold figures and why."""
    return {'effect': candidate.effect, 'round': candidate.round_number,
            'parameters': _plain(dict(candidate.parameters)),
            'held_out_gain': _number(candidate.held_out_gain),
            'mean_fold_improvement': _number(candidate.fold_improvement_rad_s),
            'fold_improvement_standard_error': _number(candidate.fold_improvement_se_rad_s),
            'worst_block_change': _number(candidate.worst_block_change),
            'reason': candidate.reason}


def _skipped_while_loading(recordings: list) -> dict:
    """Add up the rows each record skipped while loading, by reason."""
    total = {}
    for recording in recordings:
        for reason, count in recording.skipped.items():
            total[reason] = total.get(reason, 0) + count
    return total
