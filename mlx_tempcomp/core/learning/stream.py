"""
Tracking and learning over one stream: the calls the node and ``evaluate --learn`` share.

`LearningTracking` takes the rate after the prior model (the model the parameters give,
run as ever by its own stream), takes off the learnt correction in use at each sample's
temperature, and hands the result to the `BiasTracking`, which takes off its offset:

    published = prior model's rate - c(T) - tracker offset

Before each sample it asks the tracker whether the sample closes the open window
(`BiasTracking.advance`); when one closes, the `FieldLearner` takes what the tracker
learnt and may renew c, from that sample on (`FieldLearner.close`). So c changes only
where a window starts, and every window is corrected by one curve. A block (`process`)
is cut at the window boundaries and each part goes through the same numpy operations as
its rows one by one (`process_one`): any split gives the same bits, as the tracker's does.

Until the first renewal c is +0.0, which takes nothing off a rate, bit for bit, at any
temperature but NaN (`CorrectionTable.subtracts_nothing`): `process_one`, the node's
per-message path, then hands the rate on as it came (tracking alone's bits, and its cost).
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .learner import FieldLearner
from .settings import LearningSettings
from ..errors import CalibrationError
from ..standstill import BiasTracking


@dataclass(frozen=True)
class LearntBlock:
    """Per sample: the published rate, the offset's std, still or not, the correction taken off."""

    rate_rad_s: np.ndarray
    std_rad_s: np.ndarray
    still: np.ndarray
    correction_rad_s: np.ndarray


class LearningTracking:
    """A `BiasTracking` and its `FieldLearner` over one stream; see the module notes."""

    def __init__(self, tracker: BiasTracking, learner: FieldLearner):
        if tuple(tracker.axes) != tuple(learner.axes):
            msg = f'tracker axes {list(tracker.axes)} and learner axes {list(learner.axes)}'
            raise CalibrationError(msg)
        self.tracker = tracker
        self.learner = learner
        learner.seen_runs, learner.seen_withdrawn = tracker.runs, tracker.withdrawn
        # The last row of the curve taken off (curve, temperature, row): a sensor's
        # temperature holds over many samples, and a row is a pure function of both.
        self._row = (None, None, None)
        self._nothing = [0.0] * len(tracker.axes)    # the row of a curve of +0.0

    @classmethod
    def start(cls, tracker: BiasTracking, settings: LearningSettings,
              state: Optional[dict] = None) -> tuple:
        """
        Give (the stream, '' or the error a damaged ``state`` gave).

        A state that does not check (`FieldLearner.restore`) leaves the learner at its
        prior: the model in use is the prior model, and the error says why.
        """
        learner = FieldLearner(settings, tracker.axes)
        error = ''
        if state is not None:
            try:
                learner = FieldLearner.restore(settings, tracker.axes, state)
            except CalibrationError as err:
                error = f'learning state unusable, starting from the prior model: {err}'
        return cls(tracker, learner), error

    def _closing(self, time_s: float) -> None:
        if self.tracker.advance(time_s):
            self.learner.close(self.tracker)

    def process(self, time_s, rate_rad_s, temperature_c, acceleration_m_s2=None,
                rest_hint=None) -> LearntBlock:
        """
        Correct, track and learn a block in time order (arguments as `BiasTracking.process`).

        ``rate_rad_s`` is the prior model's output (samples, axes).
        """
        time_s = np.asarray(time_s, dtype=np.float64).reshape(-1)
        rows = time_s.size
        axes = len(self.tracker.axes)
        rate = np.asarray(rate_rad_s, dtype=np.float64).reshape(rows, axes)
        temperature = np.asarray(temperature_c, dtype=np.float64).reshape(rows)
        acceleration = None if acceleration_m_s2 is None else \
            np.asarray(acceleration_m_s2, dtype=np.float64).reshape(rows, 3)
        hint = None if rest_hint is None else np.asarray(rest_hint, dtype=bool).reshape(rows)
        out, std = np.empty_like(rate), np.empty_like(rate)
        correction = np.empty_like(rate)
        still = np.empty(rows, dtype=bool)
        first = 0
        while first < rows:
            self._closing(float(time_s[first]))
            bounds = self.tracker.open_window
            end = first + 1
            if bounds is not None:
                times = time_s[end:]
                outside = ((times >= bounds[1]) | (times < bounds[0])) & np.isfinite(times)
                end += int(np.argmax(outside)) if outside.any() else times.size
            part = slice(first, end)
            table = self.learner.applied
            for axis in range(axes):
                correction[part, axis] = table.at(axis, np.ascontiguousarray(temperature[part]))
            block = self.tracker.process(time_s[part], rate[part] - correction[part],
                                         temperature[part],
                                         None if acceleration is None else acceleration[part],
                                         None if hint is None else hint[part])
            out[part], std[part], still[part] = block.rate_rad_s, block.std_rad_s, block.still
            first = end
        return LearntBlock(out, std, still, correction)

    def process_one(self, time_s: float, rate_rad_s, temperature_c: float,
                    acceleration_m_s2=None, rest_hint=None) -> tuple:
        """
        Correct, track and learn one sample: (rates, stds, still, corrections, rates in use).

        Lists; the rates in use are the prior model's less the correction, before the
        tracker's offset (what the node's recalibration window takes).
        """
        self._closing(time_s)
        table = self.learner.applied
        if table.subtracts_nothing and temperature_c == temperature_c:
            # The prior in use (before the first renewal): the row is +0.0, the rate itself.
            correction, in_use = self._nothing, rate_rad_s
        else:
            cached, temperature, correction = self._row
            if cached is not table or temperature != temperature_c:
                correction = table.row(temperature_c)
                self._row = (table, temperature_c, correction)
            in_use = [r - c for r, c in zip(rate_rad_s, correction)]
        rate, std, still = self.tracker.process_one(time_s, in_use, temperature_c,
                                                    acceleration_m_s2, rest_hint)
        return rate, std, still, correction, in_use
