"""
Property-based tests (hypothesis) of the CSV and bag readers and the EEPROM decoder.

Random and mutated inputs must give a Recording that keeps its promises (time
strictly increasing, every value finite, counts that add up), a RecordingError /
BagError / EepromError naming what is wrong, or, through the command line, one
``error:`` line; never another exception, never a non-finite number.
"""

from contextlib import contextmanager
import json
import math
from pathlib import Path
import re
import shutil
import tempfile

from fuzz import examples
from hypothesis import assume, example, given, settings, strategies as st
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.errors import TempCompError
from mlx_tempcomp.core.mlx90609.conversion import Output
from mlx_tempcomp.core.mlx90609.eeprom import decode_eeprom, EEPROM_SIZE
from mlx_tempcomp.core.mlx90609.factory_table import factory_table
from mlx_tempcomp.recordings.bag import (BagError, ImuRecord, RawTopics, SupplyVoltageRecord,
                                         TemperatureRecord)
from mlx_tempcomp.recordings.bag_reader import RawBagReader
from mlx_tempcomp.recordings.bag_writer import RawBagWriter
from mlx_tempcomp.recordings.load import load_recording
from mlx_tempcomp.recordings.recording import Recording, RecordingError
from mlx_tempcomp.simulation.mlx90609 import factory_eeprom, FactoryMeasurement
from mlx_tempcomp.simulation.physics import GyroTruth
import numpy as np
import pytest

# Examples per test (the profile in conftest.py sets the rest).
FUZZ = settings(max_examples=examples(150))
# Bags cost a copy and a sqlite or mcap open per example.
BAG_FUZZ = settings(FUZZ, max_examples=examples(60))

HEADER = ['time', 'temperature', 'gyro_x', 'gyro_z', 'ref_x', 'ref_z', 'temperature_2',
          'supply_voltage']
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 10_000_000
TOPICS = RawTopics(imu='/imu/data', temperature='/imu/temperature',
                   supply_voltage='/imu/supply_voltage')


@contextmanager
def scratch():
    """Give a fresh folder per hypothesis example (tmp_path is one per test)."""
    folder = tempfile.mkdtemp(prefix='fuzz_')
    try:
        yield Path(folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def assert_sound(recording: Recording) -> None:
    """Check what a Recording promises, whatever the input was."""
    assert isinstance(recording, Recording)
    assert len(recording) >= 1
    assert np.all(np.diff(recording.time_s) > 0)
    for name in ('time_s', 'temperature_c', 'gyro_rad_s', 'reference_rad_s',
                 'acceleration_m_s2', 'temperature_2_c', 'supply_voltage_v'):
        value = getattr(recording, name)
        assert value is None or np.isfinite(value).all(), name
    assert all(count > 0 for count in recording.skipped.values())
    assert recording.sorted_rows >= 0


def read(path: Path, **options):
    """Load a recording; give it, or the RecordingError's message (it must name the file)."""
    try:
        recording = load_recording(path, **options)
    except RecordingError as err:
        assert str(path) in str(err) or 'column map' in str(err), str(err)
        return str(err)
    assert_sound(recording)
    return recording


def valid_rows(rows: int, seed: int = 0) -> list:
    rng = np.random.default_rng(seed)
    table = np.column_stack([
        100.0 + 0.1 * np.arange(rows), np.linspace(-20.0, 60.0, rows),
        rng.normal(0.0, 0.01, (rows, 4)), np.linspace(-15.0, 65.0, rows),
        5.0 + rng.normal(0.0, 0.01, rows)])
    return [[repr(float(v)) for v in row] for row in table]


def csv_text(header, rows, delimiter=',') -> str:
    return '\n'.join(delimiter.join(row) for row in [header] + rows) + '\n'


# --- CSV --------------------------------------------------------------------------------------

@FUZZ
@given(content=st.binary(max_size=2000))
@example(content=b'')
@example(content=b'time,temperature,gyro_z\n')
@example(content=b'\xef\xbb\xbftime,temperature,gyro_z\n1,2,3\n')
def test_random_bytes(content):
    with scratch() as folder:
        path = folder / 'random.csv'
        path.write_bytes(content)
        read(path)


CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-10**30, max_value=10**30).map(str),
    st.sampled_from(['', 'nan', 'NaN', '-inf', 'Infinity', 'n/a', '1e999', '-1e999', '1e308',
                     '-1e308', '0x10', '1_000', ' 1.5 ', '"2"', '1,5', '--1', 'None', '\t']),
    st.text(max_size=6))


