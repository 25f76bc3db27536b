"""Errors raised by the readers of recorded files and the bag writer."""

from ..errors import MlxTempCompError


class RecordFileError(MlxTempCompError):
    """Base class of every error of the recorded files: CSV, bags, flight-controller logs."""
