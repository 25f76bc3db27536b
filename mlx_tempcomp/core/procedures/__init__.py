"""
The at-rest calibration procedures of the ADIS16130 and the MPU-6000.

The package, by module: `adis16130_bias` (the ADIS16130 bias procedure of AN-1042, fed
one sample at a time: settle, self-heat, record, the linear BTC from two temperatures),
`mpu6000_offsets` (InvenSense MPU parts' offset registers: the bias at rest to register
values, the registers a refresh writes). Each is driven by its device's node service and
its ``mlx-tempcomp`` command.
"""

from .adis16130_bias import (adev_at_rad_s, averaging_time_s, BiasProcedure,
                             MIN_TEMPERATURE_CHANGE_C, NOTE_AVERAGE_S, NOTE_PBC_S,
                             NOTE_SELF_HEAT_S, NOTE_SETTLE_S, Phase, ProcedureSettings,
                             RECORD_FRACTION, short_window)
from .mpu6000_offsets import (accel_offset_lsb, ACCEL_OFFSET_LSB_PER_G, from_twos_complement,
                              GYRO_OFFSET_DPS_PER_LSB, gyro_offset_lsb, INT16_MAX, INT16_MIN,
                              merge_preserving_bit0, OffsetRefresh, recalibrated_offsets,
                              rest_bias, RestBias, STANDARD_GRAVITY_M_S2)

__all__ = ['accel_offset_lsb', 'ACCEL_OFFSET_LSB_PER_G', 'adev_at_rad_s', 'averaging_time_s',
           'BiasProcedure', 'from_twos_complement', 'GYRO_OFFSET_DPS_PER_LSB', 'gyro_offset_lsb',
           'INT16_MAX', 'INT16_MIN', 'merge_preserving_bit0', 'MIN_TEMPERATURE_CHANGE_C',
           'NOTE_AVERAGE_S', 'NOTE_PBC_S', 'NOTE_SELF_HEAT_S', 'NOTE_SETTLE_S', 'OffsetRefresh',
           'Phase', 'ProcedureSettings', 'recalibrated_offsets', 'RECORD_FRACTION', 'rest_bias',
           'RestBias', 'short_window', 'STANDARD_GRAVITY_M_S2']
