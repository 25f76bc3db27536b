"""
What `diagnose` writes, run as the node runs it, against PX4's cubic clamped at its range.

For every record: ``mlx-tempcomp diagnose REC --test F --average-s S --out DIR``
writes params.yaml from the first 1 - F of the rows; ``mlx-tempcomp evaluate REC
--params DIR/params.yaml --out-csv`` runs that file over the whole record as the
compensation node runs it. The bench then judges the held-out rows (the last F)
in plain numpy, apart from the code it judges: the PX4-style cubic is
np.polyfit(T - TREF, rate error, 3) on the first rows, TREF the middle of
their temperature range, run clamped at that range (as PX4 runs TC_G*); both
residuals (corrected minus truth: the reference rate, else 0 at rest) are
averaged over S-second bins from the held-out part's first row. Per record and
axis it prints the gain (the cubic's RMS over the written model's: above 1 the
written model is better), the share of held-out rows outside the fitted range,
and what the axis writes; and the geometric mean of the gains.

Records:

- real: every record under ../shared/data (CSV files, read with each column
  preset in turn, and flight-controller logs) whose temperature swings 10 C or
  more, and each ``--record PATH[,preset=NAME][,columns=SPEC][,average_s=S]``;
- simulated (``--simulated``, default on): a chamber ramping -20..70 C three
  times (1 Hz, `simulation.chamber`) with one undeclared live effect each, and
  clean, random-walk, bias-step and turn-on-drift records, ``--seeds`` seeds
  each; the undeclared effect must be the first the axis writes.

    .venv/bin/python bench/bench_real.py [--record SPEC ...] [--no-simulated] [--seeds N]
        [--test F] [--average-s S] [--diagnose-args "--validation forward ..."] [--json FILE]
"""

import argparse
import contextlib
import csv
import io
import json
import math
from pathlib import Path
import shlex
import sys
import tempfile

from mlx_tempcomp.cli import main as cli_main
from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.recordings.columns import PRESETS
from mlx_tempcomp.recordings.load import load_recording
from mlx_tempcomp.simulation.chamber import chamber_profile, chamber_run
from mlx_tempcomp.simulation.physics import Effects, Noise, Scenario, ThermalProfile
import numpy as np

# Where the tests find ../shared (MLX_TEMPCOMP_SHARED, beside this checkout, or beside the
# repository it was cloned from or is a worktree of).
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test' / 'support'))
from measured_data import FLIGHT_LOGS  # noqa: E402,I100

SHARED_DATA = FLIGHT_LOGS.parent
MIN_SWING_C = 10.0
TEST_FRACTION = 0.25

# The simulated chamber of test/toolkit/test_diagnose.py: -20..70 C three times at 1, 2 and
# 3 C/min with 10 min holds, 1 Hz, a cubic ZRO, a wandering supply recorded alongside.
PROFILE = chamber_profile(((70.0, 2.0), (-20.0, 1.0), (70.0, 3.0), (-20.0, 2.0), (70.0, 1.0),
                           (-20.0, 3.0)))
