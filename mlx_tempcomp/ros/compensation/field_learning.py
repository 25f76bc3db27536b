"""
Field learning in the compensation node: the learner beside the tracker, its state, its file.

`CompensationLearning` holds the `FieldLearner` the tracker's stream runs with
(`core.learning.LearningTracking`, built by `CompensationTracking` as ``mlx-tempcomp
evaluate --track-bias --learn`` builds it): its settings come from the node's
``learning.*`` (`FieldLearning.settings`), the tracking settings, the prior model's
``model_error.*`` table and the knots of the correction the prior model carries already,
as `toolkit.learning.learning_of` gives them, so the node gives the offline twin's bits.

The learner is relative to the prior model's coefficients (its name and fingerprint): a
ZRO recalibration keeps it, a model with other coefficients starts it from the prior. It
survives a tracker rebuilt by a parameter change or a recalibration.

Its state goes into the state file's ``learning`` section, beside and with the bias
tracking's (one atomic write): the model it is relative to and `FieldLearner.state()`.
Read back at start, a section of another model or axes is left (one line); a damaged one
(`FieldLearner.restore` refuses it) gives the prior model, one WARN line and a copy of the
file kept aside; the ZRO offset and the tracked offset beside it stay.

``imu/save_learned_model`` writes the model in use (`learned_document`): the node's
parameters of the unit (`parameters.compensation.unit_values`: the model, its
coefficients, its error table, ``bias_tracking.*``, ``learning.*``) with ``correction.*``
the prior's table plus the learnt one, as ``evaluate --learned-params`` writes it
(`parameters.files.learned_parameters`). The write runs in a thread while the stream goes
on (`LearnedModelSaver`); a call meanwhile is refused.
"""

from dataclasses import dataclass
from datetime import datetime, timezone
import math
import os
import threading
from typing import Optional

from ..service_window import Outcome, Refused
from ...core.errors import CalibrationError, TempCompError
from ...core.learning import FieldLearner
from ...core.node_models import CorrectedModel, CorrectionTable
from ...parameters.compensation import CompensationSettings, unit_values
from ...parameters.files import learned_parameters, parameter_file, write_parameter_file
from ...parameters.learning import largest_correction_rad_s, renewal_lines
from ...parameters.state_file import move_aside

LEARNING_STATE = 'saved learning state'


def _prior_key(model) -> tuple:
    """Give what the learnt correction is relative to: the model and its coefficients."""
    return (model.name, model.fingerprint())


def prior_table(model) -> Optional[CorrectionTable]:
    """Give the correction table the prior model carries already (None: none)."""
    return model.table if isinstance(model, CorrectedModel) else None


@dataclass(frozen=True)
class LearnedModel:
    """What ``imu/save_learned_model`` writes: the path, the document, its header, a summary."""

    path: str
    document: dict
    header: str
    summary: str


