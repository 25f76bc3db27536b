"""
Loading a record as every ``mlx-tempcomp`` subcommand does, and saying what was read.

`load` reads a record as the options say (`ReadOptions`, from the command
line by `read_options`) and prints the same loading line for every subcommand
(rows used, rows skipped by reason, rows sorted into time order); for a
flight log, first what each IMU instance holds. It warns of a column no gyro
record holds (`recordings.plausibility`: a still gyro beyond any offset, a
temperature slewing faster than a part can, a sample interval of the wrong
time unit), or refuses the record with ``--strict``.
"""

import argparse
from dataclasses import dataclass
from pathlib import Path
import sys
from typing import Optional

import numpy as np

from .errors import UserError
from .options import RAW_IMU_TOPIC, RAW_SUPPLY_VOLTAGE_TOPIC, RAW_TEMPERATURE_TOPIC
from ..recordings.flightlog import FlightLog, ImuInstance, is_flight_log
from ..recordings.load import csv_column_map, is_csv, load_flight_log, load_recording
from ..recordings.plausibility import implausible_columns
from ..recordings.recording import Recording, RecordingError


def loading_summary(recording: Recording) -> str:
    """Say how many rows a recording kept, skipped (by reason) and sorted into time order."""
    skipped = ', '.join(f'{reason} {count}' for reason, count in recording.skipped.items()
                        if count)
    text = f'{recording.source}: {len(recording)} rows used; skipped: {skipped or "none"}'
    if recording.sorted_rows:
        rows = 'row' if recording.sorted_rows == 1 else 'rows'
        text += (f'; {recording.sorted_rows} {rows} out of time order (whole blocks) sorted '
                 'into place')
    return text


def instance_line(instance: ImuInstance, used: bool = False) -> str:
    """Say in one line what an IMU instance of a flight log holds and whether it is used."""
    problem = instance.problem()
    moving = int(instance.moving.sum())
    text = f'  {instance.label}: {len(instance)} samples, {moving} moving'
    finite = instance.temperature_c[np.isfinite(instance.temperature_c)]
    if finite.size:
        text += f', {finite.min():.2f} to {finite.max():.2f} C'
    if used:
        return text + '; used'
    return text + (f'; not usable: {problem}' if problem else '; not used')


def flight_log_summary(log: FlightLog, used: ImuInstance = None) -> str:
    """Say what a flight log is, how it was read and each IMU instance it holds."""
    lines = [f'{log.source}: {log.log_format}, {log.system}; {"; ".join(log.notes)}']
    lines += [instance_line(i, used is not None and i.index == used.index)
              for i in log.instances]
    return '\n'.join(lines)


@dataclass(frozen=True)
class ReadOptions:
    """
    How to read a recording: the options `add_recording_options` adds.

    ``columns`` or ``preset`` map a CSV file's columns; ``instance`` picks the
    IMU of a flight log (None: the first usable one); the topics are a bag's.
    ``strict`` refuses a record `plausibility` finds fault with (else a warning);
    ``at_rest``: the command takes a record without a reference as still.
    """

    columns: Optional[str] = None
    preset: Optional[str] = None
    instance: Optional[int] = None
    imu_topic: str = RAW_IMU_TOPIC
    temperature_topic: str = RAW_TEMPERATURE_TOPIC
    supply_voltage_topic: str = RAW_SUPPLY_VOLTAGE_TOPIC
    strict: bool = False
    at_rest: bool = True


def read_options(args: argparse.Namespace, at_rest: bool = True) -> ReadOptions:
    """Give the read options of a command line (those `add_recording_options` added)."""
    return ReadOptions(columns=args.columns, preset=args.preset,
                       instance=getattr(args, 'instance', None), imu_topic=args.imu_topic,
                       temperature_topic=args.temperature_topic,
                       supply_voltage_topic=args.supply_voltage_topic,
                       strict=getattr(args, 'strict', False), at_rest=at_rest)


def load(path: str, options: ReadOptions, to_stderr: bool = False) -> Recording:
    """
    Load the recording at ``path`` as ``options`` say.

    Prints `loading_summary` (for a flight log, after `flight_log_summary`)
    on stdout, or on stderr (``to_stderr``) when stdout is kept for JSON; then
    a ``warning:`` line on stderr per column `implausible_columns` finds, or
    a UserError of the first with ``options.strict``.
    """
    stream = sys.stderr if to_stderr else sys.stdout
    try:
        if is_flight_log(path) and not Path(path).is_dir():
            if options.columns is not None or options.preset is not None:
                msg = f'{path} is a flight-controller log: --columns and --preset ' \
                      'apply to CSV files'
                raise UserError(msg)
            recording, log, used = load_flight_log(path, options.instance)
            print(flight_log_summary(log, used), file=stream)
        else:
            if options.instance is not None:
                msg = f'--instance applies to .ulg and .bin logs, not {path}'
                raise UserError(msg)
            recording = load_recording(path, columns=options.columns, preset=options.preset,
                                       imu_topic=options.imu_topic,
                                       temperature_topic=options.temperature_topic,
                                       supply_voltage_topic=options.supply_voltage_topic)
    except RecordingError as err:
        raise UserError(str(err)) from None
    print(loading_summary(recording), file=stream)
    _check_plausible(path, recording, options)
    return recording


def _check_plausible(path: str, recording: Recording, options: ReadOptions) -> None:
    """Warn of each implausible column of a loaded record, or refuse it (strict)."""
    columns = None
    if is_csv(path):   # names the file's columns and the --columns item that fixes one
        try:
            columns = csv_column_map(options.columns, options.preset)
        except RecordingError:
            columns = None
    lines = implausible_columns(recording, options.at_rest, columns)
    if lines and options.strict:
        raise UserError(f'{lines[0]}; --strict refuses the record')
    for line in lines:
        print(f'warning: {line}', file=sys.stderr)


def load_records(paths: list, options: ReadOptions) -> list:
    """Load each record of ``paths`` with `load` (the same options for all), in order."""
    return [load(path, options) for path in paths]
