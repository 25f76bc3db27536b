"""
``mlx-tempcomp diagnose``: the closed loop, its report, plots and a parameter file.

Runs `mlx_tempcomp.core.diagnosis.diagnose` on a recording, or on several
records of one unit fitted as one, and writes into ``--out DIR``:
report.md, report.json (per axis the ordered steps with their held-out error
before and after, per fold and per block, the rejected and skipped
candidates, the findings of the record-only effects; each record's offset;
a held-out record's errors as written and after a re-zero),
residual_vs_temperature.png, residual_vs_time.png, error_per_step.png,
error_by_temperature.png and params.yaml, which compensation_node loads:
live-runnable effects only, unless --record-effects put time drift and bias
steps into the search, and the held-out error by temperature
(``model_error.*``, for the Imu covariance) and the bias tracking's bounds
(``bias_tracking.*``, `toolkit.tracking`). The report says how much of the
test set and of each forward held-out block lies outside the temperature
range the model predicting it was fitted on (`uncertainty`).
``--test each`` diagnoses once per record with that record held out, then
once over all records for params.yaml.
"""

from .command import add_parser, diagnose_command

__all__ = ('add_parser', 'diagnose_command')
