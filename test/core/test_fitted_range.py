"""
What each model the node runs does beyond the temperatures it was fitted on (docs/ros.md).

eeprom, polynomial and effects clamp the temperature at their range and flag
the sample: the correction is the one at the edge. linear_btc and chain hold
no range: the ADIS16130 note's line in T goes on along that line, and the
teslameter paper's stages (offset lines in T and T2, sensitivity K(x) dT) are
evaluated as they are, unflagged.
"""

from mlx_tempcomp.core.effects import AxisTerms, EffectModel, LinearBtc, polynomial_model
from mlx_tempcomp.core.mlx90609.conversion import Output, SensorTransfer
from mlx_tempcomp.core.mlx90609.eeprom import EepromFields
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.core.mlx90609.table_compensation import table_compensation
from mlx_tempcomp.core.node_models.chain import CalibrationChain, ChainModel
from mlx_tempcomp.core.node_models.interface import ModelInputs
from mlx_tempcomp.core.node_models.rate_models import EepromModel
import numpy as np

RATES_RAD_S = np.array([[0.2], [0.2], [0.2], [0.2]])


def assert_edge_value(model, beyond_c, edge_c, inputs=ModelInputs()) -> None:
    """Temperatures beyond the range give, flagged, what the edge gives unflagged."""
    rates = np.repeat(RATES_RAD_S, model.axes, axis=1)
    beyond = model.correct(rates, beyond_c, inputs)
    edge = model.correct(rates, edge_c, inputs)
    np.testing.assert_array_equal(beyond.rate_rad_s, edge.rate_rad_s)
    assert beyond.temperature_clamped.all()
    assert not edge.temperature_clamped.any()


def test_eeprom_model_holds_the_correction_of_the_table_ends():
    transfer = SensorTransfer()
    fields = EepromFields(range_code=15, version=2, tc_mv=(1854, 2508, 3114),
                          ee_zro=(132, 133, 145), ee_sf=(120, 145, 133))
    table = factory_table(fields, Output.DIGITAL, transfer)
    model = EepromModel(table_compensation([table], 75.0, Output.DIGITAL,
                                           transfer=transfer), transfer)
    # The table's TC0 and TC2 in degC, through the transfer the model converts with.
    tc0_c, tc2_c = (25.0 + (transfer.temperature_offset_mv + transfer.temperature_mv_per_lsb
                            * tempout - transfer.temperature_sensor_mv_at_25c)
                    / transfer.temperature_sensor_mv_per_k for tempout in (table.tc[0],
                                                                           table.tc[2]))
    assert_edge_value(model, [tc0_c - 30.0, tc0_c - 1.0, tc2_c + 1.0, tc2_c + 40.0],
                      [tc0_c, tc0_c, tc2_c, tc2_c])


def test_polynomial_model_holds_the_correction_of_its_range_ends():
    model = polynomial_model(((1e-3, 2e-3, -4e-4, 5e-5),), reference_temperature_c=20.0,
                             temperature_scale_c=30.0, scale_coefficients=((0.01, -0.02),),
                             temperature_min_c=-10.0, temperature_max_c=50.0)
    assert_edge_value(model, [-40.0, -10.5, 50.5, 90.0], [-10.0, -10.0, 50.0, 50.0])


def test_effects_model_holds_the_correction_at_the_edge_of_its_effective_temperature():
    # A cubic, a scale factor and the thermal lag T_eff = T + lag dT/dt: T_eff is clamped.
    model = EffectModel(terms=(AxisTerms(bias=(1e-3, 2e-3, -4e-4, 5e-5), thermal_lag_s=100.0,
                                         scale=(0.01, -0.02)),),
                        reference_temperature_c=20.0, temperature_scale_c=30.0,
                        temperature_min_c=-10.0, temperature_max_c=50.0)
    # Held temperatures: dT/dt 0 at every sample (each batch starts afresh), so T_eff = T.
    for beyond_c, edge_c in ((-40.0, -10.0), (50.5, 50.0)):
        inputs = ModelInputs(time_s=np.arange(4.0))
        assert_edge_value(model, [beyond_c] * 4, [edge_c] * 4, inputs)
    # Warming at 0.1 C/s from 45 C: T_eff = T + 100 s x 0.1 C/s passes 50 C before T does.
    time_s = np.arange(0.0, 61.0)
    temperature_c = 45.0 + 0.1 * time_s
    result = model.correct(np.full((time_s.size, 1), 0.2), temperature_c,
                           ModelInputs(time_s=time_s))
    clamped = result.temperature_clamped[:, 0]
    assert clamped.any() and not clamped[0] and (temperature_c[clamped] < 50.0).any()
    np.testing.assert_array_equal(result.rate_rad_s[clamped],
                                  np.full((clamped.sum(), 1), result.rate_rad_s[-1, 0]))


def test_linear_btc_continues_its_line_unflagged():
    model = LinearBtc(pbc_rad_s=(0.01,), btc_rad_s_per_c=(2e-4,), t3_c=25.0).model()
    temperature_c = np.array([-60.0, 25.0, 150.0, 400.0])
    result = model.correct(np.zeros((4, 1)), temperature_c)
    np.testing.assert_allclose(result.rate_rad_s[:, 0], 0.01 + (temperature_c - 25.0) * 2e-4,
                               rtol=1e-12)
    assert not result.temperature_clamped.any()


def test_chain_evaluates_its_stages_beyond_any_temperature_unflagged():
    zeros = (0.0, 0.0, 0.0)
    chain = CalibrationChain(
        full_scale_rad_s=5.0, reference_temperature_c=25.0, reference_temperature_2_c=30.0,
        nonlinearity_rad_s=tuple((0.0, 5.0) for _ in range(3)), offset_rad_s=(1e-3,) * 3,
        offset_gradient_rad_s_per_c=(2e-4, -1e-4, 3e-5),
        sensitivity_slope_rad_s_per_c=((0.0, 1e-3),) * 3,
        sensitivity_intercept_rad_s=((0.0,),) * 3, offset_2_rad_s=zeros,
        offset_2_gradient_rad_s_per_c=(1e-5,) * 3,
        misalignment=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))
    model = ChainModel(chain)
    temperature_c = np.array([-100.0, 25.0, 150.0, 300.0])
    result = model.correct(np.zeros((4, 3)), temperature_c,
                           ModelInputs(temperature_2_c=np.full(4, 30.0)))
    # At zero rate: the offset line y2 = -(b + g dT), then the sensitivity stage
    # y3 = y2 - K(y2 / FS) dT with K(x) = 1e-3 x; no temperature is held anywhere.
    delta_c = (temperature_c - 25.0)[:, None]
    offset = -(1e-3 + delta_c * np.array([2e-4, -1e-4, 3e-5]))
    expected = offset * (1.0 - 1e-3 * delta_c / 5.0)
    np.testing.assert_allclose(result.rate_rad_s, expected, rtol=1e-12, atol=1e-15)
    assert not result.temperature_clamped.any()
