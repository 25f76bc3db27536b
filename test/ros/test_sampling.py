"""
Device-rate sampling: the driver reads the part at its own rate and publishes interval means.

The simulated ADIS16130 is sampled at its natural 5.7 kHz in real time and
published at 1 kHz over DDS, lossless (`simulation.lossless`): a driver that
falls behind lets its simulated clock lag instead of skipping samples, so
"every sample" is a property of the code, not of the machine's speed. The
driver is stopped (SIGSTOP) for longer than its backlog in the middle of the
run. A replica of the same simulated part (same parameters, same seed) read at
k / 5700 s for k = 0, 1, ... gives every device sample the driver read; each
published message must be, bit for bit, the mean of the samples of its
interval, stamped at their mean time: no sample is dropped, none counted twice.
Without lossless the same stall misses reads, which must raise a WARN (log and
diagnostics) while it happens.
"""

import re
import signal
import time

from diagnostic_msgs.msg import DiagnosticStatus
from mlx_tempcomp.parameters.driver import driver_settings, DRIVER_SPECS
from mlx_tempcomp.ros.driver.adis16130_stream import simulated_adis
from mlx_tempcomp.ros.driver.timed_stream import MAX_BACKLOG_S
from mlx_tempcomp.sources.decimation import Decimator
import numpy as np
import pytest
from ros_harness import (by_stamp, DRIVER_DIAGNOSTIC, first_line_with, rates,
                         simulated_driver_params, status_values)
from sensor_msgs.msg import Imu, Temperature

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
SAMPLE_RATE_HZ = 5700.0
PUBLISH_RATE_HZ = 1000.0
MESSAGES = 2000            # 2 s of simulated time
STALL_S = 2 * MAX_BACKLOG_S


def driver_values(overrides: dict) -> dict:
    """Every driver parameter value: the defaults with ``overrides``."""
    values = {spec.name: spec.initial_value for spec in DRIVER_SPECS}
    values.update(overrides)
    return values


def replica_intervals(values: dict, intervals: int) -> list:
    """Read a replica of the driver's part; give (mean rate, mean temperature, mean time s)."""
    source = simulated_adis(driver_settings(values))
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


def stall(driver) -> None:
    """Freeze the driver process for STALL_S (wall time), longer than its backlog."""
    driver.signal(signal.SIGSTOP)
    try:
        time.sleep(STALL_S)
    finally:
        driver.signal(signal.SIGCONT)


def adis_params(**overrides) -> dict:
    return simulated_driver_params(**{
        'device': 'adis16130', 'simulation.real_time_factor': 1.0,
        'publish_rate_hz': PUBLISH_RATE_HZ, 'sample_rate_hz': 0.0,   # natural: 5.7 kHz
        'simulation.rate_dps': [3.0], 'simulation.seed': 4, **overrides})


@pytest.mark.slow
def test_published_messages_are_the_means_of_every_device_sample(launcher, probe):
    overrides = adis_params(**{'simulation.lossless': True})
    imu = probe.subscribe(Imu, 'imu/data_raw')
    temperature = probe.subscribe(Temperature, 'imu/temperature_raw')
    probe.subscribe_diagnostics()
    driver = launcher.driver(overrides)
    probe.spin_until(lambda: len(imu) >= MESSAGES // 4, TIMEOUT_S, 'a first quarter',
                     launcher)
    stall(driver)
    probe.spin_until(lambda: len(imu) >= MESSAGES, TIMEOUT_S, f'{MESSAGES} messages', launcher)
    status = probe.wait_status(DRIVER_DIAGNOSTIC, lambda s: int(status_values(s)['messages'])
                               >= MESSAGES, TIMEOUT_S, 'the driver status', launcher)
    launcher.stop_all()
    probe.drain()
    values = status_values(status)
    assert float(values['sample_rate_hz']) == SAMPLE_RATE_HZ
    assert values['missed_reads'] == '0' and values['failed_reads'] == '0'
    assert values['samples_per_message'] in ('5', '6')
    # The whole run, up to the stop (the probe hears messages sent after that status).
    summary = re.search(r'sampling: (\d+) samples read, (\d+) missed, (\d+) failed, '
                        r'(\d+) saturated; (\d+) messages published', driver.output())
    assert summary, driver.output()
    assert summary.group(2, 3, 4) == ('0', '0', '0')

    received = by_stamp(imu)
    temperatures = by_stamp(temperature)
    stamps = sorted(received)
    published = int(summary.group(5))
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
    assert matched >= MESSAGES
    # What the probe hears of a best-effort stream depends on the load, not on the code.
    assert matched_temperatures >= MESSAGES // 2
    # Within noise, the published mean is the device's: 3 deg/s plus its bias.
    mean_dps = np.degrees(np.mean([rates(received[s])[2] for s in stamps]))
    bias_dps = driver_values(overrides)['simulation.bias_dps']
    assert mean_dps == pytest.approx(3.0 + bias_dps, abs=0.2)


def test_missed_reads_raise_a_warning_while_they_happen(launcher, probe):
    probe.subscribe(Imu, 'imu/data_raw')
    probe.subscribe_diagnostics()
    driver = launcher.driver(adis_params(**{'simulation.lossless': False}))
    probe.wait_streaming(['imu/data_raw'], TIMEOUT_S, launcher)
    stall(driver)
    status = probe.wait_status(DRIVER_DIAGNOSTIC, lambda s: s.level == DiagnosticStatus.WARN,
                               TIMEOUT_S, 'a WARN on missed reads', launcher)
    assert 'device reads missed since the last status' in status.message, status.message
    assert int(status_values(status)['missed_reads']) > 0
    probe.spin_until(lambda: 'device reads missed in the last 1 s' in driver.output(),
                     TIMEOUT_S, 'the WARN in the log', launcher)
    assert '[WARN]' in first_line_with(driver.output(), 'device reads missed')


def test_a_driver_waiting_for_its_subscriber_starts_its_clock_with_it(launcher, probe):
    # A 20 s soak at 25 C, then a ramp to 85 C: 2.6 s of wall time at 10 x.
    driver = launcher.driver(simulated_driver_params(**{
        'simulation.real_time_factor': 10.0, 'simulation.wait_for_subscriber': True,
        'simulation.start_temperature_c': 25.0, 'simulation.cycle_temperatures_c': [25.01, 85.0],
        'simulation.hold_s': 20.0, 'simulation.ramp_c_per_min': 600.0}))
    probe.spin_until(lambda: 'publishes /imu/data_raw' in driver.output(), TIMEOUT_S,
                     'the driver up', launcher)
    # Longer than the whole cycle in wall time: a clock that ran would be at 85 C by now.
    deadline = time.monotonic() + 4.0
    while time.monotonic() < deadline:
        probe.spin_once()
    assert 'the simulated clock starts' not in driver.output()
    temperature = probe.subscribe(Temperature, 'imu/temperature_raw')
    probe.subscribe(Imu, 'imu/data_raw')
    probe.spin_until(lambda: temperature, TIMEOUT_S, 'a temperature', launcher)
    assert 'subscriber present: the simulated clock starts' in driver.output()
    # The soak's (the sensed temperature reads about 1.4 C above the chamber's), not 85 C.
    assert temperature[0].temperature < 30.0, temperature[0].temperature
