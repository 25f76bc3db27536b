"""
The nodes' parameters in rclpy: descriptors, declaration and the command line.

The specs, their checks and the model they build are in `node_parameters`
(no rclpy). Each parameter is declared with a descriptor made of its spec
(type, description, range, read-only for hardware settings); rclpy enforces
those. Raise `ParameterError` naming the parameter.
"""

import difflib
import re
import sys

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterUninitializedException)
from rclpy.parameter import Parameter
import yaml

from ..node_parameters import check_choices, KNOWN_NAMES, NoDefault, ParameterError, Spec


def descriptor(spec: Spec) -> ParameterDescriptor:
    """Give the descriptor of ``spec``: description with its choices, read-only, range."""
    text = spec.description
    if spec.choices:
        text += f" (one of: {', '.join(spec.choices)})"
    result = ParameterDescriptor(description=text, read_only=spec.read_only)
    if spec.low is not None:
        if spec.value_type == 'integer':
            result.integer_range = [IntegerRange(
                from_value=int(spec.low), to_value=int(spec.high), step=1)]
        elif spec.value_type == 'double':
            result.floating_point_range = [FloatingPointRange(
                from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
        else:
            raise TypeError(f'range on non-numeric parameter {spec.name}')
    return result


def _declared_default(spec: Spec):
    """Give the value rclpy declares ``spec`` with: the type alone when it has no default."""
    if isinstance(spec.default, NoDefault):
        return Parameter.Type[spec.default.value_type.upper()]
    return spec.default


def declare(node, specs) -> dict:
    """Declare ``specs`` on ``node``; return their values. Raise `ParameterError`."""
    values = {}
    for spec in specs:
        given = _as_double(spec, node._parameter_overrides.get(spec.name))
        try:
            if given is None:
                parameter = node.declare_parameter(spec.name, _declared_default(spec),
                                                   descriptor(spec))
            else:
                parameter = node.declare_parameter(spec.name, given, descriptor(spec),
                                                   ignore_override=True)
        except (InvalidParameterTypeException, InvalidParameterValueException) as err:
            msg = f'invalid parameter {spec.name}: {err}'
            raise ParameterError(msg) from None
        values[spec.name] = value_of(parameter)
    check_choices(specs, values)
    return values


def _as_double(spec: Spec, override):
    """
    Give an integer file or -p value of a double parameter as a float, else None.

    YAML reads ``publish_rate_hz: 50`` as an integer, which rclpy refuses for a
    double; ``override`` is what rclpy holds for the parameter (node._parameter_overrides,
    the only place it keeps them).
    """
    if override is None or spec.value_type not in ('double', 'double_array'):
        return None
    if override.type_ == Parameter.Type.INTEGER:
        return float(override.value)
    if override.type_ == Parameter.Type.INTEGER_ARRAY:
        return [float(v) for v in override.value]
    return None


def unknown_parameters(node) -> list:
    """Give a warning per parameter set for ``node`` that no node here has, with the closest."""
    warnings = []
    for name in sorted(node._parameter_overrides):
        if name in KNOWN_NAMES or node.has_parameter(name):
            continue
        close = difflib.get_close_matches(name, KNOWN_NAMES, n=1)
        hint = f'; did you mean {close[0]}?' if close else ''
        warnings.append(f'unknown parameter {name} ignored: no node of mlx_tempcomp has it{hint}')
    return warnings


def _plain_overrides(args) -> dict:
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


def check_command_line(node, args=None) -> None:
    """
    Raise `ParameterError` if a ``-p`` after the parameter files did not take effect.

    rcl gives a plain ``-p`` to every node (``/**``), and a section named after the
    node in a parameter file outranks ``/**`` whatever the order.
    """
    for name, text in _plain_overrides(sys.argv if args is None else args).items():
        if not node.has_parameter(name):
            continue
        wanted = yaml.safe_load(text)
        value = node.get_parameter(name).value
        if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
            value = list(value)
        if wanted is None or wanted == value:
            continue
        node_name = node.get_name()
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


def value_of(parameter):
    try:
        value = parameter.value
    except ParameterUninitializedException:
        value = None
    return [] if value is None else value
