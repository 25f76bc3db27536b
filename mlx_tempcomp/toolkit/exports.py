"""
Exports for the flight controller: the bias cubic in PX4's and ArduPilot's own parameter files.

``fit`` and ``diagnose`` take ``--px4-params FILE`` and ``--ardupilot-parm
FILE``. Each firmware runs a cubic in temperature per gyro axis, not our full
model: the export is a least-squares cubic of the bias (gyro rate at rest,
or gyro minus the reference) fitted to all rows, written in the firmware's
form, and the command says on held-out rows how far that cubic lies from our
full model (both fitted again on the rows before them), so a user sees what
the flight controller loses. docs/flight-logs.md gives the sources.

- PX4 (``TemperatureCompensation::calc_thermal_offsets_3D``): offset =
  sum_k X_k (clamp(T, TMIN, TMAX) - TREF)^k, subtracted from the raw rate;
  TREF the middle of the range, as ``Tools/process_sensor_caldata.py`` sets
  it. The file is QGC's, as that script writes it: three comment lines, then
  ``1<TAB>1<TAB>NAME<TAB>VALUE<TAB>TYPE`` (type 6 int32, 9 float) in sorted
  name order, values as Python prints them (every digit a double holds).
  ``TC_Gn_ID`` is the gyro's device id (PX4 matches the set by it).
- ArduPilot (``AP_InertialSensor_tempcal.cpp``): v - P(T - 35) + P(caltemp - 35)
  with P(d) = (c1 d + c2 d^2 + c3 d^3) 1e-6, T clamped to [TMIN, TMAX], no
  constant term (it stays in INS_GYROFFS, learnt at boot). The file is what
  ``Tools/scripts/tempcal_IMU.py`` writes: ``NAME VALUE`` lines, TMIN and
  TMAX with one decimal, coefficients x 1e6 with nine; the cubic as those
  digits hold it is the one exported (`ardupilot_cubic`).
"""

from dataclasses import dataclass
import math

import numpy as np

from .common import check_output_file, UserError, write_result
from ..core.effects import EffectModel
from ..core.errors import TempCompError
from ..core.fitting import fit_polynomial
from ..core.model_interface import ModelInputs
from ..core.models import AXIS_NAMES
from ..node_parameters import build_model, COMPENSATION_SPECS, flat_parameters
from ..sources.flightlog import FlightLogError, is_flight_log, read_flight_log

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
PX4_GYROS = 4
ARDUPILOT_TCAL_IMUS = 3
PX4_TYPE_INT32 = 6
PX4_TYPE_FLOAT = 9
PX4_HEADER = ('# Sensor thermal compensation parameters\n#\n'
              '# Vehicle-Id Component-Id Name Value Type\n')


@dataclass(frozen=True)
class FirmwareCubic:
    """
    A bias cubic per axis in a firmware's form, in rad/s.

    offset(T) = sum_k coefficients[axis][k] (clamp(T, min, max) - reference)^k;
    ``coefficients`` has (c0, c1, c2, c3) per axis x, y, z, c_k in rad/s/C^k.
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


def px4_cubic(model: EffectModel) -> FirmwareCubic:
    """Give the PX4 form of a fitted cubic: TREF the middle of its range, TMIN/TMAX the range."""
    reference_c = 0.5 * (model.temperature_min_c + model.temperature_max_c)
    return FirmwareCubic(reference_c, _rebased(model, reference_c), model.temperature_min_c,
                         model.temperature_max_c)


def ardupilot_cubic(model: EffectModel) -> FirmwareCubic:
    """
    Give the ArduPilot form of a fitted cubic, as the .parm file's digits hold it.

    About 35 C; c1..c3 rounded as tempcal_IMU.py prints them (x 1e6, nine
    decimals); the range rounded outwards to one decimal, so no fitted
    temperature is clamped. c0, the bias at 35 C, is kept for the report:
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


def px4_params_text(cubic: FirmwareCubic, gyro: int, device_id: int) -> str:
    """Give the QGC .params text of PX4 gyro ``gyro``'s thermal set (and TC_G_ENABLE 1)."""
    prefix = f'TC_G{gyro}_'
    values = {prefix + 'ID': (device_id, PX4_TYPE_INT32),
              prefix + 'TMIN': (cubic.temperature_min_c, PX4_TYPE_FLOAT),
              prefix + 'TMAX': (cubic.temperature_max_c, PX4_TYPE_FLOAT),
              prefix + 'TREF': (cubic.reference_c, PX4_TYPE_FLOAT)}
    for axis, coefficients in enumerate(cubic.coefficients):
        values.update((f'{prefix}X{k}_{axis}', (float(c), PX4_TYPE_FLOAT))
                      for k, c in enumerate(coefficients))
    lines = [f'1\t1\tTC_G_ENABLE\t1\t{PX4_TYPE_INT32}']
    lines += [f'1\t1\t{name}\t{value}\t{kind}' for name, (value, kind) in sorted(values.items())]
    return PX4_HEADER + '\n'.join(lines) + '\n'


