"""scara_sim.arm_simulation on the Panda: energy and gravity, joint limits, effort clipping,
the seeded perturbation and determinism."""

from importlib import metadata

import numpy as np
import pytest

from hri_core.robot_model import generic_model, robot_model
from scara_sim.arm_simulation import ArmSimulator, true_arm

DT = 1e-3  # s, the node's step
SEED = 7


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


def simulator(arm, q=None, dq=None):
    q = arm.home if q is None else q
    return ArmSimulator(arm, q, np.zeros(arm.dof) if dq is None else dq, dt=DT)


def test_without_friction_or_torque_the_energy_is_kept(panda):
    """Gravity acting, no friction, no stop reached: kinetic + potential energy stays within
    1e-6 J of its start over 0.2 s of swinging (RK4's error at 1 ms)."""
    arm = true_arm(panda, 0.1, SEED, damping=np.zeros(7))
    sim = simulator(arm, dq=np.full(7, 0.3))
    start = sim.energy()
    for _ in range(200):
        sim.step('idle', None, ())
        assert np.all(sim.q > arm.limits.lower) and np.all(sim.q < arm.limits.upper)
    assert abs(sim.energy() - start) < 1e-6
    assert np.max(np.abs(sim.q - arm.home)) > 0.05  # it did swing


def test_friction_takes_energy_out(panda):
    arm = true_arm(panda, 0.1, SEED, damping=np.full(7, 2.0))
    sim = simulator(arm, dq=np.full(7, 0.3))
    energies = [arm.kinetic_energy(sim.q, sim.dq)]
    for _ in range(200):
        sim.step('effort', arm.gravity_torque(sim.q), ())
        energies.append(arm.kinetic_energy(sim.q, sim.dq))
    # With gravity compensated only the friction works: the kinetic energy falls each step.
    assert np.all(np.diff(energies) < 0.0)


def test_zero_torque_sags_under_gravity_and_the_true_gravity_torque_holds(panda):
    arm = true_arm(panda, 0.1, SEED)
    falling, held = simulator(arm), simulator(arm)
    for _ in range(300):
        falling.step('effort', np.zeros(7), ())
        held.step('effort', arm.gravity_torque(held.q), ())
    assert np.max(np.abs(falling.q - arm.home)) > 0.05
    np.testing.assert_allclose(held.q, arm.home, atol=1e-9)


def test_the_urdf_gravity_torque_does_not_hold_the_perturbed_arm(panda):
    """The model error is real: the nominal (URDF) g(q) leaves the true arm drifting."""
    arm = true_arm(panda, 0.1, SEED)
    sim = simulator(arm)
    for _ in range(300):
        sim.step('effort', panda.gravity_torque(sim.q), ())
    assert np.max(np.abs(sim.q - arm.home)) > 1e-3


def test_joint_limits_are_inelastic_stops(panda):
    arm = true_arm(panda, 0.0, SEED)
    upper = arm.limits.upper.copy()
    q = arm.home.copy()
    q[3] = upper[3] - 0.01  # joint 4, 0.01 rad below its upper limit
    sim = simulator(arm, q=q)
    push = arm.gravity_torque(q)
    push[3] += 40.0
    for _ in range(200):
        push_now = arm.gravity_torque(sim.q)
        push_now[3] += 40.0
        sim.step('effort', push_now, ())
        assert np.all(sim.q <= arm.limits.upper) and np.all(sim.q >= arm.limits.lower)
    assert sim.q[3] == upper[3]
    assert sim.dq[3] == 0.0


def test_efforts_are_clipped_at_the_urdf_limits(panda):
    arm = true_arm(panda, 0.1, SEED)
    sim = simulator(arm)
    _, _, effort = sim.step('effort', np.full(7, 500.0), ())
    np.testing.assert_array_equal(effort, [87.0] * 4 + [12.0] * 3)
    _, _, effort = sim.step('effort', np.full(7, -500.0), ())
    np.testing.assert_array_equal(effort, [-87.0] * 4 + [-12.0] * 3)
    _, _, effort = sim.step('idle', None, ())
    np.testing.assert_array_equal(effort, np.zeros(7))
    with pytest.raises(ValueError, match="unknown command mode 'velocity'"):
        sim.step('velocity', np.zeros(7), ())


