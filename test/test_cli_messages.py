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
from mlx_tempcomp.core.fitting import select_orders
from mlx_tempcomp.core.validation import one_standard_error
from mlx_tempcomp.sources.recording import load_recording
import pytest


@pytest.fixture(scope='module')
def cycle(tmp_path_factory):
    path = tmp_path_factory.mktemp('messages') / 'cycle.csv'
    assert main(['simulate', '--out', str(path), '--cycle-c', '60', '-20', '25',
                 '--ramp-c-per-min', '8', '--rate-hz', '1', '--seed', '2']) == 0
    return str(path)


def test_fit_rule_line_tells_the_best_order_from_the_chosen_one(cycle, tmp_path, capsys):
    capsys.readouterr()
    assert main(['fit', cycle, '--out', str(tmp_path / 'fit.yaml')]) == 0
    out = capsys.readouterr().out
    recording = load_recording(cycle)
    selections = select_orders(recording.temperature_c, recording.rate_error_rad_s,
                               axes=recording.axes, candidate_orders=range(9))
    apart = 0
    for selection in selections:
        (line,) = [line for line in out.splitlines() if line.startswith(f'{selection.axis}: ')]
        best = min(selection.scores, key=lambda score: score.mean_rms_rad_s).order
        rule = one_standard_error(selection.scores)   # the rule's pick, before the cubic's
        if best == rule:
            assert f'order {rule} has the lowest mean held-out RMS' in line
        else:
            apart += 1
            assert (f'order {rule} is the lowest order whose mean held-out RMS is within one '
                    f'standard error of the lowest, which order {best} has') in line
        if selection.order != rule:
            assert f'order 3 written instead of order {rule}: ' in line
    assert apart, 'the record should hold an axis whose best order is not the chosen one'


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
