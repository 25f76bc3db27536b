"""
The ``mlx-tempcomp adis-bias`` command: AN-1042's ADIS16130 bias procedure, guided.

It reads the part (over spidev, or the simulated part through the same SPI
frames), feeds every sample to `BiasProcedure` and says what each phase does:
10 s -> (T1, B1), the self-heating wait, 10 s -> (T2, B2) and BTC, the
settle wait whose end is a rest record for the Allan deviation, the PBC
window -> PBC and T3. It prints the note's Table 6 for the result, the noise
figures and averaging times, and writes the ``linear_btc`` parameter file of
the compensation node with ``rate_noise_rad_s`` from the rest record.
Nothing is written before the end; Ctrl-C exits with 130.
"""

import argparse
import math
import sys
import time

from .errors import UserError
from .options import (add_parameter_file_options, finite_float, non_negative_float,
                      non_negative_int, positive_float)
from .progress import add_progress_option, Progress
from .running import check_output_file, write_node_parameters
from .tables import format_btc_table
from ..core.errors import TempCompError
from ..core.fitting import table_step_c
from ..core.procedures import (adev_at_rad_s, averaging_time_s, BiasProcedure,
                               MIN_TEMPERATURE_CHANGE_C, NOTE_AVERAGE_S, NOTE_PBC_S,
                               NOTE_SELF_HEAT_S, NOTE_SETTLE_S, Phase, ProcedureSettings,
                               RECORD_FRACTION, short_window)
from ..core.series import allan_deviation
from ..hardware.errors import HardwareError
from ..parameters.files import linear_btc_parameters
from ..simulation.adis16130 import Adis16130Truth, self_heating_profile
from ..sources.adis16130 import (AXES, DEFAULT_SPEED_HZ, SimulatedSensor, SimulationConfig,
                                 spidev_sensor)

EXIT_INTERRUPTED = 130
DEFAULT_RATE_HZ = 500.0
DEFAULT_ALLAN_RECORD_S = 1200.0
DEFAULT_SLOPE_DPS_PER_C = 0.04     # the note's Table 6 example
DEFAULT_RISE_C = 5.0               # self_heating_profile's default (UNCONFIRMED)
WAIT_READ_S = 1.0                  # one sample a second keeps a paced wait responsive
TABLE_ROWS = 6
SECONDS_PER_HOUR = 3600.0

_SIMULATED_ONLY = ('seed', 'bias_slope_dps_per_c', 'self_heat_rise_c', 'time_scale')
_SPIDEV_ONLY = ('bus', 'cs', 'speed_hz')

_PHASE_TEXT = {
    Phase.POINT_1: 'averaging RATE and TEMP for {:g} s -> T1, B1',
    Phase.SELF_HEAT: 'waiting {:g} s while the part warms itself',
    Phase.POINT_2: 'averaging RATE and TEMP for {:g} s -> T2, B2',
    Phase.SETTLE: 'waiting {:g} s for the part to settle',
    Phase.REST_RECORD: 'recording {:g} s at rest (end of the settle wait) for the Allan '
                       'deviation',
    Phase.PBC: 'averaging RATE for {:g} s -> PBC = -mean, T3 = mean TEMP',
}


def rate_text(rate_rad_s: float) -> str:
    """Give a rate as every subcommand prints one: rad/s, with deg/s beside."""
    return f'{rate_rad_s:+.4e} rad/s ({math.degrees(rate_rad_s):+.4g} deg/s)'


def _needs(args: argparse.Namespace) -> list:
    """Give the optional packages adis-bias will import (extras.require): the rest record's."""
    return [('allantools', 'give --allan-record-s 0')] if args.allan_record_s > 0 else []


