import itertools

from mlx_tempcomp.core.errors import EepromError
from mlx_tempcomp.core.mlx90609.conversion import Output, SensorTransfer
from mlx_tempcomp.core.mlx90609.eeprom import (decode_eeprom, EEPROM_SIZE, EepromFields,
                                               encode_eeprom)
from mlx_tempcomp.core.mlx90609.factory_table import ee_from_sf, ee_from_zro, factory_table
import numpy as np
import pytest


def reference_decode(image):
    """Transcription of the AN2 C routines (sections 3.1-3.4), bit loop by bit loop."""
    def voted(low, high, mask0, mask1, mask2, top):
        value = 0
        for addr in range(low, high):
            tmp = image[addr]
            a0, a1, a2 = tmp & mask0, tmp & mask1, tmp & mask2
            value >>= 1
            if (a0 and a1) or (a0 and a2) or (a1 and a2):
                value |= top
        return value

    range_code = voted(0x68, 0x70, 0x01, 0x02, 0x04, 0x80)
    version = voted(0x60, 0x68, 0x08, 0x10, 0x20, 0x80)
    tc = [voted(0x38 + n * 16, 0x48 + n * 16, 0x01, 0x02, 0x04, 0x8000) for n in range(3)]
    ee_zro, ee_sf = [0, 0, 0], [0, 0, 0]
    tmp = 0
    for addr in range(0x20, 0x50):
        tmp = (tmp >> 1) | (0x80 if image[addr] & 0x40 else 0)
        slots = {0x27: (ee_zro, 0), 0x2F: (ee_zro, 1), 0x37: (ee_zro, 2),
                 0x3F: (ee_sf, 0), 0x47: (ee_sf, 1), 0x4F: (ee_sf, 2)}
        if addr in slots:
            target, index = slots[addr]
            target[index] = tmp
    return range_code, version, tuple(tc), tuple(ee_zro), tuple(ee_sf)


def example_fields(version=2):
    return EepromFields(range_code=15, version=version, tc_mv=(1850, 2500, 3100),
                        ee_zro=(120, 128, 140), ee_sf=(100, 128, 150))


@pytest.mark.parametrize('seed', range(20))
def test_decoder_matches_the_an2_c_code_on_random_images(seed):
    rng = np.random.default_rng(seed)
    image = bytearray(rng.integers(0, 256, EEPROM_SIZE, dtype=np.uint8).tobytes())
    # Random bytes rarely give a known VERSION: force one, keep the rest random.
    version = [0, 1, 2, 3, 255][seed % 5]
    for i, addr in enumerate(range(0x60, 0x68)):
        bit = (version >> i) & 1
        image[addr] = (image[addr] & ~0x38) | (0x38 * bit)
    fields = decode_eeprom(bytes(image))
    expected = reference_decode(image)
    assert (fields.range_code, fields.version, fields.tc_mv, fields.ee_zro,
            fields.ee_sf) == expected


@pytest.mark.parametrize('version', [0, 1, 2, 3, 255])
def test_encode_decode_round_trip_for_every_version(version):
    fields = example_fields(version)
    rng = np.random.default_rng(version)
    fill = rng.integers(0, 256, EEPROM_SIZE, dtype=np.uint8).tobytes()
    image = encode_eeprom(fields, fill=fill)
    decoded = decode_eeprom(image)
    assert decoded == fields
    assert decoded.total_outvoted_bits == 0
    # The user area 0x70..0x7F and bits the table does not use are left as they were.
    assert image[0x70:] == fill[0x70:]
    assert image[0x20] & 0xBF == fill[0x20] & 0xBF


@pytest.mark.parametrize('version, output', list(itertools.product([1, 2, 3, 255], Output)))
def test_physical_round_trip_for_every_version_and_output(version, output):
    transfer = SensorTransfer()
    typical = transfer.typical_sf(75.0, output)
    nominal = transfer.nominal_zro(output)
    # 1.6 deg/s below, about at and 2.3 deg/s above nominal: storable by every VERSION.
    zro = tuple(nominal + k * typical for k in (-1.6, 0.05, 2.3))
    sf = (0.97 * typical, typical, 1.03 * typical)
    fields = EepromFields(range_code=15, version=version, tc_mv=(1850, 2500, 3100),
                          ee_zro=tuple(ee_from_zro(version, z, output) for z in zro),
                          ee_sf=tuple(ee_from_sf(s, typical) for s in sf))
    table = factory_table(decode_eeprom(encode_eeprom(fields)), output)
    zro_step = {1: 1.0, 2: 400 / 255, 3: 400 / 255, 255: 400 / 255}[version]
    if output is Output.DIGITAL:
        zro_step *= 12 / 25
    np.testing.assert_allclose(table.zro, zro, atol=zro_step / 2 + 1e-9)
    np.testing.assert_allclose(table.sf, sf, atol=typical / 2560 / 2 + 1e-12)
    expected_tc = (1850.0, 2500.0, 3100.0) if output is Output.ANALOG else \
        tuple((mv - 300.0) * 16.0 / 25.0 for mv in (1850, 2500, 3100))
    np.testing.assert_allclose(table.tc, expected_tc)


