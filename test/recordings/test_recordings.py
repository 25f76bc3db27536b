"""Recordings for the calibration toolkit: CSV files, column maps, presets and bags."""

import dataclasses
import math
import os
from pathlib import Path
import time

from measured_data import MEASURED_CSV as TOFUPILOT_CSV
from mlx_tempcomp.recordings.bag import (ImuRecord, RawTopics, SupplyVoltageRecord,
                                         TemperatureRecord)
from mlx_tempcomp.recordings.bag_writer import RawBagWriter
from mlx_tempcomp.recordings.columns import ColumnMap, parse_column_map, PRESETS
from mlx_tempcomp.recordings.csv_reader import load_csv
from mlx_tempcomp.recordings.load import load_bag, load_recording
from mlx_tempcomp.recordings.recording import (Recording, RecordingError, SKIP_IMU_UNPAIRED,
                                               SKIP_NO_SUPPLY, SKIP_NON_FINITE, SKIP_NON_NUMERIC,
                                               SKIP_OUT_OF_RANGE, SKIP_PRESET, SKIP_REPEATED_ROW,
                                               SKIP_TEMPERATURE_UNPAIRED)
import numpy as np
import pytest

HEADER = ['time', 'temperature', 'gyro_x', 'gyro_y', 'gyro_z', 'ref_x', 'ref_y', 'ref_z',
          'acc_x', 'acc_y', 'acc_z', 'temperature_2', 'supply_voltage']
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 10_000_000


def canonical_table(rows: int = 50) -> np.ndarray:
    rng = np.random.default_rng(1)
    table = rng.normal(0.0, 0.01, (rows, len(HEADER)))
    table[:, 0] = 1000.0 + 0.1 * np.arange(rows)
    table[:, 1] = np.linspace(-40.0, 85.0, rows)
    table[:, 10] -= 9.81
    table[:, 11] = table[:, 1] + 3.0
    table[:, 12] += 5.0
    return table


def write_csv(path: Path, header, rows, delimiter: str = ',') -> Path:
    lines = [delimiter.join(header)]
    lines += [delimiter.join(repr(v) if isinstance(v, float) else str(v) for v in row)
              for row in rows]
    path.write_text('\n'.join(lines) + '\n')
    return path


def simple_csv(path: Path, rows) -> Path:
    """Write time, temperature, gyro_z rows (any cell values, written as given)."""
    return write_csv(path, ['time', 'temperature', 'gyro_z'], rows)


@pytest.mark.parametrize('delimiter', [',', '\t', ';'])
def test_canonical_csv_round_trip(tmp_path, delimiter):
    table = canonical_table()
    path = write_csv(tmp_path / 'run.csv', HEADER, table.tolist(), delimiter)
    recording = load_csv(path)
    assert recording.source == str(path)
    assert recording.axes == ('x', 'y', 'z')
    assert len(recording) == 50 and dict(recording.skipped) == {}
    np.testing.assert_array_equal(recording.time_s, table[:, 0])
    np.testing.assert_array_equal(recording.temperature_c, table[:, 1])
    np.testing.assert_array_equal(recording.gyro_rad_s, table[:, 2:5])
    np.testing.assert_array_equal(recording.reference_rad_s, table[:, 5:8])
    np.testing.assert_array_equal(recording.acceleration_m_s2, table[:, 8:11])
    np.testing.assert_array_equal(recording.temperature_2_c, table[:, 11])
    np.testing.assert_array_equal(recording.supply_voltage_v, table[:, 12])
    assert recording.gyro_rad_s.dtype == np.float64
    assert recording.duration_s == pytest.approx(4.9)
    with pytest.raises(ValueError):
        recording.gyro_rad_s[0, 0] = 1.0  # read-only


def test_single_axis_csv_without_optional_columns(tmp_path):
    path = simple_csv(tmp_path / 'z.csv', [[0.0, 20.0, 0.01], [0.5, 20.5, 0.02]])
    recording = load_recording(path)
    assert recording.axes == ('z',)
    assert recording.gyro_rad_s.shape == (2, 1)
    assert recording.reference_rad_s is None
    assert recording.acceleration_m_s2 is None
    assert recording.temperature_2_c is None
    assert recording.supply_voltage_v is None