SUPPLY_TIMES_S = tuple(float(t) for t in np.arange(0.0, PROFILE.duration_s + 400.0, 400.0))
SUPPLY_V = tuple(float(v) for v in 5.0 + 0.25 * np.sin(2.1 * np.arange(len(SUPPLY_TIMES_S))))
NOISE_DPS = 0.02
QUIET = Noise(bias_instability_dps=0.0)
# name -> (effects, noise, the effect the axis must name first, or '' for none)
SIMULATED = {
    'thermal_lag': (Effects(thermal_lag_s=200.0), QUIET, 'thermal_lag'),
    'thermal_gradient': (Effects(gradient_time_constants_s=(120.0, 900.0),
                                 gradient_dps_per_c=(0.02, 0.01)), QUIET, 'thermal_gradient'),
    'hysteresis': (Effects(hysteresis_dps=0.2, hysteresis_width_c=5.0), QUIET, 'hysteresis'),
    'temperature_rate': (Effects(zro_dps_per_c_s=4.0), QUIET, 'temperature_rate'),
    'supply_voltage': (Effects(zro_supply_dps_per_v=0.4), QUIET, 'supply_voltage'),
    'clean': (Effects(), QUIET, ''),
    'random_walk': (Effects(), Noise(bias_instability_dps=0.0, rate_random_walk_dps_rt_s=2e-4),
                    ''),
    'bias_step': (Effects(bias_steps=((9000.0, 0.2),)), QUIET, ''),
    'turn_on_drift': (Effects(), QUIET, ''),
}
TURN_ON_DRIFT_RAD_S = 2e-3
TURN_ON_TAU_S = 7200.0
# A stand-in for a motionless 3-axis IMU in a slow chamber (issue 23's kept-back record):
# three periods at 1 Hz ramping 0.08 C/min between 5 and 24 C, judged on 60 s bins; the
# last period's held-out quarter climbs past anything before it. Datasheet white noise and
# bias instability, a bias random walk, each axis its own cubic ZRO.
SLOW_PERIODS = {'slow_ramps_P0': (15.0, (24.0, 5.0, 24.0, 5.0, 24.0, 5.0)),
                'slow_ramps_P1': (10.0, (5.0, 24.0, 5.0, 24.0, 5.0, 24.0)),
                'slow_ramps_P2': (20.0, (24.0, 5.0, 24.0, 8.0, 30.0))}
SLOW_ZRO_DPS = ((0.3, 0.015, 3e-4, -4e-6), (-0.2, -0.01, 1e-4, 2e-6), (0.1, 0.02, -2e-4, 1e-6))
SLOW_NOISE = Noise(rate_random_walk_dps_rt_s=2e-4)


