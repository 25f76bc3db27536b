"""The factory table in physical units: AN2 section 3.4 VERSION formulas."""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .conversion import Output, SensorTransfer
from .eeprom import decode_eeprom, EepromFields
from .interpolation import check_triplets
from ..errors import ConfigError, EepromError

# Calibration temperatures of the triplets (AN2 section 3).
TRIPLET_TEMPERATURES_C = (-40.0, 25.0, 85.0)


@dataclass(frozen=True)
class FactoryTable:
    """
    Three triplets {TC, ZRO, SF} in the units of one output.

    Digital: TC in temperature-channel LSB, ZRO in rate LSB, SF in LSB/(deg/s).
    Analog: TC and ZRO in mV, SF in mV/(deg/s).
    """

    output: Output
    tc: tuple
    zro: tuple
    sf: tuple

    def __post_init__(self) -> None:
        check_triplets(self.tc, self.zro)
        _, sf = check_triplets(self.tc, self.sf)
        if np.any(sf <= 0.0):
            msg = f'scale factors must be positive, got SF={list(self.sf)}'
            raise ConfigError(msg)


def zro_from_ee(version: int, ee_zro: int, output: Output) -> float:
    """ZRO_i from its EEPROM byte, by the formula of ``version``."""
    if version == 1:
        return 2400.0 + ee_zro if output is Output.ANALOG else 960.0 + ee_zro * 12.0 / 25.0
    if version in (2, 3, 255):
        if output is Output.ANALOG:
            return 2300.0 + 400.0 * ee_zro / 255.0
        return 912.0 + 192.0 * ee_zro / 255.0
    msg = f'EEPROM VERSION {version} has no ZRO formula'
    raise EepromError(msg)


def sf_from_ee(ee_sf: int, typical_sf: float) -> float:
    """SF_i from its EEPROM byte: (0.95 + SF_EE / 2560) x S0, for every VERSION >= 1."""
    return (0.95 + ee_sf / 2560.0) * typical_sf


def factory_table(fields: EepromFields, output: Output,
                  transfer: SensorTransfer = SensorTransfer(),
                  full_scale_dps: Optional[float] = None) -> Optional[FactoryTable]:
    """
    Apply the VERSION formulas; None for VERSION 0 (the EEPROM holds no table).

    ``full_scale_dps`` overrides the full scale read from RANGE, which sets the
    typical scale factor S0.
    """
    if not fields.has_table:
        return None
    full_scale = fields.full_scale_dps if full_scale_dps is None else full_scale_dps
    if full_scale <= 0.0:
        msg = (f'EEPROM RANGE is {fields.range_code}, so the full scale and the typical '
               'scale factor are unknown; give the full scale explicitly')
        raise EepromError(msg)
    typical = transfer.typical_sf(full_scale, output)
    tc = tuple(float(transfer.temperature_to_output(float(mv), output)) for mv in fields.tc_mv)
    zro = tuple(zro_from_ee(fields.version, ee, output) for ee in fields.ee_zro)
    sf = tuple(sf_from_ee(ee, typical) for ee in fields.ee_sf)
    try:
        return FactoryTable(output=output, tc=tc, zro=zro, sf=sf)
    except ConfigError as err:
        msg = f'EEPROM table is unusable: {err}'
        raise EepromError(msg) from None


def ee_from_zro(version: int, zro: float, output: Output) -> int:
    """Inverse of `zro_from_ee`, rounded to the nearest storable byte."""
    if version == 1:
        ee = zro - 2400.0 if output is Output.ANALOG else (zro - 960.0) * 25.0 / 12.0
    elif version in (2, 3, 255):
        ee = ((zro - 2300.0) * 255.0 / 400.0 if output is Output.ANALOG
              else (zro - 912.0) * 255.0 / 192.0)
    else:
        msg = f'EEPROM VERSION {version} has no ZRO formula'
        raise EepromError(msg)
    return _storable_byte('ZRO', zro, ee)


def ee_from_sf(sf: float, typical_sf: float) -> int:
    """Inverse of `sf_from_ee`, rounded to the nearest storable byte."""
    return _storable_byte('SF', sf, (sf / typical_sf - 0.95) * 2560.0)


def _storable_byte(name: str, value: float, ee: float) -> int:
    code = int(round(ee))
    if not 0 <= code <= 255:
        msg = f'{name} {value:.4g} is outside what the EEPROM byte can store'
        raise EepromError(msg)
    return code


@dataclass(frozen=True)
class SensorTables:
    """The decoded EEPROMs of one to three chips read as one sensor."""

    fields: tuple
    full_scale_dps: float
    tables: tuple

    @property
    def outvoted_bits(self) -> int:
        return sum(f.total_outvoted_bits for f in self.fields)


def sensor_tables(images, output: Output, transfer: SensorTransfer = SensorTransfer(),
                  full_scale_dps: float = 0.0) -> SensorTables:
    """
    Decode each chip's EEPROM image and build its factory table.

    The chips share one full scale: ``full_scale_dps`` when positive, else
    their common RANGE field.
    """
    fields = tuple(decode_eeprom(image) for image in images)
    if not 1 <= len(fields) <= 3:
        msg = f'one to three EEPROM images are supported, got {len(fields)}'
        raise EepromError(msg)
    if full_scale_dps <= 0.0:
        scales = sorted({f.full_scale_dps for f in fields})
        if len(scales) != 1 or scales[0] <= 0.0:
            msg = (f'the chips report full scales {scales} deg/s (RANGE x 5); give the full '
                   'scale explicitly')
            raise EepromError(msg)
        full_scale_dps = scales[0]
    return SensorTables(fields=fields, full_scale_dps=full_scale_dps,
                        tables=tuple(factory_table(f, output, transfer, full_scale_dps)
                                     for f in fields))
