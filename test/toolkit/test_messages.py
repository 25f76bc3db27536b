"""
The console says what it means: the lines a new user misread, as they read now.

``fit``'s rule line names the order the one-standard-error rule picks and,
apart, the order with the lowest held-out RMS, and which order the cubic
replaces; ``evaluate`` says which rows it evaluated in words; ``inspect``
says that the thermal span it judges is that of the still samples, beside the
range over every sample.
"""

import re

from measured_data import FLIGHT_LOGS
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.fitting.bias_polynomial import select_orders
from mlx_tempcomp.recordings.load import load_recording
import pytest


@pytest.fixture(scope='module')
def cycle(tmp_path_factory):
    path = tmp_path_factory.mktemp('messages') / 'cycle.csv'
    assert main(['simulate', '--out', str(path), '--cycle-c', '60', '-20', '25',
                 '--ramp-c-per-min', '8', '--rate-hz', '1', '--seed', '2']) == 0
    return str(path)


def test_fit_rule_line_says_which_order_is_written_and_why(cycle, tmp_path, capsys):
    capsys.readouterr()
    assert main(['fit', cycle, '--out', str(tmp_path / 'fit.yaml')]) == 0
    out = capsys.readouterr().out
    recording = load_recording(cycle)
    selections = select_orders(recording.temperature_c, recording.rate_error_rad_s,
                               axes=recording.axes, candidate_orders=range(9))
    for selection in selections:
        (line,) = [line for line in out.splitlines() if line.startswith(f'{selection.axis}: ')]
        assert line.startswith(f'{selection.axis}: the PX4-style cubic unless another order '
                               'beats it on held-out blocks, fold by fold and by the margin')
        if selection.order == 3:
            assert line.endswith('no order does, so the cubic is written')
        else:
            assert f'): order {selection.order} does (of those that do, the lowest' in line
    assert ', '.join(f'{s.axis} {s.order}' for s in selections) in out


def test_evaluate_says_which_rows_it_evaluated(cycle, tmp_path, capsys):
    params = tmp_path / 'fit.yaml'
    assert main(['fit', cycle, '--out', str(params)]) == 0
    for argv, which in (([], '(every row)'),
                        (['--test-fraction', '0.25'],
                         '(the last 25% of the rows, --test-fraction 0.25)')):
        capsys.readouterr()
        assert main(['evaluate', cycle, '--params', str(params), *argv]) == 0
        (line,) = [line for line in capsys.readouterr().out.splitlines()
                   if line.startswith('evaluated ')]
        assert which in line and 'last 1 of' not in line


def test_inspect_says_the_span_it_judges_is_the_still_samples(capsys):
    path = FLIGHT_LOGS / 'px4_robologs_test.ulg'
    if not path.is_file():
        pytest.skip(f'flight log not present: {path} (set MLX_TEMPCOMP_SHARED)')
    assert main(['inspect', str(path), '--instance', '0']) == 0
    out = capsys.readouterr().out
    assert 'temperature 39.20 to 39.59 C over every sample' in out
    assert 'moved: 8 of 10 samples; 2 still samples with a temperature kept' in out
    assert re.search(r'not fit: the 2 still samples span 0\.\d\d C \(moving ones are left '
                     r'out\); a thermal calibration wants 10 C', out)