def run_cli(argv) -> str:
    """Run ``mlx-tempcomp`` in this process (the code a user's command runs); return stdout."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = cli_main([str(a) for a in argv])
    if code:
        raise RuntimeError(f'mlx-tempcomp {" ".join(map(str, argv))} exited {code}: '
                           f'{stderr.getvalue()[-500:]}')
    return stdout.getvalue()


def parse_record(spec: str) -> dict:
    """PATH[,preset=NAME][,columns=SPEC][,average_s=S] -> a record dict."""
    path, *options = spec.split(',')
    record = {'path': Path(path), 'name': Path(path).name, 'read': []}
    for option in options:
        key, _, value = option.partition('=')
        if key in ('preset', 'columns'):
            record['read'] = [f'--{key}', value]
        elif key == 'average_s':
            record['average_s'] = float(value)
        else:
            raise SystemExit(f'--record {spec}: unknown option {key!r}')
    return record


def swing_c(path: Path, read: list):
    """Give the temperature swing of a record read with ``read`` options, None if unreadable."""
    options = {'preset': read[1]} if read[:1] == ['--preset'] else \
        {'columns': read[1]} if read[:1] == ['--columns'] else {}
    try:
        recording = load_recording(path, **options)
    except Exception:   # any record the readers refuse is not one of ours
        return None
    return float(np.ptp(recording.temperature_c))


def shared_records() -> list:
    """Every record under ../shared/data that swings MIN_SWING_C or more."""
    found = []
    if not SHARED_DATA.is_dir():
        print(f'note: {SHARED_DATA} is missing: no shared records', file=sys.stderr)
        return found
    for path in sorted(SHARED_DATA.rglob('*')):
        if not path.is_file() or path.suffix.lower() not in ('.csv', '.ulg', '.bin'):
            continue
        tries = [[]] + ([['--preset', p] for p in sorted(PRESETS)]
                        if path.suffix.lower() == '.csv' else [])
        for read in tries:
            swing = swing_c(path, read)
            if swing is not None:
                if swing >= MIN_SWING_C:
                    found.append({'path': path, 'name': path.name, 'read': read})
                break
    return found


def write_csv(path: Path, run, rate: np.ndarray, supply: bool) -> None:
    """Write a chamber run as a canonical CSV record."""
    axes = 'xyz'[-rate.shape[1]:] if rate.shape[1] == 1 else 'xyz'[:rate.shape[1]]
    with path.open('w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(['time', 'temperature'] + [f'gyro_{a}' for a in axes]
                        + ['supply_voltage'] * supply)
        columns = [run.time_s, run.temperature_c] + list(rate.T) + [run.supply_v] * supply
        writer.writerows(zip(*(c.tolist() for c in columns)))


def simulated_record(folder: Path, name: str, seed: int) -> dict:
    """Write the simulated chamber record ``name`` of ``seed`` as a CSV file."""
    path = folder / f'{name}_{seed}.csv'
    if name in SLOW_PERIODS:
        start_c, cycle_c = SLOW_PERIODS[name]
        profile = ThermalProfile.cycle(cycle_c, 0.08, start_c=start_c)
        runs = [chamber_run(Effects(), SLOW_NOISE, Scenario(thermal=profile), seed + 10 * k,
                            SLOW_NOISE.white_sigma_dps, 0.02, zro_dps=zro)
                for k, zro in enumerate(SLOW_ZRO_DPS)]
        rate = np.column_stack([r.rate_rad_s[:, 0] for r in runs])
        write_csv(path, runs[0], rate, supply=False)
        return {'path': path, 'name': f'{name} (seed {seed})', 'read': [], 'expected': '',
                'average_s': 60.0}
    effects, noise, expected = SIMULATED[name]
    scenario = Scenario(thermal=PROFILE, supply_times_s=SUPPLY_TIMES_S, supply_v=SUPPLY_V)
    run = chamber_run(effects, noise, scenario, seed, NOISE_DPS, 0.02, supply_noise_v=0.002)
    rate = run.rate_rad_s
    if name == 'turn_on_drift':
        since_s = run.time_s - run.time_s[0]
        rate = rate + TURN_ON_DRIFT_RAD_S * (1.0 - np.exp(-since_s / TURN_ON_TAU_S))[:, None]
    write_csv(path, run, rate, supply=True)
    return {'path': path, 'name': f'{name} (seed {seed})', 'read': [], 'expected': expected}


def binned_rms(time_s: np.ndarray, residual: np.ndarray, average_s: float) -> np.ndarray:
    """RMS per column of residual means over average_s bins from the first row, weighted."""
    index = np.floor((time_s - time_s[0]) / average_s).astype(np.int64)
    starts = np.flatnonzero(np.concatenate(([True], index[1:] != index[:-1])))
    counts = np.diff(np.append(starts, len(time_s))).astype(np.float64)
    means = np.add.reduceat(residual, starts, axis=0) / counts[:, None]
    return np.sqrt(np.sum(counts[:, None] * means ** 2, axis=0) / np.sum(counts))


def clamped_cubic(temperature_c: np.ndarray, error: np.ndarray, fit_rows: int) -> tuple:
    """PX4's cubic: np.polyfit on T - TREF of the first rows, run clamped; (residual, range)."""
    low, high = float(np.min(temperature_c[:fit_rows])), float(np.max(temperature_c[:fit_rows]))
    reference = 0.5 * (low + high)
    clamped = np.clip(temperature_c, low, high) - reference
    residual = np.empty_like(error)
    for axis in range(error.shape[1]):
        coefficients = np.polyfit(temperature_c[:fit_rows] - reference, error[:fit_rows, axis], 3)
        residual[:, axis] = error[:, axis] - np.polyval(coefficients, clamped)
    return residual, (low, high)


def written_effects(params: Path) -> dict:
    """Say what each axis of a params.yaml writes: its effects, or the model's name."""
    values = node_values(str(params), 'compensation_node')
    model = build_model(values)
    if values['model'] != 'effects':
        return {axis: values['model'] for axis in values['axes']}
    written = {}
    for axis, terms in zip(values['axes'], model.terms):
        order = len(terms.bias) - 1
        written[axis] = '+'.join([f'polynomial {order}'] + [
            effect for effect in terms.effects if effect != 'temperature_polynomial'])
    return written


