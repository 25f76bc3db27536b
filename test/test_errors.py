"""One error root: every error class of the package lies below `MlxTempCompError`."""

import ast
import importlib
import inspect
from pathlib import Path
import pkgutil

import mlx_tempcomp
from mlx_tempcomp.errors import MlxTempCompError

PACKAGE_DIR = Path(mlx_tempcomp.__file__).parent


def package_modules():
    for info in pkgutil.walk_packages([str(PACKAGE_DIR)], prefix='mlx_tempcomp.'):
        yield importlib.import_module(info.name)


def test_every_error_class_of_the_package_is_below_the_root():
    errors = {f'{module.__name__}.{name}': cls
              for module in package_modules()
              for name, cls in inspect.getmembers(module, inspect.isclass)
              if cls.__module__ == module.__name__ and issubclass(cls, BaseException)}
    outside = sorted(name for name, cls in errors.items() if not issubclass(cls, MlxTempCompError))
    assert outside == []
    # The layers' classes the nodes and the CLI catch the root for.
    for name in ('core.errors.TempCompError', 'hardware.errors.HardwareError',
                 'recordings.errors.RecordFileError', 'recordings.bag.BagError',
                 'recordings.recording.RecordingError', 'parameters.state_file.StateFileError',
                 'toolkit.errors.UserError'):
        assert f'mlx_tempcomp.{name}' in errors


def test_the_root_module_imports_nothing():
    tree = ast.parse((PACKAGE_DIR / 'errors.py').read_text())
    assert not [node for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))]
