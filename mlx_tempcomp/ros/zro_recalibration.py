"""
The compensation node's ZRO recalibration: the state file, the window, the offset learned.

`ZroRecalibration` reads the state file at start (checked field by field,
`zro_state_fields`) and applies its offset only to the model it was learned
on, within the full scale (`saved_offset_model`). For ``imu/recalibrate_zro``
it opens a window (`start`) that the node's corrected blocks fill (`add`), learns from
the full window the offset on top of the thermal model (`learn`) and persists
it atomically (`save`). The node keeps the service: it awaits the window and
answers.
"""

from dataclasses import dataclass
from datetime import datetime, timezone
import math
from typing import Optional

from .messages import saved_reply
from .service_window import SampleWindow
from ..core.errors import CalibrationError, TempCompError
from ..core.models import AXIS_NAMES
from ..core.recalibration import check_window, RecalibrationLimits
from ..node_parameters import limits_of, ParameterError
from ..state_file import Field, load_state, reject_state, StateFileError

# How the log names the state.
ZRO_STATE = 'saved ZRO offset'
# Without sensor.full_scale_dps or the EEPROM's RANGE, a saved offset is held to the widest
# range of the parts the driver reads (MPU-6000: +-2000 deg/s): no larger offset is real.
WIDEST_FULL_SCALE_DPS = 2000.0


def full_scale_rad_s(full_scale_dps: float, sensor) -> float:
    """Give the full scale: the parameter, else the EEPROM's RANGE (``sensor``), else widest."""
    return math.radians(full_scale_dps or (sensor.full_scale_dps if sensor is not None else 0.0)
                        or WIDEST_FULL_SCALE_DPS)


def zro_state_fields(full_scale_rad_s: float) -> tuple:
    """Give what the ZRO state file must hold: the keys `ZroRecalibration.learn` gives, checked."""
    return (Field('model', 'text'), Field('fingerprint', 'text'),
            Field('axes', 'text', length=(1, len(AXIS_NAMES)), choices=AXIS_NAMES),
            Field('zro_offset', 'number', length='axes'),
            Field('offset_unit', 'text', choices=('rad/s', 'LSB', 'mV')),
            Field('zro_offset_rad_s', 'number', length='axes', low=-full_scale_rad_s,
                  high=full_scale_rad_s),
            Field('temperature_c', 'number', low=-273.15, high=1000.0),
            Field('samples', 'integer', low=1), Field('time', 'text'))


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

    ``saved`` is the state the file holds (None without a usable one);
    ``last`` the last recalibration, the saved one at start ({} without).
    """

    def __init__(self, path: str, axes: tuple, logger):
        self.path = path
        self.axes = axes
        self.logger = logger
        self.saved: Optional[dict] = None
        self.last = {}
        self.window: Optional[ZroWindow] = None

    def load(self, full_scale_rad_s: float) -> None:
        """Read the state file, checked field by field (`load_state` logs what it finds)."""
        self.saved = load_state(self.path, zro_state_fields(full_scale_rad_s), self.logger,
                                ZRO_STATE)
        self.last = self.saved or {}

    def describe(self) -> str:
        """Say what the state file held at start, for the node's start-up line."""
        state = self.saved
        if not state:
            return 'nothing saved yet'
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
            self.saved = None
            self.last = {}
            return model
        self.logger.info(f'applied {ZRO_STATE} {state["zro_offset"]} {state["offset_unit"]} '
                         f'from {self.path}')
        return offset_model

    def start(self, model, values: dict) -> str:
        """Open a window of ``recalibration.duration_s`` on ``model``; give '' or the refusal."""
        if self.window is not None:
            return 'refused: a recalibration is already running'
        if model is None:
            return 'refused: no model yet (waiting for the EEPROM tables)'
        try:
            limits = limits_of(values)
        except (ParameterError, TempCompError) as err:
            return f'refused: {err}'
        duration_s = values['recalibration.duration_s']
        self.window = ZroWindow(SampleWindow(int(duration_s * 1e9)), model, model.fingerprint(),
                                limits, duration_s)
        return ''

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

    def learn(self, window: ZroWindow, running) -> LearnedOffset:
        """
        Learn the offset of a full ``window``; ``running`` is the model running now.

        CalibrationError when the model changed during the window or the
        window was not at rest (`check_window`).
        """
        raw, temperature, corrected = window.samples.columns()
        model = window.model
        if running is not model or model.fingerprint() != window.fingerprint:
            msg = 'the model changed during the window'
            raise CalibrationError(msg)
        stats = check_window(corrected, temperature.mean(axis=1), window.limits)
        offset = model.learn_zro_offset(raw, temperature, corrected)
        new_model = model.with_zro_offset(offset)
        offset_rad_s = new_model.offset_rad_s(stats.temperature_c)
        state = {'model': model.name, 'fingerprint': model.fingerprint(),
                 'axes': list(self.axes), 'zro_offset': [float(v) for v in offset],
                 'offset_unit': model.offset_unit,
                 'zro_offset_rad_s': [float(v) for v in offset_rad_s],
                 'temperature_c': stats.temperature_c, 'samples': stats.samples,
                 'time': datetime.now(timezone.utc).isoformat(timespec='seconds')}
        summary = ', '.join(f'{axis} {value:.6g}' for axis, value in zip(self.axes,
                                                                         offset_rad_s))
        text = (f'ZRO offset {summary} rad/s at {stats.temperature_c:.2f} C from '
                f'{stats.samples} samples over {window.duration_s:g} s')
        return LearnedOffset(new_model, state, text)

    def save(self, learned: LearnedOffset) -> str:
        """Persist a learned offset atomically; give the answer: what and where, or why not."""
        self.last = learned.state
        self.saved = learned.state
        return saved_reply(self.path, learned.state, learned.text)
