"""
The text of ``mlx-tempcomp diagnose``: report.md and the lines it prints, from report.json.

Each is written from the report (`report.build_report`), so the Markdown,
the console and the JSON say the same; values in rad/s, table cells ``.3e``.
"""

import math

from ..uncertainty import (console_lines, error_lines, gain_words, normalised_text,
                           outside_lines)
from ...core.diagnosis import DEFAULT_REZERO_S, METHODS


def _e(value) -> str:
    return '-' if value is None else f'{value:.3e}'


def _table(header: tuple, rows: list) -> list:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines.extend('| ' + ' | '.join(str(cell) for cell in row) + ' |' for row in rows)
    return lines


def _parameter_text(parameters: dict) -> str:
    def show(value):
        if isinstance(value, list):
            return '[' + ', '.join(show(v) for v in value) + ']'
        if isinstance(value, float):
            return f'{value:.4g}'
        return str(value)
    return ', '.join(f'{key} {show(value)}' for key, value in parameters.items())


_METHOD_TEXT = {'none': 'no compensation', 'px4_cubic': 'PX4-style cubic in raw T',
                'temperature_polynomial': 'temperature polynomial (step 0)',
                'diagnosed': 'diagnosed model'}


def _comparison_lines(report: dict) -> list:
    lines = []
    names = list(report['axes'])
    header = ('method', *(f'{a} RMS' for a in names), *(f'{a} peak' for a in names))
    settings = report['settings']
    test = settings['test']
    held = report['held_out_records'][-1]['record'] if report['held_out_records'] else None
    scopes = {settings['validation']: f'Held-out blocks, {settings["held_out_scheme"]} '
                                      '(decides)',
              settings['other_validation']: f'Held-out blocks, {settings["other_scheme"]} '
                                            '(reported beside)',
              'test': (f'Test record {held}, as written (the written offset: its own is '
                       'unknown), never seen by the diagnosis' if held else
                       'Test set (' + ('the last full heating/cooling cycle' if test == 'cycle'
                                       else f'the last {test:g} of the record')
                       + ', never seen by the diagnosis)'),
              'test_rezeroed': f'Test record {held}, after a re-zero (its mean residual over '
                               f'its first {settings["rezero_s"]:g} s taken off, as '
                               'imu/recalibrate_zro does at rest)'}
    for scope, methods in report['comparison'].items():
        lines += ['', f'### {scopes[scope]}', '']
        rows = [(_METHOD_TEXT[m], *(_e(methods[m][a]['rms']) for a in names),
                 *(_e(methods[m][a]['peak']) for a in names)) for m in METHODS]
        lines += _table(header, rows)
        cubic, diagnosed = methods['px4_cubic'], methods['diagnosed']
        lines += ['', "Gain over the PX4-style cubic (its RMS / the diagnosed model's, above 1: "
                  'better): ' + ', '.join(f'{a} {cubic[a]["rms"] / diagnosed[a]["rms"]:.2f}x'
                                          for a in names if diagnosed[a]['rms'])]
    lines += ['', 'The cubic on held-out blocks is least squares of T^0..T^3 (raw '
                  'temperature) on the same bins; on the test set it is np.polyfit(T, rate, '
                  '3) on every row of the diagnosed part, as the PX4 script does'
              + ('; over several records each record has its own offset beside it, in the '
                 'cubic as in the diagnosed model, and both write the last one.'
                 if len(report['records']) > 1 else '.')]
    return lines


def _ratio_text(gains: dict) -> str:
    return ', '.join(f'{axis} {_gain(gain)}' for axis, gain in gains.items())


def _gain(gain) -> str:
    return '-' if gain is None else f'{gain:.2f}x'


def held_out_lines(report: dict) -> list:
    """Per held-out record, the gain over the cubic as written and after a re-zero; summary."""
    rezero = report['settings']['rezero_s']
    lines = []
    for record in report['held_out_records']:
        lines.append(f'held out {record["record"]}: gain over the PX4-style cubic (its RMS / '
                     "the model's) as written "
                     f'{_ratio_text(record["gain_as_written"])}; '
                     f'after a re-zero over its first {rezero:g} s '
                     f'{_ratio_text(record["gain_after_rezero"])}')
    if rezero != DEFAULT_REZERO_S:
        lines.append(f'the re-zero judged here averages the first {rezero:g} s of a record; '
                     'a node re-zeroes so with recalibration.duration_s: '
                     f'{rezero:g} (its default {DEFAULT_REZERO_S:g} s)')
    summary = report['held_out_summary']
    if summary and len(report['held_out_records']) > 1:
        lines.append('leave one record out, geometric mean of the gains over the cubic: as '
                     f'written {_ratio_text(summary["gain_as_written"])}; after a re-zero '
                     f'{_ratio_text(summary["gain_after_rezero"])}')
    return lines


