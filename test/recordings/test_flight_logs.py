"""
The flight-controller log readers and ``mlx-tempcomp inspect`` on the four real logs.

Figures are those of data/flight_logs/README.md (measured there with pyulog 1.3.0 and
pymavlink 2.4.50). Truncated copies of each log, cut at 10 seeded random offsets, give a
one-line ``error:`` or a counted partial read, never a traceback.
"""

import json
import struct
import tracemalloc

from cli_checks import assert_user_error
from measured_data import FLIGHT_LOGS
from mlx_tempcomp.cli import main
from mlx_tempcomp.recordings.flightlog import (FlightLogError, is_flight_log, read_flight_log,
                                               SKIP_MOVING)
from mlx_tempcomp.recordings.load import load_flight_log, load_recording
from mlx_tempcomp.recordings.recording import RecordingError
import numpy as np
import pytest

PYULOG = 'px4_pyulog_sample_log_small.ulg'
ROBOLOGS = 'px4_robologs_test.ulg'
ARDUSUB = 'ardupilot_ardusub_small.BIN'
PYMAVLINK = 'ardupilot_pymavlink_test.BIN'
LOGS = (PYULOG, ROBOLOGS, ARDUSUB, PYMAVLINK)
# Per log: (instance, samples, device id, temperature min, max) as the README gives them.
INSTANCES = {
    PYULOG: [(0, 6, 2424842, 40.03, 40.36), (1, 6, 3670050, 28.25, 28.37),
             (2, 6, 2621474, 29.43, 29.72)],
    ROBOLOGS: [(0, 10, 3932170, 39.20, 39.59), (1, 10, 4325386, None, None)],
    ARDUSUB: [(0, 594, 3080714, 51.05, 51.19)],
    PYMAVLINK: [(0, 45, 2164234, 44.42, 44.46), (1, 45, 2360330, 39.92, 39.95)],
}
TRUNCATIONS = 10


def _log(name):
    path = FLIGHT_LOGS / name
    if not path.is_file():
        pytest.skip(f'flight log not present: {path} (set MLX_TEMPCOMP_SHARED)')
    return path


def test_each_reader_registered_its_suffix_with_the_dispatcher(tmp_path):
    """The ulog and dataflash readers register .ulg and .bin; any other name is no log."""
    assert [is_flight_log(name) for name in ('a.ulg', 'b.BIN', 'c.bin', 'd.csv', 'e.db3')] == \
        [True, True, True, False, False]
    notes = tmp_path / 'notes.txt'
    notes.write_text('x\n')
    with pytest.raises(FlightLogError, match=r'notes.txt is not a flight-controller log: its '
                                             r'name ends in none of \.(bin, \.ulg|ulg, \.bin)$'):
        read_flight_log(notes)


@pytest.mark.parametrize('name', LOGS)
def test_reader_gives_the_readme_instances_counts_and_temperatures(name):
    log = read_flight_log(_log(name))
    found = [(i.index, len(i), i.device_id) for i in log.instances]
    assert found == [(index, samples, device) for index, samples, device, _, _
                     in INSTANCES[name]]
    for instance, (_, _, _, low_c, high_c) in zip(log.instances, INSTANCES[name]):
        temperature_c = instance.temperature_c
        if low_c is None:
            assert np.isnan(temperature_c).all()
            continue
        assert round(float(temperature_c.min()), 2) == low_c
        assert round(float(temperature_c.max()), 2) == high_c
        assert np.all(np.diff(instance.time_s) > 0)
        assert instance.gyro_rad_s.shape == (len(instance), 3)
        assert instance.acceleration_m_s2.shape == (len(instance), 3)


def test_accelerometers_keep_their_own_device_ids():
    # robologs: IMU 1's accelerometer is another chip than its gyro (README).
    ids = [(i.device_id, i.accel_device_id) for i in read_flight_log(_log(ROBOLOGS)).instances]
    assert ids == [(3932170, 3932170), (4325386, 4259850)]
    # pymavlink test log: INS_ACC_ID and INS_ACC2_ID beside INS_GYR_ID and INS_GYR2_ID.
    log = read_flight_log(_log(PYMAVLINK))
    assert [i.accel_device_id for i in log.instances] == [
        int(log.parameters['INS_ACC_ID']), int(log.parameters['INS_ACC2_ID'])]