def test_blank_lines_bom_and_crlf_are_tolerated(tmp_path):
    path = tmp_path / 'win.csv'
    path.write_bytes(b'\xef\xbb\xbf\r\ntime,temperature,gyro_x\r\n0,25,0.1\r\n\r\n1,26,0.2\r\n')
    recording = load_csv(path)
    np.testing.assert_array_equal(recording.temperature_c, [25.0, 26.0])
    assert dict(recording.skipped) == {}


def test_column_map_spec():
    columns = parse_column_map(
        'time=timestamp:1e-6, temperature=imu.temperature,gyro_x=imu.gyro.x,'
        'acc_x=ax,acc_y=ay,acc_z=az,ref_x=,temperature_2=,delimiter=tab,skip_rows=2')
    assert columns.time == 'timestamp' and columns.time_scale == 1e-6
    assert columns.temperature == 'imu.temperature'
    assert dict(columns.gyro) == {'x': 'imu.gyro.x', 'y': 'gyro_y', 'z': 'gyro_z'}
    assert dict(columns.reference) == {'y': 'ref_y', 'z': 'ref_z'}
    assert dict(columns.acceleration) == {'x': 'ax', 'y': 'ay', 'z': 'az'}
    assert columns.temperature_2 is None
    assert columns.delimiter == '\t' and columns.skip_rows == 2
    assert columns.required == {'time', 'temperature', 'gyro_x', 'acc_x', 'acc_y', 'acc_z'}
    assert parse_column_map('delimiter=;').delimiter == ';'
    assert parse_column_map('gyro_z=gz').sources()['gyro_z'] == 'gz'


@pytest.mark.parametrize('spec, words', [
    ('', 'empty'),
    ('time', 'not canonical=source'),
    ('=x', 'not canonical=source'),
    ('gyro_w=gw', "unknown column 'gyro_w'"),
    ('time=t,time=u', 'names time twice'),
    ('time=t:fast', 'time scale'),
    ('time=t:-1', 'time scale'),
    ('temperature=', 'needs a column name'),
    ('gyro_x=,gyro_y=,gyro_z=', 'no gyro column'),
    ('skip_rows=-1', 'skip_rows'),
    ('delimiter=ab', 'delimiter'),
])
def test_bad_column_map_spec(spec, words):
    with pytest.raises(RecordingError, match=words):
        parse_column_map(spec)


def test_column_named_in_spec_must_exist(tmp_path):
    path = simple_csv(tmp_path / 'z.csv', [[0.0, 20.0, 0.01]])
    assert load_recording(path, columns='gyro_x=gyro_z').axes == ('x',)
    with pytest.raises(RecordingError, match="missing columns 'temperature_2'"):
        load_recording(path, columns='temperature_2=temperature_2')


@pytest.mark.skipif(not TOFUPILOT_CSV.is_file(), reason='shared measured data set absent')
def test_tofupilot_preset_reads_the_measured_sweep():
    start = time.perf_counter()
    recording = load_recording(TOFUPILOT_CSV, preset='tofupilot')
    assert time.perf_counter() - start < 1.0
    assert len(recording) == 8399
    assert dict(recording.skipped) == {SKIP_PRESET: 1}
    assert recording.axes == ('x', 'y', 'z')
    assert recording.acceleration_m_s2.shape == (8399, 3)
    assert recording.acceleration_m_s2[:, 2].mean() == pytest.approx(-9.5, abs=0.3)
    assert recording.reference_rad_s is None and recording.temperature_2_c is None
    assert recording.duration_s / 60.0 == pytest.approx(70.7, abs=0.1)
    assert np.median(np.diff(recording.time_s)) == pytest.approx(0.505403, abs=1e-3)
    assert recording.temperature_c.min() == pytest.approx(-17.6, abs=0.05)
    assert recording.temperature_c.max() == pytest.approx(74.0, abs=0.05)
    peak_to_peak_deg_s = np.degrees(np.ptp(recording.gyro_rad_s, axis=0))
    np.testing.assert_allclose(peak_to_peak_deg_s[1:], [3.13, 0.65], atol=0.01)


