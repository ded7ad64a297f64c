"""The Lyapunov monitor (dV/dt predicted from the state) against V itself, in a pure loop.

An avoid task's reference drops eq. 14's hand-velocity feed-forward, so dV/dt has the term
Kp v_e^T w besides eq. 22's (arm_law's docstring). These tests run the law's step
(arm_law.ArmController on the SCARA, hri_core.robot_model.ScaraModel) on the simulated arm
(RK4 at 1 ms, the true friction) while a hand reaches in, and compare the monitor
(ArmController.lyapunov_rate) with a central difference of V (ArmController.lyapunov) along
the run.
"""

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
from hri_adaptive_controller.closed_loop import minimum_jerk_target
from hri_core.dynamics import ScaraParameters, dynamic_parameters
from hri_core.potential import TaskShape
from hri_core.robot_model import ScaraModel

PARAMS = ScaraParameters()
ARM = ScaraModel(PARAMS)
THETA = dynamic_parameters(PARAMS)
AVOID = TaskShape(1, 0.056, 25.46, 0.183, 2.0)  # Table I
FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)  # Table I
DT = 1e-3
Q0 = (0.0, math.pi / 2)  # end-effector at (0.35, 0.30) m
HAND_SPEED = 0.2  # m/s, peak


def pure_loop(shape, start, end, duration, hand_speed=HAND_SPEED):
    """Run the control step on the arm with a hand moving from `start` to `end` (offsets from
    the end-effector, m; minimum jerk from t = 0.2 s at `hand_speed` peak), the task active
    with a = 1 throughout. Returns (V, predicted dV/dt, distance, undamped and unlimited,
    hand speed) per 1 ms step."""
    controller = ArmController(ARM, SCARA_GAINS, THETA)
    q, dq = np.array(Q0), np.zeros(2)
    tip = ARM.task_kinematics(q, dq)[0]
    start, end = tip + np.asarray(start), tip + np.asarray(end)
    move_time = 1.875 * float(np.linalg.norm(end - start)) / hand_speed
    hand = minimum_jerk_target(start, end, 0.2, move_time)
    friction = ARM.friction_torque(np.ones(2))  # (b1, b2): F's diagonal
    task = ActiveTask(shape, 1.0, 0.0)
    rows = []
    for i in range(int(round(duration / DT))):
        x_d, xdot_d, xddot_d = hand(i * DT)
        out = controller.step(q, dq, HandState(x_d, xdot_d, xddot_d), task, DT, rest=tip)
        assert not out.fault
        exact = out.damping == 0.0 and not out.torque_limited
        rows.append((controller.lyapunov(out, q, task, ARM),
                     controller.lyapunov_rate(out, task, friction), out.distance, exact,
                     float(np.linalg.norm(xdot_d))))
        q, dq = ARM.rk4_step(q, dq, out.tau, DT)
    return np.array(rows, dtype=float).T


def central_difference(values):
    return (values[2:] - values[:-2]) / (2.0 * DT)


def test_monitor_matches_the_change_of_v_while_a_hand_reaches_into_an_avoid_task():
    # The hand starts 0.15 m away (inside d1 = 0.183 m) and reaches in to 0.02 m of the
    # end-effector's start at 0.4 m/s, faster than the arm's retreat: it pushes the arm, and
    # V rises while it does (the hand does work on the task).
    speed = 0.4
    v, rate, distance, exact, hand_speed = pure_loop(AVOID, (0.0, -0.15), (0.0, -0.02), 1.6,
                                                     speed)
    measured, predicted = central_difference(v), rate[1:-1]
    pushed = ((distance[1:-1] < AVOID.d1) & (hand_speed[1:-1] > 0.5 * speed)
              & (exact[:-2] > 0) & (exact[1:-1] > 0) & (exact[2:] > 0))
    assert np.count_nonzero(pushed) >= 100  # the hand pushes the arm for 0.1 s or more
    scale = np.max(np.abs(measured[pushed]))
    assert scale > 0.05  # V changes fast: the check is not of a resting arm
    # Without the feed-forward term the prediction is off by a large part of dV/dt here;
    # with it, by the 1 ms step's discretisation and the hand filter's lag only.
    assert np.max(np.abs(measured[pushed] - predicted[pushed])) <= 0.02 * scale


def test_monitor_matches_the_change_of_v_while_a_follow_task_follows_a_hand():
    # eq. 22 as printed: the follow reference keeps the feed-forward, so no extra term.
    v, rate, distance, exact, hand_speed = pure_loop(FOLLOW, (0.0, -0.15), (0.0, -0.35), 1.6)
    measured, predicted = central_difference(v), rate[1:-1]
    moving = (hand_speed[1:-1] > 0.5 * HAND_SPEED) & (exact[1:-1] > 0)
    assert np.count_nonzero(moving) >= 100
    scale = np.max(np.abs(measured[moving]))
    assert scale > 0.1
    assert np.max(np.abs(measured[moving] - predicted[moving])) <= 0.01 * scale


def test_predicted_rate_adds_kp_times_the_task_velocity_along_the_reference_offset():
    s, task = np.array([0.1, -0.3]), np.array([0.05, 0.02])
    offset = np.array([-0.2, 0.1])
    base = predicted_lyapunov_rate(s, task, 0.7, 0.4, (20.0, 4.0), 10.0, (1.0, 0.5),
                                   np.zeros(2))
    rate = predicted_lyapunov_rate(s, task, 0.7, 0.4, (20.0, 4.0), 10.0, (1.0, 0.5), offset)
    assert rate - base == pytest.approx(10.0 * (0.05 * -0.2 + 0.02 * 0.1))
    # eq. 22 without the offset: -s^T (Ks + F) s - Kp |a delta_eps|^2 + Kp (da/dt) Q.
    assert base == pytest.approx(-(21.0 * 0.01 + 4.5 * 0.09) - 10.0 * (0.0025 + 0.0004)
                                 + 10.0 * 0.7 * 0.4)
