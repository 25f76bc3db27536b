"""
ReadingPairer on plain numbers: temperature readings held or interpolated for rate samples.

Each test builds the arrival order of samples and readings from their stamps (a
driver's rate at one rate, its temperature at another, on stamps of its own,
maybe late) and checks what each sample got and when it was decided, counted in
arrivals, never in time.
"""

import math

from mlx_tempcomp.core.series.pairing import APART, ReadingPairer, SHARED
import pytest

S = 1_000_000_000     # ns per second
MS = 1_000_000


def temperature_at(stamp_ns: int) -> float:
    """Give a temperature ramp: 20 C plus 0.1 C/s, so held and interpolated values differ."""
    return 20.0 + 0.1 * stamp_ns / S


def arrivals(sample_period_ns: int, reading_period_ns: int, duration_ns: int,
             reading_offset_ns: int = 0, reading_delay_ns: int = 0, readings_until_ns=None):
    """
    Give the events of a driver in arrival order: ('sample', stamp) and ('reading', stamp).

    Readings are stamped at ``reading_offset_ns`` + k x period and arrive
    ``reading_delay_ns`` after their stamp, i.e. just after the sample of that time;
    none is stamped after ``readings_until_ns``.
    """
    events = [(stamp, 1, ('sample', stamp)) for stamp in range(0, duration_ns, sample_period_ns)]
    stamp = reading_offset_ns
    while stamp < duration_ns and (readings_until_ns is None or stamp <= readings_until_ns):
        events.append((stamp + reading_delay_ns, 2, ('reading', stamp)))
        stamp += reading_period_ns
    return Events(event for _, _, event in sorted(events))


class Events(list):
    """Events with their arrival index looked up in constant time."""

    def index(self, event) -> int:
        if not hasattr(self, 'position'):
            self.position = {e: i for i, e in enumerate(self)}
        return self.position[event]


def run(pairer: ReadingPairer, events, stream: str = 'temperature') -> dict:
    """Feed ``events`` one by one; give {sample stamp: (deciding arrival, reading or None)}."""
    decided = {}
    for index, (kind, stamp) in enumerate(events):
        if kind == 'sample':
            pairer.add_sample(stamp, stamp)
        else:
            pairer.add_reading(stream, stamp, temperature_at(stamp), payload=('msg', stamp))
        paired, unpaired = pairer.pop()
        order = [s for s, *_ in paired] + [s for s, _ in unpaired]
        assert not set(order) & set(decided), 'a sample decided twice'
        for stamp_ns, sample, readings in paired:
            assert sample == stamp_ns
            decided[stamp_ns] = (index, readings[stream])
        for stamp_ns, _ in unpaired:
            decided[stamp_ns] = (index, None)
    return decided


def arrival_index(events, stamp: int) -> int:
    return events.index(('sample', stamp))


def latest_before(stamp: int, readings) -> int:
    return max(r for r in readings if r <= stamp)


@pytest.mark.parametrize('sample_hz, reading_hz', [(100, 1), (1000, 10)])
def test_hold_pairs_every_sample_at_once_with_the_latest_reading(sample_hz, reading_hz):
    period, reading_period = S // sample_hz, S // reading_hz
    offset = 370 * MS % reading_period + 1   # stamps of its own, never a sample's
    events = arrivals(period, reading_period, 2000 * period, reading_offset_ns=offset)
    readings = [stamp for kind, stamp in events if kind == 'reading']
    pairer = ReadingPairer(('temperature',), interpolate=False, max_age_ns=2 * S)
    decided = run(pairer, events)
    samples = [stamp for kind, stamp in events if kind == 'sample']
    assert len(decided) == len(samples)
    for stamp in samples:
        index, reading = decided[stamp]
        if stamp < readings[0]:
            # Nothing measured before the first reading: unpaired once it came.
            assert reading is None and index == events.index(('reading', readings[0]))
            continue
        assert reading is not None, stamp
        held = latest_before(stamp, readings)
        assert reading.value == temperature_at(held)
        assert not reading.exact and reading.age_ns == stamp - held
        assert reading.age_ns < reading_period
        if stamp < readings[1]:
            # At start it is not known yet how the streams stamp: a sample waits for a
            # reading of its own stamp until the next reading shows there is none, once.
            assert index == events.index(('reading', readings[1]))
        else:
            assert index == arrival_index(events, stamp), 'a sample waited for a reading'
    assert pairer.stamps == APART


