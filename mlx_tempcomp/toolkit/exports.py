"""
Exports for the flight controller: the bias cubics in PX4's and ArduPilot's own parameter files.

``fit`` and ``diagnose`` take ``--px4-params FILE`` and ``--ardupilot-parm
FILE``. Each firmware runs a cubic in temperature per gyro axis (and per
accelerometer axis), not our full model: the export is a least-squares cubic
of the gyro bias (gyro rate at rest, or gyro minus the reference) and, when
the record has acceleration, of the accelerometer offset, fitted to all rows
and written in the firmware's form. The command says on held-out rows how far
the gyro cubic lies from our full model (both fitted again on the rows before
them), so a user sees what the flight controller loses, and what the
accelerometer cubic leaves. docs/flight-logs.md gives the sources.

- PX4 (``TemperatureCompensation::calc_thermal_offsets_3D``): offset =
  sum_k X_k (clamp(T, TMIN, TMAX) - TREF)^k, subtracted from the raw value;
  TREF the middle of the range, as ``Tools/process_sensor_caldata.py`` sets
  it; the accelerometer's X0 is its cubic at TREF less its median (the script
  fits the offset from the median, gravity with it). The file is QGC's, as
  that script writes it: three comment lines, then
  ``1<TAB>1<TAB>NAME<TAB>VALUE<TAB>TYPE`` (type 6 int32, 9 float), values as
  Python prints them (every digit a double holds); the TC_A block in the
  script's order (ID, TMIN, TMAX, TREF, X0..X3 per axis), the TC_G block in
  sorted name order. ``TC_Gn_ID`` / ``TC_An_ID`` are the device ids (PX4
  matches a set by them). sensor_gyro and sensor_accel are logged in the
  frame the offsets are subtracted in (before SENS_BOARD_ROT), so nothing is
  rotated, as in the script.
- ArduPilot (``AP_InertialSensor_tempcal.cpp``): v - P(T - 35) + P(caltemp - 35)
  with P(d) = (c1 d + c2 d^2 + c3 d^3) 1e-6, T clamped to [TMIN, TMAX], no
  constant term (it stays in INS_GYROFFS / INS_ACCOFFS). The file is what
  ``Tools/scripts/tempcal_IMU.py`` writes: ``NAME VALUE`` lines, TMIN and
  TMAX with one decimal, ACCk then GYRk coefficients x 1e6 with nine; the
  cubic as those digits hold it is the one exported (`ardupilot_cubic`).
  The correction acts in the sensor frame and a DataFlash log holds the
  vehicle frame, so a log's ``AHRS_ORIENTATION`` is undone first, as the
  script does. IMUs 1-3 are ``INS_TCALn_*``, IMUs 4 and 5 ``INSn_TCAL_*``.
"""

import argparse
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Optional

import numpy as np

from .errors import UserError
from .running import check_output_file, write_result
from ..core.effects import EffectModel
from ..core.errors import TempCompError
from ..core.fitting import fit_polynomial
from ..core.node_models import AXIS_NAMES, ModelInputs
from ..recordings.dataflash import board_rotation
from ..recordings.flightlog import FlightLogError, is_flight_log, read_flight_log

EXPORT_ORDER = 3
# The last fifth of the rows is held out for the comparison with the full model.
HELD_OUT_FRACTION = 0.2
ARDUPILOT_TEMP_REFERENCE_C = 35.0
ARDUPILOT_SCALE_FACTOR = 1e6
# What tempcal_IMU.py prints: TMIN/TMAX '%.1f', coefficients '%.9f'.
ARDUPILOT_RANGE_DECIMALS = 1
ARDUPILOT_COEFFICIENT_DECIMALS = 9
# ArduPilot documents TMAX at least this far above TMIN.
ARDUPILOT_MIN_SPAN_C = 10.0
PX4_SETS = 4
# ArduPilot's thermal sets: INS_TCAL1..3_ (AP_InertialSensor.cpp), INS4_TCAL_ and
# INS5_TCAL_ (the AP_InertialSensor_Params groups 4_ and 5_).
ARDUPILOT_TCAL_IMUS = 5
ARDUPILOT_OLD_GROUPS = 3
PX4_TYPE_INT32 = 6
PX4_TYPE_FLOAT = 9
PX4_HEADER = ('# Sensor thermal compensation parameters\n#\n'
              '# Vehicle-Id Component-Id Name Value Type\n')


