import warnings

from mlx_tempcomp.core.effects import polynomial_model
from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.fitting.bias_polynomial import (CHUNK_ROWS, contiguous_blocks,
                                                       fit_polynomial, fold_rows, select_orders)
from mlx_tempcomp.core.fitting.validation import FORWARD, ROUND_ROBIN
from mlx_tempcomp.toolkit.tables import format_order_table
import numpy as np
import pytest

KELVIN_OFFSET_C = 273.15
# truth in u = (T - 22.5 C) / 62.5 C, so u spans [-1, 1] over -40..85 C; rad/s
TRUE_BIAS_RAD_S = {
    2: (2e-3, 4e-3, 3e-3),
    3: (2e-3, 4e-3, -1.5e-3, 2e-3),
    5: (2e-3, 4e-3, -1.5e-3, 2e-3, 1e-3, -2e-3),
}
ORDER6_BIAS_RAD_S = (2e-3, 4e-3, -1.5e-3, 2e-3, 1e-3, -2e-3, 1.5e-3)


def true_bias_rad_s(temperature_c, coefficients):
    return np.polynomial.polynomial.polyval((temperature_c - 22.5) / 62.5, coefficients)


def thermal_cycle_c(samples, cycles=2):
    """Return a slow triangle -40 -> 85 -> -40 C, repeated `cycles` times."""
    phase = np.linspace(0.0, cycles, samples, endpoint=False) % 1.0
    return -40.0 + 125.0 * (1.0 - np.abs(2.0 * phase - 1.0))


def simulated_rate_rad_s(temperature_c, coefficients, seed):
    """Return bias plus 1e-4 rad/s white noise plus mild AR(1) noise (3e-5 rad/s)."""
    rng = np.random.default_rng(seed)
    phi = 0.99
    drive = rng.normal(0.0, 3e-5 * np.sqrt(1.0 - phi ** 2), temperature_c.size)
    correlated = np.zeros(temperature_c.size)
    for i in range(1, temperature_c.size):
        correlated[i] = phi * correlated[i - 1] + drive[i]
    white = rng.normal(0.0, 1e-4, temperature_c.size)
    return true_bias_rad_s(temperature_c, coefficients) + white + correlated


@pytest.mark.parametrize('true_order', sorted(TRUE_BIAS_RAD_S))
def test_the_cubic_is_written_unless_an_order_beats_it_fold_by_fold(true_order):
    temperature_c = thermal_cycle_c(4000)
    rate_rad_s = simulated_rate_rad_s(temperature_c, TRUE_BIAS_RAD_S[true_order], true_order)
    (selection,) = select_orders(temperature_c, rate_rad_s)
    print(f'true order {true_order}\n{format_order_table((selection,))}')
    assert selection.axis == 'x'
    assert selection.rule.startswith('the PX4-style cubic unless another order beats it')
    if true_order < 5:
        # The cubic holds an order 2: nothing beats it fold by fold, so it is written.
        assert selection.order == 3
        assert selection.rule.endswith('no order does, so the cubic is written')
    else:
        assert selection.order == true_order
        assert 'order 5 does' in selection.rule
    assert [score.order for score in selection.scores] == list(range(9))
    # round-robin (the default): 20 blocks dealt to 5 folds
    assert all(len(score.block_rms_rad_s) == 5 for score in selection.scores)


def test_an_order_that_wins_by_a_margin_but_not_fold_by_fold_is_not_taken():
    """Order 5 is far better on average; asked to win by 30 standard errors, it cannot."""
    temperature_c = thermal_cycle_c(4000)
    rate_rad_s = simulated_rate_rad_s(temperature_c, TRUE_BIAS_RAD_S[5], 5)
    (selection,) = select_orders(temperature_c, rate_rad_s, significance=1e6)
    assert selection.order == 3
    means = {score.order: score.mean_rms_rad_s for score in selection.scores}
    assert means[5] < 0.8 * means[3]


def test_order_selection_per_axis_and_table():
    temperature_c = thermal_cycle_c(3000)
    rate_rad_s = np.column_stack([simulated_rate_rad_s(temperature_c, TRUE_BIAS_RAD_S[5], 11),
                                  simulated_rate_rad_s(temperature_c, TRUE_BIAS_RAD_S[3], 12)])
    selections = select_orders(temperature_c, rate_rad_s, axes=('y', 'z'),
                               candidate_orders=range(0, 6))
    assert [(s.axis, s.order) for s in selections] == [('y', 5), ('z', 3)]
    table = format_order_table(selections)
    print(table)
    chosen = [line.split()[:2] for line in table.splitlines() if line.endswith('*')]
    assert chosen == [['y', '5'], ['z', '3']]
    assert table.splitlines()[0].split() == ['axis', 'order', 'mean', 'held-out', 'RMS', '(rad/s)',
                                             '(deg/s)', 'standard', 'error', '(rad/s)', 'chosen']


