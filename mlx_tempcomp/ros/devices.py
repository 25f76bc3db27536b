"""
Driver streams of the ADIS16130 and the MPU-6000/6500, and their services.

Each reads one part (simulated or over spidev) on the driver's schedule and
publishes through `DriverNode.publish_raw`: no EEPROM, one temperature. The
MPU stream writes the offset registers saved in its state file at start,
offers ``imu/calibrate_offsets`` and, given a bias model, refreshes the gyro
offset registers as the temperature moves; the ADIS16130 stream offers
``imu/run_bias_procedure`` (AN-1042, fed from the stream).
"""

import collections
import dataclasses
from datetime import datetime, timezone
import gc
import math
import os
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.task import Future
from std_msgs.msg import String
from std_srvs.srv import Trigger

from . import messages
from .qos import STATUS_QOS
from ..core.bias_procedure import BiasProcedure, MIN_WINDOW_SAMPLES, Phase, ProcedureSettings
from ..core.errors import CalibrationError, TempCompError
from ..core.models import AXIS_NAMES
from ..core.noise import allan_deviation, MIN_SAMPLES
from ..core.offsets import accel_offset_lsb, gyro_offset_lsb, rest_bias
from ..hardware.errors import HardwareError
from ..hardware.mpu6000 import ACCEL_LSB_PER_G, GYRO_LSB_PER_DPS
from ..model_params import linear_btc_parameters, parameter_file, write_parameter_file
from ..node_parameters import axes_of, build_model, effects_of, node_values, ParameterError
from ..simulation.adis16130 import Adis16130Truth, Fault as AdisFault
from ..simulation.mlx90609 import Fault
from ..simulation.mpu6000 import MpuTruth
from ..simulation.physics import ThermalProfile
from ..sources import adis16130, mpu6000
from ..sources.decimation import Decimator
from ..state_file import Field, load_state, StateFileError, write_state

# Faults both parts can simulate: MISO stuck high or low.
DEVICE_FAULTS = (Fault.NONE, Fault.SILENT_HIGH, Fault.SILENT_LOW)
_STUCK_MISO = {Fault.NONE: None, Fault.SILENT_HIGH: 0xFF, Fault.SILENT_LOW: 0x00}
# A sampling driver that falls this far behind (wall time) skips the older samples (missed
# reads); a lossless simulated one lets its clock fall behind instead.
MAX_BACKLOG_S = 0.25
# Missed reads above this share of the reads due over the last MISSED_WINDOW_S are a WARN
# (log, throttled, and diagnostics) while they happen.
MISSED_WARN_SHARE = 0.001
MISSED_WINDOW_S = 1.0
MISSED_LOG_THROTTLE_S = 5.0
# Shortest timer period of a driver: each tick costs the executor a wake-up.
MIN_TICK_S = 0.001
# Natural sample rates: the ADIS16130 refreshes RATE and TEMP at 5.7 kHz (AN-1042); the
# MPU-6000's gyro runs at 8 kHz with DLPF_CFG 0 or 7, else 1 kHz, over 1 + SMPLRT_DIV.
ADIS16130_SAMPLE_RATE_HZ = 5700.0
# A service window that gets no sample for this long (wall time) gives up.
STALL_TIMEOUT_S = 5.0
_POLL_S = 0.1


def _thermal(values: dict, time_constant_s: float) -> ThermalProfile:
    return ThermalProfile.cycle(tuple(values['simulation.cycle_temperatures_c']),
                                values['simulation.ramp_c_per_min'],
                                values['simulation.start_temperature_c'], time_constant_s,
                                values['simulation.hold_s'])


def _chip_select(values: dict, device: str) -> int:
    chip_selects = values['spi.chip_selects']
    if len(chip_selects) != 1:
        msg = (f'invalid parameter spi.chip_selects: the {device} is one part on one chip '
               f'select, got {len(chip_selects)}')
        raise ParameterError(msg)
    return chip_selects[0]


def _speed_hz(values: dict, default_hz: int) -> int:
    return values['spi.speed_hz'] or default_hz


def refuse_fault() -> None:
    """Refuse ``simulation.fault`` on a source that is not simulated."""
    raise ParameterError('simulation.fault applies only to the simulated source')


def _missed_share(missed: int, due: int, when: str) -> str:
    if not due or missed <= MISSED_WARN_SHARE * due:
        return ''
    return (f'{missed} of {due} device reads missed {when} ({100.0 * missed / due:.2g} %): '
            'the driver cannot keep up')


