"""
The compensation node's inputs: paired by stamp, held, taken while they wait, made a block.

Raw rate and temperature (one temperature, or one per chip for the ``eeprom``
model on several MLX90609 chips) are paired by header stamp, and so are the
model inputs on topics of their own (`AUXILIARY`) while the model names them
in ``inputs``: a second temperature, and the supply voltage under
``supply_voltage.pairing: stamp``. Under ``hold`` the supply voltage is kept
apart (`HeldSupply`) and each sample takes the latest at or before its stamp.
`CompensationInputs.block` makes paired samples what the model's stream takes
(`InputBlock`), leaving out, and counting, samples without the acceleration or
the supply voltage the model needs.
"""

import bisect
from dataclasses import dataclass
import itertools
from typing import Callable, Optional

import numpy as np
from sensor_msgs.msg import BatteryState, Temperature

from . import messages
from ..core.model_interface import ModelInputs
from ..core.pairing import StampPairer, zero_order_hold


@dataclass(frozen=True)
class AuxiliaryInput:
    """A model input on a topic of its own, subscribed while the model needs it."""

    field: str                          # the `ModelInputs` field it fills
    message_type: type
    topic: str
    value: Callable[[object], float]    # the value a message carries


TEMPERATURE_2 = 'temperature_2'
SUPPLY = 'supply_voltage'
# Pairer stream -> its input.
AUXILIARY = {
    TEMPERATURE_2: AuxiliaryInput('temperature_2_c', Temperature, 'imu/temperature_2_raw',
                                  lambda msg: msg.temperature),
    SUPPLY: AuxiliaryInput('supply_voltage_v', BatteryState, 'imu/supply_voltage',
                           lambda msg: msg.voltage),
}
# Held supply voltages kept: the slow input is seconds apart, a block spans less.
HELD_SUPPLY = 64


def waiting_messages(subscription):
    """Take the messages waiting on ``subscription``, one by one, without a callback."""
    while True:
        with subscription.handle:
            message = subscription.handle.take_message(subscription.msg_type, subscription.raw)
        if message is None:
            return
        yield message[0]


class HeldSupply:
    """The latest supply voltages, in stamp order, for a zero-order hold."""

    def __init__(self, capacity: int = HELD_SUPPLY):
        self.capacity = capacity
        self.held = []     # (stamp_ns, volts), ascending stamps

    def __bool__(self) -> bool:
        return bool(self.held)

    def add(self, msg: BatteryState) -> None:
        """Keep a voltage: a late one slots in, a repeated stamp replaces."""
        stamp_ns = messages.stamp_to_ns(msg.header.stamp)
        held = self.held
        index = bisect.bisect_left(held, (stamp_ns,))
        if index < len(held) and held[index][0] == stamp_ns:
            held[index] = (stamp_ns, msg.voltage)
        else:
            held.insert(index, (stamp_ns, msg.voltage))
            del held[:-self.capacity]

    def at(self, stamps_ns: list, max_age_ns: int) -> tuple:
        """Give (volts, usable) at each stamp: `zero_order_hold` of the voltages kept."""
        return zero_order_hold(stamps_ns, [stamp for stamp, _ in self.held],
                               [volts for _, volts in self.held], max_age_ns)


@dataclass(frozen=True)
class InputBlock:
    """Paired samples as the model's stream takes them: one row per sample, stamp order."""

    stamps_ns: list
    messages: list           # {pairer stream: message} of each sample
    raw_rad_s: list          # rate per axis
    temperature_c: list      # one per temperature stream
    columns: dict            # `ModelInputs` field -> one value per sample

    def correct(self, stream) -> tuple:
        """Run the block through the model's ``stream``: (rates of each row, rows clamped)."""
        if len(self.stamps_ns) == 1:
            # One sample, no numpy: the same numbers, bit for bit, as a block of one.
            rate, clamped = stream.correct_one(
                self.raw_rad_s[0], self.temperature_c[0],
                ModelInputs(**{name: column[0] for name, column in self.columns.items()}))
            return [rate], int(clamped)
        result = stream.correct_block(self.raw_rad_s, self.temperature_c, ModelInputs(
            **{name: np.array(column) for name, column in self.columns.items()}))
        return (result.rate_rad_s.tolist(),
                int(np.count_nonzero(result.temperature_clamped.any(axis=1))))


