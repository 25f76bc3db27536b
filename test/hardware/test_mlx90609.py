"""The SPI driver `Mlx90609` against the simulated device, frame by frame."""

# Nothing of the project is mocked: the driver talks to `SimulatedMlx90609`
# through `SimulatedTransport` in 3-byte frames. The only wrapper below stands
# for a bad wire between the two (a corrupted or a short frame).

import re

from mlx_tempcomp.core.mlx90609.conversion import Output
from mlx_tempcomp.core.mlx90609.eeprom import decode_eeprom, EepromFields, encode_eeprom
from mlx_tempcomp.core.mlx90609.factory_table import factory_table, TRIPLET_TEMPERATURES_C
from mlx_tempcomp.hardware.errors import (
    EocTimeoutError, HardwareError, ProtocolError, RefusalError, SilentBusError)
from mlx_tempcomp.hardware.mlx90609 import (
    ADCC, ADCR, ANSWER_ADEN, ANSWER_CHAN, ANSWER_EOC, Channel, Mlx90609, Mlx90609Reading, STATR)
from mlx_tempcomp.simulation.clock import SimClock
from mlx_tempcomp.simulation.mlx90609 import (
    factory_eeprom, Fault, simulated_device, SimulatedMlx90609)
from mlx_tempcomp.simulation.physics import GyroPhysics, GyroTruth, Noise, Scenario
import numpy as np
import pytest

# Without noise a device at 25 C and zero rate gives exact codes: the rate
# channel 2500 mV -> (2500 - 400) x 12/25 = 1008, the temperature channel
# 2500 mV -> (2500 - 300) x 16/25 = 1408.
QUIET = Noise(density_dps_rt_hz=0.0, bias_instability_dps=0.0, temperature_noise_mv=0.0)
ZERO_RATE_CODE = 1008
CODE_25C = 1408
FRAME_S = 24e-6          # 24 SCLK at 1 MHz
# One default conversion: ADCC frame, 120 us wait, one ADCR frame (EOC is set by then).
CONVERSION_S = FRAME_S + 120e-6 + FRAME_S
NO_FAULTS = {'refusals': 0, 'eoc_timeouts': 0, 'silent_bus': 0, 'protocol_errors': 0,
             'saturated': 0}


def quiet_device(scenario=Scenario(), seed=0):
    device = simulated_device(GyroTruth(noise=QUIET), scenario, seed=seed)
    return device, Mlx90609(device.transport())


def counters_with(**changed):
    return dict(NO_FAULTS, **changed)


def raw(transport, instruction):
    """One frame on the bare transport; returns the 16-bit answer."""
    rx = transport.transfer(bytes((instruction, 0, 0)))
    assert len(rx) == 3
    assert rx[0] == 0, 'MISO carries no answer while the instruction is clocked in'
    return (rx[1] << 8) | rx[2]


class BadWire:
    """A transport between driver and device that corrupts every frame with ``damage``."""

    def __init__(self, inner, damage):
        self.inner = inner
        self.damage = damage

    def transfer(self, tx):
        return self.damage(tx, self.inner.transfer(tx))

    def wait(self, seconds):
        self.inner.wait(seconds)

    def close(self):
        self.inner.close()


def test_fault_free_reading_and_clock():
    device, driver = quiet_device()
    assert driver.read() == Mlx90609Reading(rate_code=ZERO_RATE_CODE, temperature_code=CODE_25C,
                                            saturated=False)
    assert device.clock.now_s == pytest.approx(2 * CONVERSION_S, abs=1e-12)
    assert driver.read(oversample=4) == Mlx90609Reading(ZERO_RATE_CODE, CODE_25C, False)
    assert device.clock.now_s == pytest.approx(10 * CONVERSION_S, abs=1e-12)
    assert driver.counters.as_dict() == NO_FAULTS


def test_oversample_below_one_is_refused_by_the_driver():
    device, driver = quiet_device()
    with pytest.raises(HardwareError, match='^oversample must be at least 1, got 0$'):
        driver.read(oversample=0)
    assert device.clock.now_s == 0.0, 'no frame may be sent'


# --- faults the simulator produces on demand -------------------------------------------------

