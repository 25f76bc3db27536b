"""
Replay the recording `diagnose` studied through the nodes, with the parameter file it wrote.

Replaying the data through driver_node and compensation_node gives the
offline numbers: on the project's simulated chips with a hysteresis the
diagnosis is not told about, and on the measured thermal cycle (converted to
a bag), whose diagnosed model keeps thermal-gradient lags, a rate window and
play-operator state that the node must carry from sample to sample; and on
simulated chips with a supply-voltage ZRO shift, whose voltage travels in the
bag as sensor_msgs/BatteryState.

The test-part figures have two definitions: `evaluate --test-fraction F`
takes every row in the last F of the time and the plain RMS of its bin means;
`diagnose --test-fraction F` keeps the last floor(F x rows) rows and weights
each bin mean by its row count. Each is recomputed from the node's output
its own way.
"""

import csv
import json
import math

from measured_data import MEASURED_CSV
from mlx_tempcomp.cli import main
from mlx_tempcomp.recordings.bag import RawTopics
from mlx_tempcomp.recordings.bag_reader import RawBagReader
import numpy as np
import pytest
from ros_harness import by_stamp, finish_model_replay, start_model_replay

pytestmark = pytest.mark.ros

# Three axes, 2 Hz for 2000 s (4001 rows), two -10..60 C cycles; a 0.3 deg/s hysteresis,
# or a 2 deg/s/V ZRO shift on a supply wandering 4.8 to 5.3 V.
CYCLES = ('--axes', 'x,y,z', '--rate-hz', '2', '--duration-s', '2000', '--seed', '1',
          '--cycle-c', '60', '-10', '60', '-10', '60', '--ramp-c-per-min', '8')
HYSTERESIS = ('--hysteresis-dps', '0.3', '--hysteresis-width-c', '5')
TEST_FRACTION = 0.25
AVERAGE_S = 1.0
STATEFUL_EFFECTS = {'hysteresis', 'thermal_lag', 'thermal_gradient', 'temperature_rate'}
SUPPLY = ('--zro-supply-dps-per-v', '2', '--supply-v', '0:5.0', '500:5.3', '900:4.8',
          '1400:5.2', '2000:4.9')
TOLERANCE_RAD_S = 1e-9
RELATIVE = 1e-9


def run(capsys, *argv) -> str:
    """Run an mlx-tempcomp command in this process; give what it printed."""
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return captured.out


def bag_stamps(bag) -> tuple:
    """Give the Imu stamps (ns) of a raw bag and the number of messages in it."""
    stamps, messages = [], 0
    with RawBagReader(bag, RawTopics()) as reader:
        for _, topic, record in reader.records():
            messages += 1
            if topic == RawTopics.imu:
                stamps.append(record.stamp_ns)
    return stamps, messages


def bin_means(time_s: np.ndarray, error: np.ndarray) -> tuple:
    """Give the means (bins, axes) over AVERAGE_S bins from time_s[0] and their row counts."""
    index = np.floor((time_s - time_s[0]) / AVERAGE_S).astype(np.int64)
    starts = np.flatnonzero(np.concatenate(([True], index[1:] != index[:-1])))
    counts = np.diff(np.append(starts, len(time_s)))
    return np.add.reduceat(error, starts, axis=0) / counts[:, None], counts


def held_out_figures(time_s: np.ndarray, error: np.ndarray) -> dict:
    """Test-part figures as diagnose and evaluate define them: last rows, bins weighted by rows."""
    first = len(time_s) - int(math.floor(TEST_FRACTION * len(time_s)))
    means, counts = bin_means(time_s[first:], error[first:])
    weights = counts[:, None] / np.sum(counts)
    return {'rows': len(time_s) - first, 'bins': len(means),
            'per_sample_rms': np.sqrt(np.mean(np.square(error[first:]), axis=0)),
            'rms': np.sqrt(np.sum(weights * np.square(means), axis=0)),
            'peak': np.max(np.abs(means), axis=0)}


@pytest.mark.slow
def test_node_replay_of_a_diagnose_file_matches_the_offline_evaluation(
        launcher, probe, tmp_path, capsys):
    csv = tmp_path / 'sim.csv'
    run(capsys, 'simulate', '--out', csv, *CYCLES, *HYSTERESIS)
    replay_and_compare(launcher, probe, tmp_path, capsys, csv, ())


def float32_supply(path) -> None:
    """Round the supply_voltage column to float32, the type of BatteryState.voltage."""
    with open(path, newline='') as stream:
        rows = list(csv.reader(stream))
    column = rows[0].index('supply_voltage')
    for row in rows[1:]:
        row[column] = repr(float(np.float32(float(row[column]))))
    with open(path, 'w', newline='') as stream:
        csv.writer(stream).writerows(rows)


