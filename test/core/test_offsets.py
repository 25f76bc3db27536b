"""Offset register encoding of "Using Hardware Offset Registers for Calibration", by hand."""

import math

from mlx_tempcomp.core.effects import polynomial_model
from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.procedures.mpu6000_offsets import (accel_offset_lsb, from_twos_complement,
                                                          GYRO_OFFSET_DPS_PER_LSB, gyro_offset_lsb,
                                                          merge_preserving_bit0, OffsetRefresh,
                                                          recalibrated_offsets, rest_bias,
                                                          RestBias, STANDARD_GRAVITY_M_S2,
                                                          twos_complement)
import numpy as np
import pytest

G = STANDARD_GRAVITY_M_S2


def test_note_worked_example_0_08_g_is_164_lsb():
    # The note: 0.08 g x 2048 = 163.84, rounded to 164.
    assert accel_offset_lsb((0.08 * G, -0.08 * G, 0.0)) == (164, -164, 0)
    # The rounding boundary sits at 163.5 and 164.5 LSB.
    assert accel_offset_lsb(np.array((163.49, 163.51, 164.49)) / 2048.0 * G) == (163, 164, 164)


def test_merge_subtracts_from_the_factory_value_and_keeps_bit_0():
    assert merge_preserving_bit0(1385, 164) == 1221       # odd factory stays odd
    assert merge_preserving_bit0(1385, 165) == 1221       # an odd offset loses its bit 0
    assert merge_preserving_bit0(2210, -103) == 2314      # C: -103 & ~1 == -104
    assert merge_preserving_bit0(-1743, 62) == -1805
    for factory in (-3001, -2, 0, 1, 1384, 1385, 30001):
        for offset in (-2048, -165, -164, -1, 0, 1, 163, 164, 2047):
            merged = merge_preserving_bit0(factory, offset)
            assert merged & 1 == factory & 1
            # An odd offset is used one LSB short, an even one exactly.
            assert merged - (factory - offset) == (1 if offset % 2 else 0)


def test_merge_out_of_int16_is_an_error():
    with pytest.raises(CalibrationError, match='does not fit a 16-bit register'):
        merge_preserving_bit0(-32000, 2000)


def test_negative_values_are_twos_complement():
    assert twos_complement(-1) == 0xFFFF
    assert twos_complement(-164) == 0xFF5C
    assert twos_complement(-32768) == 0x8000
    assert twos_complement(32767) == 0x7FFF
    assert twos_complement(26) == 0x001A
    words = [twos_complement(v) for v in range(-32768, 32768)]
    assert sorted(words) == list(range(65536))
    assert all(from_twos_complement(w) == v for v, w in zip(range(-32768, 32768), words))
    for bad in (32768, -32769):
        with pytest.raises(CalibrationError, match='does not fit'):
            twos_complement(bad)
    with pytest.raises(CalibrationError, match='not 16 bits'):
        from_twos_complement(0x10000)


def test_gyro_offset_cancels_the_bias_at_the_notes_scale():
    # 1 deg/s / 0.031 = 32.26 -> 32, negated so that the register cancels it.
    assert gyro_offset_lsb(np.radians((1.0, -1.0, 0.0))) == (-32, 32, 0)
    bias_dps = np.array((0.8, -1.3, 0.45))
    registers = np.array(gyro_offset_lsb(np.radians(bias_dps)))
    assert tuple(registers) == (-26, 42, -15)
    residual = bias_dps + registers * GYRO_OFFSET_DPS_PER_LSB
    assert np.all(np.abs(residual) <= GYRO_OFFSET_DPS_PER_LSB / 2)
    # A different scale is an argument (the +-1000 dps step 1000/32768).
    assert gyro_offset_lsb(np.radians((1.0, 0.0, 0.0)), 1000.0 / 32768.0)[0] == -33


def test_gyro_offset_out_of_range_names_the_axis():
    with pytest.raises(CalibrationError, match='gyro offset y = -35484'):
        gyro_offset_lsb(np.radians((0.0, 1100.0, 0.0)))
    with pytest.raises(CalibrationError, match='3 finite values'):
        gyro_offset_lsb((0.0, float('nan'), 0.0))
    with pytest.raises(CalibrationError, match='3 finite values'):
        accel_offset_lsb((0.0, 0.0))


