"""The ``mlx-tempcomp simulate`` and ``convert`` commands: recordings, bags and their truth."""

import json
import math

from cli_checks import assert_user_error
from measured_data import MEASURED_CSV
from mlx_tempcomp.cli import main
from mlx_tempcomp.recordings.bag_reader import RawBagReader
from mlx_tempcomp.recordings.load import load_recording
import numpy as np
import pytest

RAW_TOPICS = {'imu_topic': '/imu/data_raw', 'temperature_topic': '/imu/temperature_raw'}
# One rate LSB of the nominal conversion at 75 deg/s full scale: 25/12 mV / 26.67 mV/(deg/s).
RATE_LSB_RAD_S = math.radians(25.0 / 12.0 / (2000.0 / 75.0))


def simulate(tmp_path, capsys, name, *options):
    """Run simulate into tmp_path / name; return (path, truth, printed output)."""
    path = tmp_path / name
    assert main(['simulate', '--out', str(path), *options]) == 0
    out = capsys.readouterr().out
    truth_path = path.with_name(path.stem + '.truth.json')
    assert f'truth in {truth_path}' in out
    return path, json.loads(truth_path.read_text()), out


def noiseless_bias_rad_s(truth, axis, temperature_c):
    coefficients = truth['devices'][axis]['zero_rate_bias_rad_s_in_reported_t_minus_25c']
    return np.polynomial.polynomial.polyval(np.asarray(temperature_c) - 25.0, coefficients)


def test_noiseless_csv_follows_the_truth_and_its_bias_step(tmp_path, capsys):
    path, truth, out = simulate(tmp_path, capsys, 'step.csv', '--axes', 'z', '--noise-scale',
                                '0', '--cycle-c', '45', '5', '--ramp-c-per-min', '10',
                                '--rate-hz', '2', '--bias-step', '200:0.5')
    assert '721 samples over 360.0 s, axes z' in out
    recording = load_recording(path)
    assert recording.axes == ('z',) and recording.reference_rad_s is None
    residual = recording.gyro_rad_s[:, 0] - \
        noiseless_bias_rad_s(truth, 'z', recording.temperature_c)
    before, after = residual[recording.time_s < 200.0], residual[recording.time_s >= 200.0]
    # The recorded bias is the truth to within the ADC steps of both channels.
    assert np.max(np.abs(before)) < 1.5 * RATE_LSB_RAD_S
    assert np.mean(after) - np.mean(before) == pytest.approx(math.radians(0.5),
                                                             abs=0.5 * RATE_LSB_RAD_S)
    assert truth['config']['effects']['bias_steps'] == [[200.0, 0.5]]


def test_hysteresis_separates_heating_and_cooling(tmp_path, capsys):
    path, truth, _ = simulate(tmp_path, capsys, 'hyst.csv', '--axes', 'x', '--noise-scale',
                              '0', '--cycle-c', '45', '5', '45', '--ramp-c-per-min', '10',
                              '--rate-hz', '2', '--hysteresis-dps', '0.4',
                              '--hysteresis-width-c', '1')
    recording = load_recording(path)
    residual = recording.gyro_rad_s[:, 0] - \
        noiseless_bias_rad_s(truth, 'x', recording.temperature_c)
    slope = np.gradient(recording.temperature_c, recording.time_s)
    # Away from the turning points each branch sits at +-h/2.
    settled = (recording.temperature_c > 12.0) & (recording.temperature_c < 38.0)
    heating = residual[settled & (slope > 0.1)]
    cooling = residual[settled & (slope < -0.1)]
    assert np.mean(heating) - np.mean(cooling) == pytest.approx(math.radians(0.4),
                                                                abs=0.5 * RATE_LSB_RAD_S)


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_bag_holds_the_csv_samples_on_the_raw_topics(tmp_path, capsys, storage):
    options = ('--cycle-c', '30', '--rate-hz', '5', '--duration-s', '60', '--seed', '4')
    csv_path, _, _ = simulate(tmp_path, capsys, 'same.csv', *options)
    bag_path, truth, out = simulate(tmp_path, capsys, 'bag', '--format', storage, *options)
    assert f'wrote {bag_path} ({storage} bag' in out
    assert truth['recording']['format'] == storage and truth['recording']['samples'] == 301
    from_csv = load_recording(csv_path)
    from_bag = load_recording(bag_path, **RAW_TOPICS)
    assert from_bag.axes == ('x', 'y', 'z') and len(from_bag) == 301
    np.testing.assert_allclose(from_bag.time_s, from_csv.time_s, atol=1e-9)
    np.testing.assert_allclose(from_bag.gyro_rad_s, from_csv.gyro_rad_s, rtol=1e-11,
                               atol=1e-15)
    np.testing.assert_allclose(from_bag.temperature_c, from_csv.temperature_c, rtol=1e-11)
    # The bag was staged, under its own name: its storage file is named after it.
    assert sorted(p.name for p in bag_path.iterdir())[0].startswith('bag.')
    assert not [p for p in tmp_path.iterdir() if p.name.startswith('.')]
    with RawBagReader(bag_path) as bag:
        assert set(bag.bag_topics) == {'/imu/data_raw', '/imu/temperature_raw', '/imu/eeprom',
                                       '/imu/temperature_raw/x', '/imu/temperature_raw/y',
                                       '/imu/temperature_raw/z'}
        assert len(bag.eeprom.images) == 3