@FUZZ
@given(header=st.lists(st.sampled_from(HEADER + ['x', 'gyro_y', 'acc_x', 'acc_y', 'acc_z']),
                       min_size=1, max_size=9),
       rows=st.lists(st.lists(CELLS, max_size=10), max_size=30),
       delimiter=st.sampled_from([',', ';', '\t']))
def test_random_rows_under_a_plausible_header(header, rows, delimiter):
    with scratch() as folder:
        path = folder / 'rows.csv'
        text = csv_text(header, [[cell.replace(delimiter, ' ') for cell in row] for row in rows],
                        delimiter)
        path.write_text(text, encoding='utf-8')
        read(path)


MUTATIONS = ('truncate', 'swap_columns', 'drop_column', 'bad_cells', 'huge_values',
             'duplicate_rows', 'shuffle_rows', 'swap_blocks', 'drop_header')


@FUZZ
@given(mutations=st.lists(st.sampled_from(MUTATIONS), min_size=1, max_size=4),
       data=st.data())
def test_mutated_valid_csv(mutations, data):
    header, rows = list(HEADER), valid_rows(data.draw(st.integers(1, 60), 'rows'))
    text = None
    for mutation in mutations:
        if mutation == 'swap_columns' and len(header) >= 2:
            i, j = data.draw(st.lists(st.integers(0, len(header) - 1), min_size=2, max_size=2))
            header[i], header[j] = header[j], header[i]
        elif mutation == 'drop_column' and header:
            k = data.draw(st.integers(0, len(header) - 1))
            header.pop(k)
            rows = [row[:k] + row[k + 1:] for row in rows]
        elif mutation in ('bad_cells', 'huge_values'):
            values = (st.sampled_from(['nan', 'inf', '-inf', '', 'abc', '1.2.3', '∞'])
                      if mutation == 'bad_cells' else
                      st.sampled_from(['1e308', '-1e308', '1.7976931348623157e308', '1e300',
                                       '5e-324', '1e999']))
            for _ in range(data.draw(st.integers(1, 10))):
                if rows and header:
                    row = data.draw(st.integers(0, len(rows) - 1))
                    column = data.draw(st.integers(0, len(header) - 1))
                    rows[row] = list(rows[row])
                    if column < len(rows[row]):
                        rows[row][column] = data.draw(values)
        elif mutation == 'duplicate_rows' and rows:
            picks = data.draw(st.lists(st.integers(0, len(rows) - 1), max_size=10))
            rows = rows + [rows[k] for k in picks]
        elif mutation == 'shuffle_rows':
            rows = data.draw(st.permutations(rows))
        elif mutation == 'swap_blocks' and len(rows) > 2:
            cut = data.draw(st.integers(1, len(rows) - 1))
            rows = rows[cut:] + rows[:cut]
        elif mutation == 'drop_header':
            header = rows[0] if rows else []
            rows = rows[1:]
    text = csv_text(header, rows)
    if 'truncate' in mutations:
        text = text[:data.draw(st.integers(0, len(text)))]
    with scratch() as folder:
        path = folder / 'mutated.csv'
        path.write_text(text, encoding='utf-8')
        result = read(path)
    reordered_only = set(mutations) <= {'shuffle_rows', 'swap_blocks', 'duplicate_rows'}
    if isinstance(result, Recording) and reordered_only:
        # Only the order changed: every valid row comes back, in time order.
        assert len(result) == len({tuple(row) for row in rows})


@pytest.mark.slow
@FUZZ
@given(mutations=st.lists(st.sampled_from(MUTATIONS), min_size=1, max_size=3),
       seed=st.integers(0, 2**32 - 1))
def test_mutated_csv_through_the_command_line(tmp_path, capsys, mutations, seed):
    """Fit, then evaluate: exit 0 with finite JSON figures, or exit 2 with one error line."""
    rng = np.random.default_rng(seed)
    rows = valid_rows(int(rng.integers(2, 400)), seed)
    if 'shuffle_rows' in mutations:
        rows = [rows[k] for k in rng.permutation(len(rows))]
    if 'duplicate_rows' in mutations:
        rows += [rows[k] for k in rng.integers(0, len(rows), 5)]
    if 'bad_cells' in mutations or 'huge_values' in mutations:
        for _ in range(10):
            cell = str(rng.choice(['nan', 'inf', 'abc', '', '1e308', '-1e308', '1e300']))
            rows[int(rng.integers(len(rows)))][int(rng.integers(len(HEADER)))] = cell
    header = list(HEADER)
    if 'swap_columns' in mutations:
        i, j = rng.choice(len(header), 2, replace=False)
        header[i], header[j] = header[j], header[i]
    text = csv_text(header, rows)
    if 'truncate' in mutations:
        text = text[:int(rng.integers(0, len(text) + 1))]
    with scratch() as folder:
        path = folder / 'run.csv'
        path.write_text(text)
        params = folder / 'params.yaml'
        code = main(['fit', str(path), '--out', str(params), '--max-order', '3'])
        out, err = capsys.readouterr()
        assert_command_outcome(code, out, err)
        if code == 0:
            code = main(['evaluate', str(path), '--params', str(params), '--json'])
            out, err = capsys.readouterr()
            assert_command_outcome(code, out, err)
            if code == 0:
                report = json.loads(out)
                for part in ('per_sample', 'averaged'):
                    for figures in report[part].values():
                        assert all(math.isfinite(v) for v in figures.values()), figures