def test_durations_come_from_the_stamps_not_the_header():
    # The header spans 1174 s (one late mission sample); the IMU data 21.3 to 26.3 s.
    for instance in read_flight_log(_log(PYULOG)).instances:
        assert 4.9 < instance.time_s[-1] - instance.time_s[0] < 5.1
        assert 21.3 < instance.time_s[0] < 21.4
    (ardusub,) = read_flight_log(_log(ARDUSUB)).instances
    assert round(float(ardusub.time_s[0]), 2) == 265.68
    assert round(float(ardusub.time_s[-1]), 2) == 289.40
    assert 1.0 / np.median(np.diff(ardusub.time_s)) == pytest.approx(25.0, rel=1e-3)


def test_dataflash_units_are_read_from_the_log_or_said_to_be_assumed():
    modern = read_flight_log(_log(ARDUSUB))
    assert 'units as the log declares them (FMTU)' in modern.notes
    mean = modern.instances[0].gyro_rad_s.mean(axis=0)
    assert np.round(mean, 4).tolist() == [-0.0078, -0.0062, 0.0017]   # rad/s, README
    acceleration = modern.instances[0].acceleration_m_s2.mean(axis=0)
    assert np.round(acceleration, 3).tolist() == [0.157, -0.249, -9.791]
    old = read_flight_log(_log(PYMAVLINK))
    assert any(note.startswith('no FMTU units in the log') for note in old.notes)
    assert [i.name for i in old.instances] == ['IMU', 'IMU2']


def test_a_nan_temperature_is_refused_naming_the_instance():
    with pytest.raises(RecordingError, match=r'IMU instance 1 \(sensor_gyro\[1\], device id '
                                             r'4325386\): temperature is NaN in all 10'):
        load_flight_log(_log(ROBOLOGS), 1)


def test_the_default_instance_is_the_first_usable_and_the_flight_is_skipped():
    recording, log, used = load_flight_log(_log(ROBOLOGS))
    assert used.index == 0
    # Flying between 5.0 and 9.2 s (take-offs and landings): only the still ends are kept.
    moving = int(used.moving.sum())
    assert recording.skipped[SKIP_MOVING] == moving
    assert len(recording) == 10 - moving
    assert 0 < len(recording) <= 4
    assert np.all((recording.time_s < 5.0) | (recording.time_s > 9.2))
    # The armed log that barely hops keeps every sample.
    assert len(load_recording(_log(PYULOG))) == 6


def test_only_the_imu_topics_are_held_in_memory():
    # Peak Python allocations: about 540 KiB against 1616 KiB for pyulog reading every topic.
    from pyulog import ULog
    path = _log(PYULOG)
    read_flight_log(path)   # imports done before measuring
    tracemalloc.start()
    read_flight_log(path)
    filtered = tracemalloc.get_traced_memory()[1]
    tracemalloc.reset_peak()
    ULog(str(path))
    whole = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert filtered < whole / 2, (filtered, whole)


def _inspect(capsys, *argv):
    code = main(['inspect', *map(str, argv), '--json'])
    captured = capsys.readouterr()
    return code, captured


@pytest.mark.parametrize('name', LOGS)
def test_inspect_reports_each_instance_as_the_readme_gives_it(capsys, name):
    code, captured = _inspect(capsys, _log(name))
    assert code == 0, captured.err
    report = json.loads(captured.out)
    got = [(i['instance'], i['samples'], i['device_id'],
            None if i['temperature_min_c'] is None else round(i['temperature_min_c'], 2),
            None if i['temperature_max_c'] is None else round(i['temperature_max_c'], 2))
           for i in report['instances']]
    assert got == INSTANCES[name]
    for item in report['instances']:
        # None of the logs is a thermal sweep: none can feed a fit.
        assert item['feeds']['fit'] is not None
        assert item['kept_samples'] <= item['samples'] - item['moving_samples']
        assert item['usable'] == (item['kept_samples'] > 0)


