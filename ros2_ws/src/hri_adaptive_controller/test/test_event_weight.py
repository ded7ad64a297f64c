"""Unit tests of hri_adaptive_controller.event_weight: the event weight a(E, t) of eq. 13."""

import numpy as np
import pytest

from hri_adaptive_controller.event_weight import (
    PHASE_ACTIVE,
    PHASE_FADING_IN,
    PHASE_FADING_OUT,
    PHASE_IDLE,
    SMOOTHSTEP_PEAK_SLOPE,
    EventWeightSchedule,
    quintic_smoothstep,
)

STEP = 1e-4  # s, grid of the smoothness checks


def trace(events, end, ramp_time=1.0, initial_task='A', step=STEP, min_ramp_time=None):
    """Evaluate a schedule on a grid, applying each (time, task) event at its own time.

    Returns the grid and arrays of weight, rate, acceleration, phase, active and pending task.
    """
    schedule = EventWeightSchedule(ramp_time, initial_task, min_ramp_time)
    times = np.arange(0.0, end, step)
    pending = sorted(events, key=lambda event: event[0])
    rows = []
    for t in times:
        while pending and pending[0][0] <= t:
            event_time, task = pending.pop(0)
            schedule.request(task, event_time)
        state = schedule.evaluate(t)
        rows.append((state.weight, state.rate, state.acceleration, state.phase,
                     state.active_task, state.pending_task))
    weight, rate, acceleration, phase, active, waiting = zip(*rows, strict=True)
    return (times, np.array(weight), np.array(rate), np.array(acceleration), np.array(phase),
            np.array(active, dtype=object), np.array(waiting, dtype=object))


SCENARIOS = {
    'switch': [(0.5, 'B')],
    'event_mid_fade_in': [(0.5, 'B'), (2.2, 'C')],
    'cancel_mid_fade_out': [(0.5, 'B'), (0.9, 'A')],
    'events_faster_than_ramp': [(0.5, 'B'), (0.55, 'A'), (0.6, 'C'), (0.65, 'A'), (0.7, 'B'),
                                (1.9, 'C'), (1.93, 'B'), (1.96, 'A')],
    'to_idle_and_back': [(0.5, None), (2.0, 'B')],
}


def test_quintic_smoothstep_values_and_derivatives():
    assert quintic_smoothstep(-1.0) == (0.0, 0.0, 0.0)
    assert quintic_smoothstep(2.0) == (1.0, 0.0, 0.0)
    value, slope, curvature = quintic_smoothstep(0.5)
    assert value == pytest.approx(0.5)
    assert slope == pytest.approx(SMOOTHSTEP_PEAK_SLOPE)
    assert curvature == pytest.approx(0.0, abs=1e-12)
    u = np.linspace(0.01, 0.99, 50)
    h = 1e-6
    for x in u:
        numeric = (quintic_smoothstep(x + h)[0] - quintic_smoothstep(x - h)[0]) / (2 * h)
        assert quintic_smoothstep(x)[1] == pytest.approx(numeric, rel=1e-6, abs=1e-8)
        numeric = (quintic_smoothstep(x + h)[1] - quintic_smoothstep(x - h)[1]) / (2 * h)
        assert quintic_smoothstep(x)[2] == pytest.approx(numeric, rel=1e-6, abs=1e-6)


def test_initial_states():
    active = EventWeightSchedule(1.0, 'A').evaluate(0.0)
    assert (active.weight, active.rate, active.phase, active.active_task) == (
        1.0, 0.0, PHASE_ACTIVE, 'A')
    idle = EventWeightSchedule(1.0).evaluate(0.0)
    assert (idle.weight, idle.phase, idle.active_task) == (0.0, PHASE_IDLE, None)


