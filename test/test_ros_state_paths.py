"""
Two compensation nodes in two namespaces keep two state files, each restarts on its own.

Two simulated MLX90609 drivers (two gyros of one robot, chips of other seeds, so other
offsets) in /left and /right, each with a compensation node on the default state path
(no ``recalibration.state_file``), in a home folder of the test's own with ROS_HOME
unset, as on a robot: each file is ``~/.ros/mlx_tempcomp/<namespace>/compensation_node_zro.yaml``.
A file an earlier release kept at the old default (``~/.ros/mlx_tempcomp/
compensation_node_zro.yaml``) is taken over by the first node, with one line. Each node
is re-zeroed, both are stopped and started again, and each applies its own offset.
"""

import math

from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.state_file import read_state, write_state
import pytest
from ros_harness import (COMPENSATION_DIAGNOSTIC, parse_list, simulated_driver_params,
                         status_values, UNTRACKED, write_params)
from std_srvs.srv import Trigger

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
# The raw rate as it comes: the offset a re-zero learns is the chip's own ZRO at 25 C.
MODEL = {'model': 'polynomial', 'polynomial.bias.z': [0.0],
         'recalibration.duration_s': 1.0,
         'recalibration.max_mean_rate_rad_s': math.radians(10.0)}
SEEDS = {'left': 9, 'right': 4}
OLD_OFFSET_RAD_S = 0.01


def start(launcher, namespace: str, executable: str, params: dict, label: str):
    return launcher.start(executable, '/**', params, extra_args=['-r', f'__ns:=/{namespace}'],
                          label=label)


def status_of(probe, launcher, path: str, predicate=lambda values: True) -> dict:
    """Give the values of the next compensation status of the node keeping ``path``."""
    return status_values(probe.wait_status(
        COMPENSATION_DIAGNOSTIC,
        lambda s: status_values(s)['state_file'] == path and predicate(status_values(s)),
        TIMEOUT_S, f'the status of the node keeping {path}', launcher))


def test_two_namespaces_keep_two_state_files_and_restart_each_on_its_own(launcher, probe,
                                                                         tmp_path):
    home = tmp_path / 'home'
    launcher.env['HOME'] = str(home)
    launcher.env.pop('ROS_HOME', None)
    folder = home / '.ros' / 'mlx_tempcomp'
    paths = {ns: str(folder / ns / 'compensation_node_zro.yaml') for ns in SEEDS}
    old = folder / 'compensation_node_zro.yaml'
    model = build_model(node_values(write_params(tmp_path / 'model.yaml', 'compensation_node',
                                                 MODEL), 'compensation_node'))
    write_state(str(old), {
        'model': 'polynomial', 'fingerprint': model.fingerprint(), 'axes': ['z'],
        'zro_offset': [OLD_OFFSET_RAD_S], 'offset_unit': 'rad/s',
        'zro_offset_rad_s': [OLD_OFFSET_RAD_S], 'temperature_c': 25.0, 'samples': 100,
        'time': '2026-11-25T12:00:00+00:00'})
    probe.subscribe_diagnostics()
    for namespace, seed in SEEDS.items():
        start(launcher, namespace, 'driver_node',
              simulated_driver_params(**{'simulation.seed': seed}), f'{namespace}_driver')
    # One after the other: the first takes the old file over.
    first = start(launcher, 'left', 'compensation_node', {**MODEL, **UNTRACKED}, 'left')
    values = status_of(probe, launcher, paths['left'], lambda v: v['samples_out'] != '0')
    assert parse_list(values['zro_offset']) == [OLD_OFFSET_RAD_S]
    took = [line for line in first.output().splitlines() if 'took over' in line]
    assert len(took) == 1 and f'{old}: now {paths["left"]}' in took[0], first.output()
    assert not old.exists()
    start(launcher, 'right', 'compensation_node', {**MODEL, **UNTRACKED}, 'right')
    values = status_of(probe, launcher, paths['right'], lambda v: v['samples_out'] != '0')
    assert parse_list(values['zro_offset']) == [0.0]

    offsets = {}
    for namespace in SEEDS:
        response = probe.call(Trigger, f'/{namespace}/imu/recalibrate_zro', Trigger.Request(),
                              TIMEOUT_S)
        assert response.success, response.message
        assert response.message.endswith(f'saved to {paths[namespace]}'), response.message
        offsets[namespace] = read_state(paths[namespace])['zro_offset_rad_s'][0]
    print(f'offsets learnt: {offsets} rad/s')
    assert abs(offsets['left'] - offsets['right']) > 0.005, 'two chips, two offsets'
    assert sorted(p.name for p in folder.iterdir()) == ['left', 'right']

    for process in launcher.processes[2:]:
        process.stop()
    for namespace in SEEDS:
        restarted = start(launcher, namespace, 'compensation_node', {**MODEL, **UNTRACKED},
                          f'{namespace}_restarted')
        values = status_of(probe, launcher, paths[namespace],
                           lambda v: v['samples_out'] != '0')
        assert parse_list(values['zro_offset'])[0] == pytest.approx(offsets[namespace],
                                                                    rel=1e-5)
        assert f'applied saved ZRO offset [{offsets[namespace]}] rad/s from ' \
            f'{paths[namespace]}' in restarted.output()
        assert 'took over' not in restarted.output()
