"""
Field learning in the compensation node, over DDS: the offline twin's bits, the state, the file.

A record at rest with a bowl in temperature the fitted line does not hold (as
test_cli_learning.py makes it, 2 h at 1 Hz) gets known motion from ``mlx-tempcomp
inject-motion``; ``fit --order 1`` writes the prior model; ``convert`` makes it a bag. The
bag replayed through driver_node into compensation_node with learning on must give what
``evaluate --track-bias --learn`` gives on the same bag, bit for bit, renewals included.
``imu/save_learned_model`` then writes what ``--learned-params`` writes (the same
correction table), over a symlink planted at the target, which it replaces; ``evaluate
--params`` runs the file. The learnt state survives a stop: the restarted node starts from
it and writes the same model. A damaged learning section gives the prior and one WARN line,
and the ZRO offset beside it stays. A second save while one runs is refused: the node in
this process, its service coroutine held at its await.
"""

from contextlib import redirect_stdout
import io
import json
import logging
import os
import signal
import stat

from mlx_tempcomp.cli import main
from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.node_models.correction import CorrectionTable
from mlx_tempcomp.parameters.compensation import compensation_settings
from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.state_file import read_state, write_state
from mlx_tempcomp.recordings.bag import RawTopics
from mlx_tempcomp.recordings.bag_reader import RawBagReader
from mlx_tempcomp.ros.compensation.node import CompensationNode
from mlx_tempcomp.ros.compensation.zro_recalibration import ZroRecalibration
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rest_records import bowl_record
from ros_harness import (COMPENSATION_DIAGNOSTIC, finish_model_replay, parse_list, Probe,
                         start_model_replay, status_values, write_params)
from std_srvs.srv import Trigger
import yaml

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
RAW_TOPICS = ('--imu-topic', '/imu/data_raw', '--temperature-topic', '/imu/temperature_raw')
# Tracking and learning on; the state written after every window (nothing lost at a stop).
LEARNING = {'bias_tracking.enabled': True, 'learning.enabled': True,
            'bias_tracking.save_period_s': 0.0}
SERVICE = 'imu/save_learned_model'
AXES = ('x', 'y', 'z')


def cli(*argv) -> str:
    """Run an mlx-tempcomp command in this process; give what it printed."""
    out = io.StringIO()
    with redirect_stdout(out):
        assert main([str(a) for a in argv]) == 0
    return out.getvalue()


def learning_bag(folder) -> tuple:
    """Make the bowl record with motion, fit a line, convert: (params, bag, stamps, messages)."""
    rest = bowl_record(folder / 'rest.csv', hours=2.0, rate_hz=1.0)
    cli('inject-motion', rest, '--out', folder / 'moving.csv', '--seed', '2')
    cli('fit', folder / 'moving.csv', '--order', '1', '--out', folder / 'line.yaml')
    cli('convert', folder / 'moving.csv', '--out', folder / 'bag')
    stamps, messages = [], 0
    with RawBagReader(folder / 'bag', RawTopics()) as reader:
        for _, topic, item in reader.records():
            messages += 1
            if topic == RawTopics.imu:
                stamps.append(item.stamp_ns)
    return str(folder / 'line.yaml'), folder / 'bag', stamps, messages


def correction(path) -> dict:
    """Give the correction section of a parameter file the node or evaluate wrote."""
    document = yaml.safe_load(open(path).read())
    return document['compensation_node']['ros__parameters']['correction']


def learning_status(probe, launcher, predicate, what: str) -> dict:
    return status_values(probe.wait_status(
        COMPENSATION_DIAGNOSTIC, lambda s: predicate(status_values(s)), TIMEOUT_S, what,
        launcher))


