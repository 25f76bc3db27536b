"""What ``mlx-tempcomp diagnose`` finds: the result records, a held-out error to `Diagnosis`."""

from dataclasses import dataclass, field
import math
from typing import Mapping, Optional

import numpy as np

from .settings import DiagnosisSettings
from ..effects import EffectModel
from ..fitting import OutsideRange, split, TemperatureErrors
from ..node_models import ModelErrorTable, NormalisedError

METHODS = ('none', 'px4_cubic', 'temperature_polynomial', 'diagnosed')


@dataclass(frozen=True)
class HeldOutError:
    """
    Error of binned residuals in rad/s: RMS, peak |.|, and RMS per fold and per block.

    Blocks no fold predicts (forward validation's first blocks) have NaN there.
    ``extrapolated_rms_rad_s`` is the RMS over the held-out bins that lie beyond
    their fold's training temperatures (NaN when none do), ``extrapolated_share``
    their share of the held-out rows.
    """

    rms_rad_s: float
    peak_rad_s: float
    fold_rms_rad_s: tuple = ()
    block_rms_rad_s: tuple = ()
    extrapolated_rms_rad_s: float = math.nan
    extrapolated_share: float = 0.0


@dataclass(frozen=True)
class Step:
    """One effect added to an axis, with the held-out error before and after it."""

    effect: str
    parameters: Mapping
    before: HeldOutError
    after: HeldOutError
    round_number: int
    held_out_gain: Optional[float] = None


@dataclass(frozen=True)
class Candidate:
    """An effect tried in a round and not added (or a record effect's finding)."""

    effect: str
    round_number: int
    parameters: Mapping
    held_out_gain: float
    fold_improvement_rad_s: float
    fold_improvement_se_rad_s: float
    reason: str
    worst_block_change: float = 0.0


@dataclass(frozen=True)
class ModelChoice:
    """
    The model an axis writes: the one the loop found, or the PX4-style cubic.

    ``found`` and ``cubic`` are their held-out errors under the deciding
    validation, ``other_found`` and ``other_cubic`` under the scheme reported
    beside. The found model is written when its RMS is at most (1 -
    ``margin``) x the cubic's under the first and at most the cubic's under
    the second, else ``reason`` says why the cubic is.
    """

    written: str
    found: HeldOutError
    cubic: HeldOutError
    margin: float
    other_found: HeldOutError
    other_cubic: HeldOutError
    reason: str = ''

    @property
    def ratio(self) -> float:
        """Give the found model's held-out RMS over the cubic's (deciding validation)."""
        return _ratio(self.found, self.cubic)

    @property
    def other_ratio(self) -> float:
        """Give the found model's held-out RMS over the cubic's (the scheme beside)."""
        return _ratio(self.other_found, self.other_cubic)


def _ratio(error: HeldOutError, baseline: HeldOutError) -> float:
    return error.rms_rad_s / baseline.rms_rad_s if baseline.rms_rad_s else math.inf


@dataclass(frozen=True)
class AxisDiagnosis:
    """
    What the loop found on one axis.

    ``findings`` holds the record effects (time drift, bias step) tested on
    top of the final model when the search left them out; one whose
    ``reason`` is empty passed every test. ``cause`` is the record effect
    that explained the residual better than every live effect and ended the
    search of the axis (None if none did). ``choice`` says which model the
    axis writes (`ModelChoice`).
    """

    axis: str
    order: int
    order_scores: tuple
    steps: tuple
    rejected: tuple
    findings: tuple = ()
    choice: Optional[ModelChoice] = None
    cause: Optional[Candidate] = None

    @property
    def effects(self) -> tuple:
        return tuple(step.effect for step in self.steps)


@dataclass(frozen=True)
class BinnedResidual:
    """
    Binned residuals (bins, axes) of the base and diagnosed models; rows per bin.

    ``cubic_rad_s``: the PX4-style cubic's, clamped at its fitted range, the reference.
    """

    time_s: np.ndarray
    temperature_c: np.ndarray
    heating: np.ndarray
    before_rad_s: np.ndarray
    after_rad_s: np.ndarray
    rows: Optional[np.ndarray] = None
    cubic_rad_s: Optional[np.ndarray] = None


