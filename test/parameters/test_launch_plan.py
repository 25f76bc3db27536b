"""
launch/mlx_tempcomp.launch.py: its arguments, and what it starts for them.

ROS 2's ``launch`` and ``launch_ros`` install with ROS, not from a package
index this machine reaches, so what the launch file starts is decided by
``mlx_tempcomp.parameters.launch_plan``, tested here on plain values. The launch
file itself is run twice: with the real ``launch`` where it is importable
(skipped here, with the reason), and here with stand-ins of the few launch
classes it uses, keyword for keyword as Jazzy declares them, to check its
wiring (argument names, what reaches each Node). test/ros/test_launch.py
starts the nodes as launch_ros would from a plan, over DDS.
"""

import importlib.util
from pathlib import Path
import sys
import types

from mlx_tempcomp.parameters.launch_plan import (launch_plan, LaunchedNode, ONE_PROCESS,
                                                 split_params_files, TWO_PROCESSES)
from mlx_tempcomp.parameters.specs import ParameterError
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
LAUNCH_FILE = ROOT / 'launch' / 'mlx_tempcomp.launch.py'
CONFIG = ROOT / 'config' / 'mlx_tempcomp.yaml'
# What mlx-tempcomp fit writes: the compensation node's section, by its relative name.
FITTED = """# Bias polynomials fitted by mlx-tempcomp fit from unit.csv
'compensation_node':
  'ros__parameters':
    'model': 'polynomial'
    'axes':
    - 'z'
    'polynomial':
      'reference_temperature_c': 25.0
      'bias':
        'z': [0.01, 0.002]
"""


@pytest.fixture
def fitted(tmp_path) -> Path:
    path = tmp_path / 'fitted.yaml'
    path.write_text(FITTED, encoding='utf-8')
    return path


def test_params_files_are_taken_in_order_and_bad_ones_refused(fitted, tmp_path):
    assert split_params_files(' a.yaml, b.yaml ') == ('a.yaml', 'b.yaml')
    assert split_params_files('[a.yaml, "b.yaml"]') == ('a.yaml', 'b.yaml')
    plan = launch_plan(f'{CONFIG},{fitted}')
    assert plan.params_files == (str(CONFIG), str(fitted))
    assert plan.namespace == '/' and plan.notes == ()
    assert plan.nodes == (LaunchedNode('driver_node', 'driver_node'),
                          LaunchedNode('compensation_node', 'compensation_node'))
    for text, message in (('', 'give one parameter file or several'),
                          (f'{fitted},', 'give one parameter file or several'),
                          (f'{CONFIG},{tmp_path}/fited.yaml',
                           f'params_file {tmp_path}/fited.yaml: No such file or directory'),
                          (str(ROOT / 'README.md'), 'is not YAML (line'),
                          (str(tmp_path), 'Is a directory')):
        with pytest.raises(ParameterError, match=message.replace('(', r'\(')):
            launch_plan(text)
    (tmp_path / 'list.yaml').write_text('- a\n- b\n', encoding='utf-8')
    with pytest.raises(ParameterError, match='not a ROS 2 parameter file'):
        launch_plan(str(tmp_path / 'list.yaml'))


def test_single_process_is_bringup_under_its_own_names(fitted):
    assert launch_plan(str(fitted), single_process='true').nodes == \
        (LaunchedNode('bringup', None),) == tuple(LaunchedNode(*n) for n in ONE_PROCESS)
    assert launch_plan(str(fitted), single_process='False').nodes == \
        tuple(LaunchedNode(*n) for n in TWO_PROCESSES)
    with pytest.raises(ParameterError, match="single_process 'yes': give true or false"):
        launch_plan(str(fitted), single_process='yes')


