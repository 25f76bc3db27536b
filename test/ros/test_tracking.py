"""
Bias tracking in the compensation node, over DDS: the offline twin's bits, the topics, the state.

A record at rest (a cubic in temperature, a wandering offset, noise, gravity on -z) gets
known motion from ``mlx-tempcomp inject-motion``; ``fit`` writes the model and its
``bias_tracking`` section; ``convert`` makes it a bag of the driver's raw topics. The bag
replayed through driver_node into compensation_node must give what ``evaluate
--track-bias`` gives on the same bag, bit for bit, and the bias topics and diagnostics the
twin's final estimate. The learnt offset survives a SIGKILL and applies from the first
sample after a restart; a ZRO recalibration seeds the tracker; the state file loads in
every form it can have (the format before tracking included), and a bad tracking section
is refused without losing the ZRO offset beside it; tracking turned on by a parameter (the
node in this process, stamps the test sets) writes the file only once it learns. With an
offset of 0.3 deg/s the fit never saw, a test publisher's nav_msgs/Odometry (the
schedule's truth, by stamp) makes the node track as ``evaluate --track-bias --rest-hint``
does, bit for bit; a std_msgs/Bool from a live publisher, unstamped, lets it re-zero a
supply's shift on the simulated sensor.
"""

from contextlib import redirect_stdout
from dataclasses import replace
import io
import json
import math
import signal

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped, TwistWithCovarianceStamped
from mlx_tempcomp.cli import main
from mlx_tempcomp.parameters.compensation import covariance_noise_of
from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.state_file import read_state, write_state
from mlx_tempcomp.parameters.tracking import REST_HINT_TYPES
from mlx_tempcomp.recordings.bag import RawTopics
from mlx_tempcomp.recordings.bag_reader import RawBagReader
from mlx_tempcomp.recordings.csv_writer import write_csv
from mlx_tempcomp.recordings.load import load_recording
from mlx_tempcomp.ros import messages
from mlx_tempcomp.ros.compensation import rest_hint
from mlx_tempcomp.ros.compensation.bias_tracking import NS_PER_S, stamp_second, stamp_seconds
from mlx_tempcomp.ros.compensation.node import CompensationNode
from nav_msgs.msg import Odometry
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rest_records import offset_record, rest_record
from ros_harness import (by_stamp, COMPENSATION_DIAGNOSTIC, finish_model_replay, first_line_with,
                         paired, Probe, reliable, simulated_driver_params, start_model_replay,
                         status_values, write_params)
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
import yaml

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
RAW_TOPICS = ('--imu-topic', '/imu/data_raw', '--temperature-topic', '/imu/temperature_raw')
# Tracking alone, as evaluate --track-bias runs it (field learning: ros/test_learning.py).
TRACKED = {'bias_tracking.enabled': True, 'learning.enabled': False}
# Every estimate the node sends, kept for late joiners as the node keeps it.
BIAS_RECORD_QOS = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)


def cli(*argv) -> str:
    """Run an mlx-tempcomp command in this process; give what it printed."""
    out = io.StringIO()
    with redirect_stdout(out):
        assert main([str(a) for a in argv]) == 0
    return out.getvalue()


def fitted_bag(folder, duration_s: float, motion_seed=None) -> tuple:
    """Make a record (with motion), fit and convert it: (params file, bag, stamps, messages)."""
    record = rest_record(folder / 'rest.csv', duration_s)
    if motion_seed is not None:
        cli('inject-motion', record, '--schedule', 'mixed', '--seed', motion_seed,
            '--out', folder / 'moving.csv')
        record = folder / 'moving.csv'
    cli('fit', record, '--order', '3', '--out', folder / 'fit.yaml')
    cli('convert', record, '--out', folder / 'bag')
    stamps, messages = [], 0
    with RawBagReader(folder / 'bag', RawTopics()) as reader:
        for _, topic, item in reader.records():
            messages += 1
            if topic == RawTopics.imu:
                stamps.append(item.stamp_ns)
    return str(folder / 'fit.yaml'), folder / 'bag', stamps, messages


def angular(bias) -> list:
    """Give the estimate of an imu/gyro_bias message."""
    vector = bias.twist.twist.angular
    return [vector.x, vector.y, vector.z]


