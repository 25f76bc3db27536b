from mlx_tempcomp.core.errors import ConfigError
from mlx_tempcomp.core.mlx90609.interpolation import (check_triplets, interpolate, Interpolation,
                                                      quadratic_coefficients)
import numpy as np
import pytest

TC = (994.56, 1413.12, 1800.96)
ZRO = (1011.39, 1012.14, 1021.18)


def lagrange(tc, values, x):
    """Independent evaluation: the Lagrange form of the interpolating quadratic."""
    total = 0.0
    for i in range(3):
        term = values[i]
        for j in range(3):
            if j != i:
                term *= (x - tc[j]) / (tc[i] - tc[j])
        total += term
    return total


@pytest.mark.parametrize('seed', range(10))
def test_quadratic_passes_exactly_through_the_triplets(seed):
    rng = np.random.default_rng(seed)
    tc = np.sort(rng.uniform(900.0, 1900.0, 3))
    values = rng.uniform(900.0, 1100.0, 3)
    got = interpolate(Interpolation.QUADRATIC, tc, values, tc)
    np.testing.assert_allclose(got, values, rtol=0, atol=1e-9 * np.max(np.abs(values)))


@pytest.mark.parametrize('seed', range(10))
def test_quadratic_matches_lagrange_everywhere(seed):
    rng = np.random.default_rng(100 + seed)
    tc = np.sort(rng.uniform(900.0, 1900.0, 3))
    values = rng.uniform(-50.0, 50.0, 3)
    x = np.linspace(tc[0] - 50.0, tc[2] + 50.0, 101)
    expected = [lagrange(tc, values, xi) for xi in x]
    np.testing.assert_allclose(interpolate(Interpolation.QUADRATIC, tc, values, x), expected,
                               rtol=1e-9, atol=1e-9)


def test_coefficients_follow_an2_formulas_5_to_13_by_hand():
    # TC = (1, 2, 4), values = (1, 4, 16) lie on x^2: T0 = 2, T1 = -3, T2 = 1.
    a, b, c = quadratic_coefficients((1.0, 2.0, 4.0), (1.0, 4.0, 16.0))
    assert (a, b, c) == pytest.approx((1.0, 0.0, 0.0), abs=1e-12)
    a, b, c = quadratic_coefficients((1.0, 2.0, 4.0), (5.0, 7.0, 11.0))  # 2x + 3
    assert (a, b, c) == pytest.approx((0.0, 2.0, 3.0), abs=1e-12)


def test_piecewise_linear_linear_and_step():
    tc, values = (0.0, 10.0, 30.0), (0.0, 10.0, 50.0)
    x = np.array([0.0, 5.0, 10.0, 20.0, 30.0])
    np.testing.assert_allclose(interpolate(Interpolation.PIECEWISE_LINEAR, tc, values, x),
                               [0.0, 5.0, 10.0, 30.0, 50.0])
    # Linear: one line through the outer triplets, slope 50 / 30.
    np.testing.assert_allclose(interpolate(Interpolation.LINEAR, tc, values, x),
                               x * 50.0 / 30.0)
    # Step: the nearest triplet, boundaries half-way between them (5 and 20).
    np.testing.assert_allclose(interpolate(Interpolation.STEP, tc, values,
                                           [4.9, 5.1, 19.9, 20.1, 30.0]),
                               [0.0, 10.0, 10.0, 50.0, 50.0])
    for method in Interpolation:
        np.testing.assert_allclose(interpolate(method, tc, values, tc)[[0, 2]], [0.0, 50.0])


def test_interpolation_names_parse_and_bad_names_are_refused():
    assert Interpolation.parse('piecewise_linear') is Interpolation.PIECEWISE_LINEAR
    with pytest.raises(ConfigError, match="got 'cubic'"):
        Interpolation.parse('cubic')


@pytest.mark.parametrize('tc, message', [((1.0, 1.0, 2.0), 'TC0 < TC1 < TC2'),
                                         ((3.0, 2.0, 1.0), 'TC0 < TC1 < TC2'),
                                         ((1.0, np.nan, 2.0), 'finite'),
                                         ((1.0, 2.0), 'three triplets')])
def test_bad_triplets_are_refused(tc, message):
    with pytest.raises(ConfigError, match=message):
        check_triplets(tc, (1.0, 2.0, 3.0)[:len(tc)])
