"""
The MLX90609's own formulas and tables: its EEPROM, its factory table, its conversions.

The package, by module, each importing only those above it: `conversion` (the channels'
transfer functions, ADC code to mV to deg/s or degC, analog or digital output),
`eeprom` (the look-up table's bit layout, the majority vote of its copies, the VERSION
formulas' fields), `interpolation` (ZRO(TEMPOUT) and SF(TEMPOUT) between three
calibration triplets, application note AN2), `factory_table` (the factory table a
VERSION's formulas give, the tables of several chips from their EEPROM images),
`table_compensation` (Q = (OUTAR - ZRO) / SF, AN2 formula (2), and the nominal
conversion without a table). The node's ``eeprom`` model runs these
(`node_models.EepromModel`).
"""

from .conversion import ADC_MAX_CODE, Output, SensorTransfer
from .eeprom import decode_eeprom, EEPROM_SIZE, EepromFields, encode_eeprom, VOTED_FIELDS
from .factory_table import (ee_from_sf, ee_from_zro, factory_table, sensor_tables,
                            TRIPLET_TEMPERATURES_C)
from .interpolation import Interpolation
from .table_compensation import NominalConversion, table_compensation, TableCompensation

__all__ = ['ADC_MAX_CODE', 'decode_eeprom', 'ee_from_sf', 'ee_from_zro', 'EEPROM_SIZE',
           'EepromFields', 'encode_eeprom', 'factory_table', 'Interpolation', 'NominalConversion',
           'Output', 'sensor_tables', 'SensorTransfer', 'table_compensation', 'TableCompensation',
           'TRIPLET_TEMPERATURES_C', 'VOTED_FIELDS']
