"""
What every ``mlx-tempcomp`` subcommand does with awkward inputs and output paths.

Rows out of time order are sorted when they are whole blocks and refused after
a clock reset; skipped rows are counted on the console by one shared line;
output paths are checked before any work.
"""

import json
import os

from cli_checks import assert_user_error
from mlx_tempcomp.cli import main
from mlx_tempcomp.recordings.load import load_recording
import numpy as np
import pytest

SAMPLES = 3000
NOISE_RAD_S = 0.002
HEADER = 'time,temperature,gyro_z'


def sweep(samples=SAMPLES, seed=0) -> np.ndarray:
    """Rows of time, temperature (two -20..60 C cycles) and gyro_z with a quadratic bias."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(samples) * 0.5
    temperature_c = 20.0 - 40.0 * np.cos(4.0 * np.pi * np.arange(samples) / samples)
    x = (temperature_c - 20.0) / 40.0
    rate = 0.01 + 0.02 * x - 0.01 * x * x + rng.normal(0.0, NOISE_RAD_S, samples)
    return np.column_stack([time_s, temperature_c, rate])


def write(path, rows, extra_lines=()):
    lines = [HEADER] + [','.join(repr(float(v)) for v in row) for row in rows]
    path.write_text('\n'.join(lines + list(extra_lines)) + '\n')
    return str(path)


def spliced(rows: np.ndarray) -> np.ndarray:
    """Move rows 600..1599 (8 to 13 minutes of the record) behind row 2200."""
    block, rest = rows[600:1600], np.delete(rows, np.s_[600:1600], axis=0)
    return np.concatenate([rest[:1200], block, rest[1200:]])


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def options(command: str, tmp_path, params) -> list:
    """Give the options each subcommand that reads a recording needs, outputs in tmp_path."""
    return {'fit': ['--out', tmp_path / 'x.yaml'], 'evaluate': ['--params', params],
            'allan': [], 'convert': ['--out', tmp_path / 'bag'],
            'diagnose': ['--out', tmp_path / 'report', '--no-plots']}[command]


def without_first_line(text: str) -> str:
    return text.split('\n', 1)[1]


@pytest.mark.slow
def test_a_spliced_block_is_sorted_and_said_by_every_subcommand(tmp_path, capsys):
    folders = {name: tmp_path / name for name in ('clean', 'moved')}
    for folder in folders.values():
        folder.mkdir()
    write(folders['clean'] / 'run.csv', sweep())
    write(folders['moved'] / 'run.csv', spliced(sweep()))
    params = folders['clean'] / 'params.yaml'
    assert main(['fit', str(folders['clean'] / 'run.csv'), '--out', str(params)]) == 0
    capsys.readouterr()
    outputs = {}
    for name, folder in folders.items():
        path = folder / 'run.csv'
        outputs[name] = {
            'fit': run(capsys, 'fit', path, '--out', folder / 'fitted.yaml'),
            'evaluate': run(capsys, 'evaluate', path, '--params', params),
            'allan': run(capsys, 'allan', path),
            'convert': run(capsys, 'convert', path, '--out', folder / 'bag'),
            'diagnose': run(capsys, 'diagnose', path, '--out', folder / 'report', '--no-plots'),
        }
    said = f'{folders["moved"] / "run.csv"}: 3000 rows used; skipped: none; 1000 rows out of ' \
           'time order (whole blocks) sorted into place\n'

    def same(text):
        return text.replace(str(folders['moved']), str(folders['clean']))

    for command, out in outputs['moved'].items():
        assert out.startswith(said), command
        # The rest of what each prints equals the clean file's, but for the folder.
        assert same(without_first_line(out)) == \
            without_first_line(outputs['clean'][command]), command
    assert same((folders['moved'] / 'fitted.yaml').read_text()) == \
        (folders['clean'] / 'fitted.yaml').read_text()
    bags = [load_recording(folder / 'bag', imu_topic='/imu/data_raw',
                           temperature_topic='/imu/temperature_raw')
            for folder in folders.values()]
    np.testing.assert_array_equal(bags[1].gyro_rad_s, bags[0].gyro_rad_s)
    assert len(bags[1]) == 3000
    reports = [json.loads((folder / 'report' / 'report.json').read_text())
               for folder in folders.values()]
    assert reports[1]['rows']['sorted_while_loading'] == 1000
    reports[1]['rows']['sorted_while_loading'] = 0
    assert reports[1]['axes'] == reports[0]['axes'], 'no bias step invented at the splice'
    assert reports[1]['rows'] == reports[0]['rows']
    assert 'rows out of time order sorted into place: 1000' in \
        (folders['moved'] / 'report' / 'report.md').read_text()


@pytest.mark.parametrize('command', ['fit', 'evaluate', 'allan', 'convert', 'diagnose'])
def test_a_clock_reset_is_refused_with_the_first_backward_line(tmp_path, capsys, command):
    rows = sweep(400)
    rows[200:, 0] -= 60.25          # the second half restarts a minute back: interleaved
    path = write(tmp_path / 'reset.csv', rows)
    params = write(tmp_path / 'params.csv', sweep(400))
    assert main(['fit', params, '--out', str(tmp_path / 'p.yaml')]) == 0
    capsys.readouterr()
    code = main([command, path, *map(str, options(command, tmp_path, tmp_path / 'p.yaml'))])
    assert_user_error(code, capsys, f'{path}: time goes back at line 202 (39.75 s after 99.5 s '
                                    'at line 201)', 'a clock reset or two recordings joined?')


@pytest.mark.parametrize('command', ['fit', 'evaluate', 'allan', 'convert', 'diagnose'])
def test_skipped_rows_are_counted_on_the_console_by_every_subcommand(tmp_path, capsys,
                                                                     command):
    rows = sweep(2000)
    path = write(tmp_path / 'gaps.csv', rows,
                 ['1000.0,nan,0.01', '1000.5,21.0,n/a', '1001.0,22.0,inf', '1001.5,22.0'])
    params = tmp_path / 'p.yaml'
    assert main(['fit', write(tmp_path / 'clean.csv', rows), '--out', str(params)]) == 0
    capsys.readouterr()
    out = run(capsys, command, path, *options(command, tmp_path, params))
    assert out.startswith(f'{path}: 2000 rows used; skipped: non-numeric values 2, non-finite '
                          'values 2\n')


def test_fit_on_a_constant_temperature_says_so(tmp_path, capsys):
    rows = sweep(500)
    rows[:, 1] = 31.25
    path = write(tmp_path / 'flat.csv', rows)
    for model in ('polynomial', 'relative'):
        code = main(['fit', path, '--model', model, '--out', str(tmp_path / 'p.yaml')])
        assert code == 2
        err = capsys.readouterr().err
        assert err == (f'error: {path}: the temperature does not vary: every row reads 31.25 C; '
                       'a bias(T) fit needs a recording over a temperature range (heat or cool '
                       'the sensor while recording)\n')


def output_cases(tmp_path):
    """(argv, what the error names) for bad output paths of every subcommand that writes."""
    csv_path = write(tmp_path / 'in.csv', sweep(400))
    params = tmp_path / 'p.yaml'
    assert main(['fit', csv_path, '--out', str(params)]) == 0
    a_file = tmp_path / 'a_file'
    a_file.write_text('x')
    (tmp_path / 'a_folder').mkdir()
    missing = tmp_path / 'missing'
    return [
        (['fit', csv_path, '--out', missing / 'p.yaml'], f'--out {missing / "p.yaml"}: '
                                                         f'folder {missing} does not exist'),
        (['fit', csv_path, '--out', tmp_path / 'a_folder'], 'is a folder; give a file name'),
        (['fit', csv_path, '--out', a_file / 'p.yaml'], f'{a_file} is not a folder'),
        (['evaluate', csv_path, '--params', params, '--out-csv', missing / 'c.csv'],
         f'--out-csv {missing / "c.csv"}: folder {missing} does not exist'),
        (['allan', csv_path, '--out', a_file], f'--out {a_file} is a file, not a folder'),
        (['convert', csv_path, '--out', tmp_path / 'a_folder'],
         'exists already; give a new folder'),
        (['convert', csv_path, '--out', missing / 'bag'], f'folder {missing} does not exist'),
        (['diagnose', csv_path, '--out', missing / 'report'],
         f'folder {missing} does not exist'),
        (['diagnose', csv_path, '--out', a_file], 'is a file, not a folder'),
        (['simulate', '--out', missing / 'sim.csv'], f'folder {missing} does not exist'),
        (['simulate', '--out', tmp_path / 'a_folder', '--format', 'mcap'],
         'exists already; give a new folder'),
        (['adis-bias', '--source', 'simulated', '--out', missing / 'p.yaml'],
         f'folder {missing} does not exist'),
    ]


def test_output_paths_are_checked_before_the_work(tmp_path, capsys):
    cases = output_cases(tmp_path)
    capsys.readouterr()
    for argv, needle in cases:
        code = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        assert out == '', f'{argv}: work started before the check: {out}'
        assert code == 2 and err.startswith('error: ') and err.count('\n') == 1, (argv, err)
        assert needle in err, (argv, err)


@pytest.mark.skipif(os.geteuid() == 0, reason='root writes into read-only folders')
def test_an_unwritable_output_folder_is_refused_before_the_work(tmp_path, capsys):
    csv_path = write(tmp_path / 'in.csv', sweep(400))
    locked = tmp_path / 'locked'
    locked.mkdir()
    locked.chmod(0o500)
    code = main(['fit', csv_path, '--out', str(locked / 'p.yaml')])
    assert_user_error(code, capsys, f'folder {locked} is not writable')
