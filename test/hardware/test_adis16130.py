"""The ADIS16130 protocol, code formats, simulated device and source (AN-1042)."""

# Nothing of the project is mocked: the driver talks to `SimulatedAdis16130`
# through `SimulatedTransport`. The wrappers below only watch or damage the
# wire between the two.

import math

from mlx_tempcomp.hardware import adis16130 as protocol
from mlx_tempcomp.hardware.adis16130 import (
    Adis16130, Adis16130Reading, rate_code_from_dps, rate_dps_from_code, temperature_c_from_code,
    temperature_code_from_c)
from mlx_tempcomp.hardware.errors import (
    HardwareError, ProtocolError, SilentBusError, TransportError)
from mlx_tempcomp.simulation.adis16130 import (
    ADIS16130_NOISE, Adis16130Truth, Fault, self_heating_profile, simulated_device)
from mlx_tempcomp.simulation.physics import Effects, Noise, Scenario, ThermalProfile
from mlx_tempcomp.sources.adis16130 import (
    SimulatedSensor, SimulationConfig, spidev_sensor)
import numpy as np
import pytest

# AN-1042 Table 3 as printed: (step, SDI byte, register).
TABLE_3 = (
    (1, 0x01, 'COM'), (2, 0x38, 'IOP'), (3, 0x28, 'COM'), (4, 0x0A, 'RATECS'),
    (5, 0x30, 'COM'), (6, 0x05, 'RATECONV'), (7, 0x2A, 'COM'), (8, 0x0A, 'TEMPCS'),
    (9, 0x32, 'COM'), (10, 0x05, 'TEMPCONV'), (11, 0x38, 'COM'), (12, 0x22, 'MODE'),
)
# AN-1042 Table 4 as printed: (24-bit code, 16-bit code or None, rate text in deg/s).
# "8.388,612" is read as 8,388,612.
TABLE_4 = (
    (14_260_608, 55_706, '+250'),
    (8_623_488, 33_686, '+10'),
    (8_388_612, 32_769, '+0.00017030'),
    (8_388_609, None, '+0.000042575'),
    (8_388_608, 32_768, '0'),
    (8_388_607, 8_388_607, '-0.000042575'),
    (8_388_604, 32_767, '-0.00017030'),
    (8_153_728, 31_850, '-10'),
    (2_516_608, 9_830, '-250'),
)
# AN-1042 Table 5 as printed: (24-bit code, 16-bit code, temperature in C).
TABLE_5 = (
    (9_516_048, 37_172, 105.0),
    (9_234_188, 36_071, 85.0),
    (8_402_701, 32_823, 26.0),
    (8_388_608, 32_768, 25.0),
    (8_036_283, 31_392, 0.0),
    (7_472_563, 29_189, -40.0),
)
# 16-bit entries no rounding of the 24-bit scale reproduces, with the code the
# conversion gives (docs/adis16130.md, "Misprints"). +-0.00017030 deg/s is 0.0156
# of a 16-bit LSB; 32,769 / 32,767 are +-1 LSB. The -40 C entry is 7,472,563 / 256
# = 29,189.70 truncated, while the 0 C entry (31,391.73 -> 31,392) is rounded.
MISPRINTS_16 = {'+0.00017030': 32_768, '-0.00017030': 32_768, '-0.000042575': 32_768,
                -40.0: 29_190}
QUIET = Noise(density_dps_rt_hz=0.0, bias_instability_dps=0.0, temperature_noise_mv=0.0)
QUIET_TRUTH = Adis16130Truth(temperature_noise_c=0.0, noise=QUIET)
NO_FAULTS = {'silent_bus': 0, 'protocol_errors': 0, 'saturated': 0}


