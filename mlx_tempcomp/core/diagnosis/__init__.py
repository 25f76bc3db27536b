"""
The closed loop of ``mlx-tempcomp diagnose``: fit, test the effects the model lacks, add one.

Truth is the reference rate when the recording has one, else zero (taken at
rest); the residual is corrected minus truth. The error figure is the RMS
(and peak) of the residual averaged over consecutive bins of ``average_s``
seconds (0: per sample) on held-out rows: averaging keeps white noise from
hiding a bias. The record is cut into ``blocks`` contiguous blocks dealt to
folds by `validation.split`, the code path `fit` uses too: forward in time
by default (each block after the first ``min_past`` predicted by a fit on
the blocks before it, as a node runs a model fitted on the past), or
round-robin to ``folds`` folds; ``validation`` chooses which decides, and
the other's figures are reported beside. Bins never span two blocks.
Stateful inputs (temperature slope, lags, play state) are computed over the
whole record first, then rows are split, as the node does when it replays
the record from the start. A fold's model clamps the (effective)
temperature at the range of its training blocks, as the node clamps at its
fitted range: forward, a block hotter or colder than its past is predicted
at the edge of that past.

Step 0 fits the temperature polynomial, its order per axis chosen by the
one-standard-error rule over the folds. Each round, every effect an axis
lacks is fitted jointly with the terms so far (linear least squares on bin
means, which is exact for the binned error). Time constants, the hysteresis
width and the lag are found by a bounded 1-D search on a log grid, coarse
then fine, with the linear coefficients solved at every point; the step
time of a bias step by a CUSUM. The best candidate is accepted if its
relative held-out RMS reduction is at least ``min_gain``, its mean per-fold
improvement exceeds ``significance`` standard errors, and no held-out block
but the first (where the history states start from an assumed equilibrium)
gets worse by more than ``block_tolerance`` x the larger of its RMS and the
axis's held-out RMS. The loop stops when no axis
accepts anything. Every reported error of a step comes from
`EffectModel.correct`, the code the node runs, on fold models.

The PX4-style cubic (a cubic in T, clamped as the node runs it) is the
baseline every axis must beat: the model the loop found is written only
when its held-out RMS under the deciding validation is at least
``baseline_margin`` below the cubic's and, under the scheme reported beside,
not above it; otherwise the axis writes the cubic, and `ModelChoice` says
why.

Several records of one unit (`records.join_records`) are diagnosed as one:
each keeps its own history (every stateful input starts afresh at its
first row, and a fold model runs each record from its start), and each has
its own bias offset, a constant column per record beyond the first in
every fit (a power cycle or a re-mount shifts the bias). Blocks never span
two records, and a block is predicted only when its record has training
rows (`validation.split`). The model written carries the offset of the
last record diagnosed: the robot runs after it, on the same mount, and
the node's ZRO recalibration at rest absorbs whatever a new run shifts.
``test_record`` holds the last record out; it is judged as written and
after a re-zero: its own bias over its first ``rezero_s`` seconds taken
off, as ``imu/recalibrate_zro`` does on a node.

By default the loop searches only the effects a node can run on a live
stream (`LIVE_EFFECTS`); acceleration only when the record shows the sensor
moved. The effects tied to the record's clock (time drift, bias steps) are
judged too, each round, before any live effect is added: when one passes
and gains more than every live effect that passes, nothing live is added
to that axis (a live term would only stand in for it), the search of the
axis ends and the record effect is named its ``cause``. After the loop
they are tested on top of the final model and reported as findings. Unless
``record_effects`` puts them into the search, they are never added.

Last, what the figures rest on: `OutsideFittedRange` says how much of the
test part and of each forward held-out block lies outside the temperature
range the model predicting it was fitted on (where it ran clamped), and
`ErrorByTemperature` bins the written model's held-out residuals (and the
test part's) into ``error_bins`` temperature bins (`validation.
error_by_temperature`): the validated error as a function of T, which the
node can add to its covariance.

The package, by module, each importing only those before it: `folds` (rows
cut into blocks and bins, the folds over them), `settings`
(`DiagnosisSettings`, what is searched), `results` (the result records, `Diagnosis`),
`data` (`DiagnosisData`: the rows, bins, folds, cached features and search
bounds of one diagnosis), `cubic` (the PX4-style cubic of each fold),
`fits` (`AxisSpec` and per effect its trials, design columns and terms:
`FITS`; an effect's trials see the data and a scoring function, not the
scorer), `problem` (`DiagnosisProblem`: the scorer on the data, its fold
models and runs), `acceptance` (an effect's judgement, the record cause, the guard against
the PX4-style cubic), `held_out_part` (the test part, the re-zero, the
error by temperature and the clamped rows), `loop` (`diagnose`).
"""

from .folds import ALL_ROWS, INSIDE_ROWS, SCORING
from .held_out_part import default_rezero_s, rezero_window_rows
from .loop import diagnose
from .results import (AxisDiagnosis, BinnedResidual, Candidate, Diagnosis, ErrorByTemperature,
                      HeldOutError, METHODS, ModelChoice, OutsideFittedRange, RecordFit, Step)
from .settings import (BASE_EFFECT, DEFAULT_ERROR_BINS, DEFAULT_REZERO_S, DiagnosisSettings,
                       ProgressCallback, RECORD_SEARCH, REZERO_MIN_SAMPLES, SEARCH_EFFECTS)

__all__ = ['ALL_ROWS', 'AxisDiagnosis', 'BASE_EFFECT', 'BinnedResidual', 'Candidate',
           'DEFAULT_ERROR_BINS', 'DEFAULT_REZERO_S', 'default_rezero_s', 'diagnose', 'Diagnosis',
           'DiagnosisSettings', 'ErrorByTemperature', 'HeldOutError', 'INSIDE_ROWS', 'METHODS',
           'ModelChoice', 'OutsideFittedRange', 'ProgressCallback', 'RECORD_SEARCH', 'RecordFit',
           'REZERO_MIN_SAMPLES', 'rezero_window_rows', 'SCORING', 'SEARCH_EFFECTS', 'Step']