class CompensationLearning:
    """
    The node's field learner (None while ``learning.enabled`` or tracking is off).

    ``settings`` are the node's, ``values`` its parameter values (what a save writes);
    ``section`` is the state file's ``learning`` section read at start (unchecked);
    ``path`` the state file (for the log); ``learned_model_file`` where the service writes.
    """

    def __init__(self, settings: CompensationSettings, values: dict, section, path: str,
                 learned_model_file: str, logger):
        self.enabled = settings.learning is not None
        self.axes = settings.axes
        self.logger = logger
        self.path = path
        self.learned_model_file = learned_model_file
        self.saved = section
        self.node_settings = settings
        self.values = dict(values)
        self.settings = None
        self.learner: Optional[FieldLearner] = None
        self.key = None             # (model, fingerprint) the learner is relative to
        self.prior = None           # the prior model (with its ZRO offset)
        self.restored = ''          # how the state began, for the diagnostics
        self.saves = 0
        self.saver = LearnedModelSaver()

    def configure(self, settings: CompensationSettings, values: dict) -> None:
        """Take the node's settings (the model's error table) and values (what a save writes)."""
        self.node_settings = settings
        self.values = dict(values)

    def describe(self) -> str:
        """Say what the state file's section holds, for the start-up line ('' without)."""
        section = self.saved
        if not isinstance(section, dict):
            return '' if section is None else '; a learning section'
        counts = section.get('counts')
        windows = counts.get('windows') if isinstance(counts, dict) else '?'
        return f'; a learning state of {windows} windows of {section.get("saved", "?")}'

    # The learner.

    def _settings(self, tracking, model):
        table = prior_table(model)
        return self.node_settings.learning.settings(
            tracking, self.node_settings.model_error,
            None if table is None else table.temperature_c)

    def learner_for(self, model, tracking) -> Optional[FieldLearner]:
        """
        Give the learner the stream runs with on ``model`` (the prior) and ``tracking``.

        The same coefficients keep the learner (settings renewed from the tracking's);
        others take the saved state if it was learnt on them, else the prior.
        """
        if not self.enabled or tracking is None or model is None:
            return None
        settings = self._settings(tracking, model)
        key = _prior_key(model)
        self.prior = model
        if self.key == key and self.learner is not None:
            if settings != self.settings:
                self.learner = self._restored(settings, self.learner.state(), 'kept')
                self.settings = settings
            return self.learner
        self.key, self.settings = key, settings
        self.learner = self._from_saved(settings, key)
        return self.learner

    def _restored(self, settings, state, how: str) -> FieldLearner:
        try:
            learner = FieldLearner.restore(settings, self.axes, state)
            self.restored = how
            return learner
        except CalibrationError as err:
            self.logger.warn(f'learning state not carried over ({err}); starting from the '
                             'prior model')
            self.restored = 'the prior (settings changed)'
            return FieldLearner(settings, self.axes)

    def _from_saved(self, settings, key) -> FieldLearner:
        """Give the learner of the section read at start, if learnt on ``key``; else the prior."""
        section, self.saved = self.saved, None
        if section is None:
            self.restored = 'the prior'
            return FieldLearner(settings, self.axes)
        if isinstance(section, dict) and (section.get('model'), section.get('fingerprint')) \
                != key:
            self.logger.info(
                f'{LEARNING_STATE} in {self.path} was learnt on another model (model '
                f'{section.get("model")}, fingerprint {section.get("fingerprint")}); learning '
                'starts from the prior model')
            self.restored = 'the prior (learnt on another model)'
            return FieldLearner(settings, self.axes)
        try:
            learner = FieldLearner.restore(settings, self.axes, section)
        except CalibrationError as err:
            try:
                where = f'a copy kept as {move_aside(self.path, keep=True)}'
            except OSError as copy_err:
                where = f'no copy kept ({copy_err.strerror or copy_err})'
            self.logger.warn(f'{LEARNING_STATE} in {self.path} unusable: {err}; {where}; '
                             'learning starts from the prior model (the ZRO and tracked '
                             'offsets beside it stay)')
            self.restored = f'the prior (saved state unusable: {err})'
            return FieldLearner(settings, self.axes)
        self.logger.info(f'applied {LEARNING_STATE} from {self.path}: {learner.windows} '
                         f'windows, renewals {learner.renewals}')
        self.restored = f'the state file ({learner.windows} windows)'
        return learner

    def progress(self) -> tuple:
        """Give what changes when the learner learns (a write is due when it did)."""
        learner = self.learner
        if learner is None:
            return ()
        return (learner.windows, learner.runs_committed, learner.runs_dropped, learner.swaps,
                tuple(learner.renewals), sum(learner.refused.values()))

    def section(self) -> dict:
        """Give the state file's ``learning`` section, or an empty mapping without one."""
        if self.learner is None:
            # Learning off: the section read at start is kept as it was.
            return self.saved if isinstance(self.saved, dict) else {}
        name, fingerprint = self.key
        return {'model': name, 'fingerprint': fingerprint,
                'saved': datetime.now(timezone.utc).isoformat(timespec='seconds'),
                **self.learner.state()}

    def applied(self) -> Optional[CorrectionTable]:
        """Give the correction taken off now (None without a learner)."""
        return None if self.learner is None else self.learner.applied

    # The diagnostics.

    def status_values(self) -> dict:
        """Give the diagnostics' learning values: coverage per knot, windows, the renewals."""
        learner = self.learner
        if learner is None:
            return {'learning': 'off' if not self.enabled else 'waiting for tracking'}
        status = learner.status()
        values = {'learning': 'on', 'learning_started_from': self.restored,
                  'learning_windows': status['windows'], 'learning_runs': status['runs'],
                  'learning_runs_dropped': status['runs_dropped'],
                  'learning_refused': ', '.join(f'{k} {v}' for k, v in
                                                sorted(status['refused'].items())) or 'none',
                  'learning_swaps': learner.swaps,
                  'learning_knots_c': status['knots_c'],
                  'learning_model_file': self.learned_model_file,
                  'learning_model_saves': self.saves}
        for i, axis in enumerate(self.axes):
            a = status['axes'][axis]
            renewal = a['last_renewal']
            values[f'learning_{axis}_coverage'] = status['coverage'][i]
            values[f'learning_{axis}_renewals'] = a['renewals']
            values[f'learning_{axis}_last_renewal_s'] = math.nan if renewal is None \
                else renewal[0]
            values[f'learning_{axis}_held_out_gain'] = math.nan if renewal is None \
                else renewal[1]
            values[f'learning_{axis}_reason'] = a['reason']
            values[f'learning_{axis}_correction_max_rad_s'] = max(
                (abs(v) for v in a['correction_rad_s']), default=0.0)
        return values

    def summary(self) -> str:
        """Say what the learner did, for the node's closing line ('' without)."""
        learner = self.learner
        if learner is None:
            return ''
        return (f'; field learning: {learner.windows} windows in {learner.runs_committed} '
                f'runs, renewals {dict(zip(self.axes, learner.renewals))}')

    # The model in use, written.

    def learned_model(self, node_name: str, zro_offset, running: bool) -> LearnedModel:
        """
        Give what ``imu/save_learned_model`` writes now; `Refused` when nothing to.

        ``zro_offset`` is the prior model's ZRO offset in use (kept in the state file);
        ``running``: the stream runs with the learner (tracking on, a model).
        """
        learner = self.learner
        if learner is None or not running:
            reason = 'learning is off' if not self.enabled else \
                'no learner yet (bias tracking off, or waiting for a model)'
            raise Refused(reason)
        prior = self.prior
        parameters = learned_parameters(unit_values(self.values), prior_table(prior),
                                        learner.accepted, self.axes)
        renewed = [a for a, count in zip(self.axes, learner.renewals) if count]
        lines = [f'Model in use by {node_name} (field learning), written by '
                 'imu/save_learned_model at '
                 f'{datetime.now(timezone.utc).isoformat(timespec="seconds")}:',
                 f"the {prior.name} model of the node's parameters (fingerprint "
                 f'{prior.fingerprint()}) less the learnt correction table (correction.*, rad/s,'
                 ' relative to it; cubic between the temperatures, held beyond)']
        lines += renewal_lines(learner, self.axes)
        if not renewed:
            lines.append('no renewal was accepted: the model is the one the node started with')
        if any(zro_offset):
            lines.append(f'the ZRO offset {list(zro_offset)} ({prior.offset_unit}) of '
                         'imu/recalibrate_zro is kept in the state file, not here')
        biggest = largest_correction_rad_s(learner)
        base, table = (prior.base, prior.table) if isinstance(prior, CorrectedModel) else \
            (prior, None)
        total = learner.accepted if table is None else table.added(learner.accepted)
        written = base if total.is_zero else CorrectedModel(base, total)
        change = 'no axis renewed: the model the node started with' if not renewed else \
            (f'{", ".join(renewed)} renewed ({sum(learner.renewals)} renewals since the prior: '
             f'{prior.name} model {prior.fingerprint()} to {written.fingerprint()}), learnt '
             f'correction up to {biggest:.3g} rad/s')
        return LearnedModel(self.learned_model_file, parameter_file(node_name, parameters),
                            '\n'.join(lines), change)


