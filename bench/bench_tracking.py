"""
Bias tracking against the truth: known motion injected into records at rest.

For each record (the measured cycle, and any given with its --preset or --columns), the
real command line: ``mlx-tempcomp inject-motion --schedule cycle`` (still 30 % of the
time, a 90 s rest every 5 min, turns about every axis between), ``fit`` (the params the
targets are judged on), ``evaluate --out-csv`` without and with ``--track-bias``. The
error is computed here, in plain numpy from those CSVs, against the ``ref`` columns the
injection wrote: corrected - ref per sample. Per axis:

- gain: RMS without tracking / RMS with (target >= 1.5 on every axis of the measured
  cycle);
- worst moving segment: the largest RMS with / RMS without over the runs of samples
  whose reference is not zero (target <= 1.1), beside the same figure for an oracle that
  re-zeroes on the last 10 s of each true rest (the baseline: what the drift between
  rests does to that figure even with no turn absorbed);
- learnt in motion: over each window the tracker learnt from (the ``learnt_*`` columns,
  cut on its window grid: the first sample's time plus whole ``bias_tracking.window_s``),
  the largest mean reference rate on a learnt axis, beside the slowest turn (0.2 deg/s):
  a turn it took would show here at its full rate;
- still share found by the tracker against the true one.

Then rest hints (issue 30): the measured cycle with +0.3 deg/s added to every gyro column
after the fit (here, in plain numpy: a supply's shift or a mounting stress the model never
saw), ``evaluate --out-csv`` without tracking, with ``--track-bias`` alone and with
``--track-bias --rest-hint rest_hint`` (the schedule's truth, which inject-motion writes, as
a robot's odometry would say it), beside the oracle: per axis the RMS error and its gain
over no tracking (target with the hint >= 3x on every axis), and the largest mean
reference rate over a window learnt from with the hint (a turn taken would show).

Then the simulated sensor (``mlx-tempcomp simulate``: three MLX90609 chips through the
SPI path, no accelerometer, a bias random walk and a bias step inside a rest of a
``mixed`` schedule): the same figures on 10 s means (its white noise would hide the
bias per sample), and how many still windows the tracker needed to follow the step.

    .venv/bin/python bench/bench_tracking.py [RECORD --preset NAME | --columns SPEC ...]
        [--seed N] [--keep DIR]

The measured cycle is looked up as the tests do (MLX_TEMPCOMP_SHARED, else ../shared).
"""

import argparse
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
SLOWEST_TURN_RAD_S = math.radians(0.2)
GAIN_TARGET, SEGMENT_TARGET = 1.5, 1.1
ORACLE_S = 10.0
# The hinted case: an offset the model never saw, beyond the tracker's 0.1 deg/s bound.
HINT_OFFSET_DPS, HINT_GAIN_TARGET = 0.3, 3.0
# The simulated sensor: a 3-axis MLX90609 array, its noise as a 100 Hz mean of the
# driver's 1 kHz samples (0.3 x the datasheet's per sample), a bias random walk and a
# step inside a rest.
SIM_SECONDS, SIM_RATE_HZ, SIM_SEED, SIM_SCHEDULE_SEED = 3600.0, 25.0, 3, 2
SIM_STEP_DPS, SIM_WALK_DPS_RT_S = 0.06, 0.001


def cli(*args) -> str:
    result = subprocess.run([CLI, *map(str, args)], capture_output=True, text=True,
                            check=False)
    if result.returncode:
        sys.exit(f'mlx-tempcomp {" ".join(map(str, args))} failed:\n{result.stderr}')
    return result.stdout


def read(path) -> dict:
    table = np.genfromtxt(path, delimiter=',', names=True)
    return {name: table[name] for name in table.dtype.names}


def runs(mask: np.ndarray) -> list:
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2], edges[1::2]))


def rms(values: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.square(values), axis=0))


def bin_means(time_s: np.ndarray, values: np.ndarray, average_s: float) -> np.ndarray:
    if not average_s:
        return values
    index = np.floor((time_s - time_s[0]) / average_s).astype(int)
    counts = np.bincount(index)
    keep = counts > 0
    return np.column_stack([np.bincount(index, values[:, i])[keep] / counts[keep]
                            for i in range(values.shape[1])])


def oracle(time_s: np.ndarray, error: np.ndarray, still: np.ndarray) -> np.ndarray:
    """Re-zero on the last ORACLE_S of each true rest, from the rest's end on."""
    offset = np.zeros_like(error)
    for start, end in runs(still):
        last = (time_s >= time_s[end - 1] - ORACLE_S) & (np.arange(time_s.size) >= start) & \
            (np.arange(time_s.size) < end)
        offset[end:] = error[last].mean(axis=0)
    return error - offset


