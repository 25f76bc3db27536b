"""
``core.fitting.pooling``: the fleet prior and shrunk unit fits, on seeded fleets of known truth.

Each unit is a gyro whose bias is a cubic in temperature plus c x dT/dt, its
coefficients drawn around a fleet mean; its record is two -20..70 C cycles at
0.5 C/min (or the first 6 % of them: 25 to 45 C, one ramp) with white and
slow (first-order, 300 s) noise. A fit is judged by the RMS of its bias
curve against the true one from -20 to 70 C at rest; the unit's own fit is
its least squares in the fleet design, shrunk or not.
"""

import json
import math

from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.fitting.pooling import (CONFLICT_LEVEL, fit_population, information,
                                               MOMENT_ORDER, moments_of, pool_fleet, PoolingDesign,
                                               record_moments, shrink, unit_data, unit_moments)
import numpy as np
import pytest

ROWS = 2400
STEP_S = 9.0
SHORT = 0.06
MEAN = np.array([0.01, 2e-4, 2e-6, -3e-8])      # rad/s per C^k of (T - 25)
SPREAD = np.array([0.01, 5e-5, 1e-6, 1e-8])
RATE_PER_SLOPE_S = 60.0                           # c = lag x slope, the thermal lag
GRID_C = np.linspace(-20.0, 70.0, 91)


def profile() -> tuple:
    """Give time and temperature of two -20..70 C cycles starting at 25 C, heating."""
    time_s = np.arange(ROWS) * STEP_S
    phase = (time_s / (ROWS * STEP_S / 2.0) + 0.25) % 1.0
    return time_s, 25.0 + 45.0 * (1.0 - 4.0 * np.abs(phase - 0.5))


def draw_unit(rng, outlier: bool = False) -> np.ndarray:
    truth = MEAN + SPREAD * rng.standard_normal(4)
    if outlier:
        truth[1] += 40 * SPREAD[1]
    return truth


def record(rng, truth: np.ndarray, fraction: float) -> tuple:
    time_s, temperature_c = profile()
    slope = np.gradient(temperature_c, time_s)
    bias = np.polynomial.polynomial.polyval(temperature_c - 25.0, truth) + \
        RATE_PER_SLOPE_S * truth[1] * slope
    slow = np.zeros(ROWS)
    decay = math.exp(-STEP_S / 300.0)
    kicks = rng.normal(0.0, 2e-4 * math.sqrt(1.0 - decay ** 2), ROWS)
    for k in range(1, ROWS):
        slow[k] = decay * slow[k - 1] + kicks[k]
    rate = bias + slow + rng.normal(0.0, 1e-3, ROWS)
    rows = int(ROWS * fraction)
    return time_s[:rows], temperature_c[:rows] + rng.normal(0.0, 0.02, rows), rate[:rows]


def measured(rng, truth: np.ndarray, fraction: float):
    """Give the DesignMoments of a record of a unit of coefficients ``truth``."""
    time_s, temperature_c, rate = record(rng, truth, fraction)
    # Through JSON, as the fleet stores them.
    return moments_of(json.loads(json.dumps(record_moments(time_s, temperature_c,
                                                           rate[:, None], ['z']))))['z']


def fleet(seed: int, units: int, short: set, outliers=()) -> tuple:
    """Give ({unit: DesignMoments}, {unit: true coefficients}) of a seeded fleet."""
    rng = np.random.default_rng(seed)
    moments, truths = {}, {}
    for k in range(units):
        name = f'u{k:02d}'
        truths[name] = draw_unit(rng, name in outliers)
        moments[name] = measured(rng, truths[name], SHORT if name in short else 1.0)
    return moments, truths


def curve(pool, coefficients) -> np.ndarray:
    """Give the fit's bias at rest, -20..70 C."""
    bias, _ = pool.design.bias_and_rate(coefficients)
    return np.polynomial.polynomial.polyval(
        (GRID_C - pool.design.reference_c) / pool.design.scale_c, bias)


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def curve_error(pool, coefficients, truth) -> float:
    """RMS of the fit's bias at rest against the truth, -20..70 C."""
    return rms(curve(pool, coefficients) - np.polynomial.polynomial.polyval(GRID_C - 25.0, truth))


def pool(moments: dict, pooled=None):
    pooled = list(moments) if pooled is None else pooled
    low = min(moments[u].temperature_min_c for u in pooled)
    high = max(moments[u].temperature_max_c for u in pooled)
    return pool_fleet(moments, pooled, 0.5 * (low + high), 0.5 * (high - low))


def test_a_short_record_borrows_from_the_fleet():
    units = 16
    short = {f'u{k:02d}' for k in range(1, units, 2)}
    moments, truths = fleet(1, units, short)
    result = pool(moments)
    own = [curve_error(result, result.units[u].own, truths[u]) for u in sorted(short)]
    shrunk = [curve_error(result, result.units[u].shrunk, truths[u]) for u in sorted(short)]
    prior = [curve_error(result, result.population.mean, truths[u]) for u in sorted(short)]
    better = sum(s < o for s, o in zip(shrunk, own))
    assert better >= 0.75 * len(short), (own, shrunk)
    assert np.mean(shrunk) < 0.5 * np.mean(own)
    assert np.mean(shrunk) < np.mean(prior), 'the short record still tells its unit apart'
    assert all(result.units[u].prior_share > 0.3 for u in short)


