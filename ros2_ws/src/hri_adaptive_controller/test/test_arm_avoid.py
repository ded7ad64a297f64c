"""Unit tests of arm_law's avoid tasks (return to rest, retreat from an approaching hand),
its reach-round blend and its eq. 22 monitor, on the Panda in the pure loop (RK4 at 1 kHz,
a perturbed 'true' arm, theta_hat from 70 % of the URDF's values)."""

import numpy as np
import pytest

from hri_adaptive_controller.arm_law import (
    PANDA_GAINS,
    ActiveTask,
    ArmController,
    HandState,
)
from hri_adaptive_controller.controller_node import rest_position_from
from hri_adaptive_controller.event_weight import quintic_smoothstep
from hri_adaptive_controller.joint_limits import ReachRound
from hri_adaptive_controller.task_variable import rest_term, retreat_term
from hri_core.potential import TaskShape
from hri_core.robot_model import ScaraModel, robot_model

AVOID = TaskShape(1, 0.056, 25.46, 0.183, 2.0)  # Table I's rows
FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)
DT = 1e-3
FRICTION = 0.05  # N m s/rad, the true arm's


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


def true_arm(nominal, seed):
    """The 'true' Panda: link inertias 15 % off the URDF's, friction FRICTION."""
    rng = np.random.default_rng(seed)
    return nominal.with_inertias(rng.uniform(0.85, 1.15, nominal.dof),
                                 np.full(nominal.dof, FRICTION))


def moving_hand(start, end, start_time, peak_speed):
    """A hand at `start` (3,) m that makes a minimum-jerk move to `end` from start_time (s) at
    the given peak speed (m/s): t -> HandState."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    step = end - start
    duration = 1.875 * float(np.linalg.norm(step)) / peak_speed

    def hand(t):
        s, ds, dds = quintic_smoothstep((t - start_time) / duration)
        return HandState(start + s * step, ds / duration * step, dds / duration ** 2 * step)

    return hand


def run(nominal, hand, task, duration, seed, gains=PANDA_GAINS, rest=None, monitor=False,
        after=False):
    """The Panda from home under `task` (a = 1) with the hand(t); per-step records. after:
    the law's finish_cycle after each step, as the controller calls it."""
    true = true_arm(nominal, seed)
    controller = ArmController(nominal, gains, theta_hat0=0.7 * nominal.theta)
    q, dq = nominal.home.copy(), np.zeros(nominal.dof)
    record = {key: [] for key in ('distance', 'position', 'tau', 'near', 'V', 'rate', 'exact')}
    if after:
        controller.finish_cycle()  # from the first command on
    for i in range(round(duration / DT)):
        out = controller.step(q, dq, hand(i * DT), task, DT, rest)
        assert not out.fault, out.fault_reason
        if after:
            controller.finish_cycle()
        for key, value in (('distance', out.distance), ('position', out.position),
                           ('tau', out.tau), ('near', out.near)):
            record[key].append(value)
        if monitor:
            record['V'].append(controller.lyapunov(out, q, task, true))
            record['rate'].append(controller.lyapunov_rate(out, task,
                                                           np.full(nominal.dof, FRICTION)))
            record['exact'].append(out.damping == 0.0 and out.near == 0.0
                                   and not out.torque_limited)
        q, dq = true.rk4_step(q, dq, out.tau, DT)
    return {key: np.array(value) for key, value in record.items()}


