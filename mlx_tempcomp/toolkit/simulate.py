"""
The ``mlx-tempcomp simulate`` command: a recording from the simulated sensor, and its truth.

Without ``--turntable`` the samples come through the real device path: the
simulated MLX90609 chips (`SimulatedArray`) answer SPI frames, the protocol
driver reads them, and the nominal conversion (AN2 method 1) gives rad/s
and degC, exactly as ``driver_node`` with ``source: simulated`` publishes
them. That path costs about 0.2 ms per 3-axis sample (10^5 samples in about
20 s), fast enough for thermal cycles at tens of Hz. ``--turntable`` writes
the rate-table session of `simulate_turntable` (reference rates and a
second temperature) that the calibration chain of the PSI 3-axis teslameter
calibration paper is fitted on. The truth (device coefficients, effects, profile) is
written to ``<out stem>.truth.json`` beside the output.
"""

import argparse
import dataclasses
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Optional

import numpy as np

from .convert import write_raw_bag
from .errors import UserError
from .options import non_negative_float, non_negative_int, positive_float
from .progress import add_progress_option, Progress
from .running import check_output_file, check_output_folder, write_json, write_result
from ..core.errors import EepromError, TempCompError
from ..core.mlx90609 import NominalConversion, Output, sensor_tables, SensorTransfer
from ..hardware.errors import HardwareError
from ..recordings.bag import STORAGES
from ..recordings.csv_writer import write_csv
from ..recordings.recording import AXES, Recording
from ..simulation.days import day_change, noise_seed
from ..simulation.physics import Effects, GRAVITY_M_S2, GyroTruth, Noise, NOMINAL_SUPPLY_V
from ..simulation.turntable import simulate_turntable, TurntableProtocol
from ..sources.mlx90609 import SimulatedArray, SimulationConfig

FORMATS = ('csv',) + STORAGES
DEFAULT_DURATION_S = 600.0
# Board faces up in turn with --orientation-period-s: specific force in the sensor frame.
_FACES_M_S2 = tuple(tuple(GRAVITY_M_S2 * sign * (np.arange(3) == axis))
                    for axis in (2, 0, 1) for sign in (1.0, -1.0))
_CSV_FORMAT = '%.12g'
# --fleet: effects given vary unit to unit by this relative spread; outliers get this much
# ZRO slope on top (about ten sigma of the chips' own spread, 0.02 deg/s/C).
FLEET_EFFECT_SPREAD = 0.2
FLEET_VARIED_EFFECTS = ('thermal_lag_s', 'hysteresis_dps', 'zro_supply_dps_per_v')
OUTLIER_ZRO_SLOPE_DPS_PER_C = 0.2
FLEET_UNITS_PER_OUTLIER = 50
FLEET_SEED_STRIDE = 100000
# A fleet unit whose chip the factory could not store is drawn again from its seed plus this,
# up to this many times.
FLEET_REDRAW_SEED = 10 ** 9
FLEET_REDRAWS = 10


class UnstorableChip(UserError):
    """A drawn chip whose factory table its EEPROM cannot hold (a part the factory rejects)."""


def _parse_axes(text: str) -> tuple:
    axes = tuple(a.strip() for a in text.split(',') if a.strip())
    if not axes or len(set(axes)) != len(axes) or not set(axes) <= set(AXES):
        msg = f'axes must be 1 to 3 distinct of x, y, z separated by commas, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return tuple(a for a in AXES if a in axes)


def _time_value(text: str) -> tuple:
    """Parse ``TIME:VALUE`` (argparse type)."""
    when, colon, value = text.partition(':')
    try:
        time_s, number = float(when), float(value)
    except ValueError:
        time_s, number = math.nan, math.nan
    if not colon or not (math.isfinite(time_s) and math.isfinite(number)) or time_s < 0.0:
        msg = f'expected TIME_S:VALUE with TIME_S >= 0, e.g. 1200:0.5; got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return time_s, number


def _day(text: str) -> int:
    """Parse --day: an integer >= 1 (argparse type)."""
    try:
        day = int(text)
    except ValueError:
        day = 0
    if day < 1:
        raise argparse.ArgumentTypeError(f'a day is an integer from 1, got {text!r}')
    return day


