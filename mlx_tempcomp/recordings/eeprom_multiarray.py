"""
The EEPROM images as the ``imu/eeprom`` message carries them: a std_msgs/UInt8MultiArray layout.

The images of every axis, 128 bytes each in axis order, are laid out as dims
[axis: size A, stride 128 A] and [byte: size 128, stride 128]. The message's
layout and data are taken and given as plain values (``(label, size,
stride)`` per dim, the data as bytes), so the compensation node, the driver,
and the bag reader and writer share this code and its checks without a ROS
message type here. Each check raises `EepromError` naming the first thing that
does not fit.
"""

from typing import Sequence, Tuple

import numpy as np

from ..core.errors import EepromError
from ..core.mlx90609 import EEPROM_SIZE


def _image_bytes(image, index: int) -> bytes:
    if not isinstance(image, (bytes, bytearray, memoryview)):
        msg = f'EEPROM image {index}: expected bytes, got {type(image).__name__}'
        raise EepromError(msg)
    image = bytes(image)
    if len(image) != EEPROM_SIZE:
        msg = f'EEPROM image {index}: expected {EEPROM_SIZE} bytes, got {len(image)}'
        raise EepromError(msg)
    return image


def checked_images(images) -> Tuple[bytes, ...]:
    """Give ``images`` as a tuple of 128-byte images, one per axis; EepromError if they are not."""
    if isinstance(images, (bytes, bytearray, memoryview, str)):
        msg = 'expected a sequence of images, got one bytes object'
        raise EepromError(msg)
    checked = tuple(_image_bytes(image, i) for i, image in enumerate(images))
    if not checked:
        msg = 'no image'
        raise EepromError(msg)
    return checked


LayoutDim = Tuple[str, int, int]


def _data_bytes(data) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    array = np.asarray(data)
    if array.ndim != 1 or (array.size and array.dtype.kind not in 'iu'):
        msg = f'EEPROM data must be a flat sequence of bytes, got {type(data).__name__}'
        raise EepromError(msg)
    if array.size and (array.min() < 0 or array.max() > 255):
        msg = 'EEPROM data holds values outside 0..255'
        raise EepromError(msg)
    return array.astype(np.uint8).tobytes()


def eeprom_images_from_multiarray(layout_dims: Sequence[LayoutDim], data,
                                  data_offset: int = 0) -> Tuple[bytes, ...]:
    """
    Check a UInt8MultiArray EEPROM layout and split its data into images.

    Parameters
    ----------
    layout_dims
        ``(label, size, stride)`` of each ``layout.dim`` entry; expected
        ``[('axis', A, 128 A), ('byte', 128, 128)]`` with A >= 1.
    data
        The concatenated images: bytes, bytearray, memoryview, array.array
        or a sequence of ints in 0..255.
    data_offset
        ``layout.data_offset``; the images start there.

    Returns
    -------
    tuple of bytes
        One 128-byte image per axis.

    Raises
    ------
    EepromError
        Naming the first thing that does not fit.

    """
    dims = [tuple(dim) for dim in layout_dims]
    if len(dims) != 2 or any(len(dim) != 3 for dim in dims):
        msg = (f'EEPROM layout must have 2 dims (label, size, stride): axis and byte; '
               f'got {dims}')
        raise EepromError(msg)
    (axis_label, axes, axis_stride), (byte_label, byte_size, byte_stride) = dims
    if (axis_label, byte_label) != ('axis', 'byte'):
        msg = f"EEPROM layout labels must be 'axis' and 'byte', got {axis_label!r} and " \
              f'{byte_label!r}'
        raise EepromError(msg)
    if byte_size != EEPROM_SIZE or byte_stride != EEPROM_SIZE:
        msg = (f'EEPROM byte dim must have size and stride {EEPROM_SIZE}, got size '
               f'{byte_size} and stride {byte_stride}')
        raise EepromError(msg)
    if axes < 1:
        msg = f'EEPROM axis dim must have size >= 1, got {axes}'
        raise EepromError(msg)
    if axis_stride != axes * EEPROM_SIZE:
        msg = (f'EEPROM axis dim stride must be {axes} x {EEPROM_SIZE} = '
               f'{axes * EEPROM_SIZE}, got {axis_stride}')
        raise EepromError(msg)
    if data_offset < 0:
        msg = f'EEPROM data_offset must be >= 0, got {data_offset}'
        raise EepromError(msg)
    raw = _data_bytes(data)
    expected = data_offset + axes * EEPROM_SIZE
    if len(raw) != expected:
        msg = (f'EEPROM data has {len(raw)} bytes; the layout ({axes} axes x {EEPROM_SIZE} '
               f'bytes + offset {data_offset}) needs {expected}')
        raise EepromError(msg)
    return tuple(raw[data_offset + i * EEPROM_SIZE:data_offset + (i + 1) * EEPROM_SIZE]
                 for i in range(axes))


def eeprom_multiarray_from_images(images: Sequence[bytes]) -> Tuple[list, bytes]:
    """Give the ``(layout_dims, data)`` of a UInt8MultiArray carrying the images."""
    images = checked_images(images)
    axes = len(images)
    dims = [('axis', axes, axes * EEPROM_SIZE), ('byte', EEPROM_SIZE, EEPROM_SIZE)]
    return dims, b''.join(images)
