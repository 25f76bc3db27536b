"""
What the command line alone can refuse is refused before the record is read.

Each case gives a record path that does not exist: a command that checked its
arguments only after reading the record would answer "no such file" (or run
a fit first); these answer with the argument's own one-line error, exit code
2, and write nothing. What only the record can tell (its axes for the
exports, its acceleration for TC_A) is refused right after it is read, before
the fit.
"""

from pathlib import Path

from cli_checks import assert_user_error
from mlx_tempcomp.cli import main
import numpy as np
import pytest

MISSING = 'no-such-record.csv'


@pytest.mark.parametrize('argv, needles', [
    # The exports: the case first, --ardupilot-parm beside it needs no id.
    (['fit', MISSING, '--out', '{tmp}/fit.yaml', '--px4-params', '{tmp}/px4.params',
      '--ardupilot-parm', '{tmp}/imu.parm'], ["gyro's device id", '--px4-device-id']),
    (['fit', MISSING, '--out', '{tmp}/fit.yaml', '--px4-device-id', '5'],
     ['--px4-device-id applies with --px4-params']),
    (['diagnose', MISSING, '--out', '{tmp}/d', '--px4-accel-device-id', '5'],
     ['--px4-accel-device-id applies with --px4-params']),
    (['fit', MISSING, '--out', '{tmp}/fit.yaml', '--ardupilot-parm', '{tmp}/no/imu.parm'],
     ['--ardupilot-parm', 'does not exist']),
    # The held-out blocks and the diagnosis settings.
    (['fit', MISSING, '--out', '{tmp}/fit.yaml', '--blocks', '1'],
     ['2 <= folds <= blocks, got 5 folds, 1 blocks']),
    (['fit', MISSING, '--out', '{tmp}/fit.yaml', '--validation', 'round-robin', '--folds',
      '30'], ['2 <= folds <= blocks']),
    (['diagnose', MISSING, '--out', '{tmp}/d', '--blocks', '3'], ['blocks (3)', 'folds (5)']),
    (['diagnose', MISSING, '--out', '{tmp}/d', '--error-bins', '0'], ['error_bins']),
    # Output paths.
    (['evaluate', MISSING, '--params', '{tmp}/params.yaml', '--out-csv', '{tmp}/no/c.csv'],
     ['--out-csv', 'does not exist']),
    (['diagnose', MISSING, '--out', '{tmp}'], ['holds', 'which this command does not write']),
    (['convert', MISSING, '--out', '{tmp}'], ['exists already']),
])
def test_refused_before_the_record_is_read(tmp_path, capsys, argv, needles):
    (tmp_path / 'params.yaml').write_text(
        'compensation_node:\n  ros__parameters:\n    model: polynomial\n    axes: [z]\n'
        '    polynomial:\n      bias:\n        z: [0.0]\n', encoding='utf-8')
    (tmp_path / 'keep.txt').write_text("not diagnose's", encoding='utf-8')
    before = sorted(tmp_path.rglob('*'))
    code = main([part.format(tmp=tmp_path) for part in argv])
    assert_user_error(code, capsys, *needles)
    assert sorted(tmp_path.rglob('*')) == before


@pytest.mark.parametrize('argv, message', [
    (['--px4-device-id', 'abc'], 'expected a 32-bit device id'),
    (['--px4-device-id', str(2 ** 32)], 'expected a 32-bit device id'),
    (['--node-name', 'my node'], 'expected a ROS node name'),
    (['--blocks', '-1'], 'expected a non-negative integer'),
])
def test_malformed_options_are_argparse_errors(capsys, argv, message):
    with pytest.raises(SystemExit) as end:
        main(['fit', MISSING, '--out', 'fit.yaml', *argv])
    assert end.value.code == 2
    assert message in capsys.readouterr().err


def test_diagnose_max_order_below_the_cubic_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(['diagnose', MISSING, '--out', 'd', '--max-order', '2'])
    assert 'at least 3' in capsys.readouterr().err


def test_a_device_id_may_be_given_in_hex_and_lands_in_the_file(tmp_path, capsys):
    path = tmp_path / 'cycle.csv'
    assert main(['simulate', '--out', str(path), '--cycle-c', '60', '-20', '25',
                 '--ramp-c-per-min', '8', '--rate-hz', '1', '--seed', '4']) == 0
    assert main(['fit', str(path), '--out', str(tmp_path / 'fit.yaml'), '--px4-params',
                 str(tmp_path / 'px4.params'), '--px4-device-id', '0x250012']) == 0
    assert f'TC_G0_ID\t{0x250012}\t6' in (tmp_path / 'px4.params').read_text()


def test_a_record_the_exports_cannot_use_is_refused_before_the_fit(tmp_path, capsys):
    path = tmp_path / 'z.csv'
    time_s = np.arange(400.0)
    np.savetxt(path, np.column_stack([time_s, 20.0 + 0.1 * time_s, np.zeros(400)]),
               delimiter=',', header='time,temperature,gyro_z', comments='')
    for argv, needle in (
            (['--ardupilot-parm', str(tmp_path / 'imu.parm')], 'corrects x, y and z'),
            (['--px4-params', str(tmp_path / 'p'), '--px4-device-id', '1'],
             'corrects x, y and z')):
        code = main(['fit', str(path), '--out', str(tmp_path / 'fit.yaml'), *argv])
        out = capsys.readouterr().out
        assert code == 2
        assert 'rows used' in out and 'model polynomial' not in out   # read, not fitted
    xyz = tmp_path / 'xyz.csv'
    np.savetxt(xyz, np.column_stack([time_s, 20.0 + 0.1 * time_s, np.zeros((400, 3))]),
               delimiter=',', header='time,temperature,gyro_x,gyro_y,gyro_z', comments='')
    code = main(['fit', str(xyz), '--out', str(tmp_path / 'fit.yaml'), '--px4-params',
                 str(tmp_path / 'p'), '--px4-device-id', '1', '--px4-accel-device-id', '2'])
    assert_user_error(code, capsys, 'no acceleration')
    assert sorted(p.name for p in Path(tmp_path).iterdir()) == ['xyz.csv', 'z.csv']


def test_a_fleet_manifest_row_with_a_bad_column_map_is_refused_before_any_unit(
        tmp_path, capsys):
    record = tmp_path / 'a.csv'
    record.write_text('time,temperature,gyro_z\n0,20,0\n', encoding='utf-8')
    manifest = tmp_path / 'units.csv'
    manifest.write_text(f'unit,path,columns\nu1,{record},time=t:x\n', encoding='utf-8')
    code = main(['fleet', 'fit', '--manifest', str(manifest), '--out', str(tmp_path / 'out')])
    assert_user_error(code, capsys, 'unit u1', str(record))
    assert not (tmp_path / 'out').exists()