@dataclass(frozen=True)
class FirmwareCubic:
    """
    A cubic per axis in a firmware's form, in the sensor's units (rad/s, m/s^2).

    offset(T) = sum_k coefficients[axis][k] (clamp(T, min, max) - reference)^k;
    ``coefficients`` has (c0, c1, c2, c3) per axis x, y, z, c_k in units/C^k.
    """

    reference_c: float
    coefficients: tuple
    temperature_min_c: float
    temperature_max_c: float

    def offset_rad_s(self, temperature_c, constant: bool = True) -> np.ndarray:
        """Give the offset (samples, 3); without ``constant`` the c0 term is left out."""
        clamped = np.clip(np.asarray(temperature_c, dtype=np.float64),
                          self.temperature_min_c, self.temperature_max_c)
        delta = clamped - self.reference_c
        first = 0 if constant else 1
        return np.column_stack([sum(c[k] * delta ** k for k in range(first, len(c)))
                                for c in self.coefficients])


@dataclass(frozen=True)
class ExportedImu:
    """
    What the exports need to know of the IMU: which one, its ids, how the log rotated it.

    ``rotation`` maps the sensor's axes to the record's (logged = rotation @
    sensor); ``orientation`` is the DataFlash log's AHRS_ORIENTATION (0 otherwise).
    """

    index: int = 0
    gyro_device_id: Optional[int] = None
    accel_device_id: Optional[int] = None
    orientation: int = 0
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def sensor_axes(self, values: np.ndarray) -> np.ndarray:
        """Give rows of (x, y, z) in the sensor's axes: rotation.T @ row, for every row."""
        return np.asarray(values) @ self.rotation


@dataclass(frozen=True)
class ExportedCubics:
    """The cubics fitted for the files: gyro, and accelerometer with its median (or None)."""

    gyro: EffectModel
    accel: Optional[EffectModel] = None
    accel_median: Optional[np.ndarray] = None


def _rebased(model: EffectModel, reference_c: float) -> tuple:
    """Re-expand each bias polynomial of ``model`` in powers of (T - reference_c)."""
    scale = model.temperature_scale_c
    x_of_delta = np.polynomial.Polynomial([(reference_c - model.reference_temperature_c) / scale,
                                           1.0 / scale])
    rebased = []
    for term in model.terms:
        power = np.polynomial.Polynomial(term.bias)(x_of_delta).coef
        rebased.append(tuple(float(c) for c in np.pad(power, (0, EXPORT_ORDER + 1 - power.size))))
    return tuple(rebased)


def px4_cubic(model: EffectModel, baseline=(0.0, 0.0, 0.0)) -> FirmwareCubic:
    """
    Give the PX4 form of a fitted cubic: TREF the middle of its range, TMIN/TMAX the range.

    ``baseline`` is taken off X0 per axis: the accelerometer's median, from which
    process_sensor_caldata.py fits its offset.
    """
    reference_c = 0.5 * (model.temperature_min_c + model.temperature_max_c)
    coefficients = tuple((c[0] - float(b),) + c[1:]
                         for c, b in zip(_rebased(model, reference_c), baseline))
    return FirmwareCubic(reference_c, coefficients, model.temperature_min_c,
                         model.temperature_max_c)