class Wire:
    """A transport between driver and device that records every frame and may damage it."""

    def __init__(self, inner, damage=None):
        self.inner = inner
        self.damage = damage
        self.frames = []

    def transfer(self, tx):
        self.frames.append(bytes(tx))
        rx = self.inner.transfer(tx)
        return self.damage(tx, rx) if self.damage else rx

    def wait(self, seconds):
        self.inner.wait(seconds)

    def close(self):
        self.inner.close()


def quiet_device(truth=QUIET_TRUTH, scenario=Scenario(), bits=24, seed=0):
    device = simulated_device(truth, scenario, seed=seed)
    wire = Wire(device.transport())
    driver = Adis16130(wire, resolution_bits=bits)
    driver.start()
    return device, wire, driver


# --- start-up sequence -----------------------------------------------------------------------

def test_start_up_bytes_are_table_3_byte_for_byte():
    table = bytes(byte for _, byte, _ in TABLE_3)
    assert protocol.start_up_bytes(24) == table
    assert [register for _, register in protocol.START_UP_SEQUENCE] == \
        [register for _, _, register in TABLE_3]
    # 16-bit mode differs in the MODE value only: b1 (24-bit) cleared.
    assert protocol.start_up_bytes(16) == table[:-1] + b'\x20'
    with pytest.raises(HardwareError, match='24 or 16 bits, got 12'):
        protocol.start_up_bytes(12)


@pytest.mark.parametrize('bits, mode', [(24, 0x22), (16, 0x20)])
def test_start_sends_table_3_one_byte_per_frame_and_sets_the_registers(bits, mode):
    device, wire, driver = quiet_device(bits=bits)
    start_frames = wire.frames[:12]
    assert all(len(frame) == 1 for frame in start_frames), 'AN-1042: CS high between bytes'
    assert b''.join(start_frames) == protocol.start_up_bytes(bits)
    # Then the read-back of the six registers written: 0x40 | register, one byte each.
    assert wire.frames[12:] == [bytes((0x40 | r, 0)) for r in (0x01, 0x28, 0x30, 0x2A, 0x32,
                                                               0x38)]
    assert device.registers == {0x01: 0x38, 0x28: 0x0A, 0x30: 0x05, 0x2A: 0x0A, 0x32: 0x05,
                                0x38: mode}
    assert device.resolution_bits == bits
    assert driver.counters.as_dict() == NO_FAULTS


# --- code tables -----------------------------------------------------------------------------

@pytest.mark.parametrize('code_24, code_16, printed', TABLE_4)
def test_rate_table_4_row(code_24, code_16, printed):
    rate_dps = float(printed)
    # 24 bits, both ways: the rate as printed (5 significant digits) and the code exactly.
    assert float(f'{rate_dps_from_code(code_24, 24):.5g}') == rate_dps
    assert rate_code_from_dps(rate_dps, 24) == code_24
    if code_16 is None:
        return
    expected = MISPRINTS_16.get(printed, code_16)
    assert rate_code_from_dps(rate_dps, 16) == expected
    if printed in MISPRINTS_16:
        return
    # The 16-bit code decodes to within half a 16-bit LSB of the printed rate.
    # (+-10 and +-250 sit exactly on a half-LSB tie, which rounds away from zero.)
    assert abs(rate_dps_from_code(code_16, 16) - rate_dps) <= 0.5 / 91.75 + 1e-12


def test_rate_table_4_misprinted_16_bit_codes_are_one_lsb_steps():
    assert rate_dps_from_code(32_769, 16) == 1 / 91.75
    assert rate_dps_from_code(32_767, 16) == -1 / 91.75
    assert rate_code_from_dps(1 / 91.75, 16) == 32_769
    assert rate_code_from_dps(-1 / 91.75, 16) == 32_767
    # The 16-bit cell of the -0.000042575 row repeats its 24-bit code.
    assert 8_388_607 > protocol.full_code(16)
    with pytest.raises(HardwareError, match='16-bit ADIS16130 codes are integers 0..65535'):
        rate_dps_from_code(8_388_607, 16)