def _spidev_sensor(bus, cs, speed_hz, bits: int):
    """Start the part on spidev (None: bus 0, chip select 0, the default clock); describe it."""
    bus = 0 if bus is None else bus
    cs = 0 if cs is None else cs
    speed_hz = DEFAULT_SPEED_HZ if speed_hz is None else speed_hz
    try:
        sensor = spidev_sensor(bus, cs, speed_hz=speed_hz, resolution_bits=bits)
    except HardwareError as err:
        raise UserError(f'ADIS16130: {err}') from None
    return sensor, f'/dev/spidev{bus}.{cs} at {speed_hz} Hz SCLK'


def _simulated_sensor(seed, bits: int, slope_dps_per_c, rise_c):
    """Start the simulated part (None: the defaults); give it and a description of it."""
    slope = DEFAULT_SLOPE_DPS_PER_C if slope_dps_per_c is None else slope_dps_per_c
    rise_c = DEFAULT_RISE_C if rise_c is None else rise_c
    seed = 0 if seed is None else seed
    try:
        config = SimulationConfig(seed=seed, resolution_bits=bits,
                                  truth=Adis16130Truth(bias_dps_per_c=slope),
                                  thermal=self_heating_profile(rise_c=rise_c))
        return SimulatedSensor(config), (f'the simulated part (seed {seed}, bias slope '
                                         f'{slope:g} deg/s/C, self-heating {rise_c:g} C)')
    except HardwareError as err:
        raise UserError(f'ADIS16130: {err}') from None


def _noise_figures(time_s, rate_rad_s):
    return allan_deviation(time_s, rate_rad_s.reshape(-1, 1), AXES)[0]


class _Pacer:
    """Move the sensor's clock to each target; with a time scale, hold the wall clock back."""

    def __init__(self, sensor, time_scale):
        self.clock = sensor.clock
        self.time_scale = time_scale
        self._wall_start = time.monotonic()
        self._sensor_start = self.clock.now_s

    def to(self, target_s: float) -> None:
        self.clock.advance(target_s - self.clock.now_s)
        if self.time_scale is not None:
            wall_s = (target_s - self._sensor_start) / self.time_scale
            time.sleep(max(wall_s - (time.monotonic() - self._wall_start), 0.0))


def _print_noise(procedure: BiasProcedure) -> None:
    figures = procedure.noise
    arw_deg_rt_h = math.degrees(figures.angle_random_walk_rad_s_rt_hz) * SECONDS_PER_HOUR ** 0.5
    print(f'  noise of the rest record: ARW {arw_deg_rt_h:.4g} deg/sqrt(h) '
          f'({figures.angle_random_walk_rad_s_rt_hz:.4g} rad/s/rt(Hz)), bias instability '
          f'{rate_text(figures.bias_instability_rad_s)} at tau '
          f'{figures.bias_instability_tau_s:.4g} s, rate_noise_rad_s '
          f'{figures.rate_noise_rad_s:.4g}')
    record_s = procedure.settings.allan_record_s
    advised_s = averaging_time_s(figures, NOTE_PBC_S, record_s)
    floor_rad_s, _ = adev_at_rad_s(figures, figures.bias_instability_tau_s)
    trusted_s = [tau for tau in figures.taus_s if tau <= record_s / RECORD_FRACTION * 1.000001]
    reached = bool(trusted_s) and figures.bias_instability_tau_s < max(trusted_s)
    print(f'  Allan minimum {rate_text(floor_rad_s)} at tau '
          f'{figures.bias_instability_tau_s:.4g} s'
          + ('' if reached else ' (the curve still falls at a tenth of the record: a longer '
             '--allan-record-s may find a longer one)'))
    print(f'  averaging time advised: {advised_s:g} s (the Allan minimum, at least the '
          f'{NOTE_PBC_S:g} s of the note, at most a tenth of the record)')
    print(f'  {"window":<10}{"note (s)":>10}{"used (s)":>10}{"expected bias 1-sigma":>26}')
    rows = (('point 1/2', NOTE_AVERAGE_S, procedure.settings.average_s),
            ('PBC', NOTE_PBC_S, procedure.phase_duration_s(Phase.PBC)))
    for name, note_s, used_s in rows:
        adev_rad_s, inside = adev_at_rad_s(figures, used_s)
        mark = '' if inside else ' (extrapolated)'
        print(f'  {name:<10}{note_s:>10g}{used_s:>10g}'
              f'{adev_rad_s:>16.3e} rad/s ({math.degrees(adev_rad_s):.4g} deg/s){mark}')


