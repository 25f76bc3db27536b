"""The ``mlx-tempcomp decode-eeprom`` command, in-process and as a real subprocess."""

import json
import os
from pathlib import Path
import subprocess
import sys

from mlx_tempcomp.cli import main
from mlx_tempcomp.core.mlx90609.conversion import Output
from mlx_tempcomp.core.mlx90609.eeprom import decode_eeprom, EepromFields, encode_eeprom
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.simulation.mlx90609 import factory_eeprom, FactoryMeasurement
from mlx_tempcomp.simulation.physics import GyroTruth
import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
FIELDS = EepromFields(range_code=15, version=2, tc_mv=(1861, 2507, 3093),
                      ee_zro=(17, 128, 251), ee_sf=(3, 129, 254))


def factory_image(seed=0, version=2):
    truth = GyroTruth.random(np.random.default_rng(seed))
    return factory_eeprom(truth, np.random.default_rng(seed), FactoryMeasurement(version=version))


def write(tmp_path, image, name='eeprom.bin'):
    path = tmp_path / name
    path.write_bytes(image)
    return str(path)


def run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def assert_user_error(code, out, err, message):
    assert code == 2
    assert out == ''
    assert err == f'error: {message}\n', 'exactly one line on stderr'
    assert 'Traceback' not in err


def version_7_image():
    """VERSION 7 is not defined by AN2; EepromFields refuses it, so set the bits by hand."""
    cells = bytearray(encode_eeprom(FIELDS))
    for i, address in enumerate(range(0x60, 0x68)):
        bit = (7 >> i) & 1
        cells[address] = (cells[address] & ~0b111000) | (0b111000 * bit)
    return bytes(cells)


# --- decoding --------------------------------------------------------------------------------

@pytest.mark.parametrize('output', ['digital', 'analog'])
def test_json_table_equals_factory_table(tmp_path, capsys, output):
    image = factory_image(seed=2)
    path = write(tmp_path, image)
    code, out, err = run(['decode-eeprom', path, '--output', output, '--json'], capsys)
    assert (code, err) == (0, '')
    result = json.loads(out)
    fields = decode_eeprom(image)
    table = factory_table(fields, Output(output))
    assert result['image'] == path
    assert result['output'] == output
    assert (result['version'], result['range_code'], result['full_scale_dps']) == (2, 15, 75.0)
    assert result['has_table'] is True
    assert result['tc_mv'] == list(fields.tc_mv)
    assert result['ee_zro'] == list(fields.ee_zro)
    assert result['ee_sf'] == list(fields.ee_sf)
    assert (result['tc'], result['zro'], result['sf']) == (list(table.tc), list(table.zro),
                                                           list(table.sf))
    assert result['outvoted_bits'] == {'RANGE': 0, 'VERSION': 0, 'TC0': 0, 'TC1': 0, 'TC2': 0}


def test_analog_and_digital_units(tmp_path, capsys):
    path = write(tmp_path, encode_eeprom(FIELDS))
    tables = {}
    for output in ('digital', 'analog'):
        code, out, _ = run(['decode-eeprom', path, '--output', output, '--json'], capsys)
        assert code == 0
        tables[output] = json.loads(out)
    analog, digital = tables['analog'], tables['digital']
    # Analog: TC in mV as stored; ZRO by the VERSION 2 formula 2300 + 400 x EE / 255 mV.
    assert analog['tc'] == [1861.0, 2507.0, 3093.0]
    assert analog['zro'] == pytest.approx([2300 + 400 * e / 255 for e in (17, 128, 251)])
    # SF = (0.95 + EE / 2560) x S0, S0 = 2000 mV / 75 deg/s.
    s0_mv = 2000.0 / 75.0
    assert analog['sf'] == pytest.approx([(0.95 + e / 2560) * s0_mv for e in (3, 129, 254)])
    # Digital: TEMPOUT LSB = (mV - 300) x 16/25; rate LSB = (mV - 400) x 12/25.
    assert digital['tc'] == pytest.approx([(mv - 300) * 16 / 25 for mv in (1861, 2507, 3093)])
    assert digital['zro'] == pytest.approx([(mv - 400) * 12 / 25 for mv in analog['zro']])
    assert digital['sf'] == pytest.approx([sf * 12 / 25 for sf in analog['sf']])


