"""
Per-row cost of the compensation node's models (`stream.correct_one`) beside a plain Python cubic.

The node corrects one message at a time through ``stream.correct_one`` when no
other message waits. Each model here is built from node parameters the way the
node builds it (`parameters.models.build_model`), then fed the same rows: 3 axes,
temperature rising 20 to 40 C, every input the model needs given. The
baseline is a plain Python Horner cubic of the polynomial model's coefficients,
the floor any model pays in Python. Rounds alternate over the models and the
baseline and the best of each is kept, because this machine is noisy. Each
model's rows are checked to equal ``correct_block`` on the same rows.

    .venv/bin/python bench/bench_model_row.py [--rows N] [--repeats R]

Set PYTHONPATH to another checkout to measure its models with this same script.
"""

import argparse
import math
import os
import tempfile
import time

from mlx_tempcomp.core.effects import AxisTerms, EffectModel
from mlx_tempcomp.core.mlx90609.conversion import Output
from mlx_tempcomp.core.mlx90609.eeprom import EepromFields
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.core.node_models.interface import ModelInputs
from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
import numpy as np
import yaml

AXES = ('x', 'y', 'z')
REFERENCE_C, SCALE_C = 21.17, 40.03
CUBIC = ((2.47e-3, -2.70e-3, 3.17e-3, 3.26e-4), (4.72e-3, 1.14e-2, 2.69e-3, -3.84e-3),
         (4.09e-3, -7.60e-3, -5.18e-4, -3.73e-3))
EEPROM = EepromFields(range_code=15, version=2, tc_mv=(1854, 2508, 3114),
                      ee_zro=(132, 133, 145), ee_sf=(120, 145, 133))


def _effects(history: bool) -> dict:
    """Give the effects model's node parameters: with history terms or with inputs only."""
    if history:
        extra = ({'thermal_lag_s': 20.0, 'gradient_time_constants_s': (15.0, 120.0),
                  'gradient_rad_s_per_c': (2e-4, -1e-4)},
                 {'temperature_rate_rad_s_per_c_s': 0.01, 'hysteresis_half_width_c': 1.0,
                  'hysteresis_rad_s': 3e-3},
                 {'thermal_lag_s': -10.0, 'gradient_time_constants_s': (40.0,),
                  'gradient_rad_s_per_c': (3e-4,)})
    else:
        extra = ({'secondary': (1e-3, 5e-4), 'scale': (0.01, 1e-3),
                  'cross_axis': (0.0, 0.01, 0.02)},
                 {'acceleration_rad_s_per_m_s2': (1e-4, 0.0, 2e-4),
                  'supply_voltage': (3e-3, -1e-3)},
                 {'nonlinearity': (0.01, 2e-3)})
    model = EffectModel(terms=tuple(AxisTerms(bias=bias, **terms)
                                    for bias, terms in zip(CUBIC, extra)),
                        reference_temperature_c=REFERENCE_C, temperature_scale_c=SCALE_C,
                        temperature_min_c=-20.0, temperature_max_c=60.0)
    return {f'effects.{key}': value for key, value in model.to_parameters(AXES).items()}


# A chain as its node parameters: a cubic nonlinearity, offsets with gradients, K and C
# polynomials in rate, a small misalignment.
CHAIN = {'full_scale_rad_s': 5.0, 'reference_temperature_c': 25.0,
         'reference_temperature_2_c': 30.0,
         'offset_rad_s': [2e-3, -1e-3, 5e-4], 'offset_gradient_rad_s_per_c': [1e-4, 2e-5, -3e-5],
         'offset_2_rad_s': [0.0, 1e-3, -2e-3], 'offset_2_gradient_rad_s_per_c': [0.0, 1e-4, 2e-4],
         'misalignment': [1.0, 1e-3, -2e-3, 5e-4, 1.0, 1e-3, -1e-3, 2e-3, 1.0],
         **{f'{name}.{axis}': coefficients for axis in AXES for name, coefficients in (
             ('nonlinearity_rad_s', [1e-3, 5.0, 2e-3, -1e-2]),
             ('sensitivity_slope_rad_s_per_c', [1e-5, 2e-4]),
             ('sensitivity_intercept_rad_s', [-2e-4, 1e-3]))}}


