"""
``mlx-tempcomp fleet``: every unit through the single-record command on a real Dask cluster.

Records are CSV files of a two-cycle -20..70 C chamber run, one axis, a
quadratic bias whose coefficients differ unit to unit; one unit's slope is ten
times the others' (the outlier the report must flag), two records are bad (a
missing file, a file that is no CSV), one unit has two records (diagnosed as
one). One LocalCluster of two workers, started as the fleet command starts its
own (`connect`), serves the module: the fleet runs reach it by ``--scheduler
ADDRESS``, as users give an existing Dask cluster. One fleet run on it serves
most tests; ``fleet fit``, the Ctrl-C test's interrupted run and the worker
settings' tests start a local cluster of their own, as a run without
``--scheduler`` does; the kill test starts a real ``dask scheduler`` and two
``dask worker`` processes and kills one while units run.
"""

import contextlib
from dataclasses import replace
import json
from pathlib import Path
import shutil
import signal
import subprocess
import sys

from fleet_runs import DASK, ROWS, run_cli, SLOPE_RAD_S_PER_C, wait_for, write_record
from mlx_tempcomp.fleet.manifest import read_manifest, RecordSpec, UnitSpec
from mlx_tempcomp.fleet.prior import FLEET_PARAMS, PRIOR_JSON, SHRUNK_PARAMS
from mlx_tempcomp.fleet.report import (COUNT_METRICS, FALSE_FLAGS_PER_FLEET, flag_groups,
                                       fleet_summary, outlier_threshold, OUTLIER_Z, robust_z)
from mlx_tempcomp.fleet.run import connect, finished, store_unit, WORKER_SETTINGS
from mlx_tempcomp.fleet.unit import MOMENTS_FILE, run_unit, UnitJob
from mlx_tempcomp.parameters.files import node_values
from mlx_tempcomp.parameters.models import build_model
import numpy as np
import pytest

GOOD_UNITS = ('a1', 'a2', 'a3', 'a4', 'a5', 'odd')
BAD_UNITS = {'gone': 'missing.csv', 'junk': 'junk.csv'}
# A unit of two records (one chip, re-mounted: the second PAIR_OFFSET_RAD_S off): one
# diagnosis of both, as mlx-tempcomp diagnose pair-1.csv pair-2.csv.
PAIR = ('pair-1.csv', 'pair-2.csv')
PAIR_OFFSET_RAD_S = 0.002


@pytest.fixture(scope='module')
def records(tmp_path_factory) -> Path:
    """Write the records and the manifest; give their folder."""
    folder = tmp_path_factory.mktemp('records')
    rows = ['unit,path']
    for seed, unit in enumerate(GOOD_UNITS):
        write_record(folder / f'{unit}.csv', seed, 10.0 if unit == 'odd' else 1.0)
        rows.append(f'{unit},{unit}.csv')
    for k, name in enumerate(PAIR):
        write_record(folder / name, len(GOOD_UNITS), noise_seed=100 + k,
                     offset_rad_s=k * PAIR_OFFSET_RAD_S)
    (folder / 'junk.csv').write_text('this is not\na recording\n', encoding='utf-8')
    rows += [f'{unit},{name}' for unit, name in BAD_UNITS.items()]
    rows += [f'pair,{name}' for name in PAIR]
    (folder / 'units.csv').write_text('\n'.join(rows) + '\n', encoding='utf-8')
    return folder


@pytest.fixture(scope='module')
def scheduler() -> str:
    """Start the module's cluster (two single-threaded worker processes); give its address."""
    client, cluster = connect(None, 2)
    client.close()
    yield cluster.scheduler_address
    cluster.close()


@pytest.fixture(scope='module')
def fleet_run(records, scheduler, tmp_path_factory) -> tuple:
    """Run fleet diagnose over the manifest on the module's cluster."""
    out = tmp_path_factory.mktemp('fleet') / 'out'
    result = run_cli(['fleet', 'diagnose', '--manifest', records / 'units.csv', '--out', out,
                      '--scheduler', scheduler, '--progress'])
    return out, result


