"""
The main job of ``make demo``: the ROS pipeline on the simulated sensor.

The driver (simulated MLX90609, faster than real time) and the compensation
node (EEPROM model, bias tracking on as shipped) run in one process, as
``bringup`` runs them, with a second compensation node beside them, in
namespace ``/untracked`` with ``bias_tracking.enabled: false``, handed copies of
the same raw messages; this one listens to all of them. The chamber holds at 25 C
for 2 min (the robot switched on and left standing), goes 25 -> -40 -> 85 -> 25 C, holding
at each, then goes down to -40 C again and holds. The supply sits at 5.15 V,
which shifts the ZRO by +0.3 deg/s: a shift the factory table cannot know, and a
constant rate a gyro alone cannot tell from a turn (the MLX90609 has no
accelerometer). The simulated robot never moves, and says so: beside the nodes
it publishes its wheel odometry on ``odom`` (nav_msgs/Odometry, zero twist,
stamped with each raw sample's stamp), the tracked node's rest hint, so the
tracker re-zeroes the shift at the first hold. During the hold at 25 C after the peak the
demo calls ``imu/recalibrate_zro`` on both nodes; the offset they learn is anchored
to the thermal model, so it keeps helping on the second sweep, and it seeds the
tracker, which then follows what the table leaves at the holds. It prints the
ZRO error (true rate 0) of the raw nominal stream and of the compensated
streams without and with bias tracking, before and after the recalibration,
and at each hold the tracker's estimate (``imu/gyro_bias``) beside the error
of the last seconds of the hold with and without it.
"""

import argparse
import copy
import functools
import os
import signal
import subprocess
import sys
import tempfile
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistWithCovarianceStamped
from nav_msgs.msg import Odometry
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import Trigger
import yaml

from .compensation.node import CompensationNode
from .driver.node import DriverNode
from .messages import stamp_to_ns
from .qos import SENSOR_INPUT_QOS
from .runner import run
from ..core.series import ErrorStatistics

RAMP_C_PER_MIN = 40.0
HOLD_S = 60.0
# The first two 25 C: two holds where the profile starts (ramps of no length), 2 min standing
# at switch-on; the listener hears at least 30 s of it even when it joins a minute late (3 s
# of wall time on a loaded machine).
CYCLE_C = (25.0, 25.0, -40.0, 85.0, 25.0, -40.0)
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
UNTRACKED = '/untracked'
# The holds, found afterwards: 1 s bins whose mean moved less than this from the bin before
# (the ramps move 0.67 C/s), for at least HOLD_MIN_S; their last HOLD_TAIL_S are compared.
HOLD_SLOPE_C_S = 0.05
HOLD_MIN_S = 30.0
HOLD_TAIL_S = 20.0
# Every estimate and status the tracker sends (they are latched, one kept).
BIAS_RECORD_QOS = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The robot's wheel odometry, the tracked node's rest hint: one per raw sample, sent as the
# driver hands the sample over; a hint holds 2 s of sensor time (0.1 s of wall time at 20 x
# real time), so the way through DDS to the node does not leave a window unhinted.
ODOMETRY_TOPIC = 'odom'
HINT_MAX_AGE_S = 2.0


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
    """Collects raw and compensated rate (both nodes), temperature and the tracker's estimate."""

    def __init__(self):
        super().__init__('demo_listener')
        self.raw, self.compensated, self.untracked, self.temperature = {}, {}, {}, {}
        self.bias, self.bias_status = [], {}
        self.create_subscription(Imu, 'imu/data_raw', self.on_raw, SENSOR_INPUT_QOS)
        self.create_subscription(Imu, 'imu/data', self.on_compensated, SENSOR_INPUT_QOS)
        self.create_subscription(Imu, f'{UNTRACKED}/imu/data', self.on_untracked,
                                 SENSOR_INPUT_QOS)
        self.create_subscription(Temperature, 'imu/temperature_raw', self.on_temperature,
                                 SENSOR_INPUT_QOS)
        self.create_subscription(TwistWithCovarianceStamped, 'imu/gyro_bias', self.on_bias,
                                 BIAS_RECORD_QOS)
        self.create_subscription(DiagnosticArray, 'imu/gyro_bias/status', self.on_bias_status,
                                 BIAS_RECORD_QOS)
        self.clients_ = [self.create_client(Trigger, 'imu/recalibrate_zro'),
                         self.create_client(Trigger, f'{UNTRACKED}/imu/recalibrate_zro')]

    def on_raw(self, msg: Imu) -> None:
        self.raw[stamp_to_ns(msg.header.stamp)] = msg.angular_velocity.z

    def on_compensated(self, msg: Imu) -> None:
        self.compensated[stamp_to_ns(msg.header.stamp)] = msg.angular_velocity.z

    def on_untracked(self, msg: Imu) -> None:
        self.untracked[stamp_to_ns(msg.header.stamp)] = msg.angular_velocity.z

    def on_temperature(self, msg: Temperature) -> None:
        self.temperature[stamp_to_ns(msg.header.stamp)] = msg.temperature

    def on_bias(self, msg: TwistWithCovarianceStamped) -> None:
        self.bias.append((stamp_to_ns(msg.header.stamp), msg.twist.twist.angular.z,
                          float(np.sqrt(msg.twist.covariance[35]))))

    def on_bias_status(self, msg: DiagnosticArray) -> None:
        self.bias_status[stamp_to_ns(msg.header.stamp)] = \
            {kv.key: kv.value for kv in msg.status[0].values}


