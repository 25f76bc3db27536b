"""
Field learning against the truth: the renewed model, the stale one and tracking alone.

Every figure comes from the real command line (``mlx-tempcomp inject-motion``, ``fit``,
``evaluate --out-csv`` with ``--track-bias`` and ``--learn``) and is computed here, in
plain numpy from the CSVs, against the ``ref`` columns the injection wrote: the RMS of
the 60 s means of (corrected - ref) over the last quarter of the record, per axis (what
matters for heading drift), each beside its baselines from the same run.

- **The measured cycle** with the ``cycle`` schedule injected (seed 1): ``fit`` on the
  whole record (the baseline), tracking alone on that fit, learning on it (target: never
  below 0.95x of tracking alone on any axis); and starting from nothing: a zero-order
  polynomial fitted on the record's first rest alone (the ZRO a ``imu/recalibrate_zro``
  at power-up gives, and the noise figures of that rest), the prior's error and the
  tracker's initial offset and mean-rate bound set to 1 deg/s (a datasheet's bias over
  temperature: with no model, a slower mean about gravity cannot be told from the bias),
  learning from there (target: within 1.1x of ``fit`` on the whole record, per axis), and
  beside it the same with the bound ``fit`` derived (0.1 deg/s).
- **Simulated days**: units of the simulated sensor (``mlx-tempcomp simulate``, three
  MLX90609 chips, 25 Hz, a 0-50 C cycle at 3 C/min, g-sensitivity 0.005 deg/s per m/s^2)
  on day 1 (``fit`` at rest, as a calibration) and day 2 (``--day 2``: repeatability,
  ageing, a turn onto another face; the ``cycle`` schedule injected): the stale day-1
  model, tracking alone, learning (targets: at least 2x over the stale model, geometric
  mean per unit; never below 0.95x of tracking alone on any axis).
- **Day pairs given** (``--pair DAY1 DAY2``, with ``--preset`` or ``--columns``): run
  exactly as the simulated pairs (targets: at least 1.5x over the stale model, geometric
  mean of every axis of every pair; none below 0.95x of tracking alone).
- **Size**: the learner's state (the dict a state file holds, as JSON) after each day of
  a simulated week of still windows and turns, beside the tracker's: flat.

    .venv/bin/python bench/bench_learning.py [--pair DAY1 DAY2 ...] [--preset NAME |
        --columns SPEC] [--units N] [--keep DIR] [--no-simulated] [--no-week]

The measured cycle is looked up as the tests do (MLX_TEMPCOMP_SHARED, else ../shared).
"""

import argparse
from concurrent.futures import ThreadPoolExecutor
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile

import numpy as np
import yaml

CLI = str(Path(sys.executable).with_name('mlx-tempcomp'))
ROOT = Path(__file__).resolve().parents[1]
MEASURED = Path('data') / 'tofupilot_imu_thermal_sweep' / 'imu_raw_data.csv'
AVERAGE_S, LAST = 60.0, 0.25
NOTHING_STD_RAD_S = math.radians(1.0)
SIM = ['--duration-s', 3500, '--rate-hz', 25, '--cycle-c', 50, 0, 50, 0, '--ramp-c-per-min', 3,
       '--acceleration-dps-per-m-s2', 0.005, 0.005, 0.005]
FIT_TARGET, TRACKING_TARGET, SIM_TARGET, REAL_TARGET = 1.1, 0.95, 2.0, 1.5


def cli(*args) -> str:
    result = subprocess.run([CLI, *map(str, args)], capture_output=True, text=True,
                            check=False)
    if result.returncode:
        sys.exit(f'mlx-tempcomp {" ".join(map(str, args))} failed:\n{result.stderr}')
    return result.stdout


def read(path) -> dict:
    table = np.genfromtxt(path, delimiter=',', names=True)
    return {name: table[name] for name in table.dtype.names}


def error(truth: dict, corrected: dict, axes: tuple) -> np.ndarray:
    """Give the RMS of the 60 s means of corrected - ref over the last quarter, per axis."""
    time_s = truth['time']
    assert np.array_equal(time_s, corrected['time'])
    start = time_s.size - int(round(LAST * time_s.size))
    values = np.column_stack([corrected[f'gyro_{a}'] - truth[f'ref_{a}'] for a in axes])[start:]
    index = np.floor((time_s[start:] - time_s[start]) / AVERAGE_S).astype(int)
    counts = np.bincount(index)
    kept = counts > 0
    means = np.column_stack([np.bincount(index, values[:, i])[kept] / counts[kept]
                             for i in range(len(axes))])
    return np.sqrt(np.mean(means * means, axis=0))


