"""The relative correction of "Temperature Correction in MPU6000" and the ADIS16130 BTC/PBC fit."""

import math

from mlx_tempcomp.core.effects import LinearBtc
from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.fitting.bias_polynomial import (fit_linear_btc, fit_polynomial,
                                                       relative_polynomial, table_step_c)
from mlx_tempcomp.toolkit.tables import format_btc_table
import numpy as np
import pytest

NOISE_RAD_S = 1e-3
# Table 6 of AN-1042: a bias slope of 0.04 deg/s/C.
SLOPE_RAD_S_PER_C = math.radians(0.04)


def cycle_c(samples=3000):
    """Return one slow -17 -> 73 -> 36 C cycle, like the measured sweep."""
    phase = np.linspace(0.0, 1.0, samples)
    return np.interp(phase, (0.0, 0.45, 0.85, 1.0), (52.0, -17.0, 73.0, 36.0))


def cubic_rate_rad_s(temperature_c, seed=0):
    """Return a cubic bias in raw temperature (rad/s) plus white noise, 2 axes."""
    rng = np.random.default_rng(seed)
    t = np.asarray(temperature_c)
    bias = np.column_stack([0.02 + 4e-4 * t - 1e-5 * t ** 2 + 1e-7 * t ** 3,
                            -0.01 - 2e-4 * t + 3e-6 * t ** 2])
    return bias + rng.normal(0.0, NOISE_RAD_S, bias.shape)


def test_relative_correction_is_the_seed_formula():
    temperature_c = cycle_c()
    rate_rad_s = cubic_rate_rad_s(temperature_c)
    true_c = 31.0
    model = relative_polynomial(fit_polynomial(temperature_c, rate_rad_s, 3), true_c)
    corrected = model.correct(rate_rad_s, temperature_c).rate_rad_s
    for axis in range(2):
        # The note as written: p = polyfit on the measured temperature, then
        # gyro - (polyval(p, mt) - polyval(p, tt)); float64 here.
        p = np.polyfit(temperature_c, rate_rad_s[:, axis], 3)
        expected = rate_rad_s[:, axis] - (np.polyval(p, temperature_c) - np.polyval(p, true_c))
        np.testing.assert_allclose(corrected[:, axis], expected, rtol=0.0, atol=1e-12)
    # No bias is introduced at T_true: the rate passes unchanged.
    at_true = model.correct([[0.3, -0.2]], [true_c]).rate_rad_s
    np.testing.assert_allclose(at_true, [[0.3, -0.2]], rtol=0.0, atol=1e-15)


def test_relative_keeps_the_scaling_and_only_moves_the_constant():
    temperature_c = cycle_c()
    fitted = fit_polynomial(temperature_c, cubic_rate_rad_s(temperature_c), (3, 2))
    shifted = relative_polynomial(fitted, fitted.temperature_min_c)
    assert shifted.reference_temperature_c == fitted.reference_temperature_c
    assert shifted.temperature_scale_c == fitted.temperature_scale_c
    for before, after in zip((t.bias for t in fitted.terms), (t.bias for t in shifted.terms)):
        assert after[1:] == before[1:]
        assert after[0] != before[0]


@pytest.mark.parametrize('true_c', [-17.5, 73.5, math.nan])
def test_relative_refuses_a_true_temperature_outside_the_fit(true_c):
    temperature_c = cycle_c()
    fitted = fit_polynomial(temperature_c, cubic_rate_rad_s(temperature_c), 3)
    span = f'{fitted.temperature_min_c:.2f} to {fitted.temperature_max_c:.2f} C'
    with pytest.raises(CalibrationError, match=f'outside the fitted range {span}, where'):
        relative_polynomial(fitted, true_c)


def btc_data(samples=2000, bias_at_25_rad_s=0.01, seed=1):
    """Return temperature (10..40 C) and a 0.04 deg/s/C bias on z, -0.02 on x, with noise."""
    rng = np.random.default_rng(seed)
    temperature_c = 25.0 + 15.0 * np.sin(np.linspace(0.0, 3.0 * np.pi, samples))
    bias = np.column_stack([-0.5 * SLOPE_RAD_S_PER_C * (temperature_c - 25.0),
                            bias_at_25_rad_s + SLOPE_RAD_S_PER_C * (temperature_c - 25.0)])
    return temperature_c, bias + rng.normal(0.0, NOISE_RAD_S, bias.shape)