def _records_lines(report: dict) -> list:
    """Describe the records of a unit: rows, role, offset; the written offset; held out."""
    axes = list(report['axes'])
    lines = ['## Records', '',
             f'{len(report["records"])} records of one unit, each with its own history '
             '(lags, play operators and the rate window start at its first row) and its own '
             'bias offset (a constant per record in every fit). params.yaml carries the '
             f'offset of {report["written_offset"]["record"]}, '
             f'{report["written_offset"]["why"]}.', '']
    lines += _table(('record', 'rows', 'duration (s)', 'role',
                     *(f'{a} offset vs written (rad/s)' for a in axes)),
                    [(r['record'], r['rows'], f'{r["duration_s"]:.0f}',
                      'fitted' if r['fitted'] else 'held out',
                      *(_e(r['offset_rad_s'][a]) if r['offset_rad_s'] else '-' for a in axes))
                     for r in report['records']])
    held = report['held_out_records']
    if held:
        lines += ['', '### Held-out records', '',
                  'Each fitted on the other records, run on the held-out one from its start; '
                  "gain = the PX4-style cubic's RMS / the diagnosed model's (above 1: "
                  "better), as written and after a re-zero over the record's first "
                  f'{report["settings"]["rezero_s"]:g} s.', '']
        lines += _table(('held-out record', *(f'{a} as written' for a in axes),
                         *(f'{a} after re-zero' for a in axes), 'writes'),
                        [(r['record'], *(_gain(r['gain_as_written'][a]) for a in axes),
                          *(_gain(r['gain_after_rezero'][a]) for a in axes),
                          ', '.join(f'{a} {w}' for a, w in r['written'].items()))
                         for r in held])
        summary = report['held_out_summary']
        if len(held) > 1:
            lines += ['', 'Geometric mean over the held-out records: as written '
                      f'{_ratio_text(summary["gain_as_written"])}; after a re-zero '
                      f'{_ratio_text(summary["gain_after_rezero"])}.']
    return lines + ['']


def _axis_lines(name: str, axis: dict) -> list:
    lines = [f'## Axis {name}', '']
    if axis['cause']:
        lines += ['### Cause: a record-only effect', '', axis['cause']['text'] + '.', '']
    lines += ['### Effects added', '']
    lines += _table(('round', 'effect', 'runs on', 'fitted constants', 'RMS before',
                     'RMS after', 'peak before', 'peak after'),
                    [(s['round'], s['effect'], 'live node' if s['live'] else 'this record',
                      _parameter_text({k: v for k, v in s['parameters'].items()
                                       if k != 'bias_rad_s'}),
                      _e(s['rms_before']), _e(s['rms_after']), _e(s['peak_before']),
                      _e(s['peak_after'])) for s in axis['steps']])
    first, last = axis['steps'][0], axis['steps'][-1]
    lines += ['', '### Held-out RMS per block (step 0 -> final model)', '']
    lines += _table(('block', 'step 0', 'final', 'change'),
                    [(k, _e(before), _e(after),
                      f'{(after - before) / before:+.0%}' if before else '-')
                     for k, (before, after) in enumerate(zip(first['block_rms_after'],
                                                             last['block_rms_after']))
                     if before is not None])
    lines += ['', '### Candidates rejected', '']
    lines += _table(('round', 'effect', 'held-out gain', 'why'),
                    [(c['round'], c['effect'], f'{c["held_out_gain"]:.3f}'
                      if c['held_out_gain'] is not None else '-', c['reason'])
                     for c in axis['rejected']]) if axis['rejected'] else ['none']
    if axis['findings']:
        lines += ['', "### Record-only effects (the record's clock; not in params.yaml)", '']
        lines += [f'- {f["effect"]}: {f["text"]}' for f in axis['findings']]
    lines += ['', '### Polynomial order (step 0, one-standard-error rule)', '']
    lines += _table(('order', 'mean fold RMS', 'standard error', 'chosen'),
                    [(s['order'], _e(s['mean_fold_rms']), _e(s['standard_error']),
                      '*' if s['order'] == first['parameters']['order'] else '')
                     for s in axis['order_scores']])
    return lines + ['']


