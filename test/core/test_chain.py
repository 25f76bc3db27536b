"""
The calibration chain of the PSI 3-axis teslameter paper on simulated rate-table data.

Noise budget behind the tolerances (default `TurntableProtocol`): white noise
sigma = 0.05 deg/s = 8.7e-4 rad/s per sample, 40 samples per plateau, so a plateau mean
carries sigma_p = 1.4e-4 rad/s. Line over five temperatures 40 C apart:
sigma_p / sqrt(4000 C^2) = 2.2e-6 rad/s/C per rate level. The electronics drift
(+-0.2 C x up to 0.05 deg/s/C = 1.7e-4 rad/s, slow, so correlated with the order of the
plateaus) adds a systematic part of about sigma_p to stages 1 to 3, which are fitted
before stage 4 removes it. Each tolerance is about 4 of these sigmas, and 1.5 to 2 x the
largest error seen over 60 seeds. Without noise the fit recovers the truth to 1e-13.
"""

import dataclasses
import math

from mlx_tempcomp.core.errors import CalibrationError, ConfigError
from mlx_tempcomp.core.fitting.chain_fit import (ChainSettings, find_plateaus, fit_chain,
                                                 stage_errors)
from mlx_tempcomp.core.node_models.chain import CalibrationChain, ChainModel, STAGE_NAMES
from mlx_tempcomp.core.node_models.interface import CompensationModel, ModelInputs, ModelStream
from mlx_tempcomp.simulation.turntable import simulate_turntable, TurntableProtocol
from mlx_tempcomp.toolkit.tables import format_stage_table
import numpy as np
import pytest

X = np.linspace(-1.0, 1.0, 201)


def polyval(coefficients):
    return np.polynomial.polynomial.polyval(X, coefficients)


def settings_for(session, **changes) -> ChainSettings:
    truth = session.truth
    settings = ChainSettings(full_scale_rad_s=truth.full_scale_rad_s,
                             reference_temperature_c=truth.reference_temperature_c,
                             reference_temperature_2_c=truth.reference_temperature_2_c)
    return dataclasses.replace(settings, **changes)


def fit(session, plateau_id=None, **changes):
    plateau_id = session.plateau_id if plateau_id is None else plateau_id
    return fit_chain(session.reference_rad_s, session.measured_rad_s, session.temperature_c,
                     session.temperature_2_c, plateau_id, settings_for(session, **changes))


def overall(rows, stage: str):
    return next(r for r in rows if r.stage == stage and r.axis == 'all')


@pytest.fixture(scope='module')
def session():
    return simulate_turntable(seed=4)


@pytest.fixture(scope='module')
def fitted(session):
    return fit(session)


def test_noise_free_fit_recovers_the_truth_exactly():
    protocol = dataclasses.replace(TurntableProtocol(), noise_rad_s=0.0,
                                   temperature_noise_c=0.0, temperature_2_drift_c=0.0)
    session = simulate_turntable(protocol, seed=4)
    np.testing.assert_allclose(fit(session).chain.correct(
        session.measured_rad_s, session.temperature_c, session.temperature_2_c),
        session.reference_rad_s, rtol=0.0, atol=1e-12)


