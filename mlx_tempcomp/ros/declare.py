"""
The nodes' parameters in rclpy: descriptors, declaration, and the command-line checks.

The specs, their checks and the model they build are in `parameters` (no
rclpy), and so are the command-line checks on plain values
(`parameters.command_line`); this is the glue that applies them to a node.
Each parameter is declared with a descriptor made of its spec (type,
description, range, read-only for hardware settings); rclpy enforces those.
An integer given for a double parameter is taken as the float, from a file, a
``-p`` or a set_parameters call at run time (`declare`). Raise `ParameterError`
naming the parameter.
"""

import sys

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterUninitializedException)
from rclpy.parameter import Parameter

from ..parameters.command_line import check_override, plain_overrides, unknown_parameter_warnings
from ..parameters.specs import check_choices, NoDefault, ParameterError, Spec


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
    """
    Declare ``specs`` on ``node``; return their values. Raise `ParameterError`.

    An integer for a double parameter is taken as the float: given at start (a file,
    a ``-p``), and set at run time (``ros2 param set /node window_s 5``, which rclpy
    would refuse as an INTEGER for a DOUBLE), by a callback run before the node's own.
    """
    by_name = {spec.name: spec for spec in specs}
    node.add_pre_set_parameters_callback(
        lambda parameters: [_widened(by_name.get(p.name), p) for p in parameters])
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
    Give an integer value (a Parameter) of a double parameter as a float, else None.

    YAML reads ``publish_rate_hz: 50`` as an integer, which rclpy refuses for a
    double; ``override`` is what rclpy holds for the parameter (node._parameter_overrides,
    the only place it keeps them), or a Parameter being set.
    """
    if override is None or spec is None or spec.value_type not in ('double', 'double_array'):
        return None
    if override.type_ == Parameter.Type.INTEGER:
        return float(override.value)
    if override.type_ == Parameter.Type.INTEGER_ARRAY:
        return [float(v) for v in override.value]
    return None


def _widened(spec: Spec, parameter: Parameter) -> Parameter:
    """Give ``parameter`` being set, an integer for a double ``spec`` made its float."""
    value = _as_double(spec, parameter)
    return parameter if value is None else Parameter(parameter.name, value=value)


def unknown_parameters(node) -> list:
    """Give a warning per parameter set for ``node`` that no node here has, with the closest."""
    return unknown_parameter_warnings(name for name in sorted(node._parameter_overrides)
                                      if not node.has_parameter(name))


def check_command_line(node, args=None) -> None:
    """Raise `ParameterError` if a ``-p`` after the parameter files did not take effect."""
    for name, text in plain_overrides(sys.argv if args is None else args).items():
        if node.has_parameter(name):
            check_override(name, text, node.get_parameter(name).value, node.get_name())


def value_of(parameter):
    try:
        value = parameter.value
    except ParameterUninitializedException:
        value = None
    return [] if value is None else value