def assert_command_outcome(code, out, err):
    assert code in (0, 2), (code, err)
    assert 'Traceback' not in err
    if code == 2:
        # One error line, last; the plausibility checks may warn before it.
        *warnings, error = err.splitlines()
        assert error.startswith('error: ') and err.endswith('\n'), err
        assert all(w.startswith('warning: ') for w in warnings), err
    else:
        # Whole words: a temporary folder's random name may hold 'nan' or 'inf' (fuzz_annanmd7).
        assert not re.search(r'\b(nan|inf)\b', out.lower()), out


# --- bags -------------------------------------------------------------------------------------

def write_bag(path: Path, storage: str, messages: int = 12) -> Path:
    with RawBagWriter(path, storage, TOPICS) as bag:
        bag.write_supply_voltage(T0_NS, SupplyVoltageRecord(T0_NS, 'battery', 5.0))
        for i in range(messages):
            stamp_ns = T0_NS + i * PERIOD_NS
            bag.write_temperature(stamp_ns, TemperatureRecord(stamp_ns, 'gyro', 20.0 + i, 0.0))
            bag.write_imu(stamp_ns, ImuRecord(
                stamp_ns=stamp_ns, frame_id='gyro',
                angular_velocity_rad_s=[math.nan, 0.01 * i, -0.01 * i],
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration_m_s2=[0.0, 0.0, 9.8],
                linear_acceleration_covariance=np.zeros(9),
                orientation_covariance=np.r_[-1.0, np.zeros(8)]))
    return path


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """One valid bag per storage, written with the project's writer."""
    folder = tmp_path_factory.mktemp('bags')
    return {storage: write_bag(folder / storage, storage) for storage in ('sqlite3', 'mcap')}


def storage_file(bag: Path) -> Path:
    (file,) = [p for p in bag.iterdir() if p.suffix in ('.db3', '.mcap')]
    return file


def read_bag(path: Path):
    """Load the bag as the toolkit does and iterate it as the driver does."""
    result = read(path, imu_topic=TOPICS.imu, temperature_topic=TOPICS.temperature)
    try:
        with RawBagReader(path, TOPICS) as reader:
            for _, _, record in reader.records():
                assert isinstance(record, (ImuRecord, TemperatureRecord, SupplyVoltageRecord))
    except BagError as err:
        assert str(err)
    return result


@BAG_FUZZ
@given(storage=st.sampled_from(['sqlite3', 'mcap']), fraction=st.floats(0.0, 1.0))
def test_truncated_bags(bags, storage, fraction):
    with scratch() as folder:
        bag = shutil.copytree(bags[storage], folder / 'bag')
        file = storage_file(bag)
        content = file.read_bytes()
        file.write_bytes(content[:int(len(content) * fraction)])
        read_bag(bag)


@BAG_FUZZ
@given(storage=st.sampled_from(['sqlite3', 'mcap']),
       flips=st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(1, 255)),
                      min_size=1, max_size=20))
@example(storage='mcap', flips=[(0.75, 128)])                 # a name no longer UTF-8
@example(storage='mcap', flips=[(0.49271365906316983, 128)])  # a length beyond any index
def test_bags_with_flipped_bytes(bags, storage, flips):
    with scratch() as folder:
        bag = shutil.copytree(bags[storage], folder / 'bag')
        file = storage_file(bag)
        content = bytearray(file.read_bytes())
        for where, mask in flips:
            content[int(where * len(content))] ^= mask
        file.write_bytes(bytes(content))
        read_bag(bag)


