"""
Bias tracking through the command line: inject-motion, the fit and diagnose section, evaluate.

Records at rest (made here, from the simulated sensor, or the measured cycle) get known
motion with ``mlx-tempcomp inject-motion``; ``fit`` writes the model and its
``bias_tracking`` section; ``evaluate --track-bias`` runs the node's tracker over the
model's output and is compared with the truth and with the tracker run row by row, as
the node runs it; ``--rest-hint`` gives it the schedule's truth as the robot's rest hint.
"""

import json
import math

from cli_checks import assert_user_error, node_values
from measured_data import MEASURED_CSV
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.standstill.bias_tracker import BiasTracking
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.specs import axes_of
from mlx_tempcomp.parameters.tracking import tracking_settings
from mlx_tempcomp.recordings.load import load_recording
from mlx_tempcomp.simulation.motion import motion_schedule, ScheduleSettings
import numpy as np
import pytest
from rest_records import NOISE, offset_record, rest_record
import yaml


def run(*args) -> None:
    assert main([str(a) for a in args]) == 0


def evaluate_json(capsys, *args) -> dict:
    capsys.readouterr()
    run('evaluate', *args, '--json')
    return json.loads(capsys.readouterr().out)


def test_inject_motion_adds_the_schedule_and_turns_the_specific_force(tmp_path, capsys):
    source = rest_record(tmp_path / 'rest.csv', duration_s=900.0)
    run('inject-motion', source, '--schedule', 'cycle', '--seed', '4',
        '--out', tmp_path / 'moving.csv')
    assert 'cycle schedule (seed 4) over 899.9 s: still 30.0 % in 3 rests' in \
        capsys.readouterr().out
    rest, moving = load_recording(source), load_recording(tmp_path / 'moving.csv')
    schedule = json.loads((tmp_path / 'moving.schedule.json').read_text())
    assert schedule['time_zero_s'] == 100.0 and schedule['schedule'] == 'cycle'
    expected = motion_schedule(rest.duration_s + 1e-9, ScheduleSettings.cycle(), 4)
    assert schedule['segments'] == expected.to_json()
    # The gyro is the record's plus the reference; at rest the reference is zero and the
    # specific force along z the record's (every rest is level; turns about z keep z);
    # in motion it turns.
    assert np.allclose(moving.gyro_rad_s - moving.reference_rad_s, rest.gyro_rad_s,
                       rtol=1e-11, atol=1e-15)
    still = ~np.any(moving.reference_rad_s != 0.0, axis=1)
    assert still.mean() == pytest.approx(0.3, abs=0.002)
    assert np.allclose(moving.acceleration_m_s2[still, 2], rest.acceleration_m_s2[still, 2],
                       rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(moving.acceleration_m_s2 - rest.acceleration_m_s2)) > 5.0
    # The rest hint is the schedule's truth: 1 in its rests, 0 in its turns.
    written = np.genfromtxt(tmp_path / 'moving.csv', delimiter=',', names=True)
    in_rest = np.zeros(len(written), dtype=bool)
    for segment in schedule['segments']:
        if segment['kind'] == 'rest':
            elapsed = written['time'] - written['time'][0]
            in_rest |= (elapsed >= segment['start_s']) & (elapsed < segment['end_s'])
    assert np.array_equal(written['rest_hint'], in_rest.astype(float))
    assert not np.any(moving.reference_rad_s[in_rest]) and still[~in_rest].sum() < 10
    # A record with motion in it already is refused.
    assert_user_error(main(['inject-motion', str(tmp_path / 'moving.csv'),
                            '--out', str(tmp_path / 'twice.csv')]), capsys,
                      'has a reference rate already')


