"""
Field learning's memory over a simulated week, beside tracking alone in the same run.

The node's stream (`core.learning.LearningTracking`: the `BiasTracking` with its
`FieldLearner`) and the tracker alone run over the same week of simulated sensor time, a
day at a time: 2 Hz, the temperature cycling 0 to 50 C twice a day, a bowl in temperature
the prior model does not hold, rests of 90 s every 5 min between turns. After each day the
Python heap each holds (tracemalloc, what the objects the stream keeps take once the day's
arrays are gone) and the numbers in the learner's state (what the state file holds) are
printed. Target (issue 31): flat, the learner's state the same size every day, its heap no
larger on day 7 than on day 1.

    .venv/bin/python bench/bench_learning_memory.py [--days 7] [--rate-hz 2]
"""

import argparse
import gc
import math
import tracemalloc

from mlx_tempcomp.core.learning import LearningTracking
from mlx_tempcomp.core.standstill.bias_tracker import BiasTracking, TrackingSettings
from mlx_tempcomp.core.standstill.detector import StandstillSettings
from mlx_tempcomp.parameters.learning import learning_settings
import numpy as np

AXES = ('x', 'y', 'z')
NOISE = 1e-3
DAY_S = 86400.0


def tracking() -> TrackingSettings:
    standstill = StandstillSettings(rate_noise_rad_s=(NOISE,) * 3,
                                    random_walk_rad_s_rt_s=(1e-6,), window_s=5.0,
                                    max_temperature_rate_c_s=0.05)
    return TrackingSettings(standstill, initial_std_rad_s=(1e-3,))


def day(index: int, rate_hz: float) -> tuple:
    """Give (time, rate, temperature) of day ``index``: rests of 90 s every 5 min, turns."""
    rng = np.random.default_rng(index)
    time_s = index * DAY_S + np.arange(0.0, DAY_S, 1.0 / rate_hz)
    temperature = 25.0 - 25.0 * np.cos(2.0 * math.pi * time_s / (DAY_S / 2.0))
    bowl = 2e-3 * ((temperature - 25.0) / 25.0) ** 2
    rate = bowl[:, None] * (1.0, -0.5, 0.8) + rng.normal(0.0, NOISE, (time_s.size, 3))
    moving = (time_s % 300.0) >= 90.0
    rate[moving, 2] += 0.3 * np.sin(2.0 * math.pi * time_s[moving] / 60.0)
    return time_s, rate, temperature


def heap_bytes() -> int:
    """Give the traced heap once the garbage is collected."""
    gc.collect()
    return tracemalloc.get_traced_memory()[0]


def numbers(value) -> int:
    if isinstance(value, dict):
        return sum(numbers(v) for v in value.values())
    if isinstance(value, list):
        return sum(numbers(v) for v in value)
    return int(isinstance(value, (int, float)) and not isinstance(value, bool))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--days', type=int, default=7)
    parser.add_argument('--rate-hz', type=float, default=2.0)
    args = parser.parse_args()
    settings = tracking()
    learning = learning_settings({}, settings)
    tracemalloc.start()
    gc.collect()
    base, _ = tracemalloc.get_traced_memory()
    alone = BiasTracking(settings, AXES)
    after_tracker, _ = tracemalloc.get_traced_memory()
    stream, _ = LearningTracking.start(BiasTracking(settings, AXES), learning)
    gc.collect()
    after_stream, _ = tracemalloc.get_traced_memory()
    print(f'simulated week at {args.rate_hz:g} Hz: heap of the objects kept (tracemalloc, '
          'after each day, its arrays gone), tracking alone beside tracking with learning')
    print(f'at start: tracking alone {after_tracker - base} B, with learning '
          f'{after_stream - after_tracker} B')
    print(f'{"day":>3} {"samples":>9} {"windows":>8} {"used":>6} {"renewals":>9} '
          f'{"state numbers":>13} {"heap kB (both)":>14}')
    heaps, sizes = [], []
    for index in range(args.days):
        time_s, rate, temperature = day(index, args.rate_hz)
        alone.process(time_s, rate, temperature)
        stream.process(time_s, rate, temperature)
        samples = time_s.size
        del time_s, rate, temperature
        heap = heap_bytes() - base
        heaps.append(heap)
        sizes.append(numbers(stream.learner.state()))
        learner = stream.learner
        print(f'{index + 1:>3} {samples:>9} {stream.tracker.window_count:>8} '
              f'{learner.windows:>6} {sum(learner.renewals):>9} {sizes[-1]:>13} '
              f'{heap / 1024:>14.1f}', flush=True)
    tracemalloc.stop()
    flat = len(set(sizes)) == 1 and heaps[-1] <= heaps[0] * 1.05
    print(f'state numbers day 1 {sizes[0]}, day {args.days} {sizes[-1]}; heap day 1 '
          f'{heaps[0] / 1024:.1f} kB, day {args.days} {heaps[-1] / 1024:.1f} kB '
          f'(target: flat, the state the same size and the heap within 5 % of day 1: '
          f'{"met" if flat else "NOT met"})')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