class CompensationInputs:
    """
    The inputs of the compensation node and the counts of what they could not give.

    ``subscriptions`` maps pairer streams to the node's subscriptions, which
    `take` drains; streams without one come from a driver in the process (`take_local`).
    """

    def __init__(self, axes: tuple, indices: tuple, per_axis: bool, supply_hold: bool):
        self.indices = indices
        self.temperature_streams = tuple(f'temperature_{axis}' for axis in axes) \
            if per_axis else ('temperature',)
        topics = [f'imu/temperature_raw/{axis}' for axis in axes] if per_axis else \
            ['imu/temperature_raw']
        self.temperature_topics = dict(zip(self.temperature_streams, topics))
        self.supply_hold = supply_hold
        self.pairer = StampPairer(('imu',) + self.temperature_streams)
        self.dropped_before = 0   # by pairers replaced on a model change
        self.subscriptions = {}
        self.held_supply = HeldSupply()
        self.needs_acceleration = False
        self.auxiliary = ()
        self.samples_waiting = 0
        self.no_acceleration_samples = 0
        self.no_acceleration_recent = False
        self.no_supply_samples = 0
        self.no_supply_recent = False

    @property
    def unpaired_dropped(self) -> int:
        return self.dropped_before + self.pairer.dropped

    @property
    def holds_supply(self) -> bool:
        """Tell whether the model takes a supply voltage kept by zero-order hold."""
        return SUPPLY in self.auxiliary and self.supply_hold

    @property
    def waiting_for_supply(self) -> bool:
        return self.holds_supply and not self.held_supply

    def clear_recent(self) -> None:
        """Start a new status period: no sample left out recently."""
        self.no_acceleration_recent = False
        self.no_supply_recent = False

    def held(self, stream: str) -> bool:
        """Tell whether an input stream is kept by zero-order hold rather than paired by stamp."""
        return stream == SUPPLY and self.supply_hold

    def use(self, inputs: frozenset) -> tuple:
        """Follow a model that needs ``inputs``; give its auxiliary streams not subscribed yet."""
        # Read once here, not per sample.
        self.needs_acceleration = 'acceleration_m_s2' in inputs
        self.auxiliary = tuple(stream for stream, auxiliary in AUXILIARY.items()
                               if auxiliary.field in inputs)
        streams = ('imu',) + self.temperature_streams + tuple(
            s for s in self.auxiliary if not self.held(s))
        if streams != self.pairer.streams:
            self.dropped_before += self.pairer.dropped
            self.pairer = StampPairer(streams)
        return tuple(s for s in self.auxiliary if s not in self.subscriptions)

    def _pair(self, stream: str, msg) -> list:
        return self.pairer.add(stream, messages.stamp_to_ns(msg.header.stamp), msg)

    def take(self, stream: str, msg, max_block: int) -> list:
        """
        Pair ``msg``, then what else waits on the inputs; give the samples now complete.

        Taking the waiting messages here, up to ``max_block`` in all, saves the
        executor a wake-up per message: that, not the model, limits a Python node's rate.
        """
        if stream not in self.pairer.streams:
            return []   # an auxiliary input, subscribed for an earlier model
        complete = self._pair(stream, msg)
        budget = max_block - 1
        while budget > 0:
            taken = 0
            for name, subscription in self.subscriptions.items():
                if name not in self.pairer.streams:
                    continue
                for message in itertools.islice(waiting_messages(subscription), budget):
                    complete += self._pair(name, message)
                    taken += 1
                    budget -= 1
            if not taken:
                break
        return complete

    def take_local(self, handoff: list) -> list:
        """Pair what a driver in this process sent, [(stream, msg)]; give the samples complete."""
        complete = []
        for stream, msg in handoff:
            # Auxiliary inputs subscribed over DDS come that way only.
            if stream in self.pairer.streams and stream not in self.subscriptions:
                complete += self._pair(stream, msg)
        return complete

    def block(self, samples: list, supply_max_age_s: float) -> Optional[InputBlock]:
        """
        Give paired samples [(stamp_ns, {stream: message})] as a block; None if none is usable.

        Samples without the acceleration the model needs, or without a held
        supply voltage within ``supply_max_age_s``, are left out and counted;
        before the first voltage they wait (counted too).
        """
        if self.needs_acceleration:
            # REP-145: covariance[0] = -1 says the message has no acceleration.
            usable = [(stamp, parts) for stamp, parts in samples
                      if parts['imu'].linear_acceleration_covariance[0] != -1.0]
            if len(usable) < len(samples):
                self.no_acceleration_samples += len(samples) - len(usable)
                self.no_acceleration_recent = True
            samples = usable
            if not samples:
                return None
        held_supply = None
        if self.holds_supply:
            held_supply, samples = self._hold_supply(samples, int(supply_max_age_s * 1e9))
            if not samples:
                return None
        stamps_ns = [stamp for stamp, _ in samples]
        parts = [parts for _, parts in samples]
        columns = {AUXILIARY[name].field: [AUXILIARY[name].value(p[name]) for p in parts]
                   for name in self.auxiliary if not self.held(name)}
        if held_supply is not None:
            columns[AUXILIARY[SUPPLY].field] = held_supply.tolist()
        if self.needs_acceleration:
            columns['acceleration_m_s2'] = [[p['imu'].linear_acceleration.x,
                                             p['imu'].linear_acceleration.y,
                                             p['imu'].linear_acceleration.z] for p in parts]
        columns['time_s'] = [stamp / 1e9 for stamp in stamps_ns]
        return InputBlock(
            stamps_ns=stamps_ns, messages=parts,
            raw_rad_s=[messages.imu_rates(p['imu'], self.indices) for p in parts],
            temperature_c=[[p[s].temperature for s in self.temperature_streams] for p in parts],
            columns=columns)

    def _hold_supply(self, samples: list, max_age_ns: int) -> tuple:
        """Give (held volts, samples) of the samples with a voltage; count those without."""
        # Voltages waiting in the queue count too: the executor may have served the
        # samples' subscriptions first.
        for message in waiting_messages(self.subscriptions[SUPPLY]):
            self.held_supply.add(message)
        if not self.held_supply:
            # At start, before the monitor's first reading: waiting, not a fault.
            self.samples_waiting += len(samples)
            return None, []
        held_supply, usable = self.held_supply.at([stamp for stamp, _ in samples], max_age_ns)
        if not usable.all():
            self.no_supply_samples += int(np.count_nonzero(~usable))
            self.no_supply_recent = True
            samples = [s for s, keep in zip(samples, usable.tolist()) if keep]
            held_supply = held_supply[usable]
        return held_supply, samples
