"""
The fleet prior against each unit's own fit, on a simulated fleet whose truth is known.

``mlx-tempcomp simulate --fleet N`` writes N units (one axis, one full
25 -> 70 -> -20 -> 25 C cycle at 3 C/min sampled at 0.5 Hz, a 60 s thermal
lag varying unit to unit, every chip coefficient drawn per unit, K outlier
units with a ZRO slope off by 0.2 deg/s/C), and again with ``--noise-scale
0``: the same chips without noise, whose time and temperature columns are
what the truth is evaluated on. The true bias at each sample is the chip's ZRO
polynomial at its die temperature (the chamber profile of the unit's
truth.json; the sensor reports it through the thermal lag), in rad/s.

Each unit's record is cut to the first 5 %, 25 % and 100 % of the cycle, in
two fleets: every unit cut ("whole fleet"), and every other unit cut while
the rest keep the full cycle ("half the fleet full"). Each fleet runs through
``mlx-tempcomp fleet diagnose`` (the real command, a local cluster), then every
cut unit's files are run by ``mlx-tempcomp evaluate`` over its truth record
(the node's own model building, the whole cycle, error = corrected rate with
the truth as raw rate): its own params.yaml (diagnose), its own least-squares
fit in the fleet design (from fleet_prior.json, not shrunk), fleet_params.yaml
(the prior) and its shrunk_params.yaml. Figures are RMS over the cycle in
rad/s, median and mean over the units the report did not flag; flagged
outliers are listed apart. A unit whose record rejects its shrunk fit has no
shrunk_params.yaml: its params.yaml counts as its shrunk fit, and the table
counts such units ("kept own") and gives the largest q of the test over its
threshold. Nothing is asserted: the table is printed.

    .venv/bin/python bench/bench_fleet_prior.py [--units 40] [--outliers 3] [--workers 2]
"""

import argparse
import contextlib
import io
import json
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from mlx_tempcomp.cli import main as cli_main
from mlx_tempcomp.core.effects import AxisTerms, EffectModel
from mlx_tempcomp.parameters.files import effect_parameters, parameter_file, write_parameter_file
import numpy as np

FRACTIONS = (0.05, 0.25, 1.0)
SIMULATE = ['--axes', 'z', '--cycle-c', '70', '-20', '25', '--ramp-c-per-min', '3',
            '--rate-hz', '0.5', '--thermal-lag-s', '60']
MODELS = ('own (diagnose)', 'own (fleet design)', 'fleet prior', 'shrunk')


def run(argv: list) -> None:
    """Run mlx-tempcomp in a fresh interpreter; stop with its output if it fails."""
    done = subprocess.run([sys.executable, '-m', 'mlx_tempcomp.cli', *argv],
                          capture_output=True, text=True)
    if done.returncode not in (0, 1):
        sys.exit(f'mlx-tempcomp {" ".join(argv)} failed:\n{done.stdout}{done.stderr}')


def truth_record(record: Path, quiet: Path, truth: dict, path: Path) -> None:
    """Write time, temperature of the noiseless twin and the true bias as gyro_z."""
    effects = truth['config']['effects']
    if effects['hysteresis_dps'] or any(effects['acceleration_dps_per_m_s2']) or \
            effects['bias_steps'] or effects['zro_supply_dps_per_v']:
        sys.exit(f'{record}: the truth here covers the ZRO polynomial and the thermal lag only')
    data = np.loadtxt(quiet, delimiter=',', skiprows=1)
    profile = truth['thermal_profile']
    if profile['time_constant_s']:
        sys.exit(f'{record}: the die must follow the chamber (no --die-time-constant-s)')
    die_c = np.interp(data[:, 0], profile['times_s'], profile['temperatures_c'])
    zro_dps = np.polynomial.polynomial.polyval(die_c - 25.0,
                                               truth['devices']['z']['zro_dps_coefficients'])
    np.savetxt(path, np.column_stack([data[:, 0], data[:, 1], np.radians(zro_dps)]),
               delimiter=',', header='time,temperature,gyro_z', comments='', fmt='%.12g')


