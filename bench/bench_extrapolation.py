"""
Beyond the fitted range: clamped at the edge (the node, PX4, ArduPilot) or continued linearly.

On the measured thermal cycle (the diagnosed part of ``diagnose --test 0.25``,
forward validation over 20 blocks: each block from the sixth on predicted by
a polynomial fitted on the blocks before it), every fold's polynomial of each
order is run on its held-out block twice: clamped at its training range, as
the ``polynomial`` model runs it (the baseline), and continued along its tangent at
the nearer edge. Printed per order and axis: the held-out RMS of the residual
averaged over 1 s bins, over every predicted block and over the blocks that lie
outside their training range, for both. docs/ros.md ("Beyond the fitted
temperature range") quotes it.

    .venv/bin/python bench/bench_extrapolation.py [--csv PATH]
"""

import argparse
import os
from pathlib import Path
import sys

from mlx_tempcomp.core.fitting.bias_polynomial import fit_polynomial
from mlx_tempcomp.core.fitting.validation import block_bounds, split
from mlx_tempcomp.core.series.metrics import bin_means, bin_starts, test_start_row
from mlx_tempcomp.recordings.load import load_recording
import numpy as np

RELATIVE = Path('data') / 'tofupilot_imu_thermal_sweep' / 'imu_raw_data.csv'
BLOCKS = 20
AVERAGE_S = 1.0
ORDERS = (1, 2, 3, 4)


def default_csv() -> Path:
    shared = os.environ.get('MLX_TEMPCOMP_SHARED')
    root = Path(shared) if shared else Path(__file__).resolve().parents[2] / 'shared'
    return root / RELATIVE


def continued(model, temperature_c: np.ndarray) -> np.ndarray:
    """Bias of each axis continued along the tangent at the nearer edge of the range."""
    edge_c = np.clip(temperature_c, model.temperature_min_c, model.temperature_max_c)
    x_edge = (edge_c - model.reference_temperature_c) / model.temperature_scale_c
    step = (temperature_c - edge_c) / model.temperature_scale_c
    poly = np.polynomial.polynomial
    return np.column_stack([poly.polyval(x_edge, c) + step * poly.polyval(x_edge, poly.polyder(c))
                            for c in (term.bias for term in model.terms)])


def binned_squares(time_s, residual) -> tuple:
    """Sum of count-weighted squared 1 s bin means per axis, and the rows."""
    means, counts = bin_means(residual, bin_starts(time_s, AVERAGE_S))
    return np.sum(counts[:, None] * means ** 2, axis=0), float(np.sum(counts))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--csv', type=Path, default=default_csv(),
                        help='the measured cycle (default: %(default)s)')
    args = parser.parse_args()
    if not args.csv.is_file():
        print(f'skipped: measured cycle not found at {args.csv} (give --csv or '
              'MLX_TEMPCOMP_SHARED)')
        return 0
    recording = load_recording(args.csv, preset='tofupilot')
    rows = test_start_row(len(recording.time_s), 0.25)
    time_s = recording.time_s[:rows]
    temperature_c = recording.temperature_c[:rows]
    rate_rad_s = recording.gyro_rad_s[:rows]
    bounds = block_bounds(rows, BLOCKS)
    dealt = split(BLOCKS)
    print(f'{args.csv}: {rows} rows diagnosed, {dealt.describe()}; held-out RMS of 1 s bins, '
          'rad/s')
    print('all: every predicted block; beyond: the blocks reaching outside the range of the '
          'blocks before them')
    print(f'{"order":<6}{"axis":<5}{"clamp, all":>12}{"linear, all":>13}{"clamp, beyond":>15}'
          f'{"linear, beyond":>16}{"rows beyond":>13}')
    for order in ORDERS:
        totals = {key: np.zeros(len(recording.axes)) for key in
                  ('clamp', 'linear', 'clamp_beyond', 'linear_beyond')}
        counted = {'all': 0.0, 'beyond': 0.0}
        for training, held in zip(dealt.training, dealt.held):
            train = np.concatenate([np.arange(bounds[b], bounds[b + 1])
                                    for b in np.flatnonzero(training)])
            model = fit_polynomial(temperature_c[train], rate_rad_s[train], order)
            (block,) = np.flatnonzero(held)
            part = slice(bounds[block], bounds[block + 1])
            clamp = model.correct(rate_rad_s[part], temperature_c[part])
            linear = rate_rad_s[part] - continued(model, temperature_c[part])
            beyond = bool(clamp.temperature_clamped.any())
            for key, residual in (('clamp', clamp.rate_rad_s), ('linear', linear)):
                squares, count = binned_squares(time_s[part], residual)
                totals[key] += squares
                if beyond:
                    totals[f'{key}_beyond'] += squares
            counted['all'] += count
            counted['beyond'] += count if beyond else 0.0
        for axis, name in enumerate(recording.axes):
            figures = [np.sqrt(totals[key][axis] / counted[scope]) for key, scope in
                       (('clamp', 'all'), ('linear', 'all'), ('clamp_beyond', 'beyond'),
                        ('linear_beyond', 'beyond'))]
            print(f'{order:<6}{name:<5}{figures[0]:>12.3e}{figures[1]:>13.3e}{figures[2]:>15.3e}'
                  f'{figures[3]:>16.3e}{int(counted["beyond"]):>13}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
