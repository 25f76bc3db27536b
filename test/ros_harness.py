"""
Shared helpers of the ROS tests: node subprocesses, a probe node, polling with deadlines.

Nodes run as real processes (the console scripts next to this interpreter)
and talk over DDS in the private domain test/conftest.py sets up. The probe
is an rclpy node in the test process with its own Context, so each test
starts and shuts down its own ROS instance.
"""

from collections import defaultdict
import math
import os
import signal
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from mlx_tempcomp.ros import messages
from mlx_tempcomp.ros.qos import EEPROM_QOS, SENSOR_INPUT_QOS
import pytest
from rcl_interfaces.srv import GetParameters, SetParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import UInt8MultiArray
import yaml

BIN = os.path.dirname(sys.executable)
DRIVER_DIAGNOSTIC = 'driver_node: '            # name prefix; the source follows
COMPENSATION_DIAGNOSTIC = 'compensation_node: compensation'


def executable(name: str) -> str:
    """Return the console script ``name`` of this virtual environment."""
    return os.path.join(BIN, name)


def nest(values: dict) -> dict:
    """Turn dotted parameter names into the nested mapping of a parameter file."""
    nested = {}
    for name, value in values.items():
        *groups, leaf = name.split('.')
        level = nested
        for group in groups:
            level = level.setdefault(group, {})
        level[leaf] = value
    return nested


class _QuotingDumper(yaml.SafeDumper):
    """Quote every string: rcl reads a bare y or n as a boolean (YAML 1.1)."""


_QuotingDumper.add_representer(
    str, lambda dumper, value: dumper.represent_scalar('tag:yaml.org,2002:str', value,
                                                       style="'"))


def write_params(path, node_name: str, values: dict) -> str:
    """Write a ROS 2 parameter file for ``node_name``; return its path."""
    with open(path, 'w') as stream:
        yaml.dump({node_name: {'ros__parameters': nest(values)}}, stream,
                  Dumper=_QuotingDumper)
    return str(path)


class NodeProcess:
    """One node running as a subprocess; its output goes to a log file."""

    def __init__(self, name: str, command: list, log_path, env: dict):
        self.name = name
        self.command = command
        self.log_path = str(log_path)
        self._log = open(self.log_path, 'wb')
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

    def stop(self, timeout: float = 5.0) -> int:
        """Ask the node to shut down (SIGINT), kill it if it does not; return the exit code."""
        if self.running():
            self.process.send_signal(signal.SIGINT)
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

    def __init__(self, name: str = 'probe'):
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received = defaultdict(list)
        self.diagnostics = defaultdict(list)   # status name -> [DiagnosticStatus]
        self._clients = {}

    def subscribe(self, msg_type, topic: str, qos: QoSProfile = SENSOR_INPUT_QOS) -> list:
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

    def spin_once(self, timeout: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    def spin_until(self, condition, timeout: float, what: str, logs=None):
        """Spin until ``condition()`` is truthy and return its value; fail after ``timeout``."""
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
            self.spin_once()

    def spin_for(self, seconds: float) -> None:
        """Keep receiving for ``seconds`` (wall time)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.spin_once(min(0.05, max(0.0, deadline - time.monotonic())))

    def count(self, topic: str) -> int:
        return len(self.received[topic])

    def wait_count(self, topic: str, count: int, timeout: float, logs=None) -> list:
        """Spin until ``count`` more messages... in total arrived on ``topic``."""
        self.spin_until(lambda: len(self.received[topic]) >= count, timeout,
                        f'{count} messages on {topic} (got {len(self.received[topic])})',
                        logs)
        return self.received[topic]

    def last_status(self, name_prefix: str):
        """The latest diagnostic status whose name starts with ``name_prefix``, or None."""
        latest = None
        for name, statuses in self.diagnostics.items():
            if name.startswith(name_prefix) and statuses:
                latest = statuses[-1]
        return latest

    def wait_status(self, name_prefix: str, predicate, timeout: float, what: str, logs=None):
        """Spin until a new status of ``name_prefix`` satisfies ``predicate``; return it."""
        seen = {name: len(s) for name, s in self.diagnostics.items()}

        def found():
            for name, statuses in self.diagnostics.items():
                if not name.startswith(name_prefix):
                    continue
                for status in statuses[seen.get(name, 0):]:
                    if predicate(status):
                        return status
            return None
        return self.spin_until(found, timeout, what, logs)

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
        a default), so those are asked one by one.
        """
        service = f'/{node_name}/get_parameters'
        response = self.call(GetParameters, service, GetParameters.Request(names=list(names)),
                             timeout)
        if len(response.values) == len(names):
            answers = list(response.values)
        else:
            answers = []
            for name in names:
                single = self.call(GetParameters, service, GetParameters.Request(names=[name]),
                                   timeout)
                answers.append(single.values[0] if single.values else None)
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


def rates(msg: Imu) -> list:
    v = msg.angular_velocity
    return [v.x, v.y, v.z]


def is_nan(value: float) -> bool:
    return isinstance(value, float) and math.isnan(value)


def base_compensation_params(state_file, **overrides) -> dict:
    """Compensation parameters that never touch ~/.ros: the state file goes to ``state_file``."""
    return {'recalibration.state_file': str(state_file), **overrides}


def simulated_driver_params(**overrides) -> dict:
    """A fast simulated driver: 100 Hz, 5 x real time."""
    return {'rate_hz': 100.0, 'simulation.real_time_factor': 5.0, **overrides}


def first_line_with(text: str, needle: str) -> str:
    for line in text.splitlines():
        if needle in line:
            return line
    return ''

