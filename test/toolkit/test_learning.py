"""
Field learning through the command line: evaluate --learn, the model it writes, simulate --day.

A record at rest made here (a bowl in T the fitted line does not hold, noise, gravity)
gets known motion with ``inject-motion``; ``fit --order 1`` writes the prior model;
``evaluate --track-bias --learn`` renews it and writes it with ``--learned-params``. The
file written runs again through ``evaluate`` as a parameter file, as the node loads it,
and takes off exactly the correction the learner applied at the end of the record.
"""

import contextlib
import io
import json

from cli_checks import assert_user_error, node_values
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.node_models.correction import CorrectedModel
from mlx_tempcomp.parameters.models import build_model
import numpy as np
import pytest
from rest_records import bowl_record
import yaml


def run(*args) -> None:
    assert main([str(a) for a in args]) == 0


def read(path) -> dict:
    table = np.genfromtxt(path, delimiter=',', names=True)
    return {name: table[name] for name in table.dtype.names}


@pytest.fixture(scope='module')
def learnt(tmp_path_factory):
    """
    Give the folder after inject-motion, fit --order 1, evaluate with and without --learn.

    What each evaluate printed is kept beside its CSV (NAME.txt).
    """
    folder = tmp_path_factory.mktemp('learning')
    rest = bowl_record(folder / 'rest.csv', rate_hz=1.0)
    assert main(['inject-motion', rest, '--out', str(folder / 'moving.csv'), '--seed', '2']) == 0
    assert main(['fit', str(folder / 'moving.csv'), '--order', '1',
                 '--out', str(folder / 'line.yaml')]) == 0
    for name, options in (('prior', []), ('tracked', ['--track-bias']),
                          ('learnt', ['--track-bias', '--learn', '--learned-params',
                                      str(folder / 'learnt.yaml')])):
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            assert main(['evaluate', str(folder / 'moving.csv'), '--params',
                         str(folder / 'line.yaml'), *options,
                         '--out-csv', str(folder / f'{name}.csv')]) == 0
        (folder / f'{name}.txt').write_text(printed.getvalue())
    return folder


def test_evaluate_learn_renews_the_model_and_writes_it_as_the_node_loads_it(learnt, capsys):
    document = yaml.safe_load((learnt / 'learnt.yaml').read_text())
    parameters = document['compensation_node']['ros__parameters']
    prior = yaml.safe_load((learnt / 'line.yaml').read_text())
    prior_parameters = prior['compensation_node']['ros__parameters']
    # The given file's section as it was, with the learnt correction added.
    assert {k: v for k, v in parameters.items() if k != 'correction'} == prior_parameters
    assert parameters['correction']['temperature_c'][:3] == [-40.0, -35.0, -30.0]
    values = node_values(learnt / 'learnt.yaml')
    model = build_model(values)
    assert isinstance(model, CorrectedModel) and not model.table.is_zero
    text = (learnt / 'learnt.yaml').read_text()
    assert text.startswith('# Model renewed by mlx-tempcomp evaluate --learn from ')
    assert '# axis x: ' in text and 'renewals' in text


def test_the_written_model_takes_off_what_the_learner_applied_at_the_end(learnt):
    run('evaluate', learnt / 'moving.csv', '--params', learnt / 'learnt.yaml', '--out-csv',
        learnt / 'written.csv')
    prior, written, learning = (read(learnt / f'{name}.csv')
                                for name in ('prior', 'written', 'learnt'))
    for axis in 'xyz':
        taken_off = prior[f'gyro_{axis}'] - written[f'gyro_{axis}']
        applied = learning[f'correction_{axis}']
        assert np.max(np.abs(taken_off)) > 1e-4, axis
        # From the learner's last swap on, the same table: at least the last window's rows.
        assert np.allclose(taken_off[-10:], applied[-10:], rtol=0, atol=1e-15), axis
        assert np.allclose(learning[f'gyro_{axis}'] + learning[f'offset_{axis}'],
                           prior[f'gyro_{axis}'] - applied, rtol=0, atol=1e-15)


