"""
Field learning: the temperature model renewed from the still windows the tracker learns from.

The package, by module, each importing only those above it: `settings`
(`LearningSettings`, derived from the tracker's; ``parameters.learning`` holds the
``learning.*`` table), `guard` (the paired trial of a renewed curve
against the one in use and the prior), `curve` (the Kalman filter of one axis's correction:
a level and a shape at the knots), `state` (the learner's state dict and its check),
`learner` (`FieldLearner`: windows, runs, trials, the curve in use), `stream`
(`LearningTracking`: the correction taken off before the tracker, the calls the node and
``mlx-tempcomp evaluate --learn`` share). The renewed model is the prior model less a
`core.node_models.correction.CorrectionTable`. docs/learning.md says what it learns and
what it cannot.
"""

from .learner import FieldLearner
from .settings import derive_settings, LearningSettings
from .stream import LearningTracking, LearntBlock

__all__ = ['derive_settings', 'FieldLearner', 'LearningSettings', 'LearningTracking',
           'LearntBlock']