def write_learned_model(learned: LearnedModel) -> Outcome:
    """
    Write ``learned`` atomically; give the outcome: what and where, or why not.

    Mode 0644, as ``fit`` writes a parameter file (`write_parameter_file`): a model is no
    secret, and a user reviews and commits it.

    A temporary file in the same folder renamed over the target: a symlink planted at the
    target is replaced, not followed.
    """
    path = learned.path
    try:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        header = f'{learned.header}\nUse: compensation_node --ros-args --params-file {path}'
        write_parameter_file(path, learned.document, header)
    except (OSError, TempCompError) as err:
        return Outcome(False, f'refused: cannot write {path}: '
                              f'{getattr(err, "strerror", None) or err}')
    return Outcome(True, f'wrote the model in use to {path}: {learned.summary}')


class LearnedModelSaver:
    """
    One write of the model in use at a time, in a thread of its own.

    `start` starts one and the caller awaits `answer` (None until the thread is done);
    the node's `ServiceGuard` lets one call at a time start one.
    """

    def __init__(self):
        self.thread: Optional[threading.Thread] = None
        self.result: Optional[Outcome] = None

    def start(self, learned: LearnedModel) -> None:
        """Start writing ``learned``."""
        self.result = None

        def write() -> None:
            self.result = write_learned_model(learned)

        self.thread = threading.Thread(target=write, name='save_learned_model', daemon=True)
        self.thread.start()

    def answer(self) -> Optional[Outcome]:
        """Give the write's answer once its thread is done, else None."""
        thread = self.thread
        if thread is None or thread.is_alive():
            return None
        return self.result

    def end(self) -> None:
        """Let the next call write (after its answer)."""
        if self.thread is not None:
            self.thread.join()
        self.thread = None