def _announce_close(procedure: BiasProcedure, phase: Phase) -> None:
    if phase is Phase.POINT_1:
        p = procedure.point_1
        print(f'  T1 = {p.temperature_c:.4f} C, B1 = {rate_text(p.bias_rad_s)}, '
              f'{p.samples} samples')
    elif phase is Phase.POINT_2:
        p = procedure.point_2
        print(f'  T2 = {p.temperature_c:.4f} C, B2 = {rate_text(p.bias_rad_s)}, '
              f'{p.samples} samples')
        btc = procedure.btc_rad_s_per_c
        print(f'  BTC = -(B2 - B1) / (T2 - T1) = {btc:+.4e} rad/s/C '
              f'({math.degrees(btc):+.6f} deg/s/C)')
    elif phase is Phase.REST_RECORD:
        _print_noise(procedure)
        print(f'  motion check: window rate spread at most '
              f'{procedure.settings.motion_noise_multiple:g} x rate_noise_rad_s; points 1 and '
              '2 passed')
    elif phase is Phase.PBC:
        r = procedure.result
        print(f'  PBC = -mean = {rate_text(r.pbc_rad_s)}, T3 = {r.t3_c:.4f} C, '
              f'{r.pbc_point.samples} samples')


def _run(sensor, procedure: BiasProcedure, rate_hz: float, time_scale, jump_waits: bool,
         progress_enabled) -> None:
    """
    Read and feed samples at ``rate_hz`` until the procedure is done, announcing each phase.

    ``time_scale`` holds the wall clock back (None: as fast as it goes);
    ``jump_waits``: the waits are skipped in one step (the simulated part).
    """
    pacer = _Pacer(sensor, time_scale)
    period_s = 1.0 / rate_hz
    phase = None
    progress = None
    next_s = sensor.clock.now_s
    try:
        while procedure.phase is not Phase.DONE:
            sample = sensor.read()
            procedure.add(sample.time_s, sample.rate_rad_s[0], sample.temperature_c[0])
            if procedure.phase is not phase:
                if progress is not None:
                    progress.update(1000)
                    progress.close()
                    _announce_close(procedure, phase)
                phase = procedure.phase
                if phase is Phase.DONE:
                    break
                print(f'phase {phase.value}: '
                      + _PHASE_TEXT[phase].format(procedure.phase_duration_s(phase)))
                progress = Progress(1000, f'  {phase.value}', progress_enabled)
            progress.update(int(1000 * procedure.progress))
            if phase.is_wait:
                end_s = procedure.phase_end_s
                next_s = end_s if jump_waits else min(end_s, sample.time_s + WAIT_READ_S)
            else:
                next_s += period_s
            pacer.to(next_s)
    finally:
        if progress is not None:
            progress.close()