def axes_of(params: Path) -> tuple:
    return tuple(yaml.safe_load(params.read_text())['compensation_node']['ros__parameters']
                 ['axes'])


def evaluate(folder: Path, name: str, moving: Path, params: Path, *options) -> np.ndarray:
    """Give the error of ``evaluate`` plain, with --track-bias, or with --learn too."""
    out = folder / f'{name}.csv'
    cli('evaluate', moving, '--params', params, *options, '--out-csv', out)
    return error(read(moving), read(out), axes_of(params))


def three(folder: Path, name: str, moving: Path, params: Path) -> dict:
    """Give the errors of the model alone, tracking alone and learning (two at a time)."""
    runs = {'model': (), 'tracking': ('--track-bias',),
            'learning': ('--track-bias', '--learn', '--learned-params',
                         folder / f'{name}_learned.yaml')}
    with ThreadPoolExecutor(2) as pool:
        futures = {key: pool.submit(evaluate, folder, f'{name}_{key}', moving, params, *opts)
                   for key, opts in runs.items()}
    return {key: future.result() for key, future in futures.items()}


def line(label: str, values, unit: str = '') -> str:
    return f'    {label:<28}' + ''.join(f'{v:>11.3e}' for v in values) + unit


def verdict(met: bool) -> str:
    return 'met' if met else 'NOT met'


def first_rest(moving: Path, folder: Path) -> Path:
    """Write the record's first rest (until its reference first moves) as a CSV of its own."""
    table = read(moving)
    moving_rows = np.flatnonzero(np.any(np.column_stack(
        [table[k] for k in table if k.startswith('ref_')]) != 0.0, axis=1))
    end = int(moving_rows[0]) if moving_rows.size else table['time'].size
    text = moving.read_text().splitlines()
    out = folder / 'first_rest.csv'
    out.write_text('\n'.join(text[:end + 1]) + '\n')
    return out


def nothing_params(folder: Path, moving: Path, bound_rad_s=None) -> Path:
    """
    Give 'from nothing': a zero-order polynomial on the first rest, 1 deg/s of error.

    ``bound_rad_s``: the tracker's mean-rate bound raised to it (None: as fit derived it).
    """
    params = folder / f'nothing{"" if bound_rad_s is None else "_bound"}.yaml'
    cli('fit', first_rest(moving, folder), '--order', 0, '--out', params)
    document = yaml.safe_load(params.read_text())
    values = document['compensation_node']['ros__parameters']
    values['bias_tracking']['initial_std_rad_s'] = [NOTHING_STD_RAD_S]
    if bound_rad_s is not None:
        values['bias_tracking']['max_mean_rate_rad_s'] = bound_rad_s
    values['learning'] = {'prior_std_rad_s': [NOTHING_STD_RAD_S]}
    params.write_text(yaml.safe_dump(document, sort_keys=False))
    return params


def turns_taken(moving: Path, learnt_csv: Path, params: Path) -> tuple:
    """Give the windows learnt while the reference turned, and the largest mean turn there."""
    truth, out = read(moving), read(learnt_csv)
    axes = axes_of(params)
    window_s = yaml.safe_load(params.read_text())['compensation_node']['ros__parameters'][
        'bias_tracking']['window_s']
    reference = np.column_stack([truth[f'ref_{a}'] for a in axes])
    learnt = np.column_stack([out[f'learnt_{a}'] for a in axes]) > 0.5
    window = np.floor((truth['time'] - truth['time'][0]) / window_s).astype(int)
    count, largest = 0, 0.0
    for index in np.unique(window[learnt.any(axis=1)]):
        rows = window == index
        means = np.where(learnt[rows].any(axis=0), np.abs(reference[rows].mean(axis=0)), 0.0)
        means[means < 1e-9] = 0.0       # a tilt turned back leaves float dust
        count += bool(np.any(means > 0.0))
        largest = max(largest, float(np.max(means)))
    return count, largest


