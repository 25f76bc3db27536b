"""
Shared helpers of the ROS tests: node subprocesses, a probe node, polling with deadlines.

Nodes run as real processes (the console scripts next to this interpreter)
and talk over DDS in the private domain test/conftest.py sets up. The probe
is an rclpy node in the test process with its own Context, so each test
starts and shuts down its own ROS instance.
"""

import atexit
from collections import defaultdict
import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from mlx_tempcomp.parameters.files import nest_parameters, write_parameter_file
from mlx_tempcomp.ros import messages
from mlx_tempcomp.ros.qos import EEPROM_QOS, SENSOR_INPUT_QOS
import pytest
from rcl_interfaces.srv import GetParameters, SetParameters
import rclpy
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import UInt8MultiArray

BIN = os.path.dirname(sys.executable)

# Fast DDS announces a new participant 5 times in 0.5 s, then every 3 s: a node whose
# first announcements are missed is discovered about 3 s late, which half of the test
# runs hit. Announcing for 3 s, then twice a second, makes discovery take well under
# 1 s. Set before the first participant in this process; node subprocesses inherit it.
DISCOVERY_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="mlx_tempcomp_tests" is_default_profile="true">
    <rtps>
      <builtin>
        <discovery_config>
          <initialAnnouncements>
            <count>30</count>
            <period><nanosec>100000000</nanosec></period>
          </initialAnnouncements>
          <leaseAnnouncement><sec>0</sec><nanosec>500000000</nanosec></leaseAnnouncement>
        </discovery_config>
      </builtin>
    </rtps>
  </participant>
