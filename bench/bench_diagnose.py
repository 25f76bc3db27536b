"""
Wall time and peak memory of ``fit`` and ``diagnose`` beside a PX4-style cubic polyfit.

The data: a seeded synthetic 3-axis gyro at rest, sampled at --rate-hz
(10^7 samples at 100 Hz are 27.8 h). A climatic chamber cycles between
-20 and 70 C (1 C/min ramps, 30 min dwells, 4 h per cycle); the die follows
it as a first-order lag (tau 300 s, computed at 1 Hz by a loop, then
linearly interpolated) plus 3 C of self-heating, and the temperature
reading adds 0.02 C of white noise. Each axis has a cubic bias in the die
temperature; x adds a hysteresis (play operator of half width 2 C,
+-0.06 deg/s), y a +0.05 deg/s bias step at 60% of the record, z nothing
more; all add 0.2 deg/s of white noise (an MLX90609 density of 0.03 deg/s/rtHz
over 50 Hz).

The parent generates the data once and saves it as .npy files. Each job
runs in its own fresh interpreter, which loads all the columns (time,
temperature, gyro), then resets its peak RSS (Linux /proc/self/clear_refs)
and runs the job alone, timed: ``cubic`` is np.polyfit(T, rate, 3) per
axis, what PX4's script does (best of --repeats); ``fit`` is what
``mlx-tempcomp fit`` does (select_orders with its defaults, then
fit_polynomial); ``diagnose`` is core.diagnosis.diagnose with the default
settings on a Recording of the data (live-runnable effects; the bias step
on y can only show as a record-only finding). Peak RSS (VmHWM) therefore counts
the resident data plus what the job allocates, not the transient copies of
loading. Targets (issue 4): diagnose within 20x the cubic's time; peak
memory under 2 GB.

    .venv/bin/python bench/bench_diagnose.py [--samples N] [--rate-hz F] [--seed S]
"""

import argparse
import json
import math
from pathlib import Path
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

JOBS = ('cubic', 'fit', 'diagnose')
COLUMNS = ('time_s', 'temperature_c', 'gyro_rad_s')
TARGET_RATIO = 20.0
TARGET_PEAK_MB = 2048.0
MB = 1024.0 * 1024.0

# The synthetic sensor (see the module docstring).
CHAMBER_LOW_C, CHAMBER_HIGH_C = -20.0, 70.0
RAMP_S = 90.0 * 60.0
DWELL_S = 30.0 * 60.0
START_C = 25.0
DIE_TAU_S = 300.0
SELF_HEATING_C = 3.0
TEMPERATURE_NOISE_C = 0.02
# Cubic bias per axis in deg/s, powers of x = (T_die - 25) / 45.
BIAS_DPS = ((0.3, 0.8, -0.25, 0.15), (-0.2, -0.5, 0.3, 0.1), (0.1, 0.4, 0.2, -0.2))
HYSTERESIS_HALF_WIDTH_C = 2.0
HYSTERESIS_DPS = 0.06
STEP_FRACTION = 0.6
STEP_DPS = 0.05
NOISE_DPS = 0.2