def test_unsupported_orders_score_inf_and_are_never_chosen():
    temperature_c = np.repeat(np.linspace(0.0, 30.0, 4), 50)
    rate_rad_s = 1e-3 + 1e-4 * temperature_c
    # Round-robin: forward, the first predicted block's past holds one temperature only.
    (selection,) = select_orders(temperature_c, rate_rad_s, candidate_orders=range(0, 5),
                                 validation=ROUND_ROBIN)
    print(format_order_table((selection,)))
    means = {score.order: score.mean_rms_rad_s for score in selection.scores}
    assert means[4] == np.inf and selection.order != 4
    assert 'unsupported' in format_order_table((selection,))


def test_order6_fit_is_stable_in_float64():
    temperature_c = np.linspace(-40.0, 85.0, 2000)
    truth_rad_s = true_bias_rad_s(temperature_c, ORDER6_BIAS_RAD_S)
    model = fit_polynomial(temperature_c, truth_rad_s, 6)
    assert (model.temperature_min_c, model.temperature_max_c) == (-40.0, 85.0)
    grid_c = np.linspace(-40.0, 85.0, 501)
    grid_truth_rad_s = true_bias_rad_s(grid_c, ORDER6_BIAS_RAD_S)
    ours_rad_s = -model.correct(np.zeros(grid_c.size), grid_c).rate_rad_s[:, 0]
    scale_rad_s = np.max(np.abs(grid_truth_rad_s))
    ours_error = np.max(np.abs(ours_rad_s - grid_truth_rad_s)) / scale_rad_s
    assert ours_error < 1e-12

    # the same data and truth with temperatures in kelvin-shifted form
    kelvin_model = fit_polynomial(temperature_c + KELVIN_OFFSET_C, truth_rad_s, 6)
    kelvin_rad_s = -kelvin_model.correct(np.zeros(grid_c.size),
                                         grid_c + KELVIN_OFFSET_C).rate_rad_s[:, 0]
    np.testing.assert_allclose(kelvin_rad_s, ours_rad_s, rtol=0.0, atol=1e-9 * scale_rad_s)

    # the MPU-6000 note: single-precision polyfit and polyval on raw temperature
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', np.exceptions.RankWarning)
        naive = np.polyfit(temperature_c.astype(np.float32), truth_rad_s.astype(np.float32), 6)
    naive_rad_s = np.polyval(naive.astype(np.float32), grid_c.astype(np.float32))
    naive_error = np.max(np.abs(naive_rad_s - grid_truth_rad_s)) / scale_rad_s
    print(f'order 6 relative error: float64 scaled {ours_error:.2e}, '
          f'float32 polyfit on raw T {naive_error:.2e}')
    assert naive_error > 1e3 * ours_error


def test_contiguous_blocks_cover_every_index_once_in_order():
    for samples, count in ((10, 2), (11, 3), (1003, 5), (7, 7)):
        blocks = contiguous_blocks(samples, count)
        assert len(blocks) == count
        np.testing.assert_array_equal(np.concatenate(blocks), np.arange(samples))
        sizes = [block.size for block in blocks]
        assert max(sizes) - min(sizes) <= 1
        assert all(np.all(np.diff(block) == 1) for block in blocks)


def test_error_too_narrow_span_for_the_order():
    temperature_c = np.linspace(20.0, 20.5, 100)
    with pytest.raises(CalibrationError, match=r'order 2 needs a temperature span of at least'):
        fit_polynomial(temperature_c, np.zeros(100), 2)
    constant = fit_polynomial(temperature_c, np.full(100, 1e-3), 0)
    assert constant.terms[0].bias == pytest.approx((1e-3,), rel=1e-12)


def test_error_too_few_distinct_temperatures():
    temperature_c = np.repeat([0.0, 10.0, 20.0], 30) + 1e-4
    with pytest.raises(CalibrationError, match=r'order 3 needs at least 4 distinct temperatures'):
        fit_polynomial(temperature_c, np.zeros((90, 2)), [1, 3])
    assert fit_polynomial(temperature_c, np.zeros((90, 2)), [1, 2]).axes == 2


