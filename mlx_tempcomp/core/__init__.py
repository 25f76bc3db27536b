"""
Numpy-only core: EEPROM decoding, interpolation, compensation, statistics.

Nothing in this package imports rclpy.
"""
