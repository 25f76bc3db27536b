"""
The compensation node's inputs: paired, held, taken while they wait, made a block.

The temperature (one stream, or one per chip for the ``eeprom`` model on several
MLX90609 chips) is paired with the raw rate as ``temperature.pairing`` says:
``hold`` (the default) and ``interpolate`` give each sample the latest reading,
or the two around it, within ``temperature.max_age_s`` (`ReadingPairer`: a driver
that rates and stamps its temperature its own way); ``stamp`` by equal header
stamps only (`StampPairer`); ``none``: the driver sends no temperature. A second
temperature (`AUXILIARY`, while the model names it in ``inputs``) is paired like
the temperature; the supply voltage is held apart (`HeldSupply`) or, under
``supply_voltage.pairing: stamp``, paired by stamp. A driver that sends no
temperature at all within ``temperature.wait_s`` of its first sample (sensor
time) gets its samples through without one (``without_temperature``), until one
comes. `CompensationInputs.block` makes samples what the model's stream takes
(`InputBlock`), leaving out, and counting, samples without the acceleration or
the supply voltage the model needs.
"""

import bisect
from dataclasses import dataclass
import itertools
import math
import time
from typing import Callable, Optional

import numpy as np
from sensor_msgs.msg import BatteryState, Temperature

from .. import messages
from ...core.node_models import ModelInputs
from ...core.series import ReadingPairer, StampPairer, zero_order_hold


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
# temperature.pairing: by ReadingPairer, by StampPairer, or no temperature at all.
HELD_PAIRINGS = ('hold', 'interpolate')
PAIRINGS = HELD_PAIRINGS + ('stamp', 'none')
NAN = math.nan
# With a temperature publisher matched, the samples wait this many times temperature.wait_s.
PUBLISHED_WAIT = 10


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
    temperature_c: list      # one per temperature stream (NaN without a temperature)
    columns: dict            # `ModelInputs` field -> one value per sample
    has_temperature: bool = True

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


def paired_message(reading, imu):
    """Give the Temperature a sample got: the reading's own if exact, else one at its stamp."""
    if reading.exact:
        return reading.payload
    held = reading.payload
    return messages.temperature_message(imu.header.stamp, held.header.frame_id, reading.value,
                                        held.variance)


