"""
The fleet report: one row per unit, each coefficient over the fleet, the outlier units.

Read from what ``OUT/units/`` holds (each unit's unit.json, params.yaml and,
from diagnose, report.json), so ``fleet report`` can write it again at any
time. A row is one run of the command (unit.json ``results``): a unit, whose
records ``diagnose`` fitted as one, or one record of a ``fit`` unit of
several. Per row: the effects the diagnosis added per axis, the held-out RMS
of the diagnosed model and its gain over the PX4-style cubic (cubic RMS /
diagnosed RMS): on the held-out records when ``--test record|each`` kept
some (as written, and after a re-zero beside; over several held-out records
the RMS pooled, each weighted by its rows, and the gains diagnose's
geometric mean), else on the test set when one was kept, else in the fold
cross-validation. The bias polynomials of units differ in order and
reference, so they are compared as the bias and its slope at one fleet
temperature (the median of the rows' mid-range temperatures). Outliers: the
robust z-score 0.6745 (x - median) / MAD of the bias, slope, held-out RMS
and number of effects per axis, flagged beyond `OUTLIER_Z` (Iglewicz and
Hoaglin's 3.5). The number of effects is a count: its MAD is 0 whenever more
than half the rows agree, and its smallest nonzero MAD is half a step, so
the MAD is taken as at least half a step (`COUNT_METRICS`): a count flags 3
or more away from the fleet's median (z 4.0), never 1 or 2 (z 1.3, 2.7),
however many rows share the median. A measured metric with MAD 0 (more than
half the rows equal) takes the mean absolute deviation times 1.2533.
"""

import json
import math
from pathlib import Path

import numpy as np
import yaml

from .unit import UNIT_FILE
from ..parameters.files import flat_parameters
from ..toolkit.common import write_json, write_result

OUTLIER_Z = 3.5
# MAD and mean absolute deviation scaled to the standard deviation of a normal sample.
_MAD_Z = 0.6745
_MEAN_AD_SCALE = 1.253314
MIN_UNITS_FOR_OUTLIERS = 5
PLOT = 'fleet_coefficients.png'
METRICS = ('bias_rad_s', 'slope_rad_s_per_c', 'held_out_rms_rad_s', 'effects')
# Metrics that are counts, and their step.
COUNT_METRICS = {'effects': 1.0}


def _model_values(params_path: Path) -> tuple:
    """Give (model name, axes, flattened section of the model) of a parameter file."""
    # libyaml's parser when PyYAML has it: one file per unit, read at the end of the run.
    content = yaml.load(params_path.read_text(encoding='utf-8'),
                        Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader))
    values = next(iter(content.values()))['ros__parameters']
    model = values['model']
    return model, list(values['axes']), flat_parameters(values.get(model, {}))


def _bias_and_slope(section: dict, axis: str, temperature_c: float) -> tuple:
    """Give the bias polynomial's value and slope at ``temperature_c`` (None without one)."""
    coefficients = section.get(f'bias.{axis}')
    if coefficients is None or 'temperature_scale_c' not in section:
        return None, None
    scale_c = section['temperature_scale_c']
    low, high = section.get('temperature_min_c', -math.inf), section.get('temperature_max_c',
                                                                         math.inf)
    x = (min(max(temperature_c, low), high) - section['reference_temperature_c']) / scale_c
    polynomial = np.polynomial.Polynomial(coefficients)
    return float(polynomial(x)), float(polynomial.deriv()(x) / scale_c)


def _coefficients(section: dict, axis: str) -> dict:
    """Give the per-axis numbers of a model besides its bias polynomial, lists by index."""
    found = {}
    for key, value in section.items():
        name, _, key_axis = key.rpartition('.')
        if key_axis != axis or name in ('bias', 'bias_step_time_s', 'bias_step_rad_s'):
            continue
        if isinstance(value, list):
            found.update({f'{name}[{k}]': float(v) for k, v in enumerate(value)})
        elif isinstance(value, (int, float)):
            found[name] = float(value)
    return found