def unit_files(folder: Path) -> dict:
    """Give {relative path: bytes} of a unit folder."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob('*'))
            if p.is_file()}


def same_as_diagnose(paths: list, unit: Path, single: Path) -> dict:
    """Run diagnose on ``paths`` into ``single``; check the unit folder has its files."""
    assert run_cli(['diagnose', *paths, '--out', single])[0] == 0
    fleet, alone = unit_files(unit), unit_files(single)
    assert set(fleet) == set(alone) | {'unit.json', 'log.txt', MOMENTS_FILE, SHRUNK_PARAMS}
    assert json.loads(fleet['report.json']) == json.loads(alone['report.json'])
    for name in ('params.yaml', 'report.md'):
        assert fleet[name].decode() == alone[name].decode().replace(str(single), str(unit))
    assert fleet['residual_vs_temperature.png'] == alone['residual_vs_temperature.png']
    return fleet


@pytest.mark.slow
def test_fleet_unit_is_the_single_record_command(records, fleet_run, tmp_path):
    same_as_diagnose([records / 'a1.csv'], fleet_run[0] / 'units' / 'a1', tmp_path / 'single')


@pytest.mark.slow
def test_a_unit_of_several_records_is_one_diagnose_of_them(records, fleet_run, tmp_path):
    fleet = same_as_diagnose([records / name for name in PAIR], fleet_run[0] / 'units' / 'pair',
                             tmp_path / 'single')
    assert f'Bias offset of {records / PAIR[1]}' in fleet['params.yaml'].decode()
    moments = json.loads(fleet[MOMENTS_FILE])['records']
    assert [m['path'] for m in moments] == [str(records / name) for name in PAIR]
    assert all(m['moments']['rows'] == ROWS for m in moments)
    entry = json.loads(fleet['unit.json'])
    assert entry['results'] == [{'folder': '', 'records': [m['path'] for m in moments]}]


def test_fleet_fit_is_the_single_record_command(records, tmp_path):
    out = tmp_path / 'out'
    # fsspec URLs: globbed by the client, fetched by the workers.
    url = f'file://{records}/{{unit}}.csv'
    code, stdout, stderr = run_cli(['fleet', 'fit', '--records', url, '--out', out,
                                    '--workers', 1, '--options=--max-order 3'])
    assert code == 1, 'junk.csv matches the pattern and fails'
    assert 'failed: junk: ' in stderr and 'junk.csv' in stderr
    single = tmp_path / 'a2.yaml'
    assert run_cli(['fit', records / 'a2.csv', '--out', single, '--max-order', 3])[0] == 0
    fleet = (out / 'units' / 'a2' / 'params.yaml').read_text()
    assert f'from file://{records}/a2.csv' in fleet
    assert fleet.replace('file://', '') == \
        single.read_text().replace(str(single), str(out / 'units/a2/params.yaml'))
    assert 'orders (chosen on held-out blocks' in (out / 'units' / 'a2' / 'log.txt').read_text()


def test_held_out_records_give_the_units_row_its_figures(records, scheduler, tmp_path):
    # Several files per unit from a URL pattern; a unit of one record cannot hold one out.
    for unit, names in (('two', ('a3.csv', 'a4.csv')), ('one', ('a5.csv',))):
        (tmp_path / unit).mkdir()
        for k, name in enumerate(names, start=1):
            (tmp_path / unit / f'{k}.csv').write_bytes((records / name).read_bytes())
    out = tmp_path / 'out'
    code, _, stderr = run_cli(['fleet', 'diagnose', '--records',
                               f'file://{tmp_path}/{{unit}}/*.csv', '--out', out, '--scheduler',
                               scheduler, '--options=--test each'])
    assert code == 1
    assert f'failed: one: file://{tmp_path}/one/1.csv: --test each holds out whole records' \
        in stderr
    urls = [f'file://{tmp_path}/two/{k}.csv' for k in (1, 2)]
    unit = out / 'units' / 'two'
    report = json.loads((unit / 'report.json').read_text())
    assert report['source'] == ', '.join(urls)
    assert [r['record'] for r in report['held_out_records']] == urls
    for name, data in unit_files(unit).items():
        if name.endswith(('.json', '.md', '.yaml', '.txt')):
            assert b'mlx-fleet-' not in data, f"{name} names the worker's cache"
    (row,) = json.loads((out / 'fleet.json').read_text())['rows']
    assert row['unit'] == 'two' and row['records'] == urls
    assert row['held_out'] == 'held_out_records' and row['held_out_records'] == urls
    held, summary = report['held_out_records'], report['held_out_summary']
    for kind, key in (('as_written', 'held_out_rms_rad_s'),
                      ('after_rezero', 'held_out_rms_after_rezero_rad_s')):
        pooled = sum(r['rows'] * r[kind]['diagnosed']['z']['rms'] ** 2 for r in held) / \
            sum(r['rows'] for r in held)
        assert row[key]['z'] == pytest.approx(np.sqrt(pooled), rel=1e-12)
    assert row['gain_over_cubic'] == summary['gain_as_written']
    assert row['gain_after_rezero'] == summary['gain_after_rezero']
    # Not the fold figure of the diagnosis over both records that wrote params.yaml.
    validation = report['settings']['validation']
    assert row['held_out_rms_rad_s'] != \
        {'z': report['comparison'][validation]['diagnosed']['z']['rms']}
    markdown = (out / 'fleet.md').read_text()
    assert '| after a re-zero: RMS | gain |' in markdown and '| two | 2 |' in markdown


def test_fit_runs_per_record_and_a_unit_read_two_ways_is_refused(records, tmp_path):
    """The worker's task itself (no cluster): what a unit of several records gives."""
    first, second = (str(records / name) for name in PAIR)
    job = UnitJob('fit', UnitSpec('pair', (RecordSpec(first), RecordSpec(second))), (),
                  str(tmp_path / 'out' / 'units' / 'pair'))
    outcome = run_unit(job)
    assert outcome['status'] == 'ok', outcome['error']
    assert {'record-1/params.yaml', 'record-2/params.yaml', 'record-1/log.txt',
            MOMENTS_FILE} <= set(outcome['files'])
    (tmp_path / 'out' / 'units').mkdir(parents=True)
    store_unit(job, outcome)
    rows = fleet_summary(tmp_path / 'out')['rows']
    assert [(r['unit'], r['record'], r['records']) for r in rows] == \
        [('pair', 'record-1', [first]), ('pair', 'record-2', [second])]
    mixed = UnitSpec('mixed', (RecordSpec(first), RecordSpec(second, columns='time=time')))
    outcome = run_unit(UnitJob('diagnose', mixed, (), str(tmp_path / 'mixed')))
    assert outcome['status'] == 'error' and outcome['error'] == \
        f"unit mixed: {second} has columns 'time=time', {first} no columns: diagnose reads " \
        'the records of a unit with one columns; give its rows the same, or make them units ' \
        'of their own'
    missing = str(records / 'missing.csv')
    broken = UnitSpec('broken', (RecordSpec(first), RecordSpec(missing)))
    outcome = run_unit(UnitJob('diagnose', broken, (), str(tmp_path / 'broken')))
    assert outcome['status'] == 'error' and f'{missing}: No such file' in outcome['error']
    assert '\n' not in outcome['error'] and first not in outcome['error']


