"""
package.xml declares what the code imports: what rosdep installs and ``colcon test`` needs.

Every import of every module of the package, its launch file and its tests
(ast, imports inside functions and under ``try`` included) is mapped to its
rosdep key by `ROSDEP_KEYS`. An import the table lacks fails (a new
dependency needs its row); a key the table names must be declared:
``exec_depend`` for what the package or its launch file imports,
``exec_depend`` or ``test_depend`` for what only the tests import. Packages
rosdep has no key for are pip extras: setup.py must offer them and
docs/ros.md must name them. package.xml may declare no key the table does not
hold, so an invented key (which makes ``rosdep install`` fail) is caught.
"""

import ast
import functools
from pathlib import Path
import re
import sys
import xml.etree.ElementTree as ElementTree

ROOT = Path(__file__).resolve().parent.parent
# Where the imports are read, and whether what they import runs with the package.
SOURCES = {'mlx_tempcomp': 'exec', 'launch': 'exec', 'test': 'test'}

# Top-level module -> its rosdep key, or None where rosdep has none (then the pip name).
# Keys checked against rosdep's base lists (ros/rosdistro rosdep/python.yaml): the python3-*
# keys below are defined there; rosbags, allantools, pyulog, pymavlink, dask (distributed),
# fsspec and apsw have no key of any name; spidev only as python3-spidev-pip, smbus2 only as
# python3-smbus2-pip (python3-smbus is another package, the i2c-tools binding).
ROSDEP_KEYS = {
    # ROS 2 packages: the package name is the key.
    'rclpy': 'rclpy',
    'sensor_msgs': 'sensor_msgs',
    'std_msgs': 'std_msgs',
    'std_srvs': 'std_srvs',
    'diagnostic_msgs': 'diagnostic_msgs',
    'geometry_msgs': 'geometry_msgs',
    'nav_msgs': 'nav_msgs',
    'rcl_interfaces': 'rcl_interfaces',
    'builtin_interfaces': 'builtin_interfaces',
    'launch': 'launch',
    'launch_ros': 'launch_ros',
    'ament_index_python': 'ament_index_python',
    'ament_flake8': 'ament_flake8',
    'ament_pep257': 'ament_pep257',
    # Python packages with a rosdep key.
    'numpy': 'python3-numpy',
    'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',
    'spidev': 'python3-spidev-pip',
    'smbus2': 'python3-smbus2-pip',
    'pytest': 'python3-pytest',
    'hypothesis': 'python3-hypothesis',
    'cryptography': 'python3-cryptography',   # the fleet's TLS test makes its certificates
    # No rosdep key: pip (docs/ros.md, setup.py extras).
    'rosbags': None,
    'allantools': None,
    'pyulog': None,
    'pymavlink': None,
    'dask': None,   # with its distributed scheduler (dask.distributed)
    'distributed': None,   # the same, by its own name (its Security, its comm layer)
    'fsspec': None,
    # rosbags' sqlite3 back end, installed with it (recordings/bag_*.py fall back to sqlite3).
    'apsw': None,
}
# The pip name of each package without a key, as setup.py's extras and docs/ros.md give it.
PIP_NAMES = {'rosbags': 'rosbags', 'allantools': 'allantools', 'pyulog': 'pyulog',
             'pymavlink': 'pymavlink', 'dask': 'dask[distributed]',
             'distributed': 'dask[distributed]', 'fsspec': 'fsspec',
             'apsw': 'rosbags'}


@functools.lru_cache(maxsize=None)
def _imports() -> dict:
    """Give {top-level module: set of SOURCES kinds importing it} for third-party imports."""
    local = {path.stem for path in (ROOT / 'test').rglob('*.py')} | {'mlx_tempcomp'}
    found = {}
    for folder, kind in SOURCES.items():
        for path in sorted((ROOT / folder).rglob('*.py')):
            for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split('.')[0]
                    if top not in sys.stdlib_module_names and top not in local:
                        found.setdefault(top, set()).add(kind)
    return found


def _declared() -> dict:
    """Give {tag: set of keys} of package.xml's dependency tags."""
    root = ElementTree.parse(ROOT / 'package.xml').getroot()
    declared = {}
    for element in root:
        if element.tag.endswith('depend'):
            declared.setdefault(element.tag, set()).add(element.text.strip())
    return declared


def test_every_import_has_a_row():
    missing = sorted(set(_imports()) - set(ROSDEP_KEYS))
    assert not missing, f'imports without a row in ROSDEP_KEYS: {missing}'


def test_every_import_with_a_key_is_declared():
    declared = _declared()
    run = declared.get('exec_depend', set()) | declared.get('depend', set())
    tests = run | declared.get('test_depend', set())
    wrong = []
    for module, kinds in sorted(_imports().items()):
        key = ROSDEP_KEYS.get(module)
        if key is None:
            continue
        if 'exec' in kinds and key not in run:
            wrong.append(f'{module}: <exec_depend>{key}</exec_depend> missing')
        elif key not in tests:
            wrong.append(f'{module}: <test_depend>{key}</test_depend> missing')
    assert not wrong, '\n'.join(wrong)


def test_package_xml_declares_only_known_keys():
    keys = set().union(*_declared().values())
    assert keys <= set(ROSDEP_KEYS.values()) - {None}, \
        sorted(keys - set(ROSDEP_KEYS.values()))


def test_each_row_is_imported():
    stale = sorted(set(ROSDEP_KEYS) - set(_imports()))
    assert not stale, f'rows nothing imports: {stale}'


def test_packages_without_a_key_are_pip_extras_in_setup_and_docs():
    setup = (ROOT / 'setup.py').read_text(encoding='utf-8')
    docs = (ROOT / 'docs' / 'ros.md').read_text(encoding='utf-8')
    section = docs.split('## Install on a robot', 1)[1].split('\n## ', 1)[0]
    for module, key in ROSDEP_KEYS.items():
        if key is not None:
            continue
        name = PIP_NAMES[module]
        assert re.search(rf"'{re.escape(name)}[>=<'\[]", setup), f'setup.py lacks {name}'
        assert f'`{name}`' in section or f' {name} ' in section, \
            f'docs/ros.md, Install on a robot, does not name {name}'