def _held_out(report: dict, axes: list) -> dict:
    """Give a diagnosis's effects per axis and its held-out figures (see the module)."""
    figures = {'effects': {a: [s['effect'] for s in report['axes'][a]['steps'][1:]]
                           for a in axes}}
    held = report.get('held_out_records') or []
    if held:
        summary = report['held_out_summary']
        return {**figures, 'scope': 'held_out_records',
                'held_out_records': [record['record'] for record in held],
                'held_out_rms_rad_s': {a: _pooled_rms(held, 'as_written', a) for a in axes},
                'gain_over_cubic': {a: summary['gain_as_written'][a] for a in axes},
                'held_out_rms_after_rezero_rad_s': {a: _pooled_rms(held, 'after_rezero', a)
                                                    for a in axes},
                'gain_after_rezero': {a: summary['gain_after_rezero'][a] for a in axes}}
    # The test part when held out, else the validation scheme that decided.
    scope = 'test' if 'test' in report['comparison'] else report['settings']['validation']
    methods = report['comparison'][scope]
    return {**figures, 'scope': scope,
            'held_out_rms_rad_s': {a: methods['diagnosed'][a]['rms'] for a in axes},
            'gain_over_cubic': {a: _ratio(methods['px4_cubic'][a]['rms'],
                                          methods['diagnosed'][a]['rms']) for a in axes}}


def _pooled_rms(held: list, kind: str, axis: str):
    """Give the diagnosed model's RMS over held-out records, each weighted by its rows."""
    pairs = [(record['rows'], record[kind]['diagnosed'][axis]['rms']) for record in held]
    pairs = [(rows, rms) for rows, rms in pairs if rms is not None]
    if not pairs:
        return None
    return math.sqrt(sum(rows * rms ** 2 for rows, rms in pairs)
                     / sum(rows for rows, _ in pairs))


def _result_row(unit: str, folder: Path, result: dict) -> dict:
    """Read one run's results: model section and, from diagnose, the held-out figures."""
    row = {'unit': unit, 'record': result['folder'], 'paths': result['records']}
    model, axes, section = _model_values(folder / 'params.yaml')
    row.update(model=model, axes=axes, section=section)
    report_path = folder / 'report.json'
    row['report'] = None
    if report_path.exists():
        row['report'] = _held_out(json.loads(report_path.read_text(encoding='utf-8')), axes)
    return row


def robust_z(values, step: float = 0.0) -> np.ndarray:
    """
    Give 0.6745 (x - median) / MAD of each value.

    A count in whole ``step`` takes the MAD as at least half a step; a
    measured value (``step`` 0) with MAD 0 the mean absolute deviation.
    """
    values = np.asarray(values, dtype=float)
    median = np.median(values)
    deviation = np.abs(values - median)
    mad = max(float(np.median(deviation)), 0.5 * step)
    if mad > 0.0:
        return _MAD_Z * (values - median) / mad
    spread = _MEAN_AD_SCALE * np.mean(deviation)
    return (values - median) / spread if spread > 0.0 else np.zeros_like(values)


def _metric_values(row: dict, axis: str) -> dict:
    report = row['report']
    values = {'bias_rad_s': row['bias'].get(axis), 'slope_rad_s_per_c': row['slope'].get(axis)}
    if report is not None:
        values['held_out_rms_rad_s'] = report['held_out_rms_rad_s'][axis]
        values['effects'] = float(len(report['effects'][axis]))
    return values


def _outliers(rows: list, axes: list) -> list:
    """Flag rows whose robust z-score of a metric on an axis exceeds OUTLIER_Z."""
    flagged = []
    for axis in axes:
        for metric in METRICS:
            pairs = [(row, _metric_values(row, axis).get(metric)) for row in rows
                     if axis in row['axes']]
            pairs = [(row, value) for row, value in pairs if value is not None]
            if len(pairs) < MIN_UNITS_FOR_OUTLIERS:
                continue
            values = [value for _, value in pairs]
            median = float(np.median(values))
            for (row, value), z in zip(pairs, robust_z(values, COUNT_METRICS.get(metric, 0.0))):
                if abs(z) > OUTLIER_Z:
                    flagged.append({'unit': row['unit'], 'record': row['record'],
                                    'axis': axis, 'metric': metric, 'value': value,
                                    'fleet_median': median, 'robust_z': float(z),
                                    'reason': f'axis {axis} {metric} {value:.3g} against a '
                                              f'fleet median of {median:.3g} (robust z '
                                              f'{z:+.1f})'})
    return flagged


def _distribution(values) -> dict:
    values = np.asarray(values, dtype=float)
    median = float(np.median(values))
    return {'units': int(values.size), 'nonzero': int(np.count_nonzero(values)),
            'median': median, 'mad': float(np.median(np.abs(values - median))),
            'p05': float(np.percentile(values, 5)), 'p95': float(np.percentile(values, 95)),
            'min': float(values.min()), 'max': float(values.max())}


