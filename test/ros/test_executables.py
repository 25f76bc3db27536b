"""
The node executables: console scripts of this package, clean start and stop.

test/ros/test_colcon_build.py proves the ``ros2 run`` layout; here the executables of
the virtual environment run, and ``bringup`` (both nodes in one process) is checked.
"""

from importlib.metadata import entry_points
import os
import re
import signal
import time

from diagnostic_msgs.msg import DiagnosticStatus
from mlx_tempcomp.core.node_models.chain import CalibrationChain, ChainModel
from mlx_tempcomp.parameters.files import chain_parameters
from mlx_tempcomp.ros.qos import STATUS_QOS
import pytest
from ros_harness import (by_stamp, COMPENSATION_DIAGNOSTIC, DRIVER_DIAGNOSTIC, executable, rates,
                         simulated_driver_params, start_in_namespace, write_sections)
from sensor_msgs.msg import Imu
from std_msgs.msg import String
from std_srvs.srv import Trigger

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
# The product stops within 2 s (bench/bench_stop.py measures it); a loaded machine may
# take longer, and the tests check that the node stops by itself, cleanly.
STOP_TIMEOUT_S = 60.0
NODES = {'driver_node': 'mlx_tempcomp.ros.driver.node:main',
         'compensation_node': 'mlx_tempcomp.ros.compensation.node:main',
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
    # The streams run on, so nothing goes quiet: a second takes what was queued (the
    # default waits out its whole 5 s time-out).
    probe.drain(timeout=1.0)
    compensated = set(by_stamp(probe.received['imu/data']))
    heard = [s for s in by_stamp(raw) if min(compensated) <= s <= max(compensated)]
    assert len(heard) > 100 and set(heard) <= compensated

    assert bringup.stop() == 0
    assert 'Traceback' not in bringup.output()
    assert '[driver_node]: simulated MLX90609 x1 (seed 9)' in bringup.output()
    assert '[compensation_node]: factory tables received' in bringup.output()


IDENTITY_CHAIN = chain_parameters(ChainModel(CalibrationChain(
    full_scale_rad_s=1.0, reference_temperature_c=25.0, reference_temperature_2_c=25.0,
    nonlinearity_rad_s=((0.0,),) * 3, offset_rad_s=(0.0,) * 3,
    offset_gradient_rad_s_per_c=(0.0,) * 3, sensitivity_slope_rad_s_per_c=((0.0,),) * 3,
    sensitivity_intercept_rad_s=((0.0,),) * 3, offset_2_rad_s=(0.0,) * 3,
    offset_2_gradient_rad_s_per_c=(0.0,) * 3,
    misalignment=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))))
MPU = {'device': 'mpu6000', 'axes': ['x', 'y', 'z']}
POLYNOMIAL_XYZ = {'model': 'polynomial', 'axes': ['x', 'y', 'z'],
                  **{f'polynomial.bias.{axis}': [0.001, 1e-4] for axis in 'xyz'}}
# (executable, namespace, node name, parameters, output topic or None): a driver per device,
# the compensation node on every model kind, bringup. The chain model waits for a second
# temperature no simulated driver gives, so only its start is awaited.
STOP_CASES = (
    ('driver_node', 'mlx', 'driver_node', {}, None),
    ('compensation_node', 'mlx', 'compensation_node', {'model': 'eeprom'}, 'imu/data'),
    ('compensation_node', 'mlx', 'effects_node',
     {'model': 'effects', 'effects.bias.z': [0.001, 1e-4]}, 'imu/data_effects'),
    ('driver_node', 'adis', 'driver_node', {'device': 'adis16130'}, None),
    ('compensation_node', 'adis', 'compensation_node',
     {'model': 'linear_btc', 'linear_btc.pbc_rad_s': [0.01],
      'linear_btc.btc_rad_s_per_c': [0.0002]}, 'imu/data'),
    ('driver_node', 'mpu', 'driver_node', MPU, None),
    ('compensation_node', 'mpu', 'compensation_node', POLYNOMIAL_XYZ, 'imu/data'),
    ('compensation_node', 'mpu', 'chain_node', IDENTITY_CHAIN, None),
    ('bringup', 'bringup', 'bringup', {**MPU, **POLYNOMIAL_XYZ}, 'imu/data'),
)


