"""What the device node tests share: the simulated MPU-6000, the gyro mean after a change."""

from mlx_tempcomp.simulation.mpu6000 import MpuTruth
import numpy as np
from ros_harness import by_stamp, rates

SEED = 4
TIMEOUT_S = 60.0


def mpu_truth(seed: int = SEED) -> MpuTruth:
    """Return the part the driver simulates for ``seed`` (same draw)."""
    return MpuTruth.random(np.random.default_rng(seed))


def gyro_mean_after_change_dps(launcher, probe, old_dps, samples: int = 200) -> np.ndarray:
    """
    Return the mean raw rate of the ``samples`` samples after the last one near ``old_dps``.

    Samples published before the registers changed may still be on their way to the probe
    (on a loaded machine it lags the stream): they are told apart by value, the old level
    being degrees per second from the new one (near 0).
    """
    probe.clear()

    def after() -> np.ndarray:
        msgs = by_stamp(probe.received['imu/data_raw'])
        dps = np.degrees(np.array([rates(msgs[s]) for s in sorted(msgs)]).reshape(-1, 3))
        old = np.linalg.norm(dps - old_dps, axis=1) < np.linalg.norm(dps, axis=1)
        start = int(np.flatnonzero(old)[-1]) + 1 if old.any() else 0
        return dps[start:start + samples]

    probe.spin_until(lambda: len(after()) >= samples, TIMEOUT_S,
                     f'{samples} samples after the registers changed', launcher)
    return after().mean(axis=0)