def test_unknown_preset_lists_the_known_ones(tmp_path):
    path = simple_csv(tmp_path / 'z.csv', [[0.0, 20.0, 0.01]])
    with pytest.raises(RecordingError, match="unknown column preset 'tofu'.*tofupilot"):
        load_recording(path, preset='tofu')
    with pytest.raises(RecordingError, match='not both'):
        load_recording(path, preset='tofupilot', columns=ColumnMap())


def test_missing_columns_name_a_preset_that_fits(tmp_path):
    header = ['timestamp', *(f'imu.gyro.{a}' for a in 'xyz'), *(f'imu.acc.{a}' for a in 'xyz'),
              'imu.status', 'imu.temperature']
    path = write_csv(tmp_path / 'tofu.tsv', header, [[1, 0, 0, 0, 0, 0, -9.8, 0, 20]], '\t')
    with pytest.raises(RecordingError, match="missing columns 'time'.*preset 'tofupilot'"):
        load_recording(path)
    spec = 'time=timestamp:1e-6,temperature=imu.temperature,gyro_x=imu.gyro.x'
    assert load_recording(path, columns=spec).axes == ('x',)


def test_preset_requires_its_columns(tmp_path):
    path = write_csv(tmp_path / 'p.tsv', ['timestamp', 'imu.temperature', 'imu.gyro.z'],
                     [[0, 20.0, 0.01]], '\t')
    with pytest.raises(RecordingError, match="missing columns 'imu.gyro.x'.*the file has"):
        load_csv(path, PRESETS['tofupilot'])


def test_missing_columns_are_listed_with_the_file_columns(tmp_path):
    path = write_csv(tmp_path / 'm.csv', ['t', 'gyro_x'], [[0.0, 0.1]])
    with pytest.raises(RecordingError) as caught:
        load_csv(path)
    message = str(caught.value)
    assert str(path) in message
    assert "missing columns 'time', 'temperature'" in message
    assert "the file has 't', 'gyro_x'" in message
    path = write_csv(tmp_path / 'g.csv', ['time', 'temperature'], [[0.0, 20.0]])
    with pytest.raises(RecordingError, match="one of 'gyro_x', 'gyro_y', 'gyro_z'"):
        load_csv(path)


def test_non_finite_and_non_numeric_rows_are_skipped_and_counted(tmp_path):
    rows = [[0, 20, 0.1], [1, 'nan', 0.1], [2, 21, 'inf'], [3, 21, '-Infinity'],
            [4, 'n/a', 0.1], [5, 22, ''], [6, 22], [7, 23, 0.2]]
    recording = load_csv(simple_csv(tmp_path / 'bad.csv', rows))
    np.testing.assert_array_equal(recording.time_s, [0.0, 7.0])
    assert dict(recording.skipped) == {SKIP_NON_NUMERIC: 3, SKIP_NON_FINITE: 3}


def test_implausible_values_are_skipped_and_counted(tmp_path):
    rows = [[0, 20, 0.1], [1, -999, 0.1], [2, 21, 1e308], [3, 21, -2e3], [1.7e18, 22, 0.1],
            [5, 250, 0.1], [6, 22, 0.2]]
    recording = load_csv(simple_csv(tmp_path / 'glitches.csv', rows))
    np.testing.assert_array_equal(recording.time_s, [0.0, 6.0])
    assert dict(recording.skipped) == {SKIP_OUT_OF_RANGE: 5}


