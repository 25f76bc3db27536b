"""
The compensation node's ZRO recalibration: the state file, the window, the offset learned.

`ZroRecalibration` reads the state file at start (checked field by field,
`state_fields`) and applies its offset only to the model it was learned
on, within the full scale (`saved_offset_model`). For ``imu/recalibrate_zro``
it opens a window (`start`) that the node's corrected blocks fill (`add`), learns from
the full window the offset on top of the thermal model (`learn`) and persists
it atomically (`save`). The node keeps the service: it awaits the window and
answers.

The file holds the ZRO state, the bias tracking's section (``bias_tracking``,
`TRACKING_SECTION`, checked by its user) with the field learner's beside it
(``learning``, `LEARNING_SECTION`), or both: a file written before the
sections existed loads as it did, and a tracked offset is kept before any
recalibration. Every write holds every part (`save`, `write`).

With a learnt correction in use (`core.learning`), the window holds the rate
of the model in use, the correction taken off, and the offset learnt is the
one that zeroes that: the model with the correction (`core.node_models.correction`).
"""

from dataclasses import dataclass
from datetime import datetime, timezone
import math
from typing import Optional

from ..messages import saved_reply
from ..service_window import Outcome, Refused, SampleWindow
from ...core.errors import CalibrationError, TempCompError
from ...core.node_models import AXIS_NAMES, CorrectedModel
from ...core.standstill import check_window, RecalibrationLimits
from ...parameters.compensation import CompensationSettings
from ...parameters.specs import ParameterError
from ...parameters.state_file import Field, load_state, reject_state, StateFileError, write_state

# How the log names the state.
ZRO_STATE = 'saved ZRO offset'
# The keys of the bias tracking's and the field learner's sections in the state file.
TRACKING_SECTION = 'bias_tracking'
LEARNING_SECTION = 'learning'
# Without sensor.full_scale_dps or the EEPROM's RANGE, a saved offset is held to the widest
# range of the parts the driver reads (MPU-6000: +-2000 deg/s): no larger offset is real.
WIDEST_FULL_SCALE_DPS = 2000.0


def full_scale_rad_s(full_scale_dps: float, sensor) -> float:
    """Give the full scale: the parameter, else the EEPROM's RANGE (``sensor``), else widest."""
    return math.radians(full_scale_dps or (sensor.full_scale_dps if sensor is not None else 0.0)
                        or WIDEST_FULL_SCALE_DPS)


def zro_state_fields(full_scale_rad_s: float) -> tuple:
    """Give what the ZRO state must hold: the keys `ZroRecalibration.learn` gives, checked."""
    return (Field('model', 'text', group='zro'), Field('fingerprint', 'text', group='zro'),
            Field('axes', 'text', length=(1, len(AXIS_NAMES)), choices=AXIS_NAMES,
                  group='zro'),
            Field('zro_offset', 'number', length='axes', group='zro'),
            Field('offset_unit', 'text', choices=('rad/s', 'LSB', 'mV'), group='zro'),
            Field('zro_offset_rad_s', 'number', length='axes', low=-full_scale_rad_s,
                  high=full_scale_rad_s, group='zro'),
            Field('temperature_c', 'number', low=-273.15, high=1000.0, group='zro'),
            Field('samples', 'integer', low=1, group='zro'), Field('time', 'text', group='zro'))


def state_fields(full_scale_rad_s: float) -> tuple:
    """Give what the state file may hold: the ZRO state, the sections, or both."""
    return zro_state_fields(full_scale_rad_s) + (
        Field(TRACKING_SECTION, 'section', group=TRACKING_SECTION),
        Field(LEARNING_SECTION, 'section', group=LEARNING_SECTION))


