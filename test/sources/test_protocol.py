"""Every simulated part the driver streams satisfies the source protocol of `sources.protocol`."""

from mlx_tempcomp.parameters.driver import DEVICES
from mlx_tempcomp.sources import adis16130, mlx90609
from mlx_tempcomp.sources.mpu6000 import SimulatedMpuSource
from mlx_tempcomp.sources.protocol import Reading, SampleSource, SimulatedSource
import pytest


def _mpu():
    source = SimulatedMpuSource()
    source.start()
    return source


SOURCES = {
    'mlx90609': lambda: mlx90609.SimulatedArray(mlx90609.SimulationConfig(), 2),
    'adis16130': lambda: adis16130.SimulatedSensor(),
    'mpu6000': _mpu,
}


def test_every_device_has_its_simulated_source_here():
    assert sorted(SOURCES) == sorted(DEVICES)


@pytest.mark.parametrize('device', sorted(SOURCES))
def test_simulated_sources_satisfy_the_protocol(device):
    source = SOURCES[device]()
    try:
        assert isinstance(source, SampleSource)
        assert isinstance(source, SimulatedSource)
        target_s = source.clock.now_s + 0.25
        source.advance_to(target_s)
        assert source.clock.now_s == pytest.approx(target_s)
        reading = source.read()
        assert isinstance(reading, Reading)
        assert not reading.saturated      # at rest, well inside the range
        assert source.counters and all(isinstance(count, int)
                                       for count in source.counters.values())
    finally:
        source.close()


def test_a_reading_without_saturation_is_not_a_reading():
    class Codes:
        rate_code = 0

    assert not isinstance(Codes(), Reading)
    assert not isinstance(Codes(), SampleSource)