FAULT_CASES = [
    # fault, operation, error type, exact message, counter
    (Fault.REFUSE, 'read', RefusalError,
     'instruction 0x94 refused: 0x8400 (BUSY)', 'refusals'),
    (Fault.REFUSE, 'read_eeprom', RefusalError,
     'instruction 0x00 refused: 0x8400 (BUSY)', 'refusals'),
    (Fault.NO_EOC, 'read', EocTimeoutError,
     'rate conversion: no EOC after 20 ADCR polls', 'eoc_timeouts'),
    (Fault.SILENT_HIGH, 'read', SilentBusError,
     'instruction 0x94 answered 0xFFFF: MISO stuck high, bus silent', 'silent_bus'),
    (Fault.SILENT_HIGH, 'read_eeprom', SilentBusError,
     'instruction 0x00 answered 0xFFFF: MISO stuck high, bus silent', 'silent_bus'),
    (Fault.SILENT_LOW, 'read', SilentBusError,
     'ADCC 0x94 answered 0x0000: MISO stuck low, bus silent', 'silent_bus'),
    (Fault.SILENT_LOW, 'read_eeprom', SilentBusError,
     'EEPROM read gave 128 bytes of 0x00: bus silent or part absent', 'silent_bus'),
]


@pytest.mark.parametrize('fault, operation, error, message, counter', FAULT_CASES,
                         ids=[f'{c[0].value}-{c[1]}' for c in FAULT_CASES])
def test_fault_raises_typed_error_counts_it_and_recovers(fault, operation, error, message,
                                                         counter):
    device, driver = quiet_device()
    image = bytes(device.eeprom)
    device.fault = fault
    with pytest.raises(error, match=f'^{re.escape(message)}$'):
        getattr(driver, operation)()
    assert driver.counters.as_dict() == counters_with(**{counter: 1})
    # The fault persists until it is cleared: a second attempt fails and counts again.
    with pytest.raises(error):
        getattr(driver, operation)()
    assert getattr(driver.counters, counter) == 2
    device.fault = Fault.NONE
    assert driver.read() == Mlx90609Reading(ZERO_RATE_CODE, CODE_25C, False)
    assert driver.read_eeprom() == image
    assert driver.counters.as_dict() == counters_with(**{counter: 2})


def test_refusal_error_carries_the_answer_word():
    device, driver = quiet_device()
    device.fault = Fault.REFUSE
    with pytest.raises(RefusalError) as info:
        driver.status()
    assert info.value.answer == 0x8400
    assert str(info.value) == 'instruction 0x88 refused: 0x8400 (BUSY)'


def test_no_eoc_polls_exactly_the_limit_then_gives_up():
    device, _ = quiet_device()
    driver = Mlx90609(device.transport(), eoc_max_polls=5)
    device.fault = Fault.NO_EOC
    with pytest.raises(EocTimeoutError,
                       match='^temperature conversion: no EOC after 5 ADCR polls$'):
        driver.convert(Channel.TEMPERATURE)
    # ADCC frame, the conversion wait, then 5 x (ADCR frame + poll interval).
    assert device.clock.now_s == pytest.approx(FRAME_S + 120e-6 + 5 * (FRAME_S + 20e-6),
                                               abs=1e-12)
    assert driver.counters.as_dict() == counters_with(eoc_timeouts=1)
    # NO_EOC blocks the end of conversion only: status still answers, with EOC = 0.
    assert driver.status() == ANSWER_CHAN | ANSWER_ADEN
    device.fault = Fault.NONE
    assert driver.convert(Channel.TEMPERATURE) == CODE_25C


def test_too_short_a_poll_budget_times_out_without_any_fault():
    device, _ = quiet_device()
    driver = Mlx90609(device.transport(), conversion_wait_s=0.0, eoc_max_polls=3)
    with pytest.raises(EocTimeoutError, match='no EOC after 3 ADCR polls'):
        driver.convert(Channel.RATE)
    assert driver.counters.eoc_timeouts == 1


def test_eoc_polling_without_a_wait_returns_on_the_first_eoc():
    device, _ = quiet_device()
    driver = Mlx90609(device.transport(), conversion_wait_s=0.0)
    assert driver.convert(Channel.RATE) == ZERO_RATE_CODE
    # ADCC executes at 8 us, so EOC is due at 123 us; the ADCR polls execute at
    # 32, 76, 120 and 164 us and the fourth frame ends at 180 us.
    assert device.clock.now_s == pytest.approx(180e-6, abs=1e-12)
    assert driver.counters.as_dict() == NO_FAULTS


