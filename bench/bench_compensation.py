"""
Core EEPROM compensation throughput beside a plain numpy.polyval baseline.

Both compute Q = (OUTAR - ZRO(T)) / SF(T) with the same quadratics (AN2
formulas (3)-(10)) on the same 10^7 samples; the baseline is what a user
would write with numpy.polyval. Runs alternate and the best of each is kept,
because this machine is noisy. Target: ratio >= 1 (not slower than polyval).

    .venv/bin/python bench/bench_compensation.py [--samples N] [--repeats R]
"""

import argparse
import time

from mlx_tempcomp.core.mlx90609.conversion import Output
from mlx_tempcomp.core.mlx90609.eeprom import EepromFields
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.core.mlx90609.interpolation import quadratic_coefficients
from mlx_tempcomp.core.mlx90609.table_compensation import table_compensation
import numpy as np


def polyval_baseline(zro_poly, sf_poly, outar, tempout) -> np.ndarray:
    return (outar - np.polyval(zro_poly, tempout)) / np.polyval(sf_poly, tempout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--samples', type=int, default=10_000_000)
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args()

    fields = EepromFields(range_code=15, version=2, tc_mv=(1854, 2508, 3114),
                          ee_zro=(132, 133, 145), ee_sf=(120, 145, 133))
    table = factory_table(fields, Output.DIGITAL)
    compensation = table_compensation([table], fields.full_scale_dps, Output.DIGITAL)
    zro_poly = quadratic_coefficients(table.tc, table.zro)
    sf_poly = quadratic_coefficients(table.tc, table.sf)

    rng = np.random.default_rng(0)
    # Inside [TC0, TC2], so clamping changes nothing and both compute the same numbers.
    tempout = rng.uniform(table.tc[0], table.tc[2], args.samples)
    outar = rng.uniform(100.0, 1900.0, args.samples)

    ours = compensation.compensate(outar, tempout).rate_dps
    baseline = polyval_baseline(zro_poly, sf_poly, outar, tempout)
    max_difference = float(np.max(np.abs(ours - baseline)))

    best = {'mlx_tempcomp': float('inf'), 'numpy.polyval': float('inf')}
    for _ in range(args.repeats):
        start = time.perf_counter()
        compensation.compensate(outar, tempout)
        best['mlx_tempcomp'] = min(best['mlx_tempcomp'], time.perf_counter() - start)
        start = time.perf_counter()
        polyval_baseline(zro_poly, sf_poly, outar, tempout)
        best['numpy.polyval'] = min(best['numpy.polyval'], time.perf_counter() - start)

    print(f'EEPROM quadratic compensation, {args.samples:.0e} samples, '
          f'best of {args.repeats} alternating runs')
    for name, seconds in best.items():
        print(f'  {name:<14} {args.samples / seconds / 1e6:8.1f} M samples/s '
              f'({seconds * 1e3:7.1f} ms)')
    ratio = best['numpy.polyval'] / best['mlx_tempcomp']
    print(f'  ratio mlx_tempcomp / polyval throughput: {ratio:.2f}x '
          f'(target >= 1.00: {"met" if ratio >= 1.0 else "NOT met"})')
    print(f'  max |difference| between the two: {max_difference:.2e} deg/s')


if __name__ == '__main__':
    main()