@pytest.mark.slow
def test_node_replay_with_the_supply_voltage_in_the_bag_matches_the_offline_evaluation(
        launcher, probe, tmp_path, capsys):
    csv_path = tmp_path / 'supply.csv'
    run(capsys, 'simulate', '--out', csv_path, *CYCLES, *SUPPLY)
    # The offline paths read the volts the node will get.
    float32_supply(csv_path)
    replay_and_compare(launcher, probe, tmp_path, capsys, csv_path, (), {'supply_voltage'},
                       {'supply_voltage.pairing': 'stamp'})


@pytest.mark.slow
def test_node_replay_of_the_measured_cycle_reproduces_the_held_out_figures(
        launcher, probe, tmp_path, capsys):
    if not MEASURED_CSV.is_file():
        pytest.skip(f'measured data not present: {MEASURED_CSV}')
    report = replay_and_compare(launcher, probe, tmp_path, capsys, MEASURED_CSV,
                                ('--preset', 'tofupilot'))
    # Live-runnable effects only: the file the node ran holds no stamp of the record.
    for axis in report['axes'].values():
        assert all(step['live'] for step in axis['steps'])
        assert {f['effect'] for f in axis['findings']} == {'time_drift', 'bias_step'}


def replay_and_compare(launcher, probe, tmp_path, capsys, csv, options: tuple,
                       wanted=STATEFUL_EFFECTS, node_params=None) -> dict:
    """
    Diagnose ``csv``, replay it as a bag through the nodes on the diagnosed file.

    Diagnose must add one of the ``wanted`` effects: the one the replay shows the
    node carries.

    The node's output must equal the offline evaluation to 1e-9 rad/s and give
    the test-part figures `diagnose` and `evaluate` reported; return the report.
    """
    out, bag = tmp_path / 'diagnosis', tmp_path / 'bag'
    run(capsys, 'diagnose', csv, *options, '--test-fraction', TEST_FRACTION, '--average-s',
        AVERAGE_S, '--out', out, '--no-plots')
    report = json.loads((out / 'report.json').read_text())
    axes = tuple(report['axes'])
    assert axes == ('x', 'y', 'z')
    added = {step['effect'] for a in axes for step in report['axes'][a]['steps'][1:]}
    assert added & wanted, f'diagnose added {sorted(added) or "nothing"}'

    offline_csv = tmp_path / 'offline.csv'
    evaluation = json.loads(run(capsys, 'evaluate', csv, *options, '--params',
                                out / 'params.yaml',
                                '--test-fraction', TEST_FRACTION, '--average-s', AVERAGE_S,
                                '--json', '--out-csv', offline_csv))
    assert evaluation['model'] == 'effects' and evaluation['truth'] == 'zero (at rest)'
    offline = np.genfromtxt(offline_csv, delimiter=',', names=True)
    time_s = offline['time']
    expected = np.column_stack([offline[f'gyro_{a}'] for a in axes])
    # The standard deviation the node publishes with each sample, as evaluate computes it.
    std = np.column_stack([offline[f'std_{a}'] for a in axes])
    run(capsys, 'convert', csv, *options, '--out', bag)
    stamps_ns, messages = bag_stamps(bag)
    assert len(stamps_ns) == len(time_s)
    # Within the float64 resolution of the stamps (3e-8 s at 2.6e8 s on the measured clock).
    assert np.max(np.abs(np.array(stamps_ns) / 1e9 - time_s)) <= 1e-7

    start_model_replay(launcher, probe, tmp_path, bag, str(out / 'params.yaml'),
                       **(node_params or {}))
    got = np.array(finish_model_replay(launcher, probe, stamps_ns, messages))
    difference = np.max(np.abs(got - expected))
    print(f'{len(got)} samples, largest |node - offline| {difference:.3g} rad/s')
    assert difference <= TOLERANCE_RAD_S
    published = by_stamp(probe.received['imu/data'])
    variance = np.array([[published[s].angular_velocity_covariance[4 * k] for k in range(3)]
                         for s in stamps_ns])
    np.testing.assert_allclose(variance, std ** 2, rtol=1e-9)

    # At rest the truth is 0: the node's output is its error.
    node = held_out_figures(time_s, got)
    assert node['rows'] == report['rows']['test'] == evaluation['per_sample']['x']['samples']
    assert node['bins'] == evaluation['averaged']['x']['samples']
    test = report['comparison']['test']['diagnosed']
    for i, a in enumerate(axes):
        print(f'{a}: node test-part rms {node["rms"][i]:.9e} rad/s over {node["rows"]} rows; '
              f'evaluate {evaluation["averaged"][a]["rms"]:.9e}, diagnose {test[a]["rms"]:.9e}')
        assert node['per_sample_rms'][i] == pytest.approx(
            evaluation['per_sample'][a]['rms'], rel=RELATIVE)
        for figure in ('rms', 'peak'):
            assert node[figure][i] == pytest.approx(evaluation['averaged'][a][figure],
                                                    rel=RELATIVE)
            assert node[figure][i] == pytest.approx(test[a][figure], rel=RELATIVE)
    return report