def _supply(items) -> tuple:
    """Give supply waypoints ``(times_s, volts)`` from ``V`` or ``T:V ...``."""
    try:
        if len(items) == 1 and ':' not in items[0]:
            return (0.0,), (positive_float(items[0]),)
        points = sorted(_time_value(item) for item in items)
    except argparse.ArgumentTypeError as err:
        raise UserError(f'--supply-v: {err}') from None
    if any(v <= 0.0 for _, v in points):
        raise UserError('--supply-v: volts must be positive')
    return tuple(t for t, _ in points), tuple(v for _, v in points)


@dataclass(frozen=True)
class _ChipRun:
    """
    What `_device_recording` simulates: the chips' configuration and the run around them.

    ``duration_s`` None: the thermal cycle, or `DEFAULT_DURATION_S` at a
    constant temperature. ``supply_given``: the recording carries the supply
    voltage. ``zro_slope_shift_dps_per_c`` is added to every chip's ZRO slope
    (an outlier unit of ``--fleet``) after the factory EEPROM was measured.
    """

    config: SimulationConfig
    axes: tuple
    rate_hz: float
    duration_s: Optional[float]
    supply_times_s: tuple
    supply_v: tuple
    supply_given: bool
    orientation_period_s: float
    zro_slope_shift_dps_per_c: float = 0.0
    day: int = 1


@dataclass(frozen=True)
class _Simulated:
    """A simulated recording, each chip's temperature (chips only), their EEPROMs, the truth."""

    recording: Recording
    axis_temperatures_c: Optional[np.ndarray]
    images: Optional[tuple]
    truth: dict


@dataclass(frozen=True)
class _Codes:
    """The chips' raw output at each sample time, the specific force, the samples kept."""

    time_s: np.ndarray
    rate_code: np.ndarray
    temperature_code: np.ndarray
    acceleration_m_s2: np.ndarray
    kept: np.ndarray


def _output_paths(path: str, fmt) -> tuple:
    """Check --out (``path``) for ``fmt`` (None: by the name); give (out, format, truth file)."""
    out = Path(path)
    fmt = fmt or ('csv' if out.suffix.lower() == '.csv' else 'sqlite3')
    if fmt == 'csv':
        check_output_file(out, '--out')
    else:
        check_output_folder(out, '--out', new=True)
    truth = out.with_name(out.stem + '.truth.json')
    check_output_file(truth, 'truth file of --out')
    return out, fmt, truth


def _chip_run(args: argparse.Namespace, rate_hz: float) -> _ChipRun:
    """Read the chip simulation's options (the handler's, the only reader of them)."""
    supply_times, supply_v = _supply(args.supply_v or [str(NOMINAL_SUPPLY_V)])
    effects = Effects(thermal_lag_s=args.thermal_lag_s, hysteresis_dps=args.hysteresis_dps,
                      hysteresis_width_c=args.hysteresis_width_c,
                      zro_supply_dps_per_v=args.zro_supply_dps_per_v,
                      bias_steps=tuple(args.bias_step or ()),
                      acceleration_dps_per_m_s2=tuple(args.acceleration_dps_per_m_s2))
    noise = Noise()
    noise = dataclasses.replace(
        noise, density_dps_rt_hz=noise.density_dps_rt_hz * args.noise_scale,
        bias_instability_dps=noise.bias_instability_dps * args.noise_scale,
        temperature_noise_mv=noise.temperature_noise_mv * args.noise_scale,
        rate_random_walk_dps_rt_s=args.bias_random_walk_dps_rt_s)
    config = SimulationConfig(
        seed=args.seed, full_scale_dps=args.full_scale_dps, eeprom_version=args.eeprom_version,
        start_temperature_c=args.start_c, cycle_temperatures_c=tuple(args.cycle_c or ()),
        ramp_c_per_min=args.ramp_c_per_min, hold_s=args.hold_s,
        die_time_constant_s=args.die_time_constant_s, rate_dps=tuple(args.rate_dps),
        supply_v=supply_v[0], effects=effects, noise=noise)
    return _ChipRun(config=config, axes=args.axes, rate_hz=rate_hz, duration_s=args.duration_s,
                    supply_times_s=supply_times, supply_v=supply_v,
                    supply_given=args.supply_v is not None,
                    orientation_period_s=args.orientation_period_s, day=args.day)