def judge(record: dict, work: Path, test: float, average_s: float, extra: list) -> list:
    """Diagnose, evaluate the written file, judge it against the clamped cubic; rows per axis."""
    average_s = record.get('average_s', average_s)
    work.mkdir(parents=True)
    out = work / 'diagnose'
    run_cli(['diagnose', record['path'], *record['read'], '--test', test, '--average-s',
             average_s, '--out', out, *extra])
    corrected_csv = work / 'corrected.csv'
    run_cli(['evaluate', record['path'], *record['read'], '--params', out / 'params.yaml',
             '--test-fraction', test, '--out-csv', corrected_csv])
    options = {'preset': record['read'][1]} if record['read'][:1] == ['--preset'] else \
        {'columns': record['read'][1]} if record['read'][:1] == ['--columns'] else {}
    recording = load_recording(record['path'], **options)
    with corrected_csv.open(newline='') as stream:
        rows = list(csv.reader(stream))
    header, table = rows[0], np.array(rows[1:], dtype=np.float64)
    axes = tuple(name[len('gyro_'):] for name in header if name.startswith('gyro_'))
    corrected = table[:, [header.index(f'gyro_{a}') for a in axes]]
    columns = [recording.axes.index(a) for a in axes]
    truth = 0.0 if recording.reference_rad_s is None else recording.reference_rad_s[:, columns]
    error = recording.gyro_rad_s[:, columns] - truth
    first = len(error) - int(math.floor(test * len(error)))
    cubic, (low, high) = clamped_cubic(recording.temperature_c, error, first)
    held = slice(first, len(error))
    time_s = recording.time_s[held]
    written_rms = binned_rms(time_s, (corrected - truth)[held], average_s)
    cubic_rms = binned_rms(time_s, cubic[held], average_s)
    temperature = recording.temperature_c[held]
    outside = float(np.mean((temperature < low) | (temperature > high)))
    writes = written_effects(out / 'params.yaml')
    report = json.loads((out / 'report.json').read_text())['axes']
    return [{'record': record['name'], 'axis': axis,
             'gain': float(cubic_rms[k] / written_rms[k]),
             'written_rms_rad_s': float(written_rms[k]), 'cubic_rms_rad_s': float(cubic_rms[k]),
             'outside': outside, 'writes': writes[axis], 'expected': record.get('expected'),
             'named': named(report[axis]), 'average_s': average_s}
            for k, axis in enumerate(axes)]


def named(axis: dict) -> str:
    """Name the first effect the loop added to an axis, else its cause or a passing finding."""
    steps = axis['steps']
    if len(steps) > 1:
        return steps[1]['effect']
    found = axis['cause'] or next((f for f in axis['findings'] if f['passes']), None)
    if not found:
        return ''
    where = found['parameters'].get('time_s')
    return found['effect'] + ('' if where is None else f' at {where:.0f} s')


def print_table(title: str, rows: list) -> None:
    print(f'\n{title}')
    print(f'{"record":<28}{"axis":<5}{"gain":>7}{"outside":>9}  written   (rad/s, RMS of '
          'bin means: written / clamped cubic)')
    for row in rows:
        check = ''
        if row['expected'] is not None:
            found = row['named'].split(' ')[0]
            live = found not in ('', 'bias_step', 'time_drift')
            ok = found == row['expected'] if row['expected'] else not live
            check = f'  named {row["named"] or "nothing"}' + ('' if ok else ' MISS')
        print(f'{row["record"]:<28}{row["axis"]:<5}{row["gain"]:>6.2f}x{row["outside"]:>8.0%}  '
              f'{row["writes"]}  ({row["written_rms_rad_s"]:.3e} / {row["cubic_rms_rad_s"]:.3e})'
              f'{check}')
    gains = np.array([row['gain'] for row in rows])
    if gains.size:
        print(f'geometric mean {math.exp(np.mean(np.log(gains))):.2f}x, lowest {gains.min():.2f}x '
              f'over {gains.size} axis-cases')


