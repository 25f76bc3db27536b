"""
Field learning in the toolkit: ``mlx-tempcomp evaluate --learn`` and the model it writes.

`learning_of` reads the parameter file's ``learning.*`` (the node's section, defaults where
absent; ``learning.enabled`` is the node's switch, ``--learn`` the command's) and gives
what `tracking.offline_twin` needs to build the `LearningSettings` beside the tracker's:
the prior model's own error (its ``model_error.*`` table, if any) and, when the prior
model carries a correction table already, its knots, so that the learnt one adds to it.

`write_learned` writes the model in use at the end of the record as a parameter file in
the format ``fit`` writes (atomically, staged): the file's own node section as it was,
with ``correction.*`` the prior's table plus the learnt one. A diff against the file given
shows the learnt correction and nothing else; ``evaluate --params`` and the node run it.
"""

from .errors import UserError
from .running import write_node_parameters
from ..core.errors import TempCompError
from ..parameters.compensation import model_error_of
from ..parameters.files import learned_parameters, node_overrides
from ..parameters.learning import (largest_correction_rad_s, learning_settings, PREFIX,
                                   renewal_lines)
from ..parameters.specs import ParameterError


def learning_of(params: str, node_name: str, values: dict, model):
    """
    Give the function of the tracking settings that gives the learning settings.

    ``values`` are the node's checked values of the file ``params``; ``model`` the prior
    model built from them. A wrong ``learning.*`` value is a UserError naming it.
    """
    try:
        overrides = node_overrides(params, node_name)
        error = model_error_of(values)
    except ParameterError as err:
        raise UserError(f'{params}: {err}') from None
    given = {key: value for key, value in overrides.items() if key.startswith(PREFIX)}
    table = getattr(model, 'table', None)
    knots = None if table is None else table.temperature_c

    def settings(tracking):
        try:
            return learning_settings(given, tracking, error, knots)
        except TempCompError as err:
            raise UserError(f'{params}: {err}') from None

    return settings


def write_learned(path: str, outputs, params: str, node_name: str, source: str, model,
                  learner, axes: tuple) -> str:
    """Write the model in use as a parameter file (see the module notes); give a line to print."""
    parameters = learned_parameters(node_overrides(params, node_name),
                                    getattr(model, 'table', None), learner.accepted, axes)
    renewed = [a for a, count in zip(axes, learner.renewals) if count]
    lines = [f'Model renewed by mlx-tempcomp evaluate --learn from {source}:',
             f'the model of {params} less the learnt correction table (correction.*, rad/s, '
             'relative to it; cubic between the temperatures, held beyond)']
    lines += renewal_lines(learner, axes)
    if not renewed:
        lines.append('no renewal was accepted: the model is the one given')
    write_node_parameters(path, node_name, outputs, parameters, '\n'.join(lines))
    biggest = largest_correction_rad_s(learner)
    return (f'wrote {path} (the model in use: {", ".join(renewed) or "no axis"} renewed; '
            f'learnt correction up to {biggest:.3g} rad/s)')


def learning_lines(report: dict, axes: tuple) -> list:
    """Say what the learner did, per axis."""
    refused = ', '.join(f'{reason} {count}' for reason, count in
                        sorted(report['refused'].items())) or 'none'
    lines = [f'field learning: {report["windows"]} windows used in {report["runs"]} still runs '
             f'({report["runs_dropped"]} dropped: a shift withdrawn); refused: {refused}; '
             f'the correction taken off changed {report["swaps"]} times']
    for axis in axes:
        a = report['axes'][axis]
        renewal = a['last_renewal']
        when = '' if renewal is None else \
            f', last at {renewal[0]:.1f} s (held-out gain {renewal[1]:.2f}x)'
        peak = max((abs(v) for v in a['correction_rad_s']), default=0.0)
        lines.append(f'  {axis}: {a["renewals"]} renewals{when}; correction up to '
                     f'{peak:.3g} rad/s; {a["reason"]}')
    return lines