def ardupilot_cubic(model: EffectModel) -> FirmwareCubic:
    """
    Give the ArduPilot form of a fitted cubic, as the .parm file's digits hold it.

    About 35 C; c1..c3 rounded as tempcal_IMU.py prints them (x 1e6, nine
    decimals); the range rounded outwards to one decimal, so no fitted
    temperature is clamped. c0, the value at 35 C, is kept for the report:
    ArduPilot has no parameter for it.
    """
    scale = 10.0 ** ARDUPILOT_RANGE_DECIMALS
    coefficients = tuple(
        (c[0],) + tuple(round(ck * ARDUPILOT_SCALE_FACTOR, ARDUPILOT_COEFFICIENT_DECIMALS)
                        / ARDUPILOT_SCALE_FACTOR for ck in c[1:])
        for c in _rebased(model, ARDUPILOT_TEMP_REFERENCE_C))
    return FirmwareCubic(ARDUPILOT_TEMP_REFERENCE_C, coefficients,
                         math.floor(model.temperature_min_c * scale) / scale,
                         math.ceil(model.temperature_max_c * scale) / scale)


def _px4_block(sensor: str, cubic: FirmwareCubic, index: int, device_id: int) -> dict:
    """Give one TC_<sensor><index>_* set, names to (value, type), in the script's order."""
    prefix = f'TC_{sensor}{index}_'
    values = {prefix + 'ID': (device_id, PX4_TYPE_INT32),
              prefix + 'TMIN': (cubic.temperature_min_c, PX4_TYPE_FLOAT),
              prefix + 'TMAX': (cubic.temperature_max_c, PX4_TYPE_FLOAT),
              prefix + 'TREF': (cubic.reference_c, PX4_TYPE_FLOAT)}
    for axis, coefficients in enumerate(cubic.coefficients):
        values.update((f'{prefix}X{k}_{axis}', (float(c), PX4_TYPE_FLOAT))
                      for k, c in enumerate(coefficients))
    return values


def px4_params_text(gyro: FirmwareCubic, index: int, device_id: int, accel=None) -> str:
    """
    Give the QGC .params text of PX4 IMU ``index``'s thermal sets, with their enables.

    ``accel`` is (FirmwareCubic, device id) of the accelerometer, or None. The
    script writes the TC_A block unsorted (its ``sort`` is never called) before the
    TC_G block, sorted; TC_A_ENABLE and TC_G_ENABLE 1 precede their blocks.
    """
    lines = []
    if accel is not None:
        cubic, accel_id = accel
        lines.append(f'1\t1\tTC_A_ENABLE\t1\t{PX4_TYPE_INT32}')
        lines += [f'1\t1\t{name}\t{value}\t{kind}'
                  for name, (value, kind) in _px4_block('A', cubic, index, accel_id).items()]
    lines.append(f'1\t1\tTC_G_ENABLE\t1\t{PX4_TYPE_INT32}')
    lines += [f'1\t1\t{name}\t{value}\t{kind}'
              for name, (value, kind) in sorted(_px4_block('G', gyro, index, device_id).items())]
    return PX4_HEADER + '\n'.join(lines) + '\n'


def ardupilot_tcal_prefix(imu: int) -> str:
    """Give the parameter prefix of ArduPilot IMU ``imu``'s (1-5) thermal set."""
    return f'INS_TCAL{imu}_' if imu <= ARDUPILOT_OLD_GROUPS else f'INS{imu}_TCAL_'


def ardupilot_parm_text(gyro: FirmwareCubic, imu: int,
                        accel: Optional[FirmwareCubic] = None) -> str:
    """Give the .parm text of ArduPilot IMU ``imu`` (1-5): ENABLE, TMIN, TMAX, ACCk, GYRk."""
    prefix = ardupilot_tcal_prefix(imu)
    lines = [f'{prefix}ENABLE 1',
             f'{prefix}TMIN {gyro.temperature_min_c:.{ARDUPILOT_RANGE_DECIMALS}f}',
             f'{prefix}TMAX {gyro.temperature_max_c:.{ARDUPILOT_RANGE_DECIMALS}f}']
    for name, cubic in (('ACC', accel), ('GYR', gyro)):
        if cubic is None:
            continue
        for k in range(1, EXPORT_ORDER + 1):
            lines += [f'{prefix}{name}{k}_{axis.upper()} '
                      f'{c[k] * ARDUPILOT_SCALE_FACTOR:.{ARDUPILOT_COEFFICIENT_DECIMALS}f}'
                      for axis, c in zip(AXIS_NAMES, cubic.coefficients)]
    return '\n'.join(lines) + '\n'