def test_stamps_become_seconds_as_the_bag_reader_makes_them(tmp_path):
    rng = np.random.default_rng(0)
    stamps = np.concatenate([rng.integers(0, 2 ** 31 * 10 ** 9, 2000),
                             [0, 1, 10 ** 9 - 1, 10 ** 9, 1_795_750_249_871_031_036]])
    seconds = stamp_seconds(stamps.astype(np.int64))
    assert [stamp_second(s) for s in stamps.tolist()] == seconds.tolist()
    # The bag reader's own: a recording's time from a bag of these stamps.
    rest_record(tmp_path / 'rest.csv', 20.0)
    cli('convert', tmp_path / 'rest.csv', '--out', tmp_path / 'bag')
    with RawBagReader(tmp_path / 'bag', RawTopics()) as reader:
        bag_stamps = [item.stamp_ns for _, topic, item in reader.records()
                      if topic == RawTopics.imu]
    recording = load_recording(tmp_path / 'bag', imu_topic='/imu/data_raw',
                               temperature_topic='/imu/temperature_raw')
    assert np.array_equal(stamp_seconds(np.array(bag_stamps, dtype=np.int64)),
                          recording.time_s)


@pytest.mark.slow
def test_the_node_tracks_as_evaluate_track_bias_does_to_the_bit(launcher, probe, tmp_path):
    params, bag, stamps_ns, messages_in_bag = fitted_bag(tmp_path, 600.0, motion_seed=1)
    report = json.loads(cli('evaluate', bag, *RAW_TOPICS, '--params', params, '--track-bias',
                            '--json', '--out-csv', tmp_path / 'twin.csv'))['bias_tracking']
    twin = np.genfromtxt(tmp_path / 'twin.csv', delimiter=',', names=True)
    axes = ('x', 'y', 'z')
    expected = np.column_stack([twin[f'gyro_{a}'] for a in axes])
    offset_std = np.column_stack([twin[f'offset_std_{a}'] for a in axes])
    # The twin learnt, and the tracked rate is not the model's.
    assert report['updates'] > 30 and 0.2 < report['still_share_found'] < 0.8
    assert np.count_nonzero(np.column_stack([twin[f'offset_{a}'] for a in axes])) > 3000

    bias = probe.subscribe(TwistWithCovarianceStamped, 'imu/gyro_bias', BIAS_RECORD_QOS)
    status = probe.subscribe(DiagnosticArray, 'imu/gyro_bias/status', BIAS_RECORD_QOS)
    start_model_replay(launcher, probe, tmp_path, bag, params, **TRACKED)
    got = np.array(finish_model_replay(launcher, probe, stamps_ns, messages_in_bag))
    differing = np.count_nonzero(np.any(got != expected, axis=1))
    print(f'{len(got)} samples; {differing} differ from evaluate --track-bias; '
          f'{report["updates"]} windows learnt')
    assert differing == 0
    # The covariance: the noise of a sample (each axis's, as fit measured it) plus the
    # tracked offset's variance, which is what evaluate --track-bias writes as std_*.
    noise = np.array(covariance_noise_of(node_values(params, 'compensation_node')))
    assert noise.size == 3 and len(set(noise.tolist())) == 3
    published = by_stamp(probe.received['imu/data'])
    std = np.column_stack([twin[f'std_{a}'] for a in axes])
    np.testing.assert_allclose(std ** 2, noise ** 2 + offset_std ** 2, rtol=1e-12)
    for row in range(0, len(stamps_ns), 97):
        covariance = published[stamps_ns[row]].angular_velocity_covariance
        assert [covariance[0], covariance[4], covariance[8]] == pytest.approx(
            noise ** 2 + offset_std[row] ** 2, rel=1e-12)

    # The topics end on the twin's final estimate; so do the diagnostics.
    final = report['final']
    probe.spin_until(lambda: bias and angular(bias[-1]) == final['offset_rad_s'],
                     TIMEOUT_S, 'the final estimate on imu/gyro_bias', launcher)
    covariance = bias[-1].twist.covariance
    assert [covariance[21], covariance[28], covariance[35]] == pytest.approx(
        np.square(final['std_rad_s']), rel=1e-12)
    assert [covariance[0], covariance[7], covariance[14]] == [-1.0] * 3
    # Stamped with a sample's stamp: the last block that closed a window (the record's
    # last window stays open).
    stamp_ns = messages.stamp_to_ns(bias[-1].header.stamp)
    window_s = node_values(params, 'compensation_node')['bias_tracking.window_s']
    assert stamp_ns in published and stamps_ns[-1] - stamp_ns <= 2e9 * window_s
    per_axis = {s.name.rsplit(' ', 1)[-1]: status_values(s) for s in status[-1].status}
    assert sorted(per_axis) == list(axes)
    for i, a in enumerate(axes):
        assert float(per_axis[a]['estimate_rad_s']) == final['offset_rad_s'][i]
        assert float(per_axis[a]['std_rad_s']) == final['std_rad_s'][i]
        assert per_axis[a]['stable'] == str(final['stable'][i])
    diagnostics = status_values(probe.wait_status(
        COMPENSATION_DIAGNOSTIC,
        lambda s: status_values(s).get('tracking_updates') == str(report['updates']),
        TIMEOUT_S, 'the diagnostics after the replay', launcher))
    assert diagnostics['bias_tracking'] in ('still', 'moving')
    offsets = [float(v) for v in diagnostics['tracking_offset_rad_s'][1:-1].split(',')]
    assert offsets == pytest.approx(final['offset_rad_s'], rel=1e-5)
    assert float(diagnostics['tracking_since_update_s']) >= 0.0
    assert diagnostics['tracking_windows'] == str(report['windows'])
    # The covariance judged on the still minutes: their mean rate over its std. Which
    # samples count hangs on how DDS cut the stream into blocks, so only its kind is held:
    # minutes were judged, and the figure is that of a covariance near the truth.
    assert int(diagnostics['still_windows_checked']) >= 1
    judged = [float(v) for v in diagnostics['still_normalised_error_rms'][1:-1].split(',')]
    print(f"{diagnostics['still_windows_checked']} still minutes judged: {judged}")
    assert len(judged) == 3 and all(0.1 < v < 10.0 for v in judged), judged


