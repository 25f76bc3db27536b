import logging
import os
import stat

from mlx_tempcomp.parameters.files import parameter_file, write_parameter_file
from mlx_tempcomp.parameters.state_file import (atomic_write, check_state, Field, FILE_MODE,
                                                load_state, read_state, StateFileError,
                                                write_state)
import pytest

FIELDS = (Field('model', 'text', choices=('polynomial', 'eeprom')),
          Field('axes', 'text', length=(1, 3)),
          Field('zro_offset', 'number', length='axes', low=-1.0, high=1.0),
          Field('samples', 'integer', low=1),
          Field('time', 'text'))
GOOD = {'model': 'polynomial', 'axes': ['x', 'z'], 'zro_offset': [0.25, -1], 'samples': 200,
        'time': '2026-11-25T12:00:00+00:00'}


@pytest.fixture
def logger():
    return logging.getLogger('test_state_file')


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


@pytest.mark.parametrize('content, message', [
    ('model: [unclosed', 'is damaged: not valid YAML at line '),
    ('- a list', 'is damaged: a list, not a mapping'),
    ('', 'is damaged: empty')])
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


def test_a_failed_write_leaves_the_old_file_and_no_temporary_file(tmp_path):
    path = tmp_path / 'params.yaml'
    atomic_write(path, 'old: 1\n')
    with pytest.raises(UnicodeEncodeError):
        atomic_write(path, 'new: \udcff\n')   # fails inside the write, after mkstemp
    assert os.listdir(tmp_path) == ['params.yaml']
    assert path.read_text() == 'old: 1\n'


def test_check_state_gives_the_fields_as_typed(tmp_path):
    assert check_state({**GOOD, 'extra': 1}, FIELDS) == {**GOOD, 'zro_offset': [0.25, -1.0]}


@pytest.mark.parametrize('change, message', [
    ({'zro_offset': ['abc', 0.0]}, r"zro_offset\[0\] must be a number, got 'abc'"),
    ({'zro_offset': [0.0, 1.0e300]}, r'zro_offset\[1\] 1e\+300 is outside -1 to 1'),
    ({'zro_offset': [float('nan'), 0.0]}, r'zro_offset\[0\] must be finite, got nan'),
    ({'zro_offset': [True, 0.0]}, r'zro_offset\[0\] must be a number, got True'),
    ({'zro_offset': [0.0]}, r'zro_offset must be a list of 2 values, got \[0.0\]'),
    ({'zro_offset': 0.0}, r'zro_offset must be a list of 2 values, got 0.0'),
    ({'axes': []}, r'axes must be a list of 1 to 3 values'),
    ({'samples': 2.0}, 'samples must be an integer, got 2.0'),
    ({'samples': 0}, 'samples 0 is outside 1 to inf'),
    ({'model': 'chain'}, "model must be one of polynomial, eeprom, got 'chain'"),
    ({'time': None}, 'time must be text, got None'),
])
def test_check_state_names_the_wrong_value(change, message):
    with pytest.raises(StateFileError, match=message):
        check_state({**GOOD, **change}, FIELDS)


def test_check_state_tells_a_missing_key_apart():
    state = dict(GOOD)
    del state['samples'], state['time']
    with pytest.raises(StateFileError, match=r'^damaged: samples, time missing \(truncated\?\)$'):
        check_state(state, FIELDS)


def test_load_state_gives_a_good_file_and_removes_leftover_temporary_files(tmp_path, logger,
                                                                           caplog):
    path = tmp_path / 'zro.yaml'
    write_state(str(path), GOOD)
    (tmp_path / '.zro.yaml.abc123.tmp').write_text('model: polynomial\n')
    (tmp_path / '.other.yaml.abc123.tmp').write_text('')    # another file's: kept
    with caplog.at_level(logging.INFO):
        assert load_state(str(path), FIELDS, logger, 'saved thing') == \
            {**GOOD, 'zro_offset': [0.25, -1.0]}
    assert sorted(os.listdir(tmp_path)) == ['.other.yaml.abc123.tmp', 'zro.yaml']
    assert caplog.records[0].levelname == 'WARNING'
    assert caplog.records[0].message == (f'removed 1 temporary file(s) an interrupted save of '
                                         f'{path} left: .zro.yaml.abc123.tmp')


