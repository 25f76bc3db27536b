"""
Rate models the compensation node runs: they map raw rate and temperature to corrected rate.

Every model works on rate in rad/s of shape (samples, axes) and temperature in
degC of shape (samples,) or (samples, axes), and carries a ZRO offset per axis:
the residual learned at rest on top of the thermal model (the ZRO recalibration),
so recalibration and temperature model never count the same bias twice.

- `EepromModel`: the MLX90609 factory table (AN2 method 4) with its ZRO shift;
- `OffsetModel`: the ZRO offset in rad/s of the others, the effect model
  (`core.effects`, which also runs the ``polynomial`` and ``linear_btc``
  models) and the calibration chain (`core.node_models.chain`).
"""

from dataclasses import dataclass, replace
import hashlib
import json
import math
from typing import Optional

import numpy as np

from .interface import CorrectedRate, ModelInputs, NO_INPUTS
from ..errors import ConfigError
from ..mlx90609 import Output, SensorTransfer, TableCompensation

AXIS_NAMES = ('x', 'y', 'z')


def rate_temperature_columns(rate_rad_s, temperature_c, axes: int) -> tuple:
    """Give rate and temperature as float (samples, axes) arrays; ConfigError for a shape."""
    rate = np.asarray(rate_rad_s, dtype=np.float64)
    if rate.ndim == 1:
        rate = rate[:, None]
    if rate.ndim != 2 or rate.shape[1] != axes:
        msg = f'rate must have shape (samples, {axes}), got {np.shape(rate_rad_s)}'
        raise ConfigError(msg)
    temperature = np.asarray(temperature_c, dtype=np.float64)
    if temperature.ndim == 1:
        temperature = temperature[:, None]
    if temperature.shape[0] != rate.shape[0] or temperature.shape[1] not in (1, axes):
        msg = (f'temperature shape {np.shape(temperature_c)} does not match rate '
               f'{np.shape(rate_rad_s)}')
        raise ConfigError(msg)
    return rate, np.broadcast_to(temperature, rate.shape)


def finite_tuple(name: str, values, length: Optional[int] = None) -> tuple:
    """Give the finite floats of ``values``, ``length`` of them if given; else ConfigError."""
    values = tuple(float(v) for v in values)
    if length is not None and len(values) != length:
        msg = f'{name} needs {length} values (one per axis), got {len(values)}'
        raise ConfigError(msg)
    if not all(math.isfinite(v) for v in values):
        msg = f'{name} must be finite, got {list(values)}'
        raise ConfigError(msg)
    return values


class _Streamed:
    """
    A model without state and without inputs beyond rate and temperature.

    Its ``correct`` takes the ``inputs`` every model takes, and uses none.
    """

    inputs = frozenset()

    def stream(self) -> '_StatelessStream':
        """Return the block-by-block runner the node uses; this model keeps no state."""
        return _StatelessStream(self)