def test_fit_writes_bounds_from_the_rest_and_evaluate_is_the_node_s_tracker(tmp_path, capsys):
    source = rest_record(tmp_path / 'rest.csv')
    run('inject-motion', source, '--schedule', 'mixed', '--seed', '1',
        '--out', tmp_path / 'moving.csv')
    run('fit', tmp_path / 'moving.csv', '--order', '3', '--out', tmp_path / 'fit.yaml')
    assert 'bias tracking (bias_tracking.*, on): windows of 5 s' in capsys.readouterr().out
    section = yaml.safe_load((tmp_path / 'fit.yaml').read_text())[
        'compensation_node']['ros__parameters']['bias_tracking']
    assert section['enabled'] is True and section['window_s'] == 5.0
    assert section['rate_noise_rad_s'] == pytest.approx([NOISE] * 3, rel=0.1)
    # From the rests only: the turns would have made them huge.
    assert section['max_acceleration_spread_m_s2'] < 0.02
    assert section['max_tilt_rate_rad_s'] < 1e-3
    report = evaluate_json(capsys, tmp_path / 'moving.csv', '--params', tmp_path / 'fit.yaml',
                           '--track-bias', '--average-s', 10,
                           '--out-csv', tmp_path / 'out.csv')['bias_tracking']
    assert report['learnt_windows'] > 50 and report['still_share_true'] > 0.4
    assert max(report['learnt_while_moving']['largest_mean_reference_rad_s']) < 3.5e-4
    for axis in 'xyz':
        assert report['axes'][axis]['averaged_gain'] > 1.2
    # The node's tracker, row by row on the model's output, gives the file's bits.
    values = node_values(tmp_path / 'fit.yaml')
    axes = axes_of(values)
    record = load_recording(tmp_path / 'moving.csv')
    model_out = build_model(values).correct(record.gyro_rad_s, record.temperature_c).rate_rad_s
    tracker = BiasTracking(tracking_settings(values, axes, values['rate_noise_rad_s']), axes)
    rows = [tracker.process_one(t, r, c, a) for t, r, c, a in zip(
        record.time_s.tolist(), model_out.tolist(), record.temperature_c.tolist(),
        record.acceleration_m_s2.tolist())]
    written = np.genfromtxt(tmp_path / 'out.csv', delimiter=',', names=True)
    assert np.array_equal(np.column_stack([written[f'gyro_{a}'] for a in axes]),
                          [r[0] for r in rows])
    assert np.array_equal(np.column_stack([written[f'offset_std_{a}'] for a in axes]),
                          [r[1] for r in rows])
    assert np.array_equal(written['still'], [r[2] for r in rows])


def test_tracking_settings_in_the_file_are_checked(tmp_path, capsys):
    source = rest_record(tmp_path / 'rest.csv', duration_s=300.0)
    run('fit', source, '--order', '1', '--out', tmp_path / 'fit.yaml')
    document = yaml.safe_load((tmp_path / 'fit.yaml').read_text())
    tracking = document['compensation_node']['ros__parameters']['bias_tracking']
    for change, needle in (({'enabled': False}, 'turns bias tracking off'),
                           ({'initial_std_rad_s': [1e-3, 1e-3]},
                            'invalid parameter bias_tracking.initial_std_rad_s: give one value '
                            'or one per axis (3)'),
                           ({'window_s': 0.0}, 'invalid parameter bias_tracking.window_s: 0.0 '
                                               'is outside 0.1 to 3600')):
        changed = {**tracking, **change}
        document['compensation_node']['ros__parameters']['bias_tracking'] = changed
        (tmp_path / 'bad.yaml').write_text(yaml.safe_dump(document))
        assert_user_error(main(['evaluate', source, '--params', str(tmp_path / 'bad.yaml'),
                                '--track-bias']), capsys, needle)


def test_diagnose_writes_the_section_beside_the_effects(tmp_path, capsys):
    source = rest_record(tmp_path / 'rest.csv', duration_s=600.0)
    run('diagnose', source, '--out', tmp_path / 'diagnosed', '--no-plots')
    assert 'bias tracking (bias_tracking.*, on)' in capsys.readouterr().out
    parameters = yaml.safe_load((tmp_path / 'diagnosed' / 'params.yaml').read_text())[
        'compensation_node']['ros__parameters']
    assert parameters['model'] == 'effects'
    noise = parameters['bias_tracking']['rate_noise_rad_s']
    assert noise == pytest.approx([NOISE] * 3, rel=0.1)
    report = evaluate_json(capsys, source, '--params', tmp_path / 'diagnosed' / 'params.yaml',
                           '--track-bias')['bias_tracking']
    assert report['still_share_found'] > 0.9


