"""Default state paths: under ROS_HOME, by the node's namespace and name; the old taken over."""

import os

from mlx_tempcomp.parameters.state_paths import (default_state_path, old_default_path,
                                                 ros_home, state_path)
import pytest


@pytest.fixture
def home(tmp_path, monkeypatch):
    """Give a home folder of the test's own, ROS_HOME unset: ~/.ros is home/.ros."""
    folder = tmp_path / 'home'
    folder.mkdir()
    monkeypatch.setenv('HOME', str(folder))
    monkeypatch.delenv('ROS_HOME', raising=False)
    return folder


def test_the_default_is_under_ros_home_keyed_by_the_fully_qualified_name(home, monkeypatch):
    assert ros_home() == str(home / '.ros')
    assert default_state_path('/compensation_node', '_zro.yaml') == \
        str(home / '.ros' / 'mlx_tempcomp' / 'compensation_node_zro.yaml')
    monkeypatch.setenv('ROS_HOME', str(home / 'elsewhere'))
    assert default_state_path('/robot/left/compensation_node', '_zro.yaml') == \
        str(home / 'elsewhere' / 'mlx_tempcomp' / 'robot' / 'left' / 'compensation_node_zro.yaml')
    monkeypatch.setenv('ROS_HOME', '~/ros')
    assert ros_home() == str(home / 'ros')
    # The old default ignored both.
    assert old_default_path('compensation_node', '_zro.yaml') == \
        str(home / '.ros' / 'mlx_tempcomp' / 'compensation_node_zro.yaml')


def test_a_given_path_is_used_as_given(home):
    lines = []
    assert state_path('~/mine.yaml', '/a/compensation_node', '_zro.yaml', lines.append) == \
        str(home / 'mine.yaml')
    assert lines == []


def old_file(home, text='zro_offset: [0.01]\n'):
    path = home / '.ros' / 'mlx_tempcomp' / 'compensation_node_zro.yaml'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_a_file_at_the_old_default_is_taken_over_once_with_one_line(home):
    old = old_file(home)
    lines = []
    path = state_path('', '/left/compensation_node', '_zro.yaml', lines.append)
    new = home / '.ros' / 'mlx_tempcomp' / 'left' / 'compensation_node_zro.yaml'
    assert path == str(new)
    assert new.read_text() == 'zro_offset: [0.01]\n' and not old.exists()
    assert lines == [f'took over the state file at the old default {old}: now {new} (the '
                     "default is keyed by ROS_HOME and the node's namespace and name)"]
    # Once: the other namespace's node finds nothing there, and the first keeps its file.
    assert state_path('', '/right/compensation_node', '_zro.yaml', lines.append) == \
        str(home / '.ros' / 'mlx_tempcomp' / 'right' / 'compensation_node_zro.yaml')
    assert len(lines) == 1
    old_file(home, 'an older one\n')
    state_path('', '/left/compensation_node', '_zro.yaml', lines.append)
    assert new.read_text() == 'zro_offset: [0.01]\n' and old.exists()
    assert len(lines) == 1


def test_the_root_namespace_keeps_the_old_default(home):
    old = old_file(home)
    lines = []
    assert state_path('', '/compensation_node', '_zro.yaml', lines.append) == str(old)
    assert old.exists() and lines == []


def test_with_another_ros_home_the_old_file_stays_and_the_line_says_where(home, monkeypatch):
    old = old_file(home)
    monkeypatch.setenv('ROS_HOME', str(home / 'ros_home'))
    lines = []
    path = state_path('', '/compensation_node', '_zro.yaml', lines.append)
    assert path == str(home / 'ros_home' / 'mlx_tempcomp' / 'compensation_node_zro.yaml')
    assert old.exists() and not os.path.exists(path)
    assert lines == [f'a state file of an earlier release is at {old}; this node keeps its '
                     f'state in {path} (ROS_HOME): move it there to keep it (mv {old} {path})']
