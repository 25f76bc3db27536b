"""
The fleet prior: a population model for units without a record, unit fits shrunk toward it.

Written after the fleet report, from what ``OUT`` holds: each finished unit's
`MOMENTS_FILE` (the worker's summary of each of its records, added up over a
unit's records with a bias offset per record, the unit's constant its last
record's: `core.fitting.pooling.unit_moments`), and the report's outlier units, which
are left out of the population (they are still shrunk, with the small weight
their distance gives them). The math is `core.fitting.pooling`, per axis; here the
files:

- ``OUT/fleet_params.yaml``: the population mean, an effects model the
  compensation node loads as is, for a unit that has no record of its own;
- ``OUT/units/<unit>/shrunk_params.yaml``: the unit's coefficients shrunk
  toward the fleet (partial pooling), beside its own params.yaml; none for
  a unit whose record rejects its shrunk fit (`core.fitting.pooling.ConflictTest`):
  it keeps its params.yaml;
- ``OUT/fleet_prior.json``: the design, the column tests that chose it, the
  noise figures, the population mean and covariance, each unit's own and
  shrunk coefficients, how much the fleet moved it and its record's test of
  the shrunk fit.

The population file is read back by `parameters.files.node_values` and built
by `build_model`, as the node would; each shrunk model is built from those
checked values with its own coefficients before its file is written.
"""

from collections import Counter
from dataclasses import dataclass, field
import json
import math
from pathlib import Path

import numpy as np

from .unit import command_argv, MOMENTS_FILE, parse_command, UNIT_FILE, UnitError
from ..core.effects import AxisTerms, EffectModel
from ..core.errors import TempCompError
from ..core.fitting import (CONFLICT_LEVEL, MIN_POOLED_UNITS, moments_of, pool_fleet,
                            RATE_WINDOW_S, unit_moments)
from ..parameters.files import effect_parameters, node_values, parameter_file, write_parameter_file
from ..parameters.models import build_model
from ..parameters.specs import ParameterError
from ..recordings.recording import AXES
from ..toolkit.running import write_json

FLEET_PARAMS = 'fleet_params.yaml'
SHRUNK_PARAMS = 'shrunk_params.yaml'
PRIOR_JSON = 'fleet_prior.json'
DEFAULT_NODE_NAME = 'compensation_node'
# The unit's own effects the fleet design carries (the thermal lag to first order).
POOLED_EFFECTS = frozenset({'thermal_lag', 'temperature_rate'})
# The smallest half span of the fleet's x: a fleet at one temperature still gets a scale.
MIN_SCALE_C = 0.5
METHOD = ('Per axis, every unit is fitted with one design: a bias polynomial in x = (T - '
          "reference) / scale, the fleet's reference and scale, of the highest order whose "
          'top power the units show jointly (chi^2 over the units at 0.001), and the '
          'temperature-rate coefficient when they show it. Population: beta_i ~ N(mu, Sigma '
          '/ w_i), t weights (nu 4), mu and Sigma by EM over the units the fleet report did '
          'not flag; each unit shrunk to its posterior mean with its own estimation '
          "covariance (kappa sigma^2 (X'X)^-1), unless its record rejects that mean: the rise "
          "of its residual sum of squares over its own fit's, in kappa sigma^2, beyond "
          f"chi^2's {1.0 - CONFLICT_LEVEL:g} quantile (degrees of freedom: the rank of X'X); "
          'such a unit keeps its own params.yaml (no shrunk_params.yaml).')


