"""
The MPU-6000/6050/6500 driver stream, on SPI or I2C, and its ``imu/calibrate_offsets`` service.

Gyro, accelerometer and one temperature, no EEPROM. The stream writes the
offset registers saved in its state file at start, offers
``imu/calibrate_offsets`` and, given a bias model, refreshes the gyro offset
registers as the temperature moves (`mlx_tempcomp.core.procedures.mpu6000_offsets.OffsetRefresh`).
"""

from datetime import datetime, timezone
import math
import os
import time

import numpy as np
from rclpy.callback_groups import ReentrantCallbackGroup
from std_srvs.srv import Trigger

from .timed_stream import DeviceStream, StreamPorts, thermal_profile
from .. import messages
from ..service_window import (await_window, guarded, Outcome, Refused, SampleWindow, ServiceGuard,
                              STALL_TIMEOUT_S)
from ...core.errors import CalibrationError
from ...core.procedures import INT16_MAX, INT16_MIN, OffsetRefresh, recalibrated_offsets, rest_bias
from ...core.standstill import check_window, RecalibrationLimits
from ...hardware.errors import HardwareError
from ...hardware.mpu6000 import ACCEL_LSB_PER_G, GYRO_LSB_PER_DPS, I2C_ADDRESSES, variant_named
from ...parameters.driver import DriverSettings, Mpu6000Settings
from ...parameters.files import offset_register_model
from ...parameters.specs import ParameterError
from ...parameters.state_file import Field, load_state
from ...parameters.state_paths import state_path
from ...simulation.mlx90609 import Fault
from ...simulation.mpu6000 import MpuTruth
from ...sources import mpu6000

_STUCK_MISO = {Fault.NONE: None, Fault.SILENT_HIGH: 0xFF, Fault.SILENT_LOW: 0x00}
_INT16 = {'low': INT16_MIN, 'high': INT16_MAX}

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
# The offset calibration's refusal of a window that moved (fields of
# core.standstill.recalibration's SENSOR_MOVED).
_BOARD_MOVES = ('the board moves: the {axis_name} gyro rate spread (standard deviation) '
                '{spread_rad_s:.4g} rad/s is above {noise_multiple:g} x rate_noise_rad_s '
                '{rate_noise_rad_s:.4g}; keep it still, face up or down, and call again')


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


def _offset_refresh(mpu: Mpu6000Settings):
    """Give the `_OffsetRefresh` of ``mpu6000.offset_model_file``; None when it is ''."""
    if not mpu.offset_model_file:
        return None
    path = os.path.expanduser(mpu.offset_model_file)
    return _OffsetRefresh(offset_register_model(path, mpu.offset_model_node), path,
                          mpu.offset_refresh_c)


