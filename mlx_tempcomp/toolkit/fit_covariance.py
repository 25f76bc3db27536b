"""
What ``mlx-tempcomp fit`` says of the model it writes on held-out blocks, and its covariance.

`fit` has no test part: it judges the model on blocks of the record it was
not fitted on. `held_out_judgement` refits the same model (the whole fit,
order choice and all) on the training blocks of each fold of two schemes,
the deciding one (``--validation``) and the one beside (forward, or purged
beside forward: one of the two is always forward, the model run later in
time than it was fitted), and runs it on the held-out blocks as the node
runs it (clamped at its training range). From the residuals:

- the headline: the gain over PX4's cubic clamped at its range, refitted on
  the same folds (its RMS over the model's, on the forward blocks), and the
  error in rad/s, deg/s and deg/h;
- the ``model_error`` parameters the node's covariance takes
  (`core.node_models.model_error`): the white noise of a sample per axis, and per
  temperature bin the larger bias part of the two schemes' residuals (rows
  inside their fold's training range), the noise share taken out;
- that covariance judged on the forward blocks: each block's error over the
  standard deviation a table built without that block's residuals publishes,
  RMS per sample and of 60 s means (`core.node_models.model_error.normalised_error`),
  so no block judges a table it made.
"""

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from .errors import UserError
from .tracking import model_residual
from .uncertainty import gain_words
from ..core.errors import CalibrationError, TempCompError
from ..core.fitting import (block_bounds, error_by_temperature, fit_cubic, FORWARD, PURGED, split,
                            temperature_bin_edges)
from ..core.node_models import larger_table, normalised_error, NormalisedError, sample_noise_rad_s
from ..parameters.files import model_error_parameters

ERROR_BINS = 8


@dataclass(frozen=True)
class _Scheme:
    """One scheme's held-out rows: residual of the model and of the cubic, rows counted."""

    name: str
    rows: np.ndarray
    residual: np.ndarray
    cubic: np.ndarray
    counted: np.ndarray
    block: np.ndarray


@dataclass(frozen=True)
class HeldOutJudgement:
    """The model on held-out blocks: its ``model_error`` parameters and the printed lines."""

    parameters: dict
    lines: tuple
    normalised: Optional[NormalisedError] = None


def _held_out(recording, refit, scheme: str, blocks: int, folds: int, min_past: float,
              axes: tuple) -> Optional[_Scheme]:
    """Refit on each fold's training blocks; give the held-out rows' residuals (None: none)."""
    dealt = split(blocks, scheme, folds, min_past)
    bounds = block_bounds(len(recording), blocks)
    block_of_row = np.repeat(np.arange(blocks), np.diff(bounds))
    columns = [recording.axes.index(a) for a in axes]
    error = recording.rate_error_rad_s[:, columns]
    parts = []
    for training, held in zip(dealt.training, dealt.held):
        train_rows = training[block_of_row]
        held_rows = np.flatnonzero(held[block_of_row])
        part = recording.slice(train_rows)
        try:
            model = refit(part)
            cubic = fit_cubic(part.temperature_c, error[train_rows])[0]
        except (TempCompError, UserError):   # a part the fit cannot support: no rows
            continue
        test = recording.slice(held_rows)
        temperature = test.temperature_c
        inside = (temperature >= np.min(part.temperature_c)) & \
            (temperature <= np.max(part.temperature_c))
        parts.append((held_rows, model_residual(model, test, axes),
                      cubic.corrected(error[held_rows], temperature), inside))
    if not parts:
        return None
    rows, residual, cubic, counted = (np.concatenate(p) for p in zip(*parts))
    return _Scheme(scheme, rows, residual, cubic, counted, block_of_row[rows])


