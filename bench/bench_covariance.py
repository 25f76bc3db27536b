"""
Is the covariance the node publishes true? Error over the published std, judged apart.

For each record: ``mlx-tempcomp diagnose REC --test F --out DIR`` writes
params.yaml from the first 1 - F of the rows (the model, the white noise of
each axis and its error by temperature, ``model_error.*``); ``mlx-tempcomp
evaluate REC --params DIR/params.yaml --out-csv`` runs it over the whole
record as the compensation node runs it and writes, per sample, the rate
and the standard deviation the node publishes with it (``std_*``: the square
root of the angular velocity covariance's diagonal); ``--track-bias`` does the
same with the node's bias tracking on (the tracked rate, and the noise plus
the tracked offset's variance).

The bench then judges the held-out rows (the last F) in plain numpy, apart
from the code it judges: the error is the rate less the truth (the reference
columns, else 0 at rest); per axis it prints the RMS of error / std per
sample (the target: between 0.7 and 1.5; above 1 the node is too
confident), and of each 60 s window's mean error over the std of such a mean
(the published variance less the noise, whole, plus the noise^2 over the
window's samples). It checks the ``std_*`` of the model run against the
standard deviation it computes itself from params.yaml (np.interp over the
table, held at its ends) and prints the largest relative difference.

Records: the measured thermal cycle (../shared, as the tests find it), and
with ``--simulated`` (default on) bench_real's simulated chamber records
(``--seeds`` seeds each), whose truth is known: one live effect each, a
clean one, a random walk, a bias step, a turn-on drift, three slow ramps.

    .venv/bin/python bench/bench_covariance.py [--no-simulated] [--seeds N] [--test F]
"""

import argparse
import csv
import math
from pathlib import Path
import sys
import tempfile

from bench_real import run_cli, SIMULATED, simulated_record, SLOW_PERIODS
from mlx_tempcomp.recordings.load import load_recording
import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))
from measured_data import MEASURED_CSV  # noqa: E402,I100

TARGET = (0.7, 1.5)
WINDOW_S = 60.0


def read_csv(path: Path) -> dict:
    """Give evaluate's --out-csv as columns of floats."""
    with path.open(newline='') as stream:
        rows = list(csv.reader(stream))
    table = np.array(rows[1:], dtype=np.float64)
    return {name: table[:, k] for k, name in enumerate(rows[0])}


def std_from_params(params: Path, axes: tuple, temperature_c: np.ndarray) -> tuple:
    """Give (the std the file publishes per sample, the noise per axis) in plain numpy."""
    values = yaml.safe_load(params.read_text())['compensation_node']['ros__parameters']
    table = values.get('model_error', {})
    noise = table.get('rate_noise_rad_s') or [values.get('rate_noise_rad_s', 0.0058)] * len(axes)
    columns = []
    for k, axis in enumerate(axes):
        error = np.interp(temperature_c, table['temperature_c'], table[f'{axis}_rad_s']) \
            if table.get('temperature_c') else 0.0
        columns.append(np.sqrt(noise[k] ** 2 + np.square(error)))
    return np.column_stack(columns), np.array(noise, dtype=np.float64)


def ratios(time_s: np.ndarray, error: np.ndarray, std: np.ndarray, noise: np.ndarray) -> tuple:
    """RMS per axis of error / std per sample, and of 60 s means over their own std."""
    per_sample = np.sqrt(np.mean(np.square(error / std), axis=0))
    index = np.floor((time_s - time_s[0]) / WINDOW_S).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
    rows = np.diff(np.append(starts, len(time_s))).astype(np.float64)[:, None]
    means = np.add.reduceat(error, starts, axis=0) / rows
    bias2 = np.add.reduceat(np.square(std) - noise ** 2, starts, axis=0) / rows
    spread2 = np.maximum(bias2, 0.0) + noise ** 2 / rows
    windows = np.sqrt(np.sum(rows * np.square(means) / spread2, axis=0) / np.sum(rows))
    return per_sample, windows


