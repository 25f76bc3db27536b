"""
The field learner's state as a state file holds it, and its check when read back.

`learner_state` gives plain YAML-safe values: per axis the committed and working filters
(mean, the lower triangle of the covariance row by row, time), the curve in use, the
frozen candidate, the guard's sums, the anchors, the counters. Its size is fixed by the
knots and the axes, whatever the running time. `restore_state` checks every key (a
CalibrationError names the first wrong one: missing, of another length, not finite, a
covariance that is not one, knots other than the settings') before it sets anything, so a
damaged state leaves the learner at its prior.
"""

import math

import numpy as np

from .guard import INTEGER_PAIR_FIELDS, PAIR_FIELDS, Pairs
from ..errors import CalibrationError
from ..node_models import CorrectionTable

STATE_VERSION = 1
KEYS = ('version', 'axes', 'knots_c', 'committed', 'working', 'accepted', 'candidate', 'trial',
        'run_pairs', 'anchor', 'run_last', 'applied', 'tracker_anchor', 'swaps', 'pending',
        'last_window', 'gravity', 'counts', 'refused', 'last_renewal', 'reason')
# A correction beyond this is no gyro's (ten times 2000 deg/s, as the model probe bounds it).
MAX_CORRECTION_RAD_S = 10.0 * math.radians(2000.0)


def _filters(group) -> dict:
    return {'mean': [f.mean.tolist() for f in group],
            'covariance': [f.covariance[np.tril_indices(f.mean.size)].tolist() for f in group],
            'time_s': [f.time_s for f in group]}


def _optional(values) -> list:
    return [None if v is None else list(v) for v in values]


def learner_state(learner) -> dict:
    """Give the learner's state as plain values (see the module notes)."""
    return {
        'version': STATE_VERSION, 'axes': list(learner.axes),
        'knots_c': list(learner.settings.knots_c),
        'committed': _filters(learner.committed), 'working': _filters(learner.working),
        'accepted': [list(v) for v in learner.accepted.values_rad_s],
        'candidate': _optional(learner.candidate),
        'trial': [p.to_list() for p in learner.trial],
        'run_pairs': [p.to_list() for p in learner.run_pairs],
        'anchor': _optional(learner.anchor), 'run_last': _optional(learner.run_last),
        'applied': [list(v) for v in learner.applied.values_rad_s],
        'tracker_anchor': _optional(learner.tracker_anchor), 'swaps': learner.swaps,
        'pending': learner.pending,
        'last_window': None if learner.last_window is None else list(learner.last_window),
        'gravity': None if learner.gravity is None else list(learner.gravity),
        'counts': {'windows': learner.windows, 'runs': learner.runs_committed,
                   'runs_dropped': learner.runs_dropped, 'renewals': list(learner.renewals)},
        'refused': dict(learner.refused),
        'last_renewal': _optional(learner.last_renewal),
        'reason': list(learner.reason),
    }


def _number(value, name: str, low=-math.inf, high=math.inf, integer=False, nan=False):
    if isinstance(value, bool) or not isinstance(value, int if integer else (int, float)):
        kind = 'an integer' if integer else 'a number'
        raise CalibrationError(f'{name} must be {kind}, got {value!r}')
    if value != value and nan:
        return float(value)
    if not (math.isfinite(value) and low <= value <= high):
        raise CalibrationError(f'{name} {value!r} is outside {low:g} to {high:g}')
    return value if integer else float(value)


def _numbers(value, name: str, length: int, **limits) -> list:
    if not isinstance(value, list) or len(value) != length:
        raise CalibrationError(f'{name} must be a list of {length} values, got '
                               f'{_short(value)}')
    return [_number(v, f'{name}[{k}]', **limits) for k, v in enumerate(value)]


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + '...'


def _per_axis(state: dict, key: str, axes: int) -> list:
    value = state[key]
    if not isinstance(value, list) or len(value) != axes:
        raise CalibrationError(f'{key} must be a list of {axes} (one per axis), got '
                               f'{_short(value)}')
    return value


