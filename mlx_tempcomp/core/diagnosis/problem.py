"""
The scorer of one diagnosis: `DiagnosisProblem` scores, fits and runs models on its data.

Above `data` (`DiagnosisData`: the rows, bins, folds, cached features and
bounds it inherits), `fits` (the effects' design columns and trials) and
`cubic`. It scores an `AxisSpec` on the held-out bins of each fold (least
squares on bin means, the polynomial clamped as each fold's model runs it),
fits the models the folds and the written file hold, and runs them over the
record as the node does. The PX4-style cubic (`core.fitting.baseline`) is fitted on
each fold's training rows as PX4 fits it and run clamped (`baseline_run`):
the incumbent every other model is compared with, fold by fold. An effect's
trials (`fits.best_trial`) see the problem's data and a scoring function of
a spec (`judge`), not the scorer.
"""

from dataclasses import dataclass, replace
import functools
import math
from typing import Optional

import numpy as np

from .cubic import baseline_run, BaselineRun, cubic_bias
from .data import Centring, DiagnosisData
from .fits import AxisSpec, best_trial, design, FITS, Score, Trial
from .folds import Folds, weighted_rms
from ..effects import AxisTerms, EffectModel, SLOPE_EFFECTS
from ..errors import CalibrationError
from ..fitting import buffer_blocks, PURGED, training_sums
from ..node_models import ModelInputs

# Singular values of the scaled normal matrix below this (relative) count as rank loss.
RANK_RCOND = 1e-12


@dataclass(frozen=True)
class HeldOutRun:
    """The fold models run as the node runs them: binned residual (bins, axes), errors per axis."""

    residual: np.ndarray
    errors: tuple


@dataclass(frozen=True)
class AxisFit:
    """One axis fitted: its terms, and each fitted record's offset to add to their constant."""

    terms: AxisTerms
    offsets_rad_s: tuple


def _solve_normal(gram: np.ndarray, moment: np.ndarray) -> tuple:
    """
    Solve normal equations scaled to a unit diagonal; return (coefficients, full rank).

    A column that is zero on every row (a bias step after the training
    blocks) gets coefficient 0 and does not count as rank loss: the past
    has nothing to say about it yet.
    """
    diagonal = np.sqrt(np.diag(gram))
    present = np.count_nonzero(diagonal)
    diagonal[diagonal == 0.0] = 1.0
    scaled = gram / np.outer(diagonal, diagonal)
    solution, _, rank, _ = np.linalg.lstsq(scaled, moment / diagonal, rcond=RANK_RCOND)
    return solution / diagonal, rank == present


