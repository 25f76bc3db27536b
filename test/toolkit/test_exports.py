"""
``fit`` and ``diagnose`` --px4-params, --ardupilot-parm: files checked by the firmwares' rules.

The exports are fitted on the first 80 % of the measured thermal cycle and read back as
the firmware reads them, their formulas written here from the documentation (the PX4
``calc_thermal_offsets_3D`` and ArduPilot ``AP_InertialSensor_tempcal.cpp`` sections of
data/flight_logs/README.md), not from the package's model code; on the held-out 20 %
they give our cubics' predictions (gyro bias, accelerometer offset) to 1e-9 relative.

ArduPilot logs its IMU in the vehicle frame, after AHRS_ORIENTATION; its thermal
correction acts before it. The rotations are checked against the definitions of
AP_Math/rotations.h and vector3.cpp written here, and an export from a DataFlash log
written here (a rotated IMU with a known cubic in its own axes) must give that cubic.
"""

import math
import re
import struct

from cli_checks import assert_user_error
from measured_data import MEASURED_CSV
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.fitting.bias_polynomial import fit_polynomial
from mlx_tempcomp.recordings.dataflash import board_rotation
from mlx_tempcomp.recordings.flightlog import FlightLogError, read_flight_log
from mlx_tempcomp.recordings.load import load_recording
from mlx_tempcomp.toolkit.exports import ardupilot_cubic
import numpy as np
import pytest

DEVICE_ID = 2424842
ACCEL_DEVICE_ID = 2490378
TRAIN_FRACTION = 0.8
RELATIVE = 1e-9
PX4_GYRO_NAMES = sorted(['TC_G0_ID', 'TC_G0_TMIN', 'TC_G0_TMAX', 'TC_G0_TREF']
                        + [f'TC_G0_X{k}_{a}' for k in range(4) for a in range(3)])
# process_sensor_caldata.py writes its accel dictionaries unsorted (`key_list.sort` is
# never called): ID, TMIN, TMAX, TREF, then X0..X3 of axis 0, of axis 1, of axis 2.
PX4_ACCEL_NAMES = (['TC_A0_ID', 'TC_A0_TMIN', 'TC_A0_TMAX', 'TC_A0_TREF']
                   + [f'TC_A0_X{k}_{a}' for a in range(3) for k in range(4)])
ARDUPILOT_NAMES = (['INS_TCAL1_ENABLE', 'INS_TCAL1_TMIN', 'INS_TCAL1_TMAX']
                   + [f'INS_TCAL1_{s}{k}_{a}' for s in ('ACC', 'GYR') for k in (1, 2, 3)
                      for a in 'XYZ'])


@pytest.fixture(scope='module')
def exported(tmp_path_factory):
    """Cut the measured cycle; fit the first part with both exports; give paths and rows."""
    if not MEASURED_CSV.is_file():
        pytest.skip(f'measured data not present: {MEASURED_CSV} (set MLX_TEMPCOMP_SHARED)')
    folder = tmp_path_factory.mktemp('exports')
    lines = MEASURED_CSV.read_text(encoding='utf-8').splitlines()
    cut = 1 + int(TRAIN_FRACTION * (len(lines) - 1))
    train = folder / 'train.csv'
    train.write_text('\n'.join(lines[:cut]) + '\n', encoding='utf-8')
    held_out = folder / 'held_out.csv'
    held_out.write_text('\n'.join(lines[:1] + lines[cut:]) + '\n', encoding='utf-8')
    code = main(['fit', str(train), '--preset', 'tofupilot', '--out', str(folder / 'p.yaml'),
                 '--px4-params', str(folder / 'gyro.params'),
                 '--ardupilot-parm', str(folder / 'tcal.parm'),
                 '--px4-device-id', str(DEVICE_ID),
                 '--px4-accel-device-id', str(ACCEL_DEVICE_ID)])
    assert code == 0
    # The held-out record: every row after the cut (the preset's glitch row is in train).
    held = load_recording(held_out, columns='time=timestamp:1e-6,temperature=imu.temperature,'
                                            'gyro_x=imu.gyro.x,gyro_y=imu.gyro.y,'
                                            'gyro_z=imu.gyro.z,delimiter=tab')
    recording = load_recording(train, preset='tofupilot')
    cubic = fit_polynomial(recording.temperature_c, recording.gyro_rad_s, 3)
    accel_cubic = fit_polynomial(recording.temperature_c, recording.acceleration_m_s2, 3)
    return {'folder': folder, 'train': train, 'held_temperature_c': held.temperature_c,
            'cubic': cubic, 'accel_cubic': accel_cubic,
            'accel_median': np.median(recording.acceleration_m_s2, axis=0)}


