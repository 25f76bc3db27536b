"""
The gyro at rest: the standstill detector, the bias tracker and what they rest on.

The package, by module, each importing only those above it: `detector` (is the gyro
still, judged window by window from its own output), `rest_hints` (the robot saying it
stands still, on the sensor's time line), `bias_tracker` (`BiasTracking`: the offset the
model leaves, followed while still, held in motion), `tracking_bounds` (the
``bias_tracking.*`` bounds a record at rest and its model give), `recalibration` (the
checks of a ZRO recalibration's window: still, steady temperature), `moving_samples`
(where a record moved: the samples a bias(T) fit must skip). The field learner
(`core.learning`) takes what the tracker learns.
"""

from .bias_tracker import BiasTracking, tracking_state, TrackingSettings
from .detector import StandstillSettings
from .moving_samples import MOTION_MARGIN_S, moving_samples, near
from .recalibration import check_window, RecalibrationLimits
from .rest_hints import RestHints
from .tracking_bounds import derive_bounds, RestRecord

__all__ = ['BiasTracking', 'check_window', 'derive_bounds', 'MOTION_MARGIN_S', 'moving_samples',
           'near', 'RecalibrationLimits', 'RestHints', 'RestRecord', 'StandstillSettings',
           'tracking_state', 'TrackingSettings']
