"""Unit tests of joint_limits and of the joint limits in the pure closed loop: the barrier,
the feed-forward gate, the reach-round blend and theta_hat's bounds."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from hri_adaptive_controller.adaptive_law import DEFAULT_GAINS
from hri_adaptive_controller.closed_loop import LoopConditions, path_target, simulate
from hri_adaptive_controller.controller_node import limits_mismatch, narrower_limits
from hri_adaptive_controller.joint_limits import (
    JointLimits,
    ReachRound,
    ReachRoundSettings,
    barrier,
    barrier_energy,
    gate_feed_forward,
    inverse_kinematics,
    workspace_radii,
)
from hri_core.dynamics import ScaraParameters, dynamic_parameters, forward_kinematics
from hri_core.potential import TaskShape

LIMITS = JointLimits()
FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)
FOLLOW_SAFE = TaskShape(1, 1.576, 30.78, 0.183, 0.271)
WRONG_THETA = dynamic_parameters(ScaraParameters()) * np.array(
    [0.5, 1.6, 2.0, 0.3, 2.0, 1.0, 1.0])
# The law alone: the rate limit after the clamp would hold every step bound by construction.
UNLIMITED = dataclasses.replace(DEFAULT_GAINS, max_effort_rate=1e9)
NO_LIMITS = dataclasses.replace(UNLIMITED, joint_limits=None)
SRC = Path(__file__).resolve().parents[2]
# The hand crosses over the base to the far side and stays there, reachable only by swinging
# joint 1 round (the straight task-space path runs through the hole round the base).
CROSSING = path_target([0.40, 0.20], [(3.0, [0.02, 0.05], 0.3), (6.5, [-0.35, -0.15], 0.3)])


def run(target, duration, gains=UNLIMITED, task=FOLLOW, **changes):
    # The task fades in from t = 0 (eq. 13), as the event_manager starts it.
    return simulate({'task': task}, [(0.0, 'task')], target, duration, LoopConditions(
        gains=gains, theta_hat0=WRONG_THETA, monitor=False, target_period=0.01, **changes))


@pytest.fixture(scope='module')
def crossing():
    return {name: run(CROSSING, 16.0, gains) for name, gains in
            (('limits', UNLIMITED), ('none', NO_LIMITS))}


def longest_run(mask, dt=1e-3) -> float:
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return float(np.max(ends - starts, initial=0)) * dt


def test_the_defaults_are_the_sims_and_the_controller_yamls():
    sim = yaml.safe_load((SRC / 'scara_sim/config/scara_sim.yaml').read_text())
    node = yaml.safe_load((SRC / 'hri_adaptive_controller/config/controller.yaml').read_text())
    for values in (sim['scara_sim']['ros__parameters'], node['controller']['ros__parameters']):
        assert tuple(values['joint_lower_limits']) == LIMITS.lower
        assert tuple(values['joint_upper_limits']) == LIMITS.upper
    assert node['controller']['ros__parameters']['joint_limit_band'] == LIMITS.band


def test_the_node_compares_its_limits_with_the_sims_and_keeps_the_narrower():
    ours = (LIMITS.lower, LIMITS.upper)
    assert limits_mismatch(ours, ((-2.30, -2.46), (2.30, 2.46))) == ''
    problem = limits_mismatch(ours, ((-2.0, -2.46), (2.30, 2.5)))
    assert 'differ' in problem and 'scara_sim' in problem
    assert narrower_limits(ours, ((-2.0, -2.5), (2.5, 2.4))) == ((-2.0, -2.46), (2.30, 2.4))


def test_bad_limits_are_refused():
    with pytest.raises(ValueError, match='wider than'):
        JointLimits((-0.1, -2.0), (0.1, 2.0), band=0.1)
    with pytest.raises(ValueError, match='barrier_torque'):
        JointLimits(barrier_torque=-1.0)
    with pytest.raises(ValueError, match='finite'):
        JointLimits((-math.nan, -2.0), (2.0, 2.0))
    with pytest.raises(ValueError, match='gain'):
        ReachRoundSettings(gain=0.0)


def test_barrier_is_zero_outside_the_band_and_pushes_off_each_limit():
    assert barrier(0.0, 1.0, 0.3, 0.3, LIMITS) == (0.0, 0.0, 0.0, 0.0, 0.0)
    assert barrier_energy(2.0, -2.0, LIMITS) == 0.0
    g1, g2, _, _, near = barrier(LIMITS.upper[0], LIMITS.lower[1], 0.0, 0.0, LIMITS)
    assert g1 == pytest.approx(LIMITS.barrier_torque) and g2 == pytest.approx(-g1)
    assert near == 1.0


@pytest.mark.parametrize('q', [(2.25, 0.3), (-2.27, -2.40), (0.1, 2.43), (2.29, -2.37)])
def test_barrier_gradient_and_rate_are_exact(q):
    h = 1e-7
    dq = (0.7, -0.4)
    g1, g2, gd1, gd2, _ = barrier(*q, *dq, LIMITS)
    for i, g in ((0, g1), (1, g2)):
        up, down = list(q), list(q)
        up[i] += h
        down[i] -= h
        slope = (barrier_energy(*up, LIMITS) - barrier_energy(*down, LIMITS)) / (2 * h)
        assert slope == pytest.approx(g, abs=1e-6)
    later = barrier(q[0] + h * dq[0], q[1] + h * dq[1], *dq, LIMITS)
    earlier = barrier(q[0] - h * dq[0], q[1] - h * dq[1], *dq, LIMITS)
    assert (later[0] - earlier[0]) / (2 * h) == pytest.approx(gd1, abs=1e-5)
    assert (later[1] - earlier[1]) / (2 * h) == pytest.approx(gd2, abs=1e-5)


def test_the_gate_stops_feed_forward_into_a_limit_only():
    at_limit = LIMITS.upper[0]
    towards, away = gate_feed_forward(at_limit, 0.0, 0.0, 0.0, 0.5, 0.5, 0.0, 0.0, LIMITS), \
        gate_feed_forward(at_limit, 0.0, 0.0, 0.0, -0.5, 0.5, 0.0, 0.0, LIMITS)
    assert towards[0] == 0.0 and towards[1] == 0.5
    assert away[0] == -0.5
    free = gate_feed_forward(0.0, 0.0, 0.0, 0.0, 0.5, -0.5, 1.0, 2.0, LIMITS)
    assert free == (0.5, -0.5, 1.0, 2.0)


def test_the_gated_feed_forwards_rate_is_its_time_derivative():
    # A joint moving into the band with a feed-forward speed that changes sign.
    rng = np.random.default_rng(3)
    h = 1e-6
    for _ in range(50):
        q, dq = rng.uniform(2.2, 2.3), rng.uniform(-0.5, 0.5)
        v, a = rng.uniform(-0.08, 0.08), rng.uniform(-2.0, 2.0)
        _, _, rate, _ = gate_feed_forward(q, 0.0, dq, 0.0, v, 0.0, a, 0.0, LIMITS)
        later = gate_feed_forward(q + h * dq, 0.0, dq, 0.0, v + h * a, 0.0, a, 0.0, LIMITS)
        earlier = gate_feed_forward(q - h * dq, 0.0, dq, 0.0, v - h * a, 0.0, a, 0.0, LIMITS)
        assert (later[0] - earlier[0]) / (2 * h) == pytest.approx(rate, abs=1e-5)


def test_inverse_kinematics_reaches_and_prefers_the_elbow_the_box_allows():
    l1, l2 = 0.35, 0.30
    for point in ((0.4, 0.2), (-0.35, -0.15), (0.0, -0.5), (0.3, -0.1)):
        q = inverse_kinematics(*point, 0.0, 1.0, l1, l2, LIMITS)
        np.testing.assert_allclose(forward_kinematics(np.array(q), l1, l2), point, atol=1e-9)
        assert all(low < v < high for v, low, high in zip(q, LIMITS.lower, LIMITS.upper,
                                                                   strict=True))
    inner, outer = workspace_radii(l1, l2, LIMITS)
    assert inner == pytest.approx(0.2223, abs=1e-4) and outer == pytest.approx(0.65)


def test_the_arm_no_longer_pushes_into_joint_2s_stop(crossing):
    # Before: joint 2 folded onto its stop (2.46 rad) and pushed up to the full 20 N m while
    # the hand was on the far side; theta_hat drifted (pi1 2-5 times its value).
    before, after = crossing['none'], crossing['limits']
    assert longest_run(before.q[:, 1] >= LIMITS.upper[1] - 1e-6) > 1.0
    assert np.max(np.abs(before.tau)) >= 15.0
    assert np.max(np.abs(after.q[:, 1])) <= LIMITS.upper[1] - 0.03
    assert np.max(np.abs(after.q[:, 0])) <= LIMITS.upper[0] - 0.03
    assert np.max(np.abs(after.tau)) <= 0.25 * DEFAULT_GAINS.effort_limit
    steps = np.max(np.abs(np.diff(after.tau, axis=0)))
    assert steps <= 1.0  # the law alone: no effort step from the barrier or the blend


def test_the_arm_reaches_round_to_a_hand_on_the_far_side(crossing):
    after, before = crossing['limits'], crossing['none']
    settled = after.time >= 14.0  # the hand stopped at 6.5 + 1.875 * 0.4 / 0.3 = 9 s
    assert np.max(after.distance[settled]) <= FOLLOW.d2 + 0.01
    assert np.min(before.distance[settled]) > 0.1  # stuck without reaching round
    # The blend is C1: qdot (and so the reference it tracks) has no jump, and theta_hat stays
    # in its box.
    accel = np.abs(np.diff(after.dq, axis=0)) / 1e-3
    assert np.max(accel) < 100.0
    lower, upper = np.array(DEFAULT_GAINS.theta_lower), np.array(DEFAULT_GAINS.theta_upper)
    assert np.all((after.theta_hat >= lower) & (after.theta_hat <= upper))


def test_a_hand_out_of_reach_is_held_at_the_nearest_reachable_point_without_jitter():
    far = path_target([0.45, 0.05], [(1.0, [0.95, 0.10], 0.3)])
    result = run(far, 8.0)
    last = result.time >= 6.0
    reach = np.linalg.norm(result.position[last], axis=1)
    _, outer = workspace_radii(0.35, 0.30, LIMITS)
    goal = outer - ReachRoundSettings().outer_margin
    assert np.all(np.abs(reach - goal) <= 0.01)  # held just inside the stretched reach
    assert np.max(np.abs(result.dq[last])) <= 0.01  # still: no stretched-arm jitter
    assert np.max(np.abs(result.tau[last])) <= 0.5  # with small effort
    assert np.min(np.abs(result.q[last, 1])) >= 0.3  # not stretched
    # The law's own largest step (no rate limit): 1.25 N m, as the arm, stretching after the
    # hand at 3.6 rad/s of joint 2, is turned back near the stretched arm's damping zone.
    assert np.max(np.abs(np.diff(result.tau, axis=0))) <= 2.0


def test_follow_safe_reaches_its_annulus_on_the_far_side():
    result = run(CROSSING, 16.0, task=FOLLOW_SAFE)
    settled = result.time >= 14.0
    assert np.all((result.distance[settled] >= FOLLOW_SAFE.d1 - 0.01)
                  & (result.distance[settled] <= FOLLOW_SAFE.d2 + 0.01))


def test_reach_round_blend_is_off_for_avoid_tasks_and_without_a_task():
    rr = ReachRound(ReachRoundSettings(), LIMITS, 0.35, 0.30)
    for _ in range(100):
        out = rr.update(0.0, 2.4, 0.0, 0.0, 0.2, 0.2, (-0.3, -0.1), None, 0.9, 1e-3)
        assert out == (0.0,) * 6
    assert not rr.engaged


def test_theta_hat_stays_bounded_with_the_hand_out_of_reach_half_the_time():
    # 60 s: the hand 0.1 m in front of the arm, then out of reach (1 m away) for 7.5 s, back
    # for 7.5 s, ... Afterwards the arm follows the still hand as well as before.
    moves, t = [], 1.0
    for _ in range(4):
        moves += [(t, [1.0, 0.25], 0.4), (t + 7.5, [0.45, 0.1], 0.4)]
        t += 15.0
    hand = path_target([0.45, 0.1], moves)
    result = run(hand, 60.0, gains=DEFAULT_GAINS)
    lower, upper = np.array(DEFAULT_GAINS.theta_lower), np.array(DEFAULT_GAINS.theta_upper)
    assert np.all((result.theta_hat >= lower) & (result.theta_hat <= upper))
    # theta_hat does not run away: within a factor 2.5 of the true inertias and frictions.
    ratio = result.theta_hat[-1, :5] / result.theta_true[:5]
    assert np.all((ratio > 0.4) & (ratio < 2.5)), ratio
    # Following accuracy in each reachable stretch, the last as good as the first.
    first = (result.time > 12.5) & (result.time < 15.5)
    last = (result.time > 57.0) & (result.time < 60.0)
    assert np.median(result.distance[last]) <= FOLLOW.d2 + 0.005
    assert np.median(result.distance[last]) <= np.median(result.distance[first]) + 0.005