def test_digital_is_the_default_and_the_text_table(tmp_path, capsys):
    image = bytearray(encode_eeprom(FIELDS))
    image[0x4A] ^= 0b10                  # one copy of TC1 bit 2: out-voted
    path = write(tmp_path, bytes(image))
    code, out, err = run(['decode-eeprom', path], capsys)
    assert code == 0
    assert err == (f'{path}: warning: TC1: 1 bit out-voted; copies 2507, 2511, 2507; the '
                   'majority 2507 was used (wrong if two copies of a bit went bad)\n')
    lines = out.splitlines()
    assert lines[0] == f'{path}: VERSION 2, RANGE 15 (full scale 75 deg/s)'
    assert lines[1] == 'digital output: TC in LSB of TEMPOUT, ZRO in LSB, SF in LSB/(deg/s)'
    table = factory_table(FIELDS, Output.DIGITAL)
    for row, i, label in zip(lines[3:6], range(3), ('-40', '+25', '+85')):
        assert row.split() == [label, 'C', str(FIELDS.tc_mv[i]), f'{table.tc[i]:.3f}',
                               f'{table.zro[i]:.3f}', f'{table.sf[i]:.4f}',
                               str(FIELDS.ee_zro[i]), str(FIELDS.ee_sf[i])]
    assert lines[6] == 'out-voted bits: RANGE 0, VERSION 0, TC0 0, TC1 1, TC2 0 (total 1)'
    assert len(lines) == 7


def test_every_out_voted_field_is_a_warning_and_strict_refuses_the_image(tmp_path, capsys):
    image = bytearray(encode_eeprom(FIELDS))
    image[0x38 + 3] ^= 0b110             # TC0 bit 3 flipped in two of its three copies
    image[0x68] ^= 0b001                 # RANGE bit 0 flipped in one copy
    path = write(tmp_path, bytes(image))
    code, out, err = run(['decode-eeprom', path], capsys)
    assert code == 0
    wrong_tc0 = FIELDS.tc_mv[0] ^ 0b1000
    assert err.splitlines() == [
        f'{path}: warning: RANGE: 1 bit out-voted; copies 14, 15, 15; the majority 15 was '
        'used (wrong if two copies of a bit went bad)',
        f'{path}: warning: TC0: 1 bit out-voted; copies {FIELDS.tc_mv[0]}, {wrong_tc0}, '
        f'{wrong_tc0}; the majority {wrong_tc0} was used (wrong if two copies of a bit went '
        'bad)']
    assert f'{wrong_tc0}' in out.splitlines()[3]
    code, out, err = run(['decode-eeprom', path, '--strict'], capsys)
    assert code == 2 and out == ''
    lines = err.splitlines()
    assert len(lines) == 3 and 'warning: RANGE' in lines[0] and 'warning: TC0' in lines[1]
    assert lines[2] == f'error: {path}: out-voted bits in RANGE, TC0; --strict refuses the image'
    code, out, err = run(['decode-eeprom', path, '--json'], capsys)
    assert code == 0 and err.count('warning:') == 2
    decoded = json.loads(out)
    assert decoded['voted_copies']['TC0'] == [FIELDS.tc_mv[0], wrong_tc0, wrong_tc0]
    assert decoded['voted_copies']['RANGE'] == [14, 15, 15]
    assert decoded['tc_mv'][0] == wrong_tc0


def test_strict_accepts_a_clean_image(tmp_path, capsys):
    path = write(tmp_path, encode_eeprom(FIELDS))
    code, out, err = run(['decode-eeprom', path, '--strict'], capsys)
    assert (code, err) == (0, '')
    assert 'out-voted bits: RANGE 0, VERSION 0, TC0 0, TC1 0, TC2 0 (total 0)' in out


def test_analog_text_names_millivolts(tmp_path, capsys):
    path = write(tmp_path, encode_eeprom(FIELDS))
    code, out, _ = run(['decode-eeprom', path, '--output', 'analog'], capsys)
    assert code == 0
    lines = out.splitlines()
    assert lines[1] == 'analog output: TC in mV of TEMPOUT, ZRO in mV, SF in mV/(deg/s)'
    assert lines[3].split()[2:4] == ['1861', '1861.000']


def test_version_0_has_no_table(tmp_path, capsys):
    path = write(tmp_path, factory_image(seed=1, version=0))
    code, out, err = run(['decode-eeprom', path], capsys)
    assert (code, err) == (0, '')
    assert out.splitlines()[1] == ('VERSION 0: the EEPROM holds no table; use the nominal ZRO '
                                   'and scale factor')
    code, out, _ = run(['decode-eeprom', path, '--json'], capsys)
    result = json.loads(out)
    assert (code, result['version'], result['has_table']) == (0, 0, False)
    assert 'zro' not in result and 'sf' not in result and 'tc' not in result


