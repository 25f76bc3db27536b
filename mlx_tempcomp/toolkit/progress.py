"""
A one-line progress bar on stderr for long ``mlx-tempcomp`` runs.

Shown only when stderr is a terminal, or when asked for (``--progress``), so
logs and pipes stay clean. Redrawn at most every 0.2 s.
"""

import argparse
import sys
import time
from typing import Optional

_WIDTH = 30
_REDRAW_S = 0.2


def add_progress_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--progress`` (show the bar even when stderr is not a terminal)."""
    parser.add_argument('--progress', action='store_true',
                        help='show a progress bar on stderr even when it is not a terminal')


class Progress:
    """
    Draw ``label [#####.....]  42 %`` on stderr as work advances; a context manager.

    ``enabled`` None shows the bar when stderr is a terminal.
    """

    def __init__(self, total: int, label: str, enabled: Optional[bool] = None):
        self.total = max(int(total), 1)
        self.label = label
        self.enabled = sys.stderr.isatty() if enabled is None else bool(enabled)
        self._last_draw = -float('inf')
        self._done = 0
        self._shown = None

    def __enter__(self) -> 'Progress':
        return self

    def __exit__(self, exc_type, exc_value, traceback) -> None:
        self.close()

    def update(self, done: int) -> None:
        """Record that ``done`` of ``total`` units are finished; redraw if due."""
        self._done = done
        now = time.monotonic()
        if self.enabled and (now - self._last_draw >= _REDRAW_S or done >= self.total):
            self._last_draw = now
            self._draw()

    def _draw(self) -> None:
        fraction = min(max(self._done / self.total, 0.0), 1.0)
        filled = int(round(fraction * _WIDTH))
        sys.stderr.write(f'\r{self.label} [{"#" * filled}{"." * (_WIDTH - filled)}] '
                         f'{fraction * 100.0:3.0f} %')
        sys.stderr.flush()
        self._shown = self._done

    def close(self) -> None:
        """End the bar's line (once drawn) so later output starts on a new line."""
        if self._shown is None:
            return
        if self._shown != self._done:
            self._draw()
        sys.stderr.write('\n')
        sys.stderr.flush()
        self._shown = None
