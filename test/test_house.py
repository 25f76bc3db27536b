"""
The house rules of the package's code: sizes, import cycles, what sits at the top.

No module of mlx_tempcomp/ over 700 lines, no function (or method, or
function inside one) over 80 lines, no circle of imports between its modules,
and at the package's top only ``cli.py``, ``errors.py`` and ``__init__.py``:
everything else lives in a layer's package (docs/architecture.md). Imports
are read with ast, those inside functions and under ``if TYPE_CHECKING:``
too: a circle only a type checker walks is still a circle in the design.
"""

import ast
from pathlib import Path


PACKAGE = Path(__file__).resolve().parent.parent / 'mlx_tempcomp'
MAX_MODULE_LINES = 700
MAX_FUNCTION_LINES = 80
TOP_LEVEL = {'__init__.py', 'cli.py', 'errors.py'}


def _modules() -> dict:
    """Give {dotted module name: path} of every module of the package."""
    modules = {}
    for path in sorted(PACKAGE.rglob('*.py')):
        parts = ('mlx_tempcomp',) + path.relative_to(PACKAGE).with_suffix('').parts
        modules['.'.join(parts[:-1] if parts[-1] == '__init__' else parts)] = path
    return modules


def _name(path: Path) -> str:
    return path.relative_to(PACKAGE).as_posix()


def _functions(tree, prefix: str = ''):
    """Yield (qualified name, lines) of every function in ``tree``, nested ones too."""
    for node in ast.iter_child_nodes(tree):
        name = prefix
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f'{prefix}{node.name}'
            if not isinstance(node, ast.ClassDef):
                yield name, node.end_lineno - node.lineno + 1
            name += '.'
        yield from _functions(node, name)


def _imported_modules(module: str, path: Path, modules: dict) -> set:
    """Give the package's modules ``module`` imports anywhere (a name's, if a module)."""
    tree = ast.parse(path.read_text(encoding='utf-8'))
    package = module.split('.') if path.name == '__init__.py' else module.split('.')[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            target = '.'.join(base + ([node.module] if node.module else []))
            targets = [f'{target}.{alias.name}' if f'{target}.{alias.name}' in modules else target
                       for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in modules:
                target = target.rpartition('.')[0]
            if target and target != module:
                found.add(target)
    return found


def _cycles(graph: dict) -> list:
    """Give each group of modules that import each other round a circle (Tarjan's SCC)."""
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(module):
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for imported in sorted(graph[module]):
            if imported not in index:
                visit(imported)
                low[module] = min(low[module], low[imported])
            elif imported in on_stack:
                low[module] = min(low[module], index[imported])
        if low[module] == index[module]:
            group = []
            while not group or group[-1] != module:
                group.append(stack.pop())
                on_stack.discard(group[-1])
            if len(group) > 1:
                groups.append(sorted(group))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return groups


def _long_modules() -> dict:
    return {_name(path): lines for path in _modules().values()
            if (lines := len(path.read_text(encoding='utf-8').splitlines())) > MAX_MODULE_LINES}


def _long_functions() -> dict:
    found = {}
    for path in _modules().values():
        tree = ast.parse(path.read_text(encoding='utf-8'))
        found.update((f'{_name(path)}:{name}', lines) for name, lines in _functions(tree)
                     if lines > MAX_FUNCTION_LINES)
    return found


def test_no_module_is_over_700_lines():
    assert _long_modules() == {}


def test_no_function_is_over_80_lines():
    assert _long_functions() == {}


def test_no_modules_import_each_other_round_a_circle():
    modules = _modules()
    graph = {module: _imported_modules(module, path, modules) for module, path in modules.items()}
    assert _cycles(graph) == []


def test_the_checks_see_a_long_function_and_a_circle():
    """The walks above find what they look for: a nested function, a cycle of three."""
    tree = ast.parse('class A:\n    def f(self):\n        def g():\n' + '            x = 1\n' * 90)
    assert dict(_functions(tree)) == {'A.f': 92, 'A.f.g': 91}
    assert _cycles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == [['a', 'b', 'c']]


def test_an_import_only_a_type_checker_runs_counts(tmp_path):
    """``if TYPE_CHECKING:`` hides no import from the circle check."""
    path = tmp_path / 'a.py'
    path.write_text('from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n'
                    '    from .b import B\n', encoding='utf-8')
    modules = {'package.a': path, 'package.b': tmp_path / 'b.py'}
    assert _imported_modules('package.a', path, modules) == {'package.b'}


def test_only_cli_errors_and_init_sit_at_the_top_of_the_package():
    assert sorted(path.name for path in PACKAGE.glob('*.py')) == sorted(TOP_LEVEL)


def test_the_readme_stays_under_160_lines():
    """A newcomer's first page: the rest belongs in docs/."""
    lines = (PACKAGE.parent / 'README.md').read_text(encoding='utf-8').splitlines()
    assert len(lines) < 160, f'README.md has {len(lines)} lines'


TESTS = PACKAGE.parent / 'test'
MAX_FLAT_TESTS = 10


def test_the_tests_live_in_folders_that_mirror_the_package():
    """Each folder of test/ is a layer of the package, but support/: the helpers."""
    folders = {path.name for path in TESTS.iterdir() if path.is_dir()
               and not path.name.startswith(('.', '__'))}
    layers = {path.name for path in PACKAGE.iterdir() if (path / '__init__.py').exists()}
    assert sorted(folders - layers - {'support'}) == []
    flat = sorted(path.name for path in TESTS.glob('test_*.py'))
    assert len(flat) <= MAX_FLAT_TESTS, flat


def test_no_test_module_imports_another():
    """What tests share lives in test/support/; a test module is imported by pytest alone."""
    tests = {path.stem for path in TESTS.rglob('test_*.py')}
    found = {}
    for path in sorted(TESTS.rglob('*.py')):
        for name in _imported_names(ast.parse(path.read_text())):
            if name.split('.')[0] in tests:
                found.setdefault(str(path.relative_to(TESTS)), []).append(name)
    assert found == {}


def _imported_names(tree) -> list:
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.append(node.module)
    return names
