"""
A correction of any model: a bias table in temperature, taken off after the model.

`CorrectionTable` holds, per axis, a bias in rad/s at the temperatures T_0 < ... < T_n-1
(its knots): a cubic between them (Catmull-Rom: the cubic Hermite whose slope at a knot
is that of the chord between its neighbours, one-sided at the ends; two knots give a
line), held beyond the first and the last, as PX4 clamps its cubic at its range. A value
is a weighted sum of four knot values (`knot_weights`), computed with the same operations
for a column and for a float, so a row gives, bit for bit, the element of a block.

A table of +0.0 (the learner's until its first renewal) takes nothing off any rate, bit
for bit, at any temperature but NaN (`CorrectionTable.subtracts_nothing`), so the node's
per-sample path need not compute its row: each term is a weight times +0.0, and the upper
knot's weight (h01 + g0) is never negative for a temperature held within its interval, so
the sum is +0.0 (and NaN at NaN, whose weights are NaN).

`CorrectedModel` is a model the compensation node runs (`CompensationModel`): the base
model's corrected rate less the table at each axis's temperature. The field learner
(`core.learning`) renews a model this way, whatever the model is (eeprom, polynomial,
effects, chain): the base model's parameters stay as they were and the learnt part is the
table, the ``correction.*`` parameters (`parameters.models`), so a diff of a renewed
parameter file against the factory or chamber file shows exactly what was learnt.
"""

import bisect
from dataclasses import dataclass
import functools
import math

import numpy as np

from .interface import CorrectedRate, ModelInputs, NO_INPUTS
from .model_error import table_temperatures
from .rate_models import model_fingerprint, rate_temperature_columns
from ..errors import ConfigError


@dataclass(frozen=True)
class CorrectionTable:
    """
    A bias table per axis: ``values_rad_s`` holds one tuple per axis, a value per knot.

    ``temperature_c`` are the knots, strictly increasing, degC.
    """

    temperature_c: tuple
    values_rad_s: tuple

    def __post_init__(self) -> None:
        knots = table_temperatures(self.temperature_c)
        values = tuple(tuple(float(v) for v in axis) for axis in self.values_rad_s)
        if not 1 <= len(values) <= 3:
            msg = f'a correction table needs 1 to 3 axes, got {len(values)}'
            raise ConfigError(msg)
        for axis, column in enumerate(values):
            if len(column) != len(knots):
                msg = (f'correction of axis {axis} needs {len(knots)} values (one per '
                       f'temperature), got {len(column)}')
                raise ConfigError(msg)
            if not all(math.isfinite(v) for v in column):
                msg = f'correction of axis {axis} must be finite, got {list(column)}'
                raise ConfigError(msg)
        object.__setattr__(self, 'temperature_c', knots)
        object.__setattr__(self, 'values_rad_s', values)

    @classmethod
    def zero(cls, temperature_c, axes: int) -> 'CorrectionTable':
        """Give a table of zeros on the knots ``temperature_c``."""
        return cls(tuple(temperature_c), ((0.0,) * len(temperature_c),) * axes)

    @property
    def axes(self) -> int:
        return len(self.values_rad_s)

    @property
    def is_zero(self) -> bool:
        """Tell whether every value is 0 (the table changes nothing)."""
        return not any(v for axis in self.values_rad_s for v in axis)

    def with_axis(self, axis: int, values) -> 'CorrectionTable':
        """Give the table with the values of ``axis`` (an index) replaced."""
        columns = list(self.values_rad_s)
        columns[axis] = tuple(float(v) for v in values)
        return CorrectionTable(self.temperature_c, tuple(columns))

    def added(self, other: 'CorrectionTable') -> 'CorrectionTable':
        """Give the sum of two tables on the same knots."""
        if other.temperature_c != self.temperature_c or other.axes != self.axes:
            raise ConfigError('correction tables add only on the same knots and axes')
        return CorrectionTable(self.temperature_c, tuple(
            tuple(a + b for a, b in zip(mine, theirs))
            for mine, theirs in zip(self.values_rad_s, other.values_rad_s)))

    def at(self, axis: int, temperature_c):
        """Give the bias of an axis (index) at a column of temperatures, or one, to the bit."""
        values = self.values_rad_s[axis]
        (i0, w0), (i1, w1), (i2, w2), (i3, w3) = knot_weights(self.temperature_c, temperature_c)
        if isinstance(temperature_c, np.ndarray):
            column = np.asarray(values)
            return w0 * column[i0] + w1 * column[i1] + w2 * column[i2] + w3 * column[i3]
        return w0 * values[i0] + w1 * values[i1] + w2 * values[i2] + w3 * values[i3]

    def row(self, temperature_c: float) -> list:
        """Give every axis's bias at one temperature: the bits of `at`, the weights once."""
        (i0, w0), (i1, w1), (i2, w2), (i3, w3) = knot_weights(self.temperature_c,
                                                              temperature_c)
        return [w0 * v[i0] + w1 * v[i1] + w2 * v[i2] + w3 * v[i3] for v in self.values_rad_s]

    # Cached (the table is frozen): the learner's stream asks at every sample.
    @functools.cached_property
    def subtracts_nothing(self) -> bool:
        """
        Tell whether a rate less the table is the rate, bit for bit, at any temperature but NaN.

        So it is with +0.0 on two knots or more (see the module notes): the row is +0.0, and
        r - (+0.0) is r, -0.0 included. Not with -0.0 (the terms' signs would follow the
        weights'), nor with one knot (its weight is NaN at an infinite temperature).
        """
        return len(self.temperature_c) > 1 and all(
            v == 0.0 and math.copysign(1.0, v) > 0.0 for axis in self.values_rad_s for v in axis)

    def columns(self, temperature_c: np.ndarray) -> np.ndarray:
        """Give the bias (samples, axes) at temperatures (samples, axes)."""
        return np.column_stack([self.at(axis, np.ascontiguousarray(temperature_c[:, axis]))
                                for axis in range(self.axes)])

    def to_parameters(self, axis_names) -> dict:
        """Give the ``correction`` section of the node's parameters (`parameters.models`)."""
        names = tuple(axis_names)
        if len(names) != self.axes:
            msg = f'{len(names)} axis names for a correction of {self.axes} axes'
            raise ConfigError(msg)
        return {'correction': {'temperature_c': [float(t) for t in self.temperature_c],
                               **{f'{axis}_rad_s': [float(v) for v in column]
                                  for axis, column in zip(names, self.values_rad_s)}}}