@pytest.mark.slow
def test_the_node_learns_as_evaluate_learn_does_to_the_bit_and_keeps_it(launcher, probe,
                                                                        tmp_path):
    params, bag, stamps_ns, messages_in_bag = learning_bag(tmp_path)
    report = json.loads(cli('evaluate', bag, *RAW_TOPICS, '--params', params, '--track-bias',
                            '--learn', '--json', '--out-csv', tmp_path / 'twin.csv',
                            '--learned-params', tmp_path / 'twin.yaml'))['bias_tracking']
    learnt = report['learning']
    twin = np.genfromtxt(tmp_path / 'twin.csv', delimiter=',', names=True)
    expected = np.column_stack([twin[f'gyro_{a}'] for a in AXES])
    # The twin renewed the model: a correction was taken off, changed on the way.
    assert learnt['swaps'] >= 2 and sum(a['renewals'] for a in learnt['axes'].values()) >= 2
    assert np.max(np.abs(np.column_stack([twin[f'correction_{a}'] for a in AXES]))) > 1e-4

    target = tmp_path / 'review' / 'learned.yaml'
    target.parent.mkdir()
    node_params = {**LEARNING, 'learning.learned_model_file': str(target)}
    start_model_replay(launcher, probe, tmp_path, bag, params, **node_params)
    got = np.array(finish_model_replay(launcher, probe, stamps_ns, messages_in_bag))
    differing = np.count_nonzero(np.any(got != expected, axis=1))
    print(f'{len(got)} samples; {differing} differ from evaluate --track-bias --learn; '
          f'{learnt["windows"]} windows used, {learnt["swaps"]} corrections taken in use')
    assert differing == 0

    # /diagnostics: what the learner holds, as the twin's report says it.
    diagnostics = learning_status(
        probe, launcher, lambda v: v.get('learning_windows') == str(learnt['windows']),
        'the learner in the diagnostics')
    assert diagnostics['learning'] == 'on' and diagnostics['learning_started_from'] == 'the prior'
    assert diagnostics['learning_swaps'] == str(learnt['swaps'])
    for i, axis in enumerate(AXES):
        a = learnt['axes'][axis]
        assert diagnostics[f'learning_{axis}_renewals'] == str(a['renewals'])
        assert diagnostics[f'learning_{axis}_reason'] == a['reason']
        assert parse_list(diagnostics[f'learning_{axis}_coverage']) == pytest.approx(
            learnt['coverage'][i], rel=1e-5, abs=1e-9)
        if a['last_renewal'] is not None:
            assert float(diagnostics[f'learning_{axis}_last_renewal_s']) == pytest.approx(
                a['last_renewal'][0], rel=1e-5)
            assert float(diagnostics[f'learning_{axis}_held_out_gain']) == pytest.approx(
                a['last_renewal'][1], rel=1e-5)

    # imu/save_learned_model: a symlink planted at the target is replaced, not followed.
    victim = tmp_path / 'victim.txt'
    victim.write_text('not a parameter file\n')
    os.symlink(victim, target)
    response = probe.call(Trigger, SERVICE, Trigger.Request(), TIMEOUT_S)
    print(response.message)
    assert response.success, response.message
    assert response.message.startswith(f'wrote the model in use to {target}: ')
    renewed = build_model(node_values(str(target), 'compensation_node'))
    prior = build_model(node_values(params, 'compensation_node'))
    assert f'renewals since the prior: polynomial model {prior.fingerprint()} to ' \
        f'{renewed.fingerprint()})' in response.message
    assert victim.read_text() == 'not a parameter file\n'
    assert not target.is_symlink() and stat.S_IMODE(target.stat().st_mode) == 0o644
    # The model evaluate --learned-params wrote at the end of the same record, to the bit.
    assert correction(target) == correction(tmp_path / 'twin.yaml')
    # The prior model's coefficients as they were, less the table.
    assert renewed.base.fingerprint() == prior.fingerprint()
    assert target.read_text().startswith('# Model in use by compensation_node (field learning)')
    # evaluate takes the file and runs the renewed model.
    text = cli('evaluate', bag, *RAW_TOPICS, '--params', target)
    assert 'polynomial' in text

    # A clean stop keeps the learner in the state file; the restarted node starts from it.
    node, driver = launcher.processes[-2:]
    node.signal(signal.SIGINT)
    assert node.stop() == 0
    driver.stop()
    state = read_state(str(tmp_path / 'zro.yaml'))
    section = state['learning']
    assert section['counts']['windows'] == learnt['windows']
    assert section['accepted'] == [list(v) for v in _accepted(tmp_path / 'twin.yaml')]
    os.unlink(target)
    restarted = launcher.start('compensation_node', 'compensation_node', extra_args=[
        '--params-file', params, '--params-file', str(tmp_path / 'replay_compensation.yaml')],
        label='restarted')
    second = Probe('restarted')
    try:
        second.subscribe_diagnostics()
        values = learning_status(second, launcher,
                                 lambda v: v.get('learning_windows') == str(learnt['windows']),
                                 'the restored learner')
        assert values['learning_started_from'] == f'the state file ({learnt["windows"]} windows)'
        response = second.call(Trigger, SERVICE, Trigger.Request(), TIMEOUT_S)
        assert response.success, response.message
    finally:
        second.close()
    assert correction(target) == correction(tmp_path / 'twin.yaml')
    assert f'applied saved learning state from {tmp_path / "zro.yaml"}: ' \
        f'{learnt["windows"]} windows' in restarted.output()