@pytest.mark.slow
def test_a_bad_record_is_its_units_error_and_the_rest_complete(fleet_run):
    out, (code, stdout, stderr) = fleet_run
    assert code == 1
    assert '9 units: 7 done, 0 finished before (skipped), 2 failed' in stdout
    assert '7 done, 2 failed, 0 remaining' in stderr, 'the progress line'
    assert 'failed: junk: ' in stderr
    fleet = json.loads((out / 'fleet.json').read_text())
    failed = {f['unit']: f['error'] for f in fleet['failed']}
    assert set(failed) == set(BAD_UNITS)
    for unit, name in BAD_UNITS.items():
        assert '\n' not in failed[unit] and name in failed[unit], failed[unit]
        entry = json.loads((out / 'units' / unit / 'unit.json').read_text())
        assert entry['status'] == 'error' and entry['error'] == failed[unit]
    assert 'No such file' in failed['gone'] or 'does not exist' in failed['gone']
    for unit in GOOD_UNITS:
        assert json.loads((out / 'units' / unit / 'unit.json').read_text())['status'] == 'ok'
        assert (out / 'units' / unit / 'params.yaml').exists()
    assert not [p for p in (out / 'units').iterdir() if p.name.startswith('.')]


@pytest.mark.slow
def test_the_report_has_a_row_per_unit_and_flags_the_outlier(records, fleet_run):
    out = fleet_run[0]
    fleet = json.loads((out / 'fleet.json').read_text())
    assert [(r['unit'], r['record']) for r in fleet['rows']] == \
        [(u, '') for u in (*GOOD_UNITS, 'pair')]
    assert fleet['rows'][-1]['records'] == [str(records / name) for name in PAIR]
    for row in fleet['rows']:
        assert row['held_out'] == 'round_robin'
        assert row['held_out_rms_rad_s']['z'] > 0.0 and row['gain_over_cubic']['z'] > 0.0
        assert isinstance(row['effects']['z'], list)
    slopes = fleet['coefficients']['z']['slope_rad_s_per_c']
    assert slopes['units'] == len(GOOD_UNITS) + 1
    assert 0.8 * SLOPE_RAD_S_PER_C < slopes['median'] < 1.3 * SLOPE_RAD_S_PER_C
    flagged = {(o['unit'], o['metric']) for o in fleet['outliers']}
    assert ('odd', 'slope_rad_s_per_c') in flagged
    assert {unit for unit, _ in flagged} == {'odd'}, fleet['outliers']
    markdown = (out / 'fleet.md').read_text()
    assert '| odd |' in markdown and 'slope_rad_s_per_c' in markdown
    assert "diagnose fits one model over all of a unit's records (one row per unit" in markdown
    assert '| pair | 2 | effects |' in markdown and '| record |' not in markdown
    assert (out / 'fleet_coefficients.png').read_bytes()[:4] == b'\x89PNG'
    (out / 'fleet.json').unlink()
    assert run_cli(['fleet', 'report', '--out', out])[0] == 0
    assert json.loads((out / 'fleet.json').read_text()) == fleet