def test_repeated_rows_are_dropped_and_counted(tmp_path):
    rows = [[0, 20, 0.1], [1, 21, 0.2], [1, 21, 0.2], [2, 22, 0.3], ['nan', 99, 9.9],
            [0, 20, 0.1], [3, 23, 0.4], [1, 21, 0.2]]
    recording = load_csv(simple_csv(tmp_path / 'time.csv', rows))
    np.testing.assert_array_equal(recording.time_s, [0.0, 1.0, 2.0, 3.0])
    np.testing.assert_array_equal(recording.temperature_c, [20.0, 21.0, 22.0, 23.0])
    assert dict(recording.skipped) == {SKIP_NON_FINITE: 1, SKIP_REPEATED_ROW: 3}
    assert recording.sorted_rows == 0


def test_a_time_shared_by_other_values_is_refused_naming_both_lines(tmp_path):
    rows = [[0, 20, 0.1], [1, 21, 0.2], [2, 22, 0.3], [1, 99, 9.9], [3, 23, 0.4]]
    path = simple_csv(tmp_path / 'clash.csv', rows)
    with pytest.raises(RecordingError, match=r'clash\.csv: line 5 has time 1\.0 s like line 3 '
                                             r'but other values'):
        load_csv(path)


def spliced(table: np.ndarray, start: int, stop: int, to: int) -> np.ndarray:
    """Move rows start..stop-1 so that they follow row ``to`` of the rest."""
    block, rest = table[start:stop], np.delete(table, np.s_[start:stop], axis=0)
    return np.concatenate([rest[:to], block, rest[to:]])


# sorted: the rows read behind the latest time so far (the moved block, or what it skipped).
@pytest.mark.parametrize('start, stop, to, sorted_rows', [(100, 300, 600, 200),
                                                          (700, 800, 0, 700),
                                                          (0, 500, 500, 500)])
def test_blocks_out_of_time_order_are_sorted_and_counted(tmp_path, start, stop, to,
                                                         sorted_rows):
    table = canonical_table(1000)
    path = write_csv(tmp_path / 'spliced.csv', HEADER, spliced(table, start, stop, to).tolist())
    recording = load_csv(path)
    np.testing.assert_array_equal(recording.time_s, table[:, 0])
    np.testing.assert_array_equal(recording.gyro_rad_s, table[:, 2:5])
    np.testing.assert_array_equal(recording.supply_voltage_v, table[:, 12])
    assert dict(recording.skipped) == {}
    assert recording.sorted_rows == sorted_rows


def test_several_moved_blocks_are_sorted(tmp_path):
    table = canonical_table(2000)
    # Rows 100..199 go forward, behind 800 later rows; rows 1500..1599 go back before 1000.
    moved = spliced(spliced(table, 100, 200, 900), 1500, 1600, 1000)
    recording = load_csv(write_csv(tmp_path / 'two.csv', HEADER, moved.tolist()))
    np.testing.assert_array_equal(recording.time_s, table[:, 0])
    assert recording.sorted_rows == 100 + 500


def test_a_clock_reset_is_refused_at_the_first_backward_line(tmp_path):
    table = canonical_table(1000)
    table[500:, 0] -= 30.05          # the second half restarts 30 s back, between earlier rows
    path = write_csv(tmp_path / 'reset.csv', HEADER, table.tolist())
    with pytest.raises(RecordingError) as raised:
        load_csv(path)
    message = str(raised.value)
    after, before = float(table[500, 0]), float(table[499, 0])
    assert message.startswith(f'{path}: time goes back at line 502 ({after!r} s after '
                              f'{before!r} s at line 501) and later rows fall between earlier '
                              'ones')
    assert 'a clock reset or two recordings joined?' in message


def test_time_scale_and_skip_rows(tmp_path):
    path = write_csv(tmp_path / 'us.csv', ['t_us', 'temperature', 'gyro_y'],
                     [[5_000_000, 20, 9.9], [6_000_000, 20, 0.1], [6_500_000, 21, 0.2]])
    recording = load_csv(path, parse_column_map('time=t_us:1e-6,skip_rows=1'))
    np.testing.assert_allclose(recording.time_s, [6.0, 6.5])
    assert recording.axes == ('y',)
    assert dict(recording.skipped) == {SKIP_PRESET: 1}


