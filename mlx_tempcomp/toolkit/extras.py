"""
The optional packages a subcommand will use, checked before it does any work.

The nodes' environment (the ``venv`` extra of setup.py, what ``make demo``
installs) lacks the plots, the Allan deviation, the flight-log readers and
the fleet job's engine; each comes with an extra (`OPTIONAL`). A subcommand
names what it will use in ``needs`` (``set_defaults(needs=...)``: a function
of its arguments giving (module, how to do without it) pairs), and the
readers its records need are added by their extension (`readers`).
`require` imports each (a real import, so a package whose own dependency is
missing, allantools without scipy, is caught too) and turns the first that
fails into one `UserError` line naming the package, what it is for and the
extra that installs it: exit code 2, never a traceback after a long run.
"""

import importlib
from pathlib import Path

from .errors import UserError
from ..recordings.flightlog import is_flight_log

# Optional package -> (what it is for, the extra of setup.py that installs it).
OPTIONAL = {
    'matplotlib': ('the plots', 'toolkit'),
    'allantools': ('the Allan deviation', 'toolkit'),
    'pyulog': ('reading PX4 ULogs', 'flightlogs'),
    'pymavlink': ('reading ArduPilot DataFlash logs', 'flightlogs'),
    'dask': ('the fleet job', 'fleet'),
    'distributed': ('the fleet job', 'fleet'),
    'fsspec': ('records given as URLs', 'fleet'),
}
# The reader of each flight-log extension (recordings/ulog.py, recordings/dataflash.py).
READERS = {'.ulg': 'pyulog', '.bin': 'pymavlink'}


def readers(paths) -> list:
    """Give (reader package, '') for each flight log among ``paths``, in order, once each."""
    needed = []
    for path in paths:
        if is_flight_log(path) and not Path(path).is_dir():
            module = READERS[Path(path).suffix.lower()]
            if (module, '') not in needed:
                needed.append((module, ''))
    return needed


def require(command: str, needs) -> None:
    """
    Import each (module, how to do without it) of ``needs``; UserError for the first missing.

    ``command`` names the subcommand in the message (e.g. 'diagnose',
    'fleet diagnose'); the way around it (e.g. 'give --no-plots') is added
    when there is one.
    """
    for module, instead in needs:
        try:
            importlib.import_module(module)
        except ImportError as err:
            purpose, extra = OPTIONAL[module]
            missing = err.name or module
            what = (f'{module} ({purpose}), which is not installed' if missing == module
                    else f'{module} ({purpose}), whose {missing} is not installed')
            msg = (f"mlx-tempcomp {command} needs {what}: pip install 'mlx_tempcomp[{extra}]'"
                   + (f', or {instead}' if instead else ''))
            raise UserError(msg) from None


def check(args) -> None:
    """Check what the parsed subcommand ``args`` will import (its ``needs`` and readers)."""
    paths = getattr(args, 'records', None) or ([args.input] if hasattr(args, 'input') else [])
    needs = readers(paths)
    if getattr(args, 'needs', None) is not None:
        needs += args.needs(args)
    command = ' '.join(part for part in (args.command, getattr(args, 'fleet_command', None))
                       if part)
    require(command, needs)
