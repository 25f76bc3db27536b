"""The EEPROM images as the imu/eeprom UInt8MultiArray carries them, as plain values."""

import array

from mlx_tempcomp.core.errors import EepromError
from mlx_tempcomp.recordings.eeprom_multiarray import (checked_images,
                                                       eeprom_images_from_multiarray,
                                                       eeprom_multiarray_from_images)
import pytest


def test_multiarray_round_trip_and_plain_values():
    images = tuple(bytes((a * 37 + b) % 256 for b in range(128)) for a in range(3))
    dims, data = eeprom_multiarray_from_images(images)
    assert dims == [('axis', 3, 384), ('byte', 128, 128)]
    assert eeprom_images_from_multiarray(dims, data) == images
    assert eeprom_images_from_multiarray(dims, list(data)) == images
    assert eeprom_images_from_multiarray(dims, array.array('B', data)) == images
    assert eeprom_images_from_multiarray(dims, b'\xff' + data, data_offset=1) == images


@pytest.mark.parametrize('dims, size, words', [
    ([('axis', 1, 128)], 128, '2 dims'),
    ([('byte', 128, 128), ('axis', 1, 128)], 128, "labels must be 'axis' and 'byte'"),
    ([('axis', 1, 128), ('byte', 64, 64)], 64, 'byte dim must have size and stride 128'),
    ([('axis', 0, 0), ('byte', 128, 128)], 0, 'axis dim must have size >= 1'),
    ([('axis', 2, 128), ('byte', 128, 128)], 256, 'stride must be 2 x 128 = 256, got 128'),
    ([('axis', 2, 256), ('byte', 128, 128)], 255, 'has 255 bytes.*needs 256'),
])
def test_multiarray_layout_errors(dims, size, words):
    with pytest.raises(EepromError, match=words):
        eeprom_images_from_multiarray(dims, bytes(size))


def test_multiarray_data_errors():
    dims = [('axis', 1, 128), ('byte', 128, 128)]
    with pytest.raises(EepromError, match='outside 0..255'):
        eeprom_images_from_multiarray(dims, [256] * 128)
    with pytest.raises(EepromError, match='flat sequence of bytes'):
        eeprom_images_from_multiarray(dims, [0.5] * 128)


def test_images_are_checked_before_they_are_laid_out():
    assert checked_images([bytearray(128), memoryview(bytes(128))]) == (bytes(128),) * 2
    for images, words in ((bytes(128), 'one bytes object'), ((), '^no image$'),
                          ((bytes(128), 'x' * 128), 'image 1: expected bytes, got str'),
                          ((bytes(127),), 'image 0: expected 128 bytes, got 127')):
        with pytest.raises(EepromError, match=words):
            eeprom_multiarray_from_images(images)