def generate(samples: int, rate_hz: float, seed: int) -> dict:
    """Return the columns of the synthetic recording (see the module docstring)."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(samples) / rate_hz
    coarse_s = np.arange(0.0, time_s[-1] + 2.0)
    period_s = 2.0 * (RAMP_S + DWELL_S)
    chamber_c = np.interp(coarse_s % period_s,
                          (0.0, RAMP_S, RAMP_S + DWELL_S, 2.0 * RAMP_S + DWELL_S, period_s),
                          (CHAMBER_LOW_C, CHAMBER_HIGH_C, CHAMBER_HIGH_C, CHAMBER_LOW_C,
                           CHAMBER_LOW_C))
    die_c = np.empty_like(chamber_c)
    played_c = np.empty_like(chamber_c)
    die, played = START_C, START_C + SELF_HEATING_C
    alpha = 1.0 - math.exp(-1.0 / DIE_TAU_S)
    width = HYSTERESIS_HALF_WIDTH_C
    for index, target in enumerate(chamber_c):
        die += alpha * (target - die)
        die_c[index] = die + SELF_HEATING_C
        played = min(max(played, die_c[index] - width), die_c[index] + width)
        played_c[index] = played
    die_c = np.interp(time_s, coarse_s, die_c)
    state = (die_c - np.interp(time_s, coarse_s, played_c)) / width
    x = (die_c - 25.0) / 45.0
    gyro_dps = rng.standard_normal((samples, 3)) * NOISE_DPS
    for axis, coefficients in enumerate(BIAS_DPS):
        gyro_dps[:, axis] += np.polynomial.polynomial.polyval(x, coefficients)
    gyro_dps[:, 0] += HYSTERESIS_DPS * state
    gyro_dps[time_s >= STEP_FRACTION * time_s[-1], 1] += STEP_DPS
    temperature_c = die_c + rng.standard_normal(samples) * TEMPERATURE_NOISE_C
    return {'time_s': time_s, 'temperature_c': temperature_c,
            'gyro_rad_s': np.radians(gyro_dps, out=gyro_dps)}


def _status_mb(field: str) -> float:
    """Return a memory figure of /proc/self/status (Linux, in kB there) in MB."""
    for line in Path('/proc/self/status').read_text().splitlines():
        if line.startswith(f'{field}:'):
            return float(line.split()[1]) / 1024.0
    msg = f'/proc/self/status has no {field}'
    raise RuntimeError(msg)


def _rss_mb() -> float:
    return _status_mb('VmRSS')


def _peak_mb() -> float:
    # VmHWM, not ru_maxrss: a child's ru_maxrss starts at its parent's RSS at the
    # fork (the kernel keeps it across exec), and clear_refs does not reset it.
    return _status_mb('VmHWM')


def _cpu_s() -> float:
    """Return the CPU time of this process, all threads, user and system."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _cubic(data: dict, repeats: int) -> tuple:
    best, best_cpu = math.inf, math.inf
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), _cpu_s()
        for axis in range(data['gyro_rad_s'].shape[1]):
            np.polyfit(data['temperature_c'], data['gyro_rad_s'][:, axis], 3)
        if time.perf_counter() - start < best:
            best, best_cpu = time.perf_counter() - start, _cpu_s() - start_cpu
    return best, {'cpu_s': best_cpu}


def _fit(data: dict, max_order: int, blocks: int) -> tuple:
    from mlx_tempcomp.core.fitting.bias_polynomial import fit_polynomial, select_orders
    start, start_cpu = time.perf_counter(), _cpu_s()
    selections = select_orders(data['temperature_c'], data['gyro_rad_s'], axes=('x', 'y', 'z'),
                               candidate_orders=range(max_order + 1), blocks=blocks)
    fit_polynomial(data['temperature_c'], data['gyro_rad_s'],
                   tuple(selection.order for selection in selections))
    seconds, cpu_s = time.perf_counter() - start, _cpu_s() - start_cpu
    return seconds, {'cpu_s': cpu_s, 'orders': [selection.order for selection in selections]}


def _diagnose(data: dict) -> tuple:
    from mlx_tempcomp.core.diagnosis import diagnose, DiagnosisSettings
    from mlx_tempcomp.recordings.recording import Recording
    recording = Recording(source='bench', time_s=data['time_s'],
                          temperature_c=data['temperature_c'], axes=('x', 'y', 'z'),
                          gyro_rad_s=data['gyro_rad_s'])
    # The Recording holds copies; drop the loaded arrays so the data is resident once.
    data.clear()
    _reset_peak()
    start, start_cpu = time.perf_counter(), _cpu_s()
    diagnosis = diagnose(recording, DiagnosisSettings())
    seconds, cpu_s = time.perf_counter() - start, _cpu_s() - start_cpu
    found = {axis.axis: [{'effect': step.effect, 'rms_before_dps': math.degrees(
        step.before.rms_rad_s), 'rms_after_dps': math.degrees(step.after.rms_rad_s),
        'parameters': _brief(step.parameters)} for step in axis.steps]
        for axis in diagnosis.per_axis}
    # Record-only effects (time drift, bias steps) tested on top, reported, not added.
    findings = {axis.axis: [{'effect': f.effect, 'gain': f.held_out_gain,
                             'parameters': _brief(f.parameters)}
                            for f in axis.findings if not f.reason]
                for axis in diagnosis.per_axis}
    # What each axis writes, and the record effect named the cause, if any.
    written = {axis.axis: {'model': axis.choice.written, 'ratio': axis.choice.ratio,
                           'cause': axis.cause and axis.cause.effect}
               for axis in diagnosis.per_axis}
    return seconds, {'cpu_s': cpu_s, 'found': found, 'findings': findings, 'written': written}