@pytest.mark.slow
def test_the_fleet_prior_and_shrunk_fits_load_in_the_node(records, fleet_run, tmp_path):
    out = fleet_run[0]
    assert 'fleet prior of 6 units (1 flagged unit left out' in fleet_run[1][1]
    prior = json.loads((out / PRIOR_JSON).read_text())
    assert prior['pooled'] == ['a1', 'a2', 'a3', 'a4', 'a5', 'pair']
    assert set(prior['excluded']) == {'odd'}, 'flagged by the report: shrunk, not pooled'
    assert prior['units']['pair']['rows'] == 2 * ROWS and prior['units']['pair']['records'] == 2
    assert prior['units']['odd']['axes']['z']['t_weight'] < 0.2
    design = prior['axes']['z']['design']
    assert design['order'] == 2 and not design['temperature_rate'], 'the records are quadratic'
    # The pair's own coefficients carry its last record's offset, as its params.yaml does.
    fleet = json.loads((out / 'fleet.json').read_text())
    row = fleet['rows'][-1]
    own = np.polynomial.polynomial.polyval(
        (fleet['reference_temperature_c'] - design['reference_temperature_c'])
        / design['temperature_scale_c'], prior['units']['pair']['axes']['z']['own'])
    assert row['unit'] == 'pair' and abs(own - row['bias_rad_s']['z']) < 0.1 * PAIR_OFFSET_RAD_S
    assert prior['axes']['z']['population']['converged']
    for path in [out / FLEET_PARAMS] + [out / 'units' / u / SHRUNK_PARAMS
                                        for u in (*GOOD_UNITS, 'pair')]:
        model = build_model(node_values(str(path), 'compensation_node'))
        assert model.name == 'effects' and model.inputs == frozenset()
    for unit in BAD_UNITS:
        assert not (out / 'units' / unit / SHRUNK_PARAMS).exists()
    code, stdout, _ = run_cli(['evaluate', records / 'a3.csv', '--params', out / FLEET_PARAMS,
                               '--json'])
    rms = json.loads(stdout)['averaged']['z']['rms']
    # The prior's bias curve is the fleet's: within the units' spread of a3 (offset 20 %).
    assert code == 0 and rms < 0.01
    params = (out / FLEET_PARAMS).read_text()
    (out / FLEET_PARAMS).unlink()
    assert run_cli(['fleet', 'report', '--out', out])[0] == 0
    assert (out / FLEET_PARAMS).read_text() == params


@pytest.mark.slow
def test_a_record_that_contradicts_the_fleet_keeps_its_params(fleet_run, tmp_path):
    """A unit's worker task and the report into a copy of the run: the prior tests its record."""
    out = tmp_path / 'out'
    shutil.copytree(fleet_run[0], out)
    # 10 degrees from 25 C of a chip whose curvature is 30 times the fleet's: the fleet's
    # curve, which its record is too short to tell, is not this unit's. Twice as noisy as the
    # fleet, so the report flags it (held-out RMS more than sqrt 2 times the fleet's) and the
    # prior shrinks it unpooled.
    rng = np.random.default_rng(3)
    time_s = np.arange(100) * 3.0
    temperature_c = 25.0 + time_s / 30.0 + rng.normal(0.0, 0.02, time_s.size)
    rate = 0.01 + SLOPE_RAD_S_PER_C * (temperature_c - 25.0) + \
        30 * 2e-6 * (temperature_c - 25.0) ** 2 + rng.normal(0.0, 1e-3, time_s.size)
    path = tmp_path / 'bent.csv'
    np.savetxt(path, np.column_stack([time_s, temperature_c, rate]), delimiter=',',
               header='time,temperature,gyro_z', comments='', fmt='%.17g')
    job = UnitJob('diagnose', UnitSpec('bent', (RecordSpec(str(path)),)), (),
                  str(out / 'units' / 'bent'))
    store_unit(job, run_unit(job))
    code, stdout, _ = run_cli(['fleet', 'report', '--out', out])
    assert code == 0 and '1 unit whose record rejects its shrunk fit' in stdout
    flagged = json.loads((out / 'fleet.json').read_text())['outliers']
    assert {(o['unit'], o['metric']) for o in flagged} >= {('bent', 'held_out_rms_rad_s')}
    units = json.loads((out / PRIOR_JSON).read_text())['units']
    assert units['bent']['axes']['z']['conflict']['rejected']
    assert units['bent']['kept_own'].endswith('it keeps its own params.yaml')
    assert not (out / 'units' / 'bent' / SHRUNK_PARAMS).exists()
    assert (out / 'units' / 'bent' / 'params.yaml').exists()
    for unit in (*GOOD_UNITS, 'pair'):
        assert not units[unit]['axes']['z']['conflict']['rejected'], unit
        assert (out / 'units' / unit / SHRUNK_PARAMS).exists()


