"""Unit tests of arm_law, the one adaptive law for every arm: the Panda in 3-D closed with its
own forward dynamics (RK4 at 1 kHz, a perturbed 'true' arm, theta_hat from a wrong start), and
what the law does alike on the SCARA's two task axes (test_closed_loop runs the SCARA)."""

import dataclasses
import math
from importlib import metadata

import numpy as np
import pytest

from hri_adaptive_controller.arm_law import (
    ADAPTATION_SCALE,
    KS_RATE,
    PANDA_GAINS,
    SCARA_GAINS,
    ActiveTask,
    ArmController,
    ArmGains,
    ClearanceSettings,
    HandState,
    default_arm_ks,
    default_gains,
    task_term,
)
from hri_adaptive_controller.closed_loop import LoopConditions, simulate, still_target
from hri_adaptive_controller.event_weight import quintic_smoothstep
from hri_adaptive_controller.joint_limits import (
    ReachRound,
    ReachRoundSettings,
    barrier,
    barrier_energy,
    gate_feed_forward,
)
from hri_adaptive_controller.task_variable import RETREAT_REACH, task_potential
from hri_core.potential import TaskShape
from hri_core.robot_model import ScaraModel, robot_model

FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)  # Table I's follow row
DT = 1e-3


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


def true_arm(nominal, seed):
    """The 'true' Panda: link inertias 15 % off the URDF's, friction 0.05 N m s/rad."""
    rng = np.random.default_rng(seed)
    return nominal.with_inertias(rng.uniform(0.85, 1.15, nominal.dof), np.full(nominal.dof, 0.05))


def still_hand(nominal, q, seed, distance=0.3):
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    return HandState(nominal.tool_position(q) + distance * direction, np.zeros(3), np.zeros(3))


def run(nominal, seed, duration, monitor=False):
    """The Panda from home following a still hand 0.3 m away; theta_hat from 70 % of the
    URDF's values. Returns per-step distance, tau, V (if monitored), limited flags, q and
    the controller."""
    true = true_arm(nominal, seed)
    controller = ArmController(nominal, PANDA_GAINS, theta_hat0=0.7 * nominal.theta)
    q, dq = nominal.home.copy(), np.zeros(nominal.dof)
    hand = still_hand(nominal, q, seed)
    task = ActiveTask(FOLLOW, 1.0)
    record = {'distance': [], 'tau': [], 'V': [], 'limited': [], 'q': [], 'speed': []}
    for _ in range(round(duration / DT)):
        out = controller.step(q, dq, hand, task, DT)
        assert not out.fault, out.fault_reason
        record['distance'].append(out.distance)
        record['tau'].append(out.tau)
        record['limited'].append(out.torque_limited)
        record['q'].append(q)
        record['speed'].append(float(np.linalg.norm(nominal.tool_jacobian(q) @ dq)))
        if monitor:
            record['V'].append(controller.lyapunov(out, q, task, true))
        q, dq = true.rk4_step(q, dq, out.tau, DT)
    return {key: np.array(value) for key, value in record.items()}, controller


def test_v_does_not_increase_for_a_fixed_region_and_a_still_hand(panda):
    record, controller = run(panda, seed=1, duration=2.0, monitor=True)
    assert not record['limited'].any()
    steps = np.diff(record['V'])
    # eq. 22: dV/dt <= 0 between events; the sampled law (torque held 1 ms) adds O(dt^2).
    assert steps.max() <= 1e-7, steps.max()
    # and V lost at least half its task term Kp a Q(0.3 m) (the parameter term stays).
    task_energy = PANDA_GAINS.kp * task_potential(0.3, controller.drive(FOLLOW))
    assert record['V'][0] - record['V'][-1] > 0.5 * task_energy > 0.0


