"""Rosbag2 replay and recording of the raw topics (sqlite3 and mcap), without rclpy."""

import array

from mlx_tempcomp.recordings.bag import (BagError, EepromRecord, ImuRecord, RawTopics,
                                         SupplyVoltageRecord, TemperatureRecord)
from mlx_tempcomp.recordings.bag_reader import RawBagReader
from mlx_tempcomp.recordings.bag_writer import RawBagWriter
from mlx_tempcomp.recordings.eeprom_multiarray import eeprom_multiarray_from_images
import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import get_typestore, Stores

STORAGES = ('sqlite3', 'mcap')
T0_NS = 1_700_000_000_123_456_789
N_IMU = 300
N_TEMPERATURE = 150
N_SUPPLY = 30


def imu_record(i: int) -> ImuRecord:
    rng = np.random.default_rng(i)
    rate = rng.normal(0.0, 0.1, 3)
    rate[1:] = np.nan  # single-axis gyro: y and z unmeasured
    covariance = np.zeros(9)
    covariance[0] = 1e-6 * (1 + i)
    return ImuRecord(stamp_ns=T0_NS + i * 5_000_000, frame_id='mlx_gyro',
                     angular_velocity_rad_s=rate, angular_velocity_covariance=covariance,
                     linear_acceleration_m_s2=[0.0, 0.0, 0.0],
                     linear_acceleration_covariance=np.r_[-1.0, np.zeros(8)],
                     orientation_covariance=np.r_[-1.0, np.zeros(8)])


def temperature_record(i: int, offset_c: float = 0.0) -> TemperatureRecord:
    return TemperatureRecord(stamp_ns=T0_NS + i * 10_000_000 + 1, frame_id='mlx_gyro',
                             temperature_c=-40.0 + 0.8333 * i + offset_c, variance=0.01 * i)


def supply_record(i: int) -> SupplyVoltageRecord:
    # BatteryState.voltage is a float32: these volts are exact in it.
    return SupplyVoltageRecord(stamp_ns=T0_NS + i * 50_000_000 + 3, frame_id='battery',
                               voltage_v=4.75 + i / 64)


def eeprom_record(axes: int = 3) -> EepromRecord:
    return EepromRecord(tuple(bytes((a * 37 + b) % 256 for b in range(128))
                              for a in range(axes)))


def write_bag(path, storage='sqlite3', topics=RawTopics(), imu_count=N_IMU):
    """Write IMU, two temperature topics, the supply and the EEPROM, in shuffled order."""
    rng = np.random.default_rng(0)
    items = [(T0_NS + i * 5_000_000, 'imu', i) for i in range(imu_count)]
    items += [(T0_NS + i * 10_000_000 + 1, 'temperature', i) for i in range(N_TEMPERATURE)]
    items += [(T0_NS + i * 10_000_000 + 2, 'chip_x', i) for i in range(N_TEMPERATURE)]
    items += [(T0_NS + i * 50_000_000 + 3, 'supply', i) for i in range(N_SUPPLY)]
    items.append((T0_NS - 1, 'eeprom', 0))
    order = rng.permutation(len(items))
    with RawBagWriter(path, storage, topics, extra_temperature_topics=['imu/chip_x']) as bag:
        for index in order:
            bag_time_ns, kind, i = items[index]
            if kind == 'imu':
                bag.write_imu(bag_time_ns, imu_record(i))
            elif kind == 'temperature':
                bag.write_temperature(bag_time_ns, temperature_record(i))
            elif kind == 'chip_x':
                bag.write_temperature(bag_time_ns, temperature_record(i, 0.5), '/imu/chip_x')
            elif kind == 'supply':
                bag.write_supply_voltage(bag_time_ns, supply_record(i))
            else:
                bag.write_eeprom(bag_time_ns, eeprom_record())
    return sorted(items)