@pytest.mark.parametrize('instruction, flags', [(0xFF, 'OPC'), (0xA0, 'OPC'), (0x81, 'OPC')])
def test_unknown_instruction_is_refused_with_opc(instruction, flags):
    device, driver = quiet_device()
    with pytest.raises(RefusalError) as info:
        driver.command(instruction)
    assert info.value.answer == 0xC000
    assert str(info.value) == f'instruction 0x{instruction:02X} refused: 0xC000 ({flags})'
    assert driver.counters.as_dict() == counters_with(refusals=1)
    assert driver.read() == Mlx90609Reading(ZERO_RATE_CODE, CODE_25C, False)


# --- saturation ------------------------------------------------------------------------------

@pytest.mark.parametrize('rate_dps, code', [(500.0, 2047.0), (-500.0, 0.0)])
def test_rate_far_beyond_full_scale_is_flagged_saturated(rate_dps, code):
    device, driver = quiet_device(Scenario(rate_times_s=(0.0,), rate_dps=(rate_dps,)))
    reading = driver.read()
    assert reading == Mlx90609Reading(rate_code=code, temperature_code=CODE_25C, saturated=True)
    assert driver.counters.as_dict() == counters_with(saturated=1)
    assert driver.read(oversample=8).saturated
    assert driver.counters.saturated == 2


def test_rate_inside_full_scale_is_not_saturated():
    # 60 deg/s x 12.8 LSB/(deg/s) = 768 LSB above the zero-rate code.
    device, driver = quiet_device(Scenario(rate_times_s=(0.0,), rate_dps=(60.0,)))
    assert driver.read() == Mlx90609Reading(ZERO_RATE_CODE + 768, CODE_25C, False)
    assert driver.counters.saturated == 0


def test_saturation_is_never_averaged_away():
    # The true rate ramps 0 -> 500 deg/s in 0.1 s; full scale is hit near 81 deg/s.
    scenario = Scenario(rate_times_s=(0.0, 0.1), rate_dps=(0.0, 500.0))
    device, driver = quiet_device(scenario)
    readings = []
    while device.clock.now_s < 0.1:
        readings.append(driver.read(oversample=16))
    flags = [r.saturated for r in readings]
    first = flags.index(True)
    assert all(flags[first:])
    assert driver.counters.saturated == len(readings) - first
    # The reading that crosses full scale averages below the limit, yet is flagged.
    assert readings[first].rate_code < 2047.0
    assert all(r.rate_code < 2047.0 for r in readings[:first])
    assert all(r.rate_code == 2047.0 for r in readings[first + 1:])


# --- a bad wire ------------------------------------------------------------------------------

def flip_answer_bit(bit):
    def damage(tx, rx):
        if tx[0] & 0xF3 == ADCC:
            rx = bytes((rx[0], rx[1], rx[2] ^ bit))
        return rx
    return damage


def test_wrong_chan_echo_is_a_protocol_error():
    device, _ = quiet_device()
    driver = Mlx90609(BadWire(device.transport(), flip_answer_bit(ANSWER_CHAN)))
    with pytest.raises(ProtocolError,
                       match=r'^ADCC 0x94 answered 0x000C: wrong CHAN/ADEN echo$'):
        driver.read()
    assert driver.counters.as_dict() == counters_with(protocol_errors=1)


def test_wrong_aden_echo_is_a_protocol_error():
    device, _ = quiet_device()
    driver = Mlx90609(BadWire(device.transport(), flip_answer_bit(ANSWER_ADEN)))
    with pytest.raises(ProtocolError,
                       match=r'^ADCC 0x9C answered 0x0008: wrong CHAN/ADEN echo$'):
        driver.convert(Channel.TEMPERATURE)
    assert driver.counters.as_dict() == counters_with(protocol_errors=1)


def test_short_frame_is_a_protocol_error():
    device, _ = quiet_device()
    driver = Mlx90609(BadWire(device.transport(), lambda tx, rx: rx[:2]))
    with pytest.raises(ProtocolError, match='^SPI frame returned 2 bytes, expected 3$'):
        driver.status()
    assert driver.counters.as_dict() == counters_with(protocol_errors=1)


# --- frame-level protocol --------------------------------------------------------------------

