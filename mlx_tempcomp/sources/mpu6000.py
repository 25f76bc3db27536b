"""
An MPU-6000 / MPU-6050 / MPU-6500 read as a 3-axis source: over spidev or i2c-dev, or simulated.

Each sample carries gyro rad/s, acceleration m/s^2, the die temperature and
a stamp on the source's clock (simulated seconds, or monotonic seconds on
hardware). `calibrate_offsets` runs the note's procedure: a record at rest,
the bias with gravity removed, the offsets written to the part.
"""

from dataclasses import dataclass
import time
from typing import Callable, Sequence, Tuple

import numpy as np

from ..core.procedures import accel_offset_lsb, gyro_offset_lsb, rest_bias, RestBias
from ..hardware.errors import HardwareError
from ..hardware.mpu6000 import I2C_ADDRESSES, Mpu6000, variant_named
from ..hardware.transport import open_i2c, SpidevTransport
from ..simulation.clock import SimClock
from ..simulation.mpu6000 import MpuTruth, SimulatedMpu6000

AXES = ('x', 'y', 'z')


@dataclass(frozen=True)
class ImuSample:
    """One reading and when it was taken, seconds on the source's clock."""

    time_s: float
    gyro_rad_s: np.ndarray
    acceleration_m_s2: np.ndarray
    temperature_c: float
    saturated: bool


@dataclass(frozen=True)
class ImuSamples:
    """Samples stacked: time_s (n,), gyro_rad_s (n, 3), acceleration_m_s2 (n, 3), (n,)."""

    time_s: np.ndarray
    gyro_rad_s: np.ndarray
    acceleration_m_s2: np.ndarray
    temperature_c: np.ndarray


@dataclass(frozen=True)
class OffsetCalibration:
    """What `calibrate_offsets` measured and wrote (registers signed)."""

    bias: RestBias
    temperature_c: float
    gyro_lsb: Tuple[int, int, int]
    accel_bias_lsb: Tuple[int, int, int]
    accel_registers: Tuple[int, int, int]


class MpuSource:
    """A started `Mpu6000` and the clock that stamps its samples."""

    axes = AXES

    def __init__(self, device: Mpu6000, now_s: Callable[[], float]):
        self.device = device
        self.now_s = now_s

    def start(self) -> None:
        self.device.start()

    def read(self) -> ImuSample:
        stamp = self.now_s()
        reading = self.device.read()
        return ImuSample(time_s=stamp, gyro_rad_s=reading.gyro_rad_s,
                         acceleration_m_s2=reading.acceleration_m_s2,
                         temperature_c=reading.temperature_c, saturated=reading.saturated)

    def record(self, samples: int, period_s: float) -> ImuSamples:
        """Read ``samples`` samples ``period_s`` apart (saturated ones raise)."""
        if samples < 1 or period_s < 0.0:
            msg = f'a record needs samples >= 1 and period_s >= 0, got {samples}, {period_s}'
            raise HardwareError(msg)
        rows = []
        for index in range(samples):
            if index:
                self.device.transport.wait(period_s)
            sample = self.read()
            if sample.saturated:
                msg = f'sample {index} of the record is saturated: the part is not at rest'
                raise HardwareError(msg)
            rows.append(sample)
        return ImuSamples(time_s=np.array([r.time_s for r in rows]),
                          gyro_rad_s=np.array([r.gyro_rad_s for r in rows]),
                          acceleration_m_s2=np.array([r.acceleration_m_s2 for r in rows]),
                          temperature_c=np.array([r.temperature_c for r in rows]))

    def write_offsets(self, gyro_lsb: Sequence[int],
                      accel_bias_lsb: Sequence[int]) -> Tuple[int, int, int]:
        """Write gyro offsets and merge accel biases onto the factory values (after `start`)."""
        self.device.write_gyro_offsets(gyro_lsb)
        return self.device.write_accel_offsets(accel_bias_lsb)

    def calibrate_offsets(self, samples: int = 200, period_s: float = 0.005
                          ) -> OffsetCalibration:
        """
        Measure the bias at rest and write the offsets that cancel it.

        The part must lie still, face up or down; its current user offsets are
        cleared first (gyro 0, accel factory values) so the record shows the
        bias of the bare part. 200 samples as in the note's Motion Driver.
        """
        self.write_offsets((0, 0, 0), (0, 0, 0))
        record = self.record(samples, period_s)
        bias = rest_bias(record.gyro_rad_s, record.acceleration_m_s2)
        gyro = gyro_offset_lsb(bias.gyro_rad_s)
        accel = accel_offset_lsb(bias.acceleration_m_s2)
        registers = self.write_offsets(gyro, accel)
        return OffsetCalibration(bias=bias, temperature_c=float(record.temperature_c.mean()),
                                 gyro_lsb=gyro, accel_bias_lsb=accel, accel_registers=registers)

    @property
    def counters(self) -> dict:
        return self.device.counters.as_dict()

    def close(self) -> None:
        self.device.transport.close()


class SimulatedMpuSource(MpuSource):
    """A `SimulatedMpu6000` on its own simulated clock, read over SPI or I2C (``bus``)."""

    def __init__(self, truth: MpuTruth = MpuTruth(), variant: str = 'mpu6000', seed: int = 0,
                 bus: str = 'spi', i2c_address: int = I2C_ADDRESSES[0], **options):
        self.clock = SimClock()
        self.simulated = SimulatedMpu6000(truth, variant_named(variant), self.clock, seed,
                                          i2c_address=i2c_address)
        if bus not in ('spi', 'i2c'):
            msg = f'bus must be spi or i2c, got {bus!r}'
            raise HardwareError(msg)
        transport = self.simulated.transport() if bus == 'spi' else \
            self.simulated.i2c_transport()
        super().__init__(Mpu6000(transport, variant_named(variant), **options),
                         lambda: self.clock.now_s)

    def advance_to(self, time_s: float) -> None:
        """Let simulated time pass up to ``time_s`` (never backwards)."""
        self.clock.advance(time_s - self.clock.now_s)


def spidev_mpu(bus: int, chip_select: int, speed_hz: int = 1_000_000, mode: int = 3,
               variant: str = 'mpu6000', **options) -> MpuSource:
    """Open the part on ``/dev/spidev<bus>.<chip_select>``, stamped in monotonic seconds."""
    part = variant_named(variant)
    transport = SpidevTransport(bus, chip_select, speed_hz, mode)
    try:
        device = Mpu6000(transport, part, **options)
    except HardwareError:
        transport.close()
        raise
    return MpuSource(device, time.monotonic)


def i2c_mpu(bus: int, address: int = I2C_ADDRESSES[0], variant: str = 'mpu6000',
            **options) -> MpuSource:
    """Open the part at ``address`` on ``/dev/i2c-<bus>``, stamped in monotonic seconds."""
    part = variant_named(variant)
    transport = open_i2c(bus, address)
    try:
        device = Mpu6000(transport, part, **options)
    except HardwareError:
        transport.close()
        raise
    return MpuSource(device, time.monotonic)