def test_follows_a_still_hand_and_holds_under_gravity_while_theta_adapts(panda):
    record, controller = run(panda, seed=2, duration=6.0)
    inside = record['distance'] <= FOLLOW.d2
    entered = int(np.argmax(inside))
    assert inside.any() and entered * DT <= 5.0, entered * DT
    assert inside[entered:].all()  # held, with gravity, from the wrong start on
    assert record['speed'][-500:].max() < 1e-3  # at rest in the region
    # theta_hat moved from its start (eq. 19 runs) and the gravity it implies came closer.
    start = 0.7 * panda.theta
    assert np.linalg.norm(controller.theta_hat - start) > 0.01
    q = record['q'][-1]
    gravity_true = true_arm(panda, 2).gravity_torque(q)
    y_static = controller.model.regressor(q, np.zeros(7), np.zeros(7), np.zeros(7))
    assert (np.linalg.norm(y_static @ controller.theta_hat - gravity_true)
            < np.linalg.norm(y_static @ start - gravity_true))
    effort = panda.limits.effort
    assert np.all(np.abs(record['tau']) <= effort + 1e-12)
    # Every joint stays 5 deg off its limits.
    margin = np.minimum(record['q'] - panda.limits.lower, panda.limits.upper - record['q'])
    assert margin.min() > math.radians(5.0)


def test_null_space_motion_leaves_the_tool_velocity_unchanged(panda):
    rng = np.random.default_rng(3)
    still = dataclasses.replace(PANDA_GAINS, posture_gain=0.0)
    task = ActiveTask(FOLLOW, 0.7, 0.3)
    checked = 0
    for _ in range(20):
        q = panda.home + rng.uniform(-0.5, 0.5, 7)
        dq = rng.uniform(-0.3, 0.3, 7)
        hand = HandState(panda.tool_position(q) + rng.uniform(-0.2, 0.2, 3),
                         rng.uniform(-0.1, 0.1, 3), rng.uniform(-0.5, 0.5, 3))
        with_null = ArmController(panda, PANDA_GAINS).step(q, dq, hand, task, DT)
        without = ArmController(panda, still).step(q, dq, hand, task, DT)
        if with_null.damping > 0.0 or with_null.near > 0.0:
            continue  # J+ damped or a barrier band: J N = 0 is claimed only where J+ is exact
        null_motion = with_null.qdot_r - without.qdot_r
        jac = panda.tool_jacobian(q)
        assert np.linalg.norm(null_motion) > 1e-3  # the posture term does move the joints
        assert np.linalg.norm(jac @ null_motion) <= 1e-9
        # and its rate: J (qddot_r - qddot_r') + Jdot (qdot_r - qdot_r') = d/dt (J N z) = 0
        rate = panda.tool_jacobian(q + 1e-7 * dq) - panda.tool_jacobian(q - 1e-7 * dq)
        assert np.linalg.norm(jac @ (with_null.qddot_r - without.qddot_r)
                              + rate / 2e-7 @ null_motion) <= 1e-6
        checked += 1
    assert checked >= 10


def test_the_approach_limit_takes_the_least_joint_motion_and_only_the_excess(panda):
    """limit_approach(row, v): where row qdot_r exceeds v, qdot_r loses the excess along row
    alone (the least joint motion, s follows); where it does not, nothing changes."""
    rng = np.random.default_rng(5)
    task = ActiveTask(FOLLOW, 1.0, 0.0)
    for _ in range(10):
        q = panda.home + rng.uniform(-0.5, 0.5, 7)
        dq = rng.uniform(-0.3, 0.3, 7)
        hand = HandState(panda.tool_position(q) + rng.uniform(-0.2, 0.2, 3), np.zeros(3),
                         np.zeros(3))
        free = ArmController(panda, PANDA_GAINS).command(q, dq, hand, task, DT)
        row = rng.normal(size=7)
        row *= np.sign(row @ free.qdot_r)
        speed = float(row @ free.qdot_r)
        law = ArmController(panda, PANDA_GAINS)
        law.limit_approach(row, 0.25 * speed)
        held = law.command(q, dq, hand, task, DT)
        assert row @ held.qdot_r == pytest.approx(0.25 * speed, abs=1e-12)
        change = held.qdot_r - free.qdot_r
        assert np.linalg.norm(change - (change @ row) / (row @ row) * row) <= 1e-12
        assert np.allclose(held.s, dq - held.qdot_r, atol=1e-12)
        law = ArmController(panda, PANDA_GAINS)
        law.limit_approach(row, 2.0 * speed)
        assert np.array_equal(law.command(q, dq, hand, task, DT).qdot_r, free.qdot_r)
    law = ArmController(panda, PANDA_GAINS)
    with pytest.raises(ValueError, match='approach speed limit must be >= 0'):
        law.limit_approach(np.ones(7), math.nan)
    with pytest.raises(ValueError, match='approach row must be 7 finite values'):
        law.limit_approach(np.ones(3), 0.1)


