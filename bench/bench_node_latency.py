"""
Compensation node latency, drops and CPU beside a pass-through relay node, over DDS.

Part (a), the device: the real ``driver_node`` samples the simulated
ADIS16130 at its natural 5.7 kHz in real time and publishes the interval
means at 1 kHz; the node under test (the real ``compensation_node``, a
polynomial model, with bias tracking and field learning as shipped; as
``unlearnt``, with ``learning.enabled: false``; as ``untracked``, with
``bias_tracking.enabled: false``; or the relay) forwards them, or ``bringup``
runs driver and compensation (as shipped) in one process with the in-process
hand-off. The tracking's cost is the CPU of ``unlearnt`` less that of
``untracked``; the learning's, that of ``compensation`` less ``unlearnt``. A receiver records
imu/data_raw and imu/data; lost samples are the device reads the driver
missed (its closing summary) plus the raw messages that never came out
compensated.

Part (b), the rates: a feeder publishes Temperature then Imu per sample at
each target rate, stamped with the send time; the node under test (the real
``compensation_node`` executable, eeprom model, or a relay built the same way:
same runner, same QoS, same stamp pairing, republishing both messages
unchanged) forwards them; a receiver records when each ``imu/data`` reached
it. Each runs in its own process, in a private localhost-only DDS domain.
Relay and compensation alternate at each rate, because this machine is noisy;
--rounds repeats the alternation and pools the figures. --sweep finds the
highest rate each node forwards without a drop.

Part (c), missed device reads: the driver (each part at its natural rate, the
MLX90609 at its default 1 kHz, the ADIS16130 at 5.7 kHz) feeding a
compensation node, once on the machine as it is and once beside a CPU hog
(two busy loops the benchmark starts and stops itself), side by side; the
figures are the driver's closing summary.

Part (d), bias tracking in process: a ``CompensationNode`` built in this
process (polynomial model, one axis, as in part (a)) is handed one paired
message at a time through ``process`` (pairing, model, tracking, publishing,
the recalibration's window: everything but the executor and DDS's receiving),
tracking off, on, on with field learning (the prior in use: no renewal in 20 s), and on
with a renewed curve in use (read from the state file, as after a robot's first renewal)
in 5 alternating rounds, the best of each kept: the CPU the tracking and the learning add
to a message without the machine's load in it. At rest, at 1 kHz of sensor time, so
windows close and learn every 5 s; the temperature moves at every message, as the
ADIS16130's does, so no row of the curve is reused. Windows and state writes come by
sensor time, so per message they cost what they cost a robot at 1 kHz (a window per 5000
messages), but for the start: the first learnt window writes the state at once, later
ones every ``bias_tracking.save_period_s`` (60 s). The split times each message (5
alternating runs, the lowest kept): the median of those that closed no window (per
sample), and the totals of those that closed one and of those that wrote the state.

Targets: zero lost samples at 1 kHz publish with 5.7 kHz sampling; at every
rate, compensation drops no more than the relay and its p99 latency is at
most 1.2x the relay's; bias tracking adds less than 10 % to the node's CPU; field
learning less than 5 % more (issue 31).

    .venv/bin/python bench/bench_node_latency.py [--rates 1000 2000 4000 5700] [--duration 30]
                                                 [--rounds 1] [--device-duration 20]
                                                 [--device-rounds 1] [--missed-duration 20]
                                                 [--process-messages 20000]
    .venv/bin/python bench/bench_node_latency.py --sweep [--sweep-rates ...] [--sweep-duration 10]
"""

import argparse
import os
from pathlib import Path
import struct
import subprocess
import sys
import tempfile
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from mlx_tempcomp.core.series.pairing import StampPairer
from mlx_tempcomp.ros import messages
from mlx_tempcomp.ros.qos import EEPROM_QOS, SENSOR_INPUT_QOS, SENSOR_QOS
from mlx_tempcomp.ros.runner import run
from mlx_tempcomp.sources.mlx90609 import SimulatedArray, SimulationConfig
import numpy as np
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import UInt8MultiArray
from std_srvs.srv import Trigger
import yaml

# Header stamp in a CDR message: after the 4-byte encapsulation header, int32 sec, uint32 ns.
_STAMP = struct.Struct('<iI')
_STAMP_OFFSET = 4
# Deep enough that the receiver never drops what the node under test sent.
_RECEIVER_QOS = QoSProfile(depth=20000, history=HistoryPolicy.KEEP_LAST,
                           reliability=ReliabilityPolicy.BEST_EFFORT)
NODES = ('relay', 'compensation')
DEVICE_NODES = ('relay', 'untracked', 'unlearnt', 'compensation', 'bringup')
P99_TARGET = 1.2
DEVICE_PUBLISH_HZ = 1000.0
SWEEP_RATES = (500, 750, 1000, 1250, 1500, 2000, 3000, 4000, 5700)
READY_TIMEOUT_S = 30.0
DRAIN_S = 1.5


