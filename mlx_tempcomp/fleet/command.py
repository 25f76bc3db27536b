"""
``mlx-tempcomp fleet diagnose|fit|report``: the command line of the fleet job.

``diagnose`` and ``fit`` run the single-record command on every unit of a
manifest or records pattern (`run.run_fleet`; ``diagnose`` over all of a
unit's records at once, ``fit`` per record), then write the fleet report;
``report`` writes it again from what ``OUT`` holds. The options of the
single-record command come in ``--options`` and are checked once, here,
before any work is sent.
"""

import argparse
from pathlib import Path
import shlex
import sys

from .connection import TlsOptions
from .manifest import find_records, is_url, read_manifest
from .prior import write_fleet_prior
from .report import write_fleet_report
from .unit import (command_argv, COMMANDS, parse_command, SEVERAL_RECORDS, UnitError,
                   UnitJob)
from ..recordings.columns import column_preset, parse_column_map
from ..recordings.recording import RecordingError
from ..toolkit.errors import UserError
from ..toolkit.extras import readers, require
from ..toolkit.options import non_negative_int
from ..toolkit.progress import add_progress_option
from ..toolkit.running import check_output_folder

# What a shell reports for a command stopped by Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130
EXIT_UNITS_FAILED = 1


def add_parser(commands) -> None:
    """Add the ``fleet`` subcommand and its ``diagnose``, ``fit`` and ``report``."""
    fleet = commands.add_parser(
        'fleet', help='diagnose or fit every unit of a fleet on a Dask cluster, and compare',
        description='Run diagnose or fit on every unit of a manifest or records pattern, '
                    'each unit a Dask task (a local cluster, or --scheduler), into '
                    'OUT/units/<unit>/, then write the fleet report OUT/fleet.md, '
                    'OUT/fleet.json and its plots. See docs/fleet.md.')
    actions = fleet.add_subparsers(dest='fleet_command', required=True, metavar='ACTION')
    for name in COMMANDS:
        action = actions.add_parser(
            name, help=f'run mlx-tempcomp {name} on every unit',
            description=(f'Run mlx-tempcomp {name} on every unit, one Dask task per unit: '
                         + ('all records of a unit at once (one model, as diagnose A B does)'
                            if name in SEVERAL_RECORDS else 'once per record')
                         + '; a rerun skips the finished units.'))
        records = action.add_mutually_exclusive_group(required=True)
        records.add_argument('--manifest', metavar='CSV',
                             help='CSV with columns unit,path and optional preset, columns, '
                                  'imu_topic, temperature_topic; one row per record')
        records.add_argument('--records', metavar='PATTERN',
                             help='records whose path gives the unit, e.g. '
                                  "'bags/{unit}/*.mcap' (local paths or fsspec URLs)")
        action.add_argument('--out', required=True, metavar='OUT',
                            help='folder of the results (created; reused by a rerun)')
        action.add_argument('--options', default='', metavar='ARGS',
                            help=f'options of mlx-tempcomp {name} for every unit, one '
                                 "string, e.g. --options='--folds 4'")
        action.add_argument('--scheduler', metavar='ADDRESS',
                            help='Dask scheduler to run on, e.g. tcp://host:8786 (default: '
                                 '$DASK_SCHEDULER_ADDRESS, else a local cluster); '
                                 'tls://host:port for one that requires TLS')
        add_tls_options(action)
        action.add_argument('--workers', type=non_negative_int, metavar='N',
                            help='worker processes of the local cluster (default: one per '
                                 'core)')
        action.add_argument('--force', action='store_true',
                            help='run finished units again')
        add_progress_option(action)
        action.set_defaults(handler=fleet_command, needs=_needs)
    report = actions.add_parser('report', help='write the fleet report from OUT',
                                description='Write OUT/fleet.md, OUT/fleet.json and the '
                                            'fleet plots from the units in OUT/units/.')
    report.add_argument('--out', required=True, metavar='OUT',
                        help='folder a fleet diagnose or fit wrote')
    report.set_defaults(handler=report_command, needs=_needs)


