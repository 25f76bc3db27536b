"""
``mlx-tempcomp diagnose A B C``: one model over several records of one unit.

Each record is a run of the same simulated device (`GyroPhysics`, the cubic
ZRO of test_diagnose.py, 0.02 deg/s white noise, 1 Hz) in the chamber of
test_diagnose.py, with a bias offset of its own (a re-mount between runs)
and noise of its own. The commands run with --no-plots: nothing here looks at the
plots (test_diagnose.py does), and drawing them is most of a run's time.
"""

import contextlib
import functools
import io
import json
import math

from cli_checks import assert_user_error
from diagnose_runs import device_run, NOISE_DPS, parameters_of, QUIET, run_cli, TEMPERATURE_NOISE_C
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.diagnosis import diagnose, DiagnosisSettings
from mlx_tempcomp.core.effects import EffectModel
from mlx_tempcomp.core.fitting.records import join_records
from mlx_tempcomp.core.fitting.validation import record_block_bounds, split
from mlx_tempcomp.core.node_models.interface import ModelInputs
from mlx_tempcomp.fleet.unit import parse_command
from mlx_tempcomp.parameters.files import flat_parameters
from mlx_tempcomp.recordings.recording import Recording
from mlx_tempcomp.simulation.chamber import chamber_profile
from mlx_tempcomp.simulation.physics import Effects, Scenario
from mlx_tempcomp.toolkit.running import run_handler
import numpy as np
import pytest

LAG_S = 200.0
REZERO_S = 10.0  # 11 samples at 1 Hz: imu/recalibrate_zro takes no fewer than 10
# Three runs of one unit: the first two cover the cold and the hot part of the range,
# the third (held out) all of it. (chamber legs, start C, offset deg/s)
RUNS = {'cold': (((-20.0, 2.0), (30.0, 2.0), (-20.0, 2.0)), 25.0, 0.1),
        'hot': (((70.0, 2.0), (20.0, 2.0), (70.0, 2.0)), 25.0, -0.2),
        'full': (((70.0, 2.0), (-20.0, 2.0), (70.0, 2.0)), 25.0, 0.3)}
# Two runs that start 90 C below where the one before ended.
JUMP_LEGS = {'first': ((70.0, 2.0), (-20.0, 1.0), (70.0, 3.0)),
             'second': ((70.0, 2.0), (-20.0, 1.0), (70.0, 1.0))}


@functools.lru_cache(maxsize=None)
def run(legs: tuple, start_c: float, offset_dps: float, seed: int,
        effects: Effects = Effects()) -> tuple:
    """Return (time s, temperature C, rate rad/s) of one run of the unit."""
    time_s, temperature_c, zro_dps = device_run(
        effects, QUIET, Scenario(thermal=chamber_profile(legs, start_c=start_c)), seed)
    rng = np.random.default_rng(seed + 100)
    return (time_s, temperature_c + rng.normal(0.0, TEMPERATURE_NOISE_C, time_s.size),
            np.radians(zro_dps + offset_dps + rng.normal(0.0, NOISE_DPS, time_s.size)))


def recording(name: str, legs: tuple, start_c: float, offset_dps: float, seed: int,
              effects: Effects = Effects()) -> Recording:
    time_s, temperature_c, rate_rad_s = run(legs, start_c, offset_dps, seed, effects)
    return Recording(name, time_s, temperature_c, ('z',), rate_rad_s[:, None])


def unit_runs() -> list:
    return [recording(name, *RUNS[name], seed) for seed, name in enumerate(RUNS)]


def held_out(diagnosis, scope: str, method: str = 'diagnosed') -> float:
    return diagnosis.comparison[scope][method][0].rms_rad_s