class TimedStream:
    """
    A part sampled at its own rate and published at a lower one, each message the mean.

    Subclasses give `read`, `publish` and `advance_to` (simulated time) and call
    `start_schedule` with the part's natural sample rate once the part is ready.
    Device sample k is due at k / ``sample_rate_hz`` after the start (simulated
    sources: in simulated time, paced at ``real_time_factor``; real ones: wall
    time); every timer tick reads the samples now due and publishes each publish
    interval that is complete, with the mean of its samples, stamped at their
    mean time (`mlx_tempcomp.sources.decimation`). A failed or saturated read is
    skipped and counted; samples more than MAX_BACKLOG_S behind are skipped and
    counted as missed reads, unless the source is ``lossless`` (simulated only):
    then the schedule slides instead, so every sample is read and the simulated
    clock falls behind wall time.
    """

    def start_schedule(self, node, real_time_factor, natural_rate_hz: float,
                       lossless: bool = False) -> None:
        self.node = node
        values = node.values
        publish_rate_hz = values['publish_rate_hz']
        sample_rate_hz = values['sample_rate_hz'] or natural_rate_hz
        if sample_rate_hz < publish_rate_hz:
            msg = (f'invalid parameter sample_rate_hz: {sample_rate_hz:g} Hz is below '
                   f'publish_rate_hz ({publish_rate_hz:g} Hz); every message averages the '
                   'samples of its interval, so sample at least as fast')
            raise ParameterError(msg)
        self.decimator = Decimator(sample_rate_hz, publish_rate_hz)
        self.next_index = 0
        self.samples_read = 0
        self.missed_reads = 0
        self.reads_due = 0
        self.reported = (0, 0)      # (reads due, missed) at the last status
        # (wall time, reads due, reads missed) of the ticks of the last MISSED_WINDOW_S, and
        # their sums.
        self.recent_ticks = collections.deque()
        self.recent_due = self.recent_missed = 0
        self.messages = 0
        self.samples_per_message = 0
        self.failed_reads = 0
        self.saturated = 0
        self.consecutive_failures = 0
        self.last_error = ''
        self.last_sample = time.monotonic()
        self.real_time_factor = real_time_factor
        self.lossless = lossless
        self.start_ns = node.get_clock().now().nanoseconds
        self.start_wall = time.monotonic()
        tick = 1.0 / publish_rate_hz / (real_time_factor or 1.0)
        self.timer = node.create_timer(max(tick, MIN_TICK_S), self.tick)
        # What start-up allocated (rclpy, numpy, the part and its tables: about 90,000
        # objects) lives as long as the process: out of the collector's sight, a full
        # collection takes well under 1 ms instead of about 60 ms of CPU, which on a busy
        # machine stretched past MAX_BACKLOG_S and cost device reads.
        gc.freeze()

    @property
    def rates(self) -> str:
        return (f'sampling at {self.decimator.sample_rate_hz:g} Hz, publishing at '
                f'{self.decimator.publish_rate_hz:g} Hz'
                + (', lossless (the simulated clock may fall behind wall time)'
                   if self.lossless else ''))

    def tick(self) -> None:
        rate_hz = self.decimator.sample_rate_hz
        factor = self.real_time_factor or 1.0
        now = time.monotonic()
        due = int(math.floor((now - self.start_wall) * factor * rate_hz + 1e-9)) + 1
        reads_due = due - self.next_index                     # samples 0 .. due - 1
        behind = reads_due - max(1, int(MAX_BACKLOG_S * factor * rate_hz))
        missed = 0
        if behind > 0:
            if self.lossless:
                self.start_wall += behind / rate_hz / factor
                due -= behind
                reads_due -= behind
            else:
                missed = behind
                self.missed_reads += missed
                self.next_index += missed
        self._count_missed(now, reads_due, missed)
        for index in range(self.next_index, due):
            if self.real_time_factor is not None:
                self.advance_to(index / rate_hz)
            sample = self._read_one()
            if sample is not None:
                self.samples_read += 1
                self._publish(self.decimator.add(index, sample))
        self.next_index = due
        self._publish(self.decimator.close_before(due))
        self.node.hand_off()

    def _count_missed(self, now: float, reads_due: int, missed: int) -> None:
        self.reads_due += reads_due
        recent = self.recent_ticks
        recent.append((now, reads_due, missed))
        self.recent_due += reads_due
        self.recent_missed += missed
        while recent[0][0] < now - MISSED_WINDOW_S:
            _, old_due, old_missed = recent.popleft()
            self.recent_due -= old_due
            self.recent_missed -= old_missed
        if missed:
            warning = _missed_share(self.recent_missed, self.recent_due,
                                    f'in the last {MISSED_WINDOW_S:g} s')
            if warning:
                self.node.get_logger().warn(warning,
                                            throttle_duration_sec=MISSED_LOG_THROTTLE_S)

    def missing_reads(self) -> str:
        """Say how many reads were missed since the last call if too many, else ''."""
        due, missed = self.reported
        self.reported = (self.reads_due, self.missed_reads)
        return _missed_share(self.missed_reads - missed, self.reads_due - due,
                             'since the last status')

    def _read_one(self):
        try:
            sample = self.read()
        except HardwareError as err:
            self.failed_reads += 1
            self.consecutive_failures += 1
            self.last_error = str(err)
            self.node.get_logger().warn(f'read failed: {err}', throttle_duration_sec=5.0)
            return None
        self.consecutive_failures = 0
        if sample.saturated:
            self.saturated += 1
            return None
        self.last_sample = time.monotonic()
        return sample

    def _publish(self, interval) -> None:
        if interval is None:
            return
        self.messages += 1
        self.samples_per_message = interval.samples
        self.publish(self.start_ns + int(round(interval.time_s * 1e9)), interval.mean)

    def sampling_status(self) -> dict:
        """Counters of the sampling, for diagnostics."""
        return {'sample_rate_hz': self.decimator.sample_rate_hz,
                'publish_rate_hz': self.decimator.publish_rate_hz,
                'samples_read': self.samples_read, 'messages': self.messages,
                'samples_per_message': self.samples_per_message,
                'missed_reads': self.missed_reads, 'failed_reads': self.failed_reads}

    def summary(self) -> str:
        """One line on the sampling so far, logged when the driver stops."""
        return (f'sampling: {self.samples_read} samples read, {self.missed_reads} missed, '
                f'{self.failed_reads} failed, {self.saturated} saturated; {self.messages} '
                'messages published')

    def advance_to(self, time_s: float) -> None:
        raise NotImplementedError

    def read(self):
        raise NotImplementedError

    def publish(self, stamp_ns: int, sample) -> None:
        raise NotImplementedError