def _our_bias(cubic, temperature_c):
    """Our cubic's bias prediction: what the model subtracts from a zero rate."""
    zero = np.zeros((temperature_c.size, 3))
    return zero - cubic.correct(zero, temperature_c).rate_rad_s


def _assert_relative(predicted, ours):
    for axis in range(3):
        scale = np.max(np.abs(ours[:, axis]))
        assert scale > 0
        error = np.max(np.abs(predicted[:, axis] - ours[:, axis]))
        assert error <= RELATIVE * scale, (axis, error, scale)


def _read_qgc_params(path):
    """Read a QGC .params file: '#' comment lines, then vehicle, component, name, value, type."""
    text = path.read_text(encoding='utf-8')
    lines = text.splitlines()
    assert lines[:3] == ['# Sensor thermal compensation parameters', '#',
                         '# Vehicle-Id Component-Id Name Value Type']
    values, types, order = {}, {}, []
    for line in lines[3:]:
        vehicle, component, name, value, kind = line.split('\t')
        assert (vehicle, component) == ('1', '1')
        values[name] = float(value)
        types[name] = int(kind)
        order.append(name)
    return values, types, order


def test_px4_file_matches_the_qgc_format_field_for_field(exported):
    values, types, order = _read_qgc_params(exported['folder'] / 'gyro.params')
    # The script's order: accel blocks as built, gyro blocks sorted; each enable before.
    assert order == ['TC_A_ENABLE'] + PX4_ACCEL_NAMES + ['TC_G_ENABLE'] + PX4_GYRO_NAMES
    assert {name for name, kind in types.items() if kind == 6} == {
        'TC_A_ENABLE', 'TC_A0_ID', 'TC_G_ENABLE', 'TC_G0_ID'}
    assert set(types.values()) == {6, 9}
    assert values['TC_G_ENABLE'] == 1 and values['TC_G0_ID'] == DEVICE_ID
    assert values['TC_A_ENABLE'] == 1 and values['TC_A0_ID'] == ACCEL_DEVICE_ID
    # The script's range and reference: the data's extremes and their midpoint.
    train = load_recording(exported['train'], preset='tofupilot')
    for prefix in ('TC_A0_', 'TC_G0_'):
        assert values[prefix + 'TMIN'] == train.temperature_c.min()
        assert values[prefix + 'TMAX'] == train.temperature_c.max()
        assert values[prefix + 'TREF'] == 0.5 * (values[prefix + 'TMIN']
                                                 + values[prefix + 'TMAX'])


def test_px4_gyro_set_is_px4s_own_polyfit(exported):
    """TC_G0_X*: np.polyfit(T - TREF, rate, 3) per axis, as process_sensor_caldata.py fits it."""
    values, _, _ = _read_qgc_params(exported['folder'] / 'gyro.params')
    train = load_recording(exported['train'], preset='tofupilot')
    for axis in range(3):
        expected = np.polyfit(train.temperature_c - values['TC_G0_TREF'],
                              train.gyro_rad_s[:, axis], 3)[::-1]
        written = [values[f'TC_G0_X{k}_{axis}'] for k in range(4)]
        assert written == [float(c) for c in expected]