def judge(record: dict, work: Path, test: float) -> list:
    """Diagnose, evaluate the written file with and without tracking; rows per axis."""
    work.mkdir(parents=True)
    out = work / 'diagnose'
    run_cli(['diagnose', record['path'], *record['read'], '--test', test,
             '--average-s', record.get('average_s', 1.0), '--out', out])
    options = {'preset': record['read'][1]} if record['read'][:1] == ['--preset'] else {}
    recording = load_recording(record['path'], **options)
    first = len(recording) - int(math.floor(test * len(recording)))
    held = slice(first, len(recording))
    figures = {}
    for name, extra in (('model', []), ('tracked', ['--track-bias'])):
        path = work / f'{name}.csv'
        run_cli(['evaluate', record['path'], *record['read'], '--params', out / 'params.yaml',
                 '--test-fraction', test, '--out-csv', path, *extra])
        columns = read_csv(path)
        axes = tuple(key[len('std_'):] for key in columns if key.startswith('std_'))
        rate = np.column_stack([columns[f'gyro_{a}'] for a in axes])
        std = np.column_stack([columns[f'std_{a}'] for a in axes])
        truth = 0.0 if recording.reference_rad_s is None else \
            recording.reference_rad_s[:, [recording.axes.index(a) for a in axes]]
        mine, noise = std_from_params(out / 'params.yaml', axes, columns['temperature'])
        if name == 'model':
            figures['std_check'] = float(np.max(np.abs(std - mine) / mine))
        figures[name] = ratios(columns['time'][held], (rate - truth)[held], std[held], noise)
    return [{'record': record['name'], 'axis': axis,
             **{f'{name}_{kind}': float(figures[name][k][i]) for name in ('model', 'tracked')
                for k, kind in enumerate(('sample', 'window'))},
             'std_check': figures['std_check']} for i, axis in enumerate(axes)]


def verdict(value: float) -> str:
    return 'met' if TARGET[0] <= value <= TARGET[1] else \
        'too confident' if value > TARGET[1] else 'too cautious'


def print_table(title: str, rows: list) -> None:
    print(f'\n{title}')
    print(f'{"record":<28}{"axis":<5}{"model":>8}{"60 s":>7}{"tracked":>9}{"60 s":>7}'
          f'{"std check":>11}   model per sample vs {TARGET[0]} .. {TARGET[1]}')
    for row in rows:
        print(f'{row["record"]:<28}{row["axis"]:<5}{row["model_sample"]:>8.2f}'
              f'{row["model_window"]:>7.2f}{row["tracked_sample"]:>9.2f}'
              f'{row["tracked_window"]:>7.2f}{row["std_check"]:>11.1e}   '
              f'{verdict(row["model_sample"])}')
    met = sum(TARGET[0] <= row['model_sample'] <= TARGET[1] for row in rows)
    tracked = sum(TARGET[0] <= row['tracked_sample'] <= TARGET[1] for row in rows)
    print(f'per sample within {TARGET[0]} .. {TARGET[1]}: model {met} of {len(rows)} '
          f'axis-cases, tracked {tracked} of {len(rows)}')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--no-simulated', dest='simulated', action='store_false')
    parser.add_argument('--seeds', type=int, default=1)
    parser.add_argument('--test', type=float, default=0.25)
    args = parser.parse_args()
    print(f'diagnose --test {args.test:g}, then evaluate and evaluate --track-bias; error / '
          'published std on the held-out part, per sample and of 60 s means, from '
          "evaluate's CSV (1 = honest, above 1 = too confident)")
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        if MEASURED_CSV.is_file():
            measured = {'path': MEASURED_CSV, 'name': MEASURED_CSV.name,
                        'read': ['--preset', 'tofupilot']}
            print_table('measured record', judge(measured, folder / 'measured', args.test))
        else:
            print(f'note: {MEASURED_CSV} is missing: no measured record', file=sys.stderr)
        if args.simulated:
            rows = []
            for name in (*SIMULATED, *SLOW_PERIODS):
                for seed in range(args.seeds):
                    record = simulated_record(folder, name, seed)
                    rows += judge(record, folder / f'{name}_{seed}', args.test)
            print_table('simulated records (truth known)', rows)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
