"""Unit tests of arm_kernels: the law's compiled arithmetic gives arm_law's numpy results (the
reference, `ArmController(..., compiled=False)`) to rounding, on the SCARA's two task axes and
the Panda's three, in the usual case, within the barrier bands, through the reach-round blend
(its joint motion and the SCARA's inverse kinematics) and in a closed loop."""

import dataclasses
import math
from importlib import metadata

import numpy as np
import pytest

from hri_adaptive_controller import arm_kernels, joint_limits
from hri_adaptive_controller.arm_law import (
    PANDA_GAINS,
    ActiveTask,
    ArmController,
    ClearanceSettings,
    HandState,
    body_barrier,
    default_arm_ks,
    default_gains,
)
from hri_adaptive_controller.task_variable import SECH_LIMIT, damped_pseudo_inverse, speed_cap
from hri_core.bodies import human_capsules, panda_package_dirs, robot_body
from hri_core.human_body import BODY_POINTS, standing_body
from hri_core.potential import TaskShape
from hri_core.robot_model import robot_model

FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)  # Table I's rows
AVOID = TaskShape(-1, 119.3, 4.071, 0.299, 1.0)
FOLLOW_SAFE = TaskShape(1, 17.36, 8.014, 0.189, 0.262)
DT = 1e-3
# A 3-joint arm (yaw, shoulder and elbow pitch): no null space, the kernels' other branch.
LINK = """<link name="{name}"><inertial><origin xyz="0 0 {com}"/><mass value="{mass}"/>
<inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial></link>"""
JOINT = """<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>
<origin xyz="0 0 {z}"/><axis xyz="{axis}"/>
<limit lower="-2.6" upper="2.6" effort="{effort}" velocity="2.0"/></joint>"""
THREE_JOINT_URDF = '<robot name="rrr">' + ''.join([
    LINK.format(name='base', com=0.05, mass=2.0, i=0.01),
    LINK.format(name='turret', com=0.1, mass=1.5, i=0.01),
    LINK.format(name='upper', com=0.15, mass=1.2, i=0.01),
    LINK.format(name='fore', com=0.12, mass=0.8, i=0.005),
    '<link name="tool"/>',
    JOINT.format(name='yaw', parent='base', child='turret', z=0.1, axis='0 0 1', effort=40),
    JOINT.format(name='shoulder', parent='turret', child='upper', z=0.2, axis='0 1 0',
                 effort=40),
    JOINT.format(name='elbow', parent='upper', child='fore', z=0.3, axis='0 1 0', effort=20),
    '<joint name="tool_joint" type="fixed"><parent link="fore"/><child link="tool"/>'
    '<origin xyz="0 0 0.25"/></joint>']) + '</robot>'
OUTPUTS = ('tau', 'tau_requested', 's', 'qdot_r', 'qddot_r', 'near', 'blend', 'damping',
           'barrier_gradient', 'reference_offset')


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


@pytest.fixture(scope='module', params=['scara', 'panda'])
def arm(request, panda):
    return panda if request.param == 'panda' else robot_model('scara')


def close(compiled, reference, what):
    """compiled equals reference within rounding: 1e-10 of the reference's scale."""
    compiled, reference = np.asarray(compiled, float), np.asarray(reference, float)
    scale = max(1.0, float(np.max(np.abs(reference))))
    assert np.allclose(compiled, reference, rtol=0.0, atol=1e-10 * scale), (
        f'{what}: {compiled} != {reference}')


def assert_same(compiled, reference):
    assert compiled.fault == reference.fault, (compiled.fault_reason, reference.fault_reason)
    for name in OUTPUTS:
        close(getattr(compiled, name), getattr(reference, name), name)
    assert compiled.torque_limited == reference.torque_limited


def random_states(model, rng, count):
    """(q, dq, hand, task) anywhere within the joint limits (the barrier bands included),
    hands from on the tool to 1.5 m away (out of reach: the reach-round), any task weight."""
    shapes = (FOLLOW, AVOID, FOLLOW_SAFE, None)
    for _ in range(count):
        q = rng.uniform(model.limits.lower + 0.01, model.limits.upper - 0.01)
        dq = rng.normal(0.0, 0.8, model.dof)
        axes = model.task_axes
        offset = rng.normal(size=axes)
        offset *= rng.uniform(0.0, 1.5) / np.linalg.norm(offset)
        hand = HandState(model.task_kinematics(q, dq)[0] + offset, rng.normal(0.0, 0.3, axes),
                         rng.normal(0.0, 1.0, axes))
        shape = shapes[rng.integers(len(shapes))]
        task = None if shape is None else ActiveTask(shape, float(rng.uniform()),
                                                     float(rng.normal()), 0.0)
        yield q, dq, hand, task


