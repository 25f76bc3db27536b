"""
How `fit` and `diagnose` judge a model on data it was not fitted to: one code path for both.

The record is cut into contiguous blocks. Two schemes deal them to folds:

- ``forward`` (the default), the way a node uses a model: fold j fits on
  every block before block j and predicts block j, rolling forward over the
  record. The first predicted block is the first one starting at or after
  ``min_past`` of the record, so no fold learns from a sliver of it.
- ``round_robin``: fold k holds out blocks k, k + folds, k + 2 folds, ...
  and fits on the rest, so training data surrounds every held-out block.
  A model can interpolate between its neighbours in time there, which a
  node never does; the figure is reported beside the forward one.

Several records of one unit (`records.Records`) are cut into blocks each
(`record_block_bounds`), so no block spans two records. Each record may
have its own bias offset, learnt from its own rows, so a block is predicted
only when its record has rows on the training side: forward, the first
block of every record only trains (a fold never predicts a record from its
own future, nor from nothing of it).

Each fold's held-out RMS is one score; an order (or effect) is summarised
by the mean over the folds and its standard error, and the order is chosen
by the one-standard-error rule. Least squares on the folds adds up the
normal equations of the training blocks (`training_sums`), so every fold
costs one small solve.
"""

from dataclasses import dataclass
import math
import operator

import numpy as np

from .errors import CalibrationError

FORWARD = 'forward'
ROUND_ROBIN = 'round_robin'
SCHEMES = (FORWARD, ROUND_ROBIN)
ONE_SE_RULE = 'one-standard-error'
DEFAULT_BLOCKS = 20
DEFAULT_FOLDS = 5
DEFAULT_MIN_PAST = 0.25


@dataclass(frozen=True)
class OrderScore:
    """Held-out RMS residual of one polynomial order, per fold and summarised."""

    order: int
    block_rms_rad_s: tuple
    mean_rms_rad_s: float
    standard_error_rad_s: float


@dataclass(frozen=True)
class Split:
    """
    Which blocks train (training) and which are predicted (held) in each fold.

    ``record_starts`` holds the first block of each record.
    """

    scheme: str
    training: np.ndarray
    held: np.ndarray
    record_starts: tuple = (0,)

    @property
    def folds(self) -> int:
        return self.held.shape[0]

    @property
    def blocks(self) -> int:
        return self.held.shape[1]

    @property
    def predicted(self) -> np.ndarray:
        """Whether each block is predicted by some fold."""
        return self.held.any(axis=0)

    def describe(self) -> str:
        """Say in words how the blocks are dealt."""
        records = len(self.record_starts)
        if self.scheme == FORWARD:
            first = int(np.argmax(self.predicted))
            text = (f'forward over {self.blocks} blocks: blocks {first} to {self.blocks - 1} '
                    'each predicted from the blocks before it')
            if records > 1:
                text += (f' (in {records} records, whose first blocks only train: blocks '
                         + ', '.join(str(b) for b in self.record_starts) + ')')
            return text
        return f'round-robin: {self.blocks} blocks dealt to {self.folds} folds' + (
            f' (in {records} records)' if records > 1 else '')