@pytest.mark.parametrize('sensor', ['G', 'A'])
def test_px4_formula_on_the_file_gives_our_cubic_on_held_out_data(exported, sensor):
    values, _, _ = _read_qgc_params(exported['folder'] / 'gyro.params')
    temperature_c = exported['held_temperature_c']
    p = f'TC_{sensor}0_'
    # calc_thermal_offsets_3D: dT = clamp(T, TMIN, TMAX) - TREF; offset = sum Xk dT^k.
    d_t = np.clip(temperature_c, values[p + 'TMIN'], values[p + 'TMAX']) - values[p + 'TREF']
    offset = np.column_stack([values[f'{p}X0_{a}'] + values[f'{p}X1_{a}'] * d_t
                              + values[f'{p}X2_{a}'] * d_t ** 2
                              + values[f'{p}X3_{a}'] * d_t ** 3 for a in range(3)])
    if sensor == 'G':
        ours = _our_bias(exported['cubic'], temperature_c)
    else:
        # process_sensor_caldata.py fits the accel offset from its median (gravity too).
        ours = _our_bias(exported['accel_cubic'], temperature_c) - exported['accel_median']
    _assert_relative(offset, ours)


def _read_parm(path):
    """Read a .parm file as pymavlink's mavparm does: commas as spaces, two fields a line."""
    values, lines = {}, []
    for line in path.read_text(encoding='utf-8').splitlines():
        if not line.strip() or line.startswith('#'):
            continue
        fields = line.replace(',', ' ').split()
        assert len(fields) == 2, line
        values[fields[0]] = float(fields[1])
        lines.append(line)
    return values, lines


def test_ardupilot_file_is_what_tempcal_imu_writes(exported):
    values, lines = _read_parm(exported['folder'] / 'tcal.parm')
    assert list(values) == ARDUPILOT_NAMES
    assert lines[0] == 'INS_TCAL1_ENABLE 1'
    # tempcal_IMU.py: 'NAME %.1f' for TMIN and TMAX, 'NAME %.9f' for the scaled coefficients.
    assert all(re.fullmatch(r'INS_TCAL1_TM(IN|AX) -?\d+\.\d', line) for line in lines[1:3])
    assert all(re.fullmatch(r'INS_TCAL1_(ACC|GYR)[123]_[XYZ] -?\d+\.\d{9}', line)
               for line in lines[3:])
    train = load_recording(exported['train'], preset='tofupilot')
    assert values['INS_TCAL1_TMIN'] <= train.temperature_c.min() < values['INS_TCAL1_TMIN'] + 0.1
    assert values['INS_TCAL1_TMAX'] - 0.1 < train.temperature_c.max() <= values['INS_TCAL1_TMAX']


def _ardupilot_correction(values, prefix, sensor, temperature_c, caltemp_c=35.0):
    """AP_InertialSensor_tempcal.cpp, from the file: what correct_sensor subtracts from v."""
    low, high = values[prefix + 'TMIN'], values[prefix + 'TMAX']

    def polynomial(d, axis):
        # polynomial_eval: (c1 d + c2 d^2 + c3 d^3) / SCALE_FACTOR, no constant term.
        return sum(values[f'{prefix}{sensor}{k}_{axis}'] * d ** k for k in (1, 2, 3)) * 1e-6

    # correct_sensor, ENABLE 1, both temperatures clamped: v - P(T - 35) + P(caltemp - 35).
    return np.column_stack([
        polynomial(np.clip(temperature_c, low, high) - 35.0, a)
        - polynomial(np.clip(caltemp_c, low, high) - 35.0, a) for a in 'XYZ'])