def _accepted(path) -> list:
    """Give the learnt table relative to the prior (the prior line carries none)."""
    table = correction(path)
    return [table[f'{axis}_rad_s'] for axis in AXES]


MODEL = {'model': 'polynomial', 'axes': ['z'], 'polynomial.bias.z': [0.02, 0.001]}
ZRO_OFFSET_RAD_S = 0.01


@pytest.mark.slow
def test_a_damaged_learning_section_gives_the_prior_one_warning_and_keeps_the_zro_offset(
        launcher, probe, tmp_path):
    params = write_params(tmp_path / 'model.yaml', 'compensation_node', MODEL)
    model = build_model(node_values(params, 'compensation_node'))
    path = tmp_path / 'zro.yaml'
    # A learning section cut short, beside a whole ZRO state.
    write_state(str(path), {
        'model': 'polynomial', 'fingerprint': model.fingerprint(), 'axes': ['z'],
        'zro_offset': [ZRO_OFFSET_RAD_S], 'offset_unit': 'rad/s',
        'zro_offset_rad_s': [ZRO_OFFSET_RAD_S], 'temperature_c': 25.0, 'samples': 200,
        'time': '2026-11-25T12:00:00+00:00',
        'learning': {'model': 'polynomial', 'fingerprint': model.fingerprint(), 'version': 1,
                     'axes': ['z'], 'knots_c': [-40.0, -35.0]}})
    probe.subscribe_diagnostics()
    node = launcher.compensation({**MODEL, **LEARNING, 'recalibration.state_file': str(path)})
    values = learning_status(probe, launcher, lambda v: 'learning_started_from' in v,
                             'the learner in the diagnostics')
    assert values['learning_started_from'].startswith('the prior (saved state unusable: ')
    assert values['learning_windows'] == '0'
    node.signal(signal.SIGINT)
    assert node.stop() == 0
    log = node.output()
    warnings = [line for line in log.splitlines() if 'learning' in line and '[WARN]' in line]
    print(warnings)
    assert len(warnings) == 1 and '[ERROR]' not in log, log
    assert f'saved learning state in {path} unusable: damaged: committed, working' in \
        warnings[0]
    assert 'learning starts from the prior model (the ZRO and tracked offsets beside it stay)' \
        in warnings[0]
    assert f'applied saved ZRO offset [{ZRO_OFFSET_RAD_S}] rad/s from {path}' in log
    kept = [p.name for p in tmp_path.iterdir() if p.name.startswith('zro.yaml.bad-')]
    assert len(kept) == 1, kept
    assert read_state(str(path))['zro_offset'] == [ZRO_OFFSET_RAD_S]


