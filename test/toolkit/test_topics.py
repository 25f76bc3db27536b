"""
The default topics meet the bags the package writes: the driver's raw output.

``simulate`` and ``convert`` write ``/imu/data_raw`` and
``/imu/temperature_raw``, as every driver publishes; the commands that read a
bag read those by default, so a simulated bag feeds each of them with no
topic option, and ``fleet fit --records 'bags/{unit}/*.mcap'`` (docs/fleet.md)
fits every unit. ``convert``'s replay hint is the driver command docs/ros.md
gives, ``bag.rate_factor:=0.0`` included.
"""

import json
from pathlib import Path

from mlx_tempcomp.cli import main
from mlx_tempcomp.recordings.load import load_recording
import pytest

CYCLE = ['--cycle-c', '60', '-20', '25', '--ramp-c-per-min', '8', '--rate-hz', '1']


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('bag') / 'cycle'
    assert main(['simulate', '--out', str(path), '--format', 'mcap', *CYCLE]) == 0
    return str(path)


@pytest.mark.parametrize('command', [
    ['inspect', '{bag}'],
    ['fit', '{bag}', '--out', '{tmp}/fit.yaml'],
    ['diagnose', '{bag}', '--out', '{tmp}/diagnosis', '--no-plots'],
    ['allan', '{bag}'],
    ['evaluate', '{bag}', '--params', '{tmp}/fit.yaml'],
])
def test_each_command_reads_a_simulated_bag_without_topic_options(
        bag, tmp_path, capsys, command):
    assert main(['fit', bag, '--out', str(tmp_path / 'fit.yaml')]) == 0
    capsys.readouterr()
    assert main([part.format(bag=bag, tmp=tmp_path) for part in command]) == 0
    rows = len(load_recording(bag, imu_topic='/imu/data_raw',
                              temperature_topic='/imu/temperature_raw'))
    assert f'{bag}: {rows} rows used' in capsys.readouterr().out


def test_the_help_says_which_topic_is_read(capsys):
    with pytest.raises(SystemExit):
        main(['fit', '--help'])
    help_text = ' '.join(capsys.readouterr().out.split())
    assert 'Imu topic read from a bag (default: /imu/data_raw' in help_text
    assert 'Temperature topic read from a bag (default: /imu/temperature_raw)' in help_text


def test_convert_prints_the_replay_command_of_docs_ros(tmp_path, capsys):
    csv = tmp_path / 'cycle.csv'
    assert main(['simulate', '--out', str(csv), *CYCLE, '--axes', 'z']) == 0
    assert main(['convert', str(csv), '--out', str(tmp_path / 'bag')]) == 0
    hint = capsys.readouterr().out.splitlines()[-1]
    assert hint == (f'replay: driver_node --ros-args -p source:=bag -p bag.path:={tmp_path}/bag '
                    '-p bag.rate_factor:=0.0 -p "axes:=[\'z\']"')
    ros = (Path(__file__).resolve().parents[2] / 'docs' / 'ros.md').read_text()
    assert '-p bag.rate_factor:=0.0' in ros


def test_fleet_fit_on_a_bags_pattern_fits_every_unit(tmp_path, capsys):
    for unit in ('unit-a', 'unit-b'):
        (tmp_path / 'bags' / unit).mkdir(parents=True)
        assert main(['simulate', '--out', str(tmp_path / 'bags' / unit / 'run.mcap'),
                     '--format', 'mcap', *CYCLE, '--seed', str(len(unit))]) == 0
    code = main(['fleet', 'fit', '--records', str(tmp_path / 'bags' / '{unit}' / '*.mcap'),
                 '--out', str(tmp_path / 'out'), '--options=--max-order 4', '--workers', '1'])
    assert code == 0, capsys.readouterr()
    for unit in ('unit-a', 'unit-b'):
        entry = json.loads((tmp_path / 'out' / 'units' / unit / 'unit.json').read_text())
        assert entry['status'] == 'ok', entry