def test_a_namespace_resolves_relative_sections_in_a_copy(fitted, tmp_path):
    """A section ``compensation_node:`` is /compensation_node to rcl: in /left it would miss."""
    plan = launch_plan(f'{CONFIG}, {fitted}', 'left', folder=str(tmp_path / 'copies'))
    assert plan.namespace == '/left'
    # The shipped config has /** sections only: passed as it is.
    assert plan.params_files[0] == str(CONFIG)
    copy = Path(plan.params_files[1])
    assert copy.parent.parent == tmp_path / 'copies' and copy.name == 'fitted.yaml'
    assert copy.read_text() == FITTED.replace("'compensation_node':",
                                              "'/left/compensation_node':")
    assert plan.notes == (f'{fitted}: sections resolved in namespace /left (compensation_node '
                          f'-> /left/compensation_node): {copy}',)
    assert fitted.read_text() == FITTED, 'the given file is left alone'
    # Plain and absolute keys, wildcards: only the relative ones change.
    mixed = tmp_path / 'mixed.yaml'
    mixed.write_text('/**:\n  ros__parameters: {axes: [z]}\ndriver_node:  # the driver\n'
                     '  ros__parameters: {source: simulated}\n/right/compensation_node:\n'
                     '  ros__parameters: {model: eeprom}\n', encoding='utf-8')
    plan = launch_plan(str(mixed), 'imu', pushed_namespace='/robot1', folder=str(tmp_path))
    assert plan.namespace == '/robot1/imu'
    assert Path(plan.params_files[0]).read_text() == mixed.read_text().replace(
        'driver_node:', "'/robot1/imu/driver_node':")
    assert list(yaml.safe_load(Path(plan.params_files[0]).read_text())) == \
        ['/**', '/robot1/imu/driver_node', '/right/compensation_node']
    # Without a namespace, or absolute below a pushed one.
    assert launch_plan(str(fitted), '', pushed_namespace='/robot1').namespace == '/robot1'
    assert launch_plan(str(fitted), '/imu', pushed_namespace='/robot1').namespace == '/imu'
    assert launch_plan(str(fitted), '/', folder=str(tmp_path)).params_files == (str(fitted),)
    for bad in ('1imu', 'left imu', 'a//b', 'imu/~', '{x}'):
        with pytest.raises(ParameterError, match=f'namespace {bad!r}: a ROS namespace'):
            launch_plan(str(fitted), bad)