def test_every_column_takes_a_scale(tmp_path):
    # A logger in deg/s, centi-degrees, g and mV: each column scaled to its canonical unit.
    path = write_csv(tmp_path / 'units.csv',
                     ['t_ms', 'temp_cc', 'gx_dps', 'gz_dps', 'ax_g', 'ay_g', 'az_g', 'mv'],
                     [[0, 2500, 1.0, -90.0, 0.0, 0.0, 1.0, 5000],
                      [10, 2510, 2.0, 180.0, 0.5, 0.0, -1.0, 4900]])
    columns = parse_column_map(
        'time=t_ms:1e-3,temperature=temp_cc:0.01,gyro_x=gx_dps:0.0174533,'
        'gyro_z=gz_dps:-0.0174533,acc_x=ax_g:9.80665,acc_y=ay_g:9.80665,acc_z=az_g:9.80665,'
        'supply_voltage=mv:0.001')
    assert dict(columns.scales) == {'time': 1e-3, 'temperature': 0.01, 'gyro_x': 0.0174533,
                                    'gyro_z': -0.0174533, 'acc_x': 9.80665,
                                    'acc_y': 9.80665, 'acc_z': 9.80665,
                                    'supply_voltage': 0.001}
    recording = load_csv(path, columns)
    np.testing.assert_allclose(recording.time_s, [0.0, 0.01])
    np.testing.assert_allclose(recording.temperature_c, [25.0, 25.1])
    np.testing.assert_allclose(recording.gyro_rad_s, [[0.0174533, 1.5707970],
                                                      [0.0349066, -3.1415940]])
    np.testing.assert_allclose(recording.acceleration_m_s2[:, 2], [9.80665, -9.80665])
    np.testing.assert_allclose(recording.supply_voltage_v, [5.0, 4.9])
    # A column without a scale is read as it is: 2500 C is no temperature.
    with pytest.raises(RecordingError, match='values out of range 2'):
        load_csv(path, parse_column_map('time=t_ms,temperature=temp_cc,gyro_x=gx_dps'))
    plain = load_csv(path, parse_column_map('time=t_ms,temperature=temp_cc:0.01,gyro_x=gx_dps'))
    np.testing.assert_array_equal(plain.gyro_rad_s[:, 0], [1.0, 2.0])


@pytest.mark.parametrize('spec, words', [
    ('gyro_z=gz:0', 'the gyro_z scale after ":" must be a non-zero number '
                    r'\(rad/s per unit, e.g. 0.0174533 for deg/s\)'),
    ('temperature=t:x', 'the temperature scale after ":" must be a non-zero number '
                        r'\(degC per unit\)'),
    ('acc_x=:9.8', 'acc_x needs a column name before ":"'),
])
def test_bad_column_scale(spec, words):
    with pytest.raises(RecordingError, match=words):
        parse_column_map(spec)


@pytest.mark.parametrize('content, words', [
    (b'', 'is empty'),
    (b'\n\n', 'is empty'),
    (b'time,temperature,gyro_x\n', 'header but no data rows'),
    (b'time,temperature,gyro_x\nnan,1,2\n1,inf,2\n',
     r'no usable row; all 2 rows skipped \(non-finite values 2\)'),
    (b'time,temperature,gyro_x\na,b,c\nd,e,f\n', 'no row has numbers'),
    (b'time temperature gyro_x\n1 2 3\n', 'missing columns'),
    (b'time;temperature;gyro_x\n1,2,3\n', 'is the delimiter right'),
    (b'\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe', 'not a text CSV file'),
    (b'time,temperature,gyro_x\n1,2,' + b'7' * 200_000 + b'\n', 'not a readable CSV file'),
    (b'time\x00,temperature,gyro_x\n1,2,3\n', 'NUL bytes'),
    (b'time,temperature,gyro_x,gyro_x\n1,2,3,4\n', "'gyro_x' appears 2 times"),
    (b'time,temperature,gyro_x,gyro_y,ref_x\n1,2,3,4,5\n', "not 'ref_y'"),
    (b'time,temperature,gyro_x,acc_z\n1,2,3,4\n', "has only 'acc_z'"),
])
def test_bad_csv_gives_a_clear_error(tmp_path, content, words):
    path = tmp_path / 'bad.csv'
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=words) as caught:
        load_recording(path)
    assert str(path) in str(caught.value)