def test_chain_recovers_nonlinearity_offsets_k_c_and_misalignment(session, fitted):
    chain, truth = fitted.chain, session.truth.chain()
    for axis in range(3):
        # Order-5 fit over 25 levels: edge leverage ~1, so ~sigma_p + drift per point.
        assert np.max(np.abs(polyval(chain.nonlinearity_rad_s[axis]) -
                             polyval(truth.nonlinearity_rad_s[axis]))) < 8e-4
        # Line slope 2.2e-6 rad/s/C per level; the cubic over 25 levels averages it.
        k_error = np.abs(polyval(chain.sensitivity_slope_rad_s_per_c[axis]) -
                         polyval(truth.sensitivity_slope_rad_s_per_c[axis]))
        assert np.max(k_error) < 1.2e-5
        # True C is zero (see TurntableTruth); intercepts carry sigma_p / sqrt(5) per level.
        assert np.max(np.abs(polyval(chain.sensitivity_intercept_rad_s[axis]))) < 4e-4
    # Gradients: 15 zero-rate plateaus over +-40 C (1.3e-6 rad/s/C); 7 electronics steps
    # over +-15 C of 300 samples (2e-6 rad/s/C). True values 1.7e-4 to 8.7e-4.
    np.testing.assert_allclose(chain.offset_gradient_rad_s_per_c,
                               truth.offset_gradient_rad_s_per_c, rtol=0.0, atol=1.2e-5)
    np.testing.assert_allclose(chain.offset_2_gradient_rad_s_per_c,
                               truth.offset_2_gradient_rad_s_per_c, rtol=0.0, atol=3e-5)
    # Constants at the reference are zero in the truth: a few sigma_p.
    np.testing.assert_allclose(chain.offset_rad_s, 0.0, atol=4e-4)
    np.testing.assert_allclose(chain.offset_2_rad_s, 0.0, atol=4e-4)
    # M = inv(S): plateau means against rates of a few rad/s; off-diagonals are 5e-3..1e-2.
    np.testing.assert_allclose(chain.misalignment, truth.misalignment, rtol=0.0, atol=2.5e-5)
    assert chain.reference_temperature_c == pytest.approx(20.0, abs=0.05)
    assert chain.reference_temperature_2_c == pytest.approx(25.0, abs=0.25)


def test_each_stage_lowers_the_error_on_calibration_and_fresh_data(session, fitted):
    verification = simulate_turntable(truth=session.truth, seed=40)
    inside = verification.plateau_id >= 0
    fresh = stage_errors(fitted.chain, verification.reference_rad_s[inside],
                         verification.measured_rad_s[inside],
                         verification.temperature_c[inside],
                         verification.temperature_2_c[inside])
    for rows in (fitted.stage_errors, fresh):
        rms = [overall(rows, stage).rms_rad_s for stage in STAGE_NAMES]
        assert all(after < before for before, after in zip(rms, rms[1:])), rms
        raw, calibrated = overall(rows, 'raw'), overall(rows, 'misalignment')
        assert raw.rms_rad_s / calibrated.rms_rad_s > 20.0
        assert raw.peak_percent_fs / calibrated.peak_percent_fs > 20.0
        # Calibrated down to the white noise (0.05 deg/s = 0.0167 % of 300 deg/s).
        assert calibrated.sigma_percent_fs < 1.1 * 100.0 * math.radians(0.05) / math.radians(
            300.0)


def test_nonlinearity_fixes_the_mean_and_sensitivity_the_spread_as_in_figures_20_21(
        session, fitted):
    # x turning alone at +100 deg/s (a third of full scale) through all five temperatures.
    reference = session.reference_rad_s
    one = (session.plateau_id >= 0) & np.isclose(reference[:, 0], math.radians(100.0)) & \
        np.all(reference[:, 1:] == 0.0, axis=1)
    rows = {row.stage: row for row in stage_errors(
        fitted.chain, reference[one], session.measured_rad_s[one], session.temperature_c[one],
        session.temperature_2_c[one]) if row.axis == 'x'}
    # Paper, 0.3 T: mean -1.13 % raw, 0.0097 % after nonlinearity; the spread stays.
    assert abs(rows['nonlinearity'].mean_percent_fs) < 0.01
    assert abs(rows['nonlinearity'].mean_rad_s) < 0.1 * abs(rows['raw'].mean_rad_s)
    assert rows['nonlinearity'].sigma_rad_s > 0.9 * rows['raw'].sigma_rad_s
    # K(rate) x (T - Tref) is the spread; what is left is the white noise.
    assert rows['sensitivity'].sigma_rad_s < 0.25 * rows['offset'].sigma_rad_s


def test_order_5_beats_order_3_on_a_fifth_order_truth(fitted):
    peak = {(row.axis, row.order): row.peak_rad_s for row in fitted.nonlinearity_orders}
    for axis in 'xyz':
        assert peak[axis, 5] < peak[axis, 3] / 5.0
        assert peak[axis, 5] < peak[axis, None] / 50.0
        # Order 6 has nothing left to model: no better than the noise either.
        assert peak[axis, 6] > 0.5 * peak[axis, 5]
    assert {row.order for row in fitted.nonlinearity_orders} == {None, 1, 2, 3, 4, 5, 6}


