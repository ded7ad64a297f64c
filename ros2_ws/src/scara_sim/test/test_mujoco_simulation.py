"""scara_sim.mujoco_simulation: MuJoCo's dynamics against pinocchio's, joint limits, effort
clipping, bad input, and the person's capsules pushing the arm with the contact force the
statics and MuJoCo's solver both give."""

import numpy as np
import pinocchio as pin
import pytest

from hri_core.bodies import HUMAN_RADII, Capsules, panda_package_dirs
from hri_core.robot_model import generic_model, robot_model
from scara_sim.arm_simulation import ArmSimulator, true_arm
from scara_sim.mujoco_simulation import MujocoArmSimulator, resolve_mesh_paths

DT = 1e-3  # s, the node's step
SEED = 7


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


def mujoco_sim(arm, q=None, **kwargs):
    q = arm.home if q is None else q
    return MujocoArmSimulator(arm, q, np.zeros(arm.dof), dt=DT,
                              package_dirs=panda_package_dirs(), **kwargs)


def test_without_armature_mujoco_forward_dynamics_equal_pinocchio_aba(panda):
    """The same perturbed arm: MuJoCo's ddq equals ABA's to 1e-9 on 20 seeded random states
    (no armature, no damping); with armature a, M + diag(a) (the rotor inertia)."""
    import mujoco

    arm = true_arm(panda, 0.1, SEED)
    plain = mujoco_sim(arm, joint_damping=0.0, armature=0.0)
    rotors = mujoco_sim(arm, joint_damping=0.0, armature=0.3)
    rng = np.random.default_rng(SEED)
    for _ in range(20):
        q = rng.uniform(arm.limits.lower, arm.limits.upper)
        dq, tau = rng.normal(size=7), rng.normal(scale=5.0, size=7)
        reference = pin.aba(arm.model, arm.data, q, dq, tau)
        for sim in (plain, rotors):
            sim.data.qpos[:], sim.data.qvel[:], sim.data.qfrc_applied[:] = q, dq, tau
            mujoco.mj_forward(sim.model, sim.data)
        np.testing.assert_allclose(plain.data.qacc, reference, atol=1e-9 * (1 + abs(
            reference).max()))
        bias = pin.rnea(arm.model, arm.data, q, dq, np.zeros(7))
        with_rotors = np.linalg.solve(arm.mass_matrix(q) + 0.3 * np.eye(7), tau - bias)
        np.testing.assert_allclose(rotors.data.qacc, with_rotors, atol=1e-8)


def test_a_short_free_fall_follows_the_pinocchio_engine(panda):
    """Zero torque from home for 0.1 s, the same damping (1 N m s/rad) and no armature: the
    joints within 3 % of the fall (0.16 rad) of ArmSimulator's RK4. MuJoCo's step is first
    order: its error is about dt / t of the motion, 1 % at 0.1 s (measured 1.9 %, 2.9 mrad)."""
    arm = true_arm(panda, 0.1, SEED, damping=np.full(7, 1.0))
    mujoco_run = mujoco_sim(arm, joint_damping=1.0, armature=0.0)
    pinocchio_run = ArmSimulator(arm, arm.home, np.zeros(7), dt=DT)
    for _ in range(100):
        q, _, _ = mujoco_run.step('idle', None, ())
        reference, _, _ = pinocchio_run.step('idle', None, ())
    fall = np.abs(np.array(reference) - arm.home).max()
    assert fall > 0.1
    np.testing.assert_allclose(q, reference, atol=0.03 * fall)


def test_joint_limits_hold_and_efforts_are_clipped(panda):
    """Joint 4 pushed at 40 N m onto its upper stop for 0.3 s: MuJoCo's limit constraint
    lets it in by under 5 mrad, the q returned never beyond it; commands clipped at the
    URDF's limits, idle is zero, an unknown mode is refused."""
    arm = true_arm(panda, 0.0, SEED)
    q = arm.home.copy()
    q[3] = arm.limits.upper[3] - 0.01
    sim = mujoco_sim(arm, q=q)
    for _ in range(300):
        push = arm.gravity_torque(sim.q)
        push[3] += 40.0
        q, _, _ = sim.step('effort', push, ())
        assert np.all(np.array(q) <= arm.limits.upper) and np.all(
            np.array(q) >= arm.limits.lower)
        assert sim.data.qpos[3] < arm.limits.upper[3] + 5e-3
    assert q[3] == pytest.approx(arm.limits.upper[3], abs=1e-12)
    _, _, effort = sim.step('effort', np.full(7, 500.0), ())
    np.testing.assert_array_equal(effort, [87.0] * 4 + [12.0] * 3)
    _, _, effort = sim.step('idle', None, ())
    np.testing.assert_array_equal(effort, np.zeros(7))
    _, dq, effort = sim.step('brake', None, ())
    assert dq == (0.0,) * 7 and effort == (0.0,) * 7
    with pytest.raises(ValueError, match="unknown command mode 'velocity'"):
        sim.step('velocity', np.zeros(7), ())


def test_bad_input_is_one_line(panda):
    arm = true_arm(panda, 0.0, SEED)
    with pytest.raises(ValueError, match='armature must be a finite number >= 0'):
        mujoco_sim(arm, armature=-1.0)
    with pytest.raises(ValueError, match='joint_damping must be a finite number >= 0'):
        mujoco_sim(arm, joint_damping=float('nan'))
    with pytest.raises(ValueError, match='is in none of the package folders'):
        resolve_mesh_paths(arm.urdf, package_dirs=())
    sim = mujoco_sim(arm)
    ball = np.zeros((1, 3))
    with pytest.raises(ValueError, match=r"unknown body part\(s\) \['tail'\]"):
        sim.set_body(Capsules(('tail',), ball, ball, np.array([0.1])))
    with pytest.raises(ValueError, match='must be finite'):
        sim.set_body(Capsules(('r_hand',), ball + np.nan, ball, np.array([0.1])))
    with pytest.raises(ValueError, match='became non-finite'):
        sim.step('effort', np.full(7, np.nan), ())