def test_all_rows_dropped_by_the_preset(tmp_path):
    path = simple_csv(tmp_path / 'one.csv', [[0.0, 20.0, 0.1]])
    with pytest.raises(RecordingError, match='dropped by preset 1'):
        load_csv(path, ColumnMap(skip_rows=1))


def test_unreadable_csv_paths(tmp_path):
    with pytest.raises(RecordingError, match='cannot read .*absent.csv'):
        load_recording(tmp_path / 'absent.csv')
    if os.geteuid() != 0:  # root reads anything
        path = simple_csv(tmp_path / 'locked.csv', [[0.0, 20.0, 0.1]])
        path.chmod(0)
        with pytest.raises(RecordingError, match='cannot read .*locked.csv'):
            load_recording(path)


def test_slice_selects_rows(tmp_path):
    table = canonical_table(10)
    recording = load_csv(write_csv(tmp_path / 'run.csv', HEADER, table.tolist()))
    train = recording.slice(recording.time_s < 1000.45)
    test = recording.slice(slice(5, None))
    assert len(train) == 5 and len(test) == 5
    np.testing.assert_array_equal(test.gyro_rad_s, table[5:, 2:5])
    np.testing.assert_array_equal(train.acceleration_m_s2, table[:5, 8:11])
    picked = recording.slice([1, 4, 7])
    np.testing.assert_array_equal(picked.temperature_2_c, table[[1, 4, 7], 11])
    np.testing.assert_array_equal(picked.supply_voltage_v, table[[1, 4, 7], 12])
    assert picked.axes == recording.axes and picked.source == recording.source
    assert len(recording.slice(3)) == 1
    with pytest.raises(RecordingError, match='at least one row|one or more rows'):
        recording.slice(np.zeros(10, dtype=bool))
    with pytest.raises(RecordingError, match='strictly increasing'):
        recording.slice([4, 1])
    with pytest.raises(RecordingError, match='cannot select rows'):
        recording.slice(np.ones(3, dtype=bool))


def test_recording_checks_its_arrays():
    with pytest.raises(RecordingError, match=r'gyro_rad_s must have shape \(2, 1\)'):
        Recording('mem', [0.0, 1.0], [20.0, 21.0], ('z',), [[0.1, 0.2], [0.1, 0.2]])
    with pytest.raises(RecordingError, match='axes must be some of x, y, z'):
        Recording('mem', [0.0, 1.0], [20.0, 21.0], ('z', 'x'), [[0.1, 0.2], [0.1, 0.2]])
    with pytest.raises(RecordingError, match='temperature_c holds NaN'):
        Recording('mem', [0.0, 1.0], [20.0, math.nan], ('z',), [[0.1], [0.2]])


def imu_record(i: int, acceleration: bool = False) -> ImuRecord:
    rate = [math.nan, math.nan, 0.01 * i]  # a z-only gyro: x and y unmeasured
    acceleration_covariance = np.zeros(9) if acceleration else np.r_[-1.0, np.zeros(8)]
    return ImuRecord(stamp_ns=T0_NS + i * PERIOD_NS, frame_id='mlx_gyro',
                     angular_velocity_rad_s=rate, angular_velocity_covariance=np.zeros(9),
                     linear_acceleration_m_s2=[0.1, 0.2, -9.8 + 0.001 * i],
                     linear_acceleration_covariance=acceleration_covariance,
                     orientation_covariance=np.r_[-1.0, np.zeros(8)])