class DeviceStream(TimedStream):
    """One ADIS16130 or MPU-6000 part, simulated or on spidev."""

    def __init__(self, node, source, hardware_id: str, simulated: bool,
                 natural_rate_hz: float):
        self.source = source
        self.hardware_id = hardware_id
        self.simulated = simulated
        # Start-up took simulated time (resets, settling): the schedule starts after it.
        self.source_start_s = source.clock.now_s if simulated else 0.0
        self.start_schedule(node, node.values['simulation.real_time_factor'] if simulated
                            else None, natural_rate_hz,
                            simulated and node.values['simulation.lossless'])
        node.get_logger().info(f'{hardware_id}: {self.rates}')

    def advance_to(self, time_s: float) -> None:
        self.source.advance_to(self.source_start_s + time_s)

    def check_fault(self, value: str) -> None:
        """Raise `ParameterError` unless ``simulation.fault`` = ``value`` can be switched on."""
        if not self.simulated:
            refuse_fault()
        if Fault(value) not in DEVICE_FAULTS:
            choices = ', '.join(f.value for f in DEVICE_FAULTS)
            msg = (f'invalid parameter simulation.fault: the simulated {self.node.device} '
                   f'knows {choices}, not {value!r}')
            raise ParameterError(msg)

    def set_fault(self, value: str) -> None:
        raise NotImplementedError

    def extra_status(self) -> dict:
        return {}

    def status(self) -> tuple:
        values = {'state': 'failing' if self.consecutive_failures else 'streaming',
                  'device': self.node.device, **self.sampling_status(),
                  **self.source.counters, **self.extra_status(), 'last_error': self.last_error}
        missed = self.missing_reads()
        if self.consecutive_failures:
            return DiagnosticStatus.ERROR, f'SPI reads failing: {self.last_error}', values
        if missed:
            return DiagnosticStatus.WARN, missed, values
        if self.saturated:
            return DiagnosticStatus.WARN, f'{self.saturated} saturated samples', values
        return DiagnosticStatus.OK, 'streaming', values

    def close(self) -> None:
        self.source.close()


def simulated_adis(values: dict) -> adis16130.SimulatedSensor:
    """Return the simulated ADIS16130 the driver reads for these parameter values, started."""
    rate_dps = values['simulation.rate_dps']
    if len(rate_dps) != 1:
        msg = (f'invalid parameter simulation.rate_dps: the adis16130 measures one '
               f'axis, give one value, got {len(rate_dps)}')
        raise ParameterError(msg)
    truth = Adis16130Truth(bias_dps=values['simulation.bias_dps'],
                           bias_dps_per_c=values['simulation.bias_dps_per_c'],
                           effects=effects_of(values))
    config = adis16130.SimulationConfig(
        seed=values['simulation.seed'], resolution_bits=values['adis16130.resolution_bits'],
        truth=truth, thermal=_thermal(values, values['simulation.die_time_constant_s']),
        rate_dps=rate_dps[0], supply_v=values['simulation.supply_v'],
        sclk_hz=float(_speed_hz(values, adis16130.DEFAULT_SPEED_HZ)))
    return adis16130.SimulatedSensor(config)