@BAG_FUZZ
@given(storage=st.sampled_from(['sqlite3', 'mcap']), data=st.data())
def test_bags_with_a_mutated_metadata_file(bags, storage, data):
    with scratch() as folder:
        bag = shutil.copytree(bags[storage], folder / 'bag')
        metadata = bag / 'metadata.yaml'
        text = metadata.read_text()
        mutation = data.draw(st.sampled_from(['truncate', 'replace', 'garbage', 'delete']))
        if mutation == 'truncate':
            text = text[:data.draw(st.integers(0, len(text)))]
        elif mutation == 'replace':
            old = data.draw(st.sampled_from(['message_count', 'sensor_msgs/msg/Imu', 'mcap',
                                             'sqlite3', 'version: 8', 'cdr', '/imu/data',
                                             'relative_file_paths']))
            text = text.replace(old, data.draw(st.sampled_from(['', 'x', '-1', '99',
                                                                'std_msgs/msg/String'])))
        elif mutation == 'garbage':
            text = data.draw(st.text(max_size=200))
        if mutation == 'delete':
            metadata.unlink()
        else:
            metadata.write_text(text)
        read_bag(bag)


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_bags_with_topics_of_the_wrong_type_or_missing(tmp_path, storage):
    wrong = RawTopics(imu='/imu/temperature', temperature='/imu/data')
    with RawBagWriter(tmp_path / 'swapped', storage, wrong) as bag:
        bag.write_imu(T0_NS, ImuRecord(T0_NS, 'gyro', [0.0] * 3, np.zeros(9), [0.0] * 3,
                                       np.zeros(9), np.zeros(9)))
        bag.write_temperature(T0_NS, TemperatureRecord(T0_NS, 'gyro', 25.0, 0.0))
    message = read(tmp_path / 'swapped', imu_topic=TOPICS.imu,
                   temperature_topic=TOPICS.temperature)
    assert 'has type sensor_msgs/msg/' in message and 'expected sensor_msgs/msg/' in message
    with RawBagWriter(tmp_path / 'no_imu', storage, TOPICS) as bag:
        bag.write_temperature(T0_NS, TemperatureRecord(T0_NS, 'gyro', 25.0, 0.0))
    assert 'no IMU topic /imu/data' in read(tmp_path / 'no_imu', imu_topic=TOPICS.imu)
    with RawBagWriter(tmp_path / 'no_temperature', storage, TOPICS) as bag:
        bag.write_imu(T0_NS, ImuRecord(T0_NS, 'gyro', [0.0] * 3, np.zeros(9), [0.0] * 3,
                                       np.zeros(9), np.zeros(9)))
    assert 'no message on temperature topic /imu/temperature' in \
        read(tmp_path / 'no_temperature', imu_topic=TOPICS.imu,
             temperature_topic=TOPICS.temperature)


# --- EEPROM -----------------------------------------------------------------------------------

def assert_decodes_or_refuses(image: bytes) -> None:
    """Decode and build both tables: finite values, or an error of the core's class."""
    try:
        fields = decode_eeprom(image)
        for output in Output:
            table = factory_table(fields, output)
            if table is not None:
                assert np.isfinite([*table.tc, *table.zro, *table.sf]).all()
    except TempCompError as err:
        assert str(err)


@FUZZ
@given(image=st.binary(min_size=EEPROM_SIZE, max_size=EEPROM_SIZE))
def test_random_images(image):
    assert_decodes_or_refuses(image)


@FUZZ
@given(image=st.binary(max_size=3 * EEPROM_SIZE))
def test_images_of_any_size(image):
    assume(len(image) != EEPROM_SIZE)
    with pytest.raises(TempCompError, match=f'must be {EEPROM_SIZE} bytes, got {len(image)}'):
        decode_eeprom(image)


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), version=st.sampled_from([0, 1, 2, 3, 255]),
       flips=st.lists(st.tuples(st.integers(0, EEPROM_SIZE - 1), st.integers(0, 7)),
                      max_size=12))
def test_mutated_factory_images_on_the_command_line(tmp_path, capsys, seed, version, flips):
    truth = GyroTruth.random(np.random.default_rng(seed))
    try:
        image = bytearray(factory_eeprom(truth, np.random.default_rng(seed),
                                         FactoryMeasurement(version=version)))
    except TempCompError:
        assume(False)   # the simulated factory cannot store this part's table: no image
    for address, bit in flips:
        image[address] ^= 1 << bit
    assert_decodes_or_refuses(bytes(image))
    with scratch() as folder:
        path = folder / 'eeprom.bin'
        path.write_bytes(bytes(image))
        code = main(['decode-eeprom', str(path), '--json'])
        out, err = capsys.readouterr()
    assert code in (0, 2) and 'Traceback' not in err
    if code == 2:
        assert err.startswith('error: ') and err.count('\n') == 1 + err.count('warning:'), err
        return
    decoded = json.loads(out, parse_constant=lambda name: pytest.fail(f'{name} in {out}'))
    assert err.count('warning:') == sum(1 for n in decoded['outvoted_bits'].values() if n)
