"""
The MLX90609 driver stream: one to three chips, simulated or on spidev.

It reads the chips' EEPROMs at start (published on ``imu/eeprom``, so the raw
topics reproduce compensation exactly), converts each reading with the
nominal transfer (AN2 method 1) and publishes one temperature per chip; the
simulated chips add a supply monitor (``simulation.supply_monitor_hz``).
"""

import math

from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import BatteryState

from .timed_stream import refuse_fault, StreamPorts, TimedStream
from .. import messages
from ..qos import stream_publisher
from ...core.mlx90609 import NominalConversion, Output, sensor_tables
from ...hardware.errors import HardwareError
from ...simulation.mlx90609 import Fault
from ...sources.mlx90609 import SimulatedArray, SimulationConfig, spidev_array

EEPROM_READ_ATTEMPTS = 3
MLX90609_SPEED_HZ = 500_000
# A reading is a rate and a temperature conversion of more than 115 us each (DS p.14), so
# one chip gives at most about 4 kHz; the natural rate the driver samples at is a choice
# well inside that (UNCONFIRMED: the datasheet names none).
MLX90609_SAMPLE_RATE_HZ = 1000.0


class Mlx90609Stream(TimedStream):
    """An MLX90609 array, simulated or on spidev, read on a timer."""

    def __init__(self, ports: StreamPorts):
        super().__init__(ports)
        settings = self.settings
        axes = self.axes
        self.transfer = settings.sensor.transfer
        simulation = settings.simulation
        if settings.simulated:
            config = SimulationConfig(
                seed=simulation.seed, eeprom_version=simulation.eeprom_version,
                start_temperature_c=simulation.start_temperature_c,
                cycle_temperatures_c=simulation.cycle_temperatures_c,
                ramp_c_per_min=simulation.ramp_c_per_min, hold_s=simulation.hold_s,
                die_time_constant_s=simulation.die_time_constant_s,
                rate_dps=simulation.rate_dps, supply_v=simulation.supply_v,
                effects=simulation.effects)
            self.array = SimulatedArray(config, len(axes))
            self.array.fault = Fault(simulation.fault)
            real_time_factor = simulation.real_time_factor
            self.hardware_id = f'simulated MLX90609 x{len(axes)} (seed {config.seed})'
        else:
            spi = settings.spi
            self.array = spidev_array(spi.bus, spi.chip_selects,
                                      spi.speed_hz or MLX90609_SPEED_HZ, spi.mode)
            real_time_factor = None
            self.hardware_id = f'MLX90609 on /dev/spidev{spi.bus}.{list(spi.chip_selects)}'
        self.tables = sensor_tables(self._read_eeproms(), Output.DIGITAL, self.transfer,
                                    settings.sensor.full_scale_dps)
        self.nominal = NominalConversion.for_range(self.tables.full_scale_dps, Output.DIGITAL,
                                                   len(axes), self.transfer)
        ports.eeprom_publisher.publish(messages.eeprom_message(self.images))
        self.oversample = settings.oversample
        self.simulated = real_time_factor is not None
        self.start_schedule(real_time_factor, MLX90609_SAMPLE_RATE_HZ,
                            self.simulated and simulation.lossless,
                            self.simulated and simulation.wait_for_subscriber)
        monitor_hz = simulation.supply_monitor_hz
        self.supply_publisher = stream_publisher(
            ports.node, BatteryState, 'imu/supply_voltage') if monitor_hz else None
        self.supply_period_s = 1.0 / monitor_hz if monitor_hz else None
        self.supply_readings = 0
        self.logger.info(
            f'{self.hardware_id}: EEPROM VERSION {[f.version for f in self.tables.fields]}, '
            f'full scale {self.tables.full_scale_dps:g} deg/s, {self.rates}')

    def _read_eeproms(self) -> tuple:
        attempt = 1
        while True:
            try:
                self.images = self.array.read_eeproms()
                return self.images
            except HardwareError as err:
                if attempt == EEPROM_READ_ATTEMPTS:
                    msg = f'cannot read the EEPROM after {attempt} attempts: {err}'
                    raise HardwareError(msg) from None
                self.logger.warn(f'EEPROM read failed ({err}), retrying')
                attempt += 1

    def advance_to(self, time_s: float) -> None:
        self.array.advance_to(time_s)

    def tick(self) -> None:
        super().tick()
        if self.supply_publisher is not None:
            self._monitor_supply()

    def _monitor_supply(self) -> None:
        """Publish the supply readings due by now, on instants of their own (not the samples')."""
        while True:
            time_s = (self.supply_readings + 1.0 / 3.0) * self.supply_period_s
            if time_s > self.array.clock.now_s:
                return
            stamp = messages.ns_to_stamp(self.start_ns + int(round(time_s * 1e9)))
            # Over DDS even in bringup: the compensation node subscribes to its auxiliary
            # inputs, as it would to a real monitor.
            self.supply_publisher.publish(messages.supply_voltage_message(
                stamp, self.settings.frame_id, self.array.supply_v))
            self.supply_readings += 1

    def read(self):
        return self.array.read(self.oversample)

    def publish(self, stamp_ns: int, sample) -> None:
        # AN2 method 1 per axis, in plain floats (this runs once per sample).
        nominal = self.nominal
        rates_rad_s = [math.radians((code - nominal.zro) / nominal.sf)
                       for code in sample.rate_code]
        transfer = self.transfer
        temperatures_c = [float(transfer.temperature_output_to_c(code, Output.DIGITAL))
                          for code in sample.temperature_code]
        self.ports.publish_raw(stamp_ns, rates_rad_s, temperatures_c)

    def check_fault(self, value: str) -> None:
        """Raise `ParameterError` unless the simulated chips can take a fault."""
        if not self.simulated:
            refuse_fault()

    def set_fault(self, value: str) -> None:
        self.array.fault = Fault(value)

    def status(self) -> tuple:
        counters = self.array.counters
        values = {'state': 'failing' if self.consecutive_failures else 'streaming',
                  **self.sampling_status(), **counters,
                  'eeprom_version': [f.version for f in self.tables.fields],
                  'eeprom_outvoted_bits': self.tables.outvoted_bits,
                  'full_scale_dps': self.tables.full_scale_dps,
                  'last_error': self.last_error}
        missed = self.missing_reads()
        if self.consecutive_failures:
            return DiagnosticStatus.ERROR, f'SPI reads failing: {self.last_error}', values
        if missed:
            return DiagnosticStatus.WARN, missed, values
        if self.tables.outvoted_bits:
            return DiagnosticStatus.WARN, (f'{self.tables.outvoted_bits} EEPROM bits '
                                           'out-voted: worn EEPROM or bad SPI read'), values
        if counters['saturated']:
            return DiagnosticStatus.WARN, f'{counters["saturated"]} saturated samples', values
        return DiagnosticStatus.OK, 'streaming', values

    def close(self) -> None:
        self.array.close()