def cut(record: Path, fraction: float, path: Path) -> None:
    """Write the rows of ``record`` within the first ``fraction`` of its duration."""
    lines = record.read_text().splitlines()
    times = [float(line.split(',')[0]) for line in lines[1:]]
    end = times[0] + fraction * (times[-1] - times[0])
    path.write_text('\n'.join(lines[:1] + [line for line, t in zip(lines[1:], times)
                                           if t <= end + 1e-9]) + '\n')


def rms(params: Path, truth: Path) -> float:
    """Give the RMS error over the truth record of a parameter file (mlx-tempcomp evaluate)."""
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(io.StringIO()):
        code = cli_main(['evaluate', str(truth), '--params', str(params), '--json'])
    if code:
        sys.exit(f'evaluate {params} over {truth}: exit code {code}')
    return json.loads(stdout.getvalue())['per_sample']['z']['rms']


def own_design_file(prior: dict, unit: str, node_name: str, path: Path) -> Path:
    """Write the unit's own (unshrunk) fit in the fleet design, as the prior writes its files."""
    design = prior['axes']['z']['design']
    own = prior['units'][unit]['axes']['z']['own']
    bias = own[:design['order'] + 1]
    rate = own[-1] if design['temperature_rate'] else 0.0
    low, high = prior['temperature_range_c']
    model = EffectModel(terms=(AxisTerms(bias=tuple(bias), temperature_rate_rad_s_per_c_s=rate),),
                        reference_temperature_c=design['reference_temperature_c'],
                        temperature_scale_c=design['temperature_scale_c'],
                        temperature_min_c=low, temperature_max_c=high)
    write_parameter_file(path, parameter_file(node_name, effect_parameters(model, ['z'])))
    return path


def fleet_errors(folder: Path, units: list, truths: dict, fraction: float, cut_units: set,
                 workers: int, name: str) -> dict:
    """Run fleet diagnose on a fleet whose ``cut_units`` are cut; give each cut unit's errors."""
    records = folder / f'{name}-records'
    records.mkdir()
    rows = ['unit,path']
    for unit in units:
        cut(folder / 'fleet' / f'{unit}.csv', fraction if unit in cut_units else 1.0,
            records / f'{unit}.csv')
        rows.append(f'{unit},{unit}.csv')
    (records / 'units.csv').write_text('\n'.join(rows) + '\n')
    out = folder / f'{name}-out'
    run(['fleet', 'diagnose', '--manifest', str(records / 'units.csv'), '--out', str(out),
         '--workers', str(workers)])
    prior = json.loads((out / 'fleet_prior.json').read_text())
    if 'not_written' in prior:
        sys.exit(f'{name}: fleet prior not written: {prior["not_written"]}')
    flagged = {o['unit'] for o in json.loads((out / 'fleet.json').read_text())['outliers']}
    errors = {}
    for unit in sorted(cut_units):
        folder_of = out / 'units' / unit
        own_design = own_design_file(prior, unit, prior['node_name'],
                                     folder / f'{name}-{unit}-own.yaml')
        fit = prior['units'][unit]['axes']['z']
        # A unit whose record rejects its shrunk fit has none: it keeps its params.yaml.
        shrunk = folder_of / ('params.yaml' if fit['conflict']['rejected'] else
                              'shrunk_params.yaml')
        files = (folder_of / 'params.yaml', own_design, out / 'fleet_params.yaml', shrunk)
        errors[unit] = {'flagged': unit in flagged,
                        **{model: rms(path, truths[unit]) for model, path in zip(MODELS, files)},
                        'prior_share': fit['prior_share'], 'conflict': fit['conflict']}
    return {'errors': errors, 'design': prior['axes']['z']['design'],
            'kappa': prior['axes']['z']['kappa']}


