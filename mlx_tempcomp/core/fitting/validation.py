"""
How `fit` and `diagnose` judge a model on data it was not fitted to: one code path for both.

The record is cut into contiguous blocks. Three schemes deal them to folds:

- ``forward`` (the default), the way a node uses a model: fold j fits on
  every block before block j and predicts block j, rolling forward over the
  record. The first predicted block is the first one starting at or after
  ``min_past`` of the record, so no fold learns from a sliver of it.
- ``round_robin``: fold k holds out blocks k, k + folds, k + 2 folds, ...
  and fits on the rest, so training data surrounds every held-out block.
  A model can interpolate between its neighbours in time there, which a
  node never does.
- ``purged`` (blocked cross-validation with a buffer, hv-block; the "purged
  k-fold" of time-series learning): each block is held out alone, the
  ``buffer`` blocks on either side of it are dropped, and the rest trains. The
  buffer is at least as long as the memory of the model judged (3 x its
  longest time constant, at least one block), so no history state carries
  the held-out block's neighbours into its fit. Training data lie before and
  after the block in time, at temperatures it passes through: the model is
  judged inside its calibrated range, later (and earlier) in time.

Several records of one unit (`records.Records`) are cut into blocks each
(`record_block_bounds`), so no block spans two records. Each record may
have its own bias offset, learnt from its own rows, so a block is predicted
only when its record has rows on the training side: forward, the first
block of every record only trains (a fold never predicts a record from its
own future, nor from nothing of it).

Each fold's held-out RMS is one score; an order (or effect) is summarised
by the mean over the folds and its standard error. The PX4-style cubic
(`baseline`) is the incumbent: a model other than it, a higher order or an added effect is
taken only when it beats the incumbent fold by fold (`paired`: the mean of
the per-fold differences at least ``significance`` standard errors, and a
win on a majority of the folds), and its held-out RMS is at least
``BASELINE_MARGIN`` below the cubic's (`cubic_instead`): a margin on the
pooled RMS alone can be one lucky fold. Least squares on the folds adds up
the normal equations of the training blocks (`training_sums`), so every
fold costs one small solve.

Two views of the held-out rows tell what the figures mean:
`held_out_outside_range` says how much of each held-out block lies outside
the temperature range of its fold's training blocks (where a model clamps),
and `error_by_temperature` bins held-out residuals by temperature (the RMS
per bin: the validated error as a function of T).
"""

from dataclasses import dataclass
import math
import operator

import numpy as np

from ..errors import CalibrationError

FORWARD = 'forward'
ROUND_ROBIN = 'round_robin'
PURGED = 'purged'
SCHEMES = (FORWARD, ROUND_ROBIN, PURGED)
# The scheme that decides unless told otherwise: chosen on every record we have
# (docs/diagnose.md, "Choosing the validation").
DEFAULT_VALIDATION = ROUND_ROBIN
DEFAULT_BLOCKS = 20
DEFAULT_FOLDS = 5
DEFAULT_MIN_PAST = 0.25
# A model other than the baseline (PX4's cubic) is written only when its held-out RMS is
# this fraction below the cubic's, besides beating it fold by fold.
BASELINE_MARGIN = 0.05
# The paired comparison's default: the mean per-fold gain in standard errors.
DEFAULT_SIGNIFICANCE = 2.0


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

    ``record_starts`` holds the first block of each record; ``buffer`` the
    blocks dropped on either side of a held-out block (purged).
    """

    scheme: str
    training: np.ndarray
    held: np.ndarray
    record_starts: tuple = (0,)
    buffer: int = 0

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
        if self.scheme == PURGED:
            text = (f'purged: each of {self.folds} blocks predicted from the others but '
                    f'{self.buffer} on either side')
            return text + (f' (in {records} records)' if records > 1 else '')
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
          min_past: float = DEFAULT_MIN_PAST, record_starts: tuple = (0,),
          buffer: int = 1) -> Split:
    """
    Deal ``blocks`` contiguous blocks to folds by ``scheme``; see the module docstring.

    ``record_starts`` gives the first block of each record (`record_block_bounds`),
    ``buffer`` the blocks a purged fold drops on either side of its held-out block.
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
        return Split(scheme, training, held, tuple(record_starts))
    if scheme == PURGED:
        return _purged(blocks, record_starts, buffer)
    if not 2 <= folds <= blocks:
        msg = (f'cross-validation needs 2 <= folds <= blocks, got {folds} folds, '
               f'{blocks} blocks')
        raise CalibrationError(msg)
    held = index[None, :] % folds == np.arange(folds)[:, None]
    return Split(scheme, ~held, held, tuple(record_starts))