</profiles>
"""


def _use_fast_discovery() -> None:
    if 'FASTRTPS_DEFAULT_PROFILES_FILE' in os.environ or \
            'FASTDDS_DEFAULT_PROFILES_FILE' in os.environ:
        return   # someone chose a profile: keep it
    folder = tempfile.mkdtemp(prefix='mlx_tempcomp_dds_')
    atexit.register(shutil.rmtree, folder, True)
    path = os.path.join(folder, 'fastdds_profile.xml')
    with open(path, 'w') as stream:
        stream.write(DISCOVERY_PROFILE)
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = path
    os.environ['FASTDDS_DEFAULT_PROFILES_FILE'] = path


_use_fast_discovery()
# How often Probe.spin_until checks its condition.
CHECK_PERIOD_S = 0.05
SPIN_SLICE_S = 0.01
# Service requests sent at once: fewer than the 10 a service queues by default.
REQUESTS_IN_FLIGHT = 8
DRIVER_DIAGNOSTIC = 'driver_node: '            # name prefix; the source follows
COMPENSATION_DIAGNOSTIC = 'compensation_node: compensation'
# The probe records streams with a deep queue: on this 2-core machine it shares the CPU
# with the nodes, and a burst must wait for it rather than overwrite older samples.
RECORD_QOS = QoSProfile(depth=5000, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
# A replay that checks content needs every sample: a lost input changes the node's history
# state, so every later output. Best effort drops messages on a starved machine; these
# streams are made reliable, with a deep history, by the nodes' standard qos_overrides.
RELIABLE_RECORD_QOS = QoSProfile(depth=5000, history=HistoryPolicy.KEEP_LAST,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.VOLATILE)
# The model alone, for tests of what a model computes: bias tracking would take off the
# offset it learns while the simulated gyro rests (ros/test_tracking.py tests it).
UNTRACKED = {'bias_tracking.enabled': False}
REPLAY_INPUTS = ('imu/data_raw', 'imu/temperature_raw', 'imu/temperature_raw/x',
                 'imu/temperature_raw/y', 'imu/temperature_raw/z', 'imu/temperature_2_raw',
                 'imu/supply_voltage')


def executable(name: str) -> str:
    """Return the console script ``name`` of this virtual environment."""
    return os.path.join(BIN, name)


def write_params(path, node_name: str, values: dict) -> str:
    """Write a ROS 2 parameter file for ``node_name``; return its path."""
    return write_sections(path, {node_name: values})


def write_sections(path, sections: dict) -> str:
    """Write a ROS 2 parameter file with a section per node name; return its path."""
    write_parameter_file(path, {node: {'ros__parameters': nest_parameters(values)}
                                for node, values in sections.items()})
    return str(path)


class NodeProcess:
    """One node running as a subprocess; its output goes to a log file."""

    def __init__(self, name: str, command: list, log_path, env: dict):
        self.name = name
        self.command = command
        self.log_path = str(log_path)
        self._log = open(self.log_path, 'wb')
        self.interrupted = False
        self.process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=self._log,
                                        stderr=subprocess.STDOUT, env=env)

    @property
    def pid(self) -> int:
        return self.process.pid

    def output(self) -> str:
        """Everything the process printed so far (stdout and stderr)."""
        if not self._log.closed:
            self._log.flush()
        with open(self.log_path, 'rb') as stream:
            return stream.read().decode(errors='replace')

    def running(self) -> bool:
        return self.process.poll() is None

    def wait(self, timeout: float) -> int:
        """Wait for the process to exit; return its exit code."""
        try:
            return self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f'{self.name} still running after {timeout} s; output:\n'
                                 f'{self.output()}') from None

    def signal(self, signum: int) -> None:
        if self.running():
            self.process.send_signal(signum)
            self.interrupted = self.interrupted or signum == signal.SIGINT

    def stop(self, timeout: float = 5.0) -> int:
        """Ask the node to shut down (SIGINT), kill it if it does not; return the exit code."""
        if self.running():
            if not self.interrupted:   # a second SIGINT could interrupt the clean-up
                self.signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout)
        self._log.close()
        return self.process.returncode

    def kill(self) -> None:
        """SIGKILL: no clean-up at all, as a crash or power cut would."""
        if self.running():
            self.process.kill()
        self.process.wait(5.0)


class Launcher:
    """Starts node subprocesses for one test and stops every one of them at the end."""

    def __init__(self, folder):
        self.folder = folder
        self.processes = []
        self.env = dict(os.environ, PYTHONUNBUFFERED='1',
                        RCUTILS_LOGGING_BUFFERED_STREAM='0',
                        RCUTILS_COLORIZED_OUTPUT='0',
                        ROS_LOG_DIR=str(folder / 'ros_log'))

    def start(self, executable_name: str, node_name: str, params: dict = None,
              extra_args=(), label: str = None) -> NodeProcess:
        """Start ``executable_name`` with ``params`` in a parameter file for ``node_name``."""
        label = label or f'{node_name}_{len(self.processes)}'
        command = [executable(executable_name), '--ros-args']
        if params is not None:
            path = write_params(self.folder / f'{label}.yaml', node_name, params)
            command += ['--params-file', path]
        command += list(extra_args)
        process = NodeProcess(label, command, self.folder / f'{label}.log', self.env)
        self.processes.append(process)
        return process

    def driver(self, params: dict = None, label: str = None) -> NodeProcess:
        return self.start('driver_node', 'driver_node', params, label=label)

    def compensation(self, params: dict = None, label: str = None) -> NodeProcess:
        return self.start('compensation_node', 'compensation_node', params, label=label)

    def stop_all(self) -> None:
        """Stop every process: SIGINT to all first, so they shut down side by side."""
        for process in self.processes:
            process.signal(signal.SIGINT)
        for process in self.processes:
            try:
                process.stop()
            except Exception:  # noqa: B902 - keep stopping the others
                process.kill()

    def logs(self) -> str:
        return '\n'.join(f'--- {p.name} ({" ".join(p.command)}):\n{p.output()}'
                         for p in self.processes)


@pytest.fixture
def launcher(tmp_path):
    """Give a `Launcher`; stop its processes even when the test fails."""
    launcher = Launcher(tmp_path)
    yield launcher
    launcher.stop_all()


class Probe:
    """An rclpy node with its own Context that records what it receives."""

    created = 0

    def __init__(self, name: str = 'probe'):
        Probe.created += 1
        name = f'{name}_{Probe.created}'   # unique: two probes may overlap in one process
        self.context = Context()
        # No log file in ~/.ros/log, and pytest keeps its own signal handlers.
        rclpy.init(args=['probe', '--ros-args', '--disable-external-lib-logs'],
                   context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        # No parameter services of its own: nobody asks the probe.
        self.node = rclpy.create_node(name, context=self.context, start_parameter_services=False)
        # rclpy's events executor (rclpy.experimental, in C++) takes each message as it comes
        # in; the SingleThreadedExecutor built a wait set of every entity in Python for each
        # one and took two and a half times the CPU on a 5 x real-time pipeline. What keeps
        # the nodes off it (docs/ros.md, "Executors") is not the probe's: it never spin()s
        # and serves no coroutine callback. It turns faulthandler on for sys.stderr, which
        # must then be a file: in a test that captures output (capsys) it is not.
        with contextlib.redirect_stderr(sys.__stderr__):
            self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received = defaultdict(list)
        self.diagnostics = defaultdict(list)   # status name -> [DiagnosticStatus]
        self._clients = {}

    def subscribe(self, msg_type, topic: str, qos: QoSProfile = RECORD_QOS) -> list:
        """Record every message on ``topic``; return the list they go into."""
        messages_in = self.received[topic]
        self.node.create_subscription(msg_type, topic, messages_in.append, qos)
        return messages_in

    def subscribe_diagnostics(self) -> None:
        def on_diagnostics(array: DiagnosticArray) -> None:
            for status in array.status:
                self.diagnostics[status.name].append(status)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 50)

    def subscribe_pipeline(self, axes=('z',)) -> None:
        """Record the raw and compensated topics, the EEPROM and the diagnostics."""
        for topic in ('imu/data_raw', 'imu/data'):
            self.subscribe(Imu, topic)
        for topic in ('imu/temperature_raw', 'imu/temperature'):
            self.subscribe(Temperature, topic)
        if len(axes) > 1:
            for axis in axes:
                self.subscribe(Temperature, f'imu/temperature_raw/{axis}')
        self.subscribe(UInt8MultiArray, 'imu/eeprom', EEPROM_QOS)
        self.subscribe_diagnostics()

    def raw_publishers(self, timeout: float, logs=None) -> tuple:
        """Publish imu/data_raw and imu/temperature_raw; give them once a node compensates."""
        imu = self.node.create_publisher(Imu, 'imu/data_raw', SENSOR_INPUT_QOS)
        temperature = self.node.create_publisher(Temperature, 'imu/temperature_raw',
                                                 SENSOR_INPUT_QOS)
        self.spin_until(lambda: imu.get_subscription_count() and
                        temperature.get_subscription_count() and
                        self.node.count_publishers('imu/data'),
                        timeout, 'the compensation node', logs)
        return imu, temperature

    def clear(self, keep=('imu/eeprom',)) -> None:
        """Forget what was received so far (but the topics in ``keep``)."""
        for topic, received in self.received.items():
            if topic not in keep:
                received.clear()

    def wait_streaming(self, topics, timeout: float, logs=None) -> None:
        """Spin until messages arrive on every topic in ``topics``, then clear them all."""
        self.clear()
        self.spin_until(lambda: all(self.received[t] for t in topics), timeout,
                        f'messages on {", ".join(topics)}', logs)
        self.clear()

    def spin_once(self, timeout: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    def spin_for(self, seconds: float) -> None:
        """Take every callback that becomes ready within ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            # A short wait each call (the executor takes events in the order they came), so
            # the loop ends close to its time.
            self.spin_once(SPIN_SLICE_S)

    def spin_until(self, condition, timeout: float, what: str, logs=None):
        """
        Spin until ``condition()`` is truthy and return its value; fail after ``timeout``.

        The condition is checked every CHECK_PERIOD_S, with every message that came in
        between taken: one message per check let a costly condition (pairing thousands of
        stamps) fall behind a 2,000 message/s stream until its queues overflowed.
        """
        deadline = time.monotonic() + timeout
        while True:
            value = condition()
            if value:
                return value
            if time.monotonic() > deadline:
                text = f'timed out after {timeout:g} s waiting for {what}'
                if logs is not None:
                    text += '\n' + logs.logs()
                raise AssertionError(text)
            self.spin_for(CHECK_PERIOD_S)

    def drain(self, quiet_s: float = 0.2, timeout: float = 5.0) -> None:
        """Take what is still queued: spin until nothing arrived for ``quiet_s``."""
        deadline = time.monotonic() + timeout
        last_total, last_change = -1, time.monotonic()
        while time.monotonic() < deadline:
            total = sum(len(r) for r in self.received.values())
            if total != last_total:
                last_total, last_change = total, time.monotonic()
            elif time.monotonic() - last_change > quiet_s:
                return
            self.spin_once(0.02)

    def wait_quiet(self, topics, quiet_s: float, timeout: float, logs=None) -> None:
        """Spin until nothing arrived on ``topics`` for ``quiet_s`` (a stream stopped)."""
        state = {'total': -1, 'since': time.monotonic()}

        def quiet():
            total = sum(len(self.received[t]) for t in topics)
            if total != state['total']:
                state['total'], state['since'] = total, time.monotonic()
            return time.monotonic() - state['since'] > quiet_s
        self.spin_until(quiet, timeout, f'{", ".join(topics)} to stop for {quiet_s:g} s', logs)

    def count(self, topic: str) -> int:
        return len(self.received[topic])

    def wait_count(self, topic: str, count: int, timeout: float, logs=None) -> list:
        """Spin until ``count`` more messages... in total arrived on ``topic``."""
        self.spin_until(lambda: len(self.received[topic]) >= count, timeout,
                        f'{count} messages on {topic} (got {len(self.received[topic])})',
                        logs)
        return self.received[topic]

    def wait_status(self, name_prefix: str, predicate, timeout: float, what: str, logs=None):
        """Spin until a new status of ``name_prefix`` satisfies ``predicate``; return it."""
        return self.wait_statuses({name_prefix: predicate}, timeout, what, logs)[name_prefix]

    def wait_statuses(self, predicates: dict, timeout: float, what: str, logs=None) -> dict:
        """
        Spin until, for each name prefix, a new status satisfies its predicate.

        The nodes publish diagnostics once a second each; waiting for all at once
        costs one period, not one per node. Return {prefix: the matching status}.
        """
        seen = {name: len(s) for name, s in self.diagnostics.items()}
        found = {}

        def all_found():
            for prefix, predicate in predicates.items():
                if prefix in found:
                    continue
                for name, statuses in self.diagnostics.items():
                    if name.startswith(prefix):
                        match = next((s for s in statuses[seen.get(name, 0):] if predicate(s)),
                                     None)
                        if match is not None:
                            found[prefix] = match
                            break
            return len(found) == len(predicates)
        self.spin_until(all_found, timeout,
                        f'{what} (still missing: {sorted(set(predicates) - set(found))})', logs)
        return found

    def client(self, srv_type, name: str):
        key = (srv_type, name)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(srv_type, name)
        return self._clients[key]

    def call_async(self, srv_type, name: str, request, timeout: float = 10.0):
        """Send a request once the service is there; return the future."""
        client = self.client(srv_type, name)
        self.spin_until(client.service_is_ready, timeout, f'service {name}')
        return client.call_async(request)

    def call(self, srv_type, name: str, request, timeout: float = 10.0):
        """Call a service and return its response (spinning meanwhile)."""
        future = self.call_async(srv_type, name, request, timeout)
        self.spin_until(future.done, timeout, f'a response of {name}')
        return future.result()

    def set_parameters(self, node_name: str, values: dict, timeout: float = 10.0) -> list:
        """Set parameters of a remote node; return the list of SetParametersResult."""
        request = SetParameters.Request()
        request.parameters = [Parameter(name, value=value).to_parameter_msg()
                              for name, value in values.items()]
        response = self.call(SetParameters, f'/{node_name}/set_parameters', request, timeout)
        return list(response.results)

    def get_parameters(self, node_name: str, names, timeout: float = 10.0) -> dict:
        """
        Read parameters of a remote node; unset ones come back as [].

        rclpy answers nothing at all when one name is unset (an array without
        a default), so those are asked one by one, a few requests at a time: a round
        trip costs a check period (a hundred names in turn took 5 s), and a service
        queues only 10 requests (the default QoS depth).
        """
        service = f'/{node_name}/get_parameters'
        response = self.call(GetParameters, service, GetParameters.Request(names=list(names)),
                             timeout)
        if len(response.values) == len(names):
            answers = list(response.values)
        else:
            answers = []
            for start in range(0, len(names), REQUESTS_IN_FLIGHT):
                futures = [self.call_async(GetParameters, service,
                                           GetParameters.Request(names=[name]), timeout)
                           for name in names[start:start + REQUESTS_IN_FLIGHT]]
                self.spin_until(lambda: all(f.done() for f in futures), timeout,
                                f'responses of {service}')
                answers += [f.result().values[0] if f.result().values else None
                            for f in futures]
        values = {}
        for name, value in zip(names, answers):
            python = None if value is None else parameter_value_to_python(value)
            if python is None:
                python = []
            elif not isinstance(python, (bool, int, float, str)):
                python = list(python)
            values[name] = python
        return values

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture
def probe():
    """Give a `Probe` and shut its context down afterwards."""
    probe = Probe()
    yield probe
    probe.close()