def test_a_capsule_pushed_by_the_arm_carries_the_drive_torque():
    """The SCARA (its links as capsules) drives joint 1 at 2 N m into a still forearm
    standing across link 1. At rest after 1 s the contacts' normal forces balance the drive:
    their moment about joint 1 is 2 N m within 10 %, and each force is within 10 % of MuJoCo's
    own mj_contactForce for that step (read here from its constraint forces, efc_force).
    Only arm-person contacts, on link1, named."""
    import mujoco

    arm = true_arm(generic_model(robot_model('scara')), 0.0, SEED)
    sim = mujoco_sim(arm)
    radius = HUMAN_RADII['forearm']
    x, y = 0.2, 0.05 + radius + 1e-3  # m: beside link 1 (radius 0.05 m), not touching
    sim.set_body(Capsules(('r_forearm',), np.array([[x, y, -0.2]]), np.array([[x, y, 0.2]]),
                          np.array([radius])))
    torque = 2.0
    for _ in range(1000):
        sim.step('effort', (torque, 0.0), ())
    contacts = sim.contacts
    assert contacts and {c.robot_link for c in contacts} == {'link1'}
    assert {c.body_part for c in contacts} == {'r_forearm'}
    moment = 0.0
    for index, contact in enumerate(contacts):
        mj_contact = sim.data.contact[index]
        normal = mj_contact.frame[:3]
        # The pyramid's edges carry the normal force between them (MuJoCo's own reading).
        edges = sim.data.efc_force[mj_contact.efc_address:
                                   mj_contact.efc_address + 2 * (mj_contact.dim - 1)]
        assert contact.normal_force == pytest.approx(edges.sum(), rel=0.1)
        point = np.array(contact.point)
        moment += abs(np.cross(point, normal)[2]) * contact.normal_force
    assert moment == pytest.approx(torque, rel=0.1)
    assert abs(sim.dq[0]) < 1e-3
    # The forearm taken away: no contact from the next step on.
    sim.set_body(Capsules((), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)))
    sim.step('effort', (torque, 0.0), ())
    sim.step('effort', (torque, 0.0), ())
    assert sim.contacts == ()
    log = sim.take_contacts()
    assert len(log) == 1002 and log[-1] == () and sim.take_contacts() == []
    del mujoco


def test_a_steps_contacts_are_those_of_the_state_it_started_from():
    """A forearm standing 1 cm into the SCARA's link 1 pushes the unbraked arm away; a twin
    sim told each published state (q, dq) and the next step's torque finds, by
    contacts_in_state, the next step's contacts: the same links and parts, forces within
    1e-6 N. The twin's own state is left as it was."""
    arm = true_arm(generic_model(robot_model('scara')), 0.1, SEED)
    sim, twin = mujoco_sim(arm), mujoco_sim(arm)
    radius = HUMAN_RADII['forearm']
    x, y = 0.2, 0.05 + radius - 0.01
    forearm = Capsules(('r_forearm',), np.array([[x, y, -0.2]]), np.array([[x, y, 0.2]]),
                       np.array([radius]))
    sim.set_body(forearm)
    twin.set_body(forearm)
    compared = 0
    for _ in range(200):
        expected = twin.contacts_in_state(sim.q, sim.dq, np.zeros(2))
        sim.step('effort', (0.0, 0.0), ())
        assert [(c.robot_link, c.body_part) for c in sim.contacts] == \
            [(c.robot_link, c.body_part) for c in expected]
        for got, want in zip(sim.contacts, expected, strict=True):
            assert got.normal_force == pytest.approx(want.normal_force, abs=1e-6)
        compared += len(expected)
    assert compared > 0 and sim.contacts == ()  # pushed clear within 0.2 s
    assert np.array_equal(twin.data.qpos, arm.home)
    with pytest.raises(ValueError, match=r'dq must have shape \(2,\)'):
        twin.contacts_in_state(arm.home, np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match='torque must be finite'):
        twin.contacts_in_state(arm.home, np.zeros(2), [np.nan, 0.0])


def test_a_hand_moved_onto_the_panda_touches_its_hand_only_while_they_meet(panda):
    """The right hand's sphere moved in over 50 ms steps (set_body's blend) onto the Panda's
    gripper held by its gravity torque: contacts on the gripper's links and the hand, forces
    finite and >= 0; moved away, none."""
    arm = true_arm(panda, 0.1, SEED)
    sim = mujoco_sim(arm)
    tool = arm.tool_position(arm.home)
    touched = set()
    for k in range(8):
        centre = tool + np.array([0.3 - 0.05 * k, 0.0, 0.0])
        sim.set_body(Capsules(('r_hand',), centre[None], centre[None], np.array([0.103])),
                     over=0.05)
        for _ in range(50):
            sim.step('effort', arm.gravity_torque(sim.q), ())
            for contact in sim.contacts:
                assert np.isfinite(contact.normal_force) and contact.normal_force >= 0.0
                touched.add((contact.robot_link, contact.body_part))
    assert touched and {part for _, part in touched} == {'r_hand'}
    assert {link for link, _ in touched} <= {'panda_hand', 'panda_leftfinger',
                                             'panda_rightfinger', 'panda_link7'}
    far = tool + np.array([1.0, 0.0, 0.0])
    sim.set_body(Capsules(('r_hand',), far[None], far[None], np.array([0.103])))
    sim.step('effort', arm.gravity_torque(sim.q), ())
    assert sim.contacts == ()
