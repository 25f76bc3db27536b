import math

from mlx_tempcomp.core.errors import CalibrationError, ConfigError
from mlx_tempcomp.core.series.pairing import StampPairer, zero_order_hold
from mlx_tempcomp.core.standstill.recalibration import (check_window, moving_axis,
                                                        rate_spread_rad_s, RecalibrationLimits)
import numpy as np
import pytest

LIMITS = RecalibrationLimits(rate_noise_rad_s=0.005, noise_multiple=3.0,
                             max_mean_rate_rad_s=math.radians(2.0),
                             max_temperature_change_c=0.5)


def window(mean=0.001, sigma=0.005, drift_c=0.1, samples=500, axes=1, seed=0):
    rng = np.random.default_rng(seed)
    rate = mean + rng.normal(0.0, sigma, (samples, axes))
    temperature = 30.0 + np.linspace(0.0, drift_c, samples)
    return rate, temperature


def test_window_at_rest_is_accepted():
    stats = check_window(*window(axes=3), LIMITS)
    assert stats.samples == 500
    np.testing.assert_allclose(stats.mean_rate_rad_s, 0.001, atol=0.001)
    assert stats.temperature_change_c == pytest.approx(0.1)


def test_motion_and_drift_are_refused_with_the_reason():
    with pytest.raises(CalibrationError, match='sensor moved: rate spread .* on axis 1'):
        rate, temperature = window(axes=2)
        rate[:, 1] += np.sin(np.linspace(0.0, 20.0, 500)) * 0.1
        check_window(rate, temperature, LIMITS)
    with pytest.raises(CalibrationError, match='sensor moved: mean rate'):
        check_window(*window(mean=math.radians(5.0)), LIMITS)
    with pytest.raises(CalibrationError, match='temperature drifted 2 C'):
        check_window(*window(drift_c=2.0), LIMITS)
    with pytest.raises(CalibrationError, match='only 5 valid samples'):
        check_window(*window(samples=5), LIMITS)


def test_spread_and_the_axis_that_moved():
    rate = np.array([[0.0, 1.0], [0.0, 3.0]])
    np.testing.assert_allclose(rate_spread_rad_s(rate), [0.0, 1.0])
    np.testing.assert_allclose(rate_spread_rad_s(rate, ddof=1), [0.0, math.sqrt(2.0)])
    # One sample has no sample standard deviation: no spread, not NaN.
    np.testing.assert_array_equal(rate_spread_rad_s(rate[:1], ddof=1), [0.0, 0.0])
    assert moving_axis([0.5, 0.1, 0.7], rate_noise_rad_s=0.1, noise_multiple=3.0) == 2
    assert moving_axis([0.25, 0.1], rate_noise_rad_s=0.1, noise_multiple=3.0) is None


def test_non_finite_samples_are_skipped():
    rate, temperature = window()
    rate[:10] = np.nan
    assert check_window(rate, temperature, LIMITS).samples == 490


def test_limits_are_validated():
    with pytest.raises(ConfigError, match='rate_noise_rad_s must be positive'):
        RecalibrationLimits(rate_noise_rad_s=0.0)
    with pytest.raises(ConfigError, match='rate_noise_rad_s must be positive, got inf'):
        RecalibrationLimits(rate_noise_rad_s=math.inf)


def test_a_spread_only_check_in_its_own_words():
    """As the MPU-6000 offset calibration checks: sample spread, no mean or drift limit."""
    limits = RecalibrationLimits(rate_noise_rad_s=0.005, max_mean_rate_rad_s=math.inf,
                                 max_temperature_change_c=math.inf, min_samples=2,
                                 spread_ddof=1)
    rate, temperature = window(mean=math.radians(5.0), drift_c=2.0, axes=3)
    stats = check_window(rate, temperature, limits)
    np.testing.assert_array_equal(stats.spread_rad_s, rate.std(axis=0, ddof=1))
    rate[:, 2] += np.sin(np.linspace(0.0, 20.0, 500)) * 0.1
    words = '{axis_name} moved: {spread_rad_s:.3f} > {noise_multiple:g} x {rate_noise_rad_s}'
    spread = rate[:, 2].std(ddof=1)
    with pytest.raises(CalibrationError, match=f'^z moved: {spread:.3f} > 3 x 0.005$'):
        check_window(rate, temperature, limits, words)


def test_pairer_pairs_by_stamp_and_drops_what_cannot_complete():
    pairer = StampPairer(('imu', 'temperature'))
    assert pairer.add('temperature', 1, 't1') == []
    assert pairer.add('imu', 1, 'i1') == [(1, {'temperature': 't1', 'imu': 'i1'})]
    assert pairer.add('imu', 2, 'i2') == []          # its temperature is lost
    assert pairer.add('temperature', 3, 't3') == []
    assert pairer.add('imu', 3, 'i3') == [(3, {'temperature': 't3', 'imu': 'i3'})]
    assert (pairer.paired, pairer.dropped) == (2, 1)


def test_pairer_holds_a_bounded_number_of_stamps():
    pairer = StampPairer(('imu', 'temperature'), capacity=10)
    for stamp in range(100):
        pairer.add('imu', stamp, stamp)
    assert pairer.dropped == 90
    assert pairer.add('temperature', 99, 't') == [(99, {'imu': 99, 'temperature': 't'})]


def test_zero_order_hold_takes_the_latest_value_at_or_before_each_stamp():
    values, usable = zero_order_hold([5, 10, 14, 15, 30, 41], [10, 15, 20], [1.0, 2.0, 3.0],
                                     max_age_ns=20)
    # 5 is older than every value: the oldest; 41 is 21 from the last: not usable.
    np.testing.assert_array_equal(values, [1.0, 1.0, 1.0, 2.0, 3.0, np.nan])
    np.testing.assert_array_equal(usable, [True, True, True, True, True, False])
    values, usable = zero_order_hold([1, 2], [], [], max_age_ns=10)
    assert np.isnan(values).all() and not usable.any()