@pytest.mark.parametrize('sensor', ['GYR', 'ACC'])
def test_ardupilot_formula_on_the_file_gives_our_cubic_on_held_out_data(exported, sensor):
    values, _ = _read_parm(exported['folder'] / 'tcal.parm')
    temperature_c = exported['held_temperature_c']
    cubic = exported['cubic' if sensor == 'GYR' else 'accel_cubic']
    # caltemp at the fixed TEMP_REFERENCE 35 C: the correction is P(T - 35) - P(0).
    caltemp_c = 35.0
    correction = _ardupilot_correction(values, 'INS_TCAL1_', sensor, temperature_c, caltemp_c)
    # Our cubic as the file's digits hold it: about 35 C without its constant (INS_GYROFFS,
    # INS_ACCOFFS).
    ours = ardupilot_cubic(cubic).offset_rad_s(temperature_c, constant=False)
    _assert_relative(correction, ours)
    # Those digits move it from the fitted cubic by far less than any IMU resolves.
    inside = (temperature_c >= cubic.temperature_min_c) & \
        (temperature_c <= cubic.temperature_max_c)
    exact = _our_bias(cubic, temperature_c) - _our_bias(cubic, np.array([caltemp_c]))
    assert np.max(np.abs(correction[inside] - exact[inside])) < 1e-9


def test_fit_reports_the_cubic_against_the_full_model_on_held_out_rows(exported, capsys):
    folder = exported['folder']
    code = main(['fit', str(exported['train']), '--preset', 'tofupilot', '--out',
                 str(folder / 'q.yaml'), '--px4-params', str(folder / 'again.params'),
                 '--px4-device-id', str(DEVICE_ID), '--px4-accel-device-id',
                 str(ACCEL_DEVICE_ID)])
    out = capsys.readouterr().out
    assert code == 0
    assert 'export: a cubic per axis' in out and 'held-out rows 5376-6719' in out
    export = out[out.index('export: a cubic per axis'):].splitlines()
    table = {line.split()[0]: [float(v) for v in line.split()[1:]]
             for line in export[3:6]}
    assert set(table) == {'x', 'y', 'z'}
    for difference_rms, peak, cubic_rms, full_rms in table.values():
        assert 0 <= difference_rms <= peak and cubic_rms > 0 and full_rms > 0
    # The accelerometer cubic on the same rows: spread about the median before and after.
    assert export[6].startswith('accelerometer cubic on the same rows')
    accel = {line.split()[0]: [float(v) for v in line.split()[1:]] for line in export[9:12]}
    assert set(accel) == {'x', 'y', 'z'}
    assert all(raw > 0 and after > 0 for raw, after in accel.values()), accel
    assert (folder / 'again.params').read_text() == (folder / 'gyro.params').read_text()


@pytest.mark.slow
def test_diagnose_writes_the_same_exports_as_fit(exported, capsys):
    folder = exported['folder']
    code = main(['diagnose', str(exported['train']), '--preset', 'tofupilot', '--out',
                 str(folder / 'report'), '--test', '0.2', '--px4-params',
                 str(folder / 'd.params'), '--ardupilot-parm', str(folder / 'd.parm'),
                 '--px4-device-id', str(DEVICE_ID), '--px4-accel-device-id',
                 str(ACCEL_DEVICE_ID), '--no-plots'])
    out = capsys.readouterr().out
    assert code == 0
    assert 'export: a cubic per axis' in out and 'saw these rows' not in out
    assert (folder / 'd.params').read_text() == (folder / 'gyro.params').read_text()
    assert (folder / 'd.parm').read_text() == (folder / 'tcal.parm').read_text()


def test_px4_export_of_a_csv_needs_the_device_id(exported, capsys, tmp_path):
    code = main(['fit', str(exported['train']), '--preset', 'tofupilot', '--out',
                 str(tmp_path / 'p.yaml'), '--px4-params', str(tmp_path / 'g.params')])
    assert_user_error(code, capsys, '--px4-device-id', 'CAL_GYRO0_ID')
    assert not (tmp_path / 'g.params').exists()
    code = main(['fit', str(exported['train']), '--preset', 'tofupilot', '--out',
                 str(tmp_path / 'p.yaml'), '--px4-params', str(tmp_path / 'no' / 'g.params')])
    assert_user_error(code, capsys, '--px4-params', 'does not exist')