def load_launch_file(monkeypatch, tmp_path):
    """Import the launch file with an ament index that holds this package's config."""
    prefix = tmp_path / 'prefix'
    marker = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'mlx_tempcomp'
    marker.parent.mkdir(parents=True)
    marker.write_text('')
    (prefix / 'share' / 'mlx_tempcomp' / 'config').mkdir(parents=True)
    installed = prefix / 'share' / 'mlx_tempcomp' / 'config' / 'mlx_tempcomp.yaml'
    installed.write_bytes(CONFIG.read_bytes())
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    spec = importlib.util.spec_from_file_location('mlx_tempcomp_launch', LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, installed


EXPECTED_ARGUMENTS = ('params_file', 'namespace', 'single_process')


def expected_nodes(files: list, namespace, single: bool) -> list:
    """Give (package, executable, name, namespace, parameters) of each Node to start."""
    return [('mlx_tempcomp', executable, name, namespace, files)
            for executable, name in (ONE_PROCESS if single else TWO_PROCESSES)]


class StandIns:
    """The launch classes the launch file uses, with Jazzy's keywords; they record them."""

    def __init__(self):
        self.launch = types.ModuleType('launch')
        self.actions = types.ModuleType('launch.actions')
        self.substitutions = types.ModuleType('launch.substitutions')
        self.launch_ros = types.ModuleType('launch_ros')
        self.ros_actions = types.ModuleType('launch_ros.actions')
        self.launch.LaunchDescription = self.Recorded
        self.actions.DeclareLaunchArgument = self.DeclareLaunchArgument
        self.actions.LogInfo = self.LogInfo
        self.actions.OpaqueFunction = self.OpaqueFunction
        self.substitutions.LaunchConfiguration = self.LaunchConfiguration
        self.ros_actions.Node = self.Node

    def install(self, monkeypatch) -> None:
        for name, module in (('launch', self.launch), ('launch.actions', self.actions),
                             ('launch.substitutions', self.substitutions),
                             ('launch_ros', self.launch_ros),
                             ('launch_ros.actions', self.ros_actions)):
            monkeypatch.setitem(sys.modules, name, module)

    class Recorded:
        def __init__(self, entities):
            self.entities = list(entities)

    class DeclareLaunchArgument:
        def __init__(self, name, *, default_value=None, description=None, choices=None):
            self.name, self.default_value, self.choices = name, default_value, choices

    class LogInfo:
        def __init__(self, *, msg):
            self.msg = msg

    class OpaqueFunction:
        def __init__(self, *, function, args=None, kwargs=None):
            self.function = function

    class LaunchConfiguration:
        def __init__(self, variable_name, *, default=None):
            self.variable_name = variable_name

        def perform(self, context):
            return context.launch_configurations[self.variable_name]

    class Node:
        def __init__(self, *, executable, package=None, name=None, namespace=None,
                     exec_name=None, parameters=None, remappings=None, ros_arguments=None,
                     arguments=None, output='log'):
            self.row = (package, executable, name, namespace, parameters)


def test_the_launch_file_passes_the_plan_to_launch(monkeypatch, tmp_path, fitted):
    stand_ins = StandIns()
    stand_ins.install(monkeypatch)
    module, installed = load_launch_file(monkeypatch, tmp_path)
    description = module.generate_launch_description()
    declared = [e for e in description.entities if hasattr(e, 'default_value')]
    assert tuple(d.name for d in declared) == EXPECTED_ARGUMENTS
    defaults = {d.name: d.default_value for d in declared}
    assert defaults == {'params_file': str(installed), 'namespace': '',
                        'single_process': 'false'}
    function = [e for e in description.entities if hasattr(e, 'function')]
    assert len(function) == 1
    cases = ((defaults, [str(installed)], None, False),
             ({**defaults, 'params_file': f'{installed},{fitted}', 'namespace': 'left',
               'single_process': 'true'}, None, '/left', True),
             # Included under PushRosNamespace('robot1'): the config's /** sections as they are.
             ({**defaults, 'namespace': ''}, [str(installed)], '/robot1', False))
    for arguments, files, namespace, single in cases:
        pushed = {'ros_namespace': '/robot1'} if namespace == '/robot1' else {}
        context = types.SimpleNamespace(launch_configurations={**arguments, **pushed})
        actions = function[0].function(context)
        notes = [a.msg for a in actions if hasattr(a, 'msg')]
        rows = [a.row for a in actions if hasattr(a, 'row')]
        if files is None:   # the fitted file in a namespace: a copy, logged
            assert len(notes) == 1 and notes[0].startswith(f'{fitted}: sections resolved')
            files = [str(installed), notes[0].rsplit(': ', 1)[1]]
        assert rows == expected_nodes(files, namespace, single)


def test_the_launch_file_under_ros2_launch(monkeypatch, tmp_path, fitted):
    """The same with ROS 2's launch and launch_ros (a robot's ROS install)."""
    # launch_ros first: the checkout's launch/ folder imports as a namespace package 'launch'.
    utilities = pytest.importorskip(
        'launch_ros.utilities', reason='ROS 2 launch and launch_ros install with ROS (apt '
                                       'ros-jazzy-launch-ros), not from a package index this '
                                       'machine reaches')
    launch = pytest.importorskip('launch')
    module, installed = load_launch_file(monkeypatch, tmp_path)
    description = module.generate_launch_description()
    declared = description.get_launch_arguments()
    assert tuple(d.name for d in declared) == EXPECTED_ARGUMENTS
    context = launch.LaunchContext()
    context.launch_configurations.update(params_file=f'{installed},{fitted}', namespace='left',
                                         single_process='false')
    function = [e for e in description.entities if isinstance(e, launch.actions.OpaqueFunction)]
    actions = function[0].execute(context)
    nodes = [a for a in actions if a.__class__.__name__ == 'Node']
    # Name, namespace and parameters as the Node was given them (launch_ros keeps them private).
    rows = [(n.node_package, n.node_executable, n._Node__node_name, n._Node__node_namespace,
             [str(p) for p in utilities.evaluate_parameters(context, n._Node__parameters)])
            for n in nodes]
    files = rows[0][4]
    assert files[0] == str(installed) and Path(files[1]).read_text().startswith(
        FITTED.split('\n')[0]) and "'/left/compensation_node':" in Path(files[1]).read_text()
    assert rows == expected_nodes(files, '/left', False)