@pytest.mark.parametrize('code_24, code_16, temperature_c', TABLE_5)
def test_temperature_table_5_row(code_24, code_16, temperature_c):
    assert temperature_c_from_code(code_24, 24) == temperature_c
    assert temperature_code_from_c(temperature_c, 24) == code_24
    expected = MISPRINTS_16.get(temperature_c, code_16)
    assert temperature_code_from_c(temperature_c, 16) == expected


def test_temperature_table_5_minus_40_is_truncated_not_rounded():
    assert 7_472_563 // 256 == 29_189                    # the printed entry
    assert temperature_c_from_code(29_190, 16) == pytest.approx(-39.9945, abs=1e-4)
    assert temperature_c_from_code(29_189, 16) == pytest.approx(-40.0127, abs=1e-4)
    # The 0 C entry is rounded, not truncated: no single rule gives both entries.
    assert 8_036_283 // 256 == 31_391 != 31_392


def test_ties_round_away_from_mid_scale():
    # The table's ties (+-917.5, +-22,937.5 LSB) do not tell this from round-half-even.
    assert (0.5 / 91.75) * 91.75 == 0.5 and (2.5 / 91.75) * 91.75 == 2.5
    assert rate_code_from_dps(0.5 / 91.75, 16) == 32_769
    assert rate_code_from_dps(2.5 / 91.75, 16) == 32_771
    np.testing.assert_array_equal(
        rate_code_from_dps(np.array([0.5, -0.5, -2.5]) / 91.75, 16), [32_769, 32_767, 32_765])


def test_scale_factors_come_from_the_tables():
    assert protocol.rate_lsb_per_dps(24) == (14_260_608 - 8_388_608) / 250
    assert protocol.temperature_lsb_per_c(24) == (9_516_048 - 8_036_283) / 105
    assert protocol.rate_lsb_per_dps(16) == 91.75


@pytest.mark.parametrize('bits, codes', [
    (16, np.arange(1 << 16)),
    # Every 97th 24-bit code, every code within 2**16 of mid-scale, and both ends.
    (24, np.unique(np.concatenate([np.arange(0, 1 << 24, 97),
                                   np.arange((1 << 23) - (1 << 16), (1 << 23) + (1 << 16)),
                                   [(1 << 24) - 1]])))])
def test_codes_round_trip_exactly(bits, codes):
    np.testing.assert_array_equal(rate_code_from_dps(rate_dps_from_code(codes, bits), bits),
                                  codes)
    np.testing.assert_array_equal(
        temperature_code_from_c(temperature_c_from_code(codes, bits), bits), codes)


@pytest.mark.parametrize('bits', [24, 16])
def test_values_encode_to_the_nearest_code(bits):
    rng = np.random.default_rng(1)
    rates = rng.uniform(-300.0, 300.0, 10_000)
    back = rate_dps_from_code(rate_code_from_dps(rates, bits), bits)
    assert np.max(np.abs(back - rates)) <= 0.5 / protocol.rate_lsb_per_dps(bits)
    temperatures = rng.uniform(-40.0, 105.0, 10_000)
    back = temperature_c_from_code(temperature_code_from_c(temperatures, bits), bits)
    assert np.max(np.abs(back - temperatures)) <= 0.5 / protocol.temperature_lsb_per_c(bits)
    # Scalars take the same path as arrays.
    assert rate_code_from_dps(float(rates[0]), bits) == rate_code_from_dps(rates, bits)[0]


def test_codes_clip_at_the_adc_limits_and_bad_input_is_refused():
    assert rate_code_from_dps(1000.0) == 0xFFFFFF
    assert rate_code_from_dps(np.array([-1000.0]), 16)[0] == 0
    with pytest.raises(HardwareError, match='non-finite'):
        rate_code_from_dps(float('nan'))
    with pytest.raises(HardwareError, match='non-finite'):
        temperature_code_from_c(np.array([25.0, np.inf]))
    with pytest.raises(HardwareError, match='24-bit ADIS16130 codes are integers'):
        rate_dps_from_code(1 << 24)
    with pytest.raises(HardwareError, match='24-bit ADIS16130 codes are integers'):
        temperature_c_from_code(np.array([1.5]))


