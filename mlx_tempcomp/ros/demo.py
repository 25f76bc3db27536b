"""
The main job of ``make demo``: the ROS pipeline on the simulated sensor.

The ``bringup`` executable runs the driver (simulated MLX90609, faster than
real time) and the compensation node (EEPROM model) in one process; this one
listens to both streams. The chamber
goes 25 -> -40 -> 85 -> 25 C, holds, then goes down to -40 C again. The supply
sits at 5.15 V, which shifts the ZRO by +0.3 deg/s: a shift the factory table
cannot know. During the hold the demo calls ``imu/recalibrate_zro``; the
offset it learns is anchored to the thermal model, so it keeps helping on the
second sweep. It prints the ZRO error (true rate 0) of the raw nominal
stream, of the EEPROM-compensated stream before the recalibration and of the
EEPROM-compensated stream after it.
"""

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import Trigger
import yaml

from .messages import stamp_to_ns
from .qos import SENSOR_INPUT_QOS
from ..core.metrics import ErrorStatistics

RAMP_C_PER_MIN = 40.0
HOLD_S = 60.0
CYCLE_C = (-40.0, 85.0, 25.0, -40.0)
# Times are counted from the first sample received, a little after the driver starts; the
# hold is found from the temperature: after the 85 C peak, back near 25 C and for this long
# within HOLD_SPREAD_C.
HOLD_SEEN_S = 3.0
HOLD_SPREAD_C = 0.3
PEAK_C = 80.0
HOLD_C = 25.0
HOLD_NEAR_C = 3.0
# 0.33 deg/s per conversion, averaged over 8.
NOISE_RAD_S = float(np.radians(0.33 / np.sqrt(8)))


def _run_s() -> float:
    """Return the length of the chamber profile in simulated seconds."""
    points = (25.0,) + CYCLE_C
    ramps = [abs(b - a) / RAMP_C_PER_MIN * 60.0 for a, b in zip(points, points[1:])]
    return sum(ramps) + len(ramps) * HOLD_S


def _holding(temperature: dict, after_ns: int) -> bool:
    """Tell whether the temperature stayed within HOLD_SPREAD_C for HOLD_SEEN_S up to now."""
    latest = max(temperature)
    recent = [c for s, c in temperature.items() if s >= latest - HOLD_SEEN_S * 1e9]
    return latest - HOLD_SEEN_S * 1e9 >= after_ns and max(recent) - min(recent) < HOLD_SPREAD_C


class Listener(Node):
    """Collects raw and compensated rate and temperature by stamp."""

    def __init__(self):
        super().__init__('demo_listener')
        self.raw, self.compensated, self.temperature = {}, {}, {}
        self.create_subscription(Imu, 'imu/data_raw', self.on_raw, SENSOR_INPUT_QOS)
        self.create_subscription(Imu, 'imu/data', self.on_compensated, SENSOR_INPUT_QOS)
        self.create_subscription(Temperature, 'imu/temperature_raw', self.on_temperature,
                                 SENSOR_INPUT_QOS)
        self.client = self.create_client(Trigger, 'imu/recalibrate_zro')

    def on_raw(self, msg: Imu) -> None:
        self.raw[stamp_to_ns(msg.header.stamp)] = msg.angular_velocity.z

    def on_compensated(self, msg: Imu) -> None:
        self.compensated[stamp_to_ns(msg.header.stamp)] = msg.angular_velocity.z

    def on_temperature(self, msg: Temperature) -> None:
        self.temperature[stamp_to_ns(msg.header.stamp)] = msg.temperature