def longest_run(mask) -> float:
    """The longest stretch (s) where mask (per step) holds."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return float(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1),
                        initial=0)) * DT


def test_avoid_returns_to_its_rest_position_once_outside_the_region(panda):
    """A still hand 0.4 m off (outside d1 and the return's gate): the tool goes to a rest
    position 8 cm away (given, 3 values); a still hand 10 cm off (inside d1): the tool leaves
    the region and the return holds it at the gate, not drifting further away."""
    tool = panda.tool_position(panda.home)
    rest = tool + [0.0, 0.08, 0.0]
    far = HandState(tool + [0.0, -0.4, 0.0], np.zeros(3), np.zeros(3))
    result = run(panda, lambda t: far, ActiveTask(AVOID, 1.0), 2.5, seed=11, rest=rest)
    miss = np.linalg.norm(result['position'] - rest, axis=1)
    assert miss[0] > 0.07 and miss[-1] <= 0.01, miss[-1]
    assert np.all(np.abs(result['tau']) <= panda.limits.effort)

    near = HandState(tool + [0.0, -0.10, 0.0], np.zeros(3), np.zeros(3))
    result = run(panda, lambda t: near, ActiveTask(AVOID, 1.0), 2.5, seed=12, rest=tool)
    drive = ArmController(panda, PANDA_GAINS).drive(AVOID)
    gate_end = drive.rest_gate_start() + drive.rest_gate
    assert result['distance'][-1] >= AVOID.d1  # out of the region
    assert result['distance'][-1] <= gate_end  # and held back towards rest within the gate
    assert np.linalg.norm(result['position'][-1] - tool) < gate_end - 0.10


def test_avoid_retreats_from_a_hand_approaching_at_0_4_m_s(panda):
    """The hand comes at the tool from 0.45 m at 0.4 m/s (minimum jerk, peak) and ends 0.3 m
    beyond the tool's start: the arm backs away as fast as it comes and the tool stays
    outside d1 - 3 cm throughout; efforts within the limits, steps <= 1 N m per cycle."""
    tool = panda.tool_position(panda.home)
    hand = moving_hand(tool + [0.0, 0.45, 0.0], tool + [0.0, -0.3, 0.0], 0.1, 0.4)
    result = run(panda, hand, ActiveTask(AVOID, 1.0), 4.0, seed=13)
    assert result['distance'].min() >= AVOID.d1 - 0.03, result['distance'].min()
    assert np.linalg.norm(result['position'][-1] - tool) > 0.25  # it did back away
    assert np.all(np.abs(result['tau']) <= panda.limits.effort)
    assert np.abs(np.diff(result['tau'], axis=0)).max() <= 1.0


@pytest.mark.parametrize('after', [False, True])
def test_follow_reaches_round_behind_the_base_without_stalling_at_a_limit(
        panda, after, monkeypatch):
    """A hand behind the base (x < 0): the straight descent leans the arm back into joint 2's
    and joint 6's bands and stalls there 14 cm short (reach_round off); the blend takes the
    joints to an inverse-kinematics pose instead: no stall in a band over 1 s (0.33 s
    measured), and the tool in the follow region within 4 s (2.3 s). The same with the
    solves after each command (finish_cycle, as the controller runs them): no command then
    runs the model's inverse kinematics (the engaging solve 0.9-1.1 ms, a whole period)."""
    solves = {True: 0, False: 0}  # the model's solves inside a step, and outside
    in_step = [False]
    step, solve = ArmController.step, type(panda).inverse_kinematics

    def counted_step(self, *args):
        in_step[0] = True
        try:
            return step(self, *args)
        finally:
            in_step[0] = False

    def counted_solve(self, *args):
        solves[in_step[0]] += 1
        return solve(self, *args)

    monkeypatch.setattr(ArmController, 'step', counted_step)
    monkeypatch.setattr(type(panda), 'inverse_kinematics', counted_solve)
    hand = HandState(np.array([-0.35, 0.0, 0.5]), np.zeros(3), np.zeros(3))
    result = run(panda, lambda t: hand, ActiveTask(FOLLOW, 1.0), 4.0, seed=14, after=after)
    if after:
        assert solves[True] == 0 and solves[False] >= 10, solves
    else:
        assert solves[True] >= 10 and solves[False] == 0, solves
    stalled = (result['near'] > ReachRound.NEAR_BARRIER) & (
        result['distance'] > ReachRound.FAR_GOAL)
    assert longest_run(stalled) <= 1.0, longest_run(stalled)
    assert result['distance'][-1] <= FOLLOW.d2, result['distance'][-1]
    assert np.all(np.abs(result['tau']) <= panda.limits.effort)
    # The blend is continuous: after the task's own start (a = 1 at once here), the law
    # alone steps the effort by <= 1 N m per cycle (0.83 measured).
    assert np.abs(np.diff(result['tau'][100:], axis=0)).max() <= 1.0


def test_the_monitor_predicts_dv_dt_while_a_hand_pushes_into_an_avoid_task(panda):
    """eq. 22 with the avoid term Kp v_e^T w (w = f xdot_f + a (v_rest + v_away) - xdot_d):
    the hand reaches in from 0.15 m to 0.03 m of the tool at 0.4 m/s, faster than the
    potential alone pushes the arm. Where J+ is exact and off the bands, the prediction
    matches the central difference of V to 2 % of its largest value (0.6 % measured); without
    the avoid term it is off by 9 %."""
    tool = panda.tool_position(panda.home)
    hand = moving_hand(tool + [0.0, -0.15, 0.0], tool + [0.0, -0.03, 0.0], 0.2, 0.4)
    result = run(panda, hand, ActiveTask(AVOID, 1.0), 1.2, seed=15, rest=tool, monitor=True)
    value, rate, exact = result['V'], result['rate'], result['exact']
    measured, predicted = (value[2:] - value[:-2]) / (2.0 * DT), rate[1:-1]
    pushed = (result['distance'][1:-1] < AVOID.d1) & exact[:-2] & exact[1:-1] & exact[2:]
    assert np.count_nonzero(pushed) >= 100
    scale = np.max(np.abs(measured[pushed]))
    assert scale > 0.05
    error = np.max(np.abs(measured[pushed] - predicted[pushed]))
    assert error <= 0.02 * scale, (error, scale)


def test_rest_position_takes_2_values_for_the_scara_and_3_for_an_arm(panda):
    scara = ScaraModel()
    assert rest_position_from({'rest_position': None}, panda) is None
    assert rest_position_from({'rest_position': [0.3, 0.1, 0.5]}, panda) == (0.3, 0.1, 0.5)
    assert rest_position_from({'rest_position': [0.35, 0.3]}, scara) == (0.35, 0.3)
    with pytest.raises(ValueError, match=r'must have 3 values \[x, y, z\] \(m\) for panda, '
                       'got 2'):
        rest_position_from({'rest_position': [0.35, 0.3]}, panda)
    with pytest.raises(ValueError, match=r'must have 2 values \[x, y\] \(m\) for scara'):
        rest_position_from({'rest_position': [0.3, 0.1, 0.5]}, scara)


def test_the_rest_and_retreat_terms_in_3d_are_the_planar_ones_in_the_plane(panda):
    rng = np.random.default_rng(16)
    drive = ArmController(panda, PANDA_GAINS).drive(AVOID)
    active = 0
    for _ in range(300):
        vectors = [rng.uniform(-0.3, 0.3, 2) for _ in range(6)]
        planar = [v.tolist() for v in vectors]
        lift = [np.array([*v, 0.0]).tolist() for v in vectors]
        for terms in ((rest_term(*planar[:4], drive), rest_term(*lift[:4], drive)),
                      (retreat_term(planar[0], planar[2], *planar[4:], drive),
                       retreat_term(lift[0], lift[2], *lift[4:], drive))):
            flat, spatial = terms
            assert (flat is None) == (spatial is None)
            if flat is not None:
                np.testing.assert_allclose(spatial, [[*flat[0], 0.0], [*flat[1], 0.0]],
                                           atol=1e-12)
        active += rest_term(*lift[:4], drive) is not None and retreat_term(
            lift[0], lift[2], *lift[4:], drive) is not None
    assert active >= 10  # both terms were compared where they act