def _purged(blocks: int, record_starts: tuple, buffer: int) -> Split:
    """
    Hold out each block alone, drop ``buffer`` blocks on either side in its record.

    A block is predicted only when its record keeps training blocks (its
    bias offset is learnt from them); blocks of other records always train.
    """
    if buffer < 1:
        msg = f'a purged split needs a buffer of at least 1 block, got {buffer}'
        raise CalibrationError(msg)
    index = np.arange(blocks)
    record = np.searchsorted(np.asarray(record_starts), index, side='right') - 1
    same = record[:, None] == record[None, :]
    training = ~(same & (np.abs(index[:, None] - index[None, :]) <= buffer))
    predicted = np.flatnonzero(np.any(training & same, axis=1))
    if predicted.size < 2:
        msg = (f'purged validation needs at least 2 blocks to predict: with {blocks} blocks '
               f'and a buffer of {buffer} on either side, no record keeps blocks to train on')
        raise CalibrationError(msg)
    held = predicted[:, None] == index[None, :]
    return Split(PURGED, training[predicted], held, tuple(record_starts), buffer)


def buffer_blocks(memory_s: float, block_s: float) -> int:
    """Give the purged buffer: blocks covering 3 x ``memory_s``, at least one."""
    if memory_s <= 0.0 or block_s <= 0.0:
        return 1
    return max(1, math.ceil(3.0 * memory_s / block_s - 1e-9))


def training_sums(split_: Split, per_block: np.ndarray) -> np.ndarray:
    """Sum per-block arrays (blocks, ...) over each fold's training blocks: (folds, ...)."""
    return np.tensordot(split_.training.astype(np.float64), per_block, axes=1)


def order_score(order: int, fold_rms_rad_s) -> OrderScore:
    """
    Summarise an order's held-out RMS per fold; inf when a fold could not fit it.

    A fold with no held-out rows to count (NaN: every one beyond its training
    range, scoring 'inside') is left out of the mean and its standard error.
    """
    values = np.asarray(fold_rms_rad_s, dtype=np.float64)
    folds = tuple(float(v) for v in values)
    counted = values[~np.isnan(values)]
    if counted.size < 2 or not np.all(np.isfinite(counted)):
        return OrderScore(order, folds, math.inf, math.inf)
    error = float(np.std(counted, ddof=1) / math.sqrt(counted.size))
    return OrderScore(order, folds, float(np.mean(counted)), error)


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


def cubic_instead(found_rms_rad_s: float, cubic_rms_rad_s: float, margin: float,
                  scheme: str) -> str:
    """
    Say why the PX4-style cubic is written instead of the model found ('' to keep it).

    The model found must have a held-out RMS (under ``scheme``) at least
    ``margin`` below the cubic's; a cubic the data cannot support (inf) is
    no baseline.
    """
    ratio = found_rms_rad_s / cubic_rms_rad_s if cubic_rms_rad_s else math.inf
    if ratio <= 1.0 - margin:
        return ''
    return (f'the model found has {scheme} held-out RMS {found_rms_rad_s:.3e} rad/s, '
            f"{ratio:.2f}x the PX4-style cubic's {cubic_rms_rad_s:.3e} rad/s: not "
            f'{margin:.0%} better')


@dataclass(frozen=True)
class Paired:
    """
    A challenger against the incumbent, fold by fold: its per-fold RMS gains.

    ``mean_rad_s`` and ``standard_error_rad_s`` summarise the per-fold
    differences (incumbent minus challenger, folds both can score), ``wins``
    counts the folds the challenger is better on, of ``folds``.
    """

    mean_rad_s: float
    standard_error_rad_s: float
    wins: int
    folds: int

    def beats(self, significance: float) -> bool:
        """Tell whether the gain is ``significance`` standard errors and a majority's."""
        return (self.folds >= 2 and self.mean_rad_s > 0.0
                and self.mean_rad_s >= significance * self.standard_error_rad_s
                and 2 * self.wins > self.folds)

    def why_not(self, significance: float) -> str:
        """Say why the challenger does not beat the incumbent ('' when it does)."""
        if self.beats(significance):
            return ''
        if not (self.mean_rad_s > 0.0
                and self.mean_rad_s >= significance * self.standard_error_rad_s):
            return (f'mean fold improvement {self.mean_rad_s:.3g} rad/s not '
                    f'{significance:g} standard errors ({self.standard_error_rad_s:.3g} rad/s)')
        return f'better on {self.wins} of {self.folds} folds, not a majority'


def paired(incumbent_fold_rms, challenger_fold_rms) -> Paired:
    """Compare two models' RMS per fold (the same folds); NaN folds are left out."""
    incumbent = np.asarray(incumbent_fold_rms, dtype=np.float64)
    challenger = np.asarray(challenger_fold_rms, dtype=np.float64)
    difference = (incumbent - challenger)[np.isfinite(incumbent) & np.isfinite(challenger)]
    if difference.size < 2:
        return Paired(math.nan, math.nan, int(np.count_nonzero(difference > 0.0)),
                      int(difference.size))
    return Paired(float(np.mean(difference)),
                  float(np.std(difference, ddof=1) / math.sqrt(difference.size)),
                  int(np.count_nonzero(difference > 0.0)), int(difference.size))


@dataclass(frozen=True)
class OutsideRange:
    """
    How much of a part of the record lies outside a temperature range, per column.

    ``rows`` rows were checked against [``low_c``, ``high_c``]; ``fraction``
    holds, per temperature column (one per axis when the axes' effective
    temperatures differ), the share of rows outside, ``furthest_c`` how far
    beyond the nearer edge the furthest one lies (0 when none is outside).
    """

    rows: int
    low_c: float
    high_c: float
    fraction: tuple
    furthest_c: tuple