def status_values(status) -> dict:
    """Map a DiagnosticStatus's key/value pairs into a dict of strings."""
    return {kv.key: kv.value for kv in status.values}


def parse_list(text: str) -> list:
    """Parse a diagnostics list value such as '[1.5, 2]' into floats."""
    text = text.strip()
    assert text.startswith('[') and text.endswith(']'), text
    inner = text[1:-1].strip()
    return [float(v) for v in inner.split(',')] if inner else []


def by_stamp(msgs) -> dict:
    """Index messages by their header stamp in nanoseconds."""
    return {messages.stamp_to_ns(m.header.stamp): m for m in msgs}


def paired(probe) -> tuple:
    """
    Give the stamps of imu/data the probe saw with their raw inputs, and the three by stamp.

    The raw streams are best effort: on a loaded machine the probe may miss some, so tests
    wait for the pairs themselves.
    """
    out, raw = by_stamp(probe.received['imu/data']), by_stamp(probe.received['imu/data_raw'])
    temperature = by_stamp(probe.received['imu/temperature_raw'])
    return [s for s in out if s in raw and s in temperature], out, raw, temperature


def rates(msg: Imu) -> list:
    v = msg.angular_velocity
    return [v.x, v.y, v.z]


def simulated_driver_params(**overrides) -> dict:
    """
    Return parameters of a fast simulated driver: 100 Hz, 5 x real time, lossless.

    Lossless: on a loaded machine its clock lags instead of skipping samples, so
    what a test asserts of the stream does not depend on the machine's speed.
    """
    return {'publish_rate_hz': 100.0, 'sample_rate_hz': 100.0,
            'simulation.real_time_factor': 5.0, 'simulation.lossless': True, **overrides}


