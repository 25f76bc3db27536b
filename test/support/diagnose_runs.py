"""What the diagnose tests share: the simulated device at 1 Hz, the CLI in-process, params.yaml."""

import contextlib
import io

from mlx_tempcomp.cli import main
from mlx_tempcomp.simulation.chamber import CHAMBER_ZRO_DPS, device_offsets
from mlx_tempcomp.simulation.physics import Effects, GyroTruth, Noise, Scenario
import numpy as np
import yaml

NOISE_DPS = 0.02
TEMPERATURE_NOISE_C = 0.02
QUIET = Noise(bias_instability_dps=0.0)


def device_run(effects: Effects, noise: Noise, scenario: Scenario, seed: int) -> tuple:
    """Return (time s, sensor temperature C, ZRO deg/s) of the device at 1 Hz, noiseless."""
    truth = GyroTruth(zro_dps_coefficients=CHAMBER_ZRO_DPS, effects=effects, noise=noise)
    time_s = np.arange(1.0, float(int(scenario.thermal.duration_s)) + 1.0)
    return (time_s, *device_offsets(truth, scenario, seed, time_s))


def run_cli(argv: list) -> tuple:
    """Run mlx-tempcomp in this process; give (stdout, stderr) (capsys is per test)."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main([str(arg) for arg in argv])
    assert code == 0, stderr.getvalue()
    return stdout.getvalue(), stderr.getvalue()


def parameters_of(out) -> dict:
    return yaml.safe_load((out / 'params.yaml').read_text())['compensation_node'][
        'ros__parameters']