def test_a_save_while_one_runs_is_refused_not_queued(tmp_path):
    """The node in this process: the first call's coroutine is held at its await."""
    context = Context()
    rclpy.init(args=['learning', '--ros-args', '--disable-external-lib-logs'], context=context,
               signal_handler_options=SignalHandlerOptions.NO)
    target = tmp_path / 'learned.yaml'
    overrides = {**MODEL, **LEARNING, 'recalibration.state_file': str(tmp_path / 'zro.yaml'),
                 'learning.learned_model_file': str(target)}
    node = CompensationNode(context=context, parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()])
    try:
        first = node.save_learned_model(Trigger.Request(), Trigger.Response())
        first.send(None)     # the write started; awaiting its answer (only a timer gives it)
        second = node.save_learned_model(Trigger.Request(), Trigger.Response())
        with pytest.raises(StopIteration) as stopped:
            second.send(None)
        refused = stopped.value.value
        assert not refused.success
        assert refused.message.startswith('refused: a save of the learned model is running '
                                          'since '), refused.message
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        task = executor.create_task(first)
        executor.spin_until_future_complete(task, TIMEOUT_S)
        answer = task.result()
        assert answer.success, answer.message
        assert answer.message.startswith(f'wrote the model in use to {target}: no axis renewed')
        # Nothing learnt: the prior model, no correction table.
        written = yaml.safe_load(target.read_text())['compensation_node']['ros__parameters']
        assert 'correction' not in written and written['learning']['enabled'] is True
        model_file = write_params(tmp_path / 'model.yaml', 'compensation_node', MODEL)
        prior = build_model(node_values(model_file, 'compensation_node'))
        assert build_model(node_values(str(target), 'compensation_node')).fingerprint() == \
            prior.fingerprint()
        executor.shutdown()
    finally:
        node.destroy_node()
        context.try_shutdown()


def test_a_recalibration_zeroes_the_model_in_use_with_the_learnt_correction(tmp_path):
    """The window holds the model's rate less the correction: the offset zeroes that."""
    model = build_model(node_values(write_params(tmp_path / 'model.yaml', 'compensation_node',
                                                 MODEL), 'compensation_node'))
    values = node_values(str(tmp_path / 'model.yaml'), 'compensation_node')
    table = CorrectionTable((20.0, 30.0, 40.0), ((1e-3, 2e-3, 4e-3),))
    rng = np.random.default_rng(3)
    stamps = [int(1e9 + k * 1e7) for k in range(600)]
    temperature = 30.0 + 0.02 * rng.standard_normal(len(stamps))
    raw = 0.05 + 1e-4 * rng.standard_normal(len(stamps))
    model_rate = model.correct(raw[:, None], temperature).rate_rad_s[:, 0]
    in_use = model_rate - table.columns(temperature[:, None])[:, 0]
    for correction, rows, changed in ((table, in_use, None), (None, model_rate, None),
                                      (table, in_use, table.with_axis(0, (0.0,) * 3))):
        recalibration = ZroRecalibration(str(tmp_path / 'zro.yaml'), ('z',), logging.getLogger())
        recalibration.start(model, compensation_settings(values), correction)
        window = recalibration.window
        recalibration.add(stamps, [[r] for r in raw], [[t] for t in temperature],
                          [[r] for r in rows])
        if changed is not None:
            with pytest.raises(CalibrationError, match='the learnt correction was renewed '
                                                       'during the window'):
                recalibration.learn(window, model, changed)
            continue
        learned = recalibration.learn(window, model, correction)
        # The model in use with the new offset reads zero on average over the window.
        n = len(window.samples.rows)
        assert 400 < n < len(stamps)
        after = learned.model.correct(raw[:n, None], temperature[:n]).rate_rad_s[:, 0]
        if correction is not None:
            after = after - table.columns(temperature[:n, None])[:, 0]
        assert abs(np.mean(after)) < 1e-15
        assert learned.model.zro_offset[0] == pytest.approx(np.mean(rows[:n]), rel=1e-12)


def test_the_mpu6000_offset_registers_refuse_a_learnt_correction(launcher, tmp_path):
    path = write_params(tmp_path / 'learnt.yaml', 'compensation_node', {
        'model': 'polynomial', 'axes': AXES, **{f'polynomial.bias.{a}': [0.01] for a in AXES},
        'correction.temperature_c': [20.0, 40.0],
        **{f'correction.{a}_rad_s': [1e-3, 2e-3] for a in AXES}})
    driver = launcher.driver({'device': 'mpu6000', 'axes': list(AXES),
                              'mpu6000.offset_model_file': path})
    assert driver.wait(TIMEOUT_S) == 1
    assert (f'invalid parameter mpu6000.offset_model_file ({path}): correction.* (a learnt '
            "correction table): the offset registers take the polynomial's bias alone") in \
        driver.output()