def knot_weights(knots: tuple, temperature_c) -> tuple:
    """
    Give the four (knot index, weight) pairs of the table's value at ``temperature_c``.

    A column (numpy) gives index and weight columns, a float gives ints and floats, by the
    same operations in the same order. The temperature is held at the first and last knot;
    NaN gives NaN weights.
    """
    count = len(knots)
    block = isinstance(temperature_c, np.ndarray)
    if count == 1:
        zero = np.zeros(temperature_c.shape, dtype=np.intp) if block else 0
        weight = temperature_c * 0.0 + 1.0
        return ((zero, weight), (zero, weight * 0.0), (zero, weight * 0.0), (zero, weight * 0.0))
    low, high = knots[0], knots[-1]
    if block:
        held = np.clip(temperature_c, low, high)
        interval = np.clip(np.searchsorted(knots, held, side='right') - 1, 0, count - 2)
        lower = np.asarray(knots)[interval]
        upper = np.asarray(knots)[interval + 1]
        before = np.asarray(knots)[np.maximum(interval - 1, 0)]
        after = np.asarray(knots)[np.minimum(interval + 2, count - 1)]
        first, last = np.maximum(interval - 1, 0), np.minimum(interval + 2, count - 1)
    else:
        held = low if temperature_c < low else high if temperature_c > high else temperature_c
        interval = min(max(bisect.bisect_right(knots, held) - 1, 0), count - 2) \
            if held == held else count - 2
        lower, upper = knots[interval], knots[interval + 1]
        first, last = max(interval - 1, 0), min(interval + 2, count - 1)
        before, after = knots[first], knots[last]
    span = upper - lower
    u = (held - lower) / span
    uu = u * u
    uuu = uu * u
    h00 = 2.0 * uuu - 3.0 * uu + 1.0
    h01 = -2.0 * uuu + 3.0 * uu
    # The tangents' parts: slope at the lower knot over its neighbours' chord, at the upper one.
    g0 = (uuu - 2.0 * uu + u) * span / (upper - before)
    g1 = (uuu - uu) * span / (after - lower)
    return ((first, -g0), (interval, h00 - g1), (interval + 1, h01 + g0), (last, g1))


