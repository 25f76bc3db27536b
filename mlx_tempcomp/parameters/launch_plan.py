"""
What ``launch/mlx_tempcomp.launch.py`` starts, from its arguments' text; no ``launch`` needed.

`launch_plan` turns the three launch arguments into the nodes to start, their
namespace and their parameter files, in order:

- ``params_file``: one file or several, comma-separated, each later file over
  the earlier ones (``config.yaml,fitted.yaml``: the shipped config, then
  the file ``mlx-tempcomp`` wrote). A file that is missing is an error:
  launch_ros would skip it with a warning and start the node without it.
- ``namespace``: the nodes' namespace, relative to one pushed by an including
  launch file (``PushRosNamespace``), or absolute. rcl matches a parameter
  file's section to a node by its full name, and reads a section named
  ``compensation_node`` as ``/compensation_node``: in a namespace it would
  miss the node without a word, and the node would run its defaults. So a
  file with such a relative section is given to the nodes as a copy whose
  relative sections are resolved in the namespace, as relative topic names
  are (``/left/compensation_node``), the rest of its text unchanged; ``/**``
  sections stay as they are. Each copy is one line of `LaunchPlan.notes`.
- ``single_process``: ``true`` starts ``bringup`` (both nodes in one process,
  the raw messages handed over in memory) instead of the two executables.
"""

from dataclasses import dataclass
import os
from pathlib import Path
import re
import tempfile

import yaml

from .specs import ParameterError

TWO_PROCESSES = (('driver_node', 'driver_node'), ('compensation_node', 'compensation_node'))
# bringup names its two nodes itself: a name given to the process would rename both.
ONE_PROCESS = (('bringup', None),)
# launch's own reading of a boolean argument (launch.conditions.IfCondition).
_BOOLEANS = {'true': True, '1': True, 'false': False, '0': False}
_NAME_TOKEN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')


@dataclass(frozen=True)
class LaunchedNode:
    """One process to start: its executable and node name (None: the executable's own)."""

    executable: str
    name: object = None


@dataclass(frozen=True)
class LaunchPlan:
    """The processes, their absolute namespace ('/' for none), files in order, lines to log."""

    nodes: tuple
    namespace: str
    params_files: tuple
    notes: tuple = ()


def split_params_files(text: str) -> tuple:
    """Give the files of a ``params_file`` argument: comma-separated, in order."""
    text = text.strip()
    if text.startswith('[') and text.endswith(']'):   # params_file:="[a.yaml, b.yaml]"
        text = text[1:-1]
    files = tuple(part.strip().strip('\'"') for part in text.split(','))
    if not any(files) or not all(files):
        msg = (f'params_file {text!r}: give one parameter file or several separated by '
               'commas, e.g. params_file:=mlx_tempcomp.yaml,fitted.yaml')
        raise ParameterError(msg)
    return files


def parse_bool(text: str, argument: str) -> bool:
    """Read a launch argument as launch reads a condition: true, false, 1 or 0."""
    try:
        return _BOOLEANS[text.strip().lower()]
    except KeyError:
        msg = f'{argument} {text!r}: give true or false'
        raise ParameterError(msg) from None


def full_namespace(namespace: str, pushed: str = None) -> str:
    """Give the absolute namespace of ``namespace`` below ``pushed`` ('/' for none)."""
    given = namespace.strip()
    if not given.startswith('/') and pushed:
        given = f'{pushed.rstrip("/")}/{given}'
    tokens = [token for token in given.split('/') if token]
    bad = [token for token in tokens if not _NAME_TOKEN.fullmatch(token)]
    if bad or '//' in given.strip('/'):
        msg = (f'namespace {namespace!r}: a ROS namespace is names of letters, digits and '
               'underscores, none starting with a digit, separated by single slashes')
        raise ParameterError(msg)
    return '/' + '/'.join(tokens)


def _sections(path: str, text: str) -> list:
    """Give the top-level key nodes of a parameter file's text (ParameterError if none)."""
    try:
        document = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = f' (line {mark.line + 1})' if mark is not None else ''
        msg = f'params_file {path} is not YAML{where}: {getattr(err, "problem", err)}'
        raise ParameterError(msg) from None
    if not isinstance(document, yaml.MappingNode) or not document.value:
        msg = f'params_file {path} is not a ROS 2 parameter file (a mapping of node sections)'
        raise ParameterError(msg)
    return [key for key, _ in document.value]


def _resolved(path: str, namespace: str, make_folder) -> tuple:
    """Give (the file to pass, absolute; a line to log or None) for one file in ``namespace``."""
    path = os.path.abspath(path)
    try:
        text = Path(path).read_text(encoding='utf-8')
    except OSError as err:
        msg = f'params_file {path}: {err.strerror or err}'
        raise ParameterError(msg) from None
    keys = _sections(path, text)
    relative = [key for key in keys if isinstance(key, yaml.ScalarNode)
                and not key.value.startswith('/') and '*' not in key.value]
    if namespace == '/' or not relative:
        return path, None
    # Each relative key's own text replaced, from the end so earlier positions hold.
    for key in sorted(relative, key=lambda k: k.start_mark.index, reverse=True):
        name = f'{namespace}/{key.value}'
        text = text[:key.start_mark.index] + f"'{name}'" + text[key.end_mark.index:]
    copy = Path(make_folder()) / Path(path).name
    copy.write_text(text, encoding='utf-8')
    names = ', '.join(f'{key.value} -> {namespace}/{key.value}' for key in relative)
    return str(copy), f'{path}: sections resolved in namespace {namespace} ({names}): {copy}'


def launch_plan(params_files: str, namespace: str = '', single_process: str = 'false',
                pushed_namespace: str = None, folder: str = None) -> LaunchPlan:
    """
    Give what the launch file starts for its arguments' text (see the module).

    Copies of files with relative sections go into ``folder`` (a new temporary
    folder when None). Raise ParameterError, naming the argument, on a bad one.
    """
    single = parse_bool(single_process, 'single_process')
    absolute = full_namespace(namespace, pushed_namespace)
    made = []

    def make_folder() -> str:
        if not made:
            made.append(folder or tempfile.mkdtemp(prefix='mlx_tempcomp_launch_'))
            os.makedirs(made[0], exist_ok=True)
        return made[0]

    files, notes = [], []
    for index, path in enumerate(split_params_files(params_files)):
        given, note = _resolved(path, absolute, lambda: _subfolder(make_folder(), index))
        files.append(given)
        notes += [note] if note else []
    nodes = tuple(LaunchedNode(*node) for node in (ONE_PROCESS if single else TWO_PROCESSES))
    return LaunchPlan(nodes, absolute, tuple(files), tuple(notes))


def _subfolder(folder: str, index: int) -> str:
    """Give a folder of its own for the ``index``-th file (two files may share a name)."""
    path = os.path.join(folder, str(index))
    os.makedirs(path, exist_ok=True)
    return path
