"""Property tests of hri_adaptive_controller.event_weight: for any sequence of events the
weight a(E, t) of eq. 13 stays in [0, 1] and is twice continuously differentiable."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hri_adaptive_controller.event_weight import EventWeightSchedule

GRID_POINTS_PER_MIN_RAMP = 200

tasks = st.sampled_from(('A', 'B', 'C', None))


@st.composite
def event_sequences(draw):
    """(ramp_time s, min_ramp_time s, initial task, [(time s, task)]); gaps may be 0 (two
    events at one instant) and are at most 1.5 ramp_time."""
    ramp_time = draw(st.floats(0.1, 2.0))
    min_ramp_time = ramp_time * draw(st.floats(0.25, 1.0))
    gaps = draw(st.lists(st.one_of(st.just(0.0), st.floats(0.0, 1.5)), min_size=1,
                         max_size=8))
    times = np.cumsum(np.array(gaps) * ramp_time) + 0.1
    events = [(float(t), draw(tasks)) for t in times]
    return ramp_time, min_ramp_time, draw(tasks), events


def state_tuple(state):
    return state.weight, state.rate, state.acceleration


@settings(max_examples=60)
@given(case=event_sequences())
def test_weight_stays_in_the_unit_interval_and_is_c2(case):
    ramp_time, min_ramp_time, initial, events = case
    schedule = EventWeightSchedule(ramp_time, initial, min_ramp_time)
    step = min_ramp_time / GRID_POINTS_PER_MIN_RAMP
    end = events[-1][0] + 3.0 * ramp_time
    # Scales of one ramp of the shortest duration T: |a'| <= 15/8 / T, |a''| <= 5.78 / T^2,
    # |a'''| <= 60 / T^3.
    rate_scale = 2.0 / min_ramp_time
    acceleration_scale = 6.0 / min_ramp_time ** 2
    jerk_scale = 60.0 / min_ramp_time ** 3
    pending = list(events)
    samples = []
    for t in np.arange(0.0, end, step):
        while pending and pending[0][0] <= t:
            event_time, task = pending.pop(0)
            before = state_tuple(schedule.evaluate(event_time))
            after = state_tuple(schedule.request(task, event_time))
            # No jump in a, da/dt or d2a/dt2 at an event.
            assert math.isclose(before[0], after[0], abs_tol=1e-12)
            assert math.isclose(before[1], after[1], abs_tol=1e-9 * rate_scale)
            assert math.isclose(before[2], after[2], abs_tol=1e-9 * acceleration_scale)
        samples.append(state_tuple(schedule.evaluate(float(t))))
    weight, rate, acceleration = np.array(samples).T
    assert np.all(np.isfinite(samples))
    assert np.all((weight >= 0.0) & (weight <= 1.0))
    # The reported derivatives are those of the weight, with no jump anywhere in between: a
    # jump of D leaves the central difference off by D / 2 at that sample, while a C2 weight
    # whose jerk flips sign (as at a swap, -J to +J) leaves it off by at most 2 J h / 4.
    numeric_rate = (weight[2:] - weight[:-2]) / (2.0 * step)
    numeric_acceleration = (rate[2:] - rate[:-2]) / (2.0 * step)
    assert np.max(np.abs(numeric_rate - rate[1:-1])) <= 1e-3 * rate_scale
    assert np.max(np.abs(numeric_acceleration - acceleration[1:-1])) <= jerk_scale * step
    # Every schedule comes to rest: a ramp ends with zero rate and acceleration.
    assert rate[-1] == 0.0 and acceleration[-1] == 0.0
