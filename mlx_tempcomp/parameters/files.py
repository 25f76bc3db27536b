"""
ROS 2 parameter files: reading a node's values from one, and writing a fitted model's.

Reading: `node_values` gives every compensation-node parameter with a node's
sections of a file (``/**`` first, then the node's), type and range checked as
rcl checks them, unknown names warned of as the node does (a misspelled name
of the model refused: `command_line.file_names_check`); `flat_parameters` gives
a file's keys as rcl names them; `node_overrides` every key the sections hold,
as written; `node_model` the model the compensation node runs of a command's
(nested) parameters, the node's defaults where they say nothing;
`offset_register_model` the bias a file's polynomial gives the MPU's offset registers.

Writing: one function per model the toolkit fits builds its
``ros__parameters`` mapping: `polynomial_parameters` (bias polynomials, also
the relative correction), `linear_btc_parameters`, `effect_parameters` (the
effect model of ``diagnose``) and `chain_parameters`;
`model_error_parameters` adds the model's error by temperature to any of
them; `learned_parameters` gives a file's section renewed by field learning.
`parameter_file` wraps the mapping in the section of a node and
`write_parameter_file` writes it atomically so that ``compensation_node
--ros-args --params-file FILE`` loads it as is. Every number is a Python
float (rcl refuses an int for a double parameter) and axis names are quoted
strings (YAML 1.1 reads a bare y as a boolean).
"""

import dataclasses

import yaml

from .command_line import file_names_check
from .compensation import COMPENSATION_SPECS
from .models import build_model, correction_of
from .specs import axes_of, check_choices, check_value, ParameterError, widen_integers
from .state_file import atomic_write
from ..core.effects import EffectModel, LinearBtc
from ..core.node_models import AXIS_NAMES, ChainModel, ModelErrorTable

_WILDCARDS = ('/**', '**')


def flat_parameters(tree: dict, prefix: str = '') -> dict:
    """Turn ``{'a': {'b': v}}`` into ``{'a.b': v}``: the names rcl gives a file's keys."""
    flat = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(flat_parameters(value, name + '.'))
        else:
            flat[name] = value
    return flat


def node_model(parameters: dict):
    """Build the model the compensation node runs from a command's (nested) parameters."""
    flat = flat_parameters(parameters)
    return build_model({spec.name: flat.get(spec.name, spec.initial_value)
                        for spec in COMPENSATION_SPECS})


def _read_overrides(path: str, node_name: str) -> dict:
    """Give the flat parameters of ``node_name`` in a ROS 2 parameter file (wildcards first)."""
    try:
        with open(path, encoding='utf-8') as stream:
            document = yaml.safe_load(stream)
    except OSError as err:
        msg = f'cannot read parameter file {path}: {err.strerror}'
        raise ParameterError(msg) from None
    except (yaml.YAMLError, ValueError, RecursionError) as err:
        # ValueError: not UTF-8, or a value YAML's constructors refuse (2026-13-45, !!int a).
        mark = getattr(err, 'problem_mark', None)
        where = f' (line {mark.line + 1})' if mark is not None else ''
        problem = getattr(err, 'problem', None) or str(err).split('\n')[0] or type(err).__name__
        msg = f'parameter file {path} is not YAML{where}: {problem}'
        raise ParameterError(msg) from None
    if not isinstance(document, dict):
        msg = f'parameter file {path} is not a mapping of node sections'
        raise ParameterError(msg)
    names = [key for key in _WILDCARDS if key in document] + \
        [key for key in (node_name, '/' + node_name.lstrip('/')) if key in document]
    if not names:
        sections = ', '.join(repr(str(key)) for key in document) or 'none'
        msg = f'parameter file {path} has no section for node {node_name!r} (sections: ' \
              f'{sections}); see --node-name'
        raise ParameterError(msg)
    overrides = {}
    for name in names:
        section = document[name]
        parameters = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(parameters, dict):
            msg = f'parameter file {path}: section {name!r} has no ros__parameters mapping'
            raise ParameterError(msg)
        overrides.update(flat_parameters(parameters))
    return overrides


def node_overrides(path: str, node_name: str) -> dict:
    """
    Give the flat parameters of ``node_name`` in the file ``path`` as written (``/**`` first).

    Every key, the node's or not (``learning.*``, read by ``evaluate --learn``);
    `ParameterError` where the file cannot be read as a parameter file.
    """
    return _read_overrides(path, node_name)


