"""Closed-loop tests on the SCARA: event weight + adaptive law + its dynamics (eq. 13-23), no ROS.

The controller starts from a wrong parameter estimate (50-100 % off) unless stated; the arm
starts at q = (0, pi/2), end-effector (0.35, 0.30) m, at rest, with no task (a = 0), and an
event at t = 0 fades the task in over 1 s.
"""

import dataclasses

import numpy as np
import pytest

from hri_adaptive_controller.arm_law import SCARA_GAINS as DEFAULT_GAINS
from hri_adaptive_controller.closed_loop import (
    LoopConditions,
    minimum_jerk_target,
    path_target,
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
from hri_core.robot_model import ScaraModel

TASKS = {
    'follow': TaskShape(1, 1.291, 13.66, 0.0, 0.041),
    'avoid': TaskShape(1, 0.056, 25.46, 0.183, 2.0),
    'follow_safe': TaskShape(1, 1.576, 30.78, 0.183, 0.271),
}
PARAMS = ScaraParameters()
SCARA = ScaraModel(PARAMS)
THETA = dynamic_parameters(PARAMS)
WRONG_THETA = THETA * np.array([0.5, 1.6, 2.0, 0.3, 2.0, 1.0, 1.0])
DT = 1e-3


def run(task, target, duration=5.0, theta_hat0=WRONG_THETA, monitor=True):
    return simulate(TASKS, [(0.0, task)], target, duration,
                    LoopConditions(arm=SCARA, theta_hat0=theta_hat0, dt=DT, monitor=monitor))


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
    assert np.max(np.abs(result.tau)) <= SCARA.limits.effort[0] + 1e-12


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
    result = simulate(TASKS, events, target, 8.0,
                      LoopConditions(arm=SCARA, theta_hat0=WRONG_THETA, monitor=False))
    assert_torque_safe(result)
    assert np.all((result.weight >= 0.0) & (result.weight <= 1.0))
    assert result.active_task[-1] == 'follow_safe' and result.phase[-1] == 'active'
    shape = TASKS['follow_safe']
    assert shape.d1 <= result.distance[-1] <= shape.d2


def test_theta_hat_stays_in_the_projection_box(follow):
    lower = SCARA.theta_lower
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
        simulate(TASKS, [], still_target([0.4, 0.1]), 1.0,
                 LoopConditions(initial_task='dance'))
    with pytest.raises(ValueError, match='target_period'):
        simulate(TASKS, [], still_target([0.4, 0.1]), 1.0, LoopConditions(target_period=0.0))
    with pytest.raises(ValueError, match='command_delay'):
        simulate(TASKS, [], still_target([0.4, 0.1]), 1.0, LoopConditions(command_delay=-1))
    with pytest.raises(ValueError, match='control_period'):
        simulate(TASKS, [], still_target([0.4, 0.1]), 1.0, LoopConditions(control_period=0))
    with pytest.raises(ValueError, match='duration'):
        minimum_jerk_target([0.0, 0.0], [1.0, 1.0], 0.0, -1.0)


# -- continuity of the torque and avoid's behaviour (Table I's and the demo's learned rows) ----

# Table I's rows (no K: hri_core.potential.default_task_gain) and the rows the demo learned
# (README's Table I, with their K), as (shape, K).
ROWS = {
    'table_i': {name: (shape, 0.0) for name, shape in TASKS.items()},
    'learned': {
        'follow': (TaskShape(1, 6.028, 1000.0, 0.0, 0.055), 0.1381),
        'avoid': (TaskShape(1, 44.49, 0.001, 0.165, 2.0), 1.502e4),
        'follow_safe': (TaskShape(1, 3.537, 20.1, 0.165, 0.285), 0.08706),
    },
}
MAX_EFFORT_STEP = 1.0  # N m between two consecutive 1 kHz cycles
# The law alone: the rate limit after the clamp (max_effort_rate, 1 N m per cycle) would
# otherwise hold every continuity bound below by construction.
UNLIMITED = dataclasses.replace(DEFAULT_GAINS, max_effort_rate=1e9)
ARM = np.array([0.35, 0.30])  # m, the end-effector at q = (0, pi/2)
REACH_IN_SPEED = 0.5  # m/s, peak speed of a hand reaching in


def run_rows(rows, events, target, duration, until=None, **kwargs):
    tasks = {name: shape for name, (shape, _) in rows.items()}
    gains = {name: k for name, (_, k) in rows.items()}
    return simulate(tasks, events, target, duration, LoopConditions(
        arm=SCARA, theta_hat0=WRONG_THETA, dt=DT, monitor=False, task_gains=gains,
        **kwargs), until=until)


def reach_in(stop_distance, leave_at=None, leave_speed=0.2, away=(0.35, 0.0)):
    """A hand 0.3 m from the arm that reaches in at REACH_IN_SPEED to `stop_distance` m of
    it at t = 0.5 s, and leaves (to the arm + `away`... far) at `leave_at` s."""
    moves = [(0.5, ARM + [0.0, -stop_distance], REACH_IN_SPEED)]
    if leave_at is not None:
        moves.append((leave_at, ARM + [0.0, -0.45], leave_speed))
    return path_target(ARM + [0.0, -0.30], moves)


SCENARIOS = {
    # Entry from full speed: the arm 0.3 m from a still hand, the task faded in at t = 0.
    'follow_entry': ([(0.0, 'follow')], still_target(ARM + [0.0, -0.30]), 3.5),
    'follow_safe_from_far': ([(0.0, 'follow_safe')], still_target(ARM + [-0.45, 0.0]), 4.0),
    'follow_safe_from_near': ([(0.0, 'follow_safe')], still_target(ARM + [0.06, 0.0]), 3.0),
    # The hand reaches in at 0.5 m/s to 8 cm: the arm is pushed out through d1.
    'avoid_reach_in': ([(0.0, 'avoid')], reach_in(0.08), 3.0),
    # Every switch: follow settles at the hand, avoid pushes the arm out through d1 at speed,
    # follow_safe brings it in again.
    'switches': ([(0.0, 'follow'), (3.0, 'avoid'), (6.0, 'follow_safe'), (8.0, 'follow')],
                 still_target(ARM + [0.0, -0.25]), 10.0),
    # A task-state timeout: the task fades out (over task_fade_time, 1 s) at full speed.
    'timeout': ([(0.0, 'follow'), (1.3, None)], still_target(ARM + [0.0, -0.30]), 3.0),
}


@pytest.mark.parametrize('scenario', sorted(SCENARIOS))
@pytest.mark.parametrize('rows', sorted(ROWS))
def test_effort_changes_at_most_1_nm_per_cycle(rows, scenario):
    events, target, duration = SCENARIOS[scenario]
    result = run_rows(ROWS[rows], events, target, duration, gains=UNLIMITED)
    assert_torque_safe(result)
    steps = np.max(np.abs(np.diff(result.tau, axis=0)), axis=1)
    assert np.max(steps) <= MAX_EFFORT_STEP, (rows, scenario, float(np.max(steps)),
                                               float(result.time[1 + np.argmax(steps)]))
    # The scenario did what it is named for: the arm moved at the task speed (the learned
    # follow row's own approach speed: its pull 0.2 m out, 0.09 m/s).
    speed = np.linalg.norm(np.diff(result.position, axis=0), axis=1) / DT
    assert np.max(speed) >= 0.09


def largest_effort_step(result) -> float:
    return float(np.max(np.abs(np.diff(result.tau, axis=0))))


@pytest.mark.parametrize('rows', sorted(ROWS))
def test_a_100_hz_hand_through_the_controllers_hold_steps_the_torque_no_more(rows):
    # The node sees the hand at 100 Hz (hand_sim) through signal_hold.HandHold. Each message
    # lands ~1 mm off the held hand at 0.5 m/s; held without the blend, the 0.5 m/s reach-in
    # stepped the law's torque by 0.45 (Table I) / 0.32 N m (learned) per cycle, against
    # 0.25 with the exact hand; with it, within 0.05 N m of the exact hand (before the
    # retreat).
    events, target, duration = SCENARIOS['avoid_reach_in']
    exact = run_rows(ROWS[rows], events, target, duration, gains=UNLIMITED)
    sampled = run_rows(ROWS[rows], events, target, duration, gains=UNLIMITED,
                       target_period=0.01)
    # The avoid task reads the hand's velocity through a second-order filter (its retreat and
    # rest terms): with it, 0.12-0.14 N m against 0.07 N m with the exact hand.
    assert largest_effort_step(sampled) <= largest_effort_step(exact) + 0.1
    assert np.min(sampled.distance) < ROWS[rows]['avoid'][0].d1 + 0.03  # it reached in


def test_a_loop_10_ms_late_steps_the_torque_by_less_than_1_nm_per_cycle():
    # A command applied 10 cycles after its state (the node on a loaded machine): the law's
    # largest step per cycle at the 0.5 m/s reach-in grows from 0.25 to about 0.4 N m.
    events, target, duration = SCENARIOS['avoid_reach_in']
    late = run_rows(ROWS['table_i'], events, target, duration, gains=UNLIMITED,
                    command_delay=10)
    assert largest_effort_step(late) <= 0.5 * MAX_EFFORT_STEP


def test_the_rate_limit_turns_a_torque_step_into_a_ramp():
    # No task, the arm at rest, the hand far: a ramp of a from a = 0 with a 20 ms fade
    # asks for a fast torque rise; the limit holds it to max_effort_rate.
    slow = dataclasses.replace(DEFAULT_GAINS, max_effort_rate=200.0)
    events = [(0.0, 'follow')]
    free = run_rows(ROWS['table_i'], events, still_target(ARM + [0.0, -0.3]), 0.3,
                    gains=UNLIMITED, ramp_time=0.02)
    limited = run_rows(ROWS['table_i'], events, still_target(ARM + [0.0, -0.3]), 0.3,
                       gains=slow, ramp_time=0.02)
    assert largest_effort_step(free) > 0.2
    assert largest_effort_step(limited) <= 0.2 + 1e-12


@pytest.mark.parametrize('rows', sorted(ROWS))
def test_avoid_backs_away_from_a_hand_that_reaches_in_and_returns_to_rest(rows):
    shape = ROWS[rows]['avoid'][0]
    # The hand stops 8 cm from the arm at 0.5 + 1.875 * 0.22 / 0.5 = 1.325 s, leaves at 3.5 s.
    stop = 0.5 + 1.875 * 0.22 / REACH_IN_SPEED
    leave = 3.5
    gone = leave + 1.875 * 0.37 / 0.2
    result = run_rows(ROWS[rows], [], reach_in(0.08, leave_at=leave), gone + 3.0,
                      initial_task='avoid')
    # The hand reached in to the arm's edge; the arm backed away as fast as it came (the
    # retreat, task_variable.retreat_term), so it never got inside d1 - 2 cm.
    assert np.min(result.distance) < shape.d1 + 0.03
    assert np.min(result.distance) >= shape.d1 - 0.02
    settled = (result.time >= stop + 2.0) & (result.time < leave)
    assert np.all(result.distance[settled] >= shape.d1 - 0.02)
    offset = np.linalg.norm(result.position - ARM, axis=1)
    assert np.max(offset) > 0.05  # the arm backed away
    assert offset[-1] <= 0.01  # back at rest 3 s after the hand is gone
    assert_torque_safe(result)


@pytest.mark.parametrize('rows', sorted(ROWS))
def test_avoid_does_not_follow_a_hand_that_walks_away(rows):
    # The hand, outside d1, walks 0.2 m further away at 0.1 m/s.
    target = path_target(ARM + [0.0, -0.22], [(0.5, ARM + [0.0, -0.42], 0.1)])
    result = run_rows(ROWS[rows], [], target, 5.0, initial_task='avoid')
    assert np.max(np.linalg.norm(result.position - ARM, axis=1)) <= 0.05


@pytest.mark.parametrize('rows', sorted(ROWS))
def test_avoid_returns_to_rest_after_a_hand_comes_to_10_cm_and_leaves(rows):
    target = path_target(ARM + [0.0, -0.30], [(0.5, ARM + [0.0, -0.10], 0.2),
                                              (3.0, ARM + [0.0, -0.45], 0.2)])
    gone = 3.0 + 1.875 * 0.35 / 0.2
    result = run_rows(ROWS[rows], [], target, gone + 3.0, initial_task='avoid')
    offset = np.linalg.norm(result.position - ARM, axis=1)
    assert np.max(offset) > 0.03 and offset[-1] <= 0.01


def test_avoid_returns_to_a_given_rest_position():
    rest = ARM + [0.05, 0.0]
    result = run_rows(ROWS['table_i'], [], still_target(ARM + [0.0, -0.4]), 3.0,
                      initial_task='avoid', rest_position=rest)
    assert np.linalg.norm(result.position[-1] - rest) <= 0.01


def test_follow_feeds_the_hand_velocity_forward():
    # The hand walks 0.25 m at 0.1 m/s once the arm is in the region: the arm keeps up. (It
    # ends 0.224 m from the base, where the arm reaches with joint 2 near its limit; 0.3 m
    # took it into the hole round the base, 0.206 m out, which the arm cannot reach.)
    shape = TASKS['follow']
    target = path_target(ARM + [0.0, -0.1], [(3.0, ARM + [-0.25, -0.1], 0.1)])
    result = run_rows(ROWS['table_i'], [(0.0, 'follow')], target, 9.0)
    moving = result.time >= 3.0
    assert np.max(result.distance[moving]) <= shape.d2 + 0.01
    assert result.distance[-1] <= shape.d2


def test_follow_times_to_region_change_with_a1_a2():
    # The same K, a1 and a2 four times larger: the pull differs, and so does the time.
    shape, k = ROWS['learned']['follow']
    times = []
    for scale in (1.0, 4.0):
        steeper = TaskShape(1, scale * shape.a1, scale * shape.a2, shape.d1, shape.d2)
        result = run_rows({'follow': (steeper, k)}, [], still_target(ARM + [0.0, -0.25]),
                          3.0, initial_task='follow')
        inside = np.flatnonzero(result.distance <= shape.d2)
        assert inside.size
        times.append(result.time[inside[0]])
    assert abs(times[0] - times[1]) >= 0.15 * max(times)


def test_a_slower_demonstration_gives_a_slower_approach():
    # The demo's learned follow row with its K, K / 4 (a demonstration four times slower)
    # and K / 16: from 0.25 m to the region, >= 2.5 times as long for K / 4 (the approach
    # floor follows the task's own pull, task_variable.task_approach_speed), and even K / 16
    # gets there (the floor's least speed, MIN_APPROACH_SPEED).
    shape, k = ROWS['learned']['follow']
    times = []
    for divisor in (1.0, 4.0, 16.0):
        # Up to 30 s, ended once in the region (18 s for K / 16).
        result = run_rows({'follow': (shape, k / divisor)}, [],
                          still_target(ARM + [0.0, -0.25]), 30.0, initial_task='follow',
                          until=lambda _, distance: distance <= shape.d2)
        first = np.argmax(result.distance <= result.distance[0] - 0.002)
        inside = np.flatnonzero(result.distance <= shape.d2)
        assert inside.size, divisor
        times.append(result.time[inside[0]] - result.time[first])
    assert times[1] >= 2.5 * times[0], times
    assert times[2] >= times[1]


def test_until_ends_the_run_after_the_step_it_holds_for():
    shape, k = ROWS['learned']['follow']
    result = run_rows({'follow': (shape, k)}, [], still_target(ARM + [0.0, -0.25]), 1.0,
                      initial_task='follow', until=lambda t, _: t >= 0.05 - 1e-12)
    assert result.time.size == round(0.05 / DT) + 1
    assert result.tau.shape[0] == result.distance.size == result.theta_hat.shape[0] == \
        result.phase.size == result.time.size
    assert np.all(np.isfinite(result.distance))