def learnt_reference(time_s: np.ndarray, reference: np.ndarray, learnt: np.ndarray,
                     window_s: float) -> tuple:
    """Give the largest mean reference per axis over a learnt window, and such windows."""
    window = np.floor((time_s - time_s[0]) / window_s).astype(int)
    largest, count = np.zeros(reference.shape[1]), 0
    for index in np.unique(window[learnt.any(axis=1)]):
        rows = window == index
        means = np.where(learnt[rows].any(axis=0), np.abs(reference[rows].mean(axis=0)), 0.0)
        means[means < 1e-9] = 0.0      # a turn's axis, turned back, leaves float dust
        largest = np.maximum(largest, means)
        count += bool(np.any(means > 0.0))
    return largest, count


def judge(injected: Path, without_csv: Path, with_csv: Path, axes: tuple, window_s: float,
          average_s: float = 0.0) -> dict:
    """Compute the figures of one record from the CSVs alone (see the module notes)."""
    truth, plain, tracked = read(injected), read(without_csv), read(with_csv)
    time_s = truth['time']
    assert np.array_equal(time_s, plain['time']) and np.array_equal(time_s, tracked['time'])
    reference = np.column_stack([truth[f'ref_{a}'] for a in axes])
    without = np.column_stack([plain[f'gyro_{a}'] for a in axes]) - reference
    with_ = np.column_stack([tracked[f'gyro_{a}'] for a in axes]) - reference
    learnt = np.column_stack([tracked[f'learnt_{a}'] for a in axes]) > 0.5
    moving = np.any(reference != 0.0, axis=1)
    baseline = oracle(time_s, without, ~moving)
    segments = [(a, b) for a, b in runs(moving) if b - a > 1]
    ratio = np.array([rms(with_[a:b]) / rms(without[a:b]) for a, b in segments])
    oracle_ratio = np.array([rms(baseline[a:b]) / rms(without[a:b]) for a, b in segments])
    means = [bin_means(time_s, e, average_s) for e in (without, with_, baseline)]
    absorbed, learnt_moving = learnt_reference(time_s, reference, learnt, window_s)
    return {'axes': axes, 'rows': time_s.size, 'segments': len(segments),
            'rms_without': rms(means[0]), 'rms_with': rms(means[1]),
            'gain': rms(means[0]) / rms(means[1]), 'oracle_gain': rms(means[0]) / rms(means[2]),
            'worst_segment': ratio.max(axis=0), 'oracle_worst_segment': oracle_ratio.max(axis=0),
            'segments_over': (ratio > SEGMENT_TARGET).sum(axis=0),
            'oracle_segments_over': (oracle_ratio > SEGMENT_TARGET).sum(axis=0),
            'absorbed': absorbed, 'learnt_moving': learnt_moving,
            'still_found': float(np.mean(tracked['still'])),
            'still_true': float(np.mean(~moving)), 'time_s': time_s, 'error_with': with_}


def with_offset(source: Path, target: Path, offset_rad_s: float) -> None:
    """Write ``source`` (a CSV) with ``offset_rad_s`` added to its gyro columns."""
    table = np.genfromtxt(source, delimiter=',', names=True)
    names = table.dtype.names
    data = np.column_stack([table[n] + (offset_rad_s if n.startswith('gyro_') else 0.0)
                            for n in names])
    np.savetxt(target, data, delimiter=',', header=','.join(names), comments='', fmt='%.17g')


def hinted(folder: Path, name: str, axes: tuple, window_s: float) -> dict:
    """Evaluate the record of `pipeline`, the offset added, four ways (module notes)."""
    source = folder / f'{name}_moving.csv'
    offset = folder / f'{name}_offset.csv'
    with_offset(source, offset, math.radians(HINT_OFFSET_DPS))
    params = folder / f'{name}_params.yaml'
    outputs = {case: folder / f'{name}_offset_{case}.csv'
               for case in ('none', 'alone', 'hint')}
    cli('evaluate', offset, '--params', params, '--out-csv', outputs['none'])
    cli('evaluate', offset, '--params', params, '--track-bias', '--out-csv', outputs['alone'])
    cli('evaluate', offset, '--params', params, '--track-bias', '--rest-hint', 'rest_hint',
        '--out-csv', outputs['hint'])
    truth = read(offset)
    reference = np.column_stack([truth[f'ref_{a}'] for a in axes])
    errors = {case: np.column_stack([read(path)[f'gyro_{a}'] for a in axes]) - reference
              for case, path in outputs.items()}
    moving = np.any(reference != 0.0, axis=1)
    errors['oracle'] = oracle(truth['time'], errors['none'], ~moving)
    learnt = np.column_stack([read(outputs['hint'])[f'learnt_{a}'] for a in axes]) > 0.5
    absorbed, windows = learnt_reference(truth['time'], reference, learnt, window_s)
    return {'axes': axes, 'rms': {case: rms(e) for case, e in errors.items()},
            'absorbed': absorbed, 'learnt_moving': windows,
            'at_rest': float(np.mean(truth['rest_hint']))}


