from mlx_tempcomp.core.errors import ConfigError
from mlx_tempcomp.core.mlx90609.conversion import Output, SensorTransfer
from mlx_tempcomp.core.mlx90609.eeprom import EepromFields
from mlx_tempcomp.core.mlx90609.factory_table import factory_table, FactoryTable
from mlx_tempcomp.core.mlx90609.interpolation import interpolate, Interpolation
from mlx_tempcomp.core.mlx90609.table_compensation import NominalConversion, table_compensation
from mlx_tempcomp.core.series.metrics import ErrorStatistics
import numpy as np
import pytest

FIELDS = EepromFields(range_code=15, version=2, tc_mv=(1854, 2508, 3114),
                      ee_zro=(132, 133, 145), ee_sf=(120, 145, 133))


def lagrange(tc, values, x):
    x = np.asarray(x, dtype=float)
    total = np.zeros_like(x)
    for i in range(3):
        term = np.full_like(x, values[i])
        for j in range(3):
            if j != i:
                term *= (x - tc[j]) / (tc[i] - tc[j])
        total += term
    return total


def synthesize(table, rate_dps, tempout):
    """OUTAR = ZRO(T) + SF(T) x Q, evaluated independently of the compensator."""
    return lagrange(table.tc, table.zro, tempout) + lagrange(table.tc, table.sf, tempout) \
        * rate_dps


def test_nominal_conversion_is_an2_method_1():
    nominal = NominalConversion.for_range(75.0, Output.DIGITAL)
    assert (nominal.zro, nominal.sf) == pytest.approx((1008.0, 12.8))
    result = nominal.compensate([1008.0, 1008.0 + 128.0, 880.0], [1400.0] * 3)
    np.testing.assert_allclose(result.rate_dps, [0.0, 10.0, -10.0], atol=1e-12)
    np.testing.assert_allclose(result.rate_rad_s, np.deg2rad([0.0, 10.0, -10.0]), atol=1e-12)
    analog = NominalConversion.for_range(150.0, Output.ANALOG)
    assert (analog.zro, analog.sf) == pytest.approx((2500.0, 2000.0 / 150.0))


@pytest.mark.parametrize('samples', [1, 7, 16384, 40001])
def test_table_compensation_inverts_the_table(samples):
    table = factory_table(FIELDS, Output.DIGITAL)
    rng = np.random.default_rng(samples)
    tempout = rng.uniform(table.tc[0], table.tc[2], samples)
    rate = rng.uniform(-70.0, 70.0, samples)
    compensation = table_compensation([table], 75.0, Output.DIGITAL)
    result = compensation.compensate(synthesize(table, rate, tempout), tempout)
    np.testing.assert_allclose(result.rate_dps, rate, atol=1e-9)
    assert not result.temperature_clamped.any()


def test_out_of_range_temperature_is_clamped_and_flagged():
    table = factory_table(FIELDS, Output.DIGITAL)
    compensation = table_compensation([table], 75.0, Output.DIGITAL)
    low, high = table.tc[0], table.tc[2]
    tempout = np.array([low - 80.0, low, 0.5 * (low + high), high, high + 80.0, np.nan])
    outar = synthesize(table, 5.0, np.clip(tempout, low, high))
    result = compensation.compensate(outar, tempout)
    # Clamped samples use the edge triplet's ZRO and SF, not an extrapolation.
    np.testing.assert_allclose(result.rate_dps[:5], 5.0, atol=1e-9)
    assert np.isnan(result.rate_dps[5])
    assert result.temperature_clamped.tolist() == [True, False, False, False, True, True]


@pytest.mark.parametrize('method', list(Interpolation))
def test_every_interpolation_method_compensates_its_own_curve(method):
    table = factory_table(FIELDS, Output.ANALOG)
    tempout = np.linspace(table.tc[0] - 20.0, table.tc[2] + 20.0, 301)
    clamped = np.clip(tempout, table.tc[0], table.tc[2])
    outar = interpolate(method, table.tc, table.zro, clamped) + \
        interpolate(method, table.tc, table.sf, clamped) * -12.5
    compensation = table_compensation([table], 75.0, Output.ANALOG, interpolation=method)
    result = compensation.compensate(outar, tempout)
    np.testing.assert_allclose(result.rate_dps, -12.5, atol=1e-9)
    assert result.temperature_clamped.sum() == np.count_nonzero(clamped != tempout)


