"""
Bias tracking in the compensation node: the tracker over each corrected block, topics, state.

`CompensationTracking` runs the core's `BiasTracking` (its settings built from
``bias_tracking.*`` by `tracking_settings` in the node's `CompensationSettings`, as
``mlx-tempcomp evaluate --track-bias`` builds them) over the
model's output of every block (`track`): the node publishes that rate less the tracked
offset, and the Imu covariance takes the offset's variance. Time is the header stamp
in seconds as the bag reader makes it (`stamp_seconds`), so a replayed bag gives the
offline twin's bits. The tracked offset is relative to one model with one ZRO offset:
a model with other coefficients starts a tracker from nothing (`follow`), a ZRO
recalibration seeds it with 0 and the window mean's variance (`seed`).

After each closed window the estimate goes out on ``imu/gyro_bias``
(geometry_msgs/TwistWithCovarianceStamped: estimate and variance per axis) and
``imu/gyro_bias/status`` (diagnostic_msgs/DiagnosticArray: per axis, the stable flag
as the level, estimate, standard deviation, held, still, in exact decimal text), both
reliable and transient local, so a late subscriber gets the latest.

With ``learning.enabled`` the tracker runs inside the field learner's stream
(`core.learning.LearningTracking`, the learner kept by `CompensationLearning`), as
``evaluate --track-bias --learn`` runs it: the learnt correction is taken off the model's
output before the tracker takes its offset off.

The state goes into the ZRO state file's ``bias_tracking`` section, with the model,
fingerprint, axes and ZRO offset it is relative to, and the learner's into its
``learning`` section: written atomically beside the ZRO state
(`ZroRecalibration.write`) when the tracker or the learner learnt something since the
last write, at most once every ``bias_tracking.save_period_s`` of sensor time, and at a
clean stop; read back at start (`tracking_state`) and applied when the model matches.

With ``bias_tracking.rest_hint_topic`` the node subscribes to the robot's word that it
stands still (`rest_hint.py`: Odometry, Twist, TwistStamped or Bool) and hands each
message to the tracker as a hint (`core.standstill.rest_hints`): at its stamp, or,
unstamped, at the latest sample tracked (a hint before the first sample is ignored and
counted). The hints are kept across the trackers a parameter change or a recalibration
builds; the start-up zeroing (``bias_tracking.zero_at_start``) is done once per start.
"""

from dataclasses import replace
from datetime import datetime, timezone
import math
import reprlib
from typing import Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import TwistWithCovarianceStamped
import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from . import rest_hint
from .field_learning import CompensationLearning
from .inputs import waiting_messages
from .zro_recalibration import LEARNING_SECTION, TRACKING_SECTION, ZroRecalibration
from .. import messages
from ..qos import stream_subscription
from ...core.errors import CalibrationError
from ...core.learning import LearningTracking
from ...core.node_models import AXIS_NAMES
from ...core.standstill import BiasTracking, RestHints, tracking_state
from ...parameters.compensation import CompensationSettings, RestHintSettings
from ...parameters.state_file import check_state, Field, move_aside, reject_state, StateFileError

NS_PER_S = 1_000_000_000
# The estimate: the latest kept for late joiners, as the EEPROM images are.
BIAS_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
TRACKING_STATE = 'saved bias tracking state'
# What the section names besides the filter's state (`tracking_state` checks that).
SECTION_FIELDS = (Field('model', 'text'), Field('fingerprint', 'text'),
                  Field('axes', 'text', length=(1, len(AXIS_NAMES)), choices=AXIS_NAMES),
                  Field('zro_offset', 'number', length='axes'), Field('saved', 'text'))
# REP-145's "no data" for the linear part of the bias message: it holds a rate bias only.
NO_DATA = -1.0
# The progress of a state the file does not hold (a seed's, until written with the ZRO
# state): no progress equals it, so it is written at the next chance.
UNWRITTEN = ()