@pytest.mark.parametrize('sample_hz, reading_hz', [(100, 1), (1000, 10)])
def test_interpolate_waits_for_the_next_reading_and_interpolates(sample_hz, reading_hz):
    period, reading_period = S // sample_hz, S // reading_hz
    offset = reading_period // 3 + 1
    events = arrivals(period, reading_period, 2000 * period, reading_offset_ns=offset)
    readings = [stamp for kind, stamp in events if kind == 'reading']
    pairer = ReadingPairer(('temperature',), interpolate=True, max_age_ns=2 * S)
    decided = run(pairer, events)
    for stamp in (s for kind, s in events if kind == 'sample'):
        if stamp > readings[-1]:
            assert stamp not in decided, 'decided without the reading after it'
            continue
        index, reading = decided[stamp]
        if stamp < readings[0]:
            assert reading is None
            continue
        before = latest_before(stamp, readings)
        after = min(r for r in readings if r >= stamp)
        assert index == events.index(('reading', after)), 'not decided when the reading came'
        assert reading.value == pytest.approx(temperature_at(stamp), abs=1e-12)
        assert reading.age_ns == max(stamp - before, after - stamp)
    assert pairer.waiting == sum(1 for kind, s in events if kind == 'sample' and s > readings[-1])


def test_readings_half_a_second_late():
    """A 1 Hz temperature arriving 0.5 s after its stamp: held at once, interpolated later."""
    events = arrivals(S // 100, S, 30 * S, reading_offset_ns=S // 4, reading_delay_ns=S // 2)
    readings = [stamp for kind, stamp in events if kind == 'reading']
    samples = [stamp for kind, stamp in events if kind == 'sample']
    held = run(ReadingPairer(('temperature',), False, 2 * S), events)
    for stamp in samples:
        index, reading = held[stamp]
        assert (reading is None) == (stamp < readings[0])
        if stamp > readings[1] + S // 2:
            assert index == arrival_index(events, stamp), 'held back'
            # The latest reading that had arrived: up to 1.5 s old.
            arrived = [r for r in readings if r + S // 2 < stamp]
            assert reading.value == temperature_at(max(arrived))
            assert reading.age_ns <= 3 * S // 2
    interpolated = run(ReadingPairer(('temperature',), True, 2 * S), events)
    for stamp in samples:
        if readings[0] <= stamp <= readings[-1]:
            index, reading = interpolated[stamp]
            after = min(r for r in readings if r >= stamp)
            assert index == events.index(('reading', after))
            assert reading.value == pytest.approx(temperature_at(stamp), abs=1e-12)


@pytest.mark.parametrize('interpolate', [False, True], ids=['hold', 'interpolate'])
def test_readings_that_stop(interpolate):
    """The temperature stops at 10 s: paired within the age, then unpaired and counted."""
    events = arrivals(S // 100, S, 20 * S, reading_offset_ns=S // 2,
                      readings_until_ns=10 * S)
    last = 10 * S + S // 2 - S   # the last reading's stamp: 9.5 s
    pairer = ReadingPairer(('temperature',), interpolate, 2 * S)
    decided = run(pairer, events)
    samples = [stamp for kind, stamp in events if kind == 'sample']
    for stamp in samples:
        if stamp < S // 2:
            assert decided[stamp][1] is None   # before the first reading
        elif stamp <= last:
            assert decided[stamp][1] is not None
        elif interpolate or stamp - last > 2 * S:
            if stamp < samples[-1] - 2 * S:
                assert decided[stamp][1] is None, stamp
        else:
            assert decided[stamp][1].value == temperature_at(last)
    unpaired = [s for s, (_, r) in decided.items() if r is None and s > S // 2]
    assert pairer.unpaired == len(unpaired) + pairer.before_first
    assert pairer.before_first == S // 2 // (S // 100)   # the samples before 0.5 s
    # Unpaired: held, at once; interpolated, once samples 2 s later came, no later.
    for stamp in unpaired:
        index, _ = decided[stamp]
        assert index == arrival_index(events, stamp + 2 * S + S // 100 if interpolate else stamp)


def test_a_driver_stamping_both_alike_is_paired_exactly_whatever_comes_first():
    """Equal stamps, the temperature after its sample: each waits for its own, as by stamp."""
    stamps = [k * S // 100 for k in range(300)]
    events = Events()
    for stamp in stamps:
        events += [('sample', stamp), ('reading', stamp)]
    lost = stamps[150]
    events.remove(('reading', lost))
    pairer = ReadingPairer(('temperature',), False, 2 * S)
    decided = run(pairer, events)
    for stamp in stamps:
        index, reading = decided[stamp]
        if stamp == lost:
            # Lost: unpaired, as exact pairing drops it, once the next one showed it is.
            assert reading is None
            assert index == events.index(('reading', stamps[151]))
            continue
        assert reading.exact and reading.payload == ('msg', stamp)
        assert reading.value == temperature_at(stamp)
        assert index == events.index(('reading', stamp))
    assert pairer.stamps == SHARED and pairer.lost == pairer.unpaired == 1


def test_a_slow_temperature_stamped_like_every_hundredth_sample_does_not_hold_the_rate_back():
    events = arrivals(S // 100, S, 20 * S)   # readings at whole seconds, a sample's stamp too
    pairer = ReadingPairer(('temperature',), False, 2 * S)
    decided = run(pairer, events)
    late = [stamp for stamp, (index, _) in decided.items()
            if index != arrival_index(events, stamp) and stamp % S]
    # Presumed to share stamps at start: the first second's samples wait for the second
    # reading, then the pairer knows better.
    assert late and max(late) < S
    # Afterwards each is decided with what has come: a sample at a whole second comes just
    # before its reading, and is held with the one before.
    assert all(decided[stamp][1].value == temperature_at(stamp - S)
               for stamp in decided if stamp % S == 0 and stamp > S)
    assert pairer.stamps == APART


def test_several_streams_each_paired():
    pairer = ReadingPairer(('x', 'y'), interpolate=True, max_age_ns=2 * S)
    pairer.add_reading('x', 0, 10.0)
    pairer.add_reading('y', S // 2, 20.0)
    pairer.add_sample(S, 'a')
    assert pairer.pop() == ([], [])
    pairer.add_reading('x', 2 * S, 12.0)
    assert pairer.pop() == ([], [])    # y has no reading after it yet
    pairer.add_reading('y', 3 * S // 2, 22.0)
    (stamp, sample, readings), = pairer.pop()[0]
    assert (stamp, sample) == (S, 'a')
    assert readings['x'].value == 11.0 and readings['y'].value == 21.0
    assert readings['x'].age_ns == S and readings['y'].age_ns == S // 2


def test_late_samples_and_readings_slot_in_by_stamp():
    pairer = ReadingPairer(('t',), interpolate=False, max_age_ns=5 * S)
    for stamp, value in ((0, 1.0), (2 * S, 3.0), (S, 2.0)):
        pairer.add_reading('t', stamp, value)
    pairer.add_reading('t', S, 2.5)   # the same stamp again replaces
    pairer.stamps = APART
    for stamp in (3 * S // 2, S // 2):
        pairer.add_sample(stamp, stamp)
    paired, unpaired = pairer.pop()
    assert [(s, r['t'].value) for s, _, r in paired] == [(S // 2, 1.0), (3 * S // 2, 2.5)]
    assert unpaired == []


def test_samples_before_any_reading_wait_within_the_age_then_count_apart():
    pairer = ReadingPairer(('t',), interpolate=False, max_age_ns=S)
    for k in range(30):
        pairer.add_sample(k * S // 10, k)
    paired, unpaired = pairer.pop()
    # 0.0 to 1.8 s are more than 1 s older than the newest (2.9 s): no reading can come late
    # enough for them.
    assert paired == [] and [s for _, s in unpaired] == list(range(19))
    assert pairer.before_first == 19 and pairer.waiting == 11
    pairer.add_reading('t', 5 * S // 2, 7.0)
    paired, unpaired = pairer.pop()
    # Stamped before the first reading (2.5 s): nothing measured then.
    assert [s for _, s in unpaired] == list(range(19, 25))
    assert pairer.before_first == 25
    # 2.5 s is its own; the others wait to see whether the streams share stamps.
    assert [s for _, s, _ in paired] == [25] and pairer.waiting == 4


def test_the_waiting_samples_are_bounded():
    pairer = ReadingPairer(('t',), interpolate=True, max_age_ns=10 ** 18, capacity=100)
    for k in range(150):
        pairer.add_sample(k, k)
    paired, unpaired = pairer.pop()
    assert len(unpaired) == 50 and pairer.waiting == 100
    assert math.isclose(pairer.unpaired, 50)


def shared_stamps(pairer: ReadingPairer, stamps, lost=()) -> dict:
    """Feed samples and readings stamped alike, each reading after its sample, some lost."""
    decided = {}
    for stamp in stamps:
        pairer.add_sample(stamp, stamp)
        if stamp not in lost:
            pairer.add_reading('t', stamp, temperature_at(stamp))
        paired, unpaired = pairer.pop()
        decided.update({s: r['t'] for s, _, r in paired})
        decided.update({s: None for s, _ in unpaired})
    return decided


def test_shared_stamps_survive_readings_lost_now_and_then():
    """Best effort loses a reading now and then: those samples drop, the rest stay exact."""
    stamps = [k * S // 100 for k in range(200)]
    lost = set(stamps[50:70]) | {stamps[100]}
    pairer = ReadingPairer(('t',), interpolate=False, max_age_ns=2 * S)
    decided = shared_stamps(pairer, stamps, lost)
    assert pairer.stamps == SHARED
    assert [s for s, r in decided.items() if r is None] == sorted(lost)
    assert all(r.exact for r in decided.values() if r is not None)
    assert pairer.lost == len(lost)


def test_shared_stamps_end_when_readings_stop_coming_with_every_sample():
    """Half the last samples without their own (a slower temperature now): apart, held."""
    stamps = [k * S // 100 for k in range(400)]
    pairer = ReadingPairer(('t',), interpolate=False, max_age_ns=2 * S)
    shared_stamps(pairer, stamps[:200])
    assert pairer.stamps == SHARED
    # From now on a reading with every tenth sample only: half a second dropped.
    decided = shared_stamps(pairer, stamps[200:], lost=set(stamps[200:]) - set(stamps[200::10]))
    assert pairer.stamps == APART
    assert 0 < pairer.lost <= 50
    assert all(decided[s] is not None for s in stamps[260:])


def test_a_temperature_matched_late_drops_the_samples_before_it_then_pairs_exactly():
    """A temperature subscription matched later than the rate's: dropped as by stamp."""
    stamps = [k * S // 100 for k in range(20)]
    pairer = ReadingPairer(('t',), interpolate=False, max_age_ns=2 * S)
    for stamp in stamps[:10]:
        pairer.add_sample(stamp, stamp)
    assert pairer.pop() == ([], [])
    decided = shared_stamps(pairer, stamps[10:])
    assert all(decided[s] is None for s in stamps[:10]) and pairer.before_first == 10
    assert all(decided[s].exact for s in stamps[10:])
    assert pairer.stamps == SHARED


def test_streams_change_and_waiting_samples_are_taken():
    pairer = ReadingPairer(('a',), interpolate=False, max_age_ns=S)
    pairer.add_reading('a', 0, 1.0)
    assert pairer.has_readings()
    pairer.set_streams(('a', 'b'))
    assert not pairer.has_readings() and pairer.has_readings(('a',))
    pairer.add_sample(S // 2, 'x')
    assert pairer.pop() == ([], []) and pairer.waiting == 1   # b has no reading yet
    assert pairer.take_waiting() == [(S // 2, 'x')] and pairer.waiting == 0


def test_shared_stamps_that_stop_are_dropped_as_by_stamp_then_held_then_unpaired():
    stamps = [k * S // 100 for k in range(800)]
    pairer = ReadingPairer(('t',), interpolate=False, max_age_ns=2 * S, shared_wait_ns=3 * S)
    decided = shared_stamps(pairer, stamps[:300], lost=set(stamps[100:]))
    last = stamps[99]
    # Each waits for its own, as pairing by stamp does, up to 3 s of later samples...
    assert pairer.waiting == 200 and pairer.waiting_ns == stamps[299] - stamps[100]
    assert pairer.stamps == SHARED and all(s not in decided for s in stamps[100:])
    decided.update(shared_stamps(pairer, stamps[300:], lost=set(stamps)))
    # ... then it is dropped, until half the last samples are: then apart, held within the
    # age, then none.
    dropped = [s for s in stamps[100:] if decided[s] is None and s - last <= 2 * S]
    assert 0 < len(dropped) == pairer.lost <= 50 and pairer.stamps == APART
    held = [s for s in stamps[100:] if decided[s]]
    assert held and all(decided[s].value == temperature_at(last) for s in held)
    assert all(decided[s] is None for s in stamps[100:] if s - last > 2 * S)
    assert pairer.waiting == 0