def start_pipeline(launcher, probe, driver: dict, compensation: dict, axes=('z',),
                   timeout: float = 30.0) -> dict:
    """
    Start the simulated driver and a compensation node on ``axes``; return their statuses.

    Returns once both report OK and the raw rate, raw temperature and compensated
    streams reach the probe, which has subscribed to them (and to the diagnostics)
    beforehand.
    """
    launcher.driver(simulated_driver_params(axes=list(axes), **driver))
    launcher.compensation({'axes': list(axes),
                           'recalibration.state_file': str(launcher.folder / 'zro.yaml'),
                           **compensation})
    statuses = probe.wait_statuses(
        {DRIVER_DIAGNOSTIC: lambda s: s.level == DiagnosticStatus.OK,
         COMPENSATION_DIAGNOSTIC: lambda s: s.level == DiagnosticStatus.OK},
        timeout, 'both nodes OK', launcher)
    # Each reader matches on its own: under load one can start a second of sensor time late.
    probe.wait_streaming(['imu/data_raw', 'imu/temperature_raw', 'imu/data'], timeout, launcher)
    return statuses


def first_line_with(text: str, needle: str) -> str:
    for line in text.splitlines():
        if needle in line:
            return line
    return ''


def reliable(topics, entity: str) -> dict:
    """Give the qos_overrides parameters that make ``entity`` of ``topics`` lose nothing."""
    return {f'qos_overrides./{topic}.{entity}.{policy}': value for topic in topics
            for policy, value in (('reliability', 'reliable'), ('depth', 5000))}