def assert_stopped_cleanly(process, signum) -> float:
    """Wait for ``process`` to exit after ``signum``; check it; give the seconds it took."""
    sent = time.monotonic()
    process.signal(signum)
    assert process.wait(STOP_TIMEOUT_S) == 0, process.output()
    took = time.monotonic() - sent
    output = process.output()
    assert 'Traceback' not in output, output
    assert f'{signal.Signals(signum).name}: stopping' in output, output
    return took


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_every_executable_stops_on_a_signal_with_its_summary(launcher, probe, tmp_path, signum):
    outputs = [f'/{namespace}/{topic}' for _, namespace, _, _, topic in STOP_CASES if topic]
    for topic in outputs:
        probe.subscribe(Imu, topic)
    processes = [start_in_namespace(launcher, *case[:4], tmp_path) for case in STOP_CASES]
    # Messages flow through every node that can compensate when the signal comes.
    probe.spin_until(lambda: all(probe.count(t) >= 20 for t in outputs), TIMEOUT_S * 3,
                     'every compensation node publishing', launcher)
    chain = processes[[case[2] for case in STOP_CASES].index('chain_node')]
    probe.spin_until(lambda: 'model chain on axes' in chain.output(), TIMEOUT_S,
                     'the chain node started', launcher)
    took = {}
    for process, (executable_name, namespace, node, _, topic) in zip(processes, STOP_CASES):
        took[process.name] = assert_stopped_cleanly(process, signum)
        output = process.output()
        if executable_name in ('driver_node', 'bringup'):
            assert re.search(r'driver_node sampling: [1-9]\d* samples read', output), output
        if executable_name in ('compensation_node', 'bringup'):
            compensated = re.search(r'stopping: (\d+) samples compensated', output)
            assert compensated, output
            assert int(compensated.group(1)) > 0 or not topic, output
    print(' '.join(f'{name} {seconds:.2f} s' for name, seconds in took.items()))


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_nodes_stop_during_a_recalibration_and_a_bias_procedure(launcher, probe, tmp_path,
                                                                signum):
    prefix = 'adis16130.bias_procedure.'
    driver = launcher.driver(simulated_driver_params(**{
        'device': 'adis16130', prefix + 'average_s': 600.0,
        prefix + 'output_file': str(tmp_path / 'btc.yaml')}))
    compensation = launcher.compensation({
        'model': 'linear_btc', 'linear_btc.pbc_rad_s': [0.01],
        'linear_btc.btc_rad_s_per_c': [0.0002], 'recalibration.duration_s': 600.0,
        'recalibration.state_file': str(tmp_path / 'zro.yaml')})
    status = probe.subscribe(String, 'imu/bias_procedure/status', STATUS_QOS)
    procedure = probe.call_async(Trigger, 'imu/run_bias_procedure', Trigger.Request(),
                                 TIMEOUT_S)
    recalibration = probe.call_async(Trigger, 'imu/recalibrate_zro', Trigger.Request(),
                                     TIMEOUT_S)
    probe.spin_until(lambda: any(m.data.startswith('phase point_1') for m in status),
                     TIMEOUT_S, 'the bias procedure at its first point', launcher)
    # A second request of each is refused while the first one's window runs (600 s of
    # sensor time: running, whatever the machine's speed), saying which and since when.
    second = probe.call(Trigger, 'imu/recalibrate_zro', Trigger.Request(), TIMEOUT_S)
    assert second.message.startswith('refused: a ZRO recalibration is running since '), \
        second.message
    again = probe.call(Trigger, 'imu/run_bias_procedure', Trigger.Request(), TIMEOUT_S)
    assert again.message.startswith('refused: a bias procedure is running since '), \
        again.message
    for process in (compensation, driver):
        assert_stopped_cleanly(process, signum)
    assert not procedure.done() and not recalibration.done()
    assert 'compensation_node stopping: ' in compensation.output()
    assert 'driver_node sampling: ' in driver.output()
    assert not (tmp_path / 'zro.yaml').exists() and not (tmp_path / 'btc.yaml').exists()