def test_barrier_gradient_rate_and_energy_are_exact_on_both_arms(panda):
    """g = dB/dq and its rate (the diagonal Hessian times qdot) by central differences of B,
    on random states in and near every joint's band, the SCARA's (band 0.1 rad) and the
    Panda's (0.15 rad)."""
    rng = np.random.default_rng(4)
    h = 1e-7
    for model, band in ((ScaraModel(), 0.1), (panda, 0.15)):
        lower, upper = model.limits.lower, model.limits.upper
        for _ in range(100):
            q = np.where(rng.random(model.dof) < 0.5, rng.uniform(lower, lower + 1.2 * band),
                         rng.uniform(upper - 1.2 * band, upper))
            dq = rng.uniform(-1.0, 1.0, model.dof)
            g, gd, near = barrier(q, dq, lower, upper, band, 3.0)
            numeric = np.array([(barrier_energy(q + h * e, lower, upper, band, 3.0)
                                 - barrier_energy(q - h * e, lower, upper, band, 3.0)) / (2 * h)
                                for e in np.eye(model.dof)])
            np.testing.assert_allclose(g, numeric, atol=1e-6)
            ahead = barrier(q + h * dq, dq, lower, upper, band, 3.0)[0]
            behind = barrier(q - h * dq, dq, lower, upper, band, 3.0)[0]
            np.testing.assert_allclose(gd, (ahead - behind) / (2 * h), atol=1e-5)
            assert 0.0 <= near <= 1.0 and (near > 0.0) == bool(np.any(g))


def test_the_gate_stops_feed_forward_into_a_limit_only():
    lower, upper = ScaraModel().limits.lower, ScaraModel().limits.upper
    q = np.array([upper[0] - 0.01, 0.0])  # joint 1 deep in its upper band
    towards, rate = gate_feed_forward(q, np.zeros(2), np.array([0.5, 0.5]), np.zeros(2), lower,
                                      upper, 0.1)
    assert abs(towards[0]) < 0.1 * 0.5 and towards[1] == 0.5
    away, _ = gate_feed_forward(q, np.zeros(2), np.array([-0.5, 0.5]), np.zeros(2), lower,
                                upper, 0.1)
    np.testing.assert_allclose(away, [-0.5, 0.5])


def test_the_task_term_on_two_axes_is_the_one_in_3d_in_the_plane():
    rng = np.random.default_rng(5)
    controller = ArmController(robot_model('panda'), PANDA_GAINS)
    drive = controller.drive(FOLLOW)
    for _ in range(50):
        dx = rng.uniform(-0.4, 0.4, 2)
        slope, hessian = task_term(np.array([*dx, 0.0]), drive)
        planar_slope, planar_hessian = task_term(dx, drive)
        np.testing.assert_allclose(slope, [*planar_slope, 0.0], atol=1e-12)
        np.testing.assert_allclose(hessian[:2, :2], planar_hessian, rtol=1e-9, atol=1e-12)


