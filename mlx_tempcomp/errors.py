"""
The root of the errors mlx_tempcomp raises; it imports nothing, so every layer can use it.

Each layer has its class below the root: `core.errors.TempCompError`,
`hardware.errors.HardwareError`, `recordings.errors.RecordFileError` (CSV,
bags and flight logs), `parameters.state_file.StateFileError` and `ParameterError` (what a node
is given to start with), `toolkit.errors.UserError` (the command line). Each
is raised with a message that names what is wrong, for a person to read: the
nodes catch the root at start (one fatal line, exit code 1), ``mlx-tempcomp``
around each command (one ``error:`` line, exit code 2).
"""


class MlxTempCompError(Exception):
    """Base class of every error mlx_tempcomp raises for what it was given."""
