"""Unit tests of joint_limits and of the joint limits in the pure closed loop on the SCARA
(arm_law.ArmController over hri_core.robot_model.ScaraModel, whose limits are scara_sim's):
the barrier, the feed-forward gate, the reach-round blend and theta_hat's bounds."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from hri_adaptive_controller.arm_law import (
    SCARA_GAINS,
    ActiveTask,
    ArmController,
    HandState,
)
from hri_adaptive_controller.closed_loop import LoopConditions, path_target, simulate
from hri_adaptive_controller.joint_limits import (
    ReachRound,
    ReachRoundSettings,
    barrier,
    barrier_energy,
    gate_feed_forward,
    joint_motion,
    redirected_push,
)
from hri_adaptive_controller.task_variable import CAP_BAND
from hri_core.dynamics import ScaraParameters, dynamic_parameters
from hri_core.potential import TaskShape
from hri_core.robot_model import SCARA_LIMITS, JointLimits, ScaraModel

PARAMS = ScaraParameters()
SCARA = ScaraModel(PARAMS)
L1, L2 = SCARA.link_lengths
LOWER, UPPER = SCARA.limits.lower, SCARA.limits.upper
BAND, BARRIER_TORQUE = SCARA_GAINS.limit_band, SCARA_GAINS.barrier_torque
EFFORT_LIMIT = float(SCARA.limits.effort[0])
FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)
FOLLOW_SAFE = TaskShape(1, 1.576, 30.78, 0.183, 0.271)
AVOID = TaskShape(1, 0.056, 25.46, 0.183, 2.0)
WRONG_THETA = dynamic_parameters(PARAMS) * np.array([0.5, 1.6, 2.0, 0.3, 2.0, 1.0, 1.0])
# The law alone: the rate limit after the clamp would hold every step bound by construction.
UNLIMITED = dataclasses.replace(SCARA_GAINS, max_effort_rate=1e9)
# A controller that knows no joint limits (its model's are unbounded: no barrier, no gate)
# and does not reach round; the arm it drives keeps scara_sim's stops.
UNBOUNDED = ScaraModel(PARAMS, dataclasses.replace(
    SCARA_LIMITS, lower=np.full(2, -math.inf), upper=np.full(2, math.inf)))
NO_LIMITS = dataclasses.replace(UNLIMITED, reach_round=ReachRoundSettings(enabled=False))
SRC = Path(__file__).resolve().parents[2]
# The hand crosses over the base to the far side and stays there, reachable only by swinging
# joint 1 round (the straight task-space path runs through the hole round the base).
CROSSING = path_target([0.40, 0.20], [(3.0, [0.02, 0.05], 0.3), (6.5, [-0.35, -0.15], 0.3)])


def run(target, duration, gains=UNLIMITED, task=FOLLOW, model=None):
    # The task fades in from t = 0 (eq. 13), as the event_manager starts it.
    return simulate({'task': task}, [(0.0, 'task')], target, duration, LoopConditions(
        arm=SCARA, model=model, gains=gains, theta_hat0=WRONG_THETA, monitor=False,
        target_period=0.01))


def longest_run(mask, dt=1e-3) -> float:
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return float(np.max(ends - starts, initial=0)) * dt


def test_the_models_limits_are_the_sims_and_the_band_the_controller_yamls():
    sim = yaml.safe_load((SRC / 'scara_sim/config/scara_sim.yaml').read_text())
    node = yaml.safe_load((SRC / 'hri_adaptive_controller/config/controller.yaml').read_text())
    values = sim['scara_sim']['ros__parameters']
    assert tuple(values['joint_lower_limits']) == tuple(LOWER)
    assert tuple(values['joint_upper_limits']) == tuple(UPPER)
    node_values = node['controller']['ros__parameters']
    assert node_values['joint_limit_band'] == BAND
    assert node_values['barrier_torque'] == BARRIER_TORQUE


def test_bad_limits_are_refused():
    narrow = ScaraModel(PARAMS, dataclasses.replace(SCARA_LIMITS, lower=np.array([-0.1, -2.0]),
                                                    upper=np.array([0.1, 2.0])))
    with pytest.raises(ValueError, match='wider than'):
        ArmController(narrow, SCARA_GAINS, compiled=False)
    with pytest.raises(ValueError, match='barrier_torque'):
        dataclasses.replace(SCARA_GAINS, barrier_torque=-1.0)
    with pytest.raises(ValueError, match='limit_band'):
        dataclasses.replace(SCARA_GAINS, limit_band=0.0)
    with pytest.raises(ValueError, match='must be <= upper'):
        JointLimits(np.array([-math.nan, -2.0]), np.array([2.0, 2.0]), np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match='gain'):
        ReachRoundSettings(gain=0.0)


def test_barrier_is_zero_outside_the_band_and_pushes_off_each_limit():
    g, rate, near = barrier(np.array([0.0, 1.0]), np.array([0.3, 0.3]), LOWER, UPPER, BAND,
                            BARRIER_TORQUE)
    assert np.all(g == 0.0) and np.all(rate == 0.0) and near == 0.0
    assert barrier_energy(np.array([2.0, -2.0]), LOWER, UPPER, BAND, BARRIER_TORQUE) == 0.0
    g, _, near = barrier(np.array([UPPER[0], LOWER[1]]), np.zeros(2), LOWER, UPPER, BAND,
                         BARRIER_TORQUE)
    assert g[0] == pytest.approx(BARRIER_TORQUE) and g[1] == pytest.approx(-g[0])
    assert near == 1.0


@pytest.mark.parametrize('q', [(2.25, 0.3), (-2.27, -2.40), (0.1, 2.43), (2.29, -2.37)])
def test_barrier_gradient_and_rate_are_exact(q):
    h = 1e-7
    q, dq = np.array(q), np.array([0.7, -0.4])
    g, rate, _ = barrier(q, dq, LOWER, UPPER, BAND, BARRIER_TORQUE)
    for i in range(2):
        step = h * np.eye(2)[i]
        slope = (barrier_energy(q + step, LOWER, UPPER, BAND, BARRIER_TORQUE)
                 - barrier_energy(q - step, LOWER, UPPER, BAND, BARRIER_TORQUE)) / (2 * h)
        assert slope == pytest.approx(g[i], abs=1e-6)
    later = barrier(q + h * dq, dq, LOWER, UPPER, BAND, BARRIER_TORQUE)[0]
    earlier = barrier(q - h * dq, dq, LOWER, UPPER, BAND, BARRIER_TORQUE)[0]
    np.testing.assert_allclose((later - earlier) / (2 * h), rate, atol=1e-5)


def gate(q, dq, v, rate):
    return gate_feed_forward(np.array(q, dtype=float), np.array(dq, dtype=float),
                             np.array(v, dtype=float), np.array(rate, dtype=float), LOWER,
                             UPPER, BAND)


def test_the_gate_stops_feed_forward_into_a_limit_only():
    at_limit = UPPER[0]
    towards, _ = gate([at_limit, 0.0], [0.0, 0.0], [0.5, 0.5], [0.0, 0.0])
    away, _ = gate([at_limit, 0.0], [0.0, 0.0], [-0.5, 0.5], [0.0, 0.0])
    assert towards[0] == 0.0 and towards[1] == 0.5
    assert away[0] == -0.5
    free, free_rate = gate([0.0, 0.0], [0.0, 0.0], [0.5, -0.5], [1.0, 2.0])
    assert free.tolist() == [0.5, -0.5] and free_rate.tolist() == [1.0, 2.0]


def test_the_gated_feed_forwards_rate_is_its_time_derivative():
    # A joint moving into the band with a feed-forward speed that changes sign.
    rng = np.random.default_rng(3)
    h = 1e-6
    for _ in range(50):
        q, dq = rng.uniform(2.2, 2.3), rng.uniform(-0.5, 0.5)
        v, a = rng.uniform(-0.08, 0.08), rng.uniform(-2.0, 2.0)
        _, rate = gate([q, 0.0], [dq, 0.0], [v, 0.0], [a, 0.0])
        later, _ = gate([q + h * dq, 0.0], [dq, 0.0], [v + h * a, 0.0], [a, 0.0])
        earlier, _ = gate([q - h * dq, 0.0], [dq, 0.0], [v - h * a, 0.0], [a, 0.0])
        assert (later[0] - earlier[0]) / (2 * h) == pytest.approx(rate[0], abs=1e-5)


def push_gated_along(t, g, g_rate, f, f_rate):
    """redirected_push (most 3) at time t (s) of a push g + t g_rate gated by the factors
    f + t f_rate, with their rates."""
    whole, share = g + t * g_rate, f + t * f_rate
    return redirected_push(whole, g_rate, share * whole, f_rate * whole + share * g_rate, 3.0)


def test_a_push_a_joint_in_its_band_may_not_take_goes_to_the_free_joints():
    # The SCARA's link2 pushed off a torso (g mostly on joint 2), joint 2 in its band: the
    # gated push keeps joint 1's 0.3 N m; redirected, joint 1 gets the pair's whole share.
    g, rate = np.array([0.3, -1.3]), np.zeros(2)
    gated = np.array([0.3, 0.0])
    pushed, _ = redirected_push(g, rate, gated, rate, 10.0)
    assert pushed[1] == 0.0 and pushed[0] > 0.3 * 9.0  # g.g / g.gated = 19.8, capped near 10
    assert pushed[0] <= 0.3 * 10.0 * (1.0 + CAP_BAND)  # speed_cap's smooth cap
    # Nothing gated, or everything: the push as it came.
    assert redirected_push(g, rate, g, rate, 10.0)[0].tolist() == g.tolist()
    assert redirected_push(g, rate, np.zeros(2), rate, 10.0)[0].tolist() == [0.0, 0.0]
    # Half gated along the way: the push is the whole one's share scaled up, never more
    # than `most` times the gated push, and its rate is its time derivative.
    rng = np.random.default_rng(5)
    h = 1e-7
    for _ in range(50):
        g, g_rate = rng.uniform(-2.0, 2.0, 2), rng.uniform(-5.0, 5.0, 2)
        f, f_rate = rng.uniform(0.05, 1.0, 2), rng.uniform(-2.0, 2.0, 2)
        pushed, pushed_rate = push_gated_along(0.0, g, g_rate, f, f_rate)
        assert np.all(np.abs(pushed) <= 3.0 * (1.0 + CAP_BAND) * np.abs(f * g) + 1e-12)
        numeric = (push_gated_along(h, g, g_rate, f, f_rate)[0]
                   - push_gated_along(-h, g, g_rate, f, f_rate)[0]) / (2 * h)
        assert numeric == pytest.approx(pushed_rate, rel=1e-4, abs=1e-4)


# One test for the two behaviours of the one run (the pair of 16 s runs once, not once in
# each unit-test worker as a module fixture was).
@pytest.mark.first
def test_the_arm_reaches_round_to_a_hand_on_the_far_side_without_pushing_into_a_stop():
    after, before = run(CROSSING, 16.0), run(CROSSING, 16.0, NO_LIMITS, model=UNBOUNDED)
    # Without limits joint 2 folds onto its stop (2.46 rad) and pushes up to the full 20 N m
    # while the hand is on the far side; theta_hat drifted (pi1 2-5 times its value).
    assert longest_run(before.q[:, 1] >= UPPER[1] - 1e-6) > 1.0
    assert np.max(np.abs(before.tau)) >= 15.0
    assert np.max(np.abs(after.q[:, 1])) <= UPPER[1] - 0.03
    assert np.max(np.abs(after.q[:, 0])) <= UPPER[0] - 0.03
    assert np.max(np.abs(after.tau)) <= 0.25 * EFFORT_LIMIT
    steps = np.max(np.abs(np.diff(after.tau, axis=0)))
    assert steps <= 1.0  # the law alone: no effort step from the barrier or the blend
    # Reached round: with limits and the reach-round the arm follows to the far side.
    settled = after.time >= 14.0  # the hand stopped at 6.5 + 1.875 * 0.4 / 0.3 = 9 s
    assert np.max(after.distance[settled]) <= FOLLOW.d2 + 0.01
    assert np.min(before.distance[settled]) > 0.1  # stuck without reaching round
    # The blend is C1: qdot (and so the reference it tracks) has no jump, and theta_hat stays
    # in its box.
    accel = np.abs(np.diff(after.dq, axis=0)) / 1e-3
    assert np.max(accel) < 100.0
    assert np.all((after.theta_hat >= SCARA.theta_lower)
                  & (after.theta_hat <= SCARA.theta_upper))


def test_a_hand_out_of_reach_is_held_at_the_nearest_reachable_point_without_jitter():
    far = path_target([0.45, 0.05], [(1.0, [0.95, 0.10], 0.3)])
    result = run(far, 8.0)
    last = result.time >= 6.0
    reach = np.linalg.norm(result.position[last], axis=1)
    goal = SCARA.attained_reach - ReachRoundSettings().outer_margin
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


def test_a_goal_fed_its_velocity_is_tracked_without_the_filters_lag():
    # A follow's joint goal moves with the hand. Fed forward, its velocity leaves the joint
    # motion at the goal; without it the critically damped filter trails a ramp by
    # 2 / filter_rate s (0.25 s at 8 1/s: 0.1 rad at 0.4 rad/s).
    settings = ReachRoundSettings()
    speed = np.array([0.4, -0.2])  # rad/s, within the slew
    dt = 1e-3
    lags = []
    for fed in (True, False):
        q_in = filtered = q = dq = rate = np.zeros(2)
        for step in range(3000):  # 3 s, the arm moving as asked (dq = u)
            goal = speed * (step + 1) * dt
            q_in, filtered, rate, dq, _ = joint_motion(
                goal, True, q_in, filtered, rate, q, dq, dt, settings.slew,
                settings.filter_rate, settings.gain, settings.max_speed,
                speed if fed else np.zeros(2))
            q = q + dt * dq
        lags.append(np.abs(goal - q).max())
    assert lags[0] < 1e-3
    assert lags[1] == pytest.approx(2.0 / settings.filter_rate * 0.4, rel=0.05)


def test_reach_round_blend_is_off_for_avoid_tasks_and_without_a_task():
    # Joint 2 in its band (near 0.9) and the hand on the far side: a follow task would
    # engage; without a region (no task, or an avoid task) sigma stays at 0.
    blend = ReachRound(ReachRoundSettings(), SCARA, LOWER, UPPER, BAND, L1 + L2,
                       SCARA_GAINS.damping.threshold)
    q, dq = np.array([0.0, 2.4]), np.zeros(2)
    x, jac, _ = SCARA.task_kinematics(q, dq)
    for _ in range(100):
        assert blend.update(q, dq, x, jac, np.array([-0.3, -0.1]), None, 0.9, 1e-3) is None
    assert not blend.engaged
    # The law passes no region for an avoid task, nor without one.
    hand = HandState(np.array([-0.3, -0.1]), np.zeros(2), np.zeros(2))
    for task in (None, ActiveTask(AVOID, 1.0)):
        law = ArmController(SCARA, SCARA_GAINS, compiled=False)
        for _ in range(100):
            out = law.step(q, dq, hand, task, 1e-3)
            assert not out.fault and out.near > 0.0 and out.blend == 0.0
        assert not law.reaching_round
    # ... where a follow task does.
    law = ArmController(SCARA, SCARA_GAINS, compiled=False)
    outputs = [law.step(q, dq, hand, ActiveTask(FOLLOW, 1.0), 1e-3) for _ in range(100)]
    assert law.reaching_round and outputs[-1].blend > 0.0


@pytest.mark.first
def test_theta_hat_stays_bounded_with_the_hand_out_of_reach_half_the_time():
    # 60 s: the hand 0.1 m in front of the arm, then out of reach (1 m away) for 7.5 s, back
    # for 7.5 s, ... Afterwards the arm follows the still hand as well as before.
    moves, t = [], 1.0
    for _ in range(4):
        moves += [(t, [1.0, 0.25], 0.4), (t + 7.5, [0.45, 0.1], 0.4)]
        t += 15.0
    hand = path_target([0.45, 0.1], moves)
    result = run(hand, 60.0, gains=SCARA_GAINS)
    assert np.all((result.theta_hat >= SCARA.theta_lower)
                  & (result.theta_hat <= SCARA.theta_upper))
    # theta_hat does not run away: within a factor 2.5 of the true inertias and frictions.
    ratio = result.theta_hat[-1, :5] / result.theta_true[:5]
    assert np.all((ratio > 0.4) & (ratio < 2.5)), ratio
    # Following accuracy in each reachable stretch, the last as good as the first.
    first = (result.time > 12.5) & (result.time < 15.5)
    last = (result.time > 57.0) & (result.time < 60.0)
    assert np.median(result.distance[last]) <= FOLLOW.d2 + 0.005
    assert np.median(result.distance[last]) <= np.median(result.distance[first]) + 0.005