def test_statr_and_adcc_answers_echo_chan_and_aden():
    device, _ = quiet_device()
    transport = device.transport()
    assert raw(transport, STATR) == 0x0000, 'ADC off after power-up: EOC = CHAN = ADEN = 0'
    assert raw(transport, 0x9C) == ANSWER_CHAN | ANSWER_ADEN, 'ADCC temperature, no EOC yet'
    assert raw(transport, STATR) == ANSWER_CHAN | ANSWER_ADEN
    transport.wait(115e-6)
    assert raw(transport, STATR) == ANSWER_EOC | ANSWER_CHAN | ANSWER_ADEN
    assert raw(transport, 0x94) == ANSWER_ADEN, 'ADCC rate restarts: EOC cleared, CHAN 0'
    assert raw(transport, STATR) == ANSWER_ADEN
    transport.wait(115e-6)
    assert raw(transport, STATR) == ANSWER_EOC | ANSWER_ADEN
    assert raw(transport, 0x90) == 0x0000, 'ADCC with ADEN = 0 switches the ADC off'
    assert raw(transport, STATR) == 0x0000
    assert raw(transport, ADCR) & ANSWER_EOC == 0


def test_adcr_without_eoc_then_with_the_code_in_bits_11_to_1():
    device, _ = quiet_device()
    transport = device.transport()
    raw(transport, 0x9C)                 # ADCC executes 8 us into its frame
    transport.wait(115e-6 - FRAME_S - 2e-6)
    early = raw(transport, ADCR)         # executes 113 us after ADCC
    assert early & ANSWER_EOC == 0
    late = raw(transport, ADCR)          # executes 137 us after ADCC
    assert late == ANSWER_EOC | (CODE_25C << 1) == 0x2B00
    assert late & 0x8001 == 0, 'b15 = 0 and b0 = 0'
    raw(transport, 0x94)
    transport.wait(115e-6)
    answer = raw(transport, ADCR)
    assert answer == ANSWER_EOC | (ZERO_RATE_CODE << 1) == 0x27E0
    assert (answer >> 1) & 0x7FF == ZERO_RATE_CODE


def test_adc_code_bits_are_not_polluted_by_the_status_bits():
    # A code whose AD1 and AD2 are 0 would read back 2 or 6 LSB high if the ADCR
    # answer also carried CHAN (b3) and ADEN (b2), as STATR does.
    device, driver = quiet_device()
    assert ZERO_RATE_CODE & 0b11 == 0 and CODE_25C & 0b11 == 0
    for _ in range(3):
        assert driver.convert(Channel.RATE) == ZERO_RATE_CODE
        assert driver.convert(Channel.TEMPERATURE) == CODE_25C


@pytest.mark.parametrize('sclk_hz', [1e6, 500e3, 2e6])
def test_each_frame_takes_24_bit_times(sclk_hz):
    truth = GyroTruth(noise=QUIET)
    device = SimulatedMlx90609(GyroPhysics(truth, Scenario(), seed=0),
                               factory_eeprom(truth, np.random.default_rng(0)), SimClock(),
                               sclk_hz=sclk_hz)
    transport = device.transport()
    for count, instruction in enumerate([STATR, 0x94, ADCR, 0x10, 0xFF, STATR], start=1):
        raw(transport, instruction)
        assert device.clock.now_s == pytest.approx(count * 24 / sclk_hz, rel=1e-12)


def test_transport_refuses_frames_that_are_not_three_bytes():
    device, _ = quiet_device()
    with pytest.raises(ValueError, match='^an MLX90609 frame is 3 bytes, got 2$'):
        device.transport().transfer(b'\x88\x00')


# --- EEPROM over SPI frames ------------------------------------------------------------------

FIELDS = EepromFields(range_code=30, version=2, tc_mv=(1861, 2507, 3093),
                      ee_zro=(17, 128, 251), ee_sf=(3, 129, 254))


def device_with_image(image):
    truth = GyroTruth(noise=QUIET)
    return SimulatedMlx90609(GyroPhysics(truth, Scenario(), seed=0), image, SimClock())


def test_eeprom_read_over_frames_equals_the_image_and_decodes_to_its_fields():
    fill = np.random.default_rng(7).integers(0, 256, 128, dtype=np.uint8).tobytes()
    image = encode_eeprom(FIELDS, fill=fill)
    device = device_with_image(image)
    driver = Mlx90609(device.transport())
    assert driver.read_eeprom() == image
    assert device.clock.now_s == pytest.approx(128 * FRAME_S, abs=1e-12)
    # Every byte in the low byte of the answer, high byte 0.
    assert raw(device.transport(), 0x45) == image[0x45]
    assert decode_eeprom(driver.read_eeprom()) == FIELDS
    assert driver.counters.as_dict() == NO_FAULTS


