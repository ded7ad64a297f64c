"""Closed-loop tests: event weight + adaptive controller + SCARA dynamics (eq. 13-23), no ROS.

The controller starts from a wrong parameter estimate (50-100 % off) unless stated; the arm
starts at q = (0, pi/2), end-effector (0.35, 0.30) m, at rest, with no task (a = 0), and an
event at t = 0 fades the task in over 1 s.
"""

import numpy as np
import pytest

from hri_adaptive_controller.adaptive_law import DEFAULT_GAINS
from hri_adaptive_controller.closed_loop import (
    minimum_jerk_target,
    simulate,
    still_target,
)
from hri_core.dynamics import (
    ScaraParameters,
    dynamic_parameters,
    jacobian,
    mass_matrix,
)
from hri_core.potential import TaskShape

TASKS = {
    'follow': TaskShape(1, 1.291, 13.66, 0.0, 0.041),
    'avoid': TaskShape(1, 0.056, 25.46, 0.183, 2.0),
    'follow_safe': TaskShape(1, 1.576, 30.78, 0.183, 0.271),
}
PARAMS = ScaraParameters()
THETA = dynamic_parameters(PARAMS)
WRONG_THETA = THETA * np.array([0.5, 1.6, 2.0, 0.3, 2.0, 1.0, 1.0])
DT = 1e-3


def run(task, target, duration=5.0, theta_hat0=WRONG_THETA, monitor=True):
    return simulate(TASKS, [(0.0, task)], target, duration, params=PARAMS,
                    theta_hat0=theta_hat0, dt=DT, monitor=monitor)


@pytest.fixture(scope='module')
def follow():
    return run('follow', still_target([0.45, 0.05]))


@pytest.fixture(scope='module')
def follow_safe_too_close():
    return run('follow_safe', still_target([0.40, 0.25]))


@pytest.fixture(scope='module')
def follow_safe_too_far():
    return run('follow_safe', still_target([0.60, -0.05]))


@pytest.fixture(scope='module')
def avoid():
    # The hand starts 0.12 m from the end-effector (inside d1), approaches, then stops.
    return run('avoid', minimum_jerk_target([0.45, 0.23], [0.40, 0.27], 2.0, 1.0))


def time_goal_reached(result, goal):
    """First time after which `goal(distance)` holds to the end (None if it never does)."""
    failing = np.flatnonzero(~goal(result.distance))
    if failing.size == 0:
        return 0.0
    if failing[-1] == result.distance.size - 1:
        return None
    return float(result.time[failing[-1] + 1])


def assert_torque_safe(result):
    assert not result.fault.any()
    assert np.all(np.isfinite(result.tau))
    assert np.max(np.abs(result.tau)) <= DEFAULT_GAINS.effort_limit + 1e-12


def eq_23_bound(result):
    """V(0) + Kp * integral of max(da/dt, 0) Q dt: eq. 23 with the Kp a Q term of V."""
    gain = DEFAULT_GAINS.kp * np.maximum(result.weight_rate, 0.0) * result.task_potential * DT
    return result.lyapunov[0] + np.concatenate([[0.0], np.cumsum(gain[:-1])])


def assert_lyapunov_decreases_outside_ramps(result):
    """eq. 22: dV/dt <= 0 where da/dt = 0, J+ is undamped and the torque is not limited."""
    steady = ((result.weight_rate[:-1] == 0.0) & (result.weight_rate[1:] == 0.0)
              & (result.damping[:-1] == 0.0) & ~result.torque_limited[:-1])
    assert np.count_nonzero(steady) > 0.5 * steady.size
    increase = np.diff(result.lyapunov)[steady]
    assert np.max(increase) <= 1e-9
    assert np.all(result.lyapunov_rate[:-1][steady] <= 0.0)  # eq. 22's own prediction


def test_follow_reaches_the_region_of_a_still_target(follow):
    reached = time_goal_reached(follow, lambda d: d <= TASKS['follow'].d2)
    assert reached is not None and reached < 3.0
    assert follow.distance[-1] <= TASKS['follow'].d2
    assert_torque_safe(follow)


def test_follow_lyapunov_function(follow):
    assert np.all(np.isfinite(follow.lyapunov))
    assert np.all(follow.lyapunov <= eq_23_bound(follow) + 1e-3)
    assert_lyapunov_decreases_outside_ramps(follow)


def test_follow_safe_moves_out_to_the_safe_distance(follow_safe_too_close):
    shape = TASKS['follow_safe']
    reached = time_goal_reached(follow_safe_too_close, lambda d: (d >= shape.d1) & (d <= shape.d2))
    assert reached is not None and reached < 3.0
    assert_torque_safe(follow_safe_too_close)
    assert np.all(follow_safe_too_close.lyapunov <= eq_23_bound(follow_safe_too_close) + 1e-3)
    assert_lyapunov_decreases_outside_ramps(follow_safe_too_close)