def device_id(text: str) -> int:
    """Parse a device id (argparse type): a 32-bit integer, decimal or 0x hexadecimal."""
    try:
        value = int(text, 16) if text.lower().startswith('0x') else int(text)
    except ValueError:
        value = None
    # PX4 keeps the 32-bit id in an int32 parameter, so a value may be given either way.
    if value is None or not -2 ** 31 <= value < 2 ** 32:
        msg = f'expected a 32-bit device id, e.g. 2424842 or 0x250012, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


def add_export_options(parser) -> None:
    """Add --px4-params, --ardupilot-parm, --px4-device-id and --px4-accel-device-id."""
    parser.add_argument('--px4-params', metavar='FILE',
                        help="also write the cubics as PX4's TC_G* (and TC_A*) parameters (QGC "
                             '.params, as Tools/process_sensor_caldata.py writes it)')
    parser.add_argument('--ardupilot-parm', metavar='FILE',
                        help="also write the cubics as ArduPilot's INS_TCALn_* parameters "
                             '(.parm, as Tools/scripts/tempcal_IMU.py writes it)')
    parser.add_argument('--px4-device-id', type=device_id, metavar='ID',
                        help="TC_Gn_ID: the gyro's device id (CAL_GYROn_ID); default: the "
                             "instance's device_id in a .ulg log")
    parser.add_argument('--px4-accel-device-id', type=device_id, metavar='ID',
                        help="TC_An_ID: the accelerometer's device id (CAL_ACCn_ID); default: "
                             'its device_id in a .ulg log; without one, no TC_A* set')


@dataclass(frozen=True)
class ExportRequest:
    """
    The export options (`add_export_options`) and the record they export from.

    ``record`` names the record; of a flight log, the IMU ``instance`` (None:
    the first usable one) is exported. The paths are the files to write.
    """

    record: str
    instance: Optional[int] = None
    px4_params: Optional[str] = None
    ardupilot_parm: Optional[str] = None
    px4_device_id: Optional[int] = None
    px4_accel_device_id: Optional[int] = None

    @property
    def wanted(self) -> bool:
        """Say whether a file is asked for."""
        return self.px4_params is not None or self.ardupilot_parm is not None


def export_request(args: argparse.Namespace) -> ExportRequest:
    """Give the export options of a command line and its (first) record."""
    return ExportRequest(record=args.input, instance=getattr(args, 'instance', None),
                         px4_params=args.px4_params, ardupilot_parm=args.ardupilot_parm,
                         px4_device_id=args.px4_device_id,
                         px4_accel_device_id=args.px4_accel_device_id)


def check_export_outputs(request: ExportRequest, folder=None) -> None:
    """
    Check the export options, paths and IMU before any work (UserError if one cannot be used).

    A file inside ``folder`` (diagnose's --out, which writes it with the
    rest) is checked with that folder. What the record alone can tell (its
    axes, its acceleration) is `check_export_record`'s, right after it is read.
    """
    if request.px4_params is None:
        options = (('px4_device_id', request.px4_device_id),
                   ('px4_accel_device_id', request.px4_accel_device_id))
        given = [f'--{option.replace("_", "-")}' for option, value in options
                 if value is not None]
        if given:
            msg = f'{" and ".join(given)} {"apply" if len(given) > 1 else "applies"} with ' \
                  '--px4-params'
            raise UserError(msg)
    for option, path in (('px4_params', request.px4_params),
                         ('ardupilot_parm', request.ardupilot_parm)):
        inside = folder is not None and path is not None and \
            Path(path).resolve().parent == Path(folder).resolve()
        if path is not None and not inside:
            check_output_file(path, '--' + option.replace('_', '-'))
    if not request.wanted:
        return
    imu = _exported_imu(request)
    if request.px4_params is not None and imu.index >= PX4_SETS:
        msg = (f'{request.record}: PX4 has thermal sets TC_G0..{PX4_SETS - 1}; instance '
               f'{imu.index} has none')
        raise UserError(msg)
    if request.px4_params is not None and _gyro_device_id(request, imu) is None:
        msg = ("--px4-params needs the gyro's device id, which PX4 matches TC_Gn_ID against: "
               f'give --px4-device-id (CAL_GYRO{imu.index}_ID on the vehicle); a .ulg log '
               'holds it')
        raise UserError(msg)
    if request.ardupilot_parm is not None and imu.index >= ARDUPILOT_TCAL_IMUS:
        msg = (f'{request.record}: ArduPilot has thermal sets for IMUs 1-{ARDUPILOT_TCAL_IMUS} '
               f'(INS_TCAL1..3_*, INS4_TCAL_*, INS5_TCAL_*); instance {imu.index} '
               f'(IMU {imu.index + 1}) has none')
        raise UserError(msg)