def test_sensitivity_lines_follow_k_of_the_rate(session, fitted):
    truth = session.truth.chain()
    points = [p for p in fitted.sensitivity_points if p.axis == 'y']
    assert len(points) == 25 and all(p.temperature_span_c > 75.0 for p in points)
    x = np.array([p.rate_rad_s for p in points]) / truth.full_scale_rad_s
    slopes = np.array([p.slope_rad_s_per_c for p in points])
    expected = np.polynomial.polynomial.polyval(x, truth.sensitivity_slope_rad_s_per_c[1])
    np.testing.assert_allclose(slopes, expected, rtol=0.0, atol=1.5e-5)


def test_parameters_round_trip_and_correct_identically(session, fitted):
    parameters = fitted.chain.to_parameters()
    for value in parameters.values():
        assert isinstance(value, float) or all(isinstance(v, float) for v in value)
    assert len(parameters['misalignment']) == 9
    assert len(parameters['nonlinearity_rad_s.z']) == 6
    rebuilt = CalibrationChain.from_parameters(parameters)
    assert rebuilt == fitted.chain
    args = (session.measured_rad_s, session.temperature_c, session.temperature_2_c)
    np.testing.assert_array_equal(rebuilt.correct(*args), fitted.chain.correct(*args))


def test_chain_model_has_the_model_interface_and_needs_the_second_temperature(session, fitted):
    model = ChainModel(fitted.chain)
    assert isinstance(model, CompensationModel) and isinstance(model.stream(), ModelStream)
    assert model.inputs == {'temperature_2_c'}
    rows = slice(0, 5)
    inputs = ModelInputs(temperature_2_c=session.temperature_2_c[rows])
    block = model.stream().correct_block(session.measured_rad_s[rows],
                                         session.temperature_c[rows], inputs)
    np.testing.assert_array_equal(block.rate_rad_s, fitted.chain.correct(
        session.measured_rad_s[rows], session.temperature_c[rows],
        session.temperature_2_c[rows]))
    with pytest.raises(ConfigError, match='needs temperature_2_c'):
        model.correct(session.measured_rad_s[rows], session.temperature_c[rows])


def test_chain_formula_on_hand_computed_values():
    chain = CalibrationChain(
        full_scale_rad_s=2.0, reference_temperature_c=20.0, reference_temperature_2_c=25.0,
        nonlinearity_rad_s=((0.1, 2.0, 0.0, 0.4),) * 3, offset_rad_s=(0.01, 0.0, 0.0),
        offset_gradient_rad_s_per_c=(0.001, 0.0, 0.0),
        sensitivity_slope_rad_s_per_c=((0.0, 0.002),) * 3,
        sensitivity_intercept_rad_s=((0.003, 0.004),) * 3, offset_2_rad_s=(0.0, 0.0, 0.02),
        offset_2_gradient_rad_s_per_c=(0.0, 0.0, 0.005),
        misalignment=((1.0, 0.0, 0.0), (0.01, 1.0, 0.0), (0.0, 0.0, 1.0)))
    # x = 0.5: y1 = 0.1 + 1.0 + 0.05 = 1.15; dT = 10: y2 = 1.15 - 0.01 - 0.01 = 1.13;
    # x2 = 0.565: K = 0.00113 x 10, C = 0.003 + 0.00226, y3 = 1.11344; on z, dT2 = 2: -0.03.
    rate = chain.correct([[1.0, 0.0, 1.0]], [30.0], [27.0])
    y1_y = 0.1
    y3_y = y1_y - (0.002 * 0.05 * 10.0 + 0.003 + 0.004 * 0.05)
    y3_z = 1.15 - (0.002 * 0.575 * 10.0 + 0.003 + 0.004 * 0.575) - 0.03
    np.testing.assert_allclose(rate, [[1.11344, 0.01 * 1.11344 + y3_y, y3_z]], atol=1e-12)


