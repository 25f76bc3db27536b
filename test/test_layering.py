"""
The package's layers: which may import which, and what runs without ROS.

`ALLOWED` is the import graph of docs/architecture.md ("Layers and import
direction"): every module of the package is read (ast, imports inside
functions included) and each import of another layer must be in its row. Only
``ros/`` imports rclpy or a message package, only ``fleet/`` Dask or fsspec;
no module imports a private name (``_name``) of another. Then, in a fresh
interpreter whose import system refuses rclpy and every ROS message package,
every module outside ``ros/`` imports, ``mlx-tempcomp --help`` and the help
of every subcommand print, and ``evaluate`` runs a parameter file's model (the
command that used to pull in rclpy); the optional heavy imports (matplotlib,
allantools, scipy, Dask, fsspec, and the flight-log readers' pyulog and
pymavlink, which only recordings/ulog.py and recordings/dataflash.py import, inside a
function) stay unloaded.
"""

import ast
import functools
import importlib.util
import json
from pathlib import Path
import re
import subprocess
import sys

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / 'mlx_tempcomp'
ARCHITECTURE = PACKAGE.parent / 'docs' / 'architecture.md'

# Layer (a subpackage or a top-level module) -> the other layers it may import.
ALLOWED = {
    'errors': set(),
    'core': set(),
    'hardware': {'core'},
    'simulation': {'core', 'hardware'},
    'sources': {'core', 'hardware', 'simulation'},
    'recordings': {'core'},
    'parameters': {'core', 'simulation'},
    'toolkit': {'core', 'hardware', 'simulation', 'sources', 'recordings', 'parameters'},
    'ros': {'core', 'hardware', 'simulation', 'sources', 'recordings', 'parameters'},
    'fleet': {'core', 'hardware', 'simulation', 'sources', 'recordings', 'parameters', 'toolkit'},
    'cli': {'core', 'hardware', 'simulation', 'sources', 'recordings', 'parameters', 'toolkit',
            'fleet'},
}
# The root of the package's errors (main's mlx_tempcomp/errors.py): every layer may import it.
EVERYWHERE = {'errors'}
# Third-party packages core may import: it is numpy-only (allantools inside a function).
CORE_THIRD_PARTY = {'numpy', 'allantools'}
# rclpy, its C layers and the message packages: what a machine without ROS lacks.
ROS_PACKAGE = re.compile(r'(rclpy|rcl_\w+|rmw\w*|rosidl\w*|rpyutils|ament_index_python'
                         r'|builtin_interfaces|\w+_msgs|\w+_srvs|\w+_interfaces)$')
# The flight-log libraries and the one reader module each may be imported by.
FLIGHT_LOG_READERS = {'pyulog': 'mlx_tempcomp.recordings.ulog',
                      'pymavlink': 'mlx_tempcomp.recordings.dataflash'}
# Imported only where a command needs them, never by --help.
OPTIONAL_HEAVY = ('matplotlib', 'allantools', 'scipy', 'dask', 'distributed', 'fsspec',
                  *FLIGHT_LOG_READERS)
# The fleet job's engine: imported by fleet/ only, so single-record commands and nodes never load
# it (and inside functions, so --help does not either: OPTIONAL_HEAVY).
FLEET_ONLY = ('dask', 'distributed', 'fsspec')


@functools.cache
def _modules() -> dict:
    """Give {dotted module name: path} of every module of the package (read once a run)."""
    modules = {}
    for path in sorted(PACKAGE.rglob('*.py')):
        parts = ('mlx_tempcomp',) + path.relative_to(PACKAGE).with_suffix('').parts
        if parts[-1] == '__init__':
            parts = parts[:-1]
        modules['.'.join(parts)] = path
    return modules


def _layer(module: str) -> str:
    """Give the layer of a module: its name after ``mlx_tempcomp.`` ('' for the package)."""
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else ''