def saved_offset_model(model, state: dict, full_scale_rad_s: float):
    """
    Give ``model`` with the offset of a checked ZRO ``state`` learned on it.

    StateFileError when the offset, as a rate at the state's temperature, is
    beyond the full scale: no gyro reads such a rate, so no such offset is real.
    """
    try:
        offset_model = model.with_zro_offset(state['zro_offset'])
        offset_rad_s = offset_model.offset_rad_s(state['temperature_c'])
    except TempCompError as err:
        raise StateFileError(str(err)) from None
    if not all(abs(v) <= full_scale_rad_s for v in offset_rad_s):
        unit = state['offset_unit']
        as_rate = '' if unit == 'rad/s' else \
            f' ({[float(v) for v in offset_rad_s]} rad/s at {state["temperature_c"]} C)'
        msg = (f'zro_offset {state["zro_offset"]} {unit}{as_rate} is beyond the full scale '
               f'+-{full_scale_rad_s:.4g} rad/s ({math.degrees(full_scale_rad_s):g} deg/s)')
        raise StateFileError(msg)
    return offset_model


@dataclass(frozen=True)
class ZroWindow:
    """A recalibration's window and what it was opened on."""

    samples: SampleWindow    # rows (raw rate, temperatures, corrected rate)
    model: object            # the model running when it opened
    fingerprint: str
    correction: object       # the learnt `CorrectionTable` taken off then (None: none)
    limits: RecalibrationLimits
    duration_s: float


@dataclass(frozen=True)
class LearnedOffset:
    """A full window's outcome: the model with the new offset, the state to save, the answer."""

    model: object
    state: dict     # the ZRO state file's keys (`zro_state_fields`)
    text: str       # the answer, before where it was saved