def print_hinted(name: str, figures: dict) -> None:
    rms_of = figures['rms']
    print(f'{name}, +{HINT_OFFSET_DPS} deg/s on every axis after the fit (rest hint: at rest '
          f'{100 * figures["at_rest"]:.1f} % of the samples): RMS rad/s per sample, gain over '
          'no tracking')
    print(f'  {"axis":<5}{"no tracking":>12}{"tracking":>11}{"gain":>7}{"with hint":>11}'
          f'{"gain":>7}{"oracle":>11}{"gain":>7}')
    for i, a in enumerate(figures['axes']):
        none = rms_of['none'][i]
        print(f'  {a:<5}{none:>12.3e}' + ''.join(
            f'{rms_of[case][i]:>11.3e}{none / rms_of[case][i]:>7.2f}'
            for case in ('alone', 'hint', 'oracle')))
    gains = rms_of['none'] / rms_of['hint']
    print(f'  target with the hint >= {HINT_GAIN_TARGET:g}x over no tracking on every axis: '
          f'{"met" if gains.min() >= HINT_GAIN_TARGET else "NOT met"} (lowest '
          f'{gains.min():.2f}; the oracle {min(rms_of["none"] / rms_of["oracle"]):.2f})')
    largest = max(figures['absorbed'])
    print(f'  with the hint, windows learnt from while the reference moved on a learnt axis: '
          f'{figures["learnt_moving"]}; the largest mean reference rate there {largest:.2e} '
          f'rad/s ({100 * largest / SLOWEST_TURN_RAD_S:.1f} % of the slowest turn)')


def pipeline(folder: Path, name: str, record_args: list, schedule: str, seed: int,
             average_s: float = 0.0) -> tuple:
    """Inject, fit, evaluate without and with tracking; give the figures and the params."""
    injected = folder / f'{name}_moving.csv'
    cli('inject-motion', *record_args, '--schedule', schedule, '--seed', seed, '--out',
        injected)
    params = folder / f'{name}_params.yaml'
    cli('fit', injected, '--out', params)
    parameters = yaml.safe_load(params.read_text())['compensation_node']['ros__parameters']
    plain, tracked = folder / f'{name}_without.csv', folder / f'{name}_with.csv'
    cli('evaluate', injected, '--params', params, '--out-csv', plain)
    cli('evaluate', injected, '--params', params, '--track-bias', '--out-csv', tracked)
    return judge(injected, plain, tracked, tuple(parameters['axes']),
                 parameters['bias_tracking']['window_s'], average_s), parameters


def print_figures(name: str, figures: dict, gain_target: bool) -> None:
    axes = figures['axes']
    print(f'{name}: {figures["rows"]} samples, {figures["segments"]} moving segments; still '
          f'found {100 * figures["still_found"]:.1f} % (true {100 * figures["still_true"]:.1f}'
          ' %)')
    print(f'  {"axis":<5}{"RMS without":>12}{"RMS with":>11}{"gain":>7}{"oracle":>8}'
          f'{"worst seg":>11}{"oracle":>8}{"segs>1.1":>10}{"oracle":>8}{"learnt ref":>12}')
    for i, a in enumerate(axes):
        print(f'  {a:<5}{figures["rms_without"][i]:>12.3e}{figures["rms_with"][i]:>11.3e}'
              f'{figures["gain"][i]:>7.2f}{figures["oracle_gain"][i]:>8.2f}'
              f'{figures["worst_segment"][i]:>11.2f}{figures["oracle_worst_segment"][i]:>8.2f}'
              f'{figures["segments_over"][i]:>10d}{figures["oracle_segments_over"][i]:>8d}'
              f'{figures["absorbed"][i]:>12.2e}')
    if gain_target:
        low = min(figures['gain'])
        print(f'  target gain >= {GAIN_TARGET} on every axis: '
              f'{"met" if low >= GAIN_TARGET else "NOT met"} (lowest {low:.2f})')
    worst = max(figures['worst_segment'])
    print(f'  target worst moving segment <= {SEGMENT_TARGET}: '
          f'{"met" if worst <= SEGMENT_TARGET else "NOT met"} ({worst:.2f}; the oracle '
          f'{max(figures["oracle_worst_segment"]):.2f})')
    largest = max(figures['absorbed'])
    print(f'  windows learnt from while the reference moved on a learnt axis: '
          f'{figures["learnt_moving"]}; the largest mean reference rate there {largest:.2e} '
          f'rad/s ({100 * largest / SLOWEST_TURN_RAD_S:.1f} % of the slowest turn, 0.2 deg/s)')


