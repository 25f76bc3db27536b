"""
What a sample source offers the driver: `SampleSource`, `SimulatedSource`, `Reading`.

Every part the driver streams (`mlx90609.Mlx90609Array`,
`adis16130.Adis16130Sensor`, `mpu6000.MpuSource`) is read one `Reading` at a
time, counts its bus errors and closes its transport; a simulated one also
runs on a simulated clock the driver advances. A new sensor's source
satisfies these protocols (test/sources/test_protocol.py checks each).

The readings stay three types: `mlx90609.RawSample` holds ADC codes, which
only the EEPROM tables the driver reads (and publishes, so the raw topics
reproduce compensation exactly) turn into rates and temperatures;
`adis16130.Sample` holds one axis's rate and temperature in physical units,
and `mpu6000.ImuSample` three gyro axes, acceleration and one temperature.
The driver averages each field by field (`decimation.mean_sample`) before it
converts: one type would move the MLX90609 conversion into its source or give
the others fields they never fill. What they share is `saturated`, which the
driver needs of every reading.
"""

from typing import Protocol, runtime_checkable


@runtime_checkable
class Reading(Protocol):
    """One reading of a part; a saturated one is skipped and counted."""

    saturated: bool


@runtime_checkable
class SampleSource(Protocol):
    """A started part (or array of parts) the driver reads on its schedule."""

    @property
    def counters(self) -> dict:
        """Give the bus error counters, by name."""

    def read(self) -> Reading:
        """Read one sample; `HardwareError` when the bus or the part fails."""

    def close(self) -> None:
        """Close the transport."""


@runtime_checkable
class SimulatedSource(SampleSource, Protocol):
    """A simulated source: its clock (``now_s``) moves only when it is advanced."""

    clock: object

    def advance_to(self, time_s: float) -> None:
        """Let simulated time pass up to ``time_s`` (never backwards)."""
