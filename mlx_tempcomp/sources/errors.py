"""Errors raised by the sources."""

from ..errors import MlxTempCompError


class SourceError(MlxTempCompError):
    """Base class of every error the sources raise (bags, recordings)."""