@pytest.mark.slow
def test_simulated_sensor_with_a_random_walk_and_a_step_in_a_rest(tmp_path, capsys):
    """The simulated MLX90609 (no accelerometer) through the CLI; the step is followed."""
    seed, duration_s = 2, 1500.0
    schedule = motion_schedule(duration_s + 1e-9, ScheduleSettings.mixed(), seed)
    start, end = next((a, b) for a, b in schedule.rests() if b - a > 150.0)
    step_s, step_dps = start + 62.5, 0.06
    run('simulate', '--out', tmp_path / 'rest.csv', '--duration-s', duration_s, '--rate-hz', 25,
        '--cycle-c', 40, 15, '--ramp-c-per-min', 2, '--seed', 3, '--noise-scale', 0.3,
        '--bias-random-walk-dps-rt-s', 0.003, '--bias-step', f'{step_s}:{step_dps}')
    run('inject-motion', tmp_path / 'rest.csv', '--schedule', 'mixed', '--seed', seed,
        '--out', tmp_path / 'moving.csv')
    run('fit', tmp_path / 'moving.csv', '--out', tmp_path / 'fit.yaml')
    report = evaluate_json(capsys, tmp_path / 'moving.csv', '--params', tmp_path / 'fit.yaml',
                           '--track-bias', '--average-s', 10,
                           '--out-csv', tmp_path / 'out.csv')['bias_tracking']
    assert max(report['learnt_while_moving']['largest_mean_reference_rad_s']) < 3.5e-4
    record = load_recording(tmp_path / 'moving.csv')
    written = np.genfromtxt(tmp_path / 'out.csv', delimiter=',', names=True)
    error = np.column_stack([written[f'gyro_{a}'] for a in 'xyz']) - record.reference_rad_s
    # Two windows after the step's window, the offset holds the step (within a fifth).
    window_s = yaml.safe_load((tmp_path / 'fit.yaml').read_text())[
        'compensation_node']['ros__parameters']['bias_tracking']['window_s']
    followed = (record.time_s >= step_s + 3 * window_s) & (record.time_s < end)
    before = (record.time_s >= step_s) & (record.time_s < step_s + window_s)
    step = math.radians(step_dps)
    assert np.all(np.abs(error[before].mean(axis=0)) > 0.6 * step)
    assert np.all(np.abs(error[followed].mean(axis=0)) < 0.2 * step)


@pytest.mark.skipif(not MEASURED_CSV.exists(), reason=f'the measured cycle is not at '
                    f'{MEASURED_CSV} (set MLX_TEMPCOMP_SHARED)')
def test_the_measured_cycle_with_the_cycle_schedule(tmp_path, capsys):
    run('inject-motion', MEASURED_CSV, '--preset', 'tofupilot', '--schedule', 'cycle',
        '--seed', 1, '--out', tmp_path / 'moving.csv')
    run('fit', tmp_path / 'moving.csv', '--out', tmp_path / 'fit.yaml')
    report = evaluate_json(capsys, tmp_path / 'moving.csv', '--params',
                           tmp_path / 'fit.yaml', '--track-bias')['bias_tracking']
    gains = [report['axes'][a]['gain'] for a in 'xyz']
    # docs/tracking.md: x and y above 1.5; z held back by its first rest (see there).
    assert gains[0] > 2.5 and gains[1] > 1.5 and 1.1 < gains[2] < 1.5
    assert max(report['learnt_while_moving']['largest_mean_reference_rad_s']) < 3.5e-4


