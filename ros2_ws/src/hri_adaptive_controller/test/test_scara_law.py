"""Unit tests of arm_law's one law on the SCARA's two task axes (x, y): eq. 16's torque with J^T,
eq. 19's update, the task speed under the cap, the effort limit, faults, the projection of
theta_hat, and the paper's 7 parameters (hri_core.dynamics' regressor)."""

import dataclasses
import math

import numpy as np
import pytest

from hri_adaptive_controller.arm_law import (
    SCARA_GAINS,
    ActiveTask,
    ArmController,
    HandState,
    predicted_lyapunov_rate,
)
from hri_adaptive_controller.task_variable import DampingSettings, speed_cap
from hri_core.dynamics import ScaraParameters, dynamic_parameters, jacobian, regressor
from hri_core.potential import TaskShape, log_potential_slope
from hri_core.robot_model import ScaraModel

FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)  # Table I's rows
AVOID = TaskShape(1, 0.056, 25.46, 0.183, 2.0)
PARAMS = ScaraParameters()
THETA = dynamic_parameters(PARAMS)
SCARA = ScaraModel(PARAMS)
Q = np.array([0.0, math.pi / 2])  # the tip at (0.35, 0.30) m
TIP = np.array([0.35, 0.30])
DT = 1e-3


def hand(position, velocity=(0.0, 0.0)):
    return HandState(np.asarray(position, dtype=float), np.asarray(velocity, dtype=float),
                     np.zeros(2))


def controller(theta_hat0=THETA, **changes):
    return ArmController(SCARA, dataclasses.replace(SCARA_GAINS, **changes), theta_hat0,
                         compiled=False)


def test_theta_keeps_the_papers_seven_parameters():
    assert SCARA.parameter_names == ('pi1', 'pi2', 'pi3', 'b1', 'b2', 'mlc1', 'mlc2')
    assert SCARA.adaptation_kinds == SCARA.parameter_names
    np.testing.assert_array_equal(controller().adaptation_rates, SCARA_GAINS.adaptation)
    rng = np.random.default_rng(1)
    for _ in range(20):
        q, dq, v, a = (rng.normal(size=2) for _ in range(4))
        np.testing.assert_allclose(SCARA.regressor_unchecked(q, dq, v, a),
                                   regressor(q, dq, v, a), atol=1e-14)


def test_torque_is_eq_16_with_the_transposed_jacobian_and_update_is_eq_19():
    law = controller(theta_hat0=0.7 * THETA)
    q, dq = np.array([0.3, 1.1]), np.array([0.02, -0.04])
    out = law.command(q, dq, hand([0.45, 0.2]), ActiveTask(FOLLOW, 0.8), DT)
    assert not out.torque_limited and out.near == 0.0
    y = regressor(q, dq, out.qdot_r, out.qddot_r)
    jac = jacobian(q, PARAMS.l1, PARAMS.l2)
    expected = (y @ (0.7 * THETA) - np.array(SCARA_GAINS.ks) * out.s
                - SCARA_GAINS.kp * jac.T @ out.weighted_task_variable)
    np.testing.assert_allclose(out.tau_requested, expected, atol=1e-12)
    np.testing.assert_allclose(out.s, dq - out.qdot_r, atol=1e-15)
    assert law.adapt()
    np.testing.assert_allclose(
        law.theta_hat, np.clip(0.7 * THETA - DT * np.array(SCARA_GAINS.adaptation) * (y.T @ out.s),
                               SCARA.theta_lower, SCARA.theta_upper), atol=1e-15)


def test_at_rest_in_the_region_the_law_commands_nothing_and_v_is_zero():
    law = controller()
    out = law.step(Q, np.zeros(2), hand(TIP + [0.01, 0.0]), ActiveTask(FOLLOW, 1.0), DT)
    assert not out.fault and out.distance == pytest.approx(0.01)
    np.testing.assert_allclose(out.tau, 0.0, atol=1e-12)
    assert law.lyapunov(out, Q, ActiveTask(FOLLOW, 1.0), SCARA) == pytest.approx(0.0, abs=1e-12)


