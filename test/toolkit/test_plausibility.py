"""
Columns no gyro record holds: one warning line naming the column and the fix, or exit 2.

An accelerometer column taken as a gyro at rest, a gyro in deg/s read as rad/s, a time
in ns read as µs or in µs read as ns: each is read without a skipped row and, before
`recordings.plausibility`, gave a fit with exit code 0. Now every command that reads a
record warns in one line (``--strict``: the same line as the error, exit 2), and the
``--columns`` item the line gives reads the file right.
"""

import math

from cli_checks import assert_user_error
from mlx_tempcomp.cli import main
from mlx_tempcomp.recordings.load import load_recording
from mlx_tempcomp.recordings.plausibility import (implausible_columns,
                                                  MAX_REST_OFFSET_DPS,
                                                  MAX_SAMPLE_INTERVAL_S,
                                                  MAX_TEMPERATURE_SLEW_C_S,
                                                  MIN_SAMPLE_INTERVAL_S, temperature_slew)
import numpy as np
import pytest

SAMPLES = 2000
INTERVAL_S = 0.5
HEADER = 'time,temperature,gyro_z,ax,ay,az'   # a logger's own names for acceleration


def rows(time_factor=1.0, gyro_factor=1.0, samples=SAMPLES) -> np.ndarray:
    """Give a still unit over a -20..60 C cycle (0.25 C/s at most), 2 deg/s offset, acc."""
    rng = np.random.default_rng(3)
    index = np.arange(samples)
    temperature_c = 20.0 - 40.0 * np.cos(2.0 * np.pi * index / samples)
    rate = 0.035 + 0.004 * (temperature_c - 20.0) / 40.0 + rng.normal(0.0, 0.002, samples)
    acceleration = np.array([0.1, -0.1, -9.7]) + rng.normal(0.0, 0.01, (samples, 3))
    return np.column_stack([index * INTERVAL_S * time_factor, temperature_c,
                            rate * gyro_factor, acceleration])


def write(path, table: np.ndarray) -> str:
    lines = [HEADER] + [','.join(repr(float(v)) for v in row) for row in table]
    path.write_text('\n'.join(lines) + '\n')
    return str(path)


# (file: time and gyro factors, --columns, the warning after "<file>: ", the fixing map)
CASES = {
    'accelerometer_as_gyro': (
        (1.0, 1.0), 'gyro_z=az',
        'gyro_z (column az): mean -9.7 rad/s (-555.8 deg/s) at rest (no ref_z column) is '
        "beyond any gyro's offset (50 deg/s); is it an accelerometer column (gravity reads "
        '9.80665 m/s^2)? map gyro_z=<the gyro column> (--columns)', None),
    'gyro_in_deg_s': (
        (1.0, math.degrees(1.0)), None,
        'gyro_z: mean 2.009 rad/s (115.1 deg/s) at rest (no ref_z column) is beyond any '
        "gyro's offset (50 deg/s); is it in deg/s? map gyro_z=gyro_z:0.0174533 (--columns)",
        'gyro_z=gyro_z:0.0174533'),
    'time_in_ns_read_as_us': (
        (1e9, 1.0), 'time=time:1e-6',
        'time: median sample interval 500 s, where a gyro record samples every 1e-05 to 60 s; '
        'is the time in ns? map time=time:1e-09 (--columns)', 'time=time:1e-9'),
    'time_in_us_read_as_ns': (
        (1e6, 1.0), 'time=time:1e-9',
        "temperature: changes 226 C/s (48.3 to -8.2 C in 0.25 s), where no part's "
        'temperature changes faster than 10 C/s; is the time in µs? map time=time:1e-06 '
        '(--columns)', 'time=time:1e-6'),
}


def case_file(tmp_path, case: str) -> tuple:
    (time_factor, gyro_factor), columns, warning, fixed = CASES[case]
    path = write(tmp_path / f'{case}.csv', rows(time_factor, gyro_factor))
    return path, ['--columns', columns] if columns else [], f'{path}: {warning}', fixed


def test_the_deg_s_case_is_within_the_offset_until_read_as_rad_s():
    # The deg/s file's gyro mean, 2 deg/s, is a plausible offset; read as rad/s it is not.
    mean_dps = float(np.mean(rows(gyro_factor=math.degrees(1.0))[:, 2]))
    assert mean_dps < MAX_REST_OFFSET_DPS < math.degrees(mean_dps)


@pytest.mark.parametrize('case', sorted(CASES))
def test_a_column_no_gyro_record_holds_warns_in_one_line_and_strict_refuses(
        tmp_path, capsys, case):
    path, columns, warning, fixed = case_file(tmp_path, case)
    out = tmp_path / 'p.yaml'
    assert main(['fit', path, *columns, '--out', str(out)]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f'warning: {warning}') and err.count('\n') == 1, err
    assert out.exists()
    out.unlink()
    code = main(['fit', path, *columns, '--out', str(out), '--strict'])
    assert_user_error(code, capsys, f'error: {warning}; --strict refuses the record\n')
    assert not out.exists()
    if fixed is not None:   # the map the line gives reads the file without a warning
        assert main(['fit', path, '--columns', fixed, '--out', str(out), '--strict']) == 0
        assert capsys.readouterr().err == ''