class AdisStream(DeviceStream):
    """An ADIS16130 (one axis); offers the AN-1042 bias procedure as a service."""

    def __init__(self, node):
        values = node.values
        if len(node.axes) != 1:
            msg = (f'invalid parameter axes: the adis16130 measures one axis, got '
                   f'{list(node.axes)}')
            raise ParameterError(msg)
        bits = values['adis16130.resolution_bits']
        if bits not in (16, 24):
            msg = f'invalid parameter adis16130.resolution_bits: 24 or 16, got {bits}'
            raise ParameterError(msg)
        self.oversample = values['oversample']
        speed_hz = _speed_hz(values, adis16130.DEFAULT_SPEED_HZ)
        if values['source'] == 'simulated':
            source = simulated_adis(values)
            hardware_id = f'simulated ADIS16130 (seed {values["simulation.seed"]})'
        else:
            chip_select = _chip_select(values, 'adis16130')
            source = adis16130.spidev_sensor(
                values['spi.bus'], chip_select, speed_hz, values['spi.mode'], bits,
                values['adis16130.verify_registers'])
            hardware_id = f'ADIS16130 on /dev/spidev{values["spi.bus"]}.{chip_select}'
        self.bits = bits
        self.procedure = None
        self.status_publisher = node.create_publisher(String, 'imu/bias_procedure/status',
                                                      STATUS_QOS)
        node.create_service(Trigger, 'imu/run_bias_procedure', self.run_bias_procedure,
                            callback_group=ReentrantCallbackGroup())
        super().__init__(node, source, f'{hardware_id}, {bits}-bit',
                         values['source'] == 'simulated', ADIS16130_SAMPLE_RATE_HZ)

    def read(self):
        return self.source.read(self.oversample)

    def publish(self, stamp_ns: int, sample) -> None:
        rate_rad_s = float(sample.rate_rad_s[0])
        temperature_c = float(sample.temperature_c[0])
        self.node.publish_raw(stamp_ns, [rate_rad_s], [temperature_c])
        if self.procedure is not None:
            self.procedure.add(stamp_ns / 1e9, rate_rad_s, temperature_c)

    def set_fault(self, value: str) -> None:
        self.source.fault = AdisFault(value)

    def extra_status(self) -> dict:
        running = self.procedure
        return {'resolution_bits': self.bits,
                'bias_procedure': 'idle' if running is None else running.procedure.phase.value}

    async def run_bias_procedure(self, request, response):
        """
        Run AN-1042's bias procedure on the stream; write the linear_btc parameter file.

        A coroutine: the stream keeps flowing (and feeding it) while it waits.
        """
        response.success = False
        if self.procedure is not None:
            response.message = 'refused: a bias procedure is already running'
            return response
        values = self.node.values
        try:
            running = _RunningProcedure(self, values)
        except (ParameterError, TempCompError) as err:
            response.message = f'refused: {err}'
            return response
        self.procedure = running
        timer = self.node.create_timer(1.0, running.report)
        running.announce()
        try:
            error = await running.future
        finally:
            self.procedure = None
            self.node.destroy_timer(timer)
        response.message = f'refused: {error}' if error else running.finish()
        response.success = messages.trigger_succeeded(response.message)
        self.status_publisher.publish(String(
            data=('done: ' if response.success else 'failed: ') + response.message))
        messages.log_trigger(self.node.get_logger(), response, 'bias procedure')
        return response


def _noise_figures(time_s, rate_rad_s):
    return allan_deviation(time_s, rate_rad_s.reshape(-1, 1), ('rate',))[0]


