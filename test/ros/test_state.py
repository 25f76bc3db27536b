"""
State files the compensation node cannot use, over DDS: refused, logged, moved aside.

Each case starts a compensation node (polynomial model) on the simulated driver with a
state file prepared as a user or a crash could leave it. A file that is damaged or holds
a wrong value is logged at ERROR with the reason and moved aside to ``*.bad-<stamp>``; a
whole file learned on another model is a WARN and stays; a leftover temporary file is
removed. Every compensated sample is then what the model gives without an offset, sample
by sample; a good file (the fingerprint an earlier release saved) still applies its offset.
"""

import math

from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.parameters.state_file import write_state
import numpy as np
import pytest
from ros_harness import (first_line_with, paired, simulated_driver_params, UNTRACKED,
                         write_params)
import yaml

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
SAMPLES = 100
MODEL = {'model': 'polynomial', 'polynomial.bias.z': [0.02, 0.001]}
GOOD_OFFSET_RAD_S = 0.01
# The fingerprint of MODEL as the node saved it when the polynomial model had a class of its
# own (commit 3765585): a state file saved then keeps its offset.
SAVED_FINGERPRINT = '8ac15105e9d77514'


def good_state() -> dict:
    """Give a state as the node saves it after a recalibration of MODEL."""
    return {'model': 'polynomial', 'fingerprint': SAVED_FINGERPRINT, 'axes': ['z'],
            'zro_offset': [GOOD_OFFSET_RAD_S], 'offset_unit': 'rad/s',
            'zro_offset_rad_s': [GOOD_OFFSET_RAD_S], 'temperature_c': 25.0, 'samples': 200,
            'time': '2026-11-25T12:00:00+00:00'}


def prepare(case: str, folder, state: dict) -> None:
    """Write the state file of ``case`` into ``folder`` (as zro.yaml, or beside it)."""
    path = folder / 'zro.yaml'
    if case == 'good':
        write_state(str(path), state)
    elif case == 'abc':
        write_state(str(path), {**state, 'zro_offset': ['abc']})
    elif case == '1e300':
        # zro_offset edited alone: the rad/s copy beside it still looks sane.
        write_state(str(path), {**state, 'zro_offset': [1.0e300]})
    elif case == 'truncated':
        text = yaml.safe_dump(state, sort_keys=False)
        path.write_text(text[:text.index('offset_unit')])
    elif case == 'another model':
        write_state(str(path), {**state, 'fingerprint': '0123456789abcdef'})
    elif case == 'leftover tmp':
        # A kill between the temporary file and the rename: a whole state, never renamed.
        (folder / '.zro.yaml.k1ll3d.tmp').write_text(yaml.safe_dump(state, sort_keys=False))


# case -> (level and text of the log line, files left in the folder, offset applied)
CASES = {
    'good': ('[INFO]', 'applied saved ZRO offset [0.01] rad/s from', ['zro.yaml'],
             GOOD_OFFSET_RAD_S),
    'abc': ('[ERROR]', "unusable: zro_offset[0] must be a number, got 'abc'; moved aside to",
            ['zro.yaml.bad-'], 0.0),
    '1e300': ('[ERROR]', 'unusable: zro_offset [1e+300] rad/s is beyond the full scale '
                         '+-34.91 rad/s (2000 deg/s); moved aside to', ['zro.yaml.bad-'], 0.0),
    'truncated': ('[ERROR]', 'unusable: damaged: offset_unit, zro_offset_rad_s, '
                             'temperature_c, samples, time missing (truncated?); moved aside '
                             'to', ['zro.yaml.bad-'], 0.0),
    'another model': ('[WARN]', 'is whole but was learned on another model (model '
                                "polynomial, axes ['z'], fingerprint 0123456789abcdef",
                      ['zro.yaml'], 0.0),
    'leftover tmp': ('[WARN]', 'removed 1 temporary file(s) an interrupted save of', [], 0.0),
}


def test_unusable_state_files_are_refused_and_the_node_compensates_without_them(
        launcher, probe, tmp_path):
    params_path = write_params(tmp_path / 'model.yaml', 'compensation_node', MODEL)
    model = build_model(node_values(params_path, 'compensation_node'))
    probe.subscribe_pipeline()
    launcher.driver(simulated_driver_params(**{'simulation.seed': 4,
                                               'simulation.rate_dps': [3.0]}))
    for case, (level, text, files, offset_rad_s) in CASES.items():
        folder = tmp_path / case.replace(' ', '_')
        folder.mkdir()
        prepare(case, folder, good_state())
        node = launcher.compensation(
            {**MODEL, 'recalibration.state_file': str(folder / 'zro.yaml'), **UNTRACKED},
            label=case)
        probe.wait_streaming(['imu/data'], TIMEOUT_S, launcher)
        probe.spin_until(lambda: len(paired(probe)[0]) >= SAMPLES, TIMEOUT_S,
                         f'{SAMPLES} compensated samples with their raw inputs', launcher)
        stamps, out, raw, temperature = paired(probe)
        node.stop()
        probe.wait_quiet(['imu/data'], 0.3, TIMEOUT_S, launcher)

        line = first_line_with(node.output(), text)
        assert line.startswith(level), f'{case}: {node.output()}'
        assert sorted(p.name[:len(f)] for p, f in zip(sorted(folder.iterdir()), files)) == \
            files and len(list(folder.iterdir())) == len(files), \
            f'{case}: {sorted(p.name for p in folder.iterdir())}'
        got = np.array([out[s].angular_velocity.z for s in stamps])
        expected = model.correct(
            np.array([[raw[s].angular_velocity.z] for s in stamps]),
            np.array([temperature[s].temperature for s in stamps])).rate_rad_s[:, 0]
        assert np.all(np.isfinite(got)), case
        assert got == pytest.approx(expected - offset_rad_s, rel=1e-12, abs=1e-15), case
        print(f'{case}: {len(stamps)} samples, mean {math.degrees(float(np.mean(got))):.4f} '
              f'deg/s; {line.split("]: ", 1)[-1]}')
        probe.clear()