def _truth_polynomial_rad_s(truth: GyroTruth, transfer: SensorTransfer) -> list:
    """
    Give the true zero-rate bias of the nominal output as a polynomial in (T - 25 C).

    T is the temperature the nominal conversion reports, which differs from the
    die temperature by the device's temperature-sensor spread.
    """
    polynomial = np.polynomial.Polynomial
    # die - 25 = ((T - 25) * typical slope + typical mV at 25 C - true mV at 25 C) / true slope
    die = polynomial([(transfer.temperature_sensor_mv_at_25c - truth.sensor_mv_at_25c)
                      / truth.sensor_mv_per_k,
                      transfer.temperature_sensor_mv_per_k / truth.sensor_mv_per_k])
    zro_dps = polynomial(truth.zro_dps_coefficients)(die)
    return [math.radians(c) for c in zro_dps.coef]


def _device_recording(run: _ChipRun, out: Path, progress_enabled) -> _Simulated:
    """Run the simulated chips through the driver's path and the nominal conversion."""
    try:
        array = SimulatedArray(run.config, len(run.axes))
        images = array.read_eeproms()
        transfer = SensorTransfer()
        tables = sensor_tables(images, Output.DIGITAL, transfer)
    except EepromError as err:
        raise UnstorableChip(f'simulation: {err}') from None
    except (HardwareError, TempCompError) as err:
        raise UserError(f'simulation: {err}') from None
    change = day_change(run.config.seed, len(run.axes), run.day)
    faces = _FACES_M_S2[change.face:] + _FACES_M_S2[:change.face]
    faces = faces if run.orientation_period_s else faces[:1]
    _set_scenario(array, run, faces[0])
    _set_day(array, run, change)
    codes = _sample(array, run, faces, progress_enabled)
    kept = codes.kept
    nominal = NominalConversion.for_range(tables.full_scale_dps, Output.DIGITAL, len(run.axes),
                                          transfer)
    rate_rad_s = np.radians((codes.rate_code[kept] - nominal.zro) / nominal.sf)
    axis_temperatures_c = transfer.temperature_output_to_c(codes.temperature_code[kept],
                                                           Output.DIGITAL)
    with_acceleration = run.orientation_period_s or run.day > 1 or \
        any(run.config.effects.acceleration_dps_per_m_s2)
    recording = Recording(
        source=str(out), time_s=codes.time_s[kept],
        temperature_c=axis_temperatures_c.mean(axis=1), axes=run.axes, gyro_rad_s=rate_rad_s,
        acceleration_m_s2=codes.acceleration_m_s2[kept] if with_acceleration else None,
        supply_voltage_v=np.interp(codes.time_s[kept], run.supply_times_s, run.supply_v)
        if run.supply_given else None,
        skipped={'saturated': int(np.count_nonzero(~kept))})
    truth = _device_truth(run, array, transfer)
    if run.day > 1:
        truth['day'] = {'day': run.day, 'face_up_m_s2': list(faces[0]),
                        'zro_dps_coefficients_added': {
                            axis: list(c) for axis, c in zip(run.axes,
                                                             change.zro_dps_coefficients)},
                        'notes': 'devices hold the coefficients of this day; the factory '
                                 'EEPROM was measured on day 1'}
    return _Simulated(recording, axis_temperatures_c, images, truth)


def _set_day(array: SimulatedArray, run: _ChipRun, change) -> None:
    """Give each chip the day's ZRO change and draw its noise afresh (day 1: nothing)."""
    if run.day == 1:
        return
    for axis, (device, added) in enumerate(zip(array.devices, change.zro_dps_coefficients)):
        zro = list(device.physics.truth.zro_dps_coefficients)
        zro += [0.0] * (len(added) - len(zro))
        zro = [c + a for c, a in zip(zro, added)] + zro[len(added):]
        device.physics.truth = dataclasses.replace(device.physics.truth,
                                                   zro_dps_coefficients=tuple(zro))
        device.physics.reseed(noise_seed(run.config.seed, axis, run.day))


