"""
The nodes' ROS command line without rclpy: unknown names, a ``-p`` that lost, rcl's errors.

`ros/declare.py` applies these to a running node: `unknown_parameter_warnings`
to the names set for it that it does not have, `plain_overrides` and
`check_override` to the ``-p`` given after the parameter files, and
`explain_parse_error` to rcl's error on a parameter file it cannot parse.
"""

import difflib
import re

import yaml

from .compensation import COMPENSATION_SPECS
from .driver import DRIVER_SPECS
from .specs import ParameterError

# Every parameter of the package's nodes: a /** section gives both nodes all of them.
KNOWN_NAMES = frozenset(spec.name for spec in DRIVER_SPECS + COMPENSATION_SPECS)


def unknown_parameter_warnings(names) -> list:
    """Give a warning per name that no node of the package has, with the closest known name."""
    warnings = []
    for name in names:
        if name in KNOWN_NAMES:
            continue
        close = difflib.get_close_matches(name, KNOWN_NAMES, n=1)
        hint = f'; did you mean {close[0]}?' if close else ''
        warnings.append(f'unknown parameter {name} ignored: no node of mlx_tempcomp has it{hint}')
    return warnings


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