def temperature_record(stamp_ns: int, temperature_c: float) -> TemperatureRecord:
    return TemperatureRecord(stamp_ns=stamp_ns, frame_id='mlx_gyro',
                             temperature_c=temperature_c, variance=0.0)


def write_bag(path: Path, storage: str = 'sqlite3', acceleration: bool = False,
              temperatures: bool = True) -> Path:
    """IMU 0..19; temperature for 2..19, plus one at a stamp no IMU message has."""
    topics = RawTopics(imu='/imu/data', temperature='/imu/temperature')
    with RawBagWriter(path, storage, topics) as bag:
        for i in range(20):
            stamp_ns = T0_NS + i * PERIOD_NS
            bag.write_imu(stamp_ns + 1000, imu_record(i, acceleration))
            if temperatures and i >= 2:
                bag.write_temperature(stamp_ns + 2000, temperature_record(stamp_ns, 30.0 + i))
        if temperatures:
            bag.write_temperature(T0_NS + 99 * PERIOD_NS,
                                  temperature_record(T0_NS + 5 * PERIOD_NS + 1, 0.0))
    return path


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_bag_pairs_imu_and_temperature_by_stamp(tmp_path, storage):
    path = write_bag(tmp_path / 'bag', storage)
    recording = load_recording(path)
    assert recording.source == str(path)
    assert recording.axes == ('z',)
    assert len(recording) == 18
    assert dict(recording.skipped) == {SKIP_IMU_UNPAIRED: 2, SKIP_TEMPERATURE_UNPAIRED: 1}
    np.testing.assert_allclose(recording.time_s - 1.7e9, 0.01 * np.arange(2, 20), atol=1e-6)
    np.testing.assert_allclose(recording.duration_s, 0.17, atol=1e-6)
    np.testing.assert_array_equal(recording.temperature_c, 30.0 + np.arange(2, 20))
    np.testing.assert_allclose(recording.gyro_rad_s[:, 0], 0.01 * np.arange(2, 20))
    assert recording.acceleration_m_s2 is None  # flagged unreported (covariance[0] = -1)


def test_bag_with_acceleration_and_other_topic_names(tmp_path):
    topics = RawTopics(imu='sensor/imu', temperature='sensor/die_temperature')
    with RawBagWriter(tmp_path / 'bag', 'mcap', topics) as bag:
        for i in range(5):
            bag.write_imu(T0_NS + i, imu_record(i, acceleration=True))
            bag.write_temperature(T0_NS + i, temperature_record(T0_NS + i * PERIOD_NS, 25.0))
    recording = load_bag(tmp_path / 'bag', imu_topic='sensor/imu',
                         temperature_topic='/sensor/die_temperature')
    assert len(recording) == 5 and dict(recording.skipped) == {}
    np.testing.assert_allclose(recording.acceleration_m_s2[:, 2], -9.8 + 0.001 * np.arange(5))


def test_bag_supply_voltage_on_its_own_stamps_is_held_per_sample(tmp_path):
    """A battery monitor at 0.5 Hz, silent after 4 s: held, then 5 s later samples skipped."""
    period_ns = 100_000_000
    topics = RawTopics(imu='/imu/data', temperature='/imu/temperature',
                       supply_voltage='/battery')
    with RawBagWriter(tmp_path / 'bag', 'mcap', topics) as bag:
        for k in range(3):
            stamp_ns = T0_NS + k * 2_000_000_000 + 50_000_000
            bag.write_supply_voltage(stamp_ns, SupplyVoltageRecord(stamp_ns, 'battery',
                                                                   5.0 + k / 8))
        for i in range(100):
            stamp_ns = T0_NS + i * period_ns
            bag.write_imu(stamp_ns, dataclasses.replace(imu_record(i), stamp_ns=stamp_ns))
            bag.write_temperature(stamp_ns, temperature_record(stamp_ns, 25.0))
    recording = load_bag(tmp_path / 'bag', supply_voltage_topic='battery')
    # Held until 4.05 s + 5 s = 9.05 s: samples 0..90 kept, 91..99 skipped.
    assert len(recording) == 91 and dict(recording.skipped) == {SKIP_NO_SUPPLY: 9}
    i = np.arange(91)
    expected = np.select([i < 21, i < 41], [5.0, 5.125], 5.25)   # sample 0 takes the first
    np.testing.assert_array_equal(recording.supply_voltage_v, expected)
    # Without the topic in the bag there is no supply column, and nothing is skipped for it.
    assert load_bag(tmp_path / 'bag').supply_voltage_v is None