def test_speed_cap_is_task_variables(panda):
    for speed in (0.0, 0.1, -0.29, 0.3, 0.31, -0.5, 3.0, -1e3, 1e300):
        for v_max in (0.0, 0.3, 1.0):
            assert arm_kernels.speed_cap(speed, v_max) == pytest.approx(speed_cap(speed, v_max),
                                                                        rel=1e-15, abs=0.0)
    # Beyond SECH_LIMIT sech^2 is 0, no overflow.
    assert arm_kernels.speed_cap(1e6, 0.3)[1] == 0.0
    assert SECH_LIMIT * 0.06 < 1e6


@pytest.mark.parametrize('joints', [2, 7])
def test_the_reach_rounds_joint_motion_is_the_reference(joints):
    rng = np.random.default_rng(joints)
    for scale in (1e-9, 0.01, 1.0, 1e3):  # from no joint error to one past SECH_LIMIT
        for has_goal in (True, False):
            arrays = [scale * rng.normal(size=joints) for _ in range(6)]
            args = (arrays[0], has_goal, *arrays[1:], DT, 1.0, 8.0, 4.0, 1.0,
                    scale * rng.normal(size=joints))
            for compiled, reference in zip(arm_kernels.joint_motion(*args),
                                            joint_limits.joint_motion(*args), strict=True):
                np.testing.assert_allclose(compiled, reference, rtol=1e-12, atol=1e-15)
                assert np.all(np.isfinite(compiled))


@pytest.mark.parametrize('axes', [2, 3])
def test_the_reach_rounds_goal_is_the_reference_and_in_its_shell(axes):
    rng = np.random.default_rng(axes)
    centre = rng.normal(scale=0.3, size=axes)
    low, high = 0.23, 0.62
    for _ in range(500):
        tool, hand = centre + rng.normal(scale=0.5, size=(2, axes))
        d1 = rng.choice([0.0, rng.uniform(0.0, 0.3)])
        args = (tool, hand, d1, d1 + rng.uniform(0.0, 0.3), centre, high, low)
        compiled, reference = arm_kernels.reach_goal(*args), joint_limits.reach_goal(*args)
        np.testing.assert_allclose(compiled[0], reference[0], rtol=1e-13, atol=1e-15)
        assert compiled[1:] == pytest.approx(reference[1:], rel=1e-13, abs=1e-15)
        goal, distance, radius, clearance = reference
        d2 = args[3]
        away = (tool - hand) / np.linalg.norm(tool - hand)
        unmoved = hand + (0.5 * (d1 + min(d2, d1 + 0.2)) * away if d1 > 0.0 else 0.0)
        assert radius == pytest.approx(np.linalg.norm(unmoved - centre))
        np.testing.assert_allclose(
            goal, centre + (unmoved - centre) * np.clip(radius, low, high) / radius)
        assert distance == pytest.approx(np.linalg.norm(goal - tool))
        path = tool + np.linspace(0.0, 1.0, 2001)[:, None] * (goal - tool)
        assert clearance == pytest.approx(np.min(np.linalg.norm(path - centre, axis=1)),
                                          abs=1e-3)
    # The hand on the centre: the goal is the shell's point towards the tool.
    goal = joint_limits.reach_goal(centre + 0.5, centre, 0.0, 0.04, centre, high, low)[0]
    np.testing.assert_allclose(goal, centre + low / np.sqrt(axes))


@pytest.mark.parametrize('max_damping', [0.05, 0.0])
def test_the_pseudo_inverse_is_the_numpy_one_near_and_far_from_singular(arm, max_damping):
    gains = ArmController(arm).gains
    threshold2 = gains.damping.threshold ** 2
    rng = np.random.default_rng(3)
    stretched = arm.home.copy()
    if arm.dof == 7:
        stretched[1], stretched[3] = 0.0, -0.07  # near the elbow's singularity: damped
    else:
        stretched[1] = 0.05  # the SCARA nearly stretched out
    damped = 0
    for q in [stretched, *rng.uniform(arm.limits.lower, arm.limits.upper, (200, arm.dof))]:
        _, jac, rate = arm.task_kinematics(q, rng.normal(0.0, 1.0, arm.dof))
        pinv, pinv_rate, lam2, singular = arm_kernels.damped_pseudo_inverse(
            jac, rate, threshold2, max_damping ** 2)
        assert not singular
        expected = damped_pseudo_inverse(jac, rate, threshold2, max_damping ** 2)
        close(pinv, expected[0], 'J+')
        close(pinv_rate, expected[1], 'dJ+/dt')
        assert lam2 == pytest.approx(expected[2], rel=1e-12, abs=1e-300)
        damped += lam2 > 0.0
    assert damped >= 1 or max_damping == 0.0