def ardupilot_parm_text(cubic: FirmwareCubic, imu: int) -> str:
    """Give the .parm text of ArduPilot IMU ``imu`` (1-3): ENABLE, TMIN, TMAX, GYRk_X/Y/Z."""
    prefix = f'INS_TCAL{imu}_'
    lines = [f'{prefix}ENABLE 1',
             f'{prefix}TMIN {cubic.temperature_min_c:.{ARDUPILOT_RANGE_DECIMALS}f}',
             f'{prefix}TMAX {cubic.temperature_max_c:.{ARDUPILOT_RANGE_DECIMALS}f}']
    for k in range(1, EXPORT_ORDER + 1):
        lines += [f'{prefix}GYR{k}_{axis.upper()} '
                  f'{c[k] * ARDUPILOT_SCALE_FACTOR:.{ARDUPILOT_COEFFICIENT_DECIMALS}f}'
                  for axis, c in zip(AXIS_NAMES, cubic.coefficients)]
    return '\n'.join(lines) + '\n'


def add_export_options(parser) -> None:
    """Add --px4-params, --ardupilot-parm and --px4-device-id."""
    parser.add_argument('--px4-params', metavar='FILE',
                        help="also write the bias cubic as PX4's TC_G* parameters (QGC .params, "
                             'as Tools/process_sensor_caldata.py writes it)')
    parser.add_argument('--ardupilot-parm', metavar='FILE',
                        help="also write the bias cubic as ArduPilot's INS_TCALn_* parameters "
                             '(.parm, as Tools/scripts/tempcal_IMU.py writes it)')
    parser.add_argument('--px4-device-id', type=int, metavar='ID',
                        help="TC_Gn_ID: the gyro's device id (CAL_GYROn_ID); default: the "
                             "instance's device_id in a .ulg log")


def check_export_outputs(args) -> None:
    """Check the export paths before any work (UserError if one cannot be written)."""
    for option in ('px4_params', 'ardupilot_parm'):
        if getattr(args, option, None) is not None:
            check_output_file(getattr(args, option), '--' + option.replace('_', '-'))
    if getattr(args, 'ardupilot_parm', None) is not None:
        rotation = _identity(args)[2]
        if rotation:
            # IMU messages are in the board frame; INS_TCAL corrects in the sensor frame.
            msg = (f'{args.input}: AHRS_ORIENTATION is {rotation}: ArduPilot corrects in the '
                   'sensor frame and tempcal_IMU.py undoes that rotation first; this export '
                   'does not')
            raise UserError(msg)


def _identity(args) -> tuple:
    """Give the IMU's instance number, device id and board rotation (0 unless a log says)."""
    if not is_flight_log(args.input):
        return 0, None, 0
    try:
        log = read_flight_log(args.input)
        instance = log.instance(args.instance)
    except FlightLogError as err:
        raise UserError(str(err)) from None
    return instance.index, instance.device_id, int(log.parameters.get('AHRS_ORIENTATION', 0))


def _rate_error(recording) -> np.ndarray:
    if recording.reference_rad_s is None:
        return recording.gyro_rad_s
    return recording.gyro_rad_s - recording.reference_rad_s


def _cubic(args, recording) -> EffectModel:
    try:
        return fit_polynomial(recording.temperature_c, _rate_error(recording), EXPORT_ORDER)
    except TempCompError as err:
        msg = f'{args.input}: the exported cubic: {err}'
        raise UserError(msg) from None


def _corrected(model, recording) -> np.ndarray:
    """Run a node model over the whole recording (its history from the first row)."""
    inputs = ModelInputs(**{name: getattr(recording, name) for name in model.inputs})
    return model.stream().correct_block(recording.gyro_rad_s, recording.temperature_c,
                                        inputs).rate_rad_s


def node_model(parameters: dict):
    """Build the model the compensation node runs from a command's (nested) parameters."""
    flat = flat_parameters(parameters)
    return build_model({spec.name: flat.get(spec.name, spec.initial_value)
                        for spec in COMPENSATION_SPECS})


def held_out_start(rows: int) -> int:
    """Give the first row of the held-out part when the command keeps none of its own."""
    return rows - max(1, int(round(HELD_OUT_FRACTION * rows)))


