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
temperature (the median of the rows' mid-range temperatures).

Outliers: the robust z-score 0.6745 (x - median) / MAD of each row's bias,
slope, held-out RMS and number of effects per axis, over at least
`MIN_UNITS_FOR_OUTLIERS` rows. The held-out RMS is positive and skewed, and
judged on its log (`LOG_METRICS`). A measured metric's threshold makes the
false flags principled: the |robust z| that a fleet of the same size drawn
from one normal population exceeds `FALSE_FLAGS_PER_FLEET` times in
expectation over all the measured values of the report (Bonferroni), at
least Iglewicz and Hoaglin's `OUTLIER_Z` 3.5 (`outlier_threshold`: it rises
with the fleet's size, and is far higher for a handful of units, whose MAD
is itself uncertain). An RMS is flagged only when it also differs from the
fleet's median by a factor that matters (`RELATIVE_FLOOR`, sqrt 2: the error
beyond the median's, added in quadrature, at least as large as the median's
itself): the held-out RMS of forty units can agree within 2 %, where a unit
9 % above the median has a robust z of 4 and no practical meaning. The
number of effects is a count, not a normal value: its MAD is 0 whenever
more than half the rows agree, and its smallest nonzero MAD is half a step,
so the MAD is taken as at least half a step (`COUNT_METRICS`) and a count
is flagged beyond OUTLIER_Z: 3 or more effects away from the fleet's median
(z 4.0), never 1 or 2 (z 1.3, 2.7). A measured metric with MAD 0 (more than
half the rows equal) takes the mean absolute deviation times 1.2533.
"""

import functools
import json
import math
from pathlib import Path

import numpy as np
import yaml

from .unit import UNIT_FILE
from ..parameters.files import flat_parameters
from ..toolkit.running import write_json, write_result

# The least |robust z| flagged (Iglewicz and Hoaglin; a count's threshold), and the false flags
# a fleet drawn from one normal population gets in expectation over its report's measured values.
OUTLIER_Z = 3.5
FALSE_FLAGS_PER_FLEET = 0.05
# The draws behind `outlier_threshold`: values beyond the quantile, at most this many values,
# in blocks of this many.
_THRESHOLD_EXCEEDANCES = 200
_THRESHOLD_DRAWS = 4_000_000
_THRESHOLD_BLOCK = 500_000
# MAD and mean absolute deviation scaled to the standard deviation of a normal sample.
_MAD_Z = 0.6745
_MEAN_AD_SCALE = 1.253314
MIN_UNITS_FOR_OUTLIERS = 5
PLOT = 'fleet_coefficients.png'
METRICS = ('bias_rad_s', 'slope_rad_s_per_c', 'held_out_rms_rad_s', 'effects')
# Metrics that are counts, and their step.
COUNT_METRICS = {'effects': 1.0}
# Positive, skewed metrics, judged on their log; and the ratio to the fleet's median a flagged
# one must reach, either way (see the module).
LOG_METRICS = frozenset({'held_out_rms_rad_s'})
RELATIVE_FLOOR = {'held_out_rms_rad_s': math.sqrt(2.0)}


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


@functools.lru_cache(maxsize=None)
def outlier_threshold(size: int, values_judged: int) -> float:
    """
    Give the |robust z| a value of a group of ``size`` is flagged beyond (at least OUTLIER_Z).

    The |robust z| that a value of a fleet of ``size`` drawn from one normal
    population exceeds with probability FALSE_FLAGS_PER_FLEET / ``values_judged``
    (Bonferroni over the report's values), drawn: ``size`` normal values, their
    robust z, as often as `_THRESHOLD_EXCEEDANCES` values beyond it take (at most
    `_THRESHOLD_DRAWS` values), with a seed of the two numbers. The MAD of a
    small fleet is itself uncertain, which widens the robust z's tails far
    beyond the normal's (5 units of one axis: 16 where the normal quantile is
    2.9); from a few hundred units on it is the normal quantile.
    """
    tail = FALSE_FLAGS_PER_FLEET / max(values_judged, 1)
    fleets = min(math.ceil(_THRESHOLD_EXCEEDANCES / (tail * size)),
                 max(1, _THRESHOLD_DRAWS // size))
    rng = np.random.default_rng([size, values_judged])
    beyond, drawn = [], 0
    # In blocks, keeping the upper tail only: the quantile is far out in it.
    per_block = max(1, _THRESHOLD_BLOCK // size)
    for start in range(0, fleets, per_block):
        block = rng.standard_normal((min(per_block, fleets - start), size))
        median = np.median(block, axis=1, keepdims=True)
        mad = np.median(np.abs(block - median), axis=1, keepdims=True)
        scores = np.abs(_MAD_Z * (block - median) / mad).ravel()
        beyond.append(scores[scores > OUTLIER_Z])
        drawn += scores.size
    beyond = np.sort(np.concatenate(beyond))[::-1]
    rank = math.ceil(tail * drawn)
    return float(beyond[rank - 1]) if rank <= beyond.size else OUTLIER_Z


def flag_values(metric: str, values, threshold: float) -> list:
    """
    Give (index, robust z, ratio to the median) of each of ``values`` flagged on ``metric``.

    The z of a `LOG_METRICS` metric is its log's, and its ratio must reach the
    metric's `RELATIVE_FLOOR` either way; the ratio of a signed metric is None.
    """
    values = np.asarray(values, dtype=float)
    if metric in LOG_METRICS:
        # A zero RMS (a dead output) stays finite, and far below any fleet.
        values = np.maximum(values, np.finfo(float).tiny)
        scores = robust_z(np.log(values))
        ratios = values / float(np.median(values))
        far = np.abs(np.log(ratios)) >= math.log(RELATIVE_FLOOR.get(metric, 1.0))
    else:
        scores = robust_z(values, COUNT_METRICS.get(metric, 0.0))
        ratios = [None] * values.size
        far = np.ones(values.size, dtype=bool)
    return [(k, float(scores[k]), None if ratios[k] is None else float(ratios[k]))
            for k in np.flatnonzero((np.abs(scores) > threshold) & far)]


def flag_groups(groups: list) -> tuple:
    """
    Flag values judged together: ``groups`` a list of (metric, values), e.g. one per axis.

    A group of fewer than MIN_UNITS_FOR_OUTLIERS values is not judged. A
    measured metric's threshold is `outlier_threshold` of its group's size and
    the number of measured values judged; a count's is OUTLIER_Z (see the
    module). Give the flags, (group index, value index, robust z, ratio to the
    median or None) each, and the threshold of each group (None: not judged).
    """
    sizes = [len(values) if len(values) >= MIN_UNITS_FOR_OUTLIERS else 0
             for _, values in groups]
    measured = sum(size for (metric, _), size in zip(groups, sizes)
                   if metric not in COUNT_METRICS)
    thresholds = [None if not size else OUTLIER_Z if metric in COUNT_METRICS
                  else outlier_threshold(size, measured)
                  for (metric, _), size in zip(groups, sizes)]
    return [(k, *flag) for k, ((metric, values), threshold) in enumerate(zip(groups, thresholds))
            if threshold is not None
            for flag in flag_values(metric, values, threshold)], thresholds


def _outliers(rows: list, axes: list) -> tuple:
    """Give the flagged rows (see the module) and the thresholds by axis and metric."""
    groups = []
    for axis in axes:
        for metric in METRICS:
            pairs = [(row, _metric_values(row, axis).get(metric)) for row in rows
                     if axis in row['axes']]
            groups.append((axis, metric, [(row, value) for row, value in pairs
                                          if value is not None]))
    flags, thresholds = flag_groups([(metric, [value for _, value in pairs])
                                     for _, metric, pairs in groups])
    flagged = []
    for group, k, z, ratio in flags:
        axis, metric, pairs = groups[group]
        row, value = pairs[k]
        median = float(np.median([v for _, v in pairs]))
        how = f'{ratio:.2f}x, robust z of its log' if ratio is not None else 'robust z'
        flagged.append({'unit': row['unit'], 'record': row['record'], 'axis': axis,
                        'metric': metric, 'value': value, 'fleet_median': median,
                        'robust_z': z, 'ratio_to_median': ratio,
                        'reason': f'axis {axis} {metric} {value:.3g} against a fleet median '
                                  f'of {median:.3g} ({how} {z:+.1f}, beyond '
                                  f'{thresholds[group]:.2f})'})
    by_group = {}
    for (axis, metric, _), threshold in zip(groups, thresholds):
        if threshold is not None:
            by_group.setdefault(axis, {})[metric] = threshold
    return flagged, by_group


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
    outliers, thresholds = _outliers(rows, axes)
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
        'outlier_rule': '|robust z| beyond the value that a fleet of the same size drawn from '
                        f'one normal population exceeds {FALSE_FLAGS_PER_FLEET} times over the '
                        'measured values judged (Bonferroni; at least '
                        f'{OUTLIER_Z}), over at least {MIN_UNITS_FOR_OUTLIERS} rows, robust '
                        'z = 0.6745 (x - median) / MAD; the held-out RMS judged on its log, '
                        f'and {RELATIVE_FLOOR["held_out_rms_rad_s"]:.3g}x the median or more '
                        '(or 1/that or less); the number of effects beyond '
                        f'{OUTLIER_Z} with its MAD at least half an effect',
        'outlier_thresholds': thresholds,
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