def test_the_pseudo_inverse_rate_is_its_time_derivative(arm):
    """dJ+/dt against a central difference of J+ along q + t dq, damped and not."""
    gains = ArmController(arm).gains
    threshold2, damping2 = gains.damping.threshold ** 2, gains.damping.max_damping ** 2
    rng = np.random.default_rng(8)
    h = 1e-6
    damped = 0
    for q in rng.uniform(arm.limits.lower, arm.limits.upper, (200, arm.dof)):
        dq = rng.normal(0.0, 1.0, arm.dof)
        _, jac, rate = arm.task_kinematics(q, dq)
        pinv, pinv_rate, lam2 = damped_pseudo_inverse(jac, rate, threshold2, damping2)
        ahead = damped_pseudo_inverse(*arm.task_kinematics(q + h * dq, dq)[1:], threshold2,
                                      damping2)[0]
        behind = damped_pseudo_inverse(*arm.task_kinematics(q - h * dq, dq)[1:], threshold2,
                                       damping2)[0]
        np.testing.assert_allclose(pinv_rate, (ahead - behind) / (2 * h), rtol=1e-5,
                                   atol=1e-6 * max(1.0, float(np.abs(pinv_rate).max())))
        damped += lam2 > 0.0
    assert damped >= 1  # the damping's own rate took part


def test_a_singular_jacobian_without_damping_is_a_fault(arm, monkeypatch):
    gains = dataclasses.replace(
        ArmController(arm).gains,
        damping=dataclasses.replace(ArmController(arm).gains.damping, max_damping=0.0))
    axes, n = arm.task_axes, arm.dof
    jac = np.zeros((axes, n))
    jac[0, 0] = 1.0  # rank 1: J J^T has no inverse and nothing damps it
    *_, singular = arm_kernels.damped_pseudo_inverse(jac, np.zeros((axes, n)), 1e-4, 0.0)
    assert singular
    hand = HandState(np.zeros(axes), np.zeros(axes), np.zeros(axes))
    for compiled in (True, False):
        controller = ArmController(arm, gains, compiled=compiled)
        monkeypatch.setattr(arm, 'task_kinematics',
                            lambda q, dq: (np.ones(axes), jac, np.zeros((axes, n))))
        out = controller.command(arm.home, np.zeros(n), hand, ActiveTask(FOLLOW, 1.0), DT)
        monkeypatch.undo()
        assert out.fault and 'singular Jacobian' in out.fault_reason
        assert np.all(out.tau == 0.0)


def test_commands_equal_numpys_on_random_states(arm):
    rng = np.random.default_rng(0)
    compiled = ArmController(arm, theta_hat0=0.7 * arm.theta)
    reference = ArmController(arm, theta_hat0=0.7 * arm.theta, compiled=False)
    seen = {'near': 0, 'blend': 0, 'limited': 0}
    for q, dq, hand, task in random_states(arm, rng, 600):
        # Both stateful parts (the reach-round and the hand filter) see the same sequence.
        out = compiled.step(q, dq, hand, task, DT)
        expected = reference.step(q, dq, hand, task, DT)
        assert_same(out, expected)
        close(compiled.theta_hat, reference.theta_hat, 'theta_hat')
        seen['near'] += out.near > 0.0
        seen['blend'] += out.blend > 0.0
        seen['limited'] += out.torque_limited
    assert min(seen.values()) >= 10, seen  # every branch taken


@pytest.mark.parametrize(('arm', 'hand_at'), [('panda', (-0.3, 0.0, 0.2)),
                                              ('ur5', (0.0, 0.0, 1.3)),
                                              ('scara', (-0.3, -0.15))])