def node_values(path: str, node_name: str, warn=None) -> dict:
    """
    Give every compensation-node parameter value with ``node_name``'s section of a file.

    The node's defaults, overridden by the file's ``/**`` and ``node_name`` sections,
    type and range checked as rcl checks them, then the choices. Raise `ParameterError`
    (the message starts with ``path``) where the node would refuse to start, and for
    a misspelled name of the model; ``warn`` takes a line per other unknown name
    (`file_names_check`).
    """
    overrides = _read_overrides(path, node_name)
    file_names_check(path, overrides, warn)
    values = {}
    for spec in COMPENSATION_SPECS:
        if spec.name not in overrides:
            values[spec.name] = spec.initial_value
            continue
        value = widen_integers(spec, overrides[spec.name])
        try:
            check_value(spec, value)
        except ParameterError as err:
            raise ParameterError(f'{path}: {err}') from None
        values[spec.name] = value
    try:
        check_choices(COMPENSATION_SPECS, values)
    except ParameterError as err:
        raise ParameterError(f'{path}: {err}') from None
    return values


def offset_register_model(path: str, node_name: str) -> EffectModel:
    """
    Give the bias model of ``node_name``'s polynomial in the file at ``path`` for the MPU.

    The offset registers take a polynomial bias of gyro x, y and z (``mlx-tempcomp fit``),
    without a learnt correction; its scale polynomial is left out: a register can only
    add, and at rest there is no rate to scale. `ParameterError` names
    ``mpu6000.offset_model_file`` and says what is wrong.
    """
    try:
        values = node_values(path, node_name)
        if values['model'] != 'polynomial':
            msg = (f'model {values["model"]!r}: the offset registers take a polynomial '
                   'bias (mlx-tempcomp fit --model polynomial or relative)')
            raise ParameterError(msg)
        if correction_of(values) is not None:
            msg = ('correction.* (a learnt correction table): the offset registers take the '
                   "polynomial's bias alone; run the learnt model in compensation_node (its "
                   'model less the table), or give the file the node started from')
            raise ParameterError(msg)
        if axes_of(values) != AXIS_NAMES:
            msg = f'axes {values["axes"]}: the model must cover gyro x, y and z in that order'
            raise ParameterError(msg)
        model = build_model(values)
    except ParameterError as err:
        msg = f'invalid parameter mpu6000.offset_model_file ({path}): {err}'
        raise ParameterError(msg) from None
    return dataclasses.replace(model, terms=tuple(
        dataclasses.replace(term, scale=()) for term in model.terms))


# libyaml's emitter when PyYAML has it: the same text, four times faster (a fleet writes a
# parameter file per unit).
class _QuotingDumper(getattr(yaml, 'CSafeDumper', yaml.SafeDumper)):
    """Quote every string: rcl reads a bare y or n as a boolean (YAML 1.1)."""


_QuotingDumper.add_representer(
    str, lambda dumper, value: dumper.represent_scalar('tag:yaml.org,2002:str', value,
                                                       style="'"))


def polynomial_parameters(model: EffectModel, axes) -> dict:
    """
    Return the compensation node's parameters for a ``polynomial`` model (`polynomial_model`).

    ``axes`` names the Imu axis of each of the model's bias polynomials, in
    order. Only the bias polynomials are written (the toolkit fits no
    scale): a model holding scale-factor polynomials (``polynomial.scale.*``
    of the node) or ZRO offsets (learnt by a recalibration, kept in the state
    file, not a parameter) is refused with ValueError rather than written in
    part.
    """
    axes = tuple(str(axis) for axis in axes)
    if len(axes) != model.axes or not set(axes) <= set(AXIS_NAMES) or \
            len(set(axes)) != len(axes):
        msg = (f'axes {list(axes)} must be {model.axes} distinct of '
               f'{list(AXIS_NAMES)}, one per bias polynomial')
        raise ValueError(msg)
    if model.name != 'polynomial':
        msg = f'a {model.name} model is not written as polynomial parameters'
        raise ValueError(msg)
    if any(term.scale for term in model.terms) or any(model.zro_offset_rad_s):
        msg = 'only the bias polynomials become parameters; the model has a scale or offset'
        raise ValueError(msg)
    return {
        'model': 'polynomial',
        'axes': list(axes),
        'polynomial': {
            'reference_temperature_c': float(model.reference_temperature_c),
            'temperature_scale_c': float(model.temperature_scale_c),
            'temperature_min_c': float(model.temperature_min_c),
            'temperature_max_c': float(model.temperature_max_c),
            'bias': {axis: [float(c) for c in term.bias] for axis, term in zip(axes, model.terms)},
        },
    }


