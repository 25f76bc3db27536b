"""
The PX4-style cubic (core.fitting.baseline): PX4's fit and clamp, and written as the node runs it.

`fit_cubic` must be np.polyfit on T - TREF, axis by axis, as PX4's
process_sensor_caldata.py fits it; the written cubic (`ClampedCubic.effect_model`)
must give the firmware's clamped formula to the bit, through the node's batch
and one-row paths alike.
"""

from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.fitting.baseline import cubic_scale_c, fit_cubic
from mlx_tempcomp.core.node_models.interface import ModelInputs
import numpy as np
import pytest


def record(seed: int = 0) -> tuple:
    """Give a cooling and a heating ramp, a bias curve no cubic follows exactly, and noise."""
    rng = np.random.default_rng(seed)
    temperature_c = np.concatenate([np.linspace(52.0, -17.0, 3000),
                                    np.linspace(-17.0, 74.0, 4000)]) + rng.normal(0, 0.02, 7000)
    rate_rad_s = np.column_stack([
        1e-3 * np.sin(temperature_c / 15.0) + rng.normal(0.0, 3e-4, 7000),
        2e-6 * temperature_c ** 2 - 1e-3 + rng.normal(0.0, 3e-4, 7000),
        np.exp(temperature_c / 40.0) * 1e-3 + rng.normal(0.0, 3e-4, 7000)])
    return temperature_c, rate_rad_s


def test_the_fit_is_px4s_polyfit_on_the_temperature_less_its_mid_range():
    temperature_c, rate_rad_s = record()
    (cubic,) = fit_cubic(temperature_c, rate_rad_s)
    low, high = float(temperature_c.min()), float(temperature_c.max())
    assert (cubic.low_c, cubic.high_c) == (low, high)
    assert cubic.reference_c == 0.5 * (low + high)
    for axis in range(3):
        expected = np.polyfit(temperature_c - 0.5 * (low + high), rate_rad_s[:, axis], 3)
        assert cubic.coefficients[axis] == tuple(expected[::-1])


def test_the_cubic_clamps_at_its_fitted_range_as_the_firmware_does():
    temperature_c, rate_rad_s = record()
    (cubic,) = fit_cubic(temperature_c[:5000], rate_rad_s[:5000])
    beyond = np.array([cubic.low_c - 30.0, cubic.high_c + 12.5])
    edges = np.array([cubic.low_c, cubic.high_c])
    assert np.array_equal(cubic.offset_rad_s(beyond), cubic.offset_rad_s(edges))
    inside = np.array([10.0, 20.0])
    manual = np.column_stack([np.polyval(c[::-1], inside - cubic.reference_c)
                              for c in cubic.coefficients])
    assert np.array_equal(cubic.offset_rad_s(inside), manual)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_the_written_cubic_is_the_firmware_formula_to_the_bit(seed):
    """Fitted on the first part, run over all of it (much of the rest beyond the range)."""
    temperature_c, rate_rad_s = record(seed)
    (cubic,) = fit_cubic(temperature_c[:3500], rate_rad_s[:3500])
    model = cubic.effect_model()
    scale = model.temperature_scale_c
    assert scale == cubic_scale_c(cubic.low_c, cubic.high_c)
    assert np.log2(scale) == int(np.log2(scale)) and scale >= 0.5 * (cubic.high_c - cubic.low_c)
    expected = cubic.corrected(rate_rad_s, temperature_c)
    block = model.correct(rate_rad_s, temperature_c, ModelInputs()).rate_rad_s
    assert np.array_equal(block, expected)
    stream = model.stream()
    rows = [stream.correct_one(list(rate), [t], ModelInputs())[0]
            for rate, t in zip(rate_rad_s[::7], temperature_c[::7])]
    assert np.array_equal(np.array(rows), expected[::7])


def test_records_share_a_cubic_and_each_has_its_offset():
    temperature_c, rate_rad_s = record()
    record_index = np.repeat([0, 1], [3000, 4000])
    shifted = rate_rad_s + np.where(record_index == 1, 2e-3, 0.0)[:, None]
    first, second = fit_cubic(temperature_c, shifted, record_index, 2)
    assert first.coefficients[0][1:] == second.coefficients[0][1:]
    offsets = [b[0] - a[0] for a, b in zip(first.coefficients, second.coefficients)]
    assert offsets == pytest.approx([2e-3] * 3, abs=1e-4)


def test_a_temperature_that_does_not_move_is_refused():
    with pytest.raises(CalibrationError, match='needs the temperature to move'):
        fit_cubic(np.full(10, 25.0), np.zeros(10))
    with pytest.raises(CalibrationError, match='finite temperatures'):
        fit_cubic(np.array([1.0, np.nan, 3.0]), np.zeros(3))