def test_records_lie_end_to_end_and_each_restarts_its_history():
    a = Recording('a', [10.0, 11.0, 12.0], [1.0, 2.0, 3.0], ('z',), np.zeros((3, 1)))
    b = Recording('b', [0.0, 2.0, 4.0, 6.0], [5.0, 6.0, 7.0, 8.0], ('z',), np.zeros((4, 1)))
    records = join_records([a, b])
    # b starts one of its own sample intervals after a ends.
    assert records.time_s.tolist() == [10.0, 11.0, 12.0, 14.0, 16.0, 18.0, 20.0]
    assert records.starts == (0, 3, 7) and records.own_time_s(18.0) == (1, 4.0)
    # A running sum stands for a history: it starts again at b's first row.
    assert records.each(np.cumsum, records.temperature_c).tolist() == \
        [1.0, 3.0, 6.0, 5.0, 11.0, 18.0, 26.0]
    # Blocks in proportion to rows, two at least, none spanning two records; forward,
    # the first block of a record only trains.
    edges, first = record_block_bounds([300, 100], 8)
    assert first == (0, 6) and 300 in edges.tolist()
    assert np.flatnonzero(split(8, min_past=0.25, record_starts=first).predicted).tolist() == \
        [2, 3, 4, 5, 7]


def test_one_model_over_the_records_beats_each_record_alone_on_the_held_out_one():
    """The held-out run spans -20..70 C; alone, the cold or the hot run covers half of it."""
    cold, hot, full = unit_runs()
    settings = DiagnosisSettings(test_record=True, rezero_s=REZERO_S)
    joint = diagnose([cold, hot, full], settings)
    alone = [diagnose([part, full], settings) for part in (cold, hot)]
    print(f'held-out run after a re-zero: one model over both runs '
          f'{held_out(joint, "test_rezeroed"):.3e} rad/s, the cold run alone '
          f'{held_out(alone[0], "test_rezeroed"):.3e}, the hot run alone '
          f'{held_out(alone[1], "test_rezeroed"):.3e}')
    for single in alone:
        assert held_out(joint, 'test_rezeroed') < 0.3 * held_out(single, 'test_rezeroed')
    # Each run's offset is its own, against the written one (the last run fitted: hot).
    fits = {fit.name: fit for fit in joint.records}
    assert fits['cold'].offset_rad_s[0] == pytest.approx(math.radians(0.1 + 0.2), rel=0.02)
    assert fits['hot'].offset_rad_s == (0.0,) and fits['full'].offset_rad_s is None
    assert [fit.fitted for fit in joint.records] == [True, True, False]
    # As written, the held-out run is off by its offset against the hot run's.
    assert held_out(joint, 'test') == pytest.approx(math.radians(0.3 + 0.2), rel=0.05)
    assert joint.rezero_rad_s['diagnosed'][0] == pytest.approx(math.radians(0.5), rel=0.05)
    # The cubic has the same per-run offsets and the same re-zero: here it is the model.
    assert held_out(joint, 'test_rezeroed', 'px4_cubic') == \
        pytest.approx(held_out(joint, 'test_rezeroed'), rel=1e-3)


def test_a_lag_fitted_over_two_runs_is_the_truth():
    """The second run starts 90 C below where the first ended."""
    runs = [recording(name, legs, -20.0, offset, seed, Effects(thermal_lag_s=LAG_S))
            for (name, legs), offset, seed in zip(JUMP_LEGS.items(), (0.1, -0.2), (1, 2))]
    axis = diagnose(runs).per_axis[0]
    assert axis.effects == ('temperature_polynomial', 'thermal_lag')
    assert axis.steps[1].parameters['thermal_lag_s'] == pytest.approx(LAG_S, rel=0.15)