def _check_axes(axes, count: int) -> tuple:
    axes = tuple(str(axis) for axis in axes)
    if len(axes) != count or not set(axes) <= set(AXIS_NAMES) or len(set(axes)) != len(axes):
        msg = f'axes {list(axes)} must be {count} distinct of {list(AXIS_NAMES)}'
        raise ValueError(msg)
    return axes


def nest_parameters(flat: dict) -> dict:
    """Turn ``{'a.b': v}`` into ``{'a': {'b': v}}``, as rcl reads parameter files."""
    tree = {}
    for key, value in flat.items():
        *parents, leaf = key.split('.')
        node = tree
        for parent in parents:
            node = node.setdefault(parent, {})
        node[leaf] = value
    return tree


def effect_parameters(model: EffectModel, axes) -> dict:
    """Return the compensation node's parameters for an effects model (ZRO offset excluded)."""
    axes = _check_axes(axes, model.axes)
    return {'model': 'effects', 'axes': list(axes),
            'effects': nest_parameters(model.to_parameters(axes))}


def learned_parameters(overrides: dict, prior_table, learnt, axes) -> dict:
    """
    Give a node section renewed by field learning: ``overrides`` with the correction table.

    ``overrides`` are the flat parameters of the file the model came from
    (`node_overrides`), kept as they were but their ``correction.*``; ``prior_table``
    the `CorrectionTable` the model carried already (None: none) and ``learnt`` the
    one the learner renewed it with, relative to it; the sum is written (none when zero).
    ``compensation_node`` and ``evaluate --learned-params`` write the same.
    """
    table = learnt if prior_table is None else prior_table.added(learnt)
    parameters = nest_parameters({key: value for key, value in overrides.items()
                                  if not key.startswith('correction.')})
    if not table.is_zero:
        parameters.update(table.to_parameters(_check_axes(axes, table.axes)))
    return parameters


def model_error_parameters(table: ModelErrorTable, axes, noise_rad_s=()) -> dict:
    """
    Return the compensation node's ``model_error`` parameters for any model.

    The table of the model's error by temperature (`ModelErrorTable`), which
    the node adds to the Imu angular velocity covariance; ``axes`` names the
    Imu axis of each of its error columns; ``noise_rad_s``, one per axis when
    given, the white noise of a sample the covariance takes beside it.
    """
    axes = _check_axes(axes, table.axes)
    noise = {'rate_noise_rad_s': [float(v) for v in noise_rad_s]} if len(noise_rad_s) else {}
    return {'model_error': {'temperature_c': [float(t) for t in table.temperature_c],
                            **{f'{axis}_rad_s': [float(v) for v in values]
                               for axis, values in zip(axes, table.error_rad_s)}, **noise}}


def linear_btc_parameters(model: EffectModel, axes) -> dict:
    """Return the compensation node's parameters for the ADIS16130 ``linear_btc`` model."""
    axes = _check_axes(axes, model.axes)
    line = LinearBtc.of(model)
    return {'model': 'linear_btc', 'axes': list(axes),
            'linear_btc': {'pbc_rad_s': [float(v) for v in line.pbc_rad_s],
                           'btc_rad_s_per_c': [float(v) for v in line.btc_rad_s_per_c],
                           't3_c': float(line.t3_c)}}


def chain_parameters(model: ChainModel) -> dict:
    """Return the compensation node's parameters for the calibration chain (axes x, y, z)."""
    flat = {key: [float(v) for v in value] if isinstance(value, (list, tuple)) else float(value)
            for key, value in model.chain.to_parameters().items()}
    return {'model': 'chain', 'axes': list(AXIS_NAMES), 'chain': nest_parameters(flat)}


def parameter_file(node_name: str, parameters: dict) -> dict:
    """Wrap ``parameters`` in the section of ``node_name`` of a ROS 2 parameter file."""
    return {node_name: {'ros__parameters': parameters}}


def write_parameter_file(path, content: dict, header: str = '') -> None:
    """
    Write a ROS 2 parameter file atomically, as state files are written (OSError on failure).

    ``header`` lines are written as YAML comments first. A crash leaves the
    old file, or none, never half a file.
    """
    comments = ''.join(f'# {line}\n' for line in header.splitlines())
    atomic_write(path, comments + yaml.dump(content, Dumper=_QuotingDumper, sort_keys=False))