# --- reads -----------------------------------------------------------------------------------

def test_reads_are_0x48_and_0x4a_then_3_bytes_in_one_frame():
    truth = Adis16130Truth(bias_dps=1.0, temperature_noise_c=0.0, noise=QUIET)
    scenario = Scenario(thermal=ThermalProfile(temperatures_c=(85.0,)))
    device, wire, driver = quiet_device(truth, scenario)
    del wire.frames[:]
    assert driver.read_code(protocol.RATEDATA) == 8_388_608 + 23_488
    assert driver.read_code(protocol.TEMPDATA) == 9_234_188      # Table 5: 85 C
    assert wire.frames == [b'\x48\x00\x00\x00', b'\x4a\x00\x00\x00']
    assert driver.read_rate_dps() == 1.0
    assert driver.read_temperature_c() == 85.0
    assert driver.read() == Adis16130Reading(rate_dps=1.0, temperature_c=85.0, saturated=False)


def test_16_bit_reads_are_the_command_then_2_bytes():
    scenario = Scenario(rate_dps=(10.0,))
    device, wire, driver = quiet_device(scenario=scenario, bits=16)
    del wire.frames[:]
    assert driver.read_code(protocol.RATEDATA) == 33_686            # Table 4: +10 deg/s
    assert driver.read_code(protocol.TEMPDATA) == 32_768            # 25 C
    assert wire.frames == [b'\x48\x00\x00', b'\x4a\x00\x00']
    assert driver.read_rate_dps() == pytest.approx(918 / 91.75)


def test_one_byte_per_frame_reads_the_same_code():
    # AN-1042 raises CS between bytes; the Linux driver holds it over 4 bytes.
    scenario = Scenario(rate_dps=(-10.0,))
    device, wire, driver = quiet_device(scenario=scenario)
    transport = device.transport()
    rx = b''.join(transport.transfer(bytes((byte,))) for byte in b'\x48\x00\x00\x00')
    assert int.from_bytes(rx[1:], 'big') == 8_153_728               # Table 4: -10 deg/s
    assert driver.read_code(protocol.RATEDATA) == 8_153_728


def test_data_registers_refresh_at_the_update_rate():
    truth = Adis16130Truth(temperature_noise_c=0.0)   # rate noise on
    device, wire, driver = quiet_device(truth)
    device.clock.advance(1.00001 - device.clock.now_s)
    first = driver.read_code(protocol.RATEDATA)
    assert driver.read_code(protocol.RATEDATA) == first, 'within one 1/5.7 kHz period'
    driver.transport.wait(1 / 5700)
    assert driver.read_code(protocol.RATEDATA) != first


def test_rate_sensitivity_bias_and_saturation():
    truth = Adis16130Truth(bias_dps=0.5, bias_dps_per_c=0.04, sensitivity_error=0.01,
                           temperature_noise_c=0.0, noise=QUIET)
    scenario = Scenario(thermal=ThermalProfile(temperatures_c=(35.0,)),
                        rate_times_s=(0.0, 0.5, 0.5001), rate_dps=(100.0, 100.0, 300.0))
    device, wire, driver = quiet_device(truth, scenario)
    reading = driver.read()
    assert reading.rate_dps == pytest.approx(1.01 * 100.0 + 0.5 + 0.04 * 10.0, abs=1e-4)
    assert reading.temperature_c == pytest.approx(35.0, abs=1e-4)
    assert not reading.saturated
    driver.transport.wait(1.0)
    reading = driver.read(oversample=3)
    assert reading.rate_dps == pytest.approx(303.9, abs=1e-4)
    assert reading.saturated
    assert driver.counters.as_dict() == dict(NO_FAULTS, saturated=1)
    with pytest.raises(HardwareError, match='oversample must be at least 1, got 0'):
        driver.read(0)