def summary_line(label: str, found: dict) -> str:
    good = [e for e in found['errors'].values() if not e['flagged']]
    line = f'{label:<34}{len(good):>4}'
    for model in MODELS:
        values = [e[model] for e in good]
        line += f'  {np.median(values):.2e} {np.mean(values):.2e}'
    ratio = [e['shrunk'] / e['own (diagnose)'] for e in good]
    design_ratio = [e['shrunk'] / e['own (fleet design)'] for e in good]
    line += (f'  {np.mean(np.less(ratio, 1.0)):5.0%} {max(ratio):5.2f}'
             f'  {np.mean(np.less(design_ratio, 1.0)):5.0%} {max(design_ratio):5.2f}'
             f'  {np.median([e["prior_share"] for e in good]):4.2f}'
             f'  {sum(e["conflict"]["rejected"] for e in good):4d}'
             f'  {max(e["conflict"]["chi2"] / e["conflict"]["threshold"] for e in good):5.2f}')
    design = found['design']
    return line + (f'   order {design["order"]}{" + rate" if design["temperature_rate"] else ""}'
                   f', kappa {found["kappa"]:.2f}')


def worst_line(label: str, found: dict) -> str:
    """Say the unit whose shrunk fit does worst against its unshrunk one; its own fit's rank."""
    good = {unit: e for unit, e in found['errors'].items() if not e['flagged']}
    unit = max(good, key=lambda u: good[u]['shrunk'] / good[u]['own (fleet design)'])
    e = good[unit]
    rank = sorted(f['own (fleet design)'] for f in good.values()).index(e['own (fleet design)'])
    return (f'  {label}: {unit}, own (fleet design) {e["own (fleet design)"]:.2e} (rank '
            f'{rank + 1} of {len(good)} from the best), shrunk {e["shrunk"]:.2e}, q '
            f'{e["conflict"]["chi2"]:.2f} of {e["conflict"]["threshold"]:.2f}')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--units', type=int, default=40)
    parser.add_argument('--outliers', type=int, default=3)
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix='bench-fleet-prior-') as folder:
        folder = Path(folder)
        for name, extra in (('fleet', []), ('quiet', ['--noise-scale', '0'])):
            run(['simulate', '--fleet', str(args.units), '--fleet-outliers', str(args.outliers),
                 '--seed', str(args.seed), '--out', str(folder / name), *SIMULATE, *extra])
        truth = json.loads((folder / 'fleet' / 'fleet_truth.json').read_text())
        units = [u['unit'] for u in truth['units']]
        truths = {}
        for unit in units:
            truths[unit] = folder / f'{unit}.truth.csv'
            truth_record(folder / 'fleet' / f'{unit}.csv', folder / 'quiet' / f'{unit}.csv',
                         json.loads((folder / 'fleet' / f'{unit}.truth.json').read_text()),
                         truths[unit])
        print(f'{args.units} simulated units, outliers (truth): '
              f'{", ".join(u["unit"] for u in truth["units"] if u["outlier"])}')
        print('held-out RMS error against the truth over the full cycle, rad/s: median mean '
              'over the units not flagged')
        header = f'{"record, fleet":<34}{"units":>5}' + ''.join(f'  {m:^21}' for m in MODELS)
        print(header + '  shrunk<diag worst  shrunk<own worst  fleet share  kept own  q/limit')
        flagged_lines, worst_lines = [], []
        for fraction in FRACTIONS:
            scenarios = [('whole fleet', set(units))]
            if fraction < 1.0:
                scenarios.append(('half the fleet full', set(units[1::2])))
            for scenario, cut_units in scenarios:
                name = f'{scenario.split()[0]}-{round(fraction * 100)}'
                found = fleet_errors(folder, units, truths, fraction, cut_units, args.workers,
                                     name)
                label = f'{fraction:.0%} of a cycle, {scenario}'
                print(summary_line(label, found), flush=True)
                worst_lines.append(worst_line(label, found))
                for unit, e in found['errors'].items():
                    if e['flagged']:
                        flagged_lines.append(
                            f'  {label}: {unit} ' + ', '.join(f'{m} {e[m]:.2e}' for m in MODELS)
                            + (' (kept own)' if e['conflict']['rejected'] else ''))
        print('worst unit against its unshrunk fit in the fleet design:')
        print('\n'.join(worst_lines))
        print('flagged by the fleet report (left out of the prior; shrunk with their t weight):')
        print('\n'.join(flagged_lines) or '  none')
    print(f'({time.perf_counter() - start:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