def _read_json(path: Path):
    try:
        return json.loads(path.read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return None


def _unit_moments(folder: Path) -> tuple:
    """
    Give ({axis: DesignMoments} of the unit, None) or (None, why not).

    The unit's records in its order, each with its own bias offset but the
    last (`unit_moments`): the fleet's coefficients of a unit carry the
    offset of its last record, as its params.yaml from diagnose does.
    """
    document = _read_json(folder / MOMENTS_FILE)
    if not isinstance(document, dict) or 'records' not in document:
        return None, (f'no {MOMENTS_FILE} of this version (written before the fleet prior '
                      'or before one model per unit: rerun with --force)')
    per_axis = {}
    for record in document['records']:
        if 'error' in record:
            return None, f'{record["path"]}: {record["error"]}'
        try:
            found = moments_of(record.get('moments', {}))
        except TempCompError as err:
            return None, f'{record["path"]}: {err}'
        for axis, moments in found.items():
            per_axis.setdefault(axis, []).append(moments)
    return {axis: unit_moments(records) for axis, records in per_axis.items()}, None


def _node_name(entry: dict, names: dict) -> str:
    """Give the node section the unit's params.yaml has: --node-name of its options."""
    options = tuple(entry['options'])
    if options not in names:
        try:
            names[options] = parse_command(command_argv(entry['command'], ['RECORD'], 'OUT',
                                                        [], options)).node_name
        except UnitError:
            names[options] = DEFAULT_NODE_NAME
    return names[options]


def _model(pools: dict, coefficients: dict, temperature_range: tuple) -> EffectModel:
    """Give the effects model of ``coefficients`` {axis: design coefficients}."""
    terms = []
    for axis in coefficients:
        bias, rate = pools[axis].design.bias_and_rate(coefficients[axis])
        terms.append(AxisTerms(bias=tuple(bias), temperature_rate_rad_s_per_c_s=rate))
    design = next(iter(pools.values())).design
    return EffectModel(terms=tuple(terms), reference_temperature_c=design.reference_c,
                       temperature_scale_c=design.scale_c,
                       temperature_min_c=temperature_range[0],
                       temperature_max_c=temperature_range[1],
                       temperature_rate_window_s=RATE_WINDOW_S)


def _write(path: Path, node_name: str, model: EffectModel, axes: list, header: str) -> None:
    write_parameter_file(path, parameter_file(node_name, effect_parameters(model, axes)), header)


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


@dataclass
class _Fleet:
    """What OUT holds for the prior: each unit's moments, folder, records, why left out."""

    moments: dict = field(default_factory=dict)
    folders: dict = field(default_factory=dict)
    records: dict = field(default_factory=dict)
    excluded: dict = field(default_factory=dict)
    node_names: Counter = field(default_factory=Counter)


def _gather(out: Path) -> _Fleet:
    fleet, names = _Fleet(), {}
    for path in sorted((out / 'units').glob(f'*/{UNIT_FILE}')):
        entry = _read_json(path)
        if entry is None or entry.get('status') != 'ok':
            continue
        unit = entry['unit']
        fleet.folders[unit], fleet.records[unit] = path.parent, len(entry['records'])
        found, why = _unit_moments(path.parent)
        if found is None:
            fleet.excluded[unit] = why
            continue
        fleet.moments[unit] = found
        fleet.node_names[_node_name(entry, names)] += 1
    return fleet


def _pools(fleet: _Fleet, pooled: list, summary: dict) -> dict:
    """Pool every axis that MIN_POOLED_UNITS pooled units hold; {axis: FleetPooling}."""
    found = [axis_moments for unit in pooled for axis_moments in fleet.moments[unit].values()]
    low = min(axis_moments.temperature_min_c for axis_moments in found)
    high = max(axis_moments.temperature_max_c for axis_moments in found)
    summary['temperature_range_c'] = [low, high]
    pools = {}
    for axis in AXES:
        having = {unit: axes[axis] for unit, axes in fleet.moments.items() if axis in axes}
        if len([unit for unit in having if unit in pooled]) >= MIN_POOLED_UNITS:
            pools[axis] = pool_fleet(having, pooled, 0.5 * (low + high),
                                     max(0.5 * (high - low), MIN_SCALE_C))
            summary['axes'][axis] = _axis_summary(pools[axis])
    return pools


def _unit_item(fleet: _Fleet, unit: str, axes: list, pools: dict, own_effects: dict) -> dict:
    item = {'records': fleet.records[unit], 'rows': fleet.moments[unit][axes[0]].rows,
            'axes': {}}
    for axis in axes:
        fit = pools[axis].units[unit]
        item['axes'][axis] = {
            'own': fit.own.tolist(), 'shrunk': fit.shrunk.tolist(), 't_weight': fit.weight,
            'prior_share': fit.prior_share,
            'conflict': {'chi2': fit.conflict.statistic, 'dof': fit.conflict.dof,
                         'threshold': fit.conflict.threshold, 'rejected': fit.conflict.rejected},
            'own_effects_not_pooled': sorted(own_effects.get(unit, {}).get(axis, set())
                                             - POOLED_EFFECTS)}
    return item


def _write_files(out: Path, fleet: _Fleet, pools: dict, pooled: list, summary: dict,
                 own_effects: dict) -> set:
    """
    Write the population and the shrunk fits; give the units written.

    The population file is read back by `node_values` and built by
    `build_model`, as the node would; each unit's model is built from the
    same checked values with its own coefficients before its file is written.
    ParameterError or TempCompError when the population is refused.
    """
    node_name = fleet.node_names.most_common(1)[0][0]
    summary['node_name'] = node_name
    span = tuple(summary['temperature_range_c'])
    axes = list(pools)
    _write(out / FLEET_PARAMS, node_name,
           _model(pools, {axis: pools[axis].population.mean for axis in axes}, span), axes,
           f'Fleet prior of {len(pooled)} units by mlx-tempcomp fleet: the population mean, '
           f'for a unit without a record of its own\n(method and figures in {PRIOR_JSON})')
    checked = node_values(str(out / FLEET_PARAMS), node_name)
    build_model(checked)
    written = set()
    for unit in fleet.moments:
        axes = [axis for axis in pools if unit in pools[axis].units]
        item = _unit_item(fleet, unit, axes, pools, own_effects)
        rejected = [(axis, pools[axis].units[unit].conflict) for axis in axes
                    if pools[axis].units[unit].conflict.rejected]
        if rejected:
            item['kept_own'] = 'its record rejects the shrunk fit (' + '; '.join(
                f'axis {axis}: chi^2 {test.statistic:.1f} over {test.threshold:.1f}, '
                f'the {CONFLICT_LEVEL:.0%} level' for axis, test in rejected) + \
                '): it keeps its own params.yaml'
            summary['units'][unit] = item
            continue
        model = _model(pools, {axis: pools[axis].units[unit].shrunk for axis in axes}, span)
        try:
            build_model({**checked, 'axes': axes, **{
                f'effects.{key}': value for key, value in model.to_parameters(axes).items()}})
        except (ParameterError, TempCompError) as err:
            item['refused'] = str(err)
        else:
            path = fleet.folders[unit] / SHRUNK_PARAMS
            _write(path, node_name, model, axes,
                   f'Unit {unit} shrunk toward the fleet of {len(pooled)} units by '
                   'mlx-tempcomp fleet (partial pooling)\n'
                   f'(its own fit: params.yaml beside; figures in ../../{PRIOR_JSON})')
            item['shrunk_params'] = str(path.relative_to(out))
            written.add(unit)
        summary['units'][unit] = item
    return written


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
    for row in report.get('rows', []):
        for axis, effects in row.get('effects', {}).items():
            own_effects.setdefault(row['unit'], {}).setdefault(axis, set()).update(effects)
    fleet = _gather(out)
    pooled = [unit for unit in fleet.moments if unit not in flagged]
    left_out = [unit for unit in fleet.moments if unit in flagged]
    without = len(fleet.excluded)
    fleet.excluded.update(dict.fromkeys(left_out,
                                        'flagged by the fleet report (shrunk, not pooled)'))
    summary = {'method': METHOD, 'units_with_moments': len(fleet.moments), 'pooled': pooled,
               'excluded': fleet.excluded, 'axes': {}, 'units': {}}
    pools, written, why_not = {}, set(), None
    if len(pooled) < MIN_POOLED_UNITS:
        why_not = (f'{len(pooled)} units to pool (finished, with {MOMENTS_FILE}, not flagged); '
                   f'at least {MIN_POOLED_UNITS} needed')
    else:
        pools = _pools(fleet, pooled, summary)
        why_not = None if pools else f'no axis is held by {MIN_POOLED_UNITS} pooled units'
    if pools:
        try:
            written = _write_files(out, fleet, pools, pooled, summary, own_effects)
        except (ParameterError, TempCompError) as err:
            why_not, pools = f'the population model is refused: {err}', {}
    for unit, folder in fleet.folders.items():
        if unit not in written:
            (folder / SHRUNK_PARAMS).unlink(missing_ok=True)
    if not pools:
        (out / FLEET_PARAMS).unlink(missing_ok=True)
        summary['not_written'] = why_not
        write_json(out / PRIOR_JSON, summary)
        return [f'fleet prior not written: {why_not}']
    write_json(out / PRIOR_JSON, summary)
    lines = [f'fleet prior of {len(pooled)} units ({_count(len(left_out), "flagged unit")} '
             f'left out, {_count(without, "unit")} without usable moments): wrote '
             f'{out / FLEET_PARAMS}, {PRIOR_JSON} and {len(written)} units/<unit>/'
             f'{SHRUNK_PARAMS}']
    for axis, pool in pools.items():
        shares = [fit.prior_share for fit in pool.units.values()]
        rejected = sum(fit.conflict.rejected for fit in pool.units.values())
        lines.append(f'  axis {axis}: bias order {pool.design.order}'
                     + (' and temperature rate' if pool.design.rate else '')
                     + f' in (T - {pool.design.reference_c:.2f}) / {pool.design.scale_c:.2f}; '
                     f"fleet's share of the shrunk fits {min(shares):.2f} to {max(shares):.2f}"
                     + (f'; {_count(rejected, "unit")} whose record rejects its shrunk fit '
                        '(kept its own params.yaml)' if rejected else ''))
    return lines