@pytest.mark.slow
def test_the_learnt_offset_survives_a_kill_and_applies_from_the_first_sample(
        launcher, probe, tmp_path):
    params, bag, stamps_ns, messages_in_bag = fitted_bag(tmp_path, 120.0)
    state_file = tmp_path / 'zro.yaml'
    # Written whenever a window was learnt: the SIGKILL below loses nothing learnt.
    node_params = {**TRACKED, 'bias_tracking.save_period_s': 0.0}
    start_model_replay(launcher, probe, tmp_path, bag, params, **node_params)
    first = finish_model_replay(launcher, probe, stamps_ns, messages_in_bag)
    diagnostics = status_values(probe.wait_status(
        COMPENSATION_DIAGNOSTIC, lambda s: s.values and int(status_values(s).get(
            'tracking_updates', '0')) > 5, TIMEOUT_S, 'the tracker learning', launcher))
    node, driver = launcher.processes[-2:]
    node.kill()
    driver.stop()
    state = read_state(str(state_file))
    section = state['bias_tracking']
    assert set(state) == {'bias_tracking'}, 'no recalibration: the tracker alone'
    assert section['updates'] >= int(diagnostics['tracking_updates'])
    assert section['axes'] == ['x', 'y', 'z'] and section['zro_offset'] == [0.0] * 3
    offset = section['offset_rad_s']
    assert all(v != 0.0 for v in offset)

    # Restarted on the same file and record: the offset applies from the first sample.
    second_probe = Probe('restarted')
    try:
        start_model_replay(launcher, second_probe, tmp_path, bag, params, **node_params)
        second = finish_model_replay(launcher, second_probe, stamps_ns, messages_in_bag)
    finally:
        second_probe.close()
    log = launcher.processes[-2].output()
    assert f'applied saved bias tracking state {offset} rad/s from {state_file}' in log, log
    assert second[0] == [r - o for r, o in zip(first[0], offset)]
    print(f'first sample {first[0]} before, {second[0]} after the restart; offset {offset}')


SERVICE = 'imu/recalibrate_zro'


