"""
The fleet prior: a population model for units without a record, unit fits shrunk toward it.

Written after the fleet report, from what ``OUT`` holds: each finished unit's
`MOMENTS_FILE` per record (the worker's summary of the record, added up over
a unit's records), and the report's outlier units, which are left out of the
population (they are still shrunk, with the small weight their distance
gives them). The math is `core.pooling`, per axis; here the files:

- ``OUT/fleet_params.yaml``: the population mean, an effects model the
  compensation node loads as is, for a unit that has no record of its own;
- ``OUT/units/<unit>/shrunk_params.yaml``: the unit's coefficients shrunk
  toward the fleet (partial pooling), beside its own params.yaml;
- ``OUT/fleet_prior.json``: the design, the column tests that chose it, the
  noise figures, the population mean and covariance, each unit's own and
  shrunk coefficients and how much the fleet moved it.

Every parameter file is built back through `node_parameters.build_model`
before it is kept, as the node would build it.
"""

from collections import Counter
import json
import math
from pathlib import Path

import numpy as np
import yaml

from .unit import MOMENTS_FILE, UNIT_FILE
from ..core.effects import AxisTerms, EffectModel
from ..core.errors import TempCompError
from ..core.pooling import MIN_POOLED_UNITS, moments_of, pool_fleet, RATE_WINDOW_S
from ..model_params import effect_parameters, parameter_file, write_parameter_file
from ..node_parameters import build_model, node_values, ParameterError
from ..sources.recording import AXES
from ..toolkit.common import write_json

FLEET_PARAMS = 'fleet_params.yaml'
SHRUNK_PARAMS = 'shrunk_params.yaml'
PRIOR_JSON = 'fleet_prior.json'
DEFAULT_NODE_NAME = 'compensation_node'
# The smallest half span of the fleet's x: a fleet at one temperature still gets a scale.
MIN_SCALE_C = 0.5
METHOD = ('Per axis, every unit is fitted with one design: a bias polynomial in x = (T - '
          "reference) / scale, the fleet's reference and scale, of the highest order whose "
          'top power the units show jointly (chi^2 over the units at 0.001), and the '
          'temperature-rate coefficient when they show it. Population: beta_i ~ N(mu, Sigma '
          '/ w_i), t weights (nu 4), mu and Sigma by EM over the units the fleet report did '
          'not flag; each unit shrunk to its posterior mean with its own estimation '
          "covariance (kappa sigma^2 (X'X)^-1).")


