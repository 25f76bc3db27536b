"""
Hardware offset registers of InvenSense MPU parts: bias at rest to register values.

Follows the application note "Using Hardware Offset Registers for Calibration":

- bias at rest: the mean of each axis; the accelerometer axis that sees
  gravity (the part lies face up or down) has 1 g removed, its sign kept;
- gyro: register = -round(bias_dps / 0.031), the note's conversion for the
  +-1000 dps format; the register adds to the output, so the negated bias
  cancels it; a 16-bit two's complement word;
- accelerometer: bias in LSB at +-16 g, 1 g = 2048 LSB (0.08 g -> 163.84 ->
  164), subtracted from the factory (OTP) register value with bit 0 of the
  factory value kept: new = factory - (bias & ~1).

Values are Python ints; rounding is half away from zero, so a bias and its
negative give registers of opposite sign. `recalibrated_offsets` corrects
offsets already in place by what a rest window still sees; `OffsetRefresh`
makes the gyro registers follow a bias model as the temperature moves.
"""

from dataclasses import dataclass
import math
from typing import Sequence, Tuple

import numpy as np

from ..errors import CalibrationError

STANDARD_GRAVITY_M_S2 = 9.80665
GYRO_OFFSET_DPS_PER_LSB = 0.031       # the note's figure; 1000 / 32768 = 0.0305 exactly
ACCEL_OFFSET_LSB_PER_G = 2048.0       # +-16 g format
INT16_MIN = -32768
INT16_MAX = 32767
# A level part at rest sees 1 g on one axis; further off than this it is tilted or moving.
DEFAULT_GRAVITY_TOLERANCE_G = 0.25


def _round_half_away(value: float) -> int:
    return int(math.copysign(math.floor(abs(value) + 0.5), value))


def _int16(value: int, what: str) -> int:
    if not INT16_MIN <= value <= INT16_MAX:
        msg = f'{what} = {value} does not fit a 16-bit register ({INT16_MIN}..{INT16_MAX})'
        raise CalibrationError(msg)
    return value