class _RunningProcedure:
    """One bias procedure: the state machine, its future and where it writes."""

    def __init__(self, stream: AdisStream, values: dict):
        self.stream = stream
        prefix = 'adis16130.bias_procedure.'
        rate_hz = values['publish_rate_hz']
        allan_s = values[prefix + 'allan_record_s']
        pbc_s = values[prefix + 'pbc_s'] or None
        for name, seconds in (('average_s', values[prefix + 'average_s']), ('pbc_s', pbc_s)):
            if seconds is not None and seconds * rate_hz < MIN_WINDOW_SAMPLES:
                msg = (f'invalid parameter {prefix}{name}: {seconds:g} s at rate_hz '
                       f'{rate_hz:g} gives fewer than {MIN_WINDOW_SAMPLES} samples')
                raise ParameterError(msg)
        if 0.0 < allan_s * rate_hz < MIN_SAMPLES:
            msg = (f'invalid parameter {prefix}allan_record_s: {allan_s:g} s at rate_hz '
                   f'{rate_hz:g} gives fewer than the {MIN_SAMPLES} samples an Allan '
                   'deviation needs (0 skips it)')
            raise ParameterError(msg)
        if pbc_s is None and allan_s == 0.0:
            msg = (f'invalid parameter {prefix}pbc_s: 0 (advised by the rest record) needs '
                   f'{prefix}allan_record_s > 0')
            raise ParameterError(msg)
        settings = ProcedureSettings(
            average_s=values[prefix + 'average_s'], self_heat_s=values[prefix + 'self_heat_s'],
            settle_s=values[prefix + 'settle_s'], pbc_s=pbc_s, allan_record_s=allan_s,
            min_temperature_change_c=values[prefix + 'min_temperature_change_c'],
            rate_noise_rad_s=values['rate_noise_rad_s'] or None)
        self.procedure = BiasProcedure(settings, _noise_figures if allan_s > 0.0 else None)
        path = values[prefix + 'output_file'] or os.path.join(
            '~', '.ros', 'mlx_tempcomp', f'{stream.node.get_name()}_linear_btc.yaml')
        self.path = os.path.expanduser(path)
        self.node_name = values[prefix + 'node_name']
        self.phase = self.procedure.phase
        self.future = Future()

    def add(self, time_s: float, rate_rad_s: float, temperature_c: float) -> None:
        if self.future.done():
            return
        try:
            phase = self.procedure.add(time_s, rate_rad_s, temperature_c)
        except CalibrationError as err:
            self.future.set_result(str(err))
            return
        if phase is not self.phase:
            closed, self.phase = self.phase, phase
            self.publish(f'{closed.value} closed{self._closed_text(closed)}')
            if phase is Phase.DONE:
                self.future.set_result('')
            else:
                self.announce()

    def _closed_text(self, phase: Phase) -> str:
        p = self.procedure
        if phase is Phase.POINT_1:
            return f': T1 {p.point_1.temperature_c:.4f} C, B1 {p.point_1.bias_rad_s:.6g} rad/s'
        if phase is Phase.POINT_2:
            return (f': T2 {p.point_2.temperature_c:.4f} C, B2 {p.point_2.bias_rad_s:.6g} '
                    f'rad/s, BTC {p.btc_rad_s_per_c:.6g} rad/s/C')
        if phase is Phase.REST_RECORD:
            return f': rate_noise_rad_s {p.noise.rate_noise_rad_s:.4g}'
        return ''

    def announce(self) -> None:
        phase = self.procedure.phase
        self.publish(f'phase {phase.value}: {self.procedure.phase_duration_s(phase):g} s')

    def report(self) -> None:
        """Publish the progress; give up when the stream stalled (a timer, once a second)."""
        if self.future.done():
            return
        stalled_s = time.monotonic() - self.stream.last_sample
        if stalled_s > STALL_TIMEOUT_S:
            self.future.set_result(f'no sample for {stalled_s:.1f} s: the stream stalled '
                                   f'({self.stream.last_error or "no error"})')
            return
        phase = self.procedure.phase
        self.publish(f'phase {phase.value}: {100.0 * self.procedure.progress:.0f} % of '
                     f'{self.procedure.phase_duration_s(phase):g} s')

    def publish(self, text: str) -> None:
        self.stream.status_publisher.publish(String(data=text))

    def finish(self) -> str:
        result = self.procedure.result
        axes = self.stream.node.axes
        parameters = linear_btc_parameters(result.model, axes)
        if result.noise is not None:
            parameters['rate_noise_rad_s'] = float(result.noise.rate_noise_rad_s)
        p1, p2 = result.point_1, result.point_2
        summary = (f'T1 {p1.temperature_c:.4f} C, B1 {p1.bias_rad_s:.6g} rad/s, '
                   f'T2 {p2.temperature_c:.4f} C, B2 {p2.bias_rad_s:.6g} rad/s, '
                   f'BTC {result.btc_rad_s_per_c:.6g} rad/s/C '
                   f'({math.degrees(result.btc_rad_s_per_c):+.5f} deg/s/C), '
                   f'PBC {result.pbc_rad_s:.6g} rad/s, T3 {result.t3_c:.4f} C')
        header = (f'ADIS16130 bias procedure (AN-1042) by {self.stream.node.get_name()} '
                  f'({self.stream.hardware_id}): {summary}\n'
                  f'Use: compensation_node --ros-args --params-file {self.path}')
        try:
            os.makedirs(os.path.dirname(self.path) or '.', exist_ok=True)
            write_parameter_file(self.path, parameter_file(self.node_name, parameters), header)
        except OSError as err:
            return f'applied but not saved: {summary}; cannot write {self.path}: {err.strerror}'
        return f'{summary}; wrote {self.path}'


class _RestWindow:
    """Samples collected for one offset calibration; its future resolves when full."""

    def __init__(self, duration_ns: int):
        self.duration_ns = duration_ns
        self.start_ns = None
        self.gyro, self.acceleration, self.temperature = [], [], []
        self.future = Future()

    def add(self, stamp_ns: int, sample) -> None:
        if self.future.done():
            return
        if self.start_ns is None:
            self.start_ns = stamp_ns
        self.gyro.append(sample.gyro_rad_s)
        self.acceleration.append(sample.acceleration_m_s2)
        self.temperature.append(sample.temperature_c)
        if stamp_ns - self.start_ns >= self.duration_ns:
            self.future.set_result('')


_INT16 = {'low': -2**15, 'high': 2**15 - 1}
# What imu/calibrate_offsets saves, checked at start: registers are int16.
MPU_OFFSETS_FIELDS = (
    Field('variant', 'text'),
    Field('gyro_offset_lsb', 'integer', length=3, **_INT16),
    Field('accel_bias_lsb', 'integer', length=3, **_INT16),
    Field('accel_registers', 'integer', length=3, **_INT16),
    Field('residual_gyro_rad_s', 'number', length=3),
    Field('residual_acceleration_m_s2', 'number', length=3),
    Field('gravity_axis', 'text', choices=('+x', '-x', '+y', '-y', '+z', '-z')),
    Field('temperature_c', 'number', low=-273.15, high=1000.0),
    Field('samples', 'integer', low=1),
    Field('time', 'text'))
_MPU_OFFSETS = 'saved offsets'


def offsets_state(variant: str, gyro_lsb, accel_lsb, registers, bias, temperature_c: float
                  ) -> dict:
    """Give what imu/calibrate_offsets saves (`MPU_OFFSETS_FIELDS`) for offsets it wrote."""
    return {'variant': variant, 'gyro_offset_lsb': [int(v) for v in gyro_lsb],
            'accel_bias_lsb': [int(v) for v in accel_lsb],
            'accel_registers': [int(v) for v in registers],
            'residual_gyro_rad_s': [float(v) for v in bias.gyro_rad_s],
            'residual_acceleration_m_s2': [float(v) for v in bias.acceleration_m_s2],
            'gravity_axis': f'{"+" if bias.gravity_sign > 0 else "-"}{"xyz"[bias.gravity_axis]}',
            'temperature_c': float(temperature_c), 'samples': int(bias.samples),
            'time': datetime.now(timezone.utc).isoformat(timespec='seconds')}