def test_inspect_names_the_unusable_instance_and_the_flight(capsys):
    code, captured = _inspect(capsys, _log(ROBOLOGS))
    assert code == 0
    report = json.loads(captured.out)
    first, second = report['instances']
    assert first['usable'] and first['moving_samples'] >= 6
    assert not second['usable'] and 'NaN in all 10 samples' in second['problem']
    assert report['thermal_parameters'] == {'TC_G_ENABLE': 0}
    code = main(['inspect', str(_log(ROBOLOGS))])
    text = capsys.readouterr().out
    assert 'instance 1 (sensor_gyro[1], device id 4325386):' in text
    assert 'temperature NaN in every sample' in text


def test_inspect_of_the_measured_csv_can_feed_a_fit(capsys):
    from measured_data import MEASURED_CSV
    if not MEASURED_CSV.is_file():
        pytest.skip(f'measured data not present: {MEASURED_CSV}')
    code, captured = _inspect(capsys, MEASURED_CSV, '--preset', 'tofupilot')
    assert code == 0
    (item,) = json.loads(captured.out)['instances']
    assert item['samples'] == 8399 and item['moving_samples'] == 0
    assert all(why is None for why in item['feeds'].values())
    assert round(item['temperature_min_c'], 2) == -17.60
    assert round(item['temperature_max_c'], 2) == 73.97


def test_commands_refuse_an_unusable_or_absent_instance_in_one_line(capsys, tmp_path):
    out = tmp_path / 'p.yaml'
    code = main(['fit', str(_log(ROBOLOGS)), '--instance', '1', '--out', str(out)])
    assert_user_error(code, capsys, 'IMU instance 1', 'device id 4325386', 'NaN')
    code = main(['fit', str(_log(ARDUSUB)), '--instance', '2', '--out', str(out)])
    assert_user_error(code, capsys, 'no IMU instance 2', 'instances 0')
    code = main(['fit', str(_log(ARDUSUB)), '--preset', 'tofupilot', '--out', str(out)])
    assert_user_error(code, capsys, 'flight-controller log')
    csv = tmp_path / 'rest.csv'
    csv.write_text('time,temperature,gyro_z\n0,20,0.01\n1,30,0.02\n', encoding='utf-8')
    for instance in ('0', 'all'):
        code = main(['fit', str(csv), '--instance', instance, '--out', str(out)])
        assert_user_error(code, capsys, '--instance applies to .ulg and .bin logs')
    assert not out.exists()


PARAMS = """compensation_node:
  ros__parameters:
    model: polynomial
    axes: ['x', 'y', 'z']
    polynomial:
      bias:
        x: [0.0]
        y: [0.0]
        z: [0.0]
"""


