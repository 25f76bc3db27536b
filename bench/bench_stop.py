"""
How long each executable takes to exit after SIGINT or SIGTERM (target: 2 s), wall time.

Each round starts, in a private localhost-only DDS domain, a driver per device with
a compensation node beside it (mlx90609 + eeprom, adis16130 + linear_btc, mpu6000 +
polynomial: the reported hang) and ``bringup``, lets them stream ``--stream-s``
seconds, then signals every process at once and times each exit. ``--hogs N`` runs
N busy loops (``sh -c 'while :; do :; done'``) meanwhile. Prints, per executable,
the exit codes seen and the median and largest stop time.

    .venv/bin/python bench/bench_stop.py [--rounds 5] [--stream-s 6] [--hogs 0]
"""

import argparse
import os
from pathlib import Path
import signal
import statistics
import subprocess
import sys
import tempfile
import time

from mlx_tempcomp.parameters.files import write_parameter_file

BIN = Path(sys.executable).parent
XYZ = ['x', 'y', 'z']
# namespace -> (executable, parameters), both nodes of a pair in one namespace.
CASES = {
    'mlx': [('driver_node', {}), ('compensation_node', {'model': 'eeprom'})],
    'adis': [('driver_node', {'device': 'adis16130'}),
             ('compensation_node', {'model': 'linear_btc', 'linear_btc': {
                 'pbc_rad_s': [0.01], 'btc_rad_s_per_c': [0.0002]}})],
    'mpu': [('driver_node', {'device': 'mpu6000', 'axes': XYZ}),
            ('compensation_node', {'model': 'polynomial', 'axes': XYZ, 'polynomial': {
                'bias': {axis: [0.001, 1e-4] for axis in XYZ}}})],
    'one': [('bringup', {'device': 'mpu6000', 'axes': XYZ, 'model': 'polynomial',
                         'polynomial': {'bias': {axis: [0.001, 1e-4] for axis in XYZ}}})],
}


def start(folder: Path, namespace: str, executable: str, params: dict, env: dict):
    label = f'{namespace}_{executable}'
    path = folder / f'{label}.yaml'
    params = {'recalibration': {'state_file': str(folder / f'{label}_zro.yaml')}, **params}
    write_parameter_file(path, {'/**': {'ros__parameters': params}})
    log = open(folder / f'{label}.log', 'wb')
    command = [str(BIN / executable), '--ros-args', '--params-file', str(path),
               '-r', f'__ns:=/{namespace}']
    return label, subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)


def one_round(folder: Path, signum: int, stream_s: float, env: dict) -> dict:
    processes = [start(folder, namespace, executable, params, env)
                 for namespace, nodes in CASES.items() for executable, params in nodes]
    # Streaming from when the last one has logged its start-up line: a signal before
    # Python has started kills the process the default way.
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline and not all(
            process.poll() is not None or 'publishes' in (folder / f'{label}.log').read_text()
            for label, process in processes):
        time.sleep(0.1)
    time.sleep(stream_s)
    sent = time.monotonic()
    for _, process in processes:
        process.send_signal(signum)
    results = {}
    for label, process in processes:
        try:
            code = process.wait(60.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            code = 'hung > 60 s'
        results[label] = (code, time.monotonic() - sent)
        if code != 0:
            print(f'--- {label} exited {code}:\n' + (folder / f'{label}.log').read_text())
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--stream-s', type=float, default=6.0)
    parser.add_argument('--hogs', type=int, default=0)
    options = parser.parse_args()
    env = dict(os.environ, ROS_DOMAIN_ID=str(os.getpid() % 101 + 120),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    hogs = [subprocess.Popen(['sh', '-c', 'while :; do :; done'])
            for _ in range(options.hogs)]
    seen = {}
    try:
        for index in range(options.rounds):
            signum = (signal.SIGINT, signal.SIGTERM)[index % 2]
            with tempfile.TemporaryDirectory() as folder:
                for label, result in one_round(Path(folder), signum, options.stream_s,
                                               env).items():
                    seen.setdefault(label, []).append(result)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    print(f'{options.rounds} rounds (SIGINT and SIGTERM in turn), {options.hogs} busy loops, '
          f'{os.cpu_count()} cores')
    print(f'{"executable":28} {"exit codes":14} {"median s":>9} {"max s":>7}')
    for label, results in seen.items():
        codes = sorted({str(code) for code, _ in results})
        times = [seconds for _, seconds in results]
        print(f'{label:28} {",".join(codes):14} {statistics.median(times):9.2f} '
              f'{max(times):7.2f}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
