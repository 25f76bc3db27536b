"""
The correction table any model may carry, and the node's parameters that give it (no ROS).

The table's interpolation is checked against what it must reproduce (a line, a knot's own
value, the held ends), block against row bit for bit; the corrected model against its base
model less the table, for a polynomial and for the eeprom model (whose ZRO shift is in
output units), and ``build_model`` against ``correction.*`` given whole, in part or wrong.
"""

import math

from mlx_tempcomp.core.effects import polynomial_model
from mlx_tempcomp.core.errors import ConfigError
from mlx_tempcomp.core.mlx90609.conversion import Output
from mlx_tempcomp.core.mlx90609.eeprom import EepromFields
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.core.mlx90609.table_compensation import table_compensation
from mlx_tempcomp.core.node_models.correction import CorrectedModel, CorrectionTable, knot_weights
from mlx_tempcomp.core.node_models.rate_models import EepromModel
from mlx_tempcomp.parameters.compensation import COMPENSATION_SPECS
from mlx_tempcomp.parameters.files import flat_parameters
from mlx_tempcomp.parameters.models import build_model, correction_of, MODEL_PREFIXES
from mlx_tempcomp.parameters.specs import ParameterError
import numpy as np
import pytest

KNOTS = (-10.0, 0.0, 10.0, 25.0, 40.0)
FIELDS = EepromFields(range_code=15, version=2, tc_mv=(1854, 2508, 3114),
                      ee_zro=(132, 133, 145), ee_sf=(120, 145, 133))


def test_the_weights_sum_to_one_and_a_line_is_reproduced_between_any_knots():
    temperature = np.linspace(-20.0, 50.0, 701)
    total = sum(weight for _, weight in knot_weights(KNOTS, temperature))
    assert np.allclose(total, 1.0, atol=1e-12)
    line = CorrectionTable(KNOTS, (tuple(2e-4 * t + 1e-3 for t in KNOTS),))
    held = np.clip(temperature, KNOTS[0], KNOTS[-1])
    assert np.allclose(line.at(0, temperature), 2e-4 * held + 1e-3, rtol=0, atol=1e-15)


def test_knots_give_their_values_and_the_ends_are_held():
    values = (1e-3, -2e-3, 5e-4, 0.0, 3e-3)
    table = CorrectionTable(KNOTS, (values,))
    assert [table.at(0, t) for t in KNOTS] == pytest.approx(values, abs=1e-18)
    assert table.at(0, -80.0) == values[0] and table.at(0, 120.0) == values[-1]
    assert math.isnan(table.at(0, math.nan))


def _same_bits(a, b) -> bool:
    """Tell whether two columns hold the same values, the sign of a zero included (not NaN's)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    number = ~np.isnan(a)
    return np.array_equal(a, b, equal_nan=True) and \
        np.array_equal(np.signbit(a[number]), np.signbit(b[number]))


def test_a_row_gives_the_bits_of_a_block():
    rng = np.random.default_rng(1)
    # Every knot, just below each (the end of an interval), the ends and beyond, NaN.
    temperature = np.concatenate([rng.uniform(-30.0, 60.0, 500), KNOTS,
                                  np.nextafter(KNOTS, -math.inf), [-math.inf, math.inf, math.nan]])
    tables = {'random': CorrectionTable(KNOTS, tuple(tuple(rng.normal(0.0, 1e-3, len(KNOTS)))
                                                     for _ in range(3))),
              'zeros': CorrectionTable.zero(KNOTS, 3),
              'negative zeros': CorrectionTable(KNOTS, ((-0.0,) * len(KNOTS),) * 3),
              'one knot': CorrectionTable.zero((25.0,), 3),
              'two knots': CorrectionTable((0.0, 10.0), ((1e-3, -2e-3),) * 3)}
    for name, table in tables.items():
        for axis in range(3):
            with np.errstate(invalid='ignore'):   # one knot: its weight at inf is NaN
                block = table.at(axis, temperature)
            rows = np.array([table.at(axis, float(t)) for t in temperature])
            assert _same_bits(block, rows), name
            assert _same_bits(block, [table.row(float(t))[axis] for t in temperature]), name


def test_a_table_of_positive_zeros_subtracts_nothing_at_any_temperature_but_nan():
    """The learner's table until its first renewal: its stream skips the row (bits unchanged)."""
    temperature = np.concatenate([np.linspace(-60.0, 100.0, 1601), KNOTS,
                                  np.nextafter(KNOTS, -math.inf), [-math.inf, math.inf]])
    rates = np.array([0.0, -0.0, 1e-3, -2e-3, 5e-324, math.inf, -math.inf, math.nan])
    zeros = CorrectionTable.zero(KNOTS, 2)
    assert zeros.subtracts_nothing and CorrectionTable.zero(KNOTS[:2], 1).subtracts_nothing
    for axis in range(2):
        for row in (zeros.at(axis, temperature),
                    [zeros.at(axis, float(t)) for t in temperature],
                    [zeros.row(float(t))[axis] for t in temperature]):
            row = np.asarray(row)
            assert np.all(row == 0.0) and not np.signbit(row).any()
            less = rates[:, None] - row[None, :]
            assert _same_bits(less, np.repeat(rates[:, None], row.size, axis=1))
    assert math.isnan(zeros.row(math.nan)[0])
    # -0.0 gives terms of either sign; one knot a NaN weight at an infinite temperature.
    negative = CorrectionTable(KNOTS, ((-0.0,) * len(KNOTS),))
    for table in (negative, CorrectionTable.zero((25.0,), 1),
                  CorrectionTable(KNOTS, ((0.0,) * 4 + (1e-9,),))):
        assert not table.subtracts_nothing