def test_supply_voltage_goes_into_the_csv_and_the_bag(tmp_path, capsys):
    options = ('--axes', 'z', '--rate-hz', '2', '--duration-s', '100', '--seed', '2',
               '--zro-supply-dps-per-v', '5', '--supply-v', '0:5.0', '100:5.5')
    csv_path, truth, _ = simulate(tmp_path, capsys, 'supply.csv', *options)
    assert truth['supply'] == {'times_s': [0.0, 100.0], 'volts': [5.0, 5.5], 'nominal_v': 5.0}
    recording = load_recording(csv_path)
    np.testing.assert_allclose(recording.supply_voltage_v, 5.0 + 0.005 * recording.time_s,
                               rtol=1e-9)
    # 5 deg/s/V over 0.5 V: the rate rises by 2.5 deg/s at a steady 25 C.
    rise = np.degrees(recording.gyro_rad_s[-20:, 0].mean() - recording.gyro_rad_s[:20, 0].mean())
    assert rise == pytest.approx(2.5 * 0.9, abs=0.2)   # the means are 10 s from the ends
    bag = tmp_path / 'supply_bag'
    assert main(['convert', str(csv_path), '--out', str(bag)]) == 0
    assert '/imu/temperature_raw, /imu/supply_voltage' in capsys.readouterr().out
    from_bag = load_recording(bag, **RAW_TOPICS)
    np.testing.assert_allclose(from_bag.supply_voltage_v, recording.supply_voltage_v,
                               rtol=1e-7)   # float32 in BatteryState
    # Without --supply-v the recording has no supply column.
    plain, _, _ = simulate(tmp_path, capsys, 'plain.csv', *options[:-3])
    assert load_recording(plain).supply_voltage_v is None


def test_turntable_csv_and_bag(tmp_path, capsys):
    path, truth, out = simulate(tmp_path, capsys, 'table.csv', '--turntable', '--cycle-c',
                                '0', '40', '--seed', '2')
    recording = load_recording(path)
    assert recording.reference_rad_s is not None and recording.temperature_2_c is not None
    assert truth['protocol']['chamber_temperatures_c'] == [0.0, 40.0]
    assert set(truth['chain_parameters']) >= {'misalignment', 'nonlinearity_rad_s.x'}
    # The reference holds plateaus up to 300 deg/s on every axis.
    assert np.max(np.abs(recording.reference_rad_s)) == pytest.approx(math.radians(300.0))
    bag_path, _, out = simulate(tmp_path, capsys, 'table_bag', '--turntable', '--cycle-c',
                                '0', '40', '--seed', '2', '--format', 'mcap')
    assert 'the reference rate has no topic' in out
    with RawBagReader(bag_path) as bag:
        assert '/imu/temperature_2_raw' in bag.bag_topics
    from_bag = load_recording(bag_path, **RAW_TOPICS)
    np.testing.assert_allclose(from_bag.gyro_rad_s, recording.gyro_rad_s, rtol=1e-9,
                               atol=1e-12)


def test_orientation_and_acceleration_sensitivity(tmp_path, capsys):
    path, truth, _ = simulate(tmp_path, capsys, 'tumble.csv', '--axes', 'y', '--noise-scale',
                              '0', '--duration-s', '120', '--rate-hz', '1',
                              '--orientation-period-s', '20', '--acceleration-dps-per-m-s2',
                              '0', '0', '0.05')
    recording = load_recording(path)
    assert recording.acceleration_m_s2 is not None
    np.testing.assert_allclose(np.linalg.norm(recording.acceleration_m_s2, axis=1), 9.80665)
    residual = recording.gyro_rad_s[:, 0] - \
        noiseless_bias_rad_s(truth, 'y', recording.temperature_c)
    expected = np.radians(0.05 * recording.acceleration_m_s2[:, 2])
    assert np.max(np.abs(residual - expected)) < 1.5 * RATE_LSB_RAD_S