def test_load_state_without_a_file_is_none(tmp_path, logger, caplog):
    with caplog.at_level(logging.INFO):
        assert load_state(str(tmp_path / 'zro.yaml'), FIELDS, logger, 'saved thing') is None
    assert caplog.messages == []


@pytest.mark.parametrize('content, reason', [
    ('model: polynomial\naxes: [x, z]\nzro_offset: [0.25, -1]\n',
     'damaged: samples, time missing (truncated?)'),
    ('model: polynomial\naxes: [x, z]\nzro_offset: [0.25, -1', 'damaged: not valid YAML'),
    ('model: polynomial\naxes: [x, z]\nzro_offset: [abc, 0]\nsamples: 2\ntime: t\n',
     "zro_offset[0] must be a number, got 'abc'"),
    (b'\xff\xfe', 'damaged: not UTF-8 text'),
])
def test_load_state_moves_a_bad_file_aside_never_over_an_earlier_one(tmp_path, logger, caplog,
                                                                     content, reason):
    path = tmp_path / 'zro.yaml'
    moved = set()
    for _ in range(3):
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        caplog.clear()
        assert load_state(str(path), FIELDS, logger, 'saved thing') is None
        assert not path.exists()
        [record] = caplog.records
        assert record.levelname == 'ERROR'
        assert record.message.startswith(f'saved thing in {path} unusable: {reason}')
        assert record.message.endswith('; starting without it')
        [new] = set(os.listdir(tmp_path)) - moved
        moved.add(new)
        assert f'; moved aside to {tmp_path / new}; ' in record.message
    # Three rejections in the same second: three files, each with the content it had.
    assert all(name.startswith('zro.yaml.bad-') for name in moved)
    for name in moved:
        data = (tmp_path / name).read_bytes()
        assert data == (content if isinstance(content, bytes) else content.encode())


def test_load_state_leaves_an_unreadable_file_in_place(tmp_path, logger, caplog):
    path = tmp_path / 'zro.yaml'
    path.mkdir()
    assert load_state(str(path), FIELDS, logger, 'saved thing') is None
    assert path.is_dir() and os.listdir(tmp_path) == ['zro.yaml']
    assert caplog.messages == [f'cannot read state file {path}: Is a directory; starting '
                               'without saved thing']


def _write_state(path):
    write_state(str(path), {'model': 'eeprom', 'zro_offset': [1.5]})


def _write_parameter_file(path):
    write_parameter_file(path, parameter_file('compensation_node', {'model': 'linear_btc'}),
                         header='bias procedure')


# Every file the package keeps as state goes through one of these: the ZRO and tracking state
# and the MPU offsets (write_state), the ADIS16130 procedure's and the toolkit's parameter
# files (write_parameter_file); both end in atomic_write.
WRITERS = {'write_state': _write_state, 'write_parameter_file': _write_parameter_file}


@pytest.mark.parametrize('umask', [0o077, 0o000, 0o022],
                         ids=['umask077', 'umask000', 'umask022'])
@pytest.mark.parametrize('writer', sorted(WRITERS))
def test_a_planted_symlink_is_replaced_not_followed_and_the_mode_is_0644(tmp_path, writer,
                                                                         umask):
    victim = tmp_path / 'victim.txt'
    victim.write_text('precious\n')
    os.chmod(victim, 0o600)
    target = tmp_path / 'state' / 'zro.yaml'
    target.parent.mkdir()
    os.symlink(victim, target)
    old = os.umask(umask)
    try:
        WRITERS[writer](target)
    finally:
        os.umask(old)
    assert victim.read_text() == 'precious\n'
    assert stat.S_IMODE(victim.stat().st_mode) == 0o600
    assert not target.is_symlink()
    assert stat.S_ISREG(target.lstat().st_mode)
    assert stat.S_IMODE(target.lstat().st_mode) == FILE_MODE == 0o644
    assert 'precious' not in target.read_text()
    assert sorted(os.listdir(target.parent)) == ['zro.yaml']
    # A second write over the regular file keeps the mode, whatever the umask.
    os.chmod(target, 0o666)
    old = os.umask(umask)
    try:
        WRITERS[writer](target)
    finally:
        os.umask(old)
    assert stat.S_IMODE(target.stat().st_mode) == 0o644