def test_a_count_with_zero_mad_flags_only_counts_far_from_the_median():
    # The simulated fleet of docs/fleet.md: 189 of 200 units with no effect, 11 with one.
    counts = [0.0] * 189 + [1.0] * 11 + [2.0, 3.0, 5.0]
    z = robust_z(counts, COUNT_METRICS['effects'])
    flagged = sorted({value for value, score in zip(counts, z) if abs(score) > OUTLIER_Z})
    assert flagged == [3.0, 5.0]
    flags, thresholds = flag_groups([('effects', counts)])
    assert thresholds == [OUTLIER_Z] and [counts[k] for _, k, *_ in flags] == [3.0, 5.0]
    assert robust_z([2.0] * 6 + [1.0, 3.0], 1.0).tolist() == \
        pytest.approx([0.0] * 6 + [-1.349, 1.349], abs=1e-3)
    # A count whose MAD is not 0 keeps the plain robust z.
    spread = [0.0, 1.0, 1.0, 2.0, 2.0, 3.0, 9.0]
    assert robust_z(spread, 1.0).tolist() == pytest.approx(robust_z(spread).tolist())
    # A measured value with MAD 0 still takes the mean absolute deviation.
    assert robust_z([0.0] * 9 + [1.0])[-1] == pytest.approx(1.0 / (1.253314 * 0.1))


def normal_fleet(rng, units: int) -> list:
    """Give the measured metrics of a fleet drawn from one population (no outlier)."""
    return [('bias_rad_s', rng.normal(0.0, 0.01, units)),
            ('slope_rad_s_per_c', rng.normal(1e-4, 3e-4, units)),
            ('held_out_rms_rad_s', 6e-3 * np.exp(rng.normal(0.0, 0.03, units)))]