def test_a_long_record_keeps_its_own_fit():
    moments, truths = fleet(2, 12, set())
    result = pool(moments)
    for unit, fit in result.units.items():
        own_error = curve_error(result, fit.own, truths[unit])
        moved = rms(curve(result, fit.shrunk) - curve(result, fit.own))
        assert moved < 0.5 * own_error, unit
        assert fit.prior_share < 0.35, unit
    own = np.mean([curve_error(result, f.own, truths[u]) for u, f in result.units.items()])
    shrunk = np.mean([curve_error(result, f.shrunk, truths[u])
                      for u, f in result.units.items()])
    assert shrunk <= 1.02 * own


def test_a_record_that_contradicts_the_fleet_keeps_its_own_fit():
    moments, truths = fleet(12, 12, {'u01', 'u03'})
    rng = np.random.default_rng(112)
    # A long record of a unit far from the fleet (slope 40 sd off), and a short one whose cubic,
    # which the fleet's curve gives it where its 25..45 C are silent, is 300 sd off.
    truths['far'], truths['odd'] = draw_unit(rng), draw_unit(rng)
    truths['far'][1] += 40 * SPREAD[1]
    truths['odd'][3] += 300 * SPREAD[3]
    moments['far'] = measured(rng, truths['far'], 1.0)
    moments['odd'] = measured(rng, truths['odd'], SHORT)
    result = pool(moments, [u for u in moments if u not in ('far', 'odd')])

    def error(unit, coefficients):
        return curve_error(result, coefficients, truths[unit])

    # Far from the fleet, its small t weight leaves the long record its own: nothing to reject.
    far = result.units['far']
    assert far.weight < 0.05 and far.conflict.statistic < 1.0 and not far.conflict.rejected
    assert rms(curve(result, far.shrunk) - curve(result, far.own)) < 0.1 * error('far', far.own)
    # The short record's own data reject what the fleet makes of it: its own fit, nothing shrunk.
    odd = result.units['odd']
    assert odd.conflict.rejected and odd.conflict.dof == result.design.size
    assert np.allclose(odd.shrunk, odd.own, rtol=1e-9, atol=0.0) and odd.prior_share == 0.0
    assert error('odd', odd.own) < 0.2 * error('odd', result.population.mean)
    # The fleet's own units, long and short, are still shrunk.
    for unit in ('u00', 'u01', 'u02', 'u03'):
        fit = result.units[unit]
        assert not fit.conflict.rejected and fit.conflict.statistic < 0.5 * fit.conflict.threshold
        assert fit.prior_share > (0.3 if unit in ('u01', 'u03') else 0.05), unit
    assert error('u01', result.units['u01'].shrunk) < 0.1 * error('u01', result.units['u01'].own)
    # Units drawn from the population are rejected at most at the test's level.
    info, _ = information(unit_data(moments['u01'], result.design), result.sigma2_median,
                          result.kappa)
    population = result.population
    draws = rng.multivariate_normal(population.mean, population.covariance, 1000)
    draws += rng.multivariate_normal(np.zeros(draws.shape[1]),
                                     np.linalg.pinv(info, hermitian=True), len(draws))
    rejected = [shrink(population, info, info @ own).conflict.rejected for own in draws]
    assert np.mean(rejected) <= CONFLICT_LEVEL


def test_the_design_is_what_the_fleet_shows():
    moments, _ = fleet(3, 10, set())
    result = pool(moments)
    assert all(m.rate_varies for m in moments.values())
    assert result.design.rate, 'every unit carries c x dT/dt'
    assert 2 <= result.design.order <= 3
    assert [t.column for t in result.tests if t.significant][0] == \
        f'bias[{result.design.order}] beside the rate'
    assert result.kappa > 1.0, 'the slow noise shows on the stretches'
    assert result.population.converged


def test_one_ramp_does_not_test_the_temperature_rate():
    units = 8
    moments, _ = fleet(9, units, {f'u{k:02d}' for k in range(units)})
    assert not any(m.rate_varies for m in moments.values())
    result = pool(moments)
    assert not result.design.rate, 'c x dT/dt at one rate is one more constant'
    rate = [t for t in result.tests if t.column == 'temperature_rate_rad_s_per_c_s']
    assert len(rate) == 1 and rate[0].dof == 0 and not rate[0].significant