def check_export_record(request: ExportRequest, recording) -> None:
    """Check, once the record is read and before the fit, that it can give the exports."""
    if not request.wanted:
        return
    if recording.axes != AXIS_NAMES:
        msg = (f'{request.record}: a flight controller corrects x, y and z; the recording has '
               f'gyro {", ".join(recording.axes)}')
        raise UserError(msg)
    if request.px4_accel_device_id is not None and recording.acceleration_m_s2 is None:
        msg = '--px4-accel-device-id: the record has no acceleration, so no TC_A* set'
        raise UserError(msg)


def _gyro_device_id(request: ExportRequest, imu: ExportedImu):
    """Give TC_Gn_ID: --px4-device-id, else the log's, else None."""
    return request.px4_device_id if request.px4_device_id is not None else imu.gyro_device_id


def _tcal_enabled(log, index: int) -> str:
    """Name the DataFlash log's thermal set of IMU ``index`` when the firmware applied it."""
    name = ardupilot_tcal_prefix(index + 1) + 'ENABLE'
    return name if log.parameters.get(name) == 1 else ''


def _exported_imu(request: ExportRequest) -> ExportedImu:
    """Give the IMU's instance number, device ids and board rotation (none unless a log says)."""
    if not is_flight_log(request.record):
        return ExportedImu()
    try:
        log = read_flight_log(request.record)
        instance = log.instance(request.instance)
    except FlightLogError as err:
        raise UserError(str(err)) from None
    orientation = int(log.parameters.get('AHRS_ORIENTATION', 0))
    try:
        rotation = board_rotation(orientation)
    except FlightLogError as err:
        msg = (f"{request.record}: {err}; the exports need the IMU's own axes, where it is "
               'corrected')
        raise UserError(msg) from None
    enabled = _tcal_enabled(log, instance.index)
    if enabled:
        # The logged samples are already corrected by that set; tempcal_IMU.py takes the
        # correction off again before fitting.
        msg = (f'{request.record}: {enabled} is 1 in the log: its IMU samples are already '
               'corrected by that thermal set, which this export does not undo; calibrate '
               'from a log taken with it 0')
        raise UserError(msg)
    return ExportedImu(instance.index, instance.device_id, instance.accel_device_id,
                       orientation, rotation)


def _cubic(record: str, temperature_c, values, what: str = 'cubic') -> EffectModel:
    try:
        return fit_polynomial(temperature_c, values, EXPORT_ORDER)
    except TempCompError as err:
        msg = f'{record}: the exported {what}: {err}'
        raise UserError(msg) from None


def _cubics(record: str, recording, imu: ExportedImu = ExportedImu()) -> ExportedCubics:
    """Fit the gyro cubic and, with acceleration, the accelerometer's, in the sensor's axes."""
    gyro = _cubic(record, recording.temperature_c, imu.sensor_axes(recording.rate_error_rad_s))
    if recording.acceleration_m_s2 is None:
        return ExportedCubics(gyro)
    acceleration = imu.sensor_axes(recording.acceleration_m_s2)
    accel = _cubic(record, recording.temperature_c, acceleration, 'accelerometer cubic')
    return ExportedCubics(gyro, accel, np.median(acceleration, axis=0))


def _corrected(model, recording) -> np.ndarray:
    """Run a node model over the whole recording (its history from the first row)."""
    inputs = ModelInputs(**{name: getattr(recording, name) for name in model.inputs})
    return model.stream().correct_block(recording.gyro_rad_s, recording.temperature_c,
                                        inputs).rate_rad_s


