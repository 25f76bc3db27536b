"""
The diagnosis's held-out folds: its rows cut into blocks and bins, and what each fold fits on.

The blocks are dealt to folds by `validation.split` (forward, round-robin or
purged), the code path `fit` uses too; `Folds` maps a split onto the bins of
one diagnosis, and says which held-out bins a fold's score counts: all of
them, or (scoring 'inside') only those inside the temperature range of the
fold's training blocks, the rest being extrapolation, reported apart.
"""

from dataclasses import dataclass
import math

import numpy as np

from ..fitting import record_block_bounds


@dataclass(frozen=True)
class Bins:
    """
    The diagnosed rows cut into blocks, and each block into bins of ``average_s`` seconds.

    ``block_edges`` holds each block's first row and the row count,
    ``first_blocks`` each record's first block; ``starts`` and ``counts``
    are each bin's first row and number of rows, ``bin_block`` its block.
    """

    block_edges: np.ndarray
    first_blocks: tuple
    starts: np.ndarray
    counts: np.ndarray
    bin_block: np.ndarray


def cut_bins(time_s: np.ndarray, record_rows: list, blocks: int, average_s: float) -> Bins:
    """Cut rows into blocks (none spanning two records, `record_rows` each), bins inside blocks."""
    rows = len(time_s)
    edges, first_blocks = record_block_bounds(record_rows, blocks)
    block = np.repeat(np.arange(blocks), np.diff(edges))
    boundary = np.zeros(rows, dtype=bool)
    boundary[edges[:-1]] = True
    if average_s > 0.0:
        since = time_s - time_s[edges[:-1]][block]
        index = np.floor(since / average_s).astype(np.int64)
        boundary[1:] |= index[1:] != index[:-1]
    else:
        boundary[:] = True
    starts = np.flatnonzero(boundary)
    counts = np.diff(np.append(starts, rows)).astype(np.float64)
    return Bins(edges, first_blocks, starts, counts, block[starts])


def weighted_rms(values, weights) -> float:
    """Give the RMS of bin values weighted by their rows (NaN with no weight)."""
    total = float(np.sum(weights))
    return math.sqrt(float(np.sum(weights * np.square(values))) / total) if total else math.nan


ALL_ROWS = 'all'
INSIDE_ROWS = 'inside'
SCORING = (ALL_ROWS, INSIDE_ROWS)


class Folds:
    """
    The bins each fold of a `validation.Split` fits on, predicts, and counts in its score.

    ``bin_low_c`` and ``bin_high_c`` are each bin's temperature range,
    ``block_low_c`` and ``block_high_c`` each block's; with ``scoring``
    'inside' a fold counts the held-out bins inside the range of its
    training blocks (``counted``), else all of them. ``outside`` holds per
    fold the held-out bins beyond that range. ``key`` names the folds (for
    caches): scheme, buffer and scoring.
    """

    def __init__(self, split_, bin_block: np.ndarray, block_rows: np.ndarray,
                 bin_range: tuple, block_range: tuple, scoring: str = ALL_ROWS):
        self.split = split_
        self.key = (split_.scheme, split_.buffer, scoring)
        self.train = tuple(used[bin_block] for used in split_.training)
        self.held = tuple(used[bin_block] for used in split_.held)
        bin_low, bin_high = bin_range
        block_low, block_high = block_range
        self.outside = tuple(held & ((bin_low < np.min(block_low[used]))
                                     | (bin_high > np.max(block_high[used])))
                             for used, held in zip(split_.training, self.held))
        self.counted = self.held if scoring == ALL_ROWS else tuple(
            held & ~outside for held, outside in zip(self.held, self.outside))
        # The fold predicting each block, -1 for blocks no fold predicts.
        self.block_fold = np.where(split_.predicted, np.argmax(split_.held, axis=0), -1)
        self.scored = np.any(self.counted, axis=0)
        self.extrapolated = np.any(self.outside, axis=0)
        # A fold's model runs from the record start to the end of its last held block.
        self.stop = tuple(int(block_rows[np.flatnonzero(used)[-1] + 1])
                          for used in split_.held)