# --compare: the validation schemes and row scorings diagnose can decide by.
CONFIGURATIONS = tuple((scheme, scoring) for scheme in ('forward', 'round-robin', 'purged')
                       for scoring in ('all', 'inside'))


def judge_all(records: list, folder: Path, args, extra: list) -> dict:
    """Judge every record with the extra diagnose options: rows per axis, real and simulated."""
    results = {'real': [], 'simulated': []}
    for index, record in enumerate(records):
        kind = 'simulated' if 'expected' in record else 'real'
        results[kind] += judge(record, folder / str(index), args.test, args.average_s, extra)
    return results


def geometric_mean(rows: list) -> float:
    return math.exp(float(np.mean(np.log([row['gain'] for row in rows])))) if rows else math.nan


def summary(results: dict) -> str:
    """One line: the real records' gains per axis, and the simulated records in three kinds."""
    real = ', '.join(f'{row["axis"]} {row["gain"]:.2f}' for row in results['real'])
    simulated = results['simulated']
    effects = [row for row in simulated if row['expected']]
    others = [row for row in simulated if row['expected'] == '']
    named = sum(row['named'].split(' ')[0] == row['expected'] for row in effects)
    live = sum(row['named'].split(' ')[0] not in ('', 'bias_step', 'time_drift')
               for row in others)
    lowest = min((row['gain'] for row in others), default=math.nan)
    return (f'{real or "-":<26} | {named}/{len(effects)} named, {geometric_mean(effects):5.2f}x '
            f'| {live}/{len(others)} live, lowest {lowest:.2f}x, '
            f'{geometric_mean(others):.3f}x')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--record', action='append', default=[], metavar='SPEC',
                        help='PATH[,preset=NAME][,columns=SPEC][,average_s=S] (repeatable)')
    parser.add_argument('--no-simulated', dest='simulated', action='store_false')
    parser.add_argument('--no-shared', dest='shared', action='store_false')
    parser.add_argument('--seeds', type=int, default=2)
    parser.add_argument('--test', type=float, default=TEST_FRACTION)
    parser.add_argument('--average-s', type=float, default=1.0)
    parser.add_argument('--diagnose-args', default='', help='extra diagnose options, quoted')
    parser.add_argument('--compare', action='store_true',
                        help='judge every record under each validation scheme and scoring '
                             '(--validation, --scoring) and print one line each')
    parser.add_argument('--json', metavar='FILE', help='also write every row as JSON')
    args = parser.parse_args()
    extra = shlex.split(args.diagnose_args)
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        records = (shared_records() if args.shared else []) + \
            [parse_record(r) for r in args.record]
        if args.simulated:
            records += [simulated_record(folder, name, seed)
                        for name in (*SIMULATED, *SLOW_PERIODS) for seed in range(args.seeds)]
        if args.compare:
            compared = {}
            print(f'{"validation":<13}{"scoring":<8} real (gain per axis)         | simulated '
                  'effects (named first, geometric mean) | clean, random walk, step, drift, '
                  'slow ramps (live added, lowest, geometric mean)')
            for scheme, scoring in CONFIGURATIONS:
                options = extra + ['--validation', scheme, '--scoring', scoring]
                compared[f'{scheme} {scoring}'] = judge_all(
                    records, folder / f'{scheme}-{scoring}', args, options)
                print(f'{scheme:<13}{scoring:<8}{summary(compared[f"{scheme} {scoring}"])}')
            results = compared
        else:
            results = judge_all(records, folder / 'judged', args, extra)
            print(f'diagnose --test {args.test:g} {args.diagnose_args}'.rstrip()
                  + ', then evaluate; gain = clamped cubic RMS / written RMS on the held-out '
                  'part')
            if results['real']:
                print_table('real records', results['real'])
            if results['simulated']:
                print_table('simulated records', results['simulated'])
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