def test_evaluate_with_a_rest_hint_takes_an_offset_beyond_the_bound(tmp_path, capsys):
    source = rest_record(tmp_path / 'rest.csv', duration_s=900.0)
    run('inject-motion', source, '--schedule', 'cycle', '--seed', '2',
        '--out', tmp_path / 'moving.csv')
    run('fit', tmp_path / 'moving.csv', '--order', '3', '--out', tmp_path / 'fit.yaml')
    # An offset of 0.3 deg/s after the fit (a supply, a mounting stress): beyond the bound.
    offset_record(tmp_path / 'moving.csv', tmp_path / 'offset.csv', math.radians(0.3))
    args = (tmp_path / 'offset.csv', '--params', tmp_path / 'fit.yaml', '--track-bias')
    plain = evaluate_json(capsys, *args)['bias_tracking']
    hinted = evaluate_json(capsys, *args, '--rest-hint', 'rest_hint',
                           '--out-csv', tmp_path / 'out.csv')['bias_tracking']
    # Without the hint a gyro alone takes the offset for a turn, but where a turn cancels it.
    assert plain['hinted_windows'] == 0 and plain['updates'] < hinted['updates'] / 1.5
    assert hinted['rest_hint'] == {'column': 'rest_hint',
                                   'at_rest_share': pytest.approx(0.3, abs=0.002)}
    assert hinted['hinted_windows'] > 40 and hinted['updates'] > 40
    assert max(hinted['learnt_while_moving']['largest_mean_reference_rad_s']) < 3.5e-4
    for axis in 'xyz':
        assert hinted['axes'][axis]['gain'] > max(3.0, 2.5 * plain['axes'][axis]['gain'])
    # The node's tracker, row by row with each row's hint, gives the file's bits.
    values = node_values(tmp_path / 'fit.yaml')
    axes = axes_of(values)
    record = load_recording(tmp_path / 'offset.csv')
    hint = np.genfromtxt(tmp_path / 'offset.csv', delimiter=',', names=True)['rest_hint']
    model_out = build_model(values).correct(record.gyro_rad_s, record.temperature_c).rate_rad_s
    tracker = BiasTracking(tracking_settings(values, axes, values['rate_noise_rad_s']), axes)
    rows = [tracker.process_one(t, r, c, a, h == 1.0) for t, r, c, a, h in zip(
        record.time_s.tolist(), model_out.tolist(), record.temperature_c.tolist(),
        record.acceleration_m_s2.tolist(), hint.tolist())]
    written = np.genfromtxt(tmp_path / 'out.csv', delimiter=',', names=True)
    assert np.array_equal(np.column_stack([written[f'gyro_{a}'] for a in axes]),
                          [r[0] for r in rows])
    capsys.readouterr()
    run('evaluate', *args, '--rest-hint', 'rest_hint')
    assert 'rest hint rest_hint: at rest 30.0 % of the samples; ' in capsys.readouterr().out


def test_a_rest_hint_column_is_checked(tmp_path, capsys):
    source = rest_record(tmp_path / 'rest.csv', duration_s=120.0)
    run('inject-motion', source, '--out', tmp_path / 'moving.csv')
    run('fit', tmp_path / 'moving.csv', '--order', '1', '--out', tmp_path / 'fit.yaml')
    text = (tmp_path / 'moving.csv').read_text().splitlines()
    text[5] = text[5].rsplit(',', 1)[0] + ',2'
    (tmp_path / 'bad.csv').write_text('\n'.join(text) + '\n')
    params = ['--params', str(tmp_path / 'fit.yaml')]
    for argv, needles in (
            ([str(tmp_path / 'moving.csv'), *params, '--rest-hint', 'rest_hint'],
             ['--rest-hint is the bias tracking', 'give --track-bias']),
            ([str(tmp_path / 'moving.csv'), *params, '--track-bias', '--rest-hint', 'hint'],
             ['--rest-hint hint: ', "column 'hint' is not in the header"]),
            ([str(tmp_path / 'bad.csv'), *params, '--track-bias', '--rest-hint', 'rest_hint'],
             ['bad.csv: line 6: --rest-hint column', "holds '2'; it takes 0 (moving) or 1"])):
        capsys.readouterr()
        assert_user_error(main(['evaluate', *argv]), capsys, *needles)
    run('convert', tmp_path / 'moving.csv', '--out', tmp_path / 'bag')
    capsys.readouterr()
    assert_user_error(main(['evaluate', str(tmp_path / 'bag'), '--imu-topic', '/imu/data_raw',
                            '--temperature-topic', '/imu/temperature_raw', *params,
                            '--track-bias', '--rest-hint', 'rest_hint']), capsys,
                      'reads a 0/1 column of a CSV record')