def test_instance_all_runs_the_command_once_per_usable_instance(capsys, tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text(PARAMS, encoding='utf-8')
    out = tmp_path / 'residual.csv'
    code = main(['evaluate', str(_log(PYULOG)), '--instance', 'all', '--params', str(params),
                 '--out-csv', str(out)])
    text = capsys.readouterr().out
    assert code == 0
    assert sorted(p.name for p in tmp_path.glob('residual.imu*.csv')) == [
        'residual.imu0.csv', 'residual.imu1.csv', 'residual.imu2.csv']
    assert text.count('== IMU instance') == 3
    # Only instance 1 runs in the robologs log: instance 1 has no temperature.
    code = main(['evaluate', str(_log(ROBOLOGS)), '--instance', 'all', '--params', str(params),
                 '--out-csv', str(out)])
    assert code == 0
    assert capsys.readouterr().out.count('== IMU instance') == 1


def _message_ends(data: bytes, suffix: str = '.ulg') -> list:
    """
    Where each message of a log ends.

    ULog: after the 16-byte header, uint16 size, uint8 type, data. DataFlash: 0xA3 0x95,
    uint8 type, data of the length its FMT message (type 128, 89 bytes) gives.
    """
    ends = []
    if suffix == '.ulg':
        position = 16
        while position + 3 <= len(data):
            position += 3 + struct.unpack_from('<H', data, position)[0]
            ends.append(position)
        return ends
    lengths, position = {128: 89}, 0
    while position + 3 <= len(data) and data[position:position + 2] == b'\xa3\x95':
        kind = data[position + 2]
        if kind == 128 and position + 5 <= len(data):
            lengths[data[position + 3]] = data[position + 4]
        if kind not in lengths:
            break
        position += lengths[kind]
        ends.append(position)
    return ends


@pytest.mark.parametrize('name', LOGS)
def test_truncated_copies_give_an_error_line_or_a_counted_partial_read(capsys, tmp_path,
                                                                       name):
    data = _log(name).read_bytes()
    full = {i.index: len(i) for i in read_flight_log(_log(name)).instances}
    boundaries = set(_message_ends(data, _log(name).suffix.lower()))
    rng = np.random.default_rng(17)
    for offset in sorted(rng.integers(0, len(data), TRUNCATIONS).tolist()):
        cut = tmp_path / f'cut{offset}{_log(name).suffix}'
        cut.write_bytes(data[:offset])
        code, captured = _inspect(capsys, cut)
        assert 'Traceback' not in captured.err
        if code == 2:
            assert captured.err.startswith('error: ') and captured.err.count('\n') == 1, \
                captured.err
            continue
        assert code == 0, (offset, captured.err)
        # A partial read: what was read, counted per instance, never more than the log has,
        # and a note that the file was cut unless it was cut exactly between two messages
        # (neither format declares its length: such a copy reads as a shorter whole log).
        report = json.loads(captured.out)
        for item in report['instances']:
            assert item['samples'] <= full[item['instance']], offset
        cut = any('cut short' in note for note in report['notes'])
        assert cut != (offset in boundaries), (offset, report['notes'])


@pytest.mark.parametrize('name', LOGS)
def test_a_copy_cut_inside_its_header_is_one_error_line(capsys, tmp_path, name):
    cut = tmp_path / f'head{_log(name).suffix}'
    cut.write_bytes(_log(name).read_bytes()[:10])
    for command in (['inspect'], ['fit', '--out', str(tmp_path / 'p.yaml')]):
        code = main([command[0], str(cut), *command[1:]])
        assert_user_error(code, capsys, str(cut))


def _cut_notes(path):
    return [note for note in read_flight_log(path).notes if 'cut short' in note]


def test_a_ulog_cut_inside_a_message_says_so_and_one_cut_between_messages_cannot(tmp_path):
    data = _log(PYULOG).read_bytes()
    ends = _message_ends(data)
    assert ends[-1] == len(data)
    middle = ends[len(ends) // 2]
    inside = tmp_path / 'inside.ulg'
    inside.write_bytes(data[:middle + 7])
    (note,) = _cut_notes(inside)
    assert f'the last 7 bytes (from byte {middle})' in note
    # ULog declares no length and no end: a cut between two messages reads as a whole log.
    between = tmp_path / 'between.ulg'
    between.write_bytes(data[:middle])
    assert _cut_notes(between) == [] and _cut_notes(_log(PYULOG)) == []


def test_a_ulog_whose_declared_appended_data_is_cut_off_says_so(tmp_path):
    data = bytearray(_log(PYULOG).read_bytes())
    # The flag-bits message: 16-byte header, 3-byte message header, compat[8], incompat[8],
    # appended_offsets[3]; incompat bit 0 says data is appended at those offsets.
    assert data[18] == ord('B')
    data[19 + 8] |= 1
    struct.pack_into('<Q', data, 19 + 16, len(data) + 100)
    cut = tmp_path / 'appended.ulg'
    cut.write_bytes(bytes(data))
    (note,) = _cut_notes(cut)
    assert f'data appended at byte {len(data) + 100}' in note
    assert [len(i) for i in read_flight_log(cut).instances] == [6, 6, 6]