def test_a_non_finite_state_gives_zero_torque_and_a_fault(panda):
    controller = ArmController(panda, PANDA_GAINS)
    theta = controller.theta_hat
    q = panda.home.copy()
    q[2] = math.nan
    out = controller.step(q, np.zeros(7), still_hand(panda, panda.home, 6),
                          ActiveTask(FOLLOW, 1.0), DT)
    assert out.fault and not np.any(out.tau)
    np.testing.assert_array_equal(controller.theta_hat, theta)


def test_bad_gains_and_models_are_refused(panda, tmp_path):
    scara_urdf_file = tmp_path / 'scara.urdf'  # the SCARA as a URDF arm: 3-D, 2 joints
    scara_urdf_file.write_text(ScaraModel().urdf)
    with pytest.raises(ValueError, match='ks must have 7 values'):
        ArmController(panda, dataclasses.replace(PANDA_GAINS, ks=(1.0, 1.0)))
    with pytest.raises(ValueError, match='panda takes 11 adaptation rates'):
        ArmController(panda, dataclasses.replace(PANDA_GAINS, adaptation=(1.0,)))
    with pytest.raises(ValueError, match='scara takes 7 adaptation rates'):
        ArmController(ScaraModel(), ArmGains(ks=(1.0, 1.0), kp=1.0, adaptation=(0.0,) * 11))
    with pytest.raises(ValueError, match='adaptation must be finite values >= 0'):
        dataclasses.replace(PANDA_GAINS, adaptation=(-1.0,) * 11)
    with pytest.raises(ValueError, match='effort_scale must be <= 1'):
        dataclasses.replace(PANDA_GAINS, effort_scale=1.5)
    with pytest.raises(ValueError, match='on 3 task axes needs at least 3'):
        ArmController(robot_model(urdf_file=scara_urdf_file, tool_frame='tip'),
                      ArmGains(ks=(1.0, 1.0), kp=1.0, adaptation=(0.0,) * 11))
    with pytest.raises(ValueError, match='theta_hat0 must be 77'):
        ArmController(panda, PANDA_GAINS, theta_hat0=np.zeros(3))
    with pytest.raises(ValueError, match='posture_force must be finite and >= 0 N'):
        ClearanceSettings(posture_force=-1.0)


def test_avoid_backs_away_from_a_hand_reaching_in_along_z(panda):
    """Table I's avoid row (open outward with the Panda's attained reach, 0.95 m): a hand
    comes down onto the tool at 0.5 m/s (peak; a minimum-jerk move, as the SCARA's tests'
    hands: a hand stopping at once from 0.5 m/s made the retreating arm stop at once too, a
    2.6 N m step) and stops there; within 2 s of its stop the tool is
    at least d1 - 2 cm away (and never nearer), with every effort step <= 1 N m per 1 ms
    cycle."""
    avoid = TaskShape(1, 0.056, 25.46, 0.183, 2.0)
    controller = ArmController(panda, PANDA_GAINS, theta_hat0=0.7 * panda.theta)
    assert controller.drive(avoid).open_outward
    true = true_arm(panda, 7)
    q, dq = panda.home.copy(), np.zeros(7)
    start = panda.tool_position(q)
    speed, height = 0.5, 0.35
    stop_time = 1.875 * height / speed  # a minimum-jerk move at `speed` peak
    previous, steps, distances = np.zeros(7), [], []
    for i in range(round((stop_time + 2.0) / DT)):
        s, ds, dds = quintic_smoothstep(i * DT / stop_time)
        hand = HandState(start + [0.0, 0.0, height * (1.0 - s)],
                         np.array([0.0, 0.0, -height * ds / stop_time]),
                         np.array([0.0, 0.0, -height * dds / stop_time ** 2]))
        out = controller.step(q, dq, hand, ActiveTask(avoid, 1.0), DT)
        assert not out.fault, out.fault_reason
        assert np.all(np.abs(out.tau) <= panda.limits.effort)
        if i > 0:
            steps.append(np.abs(out.tau - previous).max())
        previous = out.tau
        distances.append(out.distance)
        q, dq = true.rk4_step(q, dq, out.tau, DT)
    # The hand came within the retreat's reach (task_variable.retreat_term), and the arm
    # backed away as fast as it came.
    assert min(distances) < avoid.d1 + RETREAT_REACH
    assert distances[-1] >= avoid.d1 - 0.02, distances[-1]
    assert min(distances) >= avoid.d1 - 0.02, min(distances)
    assert max(steps) <= 1.0, max(steps)


