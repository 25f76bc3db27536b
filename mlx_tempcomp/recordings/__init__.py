"""
Recorded files for the toolkit and the driver's replay: CSV, rosbag2 bags, flight-controller logs.

`recording` is what the toolkit works on (`Recording`), `plausibility` whether its
columns hold what they claim; `load` loads one by the path's extension; `columns` and
`csv_reader` read CSV files, `csv_writer` writes them; `bag`, `bag_reader` and `bag_writer`
our raw topics in rosbag2 bags, `eeprom_multiarray` the EEPROM images as ``imu/eeprom``
lays them out (the nodes share it); `flightlog` PX4 ULog (`ulog`) and ArduPilot DataFlash
(`dataflash`) logs; `errors` the layer's error class. No rclpy. Callers import the module
they need.

The flight-log readers register their suffixes with `flightlog` when they are
imported, which is here: importing any module of this package imports them.
"""

from . import dataflash, ulog  # noqa: F401 - they register with flightlog on import

__all__ = ['bag', 'bag_reader', 'bag_writer', 'columns', 'csv_reader', 'csv_writer', 'dataflash',
           'eeprom_multiarray', 'errors', 'flightlog', 'load', 'plausibility', 'recording',
           'ulog']
