"""Tests of signal_hold: the controller's holds of the hand and of a(E, t) between messages."""

import numpy as np
import pytest

from hri_adaptive_controller.signal_hold import BlendedHold, HandHold, TaskWeightHold


def test_first_order_hold_runs_out_after_max_extrapolation():
    hold = BlendedHold(0.05)
    assert hold.evaluate(0.0) is None
    hold.offer(1.0, (0.2, -0.1), (1.0, 2.0))
    value, rate = hold.evaluate(1.02)
    assert value == pytest.approx((0.22, -0.06)) and rate == pytest.approx((1.0, 2.0))
    value, rate = hold.evaluate(1.5)
    assert value == pytest.approx((0.25, 0.0)) and rate == (0.0, 0.0)


def test_a_new_sample_is_blended_in_continuously_and_met_after_the_blend_time():
    hold = BlendedHold(1.0)
    hold.offer(0.0, (0.0,), (1.0,))
    assert hold.evaluate(0.1)[0] == pytest.approx((0.1,))
    # The new sample says 0.3 at 0.1 s, rising at 2 /s: 0.2 and 1 /s off the old hold.
    hold.offer(0.1, (0.3,), (2.0,), blend_time=0.05)
    value, rate = hold.evaluate(0.1)
    assert value == pytest.approx((0.1,)) and rate == pytest.approx((1.0,))
    times = np.arange(0.1, 0.2, 1e-4)
    values = np.array([hold.evaluate(t)[0][0] for t in times])
    assert np.max(np.abs(np.diff(values))) < 3.0 * 1e-4 * (2.0 + 15.0 / 8.0 * 0.2 / 0.05)
    after = times >= 0.15
    assert values[after] == pytest.approx(0.3 + 2.0 * (times[after] - 0.1))


def test_the_blend_rate_is_the_derivative_of_the_held_value():
    hold = BlendedHold(1.0)
    hold.offer(0.0, (0.5, 0.0), (0.0, 1.0))
    hold.evaluate(0.01)
    hold.offer(0.01, (0.6, 0.0), (-1.0, 0.5), blend_time=0.02)
    hold.evaluate(0.01)
    for t in (0.012, 0.02, 0.027):
        value, rate = hold.evaluate(t)
        ahead, _ = hold.evaluate(t + 1e-7)
        assert np.array(rate) == pytest.approx((np.array(ahead) - value) / 1e-7, abs=1e-4)


def test_pace_sets_the_least_blend_time_per_unit_of_offset():
    hold = BlendedHold(0.05, pace=1.0)
    hold.offer(0.0, (0.1,), (0.0,))
    hold.evaluate(0.0)
    hold.offer(0.3, (0.9,), (0.0,))  # 0.8 off after a 0.3 s gap: blended over 0.8 s
    assert hold.evaluate(0.3)[0] == pytest.approx((0.1,))
    assert 0.1 < hold.evaluate(0.7)[0][0] < 0.9
    assert hold.evaluate(1.1)[0] == pytest.approx((0.9,))


def test_hand_hold_blends_each_target_over_its_period_and_feeds_the_estimate_forward():
    hand = HandHold(0.05, 0.05)
    assert hand.evaluate(0.0) is None
    # A hand at 0.5 m/s sampled at 100 Hz: the estimate lags, the hold stays continuous.
    times = np.arange(0.0, 0.5, 1e-3)
    held = []
    for t in times:
        if round(t * 1e3) % 10 == 0:
            hand.offer((0.5 * t, 0.1), t)
        held.append(hand.evaluate(t))
    x = np.array([h[0][0] for h in held])
    assert np.max(np.abs(np.diff(x))) < 1.5e-3  # no jump of a message's worth (5 mm)
    assert x[-1] == pytest.approx(0.5 * times[-1], abs=2e-3)
    assert held[-1][1][0] == pytest.approx(0.5, abs=0.01)  # the estimate, not the blend
    hand.reset()
    assert hand.evaluate(1.0) is None


def test_task_weight_after_a_gap_moves_no_faster_than_the_pace():
    weights = TaskWeightHold(pace=1.0, max_extrapolation=0.05)
    assert weights.evaluate(0.0) is None
    weights.offer('follow', 'F', 0.0, 1.0, 0.0)
    assert weights.evaluate(0.01) == ('follow', 'F', 1.0, 0.0)
    # TaskStates of the fade-out stop at a = 0.35; the next says avoid at a = 0.97.
    weights.offer('follow', 'F', 0.10, 0.35, -5.9)
    times = np.arange(0.1, 2.0, 1e-3)
    path = []
    for t in times:
        if abs(t - 0.4) < 5e-4:
            weights.offer('avoid', 'A', 0.4, 0.97, 1.7)
        path.append(weights.evaluate(t))
    a = np.array([p[2] for p in path])
    tasks = [p[0] for p in path]
    assert np.all((a >= 0.0) & (a <= 1.0))
    # No step: at most the pace's peak rate (15/8 per s) plus the held ramp's own.
    assert np.max(np.abs(np.diff(a))) <= 1e-3 * (15.0 / 8.0 + 5.9)
    # follow is still in force (fading out) when the avoid TaskState comes, swaps at a = 0.
    swap = tasks.index('avoid')
    assert set(tasks[:swap]) == {'follow'} and a[swap - 1] < 2e-3 and a[swap] < 2e-3
    assert path[swap][1] == 'A' and a[-1] == 1.0
    # a's rate is its derivative (within the first-order hold's kinks).
    rates = np.array([p[3] for p in path])
    assert np.median(np.abs(np.gradient(a, 1e-3) - rates)) < 0.05


def test_task_weight_follows_a_ramp_sampled_on_time_without_lag():
    weights = TaskWeightHold(pace=1.0, max_extrapolation=0.05)
    ramp = 0.3
    for t in np.arange(0.0, 0.4, 1e-3):
        if round(t * 1e3) % 5 == 0:
            u = min(t / ramp, 1.0)
            weights.offer('follow', None, t, u ** 3 * (10 - 15 * u + 6 * u * u),
                          30 * u * u * (1 - u) ** 2 / ramp)
        _, _, a, _ = weights.evaluate(t)
        u = min(t / ramp, 1.0)
        assert a == pytest.approx(u ** 3 * (10 - 15 * u + 6 * u * u), abs=2e-3)


def test_task_weight_after_a_reset_is_taken_as_it_comes():
    weights = TaskWeightHold(pace=1.0, max_extrapolation=0.05)
    weights.offer('follow', 'F', 0.0, 1.0, 0.0)
    assert weights.evaluate(0.01)[2] == 1.0
    # Without a reset the new source's ramp from 0 is blended from the held 1 at the pace.
    weights.offer('follow', 'F', 3.0, 0.01, 0.9)
    assert weights.evaluate(3.0)[2] == pytest.approx(1.0)
    weights.reset()
    assert weights.evaluate(3.0) is None
    weights.offer('follow', 'F2', 3.0, 0.01, 0.9)
    assert weights.evaluate(3.0) == ('follow', 'F2', 0.01, 0.9)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match='max_extrapolation'):
        BlendedHold(-1.0)
    with pytest.raises(ValueError, match='pace'):
        BlendedHold(0.05, pace=float('nan'))
