"""
What the ``mlx-tempcomp`` subcommands share: user errors, options, loading and writing.

User mistakes (a missing or malformed file, data that cannot support what was
asked) raise `UserError`; ``mlx-tempcomp`` prints it in one line starting with
``error:`` and exits with code 2, never a traceback. Rates are printed in rad/s,
deg/s beside where a person reads them (`rate_text`); table cells in rad/s use
``.3e``. Every subcommand that reads a recording prints the same loading line
(rows used, rows skipped by reason, rows sorted into time order) through
`load`, and warns of a column no gyro record holds (`plausibility`: a
still gyro beyond any offset, a temperature slewing faster than a part can, a
sample interval of the wrong time unit), or refuses the record with
``--strict``. Output paths are checked before the work (`check_output_file`,
`check_output_folder`), so a typo'd folder fails at once, not after a long
fit. Every output is staged and put in place when the command is done
(`run_handler`, `outputs.Outputs`): an interrupted or failed run leaves the
previous outputs, or none, never part of them.
"""

import argparse
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import re
import sys
from typing import Optional

import numpy as np

from .outputs import Outputs
from ..core.validation import (BASELINE_MARGIN, DEFAULT_MIN_PAST, DEFAULT_SIGNIFICANCE,
                               DEFAULT_VALIDATION, SCHEMES)
from ..errors import MlxTempCompError
from ..parameters.files import parameter_file, write_parameter_file
from ..parameters.state_file import atomic_write
from ..recordings.flightlog import (FlightLog, FlightLogError, ImuInstance, is_flight_log,
                                    read_flight_log)
from ..recordings.load import csv_column_map, is_csv, load_flight_log, load_recording
from ..recordings.plausibility import implausible_columns
from ..recordings.recording import Recording, RecordingError

EXIT_USER_ERROR = 2
# The topics a bag is read from by default: the driver's raw output, what `simulate` and
# `convert` write and every driver publishes (the compensated imu/data is the node's output).
RAW_IMU_TOPIC = '/imu/data_raw'
RAW_TEMPERATURE_TOPIC = '/imu/temperature_raw'
RAW_SUPPLY_VOLTAGE_TOPIC = '/imu/supply_voltage'


class UserError(MlxTempCompError):
    """A mistake in what the user asked for; reported in one line, exit code 2."""


def rate_text(rate_rad_s: float) -> str:
    """Give a rate as every subcommand prints one: rad/s, with deg/s beside."""
    return f'{rate_rad_s:+.4e} rad/s ({math.degrees(rate_rad_s):+.4g} deg/s)'


def non_negative_int(text: str) -> int:
    """Parse a non-negative integer option (argparse type)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        msg = f'expected a non-negative integer, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


def float_type(accept, expected: str):
    """Return an argparse type for finite numbers that ``accept`` admits ("expected ...")."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and accept(value)):
            msg = f'expected {expected}, got {text!r}'
            raise argparse.ArgumentTypeError(msg)
        return value
    return parse


finite_float = float_type(lambda value: True, 'a finite number')
positive_float = float_type(lambda value: value > 0.0, 'a positive number')
non_negative_float = float_type(lambda value: value >= 0.0, 'a number >= 0')
fraction = float_type(lambda value: 0.0 <= value < 1.0, 'a number in [0, 1)')
# Validation schemes as the command line spells them.
VALIDATION_OPTIONS = {scheme.replace('_', '-'): scheme for scheme in SCHEMES}


def add_validation_options(parser: argparse.ArgumentParser, when: str = '') -> None:
    """Add --validation, --min-past, --baseline-margin, --significance; None if not given."""
    default = DEFAULT_VALIDATION.replace('_', '-')
    parser.add_argument('--validation', choices=tuple(VALIDATION_OPTIONS),
                        help=f'{when}which held-out scheme decides: forward predicts each '
                             'block from a fit on the blocks before it (as a node runs a model '
                             'fitted on the past), round-robin deals blocks to --folds folds, '
                             'purged predicts each block from the others but a buffer of '
                             "neighbours as long as the model's memory "
                             f'(default: {default})')
    parser.add_argument('--min-past', type=fraction, metavar='F',
                        help=f'{when}forward: the first predicted block starts after this '
                             f'fraction of the record (default: {DEFAULT_MIN_PAST})')
    parser.add_argument('--baseline-margin', type=fraction, metavar='F',
                        help=f'{when}write a model other than the PX4-style cubic only when '
                             "its held-out RMS is at least F below the cubic's, else write the "
                             f'cubic (default: {BASELINE_MARGIN})')
    parser.add_argument('--significance', type=non_negative_float, metavar='K',
                        help=f'{when}a model other than the cubic, a higher order or an added '
                             'effect must beat the one before it fold by fold: its mean '
                             'per-fold gain at least K standard errors, and better on most '
                             f'folds (default: {DEFAULT_SIGNIFICANCE:g})')


