"""What the fleet tests share: a unit's record, the CLI in-process, dask, a wait."""

import contextlib
import io
from pathlib import Path
import sys
import time

from mlx_tempcomp.cli import main
import numpy as np

ROWS = 600
SLOPE_RAD_S_PER_C = 2e-4
DASK = Path(sys.executable).with_name('dask')


def write_record(path: Path, seed: int, slope_factor: float = 1.0, noise_seed=None,
                 offset_rad_s: float = 0.0) -> str:
    """
    Write a CSV record of one gyro: two -20..70 C cycles, bias(T) of this unit, noise.

    ``seed`` draws the unit (and the noise, unless ``noise_seed`` draws it: another
    record of the same unit), ``offset_rad_s`` is added (a re-mount).
    """
    rng = np.random.default_rng(seed)
    noise = rng if noise_seed is None else np.random.default_rng(noise_seed)
    time_s = np.arange(ROWS) * 12.0
    phase = (2.0 * np.arange(ROWS) / ROWS) % 1.0
    temperature_c = 25.0 + 45.0 * (1.0 - 4.0 * np.abs(phase - 0.5)) + \
        noise.normal(0.0, 0.02, ROWS)
    slope = SLOPE_RAD_S_PER_C * slope_factor * (1.0 + 0.1 * rng.standard_normal())
    bias = 0.01 * (1.0 + 0.2 * rng.standard_normal()) + slope * (temperature_c - 25.0) + \
        2e-6 * (1.0 + 0.2 * rng.standard_normal()) * (temperature_c - 25.0) ** 2
    rate = bias + offset_rad_s + noise.normal(0.0, 5e-4, ROWS)
    np.savetxt(path, np.column_stack([time_s, temperature_c, rate]), delimiter=',',
               header='time,temperature,gyro_z', comments='', fmt='%.17g')
    return str(path)


def run_cli(argv: list) -> tuple:
    """Run mlx-tempcomp in this process; give (exit code, stdout, stderr)."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main([str(arg) for arg in argv])
    return code, stdout.getvalue(), stderr.getvalue()


def wait_for(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.1)