def add_tls_options(action) -> None:
    """Add the client's TLS files, named as the ``dask`` command line names them."""
    tls = action.add_argument_group(
        'TLS', "the certificates a tls:// scheduler wants (default: Dask's configuration, "
        'distributed.comm.tls.ca-file, .client.cert and .client.key); see docs/fleet.md')
    tls.add_argument('--tls-ca-file', metavar='PEM',
                     help="the CA that signed the scheduler's and workers' certificates")
    tls.add_argument('--tls-cert', metavar='PEM', help="this client's certificate")
    tls.add_argument('--tls-key', metavar='PEM',
                     help="its private key (unless the certificate's file holds it)")


def _needs(args: argparse.Namespace) -> list:
    """
    Give the optional packages the fleet command imports on this machine (extras.require).

    Dask's scheduler and workers, and matplotlib for the fleet report's plot
    (and diagnose's); what the records need is checked once they are known.
    """
    engine = [] if args.fleet_command == 'report' else [('dask', ''), ('distributed', '')]
    return engine + [('matplotlib', '')]


def _options(command: str, text: str) -> tuple:
    """Split --options and check them on the single-record command's own parser."""
    try:
        options = tuple(shlex.split(text))
    except ValueError as err:
        msg = f'--options {text!r}: {err}'
        raise UserError(msg) from None
    if {'--out', '--progress'} & {option.split('=')[0] for option in options}:
        raise UserError('--options: --out and --progress belong to the fleet command')
    try:
        parse_command(command_argv(command, ['RECORD'], 'OUT', [], options))
    except UnitError as err:
        msg = f'--options {text!r}: {err}'
        raise UserError(msg) from None
    return options


def _check_read_options(units: list) -> None:
    """Refuse a record's column map or preset before any unit is sent (UserError)."""
    for unit in units:
        for record in unit.records:
            try:
                if record.columns is not None and record.preset is not None:
                    raise RecordingError('give a column map or a preset, not both')
                if record.columns is not None:
                    parse_column_map(record.columns)
                if record.preset is not None:
                    column_preset(record.preset)
            except RecordingError as err:
                msg = f'unit {unit.unit}, {record.path}: {err}'
                raise UserError(msg) from None


def fleet_command(args: argparse.Namespace) -> int:
    """Run ``fleet diagnose`` or ``fleet fit``, then write the fleet report."""
    from .run import run_fleet
    command = args.fleet_command
    options = _options(command, args.options)
    check_output_folder(args.out, '--out')
    fetched = [('fsspec', '')]
    if args.records is not None and is_url(args.records):
        require(f'fleet {command}', fetched)
    units = read_manifest(args.manifest) if args.manifest else find_records(args.records)
    paths = [record.path for unit in units for record in unit.records]
    require(f'fleet {command}',
            readers(paths) + (fetched if any(is_url(path) for path in paths) else []))
    _check_read_options(units)
    folder = Path(args.out).resolve() / 'units'
    jobs = [UnitJob(command, unit, options, str(folder / unit.unit)) for unit in units]
    outcome = run_fleet(jobs, scheduler=args.scheduler, workers=args.workers,
                        force=args.force, progress=True if args.progress else None,
                        tls=TlsOptions(args.tls_ca_file, args.tls_cert, args.tls_key))
    print(f'fleet {command}: {len(jobs)} units: {len(outcome.done)} done, '
          f'{len(outcome.skipped)} finished before (skipped), {len(outcome.failed)} failed'
          + (', the rest interrupted: rerun the same command to resume'
             if outcome.interrupted else ''))
    for unit, error in outcome.failed:
        print(f'failed: {unit}: {error}', file=sys.stderr)
    _report(Path(args.out))
    if outcome.interrupted:
        return EXIT_INTERRUPTED
    return EXIT_UNITS_FAILED if outcome.failed else 0


def _report(out: Path) -> None:
    """Write the fleet report and prior into ``out``; UserError without units/ or on failure."""
    if not (out / 'units').is_dir():
        msg = f'--out {out}: no units/ folder; run mlx-tempcomp fleet diagnose or fit first'
        raise UserError(msg)
    try:
        print(f'wrote {write_fleet_report(out)}')
        for line in write_fleet_prior(out):
            print(line)
    except OSError as err:
        msg = f'cannot write the fleet report into {out}: {err.strerror}'
        raise UserError(msg) from None


def report_command(args: argparse.Namespace) -> int:
    """Write the fleet report and prior again from what ``--out`` holds."""
    _report(Path(args.out))
    return 0