def test_full_switch_follows_eq_13():
    times, weight, rate, _, phase, active, waiting = trace([(1.0, 'B')], 3.5, ramp_time=1.0)
    at = {t: i for i, t in enumerate(np.round(times, 6))}
    # f_dec: 1 -> 0 over ramp_time, the task swapped at a = 0, then f_inc: 0 -> 1.
    i = at[1.5]
    assert (phase[i], active[i], waiting[i]) == (PHASE_FADING_OUT, 'A', 'B')
    assert weight[i] == pytest.approx(0.5)
    assert rate[i] == pytest.approx(-SMOOTHSTEP_PEAK_SLOPE)
    i = at[2.5]
    assert (phase[i], active[i], waiting[i]) == (PHASE_FADING_IN, 'B', None)
    assert weight[i] == pytest.approx(0.5)
    i = at[3.0]
    assert (phase[i], active[i], weight[i], rate[i]) == (PHASE_ACTIVE, 'B', 1.0, 0.0)
    assert np.all(weight[np.abs(times - 2.0) < 2.5e-4] < 1e-9)
    assert np.max(np.abs(rate)) <= SMOOTHSTEP_PEAK_SLOPE / 1.0 + 1e-12


@pytest.mark.parametrize('name', sorted(SCENARIOS))
def test_weight_is_c2_and_in_unit_interval(name):
    times, weight, rate, acceleration, *_ = trace(SCENARIOS[name], 5.0)
    assert np.all(np.isfinite(weight)) and np.all((weight >= 0.0) & (weight <= 1.0))
    # The reported derivatives are those of the weight (a clipped overshoot would break this).
    numeric_rate = (weight[2:] - weight[:-2]) / (2 * STEP)
    assert np.max(np.abs(numeric_rate - rate[1:-1])) < 1e-4
    numeric_acceleration = (rate[2:] - rate[:-2]) / (2 * STEP)
    assert np.max(np.abs(numeric_acceleration - acceleration[1:-1])) < 0.2
    # No jump in a, da/dt or d2a/dt2 anywhere: increments shrink with the step (C2).
    assert np.max(np.abs(np.diff(weight))) < 4.0 * STEP
    assert np.max(np.abs(np.diff(rate))) < 50.0 * STEP
    assert np.max(np.abs(np.diff(acceleration))) < 3000.0 * STEP


def test_event_mid_ramp_continues_from_the_current_state():
    schedule = EventWeightSchedule(1.0, 'A')
    schedule.request('B', 0.0)
    schedule.evaluate(1.3)  # fading in to B
    event_time = 1.4
    before = schedule.evaluate(event_time - 1e-9)
    after = schedule.request('C', event_time)
    assert before.phase == PHASE_FADING_IN and after.phase == PHASE_FADING_OUT
    assert (after.active_task, after.pending_task) == ('B', 'C')
    assert after.weight == pytest.approx(before.weight, abs=1e-8)
    assert after.rate == pytest.approx(before.rate, abs=1e-6)
    assert after.acceleration == pytest.approx(before.acceleration, abs=1e-4)
    assert before.rate > 0.5  # it was really mid-ramp


def test_event_during_fade_in_fades_out_then_swaps_to_latest_task():
    times, weight, _, _, phase, active, _ = trace([(0.5, 'B'), (2.2, 'C')], 6.0)
    assert active[-1] == 'C' and phase[-1] == PHASE_ACTIVE and weight[-1] == 1.0
    assert 'B' in set(active) and set(active) == {'A', 'B', 'C'}
    # The fade-out from B starts where the fade-in was, and lasts max(ramp_time a, min).
    start = np.searchsorted(times, 2.2)
    swap = np.argmax(active == 'C')
    expected = max(1.0 * weight[start], 0.5)
    assert times[swap] - 2.2 == pytest.approx(expected, abs=2e-3)


def test_event_while_fading_out_only_changes_pending_task():
    _, weight_one, rate_one, _, _, active_one, _ = trace([(0.5, 'B')], 3.0)
    _, weight_two, rate_two, _, _, active_two, waiting = trace([(0.5, 'B'), (0.8, 'C')], 3.0)
    np.testing.assert_array_equal(weight_one, weight_two)
    np.testing.assert_array_equal(rate_one, rate_two)
    assert 'B' not in set(active_two) and active_two[-1] == 'C'
    assert 'C' in set(waiting)


