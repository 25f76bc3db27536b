"""
The nodes' ROS command line without rclpy: unknown names, a ``-p`` that lost, rcl's errors.

`ros/declare.py` applies these to a running node: `unknown_parameter_warnings`
to the names set for it that it does not have, `plain_overrides` and
`check_override` to the ``-p`` given after the parameter files, and
`explain_parse_error` to rcl's error on a parameter file it cannot parse.
`parameters.files.node_values` applies the first to a file the toolkit reads
(`file_names_check`), where a misspelled name the model is built from is an
error: the toolkit would judge another model than the file meant.
"""

import difflib
import re

import yaml

from .compensation import COMPENSATION_SPECS
from .driver import DRIVER_SPECS
from .models import MODEL_PREFIXES
from .specs import ParameterError

# Every parameter of the package's nodes: a /** section gives both nodes all of them.
KNOWN_NAMES = frozenset(spec.name for spec in DRIVER_SPECS + COMPENSATION_SPECS)
# What rclpy declares on every node, and per topic: a file may set them for any node.
ROS_NAMES = frozenset(('use_sim_time', 'start_type_description_service'))
ROS_PREFIXES = ('qos_overrides.',)
# What the compensation model is built from.
MODEL_NAMES = frozenset(('model', 'axes'))
MODEL_NAME_PREFIXES = MODEL_PREFIXES + ('sensor.',)


def _closest(name: str) -> str:
    """Give the known name closest to ``name``, or ''."""
    close = difflib.get_close_matches(name, KNOWN_NAMES, n=1)
    return close[0] if close else ''


def _did_you_mean(name: str) -> str:
    close = _closest(name)
    return f'; did you mean {close}?' if close else ''


def unknown_parameter_warnings(names) -> list:
    """Give a warning per name that no node of the package has, with the closest known name."""
    return [f'unknown parameter {name} ignored: no node of mlx_tempcomp has it'
            f'{_did_you_mean(name)}' for name in names if name not in KNOWN_NAMES]


def _model_name(name: str) -> bool:
    return name in MODEL_NAMES or name.startswith(MODEL_NAME_PREFIXES)


def file_names_check(path: str, names, warn=None) -> None:
    """
    Check the names a parameter file sets, as the node would: warn of the unknown ones.

    ``warn`` takes each warning line (``path: unknown parameter ... did you mean
    ...?``); rclpy's own names (``use_sim_time``, ``qos_overrides.*``) are known. An
    unknown name that is, or is closest to, one the model is built from
    (``modle``, ``polynomial.bias.zz``) raises `ParameterError`: the node would run
    another model than the file means.
    """
    unknown = sorted(name for name in names if name not in KNOWN_NAMES
                     and name not in ROS_NAMES and not name.startswith(ROS_PREFIXES))
    for name in unknown:
        if _model_name(name) or _model_name(_closest(name)):
            msg = (f'{path}: unknown parameter {name}: no node of mlx_tempcomp has it, and the '
                   f'model would be built without it{_did_you_mean(name)}')
            raise ParameterError(msg)
    for line in unknown_parameter_warnings(unknown) if warn is not None else ():
        warn(f'{path}: {line}')


def plain_overrides(args) -> dict:
    """
    Give {name: value text} of the ``-p name:=value`` after the last ``--params-file``.

    Those are meant to win; a node-qualified ``-p node:name:=value`` always does.
    """
    overrides, ros_args, expect = {}, False, None
    for token in args:
        if expect == 'param':
            name, assign, text = token.partition(':=')
            if assign and ':' not in name:
                overrides[name] = text
        elif expect == 'file':
            overrides.clear()
        expect = None
        if token == '--ros-args':
            ros_args = True
        elif token == '--':
            ros_args = False
        elif ros_args and token in ('-p', '--param'):
            expect = 'param'
        elif ros_args and token == '--params-file':
            expect = 'file'
    return overrides


def check_override(name: str, text: str, value, node_name: str) -> None:
    """
    Raise `ParameterError` if ``-p name:=text`` did not give the node's ``value``.

    rcl gives a plain ``-p`` to every node (``/**``), and a section named after the
    node in a parameter file outranks ``/**`` whatever the order.
    """
    wanted = yaml.safe_load(text)
    if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
        value = list(value)
    if wanted is None or wanted == value:
        return
    msg = (f'-p {name}:={text} did not take effect ({name} is {value!r}): a '
           f"'{node_name}:' section of a parameter file outranks a plain -p; give "
           f'-p {node_name}:{name}:={text}, or set it in a file after that one')
    raise ParameterError(msg)


def explain_parse_error(text: str) -> str:
    """Make rcl's parameter-file error one line, with what to do for the usual slips."""
    text = ' '.join(re.sub(r', at \S+:\d+', '', text).split())
    if "Value type 'bool'" in text:
        text += ('; YAML reads a bare y, n, yes, no, on or off as a boolean: quote it, '
                 "e.g. axes: ['x', 'y', 'z']")
    elif re.search(r"Sequence should be of same type. Value type '(double|integer)'", text):
        text += '; write every number of a list alike, e.g. [1.0, 2.0]'
    return text
