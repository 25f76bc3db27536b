"""
Fitting models to a record and judging them on data they were not fitted to.

The package, by module, each importing only those above it: `validation` (held-out blocks:
round-robin, forward, purged; the paired comparison fold by fold; the share outside the
fitted range; the error by temperature), `baseline` (PX4's cubic, as PX4 fits and runs
it: the baseline every model is judged against), `bias_polynomial` (least-squares bias
polynomials of temperature, the order chosen by held-out blocks; the MPU-6000 note's
relative form; the ADIS16130's linear BTC), `chain_fit` (the calibration chain fitted on
a rate-table record), `records` (several records of one unit laid end to end, each with
its own history), `pooling` (a fleet's bias models partially pooled: the population prior,
each unit's fit shrunk toward it).
"""

from .baseline import cubic_scale_c, cubic_sums, fit_cubic, PX4_ORDER, solve_cubic
from .bias_polynomial import (DISTINCT_DECIMALS, fit_linear_btc, fit_polynomial, MIN_SPAN_C,
                              relative_polynomial, select_orders, table_step_c)
from .chain_fit import ChainSettings, find_plateaus, fit_chain
from .pooling import (CONFLICT_LEVEL, MIN_POOLED_UNITS, moments_of, pool_fleet, RATE_WINDOW_S,
                      record_moments, unit_moments)
from .records import join_records
from .validation import (BASELINE_MARGIN, block_bounds, buffer_blocks, cubic_instead,
                         DEFAULT_BLOCKS, DEFAULT_FOLDS, DEFAULT_MIN_PAST, DEFAULT_SIGNIFICANCE,
                         DEFAULT_VALIDATION, error_by_temperature, FORWARD, held_out_outside_range,
                         one_standard_error, order_score, outside_range, OutsideRange, Paired,
                         paired, PURGED, record_block_bounds, SCHEMES, split,
                         temperature_bin_edges, TemperatureErrors, training_sums)

__all__ = ['BASELINE_MARGIN', 'block_bounds', 'buffer_blocks', 'ChainSettings', 'CONFLICT_LEVEL',
           'cubic_instead', 'cubic_scale_c', 'cubic_sums', 'DEFAULT_BLOCKS', 'DEFAULT_FOLDS',
           'DEFAULT_MIN_PAST', 'DEFAULT_SIGNIFICANCE', 'DEFAULT_VALIDATION', 'DISTINCT_DECIMALS',
           'error_by_temperature', 'find_plateaus', 'fit_chain', 'fit_cubic', 'fit_linear_btc',
           'fit_polynomial', 'FORWARD', 'held_out_outside_range', 'join_records',
           'MIN_POOLED_UNITS', 'MIN_SPAN_C', 'moments_of', 'one_standard_error', 'order_score',
           'outside_range', 'OutsideRange', 'Paired', 'paired', 'pool_fleet', 'PURGED',
           'PX4_ORDER', 'RATE_WINDOW_S', 'record_block_bounds', 'record_moments',
           'relative_polynomial', 'SCHEMES', 'select_orders', 'solve_cubic', 'split',
           'table_step_c', 'temperature_bin_edges', 'TemperatureErrors', 'training_sums',
           'unit_moments']