def _read_json(path: Path):
    try:
        return json.loads(path.read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return None


def _unit_moments(folder: Path, entry: dict) -> tuple:
    """Give ({axis: DesignMoments} over the unit's records, None) or (None, why not)."""
    total = {}
    for record in entry['records']:
        document = _read_json(folder / record['folder'] / MOMENTS_FILE)
        if document is None:
            return None, f'no {MOMENTS_FILE} (written before the fleet prior: rerun with --force)'
        if 'error' in document:
            return None, f'{record["path"]}: {document["error"]}'
        try:
            found = moments_of(document)
        except TempCompError as err:
            return None, f'{record["path"]}: {err}'
        for axis, moments in found.items():
            total[axis] = total[axis] + moments if axis in total else moments
    return total, None


def _node_name(folder: Path, entry: dict) -> str:
    """Give the node section of the unit's first params.yaml (the default if unreadable)."""
    try:
        content = yaml.safe_load((folder / entry['records'][0]['folder'] / 'params.yaml')
                                 .read_text(encoding='utf-8'))
        return str(next(iter(content)))
    except (OSError, yaml.YAMLError, TypeError, StopIteration):
        return DEFAULT_NODE_NAME


def _write_model(path: Path, node_name: str, pools: dict, coefficients: dict,
                 temperature_range: tuple, header: str) -> None:
    """Write an effects model of ``coefficients`` {axis: design coefficients}; check it builds."""
    axes = [axis for axis in AXES if axis in coefficients]
    terms = []
    for axis in axes:
        bias, rate = pools[axis].design.bias_and_rate(coefficients[axis])
        terms.append(AxisTerms(bias=tuple(bias), temperature_rate_rad_s_per_c_s=rate))
    design = pools[axes[0]].design
    model = EffectModel(terms=tuple(terms), reference_temperature_c=design.reference_c,
                        temperature_scale_c=design.scale_c,
                        temperature_min_c=temperature_range[0],
                        temperature_max_c=temperature_range[1],
                        temperature_rate_window_s=RATE_WINDOW_S)
    write_parameter_file(path, parameter_file(node_name, effect_parameters(model, axes)), header)
    build_model(node_values(str(path), node_name))


def _axis_summary(pool) -> dict:
    population = pool.population
    return {
        'design': {'order': pool.design.order, 'reference_temperature_c': pool.design.reference_c,
                   'temperature_scale_c': pool.design.scale_c,
                   'temperature_rate': pool.design.rate, 'coefficients': list(pool.design.names)},
        'tests': [{'column': t.column, 'chi2': t.statistic, 'dof': t.dof,
                   'threshold': t.threshold, 'significant': t.significant} for t in pool.tests],
        'kappa': pool.kappa, 'kappa_dof': pool.kappa_dof,
        'noise_rms_rad_s': math.sqrt(pool.sigma2_median),
        'population': {'units': population.units, 'mean': population.mean.tolist(),
                       'sd': np.sqrt(np.diag(population.covariance)).tolist(),
                       'covariance': population.covariance.tolist(),
                       'em_iterations': population.iterations,
                       'converged': population.converged},
    }


def _count(number: int, thing: str) -> str:
    return f'{number} {thing}' + ('' if number == 1 else 's')


def _remove(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass


def write_fleet_prior(out: Path) -> list:
    """
    Write the fleet prior into ``out`` (after the fleet report); give the lines to print.

    Files of an earlier prior that this one does not rewrite are removed, so
    every prior file in ``out`` is of the last run. OSError when a file cannot
    be written.
    """
    report = _read_json(out / 'fleet.json') or {}
    flagged = {o['unit'] for o in report.get('outliers', [])}
    own_effects = {}
    for row in report.get('records', []):
        for axis, effects in row.get('effects', {}).items():
            own_effects.setdefault(row['unit'], {}).setdefault(axis, set()).update(effects)
    moments, excluded, node_names, folders, records = {}, {}, Counter(), {}, {}
    for path in sorted((out / 'units').glob(f'*/{UNIT_FILE}')):
        entry = _read_json(path)
        if entry is None or entry.get('status') != 'ok':
            continue
        unit = entry['unit']
        folders[unit], records[unit] = path.parent, len(entry['records'])
        found, why = _unit_moments(path.parent, entry)
        if found is None:
            excluded[unit] = why
            continue
        moments[unit] = found
        node_names[_node_name(path.parent, entry)] += 1
    pooled = [unit for unit in moments if unit not in flagged]
    excluded.update({unit: 'flagged by the fleet report (shrunk, not pooled)'
                     for unit in moments if unit in flagged})
    summary = {'method': METHOD, 'units_with_moments': len(moments), 'pooled': pooled,
               'excluded': excluded, 'axes': {}, 'units': {}}
    pools, why_not = {}, None
    if len(pooled) < MIN_POOLED_UNITS:
        why_not = (f'{len(pooled)} units to pool (finished, with {MOMENTS_FILE}, not flagged); '
                   f'at least {MIN_POOLED_UNITS} needed')
    else:
        found = [axis_moments for unit in pooled for axis_moments in moments[unit].values()]
        low = min(axis_moments.temperature_min_c for axis_moments in found)
        high = max(axis_moments.temperature_max_c for axis_moments in found)
        reference_c, scale_c = 0.5 * (low + high), max(0.5 * (high - low), MIN_SCALE_C)
        summary['temperature_range_c'] = [low, high]
        for axis in AXES:
            having = {unit: axes[axis] for unit, axes in moments.items() if axis in axes}
            if len([unit for unit in having if unit in pooled]) >= MIN_POOLED_UNITS:
                pools[axis] = pool_fleet(having, pooled, reference_c, scale_c)
                summary['axes'][axis] = _axis_summary(pools[axis])
        if not pools:
            why_not = f'no axis is held by {MIN_POOLED_UNITS} pooled units'
    written = set()
    if pools:
        node_name = node_names.most_common(1)[0][0]
        summary['node_name'] = node_name
        span = (low, high)
        try:
            _write_model(out / FLEET_PARAMS, node_name, pools,
                         {axis: pool.population.mean for axis, pool in pools.items()}, span,
                         f'Fleet prior of {len(pooled)} units by mlx-tempcomp fleet: the '
                         'population mean, for a unit without a record of its own\n'
                         f'(method and figures in {PRIOR_JSON})')
        except (ParameterError, TempCompError) as err:
            why_not = f'the population model is refused: {err}'
            _remove(out / FLEET_PARAMS)
            pools = {}
        for unit in moments if pools else ():
            axes = [axis for axis in pools if unit in pools[axis].units]
            path = folders[unit] / SHRUNK_PARAMS
            item = {'records': records[unit], 'rows': moments[unit][axes[0]].rows, 'axes': {}}
            for axis in axes:
                fit = pools[axis].units[unit]
                item['axes'][axis] = {'own': fit.own.tolist(), 'shrunk': fit.shrunk.tolist(),
                                      't_weight': fit.weight, 'prior_share': fit.prior_share,
                                      'own_effects_not_pooled': sorted(
                                          own_effects.get(unit, {}).get(axis, set())
                                          - {'thermal_lag', 'temperature_rate'})}
            try:
                _write_model(path, node_name, pools,
                             {axis: pools[axis].units[unit].shrunk for axis in axes}, span,
                             f'Unit {unit} shrunk toward the fleet of {len(pooled)} units by '
                             'mlx-tempcomp fleet (partial pooling)\n'
                             f'(its own fit: params.yaml beside; figures in ../../{PRIOR_JSON})')
                item['shrunk_params'] = str(path.relative_to(out))
                written.add(unit)
            except (ParameterError, TempCompError) as err:
                item['refused'] = str(err)
            summary['units'][unit] = item
    for unit, folder in folders.items():
        if unit not in written:
            _remove(folder / SHRUNK_PARAMS)
    if not pools:
        _remove(out / FLEET_PARAMS)
        summary['not_written'] = why_not
        write_json(out / PRIOR_JSON, summary)
        return [f'fleet prior not written: {why_not}']
    write_json(out / PRIOR_JSON, summary)
    left_out = len(flagged & set(moments))
    lines = [f'fleet prior of {len(pooled)} units ({_count(left_out, "flagged unit")} left '
             f'out, {_count(len(excluded) - left_out, "unit")} without usable moments): wrote '
             f'{out / FLEET_PARAMS}, {PRIOR_JSON} and {len(written)} units/<unit>/'
             f'{SHRUNK_PARAMS}']
    for axis, pool in pools.items():
        shares = [fit.prior_share for fit in pool.units.values()]
        lines.append(f'  axis {axis}: bias order {pool.design.order}'
                     + (' and temperature rate' if pool.design.rate else '')
                     + f' in (T - {pool.design.reference_c:.2f}) / {pool.design.scale_c:.2f}; '
                     f"fleet's share of the shrunk fits {min(shares):.2f} to {max(shares):.2f}")
    return lines
