"""
Compensation node: raw rate and temperature in, temperature-compensated rate out.

Subscribes to ``imu/data_raw``, ``imu/temperature_raw`` (with several MLX90609
chips and the eeprom model, ``imu/temperature_raw/<axis>``), ``imu/eeprom`` and,
while the model needs them, ``imu/temperature_2_raw`` (a second temperature)
and ``imu/supply_voltage`` (sensor_msgs/BatteryState, its voltage); pairs
samples with the temperature by ``temperature.pairing`` (`CompensationInputs`),
runs them through the stream of the model named by ``model`` (which keeps the
state of stateful effects) and publishes ``imu/data`` and ``imu/temperature``.
Without a temperature (none within ``temperature.wait_s``, or
``temperature.pairing: none``), or without the eeprom model's factory tables
after ``eeprom.wait_s``, it runs the rate only (`RateOnlyModel`): the raw rate
less the tracked offset, its covariance holding ``rate_only.offset_std_rad_s``.
With ``bias_tracking.enabled`` the rate published is the model's less the offset
tracked at standstill (`CompensationTracking`), whose estimate goes out on
``imu/gyro_bias`` and ``imu/gyro_bias/status``; with
``bias_tracking.rest_hint_topic`` it also subscribes to the robot's rest hint. The angular
velocity covariance is ``rate_noise_rad_s``^2, plus the tracked offset's variance,
or without tracking the square of the model's error at the sample's temperature
when ``model_error.*`` gives a table. The supply voltage is held (the latest at or
before each sample's stamp, ``supply_voltage.pairing: hold``) or paired by
stamp like the temperature (``stamp``). The ``imu/recalibrate_zro`` service
(std_srvs/Trigger) learns the ZRO residual at rest (of the model in use: with the learnt
correction taken off), seeds the tracker and persists both. With ``learning.enabled`` the
tracker runs with the field learner (`CompensationLearning`), and
``imu/save_learned_model`` (std_srvs/Trigger) writes the model in use as a parameter file.
"""

import bisect
from dataclasses import replace
import math
import time

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import UInt8MultiArray
from std_srvs.srv import Trigger

from .bias_tracking import CompensationTracking
from .field_learning import CompensationLearning
from .inputs import AUXILIARY, CompensationInputs
from .outputs import CompensationOutputs
from .status import compensation_status, missing_inputs
from .zro_recalibration import full_scale_rad_s, ZroRecalibration
from .. import messages
from ..declare import declare
from ..qos import EEPROM_QOS, stream_subscription
from ..runner import run
from ..service_window import await_window, guarded, Outcome, Refused, ServiceGuard
from ...core.errors import CalibrationError, TempCompError
from ...core.mlx90609 import Output, sensor_tables
from ...core.node_models import RateOnlyModel
from ...parameters.compensation import (compensation_settings, COMPENSATION_SPECS,
                                        learned_model_file_of, state_file_of)
from ...parameters.models import build_model, MODEL_PREFIXES
from ...parameters.specs import check_choices, ParameterError
from ...recordings.eeprom_multiarray import eeprom_images_from_multiarray

_POLL_S = 0.05
# An input missing this long after the start is a WARN naming what to set, repeated at most
# once a period (wall time).
WAIT_WARN_S = 5.0
WAIT_WARN_PERIOD_S = 30.0