def block_bounds(samples: int, count: int) -> np.ndarray:
    """Return the count + 1 boundaries of ``count`` contiguous near-equal blocks of rows."""
    samples = operator.index(samples)
    count = operator.index(count)
    if count < 2:
        msg = f'cross-validation needs at least 2 blocks, got {count}'
        raise CalibrationError(msg)
    if samples < count:
        msg = f'cannot split {samples} samples into {count} blocks'
        raise CalibrationError(msg)
    sizes = np.full(count, samples // count)
    sizes[:samples % count] += 1
    return np.concatenate(([0], np.cumsum(sizes)))


def record_block_bounds(record_rows, count: int) -> tuple:
    """
    Cut records of the given rows into ``count`` blocks in all, none spanning two records.

    Each record gets blocks in proportion to its rows (largest remainders),
    but at least 2, so a block is never its record's only one. Return (the
    count + 1 row boundaries, the first block of each record).
    """
    rows = np.array([operator.index(r) for r in record_rows], dtype=np.int64)
    if rows.size == 1:
        return block_bounds(int(rows[0]), count), (0,)
    count = operator.index(count)
    if count < 2 * rows.size:
        msg = (f'{rows.size} records need at least {2 * rows.size} blocks (2 each), got '
               f'{count}')
        raise CalibrationError(msg)
    share = count * rows / rows.sum()
    dealt = np.maximum(np.floor(share).astype(np.int64), 2)
    while dealt.sum() > count:  # the floor of 2 took blocks: give back the most over share
        dealt[np.argmax(np.where(dealt > 2, dealt - share, -np.inf))] -= 1
    order = np.argsort(-(share - dealt), kind='stable')
    dealt[order[:count - int(dealt.sum())]] += 1
    edges = [np.asarray(block_bounds(int(r), int(d))[:-1]) + offset
             for r, d, offset in zip(rows, dealt, np.concatenate(([0], np.cumsum(rows))))]
    return (np.concatenate(edges + [[int(rows.sum())]]),
            tuple(int(v) for v in np.concatenate(([0], np.cumsum(dealt)[:-1]))))


def first_forward_block(blocks: int, min_past: float) -> int:
    """Return the first block the forward scheme predicts (at least 1)."""
    return max(1, math.ceil(min_past * blocks - 1e-9))


def split(blocks: int, scheme: str = FORWARD, folds: int = DEFAULT_FOLDS,
          min_past: float = DEFAULT_MIN_PAST, record_starts: tuple = (0,)) -> Split:
    """
    Deal ``blocks`` contiguous blocks to folds by ``scheme``; see the module docstring.

    ``record_starts`` gives the first block of each record (`record_block_bounds`).
    """
    if scheme not in SCHEMES:
        msg = f'validation must be one of {", ".join(SCHEMES)}, got {scheme!r}'
        raise CalibrationError(msg)
    if not (math.isfinite(min_past) and 0.0 <= min_past < 1.0):
        msg = f'min_past must be in [0, 1), got {min_past}'
        raise CalibrationError(msg)
    index = np.arange(blocks)
    if scheme == FORWARD:
        first = first_forward_block(blocks, min_past)
        predicted = np.setdiff1d(index[first:], record_starts)
        if predicted.size < 2:
            msg = (f'forward validation needs at least 2 blocks to predict: of {blocks} '
                   f'blocks the first {first} (--min-past {min_past:g}) only train')
            if len(record_starts) > 1:
                msg += ', and so does the first block of each record'
            raise CalibrationError(msg)
        held = predicted[:, None] == index[None, :]
        training = index[None, :] < predicted[:, None]
    else:
        if not 2 <= folds <= blocks:
            msg = (f'cross-validation needs 2 <= folds <= blocks, got {folds} folds, '
                   f'{blocks} blocks')
            raise CalibrationError(msg)
        held = index[None, :] % folds == np.arange(folds)[:, None]
        training = ~held
    return Split(scheme, training, held, tuple(record_starts))


def training_sums(split_: Split, per_block: np.ndarray) -> np.ndarray:
    """Sum per-block arrays (blocks, ...) over each fold's training blocks: (folds, ...)."""
    return np.tensordot(split_.training.astype(np.float64), per_block, axes=1)


def order_score(order: int, fold_rms_rad_s) -> OrderScore:
    """Summarise an order's held-out RMS per fold; inf when a fold could not fit it."""
    values = np.asarray(fold_rms_rad_s, dtype=np.float64)
    folds = tuple(float(v) for v in values)
    if not np.all(np.isfinite(values)):
        return OrderScore(order, folds, math.inf, math.inf)
    error = float(np.std(values, ddof=1) / math.sqrt(values.size))
    return OrderScore(order, folds, float(np.mean(values)), error)


def best_score(scores) -> OrderScore:
    """Return the score with the lowest mean held-out RMS."""
    return min(scores, key=lambda score: score.mean_rms_rad_s)


def one_standard_error(scores) -> int:
    """
    Return the lowest order whose mean held-out RMS is within one standard error of the best.

    Raise CalibrationError when no order has a finite score (the caller says which axis).
    """
    best = best_score(scores)
    if not math.isfinite(best.mean_rms_rad_s):
        msg = 'the training folds cannot support any polynomial order'
        raise CalibrationError(msg)
    threshold = best.mean_rms_rad_s + best.standard_error_rad_s
    return next(s.order for s in scores if s.mean_rms_rad_s <= threshold)
