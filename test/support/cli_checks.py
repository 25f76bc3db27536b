"""Checks shared by the tests of the mlx-tempcomp commands."""

from mlx_tempcomp.parameters.compensation import COMPENSATION_SPECS
import numpy as np
import yaml


def assert_user_error(code, capsys, *needles):
    """Assert exit code 2 with one 'error: ' line on stderr holding every needle, no trace."""
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith('error: ') and err.count('\n') == 1, err
    for needle in needles:
        assert needle in err, err
    assert 'Traceback' not in err


def node_values(path, node_name='compensation_node'):
    """
    Give the compensation node's parameter values with the file's loaded over the defaults.

    Every key of the file must be a declared parameter of the node, floats where the
    declared type is a double (rcl refuses ints there), as rcl would require.
    """
    with open(path) as stream:
        tree = yaml.safe_load(stream)[node_name]['ros__parameters']
    flat = {}

    def walk(prefix, node):
        for key, value in node.items():
            if isinstance(value, dict):
                walk(f'{prefix}{key}.', value)
            else:
                flat[prefix + key] = value

    walk('', tree)
    specs = {spec.name: spec for spec in COMPENSATION_SPECS}
    assert set(flat) <= set(specs), f'undeclared: {sorted(set(flat) - set(specs))}'
    for name, value in flat.items():
        if specs[name].value_type in ('double', 'double_array'):
            assert all(isinstance(v, float) for v in np.ravel(value)), name
    values = {name: spec.initial_value for name, spec in specs.items()}
    values.update(flat)
    return values