def test_a_fleet_without_outliers_gets_its_false_flags_from_the_rule_at_every_size():
    """
    Fleets drawn from one normal population, 5 to 1000 units, 300 seeded fleets each.

    The rule sets FALSE_FLAGS_PER_FLEET false flags per fleet in expectation, whatever its
    size: at most that share of fleets has one (within three binomial standard errors), so
    about 0.05 / N of the units, at most 0.5 % from 40 units up. A fixed 3.5 flags a unit
    in a third of the small fleets (the MAD of a few units is itself uncertain), and in a
    fifth of the 1000-unit ones.
    """
    rng = np.random.default_rng(30)
    fleets = 300
    bound = FALSE_FLAGS_PER_FLEET + 3.0 * np.sqrt(FALSE_FLAGS_PER_FLEET / fleets)
    for units in (5, 10, 40, 200, 1000):
        flagged_units = fleets_flagged = fixed_fleets = 0
        for _ in range(fleets if units < 1000 else fleets // 3):
            groups = normal_fleet(rng, units)
            flagged = {k for _, k, *_ in flag_groups(groups)[0]}
            flagged_units += len(flagged)
            fleets_flagged += bool(flagged)
            fixed_fleets += any(np.any(np.abs(robust_z(np.log(v) if 'rms' in m else v)) > 3.5)
                                for m, v in groups)
        drawn = fleets if units < 1000 else fleets // 3
        assert fleets_flagged / drawn <= bound, units
        assert units < 40 or flagged_units / (drawn * units) <= 0.005, units
        assert fixed_fleets / drawn > 2 * bound, 'a fixed threshold would flag more'
    assert outlier_threshold(5, 15) > 10.0 > 4.0 < outlier_threshold(200, 600) < 4.3
    assert outlier_threshold(1000, 3000) == pytest.approx(4.26, abs=0.1), 'the normal quantile'


def test_a_held_out_rms_is_judged_on_its_log_and_flagged_only_where_it_matters():
    """Forty units whose held-out RMS agree within 2 % (docs/fleet.md's fleet): 9 % is nothing."""
    rng = np.random.default_rng(17)
    rms = list(5.8e-3 * np.exp(rng.normal(0.0, 0.015, 36)))
    median = float(np.median(rms))
    odd = [1.09 * median, 1.5 * median, 0.6 * median, 0.0]
    flags, thresholds = flag_groups([('held_out_rms_rad_s', rms + odd)])
    assert robust_z(rms + odd)[36] > OUTLIER_Z, 'a robust z on the RMS itself flagged 9 %'
    assert {k: round(ratio, 2) for _, k, _, ratio in flags} == \
        {37: pytest.approx(1.5, abs=0.03), 38: pytest.approx(0.6, abs=0.02), 39: 0.0}
    # A value a fleet of one population holds can be far from its median: not an outlier.
    wide = list(5.8e-3 * np.exp(rng.normal(0.0, 0.5, 40)))
    assert flag_groups([('held_out_rms_rad_s', wide + [2.0 * float(np.median(wide))])])[0] == []


def test_slope_outliers_stand_out_of_a_fleet_of_200_and_nothing_else():
    """docs/fleet.md's fleet grown to 200: four chips 0.2 deg/s/C steeper (z about 9)."""
    rng = np.random.default_rng(4)
    groups = normal_fleet(rng, 200)
    slopes = groups[1][1]
    planted = [3, 60, 61, 150]
    slopes[planted] += np.radians(0.2)
    flags, thresholds = flag_groups(groups)
    assert sorted((group, k) for group, k, *_ in flags) == [(1, k) for k in planted]
    assert thresholds[:3] == [outlier_threshold(200, 600)] * 3


@pytest.mark.slow
def test_a_rerun_skips_finished_units_and_force_redoes_them(records, fleet_run, scheduler):
    out = fleet_run[0]
    manifest = records / 'units.csv'
    inode = {unit: (out / 'units' / unit / 'unit.json').stat().st_ino for unit in GOOD_UNITS}
    code, stdout, _ = run_cli(['fleet', 'diagnose', '--manifest', manifest, '--out', out])
    assert code == 1 and f'0 done, {len(GOOD_UNITS) + 1} finished before (skipped), 2 failed' \
        in stdout
    assert inode == {unit: (out / 'units' / unit / 'unit.json').stat().st_ino
                     for unit in GOOD_UNITS}
    # A unit is finished for the very records and options it ran with, and only for them.
    pair = {unit.unit: unit for unit in read_manifest(manifest)}['pair']
    job = UnitJob('diagnose', pair, (), str(out / 'units' / 'pair'))
    assert finished(job)
    assert not finished(replace(job, unit=UnitSpec('pair', pair.records[1:])))
    assert not finished(replace(job, unit=UnitSpec('pair', pair.records[::-1])))
    assert not finished(replace(job, options=('--test', 'each')))
    one = records / 'a1_only.csv'
    one.write_text('unit,path\na1,a1.csv\n', encoding='utf-8')
    code, stdout, _ = run_cli(['fleet', 'diagnose', '--manifest', one, '--out', out,
                               '--scheduler', scheduler, '--force'])
    assert code == 0 and '1 units: 1 done, 0 finished before (skipped), 0 failed' in stdout
    assert (out / 'units' / 'a1' / 'unit.json').stat().st_ino != inode['a1']


@pytest.mark.slow
def test_ctrl_c_keeps_what_finished_and_a_rerun_resumes(records, scheduler, tmp_path):
    manifest = tmp_path / 'good.csv'
    manifest.write_text('unit,path\n' + ''.join(f'{u},{records / u}.csv\n' for u in GOOD_UNITS),
                        encoding='utf-8')
    out = tmp_path / 'out'
    run = subprocess.Popen([sys.executable, '-m', 'mlx_tempcomp.cli', 'fleet', 'diagnose',
                            '--manifest', manifest, '--out', out, '--workers', '1'],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           # As from a terminal: a suite started in the background of a
                           # script inherits SIGINT ignored.
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # Not a staging folder (.a1.xxxx): a Ctrl-C before its rename removes it.
        wait_for(lambda: list(out.glob('units/[!.]*/unit.json')), 120.0, 'the first unit')
        run.send_signal(signal.SIGINT)
        stdout, stderr = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait(30)
    assert run.returncode == 130, stderr
    assert 'interrupted: rerun the same command to resume' in stdout
    finished = len(list(out.glob('units/[!.]*/unit.json')))
    assert 1 <= finished < len(GOOD_UNITS)
    code, stdout, _ = run_cli(['fleet', 'diagnose', '--manifest', manifest, '--out', out,
                               '--scheduler', scheduler])
    assert code == 0
    assert f'{len(GOOD_UNITS) - finished} done, {finished} finished before (skipped)' in stdout
    assert len(json.loads((out / 'fleet.json').read_text())['rows']) == len(GOOD_UNITS)


def test_mistakes_are_one_line_errors(records, tmp_path):
    for argv, expected in (
            (['--manifest', tmp_path / 'none.csv'], 'none.csv: No such file'),
            (['--records', 'no_unit_field/*.csv'], 'must hold {unit} once'),
            (['--records', f'{tmp_path}/{{unit}}.csv'], 'no record matches'),
            (['--manifest', records / 'units.csv', '--options=--folds x'],
             "--folds: expected a non-negative integer, got 'x'"),
            (['--manifest', records / 'units.csv', '--options=--out here'],
             'belong to the fleet command')):
        code, _, stderr = run_cli(['fleet', 'diagnose', '--out', tmp_path / 'out', *argv])
        assert code == 2 and stderr.startswith('error: ') and expected in stderr, stderr
        assert stderr.count('\n') == 1
    code, _, stderr = run_cli(['fleet', 'report', '--out', tmp_path])
    assert code == 2 and stderr == f'error: --out {tmp_path}: no units/ folder; run ' \
        'mlx-tempcomp fleet diagnose or fit first\n'


def test_simulate_fleet_writes_units_a_manifest_and_the_truth(tmp_path):
    out = tmp_path / 'fleet'
    code, stdout, _ = run_cli(['simulate', '--fleet', 4, '--fleet-outliers', 1, '--out', out,
                               '--duration-s', 20, '--rate-hz', 2, '--axes', 'z',
                               '--thermal-lag-s', 60, '--acceleration-dps-per-m-s2', 0, 0, 0.01])
    assert code == 0 and 'wrote 4 units' in stdout
    truth = json.loads((out / 'fleet_truth.json').read_text())
    assert [u['unit'] for u in truth['units']] == [f'unit-00{k}' for k in range(4)]
    assert sum(u['outlier'] for u in truth['units']) == 1
    lags = [u['effects']['thermal_lag_s'] for u in truth['units']]
    assert len(set(lags)) == 4 and all(30.0 <= lag <= 90.0 for lag in lags)
    g_z = [json.loads((out / u['truth']).read_text())['config']['effects']
           ['acceleration_dps_per_m_s2'][2] for u in truth['units']]
    assert len(set(g_z)) == 4 and all(0.005 <= g <= 0.015 for g in g_z)
    slopes = [json.loads((out / u['truth']).read_text())['devices']['z']
              ['zro_dps_coefficients'][1] for u in truth['units']]
    outlier = [s for s, u in zip(slopes, truth['units']) if u['outlier']][0]
    assert all(abs(outlier) > 0.1 > abs(s) for s, u in zip(slopes, truth['units'])
               if not u['outlier'])
    manifest = (out / 'units.csv').read_text().splitlines()
    assert manifest[0] == 'unit,path' and len(manifest) == 5


def test_a_fleet_chip_the_factory_could_not_store_is_drawn_again(tmp_path):
    """Seed 3582's unit 2 has a scale factor at 85 C beyond its EEPROM byte (1 in 10,000)."""
    out = tmp_path / 'fleet'
    code, stdout, stderr = run_cli(['simulate', '--fleet', 3, '--fleet-outliers', 0, '--seed',
                                    3582, '--out', out, '--duration-s', 20, '--rate-hz', 2])
    assert code == 0, stderr
    assert stdout.strip().endswith('chips the factory could not store, drawn again: 1')
    units = json.loads((out / 'fleet_truth.json').read_text())['units']
    assert [u.get('screened_out_seeds') for u in units] == [None, None, [358200002]]
    assert [u['seed'] for u in units] == [358200000, 358200001, 358200002 + 10 ** 9]
    assert json.loads((out / units[2]['truth']).read_text())['config']['seed'] == \
        units[2]['seed']
    # The unit alone, as simulate draws it: the error the fleet screens out.
    code, _, stderr = run_cli(['simulate', '--seed', 358200002, '--out', tmp_path / 'one.csv',
                               '--duration-s', 20, '--rate-hz', 2])
    assert code == 2 and 'is outside what the EEPROM byte can store' in stderr


@pytest.mark.slow
def test_a_killed_worker_costs_nothing(records, fleet_run, tmp_path):
    """A real scheduler and two workers; one is killed mid-run; the results are identical."""
    manifest = tmp_path / 'good.csv'
    manifest.write_text('unit,path\n' + ''.join(f'{u},{records / u}.csv\n' for u in GOOD_UNITS),
                        encoding='utf-8')
    scheduler_file = tmp_path / 'scheduler.json'
    started = []
    try:
        started.append(subprocess.Popen(
            [DASK, 'scheduler', '--host', '127.0.0.1', '--port', '0', '--no-dashboard',
             '--scheduler-file', scheduler_file], stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL))
        wait_for(scheduler_file.exists, 60.0, 'the scheduler file')
        for name in ('w1', 'w2'):
            started.append(subprocess.Popen(
                [DASK, 'worker', '--scheduler-file', scheduler_file, '--nthreads', '1',
                 '--no-nanny', '--no-dashboard', '--name', name], stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL))
        address = json.loads(scheduler_file.read_text())['address']
        out = tmp_path / 'out'
        fleet = subprocess.Popen(
            [sys.executable, '-m', 'mlx_tempcomp.cli', 'fleet', 'diagnose', '--manifest',
             manifest, '--out', out, '--scheduler', address], stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True)
        started.append(fleet)
        wait_for(lambda: len(list(out.glob('units/*/unit.json'))) >= 1, 120.0,
                 'the first unit')
        assert fleet.poll() is None, 'the run must still be going when the worker dies'
        started[1].send_signal(signal.SIGKILL)
        stdout, stderr = fleet.communicate(timeout=180)
        assert fleet.returncode == 0, stderr
        assert started[1].wait(10) == -signal.SIGKILL
        assert f'{len(GOOD_UNITS)} done' in stdout
        local = fleet_run[0] / 'units'
        for unit in GOOD_UNITS:
            # The shrunk fit is the fleet's (this fleet lacks the local run's pair and bad units).
            here, there = unit_files(out / 'units' / unit), unit_files(local / unit)
            del here[SHRUNK_PARAMS], there[SHRUNK_PARAMS]
            assert set(here) == set(there)
            for name, data in here.items():
                assert data.replace(str(out).encode(), b'') == \
                    there[name].replace(str(fleet_run[0]).encode(), b''), (unit, name)
    finally:
        for process in reversed(started):
            if process.poll() is None:
                process.kill()
            process.wait(30)


def test_the_local_clusters_workers_run_with_the_fleet_settings(monkeypatch):
    """No statistical profiler, slow monitors: the settings reach the worker processes."""
    import dask
    monkeypatch.delenv('DASK_SCHEDULER_ADDRESS', raising=False)
    client, cluster = connect(None, 1)
    try:
        seen = client.run(lambda: {key: dask.config.get(key) for key in WORKER_SETTINGS})
    finally:
        client.close()
        cluster.close()
    assert list(seen.values()) == [WORKER_SETTINGS]


def test_a_local_cluster_beside_another_warns_of_no_port(monkeypatch, recwarn):
    """Two fleet jobs at once: the second's scheduler takes a free port, and says nothing."""
    import socket
    monkeypatch.delenv('DASK_SCHEDULER_ADDRESS', raising=False)
    with socket.socket() as holder:   # Dask's default HTTP port, as another cluster holds it
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        with contextlib.suppress(OSError):   # already held: all the better
            holder.bind(('', 8787))
            holder.listen()
        client, cluster = connect(None, 1)
        client.close()
        cluster.close()
    assert [str(w.message) for w in recwarn if 'already in use' in str(w.message)] == []


@pytest.mark.slow
def test_the_simulated_fleet_flags_exactly_its_planted_slope_outliers(scheduler, tmp_path):
    """
    docs/fleet.md's simulated fleet, 20 units: the outliers are flagged on their slope, alone.

    An effect may not stand in for the temperature polynomial (a play operator as wide as
    the range once took an outlier's slope to 0), so the slope each unit writes is its own.
    The units' plots (nine tenths of a unit's time) are not what this checks: --no-plots.
    """
    fleet = tmp_path / 'fleet'
    code, _, _ = run_cli(['simulate', '--fleet', 20, '--fleet-outliers', 3, '--out', fleet,
                          '--axes', 'z', '--cycle-c', 70, -20, '--ramp-c-per-min', 3,
                          '--rate-hz', 0.5, '--thermal-lag-s', 60])
    assert code == 0
    truth = json.loads((fleet / 'fleet_truth.json').read_text())
    planted = {unit['unit'] for unit in truth['units'] if unit['outlier']}
    assert len(planted) == 3
    out = tmp_path / 'out'
    code, _, _ = run_cli(['fleet', 'diagnose', '--manifest', fleet / 'units.csv', '--out', out,
                          '--scheduler', scheduler, '--options=--no-plots'])
    assert code == 0
    report = json.loads((out / 'fleet.json').read_text())
    flagged = {(o['unit'], o['metric']) for o in report['outliers']}
    print(sorted(flagged))
    assert {unit for unit, metric in flagged if metric == 'slope_rad_s_per_c'} == planted
    assert {unit for unit, _ in flagged} == planted