class CompensationInputs:
    """
    The inputs of the compensation node and the counts of what they could not give.

    ``subscriptions`` maps pairer streams to the node's subscriptions, which
    `take` drains; streams without one come from a driver in the process (`take_local`).
    ``last_imu`` and ``last_temperature`` are when each last arrived (monotonic s).
    """

    def __init__(self, axes: tuple, indices: tuple, per_axis: bool, supply_hold: bool,
                 pairing: str = 'hold', max_age_s: float = 2.0, wait_s: float = 5.0):
        self.indices = indices
        self.pairing = pairing
        self.temperature_streams = () if pairing == 'none' else \
            tuple(f'temperature_{axis}' for axis in axes) if per_axis else ('temperature',)
        topics = [f'imu/temperature_raw/{axis}' for axis in axes] if per_axis else \
            ['imu/temperature_raw']
        self.temperature_topics = dict(zip(self.temperature_streams, topics))
        self.supply_hold = supply_hold
        self.wait_ns = int(wait_s * 1e9)
        held = pairing in HELD_PAIRINGS
        self.readings = ReadingPairer(self.temperature_streams, pairing == 'interpolate',
                                      int(max_age_s * 1e9)) if held else None
        self.pairer = StampPairer(('imu',) + (() if held else self.temperature_streams))
        self.dropped_before = 0   # by pairers replaced on a model change
        self.subscriptions = {}
        self.held_supply = HeldSupply()
        self.needs_acceleration = False
        self.auxiliary = ()
        self.without_temperature = pairing == 'none'
        self.first_imu_ns = None
        self.newest_imu_ns = None
        self.last_imu = None
        self.last_temperature = None
        self.samples_waiting = 0
        self.no_acceleration_samples = 0
        self.no_acceleration_recent = False
        self.no_supply_samples = 0
        self.no_supply_recent = False
        self.no_temperature_samples = 0
        self.no_temperature_recent = False
        self.temperature_stamp_age_ns = 0   # the largest paired in the status period

    @property
    def unpaired_dropped(self) -> int:
        return self.dropped_before + self.pairer.dropped + \
            (self.readings.lost if self.readings else 0)

    @property
    def holds_supply(self) -> bool:
        """Tell whether the model takes a supply voltage kept by zero-order hold."""
        return SUPPLY in self.auxiliary and self.supply_hold

    @property
    def waiting_for_supply(self) -> bool:
        return self.holds_supply and not self.held_supply

    @property
    def waiting_for_temperature(self) -> bool:
        """Tell whether samples came, but no temperature yet, and they still wait for one."""
        return not self.without_temperature and self.first_imu_ns is not None and \
            not self._temperature_came()

    @property
    def held_back(self) -> tuple:
        """Give (samples waiting for their readings, the oldest one's wait in stamps, s)."""
        readings = self.readings
        if readings is None or not readings.waiting:
            return 0, 0.0
        return readings.waiting, readings.waiting_ns / 1e9

    def clear_recent(self) -> None:
        """Start a new status period: no sample left out recently."""
        self.no_acceleration_recent = False
        self.no_supply_recent = False
        self.no_temperature_recent = False
        self.temperature_stamp_age_ns = 0

    def held(self, stream: str) -> bool:
        """Tell whether an input stream is kept by zero-order hold rather than paired by stamp."""
        return stream == SUPPLY and self.supply_hold

    def use(self, inputs: frozenset) -> tuple:
        """Follow a model that needs ``inputs``; give its auxiliary streams not subscribed yet."""
        # Read once here, not per sample.
        self.needs_acceleration = 'acceleration_m_s2' in inputs
        self.auxiliary = tuple(stream for stream, auxiliary in AUXILIARY.items()
                               if auxiliary.field in inputs)
        by_reading = self.temperature_streams + tuple(
            s for s in self.auxiliary if s == TEMPERATURE_2) if self.readings else ()
        streams = ('imu',) + tuple(s for s in self.temperature_streams + self.auxiliary
                                   if not self.held(s) and s not in by_reading)
        if streams != self.pairer.streams:
            self.dropped_before += self.pairer.dropped
            self.pairer = StampPairer(streams)
        if self.readings is not None and by_reading != self.readings.streams:
            self.readings.set_streams(by_reading)
        return tuple(s for s in self.auxiliary if s not in self.subscriptions)

    def _add(self, stream: str, msg) -> list:
        """Pair one message; give the samples it completes without a reading to wait for."""
        stamp = messages.stamp_to_ns(msg.header.stamp)
        readings = self.readings
        if readings is not None and stream in readings.streams:
            readings.add_reading(stream, stamp, msg.temperature, msg)
            if stream in self.temperature_topics:
                self.last_temperature = time.monotonic()
            return []
        if stream == 'imu':
            self.last_imu = time.monotonic()
            if self.first_imu_ns is None:
                self.first_imu_ns = stamp
            if self.newest_imu_ns is None or stamp > self.newest_imu_ns:
                self.newest_imu_ns = stamp
            if self.without_temperature:
                return [(stamp, {'imu': msg})]
        elif stream in self.temperature_topics:
            self.last_temperature = time.monotonic()
        if stream not in self.pairer.streams:
            return []   # an auxiliary input, subscribed for an earlier model
        complete = self.pairer.add(stream, stamp, msg)
        if readings is None or self.without_temperature:
            return complete
        for sample_ns, parts in complete:
            readings.add_sample(sample_ns, parts)
        return []

    def _streams(self) -> tuple:
        return self.pairer.streams + (self.readings.streams if self.readings else ())

    def take(self, stream: str, msg, max_block: int) -> list:
        """
        Pair ``msg``, then what else waits on the inputs; give the samples now complete.

        Taking the waiting messages here, up to ``max_block`` in all, saves the
        executor a wake-up per message: that, not the model, limits a Python node's rate.
        """
        streams = self._streams()
        if stream not in streams:
            return []   # an auxiliary input, subscribed for an earlier model
        complete = self._add(stream, msg)
        budget = max_block - 1
        active = [(name, subscription) for name, subscription in self.subscriptions.items()
                  if name in streams]
        while budget > 0:
            taken = 0
            # In turns: a burst of rate must not use the budget up before the temperature
            # that goes with it is taken.
            turn = max(1, budget // max(1, len(active)))
            for name, subscription in active:
                for message in itertools.islice(waiting_messages(subscription),
                                                min(turn, budget)):
                    complete += self._add(name, message)
                    taken += 1
                    budget -= 1
            if not taken:
                break
        return complete + self._paired()

    def take_local(self, handoff: list) -> list:
        """Pair what a driver in this process sent, [(stream, msg)]; give the samples complete."""
        complete = []
        streams = self._streams()
        for stream, msg in handoff:
            # Auxiliary inputs subscribed over DDS come that way only.
            if stream in streams and stream not in self.subscriptions:
                complete += self._add(stream, msg)
        return complete + self._paired()

    def _temperature_came(self) -> bool:
        if self.readings is not None:
            return self.readings.has_readings(self.temperature_streams)
        return self.last_temperature is not None

    def _waited_in_vain(self) -> bool:
        """
        Tell whether the samples waited long enough for a first temperature.

        ``temperature.wait_s`` of stamps from the first sample when nothing publishes
        the temperature; ten times as long when a publisher is matched (its first
        reading may come behind a burst of samples that span seconds of stamps).
        """
        if self.first_imu_ns is None:
            return False
        waited_ns = self.newest_imu_ns - self.first_imu_ns
        if waited_ns < self.wait_ns:
            return False
        published = any(self.subscriptions[s].get_publisher_count()
                        for s in self.temperature_streams if s in self.subscriptions)
        return not published or waited_ns >= PUBLISHED_WAIT * self.wait_ns

    def _paired(self) -> list:
        """Give the samples the readings now decide; count those without a temperature."""
        came = self._temperature_came()
        if self.without_temperature:
            if came and self.pairing != 'none':
                self.without_temperature = False   # a temperature at last: paired from now on
            return []
        if not came and self._waited_in_vain():
            # No temperature within temperature.wait_s: the samples go on without one,
            # those more than max_age_s older than the newest counted as waiting first,
            # however the samples came in blocks.
            self.without_temperature = True
            self.pairer.clear()
            readings = self.readings
            if readings is None:
                return []
            before_first = readings.before_first
            readings.pop()
            self.samples_waiting += readings.before_first - before_first
            return readings.take_waiting()
        readings = self.readings
        if readings is None:
            return []
        before_first, lost = readings.before_first, readings.lost
        paired, unpaired = readings.pop()
        if unpaired:
            # Before the first reading: waited; own reading lost: dropped as by stamp.
            waited = readings.before_first - before_first
            self.samples_waiting += waited
            stale = len(unpaired) - waited - (readings.lost - lost)
            if stale:
                self.no_temperature_samples += stale
                self.no_temperature_recent = True
        samples = []
        for stamp, parts, got in paired:
            imu = parts['imu']
            for stream, reading in got.items():
                parts[stream] = paired_message(reading, imu)
                if reading.age_ns > self.temperature_stamp_age_ns:
                    self.temperature_stamp_age_ns = reading.age_ns
            samples.append((stamp, parts))
        return samples

    def has_temperature(self, parts: dict) -> bool:
        """Tell whether a sample carries its temperature (not when the driver sends none)."""
        return bool(self.temperature_streams) and \
            all(stream in parts for stream in self.temperature_streams)

    def runs(self, samples: list) -> list:
        """Split samples into runs with and without a temperature, in order: [(with, run)]."""
        return [(has, list(run)) for has, run in itertools.groupby(
            samples, key=lambda sample: self.has_temperature(sample[1]))]

    def block(self, samples: list, supply_max_age_s: float,
              model_inputs: bool = True) -> Optional[InputBlock]:
        """
        Give samples [(stamp_ns, {stream: message})] as a block; None if none is usable.

        Samples without the acceleration the model needs, or without a held
        supply voltage within ``supply_max_age_s``, are left out and counted;
        before the first voltage they wait (counted too). Without ``model_inputs``
        (no temperature model runs) neither is asked for. Samples without a
        temperature carry NaN.
        """
        needs_acceleration = self.needs_acceleration and model_inputs
        if needs_acceleration:
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
        if self.holds_supply and model_inputs:
            held_supply, samples = self._hold_supply(samples, int(supply_max_age_s * 1e9))
            if not samples:
                return None
        stamps_ns = [stamp for stamp, _ in samples]
        parts = [parts for _, parts in samples]
        columns = {AUXILIARY[name].field: [AUXILIARY[name].value(p[name]) for p in parts]
                   for name in self.auxiliary if not self.held(name)} if model_inputs else {}
        if held_supply is not None:
            columns[AUXILIARY[SUPPLY].field] = held_supply.tolist()
        if needs_acceleration:
            columns['acceleration_m_s2'] = [[p['imu'].linear_acceleration.x,
                                             p['imu'].linear_acceleration.y,
                                             p['imu'].linear_acceleration.z] for p in parts]
        columns['time_s'] = [stamp / 1e9 for stamp in stamps_ns]
        has_temperature = self.has_temperature(parts[0])
        streams = self.temperature_streams
        return InputBlock(
            stamps_ns=stamps_ns, messages=parts,
            raw_rad_s=[messages.imu_rates(p['imu'], self.indices) for p in parts],
            temperature_c=[[p[s].temperature for s in streams] for p in parts]
            if has_temperature else [[NAN] * max(len(streams), 1)] * len(parts),
            columns=columns, has_temperature=has_temperature)

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
