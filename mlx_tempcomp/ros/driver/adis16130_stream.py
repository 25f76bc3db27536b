"""
The ADIS16130 driver stream and its ``imu/run_bias_procedure`` service.

One axis, no EEPROM, one temperature; the service runs AN-1042's bias
procedure (`mlx_tempcomp.core.procedures.adis16130_bias`) on the stream and writes the
``linear_btc`` parameter file of the compensation node.
"""

import math
import os
import time

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.task import Future
from std_msgs.msg import String
from std_srvs.srv import Trigger
import yaml

from .timed_stream import DeviceStream, StreamPorts, thermal_profile
from .. import messages
from ..qos import STATUS_QOS
from ..service_window import await_window, guarded, Outcome, Refused, ServiceGuard, STALL_TIMEOUT_S
from ...core.errors import CalibrationError, TempCompError
from ...core.procedures import BiasProcedure, Phase
from ...core.series import allan_deviation
from ...parameters.driver import DriverSettings, procedure_settings
from ...parameters.files import linear_btc_parameters, parameter_file, write_parameter_file
from ...parameters.specs import ParameterError
from ...parameters.state_paths import default_state_path
from ...simulation.adis16130 import Adis16130Truth, Fault
from ...sources import adis16130

# RATE and TEMP refresh at 5.7 kHz (AN-1042): the natural sample rate.
ADIS16130_SAMPLE_RATE_HZ = 5700.0
# The bias procedure publishes its progress (and checks for a stall) this often.
PROGRESS_PERIOD_S = 1.0


def simulated_adis(settings: DriverSettings) -> adis16130.SimulatedSensor:
    """Return the simulated ADIS16130 the driver reads with these settings, started."""
    simulation = settings.simulation
    truth = Adis16130Truth(bias_dps=simulation.bias_dps,
                           bias_dps_per_c=simulation.bias_dps_per_c, effects=simulation.effects)
    config = adis16130.SimulationConfig(
        seed=simulation.seed, resolution_bits=settings.adis16130.resolution_bits,
        truth=truth, thermal=thermal_profile(simulation, simulation.die_time_constant_s),
        rate_dps=simulation.rate_dps[0], supply_v=simulation.supply_v,
        sclk_hz=float(settings.spi.speed_hz or adis16130.DEFAULT_SPEED_HZ))
    return adis16130.SimulatedSensor(config)


class AdisStream(DeviceStream):
    """An ADIS16130 (one axis); offers the AN-1042 bias procedure as a service."""

    def __init__(self, ports: StreamPorts):
        settings = ports.settings()
        bits = settings.adis16130.resolution_bits
        self.oversample = settings.oversample
        spi = settings.spi
        if settings.simulated:
            source = simulated_adis(settings)
            hardware_id = f'simulated ADIS16130 (seed {settings.simulation.seed})'
        else:
            source = adis16130.spidev_sensor(
                spi.bus, spi.chip_selects[0], spi.speed_hz or adis16130.DEFAULT_SPEED_HZ,
                spi.mode, bits, settings.adis16130.verify_registers)
            hardware_id = f'ADIS16130 on /dev/spidev{spi.bus}.{spi.chip_selects[0]}'
        self.bits = bits
        self.procedure = None
        self.guard = ServiceGuard()   # the driver's one calibration service: one call at a time
        self.status_publisher = ports.node.create_publisher(
            String, 'imu/bias_procedure/status', STATUS_QOS)
        ports.node.create_service(Trigger, 'imu/run_bias_procedure', self.run_bias_procedure,
                                  callback_group=ReentrantCallbackGroup())
        super().__init__(ports, source, f'{hardware_id}, {bits}-bit', settings.simulated,
                         ADIS16130_SAMPLE_RATE_HZ)

    def read(self):
        return self.source.read(self.oversample)

    def publish(self, stamp_ns: int, sample) -> None:
        rate_rad_s = float(sample.rate_rad_s[0])
        temperature_c = float(sample.temperature_c[0])
        self.ports.publish_raw(stamp_ns, [rate_rad_s], [temperature_c])
        if self.procedure is not None:
            self.procedure.add(stamp_ns / 1e9, rate_rad_s, temperature_c)

    def set_fault(self, value: str) -> None:
        self.source.fault = Fault(value)

    def extra_status(self) -> dict:
        running = self.procedure
        return {'resolution_bits': self.bits,
                'bias_procedure': 'idle' if running is None else running.procedure.phase.value}

    async def run_bias_procedure(self, request, response):
        """
        Run AN-1042's bias procedure on the stream; write the linear_btc parameter file.

        A coroutine: the stream keeps flowing (and feeding it) while it waits.
        """
        outcome = await guarded(self.guard, 'a bias procedure', self._run_and_report)
        return messages.answer_trigger(self.logger, response, outcome, 'bias procedure')

    async def _run_and_report(self) -> Outcome:
        """Run the procedure; publish how it ended on its status topic; give the outcome."""
        try:
            outcome = await self._run()
        except Refused as refusal:
            outcome = refusal.outcome()
        self.status_publisher.publish(String(
            data=('done: ' if outcome.success else 'failed: ') + outcome.message))
        return outcome

    async def _run(self) -> Outcome:
        """Run the procedure while the stream feeds it (`Refused` when it fails); finish it."""
        try:
            running = _RunningProcedure(self, self.settings)
        except (ParameterError, TempCompError) as err:
            raise Refused(str(err)) from None
        self.procedure = running
        running.announce()
        try:
            error = await await_window(self.ports.node, running.future, running.report,
                                       PROGRESS_PERIOD_S)
        finally:
            self.procedure = None
        if error:
            raise Refused(error)
        return running.finish()