def test_supply_sensitivity_of_the_note():
    # AN-1042: the bias can shift 0.0002 deg/s per mV of supply.
    scenario = Scenario(supply_v=(5.1,))
    device, wire, driver = quiet_device(scenario=scenario)
    assert driver.read_rate_dps() == pytest.approx(0.02, abs=1e-4)


# --- faults ----------------------------------------------------------------------------------

@pytest.mark.parametrize('fault, word', [(Fault.SILENT_HIGH, '0xFFFFFF'),
                                         (Fault.SILENT_LOW, '0x000000')])
def test_silent_bus_is_an_error_not_a_number(fault, word):
    device, wire, driver = quiet_device()
    device.fault = fault
    with pytest.raises(SilentBusError, match=f'read 0x48 gave {word}: MISO stuck'):
        driver.read()
    with pytest.raises(SilentBusError, match='set-up registers all read'):
        driver.start()
    assert driver.counters.as_dict() == dict(NO_FAULTS, silent_bus=2)
    device.fault = Fault.NONE
    assert driver.read().rate_dps == 0.0


def test_power_cycle_is_detected_and_start_recovers():
    device, wire, driver = quiet_device()
    device.power_cycle()
    assert device.registers[protocol.MODE] == 0
    with pytest.raises(SilentBusError, match='part not started'):
        driver.read_rate_dps()
    with pytest.raises(SilentBusError, match='reset to its power-on values'):
        driver.verify_configuration()
    driver.start()
    assert driver.read() == Adis16130Reading(0.0, 25.0, False)


def test_register_read_back_mismatch_names_the_register():
    device = simulated_device(QUIET_TRUTH, Scenario(), seed=0)

    def flip_mode_bit(tx, rx):
        return rx[:1] + bytes((rx[1] ^ 0x02,)) if tx[0] == 0x40 | protocol.MODE else rx

    driver = Adis16130(Wire(device.transport(), flip_mode_bit))
    with pytest.raises(ProtocolError, match=r'0x38 = 0x20 \(wrote 0x22\)'):
        driver.start()
    assert driver.counters.protocol_errors == 1
    # Parts that cannot read back: the check can be switched off.
    unchecked = Adis16130(Wire(device.transport(), flip_mode_bit), verify_registers=False)
    unchecked.start()
    assert unchecked.read().temperature_c == 25.0


def test_short_frame_is_a_protocol_error():
    device = simulated_device(QUIET_TRUTH, Scenario(), seed=0)
    driver = Adis16130(Wire(device.transport(), lambda tx, rx: rx[:-1]))
    with pytest.raises(ProtocolError, match='returned 0 bytes, expected 1'):
        driver.start()


def test_bad_resolution_is_refused():
    device = simulated_device(QUIET_TRUTH, Scenario(), seed=0)
    with pytest.raises(HardwareError, match='24 or 16 bits, got 32'):
        Adis16130(device.transport(), resolution_bits=32)


# --- source ----------------------------------------------------------------------------------

def test_simulated_sensor_samples_in_rad_s_and_c_with_stamps():
    sensor = SimulatedSensor(SimulationConfig(truth=QUIET_TRUTH, rate_dps=90.0))
    assert sensor.axes == ('z',)
    sensor.advance_to(2.0)
    sample = sensor.read()
    assert sample.rate_rad_s.shape == (1,)
    assert sample.rate_rad_s[0] == pytest.approx(math.pi / 2, abs=1e-6)
    assert sample.temperature_c[0] == 25.0
    assert 2.0 < sample.time_s < 2.0 + 1e-4            # two 4-byte frames at 1 MHz
    record = sensor.record(1.0, 100.0)
    np.testing.assert_allclose(np.diff(record.time_s), 0.01, atol=1e-9)
    assert record.rate_rad_s.shape == (100, 1)
    assert record.saturated == 0
    assert sensor.counters == NO_FAULTS
    sensor.fault = Fault.SILENT_LOW
    assert sensor.fault is Fault.SILENT_LOW
    with pytest.raises(SilentBusError):
        sensor.read()
    with pytest.raises(HardwareError, match='positive duration and rate, got 1.0 s, 0.0 Hz'):
        sensor.record(1.0, 0.0)