def _model_text(written: dict) -> str:
    """Name a written model: the cubic, or the polynomial order and the effects beside it."""
    if written['model'] == 'px4_cubic':
        return 'the PX4-style cubic'
    added = [e for e in written['effects'] if e != 'temperature_polynomial']
    return (f'polynomial order {written["polynomial_order"]}'
            + (' + ' + ', '.join(added) if added else ''))


def written_lines(report: dict) -> list:
    """One line per axis: the model written, its held-out error and the cubic's."""
    scheme = report['settings']['validation'].replace('_', '-')
    lines = []
    for name, axis in report['axes'].items():
        written = axis['written']
        cubic = f'{_e(written["cubic_held_out_rms"])} rad/s'
        if written['model'] == 'px4_cubic':
            lines.append(f'axis {name}: writes the PX4-style cubic, {scheme}-validated RMS '
                         f'{cubic}; {written["reason"]}')
        else:
            gain = 1.0 / written['ratio'] if written['ratio'] else math.inf
            lines.append(f'axis {name}: writes {_model_text(written)}, {scheme}-validated RMS '
                         f'{_e(written["held_out_rms"])} rad/s; the cubic {cubic} '
                         f'({gain:.2f}x better)')
    return lines


def markdown(report: dict, plots: tuple) -> str:
    """Give report.md: the settings, the model written, each axis, the comparison, ``plots``."""
    rows = report['rows']
    settings = report['settings']
    effects = report['effects']
    bounds = report['search_bounds']
    lines = [f'# Diagnosis of {report["source"]}', '']
    lines += [f'- {line}' for line in headline_lines(report)] + ['']
    lines += [f'- rows diagnosed: {rows["diagnosed"]} ({rows["bins"]} bins); test rows: '
              f'{rows["test"]}; skipped while loading: '
              + (', '.join(f'{k} {v}' for k, v in rows['skipped_while_loading'].items() if v)
                 or 'none')
              + (f'; rows out of time order sorted into place: {rows["sorted_while_loading"]}'
                 if rows['sorted_while_loading'] else ''),
              f'- truth: {report["truth"]}; error figure: {report["metric"]}.',
              f'- held-out scheme (decides): {settings["held_out_scheme"]}; reported beside: '
              f'{settings["other_scheme"]}; stateful inputs (temperature slope over '
              f'{settings["temperature_rate_window_s"]:g} s, lags, play state) are computed '
              + ('over each record from its start' if len(report['records']) > 1 else
                 'over the whole record') + ' before rows are split.',
              f'- an effect is added when its relative held-out RMS reduction is at least '
              f'{settings["min_gain"]:g}, its mean per-fold improvement exceeds '
              f'{settings["significance"]:g} standard errors and no held-out block but the '
              f'first gets worse by more than {settings["block_tolerance"]:g} x the larger of '
              'its RMS and the axis RMS; the candidate with the largest gain wins the round; '
              'the polynomial order is then chosen again.',
              '- effects searched (all run causally on a live node): '
              + ', '.join(effects['searched']) + "; record-only (tied to the record's clock): "
              + ', '.join(effects['record_only'])
              + (' -- searched too (--record-effects)' if settings['record_effects'] else
                 ' -- tested as findings, not added'),
              '- search bounds: ' + '; '.join(f'{name} {low:.3g} .. {high:.3g}'
                                              for name, (low, high) in bounds.items()),
              '- step errors come from EffectModel.correct (the code the node runs) on fold '
              'models; all values in rad/s.', '']
    lines += ['## Model written (params.yaml)', '',
              f'Each axis writes the model the loop found when its held-out RMS '
              f'({settings["validation"].replace("_", "-")}) is at least '
              f'{settings["baseline_margin"]:.0%} below the PX4-style cubic\'s and, '
              f'{settings["other_validation"].replace("_", "-")}, not above it; else the '
              'cubic.', '']
    lines += [f'- {line}' for line in written_lines(report)]
    lines.append('')
    if len(report['records']) > 1:
        lines += _records_lines(report)
    if report['skipped']:
        lines += ['## Skipped candidates', '']
        lines += [f'- {s["effect"]}: {s["reason"]}' for s in report['skipped']]
        lines.append('')
    for name, axis in report['axes'].items():
        lines += _axis_lines(name, axis)
    lines += outside_lines(report['outside_fitted_range'])
    lines += error_lines(report['error_by_temperature'], list(report['axes']),
                         report['covariance'])
    lines += ['## Comparison']
    lines += _comparison_lines(report)
    lines += ['', '## Plots', '']
    lines += [f'- ![{name}]({name})' for name in plots] or ['none (--no-plots)']
    return '\n'.join(lines) + '\n'