class CompensationNode(Node):
    """Applies the configured model to the raw stream; offers ZRO recalibration."""

    def __init__(self, local_input: bool = False, **kwargs):
        """
        Build the node.

        With ``local_input`` the raw rate and temperature come from a driver in this
        process through `take_local`, not from subscriptions (bringup).
        """
        super().__init__('compensation_node', **kwargs)
        # The node reads the settings; the values build the model, the candidate settings of
        # a change and the learnt model's file.
        self.values = declare(self, COMPENSATION_SPECS)
        self.settings = settings = compensation_settings(self.values)
        self.axes = settings.axes
        self.indices = messages.axis_indices(self.axes)
        self.sensor = None
        self.eeprom_error = ''
        # The model first: a node that cannot start leaves its state file as it is.
        model = build_model(self.values)
        self.recalibration = ZroRecalibration(
            state_file_of(settings, self.get_fully_qualified_name(), self.get_logger().warn),
            self.axes, self.get_logger())
        self.recalibration.load(self._full_scale_rad_s())
        model = self._with_saved_offset(model)
        self.model = None
        self.stream = None
        self.last_input = None
        temperature = settings.temperature
        self.inputs = CompensationInputs(
            self.axes, self.indices, len(self.axes) > 1 and settings.model == 'eeprom',
            settings.supply_voltage.pairing == 'hold', temperature.pairing,
            temperature.max_age_s, temperature.wait_s)
        # The rate only, while no temperature model can run (`alone` says why).
        self.rate_only = RateOnlyModel(len(self.axes))
        self.rate_only_stream = self.rate_only.stream()
        self.alone = ''
        self.outputs = CompensationOutputs(self, settings, self.indices,
                                           self.inputs.temperature_streams)
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        learning = CompensationLearning(
            settings, self.values, self.recalibration.learning_section,
            self.recalibration.path,
            learned_model_file_of(settings, self.recalibration.path, self.get_name()),
            self.get_logger())
        self.tracking = CompensationTracking(self, settings, self.indices, self.recalibration,
                                             self._full_scale_rad_s(), learning)
        # The EEPROM subscription first: when it and samples are ready together, the
        # executor takes it first, so no sample waits for a model.
        self.create_subscription(UInt8MultiArray, 'imu/eeprom', self.on_eeprom, EEPROM_QOS)
        if not local_input:
            subscriptions = self.inputs.subscriptions
            subscriptions['imu'] = stream_subscription(self, Imu, 'imu/data_raw', self.on_imu)
            for stream, topic in self.inputs.temperature_topics.items():
                subscriptions[stream] = stream_subscription(
                    self, Temperature, topic, lambda msg, s=stream: self.on_input(s, msg))
        # Its own group: while the service awaits its window, the default group (stream,
        # timers) keeps running in the same single thread. Reentrant, so a second request
        # is taken (and refused) while the first awaits: a mutually exclusive group would
        # hold it back and run a second recalibration afterwards.
        self.service_guard = ServiceGuard()   # one calibration call at a time, of any service
        self.create_service(Trigger, 'imu/recalibrate_zro', self.recalibrate,
                            callback_group=ReentrantCallbackGroup())
        # Likewise: a call while a write runs is refused, not queued.
        self.create_service(Trigger, 'imu/save_learned_model', self.save_learned_model,
                            callback_group=ReentrantCallbackGroup())
        self.create_timer(1.0, self.publish_diagnostics)
        self.add_on_set_parameters_callback(self.validate_parameters)
        self.add_post_set_parameters_callback(self.apply_parameters)
        self._use(model)
        self.local_input = local_input
        self.started = time.monotonic()
        self.get_logger().info(self._start_summary())

    def _start_summary(self) -> str:
        """Say what the node runs, reads, writes and what it loaded, in one line."""
        settings = self.settings
        eeprom = settings.model == 'eeprom'
        inputs = ['raw rate and temperature from the driver in this process'] if \
            self.local_input else []
        hint = self.tracking.hint_topic
        inputs += [s.topic_name for s in self.subscriptions
                   if (eeprom or s.msg_type is not UInt8MultiArray) and
                   s.msg_type is not self.tracking.hint_kind.message_type]
        outputs = [p.topic_name for p in self.publishers
                   if p.topic_name not in ('/rosout', '/parameter_events')]
        table = self.outputs.model_error
        covariance = ' (covariance: rate noise + tracked offset variance)' \
            if self.tracking.settings is not None else '' if table is None else \
            f' (covariance: rate noise + model error at {len(table.temperature_c)} temperatures)'
        tracking = 'on' if self.tracking.settings is not None else 'off'
        if hint:
            tracking += f' (rest hint: {hint}, {settings.tracking.rest_hint.message_type})'
        if settings.tracking.zero_at_start:
            tracking += ' (zero at start: the first still run is taken as at rest)'
        learning = self.tracking.learning
        tracking += f', field learning {"on" if learning.enabled else "off"}'
        if learning.enabled:
            tracking += f' (imu/save_learned_model writes {learning.learned_model_file})'
        return (f'model {settings.model} on axes {list(self.axes)}, bias tracking '
                f'{tracking}; waits for {", ".join(inputs)}; {self._temperature_summary()}; '
                f'publishes {", ".join(outputs)}{covariance}; state file '
                f'{self.recalibration.path}: '
                f'{self.recalibration.describe()}{self.tracking.describe()}'
                f'{self.tracking.learning.describe()}')

    def _temperature_summary(self) -> str:
        """Say how the temperature pairs, and when the node runs the rate only."""
        settings = self.settings
        temperature = settings.temperature
        pairing = temperature.pairing
        if pairing == 'none':
            return ('no temperature (temperature.pairing none): the rate only, less the '
                    'tracked offset, no temperature model')
        within = f' within {temperature.max_age_s:g} s' \
            if pairing in ('hold', 'interpolate') else ''
        text = (f'temperature paired by {pairing}{within}, the rate only without one '
                f'{temperature.wait_s:g} s after the first sample')
        if settings.model == 'eeprom':
            text += (f'; the factory tables waited for {settings.eeprom_wait_s:g} s, then '
                     'the rate only until they come (only an MLX90609 driver sends them)')
        return text

    def _warn_waiting(self) -> None:
        """WARN, throttled, for an input still missing a few seconds after the start."""
        if time.monotonic() - self.started < WAIT_WARN_S:
            return
        missing = missing_inputs(self.settings.model, self.sensor is not None, self.inputs)
        if missing:
            self.get_logger().warn(f'waiting {time.monotonic() - self.started:.0f} s: '
                                   + '; '.join(missing), throttle_duration_sec=WAIT_WARN_PERIOD_S)

    def destroy_node(self):
        # A clean stop keeps what the tracker learnt since its last write.
        self.tracking.save(' at the stop')
        inputs, outputs = self.inputs, self.outputs
        self.get_logger().info(
            f'{self.get_name()} stopping: {outputs.samples_out} samples compensated in '
            f'{outputs.blocks} blocks, {inputs.samples_waiting} waited for a model or voltage, '
            f'{inputs.unpaired_dropped} unpaired dropped, '
            f'{inputs.no_temperature_samples} without a temperature within '
            f'temperature.max_age_s, {inputs.no_supply_samples} without a supply voltage, '
            f'{inputs.no_acceleration_samples} without acceleration'
            f'{self.tracking.summary()}')
        return super().destroy_node()

    def _full_scale_rad_s(self) -> float:
        return full_scale_rad_s(self.settings.sensor.full_scale_dps, self.sensor)

    def _with_saved_offset(self, model):
        return self.recalibration.with_saved_offset(model, self._full_scale_rad_s())

    def _use(self, model) -> None:
        """
        Run ``model`` from the next sample on.

        The stream keeps its state (temperature slope history, hysteresis play)
        when only the ZRO offset differs: same model, same fingerprint.
        """
        old, stream = self.model, self.stream
        if model is not None and old is not None and stream is not None and \
                old.name == model.name and old.fingerprint() == model.fingerprint():
            stream.model = model
        else:
            self.stream = None if model is None else model.stream()
        self.model = model
        inputs = self.inputs
        for stream in inputs.use(frozenset() if model is None else model.inputs):
            auxiliary = AUXILIARY[stream]
            callback = inputs.held_supply.add if inputs.held(stream) else \
                (lambda msg, s=stream: self.on_input(s, msg))
            inputs.subscriptions[stream] = stream_subscription(
                self, auxiliary.message_type, auxiliary.topic, callback)
        if not self.alone:   # else the tracker follows the rate only until the model runs
            self.tracking.follow(model)

    # Stream.
    def on_eeprom(self, msg: UInt8MultiArray) -> None:
        dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
        try:
            images = eeprom_images_from_multiarray(dims, msg.data, msg.layout.data_offset)
            sensor = self.settings.sensor
            self.sensor = sensor_tables(images, Output.DIGITAL, sensor.transfer,
                                        sensor.full_scale_dps)
            if len(self.sensor.tables) != len(self.axes):
                reason = (f'the sensor sent {len(self.sensor.tables)} EEPROM images for '
                          f'{len(self.axes)} axes')
                raise ParameterError(reason)
            if self.settings.model == 'eeprom':
                self._use(self._with_saved_offset(self._build(self.values)))
        except (TempCompError, ParameterError) as err:
            self.eeprom_error = str(err)
            self.get_logger().error(f'unusable EEPROM message: {err}')
            return
        self.eeprom_error = ''
        self.get_logger().info(
            f'factory tables received: VERSION {[f.version for f in self.sensor.fields]}, '
            f'{self.sensor.outvoted_bits} out-voted bits')

    def _build(self, values: dict):
        if self.sensor is None:
            return build_model(values)
        return build_model(values, self.sensor.tables, self.sensor.full_scale_dps)

    def on_imu(self, msg: Imu) -> None:
        self.on_input('imu', msg)

    def on_input(self, stream: str, msg) -> None:
        """Pair ``msg`` and what else waits (`CompensationInputs.take`); compensate."""
        complete = self.inputs.take(stream, msg, self.settings.max_block)
        if complete:
            self.process(complete)

    def take_local(self, handoff: list) -> None:
        """Pair the raw messages a driver in this process sent, [(stream, msg)]; compensate."""
        complete = self.inputs.take_local(handoff)
        if complete:
            self.process(complete)

    def process(self, samples: list) -> None:
        """Compensate samples [(stamp_ns, {stream: message})], a block per run; publish."""
        self.last_input = time.monotonic()
        for has_temperature, part in self.inputs.runs(samples):
            self._process(part, has_temperature)

    def _process(self, samples: list, has_temperature: bool) -> None:
        """Compensate samples all with or all without a temperature as one block."""
        settings = self.settings
        if has_temperature and self.stream is None:
            # The eeprom model without its tables: the samples wait eeprom.wait_s of stamps.
            wait_ns = self.inputs.first_imu_ns + int(settings.eeprom_wait_s * 1e9)
            waiting = bisect.bisect_left([stamp for stamp, _ in samples], wait_ns)
            self.inputs.samples_waiting += waiting
            samples = samples[waiting:]
            if not samples:
                return
        stream = self._running(has_temperature)
        alone = stream is self.rate_only_stream
        block = self.inputs.block(samples, settings.supply_voltage.max_age_s, not alone)
        if block is None:
            return
        rates, clamped = block.correct(stream)
        # The tracker follows the model's output (less the learnt correction); the
        # recalibration's window takes the model in use's. Without a temperature, its
        # temperature check has nothing to judge: a constant.
        tracked, stds, in_use = self.tracking.track(block if has_temperature else replace(
            block, temperature_c=[[0.0]] * len(rates)), rates)
        if alone and stds is None:
            stds = [[settings.rate_only_offset_std_rad_s] * len(self.axes)] * len(rates)
        tracker = self.tracking.tracker
        self.outputs.publish(block, tracked, clamped, stds,
                             still=tracker is not None and tracker.still)
        self.recalibration.add(block.stamps_ns, block.raw_rad_s, block.temperature_c, in_use)

    def _running(self, has_temperature: bool):
        """Give the stream to run: the model's, else the rate only's (`alone` says why)."""
        settings = self.settings
        if has_temperature and self.stream is not None:
            if self.alone:
                self.alone = ''
                self.tracking.follow(self.model)
                self.get_logger().info(f'the {settings.model} model runs from now on '
                                       '(a temperature and the model are there)')
            return self.stream
        unpaired = settings.temperature.pairing == 'none'
        if has_temperature:
            reason = (f'no factory tables on imu/eeprom {settings.eeprom_wait_s:g} s '
                      'after the first sample: the eeprom model needs an MLX90609 driver; with '
                      'another, give a fitted model (mlx-tempcomp fit) or polynomial')
        elif unpaired:
            reason = 'no temperature (temperature.pairing none)'
        else:
            reason = (f'no temperature on {", ".join(self.inputs.temperature_topics.values())} '
                      f'{settings.temperature.wait_s:g} s after the first sample')
        if self.alone != reason:
            self.alone = reason
            std = settings.rate_only_offset_std_rad_s
            self.tracking.follow(self.rate_only, [std] * len(self.axes))
            until = '' if unpaired else \
                ', until they come' if has_temperature else ', until one comes'
            self.get_logger().warn(
                f'{reason}: the rate only, less the tracked offset, no temperature model'
                f'{until}; Imu covariance: rate noise + offset std {math.degrees(std):.3g} '
                'deg/s at most (rate_only.offset_std_rad_s)')
        return self.rate_only_stream

    # Recalibration.
    async def recalibrate(self, request, response):
        """
        Average the stream over the window, check it, learn and persist the ZRO offset.

        A coroutine: the executor keeps running the stream while it waits.
        """
        started = time.monotonic()
        stale_s = self.settings.stale_timeout_s

        def stale() -> None:
            if time.monotonic() - max(self.last_input or started, started) > stale_s:
                raise Refused(f'no input for {stale_s:g} s, the stream is stale')

        outcome = await guarded(self.service_guard, 'a ZRO recalibration',
                                lambda: self._recalibrate(stale))
        return messages.answer_trigger(self.get_logger(), response, outcome,
                                       'ZRO recalibration')

    async def _recalibrate(self, stale) -> Outcome:
        """Open the window, await it (or the stall ``stale`` raises), learn; give the outcome."""
        recalibration = self.recalibration
        if self.alone:
            raise Refused(f'no temperature model runs ({self.alone}); the ZRO offset is '
                          'learnt on top of one (the bias tracking follows the rate offset at '
                          'rest meanwhile)')
        recalibration.start(self.model, self.settings, self._correction())
        window = recalibration.window
        try:
            await await_window(self, window.samples.future, stale, _POLL_S)
            return self._learn(window)
        finally:
            recalibration.end()

    def _learn(self, window) -> Outcome:
        """
        Learn the full window's offset, run the model with it, persist it; give the answer.

        The tracker starts from the re-zeroed model (offset 0, the window mean's
        variance); its state goes into the same write as the ZRO offset.
        """
        try:
            learned = self.recalibration.learn(window, self.model, self._correction())
        except CalibrationError as err:
            raise Refused(str(err)) from None
        self._use(learned.model)
        section = self.tracking.seed(learned.state['samples'])
        outcome = self.recalibration.save(replace(learned, state={**learned.state, **section}))
        if outcome.success:
            self.tracking.wrote_with_zro(section)
        return outcome

    def _correction(self):
        """Give the learnt correction taken off now (None: learning not running)."""
        return None if self.tracking.stream is None else self.tracking.learning.applied()

    # The learnt model.
    async def save_learned_model(self, request, response):
        """
        Write the model in use as a parameter file (`CompensationLearning.learned_model`).

        A coroutine: the write runs in a thread while the stream goes on; a call of any
        calibration service meanwhile is refused (the node's `ServiceGuard`).
        """
        outcome = await guarded(self.service_guard, 'a save of the learned model',
                                self._save_learned_model)
        return messages.answer_trigger(self.get_logger(), response, outcome,
                                       'save learned model')

    async def _save_learned_model(self) -> Outcome:
        """Start the write in its thread, await it; give the outcome."""
        learning = self.tracking.learning
        saver = learning.saver
        saver.start(learning.learned_model(
            self.get_name(), [] if self.model is None else self.model.zro_offset,
            self.tracking.stream is not None))
        try:
            outcome = await await_window(self, Future(), saver.answer, _POLL_S)
        finally:
            saver.end()
        if outcome.success:
            learning.saves += 1
        return outcome

    # Parameters.
    def validate_parameters(self, parameters) -> SetParametersResult:
        """Refuse a change whose candidate settings, or model, do not build; say why."""
        candidate = dict(self.values)
        candidate.update({p.name: messages_value(p) for p in parameters})
        try:
            check_choices(COMPENSATION_SPECS, candidate)
            compensation_settings(candidate)
            if _changes_model(parameters):
                if self.recalibration.window is not None:
                    raise ParameterError('a ZRO recalibration is running; try again after it')
                self._build(candidate)
        except (ParameterError, TempCompError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def apply_parameters(self, parameters) -> None:
        """Swap in the settings (and model) of the values set, validated: from the next sample."""
        for parameter in parameters:
            self.values[parameter.name] = messages_value(parameter)
        self.settings = settings = compensation_settings(self.values)
        self.outputs.configure(settings)
        self.tracking.configure(settings, self.values)
        if _changes_model(parameters):
            # Validated in validate_parameters; swapped between two samples.
            self._use(self._with_saved_offset(self._build(self.values)))
            self.get_logger().info(f'model now {settings.model}')

    def publish_diagnostics(self) -> None:
        self._warn_waiting()
        level, text, values = compensation_status(
            settings=self.settings, model=self.model, sensor=self.sensor,
            eeprom_error=self.eeprom_error, alone=self.alone, now=time.monotonic(),
            inputs=self.inputs, outputs=self.outputs, recalibration=self.recalibration,
            tracking={**self.tracking.status_values(), **self.tracking.learning_values()})
        self.outputs.clamped_recent = False
        self.inputs.clear_recent()
        status = messages.diagnostic_status(f'{self.get_name()}: compensation',
                                            self.settings.model, level, text, values)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_publisher.publish(array)


def _changes_model(parameters) -> bool:
    return any(p.name == 'model' or p.name.startswith(MODEL_PREFIXES) for p in parameters)


def messages_value(parameter):
    """Return a parameter's value, [] for an unset array."""
    value = parameter.value
    return [] if value is None else value


def main(args=None) -> int:
    return run([CompensationNode], args, 'compensation_node')


if __name__ == '__main__':
    raise SystemExit(main())