# The baseline node.
class RelayNode(Node):
    """
    Pass-through relay built like the compensation node.

    Same runner, same input QoS, same StampPairer, publishes Temperature then Imu
    on the same topics with the same QoS; also the same kinds of other entities
    (EEPROM subscription, service, 1 Hz diagnostics timer), so the executor's
    wait set has the same shape. Only the model and the message building differ.
    """

    def __init__(self, **kwargs):
        super().__init__('relay_node', **kwargs)
        self.pairer = StampPairer(('imu', 'temperature'))
        self.imu_publisher = self.create_publisher(Imu, 'imu/data', SENSOR_QOS)
        self.temperature_publisher = self.create_publisher(Temperature, 'imu/temperature',
                                                           SENSOR_QOS)
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(Imu, 'imu/data_raw', self.on_imu, SENSOR_INPUT_QOS)
        self.create_subscription(
            Temperature, 'imu/temperature_raw',
            lambda msg: self.on_temperature('temperature', msg), SENSOR_INPUT_QOS)
        self.create_subscription(UInt8MultiArray, 'imu/eeprom', lambda msg: None, EEPROM_QOS)
        self.create_service(Trigger, 'imu/recalibrate_zro', lambda request, response: response,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(1.0, lambda: self.diagnostics_publisher.publish(DiagnosticArray()))

    def on_imu(self, msg: Imu) -> None:
        for stamp_ns, parts in self.pairer.add('imu', messages.stamp_to_ns(msg.header.stamp),
                                               msg):
            self.process(stamp_ns, parts)

    def on_temperature(self, stream: str, msg: Temperature) -> None:
        for stamp_ns, parts in self.pairer.add(stream, messages.stamp_to_ns(msg.header.stamp),
                                               msg):
            self.process(stamp_ns, parts)

    def process(self, stamp_ns: int, parts: dict) -> None:
        self.temperature_publisher.publish(parts['temperature'])
        self.imu_publisher.publish(parts['imu'])


def relay_main() -> int:
    return run([RelayNode], None, 'relay_node')


# The feeder: paced raw stream.
def _templates() -> tuple:
    """Return serialized Temperature and Imu messages as the driver would publish them."""
    stamp = messages.ns_to_stamp(0)
    indices = messages.axis_indices(('z',))
    temperature = messages.temperature_message(stamp, 'imu_link', 25.0)
    imu = messages.imu_message(stamp, 'imu_link', indices, [0.001],
                               messages.rate_covariance(indices, 0.0058))
    return bytearray(serialize_message(temperature)), bytearray(serialize_message(imu))


def _feed(publishers, buffers, rate_hz: float, duration_s: float, stamps: list,
          last_ns: int) -> tuple:
    """
    Publish every sample due at ``rate_hz`` for ``duration_s``; return (elapsed, last stamp).

    One loop catches up on all samples due (Python cannot wake 5700 times a
    second on time), then sleeps until the next one is due. Each sample is
    stamped with its own send time, strictly increasing.
    """
    period = 1.0 / rate_hz
    total = int(round(rate_hz * duration_s))
    temperature_publisher, imu_publisher = publishers
    temperature_buffer, imu_buffer = buffers
    sent = 0
    start = time.perf_counter()
    while sent < total:
        due = min(total, int((time.perf_counter() - start) * rate_hz) + 1)
        while sent < due:
            stamp_ns = max(time.time_ns(), last_ns + 1)
            last_ns = stamp_ns
            sec, nanosec = divmod(stamp_ns, 1_000_000_000)
            _STAMP.pack_into(temperature_buffer, _STAMP_OFFSET, sec, nanosec)
            _STAMP.pack_into(imu_buffer, _STAMP_OFFSET, sec, nanosec)
            temperature_publisher.publish(bytes(temperature_buffer))
            imu_publisher.publish(bytes(imu_buffer))
            stamps.append(stamp_ns)
            sent += 1
        delay = start + sent * period - time.perf_counter()
        if delay > 0.0:
            time.sleep(delay)
    return time.perf_counter() - start, last_ns


def feeder_main(rate_hz: float, duration_s: float, warmup_s: float, out: str) -> int:
    """Publish the EEPROM, wait for the node, feed on 'go' from stdin, save the stamps."""
    rclpy.init()
    node = rclpy.create_node('bench_feeder')
    eeprom_publisher = node.create_publisher(UInt8MultiArray, 'imu/eeprom', EEPROM_QOS)
    eeprom_publisher.publish(messages.eeprom_message(
        SimulatedArray(SimulationConfig(), 1).read_eeproms()))
    publishers = (node.create_publisher(Temperature, 'imu/temperature_raw', SENSOR_QOS),
                  node.create_publisher(Imu, 'imu/data_raw', SENSOR_QOS))
    while min(p.get_subscription_count() for p in publishers) < 1:
        time.sleep(0.01)
    print('matched', flush=True)
    if sys.stdin.readline().strip() != 'go':
        return 1
    buffers = _templates()
    _, last_ns = _feed(publishers, buffers, rate_hz, warmup_s, [], 0)
    stamps = []
    print('start', flush=True)
    elapsed, _ = _feed(publishers, buffers, rate_hz, duration_s, stamps, last_ns)
    print(f'end {elapsed!r}', flush=True)
    np.save(out, np.array(stamps, dtype=np.int64))
    # Keep the EEPROM publisher (transient local) alive until told to stop.
    sys.stdin.readline()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# The receiver: arrival time of each compensated sample.
def receiver_main(out: str, topics=('imu/data',)) -> int:
    """
    Record (stamp, arrival, node publish time, node sequence, topic) per message till stdin closes.

    Arrival and publish times are the middleware's (DDS reception and source
    timestamps, both the system clock), so this process's own scheduling does
    not add to the figures. Messages are taken raw in a tight loop; the topic
    is its index in ``topics``.
    """
    rclpy.init()
    node = rclpy.create_node('bench_receiver')
    subscriptions = [node.create_subscription(Imu, topic, lambda msg: None, _RECEIVER_QOS,
                                              raw=True) for topic in topics]
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    while min(s.get_publisher_count() for s in subscriptions) < 1:
        time.sleep(0.01)
    print('ready', flush=True)
    wait_set = _rclpy.WaitSet(len(subscriptions), 0, 0, 0, 0, 0, node.context.handle)
    records = []
    while not stop.is_set():
        wait_set.clear_entities()
        for subscription in subscriptions:
            wait_set.add_subscription(subscription.handle)
        wait_set.wait(100_000_000)
        for topic, subscription in enumerate(subscriptions):
            handle, msg_type = subscription.handle, subscription.msg_type
            taken = handle.take_message(msg_type, True)
            while taken is not None:
                data, info = taken
                sec, nanosec = _STAMP.unpack_from(data, _STAMP_OFFSET)
                received = info['received_timestamp'] or time.time_ns()
                records.append((sec * 1_000_000_000 + nanosec, received,
                                info['source_timestamp'],
                                info['publication_sequence_number'] or 0, topic))
                taken = handle.take_message(msg_type, True)
    np.save(out, np.array(records, dtype=np.int64).reshape(-1, 5))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# The orchestrator.
def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` (all its threads)."""
    with open(f'/proc/{pid}/stat') as stat:
        fields = stat.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class _Lines:
    """Collect a child's output lines in a thread, so its pipe never fills."""

    def __init__(self, stream):
        self.lines = []
        self.changed = threading.Condition()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream) -> None:
        for line in stream:
            with self.changed:
                self.lines.append(line.rstrip('\n'))
                self.changed.notify_all()

    def wait_for(self, text: str, timeout_s: float) -> bool:
        with self.changed:
            return self.changed.wait_for(lambda: any(text in line for line in self.lines),
                                         timeout_s)


def _start(command, env, stdin=None):
    return subprocess.Popen(command, env=env, stdin=stdin, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, bufsize=1)


def _stop(process, timeout_s: float = 10.0) -> None:
    if process.poll() is not None:
        return
    process.send_signal(2)  # SIGINT: rclpy shuts down cleanly, DDS releases its segments.
    try:
        process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def _node_command(name: str, folder: str) -> list:
    if name == 'relay':
        return [sys.executable, str(Path(__file__).resolve()), '--relay']
    executable = Path(sys.executable).with_name('compensation_node')
    command = [str(executable)] if executable.exists() else \
        [sys.executable, '-m', 'mlx_tempcomp.ros.compensation.node']
    return command + ['--ros-args', '-p', 'model:=eeprom', '-p',
                      f'recalibration.state_file:={folder}/zro.yaml']


def measure(name: str, rate_hz: float, duration_s: float, warmup_s: float, env) -> dict:
    """Run node ``name`` with a feeder and a receiver; return its figures."""
    script = str(Path(__file__).resolve())
    with tempfile.TemporaryDirectory(prefix='bench_node_latency_') as folder:
        sent_file, received_file = f'{folder}/sent.npy', f'{folder}/received.npy'
        node = _start(_node_command(name, folder), env)
        node_lines = _Lines(node.stdout)
        receiver = feeder = None

        def expect(lines, text: str, what: str, timeout_s: float = READY_TIMEOUT_S) -> None:
            if not lines.wait_for(text, timeout_s):
                status = 'running' if node.poll() is None else f'exited {node.returncode}'
                output = '\n'.join(node_lines.lines[-20:])
                msg = f'{name} at {rate_hz:g} Hz: {what} (node {status}); node output:\n{output}'
                raise RuntimeError(msg)

        try:
            receiver = _start([sys.executable, script, '--receiver', received_file], env,
                              subprocess.PIPE)
            expect(_Lines(receiver.stdout), 'ready', 'the receiver never matched imu/data')
            feeder = _start([sys.executable, script, '--feeder', '--rate', repr(rate_hz),
                             '--duration', repr(duration_s), '--warmup', repr(warmup_s),
                             '--out', sent_file], env, subprocess.PIPE)
            feeder_lines = _Lines(feeder.stdout)
            expect(feeder_lines, 'matched', "the feeder never matched the node's inputs")
            if name == 'compensation':
                expect(node_lines, 'factory tables received', 'no eeprom model')
            feeder.stdin.write('go\n')
            feeder.stdin.flush()
            expect(feeder_lines, 'start', 'the feeder did not start', READY_TIMEOUT_S + warmup_s)
            processes = (node, feeder, receiver)
            cpu_start = [_cpu_seconds(p.pid) for p in processes]
            wall_start = time.perf_counter()
            expect(feeder_lines, 'end', 'the feeder did not finish', 2 * duration_s)
            cpu_end = [_cpu_seconds(p.pid) for p in processes]
            wall_end = time.perf_counter()
            feed_s = float(next(line for line in feeder_lines.lines
                                if line.startswith('end')).split()[1])
            time.sleep(DRAIN_S)
            if node.poll() is not None:
                msg = f'{name} node died:\n' + '\n'.join(node_lines.lines[-20:])
                raise RuntimeError(msg)
            receiver.stdin.close()
            receiver.wait(READY_TIMEOUT_S)
            feeder.stdin.write('stop\n')
            feeder.stdin.flush()
            feeder.wait(READY_TIMEOUT_S)
        finally:
            for process in (feeder, receiver, node):
                if process is not None:
                    _stop(process)
        sent = np.load(sent_file)
        records = np.load(received_file)
    return _figures(name, rate_hz, sent, records, feed_s,
                    [(e - s) / (wall_end - wall_start) for s, e in zip(cpu_start, cpu_end)])


def _executable(name: str) -> list:
    path = Path(sys.executable).with_name(name)
    return [str(path)] if path.exists() else [sys.executable, '-m', f'mlx_tempcomp.ros.{name}']


def _device_params(folder: str, tracking: bool, learning: bool) -> str:
    """Write the parameters of the device runs (driver and compensation); return the path."""
    path = f'{folder}/device.yaml'
    with open(path, 'w') as stream:
        yaml.safe_dump({
            'driver_node': {'ros__parameters': {
                'device': 'adis16130', 'publish_rate_hz': DEVICE_PUBLISH_HZ,
                'sample_rate_hz': 0.0, 'simulation': {'real_time_factor': 1.0}}},
            'compensation_node': {'ros__parameters': {
                'model': 'polynomial', 'polynomial': {'bias': {'z': [0.001, 0.0001]}},
                'bias_tracking': {'enabled': tracking}, 'learning': {'enabled': learning},
                'recalibration': {'state_file': f'{folder}/zro.yaml'}}}}, stream)
    return path


def measure_device(name: str, duration_s: float, warmup_s: float, env) -> dict:
    """Run the driver on the simulated ADIS16130 at 5.7 kHz into node ``name``; give figures."""
    script = str(Path(__file__).resolve())
    with tempfile.TemporaryDirectory(prefix='bench_node_latency_') as folder:
        params = _device_params(folder, tracking=name != 'untracked',
                                learning=name not in ('untracked', 'unlearnt'))
        records_file = f'{folder}/received.npy'
        if name == 'bringup':
            commands = [_executable('bringup') + ['--ros-args', '--params-file', params]]
        else:
            node = [sys.executable, script, '--relay'] if name == 'relay' else \
                _executable('compensation_node') + ['--ros-args', '--params-file', params]
            commands = [node, _executable('driver_node') + ['--ros-args', '--params-file',
                                                            params]]
        processes, lines = [], []
        receiver = None
        try:
            receiver = _start([sys.executable, script, '--receiver', records_file,
                               '--raw-too'], env, subprocess.PIPE)
            receiver_lines = _Lines(receiver.stdout)
            for command in commands:
                processes.append(_start(command, env))
                lines.append(_Lines(processes[-1].stdout))
            if not receiver_lines.wait_for('ready', READY_TIMEOUT_S):
                output = '\n'.join(line for ls in lines for line in ls.lines[-10:])
                msg = f'device run {name}: the receiver never heard both topics:\n{output}'
                raise RuntimeError(msg)
            time.sleep(warmup_s)
            cpu_start = [_cpu_seconds(p.pid) for p in processes]
            window_start = time.time_ns()
            time.sleep(duration_s)
            window_end = time.time_ns()
            cpu_end = [_cpu_seconds(p.pid) for p in processes]
            # The driver (last) first: its closing summary counts what it read and missed.
            for process in reversed(processes):
                _stop(process)
            time.sleep(DRAIN_S)
            receiver.stdin.close()
            receiver.wait(READY_TIMEOUT_S)
        finally:
            for process in [receiver] + processes:
                if process is not None:
                    _stop(process)
        records = np.load(records_file)
    summary = next((line for ls in lines for line in ls.lines if 'sampling: ' in line), '')
    missed = int(summary.split(' samples read, ')[1].split()[0]) if summary else -1
    raw, data = (records[records[:, 4] == topic] for topic in (0, 1))
    raw = raw[(raw[:, 1] >= window_start) & (raw[:, 1] < window_end)]
    out = {int(row[0]): int(row[1]) for row in data}
    compensated = [(stamp, out[int(stamp)], arrival) for stamp, arrival in raw[:, :2]
                   if int(stamp) in out]
    seconds = (window_end - window_start) / 1e9
    return {'node': name, 'raw': len(raw), 'lost': len(raw) - len(compensated),
            'missed_reads': missed, 'summary': summary,
            'latency_ms': np.array([(o - s) / 1e6 for s, o, _ in compensated]),
            'added_ms': np.array([(o - a) / 1e6 for _, o, a in compensated]),
            'cpu': [100.0 * (e - s) / seconds for s, e in zip(cpu_start, cpu_end)],
            # The node's CPU time per raw message of the window: what a missed read (fewer
            # messages on a loaded machine) does not bias.
            'us_per_msg': 1e6 * (cpu_end[0] - cpu_start[0]) / max(len(raw), 1)}


# Part (d): tracking off, on, on with field learning, and with a renewed curve in use.
PROCESS_KEYS = ('without', 'with', 'learning', 'renewed')


def _process_samples(count: int) -> list:
    """Give part (d)'s paired messages: at rest, 1 kHz of sensor time, temperature rising."""
    # Fresh each run: the node republishes the input Imu with its rate rewritten.
    rng = np.random.default_rng(0)
    paired = []
    for i in range(count):
        stamp = messages.ns_to_stamp(1_000_000_000_000 + i * 1_000_000)
        imu = messages.imu_message(stamp, 'imu_link', (2,), [float(rng.normal(0.0, 1e-3))],
                                   [0.0] * 9)
        temperature = messages.temperature_message(stamp, 'imu_link', 25.0 + i * 1e-5)
        paired.append((messages.stamp_to_ns(stamp), {'imu': imu, 'temperature': temperature}))
    return paired


def _process_node(key: str, path: str):
    """Build part (d)'s node for ``key``, its own state file ``path`` (no offset shared)."""
    from mlx_tempcomp.ros.compensation.node import CompensationNode
    from rclpy.parameter import Parameter

    return CompensationNode(local_input=True, parameter_overrides=[
        Parameter('model', value='polynomial'),
        Parameter('polynomial.bias.z', value=[0.001, 0.0001]),
        Parameter('bias_tracking.enabled', value=key != 'without'),
        Parameter('learning.enabled', value=key in ('learning', 'renewed')),
        Parameter('recalibration.state_file', value=path)])


def _renewed_state(path: str) -> None:
    """
    Write a state file whose learning section has a renewed curve in use (a bowl, 1e-4 rad/s).

    The node's own section (`CompensationLearning.section`) of a fresh learner, its curve
    accepted and taken off: what a robot holds after its first renewal, read back at start.
    """
    from mlx_tempcomp.parameters.state_file import write_state

    node = _process_node('learning', path)
    section = node.tracking.learning.section()
    node.destroy_node()
    curve = [1e-4 * ((t - 25.0) / 20.0) ** 2 for t in section['knots_c']]
    section.update(accepted=[curve], applied=[curve],
                   counts={**section['counts'], 'renewals': [1]})
    write_state(path, {'learning': section})


def measure_process(messages_count: int, rounds: int) -> dict:
    """Part (d): CPU us per message of ``CompensationNode.process`` for each of PROCESS_KEYS."""
    best, runs = {}, 0
    rclpy.init(args=[])
    try:
        with tempfile.TemporaryDirectory(prefix='bench_node_process_') as folder:
            for _ in range(rounds):
                for key in PROCESS_KEYS:
                    paired = _process_samples(messages_count)
                    path = f'{folder}/zro_{runs}.yaml'
                    runs += 1
                    if key == 'renewed':
                        _renewed_state(path)
                    node = _process_node(key, path)
                    start = time.process_time()
                    for sample in paired:
                        node.process([sample])
                    used = time.process_time() - start
                    tracking = node.tracking
                    if key != 'without':
                        best['updates'] = max(best.get('updates', 0), tracking.tracker.updates)
                    if key == 'learning':
                        best['learnt_windows'] = tracking.learning.learner.windows
                    if key == 'renewed':
                        best['renewed_in_use'] = not tracking.learning.applied().is_zero
                    node.destroy_node()
                    best[key] = min(best.get(key, float('inf')), 1e6 * used / messages_count)
    finally:
        rclpy.try_shutdown()
    return best


def measure_split(messages_count: int, rounds: int) -> dict:
    """
    Part (d), split: each message timed (thread CPU time), tracking alone and with learning.

    Give per key, the lowest of ``rounds`` alternating runs: the per-message median of the
    messages that closed no window, and the ms and count of those that closed one without a
    state write and of those that wrote.
    """
    best = {}
    rclpy.init(args=[])
    try:
        with tempfile.TemporaryDirectory(prefix='bench_node_split_') as folder:
            for round_ in range(rounds):
                for key in ('with', 'learning'):
                    figures = _timed_run(key, f'{folder}/zro_{key}_{round_}.yaml',
                                         messages_count)
                    kept = best.setdefault(key, figures)
                    for name in ('median_us', 'window_ms', 'write_ms'):
                        kept[name] = min(kept[name], figures[name])
    finally:
        rclpy.try_shutdown()
    return best


def _timed_run(key: str, path: str, messages_count: int) -> dict:
    """One run of `measure_split`: each message's CPU, by what it did."""
    paired = _process_samples(messages_count)
    node = _process_node(key, path)
    tracking = node.tracking
    used = np.empty(len(paired))
    window = np.zeros(len(paired), dtype=bool)
    wrote = np.zeros(len(paired), dtype=bool)
    for i, sample in enumerate(paired):
        windows, writes = tracking.windows, tracking.writes
        start = time.thread_time()
        node.process([sample])
        used[i] = time.thread_time() - start
        window[i], wrote[i] = tracking.windows != windows, tracking.writes != writes
    node.destroy_node()
    closed = window & ~wrote
    return {'median_us': 1e6 * float(np.median(used[~window & ~wrote])),
            'window_ms': 1e3 * float(used[closed].sum()), 'windows': int(closed.sum()),
            'write_ms': 1e3 * float(used[wrote].sum()), 'writes': int(wrote.sum())}


# Part (c): device, its natural sample rate (the driver's default), publish rate.
MISSED_DEVICES = (('mlx90609', 1000, 100.0), ('adis16130', 5700, 1000.0))
HOG = ['sh', '-c', 'while :; do :; done']


def _hog(duration_s: float) -> list:
    """Start two busy loops, each killed by timeout(1) at the latest after ``duration_s``."""
    return [subprocess.Popen(['timeout', f'{duration_s:g}'] + HOG) for _ in range(2)]


def measure_missed(device: str, publish_rate_hz: float, duration_s: float, hog: bool,
                   env) -> dict:
    """Run driver and compensation node for ``duration_s``; give the driver's read counts."""
    with tempfile.TemporaryDirectory(prefix='bench_node_latency_') as folder:
        params = f'{folder}/missed.yaml'
        with open(params, 'w') as stream:
            yaml.safe_dump({
                'driver_node': {'ros__parameters': {
                    'device': device, 'publish_rate_hz': publish_rate_hz,
                    'sample_rate_hz': 0.0, 'simulation': {'real_time_factor': 1.0}}},
                'compensation_node': {'ros__parameters': {
                    'model': 'polynomial', 'polynomial': {'bias': {'z': [0.001]}},
                    'recalibration': {'state_file': f'{folder}/zro.yaml'}}}}, stream)
        hogs = _hog(duration_s + READY_TIMEOUT_S) if hog else []
        processes = []
        try:
            for name in ('compensation_node', 'driver_node'):
                processes.append(_start(_executable(name) + ['--ros-args', '--params-file',
                                                             params], env))
            driver = _Lines(processes[-1].stdout)
            if not driver.wait_for('sampling at', READY_TIMEOUT_S):
                msg = f'{device}: the driver did not start:\n' + '\n'.join(driver.lines)
                raise RuntimeError(msg)
            time.sleep(duration_s)
            for process in reversed(processes):
                _stop(process)
            driver.wait_for('sampling: ', READY_TIMEOUT_S)
        finally:
            for process in processes + hogs:
                _stop(process)
    summary = next((line for line in driver.lines if 'sampling: ' in line), '')
    counts = [int(word) for word in summary.split('sampling: ')[1].replace(',', '').split()
              if word.isdigit()] if summary else []
    read, missed, failed, saturated = counts[:4] if counts else (0, -1, 0, 0)
    return {'device': device, 'hog': hog, 'missed': missed,
            'due': read + max(missed, 0) + failed + saturated}


def _missed_table(results) -> None:
    print(f'{"device":<10} {"sample Hz":>9} {"quiet: missed / due":>27} '
          f'{"2 busy loops: missed / due":>34}')
    for device, sample_hz, _ in MISSED_DEVICES:
        cells = []
        for hog in (False, True):
            r = next(r for r in results if r['device'] == device and r['hog'] == hog)
            share = 100.0 * r['missed'] / r['due'] if r['due'] else float('nan')
            cells.append(f'{r["missed"]} / {r["due"]} ({share:.2f} %)')
        print(f'{device:<10} {sample_hz:>9} {cells[0]:>27} {cells[1]:>34}')


def _device_table(results) -> tuple:
    """Print part (a)'s table and verdicts; give the tracking's and the learning's rise, %."""
    print(f'{"node":<13} {"raw msgs":>8} {"not out":>7} {"missed reads":>12} {"p50 ms":>7} '
          f'{"p99 ms":>7} {"+p50 ms":>7} {"+p99 ms":>7} {"CPU % node":>10} {"us/msg":>7} '
          f'{"driver":>6}')
    for r in results:
        def q(values, p):
            return float(np.percentile(values, p)) if len(values) else float('nan')
        cpu = r['cpu'] + [float('nan')] * (2 - len(r['cpu']))
        driver = 'same' if r['node'] == 'bringup' else f'{cpu[1]:.1f}'
        print(f'{r["node"]:<13} {r["raw"]:>8} {r["lost"]:>7} {r["missed_reads"]:>12} '
              f'{q(r["latency_ms"], 50):>7.3f} {q(r["latency_ms"], 99):>7.3f} '
              f'{q(r["added_ms"], 50):>7.3f} {q(r["added_ms"], 99):>7.3f} {cpu[0]:>10.1f} '
              f'{r["us_per_msg"]:>7.1f} {driver:>6}')
    for r in results:
        if r['node'] != 'relay':
            lost = r['lost'] + max(r['missed_reads'], 0)
            print(f'  {r["node"]}: zero lost samples at 1 kHz publish, 5.7 kHz sampling: '
                  f'{"met" if lost == 0 and r["missed_reads"] == 0 else "NOT met"} '
                  f'({r["missed_reads"]} device reads missed, {r["lost"]} raw messages not '
                  f'compensated)')
    by = {r['node']: r['us_per_msg'] for r in results}
    rise = by['unlearnt'] - by['untracked']
    print(f'  bias tracking: node CPU {by["unlearnt"]:.1f} us a message with, '
          f'{by["untracked"]:.1f} us without: {rise:+.1f} us, '
          f'{100.0 * rise / by["untracked"]:+.1f} % of the node\'s own (target < 10 %: '
          f'{"met" if rise < 0.1 * by["untracked"] else "NOT met"})')
    learning = by['compensation'] - by['unlearnt']
    print(f'  field learning: node CPU {by["compensation"]:.1f} us a message with, '
          f'{by["unlearnt"]:.1f} us without (tracking on): {learning:+.1f} us, '
          f'{100.0 * learning / by["unlearnt"]:+.1f} % (target < 5 %: '
          f'{"met" if learning < 0.05 * by["unlearnt"] else "NOT met"}); the relay '
          f'{by["relay"]:.1f} us')
    return 100.0 * rise / by['untracked'], 100.0 * learning / by['unlearnt']


def _figures(name: str, rate_hz: float, sent, records, feed_s: float, cpu: list) -> dict:
    mine = records[np.isin(records[:, 0], sent)]
    _, index = np.unique(mine[:, 0], return_index=True)
    mine = mine[index]
    sequence = np.sort(mine[:, 3])
    return {'rate': rate_hz, 'node': name, 'sent': len(sent), 'feed_s': feed_s,
            'received': len(mine), 'latency_ms': (mine[:, 1] - mine[:, 0]) / 1e6,
            'at_node_ms': (mine[:, 2] - mine[:, 0]) / 1e6,
            # Gaps in the node's own publication numbers: lost between node and receiver.
            'after_node': int(np.sum(np.diff(sequence) - 1)) if len(sequence) > 1 else 0,
            'cpu': cpu}


def _pool(runs) -> dict:
    """Sum counts, pool latencies and average CPU over runs of one node at one rate."""
    def percentile(values, q):
        return float(np.percentile(values, q)) if len(values) else float('nan')

    sent, received = sum(r['sent'] for r in runs), sum(r['received'] for r in runs)
    feed_s = sum(r['feed_s'] for r in runs)
    latency = np.concatenate([r['latency_ms'] for r in runs])
    at_node = np.concatenate([r['at_node_ms'] for r in runs])
    cpu = np.sum([np.multiply(r['cpu'], r['feed_s']) for r in runs], axis=0) / feed_s
    return {'rate': runs[0]['rate'], 'node': runs[0]['node'], 'sent': sent,
            'send_rate': sent / feed_s, 'received': received, 'drops': sent - received,
            'after_node': sum(r['after_node'] for r in runs),
            'p50': percentile(latency, 50), 'p99': percentile(latency, 99),
            'max': percentile(latency, 100), 'node_p99': percentile(at_node, 99),
            'cpu': 100.0 * cpu[0], 'cpu_us': 1e6 * cpu[0] * feed_s / max(received, 1),
            'feeder_cpu': 100.0 * cpu[1], 'receiver_cpu': 100.0 * cpu[2]}


def _print_table(rows) -> None:
    print(f'{"rate Hz":>8} {"node":<13} {"sent":>7} {"sent/s":>7} {"received":>8} '
          f'{"drops":>6} {"p50 ms":>7} {"p99 ms":>7} {"max ms":>7} {"CPU %":>6} '
          f'{"us/out":>6} {"feeder%":>7} {"recv%":>5}')
    for r in rows:
        print(f'{r["rate"]:>8.0f} {r["node"]:<13} {r["sent"]:>7} {r["send_rate"]:>7.0f} '
              f'{r["received"]:>8} {r["drops"]:>6} {r["p50"]:>7.3f} {r["p99"]:>7.3f} '
              f'{r["max"]:>7.2f} {r["cpu"]:>6.1f} {r["cpu_us"]:>6.0f} '
              f'{r["feeder_cpu"]:>7.1f} {r["receiver_cpu"]:>5.1f}')


def _verdicts(pooled, rates) -> None:
    by = {(r['rate'], r['node']): r for r in pooled}
    for rate in rates:
        relay, compensation = by[(rate, 'relay')], by[(rate, 'compensation')]
        ratio = compensation['p99'] / relay['p99']
        print(f'  {rate:g} Hz: p99 compensation / relay {ratio:.2f}x (target <= '
              f'{P99_TARGET:.2f}: {"met" if ratio <= P99_TARGET else "NOT met"}); drops '
              f'compensation {compensation["drops"]}, relay {relay["drops"]} (target: no more '
              f'than the relay: {"met" if compensation["drops"] <= relay["drops"] else "NOT met"}'
              f'); p99 from stamp to the node publishing: compensation '
              f'{compensation["node_p99"]:.3f} ms, relay {relay["node_p99"]:.3f} ms')
        if max(compensation['drops'], relay['drops']) > 0.01 * compensation['sent']:
            print('    with drops the input queues are full: latency is then about queue depth '
                  '/ rate for both, so the ratio says little')
        lost = {n: by[(rate, n)]['after_node'] for n in NODES if by[(rate, n)]['after_node']}
        if lost:
            print(f'    of those drops, lost between node and receiver: {lost}')
        short = [n for n in NODES if by[(rate, n)]['send_rate'] < 0.99 * rate]
        if short:
            print(f'    the feeder fell short of {rate:g} Hz for {", ".join(short)}: see sent/s')
    if 1000.0 in rates:
        drops = by[(1000.0, 'compensation')]['drops']
        print(f'  zero drops at 1 kHz (compensation): {"met" if drops == 0 else "NOT met"} '
              f'({drops} dropped)')


def _sustained(pooled) -> None:
    for name in NODES:
        sustained = None
        for r in sorted((r for r in pooled if r['node'] == name), key=lambda r: r['rate']):
            if r['drops']:
                break
            sustained = r['rate']
        print(f'  highest rate with zero drops (and at every lower rate tried), {name}: '
              f'{"none of those tried" if sustained is None else f"{sustained:g} Hz"}')


def _run(rates, rounds: int, duration_s: float, warmup_s: float, env) -> list:
    runs, turn = [], 0
    for round_ in range(rounds):
        for rate in rates:
            # Alternate which node goes first, so a drift of the machine favours neither.
            for name in NODES if turn % 2 == 0 else reversed(NODES):
                print(f'  round {round_ + 1}/{rounds}: {name} at {rate:g} Hz for '
                      f'{duration_s:g} s', flush=True)
                runs.append(measure(name, rate, duration_s, warmup_s, env))
            turn += 1
    return runs


def _device_part(args, env) -> None:
    """Part (a), ``--device-rounds`` times; the median rises of the tracking's, learning's CPU."""
    print(f'(a) driver sampling the simulated ADIS16130 at 5.7 kHz, publishing at '
          f'{DEVICE_PUBLISH_HZ:g} Hz, into each node for {args.device_duration:g} s',
          flush=True)
    rises = []
    for _ in range(args.device_rounds):
        results = [measure_device(name, args.device_duration, args.warmup, env)
                   for name in DEVICE_NODES]
        print('latency: arrival of imu/data - its stamp (the mean time of the samples it '
              'averages); +: arrival of imu/data - arrival of the same imu/data_raw')
        rises.append(_device_table(results))
        print(flush=True)
    if len(rises) < 2:
        return
    for index, (what, target) in enumerate((('bias tracking', 10.0), ('field learning', 5.0))):
        each = [r[index] for r in rises]
        median = float(np.median(each))
        listed = ', '.join(f'{r:+.1f}' for r in each)
        verdict = 'met' if median < target else 'NOT met'
        print(f"  {what} over {len(rises)} rounds: median rise {median:+.1f} % of the node's "
              f'own CPU a message (rounds: {listed}; target < {target:g} %: {verdict})',
              flush=True)


def _process_part(count: int) -> None:
    """Part (d): the tracking's and the learning's CPU a message through ``process``."""
    figures = measure_process(count, 5)
    rise = figures['with'] - figures['without']
    print(f'(d) CompensationNode.process in this process, one message at a time, {count} '
          f'messages at rest, best of 5 alternating rounds: {figures["without"]:.1f} us a '
          f'message without bias tracking, {figures["with"]:.1f} us with '
          f'({figures["updates"]} windows learnt): {rise:+.1f} us a message', flush=True)
    for key, what in (('learning', f'with field learning too ({figures["learnt_windows"]} '
                                   'windows used, no renewal: the prior in use)'),
                      ('renewed', 'with a renewed curve in use (read from the state file: '
                                  f'{"in use" if figures["renewed_in_use"] else "NOT in use"})')):
        learning = figures[key] - figures['with']
        print(f'    {what}: {figures[key]:.1f} us a message: {learning:+.1f} us, '
              f'{100.0 * learning / figures["with"]:+.1f} % over tracking alone (target < 5 %: '
              f'{"met" if learning < 0.05 * figures["with"] else "NOT met"})', flush=True)
    _split_part(count)
    print(flush=True)


def _split_part(count: int) -> None:
    """Part (d), split: per sample against per window and per state write."""
    split = measure_split(count, 5)
    print(f'    split, each message timed, lowest of 5 alternating runs: messages that closed no '
          f'window, median '
          f'{split["with"]["median_us"]:.1f} us tracking alone, '
          f'{split["learning"]["median_us"]:.1f} with learning '
          f'({split["learning"]["median_us"] - split["with"]["median_us"]:+.1f} us per sample)',
          flush=True)
    for key in ('with', 'learning'):
        s = split[key]
        print(f'      {key:<8}: {s["windows"]} windows closed without a write {s["window_ms"]:.2f}'
              f' ms, {s["writes"]} state writes {s["write_ms"]:.2f} ms: '
              f'{1e3 * (s["window_ms"] + s["write_ms"]) / count:.2f} us a message over {count}',
              flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--rates', type=float, nargs='+',
                        default=[1000.0, 2000.0, 4000.0, 5700.0])
    parser.add_argument('--device-duration', type=float, default=20.0,
                        help='seconds per device run (part a); 0 skips part a')
    parser.add_argument('--device-rounds', type=int, default=1,
                        help='repeat part a; the tracking and learning verdicts take the '
                        'median rise')
    parser.add_argument('--process-messages', type=int, default=20000,
                        help='messages per run of part d; 0 skips part d')
    parser.add_argument('--missed-duration', type=float, default=20.0,
                        help='seconds per missed-reads run (part c), quiet and beside a CPU '
                        'hog; 0 skips part c')
    parser.add_argument('--duration', type=float, default=30.0,
                        help='feed seconds per run (part b); 0 skips part b')
    parser.add_argument('--warmup', type=float, default=1.0,
                        help='seconds fed at the same rate before each measured window')
    parser.add_argument('--sweep', action='store_true',
                        help='instead: find the highest rate with zero drops')
    parser.add_argument('--sweep-rates', type=float, nargs='+', default=list(SWEEP_RATES))
    parser.add_argument('--sweep-duration', type=float, default=10.0)
    parser.add_argument('--rounds', type=int, default=1,
                        help='repeat the alternating runs; figures pool all rounds')
    # Child roles (the benchmark starts these itself).
    parser.add_argument('--relay', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--feeder', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--receiver', help=argparse.SUPPRESS)
    parser.add_argument('--raw-too', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--rate', type=float, help=argparse.SUPPRESS)
    parser.add_argument('--out', help=argparse.SUPPRESS)
    args, _ = parser.parse_known_args()
    if args.relay:
        return relay_main()
    if args.feeder:
        return feeder_main(args.rate, args.duration, args.warmup, args.out)
    if args.receiver:
        return receiver_main(args.receiver, ('imu/data_raw', 'imu/data') if args.raw_too
                             else ('imu/data',))

    env = dict(os.environ, ROS_DOMAIN_ID=str(102 + os.getpid() % 100),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    env.pop('ROS_STATIC_PEERS', None)
    if args.device_duration > 0.0 and not args.sweep:
        _device_part(args, env)
    if args.process_messages > 0 and not args.sweep:
        _process_part(args.process_messages)
    if args.missed_duration > 0.0 and not args.sweep:
        print(f'(c) missed device reads: driver into a compensation node, '
              f'{args.missed_duration:g} s per run, quiet and beside two busy loops '
              f'({os.cpu_count()} CPUs)', flush=True)
        missed = [measure_missed(device, publish_hz, args.missed_duration, hog, env)
                  for device, _, publish_hz in MISSED_DEVICES for hog in (False, True)]
        _missed_table(missed)
        print(flush=True)
    if not args.sweep:
        if args.duration <= 0.0:
            return 0
        print('(b) feeder at fixed rates', flush=True)
    rates = sorted(args.sweep_rates) if args.sweep else args.rates
    duration = args.sweep_duration if args.sweep else args.duration
    print(f'Raw Temperature + Imu fed at {", ".join(f"{r:g}" for r in rates)} Hz for '
          f'{duration:g} s per run (after {args.warmup:g} s warm-up), eeprom model, '
          f'{os.cpu_count()} CPUs, domain {env["ROS_DOMAIN_ID"]}', flush=True)
    runs = _run(rates, args.rounds, duration, args.warmup, env)
    print('latency: arrival of imu/data at the receiver - send time the feeder stamped')
    print('CPU %: process of the node under test (all threads), % of one core over the feed '
          'window; us/out: its CPU time per sample it forwarded; feeder%, recv%: the other two '
          'processes')
    if args.rounds > 1:
        print('each run:')
        _print_table([_pool([run]) for run in runs])
        print(f'pooled over {args.rounds} rounds:')
    pooled = [_pool([r for r in runs if (r['rate'], r['node']) == (rate, name)])
              for rate in rates for name in NODES]
    _print_table(pooled)
    _verdicts(pooled, rates)
    if args.sweep:
        _sustained(pooled)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