def _table(schemes: tuple, temperature_c: np.ndarray, noise: np.ndarray, edges: np.ndarray,
           leave_out: Optional[int] = None):
    """Give the node's table from the schemes' counted rows (less block ``leave_out``)."""
    tables = []
    for scheme in schemes:
        used = scheme.counted & (scheme.block != leave_out)
        residual = np.where(used[:, None], scheme.residual, np.nan)
        tables.append(error_by_temperature(temperature_c[scheme.rows], residual,
                                           np.ones(len(scheme.rows)), edges))
    return larger_table(tuple(tables), noise)


def _judged(forward: _Scheme, schemes: tuple, recording, noise: np.ndarray,
            edges: np.ndarray) -> NormalisedError:
    """Judge each forward block with the table the other blocks give; pool over the blocks."""
    order = np.argsort(forward.rows)
    rows, blocks = forward.rows[order], forward.block[order]
    variance = np.empty((len(rows), noise.size))
    for block in np.unique(blocks):
        mine = blocks == block
        table = _table(schemes, recording.temperature_c, noise, edges, leave_out=block)
        variance[mine] = table.variance(noise, recording.temperature_c[rows[mine]])
    # Windows do not span two blocks: a block's first row starts one after a gap in time.
    time_s = recording.time_s[rows] + 1e9 * blocks
    return normalised_error(time_s, forward.residual[order], variance, noise)


def _rms(values: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.square(values), axis=0))


def held_out_judgement(recording, refit, axes: tuple, blocks: int, folds: int,
                       validation: str, min_past: float) -> HeldOutJudgement:
    """
    Judge the model ``refit(part)`` gives on the held-out blocks of the record; see above.

    A scheme whose folds the record cannot support gives no rows; with no
    forward rows nothing is judged and no ``model_error`` is written.
    """
    other = PURGED if validation == FORWARD else FORWARD
    schemes = tuple(s for s in (_held_out(recording, refit, scheme, blocks, folds, min_past,
                                          axes)
                                for scheme in (validation, other)) if s is not None)
    forward = next((s for s in schemes if s.name == FORWARD), None)
    if forward is None:
        return HeldOutJudgement({}, ('model_error not written: no forward held-out block '
                                     'could be refitted',))
    noise = sample_noise_rad_s([recording.rate_error_rad_s[:, [recording.axes.index(a)
                                                               for a in axes]]])
    temperature = recording.temperature_c
    edges = temperature_bin_edges(float(np.min(temperature)), float(np.max(temperature)),
                                  ERROR_BINS)
    try:
        table = _table(schemes, temperature, noise, edges)
    except CalibrationError as err:
        return HeldOutJudgement({}, (f'model_error not written: {err}',))
    judged = _judged(forward, schemes, recording, noise, edges)
    model_rms, cubic_rms = _rms(forward.residual), _rms(forward.cubic)
    gains = gain_words({a: c / m if m else None for a, c, m in zip(axes, cubic_rms, model_rms)})
    error = '; '.join(f'{a} {v:.3e} rad/s = {math.degrees(v):.3g} deg/s = '
                      f'{3600.0 * math.degrees(v):.4g} deg/h' for a, v in zip(axes, model_rms))
    cells = ', '.join(f'{a} {v:.2f}' for a, v in zip(axes, judged.per_sample))
    means = ', '.join(f'{a} {v:.2f}' for a, v in zip(axes, judged.window_means))
    lines = (
        'forward held-out blocks (each predicted by a fit on the blocks before it, as the node '
        "runs a model later in time): the model written against PX4's cubic clamped at its "
        f"range, refitted on the same blocks (the cubic's RMS / the model's): {gains}",
        f'error left (RMS per sample): {error}',
        'covariance (model_error.*: the noise of a sample '
        + ', '.join(f'{a} {v:.3e}' for a, v in zip(axes, noise))
        + ' rad/s, and the error by temperature of the held-out blocks, the noise share out): '
        f'error / published std on the forward blocks, each judged by the table the others '
        f'give (RMS; 1 = honest, above 1 = too confident): per sample {cells}; '
        f'{judged.window_s:g} s means {means}',
    )
    return HeldOutJudgement(model_error_parameters(table, axes, noise), lines, judged)
