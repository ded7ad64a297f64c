"""Unit tests of hri_core.dynamics: the 2-link model, its regressor and the RK4 integrator."""

import numpy as np
import pytest

from hri_core.dynamics import (
    ScaraParameters,
    coriolis_matrix,
    dynamic_parameters,
    forward_dynamics,
    forward_kinematics,
    forward_kinematics_pair,
    friction_torque,
    gravity_torque,
    jacobian,
    jacobian_derivative,
    kinetic_energy,
    mass_matrix,
    potential_energy,
    regressor,
    rk4_step,
)

DEFAULT = ScaraParameters()
VERTICAL = ScaraParameters(gravity=9.81)


def random_states(seed: int, count: int):
    """`count` random (q, dq, dq_r, ddq_r), each (count, 2), in a SCARA's range."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(-2.5, 2.5, (count, 2)), rng.uniform(-3.0, 3.0, (count, 2)),
            rng.uniform(-3.0, 3.0, (count, 2)), rng.uniform(-20.0, 20.0, (count, 2)))


def total_energy(q, dq, p):
    return kinetic_energy(q, dq, p) + potential_energy(q, p)


@pytest.mark.parametrize(('params', 'bound'), [
    (ScaraParameters(b1=0.0, b2=0.0), 1e-9),
    (ScaraParameters(b1=0.0, b2=0.0, gravity=9.81), 1e-5),
])
def test_energy_is_conserved_without_torque_and_friction(params, bound):
    # Measured: horizontal arm max |E - E0| / E0 = 1.6e-11, vertical arm (gravity 9.81)
    # 6.0e-7, over 10 s at dt = 1 ms from q = [0.3, -1.2] rad, dq = [2, -3] rad/s.
    q, dq = np.array([0.3, -1.2]), np.array([2.0, -3.0])
    energy0 = total_energy(q, dq, params)
    drift = 0.0
    for _ in range(10_000):
        q, dq = rk4_step(q, dq, np.zeros(2), 1e-3, params)
        drift = max(drift, abs(total_energy(q, dq, params) - energy0) / energy0)
    assert np.all(np.abs(dq) > 0.0)
    assert drift < bound


def test_friction_dissipates_energy_at_the_rate_dq_f_dq():
    q, dq = np.array([0.2, 0.9]), np.array([1.5, -2.0])
    energy0 = kinetic_energy(q, dq, DEFAULT)
    power = -dq @ friction_torque(dq, DEFAULT)
    dt = 1e-5
    q1, dq1 = rk4_step(q, dq, np.zeros(2), dt, DEFAULT)
    assert (kinetic_energy(q1, dq1, DEFAULT) - energy0) / dt == pytest.approx(power, rel=1e-3)


def test_known_torque_at_rest_gives_the_analytic_acceleration():
    # At q2 = pi/2, M = [[pi1, pi3], [pi3, pi3]]; tau = [1, 0] N m gives
    # ddq = [pi3, -pi3] / (pi1 pi3 - pi3^2).
    pi1, _, pi3 = dynamic_parameters(DEFAULT)[:3]
    ddq = forward_dynamics([0.4, np.pi / 2], [0.0, 0.0], [1.0, 0.0], DEFAULT)
    det = pi1 * pi3 - pi3 ** 2
    np.testing.assert_allclose(ddq, [pi3 / det, -pi3 / det], rtol=1e-12)
    assert ddq[0] > 0.0


def test_forward_dynamics_at_rest_is_m_inverse_tau():
    q, _, _, _ = random_states(1, 50)
    tau = np.random.default_rng(2).uniform(-10.0, 10.0, (50, 2))
    expected = np.linalg.solve(mass_matrix(q, DEFAULT), tau[..., None])[..., 0]
    np.testing.assert_allclose(forward_dynamics(q, np.zeros((50, 2)), tau, DEFAULT), expected,
                               rtol=1e-10, atol=1e-12)


def test_forward_dynamics_inverts_the_equation_of_motion():
    q, dq, _, _ = random_states(3, 50)
    tau = np.random.default_rng(4).uniform(-10.0, 10.0, (50, 2))
    ddq = forward_dynamics(q, dq, tau, VERTICAL)
    rebuilt = (np.einsum('...ij,...j->...i', mass_matrix(q, VERTICAL), ddq)
               + np.einsum('...ij,...j->...i', coriolis_matrix(q, dq, VERTICAL), dq)
               + friction_torque(dq, VERTICAL) + gravity_torque(q, VERTICAL))
    np.testing.assert_allclose(rebuilt, tau, atol=1e-10)


@pytest.mark.parametrize('params', [DEFAULT, VERTICAL, ScaraParameters(m2=5.0, b1=0.1)])
def test_regressor_times_theta_is_the_inverse_dynamics(params):
    q, dq, dq_r, ddq_r = random_states(5, 200)
    expected = (np.einsum('...ij,...j->...i', mass_matrix(q, params), ddq_r)
                + np.einsum('...ij,...j->...i', coriolis_matrix(q, dq, params), dq_r)
                + friction_torque(dq_r, params) + gravity_torque(q, params))
    y = regressor(q, dq, dq_r, ddq_r, gravity=params.gravity)
    assert y.shape == (200, 2, 7)
    np.testing.assert_allclose(y @ dynamic_parameters(params), expected, atol=1e-10)
    single = regressor(q[0], dq[0], dq_r[0], ddq_r[0], gravity=params.gravity)
    np.testing.assert_allclose(single, y[0])


def test_regressor_gravity_columns_vanish_for_the_horizontal_arm():
    q, dq, dq_r, ddq_r = random_states(6, 20)
    assert np.all(regressor(q, dq, dq_r, ddq_r)[..., 5:] == 0.0)
    assert np.all(gravity_torque(q, DEFAULT) == 0.0)


def test_mass_matrix_is_symmetric_positive_definite():
    q = np.stack([np.zeros(361), np.linspace(-np.pi, np.pi, 361)], axis=-1)
    m = mass_matrix(q, DEFAULT)
    np.testing.assert_array_equal(m, np.swapaxes(m, -1, -2))
    assert np.all(np.linalg.eigvalsh(m) > 0.0)


def test_mdot_minus_two_c_is_skew_symmetric():
    q, dq, _, _ = random_states(7, 30)
    h = 1e-6
    mdot = (mass_matrix(q + h * dq, DEFAULT) - mass_matrix(q - h * dq, DEFAULT)) / (2 * h)
    n = mdot - 2.0 * coriolis_matrix(q, dq, DEFAULT)
    np.testing.assert_allclose(n + np.swapaxes(n, -1, -2), 0.0, atol=1e-8)


def test_gravity_torque_is_the_gradient_of_potential_energy():
    q, _, _, _ = random_states(8, 30)
    h = 1e-6
    numeric = np.stack([(potential_energy(q + h * e, VERTICAL)
                         - potential_energy(q - h * e, VERTICAL)) / (2 * h)
                        for e in np.eye(2)], axis=-1)
    np.testing.assert_allclose(gravity_torque(q, VERTICAL), numeric, atol=1e-7)


def test_forward_kinematics_of_known_poses():
    np.testing.assert_allclose(forward_kinematics([0.0, 0.0], 0.35, 0.30), [0.65, 0.0])
    np.testing.assert_allclose(forward_kinematics([0.0, np.pi / 2], 0.35, 0.30), [0.35, 0.30],
                               atol=1e-15)
    np.testing.assert_allclose(forward_kinematics([np.pi / 2, np.pi], 0.35, 0.30),
                               [0.0, 0.05], atol=1e-15)


def test_forward_kinematics_pair_equals_the_array_version():
    q, _, _, _ = random_states(11, 50)
    for q1, q2 in q.tolist():
        np.testing.assert_allclose(forward_kinematics_pair(q1, q2, 0.35, 0.30),
                                   forward_kinematics([q1, q2], 0.35, 0.30), rtol=0, atol=1e-15)


def test_jacobian_matches_finite_differences_of_forward_kinematics():
    q, _, _, _ = random_states(9, 40)
    h = 1e-6
    numeric = np.stack([(forward_kinematics(q + h * e, 0.35, 0.3)
                         - forward_kinematics(q - h * e, 0.35, 0.3)) / (2 * h)
                        for e in np.eye(2)], axis=-1)
    np.testing.assert_allclose(jacobian(q, 0.35, 0.3), numeric, atol=1e-9)


def test_jacobian_derivative_matches_finite_differences_along_the_motion():
    q, dq, _, _ = random_states(10, 40)
    h = 1e-6
    numeric = (jacobian(q + h * dq, 0.35, 0.3) - jacobian(q - h * dq, 0.35, 0.3)) / (2 * h)
    np.testing.assert_allclose(jacobian_derivative(q, dq, 0.35, 0.3), numeric, atol=1e-8)


def test_rk4_global_error_is_fourth_order():
    q0, dq0, tau = np.array([0.1, 1.0]), np.array([3.0, -4.0]), np.array([2.0, -1.0])
    params = ScaraParameters(gravity=9.81)

    def final_state(dt, horizon=0.64):
        q, dq = q0, dq0
        for _ in range(round(horizon / dt)):
            q, dq = rk4_step(q, dq, tau, dt, params)
        return np.concatenate([q, dq])

    reference = final_state(0.64 / 8192)
    errors = [np.linalg.norm(final_state(dt) - reference) for dt in (0.02, 0.01, 0.005)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    # Measured: 4.14 and 4.08 (errors 7.1e-4, 4.0e-5, 2.4e-6).
    assert np.all((orders > 3.7) & (orders < 4.3)), orders


def test_rk4_single_state_path_equals_the_batched_path():
    q, dq, _, tau = random_states(11, 25)
    batch_q, batch_dq = rk4_step(q, dq, tau, 2e-3, VERTICAL)
    for i in range(25):
        single_q, single_dq = rk4_step(q[i], dq[i], tau[i], 2e-3, VERTICAL)
        np.testing.assert_allclose(single_q, batch_q[i], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(single_dq, batch_dq[i], rtol=1e-12, atol=1e-13)


def test_positive_torque_on_joint_one_turns_it_positive():
    q, dq = np.array([0.0, 1.0]), np.zeros(2)
    for _ in range(100):
        q, dq = rk4_step(q, dq, np.array([2.0, 0.0]), 1e-3, DEFAULT)
    assert q[0] > 0.0 and dq[0] > 0.0


@pytest.mark.parametrize(('kwargs', 'message'), [
    ({'m1': 0.0}, 'm1 must be > 0'),
    ({'i2': -0.1}, 'i2 must be > 0'),
    ({'b1': -1.0}, 'b1 must be >= 0'),
    ({'l2': float('nan')}, 'l2 must be finite'),
    ({'lc1': 0.5}, 'centre of mass outside its link'),
])
def test_parameters_reject_unphysical_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ScaraParameters(**kwargs)


@pytest.mark.parametrize(('args', 'message'), [
    (([0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 0.0), 'dt must be a finite positive step'),
    (([0.0, 0.0], [0.0, 0.0], [0.0, 0.0], float('inf')), 'dt must be a finite positive'),
    (([0.0, float('nan')], [0.0, 0.0], [0.0, 0.0], 1e-3), 'q must be finite'),
    (([0.0, 0.0], [0.0, 0.0], [float('inf'), 0.0], 1e-3), 'tau must be finite'),
    (([0.0, 0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 1e-3), r'q must have shape \(\.\.\., 2\)'),
])
def test_rk4_step_rejects_bad_input(args, message):
    with pytest.raises(ValueError, match=message):
        rk4_step(*args, DEFAULT)


def test_regressor_rejects_non_finite_gravity():
    with pytest.raises(ValueError, match='gravity must be finite'):
        regressor([0, 0], [0, 0], [0, 0], [0, 0], gravity=float('nan'))