def _distributions(rows: list, axes: list) -> dict:
    """Give each coefficient's distribution over the rows that have it, per axis."""
    found = {}
    for axis in axes:
        names = {}
        for row in rows:
            if axis not in row['axes']:
                continue
            numbers = {'bias_rad_s': row['bias'].get(axis),
                       'slope_rad_s_per_c': row['slope'].get(axis),
                       **_coefficients(row['section'], axis)}
            for name, value in numbers.items():
                if value is not None:
                    names.setdefault(name, []).append(value)
        found[axis] = {name: _distribution(values) for name, values in names.items()
                       if any(values)}
    return found


def _unit_entries(units: Path) -> list:
    """Read each unit.json; one of an earlier version (no ``results``) is a failed unit."""
    entries = []
    for path in sorted(units.glob(f'*/{UNIT_FILE}')):
        try:
            entry = json.loads(path.read_text(encoding='utf-8'))
        except (OSError, ValueError):
            continue
        if entry.get('status') == 'ok' and 'results' not in entry:
            entry = {**entry, 'status': 'error',
                     'error': 'written by an earlier mlx-tempcomp fleet: run the fleet '
                              'command again to redo it'}
        entries.append(entry)
    return entries


def _ratio(numerator, denominator):
    return numerator / denominator if numerator is not None and denominator else None


def fleet_summary(out: Path) -> dict:
    """Give the content of fleet.json from the units ``out`` holds."""
    entries = _unit_entries(out / 'units')
    rows = []
    for entry in entries:
        if entry['status'] == 'ok':
            for result in entry['results']:
                rows.append(_result_row(entry['unit'], out / 'units' / entry['unit']
                                        / result['folder'], result))
    mid_c = [(row['section']['temperature_min_c'] + row['section']['temperature_max_c']) / 2
             for row in rows if math.isfinite(row['section'].get('temperature_min_c', math.nan))
             and math.isfinite(row['section'].get('temperature_max_c', math.nan))]
    reference_c = float(np.median(mid_c)) if mid_c else 25.0
    axes = sorted({axis for row in rows for axis in row['axes']})
    for row in rows:
        pairs = {a: _bias_and_slope(row['section'], a, reference_c) for a in row['axes']}
        row['bias'] = {a: pair[0] for a, pair in pairs.items()}
        row['slope'] = {a: pair[1] for a, pair in pairs.items()}
    outliers = _outliers(rows, axes)
    table = []
    for row in rows:
        report = row['report']
        item = {'unit': row['unit'], 'record': row['record'], 'records': row['paths'],
                'model': row['model'], 'axes': row['axes'],
                'bias_rad_s': row['bias'], 'slope_rad_s_per_c': row['slope'],
                'outlier': [o['reason'] for o in outliers
                            if (o['unit'], o['record']) == (row['unit'], row['record'])]}
        if report is not None:
            item.update(held_out=report['scope'],
                        **{key: value for key, value in report.items() if key != 'scope'})
        table.append(item)
    return {
        'units': len(entries),
        'finished': sum(e['status'] == 'ok' for e in entries),
        'failed': [{'unit': e['unit'], 'error': e['error']} for e in entries
                   if e['status'] != 'ok'],
        'reference_temperature_c': reference_c,
        'outlier_rule': f'|robust z| > {OUTLIER_Z} over at least {MIN_UNITS_FOR_OUTLIERS} '
                        'rows, robust z = 0.6745 (x - median) / MAD, the MAD of the number '
                        'of effects at least half an effect',
        'several_records': "diagnose fits one model over all of a unit's records (one row per "
                           "unit; params.yaml carries the last record's offset); fit takes "
                           'one record, so a fit unit of several has a row per record',
        'rows': table,
        'coefficients': _distributions(rows, axes),
        'outliers': outliers,
        'plot': PLOT,
    }


def _e(value) -> str:
    return '-' if value is None else f'{value:.3e}'


def _per_axis(values: dict, show) -> str:
    return ', '.join(f'{a} {show(v)}' for a, v in values.items())