def _offset_refresh(values: dict):
    """Give the `_OffsetRefresh` of ``mpu6000.offset_model_file``; None when it is ''."""
    path = values['mpu6000.offset_model_file']
    if not path:
        return None
    path = os.path.expanduser(path)
    try:
        model_values = node_values(path, values['mpu6000.offset_model_node'])
        if model_values['model'] != 'polynomial':
            msg = (f'model {model_values["model"]!r}: the offset registers take a polynomial '
                   'bias (mlx-tempcomp fit --model polynomial or relative)')
            raise ParameterError(msg)
        if axes_of(model_values) != AXIS_NAMES:
            msg = (f'axes {model_values["axes"]}: the model must cover gyro x, y and z in that '
                   'order')
            raise ParameterError(msg)
        model = build_model(model_values)
    except ParameterError as err:
        msg = f'invalid parameter mpu6000.offset_model_file ({path}): {err}'
        raise ParameterError(msg) from None
    # A register can only add: the scale polynomial does not apply at rest.
    return _OffsetRefresh(dataclasses.replace(model, scale_coefficients=()), path,
                          values['mpu6000.offset_refresh_c'])


class _OffsetRefresh:
    """
    Gyro offset registers that follow a bias model as the temperature moves.

    registers(T) = base + gyro_offset_lsb(bias(T) - bias(T_base)), where
    ``base`` are the registers that cancel the whole bias at ``T_base`` (the
    saved or just calibrated offsets): the model adds only the change since
    then, so a calibration and the model never count the same bias twice.
    Without a base (no saved offsets) the registers cancel the model's whole
    bias(T).
    """

    def __init__(self, model, path: str, step_c: float):
        self.model = model
        self.path = path
        self.step_c = step_c
        self.base_lsb = (0, 0, 0)
        self.base_temperature_c = None
        self.temperature_c = None       # of the last write; None: write at the next sample
        self.writes = 0
        self.failures = 0
        self.last_error = ''

    def bias_rad_s(self, temperature_c: float) -> np.ndarray:
        return -self.model.correct(np.zeros((1, 3)), [temperature_c]).rate_rad_s[0]

    def due(self, temperature_c: float) -> bool:
        return self.temperature_c is None or \
            abs(temperature_c - self.temperature_c) >= self.step_c

    def registers(self, temperature_c: float) -> tuple:
        change = self.bias_rad_s(temperature_c)
        if self.base_temperature_c is not None:
            change = change - self.bias_rad_s(self.base_temperature_c)
        return tuple(base + lsb for base, lsb in zip(self.base_lsb, gyro_offset_lsb(change)))

    def status(self) -> dict:
        return {'offset_model_file': self.path, 'offset_refresh_writes': self.writes,
                'offset_refresh_failures': self.failures,
                'offset_refresh_temperature_c': 'none' if self.temperature_c is None
                else self.temperature_c,
                'offset_refresh_base_temperature_c': 'none (whole model bias)'
                if self.base_temperature_c is None else self.base_temperature_c,
                'offset_refresh_error': self.last_error}


