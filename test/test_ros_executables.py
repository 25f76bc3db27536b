"""
The node executables: console scripts of this package, clean start and stop.

test/test_colcon_build.py proves the ``ros2 run`` layout; here the executables of
the virtual environment run, and ``bringup`` (both nodes in one process) is checked.
"""

from importlib.metadata import entry_points
import os
import signal

from diagnostic_msgs.msg import DiagnosticStatus
import pytest
from ros_harness import (by_stamp, COMPENSATION_DIAGNOSTIC, DRIVER_DIAGNOSTIC, executable,
                         rates, simulated_driver_params, write_sections)

pytestmark = pytest.mark.ros

TIMEOUT_S = 20.0
NODES = {'driver_node': 'mlx_tempcomp.ros.driver_node:main',
         'compensation_node': 'mlx_tempcomp.ros.compensation_node:main',
         'bringup': 'mlx_tempcomp.ros.bringup:main'}


def test_console_scripts_are_installed():
    scripts = {e.name: e.value for e in entry_points(group='console_scripts')
               if e.name in NODES}
    assert scripts == NODES
    for name in NODES:
        assert os.access(executable(name), os.X_OK), executable(name)


def test_bringup_runs_both_nodes_and_stops_cleanly(launcher, probe, tmp_path):
    params = write_sections(tmp_path / 'bringup.yaml', {
        'driver_node': simulated_driver_params(**{'simulation.seed': 9,
                                                  'simulation.real_time_factor': 2.0}),
        'compensation_node': {'recalibration.state_file': str(tmp_path / 'zro.yaml')}})
    probe.subscribe_pipeline()
    bringup = launcher.start('bringup', 'bringup', extra_args=['--params-file', params])
    probe.wait_statuses({name: lambda s: s.level == DiagnosticStatus.OK
                         for name in (DRIVER_DIAGNOSTIC, COMPENSATION_DIAGNOSTIC)},
                        TIMEOUT_S, 'both nodes OK', launcher)
    probe.wait_streaming(['imu/data_raw', 'imu/data'], TIMEOUT_S, launcher)
    data = probe.wait_count('imu/data', 200, TIMEOUT_S, launcher)
    assert all(m.header.frame_id == 'imu_link' for m in data)
    # Seed 9 is +1.8 deg/s off at the nominal conversion; compensated, it is near 0.
    mean_z = sum(rates(m)[2] for m in data) / len(data)
    assert abs(mean_z) < 0.01
    assert probe.received['imu/eeprom']
    # The compensation node takes the raw stream from the driver in its process, not over
    # DDS: the probe is the only subscriber of the raw topics, and every raw sample it
    # heard comes out compensated.
    assert probe.node.count_subscribers('/imu/data_raw') == 1
    assert probe.node.count_subscribers('/imu/temperature_raw') == 1
    raw = probe.wait_count('imu/data_raw', 400, TIMEOUT_S, launcher)
    probe.drain()
    compensated = set(by_stamp(probe.received['imu/data']))
    heard = [s for s in by_stamp(raw) if min(compensated) <= s <= max(compensated)]
    assert len(heard) > 100 and set(heard) <= compensated

    assert bringup.stop() == 0
    assert 'Traceback' not in bringup.output()
    assert '[driver_node]: simulated MLX90609 x1 (seed 9)' in bringup.output()
    assert '[compensation_node]: factory tables received' in bringup.output()


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_nodes_exit_0_on_a_stop_signal(launcher, probe, tmp_path, signum):
    probe.subscribe_pipeline()
    driver = launcher.driver(simulated_driver_params())
    compensation = launcher.compensation({'recalibration.state_file': str(tmp_path / 'z.yaml')})
    probe.wait_streaming(['imu/data'], TIMEOUT_S, launcher)
    for process in (compensation, driver):
        process.signal(signum)
        assert process.wait(10.0) == 0
        assert 'Traceback' not in process.output()