def test_follow_safe_follows_a_distant_target(follow_safe_too_far):
    shape = TASKS['follow_safe']
    reached = time_goal_reached(follow_safe_too_far, lambda d: (d >= shape.d1) & (d <= shape.d2))
    assert reached is not None and reached < 3.0
    assert_torque_safe(follow_safe_too_far)
    assert np.all(follow_safe_too_far.lyapunov <= eq_23_bound(follow_safe_too_far) + 1e-3)
    assert_lyapunov_decreases_outside_ramps(follow_safe_too_far)


def test_avoid_keeps_the_safe_distance_after_the_hand_stops(avoid):
    shape = TASKS['avoid']
    assert avoid.distance[0] < shape.d1
    reached = time_goal_reached(avoid, lambda d: d >= shape.d1)
    assert reached is not None and reached < 3.0  # the hand stops at t = 3 s
    assert_torque_safe(avoid)


def test_avoid_lyapunov_function_stays_bounded(avoid):
    # Avoidance's dQ/dr steps from 0 to v_max within 1e-13 m at d1: a sampled controller sees
    # the reference velocity jump there, so V may jump by at most the kinetic energy of the
    # reference speed, 1/2 v_max^2 lambda_max(task-space inertia).
    inertia = max(np.max(np.linalg.eigvalsh(
        np.linalg.inv(jacobian(q, PARAMS.l1, PARAMS.l2)).T @ mass_matrix(q, PARAMS)
        @ np.linalg.inv(jacobian(q, PARAMS.l1, PARAMS.l2)))) for q in avoid.q[::50])
    wall = 0.5 * DEFAULT_GAINS.max_task_speed ** 2 * inertia
    assert np.all(np.isfinite(avoid.lyapunov))
    assert np.max(avoid.lyapunov - eq_23_bound(avoid)) <= wall + 1e-3


def test_sliding_variable_vanishes_with_the_true_parameters():
    result = run('follow', still_target([0.45, 0.05]), duration=4.0, theta_hat0=THETA,
                 monitor=False)
    assert np.max(np.abs(result.s)) > 1e-2  # the task made the arm move
    assert np.max(np.abs(result.s[-500:])) < 1e-3
    assert result.distance[-1] <= TASKS['follow'].d2


def test_task_switches_faster_than_the_ramp_stay_safe():
    events = [(0.0, 'follow'), (2.0, 'avoid'), (2.2, 'follow_safe'), (2.3, 'follow'),
              (2.4, 'follow_safe'), (2.45, 'avoid'), (2.5, 'follow_safe')]
    target = minimum_jerk_target([0.45, 0.05], [0.40, 0.20], 3.0, 1.5)
    result = simulate(TASKS, events, target, 8.0, params=PARAMS, theta_hat0=WRONG_THETA,
                      monitor=False)
    assert_torque_safe(result)
    assert np.all((result.weight >= 0.0) & (result.weight <= 1.0))
    assert result.active_task[-1] == 'follow_safe' and result.phase[-1] == 'active'
    shape = TASKS['follow_safe']
    assert shape.d1 <= result.distance[-1] <= shape.d2


def test_theta_hat_stays_in_the_projection_box(follow):
    lower = np.asarray(DEFAULT_GAINS.theta_lower)
    assert np.all(follow.theta_hat >= lower)


def test_targets_have_consistent_derivatives():
    target = minimum_jerk_target([0.4, 0.1], [0.3, 0.3], 1.0, 2.0)
    h = 1e-6
    for t in np.linspace(0.5, 3.5, 13):
        x, v, a = target(t)
        np.testing.assert_allclose((target(t + h)[0] - target(t - h)[0]) / (2 * h), v,
                                   atol=1e-8)
        np.testing.assert_allclose((target(t + h)[1] - target(t - h)[1]) / (2 * h), a,
                                   atol=1e-6)
    np.testing.assert_allclose(target(10.0)[0], [0.3, 0.3])
    x, v, a = still_target([0.1, 0.2])(3.0)
    np.testing.assert_array_equal(x, [0.1, 0.2])
    assert not v.any() and not a.any()


def test_simulate_rejects_bad_input():
    with pytest.raises(ValueError, match='unknown task'):
        simulate(TASKS, [(0.0, 'dance')], still_target([0.4, 0.1]), 1.0)
    with pytest.raises(ValueError, match='duration'):
        simulate(TASKS, [], still_target([0.4, 0.1]), 0.0)
    with pytest.raises(ValueError, match='initial_task'):
        simulate(TASKS, [], still_target([0.4, 0.1]), 1.0, initial_task='dance')
    with pytest.raises(ValueError, match='duration'):
        minimum_jerk_target([0.0, 0.0], [1.0, 1.0], 0.0, -1.0)