def test_the_node_builds_every_arm_through_one_model_and_its_gains(panda):
    from hri_adaptive_controller.controller_node import gains_from, initial_estimate, model_from

    values = {'robot': 'scara', 'urdf_file': '', 'tool_frame': '', 'ks': None,
              'adaptation_gain': None, 'theta_hat0': None, 'kp': 10.0,
              'approach_speed': 0.1, 'region_margin': 0.02, 'max_task_speed': 0.25,
              'rest_gain': 2.0, 'rest_gate': 0.03, 'max_effort_rate': 1000.0,
              'effort_limit': 0.0, 'joint_limit_band': 0.1, 'barrier_torque': 3.0,
              'reach_round': True, 'rest_position': None}
    scara = model_from(values)
    assert scara.task_axes == 2 and gains_from(values, scara) == SCARA_GAINS
    np.testing.assert_allclose(initial_estimate(values, scara, SCARA_GAINS), 0.6 * scara.theta)
    with pytest.raises(ValueError, match=r'home_position must have shape \(2,\)'):
        model_from({**values, 'home_position': [0.0, 1.0, 2.0]})
    bent = [0.3, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8]
    assert model_from({**values, 'robot': 'panda', 'home_position': bent}).home.tolist() \
        == bent
    with pytest.raises(ValueError, match=r'home_position must have shape \(7,\)'):
        model_from({**values, 'robot': 'panda', 'home_position': bent[:6]})
    with pytest.raises(ValueError, match='outside the joint limits'):
        model_from({**values, 'robot': 'panda', 'home_position': [0.0] * 7})
    model = model_from({**values, 'robot': 'panda'})
    assert model.joint_names == panda.joint_names
    assert gains_from(values, model) == dataclasses.replace(PANDA_GAINS, limit_band=0.1)
    with pytest.raises(ValueError, match='ks must have 7 values for panda'):
        gains_from({**values, 'ks': [5.0] * 6}, model)
    with pytest.raises(ValueError, match='adaptation_gain must have 11 values for panda'):
        gains_from({**values, 'adaptation_gain': [1.0] * 7}, model)
    with pytest.raises(ValueError, match='theta_hat0 must have 77 values for panda'):
        initial_estimate({**values, 'theta_hat0': [1.0] * 7}, model, PANDA_GAINS)
    assert ArmController(model, gains_from({**values, 'effort_limit': 20.0}, model)
                         ).effort_limits.max() == 20.0
    with pytest.raises(ValueError, match='unknown robot'):
        model_from({**values, 'robot': 'no_such_arm'})


def test_the_default_gains_are_the_robots_own_or_derived(panda, tmp_path):
    assert default_gains(ScaraModel()) is SCARA_GAINS
    assert default_gains(panda) is PANDA_GAINS
    urdf = tmp_path / 'panda_copy.urdf'
    urdf.write_text(panda.urdf)
    copy = robot_model(urdf_file=str(urdf), tool_frame='panda_hand_tcp')
    assert default_gains(copy).ks == default_arm_ks(copy)