def measured(folder: Path, shared: Path) -> None:
    moving = folder / 'cycle_moving.csv'
    cli('inject-motion', shared / MEASURED, '--preset', 'tofupilot', '--out', moving,
        '--seed', 1)
    params = folder / 'cycle_fit.yaml'
    cli('fit', moving, '--out', params)
    axes = axes_of(params)
    fitted = three(folder, 'cycle_fit', moving, params)
    nothing = nothing_params(folder, moving, NOTHING_STD_RAD_S)
    start = three(folder, 'cycle_nothing', moving, nothing)
    held = three(folder, 'cycle_held', moving, nothing_params(folder, moving))
    print(f'measured cycle, cycle schedule (seed 1): RMS of {AVERAGE_S:g} s means over the last '
          'quarter, rad/s')
    print(f'    {"":<28}' + ''.join(f'{a:>11}' for a in axes))
    print(line('fit on the whole record', fitted['model']))
    print(line('  + tracking alone', fitted['tracking']))
    print(line('  + learning', fitted['learning']))
    print(line('from nothing: the first rest', start['model']))
    print(line('  + tracking alone', start['tracking']))
    print(line('  + learning', start['learning']))
    print(line('  at 0.1 deg/s: tracking', held['tracking']))
    print(line('  at 0.1 deg/s: learning', held['learning']))
    ratio = start['learning'] / fitted['model']
    print(f'  target from nothing within {FIT_TARGET}x of fit on the whole record, every axis: '
          f'{verdict(bool(np.all(ratio <= FIT_TARGET)))} ('
          + ', '.join(f'{a} {r:.2f}x' for a, r in zip(axes, ratio))
          + '; against fit + tracking: '
          + ', '.join(f'{a} {r:.2f}x' for a, r in
                      zip(axes, start['learning'] / fitted['tracking'])) + ')')
    count, largest = turns_taken(moving, folder / 'cycle_nothing_learning.csv', nothing)
    ratio = held['learning'] / fitted['model']
    print(f'  from nothing the mean-rate bound is the prior error, 1 deg/s: the tracker '
          f'learnt from {count} windows while the reference turned, the largest mean turn there '
          f'{largest:.2e} rad/s; with the bound fit derives on the first rest (0.1 deg/s) it '
          'holds every axis from the second rest on: '
          + ', '.join(f'{a} {r:.2f}x' for a, r in zip(axes, ratio)) + ' of fit')
    gain = fitted['tracking'] / fitted['learning']
    print(f'  target from its fit never below {TRACKING_TARGET}x of tracking alone: '
          f'{verdict(bool(np.all(gain >= TRACKING_TARGET)))} ('
          + ', '.join(f'{a} {g:.2f}x' for a, g in zip(axes, gain)) + ')')


def pair(folder: Path, name: str, day1: list, day2: list) -> dict:
    """Fit day 1, inject motion into day 2, run the three; give the errors and the axes."""
    params = folder / f'{name}_day1.yaml'
    cli('fit', *day1, '--out', params)
    moving = folder / f'{name}_day2_moving.csv'
    cli('inject-motion', *day2, '--out', moving, '--seed', 1)
    return {'axes': axes_of(params), **three(folder, name, moving, params)}


def print_pairs(title: str, results: list, target: float, per_pair: bool) -> None:
    print(title)
    gains, against = [], []
    for name, result in results:
        axes = result['axes']
        stale = result['model'] / result['learning']
        alone = result['tracking'] / result['learning']
        gains += list(stale)
        against += list(alone)
        print(f'  {name}: RMS of {AVERAGE_S:g} s means over the last quarter, rad/s')
        print(f'    {"":<28}' + ''.join(f'{a:>11}' for a in axes))
        for key, label in (('model', 'stale day-1 model'), ('tracking', 'tracking alone'),
                           ('learning', 'learning')):
            print(line(label, result[key]))
        mean = float(np.exp(np.mean(np.log(stale))))
        print('    over the stale model: '
              + ', '.join(f'{a} {g:.2f}x' for a, g in zip(axes, stale))
              + f' (geometric mean {mean:.2f}x); over tracking alone: '
              + ', '.join(f'{a} {g:.2f}x' for a, g in zip(axes, alone)))
        if per_pair:
            print(f'    target >= {target}x over the stale model (geometric mean): '
                  f'{verdict(mean >= target)}')
    mean = float(np.exp(np.mean(np.log(gains))))
    if not per_pair:
        print(f'  target >= {target}x over the stale model, geometric mean of '
              f'{len(gains)} axis-cases: {verdict(mean >= target)} ({mean:.2f}x)')
    low = min(against)
    print(f'  target never below {TRACKING_TARGET}x of tracking alone: '
          f'{verdict(low >= TRACKING_TARGET)} (lowest {low:.2f}x; geometric mean over the '
          f'stale model {mean:.2f}x)')