def test_full_scale_option_when_range_is_zero(tmp_path, capsys):
    fields = EepromFields(range_code=0, version=2, tc_mv=FIELDS.tc_mv, ee_zro=FIELDS.ee_zro,
                          ee_sf=FIELDS.ee_sf)
    path = write(tmp_path, encode_eeprom(fields))
    code, out, err = run(['decode-eeprom', path], capsys)
    assert_user_error(code, out, err,
                      f'{path}: EEPROM RANGE is 0, so the full scale and the typical scale '
                      'factor are unknown; give the full scale explicitly')
    code, out, err = run(['decode-eeprom', path, '--full-scale', '150', '--json'], capsys)
    assert (code, err) == (0, '')
    # S0 = 2000 mV / 150 deg/s x 12/25 LSB/mV = 6.4 LSB/(deg/s); EE_SF0 = 3.
    assert json.loads(out)['sf'][0] == pytest.approx((0.95 + 3 / 2560) * 6.4)


# --- user mistakes: exit code 2, one line, no traceback --------------------------------------

def test_missing_file(tmp_path, capsys):
    path = str(tmp_path / 'absent.bin')
    code, out, err = run(['decode-eeprom', path], capsys)
    assert_user_error(code, out, err,
                      f'cannot read EEPROM image {path}: No such file or directory')


def test_directory_instead_of_a_file(tmp_path, capsys):
    code, out, err = run(['decode-eeprom', str(tmp_path)], capsys)
    assert_user_error(code, out, err, f'cannot read EEPROM image {tmp_path}: Is a directory')


@pytest.mark.parametrize('size', [0, 127, 129, 256])
def test_wrong_size(tmp_path, capsys, size):
    path = write(tmp_path, (encode_eeprom(FIELDS) * 2)[:size])
    code, out, err = run(['decode-eeprom', path, '--json'], capsys)
    assert_user_error(code, out, err, f'{path}: EEPROM image must be 128 bytes, got {size}')


def test_unknown_version(tmp_path, capsys):
    image = version_7_image()
    assert image[0x60] & 0b111000 == 0b111000 and image[0x63] & 0b111000 == 0
    path = write(tmp_path, image)
    code, out, err = run(['decode-eeprom', path], capsys)
    assert_user_error(code, out, err,
                      f'{path}: unknown EEPROM VERSION 7 (0x07); AN2 defines 0, 1, 2, 3, 255')


def test_unusable_table(tmp_path, capsys):
    fields = EepromFields(range_code=15, version=2, tc_mv=(3093, 2507, 1861),
                          ee_zro=FIELDS.ee_zro, ee_sf=FIELDS.ee_sf)
    path = write(tmp_path, encode_eeprom(fields))
    code, out, err = run(['decode-eeprom', path], capsys)
    assert code == 2 and out == ''
    assert err.startswith(f'error: {path}: EEPROM table is unusable: ')
    assert err.count('\n') == 1 and err.endswith('\n')
    assert 'Traceback' not in err


# --- as a real process -----------------------------------------------------------------------

def run_process(*args):
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        p for p in (str(REPO_ROOT), env.get('PYTHONPATH', '')) if p)
    return subprocess.run([sys.executable, '-m', 'mlx_tempcomp.cli', *args], env=env,
                          capture_output=True, text=True, timeout=60, check=False)


def test_subprocess_decodes_and_reports_errors(tmp_path):
    image = factory_image(seed=4)
    good = write(tmp_path, image, 'good.bin')
    bad = write(tmp_path, version_7_image(), 'bad.bin')
    done = run_process('decode-eeprom', good, '--output', 'analog', '--json')
    assert (done.returncode, done.stderr) == (0, '')
    table = factory_table(decode_eeprom(image), Output.ANALOG)
    assert json.loads(done.stdout)['zro'] == list(table.zro)
    done = run_process('decode-eeprom', bad)
    assert done.returncode == 2
    assert done.stdout == ''
    assert done.stderr == (f'error: {bad}: unknown EEPROM VERSION 7 (0x07); '
                           'AN2 defines 0, 1, 2, 3, 255\n')