class MpuStream(DeviceStream):
    """
    An MPU-6000/6500: gyro, accelerometer and temperature; hardware offset registers.

    The offsets live in the part only until power-off, so the ones saved by
    ``imu/calibrate_offsets`` are written again at every start. With
    ``mpu6000.offset_model_file`` the gyro registers then follow the model's
    bias as the temperature moves (`_OffsetRefresh`).
    """

    def __init__(self, node):
        values = node.values
        if values['oversample'] != 1:
            msg = (f'invalid parameter oversample: the mpu6000 averages in its DLPF, not in '
                   f'the driver; give 1, got {values["oversample"]}')
            raise ParameterError(msg)
        self.refresh = _offset_refresh(values)
        options = {'gyro_full_scale_dps': values['mpu6000.gyro_full_scale_dps'],
                   'accel_full_scale_g': values['mpu6000.accel_full_scale_g'],
                   'dlpf_config': values['mpu6000.dlpf_config'],
                   'sample_rate_divider': values['mpu6000.sample_rate_divider']}
        for name, allowed in (('gyro_full_scale_dps', GYRO_LSB_PER_DPS),
                              ('accel_full_scale_g', ACCEL_LSB_PER_G)):
            if options[name] not in allowed:
                msg = (f'invalid parameter mpu6000.{name}: one of '
                       f'{", ".join(str(v) for v in sorted(allowed))}, got {options[name]}')
                raise ParameterError(msg)
        variant = values['mpu6000.variant']
        if values['source'] == 'simulated':
            if values['simulation.die_time_constant_s'] != 0.0:
                msg = ('invalid parameter simulation.die_time_constant_s: the simulated mpu6000 '
                       'follows its thermal profile directly, give 0')
                raise ParameterError(msg)
            source = mpu6000.SimulatedMpuSource(
                MpuTruth.random(np.random.default_rng(values['simulation.seed']),
                                rate_dps=self._true_rate_dps(values, node.axes),
                                thermal=_thermal(values, 0.0)),
                variant, values['simulation.seed'], **options)
            hardware_id = f'simulated {variant.upper()} (seed {values["simulation.seed"]})'
        else:
            chip_select = _chip_select(values, 'mpu6000')
            source = mpu6000.spidev_mpu(values['spi.bus'], chip_select,
                                        _speed_hz(values, 1_000_000), values['spi.mode'],
                                        variant, **options)
            hardware_id = f'{variant.upper()} on /dev/spidev{values["spi.bus"]}.{chip_select}'
        source.start()
        self.variant = variant
        self.acceleration_covariance = messages.acceleration_covariance(
            values['mpu6000.accel_noise_m_s2'])
        self.offsets_path = os.path.expanduser(values['mpu6000.offsets_file'] or os.path.join(
            '~', '.ros', 'mlx_tempcomp', f'{node.get_name()}_offsets.yaml'))
        self.gyro_lsb = (0, 0, 0)
        self.accel_bias_lsb = (0, 0, 0)
        self.accel_registers = tuple(source.device.factory_accel_lsb)
        self.offsets_origin = 'none'
        self.window = None
        self.source = source
        self.node = node
        self._write_saved_offsets()
        if self.refresh is not None:
            self._start_refresh()
        node.create_service(Trigger, 'imu/calibrate_offsets', self.calibrate_offsets,
                            callback_group=ReentrantCallbackGroup())
        gyro_rate_hz = 8000.0 if options['dlpf_config'] in (0, 7) else 1000.0
        super().__init__(node, source, hardware_id, values['source'] == 'simulated',
                         gyro_rate_hz / (1 + options['sample_rate_divider']))

    @staticmethod
    def _true_rate_dps(values: dict, axes) -> tuple:
        rate_dps = values['simulation.rate_dps']
        if len(rate_dps) not in (1, len(axes)):
            msg = (f'invalid parameter simulation.rate_dps: one value or one per axis '
                   f'({len(axes)}), got {len(rate_dps)}')
            raise ParameterError(msg)
        true_dps = [0.0, 0.0, 0.0]
        for position, axis in enumerate(axes):
            true_dps['xyz'.index(axis)] = rate_dps[position if len(rate_dps) > 1 else 0]
        return tuple(true_dps)

    def _write_saved_offsets(self) -> None:
        logger = self.node.get_logger()
        if not os.path.lexists(self.offsets_path):
            logger.info(f'no saved offsets in {self.offsets_path}: offset registers at their '
                        'power-on values')
        state = load_state(self.offsets_path, MPU_OFFSETS_FIELDS, logger, _MPU_OFFSETS)
        if state is None:
            return
        if state['variant'] != self.variant:
            logger.warn(f'{_MPU_OFFSETS} in {self.offsets_path} were measured on a '
                        f'{state["variant"]!r}, this is a {self.variant}: not written')
            return
        gyro, accel = state['gyro_offset_lsb'], state['accel_bias_lsb']
        try:
            registers = self.source.write_offsets(gyro, accel)
        except HardwareError as err:
            logger.error(f'writing the {_MPU_OFFSETS} from {self.offsets_path} failed: {err}; '
                         'starting without offsets')
            return
        self._offsets_now(gyro, accel, registers, 'saved file')
        if self.refresh is not None:
            self.refresh.base_lsb = tuple(gyro)
            self.refresh.base_temperature_c = state['temperature_c']
        logger.info(f'wrote the saved offsets from {self.offsets_path}: gyro {gyro} LSB, '
                    f'accel registers {list(registers)} (bias {accel} LSB at 16 g, '
                    f'calibrated {state["time"]})')

    def _offsets_now(self, gyro, accel, registers, origin: str) -> None:
        self.gyro_lsb, self.accel_bias_lsb = tuple(gyro), tuple(accel)
        self.accel_registers, self.offsets_origin = tuple(registers), origin

    def _start_refresh(self) -> None:
        refresh = self.refresh
        base = 'the whole model bias (no saved offsets)' \
            if refresh.base_temperature_c is None else \
            f'the change since {refresh.base_temperature_c:.2f} C (saved offsets)'
        self.node.get_logger().info(
            f'gyro offset refresh from {refresh.path}: {base}, rewritten every '
            f'{refresh.step_c:g} C')
        try:
            temperature_c = float(self.source.read().temperature_c)
        except HardwareError as err:
            # Counted; the first sample of the stream tries again.
            refresh.failures += 1
            refresh.last_error = str(err)
            self.node.get_logger().warn(f'gyro offset refresh at start failed: {err}')
            return
        self._refresh_offsets(temperature_c)

    def _refresh_offsets(self, temperature_c: float) -> None:
        refresh = self.refresh
        try:
            registers = refresh.registers(temperature_c)
            self.source.device.write_gyro_offsets(registers)
        except (CalibrationError, HardwareError) as err:
            # Retried at the next sample; the registers in place stay as they were.
            refresh.failures += 1
            refresh.last_error = str(err)
            self.node.get_logger().warn(f'gyro offset refresh at {temperature_c:.2f} C '
                                        f'failed: {err}', throttle_duration_sec=5.0)
            return
        refresh.writes += 1
        refresh.temperature_c = temperature_c
        self.gyro_lsb = registers

    def read(self):
        return self.source.read()

    def publish(self, stamp_ns: int, sample) -> None:
        gyro = sample.gyro_rad_s
        self.node.publish_raw(stamp_ns, [float(gyro[i]) for i in self.node.indices],
                              [float(sample.temperature_c)], sample.acceleration_m_s2,
                              self.acceleration_covariance)
        if self.window is not None:
            self.window.add(stamp_ns, sample)
        # Registers stay put while a calibration window averages over them.
        elif self.refresh is not None and self.refresh.due(sample.temperature_c):
            self._refresh_offsets(float(sample.temperature_c))

    def set_fault(self, value: str) -> None:
        self.source.simulated.stuck_miso = _STUCK_MISO[Fault(value)]

    def extra_status(self) -> dict:
        refresh = {} if self.refresh is None else self.refresh.status()
        return {'variant': self.variant, 'offsets': self.offsets_origin,
                'gyro_offset_lsb': list(self.gyro_lsb),
                'accel_offset_registers': list(self.accel_registers),
                'offsets_file': self.offsets_path, **refresh}

    async def calibrate_offsets(self, request, response):
        """
        Average the stream at rest, write offsets that cancel the bias, save them.

        A coroutine: the stream keeps flowing while the window fills. The
        window sees the offsets already in place, so its mean is the residual
        bias and the new registers are the old ones plus its correction.
        """
        response.success = False
        values = self.node.values
        noise_rad_s = values['rate_noise_rad_s']
        if self.window is not None:
            response.message = 'refused: an offset calibration is already running'
        elif noise_rad_s <= 0.0:
            response.message = ('refused: the motion check needs a positive rate_noise_rad_s '
                                '(the 1-sigma gyro noise of one sample)')
        if response.message:
            return response
        window = _RestWindow(int(values['mpu6000.calibration.duration_s'] * 1e9))

        def check_stalled():
            stalled_s = time.monotonic() - self.last_sample
            if stalled_s > STALL_TIMEOUT_S and not window.future.done():
                window.future.set_result(f'refused: no sample for {stalled_s:.1f} s, the '
                                         f'stream stalled ({self.last_error or "no error"})')

        self.window = window
        timer = self.node.create_timer(_POLL_S, check_stalled)
        try:
            refusal = await window.future
        finally:
            self.window = None
            self.node.destroy_timer(timer)
        response.message = refusal or self._finish(window, noise_rad_s,
                                                   values['mpu6000.calibration.noise_multiple'])
        response.success = messages.trigger_succeeded(response.message)
        messages.log_trigger(self.node.get_logger(), response, 'offset calibration')
        return response

    def _finish(self, window: _RestWindow, noise_rad_s: float, multiple: float) -> str:
        gyro = np.array(window.gyro)
        spread = gyro.std(axis=0, ddof=1) if len(gyro) > 1 else np.zeros(3)
        worst = int(np.argmax(spread))
        if spread[worst] > multiple * noise_rad_s:
            return (f'refused: the board moves: the {"xyz"[worst]} gyro rate spread '
                    f'(standard deviation) {spread[worst]:.4g} rad/s is above '
                    f'{multiple:g} x rate_noise_rad_s {noise_rad_s:.4g}; keep it still, face '
                    'up or down, and call again')
        try:
            bias = rest_bias(gyro, np.array(window.acceleration))
            gyro_lsb = tuple(old + new for old, new in zip(
                self.gyro_lsb, gyro_offset_lsb(bias.gyro_rad_s)))
            # The register holds the bias with bit 0 dropped: correct from what applies.
            accel_lsb = tuple((old & ~1) + new for old, new in zip(
                self.accel_bias_lsb, accel_offset_lsb(bias.acceleration_m_s2)))
            registers = self.source.write_offsets(gyro_lsb, accel_lsb)
        except CalibrationError as err:
            return f'refused: {err}'
        except HardwareError as err:
            return f'refused: writing the offset registers failed: {err}'
        self._offsets_now(gyro_lsb, accel_lsb, registers, 'calibrated')
        temperature_c = float(np.mean(window.temperature))
        if self.refresh is not None:
            # The new registers cancel the whole bias at the window's temperature.
            self.refresh.base_lsb, self.refresh.base_temperature_c = gyro_lsb, temperature_c
            self.refresh.temperature_c = temperature_c
        state = offsets_state(self.variant, gyro_lsb, accel_lsb, registers, bias, temperature_c)
        residual = ', '.join(f'{math.degrees(v):+.4f}' for v in bias.gyro_rad_s)
        text = (f'gyro offsets {list(gyro_lsb)} LSB, accel offset registers {list(registers)} '
                f'(bias {list(accel_lsb)} LSB at 16 g), gravity on {state["gravity_axis"]}, '
                f'from {bias.samples} samples at {temperature_c:.2f} C (gyro bias before '
                f'{residual} deg/s)')
        try:
            write_state(self.offsets_path, state)
        except StateFileError as err:
            return f'applied but not saved: {text}; {err}'
        return f'{text}; saved to {self.offsets_path}'