def _filter_values(state: dict, key: str, axes: int, size: int) -> list:
    """Check one group of filters: give (mean, covariance, time) per axis."""
    group = state[key]
    if not isinstance(group, dict) or set(group) != {'mean', 'covariance', 'time_s'}:
        raise CalibrationError(f'{key} must map mean, covariance and time_s, got '
                               f'{_short(group)}')
    values = []
    for i in range(axes):
        mean = np.array(_numbers(_per_axis(group, 'mean', axes)[i], f'{key}.mean[{i}]', size))
        packed = _numbers(_per_axis(group, 'covariance', axes)[i], f'{key}.covariance[{i}]',
                          size * (size + 1) // 2)
        covariance = np.zeros((size, size))
        covariance[np.tril_indices(size)] = packed
        covariance = covariance + np.tril(covariance, -1).T
        scale = float(np.max(np.abs(np.diag(covariance)), initial=0.0))
        if np.any(np.diag(covariance) < 0.0) or \
                np.min(np.linalg.eigvalsh(covariance)) < -1e-9 * max(scale, 1e-300):
            raise CalibrationError(f'{key}.covariance[{i}] is not a covariance (not positive '
                                   'semi-definite)')
        time_s = _per_axis(group, 'time_s', axes)[i]
        time_s = None if time_s is None else _number(time_s, f'{key}.time_s[{i}]')
        values.append((mean, covariance, time_s))
    return values


def _pairs(state: dict, key: str, axes: int) -> list:
    result = []
    for i, values in enumerate(_per_axis(state, key, axes)):
        if not isinstance(values, list) or len(values) != len(PAIR_FIELDS):
            raise CalibrationError(f'{key}[{i}] must be a list of {len(PAIR_FIELDS)} sums, got '
                                   f'{_short(values)}')
        checked = [_number(v, f'{key}[{i}].{name}', low=0.0 if name in INTEGER_PAIR_FIELDS or
                           name.startswith(('square', 'run_count', 'run_gain2',
                                            'prior_run_gain2')) else -math.inf,
                           integer=name in INTEGER_PAIR_FIELDS)
                   for name, v in zip(PAIR_FIELDS, values)]
        result.append(Pairs.from_list(checked))
    return result


def _optional_lists(state: dict, key: str, axes: int, length: int, **limits) -> list:
    return [None if v is None else tuple(_numbers(v, f'{key}[{i}]', length, **limits))
            for i, v in enumerate(_per_axis(state, key, axes))]


def restore_state(learner, state) -> None:
    """Check ``state`` against the learner's settings and set it; CalibrationError if wrong."""
    if not isinstance(state, dict):
        raise CalibrationError(f'the learning state must be a mapping, got {_short(state)}')
    missing = [key for key in KEYS if key not in state]
    if missing:
        raise CalibrationError(f'damaged: {", ".join(missing)} missing (truncated?)')
    if state['version'] != STATE_VERSION:
        raise CalibrationError(f'version {state["version"]!r}: this learner reads version '
                               f'{STATE_VERSION}')
    axes = len(learner.axes)
    if state['axes'] != list(learner.axes):
        raise CalibrationError(f'axes {_short(state["axes"])} are not {list(learner.axes)}')
    knots = learner.settings.knots_c
    if _numbers(state['knots_c'], 'knots_c', len(knots)) != list(knots):
        raise CalibrationError(f'knots_c {_short(state["knots_c"])} are not the settings\' '
                               f'{list(knots)} (learning.* changed): learnt on other knots')
    size = len(knots) + 1
    committed = _filter_values(state, 'committed', axes, size)
    working = _filter_values(state, 'working', axes, size)
    bound = {'low': -MAX_CORRECTION_RAD_S, 'high': MAX_CORRECTION_RAD_S}
    accepted, applied = ([_numbers(v, f'{key}[{i}]', len(knots), **bound)
                          for i, v in enumerate(_per_axis(state, key, axes))]
                         for key in ('accepted', 'applied'))
    tracker_anchor = _optional_lists(state, 'tracker_anchor', axes, 2)
    swaps = _number(state['swaps'], 'swaps', low=0, integer=True)
    candidate = _optional_lists(state, 'candidate', axes, len(knots), **bound)
    trial, run_pairs = _pairs(state, 'trial', axes), _pairs(state, 'run_pairs', axes)
    anchor = _optional_lists(state, 'anchor', axes, len(knots) + 3)
    run_last = _optional_lists(state, 'run_last', axes, len(knots) + 3)
    for key, values in (('anchor', anchor), ('run_last', run_last)):
        if any(v is not None and not v[0] >= 1.0 for v in values):
            raise CalibrationError(f'{key}: a run of fewer than one window')
    if not isinstance(state['pending'], bool):
        raise CalibrationError(f'pending must be true or false, got {_short(state["pending"])}')
    last_window = None if state['last_window'] is None else \
        tuple(_numbers(state['last_window'], 'last_window', 2))
    gravity = None if state['gravity'] is None else \
        tuple(_numbers(state['gravity'], 'gravity', 3, low=-1.0, high=1.0))
    counts = _counts(state['counts'], axes)
    refused = state['refused']
    if not isinstance(refused, dict) or not all(isinstance(k, str) for k in refused):
        raise CalibrationError(f'refused must map reasons to counts, got {_short(refused)}')
    refused = {k: _number(v, f'refused.{k}', low=0, integer=True) for k, v in refused.items()}
    last_renewal = _optional_lists(state, 'last_renewal', axes, 2)
    reason = _per_axis(state, 'reason', axes)
    if not all(isinstance(r, str) for r in reason):
        raise CalibrationError(f'reason must be texts, got {_short(reason)}')
    for group, values in ((learner.committed, committed), (learner.working, working)):
        for f, (mean, covariance, time_s) in zip(group, values):
            f.mean, f.covariance, f.time_s = mean, covariance, time_s
    learner.accepted = CorrectionTable(knots, tuple(tuple(v) for v in accepted))
    learner.applied = CorrectionTable(knots, tuple(tuple(v) for v in applied))
    learner.tracker_anchor, learner.swaps, learner.before = tracker_anchor, swaps, None
    learner.candidate, learner.trial, learner.run_pairs = candidate, trial, run_pairs
    learner.anchor, learner.run_last = anchor, run_last
    learner.pending, learner.last_window, learner.gravity = state['pending'], last_window, \
        gravity
    learner.windows, learner.runs_committed, learner.runs_dropped, learner.renewals = counts
    learner.refused, learner.last_renewal, learner.reason = refused, last_renewal, list(reason)


def _counts(counts, axes: int) -> tuple:
    keys = {'windows', 'runs', 'runs_dropped', 'renewals'}
    if not isinstance(counts, dict) or set(counts) != keys:
        raise CalibrationError(f'counts must map windows, runs, runs_dropped and renewals, got '
                               f'{_short(counts)}')
    return (_number(counts['windows'], 'counts.windows', low=0, integer=True),
            _number(counts['runs'], 'counts.runs', low=0, integer=True),
            _number(counts['runs_dropped'], 'counts.runs_dropped', low=0, integer=True),
            _numbers(counts['renewals'], 'counts.renewals', axes, low=0, integer=True))
