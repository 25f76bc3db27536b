"""
MLX90609 channel transfer functions (ADC code <-> mV <-> physical units).

AN2 confirms the rate channel (960 LSB = 2400 mV, 912 LSB = 2300 mV, so
mV = LSB x 25/12 + 400). The other values come from
the fact sheet "MLX90609 and ADIS16130" and are UNCONFIRMED by a datasheet: they
are fields with those defaults, so a user can override each one.
"""

from dataclasses import dataclass
import enum

import numpy as np

from ..errors import ConfigError

ADC_MAX_CODE = 2047


class Output(str, enum.Enum):
    """Which MLX90609 output the table and readings are expressed for."""

    DIGITAL = 'digital'   # ADC codes (LSB) read over SPI
    ANALOG = 'analog'     # millivolts on the RATE and TEMP pins

    @classmethod
    def parse(cls, value: str) -> 'Output':
        try:
            return cls(value)
        except ValueError:
            msg = f"output must be 'digital' or 'analog', got {value!r}"
            raise ConfigError(msg) from None


# Typical full-scale ranges of the ordering options (AN2 section 3.1).
RANGE_OPTIONS_DPS = {'N2': 75.0, 'E2': 150.0, 'R2': 300.0}


@dataclass(frozen=True)
class SensorTransfer:
    """Channel transfer functions of one MLX90609 (defaults: sensor-facts.md)."""

    rate_mv_per_lsb: float = 25.0 / 12.0
    rate_offset_mv: float = 400.0
    temperature_mv_per_lsb: float = 25.0 / 16.0       # UNCONFIRMED
    temperature_offset_mv: float = 300.0              # UNCONFIRMED
    nominal_zro_mv: float = 2500.0
    # Full-scale output swing: 2.5 V +- 2.0 V for every range option, so the
    # typical scale factor is swing / full scale (26.67 mV/(deg/s) for N2).
    output_swing_mv: float = 2000.0                   # UNCONFIRMED
    temperature_sensor_mv_at_25c: float = 2500.0      # UNCONFIRMED
    temperature_sensor_mv_per_k: float = 10.0         # UNCONFIRMED

    def __post_init__(self) -> None:
        for name in ('rate_mv_per_lsb', 'temperature_mv_per_lsb', 'output_swing_mv',
                     'temperature_sensor_mv_per_k'):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0.0:
                msg = f'{name} must be a positive number, got {value}'
                raise ConfigError(msg)

    # Rate channel.
    def rate_lsb_to_mv(self, code):
        return np.asarray(code, dtype=np.float64) * self.rate_mv_per_lsb + self.rate_offset_mv

    def rate_mv_to_lsb(self, mv):
        return (np.asarray(mv, dtype=np.float64) - self.rate_offset_mv) / self.rate_mv_per_lsb

    # Temperature channel.
    def temperature_lsb_to_mv(self, code):
        return (np.asarray(code, dtype=np.float64) * self.temperature_mv_per_lsb
                + self.temperature_offset_mv)

    def temperature_mv_to_lsb(self, mv):
        return ((np.asarray(mv, dtype=np.float64) - self.temperature_offset_mv)
                / self.temperature_mv_per_lsb)

    def temperature_c_from_mv(self, mv):
        """Temperature by the typical sensor transfer (for display, not compensation)."""
        return 25.0 + ((np.asarray(mv, dtype=np.float64) - self.temperature_sensor_mv_at_25c)
                       / self.temperature_sensor_mv_per_k)

    def temperature_mv_from_c(self, temperature_c):
        return (self.temperature_sensor_mv_at_25c
                + (np.asarray(temperature_c, dtype=np.float64) - 25.0)
                * self.temperature_sensor_mv_per_k)

    # Output-domain helpers: what a table or a reading in `output` units means.
    def temperature_to_output(self, mv, output: Output):
        return mv if output is Output.ANALOG else self.temperature_mv_to_lsb(mv)

    def temperature_output_to_c(self, value, output: Output):
        mv = value if output is Output.ANALOG else self.temperature_lsb_to_mv(value)
        return self.temperature_c_from_mv(mv)

    def typical_sf(self, full_scale_dps: float, output: Output) -> float:
        """Typical scale factor S0 in mV/(deg/s) or LSB/(deg/s)."""
        if not np.isfinite(full_scale_dps) or full_scale_dps <= 0.0:
            msg = f'full scale must be a positive number of deg/s, got {full_scale_dps}'
            raise ConfigError(msg)
        sf_mv = self.output_swing_mv / full_scale_dps
        return sf_mv if output is Output.ANALOG else sf_mv / self.rate_mv_per_lsb

    def nominal_zro(self, output: Output) -> float:
        if output is Output.ANALOG:
            return self.nominal_zro_mv
        return float(self.rate_mv_to_lsb(self.nominal_zro_mv))