def _phase(values: dict, temperature: dict, first_ns: int, start_s: float, end_s: float):
    stamps = np.array([s for s in values if start_s <= (s - first_ns) * 1e-9 < end_s])
    if stamps.size == 0:
        return None, (float('nan'), float('nan'))
    rates = np.degrees([values[s] for s in stamps])
    temps = [temperature[s] for s in stamps if s in temperature]
    return ErrorStatistics.of(rates), (min(temps), max(temps))


def _holds(temperature: dict) -> list:
    """Give (start_ns, end_ns, mean C) of each hold: a run of steady 1 s bins."""
    stamps = np.array(sorted(temperature))
    values = np.array([temperature[s] for s in stamps.tolist()])
    bins = (stamps - stamps[0]) // 1_000_000_000
    starts = np.r_[0, np.flatnonzero(np.diff(bins)) + 1]
    ends = np.r_[starts[1:], len(stamps)] - 1
    means = np.add.reduceat(values, starts) / (ends - starts + 1)
    steady = np.r_[False, np.abs(np.diff(means)) < HOLD_SLOPE_C_S, False]
    edges = np.flatnonzero(np.diff(steady.astype(np.int8)))
    holds = []
    for first, stop in zip(edges[::2] + 1, edges[1::2] + 1):
        start_ns, end_ns = int(stamps[starts[first]]), int(stamps[ends[stop - 1]])
        if end_ns - start_ns >= HOLD_MIN_S * 1e9:
            holds.append((start_ns, end_ns, float(np.mean(means[first:stop]))))
    return holds


def _recalibrate(listener, now_s: float) -> list:
    """Call imu/recalibrate_zro on both nodes."""
    print(f'at {now_s:.0f} s ({listener.temperature[max(listener.temperature)]:.1f} C, '
          'holding): calling imu/recalibrate_zro (tracked and untracked node)', flush=True)
    return [client.call_async(Trigger.Request()) for client in listener.clients_]