@pytest.mark.slow
def test_a_recalibration_seeds_the_tracker_and_parameters_turn_it_off(launcher, probe,
                                                                      tmp_path):
    state_file = tmp_path / 'zro.yaml'
    bias = probe.subscribe(TwistWithCovarianceStamped, 'imu/gyro_bias', BIAS_RECORD_QOS)
    status = probe.subscribe(DiagnosticArray, 'imu/gyro_bias/status', BIAS_RECORD_QOS)
    probe.subscribe_pipeline()
    launcher.driver(simulated_driver_params(**{'simulation.seed': 9}))
    launcher.compensation({'recalibration.state_file': str(state_file),
                           'recalibration.duration_s': 2.0})
    probe.wait_streaming(['imu/data'], TIMEOUT_S, launcher)
    noise = 0.0058   # the node's rate_noise_rad_s: bias_tracking.rate_noise_rad_s is 0
    seen = len(bias)
    response = probe.call(Trigger, SERVICE, Trigger.Request(), TIMEOUT_S)
    assert response.success, response.message
    state = read_state(str(state_file))
    section = state['bias_tracking']
    variance = noise * noise / state['samples']
    assert section['offset_rad_s'] == [0.0] and section['variance_rad2_s2'] == [variance]
    assert section['zro_offset'] == state['zro_offset'] and section['model'] == 'eeprom'
    assert section['fingerprint'] == state['fingerprint']
    # The seed goes out at once: estimate 0, the window mean's variance, stable.
    probe.spin_until(lambda: any(m.twist.twist.angular.z == 0.0 for m in bias[seen:]),
                     TIMEOUT_S, 'the seeded estimate', launcher)
    index = next(i for i in range(seen, len(bias)) if bias[i].twist.twist.angular.z == 0.0)
    assert bias[index].twist.covariance[35] == variance
    probe.spin_until(lambda: any(a.header == bias[index].header for a in status), TIMEOUT_S,
                     'the seeded status', launcher)
    seeded = next(a for a in status if a.header == bias[index].header).status
    assert len(seeded) == 1 and seeded[0].level == seeded[0].OK and seeded[0].message == 'stable'

    # A bad value is refused, naming the parameter; off, the covariance is the noise alone.
    results = probe.set_parameters('compensation_node',
                                   {'bias_tracking.initial_std_rad_s': [1e-3, 2e-3]})
    assert [r.successful for r in results] == [False]
    assert results[0].reason.startswith(
        'invalid parameter bias_tracking.initial_std_rad_s: give one value or one per axis (1)')
    results = probe.set_parameters('compensation_node', {'bias_tracking.enabled': False})
    assert [r.successful for r in results] == [True]
    status_off = probe.wait_status(
        COMPENSATION_DIAGNOSTIC, lambda s: status_values(s).get('bias_tracking') == 'off',
        TIMEOUT_S, 'tracking off in the diagnostics', launcher)
    assert 'tracking_offset_rad_s' not in status_values(status_off)
    probe.clear()
    received = probe.wait_count('imu/data', 50, TIMEOUT_S, launcher)
    assert all(list(m.angular_velocity_covariance) == [0.0] * 8 + [noise ** 2]
               for m in received[:50])


MODEL = {'model': 'polynomial', 'polynomial.bias.z': [0.02, 0.001]}
ZRO_OFFSET_RAD_S = 0.01
TRACKED_OFFSET_RAD_S = 0.001


def old_format(fingerprint: str) -> str:
    """Give a ZRO state file as the node wrote it before bias tracking, as text."""
    return (f'model: polynomial\nfingerprint: {fingerprint}\naxes:\n- z\nzro_offset:\n'
            f'- {ZRO_OFFSET_RAD_S}\noffset_unit: rad/s\nzro_offset_rad_s:\n- {ZRO_OFFSET_RAD_S}\n'
            "temperature_c: 25.0\nsamples: 200\ntime: '2026-11-25T12:00:00+00:00'\n")


def section(fingerprint: str, **change) -> dict:
    """Give a bias tracking section of MODEL with a ZRO offset of ZRO_OFFSET_RAD_S."""
    return {'model': 'polynomial', 'fingerprint': fingerprint, 'axes': ['z'],
            'zro_offset': [ZRO_OFFSET_RAD_S], 'offset_rad_s': [TRACKED_OFFSET_RAD_S],
            'variance_rad2_s2': [1e-8], 'time_s': 1.0e9, 'updates': 7,
            'last_update_s': 1.0e9 - 5.0, 'saved': '2026-11-26T12:00:00+00:00', **change}


# case -> (a line of the log, the files left, the offset applied: ZRO + tracked)
STATE_CASES = {
    'old format': ('[INFO]', 'applied saved ZRO offset [0.01] rad/s', ['zro.yaml'],
                   ZRO_OFFSET_RAD_S),
    'both': ('[INFO]', 'applied saved bias tracking state [0.001] rad/s', ['zro.yaml'],
             ZRO_OFFSET_RAD_S + TRACKED_OFFSET_RAD_S),
    'tracking only': ('[INFO]', 'applied saved bias tracking state [0.001] rad/s',
                      ['zro.yaml'], TRACKED_OFFSET_RAD_S),
    'bad tracking': ('[ERROR]', 'saved bias tracking state in {path} unusable: '
                                'variance_rad2_s2[0] -1.0 is outside 0 to inf; a copy kept as '
                                '{path}.bad-', ['zro.yaml', 'zro.yaml.bad-'], ZRO_OFFSET_RAD_S),
    'another model': ('[INFO]', 'was learnt on another model or ZRO offset', ['zro.yaml'],
                      ZRO_OFFSET_RAD_S),
}


