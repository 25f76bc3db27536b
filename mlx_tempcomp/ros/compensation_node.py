"""
Compensation node: raw rate and temperature in, temperature-compensated rate out.

Subscribes to ``imu/data_raw``, ``imu/temperature_raw`` (with several MLX90609
chips and the eeprom model, ``imu/temperature_raw/<axis>``), ``imu/eeprom`` and,
while the model needs them, ``imu/temperature_2_raw`` (a second temperature)
and ``imu/supply_voltage`` (sensor_msgs/BatteryState, its voltage); pairs
samples by stamp, runs them through the stream of the model named by ``model``
(which keeps the state of stateful effects) and publishes ``imu/data`` and
``imu/temperature``; the angular velocity covariance is ``rate_noise_rad_s``^2,
plus the square of the model's error at the sample's temperature when
``model_error.*`` gives a table. The supply voltage is held (the latest at or
before each sample's stamp, ``supply_voltage.pairing: hold``) or paired by
stamp like the temperature (``stamp``). The ``imu/recalibrate_zro`` service
(std_srvs/Trigger) learns the ZRO residual at rest and persists it.
"""

import bisect
from datetime import datetime, timezone
import itertools
import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import BatteryState, Imu, Temperature
from std_msgs.msg import UInt8MultiArray
from std_srvs.srv import Trigger

from . import messages
from .params import declare
from .qos import EEPROM_QOS, stream_publisher, stream_subscription
from .runner import run
from .service_window import await_window, SampleWindow
from ..core.conversion import Output
from ..core.errors import CalibrationError, TempCompError
from ..core.model_interface import ModelInputs
from ..core.models import AXIS_NAMES
from ..core.pairing import StampPairer, zero_order_hold
from ..core.recalibration import check_window
from ..core.table import sensor_tables
from ..node_parameters import (axes_of, build_model, check_choices, COMPENSATION_SPECS,
                               limits_of, model_error_of, ParameterError, state_file_of,
                               transfer_of)
from ..sources.bag import BagError, eeprom_images_from_multiarray
from ..state_file import Field, load_state, reject_state, StateFileError

# Parameters whose change rebuilds the model: model and those under these prefixes.
_MODEL_PREFIXES = ('eeprom.', 'polynomial.', 'linear_btc.', 'effects.', 'chain.')
_MODEL_ERROR_PREFIX = 'model_error.'
_TEMPERATURE_2 = 'temperature_2'
_SUPPLY = 'supply_voltage'
# Model inputs on topics of their own, subscribed while the model needs them:
# stream -> (`ModelInputs` field, message type, topic, value of a message).
_AUXILIARY = {
    _TEMPERATURE_2: ('temperature_2_c', Temperature, 'imu/temperature_2_raw',
                     lambda msg: msg.temperature),
    _SUPPLY: ('supply_voltage_v', BatteryState, 'imu/supply_voltage', lambda msg: msg.voltage),
}
_POLL_S = 0.05
# Without sensor.full_scale_dps or the EEPROM's RANGE, a saved offset is held to the widest
# range of the parts the driver reads (MPU-6000: +-2000 deg/s): no larger offset is real.
_WIDEST_FULL_SCALE_DPS = 2000.0
_ZRO_STATE = 'saved ZRO offset'
# An input missing this long after the start is a WARN naming what to set, repeated at most
# once a period (wall time).
WAIT_WARN_S = 5.0
WAIT_WARN_PERIOD_S = 30.0
# Held supply voltages kept: the slow input is seconds apart, a block spans less.
_HELD_SUPPLY = 64