def test_event_naming_the_active_task_does_nothing():
    schedule = EventWeightSchedule(1.0, 'A')
    schedule.evaluate(0.2)
    state = schedule.request('A', 0.3)
    assert (state.weight, state.rate, state.phase, state.pending_task) == (
        1.0, 0.0, PHASE_ACTIVE, None)
    schedule.request('B', 1.0)
    schedule.evaluate(2.5)  # fading in to B
    state = schedule.request('B', 2.6)
    assert state.phase == PHASE_FADING_IN and state.pending_task is None
    assert schedule.evaluate(3.0).phase == PHASE_ACTIVE


def test_request_for_the_fading_task_cancels_the_swap():
    times, weight, _, _, phase, active, _ = trace([(0.5, 'B'), (0.9, 'A')], 3.0)
    assert set(active) == {'A'}
    assert phase[-1] == PHASE_ACTIVE and weight[-1] == 1.0
    assert np.min(weight) > 0.5  # it turned back before reaching 0


def test_no_task_fades_out_to_idle_and_a_task_fades_in_again():
    times, weight, _, _, phase, active, _ = trace([(0.5, None), (2.0, 'B')], 3.5)
    idle = phase == PHASE_IDLE
    assert np.any(idle) and np.all(weight[idle] == 0.0)
    assert all(task is None for task in active[idle])
    assert phase[-1] == PHASE_ACTIVE and active[-1] == 'B'


def test_partial_ramp_is_shorter_but_not_shorter_than_minimum():
    schedule = EventWeightSchedule(2.0, 'A', min_ramp_time=0.4)
    schedule.request('B', 0.0)
    schedule.evaluate(2.0)  # swapped, fade-in to B starts
    state = schedule.request('C', 2.1)  # a small: the fade-out takes min_ramp_time
    assert state.weight < 0.01
    assert schedule.evaluate(2.1 + 0.4 - 1e-6).active_task == 'B'
    assert schedule.evaluate(2.1 + 0.4 + 1e-6).active_task == 'C'


def test_rate_bound_for_random_event_sequences():
    rng = np.random.default_rng(7)
    ramp_time = 0.8
    worst = 0.0
    for _ in range(40):
        gaps = rng.uniform(0.01, 1.0, size=8) * ramp_time
        tasks = rng.choice(np.array(['A', 'B', 'C', None], dtype=object), size=8)
        events = list(zip(np.cumsum(gaps), tasks, strict=True))
        _, weight, rate, *_ = trace(events, float(np.sum(gaps)) + 2.5 * ramp_time,
                                    ramp_time=ramp_time, step=1e-3)
        assert np.all((weight >= 0.0) & (weight <= 1.0))
        worst = max(worst, float(np.max(np.abs(rate))))
    # Documented bound: 2 * 15 / (8 ramp_time) with the default min_ramp_time.
    assert worst <= 2.0 * SMOOTHSTEP_PEAK_SLOPE / ramp_time


@pytest.mark.parametrize(('kwargs', 'match'), [
    ({'ramp_time': 0.0}, 'ramp_time'),
    ({'ramp_time': float('nan')}, 'ramp_time'),
    ({'ramp_time': 1.0, 'min_ramp_time': 2.0}, 'min_ramp_time'),
    ({'ramp_time': 1.0, 'min_ramp_time': 0.0}, 'min_ramp_time'),
])
def test_bad_settings_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        EventWeightSchedule(**kwargs)


def test_time_must_not_go_backwards():
    schedule = EventWeightSchedule(1.0, 'A')
    schedule.evaluate(5.0)
    with pytest.raises(ValueError, match='backwards'):
        schedule.evaluate(4.0)
    with pytest.raises(ValueError, match='finite'):
        schedule.request('B', float('inf'))