def validation_settings(args: argparse.Namespace) -> dict:
    """Return the validation settings asked for, defaults where not given."""
    return {'validation': VALIDATION_OPTIONS[args.validation or
                                             DEFAULT_VALIDATION.replace('_', '-')],
            'min_past': DEFAULT_MIN_PAST if args.min_past is None else args.min_past,
            'baseline_margin': (BASELINE_MARGIN if args.baseline_margin is None
                                else args.baseline_margin),
            'significance': (DEFAULT_SIGNIFICANCE if args.significance is None
                             else args.significance)}


def instance_option(text: str):
    """Parse --instance: 'all' or an IMU instance number (argparse type)."""
    return 'all' if text == 'all' else non_negative_int(text)


class _Records(argparse.Action):
    """Store the records given (``records``) and the first as ``input``."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, list(values))
        namespace.input = values[0]


def add_recording_options(parser: argparse.ArgumentParser, several: bool = False) -> None:
    """
    Add the input recording argument and how to read it (CSV columns, bag topics, IMU).

    With ``several``, one or more records of one unit: ``records`` lists them
    and ``input`` is the first (`load_records` reads them all).
    """
    kinds = ('CSV file, rosbag2 bag (folder, .db3 or .mcap), PX4 ULog (.ulg) or ArduPilot '
             'DataFlash log (.bin)')
    if several:
        parser.add_argument('records', nargs='+', action=_Records, metavar='RECORD',
                            help=f'{kinds}; several records of one unit are read the same '
                                 'way and fitted as one')
    else:
        parser.add_argument('input', help=kinds)
    parser.add_argument('--instance', type=instance_option, metavar='N|all',
                        help='IMU instance of a .ulg or .bin log (default: the first usable '
                             'one; all: each usable one in turn, output names suffixed .imuN)')
    columns = parser.add_mutually_exclusive_group()
    columns.add_argument('--preset', metavar='NAME',
                         help='column map of a known data set (CSV only)')
    columns.add_argument('--columns', metavar='SPEC',
                         help='column map, canonical=column[:scale to its unit], e.g. '
                              'time=timestamp:1e-6,gyro_z=gz_dps:0.0174533 (CSV only)')
    parser.add_argument('--imu-topic', default=RAW_IMU_TOPIC, metavar='TOPIC',
                        help="Imu topic read from a bag (default: %(default)s, the driver's raw "
                             'output, which every bag the package writes holds; calibration '
                             'fits raw data)')
    parser.add_argument('--temperature-topic', default=RAW_TEMPERATURE_TOPIC, metavar='TOPIC',
                        help='Temperature topic read from a bag (default: %(default)s)')
    parser.add_argument('--supply-voltage-topic', default=RAW_SUPPLY_VOLTAGE_TOPIC,
                        metavar='TOPIC',
                        help='BatteryState topic of a bag, held per sample as the node holds '
                             'it (default: %(default)s)')
    parser.add_argument('--strict', action='store_true',
                        help='refuse a record with a column no gyro record holds (exit 2): a '
                             'gyro at rest beyond any offset, a temperature slewing faster '
                             'than a part can, a sample interval of the wrong time unit '
                             '(default: warn and go on)')


def node_name(text: str) -> str:
    """
    Parse a node name for a parameter file's section (argparse type).

    What rcl matches a section against: a node name (letters, digits and
    underscores, not starting with a digit), optionally with its namespace
    (``/robot/compensation_node``), or ``/**`` for every node.
    """
    if text == '/**' or re.fullmatch(r'(/?[A-Za-z_][A-Za-z0-9_]*)+', text):
        return text
    msg = (f'expected a ROS node name (letters, digits, underscores; /namespace/name or /**), '
           f'got {text!r}')
    raise argparse.ArgumentTypeError(msg)


def add_parameter_file_options(parser: argparse.ArgumentParser, when: str = '') -> None:
    """Add ``--out`` and ``--node-name``: the compensation node's parameter file to write."""
    parser.add_argument('--out', required=True, metavar='PARAMS.yaml',
                        help=f'parameter file to write{when} (replaced atomically)')
    parser.add_argument('--node-name', type=node_name, default='compensation_node',
                        metavar='NAME',
                        help='node section of the parameter file (default: %(default)s)')


def write_node_parameters(path: str, node_name: str, outputs, parameters: dict,
                          header: str) -> None:
    """
    Write ``parameters`` as the compensation node's parameter file ``path``, staged.

    ``node_name`` names its section (`add_parameter_file_options`);
    ``header`` becomes its comment lines, followed by the command that loads
    the file; a file that cannot be written is a UserError. The file is
    written under its staging name in ``outputs`` (`run_handler`).
    """
    header += f'\nUse: compensation_node --ros-args --params-file {path}'
    try:
        write_parameter_file(outputs.file(path), parameter_file(node_name, parameters), header)
    except OSError as err:
        msg = f'cannot write {path}: {err.strerror}'
        raise UserError(msg) from None


def write_result(path, text: str) -> None:
    """Replace the file at ``path`` with ``text`` atomically (`FILE_MODE`); OSError on failure."""
    atomic_write(path, text)


def write_json(path, document) -> None:
    """Write ``document`` as indented JSON with `write_result`."""
    write_result(path, json.dumps(document, indent=2) + '\n')


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


# Output options a command run once per IMU instance (--instance all) suffixes with .imuN.
_OUTPUT_OPTIONS = ('out', 'out_csv', 'px4_params', 'ardupilot_parm')


def _suffixed(path, index: int) -> str:
    path = Path(path)
    return str(path.with_name(f'{path.stem}.imu{index}{path.suffix}'))


def run_handler(args: argparse.Namespace) -> int:
    """
    Run the subcommand's handler with its outputs staged (``args.outputs``), all or none.

    The handler writes each output under the staging name ``args.outputs``
    gives (`outputs.Outputs`); they replace their targets together when it
    returns, and are removed when it raises (an error, Ctrl-C).
    """
    outputs = args.outputs = Outputs()
    try:
        status = args.handler(args)
    except BaseException:
        outputs.discard()
        raise
    try:
        outputs.commit()
    except OSError as err:
        msg = f'cannot write {err.filename}: {err.strerror}; no output was written'
        raise UserError(msg) from None
    return status


def run_command(args: argparse.Namespace) -> int:
    """
    Run the subcommand's handler (`run_handler`).

    With ``--instance all`` on a flight log, once per usable IMU instance,
    each output path (--out, --out-csv, --px4-params, --ardupilot-parm)
    suffixed with ``.imuN`` before its extension.
    """
    if getattr(args, 'instance', None) != 'all' or not getattr(args, 'per_instance', True):
        return run_handler(args)
    if getattr(args, 'json', False):
        msg = '--json prints one document: give one --instance, not all'
        raise UserError(msg)
    if len(getattr(args, 'records', ())) > 1:
        msg = '--instance all runs one record per IMU instance: give one record, or --instance N'
        raise UserError(msg)
    if not is_flight_log(args.input):
        msg = f'--instance applies to .ulg and .bin logs, not {args.input}'
        raise UserError(msg)
    try:
        log = read_flight_log(args.input)
        usable = [i.index for i in log.instances if not i.problem()]
        if not usable:
            log.instance()  # raises, naming each instance and its problem
    except FlightLogError as err:
        raise UserError(str(err)) from None
    for index in usable:
        print(f'== IMU instance {index}')
        each = argparse.Namespace(**vars(args))
        each.instance = index
        for name in _OUTPUT_OPTIONS:
            if getattr(each, name, None) is not None:
                setattr(each, name, _suffixed(getattr(each, name), index))
        status = run_handler(each)
        if status:
            return status
    return 0


def _check_writable_folder(folder: Path, option: str, path) -> None:
    if not folder.exists():
        msg = f'{option} {path}: folder {folder} does not exist'
        raise UserError(msg)
    if not folder.is_dir():
        msg = f'{option} {path}: {folder} is not a folder'
        raise UserError(msg)
    if not os.access(folder, os.W_OK | os.X_OK):
        msg = f'{option} {path}: folder {folder} is not writable'
        raise UserError(msg)


def check_output_file(path, option: str) -> None:
    """Raise UserError unless a file can be written at ``path`` (its folder must exist)."""
    target = Path(path)
    if target.is_dir():
        msg = f'{option} {path} is a folder; give a file name'
        raise UserError(msg)
    _check_writable_folder(target.parent, option, path)
    if target.exists() and not os.access(target, os.W_OK):
        msg = f'{option} {path} exists and is not writable'
        raise UserError(msg)


def check_output_folder(path, option: str, new: bool = False, owns=None) -> None:
    """
    Raise UserError unless files can be written into folder ``path``.

    The folder may exist (unless ``new``) or be created; its parent must exist.
    ``owns`` names the files of a folder the command replaces as a whole: an
    existing folder holding anything else is refused, not deleted.
    """
    target = Path(path)
    if target.exists():
        if new:
            msg = f'{option} {path} exists already; give a new folder'
            raise UserError(msg)
        if not target.is_dir():
            msg = f'{option} {path} is a file, not a folder'
            raise UserError(msg)
        _check_writable_folder(target, option, path)
        foreign = sorted(p.name for p in target.iterdir() if owns is not None
                         and p.name not in owns)
        if foreign:
            msg = (f'{option} {path} holds {", ".join(foreign[:3])}'
                   + (f' and {len(foreign) - 3} more' if len(foreign) > 3 else '')
                   + ', which this command does not write: the folder is replaced as a whole '
                   'when the command is done; give a new or empty folder')
            raise UserError(msg)
        return
    _check_writable_folder(target.parent, option, path)
