"""
What the launch file starts, started here as launch_ros starts it, over DDS.

``launch`` is not installable here (test/parameters/test_launch_plan.py), so the plan the
launch file gets from `launch_plan` is run with the command line launch_ros's
Node builds from it (Jazzy: ``EXE --ros-args [-r __node:=NAME] -r __ns:=NS
--params-file F ...``, the files in order): the shipped config, a file of this
test's settings, then a fitted file whose section is named
``compensation_node``, in the namespace ``left``. The nodes take the fitted
model there; the same file given as it is would miss the node.
"""

from mlx_tempcomp.parameters.launch_plan import launch_plan
import pytest
from ros_harness import executable, NodeProcess, rates, simulated_driver_params, write_sections
from sensor_msgs.msg import Imu

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
CONFIG = 'config/mlx_tempcomp.yaml'
# A fitted model far from the factory table's: its output tells which model runs.
BIAS = [0.5, 0.0]


def launch_ros_command(node, plan) -> list:
    """Give the command launch_ros's Node runs for one node of a plan (see the module)."""
    command = [executable(node.executable), '--ros-args']
    command += ['-r', f'__node:={node.name}'] if node.name is not None else []
    command += ['-r', f'__ns:={plan.namespace}'] if plan.namespace != '/' else []
    for path in plan.params_files:
        command += ['--params-file', path]
    return command


@pytest.fixture
def files(tmp_path, request) -> str:
    """Give the params_file argument: the config, this test's settings, a fitted file."""
    root = request.config.rootpath
    settings = write_sections(tmp_path / 'settings.yaml', {'/**': {
        **simulated_driver_params(), 'recalibration.state_file': str(tmp_path / 'zro.yaml'),
        'bias_tracking.enabled': False}})
    fitted = write_sections(tmp_path / 'fitted.yaml', {'compensation_node': {
        'model': 'polynomial', 'polynomial.reference_temperature_c': 25.0,
        'polynomial.bias.z': BIAS}})
    return f'{root / CONFIG},{settings},{fitted}'


@pytest.mark.parametrize('single_process', ['false', 'true'], ids=['two', 'bringup'])
def test_the_nodes_run_the_fitted_model_in_their_namespace(launcher, probe, tmp_path, files,
                                                           single_process):
    plan = launch_plan(files, 'left', single_process, folder=str(tmp_path / 'copies'))
    assert len(plan.notes) == 1 and 'compensation_node -> /left/compensation_node' in \
        plan.notes[0]
    for node in plan.nodes:
        launcher.processes.append(launcher_process(launcher, node, plan))
    probe.subscribe(Imu, '/left/imu/data_raw')
    probe.subscribe(Imu, '/left/imu/data')
    probe.wait_streaming(['/left/imu/data_raw', '/left/imu/data'], TIMEOUT_S, launcher)
    values = probe.get_parameters('left/compensation_node', ['model', 'polynomial.bias.z'])
    assert values == {'model': 'polynomial', 'polynomial.bias.z': BIAS}
    assert probe.get_parameters('left/driver_node', ['simulation.real_time_factor']) == \
        {'simulation.real_time_factor': 5.0}, "the test's settings, after the shipped config"
    compensated = probe.wait_count('/left/imu/data', 100, TIMEOUT_S, launcher)
    # The fitted bias (0.5 rad/s) taken off a gyro at rest (the chip's own offset is within
    # 0.2 rad/s; the factory table's model takes it to about 0).
    assert sum(rates(m)[2] for m in compensated) / len(compensated) == \
        pytest.approx(-BIAS[0], abs=0.2)


def test_a_relative_section_given_as_it_is_misses_a_namespaced_node(launcher, probe, files,
                                                                    tmp_path):
    """Why the plan resolves it: rcl reads ``compensation_node:`` as /compensation_node."""
    plan = launch_plan(files, '', folder=str(tmp_path / 'copies'))
    node = [n for n in plan.nodes if n.executable == 'compensation_node'][0]
    command = launch_ros_command(node, plan) + ['-r', '__ns:=/right']
    launcher.processes.append(launcher_process(launcher, node, plan, command))
    values = probe.get_parameters('right/compensation_node', ['model'], TIMEOUT_S)
    assert values == {'model': 'eeprom'}, 'the default: the fitted section missed the node'


def launcher_process(launcher, node, plan, command=None):
    """Start one node of the plan under the test's launcher (stopped after the test)."""
    label = f'{node.executable}_{len(launcher.processes)}'
    return NodeProcess(label, command or launch_ros_command(node, plan),
                       launcher.folder / f'{label}.log', launcher.env)