def start_model_replay(launcher, probe, tmp_path, bag, model_file: str,
                       driver_params: dict = None, timeout: float = 60.0, before_driver=None,
                       **params):
    """
    Start compensation_node on ``model_file``, then the bag driver at rate factor 0.

    ``params`` (and the replay's own: state file, QoS, no bias tracking unless they
    say) come in a file after ``model_file``, so they win over it. ``before_driver()``
    runs once the node publishes, before the driver starts (e.g. to send it rest hints).
    """
    probe.subscribe(Imu, 'imu/data', RELIABLE_RECORD_QOS)
    probe.subscribe_diagnostics()
    # A state file of its own: a learned ZRO offset from elsewhere would shift every sample.
    replay = write_params(tmp_path / 'replay_compensation.yaml', 'compensation_node', {
        'recalibration.state_file': str(tmp_path / 'zro.yaml'), **UNTRACKED,
        **reliable(REPLAY_INPUTS, 'subscription'), **reliable(['imu/data'], 'publisher'),
        **params})
    launcher.start('compensation_node', 'compensation_node',
                   extra_args=['--params-file', model_file, '--params-file', replay],
                   label='compensation')
    probe.spin_until(lambda: probe.node.count_publishers('/imu/data') > 0, timeout,
                     'the compensation node publishing imu/data', launcher)
    if before_driver is not None:
        before_driver()
    # hold: the driver stays up after the replay, so finish_model_replay hears 'finished'; a
    # long pace time-out: a node stalled by a loaded machine is waited for, not overrun.
    return launcher.driver({'source': 'bag', 'bag.path': str(bag), 'bag.rate_factor': 0.0,
                            'bag.on_end': 'hold', 'bag.pace_timeout_s': 60.0,
                            **reliable(REPLAY_INPUTS, 'publisher'),
                            **(driver_params or {})}, label='driver')


