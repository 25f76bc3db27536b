"""
``fit`` and ``diagnose`` --px4-params, --ardupilot-parm: files checked by the firmwares' rules.

The exports are fitted on the first 80 % of the measured thermal cycle and read back as
the firmware reads them, their formulas written here from the documentation (the PX4
``calc_thermal_offsets_3D`` and ArduPilot ``AP_InertialSensor_tempcal.cpp`` sections of
data/flight_logs/README.md), not from the package's model code; on the held-out 20 %
they give our cubic's prediction to 1e-9 relative.
"""

import re

from cli_checks import assert_user_error
from measured_data import MEASURED_CSV
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.fitting import fit_polynomial
from mlx_tempcomp.sources.recording import load_recording
from mlx_tempcomp.toolkit.exports import ardupilot_cubic
import numpy as np
import pytest

DEVICE_ID = 2424842
TRAIN_FRACTION = 0.8
RELATIVE = 1e-9
PX4_GYRO_NAMES = sorted(['TC_G0_ID', 'TC_G0_TMIN', 'TC_G0_TMAX', 'TC_G0_TREF']
                        + [f'TC_G0_X{k}_{a}' for k in range(4) for a in range(3)])
ARDUPILOT_NAMES = (['INS_TCAL1_ENABLE', 'INS_TCAL1_TMIN', 'INS_TCAL1_TMAX']
                   + [f'INS_TCAL1_GYR{k}_{a}' for k in (1, 2, 3) for a in 'XYZ'])


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
                 '--px4-device-id', str(DEVICE_ID)])
    assert code == 0
    # The held-out record: every row after the cut (the preset's glitch row is in train).
    held = load_recording(held_out, columns='time=timestamp:1e-6,temperature=imu.temperature,'
                                            'gyro_x=imu.gyro.x,gyro_y=imu.gyro.y,'
                                            'gyro_z=imu.gyro.z,delimiter=tab')
    recording = load_recording(train, preset='tofupilot')
    cubic = fit_polynomial(recording.temperature_c, recording.gyro_rad_s, 3)
    return {'folder': folder, 'train': train, 'held_temperature_c': held.temperature_c,
            'cubic': cubic}


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
    assert order == ['TC_G_ENABLE'] + PX4_GYRO_NAMES   # the script's sorted() order
    assert {name for name, kind in types.items() if kind == 6} == {'TC_G_ENABLE', 'TC_G0_ID'}
    assert set(types.values()) == {6, 9}
    assert values['TC_G_ENABLE'] == 1 and values['TC_G0_ID'] == DEVICE_ID
    # The script's range and reference: the data's extremes and their midpoint.
    train = load_recording(exported['train'], preset='tofupilot')
    assert values['TC_G0_TMIN'] == train.temperature_c.min()
    assert values['TC_G0_TMAX'] == train.temperature_c.max()
    assert values['TC_G0_TREF'] == 0.5 * (values['TC_G0_TMIN'] + values['TC_G0_TMAX'])


def test_px4_formula_on_the_file_gives_our_cubic_on_held_out_data(exported):
    values, _, _ = _read_qgc_params(exported['folder'] / 'gyro.params')
    temperature_c = exported['held_temperature_c']
    # calc_thermal_offsets_3D: dT = clamp(T, TMIN, TMAX) - TREF; offset = sum Xk dT^k.
    d_t = np.clip(temperature_c, values['TC_G0_TMIN'], values['TC_G0_TMAX']) - \
        values['TC_G0_TREF']
    offset = np.column_stack([values[f'TC_G0_X0_{a}'] + values[f'TC_G0_X1_{a}'] * d_t
                              + values[f'TC_G0_X2_{a}'] * d_t ** 2
                              + values[f'TC_G0_X3_{a}'] * d_t ** 3 for a in range(3)])
    _assert_relative(offset, _our_bias(exported['cubic'], temperature_c))


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
    assert all(re.fullmatch(r'INS_TCAL1_GYR[123]_[XYZ] -?\d+\.\d{9}', line)
               for line in lines[3:])
    train = load_recording(exported['train'], preset='tofupilot')
    assert values['INS_TCAL1_TMIN'] <= train.temperature_c.min() < values['INS_TCAL1_TMIN'] + 0.1
    assert values['INS_TCAL1_TMAX'] - 0.1 < train.temperature_c.max() <= values['INS_TCAL1_TMAX']