def _noise_figures(time_s, rate_rad_s):
    return allan_deviation(time_s, rate_rad_s.reshape(-1, 1), ('rate',))[0]


class _RunningProcedure:
    """One bias procedure: the state machine, its future and where it writes."""

    def __init__(self, stream: AdisStream, settings: DriverSettings):
        self.stream = stream
        procedure = procedure_settings(settings)
        self.procedure = BiasProcedure(
            procedure, _noise_figures if procedure.allan_record_s > 0.0 else None)
        given = settings.adis16130.bias_procedure
        self.path = os.path.expanduser(given.output_file) or default_state_path(
            stream.ports.node.get_fully_qualified_name(), '_linear_btc.yaml')
        self.node_name = given.node_name
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
        """Publish the progress, or raise `Refused`: the stream stalled, the procedure gives up."""
        stalled_s = time.monotonic() - self.stream.last_sample
        if stalled_s > STALL_TIMEOUT_S:
            raise Refused(f'no sample for {stalled_s:.1f} s: the stream stalled '
                          f'({self.stream.last_error or "no error"})')
        phase = self.procedure.phase
        self.publish(f'phase {phase.value}: {100.0 * self.procedure.progress:.0f} % of '
                     f'{self.procedure.phase_duration_s(phase):g} s')

    def publish(self, text: str) -> None:
        self.stream.status_publisher.publish(String(data=text))

    def finish(self) -> Outcome:
        result = self.procedure.result
        axes = self.stream.axes
        parameters = linear_btc_parameters(result.model, axes)
        if result.noise is not None:
            parameters['rate_noise_rad_s'] = float(result.noise.rate_noise_rad_s)
        p1, p2 = result.point_1, result.point_2
        summary = (f'T1 {p1.temperature_c:.4f} C, B1 {p1.bias_rad_s:.6g} rad/s, '
                   f'T2 {p2.temperature_c:.4f} C, B2 {p2.bias_rad_s:.6g} rad/s, '
                   f'BTC {result.btc_rad_s_per_c:.6g} rad/s/C '
                   f'({math.degrees(result.btc_rad_s_per_c):+.5f} deg/s/C), '
                   f'PBC {result.pbc_rad_s:.6g} rad/s, T3 {result.t3_c:.4f} C')
        header = (f'ADIS16130 bias procedure (AN-1042) by {self.stream.ports.node.get_name()} '
                  f'({self.stream.hardware_id}): {summary}\n'
                  f'Use: compensation_node --ros-args --params-file {self.path}')
        change = (f'linear_btc of {self.node_name} from '
                  f'{file_linear_btc(self.path, self.node_name)} to '
                  f'{linear_btc_text(parameters["linear_btc"])}')
        try:
            os.makedirs(os.path.dirname(self.path) or '.', exist_ok=True)
            write_parameter_file(self.path, parameter_file(self.node_name, parameters), header)
        except OSError as err:
            return Outcome(False, f'applied but not saved: {summary}; {change}; cannot '
                                  f'write {self.path}: {err.strerror}')
        return Outcome(True, f'{summary}; {change}; wrote {self.path}')


def linear_btc_text(section: dict) -> str:
    """Say what a ``linear_btc`` section of parameters holds, one line."""
    def numbers(values) -> str:
        return '[' + ', '.join(f'{float(v):.6g}' for v in values) + ']'
    return (f'PBC {numbers(section["pbc_rad_s"])} rad/s, BTC '
            f'{numbers(section["btc_rad_s_per_c"])} rad/s/C, T3 {float(section["t3_c"]):.4f} C')


def file_linear_btc(path: str, node_name: str) -> str:
    """Say what ``linear_btc`` the parameter file at ``path`` holds for ``node_name`` now."""
    try:
        with open(path, 'rb') as stream:
            content = yaml.safe_load(stream)
    except FileNotFoundError:
        return 'none (no file)'
    except (OSError, yaml.YAMLError) as err:
        return f'an unreadable file ({type(err).__name__})'
    try:
        return linear_btc_text(content[node_name]['ros__parameters']['linear_btc'])
    except (TypeError, KeyError, ValueError):
        return f'a file without a linear_btc section for {node_name}'