def test_px4_export_without_the_accel_device_id_writes_the_gyro_set_and_says_so(
        exported, capsys, tmp_path):
    code = main(['fit', str(exported['train']), '--preset', 'tofupilot', '--out',
                 str(tmp_path / 'p.yaml'), '--px4-params', str(tmp_path / 'g.params'),
                 '--px4-device-id', str(DEVICE_ID)])
    out = capsys.readouterr().out
    assert code == 0
    assert 'TC_A0_* left out' in out and '--px4-accel-device-id' in out
    _, _, order = _read_qgc_params(tmp_path / 'g.params')
    assert order == ['TC_G_ENABLE'] + PX4_GYRO_NAMES


def test_exports_from_a_flight_log_are_refused_before_anything_is_written(capsys, tmp_path):
    from measured_data import FLIGHT_LOGS
    log = FLIGHT_LOGS / 'ardupilot_ardusub_small.BIN'
    if not log.is_file():
        pytest.skip(f'flight log not present: {log} (set MLX_TEMPCOMP_SHARED)')
    out = tmp_path / 'p.yaml'
    # 0.14 C is no thermal sweep: the cubic cannot be fitted, and no file is written (the
    # rotated IMU, AHRS_ORIENTATION 16, is no refusal: it is undone).
    for option in ('--ardupilot-parm', '--px4-params'):
        code = main(['fit', str(log), '--out', str(out), option, str(tmp_path / 'f')])
        assert_user_error(code, capsys, 'the exported cubic', 'temperature span')
    assert list(tmp_path.iterdir()) == []


# AP_Math/rotations.h, enum Rotation 0 to 41: each name is the rotation vector3.cpp
# applies, roll first, then pitch, then yaw (ROTATION_ROLL_90_YAW_90 rolls, then yaws).
ROTATION_NAMES = (
    'NONE', 'YAW_45', 'YAW_90', 'YAW_135', 'YAW_180', 'YAW_225', 'YAW_270', 'YAW_315',
    'ROLL_180', 'ROLL_180_YAW_45', 'ROLL_180_YAW_90', 'ROLL_180_YAW_135', 'PITCH_180',
    'ROLL_180_YAW_225', 'ROLL_180_YAW_270', 'ROLL_180_YAW_315', 'ROLL_90', 'ROLL_90_YAW_45',
    'ROLL_90_YAW_90', 'ROLL_90_YAW_135', 'ROLL_270', 'ROLL_270_YAW_45', 'ROLL_270_YAW_90',
    'ROLL_270_YAW_135', 'PITCH_90', 'PITCH_270', 'PITCH_180_YAW_90', 'PITCH_180_YAW_270',
    'ROLL_90_PITCH_90', 'ROLL_180_PITCH_90', 'ROLL_270_PITCH_90', 'ROLL_90_PITCH_180',
    'ROLL_270_PITCH_180', 'ROLL_90_PITCH_270', 'ROLL_180_PITCH_270', 'ROLL_270_PITCH_270',
    'ROLL_90_PITCH_180_YAW_90', 'ROLL_90_YAW_270', 'ROLL_90_PITCH_68_YAW_293', 'PITCH_315',
    'ROLL_90_PITCH_315', 'PITCH_7')
# vector3.cpp spells ROLL_90_PITCH_68_YAW_293 out as a matrix (the name rounds its angles).
ROTATION_38 = np.array([
    [0.14303897231223747232853327204793, 0.36877648650320382639478111741482,
     -0.91844638134308709265241077446262],
    [-0.33213277779664740485543461545603, -0.85628942146641884303193137384369,
     -0.39554550256296522325882847326284],
    [-0.93232380121551217122544130688766, 0.36162457008209242248497616856184,
     0.00000000000000002214311861220361]])
HALF_SQRT_2 = math.sqrt(0.5)
SIN_7, COS_7 = math.sin(math.radians(7)), math.cos(math.radians(7))
# Some cases of Vector3::rotate as vector3.cpp writes them, (x, y, z) -> (x', y', z').
VECTOR3_CASES = {
    1: lambda x, y, z: (HALF_SQRT_2 * (x - y), HALF_SQRT_2 * (x + y), z),
    10: lambda x, y, z: (y, x, -z),
    16: lambda x, y, z: (x, -z, y),
    25: lambda x, y, z: (-z, y, x),
    36: lambda x, y, z: (z, -x, -y),
    41: lambda x, y, z: (COS_7 * x + SIN_7 * z, y, -SIN_7 * x + COS_7 * z),
}


