"""
Angular rate from MLX90609 outputs: Q = (OUTAR - ZRO) / SF (AN2 formula (2)).

Two conversions share one interface, for one to three axes at once:

- `NominalConversion`: AN2 method 1, nominal ZRO and typical SF.
- `TableCompensation`: AN2 method 4, ZRO(TEMPOUT) and SF(TEMPOUT) interpolated
  from each axis' factory table, plus the ZRO shift learned at zero rate
  (AN2 note after formula (13)). An axis whose EEPROM holds no table
  (VERSION 0) falls back to the nominal values.

Readings are arrays of shape (samples,) for one axis or (samples, axes);
TEMPOUT of shape (samples,) is shared by all axes. Temperatures outside
[TC0, TC2] are clamped, never extrapolated, and flagged in the result.
"""

from dataclasses import dataclass, field, replace
import functools

import numpy as np

from .conversion import Output, SensorTransfer
from .interpolation import interpolate, Interpolation, quadratic_coefficients
from ..errors import ConfigError

# Samples per block: small enough for the scratch arrays to stay in cache.
_BLOCK = 1 << 14


@dataclass(frozen=True)
class CompensatedRate:
    """Rate in deg/s, and which samples had their temperature clamped."""

    rate_dps: np.ndarray
    temperature_clamped: np.ndarray

    @property
    def rate_rad_s(self) -> np.ndarray:
        return np.deg2rad(self.rate_dps)


def _as_columns(outar, tempout, axes: int) -> tuple:
    outar = np.asarray(outar, dtype=np.float64)
    tempout = np.asarray(tempout, dtype=np.float64)
    one_dimensional = outar.ndim == 1
    columns = outar[:, None] if one_dimensional else outar
    if columns.ndim != 2 or columns.shape[1] != axes:
        msg = f'readings must have shape (samples, {axes}), got {outar.shape}'
        raise ConfigError(msg)
    if tempout.ndim == 1:
        tempout = np.broadcast_to(tempout[:, None], columns.shape)
    if tempout.shape != columns.shape:
        msg = f'TEMPOUT shape {tempout.shape} does not match readings {outar.shape}'
        raise ConfigError(msg)
    return columns, tempout, one_dimensional


@dataclass(frozen=True)
class NominalConversion:
    """AN2 method 1: nominal ZRO and typical SF, no temperature dependence."""

    output: Output
    zro: float
    sf: float
    axes: int = 1

    @classmethod
    def for_range(cls, full_scale_dps: float, output: Output, axes: int = 1,
                  transfer: SensorTransfer = SensorTransfer()) -> 'NominalConversion':
        return cls(output=output, zro=transfer.nominal_zro(output),
                   sf=transfer.typical_sf(full_scale_dps, output), axes=axes)

    def compensate(self, outar, tempout) -> CompensatedRate:
        columns, temp, one_dimensional = _as_columns(outar, tempout, self.axes)
        rate = (columns - self.zro) / self.sf
        clamped = np.zeros(columns.shape, dtype=bool)
        if one_dimensional:
            return CompensatedRate(rate[:, 0], clamped[:, 0])
        return CompensatedRate(rate, clamped)