@pytest.mark.parametrize('storage', STORAGES)
def test_round_trip_in_bag_time_order(tmp_path, storage):
    # written with relative names, read with absolute ones (and the reverse for chip_x)
    written = RawTopics(imu='imu/data_raw', temperature='imu/temperature_raw',
                        eeprom='imu/eeprom', supply_voltage='imu/supply_voltage')
    items = write_bag(tmp_path / 'bag', storage, written)
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()
    suffix = '.db3' if storage == 'sqlite3' else '.mcap'
    assert len(list((tmp_path / 'bag').glob('*' + suffix))) == 1

    with RawBagReader(tmp_path / 'bag', extra_temperature_topics=['/imu/chip_x']) as bag:
        assert set(bag.bag_topics) == {'/imu/data_raw', '/imu/temperature_raw',
                                       '/imu/chip_x', '/imu/eeprom', '/imu/supply_voltage'}
        assert bag.message_count == N_IMU + 2 * N_TEMPERATURE + N_SUPPLY
        assert bag.has_supply_voltage
        assert bag.eeprom == eeprom_record()
        records = list(bag.records())
        assert bag.skipped == 0

    assert [t for t, _, _ in records] == [t for t, _, _ in items]
    topics = {'imu': '/imu/data_raw', 'temperature': '/imu/temperature_raw',
              'chip_x': '/imu/chip_x', 'eeprom': '/imu/eeprom', 'supply': '/imu/supply_voltage'}
    for (bag_time_ns, kind, i), (read_time_ns, topic, record) in zip(items, records):
        assert read_time_ns == bag_time_ns
        assert topic == topics[kind]
        if kind == 'imu':
            expected = imu_record(i)
            assert record == expected
            assert record.angular_velocity_rad_s[0] == expected.angular_velocity_rad_s[0]
            assert np.isnan(record.angular_velocity_rad_s[1:]).all()
            assert record.angular_velocity_rad_s.dtype == np.float64
        elif kind == 'temperature':
            assert record == temperature_record(i)
        elif kind == 'chip_x':
            assert record == temperature_record(i, 0.5)
        elif kind == 'supply':
            assert record == supply_record(i)
        else:
            assert record == eeprom_record()


def test_records_can_be_replayed_and_eeprom_read_midway(tmp_path):
    write_bag(tmp_path / 'bag', 'mcap')
    with RawBagReader(tmp_path / 'bag', extra_temperature_topics=['imu/chip_x']) as bag:
        first = []
        for n, item in enumerate(bag.records()):
            first.append(item)
            if n == 10:
                assert len(bag.eeprom.images) == 3
        second = list(bag.records())
    assert len(first) == len(second) == N_IMU + 2 * N_TEMPERATURE + N_SUPPLY + 1
    assert [t for t, _, _ in first] == [t for t, _, _ in second]


def test_bag_without_eeprom_gives_none(tmp_path):
    with RawBagWriter(tmp_path / 'bag', 'mcap') as bag:
        bag.write_imu(5, imu_record(0))
    with RawBagReader(tmp_path / 'bag') as bag:
        assert bag.eeprom is None
        assert bag.message_count == 1
        assert not bag.has_supply_voltage
        assert [(t, topic) for t, topic, _ in bag.records()] == [(5, '/imu/data_raw')]


@pytest.mark.parametrize('storage', STORAGES)
def test_cdr_bytes_from_rclpy_read_back_equal(tmp_path, storage):
    serialization = pytest.importorskip('rclpy.serialization')
    from sensor_msgs.msg import BatteryState, Imu, Temperature
    from std_msgs.msg import MultiArrayDimension, UInt8MultiArray

    imu = Imu()
    imu.header.stamp.sec, imu.header.stamp.nanosec = 1_700_000_000, 123_456_789
    imu.header.frame_id = 'mlx_gyro'
    imu.angular_velocity.x, imu.angular_velocity.y = 0.25, float('nan')
    imu.angular_velocity.z = -1.5
    imu.angular_velocity_covariance[0] = 1e-6
    imu.orientation_covariance[0] = -1.0
    imu.linear_acceleration.z = 9.80665
    temperature = Temperature(temperature=31.25, variance=0.04)
    temperature.header.stamp.sec, temperature.header.stamp.nanosec = 1_700_000_000, 5
    temperature.header.frame_id = 'mlx_gyro'
    supply = BatteryState(voltage=5.125)
    supply.header.stamp.sec, supply.header.stamp.nanosec = 1_700_000_000, 7
    supply.header.frame_id = 'battery'
    images = eeprom_record(2).images
    dims, data = eeprom_multiarray_from_images(images)
    eeprom = UInt8MultiArray(data=array.array('B', data))
    eeprom.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                         for label, size, stride in dims]

    with RawBagWriter(tmp_path / 'bag', storage) as bag:
        bag.write_raw(1, '/imu/eeprom', 'std_msgs/msg/UInt8MultiArray',
                      serialization.serialize_message(eeprom))
        bag.write_raw(2, '/imu/data_raw', 'sensor_msgs/msg/Imu',
                      serialization.serialize_message(imu))
        bag.write_raw(3, '/imu/temperature_raw', 'sensor_msgs/msg/Temperature',
                      serialization.serialize_message(temperature))
        bag.write_raw(4, '/imu/supply_voltage', 'sensor_msgs/msg/BatteryState',
                      serialization.serialize_message(supply))

    with RawBagReader(tmp_path / 'bag') as bag:
        assert bag.eeprom == EepromRecord(images)
        records = list(bag.records())
        assert bag.skipped == 0
    assert [(t, topic) for t, topic, _ in records] == [
        (1, '/imu/eeprom'), (2, '/imu/data_raw'), (3, '/imu/temperature_raw'),
        (4, '/imu/supply_voltage')]
    assert records[1][2] == ImuRecord(
        stamp_ns=1_700_000_000_123_456_789, frame_id='mlx_gyro',
        angular_velocity_rad_s=[0.25, np.nan, -1.5],
        angular_velocity_covariance=np.r_[1e-6, np.zeros(8)],
        linear_acceleration_m_s2=[0.0, 0.0, 9.80665],
        linear_acceleration_covariance=np.zeros(9),
        orientation_covariance=np.r_[-1.0, np.zeros(8)])
    assert records[2][2] == TemperatureRecord(1_700_000_000_000_000_005, 'mlx_gyro', 31.25, 0.04)
    assert records[3][2] == SupplyVoltageRecord(1_700_000_000_000_000_007, 'battery', 5.125)


