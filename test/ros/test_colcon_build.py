"""
Prove that ``ros2 run mlx_tempcomp mlx-tempcomp`` works after a colcon build.

The package source is copied into a temporary workspace and built with the colcon that
sits next to the running interpreter, in colcon's default isolated layout
(``install/mlx_tempcomp`` is the package prefix). Build, install and log bases all live
under ``tmp_path``, so the source tree is left untouched. The executable is then looked
up exactly as ``ros2 run`` does it: the package prefix from the ament index on
``AMENT_PREFIX_PATH``, then ``<prefix>/lib/<package>/<executable>``.
"""

import os
from pathlib import Path
import shutil
import subprocess
import sys

from ament_index_python.packages import get_package_prefix
import pytest

PACKAGE = 'mlx_tempcomp'
EXECUTABLE = 'mlx-tempcomp'
SOURCE = Path(__file__).resolve().parents[2]
# What a ROS checkout of the package needs to build; tests and tooling stay behind.
SOURCE_ITEMS = ('package.xml', 'setup.py', 'setup.cfg', 'resource', PACKAGE, 'config', 'launch')
# Environment that would make the build or the lookup depend on this machine.
FOREIGN_VARIABLES = ('AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'CMAKE_PREFIX_PATH', 'PYTHONPATH')


def _copy_sources(destination):
    ignore = shutil.ignore_patterns('__pycache__', '*.pyc', '*.egg-info')
    for item in SOURCE_ITEMS:
        source = SOURCE / item
        if source.is_dir():
            shutil.copytree(source, destination / item, ignore=ignore)
        elif source.exists():
            shutil.copy2(source, destination / item)


def _clean_environment(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in FOREIGN_VARIABLES}
    env['COLCON_HOME'] = str(tmp_path / 'colcon_home')  # no user defaults or mixins
    return env


def _install_pythonpath(prefix):
    """Return PYTHONPATH as the install's setup scripts set it, from colcon's hook."""
    hook = prefix / 'share' / PACKAGE / 'hook' / 'pythonpath.dsv'
    assert hook.is_file(), f'{hook} was not installed'
    entries = []
    for line in hook.read_text().splitlines():
        parts = line.split(';')
        if len(parts) == 3 and parts[1] == 'PYTHONPATH':
            entries.append(str(prefix / parts[2]))
    assert entries, f'{hook} does not set PYTHONPATH'
    return os.pathsep.join(entries)


@pytest.mark.slow
@pytest.mark.ros   # it starts the executables, rclpy and DDS with them
def test_colcon_build_installs_ros2_run_executable(tmp_path, monkeypatch):
    colcon = Path(sys.executable).with_name('colcon')
    assert colcon.exists(), f'colcon is not installed next to {sys.executable}'

    source = tmp_path / 'src' / PACKAGE
    source.mkdir(parents=True)
    _copy_sources(source)
    install_base = tmp_path / 'install'
    env = _clean_environment(tmp_path)

    build = subprocess.run(
        [str(colcon), '--log-base', str(tmp_path / 'log'), 'build',
         '--base-paths', str(tmp_path / 'src'),
         '--build-base', str(tmp_path / 'build'),
         '--install-base', str(install_base),
         '--event-handlers', 'console_cohesion+', 'desktop_notification-',
         'terminal_title-'],
        cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
        timeout=300)
    assert build.returncode == 0, f'colcon build failed:\n{build.stdout}\n{build.stderr}'
    # colcon-ros only warns, and fills in, when setup.py forgets the marker or package.xml.
    assert "doesn't explicitly install" not in build.stdout + build.stderr, build.stderr

    # ros2 run: package prefix from the ament index, then lib/<package>/<executable>.
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(install_base / PACKAGE))
    prefix = Path(get_package_prefix(PACKAGE))
    assert prefix == install_base / PACKAGE
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()
    assert (prefix / 'share' / PACKAGE / 'package.xml').is_file()
    executable = prefix / 'lib' / PACKAGE / EXECUTABLE
    assert executable.is_file(), f'{executable} missing; ros2 run could not find it'
    assert os.access(executable, os.X_OK) and executable.stat().st_mode & 0o111, \
        f'{executable} is not executable'

    env['AMENT_PREFIX_PATH'] = str(prefix)
    env['PYTHONPATH'] = _install_pythonpath(prefix)
    # The installed copy, not this source tree, must be what gets imported.
    where = subprocess.run(
        [sys.executable, '-c', f'import {PACKAGE}; print({PACKAGE}.__file__)'],
        cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
        timeout=60)
    assert where.returncode == 0, where.stderr
    assert Path(where.stdout.strip()).is_relative_to(prefix), where.stdout

    run = subprocess.run(
        [str(executable), '--help'],
        cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
        timeout=60)
    assert run.returncode == 0, f'{EXECUTABLE} --help failed:\n{run.stdout}\n{run.stderr}'
    assert run.stdout.strip(), f'{EXECUTABLE} --help printed nothing'
    # The nodes resolve the same way; the installed driver starts, reads its parameters and
    # refuses a bad one (exit 1), which needs rclpy and the whole package to import.
    for node in ('driver_node', 'compensation_node', 'bringup'):
        path = prefix / 'lib' / PACKAGE / node
        assert path.is_file() and os.access(path, os.X_OK), f'{path} missing or not executable'
    assert (prefix / 'share' / PACKAGE / 'config' / 'mlx_tempcomp.yaml').is_file()
    assert (prefix / 'share' / PACKAGE / 'config' / 'mlx_tempcomp.policy.xml').is_file()
    assert (prefix / 'share' / PACKAGE / 'launch' / 'mlx_tempcomp.launch.py').is_file()
    refused = subprocess.run(
        [str(prefix / 'lib' / PACKAGE / 'driver_node'), '--ros-args', '-p', 'source:=usb'],
        cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
        timeout=60)
    assert refused.returncode == 1, refused.stdout + refused.stderr
    assert 'invalid parameter source' in refused.stdout + refused.stderr