def test_digital_and_analog_outputs_give_the_same_rate():
    transfer = SensorTransfer()
    digital = table_compensation([factory_table(FIELDS, Output.DIGITAL)], 75.0, Output.DIGITAL)
    analog = table_compensation([factory_table(FIELDS, Output.ANALOG)], 75.0, Output.ANALOG)
    rng = np.random.default_rng(3)
    rate_code = rng.uniform(100.0, 1900.0, 1000)
    temperature_code = rng.uniform(1000.0, 1790.0, 1000)
    from_codes = digital.compensate(rate_code, temperature_code).rate_dps
    from_mv = analog.compensate(transfer.rate_lsb_to_mv(rate_code),
                                transfer.temperature_lsb_to_mv(temperature_code)).rate_dps
    np.testing.assert_allclose(from_codes, from_mv, rtol=1e-9, atol=1e-9)


def test_three_axes_one_without_table():
    tables = [factory_table(FIELDS, Output.DIGITAL), None,
              FactoryTable(Output.DIGITAL, tc=(1000.0, 1400.0, 1800.0),
                           zro=(990.0, 1008.0, 1030.0), sf=(12.5, 12.8, 13.1))]
    compensation = table_compensation(tables, 75.0, Output.DIGITAL)
    tempout = np.linspace(1000.0, 1800.0, 50)
    rate = np.column_stack([np.full(50, 1.0), np.full(50, -2.0), np.full(50, 3.0)])
    outar = np.column_stack([synthesize(tables[0], 1.0, tempout),
                             1008.0 + 12.8 * -2.0 + np.zeros(50),
                             synthesize(tables[2], 3.0, tempout)])
    shared = compensation.compensate(outar, tempout)
    per_axis = compensation.compensate(outar, np.column_stack([tempout] * 3))
    np.testing.assert_allclose(shared.rate_dps, rate, atol=1e-9)
    np.testing.assert_allclose(per_axis.rate_dps, rate, atol=1e-9)
    assert shared.rate_dps.shape == (50, 3)


def test_zro_shift_learned_at_rest_is_added_to_formula_4():
    table = factory_table(FIELDS, Output.DIGITAL)
    compensation = table_compensation([table], 75.0, Output.DIGITAL)
    tempout = np.linspace(1300.0, 1320.0, 200)
    supply_shift_lsb = 3.2  # the supply moved the ZRO by about 0.25 deg/s
    at_rest = synthesize(table, 0.0, tempout) + supply_shift_lsb
    assert compensation.compensate(at_rest, tempout).rate_dps.mean() == \
        pytest.approx(0.25, rel=0.01)
    shift = compensation.learn_zro_shift(at_rest, tempout)
    np.testing.assert_allclose(shift, [supply_shift_lsb])
    shifted = compensation.with_zro_shift(shift)
    np.testing.assert_allclose(shifted.compensate(at_rest, tempout).rate_dps, 0.0, atol=1e-9)
    # Learning again on the shifted model gives the same total, never a double count.
    np.testing.assert_allclose(shifted.learn_zro_shift(at_rest, tempout), shift)
    moving = synthesize(table, 20.0, tempout) + supply_shift_lsb
    np.testing.assert_allclose(shifted.compensate(moving, tempout).rate_dps, 20.0, atol=1e-9)


def test_shape_and_model_errors_name_the_problem():
    table = factory_table(FIELDS, Output.DIGITAL)
    compensation = table_compensation([table, table], 75.0, Output.DIGITAL)
    with pytest.raises(ConfigError, match=r'shape \(samples, 2\), got \(10, 3\)'):
        compensation.compensate(np.zeros((10, 3)), np.zeros(10))
    with pytest.raises(ConfigError, match='TEMPOUT shape'):
        compensation.compensate(np.zeros((10, 2)), np.zeros((9, 2)))
    with pytest.raises(ConfigError, match='zro_shift needs 2 values, got 1'):
        table_compensation([table, table], 75.0, Output.DIGITAL, zro_shift=(1.0,))
    with pytest.raises(ConfigError, match='analog output'):
        table_compensation([factory_table(FIELDS, Output.ANALOG)], 75.0, Output.DIGITAL)
    with pytest.raises(ConfigError, match='one to three axes'):
        table_compensation([table] * 4, 75.0, Output.DIGITAL)
    with pytest.raises(ConfigError, match='no readings'):
        compensation.learn_zro_shift(np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(ConfigError, match='scale factors must be positive'):
        FactoryTable(Output.DIGITAL, tc=(1.0, 2.0, 3.0), zro=(0.0, 0.0, 0.0),
                     sf=(1.0, -1.0, 1.0))


def test_error_statistics():
    stats = ErrorStatistics.of([1.0, -3.0, 2.0, np.nan])
    assert stats.samples == 3
    assert stats.mean == pytest.approx(0.0)
    assert stats.peak == 3.0
    assert stats.rms == pytest.approx(np.sqrt(14.0 / 3.0))
    assert stats.sigma == pytest.approx(np.sqrt(14.0 / 3.0))
    with pytest.raises(ConfigError, match='no finite samples'):
        ErrorStatistics.of([np.nan])