@dataclass(frozen=True)
class TableCompensation:
    """AN2 method 4 for each axis, with an optional ZRO shift in output units."""

    tables: tuple
    nominal: NominalConversion
    interpolation: Interpolation = Interpolation.QUADRATIC
    zro_shift: tuple = field(default=())

    def __post_init__(self) -> None:
        if not 1 <= len(self.tables) <= 3:
            msg = f'one to three axes are supported, got {len(self.tables)} tables'
            raise ConfigError(msg)
        if self.nominal.axes != len(self.tables):
            msg = f'nominal conversion is for {self.nominal.axes} axes, not {len(self.tables)}'
            raise ConfigError(msg)
        for axis, table in enumerate(self.tables):
            if table is not None and table.output is not self.nominal.output:
                msg = (f'axis {axis} table is for the {table.output.value} output, '
                       f'the conversion for the {self.nominal.output.value} output')
                raise ConfigError(msg)
        if not self.zro_shift:
            object.__setattr__(self, 'zro_shift', (0.0,) * len(self.tables))
        if len(self.zro_shift) != len(self.tables):
            msg = f'zro_shift needs {len(self.tables)} values, got {len(self.zro_shift)}'
            raise ConfigError(msg)
        if not np.all(np.isfinite(self.zro_shift)):
            msg = f'zro_shift must be finite, got {list(self.zro_shift)}'
            raise ConfigError(msg)

    @property
    def axes(self) -> int:
        return len(self.tables)

    @property
    def output(self) -> Output:
        return self.nominal.output

    @functools.cached_property
    def _quadratics(self) -> tuple:
        """Per axis: ((A_z, B_z, C_z), (A_s, B_s, C_s)) or None without a table."""
        return tuple(
            None if t is None else (quadratic_coefficients(t.tc, t.zro),
                                    quadratic_coefficients(t.tc, t.sf))
            for t in self.tables)

    def with_zro_shift(self, zro_shift) -> 'TableCompensation':
        return replace(self, zro_shift=tuple(float(s) for s in np.ravel(zro_shift)))

    def zro(self, axis: int, tempout) -> np.ndarray:
        """ZRO(TEMPOUT) of one axis in output units, shift included, TEMPOUT clamped."""
        table = self.tables[axis]
        if table is None:
            return np.full(np.shape(tempout), self.nominal.zro + self.zro_shift[axis])
        clamped = np.clip(tempout, table.tc[0], table.tc[2])
        return interpolate(self.interpolation, table.tc, table.zro, clamped) + \
            self.zro_shift[axis]

    def sf(self, axis: int, tempout) -> np.ndarray:
        """SF(TEMPOUT) of one axis in output units per deg/s, TEMPOUT clamped."""
        table = self.tables[axis]
        if table is None:
            return np.full(np.shape(tempout), self.nominal.sf)
        clamped = np.clip(tempout, table.tc[0], table.tc[2])
        return interpolate(self.interpolation, table.tc, table.sf, clamped)

    def learn_zro_shift(self, outar, tempout) -> np.ndarray:
        """
        Mean of OUTAR - ZRO(TEMPOUT) per axis over readings taken at zero rate.

        The result is the total shift to use, this model's own shift included.
        """
        columns, temp, _ = _as_columns(outar, tempout, self.axes)
        if columns.shape[0] == 0:
            msg = 'no readings to learn the ZRO shift from'
            raise ConfigError(msg)
        base = replace(self, zro_shift=(0.0,) * self.axes)
        return np.array([np.mean(columns[:, a] - base.zro(a, temp[:, a]))
                         for a in range(self.axes)])

    def compensate(self, outar, tempout) -> CompensatedRate:
        columns, temp, one_dimensional = _as_columns(outar, tempout, self.axes)
        rate = np.empty(columns.shape)
        clamped = np.zeros(columns.shape, dtype=bool)
        for axis, table in enumerate(self.tables):
            if table is None:
                rate[:, axis] = (columns[:, axis] - self.nominal.zro - self.zro_shift[axis]) \
                    / self.nominal.sf
                continue
            if self.interpolation is Interpolation.QUADRATIC:
                self._compensate_quadratic(axis, columns[:, axis], temp[:, axis],
                                           rate[:, axis], clamped[:, axis])
                continue
            t = temp[:, axis]
            clamped[:, axis] = (t < table.tc[0]) | (t > table.tc[2]) | np.isnan(t)
            rate[:, axis] = (columns[:, axis] - self.zro(axis, t)) / self.sf(axis, t)
        if one_dimensional:
            return CompensatedRate(rate[:, 0], clamped[:, 0])
        return CompensatedRate(rate, clamped)

    def compensate_row(self, outar: list, tempout: list) -> tuple:
        """
        Compensate one reading in plain floats: (rate in deg/s per axis, any clamped).

        Bit for bit what `compensate` gives that row (the same operations in the same
        order) for the quadratic interpolation; None for the others.
        """
        if self.interpolation is not Interpolation.QUADRATIC:
            return None
        shared = len(tempout) == 1
        rates, clamped = [], False
        for axis, table in enumerate(self.tables):
            reading = outar[axis]
            if table is None:
                rates.append((reading - self.nominal.zro - self.zro_shift[axis])
                             / self.nominal.sf)
                continue
            (az, bz, cz), (a_s, b_s, c_s) = self._quadratics[axis]
            cz = cz + self.zro_shift[axis]
            raw = tempout[0] if shared else tempout[axis]
            low, high = table.tc[0], table.tc[2]
            t = low if raw < low else high if raw > high else raw   # NaN stays NaN
            clamped = clamped or t != raw
            rates.append((reading - ((t * az + bz) * t + cz)) / ((t * a_s + b_s) * t + c_s))
        return rates, clamped

    def _compensate_quadratic(self, axis: int, outar: np.ndarray, tempout: np.ndarray,
                              rate: np.ndarray, clamped: np.ndarray) -> None:
        """Horner evaluation of formulas (3) and (4) block by block, in place."""
        (az, bz, cz), (a_s, b_s, c_s) = self._quadratics[axis]
        cz = cz + self.zro_shift[axis]
        low, high = self.tables[axis].tc[0], self.tables[axis].tc[2]
        block = min(_BLOCK, len(outar))
        t_buf = np.empty(block)
        v_buf = np.empty(block)
        for start in range(0, len(outar), block):
            stop = min(start + block, len(outar))
            t = t_buf[:stop - start]
            v = v_buf[:stop - start]
            r = rate[start:stop]
            np.clip(tempout[start:stop], low, high, out=t)
            # Clamped, or NaN (NaN != NaN), so a bad reading is never unflagged.
            np.not_equal(t, tempout[start:stop], out=clamped[start:stop])
            np.multiply(t, az, out=v)
            v += bz
            v *= t
            v += cz
            np.subtract(outar[start:stop], v, out=r)
            np.multiply(t, a_s, out=v)
            v += b_s
            v *= t
            v += c_s
            r /= v


def table_compensation(tables, full_scale_dps: float, output: Output,
                       interpolation: Interpolation = Interpolation.QUADRATIC,
                       transfer: SensorTransfer = SensorTransfer(),
                       zro_shift: tuple = ()) -> TableCompensation:
    """Build a `TableCompensation` with its nominal fallback for ``full_scale_dps``."""
    tables = tuple(tables)
    nominal = NominalConversion.for_range(full_scale_dps, output, len(tables), transfer)
    return TableCompensation(tables=tables, nominal=nominal, interpolation=interpolation,
                             zro_shift=tuple(zro_shift))
