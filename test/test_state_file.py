import os

from mlx_tempcomp.state_file import read_state, StateFileError, write_state
import pytest


def test_write_then_read_round_trip(tmp_path):
    path = tmp_path / 'deep' / 'folder' / 'zro.yaml'
    state = {'model': 'eeprom', 'zro_offset': [1.5, -0.25], 'samples': 500}
    write_state(str(path), state)
    assert read_state(str(path)) == state
    write_state(str(path), {'model': 'polynomial'})
    assert read_state(str(path)) == {'model': 'polynomial'}
    # No temporary file is left behind.
    assert os.listdir(path.parent) == ['zro.yaml']


def test_missing_file_is_no_state(tmp_path):
    assert read_state(str(tmp_path / 'none.yaml')) is None


@pytest.mark.parametrize('content, message', [('model: [unclosed', 'not valid YAML'),
                                              ('- a list', 'does not hold a mapping')])
def test_corrupt_file_is_a_clear_error(tmp_path, content, message):
    path = tmp_path / 'zro.yaml'
    path.write_text(content)
    with pytest.raises(StateFileError, match=message):
        read_state(str(path))


def test_unwritable_folder_is_a_clear_error(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    with pytest.raises(StateFileError, match='cannot write state file'):
        write_state(str(blocker / 'zro.yaml'), {'a': 1})