def simulated(folder: Path, units: int) -> None:
    def simulate(seed: int, day: int) -> Path:
        out = folder / f'unit{seed}_day{day}.csv'
        cli('simulate', '--out', out, *SIM, '--seed', seed, '--day', day)
        return out

    jobs = [(seed, day) for seed in range(1, units + 1) for day in (1, 2)]
    with ThreadPoolExecutor(2) as pool:
        paths = dict(zip(jobs, pool.map(lambda job: simulate(*job), jobs)))
    results = []
    for seed in range(1, units + 1):
        truth = json.loads(paths[(seed, 2)].with_name(f'unit{seed}_day2.truth.json')
                           .read_text())['day']
        name = f'unit {seed} (day 2 on the face {truth["face_up_m_s2"]} m/s^2 up)'
        results.append((name, pair(folder, f'unit{seed}', [paths[(seed, 1)]],
                                   [paths[(seed, 2)]])))
    print_pairs(f'simulated days: {units} units of three simulated MLX90609 chips, fit on day 1 '
                'at rest, day 2 with the cycle schedule', results, SIM_TARGET, per_pair=True)


def real_pairs(folder: Path, pairs: list, given: list) -> None:
    results = []
    for index, (day1, day2) in enumerate(pairs):
        result = pair(folder, f'pair{index}', [day1, *given], [day2, *given])
        results.append((f'{day1} -> {day2}', result))
    print_pairs(f'day pairs given ({len(pairs)}), fit on day 1, day 2 with the cycle schedule',
                results, REAL_TARGET, per_pair=False)


def week() -> None:
    """Run tracking and learning over a simulated week; print the state sizes each day."""
    sys.path.insert(0, str(ROOT))
    from mlx_tempcomp.core.standstill.bias_tracker import BiasTracking, TrackingSettings
    from mlx_tempcomp.core.learning import LearningTracking
    from mlx_tempcomp.core.standstill.detector import StandstillSettings
    from mlx_tempcomp.parameters.learning import learning_settings
    rate_hz, axes = 2.0, ('x', 'y', 'z')
    tracking = TrackingSettings(StandstillSettings(rate_noise_rad_s=(2e-4,) * 3,
                                                   random_walk_rad_s_rt_s=(1e-6,),
                                                   window_s=5.0), initial_std_rad_s=(2e-3,))
    stream, _ = LearningTracking.start(BiasTracking(tracking, axes),
                                       learning_settings({}, tracking))
    rng = np.random.default_rng(7)
    sizes = []
    for day in range(7):
        time_s = day * 86400.0 + np.arange(int(86400 * rate_hz)) / rate_hz
        temperature = 25.0 + 15.0 * np.sin(2.0 * math.pi * time_s / 86400.0)
        rate = 1e-3 * ((temperature - 25.0) / 15.0)[:, None] ** 2 + \
            2e-4 * rng.standard_normal((time_s.size, 3))
        # Turns of 30 s every 5 min, still between.
        turning = (time_s % 300.0) < 30.0
        rate[turning] += 0.3
        stream.process(time_s, rate, temperature)
        state = stream.learner.state()
        sizes.append((numbers(state), len(json.dumps(state))))
    learner = stream.learner
    print(f'size: a simulated week at {rate_hz:g} Hz ({learner.windows} windows learnt, '
          f'{learner.runs_committed} still runs): the learner state, numbers (JSON bytes), '
          'day by day: ' + ', '.join(f'{n} ({b})' for n, b in sizes)
          + f'; the tracker state {numbers(stream.tracker.state())}; flat: '
          f'{verdict(len({n for n, _ in sizes}) == 1)}')


def numbers(value) -> int:
    """Count the numbers a state holds (its size, whatever their digits)."""
    if isinstance(value, dict):
        return sum(numbers(v) for v in value.values())
    if isinstance(value, list):
        return sum(numbers(v) for v in value)
    return int(isinstance(value, (int, float)) and not isinstance(value, bool))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--pair', nargs=2, action='append', default=[], metavar=('DAY1', 'DAY2'),
                        help='a record of a unit at rest on one day and one of the next day')
    columns = parser.add_mutually_exclusive_group()
    columns.add_argument('--preset')
    columns.add_argument('--columns')
    parser.add_argument('--units', type=int, default=3, help='simulated units (default: 3)')
    parser.add_argument('--keep', help='keep the files in this folder')
    parser.add_argument('--no-simulated', action='store_true')
    parser.add_argument('--no-week', action='store_true')
    args = parser.parse_args()
    shared = Path(os.environ.get('MLX_TEMPCOMP_SHARED', ROOT.parent / 'shared'))
    given = ['--preset', args.preset] if args.preset else \
        ['--columns', args.columns] if args.columns else []
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.keep or scratch)
        folder.mkdir(exist_ok=True)
        if (shared / MEASURED).exists():
            measured(folder, shared)
        else:
            print(f'measured cycle not found at {shared / MEASURED}: skipped')
        if not args.no_simulated:
            simulated(folder, args.units)
        if args.pair:
            real_pairs(folder, args.pair, given)
        if not args.no_week:
            week()


if __name__ == '__main__':
    main()