def _three(values, what: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        msg = f'{what} needs 3 finite values, got {values!r}'
        raise CalibrationError(msg)
    return array


def twos_complement(value: int) -> int:
    """Encode a signed 16-bit value as its unsigned register word (0..65535)."""
    return _int16(int(value), 'register value') & 0xFFFF


def from_twos_complement(word: int) -> int:
    """Decode an unsigned 16-bit register word into a signed value."""
    word = int(word)
    if not 0 <= word <= 0xFFFF:
        msg = f'register word {word} is not 16 bits'
        raise CalibrationError(msg)
    return word - 0x10000 if word & 0x8000 else word


def gyro_offset_lsb(bias_rad_s: Sequence[float],
                    dps_per_lsb: float = GYRO_OFFSET_DPS_PER_LSB) -> Tuple[int, int, int]:
    """
    Return the XG/YG/ZG_OFFS_USR values that cancel a gyro bias.

    ``bias_rad_s`` is the mean rate at rest of x, y, z. Each register is
    -round(bias_dps / ``dps_per_lsb``); a value outside int16 raises
    `CalibrationError` naming the axis.
    """
    if not dps_per_lsb > 0.0:
        msg = f'dps_per_lsb must be positive, got {dps_per_lsb}'
        raise CalibrationError(msg)
    bias_dps = np.degrees(_three(bias_rad_s, 'gyro bias'))
    return tuple(_int16(-_round_half_away(b / dps_per_lsb), f'gyro offset {axis}')
                 for axis, b in zip('xyz', bias_dps))


def accel_offset_lsb(bias_m_s2: Sequence[float],
                     gravity_m_s2: float = STANDARD_GRAVITY_M_S2) -> Tuple[int, int, int]:
    """
    Return an accelerometer bias in LSB of the +-16 g format (2048 LSB/g).

    The sign is that of the bias (0.08 g -> +164); `merge_preserving_bit0`
    subtracts it from the factory value.
    """
    bias_g = _three(bias_m_s2, 'accelerometer bias') / gravity_m_s2
    return tuple(_int16(_round_half_away(b * ACCEL_OFFSET_LSB_PER_G), f'accel offset {axis}')
                 for axis, b in zip('xyz', bias_g))


def merge_preserving_bit0(factory: int, offset: int) -> int:
    """
    Return factory - (offset & ~1): the new accelerometer offset register value.

    ``factory`` is the signed value read from the register (OTP trim),
    ``offset`` the bias in LSB from `accel_offset_lsb`. Bit 0 of the factory
    value is reserved (temperature compensation) and stays as it was; the
    offset is used to within one LSB (an odd offset loses its bit 0).
    """
    merged = int(factory) - (int(offset) & ~1)
    return _int16(merged, f'factory {factory} - offset {offset}')


@dataclass(frozen=True)
class RestBias:
    """
    Mean bias of a record taken at rest, gravity removed.

    ``gravity_axis`` (0, 1, 2) is the accelerometer axis that saw gravity and
    ``gravity_sign`` its sign (+1: the axis points up, reading +1 g).
    """

    gyro_rad_s: Tuple[float, float, float]
    acceleration_m_s2: Tuple[float, float, float]
    gravity_axis: int
    gravity_sign: int
    samples: int


def rest_bias(gyro_rad_s, acceleration_m_s2, gravity_m_s2: float = STANDARD_GRAVITY_M_S2,
              tolerance_g: float = DEFAULT_GRAVITY_TOLERANCE_G) -> RestBias:
    """
    Return the gyro and accelerometer bias of samples taken at rest.

    ``gyro_rad_s`` and ``acceleration_m_s2`` have shape (samples, 3). The
    gravity axis is the one whose mean is within ``tolerance_g`` of 1 g in
    magnitude while the other two are within ``tolerance_g`` of 0; 1 g with
    that axis's sign is removed from its mean. Anything else (tilted, moving,
    wrong units) raises `CalibrationError` with the means.
    """
    gyro = np.asarray(gyro_rad_s, dtype=np.float64)
    accel = np.asarray(acceleration_m_s2, dtype=np.float64)
    for name, array in (('gyro', gyro), ('acceleration', accel)):
        if array.ndim != 2 or array.shape[1] != 3 or len(array) == 0:
            msg = f'{name} samples need shape (samples, 3), got {array.shape}'
            raise CalibrationError(msg)
        if not np.all(np.isfinite(array)):
            msg = f'{name} samples contain {int(np.sum(~np.isfinite(array)))} non-finite values'
            raise CalibrationError(msg)
    if len(gyro) != len(accel):
        msg = f'{len(gyro)} gyro samples but {len(accel)} acceleration samples'
        raise CalibrationError(msg)
    mean_accel_g = accel.mean(axis=0) / gravity_m_s2
    axis = int(np.argmax(np.abs(mean_accel_g)))
    others = np.delete(mean_accel_g, axis)
    if abs(abs(mean_accel_g[axis]) - 1.0) > tolerance_g or np.any(np.abs(others) > tolerance_g):
        means = ', '.join(f'{v:+.3f}' for v in mean_accel_g)
        msg = (f'no accelerometer axis sees 1 g alone (means {means} g, tolerance '
               f'{tolerance_g} g): the part must lie still, face up or down')
        raise CalibrationError(msg)
    sign = 1 if mean_accel_g[axis] > 0.0 else -1
    bias_accel = accel.mean(axis=0)
    bias_accel[axis] -= sign * gravity_m_s2
    return RestBias(gyro_rad_s=tuple(float(v) for v in gyro.mean(axis=0)),
                    acceleration_m_s2=tuple(float(v) for v in bias_accel),
                    gravity_axis=axis, gravity_sign=sign, samples=len(gyro))


def recalibrated_offsets(gyro_lsb: Sequence[int], accel_bias_lsb: Sequence[int],
                         bias: RestBias) -> Tuple[Tuple[int, ...], Tuple[int, ...]]:
    """
    Give the gyro offsets and accelerometer bias (LSB) that cancel a bias seen through offsets.

    ``bias`` was measured with ``gyro_lsb`` and ``accel_bias_lsb`` in place, so it
    is what they left: the new values are the old ones plus its correction. The
    accelerometer register holds the bias with bit 0 dropped (`merge_preserving_bit0`):
    the correction adds to what applies.
    """
    gyro = tuple(old + new for old, new in zip(gyro_lsb, gyro_offset_lsb(bias.gyro_rad_s)))
    accel = tuple((old & ~1) + new for old, new in zip(
        accel_bias_lsb, accel_offset_lsb(bias.acceleration_m_s2)))
    return gyro, accel


class OffsetRefresh:
    """
    Gyro offset registers that follow a bias model as the temperature moves.

    registers(T) = base + gyro_offset_lsb(bias(T) - bias(T_base)), where
    ``base`` are the registers that cancel the whole bias at ``T_base`` (the
    saved or just calibrated offsets): the model adds only the change since
    then, so a calibration and the model never count the same bias twice.
    Without a base (no saved offsets) the registers cancel the model's whole
    bias(T). ``model`` is a bias model of x, y and z whose ``correct`` at zero
    rate gives minus the bias.
    """

    def __init__(self, model, step_c: float):
        self.model = model
        self.step_c = step_c
        self.base_lsb = (0, 0, 0)
        self.base_temperature_c = None
        self.temperature_c = None       # of the last write; None: write at the next sample

    def bias_rad_s(self, temperature_c: float) -> np.ndarray:
        return -self.model.correct(np.zeros((1, 3)), [temperature_c]).rate_rad_s[0]

    def due(self, temperature_c: float) -> bool:
        """Tell whether the temperature moved ``step_c`` since the last write (or none yet)."""
        return self.temperature_c is None or \
            abs(temperature_c - self.temperature_c) >= self.step_c

    def registers(self, temperature_c: float) -> tuple:
        """Give the gyro registers for ``temperature_c``; `CalibrationError` if out of range."""
        change = self.bias_rad_s(temperature_c)
        if self.base_temperature_c is not None:
            change = change - self.bias_rad_s(self.base_temperature_c)
        return tuple(base + lsb for base, lsb in zip(self.base_lsb, gyro_offset_lsb(change)))