def test_a_wrench_at_the_tool_accelerates_it_as_the_dynamics_say(panda):
    """From rest with gravity compensated, one step under a force f at the tool moves it by
    1/2 dt^2 J M^-1 J^T f (the tool's acceleration), to 1 %; a torque alone turns the hand."""
    arm = true_arm(panda, 0.1, SEED)
    sim = simulator(arm)
    start = arm.tool_position(sim.q)
    force = np.array([5.0, -10.0, 20.0])
    jacobian = arm.tool_jacobian(sim.q)
    expected = 0.5 * DT ** 2 * jacobian @ arm.inverse_mass_matrix(sim.q) @ jacobian.T @ force
    sim.step('effort', arm.gravity_torque(sim.q), tuple(force))
    np.testing.assert_allclose(arm.tool_position(sim.q) - start, expected,
                               rtol=0.01, atol=1e-3 * np.max(np.abs(expected)))
    turned = simulator(arm)
    torque = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    expected_dq = DT * arm.inverse_mass_matrix(turned.q) @ arm.tool_wrench_jacobian(
        turned.q).T @ torque
    turned.step('effort', arm.gravity_torque(turned.q), tuple(torque))
    np.testing.assert_allclose(turned.dq, expected_dq, rtol=0.01,
                               atol=1e-3 * np.max(np.abs(expected_dq)))


def test_hitting_a_stop_is_a_plastic_impact(panda):
    """The joint stops on its limit; the others keep the velocity the impulse leaves them,
    and kinetic energy is lost, not gained."""
    arm = true_arm(panda, 0.0, SEED, damping=np.zeros(7))
    q = arm.home.copy()
    q[5] = arm.limits.upper[5] - 1e-4
    dq = np.zeros(7)
    dq[5] = 1.0
    sim = simulator(arm, q=q, dq=dq)
    before = arm.kinetic_energy(sim.q, sim.dq)
    sim.step('effort', arm.gravity_torque(sim.q), ())
    assert sim.q[5] == arm.limits.upper[5] and sim.dq[5] == 0.0
    assert arm.kinetic_energy(sim.q, sim.dq) < before


def test_the_same_seed_gives_the_same_run_and_another_seed_another_arm(panda):
    runs = []
    for seed in (SEED, SEED, SEED + 1):
        sim = simulator(true_arm(panda, 0.1, seed))
        for _ in range(100):
            sim.step('effort', np.full(7, 1.0), ())
        runs.append(sim.q.copy())
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.max(np.abs(runs[0] - runs[2])) > 1e-6


def test_perturbation_keeps_masses_within_its_bounds(panda):
    nominal = panda.theta[0:70:10]
    for seed in range(20):
        masses = true_arm(panda, 0.1, seed).theta[0:70:10]
        assert np.all(masses >= 0.9 * nominal - 1e-12)
        assert np.all(masses <= 1.1 * nominal + 1e-12)
    np.testing.assert_array_equal(true_arm(panda, 0.0, 3).theta, panda.theta)


@pytest.mark.parametrize(('kwargs', 'reason'), [
    ({'perturbation': 1.0}, r'perturbation must be in \[0, 1\)'),
    ({'damping': np.zeros(6)}, 'damping must be 7 finite values'),
    ({'damping': np.full(7, -1.0)}, 'damping must be 7 finite values'),
])
def test_bad_perturbations_are_refused(panda, kwargs, reason):
    arguments = {'perturbation': 0.1, 'seed': 0, **kwargs}
    with pytest.raises(ValueError, match=reason):
        true_arm(panda, **arguments)


def test_bad_initial_states_are_refused(panda):
    with pytest.raises(ValueError, match='outside the joint limits'):
        simulator(panda, q=np.zeros(7))  # joint 4's range is -3.07 .. -0.07 rad
    with pytest.raises(ValueError, match=r'initial q must have shape \(7,\)'):
        simulator(panda, q=np.zeros(2))
    with pytest.raises(ValueError, match='dt must be finite and > 0'):
        ArmSimulator(panda, panda.home, np.zeros(7), dt=0.0)


def test_a_non_finite_state_is_reported():
    scara = generic_model(robot_model('scara'))
    sim = simulator(scara)
    sim.dq = np.array([np.inf, 0.0])
    with pytest.raises(ValueError, match='the simulated state became non-finite'):
        sim.step('idle', None, ())


def test_the_generic_scara_steps_like_scara_sim():
    """arm_sim robot:=scara and scara_sim integrate the same arm: one RK4 step agrees."""
    from hri_core.dynamics import ScaraParameters, rk4_step

    scara = generic_model(robot_model('scara'))
    sim = simulator(scara, dq=np.array([0.5, -0.3]))
    tau = np.array([3.0, -1.0])
    q, dq = rk4_step(sim.q, sim.dq, tau, DT, ScaraParameters())
    sim.step('effort', tau, ())
    np.testing.assert_allclose(sim.q, q, atol=1e-12)
    np.testing.assert_allclose(sim.dq, dq, atol=1e-12)


