"""Allan deviation noise figures of synthetic gyro records of known noise."""

from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.series.noise import allan_deviation
import numpy as np
import pytest

RATE_HZ = 100.0
ARW_RAD_S_RT_HZ = 0.01  # white rate noise density: per-sample sigma 0.1 rad/s at 100 Hz


def white_rate_rad_s(rng, samples, density_rad_s_rt_hz=ARW_RAD_S_RT_HZ):
    return rng.normal(0.0, density_rad_s_rt_hz * np.sqrt(RATE_HZ), samples)


def time_s(samples):
    return np.arange(samples) / RATE_HZ


def gauss_markov_rad_s(rng, samples, sigma_rad_s, correlation_time_s):
    """Give a stationary first-order Gauss-Markov bias of the given sigma."""
    decay = np.exp(-1.0 / (RATE_HZ * correlation_time_s))
    drive = rng.normal(0.0, sigma_rad_s * np.sqrt(1.0 - decay ** 2), samples)
    bias = np.empty(samples)
    bias[0] = rng.normal(0.0, sigma_rad_s)
    for i in range(1, samples):
        bias[i] = decay * bias[i - 1] + drive[i]
    return bias


def test_white_noise_gives_its_density_and_per_sample_sigma():
    samples = 100_000
    rate_rad_s = white_rate_rad_s(np.random.default_rng(1), samples)
    figures = allan_deviation(time_s(samples), rate_rad_s[:, None], ('z',))
    assert [f.axis for f in figures] == ['z']
    assert figures[0].angle_random_walk_rad_s_rt_hz == pytest.approx(ARW_RAD_S_RT_HZ, rel=0.1)
    assert figures[0].rate_noise_rad_s == pytest.approx(
        ARW_RAD_S_RT_HZ * np.sqrt(RATE_HZ), rel=0.1)
    assert figures[0].taus_s[0] == pytest.approx(1.0 / RATE_HZ)
    assert np.allclose(np.diff(np.log2(figures[0].taus_s)), 1.0)


def test_bias_random_walk_raises_the_long_tau_deviation():
    samples = 100_000
    rng = np.random.default_rng(2)
    white = white_rate_rad_s(rng, samples)
    walk = np.cumsum(rng.normal(0.0, 1e-3, samples))
    figures = allan_deviation(time_s(samples), np.column_stack([white, white + walk]),
                              ('x', 'y'))
    assert figures[1].adev_rad_s[-1] > 10.0 * figures[0].adev_rad_s[-1]
    assert figures[1].adev_rad_s[0] == pytest.approx(figures[0].adev_rad_s[0], rel=0.1)


def test_gauss_markov_bias_gives_bias_instability_of_its_sigma():
    # The Allan deviation of first-order Gauss-Markov noise of sigma s and
    # correlation time T peaks at about 0.62 s near tau = 1.9 T and falls only
    # to about 0.53 s at 5 T; with white noise large enough to keep its short-tau
    # dip above that, the floor searched up to a tenth of a 100 T record lies
    # between 0.5 s and 0.62 s, so min / 0.664 is 0.75-0.95 s, within 1.5x of s.
    samples, sigma_rad_s, correlation_time_s = 10_000, 0.01, 1.0
    rng = np.random.default_rng(0)
    rate_rad_s = gauss_markov_rad_s(rng, samples, sigma_rad_s, correlation_time_s) + \
        white_rate_rad_s(rng, samples, 0.005)
    figures, = allan_deviation(time_s(samples), rate_rad_s[:, None], ('x',))
    assert sigma_rad_s / 1.5 < figures.bias_instability_rad_s < 1.5 * sigma_rad_s
    assert correlation_time_s <= figures.bias_instability_tau_s <= samples / RATE_HZ / 10


def test_short_record_is_refused():
    with pytest.raises(CalibrationError, match='at least 100 samples, got 99'):
        allan_deviation(time_s(99), np.zeros((99, 1)), ('z',))


def test_irregular_sampling_is_refused_naming_the_spread():
    time = time_s(1000)
    time[500:] += 0.005  # one interval of 1.5 times the median
    with pytest.raises(CalibrationError, match=r'irregular sampling: .*spread of 50\.0 %'):
        allan_deviation(time, np.zeros((1000, 1)), ('z',))


def test_mismatched_shapes_are_refused():
    with pytest.raises(CalibrationError, match='shape'):
        allan_deviation(time_s(200), np.zeros((200, 2)), ('z',))