def _set_scenario(array: SimulatedArray, run: _ChipRun, face_m_s2: tuple) -> None:
    """Give each chip the supply, the first face's specific force and an outlier's ZRO slope."""
    for device in array.devices:
        device.physics.scenario = dataclasses.replace(
            device.physics.scenario, supply_times_s=run.supply_times_s, supply_v=run.supply_v,
            acceleration_m_s2=face_m_s2)
        if run.zro_slope_shift_dps_per_c:
            zro = list(device.physics.truth.zro_dps_coefficients)
            zro += [0.0] * (2 - len(zro))
            zro[1] += run.zro_slope_shift_dps_per_c
            device.physics.truth = dataclasses.replace(device.physics.truth,
                                                       zro_dps_coefficients=tuple(zro))


def _sample(array: SimulatedArray, run: _ChipRun, faces: tuple, progress_enabled) -> _Codes:
    """Read the chips at each sample time, turning the board to the next face on time."""
    duration_s = run.duration_s
    if duration_s is None:
        duration_s = run.config.thermal_profile().duration_s \
            if run.config.cycle_temperatures_c else DEFAULT_DURATION_S
    samples = int(math.floor(duration_s * run.rate_hz + 1e-9)) + 1
    time_s = np.arange(samples) / run.rate_hz
    rate_code = np.empty((samples, len(run.axes)))
    temperature_code = np.empty((samples, len(run.axes)))
    acceleration = np.empty((samples, 3))
    kept = np.ones(samples, dtype=bool)
    face = 0
    with Progress(samples, f'simulating {samples} samples', progress_enabled) as progress:
        for i, t in enumerate(time_s.tolist()):
            if run.orientation_period_s:
                wanted = int(t // run.orientation_period_s) % len(faces)
                if wanted != face:
                    face = wanted
                    for device in array.devices:
                        device.physics.scenario = dataclasses.replace(
                            device.physics.scenario, acceleration_m_s2=faces[face])
            array.advance_to(t)
            sample = array.read(1)
            kept[i] = not sample.saturated
            rate_code[i] = sample.rate_code
            temperature_code[i] = sample.temperature_code
            acceleration[i] = faces[face]
            progress.update(i + 1)
    return _Codes(time_s, rate_code, temperature_code, acceleration, kept)


def _device_truth(run: _ChipRun, array: SimulatedArray, transfer: SensorTransfer) -> dict:
    """Give the truth behind a chip recording: configuration, profile, supply, each chip."""
    config = run.config
    return {
        'source': 'simulated MLX90609 chips through the SPI protocol and the nominal '
                  'conversion (driver_node source simulated)',
        'axes': list(run.axes),
        'config': dataclasses.asdict(config),
        'thermal_profile': dataclasses.asdict(config.thermal_profile()),
        'supply': {'times_s': list(run.supply_times_s), 'volts': list(run.supply_v),
                   'nominal_v': NOMINAL_SUPPLY_V},
        'orientation_period_s': run.orientation_period_s,
        'devices': {axis: {
            **dataclasses.asdict(device.physics.truth),
            'zero_rate_bias_rad_s_in_reported_t_minus_25c': _truth_polynomial_rad_s(
                device.physics.truth, transfer),
        } for axis, device in zip(run.axes, array.devices)},
        'notes': 'zro_dps_coefficients and sf_relative_coefficients are polynomials in '
                 '(die temperature - 25 C), lowest order first; the zero_rate_bias polynomial '
                 'is the bias of the recorded rate at the recorded temperature without '
                 'effects or noise. Effects add: hysteresis +-hysteresis_dps/2 by branch, '
                 'bias steps, zro_supply_dps_per_v x (supply - 5 V), '
                 'acceleration_dps_per_m_s2 . specific force.',
    }


def _turntable_recording(out: Path, axes: tuple, seed: int, chamber_c,
                         sample_rate_hz) -> _Simulated:
    """Simulate the rate-table session; ``chamber_c``, ``sample_rate_hz`` None: its own."""
    if axes != AXES:
        raise UserError('--turntable simulates a 3-axis gyro: --axes must be x,y,z')
    protocol = TurntableProtocol()
    if chamber_c:
        protocol = dataclasses.replace(protocol, chamber_temperatures_c=tuple(chamber_c))
    if sample_rate_hz is not None:
        protocol = dataclasses.replace(protocol, sample_rate_hz=sample_rate_hz)
    try:
        session = simulate_turntable(protocol, seed=seed)
    except TempCompError as err:
        raise UserError(f'turntable simulation: {err}') from None
    recording = Recording(source=str(out), time_s=session.time_s,
                          temperature_c=session.temperature_c, axes=AXES,
                          gyro_rad_s=session.measured_rad_s,
                          reference_rad_s=session.reference_rad_s,
                          temperature_2_c=session.temperature_2_c)
    chain = session.truth.chain()
    truth = {
        'source': 'simulated rate table (mlx_tempcomp.simulation.turntable), calibration chain '
                  'of the PSI 3-axis teslameter calibration paper',
        'axes': list(AXES),
        'protocol': dataclasses.asdict(protocol),
        'turntable_truth': dataclasses.asdict(session.truth),
        'chain_parameters': {key: np.asarray(value).tolist()
                             for key, value in chain.to_parameters().items()},
        'plateaus': int(session.plateau_id.max()) + 1,
    }
    return _Simulated(recording, None, None, truth)


def _write_csv(path: Path, recording: Recording, target: Path) -> None:
    try:
        write_csv(path, recording, _CSV_FORMAT)
    except OSError as err:
        msg = f'cannot write {target}: {err.strerror}'
        raise UserError(msg) from None


# Options of the chip simulation that --turntable refuses.
_CHIP_ONLY = ('thermal_lag_s', 'hysteresis_dps', 'zro_supply_dps_per_v', 'bias_step',
              'orientation_period_s', 'bias_random_walk_dps_rt_s')
# Given with --turntable, these are refused too (their defaults are not falsy).
_CHIP_ONLY_VALUES = {'day': 1}


def simulate_command(args: argparse.Namespace) -> int:
    rate_hz = 10.0 if args.rate_hz is None else args.rate_hz
    progress = args.progress or None
    if args.turntable:
        given = [name for name in _CHIP_ONLY if getattr(args, name)]
        if any(args.acceleration_dps_per_m_s2):
            given.append('acceleration_dps_per_m_s2')
        if args.supply_v is not None:
            given.append('supply_v')
        given += [name for name, default in _CHIP_ONLY_VALUES.items()
                  if getattr(args, name) != default]
        if given:
            names = ', '.join('--' + name.replace('_', '-') for name in given)
            msg = f'{names}: effects apply to the chip simulation, not to --turntable'
            raise UserError(msg)
    if args.fleet is not None:
        if args.turntable or args.fleet == 0:
            raise UserError('--fleet takes at least one unit, and simulates chips, not '
                            '--turntable')
        folder = Path(args.out)
        check_output_folder(folder, '--out', new=True)
        _simulate_fleet(folder, args.format or 'csv', _chip_run(args, rate_hz), args.fleet,
                        args.fleet_outliers, args.outputs, progress)
        return 0
    out, fmt, truth_path = _output_paths(args.out, args.format)
    if args.turntable:
        simulated = _turntable_recording(out, args.axes, args.seed, args.cycle_c, args.rate_hz)
    else:
        simulated = _device_recording(_chip_run(args, rate_hz), out, progress)
    for line in _write_simulated(simulated, out, fmt, truth_path, rate_hz, args.outputs,
                                 progress):
        print(line)
    return 0


def _write_simulated(simulated: _Simulated, out: Path, fmt: str, truth_path: Path,
                     rate_hz: float, outputs, progress_enabled) -> list:
    """Write a simulated recording and its truth (staged in ``outputs``); give lines to print."""
    recording = simulated.recording
    truth = simulated.truth
    if fmt == 'csv':
        _write_csv(outputs.file(out), recording, out)
        what = 'CSV'
    else:
        messages = write_raw_bag(outputs.folder(out, create=False, replace=False), fmt,
                                 recording, simulated.axis_temperatures_c, simulated.images,
                                 progress_enabled, out)
        what = f'{fmt} bag, {messages} messages on /imu/data_raw, /imu/temperature_raw'
        if recording.temperature_2_c is not None:
            what += ', /imu/temperature_2_raw'
        if recording.supply_voltage_v is not None:
            what += ', /imu/supply_voltage'
        if simulated.images is not None:
            what += ', /imu/eeprom'
        if recording.reference_rad_s is not None:
            what += '; the reference rate has no topic: evaluate the CSV form'
    truth['recording'] = {'path': str(out), 'format': fmt, 'samples': len(recording),
                          'duration_s': recording.duration_s,
                          'rate_hz': rate_hz,
                          'skipped': dict(recording.skipped)}
    try:
        write_json(outputs.file(truth_path), truth)
    except OSError as err:
        msg = f'cannot write {truth_path}: {err.strerror}'
        raise UserError(msg) from None
    low, high = float(recording.temperature_c.min()), float(recording.temperature_c.max())
    skipped = ', '.join(f'{reason} {count}' for reason, count in recording.skipped.items()
                        if count)
    return [f'{len(recording)} samples over {recording.duration_s:.1f} s, axes '
            f'{", ".join(recording.axes)}, temperature {low:.2f} to {high:.2f} C; '
            f'skipped: {skipped or "none"}',
            f'wrote {out} ({what})',
            f'truth in {truth_path}']


def _fleet_units(seed: int, count: int, outliers, effects: Effects) -> list:
    """
    Draw each of ``count`` units: its seed, effect sizes and whether it is an outlier.

    Every chip coefficient varies through the seed (`GyroTruth.random`); each
    effect coefficient given (and each of the three g-sensitivities) by a
    factor 1 + 0.2 N(0, 1) kept within 0.5 to 1.5. ``outliers`` None: one
    unit in `FLEET_UNITS_PER_OUTLIER`, at least one.
    """
    def factor(rng) -> float:
        return float(np.clip(1.0 + FLEET_EFFECT_SPREAD * rng.standard_normal(), 0.5, 1.5))

    rng = np.random.default_rng([seed, count])
    later = np.random.default_rng([seed, count, 1])
    drawn = max(1, count // FLEET_UNITS_PER_OUTLIER) if outliers is None \
        else min(outliers, count)
    chosen = set(rng.choice(count, size=drawn, replace=False).tolist())
    units = []
    for k in range(count):
        varied = {name: getattr(effects, name) * factor(rng) for name in FLEET_VARIED_EFFECTS}
        # Varied too, from a stream of their own (the fleets drawn before them stay as
        # they were).
        varied['hysteresis_width_c'] = effects.hysteresis_width_c * factor(later)
        varied['acceleration_dps_per_m_s2'] = [g * factor(later)
                                               for g in effects.acceleration_dps_per_m_s2]
        units.append({'unit': f'unit-{k:03d}', 'seed': seed * FLEET_SEED_STRIDE + k,
                      'effects': varied,
                      'outlier': k in chosen,
                      'zro_slope_shift_dps_per_c': OUTLIER_ZRO_SLOPE_DPS_PER_C
                      if k in chosen else 0.0})
    return units


def _unit_run(run: _ChipRun, unit: dict) -> _ChipRun:
    """Give the chip run of one unit of `_fleet_units`: its seed, effects and ZRO slope."""
    varied = {**unit['effects'], 'acceleration_dps_per_m_s2':
              tuple(unit['effects']['acceleration_dps_per_m_s2'])}
    config = dataclasses.replace(run.config, seed=unit['seed'],
                                 effects=dataclasses.replace(run.config.effects, **varied))
    return dataclasses.replace(run, config=config,
                               zro_slope_shift_dps_per_c=unit['zro_slope_shift_dps_per_c'])


def _screened_unit(run: _ChipRun, unit: dict, out: Path) -> _Simulated:
    """
    Simulate one unit of `_fleet_units`; a chip the factory could not store is drawn again.

    A chip whose scale factor or ZRO at a table temperature is beyond what its
    EEPROM byte holds is one the factory screens out (one in several hundred
    draws): the unit's seed moves on by FLEET_REDRAW_SEED, and ``unit`` keeps the
    seeds screened out. A fleet without such a draw is the same as before.
    """
    for _ in range(FLEET_REDRAWS):
        try:
            return _device_recording(_unit_run(run, unit), out, False)
        except UnstorableChip:
            unit.setdefault('screened_out_seeds', []).append(unit['seed'])
            unit['seed'] += FLEET_REDRAW_SEED
    return _device_recording(_unit_run(run, unit), out, False)


def _simulate_fleet(folder: Path, fmt: str, run: _ChipRun, count: int, outliers, outputs,
                    progress_enabled) -> None:
    """Write ``count`` unit recordings, their truths, a manifest and fleet_truth.json."""
    outputs.folder(folder, replace=False)   # the units go in with it, when all are done
    units = _fleet_units(run.config.seed, count, outliers, run.config.effects)
    rows = ['unit,path']
    with Progress(len(units), f'simulating {len(units)} units', progress_enabled) as bar:
        for done, unit in enumerate(units):
            name = unit['unit'] + ('.csv' if fmt == 'csv' else '')
            out = folder / name
            unit['path'] = name
            unit['truth'] = unit['unit'] + '.truth.json'
            _write_simulated(_screened_unit(run, unit, out), out, fmt,
                             folder / unit['truth'], run.rate_hz, outputs, False)
            rows.append(f'{unit["unit"]},{name}')
            bar.update(done + 1)
    try:
        write_result(outputs.file(folder / 'units.csv'), '\n'.join(rows) + '\n')
        write_json(outputs.file(folder / 'fleet_truth.json'), {
            'units': units, 'base_seed': run.config.seed,
            'notes': 'each unit is mlx-tempcomp simulate with its seed (chip coefficients '
                     'drawn by GyroTruth.random) and its effect sizes; an outlier unit has '
                     f'{OUTLIER_ZRO_SLOPE_DPS_PER_C} deg/s/C added to every chip ZRO slope. '
                     'Per-unit truth in <unit>.truth.json.'})
    except OSError as err:
        msg = f'cannot write to {folder}: {err.strerror}'
        raise UserError(msg) from None
    outliers_drawn = ', '.join(u['unit'] for u in units if u['outlier']) or 'none'
    screened = sum(len(u.get('screened_out_seeds', ())) for u in units)
    print(f'wrote {len(units)} units into {folder} (manifest units.csv, fleet_truth.json); '
          f'outliers: {outliers_drawn}' + (f'; chips the factory could not store, drawn '
                                           f'again: {screened}' if screened else ''))


def add_parser(commands) -> None:
    """Add the ``simulate`` subcommand."""
    simulate = commands.add_parser(
        'simulate', help='write a recording (CSV or bag) from the simulated sensor',
        description='Simulate MLX90609 chips through the real SPI protocol and nominal '
                    'conversion (what driver_node publishes), with chosen thermal profile '
                    'and effects, or a rate-table session (--turntable), and write a CSV '
                    'file or a rosbag2 bag on the raw topics, plus <stem>.truth.json with '
                    'the truth behind the data.')
    simulate.add_argument('--out', required=True, metavar='PATH',
                          help='CSV file, or bag folder to create')
    simulate.add_argument('--format', choices=FORMATS,
                          help='csv, sqlite3 or mcap (default: csv for a .csv name, '
                               'else sqlite3)')
    simulate.add_argument('--duration-s', type=positive_float, metavar='S',
                          help='length (default: the thermal cycle, or '
                               f'{DEFAULT_DURATION_S:g} s at constant temperature)')
    simulate.add_argument('--rate-hz', type=positive_float, metavar='HZ',
                          help='sample rate (default: 10)')
    simulate.add_argument('--axes', type=_parse_axes, default=AXES, metavar='AXES',
                          help='gyro axes, e.g. z or x,y,z (default: x,y,z)')
    simulate.add_argument('--seed', type=non_negative_int, default=0, metavar='N',
                          help='seed of the devices and the noise (default: %(default)s)')
    simulate.add_argument('--full-scale-dps', type=positive_float, default=75.0, metavar='DPS',
                          help='full scale of the chips (default: %(default)s)')
    simulate.add_argument('--eeprom-version', type=non_negative_int, default=2, metavar='N',
                          help='EEPROM VERSION the simulated factory writes '
                               '(default: %(default)s)')
    simulate.add_argument('--noise-scale', type=non_negative_float, default=1.0, metavar='F',
                          help='multiply the datasheet noise (0: no noise; default: 1)')
    simulate.add_argument('--rate-dps', type=float, nargs='+', default=[0.0], metavar='DPS',
                          help='true rate, one value or one per axis (default: 0)')
    _add_thermal_options(simulate)
    _add_effect_options(simulate)
    simulate.add_argument('--turntable', action='store_true',
                          help='rate plateaus on each axis at several chamber temperatures '
                               'with a reference rate and a second temperature, for fit --model '
                               'chain')
    _add_fleet_options(simulate)
    add_progress_option(simulate)
    simulate.set_defaults(handler=simulate_command)


def _add_thermal_options(simulate) -> None:
    """Add the thermal profile: start, cycle, ramp, holds, die lag."""
    thermal = simulate.add_argument_group('thermal profile')
    thermal.add_argument('--start-c', type=float, default=25.0, metavar='C',
                         help='chamber temperature at start (default: %(default)s)')
    thermal.add_argument('--cycle-c', type=float, nargs='+', metavar='C',
                         help='temperatures to ramp through in turn, e.g. 60 -20 25; with '
                              '--turntable the chamber temperatures of the sessions')
    thermal.add_argument('--ramp-c-per-min', type=positive_float, default=2.0, metavar='R',
                         help='ramp rate (default: %(default)s)')
    thermal.add_argument('--hold-s', type=non_negative_float, default=0.0, metavar='S',
                         help='hold at each cycle temperature (default: %(default)s)')
    thermal.add_argument('--die-time-constant-s', type=non_negative_float, default=0.0,
                         metavar='S', help='die follows the chamber with this lag')


def _add_effect_options(simulate) -> None:
    """Add the effects of the chip simulation (not of --turntable)."""
    effects = simulate.add_argument_group('effects (chip simulation only)')
    effects.add_argument('--thermal-lag-s', type=non_negative_float, default=0.0, metavar='S',
                         help='temperature sensor lags the die (first order)')
    effects.add_argument('--hysteresis-dps', type=float, default=0.0, metavar='DPS',
                         help='ZRO difference between heating and cooling branches')
    effects.add_argument('--hysteresis-width-c', type=positive_float, default=5.0, metavar='C',
                         help='temperature change that flips the branch (default: %(default)s)')
    effects.add_argument('--bias-step', type=_time_value, action='append', metavar='T:DPS',
                         help='bias step of DPS at time T s (repeatable)')
    effects.add_argument('--bias-random-walk-dps-rt-s', type=non_negative_float, default=0.0,
                         metavar='K', help='bias random walk in deg/s per sqrt(s) (default: 0)')
    effects.add_argument('--acceleration-dps-per-m-s2', type=float, nargs=3,
                         default=[0.0, 0.0, 0.0], metavar=('GX', 'GY', 'GZ'),
                         help='g-sensitivity: deg/s per m/s^2 of specific force x, y, z')
    effects.add_argument('--orientation-period-s', type=non_negative_float, default=0.0,
                         metavar='S', help='turn the board to the next of six faces up every '
                                           'S seconds (writes acc_x|y|z)')
    effects.add_argument('--day', type=_day, default=1, metavar='N',
                         help='the unit on day N (1: as drawn): from the seed, its bias(T) '
                              'moved by a repeatability offset, ageing of the curve and a '
                              'turn onto another face (with --acceleration-dps-per-m-s2 that '
                              'moves each bias), fresh noise; the EEPROM stays that of day 1')
    effects.add_argument('--zro-supply-dps-per-v', type=float, default=0.0, metavar='K',
                         help='ZRO shift per volt off the nominal 5 V')
    effects.add_argument('--supply-v', nargs='+', metavar='V',
                         help='supply: one voltage, or waypoints T:V ... (linear between); '
                              'given, the recording carries it (supply_voltage, '
                              '/imu/supply_voltage); default 5')


def _add_fleet_options(simulate) -> None:
    """Add --fleet and its outliers."""
    fleet = simulate.add_argument_group('fleet')
    fleet.add_argument('--fleet', type=non_negative_int, metavar='N',
                       help='simulate N units into the new folder --out: unit-to-unit '
                            'variation of every coefficient, a few outlier units, a manifest '
                            'units.csv for mlx-tempcomp fleet and fleet_truth.json')
    fleet.add_argument('--fleet-outliers', type=non_negative_int, metavar='K',
                       help=f'units of --fleet whose ZRO slope is off by '
                            f'{OUTLIER_ZRO_SLOPE_DPS_PER_C} deg/s/C (default: one in '
                            f'{FLEET_UNITS_PER_OUTLIER}, at least one)')