def _imports(module: str, path: Path):
    """Yield (line, imported module, names) of every import in ``path``, made absolute."""
    package = module.split('.') if path.name == '__init__.py' else module.split('.')[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            target = '.'.join(base + ([node.module] if node.module else []))
            yield node.lineno, target, tuple(alias.name for alias in node.names)


@functools.cache
def _package_imports() -> tuple:
    """Give (module, line, imported module, names) of every import of the package, parsed once."""
    return tuple((module, line, target, names) for module, path in _modules().items()
                 for line, target, names in _imports(module, path))


def test_every_module_is_in_a_layer():
    unplaced = [m for m in _modules() if _layer(m) and _layer(m) not in ALLOWED]
    assert not unplaced, (f'{unplaced}: add their layer to ALLOWED here and to '
                          f'{ARCHITECTURE.name}')


def test_every_layer_imports_only_the_layers_below_it():
    wrong = []
    for module, line, target, _ in _package_imports():
        if not target.startswith('mlx_tempcomp.') or not _layer(module):
            continue
        # ``from ..sources import adis16130``: the layer is in the module part.
        layer, imported = _layer(module), _layer(target)
        if imported != layer and imported not in ALLOWED.get(layer, set()) | EVERYWHERE:
            wrong.append(f'{module}:{line} imports {target} ({layer} -> {imported})')
    assert not wrong, '\n'.join(wrong)


def test_only_ros_imports_ros_packages_and_core_only_numpy():
    wrong = []
    for module, line, target, _ in _package_imports():
        top = target.split('.')[0]
        layer = _layer(module)
        if ROS_PACKAGE.match(top) and layer != 'ros':
            wrong.append(f'{module}:{line} imports {target}: only ros/ may')
        if layer == 'core' and top not in ('mlx_tempcomp', *sys.stdlib_module_names,
                                           *CORE_THIRD_PARTY):
            wrong.append(f'{module}:{line} imports {target}: core is numpy-only')
    assert not wrong, '\n'.join(wrong)


def _top_level_imports(tree) -> list:
    """Give (line, imported module) of the imports a module runs when it is imported."""
    found = []
    for node in tree.body:
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.append((node.lineno, node.module))
    return found


def test_flight_log_libraries_are_imported_only_by_their_readers_inside_a_function():
    wrong = [f'{module}:{line} imports {target}: only {FLIGHT_LOG_READERS[target.split(".")[0]]}'
             ' may' for module, line, target, _ in _package_imports()
             if FLIGHT_LOG_READERS.get(target.split('.')[0], module) != module]
    for library, module in FLIGHT_LOG_READERS.items():
        tree = ast.parse(_modules()[module].read_text(encoding='utf-8'))
        wrong += [f'{module}:{line} imports {target} at module level: --help would load it'
                  for line, target in _top_level_imports(tree)
                  if target.split('.')[0] == library]
    assert not wrong, '\n'.join(wrong)


def test_only_the_fleet_job_imports_dask():
    wrong = [f'{module}:{line} imports {target}: only fleet/ may'
             for module, line, target, _ in _package_imports()
             if target.split('.')[0] in FLEET_ONLY and _layer(module) != 'fleet']
    assert not wrong, '\n'.join(wrong)


def test_no_module_imports_a_private_name_of_another():
    wrong = [f'{module}:{line} imports {name} from {target}'
             for module, line, target, names in _package_imports()
             if target.startswith('mlx_tempcomp') for name in names
             if name.startswith('_') and not name.startswith('__')]
    assert not wrong, '\n'.join(wrong)


def test_the_architecture_document_shows_the_same_graph():
    text = ARCHITECTURE.read_text(encoding='utf-8')
    section = text.split('## Layers and import direction', 1)[1].split('\n## ', 1)[0]
    documented = {}
    for row in re.findall(r'^\|\s*`(\w+)`\s*\|(.*)\|\s*$', section, flags=re.MULTILINE):
        layer, cells = row
        documented[layer] = set(re.findall(r'`(\w+)`', cells.split('|')[-1]))
    assert documented == ALLOWED


# The rooms of core (its sub-packages) -> the other rooms each may import; errors, the
# core's error classes, is the one loose module, and every room may import it
# (docs/architecture.md, "The rooms of core").
CORE_ROOMS = {
    'series': set(),
    'mlx90609': set(),
    'node_models': {'mlx90609'},
    'effects': {'node_models'},
    'fitting': {'series', 'node_models', 'effects'},
    'standstill': {'node_models'},
    'learning': {'node_models', 'fitting', 'standstill'},
    'diagnosis': {'series', 'node_models', 'effects', 'fitting', 'standstill'},
    'procedures': {'series', 'effects'},
}
CORE_LOOSE = {'errors'}
# The packages whose __init__ lists __all__: each room of core, and these layers.
LISTED_LAYERS = ('parameters', 'recordings')


def _room(module: str) -> str:
    """Give the room of a core module ('' outside core, the module's name if loose)."""
    parts = module.split('.')
    return parts[2] if len(parts) > 2 and parts[1] == 'core' else ''


def test_core_holds_only_rooms_and_its_errors():
    modules = [m for m in _modules() if _layer(m) == 'core' and m != 'mlx_tempcomp.core']
    loose = sorted({_room(m) for m in modules} - set(CORE_ROOMS))
    assert loose == sorted(CORE_LOOSE), 'place them in a room of CORE_ROOMS and the docs'


def test_every_room_of_core_imports_only_the_rooms_below_it():
    wrong = []
    for module, line, target, _ in _package_imports():
        room, imported = _room(module), _room(target)
        if room and imported and imported != room and imported not in CORE_LOOSE and \
                imported not in CORE_ROOMS.get(room, set()):
            wrong.append(f'{module}:{line} imports {target} ({room} -> {imported})')
    assert not wrong, '\n'.join(wrong)


def test_outside_a_room_the_package_imports_what_the_room_lists():
    """A room's modules are its own: others take the names its ``__init__`` lists."""
    wrong = []
    for module, line, target, names in _package_imports():
        room = _room(target)
        if room in CORE_ROOMS and _room(module) != room:
            package = importlib.import_module(f'mlx_tempcomp.core.{room}')
            if target != package.__name__:
                wrong.append(f'{module}:{line} imports {target}: import from {package.__name__}')
            wrong += [f'{module}:{line} imports {name}, which {package.__name__}.__all__ '
                      'does not list' for name in names if name not in package.__all__]
    assert not wrong, '\n'.join(wrong)


@pytest.mark.parametrize('package', [f'core.{room}' for room in CORE_ROOMS] +
                         ['core', *LISTED_LAYERS])
def test_every_room_lists_what_it_gives(package):
    """``__all__`` names what the package gives, and each name is there."""
    module = importlib.import_module(f'mlx_tempcomp.{package}')
    given = getattr(module, '__all__', None)
    assert given, f'mlx_tempcomp/{package.replace(".", "/")}/__init__.py lists no __all__'
    missing = [name for name in given if not hasattr(module, name) and
               importlib.util.find_spec(f'{module.__name__}.{name}') is None]
    assert missing == []
    assert len(set(given)) == len(given)
    if package in ('core', *LISTED_LAYERS):   # a layer lists its modules (and rooms)
        folder = PACKAGE.joinpath(*package.split('.'))
        assert sorted(given) == sorted(path.stem if path.suffix else path.name
                                       for path in folder.iterdir()
                                       if path.suffix == '.py' and path.stem != '__init__'
                                       or (path / '__init__.py').exists())


def test_the_architecture_document_shows_the_rooms_of_core():
    text = ARCHITECTURE.read_text(encoding='utf-8')
    section = text.split('## The rooms of core', 1)[1].split('\n## ', 1)[0]
    documented = {}
    for room, cells in re.findall(r'^\|\s*`(\w+)/`\s*\|(.*)\|\s*$', section,
                                  flags=re.MULTILINE):
        documented[room] = set(re.findall(r'`(\w+)`', cells.split('|')[-1]))
    assert documented == CORE_ROOMS


# The nodes' rooms of ros/: each imports the modules both share, never the other; only
# bringup and the demo, which run both nodes in one process, import both.
ROS_ROOMS = ('driver', 'compensation')
BOTH_NODES = {'mlx_tempcomp.ros.bringup', 'mlx_tempcomp.ros.demo'}


def test_the_nodes_rooms_import_only_what_both_share():
    wrong = []
    for module, line, target, _ in _package_imports():
        if _layer(module) != 'ros' or module in BOTH_NODES:
            continue
        room = module.split('.')[2] if len(module.split('.')) > 3 else ''
        for other in ROS_ROOMS:
            if other != room and (target + '.').startswith(f'mlx_tempcomp.ros.{other}.'):
                wrong.append(f'{module}:{line} imports {target}')
    assert not wrong, '\n'.join(wrong)


# Run by a fresh interpreter: argv[1] is JSON {modules, folder}; prints a JSON report.
_WITHOUT_ROS = r"""
import contextlib, importlib, io, json, re, sys

class RefuseRos:
    # Refuse rclpy and the message packages, as on a machine without ROS.
    def find_spec(self, name, path=None, target=None):
        if re.match(PATTERN, name.split('.')[0]):
            raise ModuleNotFoundError(f'{name} refused: this process runs without ROS')
        return None

sys.meta_path.insert(0, RefuseRos())
job = json.loads(sys.argv[1])
for module in job['modules']:
    importlib.import_module(module)
from mlx_tempcomp.cli import build_parser, main
report = {'loaded': sorted(name for name in sys.modules
                           if name.split('.')[0] in job['optional']), 'help': {}}
commands = [action for action in build_parser()._actions if action.choices and
            action.dest == 'command'][0].choices
for argv in [['--help']] + [[command, '--help'] for command in commands]:
    out, code = io.StringIO(), None
    with contextlib.redirect_stdout(out):
        try:
            main(argv)
        except SystemExit as end:
            code = end.code
    report['help'][' '.join(argv)] = [code, out.getvalue()]
out = io.StringIO()
with contextlib.redirect_stdout(out):
    code = main(['evaluate', job['folder'] + '/rest.csv', '--params',
                 job['folder'] + '/params.yaml', '--json'])
report['evaluate'] = [code, json.loads(out.getvalue())]
report['ros_loaded'] = sorted(name for name in sys.modules
                              if re.match(PATTERN, name.split('.')[0]))
print(json.dumps(report))
"""

PARAMS = """compensation_node:
  ros__parameters:
    model: polynomial
    axes: ['z']
    polynomial:
      bias:
        z: [0.01, 0.002]
"""


@pytest.fixture(scope='module')
def without_ros(tmp_path_factory):
    """Import the package outside ros/ and run the CLI with ROS refused; give the report."""
    folder = tmp_path_factory.mktemp('without_ros')
    # At rest, temperature 20 to 30 C: the model's bias is exactly what the gyro reads.
    rows = ['time,temperature,gyro_z'] + [
        f'{0.1 * k!r},{20.0 + k!r},{0.01 + 0.002 * (20.0 + k - 25.0)!r}' for k in range(11)]
    (folder / 'rest.csv').write_text('\n'.join(rows) + '\n', encoding='utf-8')
    (folder / 'params.yaml').write_text(PARAMS, encoding='utf-8')
    modules = [m for m in _modules() if _layer(m) != 'ros']
    job = json.dumps({'modules': modules, 'folder': str(folder), 'optional': OPTIONAL_HEAVY})
    script = _WITHOUT_ROS.replace('PATTERN', repr(ROS_PACKAGE.pattern))
    done = subprocess.run([sys.executable, '-c', script, job], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_every_module_outside_ros_imports_without_ros(without_ros):
    assert without_ros['ros_loaded'] == []


def test_help_of_every_subcommand_prints_without_ros(without_ros):
    helps = without_ros['help']
    assert {'--help', 'evaluate --help', 'fit --help', 'diagnose --help'} <= set(helps)
    for argv, (code, text) in helps.items():
        assert code == 0 and text.startswith('usage: mlx-tempcomp'), (argv, code, text)


def test_evaluate_runs_a_parameter_file_without_ros(without_ros):
    code, report = without_ros['evaluate']
    assert code == 0
    assert report['model'] == 'polynomial' and report['rows'] == 11
    assert report['per_sample']['z']['samples'] == 11
    assert abs(report['per_sample']['z']['peak']) < 1e-15


def test_optional_heavy_imports_stay_out(without_ros):
    assert without_ros['loaded'] == []