def _comparison(args, recording, full_model_on, start: int, full_saw_held_out: bool) -> list:
    """Say on the held-out rows how far the cubic lies from the full model, per axis."""
    train, held = recording.slice(slice(0, start)), slice(start, len(recording))
    cubic = px4_cubic(_cubic(args, train))
    truth = 0.0 if recording.reference_rad_s is None else recording.reference_rad_s[held]
    cubic_rad_s = recording.gyro_rad_s[held] - cubic.offset_rad_s(recording.temperature_c[held])
    try:
        full_rad_s = _corrected(full_model_on(train), recording)[held]
    except TempCompError as err:
        msg = f'{args.input}: the full model on the rows before the held-out part: {err}'
        raise UserError(msg) from None
    seen = ('; the full model saw these rows (diagnose without --test)' if full_saw_held_out
            else '')
    lines = [f'export: a cubic per axis, the form PX4 and ArduPilot run; on the held-out rows '
             f'{start + 1}-{len(recording)} (both refitted on rows 1-{start}{seen}):',
             f'{"axis":<6}{"cubic - full":>14}{"peak":>12}{"cubic resid.":>14}'
             f'{"full resid.":>13}',
             f'{"":<6}{"RMS rad/s":>14}{"rad/s":>12}{"RMS rad/s":>14}{"RMS rad/s":>13}']

    def rms(values):
        return float(np.sqrt(np.mean(np.square(values))))

    for i, axis in enumerate(recording.axes):
        difference = cubic_rad_s[:, i] - full_rad_s[:, i]
        truth_i = truth if np.isscalar(truth) else truth[:, i]
        lines.append(f'{axis:<6}{rms(difference):>14.3e}{np.max(np.abs(difference)):>12.3e}'
                     f'{rms(cubic_rad_s[:, i] - truth_i):>14.3e}'
                     f'{rms(full_rad_s[:, i] - truth_i):>13.3e}')
    return lines


def write_exports(args, recording, full_model_on, start=None, full_saw_held_out=False) -> None:
    """
    Write the files --px4-params and --ardupilot-parm name, and print the comparison.

    ``full_model_on(part)`` gives our full model fitted to a part of the
    recording (a node model: ``stream().correct_block``); ``start`` is the
    first held-out row (default: the last `HELD_OUT_FRACTION` of the rows).
    """
    if args.px4_params is None and args.ardupilot_parm is None:
        if args.px4_device_id is not None:
            msg = '--px4-device-id applies with --px4-params'
            raise UserError(msg)
        return
    if recording.axes != AXIS_NAMES:
        msg = (f'{args.input}: a flight controller corrects x, y and z; the recording has '
               f'gyro {", ".join(recording.axes)}')
        raise UserError(msg)
    index, device_id, _ = _identity(args)
    start = held_out_start(len(recording)) if start is None else start
    for line in _comparison(args, recording, full_model_on, start, full_saw_held_out):
        print(line)
    model = _cubic(args, recording)
    try:
        if args.px4_params is not None:
            _write_px4(args, model, index, device_id)
        if args.ardupilot_parm is not None:
            _write_ardupilot(args, model, index)
    except OSError as err:
        msg = f'cannot write {err.filename}: {err.strerror}'
        raise UserError(msg) from None


def _write_px4(args, model, index: int, device_id) -> None:
    device_id = args.px4_device_id if args.px4_device_id is not None else device_id
    if device_id is None:
        msg = ("--px4-params needs the gyro's device id, which PX4 matches TC_Gn_ID against: "
               'give --px4-device-id (CAL_GYRO0_ID on the vehicle); a .ulg log holds it')
        raise UserError(msg)
    if index >= PX4_GYROS:
        msg = f'PX4 has thermal sets TC_G0..{PX4_GYROS - 1}; instance {index} has none'
        raise UserError(msg)
    cubic = px4_cubic(model)
    write_result(args.px4_params, px4_params_text(cubic, index, device_id))
    print(f'wrote {args.px4_params} (PX4 TC_G{index}_*, TC_G{index}_ID {device_id}, TREF '
          f'{cubic.reference_c:.2f} C, range {cubic.temperature_min_c:.2f} to '
          f'{cubic.temperature_max_c:.2f} C; TC_G_ENABLE 1; reboot to apply)')


def _write_ardupilot(args, model, index: int) -> None:
    if index >= ARDUPILOT_TCAL_IMUS:
        msg = (f'ArduPilot names INS_TCAL1..{ARDUPILOT_TCAL_IMUS}_*; instance {index} needs '
               f'INS{index + 1}_TCAL_*, which this export does not write')
        raise UserError(msg)
    cubic = ardupilot_cubic(model)
    write_result(args.ardupilot_parm, ardupilot_parm_text(cubic, index + 1))
    exact = px4_cubic(model)
    grid_c = np.linspace(exact.temperature_min_c, exact.temperature_max_c, 1001)
    rounding = np.max(np.abs((cubic.offset_rad_s(grid_c) - exact.offset_rad_s(grid_c))))
    constant = ', '.join(f'{axis} {c[0]:+.4e}'
                         for axis, c in zip(AXIS_NAMES, cubic.coefficients))
    print(f'wrote {args.ardupilot_parm} (ArduPilot INS_TCAL{index + 1}_*, about 35 C, range '
          f'{cubic.temperature_min_c:.1f} to {cubic.temperature_max_c:.1f} C; the file '
          f'digits move the cubic by at most {rounding:.1e} rad/s; reboot to apply)')
    print(f'  the bias at 35 C (rad/s: {constant}) has no INS_TCAL parameter: ArduPilot '
          'keeps it in INS_GYROFFS_*, learnt at boot')
    if cubic.temperature_max_c - cubic.temperature_min_c < ARDUPILOT_MIN_SPAN_C:
        print(f'  note: ArduPilot documents TMAX at least {ARDUPILOT_MIN_SPAN_C:g} C above TMIN; '
              f'this range spans {cubic.temperature_max_c - cubic.temperature_min_c:.1f} C')
