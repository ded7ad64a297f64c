"""read_together: the other clock's reading comes with the monotonic time around it."""

import itertools

import pytest

from hri_core.paired_clocks import read_together


def test_a_read_without_preemption_is_taken_at_once():
    monotonic = iter([10.0, 10.00001]).__next__
    readings = iter(['stamp']).__next__
    assert read_together(monotonic, readings) == (pytest.approx(10.000005), 'stamp')


def test_a_preempted_read_is_taken_again():
    # The first pair is 5 ms apart (preempted between the reads), the second is tight.
    monotonic = iter([1.0, 1.005, 1.006, 1.00601]).__next__
    readings = iter(['late', 'good']).__next__
    assert read_together(monotonic, readings) == (pytest.approx(1.006005), 'good')


def test_without_a_tight_pair_the_closest_of_the_attempts_wins():
    spreads = [0.01, 0.002, 0.03]
    times = []
    start = 0.0
    for spread in spreads:
        times += [start, start + spread]
        start += 1.0
    monotonic = iter(times).__next__
    readings = itertools.count().__next__
    assert read_together(monotonic, readings, attempts=3) == (pytest.approx(1.001), 1)


@pytest.mark.parametrize(('tolerance', 'attempts', 'message'), [
    (-1e-3, 5, 'tolerance must be >= 0'),
    (float('nan'), 5, 'tolerance must be >= 0'),
    (1e-4, 0, 'attempts must be >= 1'),
])
def test_bad_settings_are_refused(tolerance, attempts, message):
    with pytest.raises(ValueError, match=message):
        read_together(lambda: 0.0, lambda: 0, tolerance, attempts)