def prepare(case: str, path, fingerprint: str) -> None:
    old = old_format(fingerprint)
    if case == 'old format':
        path.write_text(old)
    elif case == 'both':
        write_state(str(path), {**yaml.safe_load(old), 'bias_tracking': section(fingerprint)})
    elif case == 'tracking only':
        write_state(str(path), {'bias_tracking': section(fingerprint, zro_offset=[0.0])})
    elif case == 'bad tracking':
        write_state(str(path), {**yaml.safe_load(old), 'bias_tracking': section(
            fingerprint, variance_rad2_s2=[-1.0])})
    elif case == 'another model':
        write_state(str(path), {**yaml.safe_load(old), 'bias_tracking': section(
            '0123456789abcdef')})


@pytest.mark.slow
def test_every_form_of_the_state_file_loads_and_a_bad_section_keeps_the_zro_offset(
        launcher, probe, tmp_path):
    params_path = write_params(tmp_path / 'model.yaml', 'compensation_node', MODEL)
    model = build_model(node_values(params_path, 'compensation_node'))
    probe.subscribe_pipeline()
    # A constant 10 deg/s turn: moving, so the tracker learns nothing and the offset stays
    # however many windows close before the stop (3 deg/s, less a case's ZRO offset of
    # 0.01 rad/s, looked still: a loaded machine that let a window close had it learnt).
    launcher.driver(simulated_driver_params(**{'simulation.seed': 4,
                                               'simulation.rate_dps': [10.0]}))
    for case, (level, text, files, offset_rad_s) in STATE_CASES.items():
        folder = tmp_path / case.replace(' ', '_')
        folder.mkdir()
        path = folder / 'zro.yaml'
        prepare(case, path, model.fingerprint())
        before = path.read_bytes()
        # Learning on, as shipped (its own section's forms: ros/test_learning.py).
        node = launcher.compensation({**MODEL, 'recalibration.state_file': str(path)},
                                     label=case)
        probe.wait_streaming(['imu/data'], TIMEOUT_S, launcher)
        probe.spin_until(lambda: len(paired(probe)[0]) >= 20, TIMEOUT_S,
                         '20 compensated samples with their raw inputs', launcher)
        stamps, out, raw, temperature = paired(probe)
        node.signal(signal.SIGINT)
        assert node.stop() == 0
        probe.wait_quiet(['imu/data'], 0.3, TIMEOUT_S, launcher)
        line = first_line_with(node.output(), text.format(path=path))
        assert line.startswith(level), f'{case}: {node.output()}'
        assert '[ERROR]' not in node.output().replace(line, ''), node.output()
        names = sorted(p.name for p in folder.iterdir())
        assert [n[:len(f)] for n, f in zip(names, files)] == files and \
            len(names) == len(files), f'{case}: {names}'
        # Nothing learnt, so nothing written: the file is as it was.
        assert path.read_bytes() == before, case
        # Within the first window: the offset as saved, not yet carried forward.
        stamps = stamps[:20]
        got = np.array([out[s].angular_velocity.z for s in stamps])
        expected = model.correct(np.array([[raw[s].angular_velocity.z] for s in stamps]),
                                 np.array([temperature[s].temperature for s in stamps]))
        # The saved offset fades toward the model by 1e-4 of itself a window: abs 1e-6.
        assert got == pytest.approx(expected.rate_rad_s[:, 0] - offset_rad_s, rel=0.0,
                                    abs=1e-6), case
        print(f'{case}: {line.split("]: ", 1)[-1]}')
        probe.clear()


def _hand_off(node, stamps_ns, rates_rad_s, temperature_c: float) -> None:
    """Give the node one sample at a time as a driver in its process would (bringup)."""
    for stamp_ns, rate in zip(stamps_ns, rates_rad_s):
        stamp = messages.ns_to_stamp(int(stamp_ns))
        node.take_local([
            ('temperature', messages.temperature_message(stamp, 'imu_link', temperature_c)),
            ('imu', messages.imu_message(stamp, 'imu_link', (2,), [float(rate)], [0.0] * 9))])