def test_each_run_starts_its_history_afresh():
    """
    A thermal gradient over the two runs: found; the same rows as one record do worse.

    As one record, the lag of the gradient carries 70 C from the end of the
    first run into the second, which starts at -20 C: a bias of 1.8 deg/s that
    no run had, hiding the effect (a play operator stands in for part of it).
    """
    effects = Effects(gradient_time_constants_s=(600.0,), gradient_dps_per_c=(0.02,))
    first, second = (run(legs, -20.0, 0.1, seed, effects)
                     for legs, seed in zip(JUMP_LEGS.values(), (1, 2)))
    runs = [Recording(name, *columns[:2], ('z',), columns[2][:, None])
            for name, columns in zip(JUMP_LEGS, (first, second))]
    separate = diagnose(runs).per_axis[0]
    time_s = np.concatenate([first[0], second[0] + first[0][-1] + 1.0 - second[0][0]])
    temperature_c, rate_rad_s = (np.concatenate([a, b]) for a, b in zip(first[1:], second[1:]))
    as_one = diagnose(Recording('as one', time_s, temperature_c, ('z',),
                                rate_rad_s[:, None])).per_axis[0]
    print(f'held-out RMS / the cubic: runs apart {separate.choice.ratio:.2f} '
          f'({", ".join(separate.effects)}), as one record {as_one.choice.ratio:.2f} '
          f'({", ".join(as_one.effects)})')
    assert separate.effects[:2] == ('temperature_polynomial', 'thermal_gradient')
    assert separate.choice.written == 'diagnosed' and separate.choice.ratio < 0.2
    assert 'thermal_gradient' not in as_one.effects
    assert as_one.choice.ratio > 4.0 * separate.choice.ratio


def write_runs(folder, names=tuple(RUNS), extra=None) -> list:
    """Write runs of the unit as CSV files (time, temperature, gyro_z); give their paths."""
    paths = []
    for seed, name in enumerate(names):
        time_s, temperature_c, rate_rad_s = run(*RUNS[name], seed)
        columns = {'time': time_s, 'temperature': temperature_c, 'gyro_z': rate_rad_s}
        columns.update((extra or {}).get(name, {}))
        path = folder / f'{name}.csv'
        np.savetxt(path, np.column_stack([np.broadcast_to(v, time_s.shape)
                                          for v in columns.values()]),
                   delimiter=',', header=','.join(columns), comments='', fmt='%.17g')
        paths.append(str(path))
    return paths


@pytest.fixture(scope='module')
def runs_csv(tmp_path_factory):
    return write_runs(tmp_path_factory.mktemp('runs'))


def node_residual(out, path) -> np.ndarray:
    """Run the written params.yaml model over a record from its start: corrected rate."""
    values = parameters_of(out)
    model = EffectModel.from_parameters(flat_parameters(values['effects']), values['axes'])
    table = np.genfromtxt(path, delimiter=',', names=True)
    return model.correct(table['gyro_z'][:, None], table['temperature'],
                         ModelInputs(time_s=table['time'])).rate_rad_s[:, 0]


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def test_cli_test_record_holds_out_the_last_run_as_the_node_would_run_it(runs_csv, tmp_path):
    out = tmp_path / 'out'
    stdout, _ = run_cli(['diagnose', *runs_csv, '--test', 'record', '--rezero-s', REZERO_S,
                         '--out', out, '--no-plots'])
    report = json.loads((out / 'report.json').read_text())
    cold, hot, full = runs_csv
    assert report['settings']['test'] == 'record' and report['settings']['rezero_s'] == REZERO_S
    assert report['written_offset']['record'] == hot
    assert [r['fitted'] for r in report['records']] == [True, True, False]
    (held,) = report['held_out_records']
    assert held['record'] == full and held['fitted_on'] == [cold, hot]
    # The written model run over the held-out record from its first row, at 1 s bins (one
    # sample each), gives the reported figures: as written, and less its mean over the
    # first 10 s (11 samples).
    corrected = node_residual(out, full)
    assert held['as_written']['diagnosed']['z']['rms'] == pytest.approx(rms(corrected),
                                                                        rel=1e-9)
    assert held['after_rezero']['diagnosed']['z']['rms'] == pytest.approx(
        rms(corrected - corrected[:11].mean()), rel=1e-9)
    assert held['rezero_rad_s']['diagnosed']['z'] == pytest.approx(corrected[:11].mean(),
                                                                   rel=1e-9)
    assert report['comparison']['test_rezeroed']['diagnosed']['z'] == \
        held['after_rezero']['diagnosed']['z']
    gain = held['gain_after_rezero']['z']
    assert gain == pytest.approx(held['after_rezero']['px4_cubic']['z']['rms']
                                 / held['after_rezero']['diagnosed']['z']['rms'])
    assert f'held out {full}: gain over the PX4-style cubic' in stdout
    assert 'after a re-zero over its first 10 s' in stdout
    assert stdout.splitlines()[-1].startswith('axis z: writes')
    assert f'Bias offset of {hot}, the last record fitted' in (out / 'params.yaml').read_text()
    report_md = (out / 'report.md').read_text()
    assert '## Records' in report_md and '### Held-out records' in report_md
    assert f'### Test record {full}, after a re-zero' in report_md