class _OffsetRefresh(OffsetRefresh):
    """The core refresh, with its file and the counters of its register writes."""

    def __init__(self, model, path: str, step_c: float):
        super().__init__(model, step_c)
        self.path = path
        self.writes = 0
        self.failures = 0
        self.last_error = ''

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
    An MPU-6000/6050/6500 on SPI or I2C: gyro, accelerometer and temperature; offset registers.

    The offsets live in the part only until power-off, so the ones saved by
    ``imu/calibrate_offsets`` are written again at every start. With
    ``mpu6000.offset_model_file`` the gyro registers then follow the model's
    bias as the temperature moves (`_OffsetRefresh`).
    """

    def __init__(self, ports: StreamPorts):
        settings = ports.settings()
        mpu = settings.mpu6000
        self.refresh = _offset_refresh(mpu)
        options = {'gyro_full_scale_dps': mpu.gyro_full_scale_dps,
                   'accel_full_scale_g': mpu.accel_full_scale_g,
                   'dlpf_config': mpu.dlpf_config, 'sample_rate_divider': mpu.sample_rate_divider}
        for name, allowed in (('gyro_full_scale_dps', GYRO_LSB_PER_DPS),
                              ('accel_full_scale_g', ACCEL_LSB_PER_G)):
            if options[name] not in allowed:
                msg = (f'invalid parameter mpu6000.{name}: one of '
                       f'{", ".join(str(v) for v in sorted(allowed))}, got {options[name]}')
                raise ParameterError(msg)
        source, hardware_id = self._open(settings, options)
        source.start()
        self.variant = mpu.variant
        self.acceleration_covariance = messages.acceleration_covariance(mpu.accel_noise_m_s2)
        self.offsets_path = state_path(mpu.offsets_file, ports.node.get_fully_qualified_name(),
                                       '_offsets.yaml', ports.node.get_logger().warn)
        self.gyro_lsb = (0, 0, 0)
        self.accel_bias_lsb = (0, 0, 0)
        self.accel_registers = tuple(source.device.factory_accel_lsb)
        self.offsets_origin = 'none'
        self.window = None
        self.guard = ServiceGuard()   # the driver's one calibration service: one call at a time
        self.source = source
        self.logger = ports.node.get_logger()
        self.indices = messages.axis_indices(settings.axes)
        self._write_saved_offsets()
        if self.refresh is not None:
            self._start_refresh()
        ports.node.create_service(Trigger, 'imu/calibrate_offsets', self.calibrate_offsets,
                                  callback_group=ReentrantCallbackGroup())
        # The gyro's natural rate: 8 kHz with DLPF_CFG 0 or 7, else 1 kHz, over 1 + SMPLRT_DIV.
        gyro_rate_hz = 8000.0 if options['dlpf_config'] in (0, 7) else 1000.0
        super().__init__(ports, source, hardware_id, settings.simulated,
                         gyro_rate_hz / (1 + options['sample_rate_divider']))

    def _open(self, settings: DriverSettings, options: dict) -> tuple:
        """Open the part on its bus (`DriverSettings.bus`): give the source and its hardware id."""
        variant = settings.mpu6000.variant
        self.bus_name = settings.bus.upper()
        bus_parameter = 'source' if not settings.simulated else 'simulation.bus'
        if self.bus_name == 'SPI' and not variant_named(variant).spi:
            msg = (f'invalid parameter {bus_parameter}: the {variant} speaks I2C only, give i2c '
                   '(and i2c.bus, i2c.address)')
            raise ParameterError(msg)
        address = settings.i2c.address
        if self.bus_name == 'I2C' and address not in I2C_ADDRESSES:
            msg = (f'invalid parameter i2c.address: an MPU answers at 0x68 (104, AD0 low) or '
                   f'0x69 (105, AD0 high), got 0x{address:02X} ({address})')
            raise ParameterError(msg)
        at = f' on I2C at 0x{address:02X}' if self.bus_name == 'I2C' else ''
        if settings.simulated:
            seed = settings.simulation.seed
            source = mpu6000.SimulatedMpuSource(
                MpuTruth.random(np.random.default_rng(seed),
                                rate_dps=self._true_rate_dps(settings),
                                thermal=thermal_profile(settings.simulation, 0.0)),
                variant, seed, self.bus_name.lower(), address, **options)
            return source, f'simulated {variant.upper()}{at} (seed {seed})'
        if self.bus_name == 'I2C':
            bus = settings.i2c.bus
            source = mpu6000.i2c_mpu(bus, address, variant, **options)
            return source, f'{variant.upper()} on /dev/i2c-{bus} at 0x{address:02X}'
        spi = settings.spi
        cs = spi.chip_selects[0]
        source = mpu6000.spidev_mpu(spi.bus, cs, spi.speed_hz or 1_000_000, spi.mode, variant,
                                    **options)
        return source, f'{variant.upper()} on /dev/spidev{spi.bus}.{cs}'

    @staticmethod
    def _true_rate_dps(settings: DriverSettings) -> tuple:
        """Give the true rate of gyro x, y and z: ``simulation.rate_dps`` on the axes measured."""
        rate_dps = settings.simulation.rate_dps
        true_dps = [0.0, 0.0, 0.0]
        for position, axis in enumerate(settings.axes):
            true_dps['xyz'.index(axis)] = rate_dps[position if len(rate_dps) > 1 else 0]
        return tuple(true_dps)

    def _write_saved_offsets(self) -> None:
        logger = self.logger
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
        self.logger.info(
            f'gyro offset refresh from {refresh.path}: {base}, rewritten every '
            f'{refresh.step_c:g} C')
        try:
            temperature_c = float(self.source.read().temperature_c)
        except HardwareError as err:
            # Counted; the first sample of the stream tries again.
            refresh.failures += 1
            refresh.last_error = str(err)
            self.logger.warn(f'gyro offset refresh at start failed: {err}')
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
            self.logger.warn(f'gyro offset refresh at {temperature_c:.2f} C failed: {err}',
                             throttle_duration_sec=5.0)
            return
        refresh.writes += 1
        refresh.temperature_c = temperature_c
        self.gyro_lsb = registers

    def read(self):
        return self.source.read()

    def publish(self, stamp_ns: int, sample) -> None:
        gyro = sample.gyro_rad_s
        self.ports.publish_raw(stamp_ns, [float(gyro[i]) for i in self.indices],
                               [float(sample.temperature_c)], sample.acceleration_m_s2,
                               self.acceleration_covariance)
        if self.window is not None:
            self.window.add(stamp_ns, sample.gyro_rad_s, sample.acceleration_m_s2,
                            sample.temperature_c)
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
        outcome = await guarded(self.guard, 'an offset calibration', self._calibrate)
        return messages.answer_trigger(self.logger, response, outcome, 'offset calibration')

    async def _calibrate(self) -> Outcome:
        """Fill the window from the stream (or raise `Refused` on a stall); finish it."""
        settings = self.settings
        noise_rad_s = settings.rate_noise_rad_s
        if noise_rad_s <= 0.0:
            raise Refused('the motion check needs a positive rate_noise_rad_s (the 1-sigma '
                          'gyro noise of one sample)')
        window = SampleWindow(int(settings.mpu6000.calibration_duration_s * 1e9))

        def stalled() -> None:
            stalled_s = time.monotonic() - self.last_sample
            if stalled_s > STALL_TIMEOUT_S:
                raise Refused(f'no sample for {stalled_s:.1f} s, the stream stalled '
                              f'({self.last_error or "no error"})')

        self.window = window
        try:
            await await_window(self.ports.node, window.future, stalled)
        finally:
            self.window = None
        return self._finish(window, noise_rad_s, settings.mpu6000.calibration_noise_multiple)

    def _finish(self, window: SampleWindow, noise_rad_s: float, multiple: float) -> Outcome:
        gyro, acceleration, temperature = window.columns()
        # Only the spread: the mean is the bias to cancel, the temperature free to move.
        limits = RecalibrationLimits(rate_noise_rad_s=noise_rad_s, noise_multiple=multiple,
                                     max_mean_rate_rad_s=math.inf,
                                     max_temperature_change_c=math.inf, min_samples=2,
                                     spread_ddof=1)
        try:
            check_window(gyro, temperature, limits, _BOARD_MOVES)
            bias = rest_bias(gyro, acceleration)
            gyro_lsb, accel_lsb = recalibrated_offsets(self.gyro_lsb, self.accel_bias_lsb, bias)
            registers = self.source.write_offsets(gyro_lsb, accel_lsb)
        except CalibrationError as err:
            raise Refused(str(err)) from None
        except HardwareError as err:
            raise Refused(f'writing the offset registers failed: {err}') from None
        before_gyro, before_registers = list(self.gyro_lsb), list(self.accel_registers)
        self._offsets_now(gyro_lsb, accel_lsb, registers, 'calibrated')
        temperature_c = float(np.mean(temperature))
        if self.refresh is not None:
            # The new registers cancel the whole bias at the window's temperature.
            self.refresh.base_lsb, self.refresh.base_temperature_c = gyro_lsb, temperature_c
            self.refresh.temperature_c = temperature_c
        state = offsets_state(self.variant, gyro_lsb, accel_lsb, registers, bias, temperature_c)
        residual = ', '.join(f'{math.degrees(v):+.4f}' for v in bias.gyro_rad_s)
        text = (f'gyro offsets from {before_gyro} to {list(gyro_lsb)} LSB, accel offset '
                f'registers from {before_registers} to {list(registers)} (bias '
                f'{list(accel_lsb)} LSB at 16 g), gravity on {state["gravity_axis"]}, '
                f'{bias.samples} samples at {temperature_c:.2f} C (gyro bias before '
                f'{residual} deg/s)')
        return messages.saved_reply(self.offsets_path, state, text)