def teach_simulator(arm, dq=None, damping=1.0):
    return ArmSimulator(arm, arm.home, np.zeros(arm.dof) if dq is None else dq, dt=DT,
                        teach_mode=True, teach_damping=damping)


def test_teach_mode_floats_the_perturbed_arm_where_it_is(panda):
    """Idle in teach mode: the drive holds the true arm's own gravity, so it stays put, where
    the same arm idle without teach mode sags."""
    arm = true_arm(panda, 0.1, SEED)
    taught, idle = teach_simulator(arm), simulator(arm)
    for _ in range(500):
        taught.step('idle', None, ())
        idle.step('idle', None, ())
    np.testing.assert_allclose(taught.q, arm.home, atol=1e-12)
    np.testing.assert_allclose(taught.applied_effort, arm.gravity_torque(taught.q), atol=1e-12)
    assert np.max(np.abs(idle.q - arm.home)) > 0.05


def test_teach_mode_damps_a_moving_arm_to_rest(panda):
    """The teach damping takes the arm's motion out: the kinetic energy falls every step and
    is under a fifth of its start after 1 s, where the URDF's 0.003 N m s/rad alone keeps
    over 90 % of it."""
    arm = true_arm(panda, 0.1, SEED)
    sim = teach_simulator(arm, dq=np.full(7, 0.3))
    energies = [arm.kinetic_energy(sim.q, sim.dq)]
    for _ in range(1000):
        sim.step('idle', None, ())
        energies.append(arm.kinetic_energy(sim.q, sim.dq))
    assert np.all(np.diff(energies) < 0.0)
    assert energies[-1] < 0.2 * energies[0]
    undamped = teach_simulator(arm, dq=np.full(7, 0.3), damping=0.0)
    for _ in range(1000):
        undamped.step('idle', None, ())
    assert arm.kinetic_energy(undamped.q, undamped.dq) > 0.9 * energies[0]


def test_teach_mode_a_push_at_the_tool_moves_it_along_the_push(panda):
    arm = true_arm(panda, 0.1, SEED)
    sim = teach_simulator(arm)
    start = arm.tool_position(sim.q)
    push = np.array([0.0, 3.0, -4.0])  # N, sideways and down
    for _ in range(300):
        sim.step('idle', None, (*push, 0.0, 0.0, 0.0))
    moved = arm.tool_position(sim.q) - start
    assert np.linalg.norm(moved) > 0.005
    assert moved @ push / (np.linalg.norm(moved) * np.linalg.norm(push)) > 0.8


def test_teach_mode_keeps_the_efforts_within_the_limits(panda):
    arm = true_arm(panda, 0.1, SEED)
    sim = teach_simulator(arm, dq=np.full(7, 2.0), damping=50.0)
    sim.step('effort', np.full(7, 80.0), ())
    assert np.all(np.abs(sim.applied_effort) <= arm.limits.effort)
    assert np.any(np.abs(sim.applied_effort) == arm.limits.effort)
    with pytest.raises(ValueError, match='teach_damping must be finite and >= 0'):
        teach_simulator(arm, damping=-1.0)


def test_brake_holds_the_arm_still_against_gravity_and_a_push(panda):
    sim = simulator(true_arm(panda, 0.1, SEED), dq=np.full(7, 0.3))
    start = sim.q.copy()
    for _ in range(200):
        q, dq, effort = sim.step('brake', None, (5.0, 0.0, -5.0))
    np.testing.assert_array_equal(np.array(q), start)
    assert not any(dq) and not any(effort)


XARM7 = 'cmeel.prefix/share/example-robot-data/robots/xarm_description/urdf/xarm7.urdf'


def test_friction_stiff_against_a_light_wrist_stays_finite():
    # The xArm7's URDF (example-robot-data): 2 N m s/rad of friction on a wrist of
    # 1.4e-4 kg m^2. In the RK4 it made the state non-finite within 8 steps; applied
    # implicitly after the step it slows the falling arm, which comes to rest on its stops.
    path = metadata.distribution('example-robot-data').locate_file(XARM7)
    arm = true_arm(robot_model(urdf_file=str(path), tool_frame='link_eef'), 0.1, SEED)
    assert np.max(DT * arm.damping / np.linalg.eigvalsh(arm.mass_matrix(arm.home)).min()) > 10
    sim = simulator(arm, dq=np.full(arm.dof, 0.5))
    for _ in range(2000):
        sim.step('idle', None, ())
        assert np.all(np.isfinite(sim.dq))
        assert np.all(sim.q >= arm.limits.lower) and np.all(sim.q <= arm.limits.upper)
    assert np.max(np.abs(sim.dq)) < 0.5