def test_outliers_do_not_drag_the_prior_and_are_not_pulled():
    moments, truths = fleet(4, 14, {'u00'}, {'u00', 'u01'})
    clean = pool(moments, [u for u in moments if u not in ('u00', 'u01')])
    sd = np.sqrt(np.diag(clean.population.covariance))
    # One far unit the report missed: the t population weighs it little (two of fourteen,
    # beyond the t's breakdown of about 1 / (p + nu), is what leaving out flagged units is for).
    with_one = pool(moments, [u for u in moments if u != 'u00'])
    assert np.all(np.abs(with_one.population.mean - clean.population.mean) < 0.5 * sd)
    assert with_one.units['u01'].weight < 0.2
    for unit in ('u00', 'u01'):
        assert not clean.units[unit].pooled and clean.units[unit].weight < 0.2
    # Its long record keeps the outlier's own fit; the short one borrows the fleet's shape.
    assert curve_error(clean, clean.units['u01'].shrunk, truths['u01']) < \
        1.2 * curve_error(clean, clean.units['u01'].own, truths['u01'])
    assert curve_error(clean, clean.units['u00'].shrunk, truths['u00']) < \
        curve_error(clean, clean.units['u00'].own, truths['u00'])


def test_the_design_transform_is_least_squares_in_the_fleet_basis():
    rng = np.random.default_rng(5)
    time_s, temperature_c, rate = record(rng, draw_unit(rng), 1.0)
    moments = moments_of(record_moments(time_s, temperature_c, rate[:, None], ['z']))['z']
    design = PoolingDesign(3, 21.0, 37.0, rate=False)
    x = (temperature_c - 21.0) / 37.0
    direct = np.linalg.lstsq(x[:, None] ** np.arange(4), rate, rcond=None)[0]
    assert np.allclose(unit_data(moments, design).coefficients, direct, rtol=1e-7, atol=1e-12)
    both = moments + moments
    assert both.rows == 2 * moments.rows and both.block_record.max() == 1
    assert np.allclose(unit_data(both, design).coefficients, direct, rtol=1e-7, atol=1e-12)


def test_each_record_of_a_unit_has_its_own_offset_and_the_last_ones_is_the_units():
    rng = np.random.default_rng(10)
    truth = draw_unit(rng)
    time_s, temperature_c, rate = record(rng, truth, 1.0)
    # Two runs of one unit, the first re-mounted 0.03 rad/s off (its second half cooling).
    half = ROWS // 2 + ROWS // 8
    offset = np.where(np.arange(ROWS) < half, 0.03, 0.0)
    runs = [moments_of(record_moments(time_s[rows], temperature_c[rows],
                                      (rate + offset)[rows, None], ['z']))['z']
            for rows in (slice(0, half), slice(half, None))]
    unit = unit_moments(runs)
    assert unit.rows == ROWS and unit.offsets == 1 and unit.block_record.max() == 1
    design = PoolingDesign(3, 25.0, 45.0, rate=False)
    x = (temperature_c - 25.0) / 45.0
    # Least squares with an indicator column of the first run: its offset a nuisance.
    columns = np.column_stack([x[:, None] ** np.arange(4), offset > 0.0])
    direct, residual, _, _ = np.linalg.lstsq(columns, rate + offset, rcond=None)
    fit = unit_data(unit, design)
    assert np.allclose(fit.coefficients, direct[:4], rtol=1e-7, atol=1e-12)
    assert direct[4] == pytest.approx(0.03, abs=2e-4)
    assert fit.sigma2 == pytest.approx(residual[0] / (ROWS - 5), rel=1e-6)
    # The constant is the last run's: the truth's at 25 C, not a mean over the two mounts.
    assert fit.coefficients[0] == pytest.approx(truth[0], abs=5e-4)
    summed = unit_data(runs[0] + runs[1], design)
    assert abs(summed.coefficients[0] - truth[0]) > 0.01
    # One record is itself.
    assert unit_moments(runs[1:]) is runs[1]


def test_a_record_shorter_than_the_design_takes_the_fleets_noise():
    moments, _ = fleet(6, 8, set())
    rng = np.random.default_rng(7)
    time_s, temperature_c, rate = record(rng, draw_unit(rng), 3 / ROWS)
    moments['tiny'] = moments_of(record_moments(time_s, temperature_c, rate[:, None],
                                                ['z']))['z']
    result = pool(moments, [u for u in moments if u != 'tiny'])
    assert result.units['tiny'].prior_share > 0.7, 'three rows tell the offset only'
    assert np.all(np.isfinite(result.units['tiny'].shrunk))


def test_bad_input_is_a_calibration_error():
    with pytest.raises(CalibrationError, match='2 rows or more'):
        record_moments([0.0], [25.0], [[0.0]], ['z'])
    with pytest.raises(CalibrationError, match='design moments'):
        moments_of({'rows': 3})
    with pytest.raises(CalibrationError, match='order must be 0 to'):
        PoolingDesign(MOMENT_ORDER + 1, 25.0, 10.0)
    moments, _ = fleet(8, 3, set())
    data = [unit_data(m, PoolingDesign(2, 25.0, 45.0)) for m in moments.values()]
    with pytest.raises(CalibrationError, match='at least 5 units'):
        fit_population([information(d, d.sigma2, 1.0) for d in data])
    population = fit_population([information(d, d.sigma2, 1.0) for d in data] * 2)
    assert shrink(population, *information(data[0], data[0].sigma2, 1.0)).weight > 0.0
