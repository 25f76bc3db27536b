"""
The error-by-temperature path: binning held-out residuals, the node's table, the fitted range.

`validation.error_by_temperature` bins residuals by temperature;
`ModelErrorTable` is what the node interpolates for its covariance, built
from the held-out errors less their white-noise share (`bias_rms_rad_s`,
`larger_table`) and judged against the error (`normalised_error`, live:
`StillWindows`);
`validation.outside_range` / `held_out_outside_range` measure the rows a
model runs clamped.
"""

import math

from mlx_tempcomp.core.errors import CalibrationError, ConfigError
from mlx_tempcomp.core.fitting.validation import (block_bounds, error_by_temperature,
                                                  held_out_outside_range, outside_range, split,
                                                  temperature_bin_edges)
from mlx_tempcomp.core.node_models.model_error import (bias_rms_rad_s, larger_table,
                                                       ModelErrorTable, normalised_error,
                                                       sample_noise_rad_s, StillWindows)
import numpy as np
import pytest


def test_error_by_temperature_gives_the_weighted_rms_per_bin():
    temperature = np.array([0.0, 1.0, 4.9, 5.0, 7.0, 10.0, 3.0, -1.0])
    residual = np.array([[1.0, 2.0], [3.0, 0.0], [-1.0, 1.0], [2.0, 2.0], [4.0, -2.0],
                         [6.0, 1.0], [np.nan, np.nan], [9.0, 9.0]])
    weights = np.array([1.0, 3.0, 2.0, 1.0, 1.0, 2.0, 5.0, 1.0])
    errors = error_by_temperature(temperature, residual, weights,
                                  temperature_bin_edges(0.0, 10.0, 2))
    # Bin [0, 5): rows 0, 1, 2 (row 6 is NaN, row 7 below the edges); [5, 10]: rows 3, 4, 5.
    assert errors.edges_c == (0.0, 5.0, 10.0)
    assert errors.count == (3, 3)
    assert errors.weight == (6.0, 4.0)
    assert errors.temperature_c == pytest.approx(((0 + 3 + 9.8) / 6, (5 + 7 + 20) / 4))
    assert errors.rms_rad_s[0] == pytest.approx((math.sqrt((1 + 27 + 2) / 6),
                                                 math.sqrt((4 + 0 + 2) / 6)))
    assert errors.rms_rad_s[1] == pytest.approx((math.sqrt((4 + 16 + 72) / 4),
                                                 math.sqrt((4 + 4 + 2) / 4)))
    assert errors.filled() == (0, 1)


def test_error_by_temperature_leaves_empty_bins_unfilled():
    errors = error_by_temperature([1.0, 9.0], [[1.0], [2.0]], [1.0, 1.0],
                                  temperature_bin_edges(0.0, 9.0, 3))
    assert errors.count == (1, 0, 1) and errors.filled() == (0, 2)
    assert math.isnan(errors.temperature_c[1]) and math.isnan(errors.rms_rad_s[1][0])
    with pytest.raises(CalibrationError, match='1 or more bins'):
        temperature_bin_edges(0.0, 1.0, 0)


def test_model_error_table_is_linear_inside_and_held_at_the_edges():
    table = ModelErrorTable((10.0, 20.0, 40.0), ((1e-3, 3e-3, 2e-3), (0.0, 1e-3, 1e-3)))
    error = table.error_at([0.0, 10.0, 15.0, 30.0, 40.0, 100.0, math.nan])
    np.testing.assert_allclose(error[:, 0], [1e-3, 1e-3, 2e-3, 2.5e-3, 2e-3, 2e-3, 3e-3])
    np.testing.assert_allclose(error[:, 1], [0.0, 0.0, 5e-4, 1e-3, 1e-3, 1e-3, 1e-3])
    # Per-axis temperatures (one chip per axis) each look up their own.
    np.testing.assert_allclose(table.error_at([[15.0, 30.0]]), [[2e-3, 1e-3]])
    np.testing.assert_allclose(table.variance(0.01, [15.0]), [[1e-4 + 4e-6, 1e-4 + 2.5e-7]])


@pytest.mark.parametrize('temperature, errors, message', [
    ((), ((),), 'needs finite temperatures'),
    ((10.0, 10.0), ((1.0, 1.0),), 'strictly increasing'),
    ((20.0, 10.0), ((1.0, 1.0),), 'strictly increasing'),
    ((10.0, math.inf), ((1.0, 1.0),), 'needs finite temperatures'),
    ((10.0, 20.0), ((1.0,),), 'needs 2 values'),
    ((10.0, 20.0), ((1.0, -1.0),), 'finite and >= 0'),
    ((10.0, 20.0), (), 'at least one axis'),
])
def test_model_error_table_refuses_what_is_not_a_table(temperature, errors, message):
    with pytest.raises(ConfigError, match=message):
        ModelErrorTable(temperature, errors)


def test_outside_range_counts_rows_beyond_either_edge_per_column():
    part = outside_range([[0.0, 5.0], [11.0, 5.0], [12.5, 10.0], [-3.0, 4.0]], 0.0, 10.0)
    assert part.rows == 4 and part.fraction == (0.75, 0.0)
    assert part.furthest_c == (3.0, 0.0)


