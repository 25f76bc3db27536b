"""
Where the nodes keep their state by default: under ROS_HOME, one file per node.

`ros_home` is where ROS 2 tools keep theirs (``$ROS_HOME``, else ``~/.ros``).
`default_state_path` keys a node's file by its fully qualified name, so two
nodes in two namespaces (two gyros on one robot) keep two files:
``/left/compensation_node`` keeps ``$ROS_HOME/mlx_tempcomp/left/compensation_node_zro.yaml``.
`state_path` gives the path a node uses and takes over, once, a file an earlier
release kept at its old default (``~/.ros/mlx_tempcomp/<node name><suffix>``,
whatever the namespace and ROS_HOME).
"""

import os
import shutil
from typing import Callable

# Under ROS_HOME, the package's folder.
FOLDER = 'mlx_tempcomp'


def ros_home() -> str:
    """Give ``$ROS_HOME``, else ``~/.ros``, as ROS 2 tools take it."""
    return os.path.expanduser(os.environ.get('ROS_HOME') or os.path.join('~', '.ros'))


def _old_home() -> str:
    return os.path.expanduser(os.path.join('~', '.ros'))


def default_state_path(fully_qualified_name: str, suffix: str) -> str:
    """Give ``$ROS_HOME/mlx_tempcomp/<namespace>/<name><suffix>`` of a node."""
    parts = [part for part in fully_qualified_name.split('/') if part]
    return os.path.join(ros_home(), FOLDER, *parts[:-1], parts[-1] + suffix)


def old_default_path(node_name: str, suffix: str) -> str:
    """Give the default of releases before ROS_HOME and the namespace keyed it."""
    return os.path.join(_old_home(), FOLDER, node_name + suffix)


def _move(old: str, new: str) -> None:
    """Move ``old`` to ``new``, never over a file there; FileExistsError if one is."""
    os.makedirs(os.path.dirname(new), exist_ok=True)
    try:
        os.link(old, new)
    except OSError as err:
        if isinstance(err, (FileExistsError, FileNotFoundError)):
            raise
        # Another file system: a copy under a temporary name, linked to its name.
        temporary = f'{new}.{os.getpid()}.tmp'
        shutil.copy2(old, temporary)
        try:
            os.link(temporary, new)
        finally:
            os.unlink(temporary)
    os.unlink(old)


def take_over(old: str, new: str) -> str:
    """
    Move a state file at its ``old`` default to ``new`` once; give the log line ('' if none).

    Nothing happens when ``new`` exists (the node has its own) or ``old`` does not.
    The file moves only within the ROS home of the old default (ROS_HOME unset or
    ``~/.ros``): with another ROS_HOME, the line says where the file is, and leaves it.
    """
    if os.path.abspath(old) == os.path.abspath(new) or os.path.lexists(new) or \
            not os.path.isfile(old):
        return ''
    if os.path.abspath(ros_home()) != os.path.abspath(_old_home()):
        return (f'a state file of an earlier release is at {old}; this node keeps its state in '
                f'{new} (ROS_HOME): move it there to keep it (mv {old} {new})')
    try:
        _move(old, new)
    except FileNotFoundError:
        return ''   # another node took it over first
    except OSError as err:
        return f'cannot take over the state file at {old} to {new}: {err.strerror or err}'
    return (f'took over the state file at the old default {old}: now {new} (the default is '
            "keyed by ROS_HOME and the node's namespace and name)")


def state_path(given: str, fully_qualified_name: str, suffix: str,
               log: Callable[[str], None]) -> str:
    """
    Give the state file a node uses: ``given`` (a parameter), else its default.

    For the default, a file at the old default is taken over first (`take_over`),
    its one line given to ``log``.
    """
    if given:
        return os.path.expanduser(given)
    path = default_state_path(fully_qualified_name, suffix)
    name = [part for part in fully_qualified_name.split('/') if part][-1]
    line = take_over(old_default_path(name, suffix), path)
    if line:
        log(line)
    return path