def test_tracking_turned_on_writes_the_state_file_only_once_it_learns(tmp_path):
    """
    Off at start, on by a parameter: its state is the file's, nothing to write till it learns.

    The node in this process, fed samples whose stamps the test sets (100 Hz, 5 s windows).
    """
    params_path = write_params(tmp_path / 'model.yaml', 'compensation_node', MODEL)
    model = build_model(node_values(params_path, 'compensation_node'))
    path = tmp_path / 'zro.yaml'
    write_state(str(path), {'bias_tracking': section(model.fingerprint(), zro_offset=[0.0])})
    before = path.read_bytes()
    context = Context()
    rclpy.init(args=['tracking', '--ros-args', '--disable-external-lib-logs'], context=context,
               signal_handler_options=SignalHandlerOptions.NO)
    overrides = {**MODEL, 'bias_tracking.enabled': False, 'recalibration.state_file': str(path)}
    node = CompensationNode(context=context, local_input=True, parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()])
    try:
        rng = np.random.default_rng(5)
        temperature_c = 30.0
        at_rest = -model.correct(np.zeros((1, 1)), np.array([temperature_c])).rate_rad_s[0, 0]
        stamps = 1_800_000_000 * NS_PER_S + np.arange(6000) * NS_PER_S // 100
        turning = at_rest + math.radians(10.0) + 1e-4 * rng.standard_normal(6000)
        _hand_off(node, stamps[:200], turning[:200], temperature_c)
        assert node.set_parameters([Parameter('bias_tracking.enabled', value=True)])[0].successful
        _hand_off(node, stamps[200:3200], turning[200:3200], temperature_c)
        tracking = node.tracking
        assert tracking.tracker.window_count >= 5 and tracking.tracker.updates == 7
        assert tracking.writes == 0 and path.read_bytes() == before
        # At rest it learns, and the next window writes.
        resting = at_rest + 1e-4 * rng.standard_normal(6000)
        _hand_off(node, stamps[3200:], resting[3200:], temperature_c)
        assert tracking.tracker.updates > 7 and tracking.writes >= 1
        assert read_state(str(path))['bias_tracking']['updates'] > 7
    finally:
        node.destroy_node()
        context.try_shutdown()


def test_each_hint_type_says_at_rest_by_its_bounds_and_takes_its_stamp():
    assert tuple(rest_hint.KINDS) == REST_HINT_TYPES
    limits = (0.001, 0.002)
    odometry_kind = rest_hint.KINDS['nav_msgs/Odometry']
    msg = Odometry()
    msg.twist.twist.linear.x, msg.twist.twist.angular.z = 0.0009, -0.0019
    assert rest_hint.at_rest(odometry_kind, msg, *limits)
    assert rest_hint.stamp_ns(odometry_kind, msg) is None        # a zero stamp: none
    msg.header.stamp = messages.ns_to_stamp(1_795_750_249_871_031_036)
    assert rest_hint.stamp_ns(odometry_kind, msg) == 1_795_750_249_871_031_036
    for x, z in ((0.0011, 0.0), (0.0, 0.0021), (math.nan, 0.0)):
        msg.twist.twist.linear.x, msg.twist.twist.angular.z = x, z
        assert not rest_hint.at_rest(odometry_kind, msg, *limits)
    twist = Twist()
    twist.angular.y = 0.0015
    assert rest_hint.at_rest(rest_hint.KINDS['geometry_msgs/Twist'], twist, *limits)
    assert rest_hint.stamp_ns(rest_hint.KINDS['geometry_msgs/Twist'], twist) is None
    stamped = TwistStamped()
    stamped.twist.linear.y = 0.5
    assert not rest_hint.at_rest(rest_hint.KINDS['geometry_msgs/TwistStamped'], stamped,
                                 *limits)
    assert rest_hint.at_rest(rest_hint.KINDS['std_msgs/Bool'], Bool(data=True), *limits)
    assert not rest_hint.at_rest(rest_hint.KINDS['std_msgs/Bool'], Bool(data=False), *limits)