@dataclass(frozen=True)
class OutsideFittedRange:
    """
    Where the model runs outside the temperature range it was fitted on: it clamps there.

    Temperatures are the effective ones each axis's model clamps (T, or
    T_eff with a thermal lag), one column per axis; ``per_axis`` says whether
    they differ. ``blocks`` holds per block of the forward scheme the
    `OutsideRange` of its rows against the blocks before it (None: not
    predicted), ``deciding_blocks`` the same against its fold's training
    blocks under the deciding scheme (``deciding``; None when it is forward),
    ``test`` the test part's against the written model's range.
    """

    per_axis: bool
    blocks: tuple
    test: Optional[OutsideRange] = None
    deciding: str = ''
    deciding_blocks: Optional[tuple] = None


@dataclass(frozen=True)
class ErrorByTemperature:
    """
    The written model's held-out error per temperature bin (`TemperatureErrors`), and its table.

    ``held_out``: the residuals of the deciding validation's folds,
    ``other_held_out`` those of the scheme beside (``other``; one of the two
    is forward: later in time); ``test``: the written model on the test
    part. ``rows_per_bin`` is the mean number of samples per averaging bin.
    ``noise_rad_s`` is the white noise of a sample per axis on the diagnosed
    rows, ``table`` the node's `ModelErrorTable`: per bin the larger bias
    part of the two schemes (`model_error.larger_table`), None without a
    held-out residual. ``cubic``: the PX4-style cubic's error per bin, the
    reference: on the test part when there is one, else on the deciding
    scheme's held-out blocks.
    """

    validation: str
    held_out: TemperatureErrors
    rows_per_bin: float
    test: Optional[TemperatureErrors] = None
    other: str = ''
    other_held_out: Optional[TemperatureErrors] = None
    noise_rad_s: tuple = ()
    table: Optional[ModelErrorTable] = None
    cubic: Optional[TemperatureErrors] = None


@dataclass(frozen=True)
class RecordFit:
    """
    One record of the input: its name and rows, and whether the diagnosis fitted it.

    ``offset_rad_s`` is its bias offset per axis against the written one
    (the last fitted record's), None for a held-out record.
    """

    name: str
    rows: int
    fitted: bool
    offset_rad_s: Optional[tuple]


@dataclass(frozen=True)
class Diagnosis:
    """
    The result: the model, the steps per axis, and the comparison with simpler models.

    ``comparison`` maps each validation scheme, the deciding one first (and
    'test' with a test part), to a mapping of each of METHODS to one
    `HeldOutError` per axis.
    ``skipped`` lists (effect, reason) for effects the data cannot support
    or the settings leave out. ``records`` describes each record
    (`RecordFit`); with a held-out record, 'test_rezeroed' in ``comparison``
    holds the errors after its re-zero, and ``rezero_rad_s`` maps each of
    METHODS to what the re-zero took off per axis. ``outside_range`` and
    ``error_by_temperature`` are the package docstring's last paragraph;
    ``normalised`` judges the covariance the written file publishes (white
    noise and table) on the test part as written, None without one.
    """

    axes: tuple
    settings: DiagnosisSettings
    model: EffectModel
    base_model: EffectModel
    per_axis: tuple
    skipped: tuple
    comparison: Mapping
    rows: int
    test_rows: int
    bins: int
    truth: str
    held_out: BinnedResidual
    test: Optional[BinnedResidual] = None
    bounds: Mapping = field(default_factory=dict)
    records: tuple = ()
    rezero_rad_s: Mapping = field(default_factory=dict)
    first_blocks: tuple = (0,)
    outside_range: Optional[OutsideFittedRange] = None
    error_by_temperature: Optional[ErrorByTemperature] = None
    normalised: Optional[NormalisedError] = None

    def split(self, scheme: Optional[str] = None):
        """Give the blocks as a scheme (default: the deciding one) dealt them, records and all."""
        settings = self.settings
        return split(settings.blocks, scheme or settings.validation, settings.folds,
                     settings.min_past, self.first_blocks)