def test_version_formulas_as_printed_in_an2():
    fields = EepromFields(range_code=30, version=1, tc_mv=(1850, 2500, 3100),
                          ee_zro=(0, 100, 255), ee_sf=(0, 128, 255))
    analog = factory_table(fields, Output.ANALOG)
    digital = factory_table(fields, Output.DIGITAL)
    assert analog.zro == (2400.0, 2500.0, 2655.0)
    assert digital.zro == (960.0, 960.0 + 100 * 12 / 25, 960.0 + 255 * 12 / 25)
    s0_mv = 2000.0 / 150.0  # E2: +-150 deg/s
    np.testing.assert_allclose(analog.sf, [0.95 * s0_mv, (0.95 + 128 / 2560) * s0_mv,
                                           (0.95 + 255 / 2560) * s0_mv])
    np.testing.assert_allclose(digital.sf, np.array(analog.sf) * 12 / 25)
    v2 = factory_table(EepromFields(range_code=15, version=2, tc_mv=(1850, 2500, 3100),
                                    ee_zro=(0, 255, 51), ee_sf=(0, 0, 0)), Output.DIGITAL)
    np.testing.assert_allclose(v2.zro, [912.0, 912.0 + 192.0, 912.0 + 192.0 * 51 / 255])


def test_full_scale_and_typical_scale_factor_from_range():
    for code, full_scale, sf_lsb in ((15, 75.0, 12.8), (30, 150.0, 6.4), (60, 300.0, 3.2)):
        fields = EepromFields(range_code=code, version=2, tc_mv=(1850, 2500, 3100),
                              ee_zro=(0, 0, 0), ee_sf=(128, 128, 128))
        assert fields.full_scale_dps == full_scale
        table = factory_table(fields, Output.DIGITAL)
        assert table.sf[0] == pytest.approx(sf_lsb)


@pytest.mark.parametrize('field, address', [('RANGE', 0x6A), ('VERSION', 0x61),
                                            ('TC0', 0x38), ('TC1', 0x50), ('TC2', 0x67)])
@pytest.mark.parametrize('copy', [0, 1, 2])
def test_one_flipped_copy_is_corrected_and_counted(field, address, copy):
    image = bytearray(encode_eeprom(example_fields()))
    bit = (3 + copy) if field == 'VERSION' else copy
    image[address] ^= 1 << bit
    decoded = decode_eeprom(bytes(image))
    assert decoded == example_fields()  # the value survives the vote
    assert decoded.outvoted_bits[field] == 1
    assert decoded.total_outvoted_bits == 1
    # Each copy on its own: the flipped one differs from the value in the flipped bit.
    values = {'RANGE': (decoded.range_code, 0x68), 'VERSION': (decoded.version, 0x60),
              **{f'TC{i}': (decoded.tc_mv[i], 0x38 + 16 * i) for i in range(3)}}
    value, first_address = values[field]
    flipped = value ^ (1 << (address - first_address))
    assert decoded.voted_copies[field] == tuple(flipped if i == copy else value
                                                for i in range(3))


def test_two_flipped_copies_lose_the_vote():
    image = bytearray(encode_eeprom(example_fields()))
    tc1_bit0 = 2500 & 1
    image[0x48] ^= 0b011  # two of the three copies of TC1 bit 0
    decoded = decode_eeprom(bytes(image))
    assert decoded.tc_mv[1] == 2500 ^ 1
    assert decoded.tc_mv[1] & 1 != tc1_bit0
    assert decoded.outvoted_bits['TC1'] == 1
    assert decoded.voted_copies['TC1'] == (2501, 2501, 2500)


def test_unknown_version_names_the_value():
    image = bytearray(encode_eeprom(example_fields()))
    for i, addr in enumerate(range(0x60, 0x68)):
        image[addr] = (image[addr] & ~0x38) | (0x38 * ((7 >> i) & 1))
    with pytest.raises(EepromError, match=r'unknown EEPROM VERSION 7 \(0x07\)'):
        decode_eeprom(bytes(image))
    with pytest.raises(EepromError, match='VERSION 4'):
        EepromFields(range_code=15, version=4, tc_mv=(1, 2, 3), ee_zro=(0, 0, 0),
                     ee_sf=(0, 0, 0))


def test_version_zero_means_no_table():
    fields = decode_eeprom(encode_eeprom(example_fields(version=0)))
    assert not fields.has_table
    assert factory_table(fields, Output.DIGITAL) is None


@pytest.mark.parametrize('size', [0, 127, 129, 256])
def test_wrong_image_size_is_refused(size):
    with pytest.raises(EepromError, match=f'128 bytes, got {size}'):
        decode_eeprom(bytes(size))


def test_unusable_table_is_an_eeprom_error():
    # TC values not increasing: the interpolation has no basis.
    fields = EepromFields(range_code=15, version=2, tc_mv=(2500, 2500, 3100),
                          ee_zro=(0, 0, 0), ee_sf=(0, 0, 0))
    with pytest.raises(EepromError, match='TC0 < TC1 < TC2'):
        factory_table(fields, Output.DIGITAL)
    no_range = EepromFields(range_code=0, version=2, tc_mv=(1850, 2500, 3100),
                            ee_zro=(0, 0, 0), ee_sf=(0, 0, 0))
    with pytest.raises(EepromError, match='RANGE is 0'):
        factory_table(no_range, Output.DIGITAL)
    assert factory_table(no_range, Output.DIGITAL, full_scale_dps=75.0).sf[0] == \
        pytest.approx(0.95 * 12.8)


def test_values_that_do_not_fit_are_refused():
    with pytest.raises(EepromError, match='does not fit in 16 bits'):
        EepromFields(range_code=15, version=2, tc_mv=(1, 2, 70000), ee_zro=(0, 0, 0),
                     ee_sf=(0, 0, 0))
    with pytest.raises(EepromError, match='ZRO 3000 is outside'):
        ee_from_zro(2, 3000.0, Output.ANALOG)