def test_error_non_finite_input():
    temperature_c = np.linspace(0.0, 40.0, 50)
    rate_rad_s = np.zeros(50)
    rate_rad_s[7] = np.nan
    with pytest.raises(CalibrationError, match=r'1 non-finite temperature or rate'):
        fit_polynomial(temperature_c, rate_rad_s, 1)
    temperature_c[3] = np.inf
    with pytest.raises(CalibrationError, match=r'non-finite'):
        select_orders(temperature_c, np.zeros(50))


def test_error_fewer_than_two_blocks_or_folds():
    with pytest.raises(CalibrationError, match=r'at least 2 blocks, got 1'):
        contiguous_blocks(100, 1)
    with pytest.raises(CalibrationError, match=r'2 <= folds <= blocks, got 5 folds, 1 blocks'):
        select_orders(np.linspace(0.0, 40.0, 100), np.zeros(100), blocks=1,
                      validation=ROUND_ROBIN)
    with pytest.raises(CalibrationError, match=r'got 1 folds'):
        select_orders(np.linspace(0.0, 40.0, 100), np.zeros(100), folds=1,
                      validation=ROUND_ROBIN)
    with pytest.raises(CalibrationError, match=r'of 4 blocks the first 3 \(--min-past 0.75\)'):
        select_orders(np.linspace(0.0, 40.0, 100), np.zeros(100), blocks=4, min_past=0.75,
                      validation=FORWARD)


def test_folds_deal_contiguous_blocks_round_robin_or_forward():
    held_out = fold_rows(20, blocks=10, folds=5, scheme=ROUND_ROBIN)
    assert [rows.tolist() for rows in held_out] == [
        [0, 1, 10, 11], [2, 3, 12, 13], [4, 5, 14, 15], [6, 7, 16, 17], [8, 9, 18, 19]]
    # Forward: each block after the first quarter alone, in time order.
    held_out = fold_rows(20, blocks=10, min_past=0.25)
    assert [rows.tolist() for rows in held_out] == [[6, 7], [8, 9], [10, 11], [12, 13],
                                                    [14, 15], [16, 17], [18, 19]]
    with pytest.raises(CalibrationError, match=r'cannot split 3 samples into 5 blocks'):
        contiguous_blocks(3, 5)


def direct_fit(temperature_c, rate_rad_s, order):
    """
    Return the power coefficients in x of the data's range by np.linalg.lstsq on polyvander.

    x = (T - centre) / scale, the scale the power of two at or above the half span.
    """
    low_c, high_c = np.min(temperature_c), np.max(temperature_c)
    scale = 2.0 ** np.ceil(np.log2(0.5 * (high_c - low_c)))
    x = (temperature_c - 0.5 * (low_c + high_c)) / scale
    design = np.polynomial.polynomial.polyvander(x, order)
    return np.linalg.lstsq(design, rate_rad_s, rcond=None)[0]


def test_fit_equals_a_direct_lstsq_per_axis():
    rng = np.random.default_rng(5)
    temperature_c = np.sort(rng.uniform(-30.0, 70.0, 700)) + KELVIN_OFFSET_C
    rate_rad_s = np.column_stack([
        true_bias_rad_s(temperature_c - KELVIN_OFFSET_C, TRUE_BIAS_RAD_S[order])
        + rng.normal(0.0, 3e-4, temperature_c.size) for order in (2, 3, 5)])
    orders = (2, 8, 5)
    model = fit_polynomial(temperature_c, rate_rad_s, orders)
    assert (model.temperature_min_c, model.temperature_max_c) == (temperature_c[0],
                                                                  temperature_c[-1])
    for axis, order in enumerate(orders):
        expected = direct_fit(temperature_c, rate_rad_s[:, axis], order)
        ours = np.asarray(model.terms[axis].bias)
        assert ours.shape == expected.shape
        error = np.max(np.abs(ours - expected)) / np.max(np.abs(expected))
        print(f'axis {axis} order {order}: relative coefficient difference {error:.1e}')
        assert error < 1e-10