def _brief(parameters) -> str:
    """Return the scalar parameters of a step as short text."""
    return ', '.join(f'{name} {value:.4g}' for name, value in parameters.items()
                     if isinstance(value, (int, float)))


def _reset_peak() -> bool:
    """Reset this process's peak RSS to its current RSS (Linux 4.0+); False if refused."""
    try:
        Path('/proc/self/clear_refs').write_text('5')
    except OSError:
        return False
    return True


def child(args: argparse.Namespace) -> None:
    """Run one job on the saved data and print its figures as one JSON line."""
    data = {name: np.load(Path(args.data) / f'{name}.npy') for name in COLUMNS}
    loading_mb = _peak_mb()
    reset = _reset_peak()
    start_mb = _rss_mb()
    if args.child == 'cubic':
        seconds, extra = _cubic(data, args.repeats)
    elif args.child == 'fit':
        seconds, extra = _fit(data, args.max_order, args.blocks)
    else:
        seconds, extra = _diagnose(data)
    print(json.dumps({'seconds': seconds, 'start_mb': start_mb, 'peak_mb': _peak_mb(),
                      'loading_mb': loading_mb, 'reset': reset, **extra}))


def _run_job(job: str, args: argparse.Namespace, data_dir: str) -> dict:
    command = [sys.executable, __file__, '--child', job, '--data', data_dir,
               '--repeats', str(args.repeats), '--max-order', str(args.max_order),
               '--blocks', str(args.blocks)]
    print(f'  running {job} ...', flush=True)
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode:
        sys.exit(f'{job} failed (exit {done.returncode}):\n{done.stderr}')
    return json.loads(done.stdout.strip().splitlines()[-1])


def _verdict(ok: bool) -> str:
    return 'met' if ok else 'NOT met'