def _named_rotation(orientation):
    """Build the rotation the enum name says from rotations about one axis each."""
    if orientation == 38:
        return ROTATION_38
    angles = dict(re.findall(r'(ROLL|PITCH|YAW)_(\d+)', ROTATION_NAMES[orientation]))
    roll, pitch, yaw = (math.radians(float(angles.get(a, 0))) for a in ('ROLL', 'PITCH', 'YAW'))
    about_x = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)],
                        [0, math.sin(roll), math.cos(roll)]])
    about_y = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0],
                        [-math.sin(pitch), 0, math.cos(pitch)]])
    about_z = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                        [0, 0, 1]])
    return about_z @ about_y @ about_x


def test_board_rotations_are_ardupilots_table():
    for orientation in range(len(ROTATION_NAMES)):
        assert np.allclose(board_rotation(orientation), _named_rotation(orientation),
                           rtol=0, atol=1e-12), ROTATION_NAMES[orientation]
    for orientation, rotate in VECTOR3_CASES.items():
        columns = np.array([rotate(*axis) for axis in np.eye(3)]).T
        assert np.allclose(board_rotation(orientation), columns, rtol=0, atol=1e-12)
    # Past tempcal_IMU.py's table (pymavlink's rotmat): ROLL_45, ROLL_315, custom.
    for orientation in (42, 43, 100, 101, 102):
        with pytest.raises(FlightLogError, match=f'AHRS_ORIENTATION {orientation} is not'):
            board_rotation(orientation)


# A DataFlash log as ArduPilot writes one: FMT messages, PARM, IMU (LogStructure.h formats).
DATAFLASH_FORMATS = {
    'FMT': (128, 'BBnNZ', '<BB4s16s64s', 'Type,Length,Name,Format,Columns'),
    'PARM': (129, 'QNf', '<Q16sf', 'TimeUS,Name,Value'),
    'IMU': (130, 'QBffffffIIfBBHH', '<QBffffffIIfBBHH',
            'TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz'),
}
GRAVITY_M_S2 = np.array([0.0, 0.0, -9.80665])
# The IMU's own thermal cubics about 35 C, (c0, c1, c2, c3) per axis.
GYRO_TRUTH = np.array([[0.01, 2e-4, 3e-6, -5e-8], [-0.02, -3e-4, -2e-6, 6e-8],
                       [0.005, 1e-4, 4e-6, 2e-8]])
ACCEL_TRUTH = np.array([[0.05, 1e-3, 2e-5, 1e-7], [-0.03, -2e-3, 1e-5, -2e-7],
                        [0.02, 3e-3, -3e-5, 3e-7]])


def _dataflash_message(name, *fields):
    type_id, _, layout, _ = DATAFLASH_FORMATS[name]
    return b'\xa3\x95' + bytes([type_id]) + struct.pack(layout, *fields)


def _truth(coefficients, temperature_c):
    d = np.asarray(temperature_c)[:, None] - 35.0
    return sum(coefficients[:, k] * d ** k for k in range(4))