def direct_block_rms_rad_s(temperature_c, rate_rad_s, order, blocks, folds, scheme):
    """Return the held-out RMS per fold: lstsq on the training rows, correct on the held out."""
    rms = []
    for held_out in fold_rows(temperature_c.size, blocks, folds, scheme):
        rows = np.arange(temperature_c.size)
        train = rows[:held_out[0]] if scheme == FORWARD else np.delete(rows, held_out)
        low_c, high_c = np.min(temperature_c[train]), np.max(temperature_c[train])
        model = polynomial_model(
            (direct_fit(temperature_c[train], rate_rad_s[train], order),),
            reference_temperature_c=0.5 * (low_c + high_c),
            temperature_scale_c=2.0 ** np.ceil(np.log2(0.5 * (high_c - low_c))),
            temperature_min_c=low_c, temperature_max_c=high_c)
        residual = model.correct(rate_rad_s[held_out], temperature_c[held_out]).rate_rad_s
        rms.append(np.sqrt(np.mean(np.square(residual))))
    return np.array(rms)


@pytest.mark.parametrize('samples, blocks, folds, highest, scheme', [
    (3000, 20, 5, 8, ROUND_ROBIN), (3000, 20, 5, 8, FORWARD),
    (2 * CHUNK_ROWS + 1001, 2, 2, 3, ROUND_ROBIN),  # blocks of 2 chunks
    (2 * CHUNK_ROWS + 1001, 4, 2, 3, FORWARD)])
def test_held_out_scores_equal_direct_fits_on_the_training_rows(samples, blocks, folds,
                                                                highest, scheme):
    # a ramp up then a cycle: the first block's lowest temperatures are held out alone, so
    # its fold's model is clamped to a narrower range than the whole record's
    phase = np.linspace(0.0, 1.0, samples)
    temperature_c = np.where(phase < 0.3, -40.0 + 400.0 * phase,
                             60.0 - 60.0 * np.sin(np.pi * (phase - 0.3) / 0.35) ** 2)
    rng = np.random.default_rng(blocks)
    rate_rad_s = (true_bias_rad_s(temperature_c, TRUE_BIAS_RAD_S[3])
                  + rng.normal(0.0, 1e-4, samples))
    (selection,) = select_orders(temperature_c, rate_rad_s,
                                 candidate_orders=range(0, highest + 1), blocks=blocks,
                                 folds=folds, validation=scheme)
    held = fold_rows(samples, blocks, folds, scheme)[0]
    train = temperature_c[:held[0]] if scheme == FORWARD else np.delete(temperature_c, held)
    assert np.ptp(np.concatenate((train, temperature_c[held]))) > np.ptp(train)
    for score in selection.scores:
        expected = direct_block_rms_rad_s(temperature_c, rate_rad_s, score.order, blocks,
                                          folds, scheme)
        np.testing.assert_allclose(score.block_rms_rad_s, expected, rtol=1e-9, atol=0.0)


def test_distinct_temperatures_are_counted_across_chunks():
    temperature_c = np.repeat([10.0, 20.0, 30.0], CHUNK_ROWS - 7)
    rate_rad_s = 1e-3 + 1e-5 * temperature_c
    message = (r'order 3 needs at least 4 distinct temperatures \(rounded to 0.01 C\), '
               r'the data has 3$')
    with pytest.raises(CalibrationError, match=message):
        fit_polynomial(temperature_c, rate_rad_s, 3)
    model = fit_polynomial(temperature_c, rate_rad_s, 2)
    # x = (T - 20 C) / 16 C: the scale is the power of two above the half span
    np.testing.assert_allclose(model.terms[0].bias, (1.2e-3, 1.6e-4, 0.0),
                               rtol=0.0, atol=1e-15)


def test_temperatures_too_close_to_determine_the_order():
    # three distinct values after rounding, but two of them 2e-10 C apart
    temperature_c = np.repeat([0.0049999999, 0.0050000001, 30.0], 20)
    rate_rad_s = 1e-3 * temperature_c
    message = (r'axis x: the temperatures cannot determine an order 2 polynomial '
               r'\(design matrix rank 2\)')
    with pytest.raises(CalibrationError, match=message):
        fit_polynomial(temperature_c, rate_rad_s, 2)
    # Round-robin: forward, the first predicted blocks' past holds one temperature only.
    (selection,) = select_orders(temperature_c, rate_rad_s, candidate_orders=range(3),
                                 blocks=6, folds=3, validation=ROUND_ROBIN)
    # The cubic is always scored: here the folds cannot support it, so the lowest order
    # within one standard error of the best is taken.
    unsupported = [score.mean_rms_rad_s == np.inf for score in selection.scores]
    assert unsupported == [False, False, True, True]
    assert selection.order == 1 and 'cannot support the PX4-style cubic' in selection.rule
