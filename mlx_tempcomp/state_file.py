"""
Calibration state on disk: written atomically, read back at start.

A write goes to a temporary file in the same folder, is flushed and fsynced,
then renamed over the old file (rename is atomic on POSIX), and the folder is
fsynced. A crash at any point leaves either the old or the new file, whole.
"""

import os
import tempfile

import yaml


class StateFileError(Exception):
    """The state file cannot be read or written."""


def write_state(path: str, state: dict) -> None:
    """Replace the YAML file at ``path`` with ``state``, atomically."""
    folder = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(folder, exist_ok=True)
        descriptor, temporary = tempfile.mkstemp(prefix='.' + os.path.basename(path) + '.',
                                                 suffix='.tmp', dir=folder)
    except OSError as err:
        msg = f'cannot write state file {path}: {err.strerror}'
        raise StateFileError(msg) from None
    try:
        with os.fdopen(descriptor, 'w') as state_file:
            yaml.safe_dump(state, state_file, sort_keys=False)
            state_file.flush()
            os.fsync(state_file.fileno())
        os.replace(temporary, path)
        folder_descriptor = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(folder_descriptor)
        finally:
            os.close(folder_descriptor)
    except OSError as err:
        if os.path.exists(temporary):
            os.unlink(temporary)
        msg = f'cannot write state file {path}: {err.strerror}'
        raise StateFileError(msg) from None


def read_state(path: str):
    """Return the state dict at ``path``, or None when there is no file yet."""
    try:
        with open(path) as state_file:
            state = yaml.safe_load(state_file)
    except FileNotFoundError:
        return None
    except OSError as err:
        msg = f'cannot read state file {path}: {err.strerror}'
        raise StateFileError(msg) from None
    except yaml.YAMLError as err:
        msg = f'state file {path} is not valid YAML: {err}'
        raise StateFileError(msg) from None
    if not isinstance(state, dict):
        msg = f'state file {path} does not hold a mapping'
        raise StateFileError(msg)
    return state