def test_factory_eeprom_holds_the_devices_own_table():
    truth = GyroTruth.random(np.random.default_rng(11))
    device = simulated_device(truth, Scenario(), seed=11)
    image = Mlx90609(device.transport()).read_eeprom()
    assert image == bytes(device.eeprom)
    # simulated_device writes what factory_eeprom writes with the same seed.
    assert image == factory_eeprom(truth, np.random.default_rng(11))
    fields = decode_eeprom(image)
    assert (fields.range_code, fields.version, fields.full_scale_dps) == (15, 2, 75.0)
    assert fields.total_outvoted_bits == 0
    for tc, temperature_c in zip(fields.tc_mv, TRIPLET_TEMPERATURES_C):
        assert tc == pytest.approx(truth.sensor_mv(temperature_c), abs=5.0)
    table = factory_table(fields, Output.ANALOG)
    s0 = truth.typical_sf_mv
    for i, temperature_c in enumerate(TRIPLET_TEMPERATURES_C):
        # Factory error 0.05 deg/s (1 sigma) plus half a ZRO step of 400/255 mV.
        assert table.zro[i] == pytest.approx(truth.zro_mv(temperature_c), abs=0.3 * s0)
        assert table.sf[i] == pytest.approx(truth.sf_mv(temperature_c), rel=0.01)


def test_one_flipped_copy_is_outvoted_and_counted():
    image = encode_eeprom(FIELDS)
    device = device_with_image(image)
    driver = Mlx90609(device.transport())
    device.flip_eeprom_bit(0x4A, 1)      # TC1 bit 2, second copy
    read = driver.read_eeprom()
    assert read != image and read[0x4A] == image[0x4A] ^ 0b10
    fields = decode_eeprom(read)
    assert fields.tc_mv == FIELDS.tc_mv
    assert dict(fields.outvoted_bits) == {'RANGE': 0, 'VERSION': 0, 'TC0': 0, 'TC1': 1,
                                          'TC2': 0}
    assert factory_table(fields, Output.DIGITAL) == factory_table(FIELDS, Output.DIGITAL)


def test_two_flipped_copies_lose_the_majority():
    device = device_with_image(encode_eeprom(FIELDS))
    driver = Mlx90609(device.transport())
    device.flip_eeprom_bit(0x4A, 1)
    device.flip_eeprom_bit(0x4A, 2)
    fields = decode_eeprom(driver.read_eeprom())
    assert fields.tc_mv == (1861, 2507 ^ 0b100, 3093) == (1861, 2511, 3093)
    assert fields.outvoted_bits['TC1'] == 1
    assert fields.total_outvoted_bits == 1


def test_outvoted_bits_in_range_and_version_are_attributed_to_them():
    device = device_with_image(encode_eeprom(FIELDS))
    driver = Mlx90609(device.transport())
    device.flip_eeprom_bit(0x60, 5)      # VERSION bit 0, third copy
    device.flip_eeprom_bit(0x69, 0)      # RANGE bit 1, first copy
    device.flip_eeprom_bit(0x6C, 2)      # RANGE bit 4, third copy
    fields = decode_eeprom(driver.read_eeprom())
    assert (fields.version, fields.range_code) == (2, 30)
    assert dict(fields.outvoted_bits) == {'RANGE': 2, 'VERSION': 1, 'TC0': 0, 'TC1': 0,
                                          'TC2': 0}
    device.flip_eeprom_bit(0x60, 4)      # VERSION bit 0, second copy too: 2 -> 3
    fields = decode_eeprom(driver.read_eeprom())
    assert fields.version == 3
    assert fields.outvoted_bits['VERSION'] == 1


def test_single_stored_bytes_change_without_a_count():
    device = device_with_image(encode_eeprom(FIELDS))
    driver = Mlx90609(device.transport())
    device.flip_eeprom_bit(0x20, 6)      # EE_ZRO0 bit 0: stored once, nothing to vote
    fields = decode_eeprom(driver.read_eeprom())
    assert fields.ee_zro == (16, 128, 251)
    assert fields.total_outvoted_bits == 0