@pytest.mark.parametrize('robot', ['ur3', 'ur5', 'ur10'])
def test_an_arm_without_gains_of_its_own_follows_a_still_hand(robot):
    # With the Panda's adaptation rates the UR3 and the UR10 ran away from the hand (0.90 and
    # 1.72 m after 4 s); with the default gains' (ADAPTATION_SCALE) they follow it.
    model = robot_model(robot)
    assert default_gains(model).adaptation == tuple(
        ADAPTATION_SCALE * rate for rate in PANDA_GAINS.adaptation)
    inward = np.array([-0.2, 0.15, 0.15]) / np.linalg.norm([-0.2, 0.15, 0.15])
    hand = model.tool_position(model.home) + 0.3 * inward
    result = simulate({'follow': FOLLOW}, [], still_target(hand), 4.0,
                      LoopConditions(arm=model, initial_task='follow', monitor=False))
    assert np.all(result.distance[result.time >= 3.0] <= FOLLOW.d2), robot
    assert np.all(np.abs(result.tau) <= model.limits.effort + 1e-9)


def test_the_ur10_holds_a_still_hand_when_its_controller_takes_every_other_state():
    # The node takes the newest joint state: on a loaded machine the UR10's controller
    # computed 2866 commands from 5986 states, each 2 ms late. At 1 N m a command the
    # shoulder's 115 N m of gravity then took 0.23 s while the arm fell, and eq. 19, run on
    # commands the rate limit held off the law's torque, wound the wrist's 5e-4 kg m^2 up to
    # 0.84 kg m^2: the wrist oscillated and the tool never entered the region (0.050-0.609 m
    # from the hand). Eq. 19 pauses while the limit acts (ArmController.adapt): in at 2.9 s.
    model = robot_model('ur10')
    rng = np.random.default_rng(0)  # the true arm: masses and inertias 10 % off (as arm_sim)
    arm = model.with_inertias(rng.uniform(0.9, 1.1, model.dof), model.damping)
    inward = np.array([-0.2, 0.15, 0.15]) / np.linalg.norm([-0.2, 0.15, 0.15])
    hand = model.tool_position(model.home) + 0.3 * inward
    result = simulate({'follow': FOLLOW}, [], still_target(hand), 5.0, LoopConditions(
        arm=arm, model=model, initial_task='follow', monitor=False, target_period=0.01,
        control_period=2, command_delay=2))
    distance = np.linalg.norm(
        np.array([model.tool_position(q) for q in result.q[::10]]) - hand, axis=1)
    inside = distance <= FOLLOW.d2
    entered = int(np.argmax(inside))
    assert inside[entered] and result.time[::10][entered] <= 4.0, distance.min()
    assert inside[entered:].all(), distance[entered:].max()
    assert np.all(np.abs(result.tau) <= model.limits.effort + 1e-9)
    assert np.abs(np.diff(result.tau, axis=0)).max() <= 1.0 + 1e-9  # 1 N m a command


def test_a_joint_started_in_its_limit_band_is_pushed_out(panda):
    """Joint 4 starts 0.08 rad (4.6 deg) from its upper limit, inside the 0.15 rad band, the
    hand still at the tool: the barrier and the null-space push take it out of the band
    while the tool stays in the follow region."""
    controller = ArmController(panda, PANDA_GAINS, theta_hat0=0.7 * panda.theta)
    true = true_arm(panda, 8)
    q, dq = panda.home.copy(), np.zeros(7)
    q[3] = panda.limits.upper[3] - 0.08
    hand = HandState(panda.tool_position(q), np.zeros(3), np.zeros(3))
    nears, distances = [], []
    for _ in range(3000):
        out = controller.step(q, dq, hand, ActiveTask(FOLLOW, 1.0), DT)
        assert not out.fault, out.fault_reason
        assert np.all(np.abs(out.tau) <= panda.limits.effort)
        nears.append(out.near)
        distances.append(out.distance)
        q, dq = true.rk4_step(q, dq, out.tau, DT)
    assert nears[0] > 0.0 and nears[-1] == 0.0
    assert panda.limits.upper[3] - q[3] > PANDA_GAINS.limit_band
    assert max(distances) <= FOLLOW.d2


UR_URDFS = 'cmeel.prefix/share/example-robot-data/robots/ur_description/urdf'