def finish_model_replay(launcher, probe, stamps_ns, messages_in_bag: int,
                        timeout: float = 60.0) -> list:
    """Wait for the replay and every compensated sample; give their rates in stamp order."""
    status = probe.wait_status(DRIVER_DIAGNOSTIC,
                               lambda s: status_values(s).get('state') == 'finished',
                               timeout, 'the replay to finish', launcher)
    assert status_values(status)['published'] == str(messages_in_bag)
    assert status_values(status)['pace_timeouts'] == '0'
    samples = len(stamps_ns)
    probe.spin_until(lambda: probe.count('imu/data') >= samples, 30.0,
                     f'{samples} compensated samples', launcher)
    probe.drain()
    received = by_stamp(probe.received['imu/data'])
    missing = [s for s in stamps_ns if s not in received]
    assert not missing, f'{len(missing)} stamps missing, first {missing[0]}'
    assert len(received) == samples
    return [rates(received[s]) for s in stamps_ns]


def start_in_namespace(launcher, executable_name: str, namespace: str, node: str,
                       params: dict, tmp_path):
    """
    Start ``executable_name`` as /``namespace``/``node`` with a state file of its own.

    Several pipelines run side by side that way; a node renamed from its default
    (``chain_node``) publishes on ``imu/data_chain``, beside the one it shares a driver with.
    """
    label = f'{namespace}_{node}'
    args = ['-r', f'__ns:=/{namespace}']
    if node not in ('driver_node', 'compensation_node', 'bringup'):
        args += ['-r', f'__node:={node}', '-r', f'imu/data:=imu/data_{node[:-5]}']
    # A /** section: a node-name section would miss the namespaced node.
    return launcher.start(executable_name, '/**', {
        **simulated_driver_params(), 'recalibration.state_file': str(tmp_path / label),
        **params}, extra_args=args, label=label)