def command_options(command: str, tmp_path, params) -> list:
    """Give the options each command that reads a record needs, outputs in tmp_path."""
    return {'fit': ['--out', tmp_path / 'x.yaml'], 'evaluate': ['--params', params],
            'allan': [], 'convert': ['--out', tmp_path / 'bag'],
            'diagnose': ['--out', tmp_path / 'report', '--no-plots'], 'inspect': [],
            'inject-motion': ['--out', tmp_path / 'moving.csv']}[command]


COMMANDS = ('fit', 'evaluate', 'allan', 'convert', 'diagnose', 'inspect', 'inject-motion')


@pytest.fixture(scope='module')
def clean_params(tmp_path_factory):
    """Give the parameter file fit writes for the clean record (evaluate's model)."""
    folder = tmp_path_factory.mktemp('clean')
    params = folder / 'p.yaml'
    assert main(['fit', write(folder / 'clean.csv', rows()), '--out', str(params)]) == 0
    return params


# inject-motion takes the ns read as µs at its word: 2000 samples 500 s apart are 11.5 days
# of motion to schedule (a 23 MB schedule), some seconds: in the slow tier.
LONG_RUNS = {('time_in_ns_read_as_us', 'inject-motion')}


@pytest.mark.parametrize('case, command', [
    pytest.param(case, command, marks=[pytest.mark.slow] if (case, command) in LONG_RUNS
                 else []) for case in ('accelerometer_as_gyro', 'time_in_ns_read_as_us')
    for command in COMMANDS])
def test_every_command_that_reads_a_record_warns_or_refuses(tmp_path, capsys, clean_params,
                                                            case, command):
    path, columns, warning, _ = case_file(tmp_path, case)
    params = clean_params
    capsys.readouterr()
    argv = [command, path, *columns, *map(str, command_options(command, tmp_path, params))]
    # convert writes a bag of what it reads: it takes no record as still.
    rest_only = case == 'accelerometer_as_gyro' and command == 'convert'
    code = main(argv + ['--strict'])
    if rest_only:
        assert code == 0 and capsys.readouterr().err == ''
        return
    assert_user_error(code, capsys, f'error: {warning}; --strict refuses the record\n')
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 0, err
    assert [line for line in err.splitlines() if 'warning' in line] == \
        [f'warning: {warning}'], err
    assert 'Traceback' not in err


def test_a_bag_says_what_is_wrong_without_a_column_map(tmp_path, capsys):
    # A CSV in ns read as µs, written as a bag: its stamps are 500 s apart, 1000 times
    # what they are: as if in ms.
    path, columns, _, _ = case_file(tmp_path, 'time_in_ns_read_as_us')
    assert main(['convert', path, *columns, '--out', str(tmp_path / 'bag')]) == 0
    capsys.readouterr()
    assert main(['fit', str(tmp_path / 'bag'), '--out', str(tmp_path / 'p.yaml')]) == 0
    err = capsys.readouterr().err
    assert err == (f'warning: {tmp_path / "bag"}: time: median sample interval 500 s, where a '
                   'gyro record samples every 1e-05 to 60 s; is the time in ms?\n')


def test_a_record_with_a_reference_is_not_taken_as_still(tmp_path):
    table = rows()
    table[:, 2] += 5.0    # turning at 5 rad/s, as the reference says
    path = tmp_path / 'turning.csv'
    lines = [HEADER + ',ref_z'] + [','.join(repr(float(v)) for v in row) + ',5.0'
                                   for row in table]
    path.write_text('\n'.join(lines) + '\n')
    recording = load_recording(path)
    assert implausible_columns(recording) == []
    without = load_recording(path, columns='ref_z=')
    assert len(implausible_columns(without)) == 1
    assert implausible_columns(without, at_rest=False) == []


def test_the_bounds_hold_for_what_gyro_records_are():
    # The measured sweep's rate of change, a chamber's, is far below the bound; quantization
    # noise at 1 kHz (a 1/340 C step each sample) reads as none.
    time_s = np.arange(100_000) * 1e-3
    temperature_c = 25.0 + np.round(np.random.default_rng(0).normal(0.0, 0.01, time_s.size)
                                    * 340.0) / 340.0
    assert temperature_slew(time_s, temperature_c)[0] < 0.01
    # A 165 C thermal-shock step followed with a 20 s time constant: 8.25 C/s at most.
    time_s = np.arange(0.0, 200.0, 0.01)
    shock = -40.0 + 165.0 * (1.0 - np.exp(-time_s / 20.0))
    slew = temperature_slew(time_s, shock)[0]
    assert slew < MAX_TEMPERATURE_SLEW_C_S and slew > 0.5 * 165.0 / 20.0
    # A glitch row moves no window's median.
    glitched = shock.copy()
    glitched[5000] = 199.0
    assert temperature_slew(time_s, glitched)[0] == slew
    assert MIN_SAMPLE_INTERVAL_S < 1.0 / 32_000 and MAX_SAMPLE_INTERVAL_S >= 60.0
