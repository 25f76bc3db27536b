"""
MLX90609 EEPROM look-up table: bit layout, majority voting, VERSION formulas.

Implements sections 3.1-3.4 of Melexis AN2 "MLX90609 Temperature Compensation
Improvement" (rev 1.3).

Layout (LSB at the lowest address, one bit of each field per byte):

- RANGE: bits 0, 1, 2 of 0x68..0x6F, majority-voted; full scale = 5 x RANGE deg/s.
- VERSION: bits 3, 4, 5 of 0x60..0x67, majority-voted.
- TC0, TC1, TC2 (16 bit, mV on TEMPOUT): bits 0, 1, 2 of 0x38..0x47,
  0x48..0x57 and 0x58..0x67, majority-voted.
- EE_ZRO0..2 and EE_SF0..2 (8 bit): bit 6 of 0x20..0x27, 0x28..0x2F, 0x30..0x37,
  0x38..0x3F, 0x40..0x47 and 0x48..0x4F, stored once (not voted).
"""

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..errors import EepromError

EEPROM_SIZE = 128

VERSION_NO_TABLE = 0
KNOWN_VERSIONS = (0, 1, 2, 3, 255)

# The voted copies sit in three adjacent bits of each byte.
_LOW_VOTE_BITS = (0, 1, 2)
_VERSION_VOTE_BITS = (3, 4, 5)
_SINGLE_BIT = 6


@dataclass(frozen=True)
class _FieldLayout:
    name: str
    first_address: int
    width_bits: int
    bits: tuple


_RANGE = _FieldLayout('RANGE', 0x68, 8, _LOW_VOTE_BITS)
_VERSION = _FieldLayout('VERSION', 0x60, 8, _VERSION_VOTE_BITS)
_TC = tuple(_FieldLayout(f'TC{i}', 0x38 + 16 * i, 16, _LOW_VOTE_BITS) for i in range(3))
_EE_ZRO = tuple(_FieldLayout(f'EE_ZRO{i}', 0x20 + 8 * i, 8, (_SINGLE_BIT,)) for i in range(3))
_EE_SF = tuple(_FieldLayout(f'EE_SF{i}', 0x38 + 8 * i, 8, (_SINGLE_BIT,)) for i in range(3))
VOTED_FIELDS = tuple(f.name for f in (_RANGE, _VERSION) + _TC)


@dataclass(frozen=True)
class EepromFields:
    """
    Raw fields of the factory table, as stored (before the VERSION formulas).

    ``outvoted_bits`` counts, per voted field, the bits whose three copies
    disagreed (a worn cell or a bad SPI read); the majority value was used.
    ``voted_copies`` gives, per voted field, the value each copy holds on its
    own (copy i is stored in the i-th vote bit). Both describe the read, not
    the table, so equality ignores them.
    """

    range_code: int
    version: int
    tc_mv: tuple
    ee_zro: tuple
    ee_sf: tuple
    outvoted_bits: Mapping[str, int] = field(
        default_factory=lambda: dict.fromkeys(VOTED_FIELDS, 0), compare=False)
    voted_copies: Mapping[str, tuple] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if self.version not in KNOWN_VERSIONS:
            msg = (f'unknown EEPROM VERSION {self.version} (0x{self.version:02X}); '
                   f'AN2 defines {", ".join(str(v) for v in KNOWN_VERSIONS)}')
            raise EepromError(msg)
        _check_width('RANGE', (self.range_code,), 8)
        _check_width('TC', self.tc_mv, 16)
        _check_width('EE_ZRO', self.ee_zro, 8)
        _check_width('EE_SF', self.ee_sf, 8)

    @property
    def has_table(self) -> bool:
        return self.version != VERSION_NO_TABLE

    @property
    def full_scale_dps(self) -> float:
        return 5.0 * self.range_code

    @property
    def total_outvoted_bits(self) -> int:
        return sum(self.outvoted_bits.values())


def _check_width(name: str, values: tuple, width: int) -> None:
    if len(values) not in (1, 3):
        msg = f'{name} needs 3 values, got {len(values)}'
        raise EepromError(msg)
    for value in values:
        if not 0 <= int(value) < (1 << width) or int(value) != value:
            msg = f'{name} value {value} does not fit in {width} bits'
            raise EepromError(msg)


def _read_field(image: np.ndarray, layout: _FieldLayout) -> tuple:
    """Return (value, outvoted bit count, value of each copy) of one field."""
    cells = image[layout.first_address:layout.first_address + layout.width_bits]
    copies = np.stack([(cells >> b) & 1 for b in layout.bits])
    votes = copies.sum(axis=0)
    bits = (2 * votes > len(layout.bits)).astype(np.int64)
    outvoted = int(np.count_nonzero((votes != 0) & (votes != len(layout.bits))))
    weights = np.int64(1) << np.arange(layout.width_bits, dtype=np.int64)
    value = int((bits * weights).sum())
    return value, outvoted, tuple(int((copy * weights).sum()) for copy in copies)


def _voted_value(image: np.ndarray, layout: _FieldLayout) -> int:
    """Return the voted value of one field."""
    value, _, _ = _read_field(image, layout)
    return value


def decode_eeprom(image: bytes) -> EepromFields:
    """
    Recover RANGE, VERSION, TC0..2, EE_ZRO0..2 and EE_SF0..2 from a 128-byte image.

    Raises
    ------
    EepromError
        Wrong image size, or a VERSION that AN2 does not define.

    """
    if len(image) != EEPROM_SIZE:
        msg = f'EEPROM image must be {EEPROM_SIZE} bytes, got {len(image)}'
        raise EepromError(msg)
    cells = np.frombuffer(bytes(image), dtype=np.uint8).astype(np.int64)
    outvoted = {}
    copies = {}
    values = {}
    for layout in (_RANGE, _VERSION) + _TC:
        values[layout.name], outvoted[layout.name], copies[layout.name] = \
            _read_field(cells, layout)
    ee_zro = tuple(_voted_value(cells, layout) for layout in _EE_ZRO)
    ee_sf = tuple(_voted_value(cells, layout) for layout in _EE_SF)
    return EepromFields(range_code=values['RANGE'], version=values['VERSION'],
                        tc_mv=tuple(values[layout.name] for layout in _TC), ee_zro=ee_zro,
                        ee_sf=ee_sf, outvoted_bits=outvoted, voted_copies=copies)


def encode_eeprom(fields: EepromFields, *, fill: bytes = bytes(EEPROM_SIZE)) -> bytes:
    """
    Build a 128-byte image holding ``fields``: the inverse of `decode_eeprom`.

    Bits the table does not use keep their value from ``fill`` (for example the
    user area 0x70..0x7F, or unrelated bits a real part carries).
    """
    if len(fill) != EEPROM_SIZE:
        msg = f'fill image must be {EEPROM_SIZE} bytes, got {len(fill)}'
        raise EepromError(msg)
    cells = bytearray(fill)
    layouts = ((_RANGE, fields.range_code), (_VERSION, fields.version))
    layouts += tuple(zip(_TC, fields.tc_mv)) + tuple(zip(_EE_ZRO, fields.ee_zro))
    layouts += tuple(zip(_EE_SF, fields.ee_sf))
    for layout, value in layouts:
        for i in range(layout.width_bits):
            bit = (int(value) >> i) & 1
            for position in layout.bits:
                address = layout.first_address + i
                cells[address] = (cells[address] & ~(1 << position)) | (bit << position)
    return bytes(cells)