class ZroRecalibration:
    """
    The ZRO state of the compensation node: what the state file holds, the window open.

    ``saved`` is the ZRO state the file holds (None without a usable one);
    ``last`` the last recalibration, the saved one at start ({} without);
    ``tracking_section`` and ``learning_section`` the sections read at start (None
    without), unchecked: their users check them.
    """

    def __init__(self, path: str, axes: tuple, logger):
        self.path = path
        self.axes = axes
        self.logger = logger
        self.saved: Optional[dict] = None
        self.last = {}
        self.tracking_section: Optional[dict] = None
        self.learning_section = None
        self.window: Optional[ZroWindow] = None

    def load(self, full_scale_rad_s: float) -> None:
        """Read the state file, checked field by field (`load_state` logs what it finds)."""
        state = load_state(self.path, state_fields(full_scale_rad_s), self.logger, ZRO_STATE)
        self.tracking_section = None if state is None else state.pop(TRACKING_SECTION, None)
        self.learning_section = None if state is None else state.pop(LEARNING_SECTION, None)
        self.saved = state or None
        self.last = self.saved or {}

    def describe(self) -> str:
        """Say what the state file held at start, for the node's start-up line."""
        state = self.saved
        if not state:
            return 'no ZRO offset saved' if self.tracking_section else 'nothing saved yet'
        return (f"a {state['model']} ZRO offset {state['zro_offset']} {state['offset_unit']} "
                f"of {state['time']}")

    def with_saved_offset(self, model, full_scale_rad_s: float):
        """Apply the saved offset if it was learned on this very model and is within its range."""
        state = self.saved
        if model is None or not state:
            return model
        if state['model'] != model.name or state['fingerprint'] != model.fingerprint() or \
                tuple(state['axes']) != self.axes:
            self.logger.warn(
                f'{ZRO_STATE} in {self.path} is whole but was learned on another model '
                f'(model {state["model"]}, axes {state["axes"]}, fingerprint '
                f'{state["fingerprint"]}; running {model.name}, {list(self.axes)}, '
                f'{model.fingerprint()}); not applied')
            return model
        try:
            offset_model = saved_offset_model(model, state, full_scale_rad_s)
        except StateFileError as err:
            reject_state(self.path, str(err), self.logger, ZRO_STATE)
            # The file is gone, and with it the tracking relative to that offset.
            self.saved = None
            self.tracking_section = None
            self.learning_section = None
            self.last = {}
            return model
        self.logger.info(f'applied {ZRO_STATE} {state["zro_offset"]} {state["offset_unit"]} '
                         f'from {self.path}')
        return offset_model

    def start(self, model, settings: CompensationSettings, correction=None) -> None:
        """
        Open a window of ``recalibration.duration_s`` of ``settings`` on ``model``, or `Refused`.

        ``correction``: the learnt `CorrectionTable` taken off after ``model`` (None: none).
        One at a time: the node's `ServiceGuard` refuses a second call before this.
        """
        if model is None:
            raise Refused('no model yet (waiting for the EEPROM tables)')
        try:
            limits = settings.recalibration_limits()
        except (ParameterError, TempCompError) as err:
            raise Refused(str(err)) from None
        duration_s = settings.recalibration.duration_s
        self.window = ZroWindow(SampleWindow(int(duration_s * 1e9)), model, model.fingerprint(),
                                correction, limits, duration_s)

    def add(self, stamps_ns: list, raw_rad_s: list, temperature_c: list, rate_rad_s: list) -> None:
        """Give the open window, if any, a corrected block's rows."""
        window = self.window
        if window is None:
            return
        for row in zip(stamps_ns, raw_rad_s, temperature_c, rate_rad_s):
            window.samples.add(*row)

    def end(self) -> None:
        """Close the window, whether it filled or not."""
        self.window = None

    def learn(self, window: ZroWindow, running, correction=None) -> LearnedOffset:
        """
        Learn the offset of a full ``window``; ``running`` is the model running now.

        ``correction`` is the learnt table taken off now: the window's rows are the
        model's less it, and the offset zeroes the model with it (`CorrectedModel`).
        CalibrationError when the model or the correction changed during the window or
        the window was not at rest (`check_window`).
        """
        raw, temperature, corrected = window.samples.columns()
        model = window.model
        if running is not model or model.fingerprint() != window.fingerprint:
            msg = 'the model changed during the window'
            raise CalibrationError(msg)
        if correction != window.correction:
            msg = 'the learnt correction was renewed during the window'
            raise CalibrationError(msg)
        stats = check_window(corrected, temperature.mean(axis=1), window.limits)
        in_use = model if correction is None or correction.is_zero else \
            CorrectedModel(model, correction)
        offset = in_use.learn_zro_offset(raw, temperature, corrected)
        new_model = model.with_zro_offset(offset)
        offset_rad_s = new_model.offset_rad_s(stats.temperature_c)
        state = {'model': model.name, 'fingerprint': model.fingerprint(),
                 'axes': list(self.axes), 'zro_offset': [float(v) for v in offset],
                 'offset_unit': model.offset_unit,
                 'zro_offset_rad_s': [float(v) for v in offset_rad_s],
                 'temperature_c': stats.temperature_c, 'samples': stats.samples,
                 'time': datetime.now(timezone.utc).isoformat(timespec='seconds')}
        # What changed, from what to what: both as rates at the window's temperature.
        before_rad_s = model.offset_rad_s(stats.temperature_c)
        summary = ', '.join(f'{axis} from {old:.6g} to {new:.6g}' for axis, old, new in
                            zip(self.axes, before_rad_s, offset_rad_s))
        text = (f'ZRO offset {summary} rad/s at {stats.temperature_c:.2f} C ('
                f'{stats.samples} samples over {window.duration_s:g} s)')
        return LearnedOffset(new_model, state, text)

    def save(self, learned: LearnedOffset) -> Outcome:
        """
        Persist a learned offset atomically; give the outcome: what and where, or why not.

        ``learned.state`` may hold the bias tracking's and the learner's sections beside
        the ZRO state: all go in the one write.
        """
        zro = {key: value for key, value in learned.state.items()
               if key not in (TRACKING_SECTION, LEARNING_SECTION)}
        self.last = zro
        self.saved = zro
        return saved_reply(self.path, learned.state, learned.text)

    def write(self, sections: dict) -> None:
        """Write ``sections`` (tracking, learning) beside the ZRO state held; StateFileError."""
        write_state(self.path, {**(self.saved or {}), **sections})