def step_windows(figures: dict, step_s: float, rest_end_s: float, window_s: float,
                 step_rad_s: float) -> int:
    """Give the first window from the step on whose mean error is under a fifth of it."""
    time_s, error = figures['time_s'], figures['error_with']
    start = step_s
    count = 0
    while start + window_s <= rest_end_s:
        rows = (time_s >= start) & (time_s < start + window_s)
        if np.all(np.abs(error[rows].mean(axis=0)) < 0.2 * step_rad_s):
            return count
        count += 1
        start += window_s
    return -1


def simulated(folder: Path) -> None:
    sys.path.insert(0, str(ROOT))
    from mlx_tempcomp.simulation.motion import motion_schedule, ScheduleSettings
    schedule = motion_schedule(SIM_SECONDS + 1e-9, ScheduleSettings.mixed(), SIM_SCHEDULE_SEED)
    start, end = next((a, b) for a, b in schedule.rests() if b - a > 150.0)
    step_s = start + 62.5
    rest = folder / 'sim_rest.csv'
    cli('simulate', '--out', rest, '--duration-s', SIM_SECONDS, '--rate-hz', SIM_RATE_HZ,
        '--cycle-c', 40, 10, 35, '--ramp-c-per-min', 2, '--seed', SIM_SEED,
        '--noise-scale', 0.3, '--bias-random-walk-dps-rt-s', SIM_WALK_DPS_RT_S,
        '--bias-step', f'{step_s}:{SIM_STEP_DPS}')
    figures, parameters = pipeline(folder, 'sim', [rest], 'mixed', SIM_SCHEDULE_SEED,
                                   average_s=10.0)
    print_figures(f'simulated MLX90609 x3 ({SIM_SECONDS:g} s at {SIM_RATE_HZ:g} Hz, mixed '
                  'schedule, 10 s means)', figures, gain_target=False)
    window_s = parameters['bias_tracking']['window_s']
    windows = step_windows(figures, step_s, end, window_s, math.radians(SIM_STEP_DPS))
    # The window holding the step cannot learn it; the two still windows after it must:
    # from three windows after the step on, the error is under a fifth of it.
    met = 'met' if 0 <= windows <= 3 else 'NOT met'
    print(f'  bias step of {SIM_STEP_DPS} deg/s at {step_s:g} s, {step_s - start:g} s into a '
          f'rest of {end - start:.0f} s: the error of {window_s:g} s windows from the step on '
          f"is under a fifth of it from window {windows} (target: the step's window and two "
          f'still windows, <= 3: {met})')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('records', nargs='*', help='more records at rest')
    columns = parser.add_mutually_exclusive_group()
    columns.add_argument('--preset')
    columns.add_argument('--columns')
    parser.add_argument('--seed', type=int, default=1, help='schedule seed (default: 1)')
    parser.add_argument('--keep', help='keep the files in this folder')
    parser.add_argument('--no-simulated', action='store_true')
    args = parser.parse_args()
    shared = Path(os.environ.get('MLX_TEMPCOMP_SHARED', ROOT.parent / 'shared'))
    records = []
    if (shared / MEASURED).exists():
        records.append(('measured cycle', [shared / MEASURED, '--preset', 'tofupilot']))
    else:
        print(f'measured cycle not found at {shared / MEASURED}: skipped')
    for path in args.records:
        given = ['--preset', args.preset] if args.preset else \
            ['--columns', args.columns] if args.columns else []
        records.append((str(path), [path, *given]))
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.keep or scratch)
        folder.mkdir(exist_ok=True)
        for index, (name, record_args) in enumerate(records):
            figures, parameters = pipeline(folder, f'record{index}', record_args, 'cycle',
                                           args.seed)
            print_figures(f'{name} (cycle schedule, seed {args.seed}, per sample)', figures,
                          gain_target=True)
            print_hinted(name, hinted(folder, f'record{index}', tuple(parameters['axes']),
                                      parameters['bias_tracking']['window_s']))
        if not args.no_simulated:
            simulated(folder)


if __name__ == '__main__':
    main()
