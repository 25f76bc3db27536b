"""The ``mlx-tempcomp allan`` command: the table, allan.json, allan.png, imu.yaml, user errors."""

import json

from cli_checks import assert_user_error
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.series.noise import allan_deviation
import numpy as np
from plot_checks import drawn_figures
import pytest
import yaml

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


# Kalibr's imu.yaml. A rest record of known white noise N (per axis, continuous-time density)
# and bias random walk K: per sample at f Hz, white noise of sigma N sqrt(f) on top of a bias
# stepping by K / sqrt(f).
KALIBR_RATE_HZ = 5.0
KALIBR_DURATION_S = 20000.0
GYRO_N, GYRO_K = 0.003, 0.002      # rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)
ACCEL_N, ACCEL_K = 0.02, 0.005     # m/s^2/sqrt(Hz), m/s^3/sqrt(Hz)


def rest_record_csv(tmp_path, seed=3, accelerometer=True):
    """Write a still record of white noise plus bias random walk; return its path."""
    rng = np.random.default_rng(seed)
    samples = int(KALIBR_RATE_HZ * KALIBR_DURATION_S)

    def noise(density, walk):
        return (rng.normal(0.0, density * KALIBR_RATE_HZ ** 0.5, samples)
                + np.cumsum(rng.normal(0.0, walk / KALIBR_RATE_HZ ** 0.5, samples)))

    columns = {'time': np.arange(samples) / KALIBR_RATE_HZ,
               'temperature': np.full(samples, 25.0)}
    columns.update((f'gyro_{a}', noise(GYRO_N, GYRO_K)) for a in 'xyz')
    if accelerometer:
        columns.update((f'acc_{a}', noise(ACCEL_N, ACCEL_K) + (9.81 if a == 'z' else 0.0))
                       for a in 'xyz')
    path = tmp_path / 'rest.csv'
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',', fmt='%.10g',
               header=','.join(columns), comments='')
    return str(path)


def test_kalibr_yaml_gives_the_known_densities(tmp_path, capsys):
    target = tmp_path / 'imu.yaml'
    assert main(['allan', rest_record_csv(tmp_path), '--kalibr-yaml', str(target)]) == 0
    out = capsys.readouterr().out
    imu = yaml.safe_load(target.read_text())
    assert set(imu) == {'gyroscope_noise_density', 'gyroscope_random_walk',
                        'accelerometer_noise_density', 'accelerometer_random_walk',
                        'rostopic', 'update_rate'}
    for key, truth in (('gyroscope_noise_density', GYRO_N), ('gyroscope_random_walk', GYRO_K),
                       ('accelerometer_noise_density', ACCEL_N),
                       ('accelerometer_random_walk', ACCEL_K)):
        print(f'{key}: {imu[key]:.4e}, true {truth:.4e} ({imu[key] / truth - 1:+.1%})')
        assert imu[key] == pytest.approx(truth, rel=0.10), key
    print(''.join(line for line in target.read_text().splitlines(True)
                  if not line.startswith('#')), end='')   # the file, for docs/toolkit-allan.md
    assert imu['rostopic'] == '/imu/data' and imu['update_rate'] == KALIBR_RATE_HZ
    assert f'wrote {target}' in out and 'upper bound' not in target.read_text()


def test_the_allan_plot_shows_the_lines_and_where_each_figure_was_read(tmp_path, monkeypatch):
    with drawn_figures(monkeypatch) as saved:
        assert main(['allan', rest_record_csv(tmp_path), '--out', str(tmp_path / 'out')]) == 0
    result = json.loads((tmp_path / 'out' / 'allan.json').read_text())
    overlaps, figure = saved['allan.png']
    assert overlaps == []
    gyro, accel = figure.axes   # each sensor on axes of its own
    assert (gyro.get_title(), accel.get_title()) == ('gyro', 'accelerometer')
    assert 'rad/s' in gyro.get_ylabel() and 'm/s^2' in accel.get_ylabel()
    for plot, figures in ((gyro, result['axes']), (accel, result['accelerometer_axes'])):
        for k, axis in enumerate(figures):
            lines = [line for line in plot.get_lines() if line.get_color() == f'C{k}']
            by_style = {(line.get_linestyle(), line.get_marker()): line for line in lines}
            # The white-noise and random-walk lines, through the figures read.
            white, walk = by_style[('--', 'None')], by_style[(':', 'None')]
            taus = white.get_xdata()
            np.testing.assert_allclose(white.get_ydata(),
                                       axis['noise_density_rad_s_rt_hz' if plot is gyro else
                                            'noise_density_m_s2_rt_hz'] / np.sqrt(taus))
            np.testing.assert_allclose(walk.get_ydata() / np.sqrt(walk.get_xdata() / 3.0),
                                       axis['random_walk_rad_s_s_rt_hz' if plot is gyro else
                                            'random_walk_m_s2_s_rt_hz'])
            # Where N, K and the bias instability's floor were read.
            assert by_style[('None', 's')].get_xdata()[0] == 1.0
            assert by_style[('None', '^')].get_xdata()[0] == 3.0
            floor = by_style[('None', 'v')]
            assert floor.get_xdata()[0] == axis['bias_instability_tau_s']
            at = axis['taus_s'].index(axis['bias_instability_tau_s'])
            assert floor.get_ydata()[0] == pytest.approx(axis['adev_rad_s'][at], rel=1e-12)
    labels = [text.get_text() for text in figure.legends[0].get_texts()]
    assert 'N read at tau = 1 s' in labels and 'K read at tau = 3 s' in labels