def test_a_closed_loop_follows_the_same_path_compiled(panda, arm, hand_at):
    # The hand low behind the Panda's base (its joints reach their barrier bands), above
    # the UR5, out of reach, or across the SCARA's base: the reach-round blends in, the null
    # space acts, and the two laws drive the same arm along the same path.
    if arm == 'panda':
        model, gains = panda, PANDA_GAINS
    elif arm == 'scara':
        model = robot_model('scara')
        gains = ArmController(model).gains
    else:
        path = metadata.distribution('example-robot-data').locate_file(
            'cmeel.prefix/share/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf')
        model = robot_model(urdf_file=str(path), tool_frame='tool0')
        gains = dataclasses.replace(PANDA_GAINS, ks=default_arm_ks(model))
    laws = [ArmController(model, gains, theta_hat0=0.7 * model.theta, compiled=flag)
            for flag in (True, False)]
    states = [(model.home.copy(), np.zeros(model.dof)) for _ in laws]
    axes = model.task_axes
    hand = HandState(np.array(hand_at), np.zeros(axes), np.zeros(axes))
    blended = near = 0
    for i in range(1500):
        task = ActiveTask(FOLLOW, min(1.0, i / 300))
        outs = [law.step(q, dq, hand, task, DT) for law, (q, dq) in zip(laws, states, strict=True)]
        assert_same(*outs)
        blended, near = blended + (outs[0].blend > 0.0), near + (outs[0].near > 0.0)
        states = [model.rk4_step(q, dq, out.tau, DT)
                  for (q, dq), out in zip(states, outs, strict=True)]
        assert math.isfinite(outs[0].distance)
    close(states[0][0], states[1][0], 'q after 1.5 s')
    assert blended > 100, blended  # the reach-round blend took part
    assert near > 100 or arm != 'panda', near  # and the Panda's barrier


def test_a_three_joint_arm_has_no_null_space_and_the_same_path(tmp_path):
    urdf = tmp_path / 'rrr.urdf'
    urdf.write_text(THREE_JOINT_URDF)
    model = robot_model(urdf_file=str(urdf), tool_frame='tool')
    model.home = np.array([0.0, 0.6, 0.9])  # bent: off the stretched singularity
    gains = dataclasses.replace(PANDA_GAINS, ks=default_arm_ks(model))
    laws = [ArmController(model, gains, theta_hat0=0.7 * model.theta, compiled=flag)
            for flag in (True, False)]
    states = [(model.home.copy(), np.zeros(3)) for _ in laws]
    hand = HandState(model.tool_position(model.home) + np.array([0.1, 0.15, -0.1]),
                     np.zeros(3), np.zeros(3))
    for i in range(1500):
        task = ActiveTask(FOLLOW, min(1.0, i / 300))
        outs = [law.step(q, dq, hand, task, DT) for law, (q, dq) in zip(laws, states,
                                                                         strict=True)]
        assert_same(*outs)
        states = [model.rk4_step(q, dq, out.tau, DT)
                  for (q, dq), out in zip(states, outs, strict=True)]
    close(states[0][0], states[1][0], 'q after 1.5 s')
    assert outs[0].distance < 0.1  # it followed the hand (0.21 m away at the start)


def random_person(arm, q, rng, moving: bool):
    """The capsules of a person standing round the arm's tool at q, in any direction, the
    right wrist within about 0.15 m of the tool; moving: its points at random velocities."""
    tool = np.zeros(3)
    tool[:arm.task_axes] = arm.task_kinematics(q, np.zeros(arm.dof))[0]
    wrist = tool + rng.normal(scale=0.15, size=3)
    place = wrist[:2] + rng.normal(scale=0.3, size=2)
    points = standing_body(place, rng.uniform(-3.0, 3.0), rng.uniform(-0.6, 0.1), wrist)
    velocities = rng.normal(scale=0.3, size=points.shape) if moving else None
    return human_capsules(list(BODY_POINTS), points, velocities=velocities)


def body_law(arm, compiled: bool = True) -> ArmController:
    body = robot_body(arm, panda_package_dirs()) if arm.name == 'panda' else robot_body(arm)
    gains = dataclasses.replace(default_gains(arm), body=ClearanceSettings())
    return ArmController(arm, gains, theta_hat0=0.7 * arm.theta, compiled=compiled, body=body)


def test_the_compiled_body_barrier_is_the_reference(arm):
    """The law's compiled whole-body barrier (arm_kernels.body_barrier on the body's chain)
    gives body_barrier's g, rate, U, posture push, gate, nearest pair and the approach
    damper's pairs (rows, distances, approach speeds) on random states:
    people standing round the tool in any direction, still or moving, with and without the
    follow exemption. The rates are forward differences over 1 us, so 1e-7 of their scale."""
    law = body_law(arm)
    rng = np.random.default_rng(21)
    pulled = 0
    for trial in range(60):
        q = rng.uniform(arm.limits.lower, arm.limits.upper)
        dq = rng.normal(size=arm.dof)
        human = random_person(arm, q, rng, moving=trial % 2 == 1)
        hand = [j for j, name in enumerate(human.names) if name in ('r_forearm', 'r_hand')]
        exempt = (hand, [human.names.index('r_upper_arm')]) if trial % 3 == 0 else None
        reference = body_barrier(law.body, q, dq, human, law.gains.body, exempt,
                                 arm.dof > arm.task_axes)
        compiled = law.whole_body_barrier(q, dq, human, exempt)
        assert compiled.pair == reference.pair
        for name in ('energy', 'distance', 'gate', 'gradient', 'posture', 'rows', 'gaps',
                     'approach'):
            expected = getattr(reference, name)
            assert (getattr(compiled, name) is None) == (expected is None), name
            if expected is not None:
                close(getattr(compiled, name), expected, name)
        for name in ('rate', 'posture_rate', 'gate_rate'):
            expected, got = getattr(reference, name), getattr(compiled, name)
            assert (got is None) == (expected is None), name
            if expected is not None:
                scale = max(1.0, float(np.max(np.abs(expected))))
                np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-7 * scale)
        pulled += reference.gradient is not None
    assert pulled >= 20  # most states put some link in the band