def test_ardupilot_formula_on_the_file_gives_our_cubic_on_held_out_data(exported):
    values, _ = _read_parm(exported['folder'] / 'tcal.parm')
    temperature_c = exported['held_temperature_c']
    low, high = values['INS_TCAL1_TMIN'], values['INS_TCAL1_TMAX']

    def polynomial(d, axis):
        # polynomial_eval: (c1 d + c2 d^2 + c3 d^3) / SCALE_FACTOR, no constant term.
        return sum(values[f'INS_TCAL1_GYR{k}_{axis}'] * d ** k for k in (1, 2, 3)) * 1e-6

    # correct_sensor, ENABLE 1, caltemp at the fixed TEMP_REFERENCE 35 C (both clamped):
    # v - P(T - 35) + P(caltemp - 35); the correction subtracted from v is P(T - 35) - P(0).
    caltemp_c = 35.0
    correction = np.column_stack([
        polynomial(np.clip(temperature_c, low, high) - 35.0, a)
        - polynomial(np.clip(caltemp_c, low, high) - 35.0, a) for a in 'XYZ'])
    # Our cubic as the file's digits hold it: about 35 C without its constant (INS_GYROFFS).
    ours = ardupilot_cubic(exported['cubic']).offset_rad_s(temperature_c, constant=False)
    _assert_relative(correction, ours)
    # Those digits move it from the fitted cubic by far less than any gyro resolves.
    inside = (temperature_c >= exported['cubic'].temperature_min_c) & \
        (temperature_c <= exported['cubic'].temperature_max_c)
    exact = _our_bias(exported['cubic'], temperature_c) - _our_bias(
        exported['cubic'], np.array([caltemp_c]))
    assert np.max(np.abs(correction[inside] - exact[inside])) < 1e-9


def test_fit_reports_the_cubic_against_the_full_model_on_held_out_rows(exported, capsys):
    folder = exported['folder']
    code = main(['fit', str(exported['train']), '--preset', 'tofupilot', '--out',
                 str(folder / 'q.yaml'), '--px4-params', str(folder / 'again.params'),
                 '--px4-device-id', str(DEVICE_ID)])
    out = capsys.readouterr().out
    assert code == 0
    assert 'export: a cubic per axis' in out and 'held-out rows 5376-6719' in out
    export = out[out.index('export: a cubic per axis'):].splitlines()
    table = {line.split()[0]: [float(v) for v in line.split()[1:]]
             for line in export[3:6]}
    assert set(table) == {'x', 'y', 'z'}
    for difference_rms, peak, cubic_rms, full_rms in table.values():
        assert 0 <= difference_rms <= peak and cubic_rms > 0 and full_rms > 0
    assert (folder / 'again.params').read_text() == (folder / 'gyro.params').read_text()


def test_diagnose_writes_the_same_exports_as_fit(exported, capsys):
    folder = exported['folder']
    code = main(['diagnose', str(exported['train']), '--preset', 'tofupilot', '--out',
                 str(folder / 'report'), '--test', '0.2', '--px4-params',
                 str(folder / 'd.params'), '--ardupilot-parm', str(folder / 'd.parm'),
                 '--px4-device-id', str(DEVICE_ID)])
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


def test_exports_from_a_flight_log_are_refused_before_anything_is_written(capsys, tmp_path):
    from measured_data import FLIGHT_LOGS
    log = FLIGHT_LOGS / 'ardupilot_ardusub_small.BIN'
    if not log.is_file():
        pytest.skip(f'flight log not present: {log} (set MLX_TEMPCOMP_SHARED)')
    out = tmp_path / 'p.yaml'
    # The log's IMU is rotated (AHRS_ORIENTATION 16); INS_TCAL works in the sensor frame.
    code = main(['fit', str(log), '--out', str(out), '--ardupilot-parm', str(tmp_path / 't')])
    assert_user_error(code, capsys, 'AHRS_ORIENTATION is 16')
    # 0.14 C is no thermal sweep: the cubic cannot be fitted, and no file is written.
    code = main(['fit', str(log), '--out', str(out), '--px4-params', str(tmp_path / 'g')])
    assert_user_error(code, capsys, 'the exported cubic', 'temperature span')
    assert list(tmp_path.iterdir()) == []
