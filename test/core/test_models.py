import math

from mlx_tempcomp.core.effects import AxisTerms, EffectModel, LinearBtc, polynomial_model
from mlx_tempcomp.core.errors import ConfigError
from mlx_tempcomp.core.mlx90609.conversion import Output, SensorTransfer
from mlx_tempcomp.core.mlx90609.eeprom import EepromFields
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.core.mlx90609.interpolation import Interpolation
from mlx_tempcomp.core.mlx90609.table_compensation import table_compensation
from mlx_tempcomp.core.node_models.interface import (CompensationModel, INPUTS, ModelInputs,
                                                     ModelStream)
from mlx_tempcomp.core.node_models.rate_models import EepromModel, RateOnlyModel
import numpy as np
import pytest

FIELDS = EepromFields(range_code=15, version=2, tc_mv=(1854, 2508, 3114),
                      ee_zro=(132, 133, 145), ee_sf=(120, 145, 133))


def test_polynomial_model_removes_its_bias_and_scale():
    model = polynomial_model(((1e-3, 2e-4, -3e-6),), reference_temperature_c=25.0,
                             temperature_scale_c=10.0, scale_coefficients=((0.01, 1e-3),))
    temperature = np.linspace(-20.0, 60.0, 9)
    x = (temperature - 25.0) / 10.0
    true_rate = 0.5
    bias = 1e-3 + 2e-4 * x - 3e-6 * x ** 2
    raw = true_rate * (1.0 + 0.01 + 1e-3 * x) + bias
    corrected = model.correct(raw, temperature)
    np.testing.assert_allclose(corrected.rate_rad_s[:, 0], true_rate, atol=1e-15)
    assert not corrected.temperature_clamped.any()


def test_polynomial_model_clamps_outside_its_range():
    model = polynomial_model(((0.0, 1e-3),), temperature_min_c=0.0, temperature_max_c=50.0)
    corrected = model.correct(np.zeros(3), np.array([-10.0, 20.0, 70.0]))
    # Clamped to 0 and 50 C: x = -25 and +25 around the default 25 C reference.
    np.testing.assert_allclose(corrected.rate_rad_s[:, 0], [0.025, 0.005, -0.025])
    assert corrected.temperature_clamped[:, 0].tolist() == [True, False, True]


def test_linear_btc_reproduces_table_6_of_the_adis16130_note():
    # Bias slope 0.04 deg/s/C: BTC = -0.04 deg/s/C, so +0.12 C gives -0.0048 deg/s.
    btc = math.radians(-0.04)
    model = LinearBtc(pbc_rad_s=(0.0,), btc_rad_s_per_c=(btc,), t3_c=30.0).model()
    steps = np.array([0.12, 0.10, 0.02, 0.0, -0.02, -0.12])
    corrected = model.correct(np.zeros(len(steps)), 30.0 + steps)
    np.testing.assert_allclose(np.degrees(corrected.rate_rad_s[:, 0]),
                               [-0.0048, -0.0040, -0.0008, 0.0, 0.0008, 0.0048], atol=1e-12)
    with_pbc = LinearBtc(pbc_rad_s=(-0.01,), btc_rad_s_per_c=(btc,), t3_c=30.0).model()
    np.testing.assert_allclose(with_pbc.correct([0.01], [30.0]).rate_rad_s, [[0.0]])


@pytest.mark.parametrize('output', list(Output))
def test_eeprom_model_on_nominal_rate_equals_table_compensation_on_codes(output):
    transfer = SensorTransfer()
    table = factory_table(FIELDS, output, transfer)
    compensation = table_compensation([table], 75.0, output, transfer=transfer)
    model = EepromModel(compensation, transfer)
    rng = np.random.default_rng(1)
    codes = rng.uniform(900.0, 1100.0, 200)
    temperature_codes = rng.uniform(1000.0, 1790.0, 200)
    if output is Output.ANALOG:
        outar, tempout = transfer.rate_lsb_to_mv(codes), transfer.temperature_lsb_to_mv(
            temperature_codes)
    else:
        outar, tempout = codes, temperature_codes
    # What the driver publishes: nominal rate (rad/s) and the typical sensed temperature.
    nominal = compensation.nominal
    raw_rad_s = np.radians((outar - nominal.zro) / nominal.sf)
    mv = tempout if output is Output.ANALOG else transfer.temperature_lsb_to_mv(tempout)
    temperature_c = transfer.temperature_c_from_mv(mv)
    expected = np.radians(compensation.compensate(outar, tempout).rate_dps)
    np.testing.assert_allclose(model.correct(raw_rad_s, temperature_c).rate_rad_s[:, 0],
                               expected, rtol=0, atol=1e-12)