@dataclass(frozen=True)
class CorrectedModel:
    """
    A model less a `CorrectionTable`: ``base``'s corrected rate minus the table at T.

    Each axis takes its own temperature when the base model is given one per axis. The
    base model's ZRO offset stays the base's (taken off inside it); its name, inputs and
    units are the base's.
    """

    base: object
    table: CorrectionTable

    def __post_init__(self) -> None:
        if self.table.axes != self.base.axes:
            msg = f'a correction of {self.table.axes} axes for a model of {self.base.axes}'
            raise ConfigError(msg)

    @property
    def name(self) -> str:
        return self.base.name

    @property
    def axes(self) -> int:
        return self.base.axes

    @property
    def inputs(self) -> frozenset:
        return self.base.inputs

    @property
    def offset_unit(self) -> str:
        return self.base.offset_unit

    @property
    def zro_offset(self) -> tuple:
        return self.base.zro_offset

    def fingerprint(self) -> str:
        """Hash the base model's fingerprint and the table."""
        return model_fingerprint(self.name, {
            'base': self.base.fingerprint(), 'correction_c': list(self.table.temperature_c),
            'correction_rad_s': [list(column) for column in self.table.values_rad_s]})

    def correct(self, rate_rad_s, temperature_c, inputs: ModelInputs = NO_INPUTS
                ) -> CorrectedRate:
        result = self.base.correct(rate_rad_s, temperature_c, inputs)
        return self.less_table(result, temperature_c)

    def less_table(self, result: CorrectedRate, temperature_c) -> CorrectedRate:
        """Give the base model's ``result`` less the table at ``temperature_c``."""
        _, temperature = rate_temperature_columns(result.rate_rad_s, temperature_c, self.axes)
        return CorrectedRate(result.rate_rad_s - self.table.columns(temperature),
                             result.temperature_clamped)

    def stream(self) -> 'CorrectedStream':
        return CorrectedStream(self, self.base.stream())

    def with_zro_offset(self, offset) -> 'CorrectedModel':
        return CorrectedModel(self.base.with_zro_offset(offset), self.table)

    def learn_zro_offset(self, rate_rad_s, temperature_c, corrected_rad_s) -> np.ndarray:
        """
        Give the base model's ZRO offset that zeroes readings at rest once the table is off.

        A rad/s offset is taken off last: the base model's answer from what this model gave.
        Another unit (the eeprom model's shift, inside its formula) is found on the readings:
        the model's output is linear in the offset, so its slope from one probe gives the
        offset that brings the mean to zero.
        """
        if self.base.offset_unit == 'rad/s':
            return self.base.learn_zro_offset(rate_rad_s, temperature_c, corrected_rad_s)
        zeroed = np.asarray(self.base.learn_zro_offset(rate_rad_s, temperature_c,
                                                       corrected_rad_s), dtype=np.float64)

        def mean_at(offset):
            return np.mean(self.with_zro_offset(offset).correct(rate_rad_s, temperature_c)
                           .rate_rad_s, axis=0)

        left = mean_at(zeroed)
        probe = np.where(zeroed != 0.0, np.abs(zeroed), 1.0)
        slope = (mean_at(zeroed + probe) - left) / probe
        return zeroed - left / slope

    def offset_rad_s(self, temperature_c: float) -> np.ndarray:
        return self.base.offset_rad_s(temperature_c)


class CorrectedStream:
    """The node's runner of a `CorrectedModel`: the base model's stream, less the table."""

    def __init__(self, model: CorrectedModel, base_stream):
        self.model = model
        self.base_stream = base_stream

    def correct_block(self, rates_rad_s, temperatures_c,
                      inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        result = self.base_stream.correct_block(rates_rad_s, temperatures_c, inputs)
        return self.model.less_table(result, temperatures_c)

    def correct_one(self, rates_rad_s: list, temperatures_c: list,
                    inputs: ModelInputs = NO_INPUTS) -> tuple:
        """Correct one row: the bits of a block of one (the table's row is the block's)."""
        rates, clamped = self.base_stream.correct_one(rates_rad_s, temperatures_c, inputs)
        table = self.model.table
        if len(temperatures_c) == 1:
            values = table.row(float(temperatures_c[0]))
        else:
            values = [table.at(axis, float(t)) for axis, t in enumerate(temperatures_c)]
        return [r - v for r, v in zip(rates, values)], clamped