def test_commands_with_a_person_equal_numpys(arm):
    """With a person beside the arm the compiled law (the barrier and the reference motion
    through the kernels) commands what the numpy law does: torque, s, qdot_r, qddot_r and the
    barrier's task velocity to rounding (the body barrier's rate is a forward difference
    over 1 us: 1e-6 of the scale for what depends on it)."""
    rng = np.random.default_rng(22)
    compiled, reference = body_law(arm), body_law(arm, compiled=False)
    pushed = 0
    for k, (q, dq, hand, task) in enumerate(random_states(arm, rng, 150)):
        human = random_person(arm, q, rng, moving=k % 2 == 1)
        out = compiled.step(q, dq, hand, task, DT, human=human)
        expected = reference.step(q, dq, hand, task, DT, human=human)
        assert out.fault == expected.fault
        for name in ('tau', 'tau_requested', 's', 'qdot_r', 'qddot_r', 'barrier_gradient'):
            got, want = np.asarray(getattr(out, name)), np.asarray(getattr(expected, name))
            scale = max(1.0, float(np.max(np.abs(want))))
            np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-6 * scale, err_msg=name)
        assert (out.barrier_task_velocity is None) == (expected.barrier_task_velocity is None)
        pushed += expected.barrier_task_velocity is not None and out.near == 0.0
    assert pushed >= 20  # the person's barrier on, outside the joint limits' bands


def test_the_compiled_body_damper_is_the_reference():
    """arm_kernels.body_damper gives arm_law.body_damper's qdot_r on random pairs (1 to 8
    rows on 2 to 7 joints, some of them over their bound, some parallel), and the result is
    the projection: every row within its target, the change R^T lambda with lambda >= 0 and
    zero on the rows it leaves short of their target."""
    from hri_adaptive_controller.arm_law import DAMPER_RIDGE, DAMPER_SOFTNESS, body_damper

    rng = np.random.default_rng(23)
    held = 0
    for trial in range(300):
        n, m = int(rng.integers(2, 8)), int(rng.integers(1, 9))
        rows = rng.normal(scale=0.4, size=(m, n))
        if m > 1 and trial % 4 == 0:
            rows[1] = 0.7 * rows[0]  # two pairs of one link, one normal
        gaps = rng.uniform(0.05, 0.2, m)
        # independent rows meet any bounds; others meet bounds >= 0 (at x = 0)
        approach = rng.uniform(0.0, 0.1, m) if m <= n and trial % 4 else np.zeros(m)
        qdot_r = rng.normal(size=n)
        args = (rows, gaps, approach, 5.0, 0.09, 0.0, DAMPER_SOFTNESS, DAMPER_RIDGE)
        want, changed = body_damper(qdot_r, *args)
        got, compiled_changed = arm_kernels.body_damper(qdot_r, *args)
        assert changed == compiled_changed
        close(got, want, 'qdot_r')
        if not changed:
            continue
        held += 1
        speeds = rows @ qdot_r
        bounds = np.maximum(5.0 * (gaps - 0.09), 0.0) - approach
        targets = np.where(speeds > bounds, bounds + DAMPER_SOFTNESS * np.tanh(
            np.maximum(speeds - bounds, 0.0) / DAMPER_SOFTNESS), bounds)
        # to DAMPER_RIDGE times the multipliers (below 1e-4 m/s)
        assert np.all(rows @ want <= targets + 1e-4), (rows @ want - targets)
        if np.linalg.matrix_rank(rows) == m:  # lambda unique: KKT's signs and slackness
            multipliers = np.linalg.lstsq(rows.T, qdot_r - want, rcond=None)[0]
            slack = targets - rows @ want
            assert np.all(multipliers >= -1e-6), multipliers
            assert np.all(np.abs(multipliers[slack > 1e-4]) <= 1e-4), (multipliers, slack)
    assert held >= 100