def held_out_start(rows: int) -> int:
    """Give the first row of the held-out part when the command keeps none of its own."""
    return rows - max(1, int(round(HELD_OUT_FRACTION * rows)))


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _comparison(record: str, recording, full_model_on, start: int,
                full_saw_held_out: bool) -> list:
    """
    Say on the held-out rows how far the cubics leave the full model, per axis.

    Both in the record's axes: a least-squares cubic per axis turns with its data.
    """
    train, held = recording.slice(slice(0, start)), slice(start, len(recording))
    cubics = _cubics(record, train)
    cubic = px4_cubic(cubics.gyro)
    truth = 0.0 if recording.reference_rad_s is None else recording.reference_rad_s[held]
    cubic_rad_s = recording.gyro_rad_s[held] - cubic.offset_rad_s(recording.temperature_c[held])
    try:
        full_rad_s = _corrected(full_model_on(train), recording)[held]
    except TempCompError as err:
        msg = f'{record}: the full model on the rows before the held-out part: {err}'
        raise UserError(msg) from None
    seen = ('; the full model saw these rows (diagnose without --test)' if full_saw_held_out
            else '')
    lines = [f'export: a cubic per axis, the form PX4 and ArduPilot run; on the held-out rows '
             f'{start + 1}-{len(recording)} (both refitted on rows 1-{start}{seen}):',
             f'{"axis":<6}{"cubic - full":>14}{"peak":>12}{"cubic resid.":>14}'
             f'{"full resid.":>13}',
             f'{"":<6}{"RMS rad/s":>14}{"rad/s":>12}{"RMS rad/s":>14}{"RMS rad/s":>13}']
    for i, axis in enumerate(recording.axes):
        difference = cubic_rad_s[:, i] - full_rad_s[:, i]
        truth_i = truth if np.isscalar(truth) else truth[:, i]
        lines.append(f'{axis:<6}{_rms(difference):>14.3e}{np.max(np.abs(difference)):>12.3e}'
                     f'{_rms(cubic_rad_s[:, i] - truth_i):>14.3e}'
                     f'{_rms(full_rad_s[:, i] - truth_i):>13.3e}')
    if cubics.accel is None:
        return lines
    # What the accelerometer cubic (offset from the median, as PX4 fits it) leaves of the
    # rows' spread about the median of the rows before them; no full model to set beside.
    acceleration = recording.acceleration_m_s2[held]
    after = acceleration - (px4_cubic(cubics.accel, cubics.accel_median).offset_rad_s(
        recording.temperature_c[held]) + cubics.accel_median)
    lines += ['accelerometer cubic on the same rows (the toolkit has no full accelerometer '
              'model):',
              f'{"axis":<6}{"raw - median":>14}{"after cubic":>14}',
              f'{"":<6}{"RMS m/s^2":>14}{"RMS m/s^2":>14}']
    lines += [f'{axis:<6}{_rms(acceleration[:, i] - cubics.accel_median[i]):>14.3e}'
              f'{_rms(after[:, i]):>14.3e}' for i, axis in enumerate(AXIS_NAMES)]
    return lines


def write_exports(request: ExportRequest, outputs, recording, full_model_on, start=None,
                  full_saw_held_out=False) -> None:
    """
    Write the files ``request`` names (staged in ``outputs``), and print the comparison.

    ``full_model_on(part)`` gives our full model fitted to a part of the
    recording (a node model: ``stream().correct_block``); ``start`` is the
    first held-out row (default: the last `HELD_OUT_FRACTION` of the rows).
    """
    if not request.wanted:
        return
    check_export_record(request, recording)
    imu = _exported_imu(request)
    start = held_out_start(len(recording)) if start is None else start
    for line in _comparison(request.record, recording, full_model_on, start, full_saw_held_out):
        print(line)
    cubics = _cubics(request.record, recording, imu)
    if imu.orientation:
        print(f'AHRS_ORIENTATION {imu.orientation} undone: the files hold the cubics in the '
              "IMU's own axes, in which ArduPilot corrects (as tempcal_IMU.py)")
    try:
        if request.px4_params is not None:
            _write_px4(request, outputs, cubics, imu)
        if request.ardupilot_parm is not None:
            _write_ardupilot(request.ardupilot_parm, outputs, cubics, imu.index)
    except OSError as err:
        msg = f'cannot write {err.filename}: {err.strerror}'
        raise UserError(msg) from None


