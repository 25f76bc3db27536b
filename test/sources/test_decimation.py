"""Decimator: device samples into publish intervals, each sample once, means and mean times."""

from dataclasses import replace

from mlx_tempcomp.sources.adis16130 import Sample
from mlx_tempcomp.sources.decimation import Decimator, mean_sample
import numpy as np
import pytest


def sample(index: int) -> Sample:
    return Sample(time_s=index / 5700.0, rate_rad_s=np.array([float(index)]),
                  temperature_c=np.array([20.0 + index]), saturated=False)


def test_every_sample_lands_in_exactly_one_interval_in_order():
    decimator = Decimator(5700.0, 1000.0)
    intervals = []
    for index in range(5700):
        closed = decimator.add(index, sample(index))
        if closed is not None:
            intervals.append(closed)
    intervals.append(decimator.close_before(5700))
    assert [i.number for i in intervals] == list(range(1000))
    # 5.7 samples per interval: 5 or 6, 5700 in all, none twice, none skipped.
    assert {i.samples for i in intervals} == {5, 6}
    assert sum(i.samples for i in intervals) == 5700
    assert [i.first_index for i in intervals[1:]] == [i.last_index + 1 for i in intervals[:-1]]
    for interval in intervals:
        indices = np.arange(interval.first_index, interval.last_index + 1)
        # Interval j holds the samples taken in [j, j + 1) ms.
        assert np.all(np.floor(indices / 5.7 + 1e-9) == interval.number)
        assert interval.mean.rate_rad_s[0] == pytest.approx(indices.mean())
        assert interval.time_s == pytest.approx(indices.mean() / 5700.0)


def test_missing_samples_leave_their_interval_short_and_close_it_in_time():
    decimator = Decimator(1000.0, 100.0)
    for index in (0, 1, 2, 7):               # 3 .. 6 and 8, 9 never read
        assert decimator.add(index, sample(index)) is None
    assert decimator.close_before(9) is None  # sample 9 still belongs to interval 0
    closed = decimator.close_before(10)
    assert closed.samples == 4 and closed.mean.rate_rad_s[0] == pytest.approx(2.5)
    assert decimator.close_before(10) is None


def test_mean_sample_averages_numbers_and_ors_flags():
    first, second = sample(1), replace(sample(3), saturated=True)
    mean = mean_sample([first, second])
    assert mean.rate_rad_s[0] == 2.0 and mean.temperature_c[0] == 22.0
    assert mean.saturated is True and mean.time_s == pytest.approx(2.0 / 5700.0)
    assert mean_sample([first]) is first


def test_sampling_slower_than_publishing_is_refused():
    with pytest.raises(ValueError, match='must be at least the publish rate'):
        Decimator(50.0, 100.0)