PARAMETERS = {
    'eeprom': {'model': 'eeprom'},
    'polynomial': {'model': 'polynomial', 'polynomial.reference_temperature_c': REFERENCE_C,
                   'polynomial.temperature_scale_c': SCALE_C,
                   'polynomial.temperature_min_c': -20.0, 'polynomial.temperature_max_c': 60.0,
                   **{f'polynomial.bias.{axis}': list(c) for axis, c in zip(AXES, CUBIC)}},
    'linear_btc': {'model': 'linear_btc', 'linear_btc.pbc_rad_s': [-3.5e-3, -5.6e-3, -3.9e-3],
                   'linear_btc.btc_rad_s_per_c': [6.3e-5, -2.3e-4, 2.5e-4],
                   'linear_btc.t3_c': 21.15},
    'effects, no history': {'model': 'effects', **_effects(history=False)},
    'effects, history': {'model': 'effects', **_effects(history=True)},
    'chain': {'model': 'chain', **{f'chain.{key}': value for key, value in CHAIN.items()}},
}


def _plain(value):
    """Give YAML-safe plain values: tuples as lists."""
    return [float(v) for v in value] if isinstance(value, (list, tuple)) else value


def build(name: str, folder: str):
    """Build a model from its parameters through a parameter file, as the node reads one."""
    path = os.path.join(folder, 'parameters.yaml')
    parameters = {'axes': list(AXES)}
    parameters.update({key: _plain(value) for key, value in PARAMETERS[name].items()})
    with open(path, 'w', encoding='utf-8') as stream:
        yaml.safe_dump({'compensation_node': {'ros__parameters': parameters}}, stream)
    values = node_values(path, 'compensation_node')
    tables = [factory_table(EEPROM, Output.DIGITAL)] * len(AXES)
    return build_model(values, tuple(tables), EEPROM.full_scale_dps)


def rows(count: int) -> tuple:
    """Give (rates, temperatures, inputs) lists of ``count`` rows, 1 kHz, 20 to 40 C."""
    rng = np.random.default_rng(0)
    time_s = 1e-3 * np.arange(count)
    temperature = np.linspace(20.0, 40.0, count) + rng.normal(0.0, 0.05, count)
    rates = rng.normal(0.0, 0.2, (count, len(AXES))).tolist()
    temperatures = temperature[:, None].tolist()
    acceleration = (np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.1, (count, 3))).tolist()
    inputs = [ModelInputs(time_s=t, temperature_2_c=t2, acceleration_m_s2=a, supply_voltage_v=v)
              for t, t2, a, v in zip(time_s.tolist(), (temperature + 5.0).tolist(),
                                     acceleration, (5.0 + 0.01 * temperature).tolist())]
    return rates, temperatures, inputs


def cubic_rows(rates, temperatures) -> list:
    """Correct rows as the baseline does: r - cubic(x) per axis, x = (T - Tref) / scale."""
    out = []
    for rate, (temperature,) in zip(rates, temperatures):
        x = (temperature - REFERENCE_C) / SCALE_C
        out.append([r - (c0 + x * (c1 + x * (c2 + x * c3)))
                    for r, (c0, c1, c2, c3) in zip(rate, CUBIC)])
    return out


def model_rows(model, rates, temperatures, inputs) -> list:
    correct_one = model.stream().correct_one
    return [correct_one(r, t, i)[0] for r, t, i in zip(rates, temperatures, inputs)]


def same_as_block(model, got, rates, temperatures, inputs) -> bool:
    """Whether the rows equal ``correct_block`` on all of them (NaN equal to NaN)."""
    columns = {name: np.array([getattr(i, name) for i in inputs]) for name in
               ('time_s', 'temperature_2_c', 'acceleration_m_s2', 'supply_voltage_v')}
    block = model.stream().correct_block(rates, temperatures, ModelInputs(**columns))
    return np.array_equal(np.array(got), block.rate_rad_s, equal_nan=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--rows', type=int, default=20000)
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args()

    data = rows(args.rows)
    with tempfile.TemporaryDirectory() as folder:
        models = {name: build(name, folder) for name in PARAMETERS}
    checks = {name: same_as_block(model, model_rows(model, *data), *data)
              for name, model in models.items()}
    best = dict.fromkeys(['plain Python cubic', *models], math.inf)
    for _ in range(args.repeats):
        start = time.perf_counter()
        cubic_rows(*data[:2])
        best['plain Python cubic'] = min(best['plain Python cubic'],
                                         time.perf_counter() - start)
        for name, model in models.items():
            start = time.perf_counter()
            model_rows(model, *data)
            best[name] = min(best[name], time.perf_counter() - start)

    print(f'stream.correct_one, {args.rows} rows x {len(AXES)} axes, best of {args.repeats} '
          'alternating rounds')
    print(f'  {"model":<22} {"us/row":>7} {"x cubic":>8}  rows = correct_block')
    floor = best['plain Python cubic']
    for name, seconds in best.items():
        check = '' if name not in checks else 'yes' if checks[name] else 'NO'
        print(f'  {name:<22} {seconds / args.rows * 1e6:7.2f} {seconds / floor:8.1f}  {check}')


if __name__ == '__main__':
    main()
