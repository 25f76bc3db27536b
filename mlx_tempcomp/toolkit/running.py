"""
How a subcommand runs: its outputs checked before the work, written whole or not at all.

Output paths are checked before the work (`check_output_file`,
`check_output_folder`), so a typo'd folder fails at once, not after a long
fit. Every output is staged and put in place when the command is done
(`run_handler`, `outputs.Outputs`): an interrupted or failed run leaves the
previous outputs, or none, never part of them. `run_command` runs a command
once per IMU instance of a flight log with ``--instance all``.
"""

import argparse
import json
import os
from pathlib import Path

from .errors import UserError
from .outputs import Outputs
from ..parameters.files import parameter_file, write_parameter_file
from ..parameters.state_file import atomic_write
from ..recordings.flightlog import FlightLogError, is_flight_log, read_flight_log


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
    """Replace the file at ``path`` with ``text`` atomically (mode 0644); OSError on failure."""
    atomic_write(path, text, 0o644)


def write_json(path, document) -> None:
    """Write ``document`` as indented JSON with `write_result`."""
    write_result(path, json.dumps(document, indent=2) + '\n')


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
