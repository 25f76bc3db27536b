"""
SPI faults of the simulated MLX90609, switched at runtime: the driver keeps running.

While the device refuses or stays silent, the driver reports ERROR with rising
counters and publishes nothing, the compensation node reports stale input; both
recover when the fault clears.
"""

from diagnostic_msgs.msg import DiagnosticStatus
import pytest
from ros_harness import (COMPENSATION_DIAGNOSTIC, DRIVER_DIAGNOSTIC, simulated_driver_params,
                         status_values)

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
# The counter each fault raises, and what the driver's error message says about it.
FAULTS = {
    'refuse': ('refusals', 'refused'),
    'silent_low': ('silent_bus', 'answered 0x0000: MISO stuck low, bus silent'),
    'silent_high': ('silent_bus', 'answered 0xFFFF: MISO stuck high, bus silent'),
    'no_eoc': ('eoc_timeouts', 'conversion: no EOC after'),
}


def start_pipeline(launcher, probe, tmp_path) -> None:
    probe.subscribe_pipeline()
    launcher.driver(simulated_driver_params())
    launcher.compensation({'recalibration.state_file': str(tmp_path / 'zro.yaml'),
                           'stale_timeout_s': 0.5})
    probe.wait_status(COMPENSATION_DIAGNOSTIC, lambda s: s.level == DiagnosticStatus.OK,
                      TIMEOUT_S, 'compensation OK', launcher)
    probe.wait_streaming(['imu/data_raw', 'imu/data'], TIMEOUT_S, launcher)


def set_fault(probe, fault: str) -> None:
    results = probe.set_parameters('driver_node', {'simulation.fault': fault})
    assert [r.successful for r in results] == [True], results[0].reason


def driver_counter(status, counter: str) -> int:
    return int(status_values(status)[counter])


def check_fault(launcher, probe, fault: str) -> None:
    """Switch ``fault`` on: ERROR, counters rising, no stream, stale compensation; then off."""
    counter, says = FAULTS[fault]
    set_fault(probe, fault)
    first = probe.wait_status(
        DRIVER_DIAGNOSTIC, lambda s: s.level == DiagnosticStatus.ERROR and
        driver_counter(s, counter) > 0, TIMEOUT_S, f'driver ERROR under {fault}', launcher)
    assert first.message.startswith('SPI reads failing: '), first.message
    assert says in first.message
    assert status_values(first)['state'] == 'failing'
    assert first.message == f'SPI reads failing: {status_values(first)["last_error"]}'
    # Both streams stop (once what was in flight has arrived), the compensation node
    # reports stale input, while the driver keeps trying, and counting, at its rate.
    probe.wait_quiet(['imu/data_raw', 'imu/data'], 0.3, TIMEOUT_S, launcher)
    probe.clear()
    statuses = probe.wait_statuses(
        {DRIVER_DIAGNOSTIC: lambda s: True,
         COMPENSATION_DIAGNOSTIC: lambda s: s.level == DiagnosticStatus.ERROR},
        TIMEOUT_S, f'the next driver status and stale compensation under {fault}', launcher)
    stale = statuses[COMPENSATION_DIAGNOSTIC]
    assert stale.message == 'stale input: no raw samples'
    assert float(status_values(stale)['input_age_s']) > 0.5
    second = statuses[DRIVER_DIAGNOSTIC]
    assert second.level == DiagnosticStatus.ERROR
    assert driver_counter(second, counter) > driver_counter(first, counter)
    assert int(status_values(second)['failed_reads']) > int(status_values(first)['failed_reads'])
    assert probe.count('imu/data_raw') == 0, f'raw samples published under {fault}'
    assert probe.count('imu/data') == 0

    set_fault(probe, 'none')
    statuses = probe.wait_statuses(
        {DRIVER_DIAGNOSTIC: lambda s: s.level == DiagnosticStatus.OK,
         COMPENSATION_DIAGNOSTIC: lambda s: s.level == DiagnosticStatus.OK},
        TIMEOUT_S, f'both nodes OK after {fault}', launcher)
    recovered = statuses[DRIVER_DIAGNOSTIC]
    assert recovered.message == 'streaming'
    assert status_values(recovered)['state'] == 'streaming'
    assert statuses[COMPENSATION_DIAGNOSTIC].message == 'compensating (eeprom)'
    probe.wait_streaming(['imu/data_raw', 'imu/data'], TIMEOUT_S, launcher)


def test_refusing_device_is_reported_and_recovers(launcher, probe, tmp_path):
    start_pipeline(launcher, probe, tmp_path)
    results = probe.set_parameters('driver_node', {'simulation.fault': 'smoke'})
    assert not results[0].successful
    assert results[0].reason == ("invalid parameter simulation.fault: 'smoke' is not one of "
                                 'none, refuse, no_eoc, silent_high, silent_low')
    check_fault(launcher, probe, 'refuse')


@pytest.mark.slow
def test_silent_bus_and_missing_eoc_are_reported_and_recover(launcher, probe, tmp_path):
    start_pipeline(launcher, probe, tmp_path)
    for fault in ('silent_low', 'silent_high', 'no_eoc'):
        check_fault(launcher, probe, fault)
    assert launcher.processes[0].running()
