"""
Device-rate sampling: the driver reads the part at its own rate and publishes interval means.

The simulated ADIS16130 is sampled at its natural 5.7 kHz in real time and
published at 1 kHz over DDS. A replica of the same simulated part (same
parameters, same seed) read at k / 5700 s for k = 0, 1, ... gives every device
sample the driver read; each published message must be, bit for bit, the mean
of the samples of its interval, stamped at their mean time: no sample is
dropped, none counted twice.
"""

from mlx_tempcomp.node_parameters import DRIVER_SPECS
from mlx_tempcomp.ros.devices import simulated_adis
from mlx_tempcomp.sources.decimation import Decimator
import numpy as np
import pytest
from ros_harness import (by_stamp, DRIVER_DIAGNOSTIC, rates, simulated_driver_params,
                         status_values)
from sensor_msgs.msg import Imu, Temperature

pytestmark = pytest.mark.ros

TIMEOUT_S = 30.0
SAMPLE_RATE_HZ = 5700.0
PUBLISH_RATE_HZ = 1000.0
MESSAGES = 2000            # 2 s of real time


def driver_values(overrides: dict) -> dict:
    """Every driver parameter value: the defaults with ``overrides``."""
    values = {spec.name: spec.initial_value for spec in DRIVER_SPECS}
    values.update(overrides)
    return values


def replica_intervals(values: dict, intervals: int) -> list:
    """Read a replica of the driver's part; give (mean rate, mean temperature, mean time s)."""
    source = simulated_adis(values)
    start_s = source.clock.now_s
    decimator = Decimator(SAMPLE_RATE_HZ, PUBLISH_RATE_HZ)
    means, index = [], 0
    while len(means) < intervals:
        source.advance_to(start_s + index / SAMPLE_RATE_HZ)
        closed = decimator.add(index, source.read(values['oversample']))
        if closed is not None:
            assert closed.samples in (5, 6) and closed.number == len(means)
            means.append((float(closed.mean.rate_rad_s[0]), float(closed.mean.temperature_c[0]),
                          closed.time_s))
        index += 1
    return means


@pytest.mark.slow
def test_published_messages_are_the_means_of_every_device_sample(launcher, probe):
    overrides = simulated_driver_params(**{
        'device': 'adis16130', 'simulation.real_time_factor': 1.0,
        'publish_rate_hz': PUBLISH_RATE_HZ, 'sample_rate_hz': 0.0,   # natural: 5.7 kHz
        'simulation.rate_dps': [3.0], 'simulation.seed': 4})
    imu = probe.subscribe(Imu, 'imu/data_raw')
    temperature = probe.subscribe(Temperature, 'imu/temperature_raw')
    probe.subscribe_diagnostics()
    launcher.driver(overrides)
    probe.spin_until(lambda: len(imu) >= MESSAGES, TIMEOUT_S, f'{MESSAGES} messages', launcher)
    status = probe.wait_status(DRIVER_DIAGNOSTIC, lambda s: int(status_values(s)['messages'])
                               >= MESSAGES, TIMEOUT_S, 'the driver status', launcher)
    launcher.stop_all()
    probe.drain()
    values = status_values(status)
    assert float(values['sample_rate_hz']) == SAMPLE_RATE_HZ
    assert values['missed_reads'] == '0' and values['failed_reads'] == '0'
    assert values['samples_per_message'] in ('5', '6')

    received = by_stamp(imu)
    temperatures = by_stamp(temperature)
    stamps = sorted(received)
    published = int(values['messages'])
    means = replica_intervals(driver_values(overrides), published + 100)
    # The first message heard: the interval whose mean it is (the probe joined late).
    first = next(j for j, mean in enumerate(means) if mean[0] == rates(received[stamps[0]])[2])
    start_ns = stamps[0] - int(round(means[first][2] * 1e9))
    matched, matched_temperatures, number = 0, 0, first
    for stamp in stamps:
        # Each stamp names its interval: the mean time of its samples after the start.
        while abs(start_ns + means[number + 1][2] * 1e9 - stamp) < \
                abs(start_ns + means[number][2] * 1e9 - stamp):
            number += 1
        rate_rad_s, temperature_c, time_s = means[number]
        assert abs(start_ns + int(round(time_s * 1e9)) - stamp) <= 1
        assert rates(received[stamp])[2] == rate_rad_s
        # Best effort: a temperature may be lost on the way (the Imu was heard).
        if stamp in temperatures:
            assert temperatures[stamp].temperature == temperature_c
            matched_temperatures += 1
        matched += 1
    print(f'{matched} messages heard of {published} published (intervals {first} to '
          f'{first + matched - 1} seen), each the mean of its 5 or 6 device samples; '
          f'{matched_temperatures} temperatures')
    assert matched >= 0.9 * MESSAGES
    assert matched_temperatures >= 0.9 * MESSAGES
    # Within noise, the published mean is the device's: 3 deg/s plus its bias.
    mean_dps = np.degrees(np.mean([rates(received[s])[2] for s in stamps]))
    bias_dps = driver_values(overrides)['simulation.bias_dps']
    assert mean_dps == pytest.approx(3.0 + bias_dps, abs=0.2)
