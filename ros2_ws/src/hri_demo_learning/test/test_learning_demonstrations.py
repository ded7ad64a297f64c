"""Unit tests of learning.learn_from_demonstrations on synthetic demonstrations (no bags).

The speed-independence matrix (one path demonstrated in 2-15 s at 100 Hz and 1 kHz), a
demonstration the model cannot describe, the task gain K from demonstrations of known speed,
the reach (a fit constrained or refused, never deaf) and repeated demonstrations (averaged x_d).
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from hri_core.potential import TaskShape, log_potential_slope, reach_shortfall
from hri_demo_learning import learning
from hri_demo_learning.learning import (
    DEFAULT_MAX_TASK_SPEED,
    Demonstration,
    LearningError,
    LearningSettings,
    learn_from_demonstrations,
)
from hri_demo_learning.task_gain import fit_task_gain

REFERENCE = np.array([0.45, 0.05])  # m, x_r
HEADING = np.array([-0.35, 0.94]) / math.hypot(0.35, 0.94)  # from x_r toward the start
SETTINGS = LearningSettings(n=3, stationary_speed=0.004, workspace_radius=2.0, method='trf',
                            tolerance=1e-10, max_iterations=200, l1=0.35, l2=0.30)
REACH = SETTINGS.reach  # m, l1 + l2 of the sim's arm
NOISE = 1e-4  # m, position noise (0.1 mm)
HOLD_BEFORE, HOLD_AFTER = 1.0, 1.5  # s at rest before and after a push


def minimum_jerk(tau):
    tau = np.clip(tau, 0.0, 1.0)
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)


def push(start, stop, duration, rate, rng, reference=REFERENCE):
    """A minimum-jerk push along a ray from x_r, from `start` to `stop` m in `duration` s,
    sampled at `rate` Hz with NOISE of position noise; at rest before and after."""
    times = np.arange(0.0, HOLD_BEFORE + duration + HOLD_AFTER, 1.0 / rate)
    distance = start + (stop - start) * minimum_jerk((times - HOLD_BEFORE) / duration)
    positions = reference + distance[:, None] * HEADING
    positions = positions + rng.normal(0.0, NOISE, positions.shape)
    return Demonstration(times, positions, np.asarray(reference, dtype=float),
                         f'push {duration} s at {rate} Hz')


def learn(demos, shifts=None, **overrides):
    shifts = [0.0] * len(demos) if shifts is None else shifts
    return learn_from_demonstrations(demos, shifts, 'task', replace(SETTINGS, **overrides))


# -- 1. speed independence -----------------------------------------------------------------

DURATIONS = (2.0, 5.0, 8.0, 15.0)  # s
RATES = (100.0, 1000.0)  # Hz


@pytest.fixture(scope='module')
def speed_matrix():
    """{(duration, rate): LearnedTask} of one follow path, 0.30 m -> 0.033 m from x_r."""
    rng = np.random.default_rng(12)
    return {(duration, rate): learn([push(0.30, 0.033, duration, rate, rng)])
            for duration in DURATIONS for rate in RATES}


def test_the_same_path_at_any_pace_gives_the_same_task(speed_matrix):
    reference = speed_matrix[(2.0, 1000.0)].record
    assert (reference.s, reference.d1) == (1, 0.0)
    assert reference.d2 == pytest.approx(0.033, abs=0.002)
    for cell, learned in speed_matrix.items():
        record = learned.record
        assert record.s == reference.s, cell
        assert record.d1 == pytest.approx(reference.d1, abs=0.005), cell
        assert record.d2 == pytest.approx(reference.d2, abs=0.005), cell


def test_the_task_gain_scales_with_the_pace(speed_matrix):
    # The same path in 2 s and in 8 s: K |dP/dz| must match speeds 4 times lower.
    brisk = speed_matrix[(2.0, 1000.0)].record
    slow = speed_matrix[(8.0, 1000.0)].record
    assert (brisk.a1, brisk.a2) == pytest.approx((slow.a1, slow.a2), rel=0.05)
    assert brisk.k / slow.k == pytest.approx(4.0, rel=0.1)


# -- 1. a demonstration the model cannot describe -------------------------------------------

def out_and_back(rng, rate=200.0):
    """Away from x_r and back again, stopping where it started: P_d is no function of
    |x - x_r| (it is high at both ends of the path at one distance)."""
    times = np.arange(0.0, 5.5, 1.0 / rate)
    tau = minimum_jerk((times - 0.5) / 4.0)
    angle = np.pi * tau
    radius = 0.15 + 0.15 * np.sin(angle)  # 0.15 m -> 0.30 m -> 0.15 m
    direction = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    positions = REFERENCE + radius[:, None] * direction + rng.normal(0.0, NOISE, (times.size, 2))
    return Demonstration(times, positions, REFERENCE.copy(), 'out_and_back')


def test_a_demonstration_the_model_cannot_describe_is_refused_in_one_line():
    demo = out_and_back(np.random.default_rng(3))
    with pytest.raises(LearningError, match=r'does not describe the demonstration: best fit '
                                            r'cost C = [0-9.]+ > max_cost 0\.1') as error:
        learn([demo])
    assert '\n' not in str(error.value)


def test_max_cost_is_the_threshold():
    demo = out_and_back(np.random.default_rng(3))
    learned = learn([demo], max_cost=2.0)  # any cost passes
    assert learned.record.cost > 0.1
    with pytest.raises(LearningError, match='max_cost'):
        learn([demo], max_cost=learned.record.cost * 0.99)


# -- 2. task gain K --------------------------------------------------------------------------

@pytest.mark.parametrize('k_true', [0.05, 0.3, 2.0])
def test_fit_task_gain_recovers_k_from_noisy_speeds(k_true):
    rng = np.random.default_rng(int(k_true * 100))
    shape = TaskShape(1, 5.0, 40.0, 0.0, 0.04)
    distance = rng.uniform(0.06, 0.6, 500)
    speed = k_true * np.exp(log_potential_slope(distance, shape))
    speed = speed * (1.0 + rng.normal(0.0, 0.1, speed.size))
    assert fit_task_gain(distance, np.abs(speed), np.ones(500, bool), shape) == \
        pytest.approx(k_true, rel=0.1)


@pytest.mark.parametrize(('duration', 'rate'), [(2.0, 1000.0), (4.0, 100.0), (8.0, 250.0)])
def test_k_is_recovered_from_a_demonstration_of_known_speed(duration, rate):
    # A minimum-jerk push whose true speed v_i at each sample is known: the learner, from the
    # noisy positions alone, must give the K that fits K |dP/dz| to the true speeds.
    rng = np.random.default_rng(int(duration * rate))
    demo = push(0.30, 0.041, duration, rate, rng)
    task = learn([demo])
    learned = task.record
    # The samples the learner counts as moving (its profile starts at the first of them).
    first = demo.times.size - task.profile.distance.size
    tau = np.clip((demo.times[first:][task.profile.moving] - 1.0) / duration, 0.0, 1.0)
    distance = 0.30 + (0.041 - 0.30) * minimum_jerk(tau)
    true_speed = (0.30 - 0.041) / duration * 30.0 * tau ** 2 * (1.0 - tau) ** 2
    slope = np.exp(log_potential_slope(distance, learned.shape))
    k_true = float(np.dot(slope, true_speed) / np.dot(slope, slope))
    assert learned.k == pytest.approx(k_true, rel=0.1)


# -- 3. reach ---------------------------------------------------------------------------------

def test_the_deaf_follow_rows_do_not_reach():
    for a1, a2, d2 in ((1000.0, 237.8, 0.033), (329.7, 1000.0, 0.041)):
        shape = TaskShape(1, a1, a2, 0.0, d2)
        assert reach_shortfall(shape, 0.0, DEFAULT_MAX_TASK_SPEED, REACH) is not None
        for k in (0.01, 1.0, 100.0):
            assert reach_shortfall(shape, k, DEFAULT_MAX_TASK_SPEED, REACH) is not None


def test_a_push_that_starts_near_x_r_is_constrained_to_reach():
    # The demonstration that gave (1000, 237.8) unconstrained: 0.1 m -> 0.033 m. The fit's
    # a1 is capped by the workspace, so the task it learns reaches, or it is refused.
    rng = np.random.default_rng(5)
    demo = push(0.10, 0.033, 1.5, 500.0, rng)
    try:
        learned = learn([demo])
    except LearningError as error:
        assert 'does not reach' in str(error) or 'does not describe' in str(error)
        return
    record = learned.record
    assert learned.a1_max is not None and record.a1 <= learned.a1_max * (1 + 1e-9)
    assert reach_shortfall(record.shape, record.k, DEFAULT_MAX_TASK_SPEED, REACH) is None


def test_without_the_cap_the_fit_is_deaf_and_refused_in_one_line(monkeypatch):
    # The unconstrained fit of a follow push puts a1 near 33, a2 on 1000: P is flat beyond
    # 0.4 m. With the cap lifted the learner must refuse it rather than publish it.
    rng = np.random.default_rng(5)
    demo = push(0.30, 0.033, 2.0, 500.0, rng)
    monkeypatch.setattr(learning, 'reach_steepness_limit', lambda *args: None)
    with pytest.raises(LearningError, match=r'does not reach: its pull K \|dP/dz\| is') \
            as error:
        learn([demo])
    assert '\n' not in str(error.value)


# -- 4. repeated demonstrations ----------------------------------------------------------------

def test_repeated_demonstrations_share_the_averaged_x_d():
    rng = np.random.default_rng(21)
    stops = (0.036, 0.041, 0.046)
    demos = [push(0.30, stop, duration, 500.0, rng)
             for stop, duration in zip(stops, (2.0, 3.0, 4.0), strict=True)]
    rests = [demo.positions[demo.times > demo.times[-1] - 1.0].mean(axis=0) for demo in demos]
    learned = learn(demos, combine=False)
    assert len(learned.targets) == 3
    for target in learned.targets:
        np.testing.assert_allclose(target, [*np.mean(rests, axis=0), 0.0], atol=2e-4)  # z = 0
    assert learned.record.d1 == 0.0
    assert learned.record.d2 == pytest.approx(max(stops), abs=0.002)  # eq. 5: all rests
    combined = learn(demos)  # eq. 4, no shift: each demonstration keeps its own x_d
    assert not np.allclose(combined.targets[0], combined.targets[2], atol=1e-3)


def test_repetitions_take_no_shift_and_need_one_reference():
    rng = np.random.default_rng(22)
    demos = [push(0.30, 0.041, 2.0, 500.0, rng), push(0.30, 0.041, 2.0, 500.0, rng)]
    with pytest.raises(LearningError, match='repetitions .*take no shift'):
        learn(demos, shifts=[0.0, 0.1], combine=False)
    moved = push(0.30, 0.041, 2.0, 500.0, rng, reference=REFERENCE + [0.02, 0.0])
    with pytest.raises(LearningError, match='need one x_r'):
        learn([demos[0], moved], combine=False)