def stamp_seconds(stamps_ns: np.ndarray) -> np.ndarray:
    """Give int64 stamps in seconds as `recordings.load.load_bag` does: seconds + ns x 1e-9."""
    return (stamps_ns // NS_PER_S).astype(np.float64) + (stamps_ns % NS_PER_S) * 1e-9


def stamp_second(stamp_ns: int) -> float:
    """Give one stamp in seconds: the same operations, bit for bit, as `stamp_seconds`."""
    return float(stamp_ns // NS_PER_S) + (stamp_ns % NS_PER_S) * 1e-9


def checked_section(section: dict, full_scale_rad_s: float) -> dict:
    """
    Check the state file's ``bias_tracking`` section; give its head and its `TrackingState`.

    StateFileError or CalibrationError names the first wrong key.
    """
    if not isinstance(section, dict):
        raise StateFileError(f'{TRACKING_SECTION} must be a mapping, got {reprlib.repr(section)}')
    head = check_state(section, SECTION_FIELDS)
    return {**head, 'state': tracking_state(section, len(head['axes']), full_scale_rad_s)}


def _acceleration(imu) -> Optional[list]:
    """Give an Imu's specific force, None when it carries none (REP-145: covariance[0] -1)."""
    if imu.linear_acceleration_covariance[0] == -1.0:
        return None
    a = imu.linear_acceleration
    return [a.x, a.y, a.z]


def _model_key(model) -> tuple:
    """Give what a tracked offset is relative to: the model, its coefficients, its ZRO offset."""
    return (model.name, model.fingerprint(), [float(v) for v in model.zro_offset])


class CompensationTracking:
    """
    The node's bias tracker (None while ``bias_tracking.enabled`` is false or before a model).

    ``recalibration`` holds the state file (its path, the ZRO state written beside the
    section, the section read at start); ``full_scale_rad_s`` bounds a saved offset;
    ``learning`` the field learner the stream runs with while it is on.
    """

    def __init__(self, node, settings: CompensationSettings, indices: tuple,
                 recalibration: ZroRecalibration, full_scale_rad_s: float,
                 learning: CompensationLearning):
        self.node = node
        self.axes = settings.axes
        self.indices = indices
        self.recalibration = recalibration
        self.logger = node.get_logger()
        tracking = settings.tracking
        self.settings = tracking.tracker
        self.save_period_s = tracking.save_period_s
        self.tracker: Optional[BiasTracking] = None
        self.learning = learning
        self.stream: Optional[LearningTracking] = None   # the tracker with the learner
        self.model = None
        self.key = None
        self.initial_std_rad_s = None   # the followed model's own, else the settings'
        self.held_state = None          # the state while tracking is off, to resume from
        self.saved = self._checked(recalibration.tracking_section, full_scale_rad_s)
        # The tracker's and learner's progress at the last write; None while no tracker ran
        # since the model was followed (the next one starts from what the file holds).
        self.written = None
        self.written_s = None           # and its sensor time
        self.writes = 0
        self.write_error = ''
        self.latest_s = None
        self.windows = 0
        self.bias_publisher = None      # imu/gyro_bias, created when tracking is first on
        self.status_publisher = None    # imu/gyro_bias/status, with it
        if self.settings is not None:
            self._create_publishers()
        self.hints = RestHints()
        self.hint_topic = tracking.rest_hint.topic
        self.hint_kind = rest_hint.KINDS[tracking.rest_hint.message_type]
        self.hint_limits = ()
        self.hint_messages = 0
        self.hints_ignored = 0          # unstamped hints before the first sample
        self.zeroed_at_start = False    # the start-up zeroing is done (or not wanted)
        self._hint_limits(tracking.rest_hint)
        self.hint_subscription = None if not self.hint_topic else stream_subscription(
            node, self.hint_kind.message_type, self.hint_topic, self.on_hint)

    # The state file.

    def _checked(self, section, full_scale_rad_s: float) -> Optional[dict]:
        """Check the section read at start; report and set aside a bad one (the ZRO part stays)."""
        if section is None:
            return None
        try:
            return checked_section(section, full_scale_rad_s)
        except (StateFileError, CalibrationError) as err:
            path = self.recalibration.path
            if self.recalibration.saved is None:
                reject_state(path, str(err), self.logger, TRACKING_STATE)
                return None
            try:
                where = f'a copy kept as {move_aside(path, keep=True)}'
            except OSError as copy_err:
                where = f'no copy kept ({copy_err.strerror or copy_err})'
            self.logger.error(f'{TRACKING_STATE} in {path} unusable: {err}; {where}; the ZRO '
                              'offset beside it stays in use; tracking starts from nothing')
            return None

    def describe(self) -> str:
        """Say what the state file's section holds, for the start-up line ('' without)."""
        saved = self.saved
        if saved is None:
            return ''
        offsets = [float(f'{v:.6g}') for v in saved['state'].offset_rad_s]
        return f'; a bias tracking offset {offsets} rad/s of {saved["saved"]}'

    def section(self) -> dict:
        """Give the state file's sections for the tracker and learner now ({} without)."""
        if self.tracker is None:
            return {}
        name, fingerprint, zro_offset = self.key
        learning = self.learning.section()
        return {TRACKING_SECTION: {
            'model': name, 'fingerprint': fingerprint, 'axes': list(self.axes),
            'zro_offset': zro_offset, **self.tracker.state(),
            'saved': datetime.now(timezone.utc).isoformat(timespec='seconds')},
            **({LEARNING_SECTION: learning} if learning else {})}

    def _progress(self) -> tuple:
        return (self.tracker.updates,) + (self.learning.progress() if self.stream else ())

    def _wrote(self, section: dict) -> None:
        """Note a section written: nothing pending, the file's section is this one."""
        self.written, self.written_s = self._progress(), self.latest_s
        self.writes += 1
        self.write_error = ''
        entry = section[TRACKING_SECTION]
        self.saved = {**entry, 'state': tracking_state(entry, len(self.axes))}

    def _pending(self) -> bool:
        return self.tracker is not None and self._progress() != self.written

    def save(self, why: str = '') -> None:
        """Write the sections now if the tracker learnt since the last write; log a failure."""
        if not self._pending():
            return
        section = self.section()
        try:
            self.recalibration.write(section)
        except StateFileError as err:
            self.write_error = str(err)
            self.logger.warn(f'bias tracking state not saved{why}: {err}',
                             throttle_duration_sec=60.0)
            return
        self._wrote(section)

    def _save_if_due(self) -> None:
        elapsed = None if self.written_s is None else self.latest_s - self.written_s
        if self._pending() and (elapsed is None or not 0.0 <= elapsed < self.save_period_s):
            self.save()

    # The model and the parameters.

    def follow(self, model, initial_std_rad_s=None) -> None:
        """
        Track relative to ``model`` from the next sample on.

        The same coefficients keep the tracker (a new ZRO offset comes with a `seed`);
        others start it from the saved state if that was learnt on this very model and
        ZRO offset, else from nothing. ``initial_std_rad_s`` (per axis) replaces the
        settings' for this model: the rate only's offset is not a model's residual.
        """
        if model is None:
            return
        self.initial_std_rad_s = initial_std_rad_s
        self.model = model
        key = _model_key(model)
        if self.key is not None and key[:2] == self.key[:2]:
            self.key = key
            if initial_std_rad_s is None:
                self.learning.learner_for(model, self.settings)
            return
        self.key = key
        saved = self.saved
        state = None
        if saved is not None:
            if (saved['model'], saved['fingerprint'], saved['zro_offset']) == key and \
                    tuple(saved['axes']) == self.axes:
                state = saved['state']
                self.logger.info(f'applied {TRACKING_STATE} {list(state.offset_rad_s)} rad/s '
                                 f'from {self.recalibration.path}')
            else:
                self.logger.info(f'{TRACKING_STATE} in {self.recalibration.path} was learnt on '
                                 f'another model or ZRO offset (model {saved["model"]}, '
                                 f'fingerprint {saved["fingerprint"]}, axes {saved["axes"]}, '
                                 f'ZRO offset {saved["zro_offset"]}); tracking starts from '
                                 'nothing')
        self.held_state = state
        self._build(state)
        # Nothing to write until it learns (a restored state is what the file holds).
        self.written = None if self.tracker is None else self._progress()

    def _build(self, state) -> None:
        settings = self.settings
        if settings is not None and self.initial_std_rad_s is not None:
            settings = replace(settings, initial_std_rad_s=tuple(self.initial_std_rad_s))
        self.tracker = None if settings is None or self.key is None else \
            BiasTracking(settings, self.axes, state=state, hints=self.hints)
        if self.tracker is not None and self.zeroed_at_start:
            self.tracker.zeroing = False
        self._stream()

    def _stream(self) -> None:
        """
        Put the tracker in the learner's stream while learning is on (the learner kept).

        Not with the rate only (``initial_std_rad_s``): no temperature to learn a curve in;
        the learner waits, kept, for the temperature model.
        """
        learner = None if self.tracker is None or self.initial_std_rad_s is not None else \
            self.learning.learner_for(self.model, self.settings)
        self.stream = None if learner is None else LearningTracking(self.tracker, learner)

    def _hint_limits(self, hint: RestHintSettings) -> None:
        self.hint_limits = (hint.max_linear_m_s, hint.max_angular_rad_s)

    def on_hint(self, msg) -> None:
        """Take a rest hint and those waiting behind it (a busy node must not fall behind)."""
        self._hint(msg)
        for waiting in waiting_messages(self.hint_subscription):
            self._hint(waiting)

    def _hint(self, msg) -> None:
        """Take one rest hint: at its stamp, or unstamped at the latest sample tracked."""
        self.hint_messages += 1
        if self.tracker is None:
            return
        stamp_ns = rest_hint.stamp_ns(self.hint_kind, msg)
        time_s = self.latest_s if stamp_ns is None else stamp_second(stamp_ns)
        if time_s is None:
            self.hints_ignored += 1
            return
        self.tracker.hint(time_s, rest_hint.at_rest(self.hint_kind, msg, *self.hint_limits))

    def configure(self, node_settings: CompensationSettings, values: dict) -> None:
        """Take the node's new settings (``values``: the learner's); the offset carries over."""
        tracking = node_settings.tracking
        self.save_period_s = tracking.save_period_s
        self._hint_limits(tracking.rest_hint)
        settings = tracking.tracker
        self.learning.configure(node_settings, values)
        if settings == self.settings:
            # The learner's prior error may have changed (model_error.*).
            if self.tracker is not None:
                self._stream()
            return
        if self.tracker is not None:
            self.save(' (tracking reconfigured)')
            self.held_state = tracking_state(self.tracker.state(), len(self.axes))
        self.settings = settings
        if settings is not None and self.bias_publisher is None:
            self._create_publishers()
        written = self.written
        self._build(self.held_state)
        # Turned on, it starts from the file's state or from nothing: nothing to write yet.
        self.written = self._progress() if written is None and self.tracker is not None \
            else written

    def seed(self, samples: int) -> dict:
        """
        Start from the re-zeroed model: offset 0, the variance of a mean of ``samples``.

        A new window grid too: the window open holds rates of the model before.
        Give the state file's section for the write of the ZRO state ({} when off).
        """
        if self.tracker is None:
            return {}
        noise = self.settings.standstill.rate_noise_rad_s
        state = tracking_state(self.tracker.state(), len(self.axes))
        self.tracker = BiasTracking(self.settings, self.axes, state=state, hints=self.hints)
        self.zeroed_at_start = True
        self.tracker.seed([0.0] * len(self.axes), [n * n / samples for n in noise],
                          self.latest_s)
        self._stream()
        self.held_state = None
        self.written = UNWRITTEN
        self._publish(None, '')
        return self.section()

    def wrote_with_zro(self, section: dict) -> None:
        """Note the section `seed` gave as written with the ZRO state."""
        if section:
            self._wrote(section)

    # The stream.

    def track(self, block, rates: list) -> tuple:
        """
        Track a corrected block; give (rates to publish, std of each row or None, in use).

        ``rates``: the model's output of each row of ``block`` (`InputBlock`); in use: the
        rate of the model in use, the learnt correction taken off (``rates`` without).
        """
        tracker = self.tracker
        if tracker is None:
            return rates, None, rates
        stamps_ns = block.stamps_ns
        temperatures = block.temperature_c
        if len(temperatures[0]) == 1:
            temperature_c = [t[0] for t in temperatures]
        else:
            temperature_c = [sum(t) / len(t) for t in temperatures]
        acceleration = block.columns.get('acceleration_m_s2')
        if acceleration is None:
            acceleration = [_acceleration(parts['imu']) for parts in block.messages]
        in_use = rates
        if len(rates) == 1:
            stamp_s = stamp_second(stamps_ns[0])
            if self.stream is None:
                rate, std, _ = tracker.process_one(stamp_s, rates[0], temperature_c[0],
                                                   acceleration[0])
            else:
                rate, std, _, _, row_in_use = self.stream.process_one(
                    stamp_s, rates[0], temperature_c[0], acceleration[0])
                in_use = [row_in_use]
            tracked, stds = [rate], [std]
        else:
            stamp_s, tracked, stds, in_use = self._track_block(stamps_ns, rates, temperature_c,
                                                               acceleration)
        self.latest_s = stamp_s
        if not tracker.zeroing:
            self.zeroed_at_start = True
        if tracker.window_count != self.windows:
            self.windows = tracker.window_count
            imu = block.messages[-1]['imu']
            self._publish(imu.header.stamp, imu.header.frame_id)
            self._save_if_due()
        return tracked, stds, in_use

    def _track_block(self, stamps_ns: list, rates: list, temperature_c: list,
                     acceleration: list) -> tuple:
        """
        Track a block in runs of rows with and without acceleration.

        Give (last s, rates, stds, rates of the model in use).
        """
        time_s = stamp_seconds(np.array(stamps_ns, dtype=np.int64))
        rate = np.array(rates)
        temperature = np.array(temperature_c)
        tracked, stds = [], []
        runner = self.tracker if self.stream is None else self.stream
        corrections = []
        start = 0
        while start < len(rates):
            has = acceleration[start] is not None
            end = start + 1
            while end < len(rates) and (acceleration[end] is not None) == has:
                end += 1
            out = runner.process(time_s[start:end], rate[start:end], temperature[start:end],
                                 np.array(acceleration[start:end]) if has else None)
            tracked += out.rate_rad_s.tolist()
            stds += out.std_rad_s.tolist()
            if self.stream is not None:
                corrections.append(out.correction_rad_s)
            start = end
        in_use = rates if not corrections else (rate - np.concatenate(corrections)).tolist()
        return float(time_s[-1]), tracked, stds, in_use

    # Outputs.

    def _create_publishers(self) -> None:
        node = self.node
        self.bias_publisher = node.create_publisher(TwistWithCovarianceStamped,
                                                    'imu/gyro_bias', BIAS_QOS)
        self.status_publisher = node.create_publisher(DiagnosticArray, 'imu/gyro_bias/status',
                                                      BIAS_QOS)

    def _publish(self, stamp, frame_id: str) -> None:
        """Publish the estimate (at ``stamp``; None: the latest sample's time) and its status."""
        tracker = self.tracker
        if tracker is None or self.bias_publisher is None:
            return
        if stamp is None:
            stamp = messages.ns_to_stamp(0 if self.latest_s is None else
                                         round(self.latest_s * NS_PER_S))
        status = tracker.status()
        variance = tracker.state()['variance_rad2_s2']
        bias = TwistWithCovarianceStamped()
        bias.header.stamp = stamp
        bias.header.frame_id = frame_id
        angular = [math.nan] * 3
        covariance = [0.0] * 36
        for index in (0, 1, 2):
            covariance[7 * index] = NO_DATA
        for index, offset, v in zip(self.indices, status.offset_rad_s, variance):
            angular[index] = offset
            covariance[7 * (3 + index)] = v
        angular_velocity = bias.twist.twist.angular
        angular_velocity.x, angular_velocity.y, angular_velocity.z = angular
        bias.twist.covariance = covariance
        array = DiagnosticArray(status=[
            self._axis_status(status, i, axis) for i, axis in enumerate(self.axes)])
        array.header = bias.header
        self.bias_publisher.publish(bias)
        self.status_publisher.publish(array)

    def _axis_status(self, status, i: int, axis: str) -> DiagnosticStatus:
        """One axis: OK while its estimate is stable, else WARN saying why not."""
        stable = status.stable[i]
        std = status.std_rad_s[i]
        text = 'stable' if stable else \
            f'not stable: std {std:.3g} rad/s (stable at {self.settings.stable_std_rad_s:.3g})' \
            if status.updates or std < self.settings.initial_std_rad_s[i] else \
            'not stable: nothing learnt yet'
        values = {'estimate_rad_s': repr(status.offset_rad_s[i]), 'std_rad_s': repr(std),
                  'stable': str(stable), 'held': str(status.held[i]),
                  'still': str(status.still), 'updates': str(status.updates),
                  'last_update_s': repr(status.last_update_s), 'reason': status.reason}
        return DiagnosticStatus(
            level=DiagnosticStatus.OK if stable else DiagnosticStatus.WARN,
            name=f'{self.node.get_name()}: gyro bias {axis}', message=text,
            hardware_id=self.key[0],
            values=[KeyValue(key=k, value=v) for k, v in values.items()])

    def _hint_values(self) -> dict:
        """Give the rest hint's values: its topic, messages, and what it says now."""
        if not self.hint_topic:
            return {'rest_hint': 'none'}
        values = {'rest_hint': self.hint_topic, 'rest_hint_messages': self.hint_messages,
                  'rest_hint_ignored': self.hints_ignored}
        latest = None if self.latest_s is None else self.hints.latest(self.latest_s)
        if latest is None:
            values['rest_hint_state'] = 'no hint yet'
            return values
        age = self.latest_s - latest[0]
        stale = self.settings is not None and age > self.settings.rest_hint_max_age_s
        values['rest_hint_state'] = 'stale' if stale else 'at rest' if latest[1] else 'moving'
        values['rest_hint_age_s'] = age
        return values

    def summary(self) -> str:
        """Say what the tracker did, for the node's closing line ('' while off)."""
        tracker = self.tracker
        if tracker is None:
            return ''
        return (f'; bias tracking: {tracker.window_count} windows, {tracker.updates} '
                f'learnt, offset {[float(f"{v:.6g}") for v in tracker.status().offset_rad_s]} '
                f'rad/s, state written {self.writes} times'
                f'{self.learning.summary() if self.stream else ""}')

    def learning_values(self) -> dict:
        """Give the diagnostics' field learning values (`CompensationLearning`)."""
        if self.stream is None:
            return {'learning': 'off' if not self.learning.enabled else
                    'off (bias tracking off)' if self.settings is None else
                    'waiting for a model' if self.initial_std_rad_s is None else
                    'waiting for a temperature model (the rate only runs)'}
        return self.learning.status_values()

    def status_values(self) -> dict:
        """Give the diagnostics' tracking values: on or off, still, the estimate, its age."""
        tracker = self.tracker
        if tracker is None:
            return {'bias_tracking': 'off' if self.settings is None else 'waiting for a model',
                    **self._hint_values()}
        status = tracker.status()
        since = math.nan if status.last_update_s is None or self.latest_s is None else \
            self.latest_s - status.last_update_s
        return {'bias_tracking': 'still' if status.still else 'moving', **self._hint_values(),
                'tracking_hinted': status.hinted,
                'tracking_zero_at_start': 'off' if not self.settings.zero_at_start else
                'done' if self.zeroed_at_start else 'waiting for the first still run',
                'tracking_offset_rad_s': list(status.offset_rad_s),
                'tracking_std_rad_s': list(status.std_rad_s),
                'tracking_stable': list(status.stable), 'tracking_held': list(status.held),
                'tracking_since_update_s': since, 'tracking_updates': status.updates,
                'tracking_windows': status.windows, 'tracking_reason': status.reason,
                'tracking_state_writes': self.writes,
                'tracking_state_error': self.write_error}