def test_learned_offsets_zero_the_rest_window_without_double_counting():
    table = factory_table(FIELDS, Output.DIGITAL)
    eeprom = EepromModel(table_compensation([table], 75.0, Output.DIGITAL))
    polynomial = polynomial_model(((1e-3, 1e-5),))
    btc = LinearBtc(pbc_rad_s=(0.0,), btc_rad_s_per_c=(1e-5,), t3_c=25.0).model()
    temperature = np.full(100, 31.0)
    raw = np.full(100, 0.004) + np.random.default_rng(0).normal(0.0, 1e-4, 100)
    for model in (eeprom, polynomial, btc):
        offset = model.learn_zro_offset(raw, temperature,
                                        model.correct(raw, temperature).rate_rad_s)
        shifted = model.with_zro_offset(offset)
        residual = shifted.correct(raw, temperature).rate_rad_s.mean()
        assert residual == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose(shifted.learn_zro_offset(
            raw, temperature, shifted.correct(raw, temperature).rate_rad_s), offset)
        assert shifted.fingerprint() == model.fingerprint()
        np.testing.assert_allclose(shifted.offset_rad_s(31.0),
                                   model.correct(raw, temperature).rate_rad_s.mean(axis=0),
                                   rtol=1e-9)
    assert eeprom.offset_unit == 'LSB' and polynomial.offset_unit == 'rad/s'


def test_fingerprint_changes_with_coefficients():
    a = polynomial_model(((1e-3, 1e-5),))
    b = polynomial_model(((1e-3, 2e-5),))
    assert a.fingerprint() != b.fingerprint()
    assert a.fingerprint() == polynomial_model(((1e-3, 1e-5),)).fingerprint()


def test_models_refuse_bad_coefficients():
    with pytest.raises(ConfigError, match='bias coefficients of axis y'):
        polynomial_model(((1.0,), ()))
    with pytest.raises(ConfigError, match='scale coefficients given for 1 axes, bias for 2'):
        polynomial_model(((1.0,), (1.0,)), scale_coefficients=((0.0,),))
    with pytest.raises(ConfigError, match='linear_btc.btc needs 2 values'):
        LinearBtc(pbc_rad_s=(0.0, 0.0), btc_rad_s_per_c=(0.0,), t3_c=25.0).model()
    with pytest.raises(ConfigError, match=r'rate must have shape \(samples, 1\)'):
        polynomial_model(((1.0,),)).correct(np.zeros((4, 2)), np.zeros(4))
    with pytest.raises(ConfigError, match='must be finite'):
        polynomial_model(((1.0,),)).with_zro_offset([math.nan])


@pytest.mark.parametrize('interpolation', ['quadratic', 'step'])
def test_stream_rows_one_by_one_equal_the_array_path(interpolation):
    table = factory_table(FIELDS, Output.DIGITAL)
    tables = [table, None, table]
    compensation = table_compensation(tables, 75.0, Output.DIGITAL,
                                      Interpolation(interpolation), zro_shift=(0.5, 1.0, -2.0))
    eeprom = EepromModel(compensation)
    polynomial = polynomial_model(((1e-3, 1e-5),) * 3, temperature_min_c=-10.0,
                                  temperature_max_c=60.0)
    btc = LinearBtc(pbc_rad_s=(1e-3,) * 3, btc_rad_s_per_c=(1e-5,) * 3, t3_c=25.0).model()
    rng = np.random.default_rng(2)
    rates = rng.normal(0.0, 0.5, (300, 3))
    temperatures = np.column_stack([rng.uniform(-60.0, 100.0, 300)] * 3)
    temperatures[0, :] = np.nan
    for model in (eeprom, polynomial, btc):
        expected = model.correct(rates, temperatures)
        stream = model.stream()
        for i in range(300):
            result = stream.correct_block(rates[i:i + 1], temperatures[i:i + 1])
            np.testing.assert_array_equal(result.rate_rad_s[0], expected.rate_rad_s[i])
            np.testing.assert_array_equal(result.temperature_clamped[0],
                                          expected.temperature_clamped[i])
        shared = stream.correct_block(rates[1:2], temperatures[1:2, :1]).rate_rad_s[0]
        np.testing.assert_array_equal(shared, model.correct(rates[1:2], temperatures[1:2, 0])
                                      .rate_rad_s[0])