def test_find_plateaus_recovers_the_simulated_plateaus(session):
    found = find_plateaus(session.reference_rad_s, session.temperature_c,
                          session.temperature_2_c)
    np.testing.assert_array_equal(found, session.plateau_id)


def test_stage_table_lists_every_stage_and_axis(fitted):
    assert [(r.stage, r.axis) for r in fitted.stage_errors] == \
        [(s, a) for s in STAGE_NAMES for a in ('x', 'y', 'z', 'all')]
    table = format_stage_table(fitted.stage_errors)
    assert len(table.splitlines()) == 1 + 24 and 'misalignment all' in table


def without(session, drop) -> np.ndarray:
    return np.where(drop, -1, session.plateau_id)


@pytest.mark.parametrize('case, match', [
    ('no zero rate', 'offset: no zero-rate plateaus'),
    ('one temperature', r'offset: the zero-rate plateaus span 0\.\d+ C'),
    ('no electronics sweep', r'offset_2: the zero-rate plateaus span 0\.\d+ C'),
    ('order too high', 'nonlinearity of axis x: 25 rate levels .* order 30 needs 31'),
    ('reference elsewhere', 'nonlinearity of axis x: 0 rate levels within 2 C of 30 C'),
    ('cubic K on 3 levels', 'sensitivity of axis x: 3 rate levels span 2 C .* need 4'),
])
def test_calibration_errors_say_what_is_missing(session, case, match):
    reference, temperature = session.reference_rad_s, session.temperature_c
    zero_rate = np.all(reference == 0.0, axis=1)
    electronics = session.time_s > session.time_s[-1] - 1000.0
    if case == 'no zero rate':
        args = {'plateau_id': without(session, zero_rate)}
    elif case == 'one temperature':
        args = {'plateau_id': without(session, np.abs(temperature - 20.0) > 1.0)}
    elif case == 'no electronics sweep':
        args = {'plateau_id': without(session, electronics)}
    elif case == 'order too high':
        args = {'nonlinearity_order': 30}
    elif case == 'reference elsewhere':
        args = {'reference_temperature_c': 30.0}
    else:
        # Only three rate levels on x away from the reference temperature.
        kept = np.isin(np.round(np.degrees(reference[:, 0])), (-300.0, 0.0, 300.0))
        args = {'plateau_id': without(session, ~kept & (np.abs(temperature - 20.0) > 1.0))}
    with pytest.raises(CalibrationError, match=match):
        fit(session, **args)


def test_bad_shapes_and_parameters_are_config_errors(session, fitted):
    with pytest.raises(ConfigError, match=r'rate_rad_s must have shape \(samples, 3\)'):
        fitted.chain.correct(np.zeros((4, 2)), np.zeros(4), np.zeros(4))
    with pytest.raises(ConfigError, match=r'temperature_2_c must have shape \(4,\)'):
        fitted.chain.correct(np.zeros((4, 3)), np.zeros(4), np.zeros(3))
    parameters = fitted.chain.to_parameters()
    del parameters['sensitivity_slope_rad_s_per_c.y']
    with pytest.raises(ConfigError, match='sensitivity_slope_rad_s_per_c.y is missing'):
        CalibrationChain.from_parameters(parameters)
    parameters = {**fitted.chain.to_parameters(), 'misalignment': [1.0] * 8}
    with pytest.raises(ConfigError, match='misalignment needs 9 values'):
        CalibrationChain.from_parameters(parameters)
    parameters = {**fitted.chain.to_parameters(), 'offset_rad_s': [0.0, math.nan, 0.0]}
    with pytest.raises(ConfigError, match='offset_rad_s must be finite'):
        CalibrationChain.from_parameters(parameters)
    with pytest.raises(ConfigError, match='plateau_id must be integers'):
        fit(session, plateau_id=session.plateau_id.astype(float))
    with pytest.raises(ConfigError, match='nonlinearity_order must be >= 1'):
        settings_for(session, nonlinearity_order=0)
    with pytest.raises(ConfigError, match='min_temperature_span_c must be positive'):
        settings_for(session, min_temperature_span_c=0.0)