def test_kalibr_yaml_without_an_accelerometer_leaves_its_entries_out(tmp_path, capsys):
    target = tmp_path / 'imu.yaml'
    assert main(['allan', rest_record_csv(tmp_path, accelerometer=False), '--kalibr-yaml',
                 str(target), '--kalibr-topic', '/robot/imu']) == 0
    imu = yaml.safe_load(target.read_text())
    assert set(imu) == {'gyroscope_noise_density', 'gyroscope_random_walk', 'rostopic',
                        'update_rate'}
    assert imu['rostopic'] == '/robot/imu'
    assert 'accelerometer_* left out' in target.read_text()


def nbs14_1000():
    """
    Give the NBS14 1000-point frequency data set (NIST SP 1065, p. 107).

    The uniform random numbers of the generator published there: n(0) = 1234567890,
    n(i+1) = 16807 n(i) mod 2147483647, x = n / 2147483647.
    """
    n = [1234567890]
    for _ in range(999):
        n.append(16807 * n[-1] % 2147483647)
    assert n[1:4] == [395529916, 1209410747, 633705974]   # as published
    return np.array(n, dtype=float) / 2147483647


# Its published overlapping Allan deviation at tau = 1, 10 and 100 (NIST SP 1065, p. 108;
# allantools' own tests check against the same values).
NBS14_1000_OADEV = (2.922319e-01, 9.159953e-02, 3.241343e-02)


def test_allan_deviation_matches_the_nbs14_reference_values():
    (figures,) = allan_deviation(np.arange(1000.0), nbs14_1000()[:, None], ('x',),
                                 taus=[1.0, 10.0, 100.0])
    assert figures.taus_s.tolist() == [1.0, 10.0, 100.0]
    assert figures.adev_rad_s == pytest.approx(NBS14_1000_OADEV, rel=1e-6)


def test_the_nbs14_set_through_the_command_gives_its_published_deviation(tmp_path, capsys):
    # White noise: the white-noise line is the deviation itself, read at tau = 1 s; the set
    # holds no random walk, so its figure is a bound and the file says so.
    path = tmp_path / 'nbs14.csv'
    np.savetxt(path, np.column_stack([np.arange(1000.0), np.full(1000, 25.0), nbs14_1000()]),
               delimiter=',', fmt='%.17g', header='time,temperature,gyro_x', comments='')
    target = tmp_path / 'imu.yaml'
    assert main(['allan', str(path), '--out', str(tmp_path / 'noise'), '--kalibr-yaml',
                 str(target)]) == 0
    (axis,) = json.loads((tmp_path / 'noise' / 'allan.json').read_text())['axes']
    assert axis['taus_s'][0] == 1.0
    assert axis['adev_rad_s'][0] == pytest.approx(NBS14_1000_OADEV[0], rel=1e-6)
    imu = yaml.safe_load(target.read_text())
    assert imu['gyroscope_noise_density'] == pytest.approx(NBS14_1000_OADEV[0], rel=0.10)
    assert 'random_walk: ' in target.read_text() and 'an upper bound' in target.read_text()
    assert axis['random_walk_upper_bound'] and not axis['noise_density_upper_bound']


def test_kalibr_yaml_path_is_checked_before_the_record_is_read(tmp_path, capsys):
    code = main(['allan', str(tmp_path / 'absent.csv'), '--kalibr-yaml',
                 str(tmp_path / 'no' / 'imu.yaml')])
    assert_user_error(code, capsys, '--kalibr-yaml', 'does not exist')
