"""
Session-wide test set-up: the helpers' folder, private DDS traffic and hardware-only tests.

The tests live in folders that mirror the package; what several share is in
``test/support/``, importable by name from any of them (and from nothing else: pytest
imports each test module on its own, ``--import-mode=importlib``, so no test module
imports another).
"""

import atexit
import fcntl
import glob
import os
from pathlib import Path
import shutil
import sys
import tempfile

from hypothesis import HealthCheck, settings
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / 'support'))


def _claim_domain_id() -> int:
    """
    Give a ROS domain no other test session on this machine holds, and hold it.

    A lock file per domain, held (flock) until this process exits: two sessions at once
    (CI beside a developer's run) never share a domain, whatever their pids.
    """
    for offset in range(101):
        domain_id = (os.getpid() + offset) % 101 + 1
        lock = open(os.path.join(_LOCK_DIR, f'mlx_tempcomp_test_domain_{domain_id}.lock'), 'w')
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        _DOMAIN_LOCKS.append(lock)   # kept open: the lock lasts as long as the session
        return domain_id
    raise RuntimeError('every ROS domain 1-101 is held by another test session')


_DOMAIN_LOCKS = []
# Machine-wide, whatever TMPDIR says: docs_check.py gives the commands it runs a TMPDIR of
# their own, and their tests must still see the domains other sessions hold (sharing one,
# a node of another session fed this one's: its EEPROM, its samples).
_LOCK_DIR = '/tmp' if os.path.isdir('/tmp') else tempfile.gettempdir()
# Set at import time, before any test initializes rclpy. Every subprocess a test starts
# inherits os.environ, so nodes it launches join the same private, localhost-only domain
# and never see (or disturb) a robot or another test session on the network.
os.environ['ROS_DOMAIN_ID'] = str(_claim_domain_id())
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_STATIC_PEERS', None)


def _scratch_ros_home() -> str:
    """Give a ROS_HOME of this session's own, removed when it ends."""
    folder = tempfile.mkdtemp(prefix='mlx_tempcomp_ros_home_')
    atexit.register(shutil.rmtree, folder, True)
    return folder


# The nodes keep their state files under ROS_HOME by default (parameters/state_paths.py):
# a session of its own, so no state an earlier run left there (or in ~/.ros) changes what
# a test sees, and none is left behind. docs_check.py imports this module too, so each doc
# it checks runs in a ROS_HOME of its own.
os.environ['ROS_HOME'] = _scratch_ros_home()

# Property-based tests (test_fuzz_*.py): the same examples on every run by default, so the
# suite gives one answer; HYPOTHESIS_PROFILE=explore draws new ones each run. Either way a
# failure prints the example and a @reproduce_failure blob, and no example database is
# written into the checkout.
_FUZZ_COMMON = {'deadline': None, 'database': None, 'print_blob': True,
                'suppress_health_check': [HealthCheck.too_slow,
                                          HealthCheck.function_scoped_fixture]}
settings.register_profile('ci', derandomize=True, **_FUZZ_COMMON)
# make test-fast: the same, each test drawing a quarter of its examples (test/support/fuzz.py).
settings.register_profile('fast', derandomize=True, **_FUZZ_COMMON)
settings.register_profile('explore', derandomize=False, **_FUZZ_COMMON)
settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'ci'))


def pytest_collection_modifyitems(config, items):
    """
    Run the linters first; skip tests marked ``hardware`` without the devices they need.

    Each linter is one test of some seconds over every file: last (where pytest-xdist's
    default order, files by their number of tests, put them), one process linted while
    the other had nothing left (make test runs the files in this order instead).
    """
    items.sort(key=lambda item: item.get_closest_marker('linter') is None)
    for item in items:
        marker = item.get_closest_marker('hardware')
        if marker is None:
            continue
        # hardware(devices='/dev/i2c-*') for an I2C part; an SPI device by default.
        pattern = marker.kwargs.get('devices', '/dev/spidev*')
        if not glob.glob(pattern):
            item.add_marker(pytest.mark.skip(reason=f'needs a device node ({pattern})'))


# Fixtures of the ROS tests (launcher: node subprocesses, probe: an rclpy node with its own
# context) and their helpers live in test/support/ros_harness.py.
pytest_plugins = ['ros_harness']