def rest_record(mean_accel_g, mean_gyro_rad_s=(0.01, -0.02, 0.005), samples=50, seed=1):
    rng = np.random.default_rng(seed)
    accel = rng.normal(0.0, 0.01 * G, (samples, 3))
    accel += np.asarray(mean_accel_g) * G - accel.mean(axis=0)
    gyro = rng.normal(0.0, 0.001, (samples, 3))
    gyro += np.asarray(mean_gyro_rad_s) - gyro.mean(axis=0)
    return gyro, accel


@pytest.mark.parametrize('mean_g, axis, sign, bias_g', [
    ((0.03, -0.05, 1.08), 2, 1, (0.03, -0.05, 0.08)),        # face up
    ((0.03, -0.05, -0.92), 2, -1, (0.03, -0.05, 0.08)),      # face down: +0.08 g all the same
    ((0.02, -0.97, 0.04), 1, -1, (0.02, 0.03, 0.04)),         # on its side
])
def test_rest_bias_removes_gravity_from_the_axis_that_sees_it(mean_g, axis, sign, bias_g):
    gyro, accel = rest_record(mean_g)
    bias = rest_bias(gyro, accel)
    assert (bias.gravity_axis, bias.gravity_sign, bias.samples) == (axis, sign, 50)
    np.testing.assert_allclose(bias.acceleration_m_s2, np.array(bias_g) * G, atol=1e-12)
    np.testing.assert_allclose(bias.gyro_rad_s, (0.01, -0.02, 0.005), atol=1e-15)


@pytest.mark.parametrize('mean_g', [
    (0.7, 0.0, 0.7),            # tilted 45 degrees
    (0.0, 0.0, 0.1),            # accelerometer in g, not m/s^2
    (0.3, 0.0, 1.0),            # gravity plus a large bias on another axis
])
def test_rest_bias_refuses_records_without_one_gravity_axis(mean_g):
    gyro, accel = rest_record(mean_g)
    with pytest.raises(CalibrationError, match='no accelerometer axis sees 1 g alone'):
        rest_bias(gyro, accel)


def test_rest_bias_checks_shapes_and_values():
    gyro, accel = rest_record((0.0, 0.0, 1.0))
    with pytest.raises(CalibrationError, match='50 gyro samples but 49'):
        rest_bias(gyro, accel[1:])
    with pytest.raises(CalibrationError, match=r'shape \(samples, 3\)'):
        rest_bias(gyro[:, :2], accel)
    accel[3, 1] = np.inf
    with pytest.raises(CalibrationError, match='1 non-finite'):
        rest_bias(gyro, accel)


def test_recalibration_adds_its_correction_to_the_offsets_in_place():
    # The window saw the offsets in place: its bias is a residual on top of them.
    bias = RestBias(gyro_rad_s=(math.radians(2 * GYRO_OFFSET_DPS_PER_LSB), 0.0, 0.0),
                    acceleration_m_s2=(0.08 * G, 0.0, 0.0), gravity_axis=2, gravity_sign=1,
                    samples=10)
    gyro, accel = recalibrated_offsets((10, -20, 0), (165, 0, -3), bias)
    assert gyro == (8, -20, 0)
    # The register holds 165 as 164 and -3 as -4 (bit 0 dropped): the correction adds to that.
    assert accel == (164 + 164, 0, -4)


def test_offset_refresh_adds_the_model_change_since_its_base():
    lsb_rad_s = math.radians(GYRO_OFFSET_DPS_PER_LSB)
    model = polynomial_model(((0.3, lsb_rad_s), (0.0, -2 * lsb_rad_s), (0.1, 0.0)))
    refresh = OffsetRefresh(model, step_c=0.5)
    assert refresh.due(25.0)                          # nothing written yet
    # Without a base the registers cancel the whole bias.
    assert refresh.registers(25.0) == gyro_offset_lsb(refresh.bias_rad_s(25.0))
    refresh.base_lsb, refresh.base_temperature_c = (5, 0, -7), 25.0
    assert refresh.registers(35.0) == (5 - 10, 0 + 20, -7)
    refresh.temperature_c = 35.0
    assert not refresh.due(35.4) and refresh.due(35.5) and refresh.due(34.5)