class DiagnosisProblem(DiagnosisData):
    """
    The scorer of one diagnosis: its `DiagnosisData` scored, fitted and run (module notes).

    Built as `DiagnosisData` is, from the records, the rows to diagnose, the
    settings and the progress callback.
    """

    def memory_s(self, spec: AxisSpec) -> float:
        """Give how far back the spec's history states reach: its longest time constant."""
        memory = [abs(spec.thermal_lag_s), *spec.gradient_s]
        if spec.thermal_lag_s > 0.0 or any(spec.get(effect.name) for effect in SLOPE_EFFECTS):
            memory.append(self.settings.rate_window_s)
        return max(memory)

    def folds_for(self, spec: AxisSpec, scheme: Optional[str] = None) -> Optional[Folds]:
        """
        Give the folds a spec is judged on: purged, a buffer of 3 x its memory.

        None when the buffer leaves no fold to judge it on: the record is too
        short for a model that remembers that long.
        """
        scheme = scheme or self.settings.validation
        if scheme != PURGED:
            return self.folds_of(scheme)
        try:
            return self.folds_of(scheme, buffer_blocks(self.memory_s(spec), self.block_s))
        except CalibrationError:
            return None

    def design(self, axis: int, spec: AxisSpec) -> np.ndarray:
        """Return the bin-mean design matrix of an axis (`fits.design`); `_terms` order."""
        return design(self, axis, spec)

    def judge(self, axis: int, spec: AxisSpec) -> Optional[Score]:
        """Score a spec on an axis on its own folds; None when no fold can judge it."""
        folds = self.folds_for(spec)
        if folds is None:   # no fold can judge a memory this long
            return None
        return self.score_spec(axis, spec, folds)

    def best_trial(self, axis: int, spec: AxisSpec, effect: str) -> Optional[Trial]:
        """Give the best `Trial` of one effect added to ``spec`` (`fits.best_trial`)."""
        return best_trial(self, functools.partial(self.judge, axis), axis, spec, effect)

    def score_spec(self, axis: int, spec: AxisSpec, folds: Optional[Folds] = None) -> Score:
        """
        Score the terms of ``spec`` on an axis, the polynomial clamped as the folds run it.

        The folds default to the spec's own (`folds_for`); the PX4-style cubic
        scores as PX4 fits and runs it (`baseline_run`).
        """
        folds = folds or self.folds_for(spec)
        if spec.baseline:
            run = self.baseline_run(folds)
            return Score(run.fold_rms[:, axis], run.errors[axis].rms_rad_s, True,
                         run.residual[:, axis])
        design = self.design(axis, spec)
        predict = design.copy()
        # The polynomial's columns come first (`design`).
        width = spec.order + 1
        predict[:, :width] = self.predicted_polynomial(spec.thermal_lag_s, folds)[:, :width]
        return self.score(design, predict, axis, folds)

    def score(self, design: np.ndarray, predict: np.ndarray, axis: int,
              folds: Folds) -> Score:
        """
        Fit on the training bins of each fold, predict the held-out bins (NaN elsewhere).

        ``predict`` is the design the held-out bins are predicted from.
        """
        target = self.target[:, axis]
        weighted = design * self.counts[:, None]
        edges = np.searchsorted(self.bin_block, np.arange(self.settings.blocks + 1))
        blocks = [slice(first, last) for first, last in zip(edges[:-1], edges[1:])]
        grams = training_sums(folds.split, np.array([weighted[b].T @ design[b] for b in blocks]))
        moments = training_sums(folds.split, np.array([weighted[b].T @ target[b]
                                                       for b in blocks]))
        residual = np.full_like(target, math.nan)
        fold_rms = np.empty(folds.split.folds)
        rank_ok = True
        for fold, (held, counted) in enumerate(zip(folds.held, folds.counted)):
            solution, full_rank = _solve_normal(grams[fold], moments[fold])
            rank_ok = rank_ok and full_rank
            residual[held] = target[held] - predict[held] @ solution
            fold_rms[fold] = weighted_rms(residual[counted], self.counts[counted])
        scored = folds.scored
        return Score(fold_rms, weighted_rms(residual[scored], self.counts[scored]), rank_ok,
                     residual)

    def baseline_run(self, folds: Optional[Folds] = None) -> BaselineRun:
        """Give the PX4-style cubic of each fold run on its held bins (`cubic.baseline_run`)."""
        folds = folds or self.folds
        return self.cached(('baseline', folds.key), lambda: baseline_run(self, folds))

    def fit_terms(self, axis: int, spec: AxisSpec, bins=None) -> AxisTerms:
        """Fit one axis on the given bins (all when None); its terms with the written offset."""
        fit = self.fit_offsets(axis, spec, bins)
        return _shifted(fit.terms, fit.offsets_rad_s[-1])

    def fit_offsets(self, axis: int, spec: AxisSpec, bins=None) -> AxisFit:
        """
        Fit one axis on the given bins (all when None): its terms, and each record's offset.

        The offsets add to the terms' constant: the first record's is 0. The
        PX4-style cubic is fitted on the bins' rows (`baseline.fit_cubic`) and
        its terms are the last record's, whose offset is 0: written, it is its
        own formula to the bit (x's scale is a power of two).
        """
        if spec.baseline:
            return self._cubic_fit(axis, None if bins is None else self.blocks_of(bins))
        design = self.design(axis, spec)
        target = self.target[:, axis]
        if bins is not None:
            design, target = design[bins], target[bins]
        weights = self.counts if bins is None else self.counts[bins]
        # The solver `score` uses: a fold's model is the one its score was judged on.
        weighted = design * weights[:, None]
        solution, _ = _solve_normal(weighted.T @ design, weighted.T @ target)
        offsets = self.fitted_records - 1
        return AxisFit(self._terms(axis, spec, solution[:solution.size - offsets]),
                       (0.0,) + tuple(float(v) for v in solution[solution.size - offsets:]))

    def _cubic_fit(self, axis: int, blocks: Optional[np.ndarray]) -> AxisFit:
        """Give the PX4-style cubic as an `AxisFit` in x: its terms are the last record's."""
        cubics = self.cubics() if blocks is None else self.fold_cubics(blocks)
        biases = [cubic_bias(cubic, axis, self.centre_c, self.scale_c) for cubic in cubics]
        return AxisFit(AxisTerms(bias=biases[-1]), tuple(b[0] - biases[-1][0] for b in biases))

    def _terms(self, axis: int, spec: AxisSpec, solution: np.ndarray) -> AxisTerms:
        values = iter(float(v) for v in solution)

        def take(count: int) -> tuple:
            return tuple(next(values) for _ in range(count))

        terms = {'bias': take(spec.order + 1)}
        for effect, choice in spec.choices:
            terms.update(FITS[effect].terms(self, axis, choice, take))
        return AxisTerms(**terms)

    def model(self, specs: tuple, fold: Optional[int] = None,
              folds: Optional[Folds] = None) -> EffectModel:
        """Fit every axis on all bins, or on the training bins of ``fold``; written offset."""
        return self.record_models(specs, fold, folds)[-1]

    def record_models(self, specs: tuple, fold: Optional[int] = None,
                      folds: Optional[Folds] = None) -> tuple:
        """
        Fit every axis on all bins, or on the training bins of ``fold``: one model per record.

        Each fitted record's model has its own offset; a record after them
        (the test record) runs the last one's, the written offset.
        """
        folds = folds or self.folds
        bins = None if fold is None else folds.train[fold]
        low, high = self.clamp_range(specs, None if fold is None else
                                     folds.split.training[fold])
        secondary = self.secondary or Centring(25.0, 1.0)
        supply = self.supply_reference or Centring(EffectModel.supply_reference_v, 1.0)
        fits = [self.fit_offsets(axis, spec, bins) for axis, spec in enumerate(specs)]
        model = EffectModel(
            terms=tuple(fit.terms for fit in fits),
            reference_temperature_c=self.centre_c, temperature_scale_c=self.scale_c,
            temperature_min_c=low, temperature_max_c=high,
            temperature_rate_window_s=self.settings.rate_window_s,
            time_reference_s=self.time_reference_s, secondary_reference_c=secondary.centre,
            secondary_scale_c=secondary.half_span, supply_reference_v=supply.centre)
        models = tuple(replace(model, terms=tuple(_shifted(fit.terms, fit.offsets_rad_s[record])
                                                  for fit in fits))
                       for record in range(self.fitted_records))
        return models + models[-1:] * (self.records.count - self.fitted_records)

    def record_offsets(self, specs: tuple) -> np.ndarray:
        """Give each fitted record's bias offset (records, axes) against the written one."""
        offsets = np.array([self.fit_offsets(axis, spec).offsets_rad_s
                            for axis, spec in enumerate(specs)])
        return (offsets - offsets[:, -1:]).T

    def residual(self, model, axis: int, stop: Optional[int] = None) -> np.ndarray:
        """
        Return corrected minus truth for one axis up to row ``stop``.

        ``model`` is one `EffectModel`, or one per record (`record_models`);
        each record runs from its own start, its history fresh.
        """
        models = model if isinstance(model, tuple) else (model,) * self.records.count
        parts = [self._run(models[record], axis, rows)
                 for record, rows in enumerate(self.records.segments(stop))]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _run(self, model: EffectModel, axis: int, span: slice) -> np.ndarray:
        """
        Return corrected minus truth for one axis on the rows of ``span``, from its start.

        Without cross-axis terms the axis runs alone: a third of the memory.
        """
        source = self.full
        column = axis
        rate = source.gyro_rad_s[span]
        if not model.has_cross_axis:
            model = replace(model, terms=(model.terms[axis],),
                            zro_offset_rad_s=(model.zro_offset_rad_s[axis],))
            rate = rate[:, axis:axis + 1]
            column = 0

        inputs = ModelInputs(**{name: getattr(source, name)[span] for name in model.inputs})
        corrected = model.correct(rate, source.temperature_c[span],
                                  inputs).rate_rad_s[:, column]
        if source.reference_rad_s is not None:
            corrected = corrected - source.reference_rad_s[span, axis]
        return corrected

    def test_residual(self, model: EffectModel, axis: int) -> np.ndarray:
        """Return corrected minus truth on the test rows, run from their record's start."""
        first = self.records.starts[self.records.record_of(self.rows)]
        return self._run(model, axis, slice(first, len(self.full)))[self.rows - first:]

    def held_out(self, specs: tuple, label: str, folds: Optional[Folds] = None,
                 axes: Optional[tuple] = None) -> HeldOutRun:
        """
        Run each fold's models on the bins it predicts; give the `HeldOutRun`.

        Only ``axes`` (default: all) are run; the others' columns stay NaN,
        their errors None. An axis that is the PX4-style cubic takes the
        cubic's own fold runs (`baseline_run`).
        """
        folds = folds or self.folds
        axes = range(len(self.axes)) if axes is None else axes
        residual = np.full((len(self.starts), len(self.axes)), math.nan)
        cubic = [axis for axis in axes if specs[axis].baseline]
        if cubic:
            residual[:, cubic] = self.baseline_run(folds).residual[:, cubic]
        run = [axis for axis in axes if not specs[axis].baseline]
        count = folds.split.folds
        for fold, held in enumerate(folds.held):
            if not run:
                break
            self.report(fold, count, label)
            model = self.record_models(specs, fold, folds)
            for axis in run:
                binned = self.mean(self.residual(model, axis, folds.stop[fold]))
                residual[:binned.size, axis][held[:binned.size]] = binned[held[:binned.size]]
        self.report(count, count, label)
        return HeldOutRun(residual, tuple(self.error(residual[:, axis], folds) if axis in axes
                                          else None for axis in range(len(self.axes))))


def _shifted(terms: AxisTerms, offset_rad_s: float) -> AxisTerms:
    """Give the terms with ``offset_rad_s`` added to the polynomial's constant."""
    if not offset_rad_s:
        return terms
    return replace(terms, bias=(terms.bias[0] + offset_rad_s,) + terms.bias[1:])
