"""
The error every ``mlx-tempcomp`` subcommand raises for a user's mistake, and its exit code.

User mistakes (a missing or malformed file, data that cannot support what was
asked) raise `UserError`; ``mlx-tempcomp`` prints it in one line starting with
``error:`` and exits with `EXIT_USER_ERROR`, never a traceback.
"""

from ..errors import MlxTempCompError

EXIT_USER_ERROR = 2


class UserError(MlxTempCompError):
    """A mistake in what the user asked for; reported in one line, exit code 2."""
