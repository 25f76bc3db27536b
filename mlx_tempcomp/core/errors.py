"""Errors raised by the numpy-only core."""

from ..errors import MlxTempCompError


class TempCompError(MlxTempCompError):
    """Base class of every error the core raises."""


class ConfigError(TempCompError):
    """A model, parameter or coefficient set is invalid."""


class EepromError(TempCompError):
    """An EEPROM image cannot be decoded or encoded."""


class CalibrationError(TempCompError):
    """A calibration or recalibration cannot be done with the data given."""