def example_robot(urdf: str):
    """A UR arm of example-robot-data (requirements.lock), tool frame tool0."""
    path = metadata.distribution('example-robot-data').locate_file(f'{UR_URDFS}/{urdf}')
    return robot_model(urdf_file=str(path), tool_frame='tool0')


@pytest.mark.parametrize('urdf', ['ur3_joint_limited_robot.urdf', 'ur10_robot.urdf'])
def test_a_urdf_arm_without_gains_of_its_own_follows_a_still_hand(urdf):
    # Ks from the effort limits alone gave the UR3's and UR10's wrists Ks dt / M = 3-47:
    # the arm spun through its limits. default_arm_ks bounds Ks by the inertia each joint
    # moves.
    model = example_robot(urdf)
    ks = np.array(default_arm_ks(model))
    rng = np.random.default_rng(2)
    for q in [model.home, *rng.uniform(model.limits.lower, model.limits.upper, (20, model.dof))]:
        assert np.all(ks * DT / np.diag(model.mass_matrix(q)) <= KS_RATE * DT + 1e-12)
    controller = ArmController(model, dataclasses.replace(PANDA_GAINS, ks=tuple(ks)))
    q, dq = model.home.copy(), np.zeros(model.dof)
    # 0.3 m from the tool, towards the shoulder (the home pose is stretched out).
    inward = np.array([-0.2, 0.15, 0.15]) / np.linalg.norm([-0.2, 0.15, 0.15])
    hand = HandState(model.tool_position(q) + 0.3 * inward, np.zeros(3), np.zeros(3))
    distances = []
    for i in range(4000):
        out = controller.step(q, dq, hand, ActiveTask(FOLLOW, min(1.0, i / 1000)), DT)
        assert not out.fault, out.fault_reason
        assert np.all(np.abs(out.tau) <= model.limits.effort + 1e-9)
        distances.append(out.distance)
        q, dq = model.rk4_step(q, dq, out.tau, DT)
    entered = int(np.argmax(np.array(distances) <= FOLLOW.d2))
    assert distances[entered] <= FOLLOW.d2 and entered * DT <= 3.0, min(distances)
    assert max(distances[entered:]) <= FOLLOW.d2 + 0.005
    assert np.all((q > model.limits.lower) & (q < model.limits.upper))


def test_the_reach_round_joint_motion_stays_finite_for_any_joint_error(panda):
    # 1000 rad between the joints and the filtered goal (a state no arm reaches, but a law
    # must not raise on it): sech^2 of the capped motion underflows instead of cosh
    # overflowing (an OverflowError left the arm without torque).
    settings = ReachRoundSettings()
    for compiled in (False, True):
        blend = ReachRound(settings, panda, panda.limits.lower, panda.limits.upper, 0.15, 0.8,
                           PANDA_GAINS.damping.threshold, compiled)
        q, dq = panda.home.copy(), np.zeros(7)
        blend._blend(True, None, q, dq, DT)
        q[0] += 1000.0
        sigma, sigma_rate, u, u_rate = blend._blend(True, None, q, dq, DT)
        assert all(math.isfinite(v) for v in (sigma, sigma_rate, *u, *u_rate))
        assert np.linalg.norm(u) <= settings.max_speed + 1e-9


def test_the_gravity_hold_is_the_estimates_gravity_within_the_limits(panda):
    # What the controller sends while its joint states are stale (controller_node).
    q = panda.home + 0.2
    hold = ArmController(panda, PANDA_GAINS).gravity_hold(q)
    np.testing.assert_allclose(hold, panda.gravity_torque(q), atol=1e-9)
    assert np.abs(hold).max() > 5.0
    heavy = ArmController(panda, PANDA_GAINS, theta_hat0=5.0 * panda.theta)
    hold = heavy.gravity_hold(q)
    assert np.all(np.abs(hold) <= heavy.effort_limits + 1e-9)
    assert np.all(ArmController(panda, PANDA_GAINS).gravity_hold(np.full(7, np.nan)) == 0.0)