def test_held_out_blocks_are_judged_against_the_range_of_their_training_blocks():
    # Four blocks of two rows warming, then one back inside: forward from block 1.
    temperature = np.array([20.0, 21.0, 22.0, 23.0, 20.5, 21.5, 19.0, 24.0])
    bounds = block_bounds(temperature.size, 4)
    blocks = held_out_outside_range(temperature, bounds, split(4, min_past=0.25))
    assert blocks[0] is None
    assert (blocks[1].low_c, blocks[1].high_c) == (20.0, 21.0)
    assert blocks[1].fraction == (1.0,) and blocks[1].furthest_c == (2.0,)
    assert blocks[2].fraction == (0.0,)
    assert (blocks[3].low_c, blocks[3].high_c) == (20.0, 23.0)
    assert blocks[3].fraction == (1.0,) and blocks[3].furthest_c == (1.0,)
    # Two columns (axes with their own effective T): the range spans both, as a model's does.
    both = held_out_outside_range(np.column_stack([temperature, temperature + 2.0]), bounds,
                                  split(4, min_past=0.25))
    assert (both[1].low_c, both[1].high_c) == (20.0, 23.0)
    assert both[1].fraction == (0.0, 1.0)


def test_the_sample_noise_is_the_white_noise_the_slow_bias_leaves_out():
    generator = np.random.default_rng(3)
    time_s = np.arange(20000.0)
    bias = np.column_stack([1e-3 * np.sin(time_s / 500.0), np.full(time_s.size, 0.2)])
    noise = generator.normal(0.0, 1.0, bias.shape) * [2e-4, 5e-4]
    found = sample_noise_rad_s([bias[:12000] + noise[:12000], bias[12000:] + noise[12000:]])
    np.testing.assert_allclose(found, [2e-4, 5e-4], rtol=0.03)
    with pytest.raises(CalibrationError, match='two consecutive samples'):
        sample_noise_rad_s([np.zeros((1, 2))])


def test_the_bias_part_takes_the_noise_share_of_each_averaged_value_out():
    # Bin [0, 5): values averaging 2 and 4 rows; [5, 10]: one value of 1 row (all noise).
    errors = error_by_temperature([1.0, 2.0, 7.0], [[3e-3], [1e-3], [1e-4]], [2.0, 4.0, 1.0],
                                  temperature_bin_edges(0.0, 10.0, 3))
    noise = 2e-3
    bias = bias_rms_rad_s(errors, [noise])
    mean_square = (2.0 * 9e-6 + 4.0 * 1e-6) / 6.0
    assert bias[0, 0] == pytest.approx(math.sqrt(mean_square - noise ** 2 * 2 / 6.0))
    assert math.isnan(bias[1, 0]) and bias[2, 0] == 0.0


def test_the_node_s_table_is_the_larger_bias_part_of_two_schemes():
    edges = temperature_bin_edges(0.0, 10.0, 3)
    deciding = error_by_temperature([1.0, 5.0], [[2e-3, 1e-3], [1e-3, 1e-3]], [1.0, 1.0], edges)
    forward = error_by_temperature([2.0, 9.0], [[1e-3, 3e-3], [4e-3, 5e-4]], [1.0, 1.0], edges)
    table = larger_table((deciding, forward), [0.0, 0.0])
    # Bins 0 (both), 1 (deciding only), 2 (forward only), at the first table's mean T.
    assert table.temperature_c == (1.0, 5.0, 9.0)
    assert table.error_rad_s == ((2e-3, 1e-3, 4e-3), (3e-3, 1e-3, 5e-4))
    empty = error_by_temperature([1.0], [[math.nan, math.nan]], [1.0], edges)
    with pytest.raises(CalibrationError, match='no held-out residual'):
        larger_table((empty, empty), [0.0, 0.0])


def test_the_normalised_error_is_one_when_the_covariance_is_true():
    generator = np.random.default_rng(5)
    time_s = np.arange(36000.0) * 0.1
    noise, bias = np.array([1e-3, 2e-4]), np.array([5e-4, 1e-3])
    # A bias constant over each minute, normal with the std published, and white noise.
    minutes = generator.normal(0.0, 1.0, (60, 2)) * bias
    error = minutes[(time_s // 60.0).astype(int)] + generator.normal(0.0, 1.0, (36000, 2)) * noise
    judged = normalised_error(time_s, error, noise ** 2 + bias ** 2, noise)
    np.testing.assert_allclose(judged.per_sample, [1.0, 1.0], atol=0.1)
    np.testing.assert_allclose(judged.window_means, [1.0, 1.0], atol=0.25)
    assert (judged.samples, judged.windows, judged.window_s) == (36000, 60, 60.0)
    # Told only the white noise, the window means are far too confident, samples less so.
    naive = normalised_error(time_s, error, noise ** 2, noise)
    assert naive.window_means[1] > 10.0 and naive.per_sample[1] > 4.0


def test_still_windows_judge_the_mean_of_each_still_minute():
    windows = StillWindows(window_s=10.0)
    noise = (0.1, 0.0)
    for k in range(25):     # 2.5 windows of 10 samples, the last one left open
        windows.add(float(k), (0.02 + 0.1 * (-1) ** k, 0.03), (0.01, 0.01), noise, True)
    assert windows.windows == 2
    # Mean 0.02 over sqrt(0.01^2 + 0.1^2 / 10); the second axis 0.03 over 0.01.
    np.testing.assert_allclose(windows.rms(), [0.02 / math.sqrt(1e-4 + 1e-3), 3.0])
    windows.add(25.0, (5.0, 5.0), (0.01, 0.01), noise, False)   # moving: the open one dropped
    for k in range(26, 37):
        windows.add(float(k), (0.0, 0.0), (0.01, 0.01), noise, True)
    assert windows.windows == 3
    assert StillWindows().rms() == []