def _print_tables(listener, first_ns: int, end_s: float, recalibrate_at_s: float,
                  recalibrated_s: float) -> None:
    raw, tracked, untracked = listener.raw, listener.compensated, listener.untracked
    temperature = listener.temperature
    rows = [('nominal (raw, AN2 method 1)', raw, 0.0, end_s),
            ('EEPROM, before recalibration', untracked, 0.0, recalibrate_at_s),
            ('  + bias tracking', tracked, 0.0, recalibrate_at_s),
            ('EEPROM, after recalibration', untracked, recalibrated_s, end_s),
            ('  + bias tracking', tracked, recalibrated_s, end_s)]
    print(f'\nZRO error, deg/s (true rate 0; {len(raw)} raw, {len(untracked)} compensated '
          f'without and {len(tracked)} with bias tracking)')
    print(f'{"stream":<30}{"mean":>8}{"1 sigma":>9}{"peak":>8}{"RMS":>8}   sensed range')
    rms = []
    for name, values, start_s, stop_s in rows:
        stats, (low, high) = _phase(values, temperature, first_ns, start_s, stop_s)
        rms.append(stats.rms)
        print(f'{name:<30}{stats.mean:>8.3f}{stats.sigma:>9.3f}{stats.peak:>8.3f}'
              f'{stats.rms:>8.3f}   {low:.0f} .. {high:.0f} C')
    print(f'before the recalibration, bias tracking told the robot stands still: RMS '
          f'{rms[2]:.3f} deg/s against {rms[1]:.3f} untracked, {rms[1] / rms[2]:.2f}x better')
    print(f'\nbias tracking at the holds: mean error of their last {HOLD_TAIL_S:g} s without and '
          'with it, and its estimate (imu/gyro_bias) at their end, deg/s')
    print(f'{"hold":<14}{"without":>9}{"with":>8}{"estimate":>10}{"std":>8}   state')
    for start_ns, end_ns, mean_c in _holds(temperature):
        tail = end_ns - HOLD_TAIL_S * 1e9
        means = [np.degrees(np.mean([v for s, v in values.items() if tail <= s <= end_ns]
                                    or [np.nan])) for values in (untracked, tracked)]
        bias = [b for b in listener.bias if b[0] <= end_ns]
        estimate, std = (np.degrees(bias[-1][1]), np.degrees(bias[-1][2])) if bias else \
            (np.nan, np.nan)
        state = listener.bias_status.get(bias[-1][0], {}) if bias else {}
        text = ('still' if state.get('still') == 'True' else 'moving') + \
            (', stable' if state.get('stable') == 'True' else '') + \
            (', held: its mean is beyond 0.1 deg/s, a turn to a gyro alone'
             if state.get('held') == 'True' else '')
        recalibrated = ' (recal.)' if start_ns <= first_ns + recalibrate_at_s * 1e9 <= end_ns \
            else ''
        print(f'{mean_c:>5.0f} C{recalibrated:<8}{means[0]:>9.3f}{means[1]:>8.3f}'
              f'{estimate:>10.3f}{std:>8.3f}   {text}')


class SimulatedRobot(Node):
    """The robot the gyro sits on: it never moves, and its odometry says so."""

    def __init__(self):
        super().__init__('simulated_robot')
        self.odometry = self.create_publisher(Odometry, ODOMETRY_TOPIC, 100)

    def hand_off(self, handoff: list) -> None:
        """Publish the odometry of each raw sample's time: zero twist."""
        for stream, msg in handoff:
            if stream == 'imu':
                odometry = Odometry()
                odometry.header.stamp = msg.header.stamp
                odometry.header.frame_id = ODOMETRY_TOPIC
                self.odometry.publish(odometry)


def _hand_off(nodes) -> None:
    """Give both compensation nodes the driver's raw messages, the untracked one copies."""
    driver, tracked, untracked, robot = nodes
    # The robot's odometry of a sample goes out first, as a robot's would beside its IMU.
    driver.local_consumers.append(robot.hand_off)
    # Copies, first: a compensation node rewrites the rate of the Imu it republishes.
    driver.local_consumers.append(lambda handoff: untracked.take_local(
        [(stream, copy.deepcopy(msg)) for stream, msg in handoff]))
    driver.local_consumers.append(tracked.take_local)


def run_nodes(args=None) -> int:
    """Run the demo's nodes in this process (``python -m mlx_tempcomp.ros.demo --nodes``)."""
    untracked = functools.partial(CompensationNode, local_input=True, namespace=UNTRACKED,
                                  cli_args=['--ros-args', '-r', 'imu/eeprom:=/imu/eeprom'])
    return run([DriverNode, functools.partial(CompensationNode, local_input=True), untracked,
                SimulatedRobot], args, 'demo_nodes', connect=_hand_off)


