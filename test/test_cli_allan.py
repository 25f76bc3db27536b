"""The ``mlx-tempcomp allan`` command: the table, allan.json, allan.png and user errors."""

import json

from cli_checks import assert_user_error
from mlx_tempcomp.cli import main
import numpy as np
import pytest

RATE_HZ = 100.0
SIGMA_RAD_S = 0.1  # per-sample white noise: ARW 0.01 rad/s/sqrt(Hz) at 100 Hz
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def white_noise_csv(tmp_path, samples=20_000, seed=0):
    """Write a CSV of white gyro noise on x and z at 100 Hz; return its path."""
    rng = np.random.default_rng(seed)
    columns = {'time': np.arange(samples) / RATE_HZ, 'temperature': np.full(samples, 25.0),
               'gyro_x': rng.normal(0.0, SIGMA_RAD_S, samples),
               'gyro_z': rng.normal(0.0, SIGMA_RAD_S, samples)}
    path = tmp_path / 'still.csv'
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',',
               header=','.join(columns), comments='')
    return str(path)


def test_allan_prints_the_table_and_writes_json_and_png(tmp_path, capsys):
    out_dir = tmp_path / 'noise'
    assert main(['allan', white_noise_csv(tmp_path), '--out', str(out_dir)]) == 0
    out, err = capsys.readouterr()
    assert err == ''
    assert 'deg/sqrt(h)' in out and 'rate_noise' in out
    result = json.loads((out_dir / 'allan.json').read_text())
    assert [a['axis'] for a in result['axes']] == ['x', 'z']
    for axis in result['axes']:
        assert axis['rate_noise_rad_s'] == pytest.approx(SIGMA_RAD_S, rel=0.1)
        assert len(axis['taus_s']) == len(axis['adev_rad_s']) > 5
    assert (out_dir / 'allan.png').read_bytes()[:8] == PNG_SIGNATURE


def test_allan_without_out_writes_nothing(tmp_path, capsys):
    assert main(['allan', white_noise_csv(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ['still.csv']
    assert 'wrote' not in capsys.readouterr().out


def test_allan_missing_file_is_one_error_line(tmp_path, capsys):
    assert_user_error(main(['allan', str(tmp_path / 'absent.csv')]), capsys, 'absent.csv')


def test_allan_short_record_is_one_error_line(tmp_path, capsys):
    code = main(['allan', white_noise_csv(tmp_path, samples=50)])
    assert_user_error(code, capsys, 'at least 100 samples')
