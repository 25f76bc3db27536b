"""
Temperature sweep of a simulated MLX90609, read through the SPI driver.

The sensor-level demo, without ROS (``make demo`` runs the ROS pipeline,
`mlx_tempcomp.ros.demo`): simulate a -40..85 C sweep of one device at
zero rate, read it frame by frame through `Mlx90609`, compensate it with the
factory table read from its own EEPROM, and print the ZRO error of the
nominal conversion (AN2 method 1) beside the EEPROM-compensated one (method 4).

Run ``python -m mlx_tempcomp.simulation.sweep --help`` for the options.
"""

import argparse
from dataclasses import dataclass
import sys

import numpy as np

from .mlx90609 import FactoryMeasurement, simulated_device
from .physics import GyroTruth, Scenario, ThermalProfile
from ..core.errors import TempCompError
from ..core.mlx90609 import (decode_eeprom, EepromFields, factory_table, NominalConversion, Output,
                             table_compensation)
from ..core.series import ErrorStatistics
from ..hardware.mlx90609 import Mlx90609


@dataclass(frozen=True)
class SweepResult:
    """What the driver read during the sweep, and the errors of both conversions."""

    fields: EepromFields
    time_s: np.ndarray
    rate_code: np.ndarray
    temperature_code: np.ndarray
    temperature_c: np.ndarray
    saturated: np.ndarray
    nominal: ErrorStatistics
    eeprom: ErrorStatistics
    clamped_samples: int


def run_sweep(seed: int = 0, low_c: float = -40.0, high_c: float = 85.0,
              duration_s: float = 1800.0, period_s: float = 0.5, oversample: int = 16,
              version: int = 2) -> SweepResult:
    """Sweep one simulated device at zero rate and compensate what the driver read."""
    rng = np.random.default_rng(seed)
    truth = GyroTruth.random(rng)
    scenario = Scenario(thermal=ThermalProfile.sweep(low_c, high_c, duration_s))
    device = simulated_device(truth, scenario, seed=seed,
                              measurement=FactoryMeasurement(version=version))
    transport = device.transport()
    driver = Mlx90609(transport)
    fields = decode_eeprom(driver.read_eeprom())
    table = factory_table(fields, Output.DIGITAL)
    times, rates, temperatures, saturated = [], [], [], []
    clock = device.clock
    while clock.now_s < duration_s:
        start_s = clock.now_s
        reading = driver.read(oversample)
        times.append(start_s)
        rates.append(reading.rate_code)
        temperatures.append(reading.temperature_code)
        saturated.append(reading.saturated)
        transport.wait(period_s - (clock.now_s - start_s))
    rate_code = np.array(rates)
    temperature_code = np.array(temperatures)
    nominal = NominalConversion.for_range(fields.full_scale_dps, Output.DIGITAL)
    compensation = table_compensation([table], fields.full_scale_dps, Output.DIGITAL)
    compensated = compensation.compensate(rate_code, temperature_code)
    # The true rate is zero, so every output is ZRO error.
    return SweepResult(
        fields=fields, time_s=np.array(times), rate_code=rate_code,
        temperature_code=temperature_code,
        temperature_c=truth.transfer.temperature_output_to_c(temperature_code, Output.DIGITAL),
        saturated=np.array(saturated),
        nominal=ErrorStatistics.of(nominal.compensate(rate_code, temperature_code).rate_dps),
        eeprom=ErrorStatistics.of(compensated.rate_dps),
        clamped_samples=int(np.count_nonzero(compensated.temperature_clamped)))


def format_report(result: SweepResult) -> str:
    f = result.fields
    rows = [('nominal (AN2 method 1)', result.nominal),
            ('EEPROM table (method 4)', result.eeprom)]
    lines = [
        f'EEPROM: VERSION {f.version}, full scale {f.full_scale_dps:g} deg/s, '
        f'TC = {list(f.tc_mv)} mV, out-voted bits {f.total_outvoted_bits}',
        f'{len(result.rate_code)} readings, sensed {result.temperature_c.min():.1f} .. '
        f'{result.temperature_c.max():.1f} C, {result.clamped_samples} clamped to [TC0, TC2], '
        f'{int(np.count_nonzero(result.saturated))} saturated',
        '',
        'ZRO error over the sweep, deg/s (true rate 0)',
        f'{"conversion":<26}{"mean":>9}{"1 sigma":>9}{"peak":>9}{"RMS":>9}',
    ]
    for name, stats in rows:
        lines.append(f'{name:<26}{stats.mean:>9.3f}{stats.sigma:>9.3f}{stats.peak:>9.3f}'
                     f'{stats.rms:>9.3f}')
    lines.append(f'RMS improvement: {result.nominal.rms / result.eeprom.rms:.1f}x')
    return '\n'.join(lines)


def format_population(seeds, results) -> str:
    """One row per device, then the RMS pooled over all of them."""
    lines = ['ZRO error RMS per simulated device, deg/s (true rate 0)',
             f'{"seed":>6}{"nominal":>10}{"EEPROM":>10}{"improvement":>13}']
    for seed, result in zip(seeds, results):
        lines.append(f'{seed:>6}{result.nominal.rms:>10.3f}{result.eeprom.rms:>10.3f}'
                     f'{result.nominal.rms / result.eeprom.rms:>12.1f}x')
    nominal = float(np.sqrt(np.mean([r.nominal.rms ** 2 for r in results])))
    eeprom = float(np.sqrt(np.mean([r.eeprom.rms ** 2 for r in results])))
    lines.append(f'{"pooled":>6}{nominal:>10.3f}{eeprom:>10.3f}{nominal / eeprom:>12.1f}x')
    return '\n'.join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m mlx_tempcomp.simulation.sweep',
        description='Sweep a simulated MLX90609 through -40..85 C, read it over the SPI '
                    'driver and compare nominal with EEPROM-compensated ZRO error.')
    parser.add_argument('--seed', type=int, default=0, help='device and noise seed (0)')
    parser.add_argument('--duration', type=float, default=1800.0,
                        help='simulated sweep duration in s (1800)')
    parser.add_argument('--period', type=float, default=0.5,
                        help='reading period in simulated s (0.5)')
    parser.add_argument('--oversample', type=int, default=16,
                        help='conversions averaged per reading (16)')
    parser.add_argument('--version', type=int, default=2, choices=(0, 1, 2, 3, 255),
                        help='EEPROM VERSION the simulated factory writes (2)')
    parser.add_argument('--devices', type=int, default=1,
                        help='sweep this many devices (seeds from --seed on) and print '
                             'one row each plus the pooled RMS (1)')
    args = parser.parse_args(argv)
    if args.duration <= 0.0 or args.period <= 0.0 or args.oversample < 1 or args.devices < 1:
        parser.error('--duration and --period must be positive, --oversample and --devices '
                     'at least 1')
    seeds = range(args.seed, args.seed + args.devices)
    try:
        results = [run_sweep(seed=seed, duration_s=args.duration, period_s=args.period,
                             oversample=args.oversample, version=args.version)
                   for seed in seeds]
    except TempCompError as err:
        print(f'error: {err}', file=sys.stderr)
        return 2
    print(format_report(results[0]) if args.devices == 1 else format_population(seeds, results))
    return 0


if __name__ == '__main__':
    sys.exit(main())