def write_stamped_bag(path: Path, stamps_ns) -> Path:
    """One IMU and one temperature message per stamp, in the order given (bag time rising)."""
    topics = RawTopics(imu='/imu/data', temperature='/imu/temperature')
    with RawBagWriter(path, 'mcap', topics) as bag:
        for k, stamp_ns in enumerate(stamps_ns):
            i = (stamp_ns - T0_NS) // PERIOD_NS
            bag.write_temperature(T0_NS + k, temperature_record(stamp_ns, 25.0 + i))
            bag.write_imu(T0_NS + k, dataclasses.replace(imu_record(i), stamp_ns=stamp_ns))
    return path


def test_bag_block_out_of_stamp_order_is_sorted(tmp_path):
    order = list(range(0, 20)) + list(range(40, 60)) + list(range(20, 40)) + [60]
    path = write_stamped_bag(tmp_path / 'bag', [T0_NS + i * PERIOD_NS for i in order])
    recording = load_bag(path)
    np.testing.assert_array_equal(recording.temperature_c, 25.0 + np.arange(61))
    np.testing.assert_allclose(recording.gyro_rad_s[:, 0], 0.01 * np.arange(61))
    assert recording.sorted_rows == 20 and dict(recording.skipped) == {}


def test_bag_clock_reset_is_refused_naming_the_message(tmp_path):
    stamps = [T0_NS + i * PERIOD_NS for i in range(30)]
    stamps += [T0_NS + i * PERIOD_NS + PERIOD_NS // 2 for i in range(30)]
    path = write_stamped_bag(tmp_path / 'bag', stamps)
    with pytest.raises(RecordingError, match='time goes back at /imu/data message 31 '):
        load_bag(path)


def test_bad_bags_give_a_clear_error(tmp_path):
    with pytest.raises(RecordingError, match='does not exist'):
        load_recording(tmp_path / 'absent.db3')
    (tmp_path / 'not_a_bag').mkdir()
    with pytest.raises(RecordingError, match='not a rosbag2 folder'):
        load_recording(tmp_path / 'not_a_bag')
    RawBagWriter(tmp_path / 'empty').close()
    with pytest.raises(RecordingError, match='no IMU topic /imu/data.*no topics'):
        load_recording(tmp_path / 'empty')
    write_bag(tmp_path / 'no_temperature', temperatures=False)
    with pytest.raises(RecordingError, match='no message on temperature topic'):
        load_recording(tmp_path / 'no_temperature')
    with pytest.raises(RecordingError, match='applies to CSV files only'):
        load_recording(tmp_path / 'no_temperature', preset='tofupilot')
    garbage = tmp_path / 'garbage.mcap'
    garbage.write_bytes(b'\x00\x01not an mcap file' * 10)
    with pytest.raises(RecordingError, match='garbage.mcap'):
        load_recording(garbage)


def test_bag_where_nothing_pairs(tmp_path):
    topics = RawTopics(imu='/imu/data', temperature='/imu/temperature')
    with RawBagWriter(tmp_path / 'bag', 'sqlite3', topics) as bag:
        for i in range(3):
            bag.write_imu(T0_NS + i * PERIOD_NS, imu_record(i))
            bag.write_temperature(T0_NS + i * PERIOD_NS,
                                  temperature_record(T0_NS + i * PERIOD_NS + 1, 25.0))
    with pytest.raises(RecordingError, match=r'no message on /imu/data has a temperature.*'
                                             r'\(3 IMU and 3 temperature messages\)'):
        load_bag(tmp_path / 'bag')