@pytest.mark.slow
def test_cli_test_each_leaves_each_record_out_then_writes_all(runs_csv, tmp_path):
    out = tmp_path / 'out'
    stdout, _ = run_cli(['diagnose', *runs_csv, '--test', 'each', '--rezero-s', REZERO_S,
                         '--out', out, '--no-plots'])
    report = json.loads((out / 'report.json').read_text())
    held = report['held_out_records']
    assert [r['record'] for r in held] == runs_csv
    assert held[0]['fitted_on'] == runs_csv[1:] and held[1]['fitted_on'] == runs_csv[::2]
    summary = report['held_out_summary']
    for kind in ('gain_as_written', 'gain_after_rezero'):
        assert summary[kind]['z'] == pytest.approx(
            math.exp(np.mean([math.log(r[kind]['z']) for r in held])))
    # params.yaml comes from all three, with the last one's offset; no test part there.
    assert report['settings']['test'] == 'each' and report['rows']['test'] == 0
    assert all(r['fitted'] for r in report['records'])
    assert report['written_offset']['record'] == runs_csv[-1]
    assert 'leave one record out, geometric mean of the gains over the cubic' in stdout
    for path in runs_csv:
        assert f'held out {path}: ' in stdout


def test_cli_refuses_records_it_cannot_join_or_hold_out(tmp_path, capsys):
    cold, hot, full = write_runs(tmp_path)
    out = str(tmp_path / 'out')

    def refused(argv, *needles):
        assert_user_error(main(['diagnose', *argv, '--out', out]), capsys, *needles)

    x_axis = tmp_path / 'x_axis.csv'
    x_axis.write_text(open(hot).read().replace('gyro_z', 'gyro_x', 1))
    refused([cold, str(x_axis)], f'{x_axis}: gyro axes x, but {cold} has z')
    (tmp_path / 'supply').mkdir()
    (supply,) = write_runs(tmp_path / 'supply', ('hot',), {'hot': {'supply_voltage': 5.0}})
    refused([cold, supply], f'{supply}: has supply_voltage, which {cold} lacks')
    refused([cold, '--test', 'record'], f'{cold}: --test record holds out whole records')
    refused([cold, '--test', 'each'], '--test each holds out whole records')
    refused([cold, hot, '--test', '0.25'], 'hold out a whole record (--test record')
    refused([cold, hot, '--record-effects'], "record-only effects run on one record's clock")
    refused([cold, hot, cold], f'{cold} is given twice')
    refused([cold, hot, '--px4-params', str(tmp_path / 'p.params')],
            'export the cubic of one record')
    refused([cold, hot, '--instance', 'all'], '--instance all runs one record per IMU instance')
    # The node's re-zero needs 10 samples in its window, and the record must be that long.
    refused([cold, hot, '--test', 'record', '--rezero-s', '5'],
            f'{hot}: its first 5 s hold 6 samples, and imu/recalibrate_zro refuses fewer '
            'than 10: give --rezero-s 9 or more')
    refused([cold, hot, '--test', 'each', '--rezero-s', '1e5'],
            f'{cold}: the record lasts 6.15e+03 s, shorter than the re-zero window')
    refused([cold, str(tmp_path / 'missing.csv')], 'missing.csv')
    assert not (tmp_path / 'out').exists()