def test_progress_bar_on_request(tmp_path, capsys):
    assert main(['simulate', '--out', str(tmp_path / 'p.csv'), '--duration-s', '10',
                 '--progress']) == 0
    err = capsys.readouterr().err
    assert err.endswith('] 100 %\n') and 'simulating 101 samples [' in err


def test_simulate_bad_requests_are_user_errors(tmp_path, capsys):
    code = main(['simulate', '--out', str(tmp_path / 't.csv'), '--turntable',
                 '--hysteresis-dps', '0.2'])
    assert_user_error(code, capsys, '--hysteresis-dps: effects apply to the chip simulation')
    (tmp_path / 'taken').mkdir()
    code = main(['simulate', '--out', str(tmp_path / 'taken'), '--format', 'mcap'])
    assert_user_error(code, capsys, 'exists already')
    with pytest.raises(SystemExit) as exit_info:
        main(['simulate', '--out', str(tmp_path / 's.csv'), '--bias-step', 'soon'])
    assert exit_info.value.code == 2
    assert 'expected TIME_S:VALUE' in capsys.readouterr().err
    for supply, needle in (('abc', "--supply-v: expected a positive number, got 'abc'"),
                           ('0:abc', '--supply-v: expected TIME_S:VALUE')):
        code = main(['simulate', '--out', str(tmp_path / 'v.csv'), '--supply-v', supply])
        assert_user_error(code, capsys, needle)
    assert not list(tmp_path.glob('*v.csv*'))


def test_convert_skips_and_counts_bad_rows(tmp_path, capsys):
    path = tmp_path / 'rows.csv'
    rows = ['time,temperature,gyro_z,temperature_2', '0.0,25.0,0.01,30.0',
            '0.5,25.1,nan,30.0', '1.0,25.2,0.02,inf', '1.0,25.3,0.03,30.0',
            '0.8,25.4,0.04,30.0', '1.5,25.5,0.05,30.1', '1.5,25.5,0.05,30.1',
            '2.0,25.6,0.06,30.2']
    path.write_text('\n'.join(rows) + '\n')
    bag = tmp_path / 'rows_bag'
    assert main(['convert', str(path), '--out', str(bag), '--storage', 'mcap']) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'{path}: 5 rows used; skipped: non-finite values 2, repeated rows 1; '
                          '1 row out of time order (whole blocks) sorted into place\n'
                          f'{path}: axes z, 2.0 s\n')
    assert f'wrote {bag} (mcap): 15 messages on /imu/data_raw, /imu/temperature_raw, ' \
           '/imu/temperature_2_raw' in out
    recording = load_recording(bag, **RAW_TOPICS)
    np.testing.assert_allclose(recording.time_s, [0.0, 0.8, 1.0, 1.5, 2.0])
    np.testing.assert_allclose(recording.gyro_rad_s[:, 0], [0.01, 0.04, 0.03, 0.05, 0.06])
    np.testing.assert_allclose(recording.temperature_c, [25.0, 25.4, 25.3, 25.5, 25.6])
    assert recording.acceleration_m_s2 is None


def test_convert_measured_preset(tmp_path, capsys):
    measured = MEASURED_CSV
    if not measured.is_file():
        pytest.skip(f'measured data not present: {measured}')
    bag = tmp_path / 'measured'
    assert main(['convert', str(measured), '--preset', 'tofupilot', '--out', str(bag)]) == 0
    assert '8399 rows used; skipped: dropped by preset 1\n' in capsys.readouterr().out
    original = load_recording(measured, preset='tofupilot')
    replayed = load_recording(bag, **RAW_TOPICS)
    np.testing.assert_allclose(replayed.time_s, original.time_s, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(replayed.gyro_rad_s, original.gyro_rad_s)
    np.testing.assert_array_equal(replayed.acceleration_m_s2, original.acceleration_m_s2)


def test_convert_refuses_negative_time_and_missing_columns(tmp_path, capsys):
    path = tmp_path / 'negative.csv'
    path.write_text('time,temperature,gyro_x\n-1.0,25.0,0.0\n0.0,25.0,0.0\n')
    code = main(['convert', str(path), '--out', str(tmp_path / 'b')])
    assert_user_error(code, capsys, 'time must be >= 0 s to become ROS stamps; row 0 has -1 s')
    assert not (tmp_path / 'b').exists()
    path = tmp_path / 'columns.csv'
    path.write_text('time,temp,gyro_x\n0.0,25.0,0.0\n')
    code = main(['convert', str(path), '--out', str(tmp_path / 'c')])
    assert_user_error(code, capsys, "missing columns 'temperature'")