def _markdown(summary: dict) -> str:
    lines = ['# Fleet report', '',
             f'- units: {summary["units"]}, finished {summary["finished"]}, failed '
             f'{len(summary["failed"])}.',
             f'- bias and slope compared at {summary["reference_temperature_c"]:.2f} C (the '
             "median of the rows' mid-range temperatures); errors in rad/s.",
             '- held-out RMS: of the diagnosed model on the held-out records as written (with '
             'the written offset: theirs is unknown) when --test record|each kept some, '
             'pooled over them, each weighted by its rows (after a re-zero beside); else on '
             'the test set when one was kept, else in fold cross-validation; gain over the '
             'cubic: PX4-style cubic RMS / diagnosed RMS on the same rows (over several '
             "held-out records diagnose's geometric mean of their gains).",
             f'- outliers: {summary["outlier_rule"]}.',
             f'- {summary["several_records"]}.', '', '## Units', '']
    rows = summary['rows']
    by_record = any(row['record'] for row in rows)
    rezeroed = any('gain_after_rezero' in row for row in rows)
    header = ['unit', *(['record'] if by_record else []), 'records', 'model', 'effects found',
              'held-out RMS', 'gain over cubic',
              *(['after a re-zero: RMS', 'gain'] if rezeroed else []), 'bias',
              'slope (rad/s/C)', 'outlier']
    lines += ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]

    def gains(values: dict) -> str:
        return _per_axis(values, lambda v: '-' if v is None else f'{v:.2f}x')

    for row in rows:
        diagnosed = 'effects' in row
        cells = [row['unit'], *([row['record'] or '-'] if by_record else []),
                 str(len(row['records'])), row['model'],
                 _per_axis(row['effects'], lambda v: '+'.join(v) or 'none')
                 if diagnosed else '-',
                 _per_axis(row['held_out_rms_rad_s'], _e) if diagnosed else '-',
                 gains(row['gain_over_cubic']) if diagnosed else '-']
        if rezeroed:
            cells += ([_per_axis(row['held_out_rms_after_rezero_rad_s'], _e),
                       gains(row['gain_after_rezero'])]
                      if 'gain_after_rezero' in row else ['-', '-'])
        cells += [_per_axis(row['bias_rad_s'], _e), _per_axis(row['slope_rad_s_per_c'], _e),
                  'yes' if row['outlier'] else '']
        lines.append('| ' + ' | '.join(cells) + ' |')
    lines += ['', '## Coefficients over the fleet', '',
              '| axis | coefficient | rows | nonzero | median | MAD | 5 % | 95 % | min | '
              'max |', '|---|---|---|---|---|---|---|---|---|---|']
    for axis, names in summary['coefficients'].items():
        for name, d in names.items():
            lines.append(f'| {axis} | {name} | {d["units"]} | {d["nonzero"]} | '
                         f'{_e(d["median"])} | {_e(d["mad"])} | {_e(d["p05"])} | '
                         f'{_e(d["p95"])} | {_e(d["min"])} | {_e(d["max"])} |')
    lines += ['', '## Outlier units', '']
    lines += [f'- {o["unit"]}{"/" + o["record"] if o["record"] else ""}: {o["reason"]}'
              for o in summary['outliers']] or ['none']
    if summary['failed']:
        lines += ['', '## Failed units', '']
        lines += [f'- {f["unit"]}: {f["error"]}' for f in summary['failed']]
    lines += ['', '## Plots', '', f'- ![{PLOT}]({PLOT})']
    return '\n'.join(lines) + '\n'


def _plot(path: Path, summary: dict) -> None:
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot

    axes = list(summary['coefficients'])
    metrics = ('bias_rad_s', 'slope_rad_s_per_c', 'held_out_rms_rad_s')
    figure, grid = pyplot.subplots(max(len(axes), 1), len(metrics),
                                   figsize=(12.0, 3.0 * max(len(axes), 1)), squeeze=False)
    flagged = {(o['unit'], o['record'], o['axis'], o['metric']) for o in summary['outliers']}
    for row, axis in enumerate(axes):
        for column, metric in enumerate(metrics):
            plot = grid[row][column]
            pairs = [(r[metric][axis], (r['unit'], r['record'], axis, metric) in flagged)
                     for r in summary['rows'] if metric in r and axis in r[metric]
                     and r[metric][axis] is not None]
            if pairs:
                plot.hist([v for v, _ in pairs], bins=min(30, max(5, len(pairs) // 3)),
                          color='tab:blue')
                for value in (v for v, out in pairs if out):
                    plot.axvline(value, color='tab:red', linewidth=1.0)
            plot.set_title(f'{axis}: {metric}', fontsize='small')
            plot.set_ylabel('rows')
    figure.suptitle('Fleet distribution (red: outlier units)')
    try:
        figure.tight_layout()
        figure.savefig(path, dpi=90)
    finally:
        pyplot.close(figure)


def write_fleet_report(out: Path) -> Path:
    """Write fleet.json, fleet.md and the plot into ``out``; give the path of fleet.md."""
    summary = fleet_summary(out)
    write_json(out / 'fleet.json', summary)
    write_result(out / 'fleet.md', _markdown(summary))
    _plot(out / PLOT, summary)
    return out / 'fleet.md'