class _StatelessStream:
    """
    The `ModelStream` of a model without state.

    Every operation of the models is element by element, so a block gives,
    bit for bit, what its rows give one at a time.
    """

    def __init__(self, model: _Streamed):
        self.model = model

    def correct_block(self, rates_rad_s, temperatures_c,
                      inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        return self.model.correct(rates_rad_s, temperatures_c)

    def correct_one(self, rates_rad_s: list, temperatures_c: list,
                    inputs: ModelInputs = NO_INPUTS) -> tuple:
        """Correct one row: (rad/s per axis as a list, any clamped); as `correct_block`."""
        row = getattr(self.model, 'correct_row', None)
        result = None if row is None else row(rates_rad_s, temperatures_c)
        return one_row(self, rates_rad_s, temperatures_c) if result is None else result


def one_row(stream, rates_rad_s: list, temperatures_c: list,
            inputs: ModelInputs = NO_INPUTS) -> tuple:
    """Correct one row through ``stream.correct_block``: (rad/s list, any clamped)."""
    result = stream.correct_block([rates_rad_s], [temperatures_c], inputs.rows())
    return result.rate_rad_s[0].tolist(), bool(result.temperature_clamped.any())


def model_fingerprint(name: str, content: dict) -> str:
    """Give a short hash of a model's name and parameters (JSON, keys sorted)."""
    text = json.dumps({'model': name, **content}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class OffsetModel(_Streamed):
    """ZRO offset handling shared by the models whose offset is in rad/s."""

    offset_unit = 'rad/s'

    @property
    def zro_offset(self) -> tuple:
        return self.zro_offset_rad_s

    def with_zro_offset(self, offset):
        offset = finite_tuple('zro_offset_rad_s', np.ravel(offset), self.axes)
        return replace(self, zro_offset_rad_s=offset)

    def learn_zro_offset(self, rate_rad_s, temperature_c, corrected_rad_s) -> np.ndarray:
        """
        Return the total offset that zeroes the mean of readings taken at rest.

        ``corrected_rad_s`` is what this model gave for them. The offset is taken
        off last, so the answer is the current offset plus the mean corrected
        rate: no need to replay the readings (stateful models could not).
        """
        return np.asarray(self.zro_offset_rad_s) + np.mean(
            np.asarray(corrected_rad_s, dtype=np.float64).reshape(-1, self.axes), axis=0)

    def offset_rad_s(self, temperature_c: float) -> np.ndarray:
        return np.asarray(self.zro_offset_rad_s)


@dataclass(frozen=True)
class EepromModel(_Streamed):
    """
    AN2 method 4 on rate published by the nominal conversion.

    The raw stream carries the nominal rate (rad/s) and the sensed temperature
    (degC by the typical transfer); both map back exactly to the output units
    (ADC codes or mV) the factory table is in. The ZRO offset is AN2's ZRO shift,
    in output units, added to formula (4).
    """

    compensation: TableCompensation
    transfer: SensorTransfer = SensorTransfer()

    name = 'eeprom'

    @property
    def axes(self) -> int:
        return self.compensation.axes

    @property
    def zro_offset(self) -> tuple:
        return self.compensation.zro_shift

    @property
    def offset_unit(self) -> str:
        return 'LSB' if self.compensation.output.value == 'digital' else 'mV'

    def fingerprint(self) -> str:
        tables = [None if t is None else [t.output.value, t.tc, t.zro, t.sf]
                  for t in self.compensation.tables]
        return model_fingerprint(self.name, {
            'tables': tables, 'interpolation': self.compensation.interpolation.value,
            'nominal': [self.compensation.nominal.zro, self.compensation.nominal.sf]})

    def _to_output_units(self, rate_rad_s, temperature_c) -> tuple:
        rate, temperature = rate_temperature_columns(rate_rad_s, temperature_c, self.axes)
        nominal = self.compensation.nominal
        outar = np.rad2deg(rate) * nominal.sf + nominal.zro
        mv = self.transfer.temperature_mv_from_c(temperature)
        return outar, self.transfer.temperature_to_output(mv, nominal.output)

    def correct(self, rate_rad_s, temperature_c,
                inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        outar, tempout = self._to_output_units(rate_rad_s, temperature_c)
        result = self.compensation.compensate(outar, tempout)
        return CorrectedRate(np.deg2rad(result.rate_dps), result.temperature_clamped)

    def correct_row(self, rates_rad_s: list, temperatures_c: list):
        """
        Correct one reading in plain floats, bit for bit as `correct` does; None if it cannot.

        The per-message path of the node, where numpy's per-call overhead would dominate.
        """
        nominal = self.compensation.nominal
        transfer = self.transfer
        outar = [math.degrees(r) * nominal.sf + nominal.zro for r in rates_rad_s]
        mv = [transfer.temperature_sensor_mv_at_25c
              + (t - 25.0) * transfer.temperature_sensor_mv_per_k for t in temperatures_c]
        tempout = mv if nominal.output is Output.ANALOG else \
            [(v - transfer.temperature_offset_mv) / transfer.temperature_mv_per_lsb for v in mv]
        result = self.compensation.compensate_row(outar, tempout)
        if result is None:
            return None
        rates_dps, clamped = result
        return [math.radians(r) for r in rates_dps], clamped

    def with_zro_offset(self, offset) -> 'EepromModel':
        return replace(self, compensation=self.compensation.with_zro_shift(offset))

    def learn_zro_offset(self, rate_rad_s, temperature_c, corrected_rad_s) -> np.ndarray:
        """
        Return AN2's ZRO shift (output units) that zeroes readings taken at rest.

        The shift sits inside formula (4), so it is learned from the raw readings;
        ``corrected_rad_s`` is not needed.
        """
        outar, tempout = self._to_output_units(rate_rad_s, temperature_c)
        return self.compensation.learn_zro_shift(outar, tempout)

    def offset_rad_s(self, temperature_c: float) -> np.ndarray:
        """Express the ZRO shift as rate at ``temperature_c`` (for reports)."""
        _, tempout = self._to_output_units(np.zeros((1, self.axes)), [temperature_c])
        sf = [self.compensation.sf(a, tempout[0, a]) for a in range(self.axes)]
        return np.deg2rad(np.asarray(self.compensation.zro_shift) / np.asarray(sf, dtype=float))


@dataclass(frozen=True)
class RateOnlyModel(OffsetModel):
    """
    No temperature model: the raw rate less the ZRO offset, whatever the temperature.

    What the node runs while it has no temperature, or no factory tables for the
    eeprom model: the bias tracking then follows the raw rate's offset alone.
    """

    axes: int = 1
    zro_offset_rad_s: tuple = ()

    name = 'rate_only'

    def __post_init__(self) -> None:
        offset = self.zro_offset_rad_s or (0.0,) * self.axes
        object.__setattr__(self, 'zro_offset_rad_s',
                           finite_tuple('zro_offset_rad_s', offset, self.axes))

    def fingerprint(self) -> str:
        return model_fingerprint(self.name, {'axes': self.axes})

    def correct(self, rate_rad_s, temperature_c, inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        """Take the offset off the rate; the temperature (NaN when there is none) is not used."""
        rate = np.asarray(rate_rad_s, dtype=np.float64).reshape(-1, self.axes)
        return CorrectedRate(rate - np.asarray(self.zro_offset_rad_s),
                             np.zeros(rate.shape, dtype=bool))

    def correct_row(self, rates_rad_s: list, temperatures_c: list) -> tuple:
        """Correct one row in plain floats, bit for bit `correct`'s."""
        return [r - o for r, o in zip(rates_rad_s, self.zro_offset_rad_s)], False
