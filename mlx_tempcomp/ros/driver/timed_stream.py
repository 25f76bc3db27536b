"""
Driver streams: a part sampled at its own rate on a timer, published as means at a lower one.

`TimedStream` is the schedule every part shares (`mlx_tempcomp.ros.driver.mlx90609_stream`,
`adis16130_stream`, `mpu6000_stream`); `DeviceStream` adds what the one-part
devices (SPI, or I2C for the MPU) share: a source of
`mlx_tempcomp.sources.protocol`, data-line faults and the diagnostics. A
stream gets `StreamPorts` from the driver node: what it may use of it, no
more; its settings (`parameters.driver.DriverSettings`) among them, as the node
holds them now: a parameter change swaps them, and a service reads them when called.
"""

import collections
from dataclasses import dataclass
import gc
import math
import time
from typing import Callable, Optional

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node

from ...hardware.errors import HardwareError
from ...parameters.driver import DriverSettings, SimulationSettings
from ...parameters.specs import ParameterError
from ...simulation.mlx90609 import Fault
from ...simulation.physics import ThermalProfile
from ...sources.decimation import Decimator
from ...sources.protocol import SampleSource

# Faults both parts can simulate: MISO stuck high or low.
DEVICE_FAULTS = (Fault.NONE, Fault.SILENT_HIGH, Fault.SILENT_LOW)

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


@dataclass(frozen=True)
class StreamPorts:
    """What a driver stream gets from its node: it reaches no further."""

    node: Node                  # creates the stream's timers, services and publishers
    settings: Callable[[], DriverSettings]     # the node's settings now
    publish_raw: Callable       # DriverNode.publish_raw
    hand_off: Callable          # DriverNode.hand_off, at the end of every tick
    has_consumer: Callable      # DriverNode.has_consumer: someone takes imu/data_raw
    eeprom_publisher: Optional[object]      # imu/eeprom, where the device has one


def thermal_profile(simulation: SimulationSettings, time_constant_s: float) -> ThermalProfile:
    return ThermalProfile.cycle(simulation.cycle_temperatures_c, simulation.ramp_c_per_min,
                                simulation.start_temperature_c, time_constant_s,
                                simulation.hold_s)


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

    Subclasses call ``__init__`` with the `StreamPorts`, give `read`, `publish` and
    `advance_to` (simulated time) and call `start_schedule` with the part's
    natural sample rate once the part is ready.
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

    def __init__(self, ports: StreamPorts):
        self.ports = ports
        self.axes = ports.settings().axes
        self.logger = ports.node.get_logger()

    @property
    def settings(self) -> DriverSettings:
        """Give the node's settings now."""
        return self.ports.settings()

    def start_schedule(self, real_time_factor, natural_rate_hz: float,
                       lossless: bool = False, wait_for_subscriber: bool = False) -> None:
        settings = self.settings
        publish_rate_hz = settings.publish_rate_hz
        sample_rate_hz = settings.sample_rate_hz or natural_rate_hz
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
        self.waiting_for_subscriber = wait_for_subscriber
        self.start_ns = self.ports.node.get_clock().now().nanoseconds
        self.start_wall = time.monotonic()
        tick = 1.0 / publish_rate_hz / (real_time_factor or 1.0)
        self.timer = self.ports.node.create_timer(max(tick, MIN_TICK_S), self.tick)
        # What start-up allocated lives as long as the process: frozen, a full collection
        # skips it and stays short enough not to stretch a tick past MAX_BACKLOG_S.
        gc.freeze()

    @property
    def rates(self) -> str:
        return (f'sampling at {self.decimator.sample_rate_hz:g} Hz, publishing at '
                f'{self.decimator.publish_rate_hz:g} Hz'
                + (', lossless (the simulated clock may fall behind wall time)'
                   if self.lossless else ''))

    def tick(self) -> None:
        if self.waiting_for_subscriber:
            if not self.ports.has_consumer():
                return
            # The schedule (and the stamps) start now, at simulated time 0.
            self.waiting_for_subscriber = False
            self.start_wall = time.monotonic()
            self.start_ns = self.ports.node.get_clock().now().nanoseconds
            self.logger.info('subscriber present: the simulated clock starts')
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
        self.ports.hand_off()

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
                self.logger.warn(warning, throttle_duration_sec=MISSED_LOG_THROTTLE_S)

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
            self.logger.warn(f'read failed: {err}', throttle_duration_sec=5.0)
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
    """One ADIS16130 or MPU-6000 part, simulated (a `SimulatedSource`) or on spidev or i2c-dev."""

    bus_name = 'SPI'            # the bus the part is read over, as the diagnostics name it

    def __init__(self, ports: StreamPorts, source: SampleSource, hardware_id: str,
                 simulated: bool, natural_rate_hz: float):
        super().__init__(ports)
        self.source = source
        self.hardware_id = hardware_id
        self.simulated = simulated
        # Start-up took simulated time (resets, settling): the schedule starts after it.
        self.source_start_s = source.clock.now_s if simulated else 0.0
        simulation = self.settings.simulation
        self.start_schedule(simulation.real_time_factor if simulated else None, natural_rate_hz,
                            simulated and simulation.lossless,
                            simulated and simulation.wait_for_subscriber)
        self.logger.info(f'{hardware_id}: {self.rates}')

    def advance_to(self, time_s: float) -> None:
        self.source.advance_to(self.source_start_s + time_s)

    def check_fault(self, value: str) -> None:
        """Raise `ParameterError` unless ``simulation.fault`` = ``value`` can be switched on."""
        if not self.simulated:
            refuse_fault()
        if Fault(value) not in DEVICE_FAULTS:
            choices = ', '.join(f.value for f in DEVICE_FAULTS)
            msg = (f'invalid parameter simulation.fault: the simulated '
                   f'{self.settings.device} knows {choices}, not {value!r}')
            raise ParameterError(msg)

    def set_fault(self, value: str) -> None:
        raise NotImplementedError

    def extra_status(self) -> dict:
        return {}

    def status(self) -> tuple:
        values = {'state': 'failing' if self.consecutive_failures else 'streaming',
                  'device': self.settings.device, **self.sampling_status(),
                  **self.source.counters, **self.extra_status(), 'last_error': self.last_error}
        missed = self.missing_reads()
        if self.consecutive_failures:
            return (DiagnosticStatus.ERROR, f'{self.bus_name} reads failing: {self.last_error}',
                    values)
        if missed:
            return DiagnosticStatus.WARN, missed, values
        if self.saturated:
            return DiagnosticStatus.WARN, f'{self.saturated} saturated samples', values
        return DiagnosticStatus.OK, 'streaming', values

    def close(self) -> None:
        self.source.close()
