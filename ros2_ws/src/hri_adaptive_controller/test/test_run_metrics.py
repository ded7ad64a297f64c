"""Unit tests of run_metrics: time to region, steady distance, torque peaks, take figures."""

import math
from pathlib import Path

import numpy as np
import pytest

from hri_adaptive_controller.run_metrics import (
    TakeCriteria,
    considered_samples,
    hand_speed,
    in_region,
    largest_effort_step,
    longest_high_effort_hold,
    run_metrics,
    steady_distance,
    take_metrics,
    time_to_region,
)
from hri_core.recorded_motion import ReachAnnulus, read_vicon_csv

TAKES = Path(__file__).resolve().parents[4] / 'data' / 'human-motion'
CRITERIA = TakeCriteria(d1=0.183, effort_limit=20.0, task_speed=0.25,
                        reach=ReachAnnulus(0.222, 0.65))


def approach_run(seed: int = 3):
    """A distance that decays from 0.3 m to 0.02 m (time constant 1 s) with sensor noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, 0.01)
    distance = 0.02 + 0.28 * np.exp(-t) + rng.normal(0.0, 1e-4, t.size)
    tau = np.column_stack([np.exp(-t), -0.5 * np.exp(-t)]) * 4.0
    return t, distance, tau


def test_time_to_region_is_the_last_entry():
    t, distance, _ = approach_run()
    # 0.02 + 0.28 e^-t = 0.041  ->  t = ln(0.28 / 0.021) = 2.590 s
    assert time_to_region(t, distance, 0.0, 0.041) == pytest.approx(2.59, abs=0.05)


def test_leaving_the_region_again_resets_the_entry_time():
    t = np.arange(0.0, 6.0, 0.5)
    distance = np.array([0.3, 0.1, 0.03, 0.03, 0.2, 0.2, 0.03, 0.03, 0.03, 0.03, 0.03, 0.03])
    assert time_to_region(t, distance, 0.0, 0.041) == pytest.approx(3.0)
    assert time_to_region(t, distance, 0.0, 0.041, start=1.0) == pytest.approx(2.0)


def test_never_settling_in_the_region_gives_none():
    t = np.linspace(0.0, 5.0, 51)
    assert time_to_region(t, np.full(51, 0.1), 0.183, 2.0) is None


def test_in_region_with_tolerance():
    mask = in_region([0.17, 0.18, 0.25, 0.28], 0.183, 0.271, tolerance=0.005)
    assert mask.tolist() == [False, True, True, False]


def test_run_metrics_of_an_approach():
    t, distance, tau = approach_run()
    metrics = run_metrics(t, distance, tau, 0.0, 0.041, window=2.0)
    assert metrics.in_region_at_end
    assert metrics.steady_distance == pytest.approx(0.02, abs=1e-3)
    assert metrics.peak_torque == pytest.approx(4.0, rel=1e-6)
    assert metrics.final_peak_torque < 0.01
    assert steady_distance(t, distance, 2.0) == metrics.steady_distance


def test_bad_series_are_rejected():
    with pytest.raises(ValueError, match='matching non-empty'):
        run_metrics([0.0, 1.0], [0.1], np.zeros((2, 2)), 0.0, 0.1)
    with pytest.raises(ValueError, match='finite'):
        time_to_region([0.0, 1.0], [0.1, np.nan], 0.0, 0.1)


def circling_hand(speed=0.2, radius=0.4, rate=1000.0, duration=6.0):
    """A hand going round the base at `speed` m/s on a circle of `radius` m."""
    t = np.arange(0.0, duration, 1.0 / rate)
    angle = speed / radius * t
    return t, np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])


def test_hand_speed_of_a_steady_circle():
    t, hand = circling_hand(speed=0.2)
    np.testing.assert_allclose(hand_speed(t, hand), 0.2, rtol=0.01)


def test_hand_speed_ignores_marker_swaps_and_lost_frames():
    rng = np.random.default_rng(11)
    t, hand = circling_hand(speed=0.2)
    glitched = hand.copy()
    for start in rng.choice(len(t) - 40, 6, replace=False):
        glitched[start:start + 30] += rng.uniform(-2.0, 2.0, 2)     # 30 ms, metres away
    glitched[rng.choice(len(t), 300, replace=False)] = np.nan
    speed = hand_speed(t, glitched)
    kept = np.isfinite(speed)
    assert not np.any(kept & (np.isnan(glitched[:, 0]) | np.any(glitched != hand, axis=1)))
    np.testing.assert_allclose(speed[kept], 0.2, rtol=0.01)  # never mistaken for a fast hand
    assert kept.mean() > 0.9


def test_hand_speed_of_a_recorded_take_is_below_its_raw_glitches():
    motion = read_vicon_csv(TAKES / 'HumanRobotHandover_0.csv')     # four 6 m/s one-frame jumps
    speed = hand_speed(motion.times, motion.positions)
    assert np.max(speed[np.isfinite(speed)]) < 2.0
    assert np.median(speed[np.isfinite(speed)]) == pytest.approx(0.14, abs=0.05)


def test_considered_samples_need_reach_and_a_slow_hand():
    t, hand = circling_hand(speed=0.2)
    assert np.all(considered_samples(t, hand, CRITERIA))
    assert not np.any(considered_samples(t, hand * 0.4, CRITERIA))     # r = 0.16 m: the hole
    assert not np.any(considered_samples(t, hand * 2.0, CRITERIA))     # r = 0.8 m: beyond
    t, fast = circling_hand(speed=0.5)
    assert not np.any(considered_samples(t, fast, CRITERIA))


def test_effort_step_and_high_effort_hold():
    t = np.arange(0.0, 3.0, 0.001)
    effort = np.zeros((len(t), 2))
    effort[(t >= 0.5) & (t < 0.8), 0] = 6.0           # 0.3 s above 5 N m
    effort[(t >= 1.0) & (t < 1.7), 1] = -5.5          # 0.7 s above 5 N m in magnitude
    assert largest_effort_step(effort) == pytest.approx(6.0)
    assert longest_high_effort_hold(t, effort, 5.0) == pytest.approx(0.7, abs=2e-3)
    assert longest_high_effort_hold(t, effort, 7.0) == 0.0
    effort[t >= 2.5, 0] = 9.0                          # still high at the end
    assert longest_high_effort_hold(t, effort, 8.0) == pytest.approx(0.5, abs=2e-3)
    assert largest_effort_step(effort[:1]) == 0.0


def test_take_metrics_of_a_follower_lagging_by_3_cm():
    t, hand = circling_hand(speed=0.2)
    tool = hand - 0.03 * hand / np.linalg.norm(hand, axis=1, keepdims=True)
    effort = np.column_stack([np.full(len(t), 2.0), np.sin(t)])
    metrics = take_metrics(t, hand, tool, effort, CRITERIA)
    assert metrics.follow_median_distance == pytest.approx(0.03, abs=1e-9)
    assert metrics.close_fraction == 1.0                # 3 cm < d1 - 3 cm = 15.3 cm
    assert metrics.considered == len(t)
    assert metrics.largest_effort_step < 0.01
    assert metrics.longest_high_effort_hold == 0.0


def test_take_metrics_of_an_avoider_and_of_no_considered_sample():
    t, hand = circling_hand(speed=0.2)
    tool = hand * (1.0 + 0.16 / 0.4)                    # 16 cm outside the hand
    tool[:len(t) // 10] = hand[:len(t) // 10] * 1.1     # the first tenth 4 cm away
    metrics = take_metrics(t, hand, tool, np.zeros((len(t), 2)), CRITERIA)
    assert metrics.close_fraction == pytest.approx(0.1, abs=1e-3)
    none = take_metrics(t, np.full_like(hand, np.nan), tool, np.zeros((len(t), 2)), CRITERIA)
    assert math.isnan(none.follow_median_distance) and none.considered == 0


def test_take_metrics_reject_mismatched_series():
    t, hand = circling_hand()
    with pytest.raises(ValueError, match='tool must be'):
        take_metrics(t, hand, hand[:-1], np.zeros((len(t), 2)), CRITERIA)
    with pytest.raises(ValueError, match='non-decreasing'):
        hand_speed(t[::-1], hand)
