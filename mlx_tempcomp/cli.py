"""
The ``mlx-tempcomp`` command line: the subcommands of `mlx_tempcomp.toolkit`, one module each.

Plus ``fleet`` (`mlx_tempcomp.fleet.command`): those commands over every unit of a fleet.

User mistakes (a missing or malformed file, an unknown VERSION, data that
cannot support the fit asked for) print one line starting with ``error:``
and exit with code 2, never a traceback.
"""

import argparse
import os
import sys

from .errors import MlxTempCompError
from .fleet import command as fleet
from .toolkit import (adis_bias, allan, convert, diagnose, eeprom, evaluate, extras, fit,
                      inject_motion, inspection, simulate)
from .toolkit.errors import EXIT_USER_ERROR
from .toolkit.running import run_command

# Each adds its subcommand with add_parser(commands), in this order in --help.
_COMMAND_MODULES = (inspection, eeprom, fit, allan, adis_bias, convert, diagnose, evaluate,
                    simulate, inject_motion, fleet)

# 128 + SIGPIPE, what a shell reports for a command killed by a broken pipe.
EXIT_BROKEN_PIPE = 141
# 128 + SIGINT, what a shell reports for a command stopped by Ctrl-C.
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='mlx-tempcomp',
        description='MLX90609 temperature compensation toolkit.')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for module in _COMMAND_MODULES:
        module.add_parser(commands)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        extras.check(args)
        return run_command(args)
    except MlxTempCompError as err:
        print(f'error: {err}', file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        # Outputs are staged (toolkit/outputs.py): nothing of this run was put in place.
        print('interrupted: no output of this run was written', file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader went away (e.g. `| head`): stop quietly, as Unix tools do.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


if __name__ == '__main__':
    sys.exit(main())