def test_supply_voltage_written_here_deserializes_in_rclpy(tmp_path):
    serialization = pytest.importorskip('rclpy.serialization')
    from rosbags.rosbag2 import Reader
    from sensor_msgs.msg import BatteryState

    with RawBagWriter(tmp_path / 'bag') as bag:
        bag.write_supply_voltage(9, supply_record(4))
    with Reader(tmp_path / 'bag') as reader:
        [(connection, _, data)] = list(reader.messages())
    assert connection.msgtype == 'sensor_msgs/msg/BatteryState'
    msg = serialization.deserialize_message(data, BatteryState)
    assert (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg.header.frame_id,
            msg.voltage) == (supply_record(4).stamp_ns, 'battery', 4.8125)
    # Only the voltage is measured: REP-compatible NaN for the rest, status unknown.
    assert np.isnan([msg.current, msg.charge, msg.capacity, msg.percentage]).all()
    assert msg.present and msg.power_supply_status == BatteryState.POWER_SUPPLY_STATUS_UNKNOWN


def test_corrupt_messages_are_skipped_and_counted(tmp_path):
    with RawBagWriter(tmp_path / 'bag') as bag:
        bag.write_imu(1, imu_record(1))
        bag.write_raw(2, '/imu/data_raw', 'sensor_msgs/msg/Imu', b'\x00\x01\x00\x00garbage')
        bag.write_raw(3, 'imu/temperature_raw', 'sensor_msgs/msg/Temperature', b'')
        bag.write_imu(4, imu_record(4))
    with RawBagReader(tmp_path / 'bag') as bag:
        records = list(bag.records())
        assert [t for t, _, _ in records] == [1, 4]
        assert bag.skipped == 2
        assert '/imu/temperature_raw at 3 ns' in bag.last_skip_reason


def test_bad_eeprom_is_skipped_in_records_and_refused_by_eeprom(tmp_path):
    typestore = get_typestore(Stores.ROS2_JAZZY)
    types = typestore.types
    dimension = types['std_msgs/msg/MultiArrayDimension']
    layout = types['std_msgs/msg/MultiArrayLayout'](
        dim=[dimension(label='axis', size=1, stride=128),
             dimension(label='byte', size=128, stride=128)], data_offset=0)
    short = types['std_msgs/msg/UInt8MultiArray'](layout=layout,
                                                  data=np.zeros(100, dtype=np.uint8))
    with RawBagWriter(tmp_path / 'bag') as bag:
        bag.write_raw(1, '/imu/eeprom', 'std_msgs/msg/UInt8MultiArray',
                      typestore.serialize_cdr(short, 'std_msgs/msg/UInt8MultiArray'))
        bag.write_imu(2, imu_record(2))
    with RawBagReader(tmp_path / 'bag') as bag:
        assert len(list(bag.records())) == 1
        assert bag.skipped == 1
        with pytest.raises(BagError, match='no valid EEPROM.*100 bytes'):
            bag.eeprom


def test_first_valid_eeprom_wins(tmp_path):
    with RawBagWriter(tmp_path / 'bag') as bag:
        bag.write_raw(1, '/imu/eeprom', 'std_msgs/msg/UInt8MultiArray', b'\x00\x01\x00\x00')
        bag.write_eeprom(2, eeprom_record(1))
        bag.write_eeprom(3, eeprom_record(3))
        bag.write_imu(4, imu_record(4))
    with RawBagReader(tmp_path / 'bag') as bag:
        assert bag.eeprom == eeprom_record(1)


def test_missing_path(tmp_path):
    with pytest.raises(BagError, match='does not exist'):
        RawBagReader(tmp_path / 'nope')