def outside_range(temperature_c, low_c: float, high_c: float) -> OutsideRange:
    """Measure the rows of ``temperature_c`` ((rows,) or (rows, columns)) outside [low, high]."""
    columns = np.asarray(temperature_c, dtype=np.float64)
    columns = columns.reshape(len(columns), -1)
    beyond = np.maximum(low_c - columns, columns - high_c)
    rows = columns.shape[0]
    fraction = np.count_nonzero(beyond > 0.0, axis=0) / rows if rows else \
        np.zeros(columns.shape[1])
    furthest = np.maximum(np.max(beyond, axis=0, initial=0.0), 0.0)
    return OutsideRange(rows, float(low_c), float(high_c), tuple(float(f) for f in fraction),
                        tuple(float(f) for f in furthest))


def held_out_outside_range(temperature_c, bounds: np.ndarray, split_: Split) -> tuple:
    """
    Give, per block, the `OutsideRange` of its rows against its fold's training range.

    ``temperature_c`` is (rows,) or (rows, columns), cut at ``bounds``
    (`block_bounds`); a fold's range spans every column of its training
    blocks, as a model clamps every axis at one fitted range. Blocks no fold
    predicts give None.
    """
    columns = np.asarray(temperature_c, dtype=np.float64)
    columns = columns.reshape(len(columns), -1)
    starts = bounds[:-1]
    low = np.min(np.minimum.reduceat(columns, starts, axis=0), axis=1)
    high = np.max(np.maximum.reduceat(columns, starts, axis=0), axis=1)
    result = [None] * split_.blocks
    for training, held in zip(split_.training, split_.held):
        for block in np.flatnonzero(held):
            result[block] = outside_range(columns[bounds[block]:bounds[block + 1]],
                                          np.min(low[training]), np.max(high[training]))
    return tuple(result)


@dataclass(frozen=True)
class TemperatureErrors:
    """
    RMS of held-out residuals per temperature bin: the validated error as a function of T.

    ``edges_c`` bounds the bins (``bins`` + 1 values); per bin, ``count`` is
    the number of residual values in it (each the mean over one averaging
    bin), ``weight`` the sum of their weights (the samples they average),
    ``temperature_c`` their weighted mean temperature (NaN when empty) and
    ``rms_rad_s`` (bins, axes) their weighted RMS per axis.
    """

    edges_c: tuple
    temperature_c: tuple
    count: tuple
    weight: tuple
    rms_rad_s: tuple

    def filled(self) -> tuple:
        """Give the indices of the bins holding residuals."""
        return tuple(k for k, count in enumerate(self.count) if count)


def temperature_bin_edges(low_c: float, high_c: float, bins: int) -> np.ndarray:
    """Give ``bins`` + 1 edges of equal-width bins from ``low_c`` to ``high_c``."""
    if bins < 1 or not (math.isfinite(low_c) and math.isfinite(high_c) and low_c <= high_c):
        msg = f'temperature bins need 1 or more bins over a finite range, got {bins}, ' \
              f'{low_c} to {high_c} C'
        raise CalibrationError(msg)
    return np.linspace(low_c, high_c, bins + 1)


def error_by_temperature(temperature_c, residual_rad_s, weights, edges_c) -> TemperatureErrors:
    """
    Bin residuals (values, axes) by their temperature (values,) and give the RMS per bin.

    ``weights`` (values,) weigh each value (the rows of its averaging bin), as
    the held-out RMS does. Values NaN on any axis (bins no fold predicts) and
    outside the edges are left out; the last bin includes its upper edge.
    """
    temperature = np.asarray(temperature_c, dtype=np.float64)
    residual = np.asarray(residual_rad_s, dtype=np.float64).reshape(len(temperature), -1)
    weights = np.asarray(weights, dtype=np.float64)
    edges = np.asarray(edges_c, dtype=np.float64)
    bins = edges.size - 1
    index = np.searchsorted(edges, temperature, side='right') - 1
    index[temperature == edges[-1]] = bins - 1
    used = np.all(np.isfinite(residual), axis=1) & (index >= 0) & (index < bins)
    index, weights, temperature = index[used], weights[used], temperature[used]
    residual = residual[used]
    count = np.bincount(index, minlength=bins)
    total = np.bincount(index, weights=weights, minlength=bins)
    with np.errstate(invalid='ignore', divide='ignore'):
        mean_c = np.bincount(index, weights=weights * temperature, minlength=bins) / total
        rms = np.column_stack([np.sqrt(np.bincount(index, weights=weights * residual[:, a] ** 2,
                                                   minlength=bins) / total)
                               for a in range(residual.shape[1])])
    return TemperatureErrors(tuple(float(e) for e in edges), tuple(float(t) for t in mean_c),
                             tuple(int(c) for c in count), tuple(float(w) for w in total),
                             tuple(tuple(float(v) for v in row) for row in rms))