def test_a_table_is_checked_and_adds_on_its_knots():
    with pytest.raises(ConfigError, match='strictly increasing'):
        CorrectionTable((0.0, 0.0), ((0.0, 0.0),))
    with pytest.raises(ConfigError, match='needs 2 values'):
        CorrectionTable((0.0, 1.0), ((0.0,),))
    with pytest.raises(ConfigError, match='finite'):
        CorrectionTable((0.0, 1.0), ((0.0, math.inf),))
    a = CorrectionTable((0.0, 1.0), ((1.0, 2.0),))
    assert a.added(a).values_rad_s == ((2.0, 4.0),)
    with pytest.raises(ConfigError, match='same knots'):
        a.added(CorrectionTable((0.0, 2.0), ((1.0, 2.0),)))


def test_the_corrected_model_is_the_base_less_the_table_block_and_rows():
    base = polynomial_model(((1e-3, 2e-4), (0.0,)), temperature_min_c=-5.0,
                            temperature_max_c=45.0)
    table = CorrectionTable(KNOTS, ((1e-4, 2e-4, 0.0, -1e-4, 3e-4), (0.0, 0.0, 1e-3, 0.0, 0.0)))
    model = CorrectedModel(base, table)
    rng = np.random.default_rng(2)
    rate = rng.normal(0.0, 0.01, (200, 2))
    temperature = rng.uniform(-20.0, 60.0, 200)
    expected = base.correct(rate, temperature).rate_rad_s - table.columns(
        np.column_stack([temperature, temperature]))
    assert np.array_equal(model.correct(rate, temperature).rate_rad_s, expected)
    stream = model.stream()
    rows = [stream.correct_one(list(r), [t])[0]
            for r, t in zip(rate.tolist(), temperature.tolist())]
    assert np.array_equal(np.array(rows), expected)
    assert model.name == 'polynomial' and model.fingerprint() != base.fingerprint()


def test_a_zro_recalibration_zeroes_the_corrected_output_for_any_offset_unit():
    table = CorrectionTable(KNOTS, ((4e-3, 3e-3, 2e-3, 1e-3, 0.0),))
    compensation = table_compensation([factory_table(FIELDS, Output.DIGITAL)], 75.0,
                                      Output.DIGITAL)
    for base in (polynomial_model(((1e-3,),)), EepromModel(compensation)):
        model = CorrectedModel(base, table)
        temperature = np.linspace(5.0, 15.0, 100)
        rate = np.full((100, 1), 0.02)
        corrected = model.correct(rate, temperature).rate_rad_s
        offset = model.learn_zro_offset(rate, temperature, corrected)
        zeroed = model.with_zro_offset(offset).correct(rate, temperature).rate_rad_s
        assert abs(float(np.mean(zeroed))) < 1e-9, base.name


def values(**given) -> dict:
    result = {spec.name: spec.initial_value for spec in COMPENSATION_SPECS}
    result.update({'model': 'polynomial', 'axes': ['x', 'z'],
                   'polynomial.bias.x': [1e-3], 'polynomial.bias.z': [0.0]})
    result.update(given)
    return result


def test_build_model_takes_the_correction_off_any_model_it_builds():
    table = CorrectionTable((0.0, 50.0), ((1e-3, 2e-3), (0.0, -1e-3)))
    flat = flat_parameters(table.to_parameters(('x', 'z')))
    model = build_model(values(**flat))
    assert isinstance(model, CorrectedModel) and model.table == table
    assert correction_of(values()) is None and not isinstance(build_model(values()),
                                                              CorrectedModel)
    assert 'correction.' in MODEL_PREFIXES


@pytest.mark.parametrize('given, message', [
    ({'correction.temperature_c': [0.0, 50.0], 'correction.x_rad_s': [0.0, 1e-3]},
     'invalid parameter correction.z_rad_s: unset'),
    ({'correction.x_rad_s': [0.0], 'correction.z_rad_s': [0.0]},
     'invalid parameter correction.temperature_c: unset'),
    ({'correction.temperature_c': [0.0, 50.0], 'correction.x_rad_s': [0.0],
      'correction.z_rad_s': [0.0, 0.0]}, 'correction.x_rad_s: needs 2 values'),
    ({'correction.temperature_c': [50.0, 0.0], 'correction.x_rad_s': [0.0, 0.0],
      'correction.z_rad_s': [0.0, 0.0]}, 'strictly increasing'),
    ({'correction.temperature_c': [0.0, 50.0], 'correction.x_rad_s': [0.0, 1000.0],
      'correction.z_rad_s': [0.0, 0.0]}, 'axis x gives'),
])
def test_a_wrong_correction_is_refused_naming_it(given, message):
    with pytest.raises(ParameterError, match=message):
        build_model(values(**given))