def _phase(values: dict, temperature: dict, first_ns: int, start_s: float, end_s: float):
    stamps = np.array([s for s in values if start_s <= (s - first_ns) * 1e-9 < end_s])
    if stamps.size == 0:
        return None, (float('nan'), float('nan'))
    rates = np.degrees([values[s] for s in stamps])
    temps = [temperature[s] for s in stamps if s in temperature]
    return ErrorStatistics.of(rates), (min(temps), max(temps))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m mlx_tempcomp.ros.demo',
                                     description=__doc__.split('\n\n')[1])
    parser.add_argument('--real-time-factor', type=float, default=20.0,
                        help='simulated seconds per wall second (20)')
    parser.add_argument('--seed', type=int, default=0, help='simulated chip seed (0)')
    args = parser.parse_args(argv)
    # A demo stays on this machine, whatever network it is on.
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    end_s = _run_s()
    folder = tempfile.mkdtemp(prefix='mlx_tempcomp_demo_')
    state_file = os.path.join(folder, 'zro.yaml')
    params_file = os.path.join(folder, 'demo.yaml')
    with open(params_file, 'w') as params:
        yaml.safe_dump({
            '/**': {'ros__parameters': {'rate_noise_rad_s': NOISE_RAD_S}},
            'driver_node': {'ros__parameters': {
                'publish_rate_hz': 10.0, 'sample_rate_hz': 10.0, 'oversample': 8,
                'simulation': {'seed': args.seed, 'real_time_factor': args.real_time_factor,
                               'cycle_temperatures_c': list(CYCLE_C),
                               'ramp_c_per_min': RAMP_C_PER_MIN, 'hold_s': HOLD_S,
                               'supply_v': 5.15, 'zro_supply_dps_per_v': 2.0}}},
            'compensation_node': {'ros__parameters': {
                'recalibration': {'state_file': state_file}}}}, params)
    bringup = subprocess.Popen([sys.executable, '-m', 'mlx_tempcomp.ros.bringup',
                                '--ros-args', '--params-file', params_file])
    rclpy.init(args=[])
    listener = Listener()
    print(f'simulating {end_s / 60:.1f} min of chamber time at {args.real_time_factor:g}x '
          'real time ...', flush=True)
    future = None
    peak_ns = None
    recalibrate_at_s = recalibrated_s = None
    try:
        while True:
            rclpy.spin_once(listener, timeout_sec=0.05)
            if bringup.poll() is not None:
                print(f'bringup exited with code {bringup.returncode}', file=sys.stderr)
                return 1
            if not listener.raw:
                continue
            first_ns = min(listener.raw)
            now_s = (max(listener.raw) - first_ns) * 1e-9
            latest_ns = max(listener.temperature, default=first_ns)
            if peak_ns is None and listener.temperature.get(latest_ns, 0.0) >= PEAK_C:
                peak_ns = latest_ns
            if future is None and peak_ns is not None and \
                    abs(listener.temperature[latest_ns] - HOLD_C) < HOLD_NEAR_C and \
                    _holding(listener.temperature, peak_ns):
                print(f'at {now_s:.0f} s ({listener.temperature[latest_ns]:.1f} C, holding): '
                      'calling imu/recalibrate_zro', flush=True)
                future = listener.client.call_async(Trigger.Request())
                recalibrate_at_s = now_s
            if future is not None and future.done() and recalibrated_s is None:
                response = future.result()
                print(f'  -> success={response.success}: {response.message}', flush=True)
                if not response.success:
                    return 1
                recalibrated_s = now_s
            if now_s >= end_s:
                break
    finally:
        listener.destroy_node()
        rclpy.try_shutdown()
        bringup.send_signal(signal.SIGINT)
        try:
            bringup.wait(timeout=10)
        except subprocess.TimeoutExpired:
            bringup.kill()

    first_ns = min(listener.raw)
    rows = [('nominal (raw, AN2 method 1)',) + _phase(listener.raw, listener.temperature,
                                                      first_ns, 0.0, end_s),
            ('EEPROM, before recalibration',) + _phase(listener.compensated,
                                                       listener.temperature, first_ns, 0.0,
                                                       recalibrate_at_s),
            ('EEPROM, after recalibration',) + _phase(listener.compensated,
                                                      listener.temperature, first_ns,
                                                      recalibrated_s, end_s)]
    print(f'\nZRO error, deg/s (true rate 0; {len(listener.raw)} raw and '
          f'{len(listener.compensated)} compensated samples)')
    print(f'{"stream":<30}{"mean":>8}{"1 sigma":>9}{"peak":>8}{"RMS":>8}   sensed range')
    for name, stats, (low, high) in rows:
        print(f'{name:<30}{stats.mean:>8.3f}{stats.sigma:>9.3f}{stats.peak:>8.3f}'
              f'{stats.rms:>8.3f}   {low:.0f} .. {high:.0f} C')
    print(f'state file: {state_file}')
    return 0


if __name__ == '__main__':
    start = time.monotonic()
    code = main()
    print(f'({time.monotonic() - start:.0f} s wall)')
    sys.exit(code)