# Issue 15's kept-back record, shortened: three periods of a motionless 3-axis IMU at
# 1 Hz, ramping at 0.08 C/min between 5 and 24 C (4 h a ramp), re-mounted between
# periods (a bias offset each). (start C, turning temperatures, offset deg/s)
PERIODS = ((15.0, (24.0, 5.0), 0.05), (10.0, (5.0, 24.0), -0.03), (20.0, (24.0, 5.0), 0.1))
PERIOD_S = 14000


@pytest.mark.slow
def test_three_periods_of_slow_ramps_held_out_are_no_worse_than_the_cubic(tmp_path):
    """
    A stand-in for issue 15's kept-back record: diagnose P0 P1 P2 --test record --average-s 60.

    Simulated MLX90609 chips at rest (the same seed: one unit), each period one ramp up
    and most of one down (the record has three of each per period). At 1 Hz the node's 5 s
    re-zero window holds 6 samples, which imu/recalibrate_zro refuses: without --rezero-s
    the judgement widens it to the 9 s that hold 10, as a node at 1 Hz would be set.
    """
    paths = []
    for index, (start_c, cycle_c, offset_dps) in enumerate(PERIODS):
        paths.append(tmp_path / f'P{index}.csv')
        run_cli(['simulate', '--out', paths[-1], '--rate-hz', 1, '--start-c', start_c,
                 '--cycle-c', *cycle_c, '--ramp-c-per-min', 0.08, '--duration-s', PERIOD_S,
                 '--bias-step', f'0:{offset_dps}'])
    out = tmp_path / 'out'
    stdout, _ = run_cli(['diagnose', *paths, '--test', 'record', '--average-s', 60,
                         '--out', out, '--no-plots'])
    print(stdout)
    report = json.loads((out / 'report.json').read_text())
    assert report['settings']['rezero_s'] == 9.0
    assert 'recalibration.duration_s: 9' in stdout
    (held,) = report['held_out_records']
    for kind in ('gain_as_written', 'gain_after_rezero'):
        for axis, gain in held[kind].items():
            assert gain >= 1.0 / 1.05, (kind, axis)


@pytest.mark.slow
def test_the_fleet_runs_several_records_as_one_command(runs_csv, tmp_path):
    """A fleet worker parses the command with diagnose's own parser and runs its handler."""
    out = tmp_path / 'out'
    args = parse_command(['diagnose', *runs_csv, '--out', str(out), '--test', 'record',
                          '--rezero-s', str(REZERO_S), '--no-plots'])
    assert args.records == runs_csv and args.input == runs_csv[0]
    with contextlib.redirect_stdout(io.StringIO()):
        assert run_handler(args) == 0
    report = json.loads((out / 'report.json').read_text())
    assert [r['record'] for r in report['records']] == runs_csv
    assert report['held_out_records'][0]['record'] == runs_csv[-1]


def test_a_written_cubic_is_the_baseline_in_every_scope_of_several_records():
    """Three clean runs, the last held out: the cubic is written, its figures the cubic's."""
    diagnosis = diagnose(unit_runs(), DiagnosisSettings(test_record=True, rezero_s=REZERO_S))
    (axis,) = diagnosis.per_axis
    assert axis.choice.written == 'px4_cubic'
    scopes = ('round_robin', 'forward', 'test', 'test_rezeroed')
    assert set(scopes) <= set(diagnosis.comparison)
    for scope in scopes:
        found, cubic = (diagnosis.comparison[scope][method][0]
                        for method in ('diagnosed', 'px4_cubic'))
        for name in ('rms_rad_s', 'peak_rad_s', 'fold_rms_rad_s', 'block_rms_rad_s'):
            np.testing.assert_array_equal(getattr(found, name), getattr(cubic, name),
                                          err_msg=f'{scope} {name}')
    assert diagnosis.rezero_rad_s['diagnosed'] == diagnosis.rezero_rad_s['px4_cubic']