def _write_px4(request: ExportRequest, outputs, cubics: ExportedCubics,
               imu: ExportedImu) -> None:
    index = imu.index
    device_id = _gyro_device_id(request, imu)   # check_export_outputs made sure there is one
    accel, left_out = None, ''
    if cubics.accel is not None:
        accel_id = request.px4_accel_device_id if request.px4_accel_device_id is not None \
            else imu.accel_device_id
        if accel_id is None:
            left_out = (f'  TC_A{index}_* left out: PX4 matches it by the device id of the '
                        f'accelerometer; give --px4-accel-device-id (CAL_ACC{index}_ID)')
        else:
            accel = (px4_cubic(cubics.accel, cubics.accel_median), accel_id)
    cubic = px4_cubic(cubics.gyro)
    write_result(outputs.file(request.px4_params),
                 px4_params_text(cubic, index, device_id, accel))
    sets, enables = f'TC_G{index}_* (ID {device_id})', 'TC_G_ENABLE 1'
    if accel is not None:
        sets, enables = f'TC_A{index}_* (ID {accel_id}) and {sets}', 'TC_A_ENABLE and ' + enables
    print(f'wrote {request.px4_params} (PX4 {sets}, TREF {cubic.reference_c:.2f} C, range '
          f'{cubic.temperature_min_c:.2f} to {cubic.temperature_max_c:.2f} C; {enables}; '
          'reboot to apply)')
    if left_out:
        print(left_out)
    elif cubics.accel is None:
        print(f'  TC_A{index}_* left out: the record has no acceleration')


def _rounding(model: EffectModel, written: FirmwareCubic) -> float:
    """Give how far the written digits move a cubic over its fitted range."""
    exact = px4_cubic(model)
    grid_c = np.linspace(exact.temperature_min_c, exact.temperature_max_c, 1001)
    return float(np.max(np.abs(written.offset_rad_s(grid_c) - exact.offset_rad_s(grid_c))))


def _write_ardupilot(path: str, outputs, cubics: ExportedCubics, index: int) -> None:
    imu = index + 1
    gyro = ardupilot_cubic(cubics.gyro)
    accel = None if cubics.accel is None else ardupilot_cubic(cubics.accel)
    write_result(outputs.file(path), ardupilot_parm_text(gyro, imu, accel))
    prefix = ardupilot_tcal_prefix(imu)
    rounding = f'gyro {_rounding(cubics.gyro, gyro):.1e} rad/s'
    if accel is not None:
        rounding += f', accelerometer {_rounding(cubics.accel, accel):.1e} m/s^2'
    print(f'wrote {path} (ArduPilot {prefix}*, about 35 C, range '
          f'{gyro.temperature_min_c:.1f} to {gyro.temperature_max_c:.1f} C; the file digits '
          f'move the cubics by at most {rounding}; reboot to apply)')
    constant = ', '.join(f'{axis} {c[0]:+.4e}' for axis, c in zip(AXIS_NAMES, gyro.coefficients))
    print(f'  the bias at 35 C (rad/s: {constant}) has no INS_TCAL parameter: ArduPilot '
          'keeps it in INS_GYROFFS_*, learnt at boot')
    if accel is None:
        print(f'  {prefix}ACC* left out: the record has no acceleration; the board keeps the '
              f'{prefix}ACC* it has')
    if gyro.temperature_max_c - gyro.temperature_min_c < ARDUPILOT_MIN_SPAN_C:
        print(f'  note: ArduPilot documents TMAX at least {ARDUPILOT_MIN_SPAN_C:g} C above TMIN; '
              f'this range spans {gyro.temperature_max_c - gyro.temperature_min_c:.1f} C')