def test_the_task_velocity_points_to_the_target_at_k_times_the_slope_under_the_cap():
    law = controller(theta_hat0=0.7 * THETA)
    target = np.array([0.45, 0.05])
    out = law.step(Q, np.zeros(2), hand(target), ActiveTask(FOLLOW, 1.0), DT)
    distance = float(np.linalg.norm(TIP - target))
    pull = math.exp(math.log(law.task_gain(FOLLOW)) + float(log_potential_slope(distance,
                                                                               FOLLOW)))
    assert pull > SCARA_GAINS.max_task_speed
    towards = (target - TIP) / distance
    assert out.weighted_task_variable @ -towards == pytest.approx(
        speed_cap(pull, SCARA_GAINS.max_task_speed)[0], rel=1e-9)
    assert not np.allclose(law.theta_hat, 0.7 * THETA)  # it adapted
    assert out.task_gain == law.task_gain(FOLLOW) > 0.0


def test_a_huge_avoidance_gradient_gives_a_bounded_torque():
    law = controller()
    # Table I's avoid row: P ~ 1e124 here, K ~ 1e-126 m^2/s; the push is an ordinary speed.
    for offset in (1e-9, 0.01, 0.05, 0.1):
        out = law.step(Q, np.zeros(2), hand(TIP + [offset, 0.0]), ActiveTask(AVOID, 1.0), DT)
        assert not out.fault
        assert np.all(np.isfinite(out.tau)) and np.max(np.abs(out.tau)) <= 20.0
        pull = math.exp(math.log(law.task_gain(AVOID)) + float(log_potential_slope(offset,
                                                                                  AVOID)))
        assert np.linalg.norm(out.weighted_task_variable) == pytest.approx(
            speed_cap(pull, SCARA_GAINS.max_task_speed)[0], rel=1e-9)


def test_the_effort_limit_scales_the_torque_and_keeps_its_direction():
    law = controller(effort_limit=0.5)
    out = law.step(Q, np.array([3.0, -3.0]), hand([0.45, 0.05]), ActiveTask(FOLLOW, 1.0), DT)
    assert out.torque_limited and np.max(np.abs(out.tau)) == pytest.approx(0.5)
    np.testing.assert_allclose(out.tau / np.linalg.norm(out.tau),
                               out.tau_requested / np.linalg.norm(out.tau_requested))


def test_non_finite_state_and_singular_jacobian_are_faults_not_crashes():
    law = controller(theta_hat0=0.7 * THETA)
    before = law.theta_hat
    out = law.step(np.array([np.nan, 1.0]), np.zeros(2), hand(TIP), ActiveTask(FOLLOW, 1.0), DT)
    assert out.fault and not np.any(out.tau)
    np.testing.assert_array_equal(law.theta_hat, before)
    stiff = controller(damping=DampingSettings(threshold=0.05, max_damping=0.0))
    out = stiff.step(np.array([0.0, 0.0]), np.zeros(2), hand([0.3, 0.0]),
                     ActiveTask(FOLLOW, 1.0), DT)
    assert out.fault and 'singular' in out.fault_reason and not np.any(out.tau)


def test_the_projection_keeps_theta_hat_in_the_models_box():
    law = controller(theta_hat0=SCARA.theta_lower)
    rng = np.random.default_rng(8)
    for _ in range(200):
        q = rng.uniform(SCARA.limits.lower + 0.2, SCARA.limits.upper - 0.2)
        law.step(q, rng.normal(size=2) * 4.0, hand(rng.uniform(0.2, 0.5, 2), rng.normal(size=2)),
                 ActiveTask(FOLLOW, 1.0), 1e-2)
        assert np.all(law.theta_hat >= SCARA.theta_lower)
        assert np.all(law.theta_hat <= SCARA.theta_upper)


def test_without_a_task_the_arm_tracks_the_hands_velocity_only():
    law = controller()
    q = np.array([0.2, 1.2])
    out = law.step(q, np.zeros(2), hand([5.0, 5.0], [0.1, 0.0]), None, DT)
    np.testing.assert_allclose(out.qdot_r,
                               np.linalg.solve(jacobian(q, PARAMS.l1, PARAMS.l2), [0.1, 0.0]))
    assert out.task_gain == 0.0


def test_the_predicted_rate_is_eq_22():
    s, task = np.array([0.1, -0.3]), np.array([0.05, 0.02])
    rate = predicted_lyapunov_rate(s, task, 0.7, 0.4, (20.0, 4.0), 10.0, (1.0, 0.5),
                                   np.zeros(2))
    expected = -(21.0 * 0.01 + 4.5 * 0.09) - 10.0 * (0.05 ** 2 + 0.02 ** 2) + 10.0 * 0.7 * 0.4
    assert rate == pytest.approx(expected)


def test_the_gravity_hold_of_the_horizontal_arm_is_zero():
    np.testing.assert_array_equal(controller().gravity_hold(Q), 0.0)
