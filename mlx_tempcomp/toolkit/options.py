"""
The options the ``mlx-tempcomp`` subcommands share: argparse types and option groups.

The number types refuse what is not finite or out of range in argparse's own
message; `add_recording_options` adds a record and how to read it (CSV columns,
bag topics, the IMU of a flight log), `add_validation_options` the held-out
scheme and its guard (`validation_settings` reads them back), and
`add_parameter_file_options` the parameter file a command writes.
"""

import argparse
import math
import re

from ..core.fitting import (BASELINE_MARGIN, DEFAULT_MIN_PAST, DEFAULT_SIGNIFICANCE,
                            DEFAULT_VALIDATION, SCHEMES)

# The topics a bag is read from by default: the driver's raw output, what `simulate` and
# `convert` write and every driver publishes (the compensated imu/data is the node's output).
RAW_IMU_TOPIC = '/imu/data_raw'
RAW_TEMPERATURE_TOPIC = '/imu/temperature_raw'
RAW_SUPPLY_VOLTAGE_TOPIC = '/imu/supply_voltage'


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
