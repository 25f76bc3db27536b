"""
`EffectStream`: an `EffectModel` run block by block or row by row, as the node runs it.

Each axis keeps the runners of its history operators (`_AxisRunner`) across
blocks; the rest is the model's `correct_axes`, element by element, so a
row in plain floats (`EffectStream.correct_one`) takes the same operations
as a block's columns, numpy's per-call cost being most of a row's. The
stream is given its model and never imports `model` (which imports it).
"""

from typing import Optional

import numpy as np

from .history import FirstOrderLag, History, NO_HISTORY, PlayOperator, TemperatureSlope
from ..node_models import CorrectedRate, INPUTS, ModelInputs, NO_INPUTS, one_row


class _AxisRunner:
    """The history operators of one axis, run one sample at a time across blocks."""

    def __init__(self, term, window_s: float):
        """Start the runners the effects of ``term`` (an `AxisTerms`) need."""
        self.slope = TemperatureSlope(window_s).runner() if term.needs_slope else None
        self.lag = (FirstOrderLag(-term.thermal_lag_s).runner() if term.thermal_lag_s < 0.0
                    else None)
        self.gradients = [FirstOrderLag(tau).runner() for tau in term.gradient_time_constants_s]
        self.play = (PlayOperator(term.hysteresis_half_width_c).runner() if term.hysteresis_rad_s
                     else None)
        self.idle = self.slope is self.lag is self.play is None and not self.gradients

    def run(self, time, temperature: np.ndarray) -> History:
        if self.idle:
            return NO_HISTORY
        values = temperature.tolist()
        times = None if time is None else time.tolist()

        def each(step, *columns) -> np.ndarray:
            return np.array([step(*row) for row in zip(*columns)], dtype=np.float64)

        return History(
            slope=None if self.slope is None else each(self.slope.step, times, values),
            lagged=None if self.lag is None else each(self.lag.step, times, values),
            gradients=[temperature - each(lag.step, times, values) for lag in self.gradients],
            play=None if self.play is None else each(self.play.step, values))

    def step(self, time_s: Optional[float], temperature_c: float) -> History:
        """Run one row: the operators' floats."""
        if self.idle:
            return NO_HISTORY
        return History(
            slope=None if self.slope is None else self.slope.step(time_s, temperature_c),
            lagged=None if self.lag is None else self.lag.step(time_s, temperature_c),
            gradients=[temperature_c - lag.step(time_s, temperature_c)
                       for lag in self.gradients],
            play=None if self.play is None else self.play.step(temperature_c))


class EffectStream:
    """
    Runs an `EffectModel` block by block, keeping the temperature history and play state.

    The history operators step sample by sample (their runners); the rest is
    element by element on the block, so any split of a stream into blocks, or
    rows one at a time, gives the same numbers bit for bit. The whole stream
    gives what `EffectModel.correct` gives on it as one batch, to rounding
    (the batch first-order lag sums in another order).
    """

    def __init__(self, model):
        """Start a stream of ``model``, an `EffectModel`, its history empty."""
        self.model = model
        self.runners = [_AxisRunner(term, model.temperature_rate_window_s)
                        for term in model.terms]

    def correct_block(self, rates_rad_s, temperatures_c,
                      inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        """
        Correct the next rows of the stream; arguments as for `EffectModel.correct`.

        ``temperatures_c`` has one column, or one per axis.
        """
        model = self.model
        block = model.checked_block(rates_rad_s, temperatures_c, inputs)
        histories = [runner.run(block.inputs.time_s, block.temperature_c[:, axis])
                     for axis, runner in enumerate(self.runners)]
        return model.correct_checked(block, histories)

    def correct_one(self, rates_rad_s, temperatures_c, inputs: ModelInputs = NO_INPUTS) -> tuple:
        """
        Correct one row: (rad/s per axis as a list, any clamped); bit for bit as `correct_block`.

        In plain floats, numpy's per-call cost being most of a row's. A row that
        is not plain numbers in the model's shape goes through `correct_block`,
        which names what is wrong.
        """
        row = self._row(rates_rad_s, temperatures_c, inputs)
        if row is None:
            return one_row(self, rates_rad_s, temperatures_c, inputs)
        rates, temperatures, inputs = row
        histories = [runner.step(inputs.time_s, temperature)
                     for runner, temperature in zip(self.runners, temperatures)]
        corrected, clamped = self.model.correct_axes(rates, temperatures, inputs, histories)
        return corrected, any(clamped)

    def _row(self, rates_rad_s, temperatures_c, inputs: ModelInputs) -> Optional[tuple]:
        """Give (rates, temperatures per axis, inputs) of one row in floats; None if it is not."""
        axes = self.model.axes
        rates = _row_floats(rates_rad_s, (axes,))
        temperatures = _row_floats(temperatures_c, (1, axes))
        if rates is None or temperatures is None:
            return None
        values, converted = {}, False
        for name, spec in INPUTS.items():
            given = getattr(inputs, name)
            if given is None:
                if name in self.model.inputs:
                    return None
                continue
            value = _row_floats(given, spec.shape) if spec.shape else _row_float(given)
            if value is None:
                return None
            values[name] = value
            converted = converted or value is not given
        return (rates, temperatures * (axes // len(temperatures)),
                ModelInputs(**values) if converted else inputs)


def _row_float(value) -> Optional[float]:
    """Give a plain number as a float, as numpy would convert it; None for anything else."""
    if type(value) is float:
        return value
    try:
        return float(value) if np.ndim(value) == 0 else None
    except (TypeError, ValueError):
        return None


def _row_floats(values, lengths: tuple) -> Optional[list]:
    """Give a row of plain numbers, as many as one of ``lengths``, as floats; else None."""
    try:
        if len(values) not in lengths:
            return None
    except TypeError:
        return None
    floats = [value if type(value) is float else _row_float(value) for value in values]
    return None if None in floats else floats