def test_linear_btc_recovers_the_slope_with_the_note_sign():
    temperature_c, rate_rad_s = btc_data()
    model = fit_linear_btc(temperature_c, rate_rad_s, t3_c=25.0)
    line = LinearBtc.of(model)
    # Slope error: noise / (sqrt(n) x std(T)) = 1e-3 / (45 x 10.6) = 2e-6 rad/s/C.
    np.testing.assert_allclose(line.btc_rad_s_per_c,
                               [0.5 * SLOPE_RAD_S_PER_C, -SLOPE_RAD_S_PER_C], atol=1e-5)
    assert line.btc_rad_s_per_c[1] < 0.0, 'BTC is minus the bias slope (Table 6)'
    # PBC is minus the bias at T3.
    np.testing.assert_allclose(line.pbc_rad_s, [0.0, -0.01], atol=1e-4)
    assert line.t3_c == 25.0
    corrected = model.correct(rate_rad_s, temperature_c).rate_rad_s
    assert np.max(np.abs(np.mean(corrected, axis=0))) < 1e-4
    assert np.std(corrected, axis=0) == pytest.approx([NOISE_RAD_S] * 2, rel=0.1)


def test_table_6_of_the_note():
    model = LinearBtc(pbc_rad_s=(0.0,), btc_rad_s_per_c=(-SLOPE_RAD_S_PER_C,), t3_c=25.0).model()
    lines = format_btc_table(model, ('z',), 0.02).splitlines()
    assert lines[0].split() == ['TEMP', '-', 'T3', '(C)', 'z', '(rad/s)', 'z', '(deg/s)']
    rows = [line.split() for line in lines[1:]]
    assert rows[0] == ['+0.12', f'{math.radians(-0.0048):+.4g}', '-0.0048']
    assert rows[5] == ['+0.02', f'{math.radians(-0.0008):+.4g}', '-0.0008']
    assert rows[6] == ['0', '0', '0']
    assert rows[-1] == ['-0.12', f'{math.radians(0.0048):+.4g}', '+0.0048']
    assert len(rows) == 13
    # The table is what the model applies: RBC - RATE - PBC at T3 + 0.12 C.
    step = model.correct([[0.0]], [25.12]).rate_rad_s[0, 0]
    assert math.degrees(step) == pytest.approx(-0.0048, abs=1e-12)


def test_linear_btc_t3_defaults_to_the_mean_temperature():
    temperature_c, rate_rad_s = btc_data()
    line = LinearBtc.of(fit_linear_btc(temperature_c, rate_rad_s))
    assert line.t3_c == pytest.approx(np.mean(temperature_c), abs=1e-12)
    # PBC at another T3 moves along the line: -(bias at T3).
    expected = -(0.01 + SLOPE_RAD_S_PER_C * (line.t3_c - 25.0))
    assert line.pbc_rad_s[1] == pytest.approx(expected, abs=1e-4)


def test_linear_btc_needs_a_temperature_span():
    temperature_c = 25.0 + np.linspace(0.0, 0.5, 100)
    with pytest.raises(CalibrationError, match='needs a temperature span of at least 1.0 C'):
        fit_linear_btc(temperature_c, np.zeros(100))
    with pytest.raises(CalibrationError, match='T3 must be finite'):
        fit_linear_btc(*btc_data(), t3_c=math.inf)


@pytest.mark.parametrize('extent_c, step_c', [(0.12, 0.02), (46.5, 10.0), (7.0, 2.0),
                                              (30.0, 5.0), (6.0, 1.0)])
def test_table_step_is_a_1_2_5_step_reaching_the_extent(extent_c, step_c):
    assert table_step_c(extent_c, 6) == pytest.approx(step_c, rel=1e-12)
