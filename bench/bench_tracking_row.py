"""
Per-row cost of the bias tracker (`BiasTracking.process_one`) beside the model's own row.

The compensation node corrects one message at a time through the model's
``stream.correct_one`` when no other message waits (docs/ros.md, "Executors, queues and
blocks"); with bias tracking on it then passes the row to ``process_one``. Both are
built here from node parameters as the node builds them (`node_values`,
`build_model`, `tracking_settings`) and fed the same rows: 3 axes at 1 kHz, at rest
(windows close and learn every 5 s), temperature rising 1 C over the rows, with and without
an accelerometer. The baseline is the polynomial model's ``correct_one`` on those rows,
the node's model path; the tracker must stay a small part of the node's CPU per
message (bench/bench_node_latency.py: about 300 us of CPU per message at 1 kHz through
rclpy, so 10 % is about 30 us). A block of 500 rows (``process``, the node's burst
path) is timed per row too. Rounds alternate and the best of each is kept, because
this machine is noisy. The rows are checked to equal one block's.

    .venv/bin/python bench/bench_tracking_row.py [--rows N] [--repeats R]
"""

import argparse
import math
import os
import tempfile
import time

from mlx_tempcomp.core.standstill.bias_tracker import BiasTracking
from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.tracking import tracking_settings
import numpy as np
import yaml

AXES = ('x', 'y', 'z')
CUBIC = ((2.47e-3, -2.70e-3, 3.17e-3, 3.26e-4), (4.72e-3, 1.14e-2, 2.69e-3, -3.84e-3),
         (4.09e-3, -7.60e-3, -5.18e-4, -3.73e-3))
BLOCK = 500


def build(folder: str) -> tuple:
    """Give (values, model) from a parameter file, as the node reads one."""
    parameters = {'axes': list(AXES), 'model': 'polynomial', 'rate_noise_rad_s': 2e-3,
                  'polynomial': {'reference_temperature_c': 21.17, 'temperature_scale_c': 40.03,
                                 'bias': {a: list(c) for a, c in zip(AXES, CUBIC)}}}
    path = os.path.join(folder, 'parameters.yaml')
    with open(path, 'w', encoding='utf-8') as stream:
        yaml.safe_dump({'compensation_node': {'ros__parameters': parameters}}, stream)
    values = node_values(path, 'compensation_node')
    return values, build_model(values)


def rows(count: int) -> dict:
    rng = np.random.default_rng(0)
    time_s = 1000.0 + 1e-3 * np.arange(count)
    return {'time': time_s, 'rate': rng.normal(0.0, 2e-3, (count, 3)),
            'temperature': np.linspace(25.0, 26.0, count),
            'acceleration': np.array([0.1, -0.05, -9.8]) + rng.normal(0.0, 0.02, (count, 3))}


def model_rows(model, data) -> float:
    correct_one = model.stream().correct_one
    start = time.perf_counter()
    for rate, temperature in zip(data['rate_list'], data['temperature_list']):
        correct_one(rate, [temperature])
    return time.perf_counter() - start


def tracker_rows(settings, data, acceleration: bool) -> tuple:
    tracker = BiasTracking(settings, AXES)
    process_one = tracker.process_one
    accelerations = data['acceleration_list'] if acceleration else [None] * len(data['time'])
    start = time.perf_counter()
    out = [process_one(t, r, c, a) for t, r, c, a in zip(
        data['time_list'], data['rate_list'], data['temperature_list'], accelerations)]
    return time.perf_counter() - start, out, tracker


def tracker_blocks(settings, data, acceleration: bool) -> float:
    tracker = BiasTracking(settings, AXES)
    start = time.perf_counter()
    for first in range(0, len(data['time']), BLOCK):
        part = slice(first, first + BLOCK)
        tracker.process(data['time'][part], data['rate'][part], data['temperature'][part],
                        data['acceleration'][part] if acceleration else None)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--rows', type=int, default=30000)
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args()
    data = rows(args.rows)
    data.update({f'{k}_list': v.tolist() for k, v in list(data.items())})
    with tempfile.TemporaryDirectory() as folder:
        values, model = build(folder)
    settings = tracking_settings(values, AXES, values['rate_noise_rad_s'])
    names = ['model correct_one (baseline)', 'tracker process_one, accelerometer',
             'tracker process_one, none', f'tracker process, blocks of {BLOCK}']
    best = dict.fromkeys(names, math.inf)
    checks = {}
    for _ in range(args.repeats):
        best[names[0]] = min(best[names[0]], model_rows(model, data))
        for name, acceleration in ((names[1], True), (names[2], False)):
            seconds, out, tracker = tracker_rows(settings, data, acceleration)
            best[name] = min(best[name], seconds)
            block = BiasTracking(settings, AXES).process(
                data['time'], data['rate'], data['temperature'],
                data['acceleration'] if acceleration else None)
            checks[name] = (np.array_equal(block.rate_rad_s, [o[0] for o in out]) and
                            np.array_equal(block.still, [o[2] for o in out]),
                            tracker.window_count, tracker.updates)
        best[names[3]] = min(best[names[3]], tracker_blocks(settings, data, True))
    print(f'{args.rows} rows x {len(AXES)} axes at 1 kHz, best of {args.repeats} alternating '
          'rounds')
    print(f'  {"path":<38}{"us/row":>8}{"x model":>9}  rows = one block, windows, learnt')
    floor = best[names[0]]
    for name in names:
        check = ''
        if name in checks:
            same, windows, updates = checks[name]
            check = f'{"yes" if same else "NO"}, {windows}, {updates}'
        print(f'  {name:<38}{best[name] / args.rows * 1e6:8.2f}{best[name] / floor:9.2f}  '
              f'{check}')


if __name__ == '__main__':
    main()