def adis_bias_command(args: argparse.Namespace) -> int:
    wrong = _SPIDEV_ONLY if args.source == 'simulated' else _SIMULATED_ONLY
    given = ['--' + name.replace('_', '-') for name in wrong if getattr(args, name) is not None]
    if given:
        msg = f'{", ".join(given)} {"does" if len(given) == 1 else "do"} not apply to ' \
              f'--source {args.source}'
        raise UserError(msg)
    short = short_window(args.rate_hz, args.average_s, args.pbc_s or NOTE_PBC_S,
                         args.allan_record_s)
    if short is not None:
        name, seconds, why = short
        msg = f'--{name.replace("_", "-")} {seconds:g} at --rate-hz {args.rate_hz:g} {why}'
        raise UserError(msg)
    check_output_file(args.out, '--out')
    try:
        settings = ProcedureSettings(
            average_s=args.average_s, self_heat_s=args.self_heat_s, settle_s=args.settle_s,
            pbc_s=args.pbc_s, allan_record_s=args.allan_record_s,
            min_temperature_change_c=args.min_temperature_change_c)
    except TempCompError as err:
        raise UserError(str(err)) from None
    procedure = BiasProcedure(settings, _noise_figures if args.allan_record_s > 0 else None)
    try:
        sensor, described = (
            _spidev_sensor(args.bus, args.cs, args.speed_hz, args.bits)
            if args.source == 'spidev' else
            _simulated_sensor(args.seed, args.bits, args.bias_slope_dps_per_c,
                              args.self_heat_rise_c))
        try:
            print(f'ADIS16130 bias procedure (AN-1042) on {described}, {args.bits}-bit, '
                  f'{args.rate_hz:g} Hz', flush=True)
            print('keep the part still on a fixed platform with a steady 5 V supply until the '
                  'end; Ctrl-C stops, nothing is written before the end')
            if args.allan_record_s == 0:
                print('no rest record (--allan-record-s 0): no noise figures, no motion check, '
                      'rate_noise_rad_s not written')
            _run(sensor, procedure, args.rate_hz, args.time_scale,
                 args.source == 'simulated' and args.time_scale is None, args.progress or None)
        finally:
            sensor.close()
    except KeyboardInterrupt:
        print('interrupted: nothing written', file=sys.stderr)
        return EXIT_INTERRUPTED
    except TempCompError as err:
        raise UserError(str(err)) from None
    except HardwareError as err:
        raise UserError(f'ADIS16130: {err}') from None
    _report_and_write(procedure, args.source, args.out, args.node_name, args.outputs)
    return 0


def _report_and_write(procedure: BiasProcedure, source: str, out: str, node_name: str,
                      outputs) -> None:
    """Print the result and write it as the node's linear_btc parameters (``out``, staged)."""
    result = procedure.result
    model = result.model
    p1, p2 = result.point_1, result.point_2
    print('result: RBC = RATE + PBC + (TEMP - T3) x BTC')
    print(f'  T1 = {p1.temperature_c:.4f} C   B1 = {rate_text(p1.bias_rad_s)}')
    print(f'  T2 = {p2.temperature_c:.4f} C   B2 = {rate_text(p2.bias_rad_s)}')
    btc = result.btc_rad_s_per_c
    uncertainty = result.btc_uncertainty_rad_s_per_c
    spread = '' if uncertainty is None else \
        f' +- {uncertainty:.2g} rad/s/C expected (1 sigma)'
    print(f'  BTC = {btc:+.4e} rad/s/C ({math.degrees(btc):+.6f} deg/s/C){spread}; '
          f'bias slope {math.degrees(-btc):+.6f} deg/s/C')
    print(f'  PBC = {rate_text(result.pbc_rad_s)}   T3 = {result.t3_c:.4f} C')
    skipped = ', '.join(f'{reason} {count}' for reason, count in procedure.skipped.items()
                        if count)
    print(f'  samples skipped: {skipped or "none"}')
    extent_c = max(abs(p1.temperature_c - result.t3_c), abs(p2.temperature_c - result.t3_c))
    print('correction factors (TEMP - T3) x BTC, as Table 6 of the note:')
    print(format_btc_table(model, AXES, table_step_c(extent_c, TABLE_ROWS), TABLE_ROWS))
    parameters = linear_btc_parameters(model, AXES)
    if result.noise is not None:
        parameters['rate_noise_rad_s'] = float(result.noise.rate_noise_rad_s)
    header = (f'ADIS16130 bias procedure (AN-1042) by mlx-tempcomp adis-bias, source '
              f'{source}: T1 {p1.temperature_c:.4f} C, T2 {p2.temperature_c:.4f} C, '
              f'T3 {result.t3_c:.4f} C')
    write_node_parameters(out, node_name, outputs, parameters, header)
    noise = '' if result.noise is None else \
        f', rate_noise_rad_s {parameters["rate_noise_rad_s"]:.4g}'
    print(f'wrote {out} (model linear_btc{noise})')