@pytest.mark.parametrize('interpolation', ['quadratic', 'step'])
def test_one_row_gives_the_block_bits(interpolation):
    """The node's per-message path (plain floats) and its block path agree bit for bit."""
    table = factory_table(FIELDS, Output.DIGITAL)
    compensation = table_compensation([table, None, table], 75.0, Output.DIGITAL,
                                      Interpolation(interpolation), zro_shift=(0.5, 1.0, -2.0))
    rng = np.random.default_rng(5)
    rates = rng.normal(0.0, 0.5, (300, 3))
    temperatures = rng.uniform(-60.0, 100.0, (300, 3))
    temperatures[0, 1] = np.nan
    for model in (EepromModel(compensation),
                  polynomial_model(((1e-3, 1e-5),) * 3)):
        stream = model.stream()
        for shared in (False, True):
            columns = temperatures[:, :1] if shared else temperatures
            block = stream.correct_block(rates, columns)
            for i in range(300):
                rate, clamped = stream.correct_one(rates[i].tolist(), columns[i].tolist())
                np.testing.assert_array_equal(rate, block.rate_rad_s[i])
                assert clamped == bool(block.temperature_clamped[i].any())


def test_every_model_the_node_runs_has_the_model_interface():
    table = factory_table(FIELDS, Output.DIGITAL)
    models = (EepromModel(table_compensation([table], 75.0, Output.DIGITAL)),
              polynomial_model(((1e-3, 1e-5),)),
              LinearBtc(pbc_rad_s=(1e-3,), btc_rad_s_per_c=(1e-5,), t3_c=25.0).model(),
              EffectModel(terms=(AxisTerms(bias=(1e-3,), secondary=(1e-4,)),)))
    for model in models:
        assert isinstance(model, CompensationModel), model.name
        assert isinstance(model.stream(), ModelStream), model.name
        assert model.inputs <= set(INPUTS), model.name
    assert models[3].inputs == {'temperature_2_c'}
    # A stateless model takes the inputs every model takes, and ignores them.
    given = ModelInputs(time_s=[0.0], temperature_2_c=[30.0])
    for model in models[:3]:
        assert model.inputs == frozenset()
        np.testing.assert_array_equal(model.stream().correct_block([[0.1]], [30.0], given)
                                      .rate_rad_s, model.correct([[0.1]], [30.0]).rate_rad_s)


def test_the_rate_only_takes_the_offset_off_whatever_the_temperature():
    """No temperature model (the node without a temperature): the raw rate less the offset."""
    model = RateOnlyModel(2)
    assert isinstance(model, CompensationModel) and isinstance(model.stream(), ModelStream)
    assert model.inputs == frozenset() and model.zro_offset == (0.0, 0.0)
    raw = np.array([[0.1, -0.2], [0.3, 0.4]])
    nan = np.full((2, 1), math.nan)
    corrected = model.correct(raw, nan)
    np.testing.assert_array_equal(corrected.rate_rad_s, raw)
    assert not corrected.temperature_clamped.any()
    offset = model.learn_zro_offset(raw, nan, raw)
    np.testing.assert_allclose(offset, [0.2, 0.1])
    shifted = model.with_zro_offset(offset)
    assert shifted.fingerprint() == model.fingerprint() != RateOnlyModel(1).fingerprint()
    block = shifted.stream().correct_block(raw, nan).rate_rad_s
    np.testing.assert_array_equal(block, raw - offset)
    for row, expected in zip(raw.tolist(), block.tolist()):
        assert shifted.stream().correct_one(row, [math.nan]) == (expected, False)
    with pytest.raises(ConfigError):
        model.with_zro_offset([math.inf, 0.0])