def _write_dataflash(path, parameters, instance, rows=3000):
    """Write a still IMU warming 20 to 60 C at 4 Hz as ArduPilot logs it: rotated."""
    orientation = int(parameters.get('AHRS_ORIENTATION', 0))
    # Past the table the samples stay unrotated: the exports refuse such a log unread.
    rotation = _named_rotation(orientation) if orientation < len(ROTATION_NAMES) else np.eye(3)
    time_s = 1.0 + 0.25 * np.arange(rows)
    temperature_c = np.linspace(20.0, 60.0, rows)
    gyro = _truth(GYRO_TRUTH, temperature_c) @ rotation.T
    accel = (rotation.T @ GRAVITY_M_S2 + _truth(ACCEL_TRUTH, temperature_c)) @ rotation.T
    messages = [_dataflash_message('FMT', type_id, 3 + struct.calcsize(layout), name.encode(),
                                   form.encode(), columns.encode())
                for name, (type_id, form, layout, columns) in DATAFLASH_FORMATS.items()]
    messages += [_dataflash_message('PARM', 0, name.encode(), value)
                 for name, value in parameters.items()]
    messages += [_dataflash_message('IMU', int(t * 1e6), instance, *g, *a, 0, 0, c, 1, 1,
                                    1000, 1000)
                 for t, g, a, c in zip(time_s, gyro, accel, temperature_c)]
    path.write_bytes(b''.join(messages))


def test_ardupilot_export_of_a_rotated_imu_gives_its_own_cubic(capsys, tmp_path):
    # AHRS_ORIENTATION 38, the one pymavlink's table (so tempcal_IMU.py) has otherwise than
    # the firmware; instance 3 is IMU 4, whose set is INS4_TCAL_*.
    log = tmp_path / 'warm.bin'
    _write_dataflash(log, {'AHRS_ORIENTATION': 38, 'INS_TCAL1_ENABLE': 0,
                           'INS4_GYR_ID': 3081234, 'INS4_ACC_ID': 3015698}, instance=3)
    (imu,) = read_flight_log(log).instances
    assert (imu.index, imu.device_id, imu.accel_device_id) == (3, 3081234, 3015698)
    code = main(['fit', str(log), '--instance', '3', '--out', str(tmp_path / 'p.yaml'),
                 '--ardupilot-parm', str(tmp_path / 'tcal.parm')])
    out = capsys.readouterr().out
    assert code == 0, out
    assert 'AHRS_ORIENTATION 38 undone' in out
    values, lines = _read_parm(tmp_path / 'tcal.parm')
    assert lines[0] == 'INS4_TCAL_ENABLE 1'
    assert set(values) == {'INS4_TCAL_ENABLE', 'INS4_TCAL_TMIN', 'INS4_TCAL_TMAX'} | {
        f'INS4_TCAL_{s}{k}_{a}' for s in ('ACC', 'GYR') for k in (1, 2, 3) for a in 'XYZ'}
    temperature_c = np.linspace(values['INS4_TCAL_TMIN'], values['INS4_TCAL_TMAX'], 200)
    for sensor, truth, tolerance in (('GYR', GYRO_TRUTH, 1e-7), ('ACC', ACCEL_TRUTH, 1e-5)):
        correction = _ardupilot_correction(values, 'INS4_TCAL_', sensor, temperature_c)
        # The IMU's own cubic without its constant, relative to 35 C.
        expected = _truth(truth, temperature_c) - truth[:, 0]
        assert np.max(np.abs(correction - expected)) < tolerance, sensor


def test_exports_refuse_what_the_firmware_cannot_take_in_one_line(capsys, tmp_path):
    out = tmp_path / 'p.yaml'
    cases = (({'AHRS_ORIENTATION': 42}, 0, 'AHRS_ORIENTATION 42 is not one'),
             ({'AHRS_ORIENTATION': 0}, 5, 'instance 5 (IMU 6) has none'),
             ({'INS_TCAL2_ENABLE': 1}, 1, 'INS_TCAL2_ENABLE is 1 in the log'),
             ({'INS5_TCAL_ENABLE': 1}, 4, 'INS5_TCAL_ENABLE is 1 in the log'))
    for parameters, instance, needle in cases:
        log = tmp_path / f'imu{instance}.bin'
        _write_dataflash(log, parameters, instance, rows=40)
        code = main(['fit', str(log), '--instance', str(instance), '--out', str(out),
                     '--ardupilot-parm', str(tmp_path / 'tcal.parm')])
        assert_user_error(code, capsys, str(log), needle)
    assert not out.exists() and not (tmp_path / 'tcal.parm').exists()