def add_parser(commands) -> None:
    """Add the ``adis-bias`` subcommand."""
    parser = commands.add_parser(
        'adis-bias', help="run the ADIS16130 note's bias procedure and write linear_btc "
                          'parameters',
        description="Run AN-1042's ADIS16130 bias procedure step by step on the part (spidev) "
                    'or the simulated part: 10 s of RATE and TEMP -> (T1, B1); wait for '
                    'self-heating; again -> (T2, B2) and BTC = -(B2 - B1) / (T2 - T1); wait '
                    'for the part to settle, the end of the wait being a rest record whose '
                    'Allan deviation gives the noise figures and the advised averaging time; '
                    'average RATE -> PBC = -mean, T3. Prints Table 6 of the note for the '
                    'result and writes the linear_btc parameter file with rate_noise_rad_s. '
                    'A window whose rate spread exceeds twice the rest noise is refused.')
    parser.add_argument('--source', required=True, choices=('simulated', 'spidev'),
                        help='read the part over spidev, or the simulated part')
    parser.add_argument('--bus', type=non_negative_int, metavar='N',
                        help='spidev: SPI bus (default 0)')
    parser.add_argument('--cs', type=non_negative_int, metavar='N',
                        help='spidev: chip select (default 0)')
    parser.add_argument('--speed-hz', type=non_negative_int, metavar='HZ',
                        help=f'spidev: SCLK in Hz (default {DEFAULT_SPEED_HZ})')
    parser.add_argument('--bits', type=int, choices=(24, 16), default=24,
                        help='conversion resolution (default: %(default)s)')
    parser.add_argument('--rate-hz', type=positive_float, default=DEFAULT_RATE_HZ, metavar='HZ',
                        help='sample rate of the averaging windows (default: %(default)g; the '
                             'note reads at 5700)')
    parser.add_argument('--average-s', type=positive_float, default=NOTE_AVERAGE_S,
                        metavar='S', help='window of each point (default: %(default)g)')
    parser.add_argument('--self-heat-s', type=non_negative_float, default=NOTE_SELF_HEAT_S,
                        metavar='S', help='wait between the points (default: %(default)g)')
    parser.add_argument('--settle-s', type=non_negative_float, default=NOTE_SETTLE_S, metavar='S',
                        help='wait before the PBC window, the rest record included '
                             '(default: %(default)g)')
    parser.add_argument('--pbc-s', type=positive_float, metavar='S',
                        help='PBC window (default: the averaging time the rest record advises, '
                             f'at least the {NOTE_PBC_S:g} of the note)')
    parser.add_argument('--allan-record-s', type=non_negative_float,
                        default=DEFAULT_ALLAN_RECORD_S, metavar='S',
                        help='rest record for the Allan deviation at the end of the settle '
                             'wait; 0 skips it (default: %(default)g)')
    parser.add_argument('--min-temperature-change-c', type=positive_float,
                        default=MIN_TEMPERATURE_CHANGE_C, metavar='C',
                        help='smallest T2 - T1 a BTC is computed from (default: %(default)g)')
    parser.add_argument('--seed', type=non_negative_int, metavar='N',
                        help='simulated: noise seed (default 0)')
    parser.add_argument('--bias-slope-dps-per-c', type=finite_float, metavar='DPS_PER_C',
                        help=f'simulated: true bias slope (default {DEFAULT_SLOPE_DPS_PER_C})')
    parser.add_argument('--self-heat-rise-c', type=non_negative_float, metavar='C',
                        help=f'simulated: how much the part warms itself (default '
                             f'{DEFAULT_RISE_C:g})')
    parser.add_argument('--time-scale', type=positive_float, metavar='FACTOR',
                        help='simulated: simulated seconds per wall second (default: as fast '
                             'as possible)')
    add_parameter_file_options(parser, ' at the end')
    add_progress_option(parser)
    parser.set_defaults(handler=adis_bias_command, needs=_needs)