class CompensationNode(Node):
    """Applies the configured model to the raw stream; offers ZRO recalibration."""

    def __init__(self, local_input: bool = False, **kwargs):
        """
        Build the node.

        With ``local_input`` the raw rate and temperature come from a driver in this
        process through `take_local`, not from subscriptions (bringup).
        """
        super().__init__('compensation_node', **kwargs)
        self.values = declare(self, COMPENSATION_SPECS)
        self.axes = axes_of(self.values)
        self.indices = messages.axis_indices(self.axes)
        self.transfer = transfer_of(self.values)
        self.state_path = state_file_of(self.values, self.get_name())
        self.sensor = None
        self.eeprom_error = ''
        # The model first: a node that cannot start leaves its state file as it is.
        model = build_model(self.values)
        self.saved_state = self._load_state()
        self.last_recalibration = self.saved_state or {}
        model = self._with_saved_offset(model)
        self.model = None
        self.stream = None
        self.window = None
        self.samples_out = 0
        self.blocks = 0
        self.largest_block = 0
        self.samples_waiting = 0
        self.clamped_samples = 0
        self.clamped_recent = False
        self.no_acceleration_samples = 0
        self.no_acceleration_recent = False
        self.supply_hold = self.values['supply_voltage.pairing'] == 'hold'
        self.held_supply = []     # (stamp_ns, volts), ascending stamps
        self.no_supply_samples = 0
        self.no_supply_recent = False
        self.last_input = None
        self.covariance = messages.rate_covariance(self.indices, self.values['rate_noise_rad_s'])
        self.model_error = model_error_of(self.values)

        per_axis = len(self.axes) > 1 and self.values['model'] == 'eeprom'
        self.temperature_streams = tuple(f'temperature_{axis}' for axis in self.axes) \
            if per_axis else ('temperature',)
        self.pairer = StampPairer(('imu',) + self.temperature_streams)
        self.dropped_before = 0   # by pairers replaced on a model change
        # Pairer stream -> subscription: what on_input takes waiting messages from.
        self.input_subscriptions = {}
        self.imu_publisher = stream_publisher(self, Imu, 'imu/data')
        self.temperature_publisher = stream_publisher(self, Temperature,
                                                      'imu/temperature')
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The EEPROM subscription first: when it and samples are ready together, the
        # executor takes it first, so no sample waits for a model.
        self.create_subscription(UInt8MultiArray, 'imu/eeprom', self.on_eeprom, EEPROM_QOS)
        if not local_input:
            self.input_subscriptions['imu'] = stream_subscription(
                self, Imu, 'imu/data_raw', self.on_imu)
            topics = [f'imu/temperature_raw/{axis}' for axis in self.axes] if per_axis else \
                ['imu/temperature_raw']
            for stream, topic in zip(self.temperature_streams, topics):
                self.input_subscriptions[stream] = stream_subscription(
                    self, Temperature, topic, lambda msg, s=stream: self.on_temperature(s, msg))
        # Its own group: while the service awaits its window, the default group (stream,
        # timers) keeps running in the same single thread. Reentrant, so a second request
        # is taken (and refused) while the first awaits: a mutually exclusive group would
        # hold it back and run a second recalibration afterwards.
        self.create_service(Trigger, 'imu/recalibrate_zro', self.recalibrate,
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
        eeprom = self.values['model'] == 'eeprom'
        inputs = ['raw rate and temperature from the driver in this process'] if \
            self.local_input else []
        inputs += [s.topic_name for s in self.subscriptions
                   if eeprom or s.msg_type is not UInt8MultiArray]
        outputs = [p.topic_name for p in self.publishers
                   if p.topic_name not in ('/rosout', '/parameter_events')]
        state = self.saved_state
        loaded = 'nothing saved yet' if not state else \
            (f"a {state['model']} ZRO offset {state['zro_offset']} {state['offset_unit']} "
             f"of {state['time']}")
        table = self.model_error
        covariance = '' if table is None else \
            f' (covariance: rate noise + model error at {len(table.temperature_c)} temperatures)'
        return (f'model {self.values["model"]} on axes {list(self.axes)}; waits for '
                f'{", ".join(inputs)}; publishes {", ".join(outputs)}{covariance}; state file '
                f'{self.state_path}: {loaded}')

    def _warn_waiting(self) -> None:
        """WARN, throttled, for an input still missing a few seconds after the start."""
        if time.monotonic() - self.started < WAIT_WARN_S:
            return
        model = self.values['model']
        missing = []
        if self.last_input is None:
            missing.append('no raw samples yet: start a driver_node (same namespace and '
                           'ROS_DOMAIN_ID) publishing imu/data_raw and imu/temperature_raw')
        if model == 'eeprom' and self.sensor is None:
            missing.append('the eeprom model waits for the factory tables on imu/eeprom, which '
                           'only an MLX90609 driver (device: mlx90609) or a bag holding them '
                           'sends; with an ADIS16130 or MPU-6000 choose another model '
                           '(polynomial, linear_btc, effects or chain)')
        if _SUPPLY in self.auxiliary and self.supply_hold and not self.held_supply:
            missing.append(f'the {model} model has supply_voltage terms and waits for a '
                           'voltage on imu/supply_voltage (sensor_msgs/BatteryState): remap '
                           "your supply monitor's topic to it, or set "
                           'simulation.supply_monitor_hz on a simulated MLX90609 driver')
        if missing:
            self.get_logger().warn(f'waiting {time.monotonic() - self.started:.0f} s: '
                                   + '; '.join(missing), throttle_duration_sec=WAIT_WARN_PERIOD_S)

    def destroy_node(self):
        self.get_logger().info(
            f'{self.get_name()} stopping: {self.samples_out} samples compensated in '
            f'{self.blocks} blocks, {self.samples_waiting} waited for a model or voltage, '
            f'{self.dropped_before + self.pairer.dropped} unpaired dropped, '
            f'{self.no_supply_samples} without a supply voltage, '
            f'{self.no_acceleration_samples} without acceleration')
        return super().destroy_node()

    # State file.
    def _full_scale_rad_s(self) -> float:
        full_scale_dps = self.values['sensor.full_scale_dps'] or \
            (self.sensor.full_scale_dps if self.sensor is not None else 0.0) or \
            _WIDEST_FULL_SCALE_DPS
        return math.radians(full_scale_dps)

    def _load_state(self):
        """Read the ZRO state file, checked field by field (`load_state` logs what it finds)."""
        full_scale = self._full_scale_rad_s()
        return load_state(self.state_path, zro_state_fields(full_scale), self.get_logger(),
                          _ZRO_STATE)

    def _with_saved_offset(self, model):
        """Apply the saved offset if it was learned on this very model and is within its range."""
        state = self.saved_state
        if model is None or not state:
            return model
        if state['model'] != model.name or state['fingerprint'] != model.fingerprint() or \
                tuple(state['axes']) != self.axes:
            self.get_logger().warn(
                f'{_ZRO_STATE} in {self.state_path} is whole but was learned on another model '
                f'(model {state["model"]}, axes {state["axes"]}, fingerprint '
                f'{state["fingerprint"]}; running {model.name}, {list(self.axes)}, '
                f'{model.fingerprint()}); not applied')
            return model
        try:
            offset_model = saved_offset_model(model, state, self._full_scale_rad_s())
        except StateFileError as err:
            reject_state(self.state_path, str(err), self.get_logger(), _ZRO_STATE)
            self.saved_state = None
            self.last_recalibration = {}
            return model
        self.get_logger().info(f'applied {_ZRO_STATE} {state["zro_offset"]} '
                               f'{state["offset_unit"]} from {self.state_path}')
        return offset_model

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
        # Read once here, not per sample: what the model needs besides rate and temperature.
        inputs = frozenset() if model is None else model.inputs
        self.needs_acceleration = 'acceleration_m_s2' in inputs
        self.auxiliary = tuple(stream for stream, (name, *_) in _AUXILIARY.items()
                               if name in inputs)
        for stream in self.auxiliary:
            if stream not in self.input_subscriptions:
                _, kind, topic, _ = _AUXILIARY[stream]
                callback = self.on_supply_voltage if self.held(stream) else \
                    (lambda msg, s=stream: self.on_temperature(s, msg))
                self.input_subscriptions[stream] = stream_subscription(
                    self, kind, topic, callback)
        streams = ('imu',) + self.temperature_streams + tuple(
            s for s in self.auxiliary if not self.held(s))
        if streams != self.pairer.streams:
            self.dropped_before += self.pairer.dropped
            self.pairer = StampPairer(streams)

    # Stream.
    def on_eeprom(self, msg: UInt8MultiArray) -> None:
        dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
        try:
            images = eeprom_images_from_multiarray(dims, msg.data, msg.layout.data_offset)
            self.sensor = sensor_tables(images, Output.DIGITAL, self.transfer,
                                        self.values['sensor.full_scale_dps'])
            if len(self.sensor.tables) != len(self.axes):
                msg = (f'the sensor sent {len(self.sensor.tables)} EEPROM images for '
                       f'{len(self.axes)} axes')
                raise ParameterError(msg)
            if self.values['model'] == 'eeprom':
                self._use(self._with_saved_offset(self._build(self.values)))
        except (BagError, TempCompError, ParameterError) as err:
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

    def held(self, stream: str) -> bool:
        """Tell whether an input stream is kept by zero-order hold rather than paired by stamp."""
        return stream == _SUPPLY and self.supply_hold

    def on_imu(self, msg: Imu) -> None:
        self.on_input('imu', msg)

    def on_supply_voltage(self, msg: BatteryState) -> None:
        """Keep a held supply voltage, in stamp order (a late one slots in, a repeat replaces)."""
        stamp_ns = messages.stamp_to_ns(msg.header.stamp)
        held = self.held_supply
        index = bisect.bisect_left(held, (stamp_ns,))
        if index < len(held) and held[index][0] == stamp_ns:
            held[index] = (stamp_ns, msg.voltage)
        else:
            held.insert(index, (stamp_ns, msg.voltage))
            del held[:-_HELD_SUPPLY]

    def on_temperature(self, stream: str, msg) -> None:
        if stream not in self.pairer.streams:
            return   # an auxiliary input, subscribed for an earlier model
        self.on_input(stream, msg)

    def on_input(self, stream: str, msg) -> None:
        """
        Pair ``msg``, then take what else waits on the inputs, and compensate it as one block.

        Taking the waiting messages here, up to ``max_block``, saves the executor a
        wake-up per message: that, not the model, limits a Python node's rate.
        """
        complete = self.pairer.add(stream, messages.stamp_to_ns(msg.header.stamp), msg)
        budget = self.values['max_block'] - 1
        while budget > 0:
            taken = 0
            for name, subscription in self.inputs():
                for message in itertools.islice(self._waiting(subscription), budget):
                    complete += self.pairer.add(name, messages.stamp_to_ns(message.header.stamp),
                                                message)
                    taken += 1
                    budget -= 1
            if not taken:
                break
        if complete:
            self.process(complete)

    @staticmethod
    def _waiting(subscription):
        """Take the messages waiting on ``subscription``, one by one, without a callback."""
        while True:
            with subscription.handle:
                message = subscription.handle.take_message(subscription.msg_type,
                                                           subscription.raw)
            if message is None:
                return
            yield message[0]

    def take_local(self, handoff: list) -> None:
        """Pair the raw messages a driver in this process sent, [(stream, msg)]; compensate."""
        complete = []
        for stream, msg in handoff:
            # Auxiliary inputs subscribed over DDS come that way only.
            if stream in self.pairer.streams and stream not in self.input_subscriptions:
                complete += self.pairer.add(stream, messages.stamp_to_ns(msg.header.stamp),
                                            msg)
        if complete:
            self.process(complete)

    def inputs(self):
        """Yield (pairer stream, subscription) of every input the model uses now."""
        for stream, subscription in self.input_subscriptions.items():
            if stream in self.pairer.streams:
                yield stream, subscription

    def process(self, samples: list) -> None:
        """Compensate paired samples [(stamp_ns, {stream: message})] as one block; publish."""
        self.last_input = time.monotonic()
        stream = self.stream
        if stream is None:
            self.samples_waiting += len(samples)
            return
        if self.needs_acceleration:
            # REP-145: covariance[0] = -1 says the message has no acceleration.
            usable = [s for s in samples if s[1]['imu'].linear_acceleration_covariance[0] != -1.0]
            if len(usable) < len(samples):
                self.no_acceleration_samples += len(samples) - len(usable)
                self.no_acceleration_recent = True
            samples = usable
            if not samples:
                return
        held_supply = None
        if _SUPPLY in self.auxiliary and self.supply_hold:
            # Voltages waiting in the queue count too: the executor may have served the
            # samples' subscriptions first.
            for message in self._waiting(self.input_subscriptions[_SUPPLY]):
                self.on_supply_voltage(message)
            if not self.held_supply:
                # At start, before the monitor's first reading: waiting, not a fault.
                self.samples_waiting += len(samples)
                return
            held_supply, usable = zero_order_hold(
                [stamp for stamp, _ in samples], [stamp for stamp, _ in self.held_supply],
                [volts for _, volts in self.held_supply],
                int(self.values['supply_voltage.max_age_s'] * 1e9))
            if not usable.all():
                self.no_supply_samples += int(np.count_nonzero(~usable))
                self.no_supply_recent = True
                samples = [s for s, keep in zip(samples, usable.tolist()) if keep]
                held_supply = held_supply[usable]
                if not samples:
                    return
        raw = [messages.imu_rates(parts['imu'], self.indices) for _, parts in samples]
        temperatures = [[parts[s].temperature for s in self.temperature_streams]
                        for _, parts in samples]
        # The model's inputs beyond rate and temperature: field of ModelInputs -> column.
        extra = {_AUXILIARY[name][0]: [_AUXILIARY[name][3](parts[name]) for _, parts in samples]
                 for name in self.auxiliary if not self.held(name)}
        if held_supply is not None:
            extra[_AUXILIARY[_SUPPLY][0]] = held_supply.tolist()
        if self.needs_acceleration:
            extra['acceleration_m_s2'] = [[parts['imu'].linear_acceleration.x,
                                           parts['imu'].linear_acceleration.y,
                                           parts['imu'].linear_acceleration.z]
                                          for _, parts in samples]
        extra['time_s'] = [stamp / 1e9 for stamp, _ in samples]
        if len(samples) == 1:
            # One sample, no numpy: the same numbers, bit for bit, as a block of one.
            rate, clamped = stream.correct_one(raw[0], temperatures[0], ModelInputs(
                **{name: column[0] for name, column in extra.items()}))
            rates, clamped = [rate], int(clamped)
        else:
            result = stream.correct_block(raw, temperatures, ModelInputs(
                **{name: np.array(column) for name, column in extra.items()}))
            rates = result.rate_rad_s.tolist()
            clamped = int(np.count_nonzero(result.temperature_clamped.any(axis=1)))
        if clamped:
            self.clamped_samples += clamped
            self.clamped_recent = True
        covariances = self._covariances(temperatures)
        window = self.window
        first = self.temperature_streams[0]
        for row, ((stamp_ns, parts), rate) in enumerate(zip(samples, rates)):
            # The input messages go out again, rate rewritten (the rest passes through
            # unchanged): building new ones would cost more than the model.
            imu = parts['imu']
            if len(self.temperature_streams) == 1:
                self.temperature_publisher.publish(parts[first])
            else:
                self.temperature_publisher.publish(messages.temperature_message(
                    imu.header.stamp, imu.header.frame_id,
                    sum(temperatures[row]) / len(temperatures[row]), parts[first].variance))
            self.imu_publisher.publish(messages.set_rates(imu, self.indices, rate,
                                                          covariances[row]))
            if window is not None:
                window.add(stamp_ns, raw[row], temperatures[row], rate)
        self.samples_out += len(samples)
        self.blocks += 1
        self.largest_block = max(self.largest_block, len(samples))

    def _covariances(self, temperatures: list) -> list:
        """
        Give the angular velocity covariance of each sample at its temperatures.

        rate_noise_rad_s^2, plus the model error's square at the temperature
        when a table is given; with the noise unknown (0) it stays all 0.
        """
        noise = self.values['rate_noise_rad_s']
        if self.model_error is None or noise <= 0.0:
            return [self.covariance] * len(temperatures)
        return [messages.diagonal_covariance(self.indices, row)
                for row in self.model_error.variance(noise, temperatures).tolist()]

    # Recalibration.
    async def recalibrate(self, request, response):
        """
        Average the stream over the window, check it, learn and persist the ZRO offset.

        A coroutine: the executor keeps running the stream while it waits.
        """
        response.success = False
        if self.window is not None:
            response.message = 'refused: a recalibration is already running'
            return response
        model = self.model
        if model is None:
            response.message = 'refused: no model yet (waiting for the EEPROM tables)'
            return response
        try:
            limits = limits_of(self.values)
        except (ParameterError, TempCompError) as err:
            response.message = f'refused: {err}'
            return response
        duration_s = self.values['recalibration.duration_s']
        window = SampleWindow(int(duration_s * 1e9))
        fingerprint = model.fingerprint()
        started = time.monotonic()
        stale_s = self.values['stale_timeout_s']

        def stale() -> str:
            if time.monotonic() - max(self.last_input or started, started) > stale_s:
                return f'refused: no input for {stale_s:g} s, the stream is stale'
            return ''

        self.window = window
        try:
            refusal = await await_window(self, window.future, stale, _POLL_S)
            response.message = refusal or self._finish_window(window, model, fingerprint,
                                                              limits, duration_s)
        finally:
            self.window = None
        response.success = messages.trigger_succeeded(response.message)
        messages.log_trigger(self.get_logger(), response, 'ZRO recalibration')
        return response

    def _finish_window(self, window: SampleWindow, model, fingerprint: str, limits,
                       duration_s: float) -> str:
        raw, temperature, corrected = window.columns()
        if self.model is not model or model.fingerprint() != fingerprint:
            return 'refused: the model changed during the window'
        try:
            stats = check_window(corrected, temperature.mean(axis=1), limits)
        except CalibrationError as err:
            return f'refused: {err}'
        offset = model.learn_zro_offset(raw, temperature, corrected)
        new_model = model.with_zro_offset(offset)
        offset_rad_s = new_model.offset_rad_s(stats.temperature_c)
        self._use(new_model)
        state = {'model': model.name, 'fingerprint': model.fingerprint(),
                 'axes': list(self.axes), 'zro_offset': [float(v) for v in offset],
                 'offset_unit': model.offset_unit,
                 'zro_offset_rad_s': [float(v) for v in offset_rad_s],
                 'temperature_c': stats.temperature_c, 'samples': stats.samples,
                 'time': datetime.now(timezone.utc).isoformat(timespec='seconds')}
        self.last_recalibration = state
        self.saved_state = state
        summary = ', '.join(f'{axis} {value:.6g}' for axis, value in zip(self.axes,
                                                                         offset_rad_s))
        text = (f'ZRO offset {summary} rad/s at {stats.temperature_c:.2f} C from '
                f'{stats.samples} samples over {duration_s:g} s')
        return messages.saved_reply(self.state_path, state, text)

    # Parameters.
    def validate_parameters(self, parameters) -> SetParametersResult:
        candidate = dict(self.values)
        candidate.update({p.name: messages_value(p) for p in parameters})
        try:
            check_choices(COMPENSATION_SPECS, candidate)
            if any(p.name.startswith(_MODEL_ERROR_PREFIX) for p in parameters):
                model_error_of(candidate)
            if _changes_model(parameters):
                if self.window is not None:
                    raise ParameterError('a ZRO recalibration is running; try again after it')
                self._build(candidate)
        except (ParameterError, TempCompError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def apply_parameters(self, parameters) -> None:
        for parameter in parameters:
            self.values[parameter.name] = messages_value(parameter)
        self.covariance = messages.rate_covariance(self.indices, self.values['rate_noise_rad_s'])
        self.model_error = model_error_of(self.values)
        if _changes_model(parameters):
            # Validated in validate_parameters; swapped between two samples.
            self._use(self._with_saved_offset(self._build(self.values)))
            self.get_logger().info(f'model now {self.values["model"]}')

    def publish_diagnostics(self) -> None:
        self._warn_waiting()
        model = self.model
        age = None if self.last_input is None else time.monotonic() - self.last_input
        recal = self.last_recalibration
        values = {
            'model': self.values['model'],
            'fingerprint': '' if model is None else model.fingerprint(),
            'zro_offset': [] if model is None else list(model.zro_offset),
            'offset_unit': '' if model is None else model.offset_unit,
            'samples_out': self.samples_out, 'samples_waiting': self.samples_waiting,
            'blocks': self.blocks, 'largest_block': self.largest_block,
            'unpaired_dropped': self.dropped_before + self.pairer.dropped,
            'temperature_clamped_samples': self.clamped_samples,
            'model_error_temperatures': 0 if self.model_error is None else
            len(self.model_error.temperature_c),
            'no_acceleration_samples': self.no_acceleration_samples,
            'no_supply_voltage_samples': self.no_supply_samples,
            'input_age_s': float('nan') if age is None else age,
            'last_recalibration_time': recal.get('time', 'never'),
            'last_recalibration_offset_rad_s': recal.get('zro_offset_rad_s', []),
            'last_recalibration_temperature_c': recal.get('temperature_c', float('nan')),
            'state_file': self.state_path,
            'eeprom_outvoted_bits': 0 if self.sensor is None else self.sensor.outvoted_bits,
        }
        if age is None or age > self.values['stale_timeout_s']:
            level, text = DiagnosticStatus.ERROR, 'stale input: no raw samples'
        elif self.eeprom_error:
            level, text = DiagnosticStatus.ERROR, f'EEPROM unusable: {self.eeprom_error}'
        elif self.no_acceleration_recent:
            level, text = (DiagnosticStatus.ERROR,
                           f'the {self.values["model"]} model needs acceleration but Imu '
                           'messages carry none (linear_acceleration_covariance[0] = -1): '
                           f'{self.no_acceleration_samples} samples not compensated')
        elif self.no_supply_recent:
            level, text = (DiagnosticStatus.ERROR,
                           f'the {self.values["model"]} model needs the supply voltage but '
                           'imu/supply_voltage gave none within supply_voltage.max_age_s '
                           f'({self.values["supply_voltage.max_age_s"]:g} s) of the samples: '
                           f'{self.no_supply_samples} samples not compensated')
        elif model is None:
            level, text = DiagnosticStatus.WARN, 'waiting for the EEPROM tables'
        elif _SUPPLY in self.auxiliary and self.supply_hold and not self.held_supply:
            level, text = (DiagnosticStatus.WARN,
                           'waiting for a supply voltage on imu/supply_voltage')
        elif self.clamped_recent:
            level, text = (DiagnosticStatus.WARN,
                           'temperature outside the calibrated range: clamped')
        else:
            level, text = DiagnosticStatus.OK, f'compensating ({self.values["model"]})'
        self.clamped_recent = False
        self.no_acceleration_recent = False
        self.no_supply_recent = False
        status = messages.diagnostic_status(f'{self.get_name()}: compensation',
                                            self.values['model'], level, text, values)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_publisher.publish(array)


def _changes_model(parameters) -> bool:
    return any(p.name == 'model' or p.name.startswith(_MODEL_PREFIXES) for p in parameters)


def zro_state_fields(full_scale_rad_s: float) -> tuple:
    """Give what the ZRO state file must hold: the keys `_finish_window` writes, checked."""
    return (Field('model', 'text'), Field('fingerprint', 'text'),
            Field('axes', 'text', length=(1, len(AXIS_NAMES)), choices=AXIS_NAMES),
            Field('zro_offset', 'number', length='axes'),
            Field('offset_unit', 'text', choices=('rad/s', 'LSB', 'mV')),
            Field('zro_offset_rad_s', 'number', length='axes', low=-full_scale_rad_s,
                  high=full_scale_rad_s),
            Field('temperature_c', 'number', low=-273.15, high=1000.0),
            Field('samples', 'integer', low=1), Field('time', 'text'))


def saved_offset_model(model, state: dict, full_scale_rad_s: float):
    """
    Give ``model`` with the offset of a checked ZRO ``state`` learned on it.

    StateFileError when the offset, as a rate at the state's temperature, is
    beyond the full scale: no gyro reads such a rate, so no such offset is real.
    """
    try:
        offset_model = model.with_zro_offset(state['zro_offset'])
        offset_rad_s = offset_model.offset_rad_s(state['temperature_c'])
    except TempCompError as err:
        raise StateFileError(str(err)) from None
    if not all(abs(v) <= full_scale_rad_s for v in offset_rad_s):
        unit = state['offset_unit']
        as_rate = '' if unit == 'rad/s' else \
            f' ({[float(v) for v in offset_rad_s]} rad/s at {state["temperature_c"]} C)'
        msg = (f'zro_offset {state["zro_offset"]} {unit}{as_rate} is beyond the full scale '
               f'+-{full_scale_rad_s:.4g} rad/s ({math.degrees(full_scale_rad_s):g} deg/s)')
        raise StateFileError(msg)
    return offset_model


def messages_value(parameter):
    """Return a parameter's value, [] for an unset array."""
    value = parameter.value
    return [] if value is None else value


def main(args=None) -> int:
    return run([CompensationNode], args, 'compensation_node')


if __name__ == '__main__':
    raise SystemExit(main())