# An axis's test part is said to hold an offset when its mean is at least this share of
# its RMS.
OFFSET_SHARE = 0.5


def _degrees(value_rad_s: float) -> str:
    return (f'{value_rad_s:.3e} rad/s = {math.degrees(value_rad_s):.3g} deg/s = '
            f'{3600.0 * math.degrees(value_rad_s):.4g} deg/h')


def _scope_text(report: dict, scope: str) -> str:
    """Name the rows the headline is measured on."""
    settings = report['settings']
    if scope != 'test':
        return (f'held-out blocks ({settings["held_out_scheme"]}; no test part: give --test '
                'to judge on rows no fit saw)')
    if report['held_out_records']:
        return f'test record {report["held_out_records"][-1]["record"]}, never seen by the fit'
    test = settings['test']
    return ('test part (' + ('the last full heating/cooling cycle' if test == 'cycle' else
                             f'the last {test:.0%} of the record') + ', never seen by the fit)')


def _left_text(axis: str, left: dict, rms: float) -> str:
    """Say what is left on an axis: the test part's offset, the record-only effect."""
    parts = []
    mean = left['test_mean_rad_s']
    if mean is not None and rms and abs(mean) >= OFFSET_SHARE * rms:
        parts.append(f'an offset of {mean:+.2e} rad/s over the test part ({abs(mean) / rms:.0%} '
                     'of its RMS): drift over time or a shift after the temperature turned, '
                     'which a re-zero at rest takes out')
    elif mean is not None:
        parts.append(f'no offset over the test part (mean {mean:+.2e} rad/s)')
    effect = left['effect']
    if effect is not None:
        parts.append(f'the record-only effect that explains most: {effect["text"]} (held-out '
                     f'gain {effect["held_out_gain"]:.2f}'
                     + ('' if effect['passes'] else ', not significant') + ')')
    return f'left on {axis}: ' + ('; '.join(parts) if parts else 'nothing the diagnosis names')


def headline_lines(report: dict) -> list:
    """Give the first lines: the gain over the clamped cubic, the error, what is left."""
    head = report['headline']
    lines = [f"{_scope_text(report, head['scope'])}: the written model against PX4's cubic "
             "clamped at its range (the cubic's RMS / the model's): "
             + gain_words(head['gain']),
             'error left (RMS of the residual averaged over '
             f'{report["settings"]["average_s"]:g} s): '
             + '; '.join(f'{a} {_degrees(v)}' for a, v in head['rms_rad_s'].items())]
    lines += [_left_text(a, left, head['rms_rad_s'][a]) for a, left in head['left'].items()]
    if report['covariance'] is not None:
        lines.append('covariance on the test part: ' + normalised_text(report['covariance']))
    return lines


def summary(report: dict) -> str:
    """Give what diagnose prints: the headline, the held-out RMS step by step, the comparison."""
    rows = report['rows']
    lines = headline_lines(report)
    lines += [f'{report["source"]}: {rows["diagnosed"]} rows diagnosed in {rows["bins"]} bins'
              + (f', last {rows["test"]} rows kept as the test set' if rows['test'] else '')
              + f'; truth {report["truth"]}; errors in rad/s']
    if len(report['records']) > 1:
        lines.append(f'{len(report["records"])} records, each with its own history and bias '
                     f'offset; params.yaml carries the offset of '
                     f'{report["written_offset"]["record"]} (the last record fitted)')
    for skipped in report['skipped']:
        lines.append(f'skipped {skipped["effect"]}: {skipped["reason"]}')
    for name, axis in report['axes'].items():
        steps = axis['steps']
        chain = ' -> '.join([_e(steps[0]['rms_before'])]
                            + [f'{s["effect"]} {_e(s["rms_after"])}' for s in steps])
        lines.append(f'axis {name}: held-out RMS {chain}')
        if axis['cause']:
            lines.append(f'axis {name}: cause: {axis["cause"]["text"]}')
        lines.extend(f'axis {name}: record-only finding {f["effect"]}: {f["text"]}'
                     for f in axis['findings'] if f['passes'])
    for scope, methods in report['comparison'].items():
        for method in METHODS:
            values = ', '.join(f'{a} {_e(e["rms"])}' for a, e in methods[method].items())
            lines.append(f'{scope:<16} {method:<22} {values}')
    lines += console_lines(report)
    not_written = report['error_by_temperature']['not_written']
    if not_written:
        lines.append(not_written)
    return '\n'.join(lines)
