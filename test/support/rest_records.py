"""
A record at rest for the bias-tracking tests: a cubic in T, a wandering offset, noise, gravity.

Shared by the toolkit's tests (toolkit/test_tracking.py) and the node's (ros/test_tracking.py),
which inject the same motion into it; `offset_record` adds an offset the fit never saw.
"""

import math
from pathlib import Path

import numpy as np

NOISE = 1e-3


def rest_record(path: Path, duration_s: float = 1500.0, rate_hz: float = 10.0,
                seed: int = 0) -> str:
    """Write a record at rest: a cubic in T, a wandering offset, noise, gravity on -z."""
    rng = np.random.default_rng(seed)
    time_s = 100.0 + np.arange(0.0, duration_s, 1.0 / rate_hz)
    temperature = 30.0 + 10.0 * np.sin(2.0 * np.pi * (time_s - 100.0) / duration_s)
    x = (temperature - 30.0) / 10.0
    wander = np.cumsum(rng.normal(0.0, 5e-5 / math.sqrt(rate_hz), (time_s.size, 3)), axis=0)
    gyro = 0.01 * x[:, None] ** np.arange(1, 4) + wander + rng.normal(0, NOISE, wander.shape)
    acceleration = np.array([0.1, -0.05, -9.8]) + rng.normal(0.0, 0.005, (time_s.size, 3))
    columns = {'time': time_s, 'temperature': temperature,
               **{f'gyro_{a}': gyro[:, i] for i, a in enumerate('xyz')},
               **{f'acc_{a}': acceleration[:, i] for i, a in enumerate('xyz')}}
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',',
               header=','.join(columns), comments='', fmt='%.17g')
    return str(path)


def offset_record(source, target, offset_rad_s: float) -> str:
    """Copy a CSV record with ``offset_rad_s`` added to its gyro columns (after the fit)."""
    table = np.genfromtxt(source, delimiter=',', names=True)
    names = table.dtype.names
    data = np.column_stack([table[n] + (offset_rad_s if n.startswith('gyro_') else 0.0)
                            for n in names])
    np.savetxt(target, data, delimiter=',', header=','.join(names), comments='', fmt='%.17g')
    return str(target)


def bowl_record(path, hours: float = 5.0, rate_hz: float = 2.0) -> str:
    """Write a record at rest: a bowl in T cycling 0 to 50 C every two hours, noise, gravity."""
    rng = np.random.default_rng(11)
    time_s = np.arange(0.0, hours * 3600.0, 1.0 / rate_hz)
    temperature = 25.0 - 25.0 * np.cos(2.0 * math.pi * time_s / 7200.0)
    bowl = 1.5e-3 * ((temperature - 25.0) / 25.0) ** 2
    gyro = bowl[:, None] * (1.0, -0.5, 0.8) + 2e-4 * rng.standard_normal((time_s.size, 3))
    acceleration = np.array([0.05, -0.02, -9.8]) + 0.003 * rng.standard_normal((time_s.size, 3))
    columns = {'time': time_s, 'temperature': temperature,
               **{f'gyro_{a}': gyro[:, i] for i, a in enumerate('xyz')},
               **{f'acc_{a}': acceleration[:, i] for i, a in enumerate('xyz')}}
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',',
               header=','.join(columns), comments='', fmt='%.17g')
    return str(path)