HINT_TOPIC = 'odom'
# Every hint delivered: the node's subscription is made as reliable and deep (qos_overrides).
HINT_QOS = QoSProfile(depth=5000, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def odometry(stamp_ns: int, at_rest: bool) -> Odometry:
    """Give wheel odometry at ``stamp_ns``: standing, or driving at 0.5 m/s."""
    msg = Odometry()
    msg.header.stamp = messages.ns_to_stamp(stamp_ns)
    msg.header.frame_id = 'odom'
    msg.twist.twist.linear.x = 0.0 if at_rest else 0.5
    return msg


@pytest.mark.slow
def test_odometry_hints_make_the_node_track_as_evaluate_rest_hint_does_to_the_bit(
        launcher, probe, tmp_path):
    rest = rest_record(tmp_path / 'rest.csv', 600.0)
    cli('inject-motion', rest, '--schedule', 'mixed', '--seed', 1, '--out',
        tmp_path / 'moving.csv')
    cli('fit', tmp_path / 'moving.csv', '--order', '3', '--out', tmp_path / 'fit.yaml')
    params = str(tmp_path / 'fit.yaml')
    # 0.3 deg/s the fit never saw: beyond the tracker's bound, a turn to a gyro alone.
    offset = offset_record(tmp_path / 'moving.csv', tmp_path / 'offset.csv', math.radians(0.3))
    cli('convert', offset, '--out', tmp_path / 'bag')
    bag_record = load_recording(tmp_path / 'bag', imu_topic='/imu/data_raw',
                                temperature_topic='/imu/temperature_raw')
    with RawBagReader(tmp_path / 'bag', RawTopics()) as reader:
        records = [(topic, item.stamp_ns) for _, topic, item in reader.records()]
    stamps_ns = [stamp for topic, stamp in records if topic == RawTopics.imu]
    hint = np.genfromtxt(offset, delimiter=',', names=True)['rest_hint'] == 1.0
    assert len(stamps_ns) == len(bag_record) == hint.size == 6000
    # The twin reads the bag's samples (its stamps as the node makes seconds of them), the
    # truth (the bag has no reference) and each row's hint.
    truth = load_recording(offset).reference_rad_s
    write_csv(tmp_path / 'twin_input.csv', replace(bag_record, reference_rad_s=truth), '%.17g',
              {'rest_hint': hint.astype(int)})
    twin_args = (tmp_path / 'twin_input.csv', '--params', params, '--track-bias')
    plain = json.loads(cli(*('evaluate',) + twin_args + ('--json',)))['bias_tracking']
    report = json.loads(cli('evaluate', *twin_args, '--rest-hint', 'rest_hint', '--json',
                            '--out-csv', tmp_path / 'twin.csv'))['bias_tracking']
    twin = np.genfromtxt(tmp_path / 'twin.csv', delimiter=',', names=True)
    axes = ('x', 'y', 'z')
    expected = np.column_stack([twin[f'gyro_{a}'] for a in axes])
    # The hint is what re-zeroes the offset: far better than without it.
    # (Without it the accelerometer lets x and y learn where a turn about gravity would not
    # show on them; z, the vertical, learns nothing.)
    assert report['hinted_windows'] > 30 and report['updates'] > plain['updates']
    assert all(report['axes'][a]['gain'] > max(3.0, plain['axes'][a]['gain']) for a in axes)
    assert plain['axes']['z']['gain'] < 1.01

    # The robot's odometry: wherever the hint changes, and every tenth sample (1 s, within
    # the 1.5 s a hint holds): at every instant it says what the column says.
    changes = [k for k in range(len(stamps_ns))
               if k % 10 == 0 or hint[k] != hint[k - 1]]
    hints = probe.node.create_publisher(Odometry, HINT_TOPIC, HINT_QOS)

    def send_hints():
        probe.spin_until(lambda: hints.get_subscription_count() > 0, TIMEOUT_S,
                         'the node subscribing to the rest hint', launcher)
        for k in changes:
            hints.publish(odometry(stamps_ns[k], bool(hint[k])))
        # Before the first sample: each window is judged with every hint it needs.
        probe.wait_status(COMPENSATION_DIAGNOSTIC, lambda s: status_values(s).get(
            'rest_hint_messages') == str(len(changes)), TIMEOUT_S, 'every hint received',
            launcher)

    start_model_replay(launcher, probe, tmp_path, tmp_path / 'bag', params,
                       before_driver=send_hints, **TRACKED,
                       **{'bias_tracking.rest_hint_topic': HINT_TOPIC,
                          'bias_tracking.rest_hint_max_age_s': 1.5},
                       **reliable([HINT_TOPIC], 'subscription'))
    got = np.array(finish_model_replay(launcher, probe, stamps_ns, len(records)))
    differing = np.count_nonzero(np.any(got != expected, axis=1))
    print(f'{len(got)} samples, {len(changes)} odometry messages; {differing} differ from '
          f'evaluate --track-bias --rest-hint; {report["hinted_windows"]} windows hinted, '
          f'{report["updates"]} learnt (without the hint {plain["updates"]})')
    assert differing == 0
    diagnostics = status_values(probe.wait_status(
        COMPENSATION_DIAGNOSTIC,
        lambda s: status_values(s).get('tracking_updates') == str(report['updates']),
        TIMEOUT_S, 'the diagnostics after the replay', launcher))
    assert diagnostics['rest_hint'] == HINT_TOPIC
    assert diagnostics['rest_hint_state'] == ('at rest' if hint[-1] else 'moving')
    assert diagnostics['tracking_zero_at_start'] == 'off'
    log = launcher.processes[-2].output()
    assert 'bias tracking on (rest hint: odom, nav_msgs/Odometry)' in log, log


@pytest.mark.slow
def test_a_bool_hint_re_zeroes_a_supply_shift_the_gyro_alone_takes_for_a_turn(
        launcher, probe, tmp_path):
    """A live publisher of std_msgs/Bool (unstamped): at the latest sample tracked."""
    probe.subscribe_pipeline()
    status = probe.subscribe(DiagnosticArray, 'imu/gyro_bias/status', BIAS_RECORD_QOS)
    # The supply at 5.15 V shifts the ZRO by 0.3 deg/s (as in make demo).
    launcher.driver(simulated_driver_params(**{'simulation.supply_v': 5.15,
                                               'simulation.zro_supply_dps_per_v': 2.0,
                                               'simulation.seed': 2}))
    launcher.compensation({'recalibration.state_file': str(tmp_path / 'zro.yaml'),
                           'bias_tracking.rest_hint_topic': 'at_rest',
                           'bias_tracking.rest_hint_type': 'std_msgs/Bool',
                           'bias_tracking.rest_hint_max_age_s': 3.0})
    probe.wait_streaming(['imu/data'], TIMEOUT_S, launcher)
    # Without the hint: held, nothing learnt (a turn of 0.3 deg/s to a gyro alone).
    held = status_values(probe.wait_status(
        COMPENSATION_DIAGNOSTIC, lambda s: int(status_values(s).get('tracking_windows', 0)) >= 3,
        TIMEOUT_S, 'three windows judged', launcher))
    assert held['tracking_updates'] == '0' and held['tracking_held'] == '[True]'
    assert held['rest_hint_state'] == 'no hint yet'
    # What the model leaves (nothing learnt yet): the offset to take.
    before = [m.angular_velocity.z for m in probe.received['imu/data']]
    assert len(before) >= 500
    left = np.mean(before)
    # The robot says it stands still, ten times a second.
    publisher = probe.node.create_publisher(Bool, 'at_rest', 10)
    timer = probe.node.create_timer(0.1, lambda: publisher.publish(Bool(data=True)))
    # (A publisher stalled by a loaded machine lets a hint go stale: that window is not
    # hinted, and a later one is.)
    probe.wait_status(COMPENSATION_DIAGNOSTIC, lambda s: int(status_values(s).get(
        'tracking_updates', 0)) >= 2 and status_values(s)['tracking_hinted'] == 'True' and
        status_values(s)['rest_hint_state'] == 'at rest', TIMEOUT_S,
        'the tracker learning under the hint', launcher)
    # The estimate goes out stamped with the sample that closed its window: later samples
    # have it applied.
    probe.spin_until(lambda: any(int(status_values(a.status[0])['updates']) >= 2
                                 for a in status), TIMEOUT_S, 'the estimate', launcher)
    estimate = next(a for a in status if int(status_values(a.status[0])['updates']) >= 2)
    offset = float(status_values(estimate.status[0])['estimate_rad_s'])
    applied_ns = messages.stamp_to_ns(estimate.header.stamp)

    def after():
        return [m.angular_velocity.z for m in probe.received['imu/data']
                if messages.stamp_to_ns(m.header.stamp) >= applied_ns]
    probe.spin_until(lambda: len(after()) >= 300, TIMEOUT_S, '300 samples after it', launcher)
    mean = np.mean(after()[:300])
    print(f'the model leaves {math.degrees(left):.3f} deg/s; learnt offset '
          f'{math.degrees(offset):.3f} deg/s; imu/data mean after it {math.degrees(mean):.4f}')
    # The table leaves a few hundredths at 25 C, the supply adds 0.3: all of it is taken,
    # within the noise of the means (0.0058 rad/s a sample; a window holds 500).
    noise = 0.0058 * math.sqrt(1.0 / len(before) + 1.0 / 500)
    assert math.degrees(left) > 0.25 and offset == pytest.approx(left, abs=5 * noise)
    assert abs(mean) < 5 * 0.0058 * math.sqrt(1.0 / 300 + 1.0 / 500)
    timer.cancel()
    stale = status_values(probe.wait_status(
        COMPENSATION_DIAGNOSTIC, lambda s: status_values(s).get('rest_hint_state') == 'stale',
        TIMEOUT_S, 'the hint going stale', launcher))
    assert float(stale['rest_hint_age_s']) > 3.0