def report(args: argparse.Namespace, data_mb: float, results: dict) -> None:
    """Print the table, the targets and what fit and diagnose found."""
    cubic_s = results['cubic']['seconds']
    rows = [(job, results[job]['seconds'], results[job]['cpu_s'], results[job]['start_mb'],
             results[job]['peak_mb']) for job in JOBS]
    rows.append(('fit + diagnose', *(results['fit'][key] + results['diagnose'][key]
                                     for key in ('seconds', 'cpu_s')),
                 math.nan, max(results['fit']['peak_mb'], results['diagnose']['peak_mb'])))
    print(f'\n{args.samples:.0e} samples x 3 axes at {args.rate_hz:g} Hz '
          f'({args.samples / args.rate_hz / 3600.0:.1f} h); data {data_mb:.0f} MiB '
          '(time, temperature, gyro in float64); each job in a fresh process')
    print(f'  {"job":<15}{"wall s":>9}{"x cubic":>9}{"CPU s":>9}{"RSS at start MiB":>18}'
          f'{"peak RSS MiB":>14}{"added MiB":>11}')
    for job, seconds, cpu_s, start_mb, peak_mb in rows:
        start_text = '' if math.isnan(start_mb) else f'{start_mb:.0f}'
        added_text = '' if math.isnan(start_mb) else f'{peak_mb - start_mb:.0f}'
        print(f'  {job:<15}{seconds:9.2f}{seconds / cubic_s:9.1f}{cpu_s:9.2f}{start_text:>18}'
              f'{peak_mb:14.0f}{added_text:>11}')
    print(f'  cubic: best of {args.repeats}; fit and diagnose: one run each. RSS at start: '
          'interpreter, numpy and the loaded data')
    if not all(result['reset'] for result in results.values()):
        print('  peak RSS could not be reset after loading: peaks include loading')
    loading = ', '.join(f'{job} {results[job]["loading_mb"]:.0f} MiB' for job in JOBS)
    print(f'  peak while loading (np.load, not counted above): {loading}; diagnose also '
          'copies the data into a Recording before its peak is reset')
    diagnose_ratio = results['diagnose']['seconds'] / cubic_s
    both_ratio = rows[-1][1] / cubic_s
    cpu_ratios = [row[2] / results['cubic']['cpu_s'] for row in (rows[2], rows[3])]
    peak_mb = max(results[job]['peak_mb'] for job in JOBS)
    print(f'  target diagnose <= {TARGET_RATIO:g}x cubic: {diagnose_ratio:.1f}x, '
          f'{_verdict(diagnose_ratio <= TARGET_RATIO)} (CPU time {cpu_ratios[0]:.1f}x)')
    print(f'  target fit + diagnose <= {TARGET_RATIO:g}x cubic: {both_ratio:.1f}x, '
          f'{_verdict(both_ratio <= TARGET_RATIO)} (CPU time {cpu_ratios[1]:.1f}x)')
    print(f'  target peak RSS < {TARGET_PEAK_MB:.0f} MiB in every job: {peak_mb:.0f} MiB, '
          f'{_verdict(peak_mb < TARGET_PEAK_MB)}')
    print(f'\nfit: orders chosen {results["fit"]["orders"]} (x, y, z; the data has cubic biases) '
          f'from 0..{args.max_order} over {args.blocks} blocks (the fit defaults)')
    print('diagnose, per axis (held-out RMS of 1 s bin means, deg/s); injected: x hysteresis '
          f'half width {HYSTERESIS_HALF_WIDTH_C:g} C, {HYSTERESIS_DPS:g} deg/s; y bias step '
          f'{STEP_DPS:g} deg/s at {STEP_FRACTION * args.samples / args.rate_hz:.0f} s; z none')
    for axis, steps in results['diagnose']['found'].items():
        for step in steps:
            print(f'  {axis}  {step["effect"]:<24}{step["rms_before_dps"]:9.4f} -> '
                  f'{step["rms_after_dps"]:.4f}  ({step["parameters"]})')
        for finding in results['diagnose']['findings'][axis]:
            print(f'  {axis}  finding, not added: {finding["effect"]}, held-out gain '
                  f'{finding["gain"]:.3f} ({finding["parameters"]})')
        written = results['diagnose']['written'][axis]
        print(f'  {axis}  writes {written["model"]} (found / cubic held-out RMS '
              f'{written["ratio"]:.2f}x)'
              + (f'; cause: {written["cause"]}' if written['cause'] else ''))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--samples', type=int, default=10_000_000)
    parser.add_argument('--rate-hz', type=float, default=100.0)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--repeats', type=int, default=3, help='runs of the cubic baseline')
    # Internal: run one job in this (fresh) process.
    parser.add_argument('--child', choices=JOBS, help=argparse.SUPPRESS)
    parser.add_argument('--data', help=argparse.SUPPRESS)
    parser.add_argument('--max-order', type=int, help=argparse.SUPPRESS)
    parser.add_argument('--blocks', type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args)
        return
    if args.samples < 1000 or not args.rate_hz > 0.0:
        parser.error('--samples must be at least 1000 and --rate-hz positive')
    # The defaults of `mlx-tempcomp fit`.
    from mlx_tempcomp.toolkit.fit import DEFAULT_BLOCKS, DEFAULT_MAX_ORDER
    args.max_order, args.blocks = DEFAULT_MAX_ORDER, DEFAULT_BLOCKS
    start = time.perf_counter()
    data = generate(args.samples, args.rate_hz, args.seed)
    print(f'generated in {time.perf_counter() - start:.1f} s (not timed in the jobs)',
          flush=True)
    data_mb = sum(column.nbytes for column in data.values()) / MB
    with tempfile.TemporaryDirectory(prefix='bench_diagnose_') as data_dir:
        for name, column in data.items():
            np.save(Path(data_dir) / f'{name}.npy', column)
        del data, column
        results = {job: _run_job(job, args, data_dir) for job in JOBS}
    report(args, data_mb, results)


if __name__ == '__main__':
    main()