def test_folder_without_metadata(tmp_path):
    with pytest.raises(BagError, match='not a rosbag2 folder.*metadata.yaml'):
        RawBagReader(tmp_path)


def test_unreadable_metadata(tmp_path):
    (tmp_path / 'metadata.yaml').write_text(': : [\n')
    with pytest.raises(BagError, match=f'cannot open bag {tmp_path}'):
        RawBagReader(tmp_path)


def test_unknown_file(tmp_path):
    (tmp_path / 'notes.txt').write_text('hello\n')
    with pytest.raises(BagError, match='cannot open bag.*notes.txt'):
        RawBagReader(tmp_path / 'notes.txt')


def test_no_imu_topic_lists_the_topics(tmp_path):
    with RawBagWriter(tmp_path / 'bag') as bag:
        bag.write_temperature(1, temperature_record(1))
    with pytest.raises(BagError, match=r'no IMU topic /imu/data_raw.*/imu/temperature_raw '
                                       r'\(sensor_msgs/msg/Temperature\)'):
        RawBagReader(tmp_path / 'bag')
    with RawBagWriter(tmp_path / 'empty', 'mcap'):
        pass
    with pytest.raises(BagError, match='no IMU topic.*no topics'):
        RawBagReader(tmp_path / 'empty')


def test_empty_imu_topic(tmp_path):
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Writer(tmp_path / 'bag', version=8) as writer:
        writer.add_connection('/imu/data_raw', 'sensor_msgs/msg/Imu', typestore=typestore)
    with pytest.raises(BagError, match='empty: no message on IMU topic /imu/data_raw'):
        RawBagReader(tmp_path / 'bag')


@pytest.mark.parametrize('topic', ['/imu/data_raw', 'imu/temperature_raw', '/imu/eeprom',
                                   '/imu/supply_voltage'])
def test_wrong_message_type(tmp_path, topic):
    with RawBagWriter(tmp_path / 'bag') as bag:
        if topic != '/imu/data_raw':
            bag.write_imu(1, imu_record(1))
        bag.write_raw(2, topic, 'std_msgs/msg/String', b'\x00\x01\x00\x00\x01\x00\x00\x00\x00')
    with pytest.raises(BagError, match=f'topic /?{topic.lstrip("/")} in .* has type '
                                       'std_msgs/msg/String, expected'):
        RawBagReader(tmp_path / 'bag')


def test_writer_refuses_existing_folder_and_bad_storage(tmp_path):
    with pytest.raises(BagError, match='exists already'):
        RawBagWriter(tmp_path)
    with pytest.raises(BagError, match="unknown bag storage 'rosbag1'.*sqlite3, mcap"):
        RawBagWriter(tmp_path / 'bag', 'rosbag1')
    assert not (tmp_path / 'bag').exists()


def test_writer_refuses_bad_input(tmp_path):
    bag = RawBagWriter(tmp_path / 'bag', extra_temperature_topics=['/imu/chip_x'])
    with pytest.raises(BagError, match='/imu/other is not a temperature topic'):
        bag.write_temperature(1, temperature_record(1), '/imu/other')
    with pytest.raises(BagError, match='expected a ImuRecord'):
        bag.write_imu(1, temperature_record(1))
    with pytest.raises(BagError, match='unknown message type'):
        bag.write_raw(1, '/x', 'my_msgs/msg/Nope', b'')
    with pytest.raises(BagError, match='bag_time_ns'):
        bag.write_raw(-1, '/x', 'std_msgs/msg/String', b'')
    bag.write_imu(1, imu_record(1))
    with pytest.raises(BagError, match='already holds sensor_msgs/msg/Imu'):
        bag.write_raw(2, 'imu/data_raw', 'std_msgs/msg/String', b'')
    bag.close()
    bag.close()
    with pytest.raises(BagError, match='closed'):
        bag.write_imu(3, imu_record(3))


def test_record_validation():
    with pytest.raises(BagError, match=r'angular_velocity_rad_s: expected shape \(3,\)'):
        ImuRecord(0, 'f', [0.0, 1.0], np.zeros(9), np.zeros(3), np.zeros(9), np.zeros(9))
    with pytest.raises(BagError, match='^EepromRecord.images: EEPROM image 1: expected 128 bytes, '
                                       'got 127$'):
        EepromRecord((bytes(128), bytes(127)))
    with pytest.raises(BagError, match='no image'):
        EepromRecord(())
    with pytest.raises(BagError, match='stamp_ns'):
        TemperatureRecord(1.5, 'f', 20.0, 0.0)
    record = imu_record(0)
    with pytest.raises(ValueError):
        record.angular_velocity_rad_s[0] = 1.0
    assert record == imu_record(0)
    assert record != imu_record(1)