def test_learning_beats_tracking_alone_on_the_bowl(learnt):
    truth = read(learnt / 'moving.csv')
    errors = {}
    for name in ('prior', 'tracked', 'learnt'):
        out = read(learnt / f'{name}.csv')
        start = truth['time'].size * 3 // 4
        error = np.column_stack([out[f'gyro_{a}'] - truth[f'ref_{a}'] for a in 'xyz'])[start:]
        errors[name] = np.sqrt(np.mean(error * error, axis=0))
    assert np.all(errors['learnt'] < errors['tracked']) and \
        np.all(errors['tracked'] < errors['prior'])


def test_evaluate_learn_reports_in_text_and_json(learnt, capsys):
    out = (learnt / 'learnt.txt').read_text()
    assert 'field learning: ' in out and ' windows used in ' in out
    for axis in 'xyz':
        assert f'\n  {axis}: ' in out
    run('evaluate', learnt / 'moving.csv', '--params', learnt / 'line.yaml', '--track-bias',
        '--learn', '--json')
    report = json.loads(capsys.readouterr().out)['bias_tracking']['learning']
    assert report['windows'] > 100 and set(report['axes']) == {'x', 'y', 'z'}
    assert len(report['coverage']) == 3 and len(report['knots_c']) == 26


def test_evaluate_learn_refuses_what_does_not_go_together(learnt, capsys):
    moving, line = learnt / 'moving.csv', learnt / 'line.yaml'
    assert_user_error(main(['evaluate', str(moving), '--params', str(line), '--learn']), capsys,
                      '--learn runs with the bias tracking: give --track-bias too')
    assert_user_error(main(['evaluate', str(moving), '--params', str(line), '--track-bias',
                            '--learned-params', str(learnt / 'x.yaml')]), capsys,
                      '--learned-params writes what --learn learnt: give --learn too')
    bad = learnt / 'bad.yaml'
    document = yaml.safe_load(line.read_text())
    document['compensation_node']['ros__parameters']['learning'] = {'knot_step_c': -1.0}
    bad.write_text(yaml.safe_dump(document))
    assert_user_error(main(['evaluate', str(moving), '--params', str(bad), '--track-bias',
                            '--learn']), capsys,
                      f'{bad}: invalid parameter learning.knot_step_c: -1.0 is outside 0.5 to 100')


def test_simulate_day_moves_the_unit_from_the_seed(tmp_path, capsys):
    common = ['simulate', '--duration-s', '20', '--rate-hz', '10', '--seed', '5',
              '--acceleration-dps-per-m-s2', '0.01', '0.01', '0.01']
    run(*common, '--out', tmp_path / 'plain.csv')
    run(*common, '--day', '1', '--out', tmp_path / 'day1.csv')
    run(*common, '--day', '2', '--out', tmp_path / 'day2.csv')
    run(*common, '--day', '2', '--out', tmp_path / 'again.csv')
    assert (tmp_path / 'plain.csv').read_text() == (tmp_path / 'day1.csv').read_text()
    assert (tmp_path / 'day2.csv').read_text() == (tmp_path / 'again.csv').read_text()
    day1, day2 = read(tmp_path / 'day1.csv'), read(tmp_path / 'day2.csv')
    truth = json.loads((tmp_path / 'day2.truth.json').read_text())
    assert truth['day']['day'] == 2 and 'day' not in json.loads(
        (tmp_path / 'day1.truth.json').read_text())
    change = truth['day']['zro_dps_coefficients_added']
    assert set(change) == {'x', 'y', 'z'} and all(len(c) == 4 and c[0] for c in change.values())
    face = truth['day']['face_up_m_s2']
    assert np.allclose(np.median(np.column_stack([day2[f'acc_{a}'] for a in 'xyz']), axis=0),
                       face)
    # The factory table stays the one measured on day 1: the same chips, other biases.
    assert truth['devices']['x']['sensor_mv_at_25c'] == json.loads(
        (tmp_path / 'day1.truth.json').read_text())['devices']['x']['sensor_mv_at_25c']
    assert not np.allclose(day1['gyro_x'], day2['gyro_x'])
    capsys.readouterr()
    with pytest.raises(SystemExit) as end:
        main(['simulate', '--out', str(tmp_path / 'x.csv'), '--day', '0'])
    assert end.value.code == 2
    assert "argument --day: a day is an integer from 1, got '0'" in capsys.readouterr().err
    assert_user_error(main(['simulate', '--out', str(tmp_path / 'y.csv'), '--turntable',
                            '--day', '2']), capsys, '--day')