def _write_params(folder: str, args) -> str:
    path = os.path.join(folder, 'demo.yaml')
    with open(path, 'w') as params:
        yaml.safe_dump({
            '/**': {'ros__parameters': {'rate_noise_rad_s': NOISE_RAD_S}},
            'driver_node': {'ros__parameters': {
                'publish_rate_hz': 10.0, 'sample_rate_hz': 10.0, 'oversample': 8,
                # Lossless: on a busy machine the simulated clock lags, no sample is skipped.
                'simulation': {'seed': args.seed, 'real_time_factor': args.real_time_factor,
                               'lossless': True,
                               'cycle_temperatures_c': list(CYCLE_C),
                               'ramp_c_per_min': RAMP_C_PER_MIN, 'hold_s': HOLD_S,
                               'supply_v': 5.15, 'zro_supply_dps_per_v': 2.0}}},
            'compensation_node': {'ros__parameters': {
                'recalibration': {'state_file': os.path.join(folder, 'zro.yaml')},
                'bias_tracking': {'rest_hint_topic': ODOMETRY_TOPIC,
                                  'rest_hint_max_age_s': HINT_MAX_AGE_S}}},
            f'{UNTRACKED}/compensation_node': {'ros__parameters': {
                'bias_tracking': {'enabled': False},
                'recalibration': {'state_file': os.path.join(folder, 'untracked.yaml')}}}},
            params)
    return path


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
    params_file = _write_params(folder, args)
    # The listener first: it hears the run from its first samples (the hold at 25 C).
    rclpy.init(args=[])
    listener = Listener()
    nodes = [subprocess.Popen([sys.executable, '-m', 'mlx_tempcomp.ros.demo', '--nodes',
                               '--ros-args', '--params-file', params_file])]
    print(f'simulating {end_s / 60:.1f} min of chamber time at {args.real_time_factor:g}x '
          'real time ...', flush=True)
    futures = None
    peak_ns = None
    recalibrate_at_s = recalibrated_s = None
    try:
        while True:
            rclpy.spin_once(listener, timeout_sec=0.05)
            for node in nodes:
                if node.poll() is not None:
                    print(f'the nodes exited with code {node.returncode}', file=sys.stderr)
                    return 1
            if not listener.raw:
                continue
            first_ns = min(listener.raw)
            now_s = (max(listener.raw) - first_ns) * 1e-9
            latest_ns = max(listener.temperature, default=first_ns)
            if peak_ns is None and listener.temperature.get(latest_ns, 0.0) >= PEAK_C:
                peak_ns = latest_ns
            if futures is None and peak_ns is not None and \
                    abs(listener.temperature[latest_ns] - HOLD_C) < HOLD_NEAR_C and \
                    _holding(listener.temperature, peak_ns):
                futures = _recalibrate(listener, now_s)
                recalibrate_at_s = now_s
            if futures is not None and all(f.done() for f in futures) and \
                    recalibrated_s is None:
                for name, future in zip(('tracked', 'untracked'), futures):
                    response = future.result()
                    print(f'  -> {name}: success={response.success}: {response.message}',
                          flush=True)
                    if not response.success:
                        return 1
                recalibrated_s = now_s
            if now_s >= end_s:
                break
    finally:
        listener.destroy_node()
        rclpy.try_shutdown()
        for node in nodes:
            node.send_signal(signal.SIGINT)
        for node in nodes:
            try:
                node.wait(timeout=10)
            except subprocess.TimeoutExpired:
                node.kill()

    _print_tables(listener, min(listener.raw), end_s, recalibrate_at_s, recalibrated_s)
    print(f'state files: {folder}')
    return 0


if __name__ == '__main__':
    if sys.argv[1:2] == ['--nodes']:
        sys.exit(run_nodes(sys.argv[:1] + sys.argv[2:]))
    start = time.monotonic()
    code = main()
    print(f'({time.monotonic() - start:.0f} s wall)')
    sys.exit(code)