def test_simulated_sensor_in_16_bit_mode():
    sensor = SimulatedSensor(SimulationConfig(truth=QUIET_TRUTH, resolution_bits=16,
                                              rate_dps=-250.0))
    assert sensor.device.registers[protocol.MODE] == 0x20
    assert sensor.read().rate_rad_s[0] == pytest.approx(math.radians(-22938 / 91.75))


@pytest.mark.parametrize('slope_dps_per_c', [0.04, -0.04])
def test_bias_temperature_coefficient_through_the_frames(slope_dps_per_c):
    # AN-1042 procedure on a noise-free part: mean over 10 s at start-up -> (T1, B1),
    # self-heating for 10 min, again -> (T2, B2); the slope is the truth's.
    truth = Adis16130Truth(bias_dps=0.3, bias_dps_per_c=slope_dps_per_c,
                           temperature_noise_c=0.0, noise=QUIET)
    sensor = SimulatedSensor(SimulationConfig(truth=truth, thermal=self_heating_profile(
        25.0, 5.0, 120.0)))
    first = sensor.record(10.0, 50.0)
    sensor.advance_to(600.0)
    second = sensor.record(10.0, 50.0)
    t1, t2 = first.temperature_c.mean(), second.temperature_c.mean()
    b1, b2 = (math.degrees(r.rate_rad_s.mean()) for r in (first, second))
    assert t2 - t1 > 4.0
    assert (b2 - b1) / (t2 - t1) == pytest.approx(slope_dps_per_c, rel=1e-4)


def test_bias_temperature_coefficient_with_noise():
    truth = Adis16130Truth(bias_dps_per_c=0.04, noise=ADIS16130_NOISE)
    sensor = SimulatedSensor(SimulationConfig(seed=3, truth=truth,
                                              thermal=self_heating_profile()))
    first = sensor.record(10.0, 500.0)
    sensor.advance_to(600.0)
    second = sensor.record(10.0, 500.0)
    slope = (math.degrees(second.rate_rad_s.mean() - first.rate_rad_s.mean())
             / (second.temperature_c.mean() - first.temperature_c.mean()))
    # 5000 samples of 0.22 deg/s noise and the bias instability: 1 sigma of the slope
    # is about 0.001 deg/s/C.
    assert slope == pytest.approx(0.04, abs=0.004)


def test_same_seed_same_record_and_effects_pass_through():
    def run(seed):
        effects = Effects(zro_supply_dps_per_v=0.2, bias_steps=((0.5, 1.0),))
        truth = Adis16130Truth(effects=effects)
        return SimulatedSensor(SimulationConfig(seed=seed, truth=truth)).record(1.0, 1000.0)

    a, b, c = run(1), run(1), run(2)
    np.testing.assert_array_equal(a.rate_rad_s, b.rate_rad_s)
    assert np.any(a.rate_rad_s != c.rate_rad_s)
    step = np.degrees(a.rate_rad_s[500:].mean() - a.rate_rad_s[:500].mean())
    assert step == pytest.approx(1.0, abs=0.1)      # 1 sigma: 0.014 deg/s


def test_spidev_sensor_without_a_device_is_a_transport_error():
    with pytest.raises(TransportError, match=r'/dev/spidev99\.0 \(mode 3, 1000000 Hz\)'):
        spidev_sensor(99, 0)
