"""Unit tests of hri_adaptive_controller.adaptive_law: eq. 16-22, limits and the controller."""

import dataclasses
import math

import numpy as np
import pytest

from hri_adaptive_controller.adaptive_law import (
    DEFAULT_GAINS,
    AdaptiveController,
    adaptive_torque,
    limit_torque,
    lyapunov,
    mass_matrix_from_parameters,
    parameter_update_rate,
    predicted_lyapunov_rate,
)
from hri_adaptive_controller.task_variable import DampingSettings, speed_cap
from hri_core.dynamics import (
    ScaraParameters,
    dynamic_parameters,
    jacobian,
    mass_matrix,
    regressor,
)
from hri_core.potential import TaskShape, log_potential_slope

PARAMS = ScaraParameters()
THETA = dynamic_parameters(PARAMS)
FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)
AVOID = TaskShape(1, 0.056, 25.46, 0.183, 2.0)


def controller(theta_hat0=THETA, **changes):
    gains = dataclasses.replace(DEFAULT_GAINS, **changes)
    return AdaptiveController(gains, theta_hat0, PARAMS.l1, PARAMS.l2)


def state(rng):
    q = np.array([rng.uniform(-1.0, 1.0), rng.uniform(0.7, 2.2)])
    return q, rng.normal(0.0, 0.5, 2)


def test_limit_torque_keeps_the_direction():
    rng = np.random.default_rng(3)
    for _ in range(100):
        tau = rng.normal(0.0, 30.0, 2)
        limited, scaled = limit_torque(tau, 20.0)
        assert np.max(np.abs(limited)) <= 20.0 + 1e-12
        assert scaled == (np.max(np.abs(tau)) > 20.0)
        assert limited @ tau == pytest.approx(np.linalg.norm(limited) * np.linalg.norm(tau))
    unchanged, scaled = limit_torque(np.array([3.0, -4.0]), 20.0)
    np.testing.assert_array_equal(unchanged, [3.0, -4.0])
    assert not scaled
    with pytest.raises(ValueError, match='effort_limit'):
        limit_torque(np.zeros(2), 0.0)


def test_torque_law_is_eq_16_with_the_transposed_jacobian():
    rng = np.random.default_rng(4)
    q, dq = state(rng)
    s, task = rng.normal(size=2), rng.normal(size=2)
    y_d = regressor(q, dq, rng.normal(size=2), rng.normal(size=2))
    jac = jacobian(q, PARAMS.l1, PARAMS.l2)
    tau = adaptive_torque(s, jac, task, y_d, THETA, np.array([20.0, 4.0]), 10.0)
    expected = -np.diag([20.0, 4.0]) @ s - jac.T @ (10.0 * task) + y_d @ THETA
    np.testing.assert_allclose(tau, expected)


def test_update_law_is_eq_19():
    rng = np.random.default_rng(5)
    q, dq = state(rng)
    y_d = regressor(q, dq, rng.normal(size=2), rng.normal(size=2))
    s = rng.normal(size=2)
    gains = np.arange(1.0, 8.0)
    np.testing.assert_allclose(parameter_update_rate(y_d, s, gains), -np.diag(gains) @ y_d.T @ s)


def test_mass_matrix_from_parameters_is_the_model_inertia():
    rng = np.random.default_rng(6)
    vertical = ScaraParameters(gravity=9.81)
    for _ in range(10):
        q, _ = state(rng)
        np.testing.assert_allclose(mass_matrix_from_parameters(q, THETA), mass_matrix(q, PARAMS),
                                   atol=1e-12)
        np.testing.assert_allclose(
            mass_matrix_from_parameters(q, dynamic_parameters(vertical), 9.81),
            mass_matrix(q, vertical), atol=1e-12)


def test_lyapunov_function_terms():
    q, s = np.array([0.2, 1.0]), np.array([0.3, -0.2])
    gains = np.array(DEFAULT_GAINS.adaptation)
    kinetic = 0.5 * s @ mass_matrix(q, PARAMS) @ s
    assert lyapunov(s, q, 0.5, 0.2, 10.0, THETA, gains) == pytest.approx(kinetic + 1.0)
    theta_hat = THETA * 1.1
    error = THETA - theta_hat
    expected = kinetic + 1.0 + 0.5 * np.sum(error ** 2 / gains)
    assert lyapunov(s, q, 0.5, 0.2, 10.0, theta_hat, gains, theta_true=THETA) == pytest.approx(
        expected)
    # Unknown true parameters: the inertia comes from theta_hat.
    estimate = 0.5 * s @ mass_matrix_from_parameters(q, theta_hat) @ s + 1.0
    assert lyapunov(s, q, 0.5, 0.2, 10.0, theta_hat, gains) == pytest.approx(estimate)


def test_predicted_rate_is_eq_22():
    s, task = np.array([0.1, -0.3]), np.array([0.05, 0.02])
    rate = predicted_lyapunov_rate(s, task, 0.7, 0.4, (20.0, 4.0), 10.0, (1.0, 0.5))
    expected = -(21.0 * 0.01 + 4.5 * 0.09) - 10.0 * (0.05 ** 2 + 0.02 ** 2) + 10.0 * 0.7 * 0.4
    assert rate == pytest.approx(expected)


def test_step_at_rest_in_the_region_commands_nothing():
    ctrl = controller()
    q = np.array([0.0, math.pi / 2])
    x = np.array([0.35, 0.30])
    out = ctrl.step(q, np.zeros(2), x + [0.01, 0.0], np.zeros(2), np.zeros(2), 1.0, 0.0, FOLLOW,
                    1e-3)
    assert not out.fault and out.distance == pytest.approx(0.01)
    np.testing.assert_allclose(out.tau, 0.0, atol=1e-12)
    assert out.lyapunov == pytest.approx(0.0, abs=1e-12)


def test_step_moves_towards_the_target_and_adapts():
    ctrl = controller(theta_hat0=THETA * 0.7)
    q = np.array([0.0, math.pi / 2])
    target = np.array([0.45, 0.05])
    out = ctrl.step(q, np.zeros(2), target, np.zeros(2), np.zeros(2), 1.0, 0.0, FOLLOW, 1e-3)
    reference = out.reference
    # The task velocity points from the end-effector to the target at K |dP/dz| under the cap.
    distance = float(np.linalg.norm(reference.dx))
    pull = math.exp(math.log(ctrl.task_gain(FOLLOW)) + float(log_potential_slope(distance,
                                                                                 FOLLOW)))
    assert pull > DEFAULT_GAINS.max_task_speed
    assert reference.task_velocity @ (-reference.dx / distance) == pytest.approx(
        speed_cap(pull, DEFAULT_GAINS.max_task_speed)[0], rel=1e-9)
    assert not np.allclose(ctrl.theta_hat, THETA * 0.7)
    assert out.task_gain == ctrl.task_gain(FOLLOW) > 0.0


def test_huge_avoidance_gradient_gives_bounded_torque():
    ctrl = controller()
    q = np.array([0.0, math.pi / 2])
    # Table I's avoid row: P ~ 1e124 here, K ~ 1e-126 m^2/s; the push is an ordinary speed.
    for offset in (1e-9, 0.01, 0.05, 0.1):
        out = ctrl.step(q, np.zeros(2), np.array([0.35, 0.30]) + [offset, 0.0], np.zeros(2),
                        np.zeros(2), 1.0, 0.0, AVOID, 1e-3)
        assert not out.fault
        assert np.all(np.isfinite(out.tau)) and np.max(np.abs(out.tau)) <= 20.0
        pull = math.exp(math.log(ctrl.task_gain(AVOID)) + float(log_potential_slope(offset,
                                                                                    AVOID)))
        assert np.linalg.norm(out.reference.task_velocity) == pytest.approx(
            speed_cap(pull, DEFAULT_GAINS.max_task_speed)[0], rel=1e-9)


def test_non_finite_measurement_gives_zero_torque_and_a_fault():
    ctrl = controller(theta_hat0=THETA * 0.7)
    before = ctrl.theta_hat
    out = ctrl.step(np.array([np.nan, 1.0]), np.zeros(2), np.zeros(2), np.zeros(2),
                    np.zeros(2), 1.0, 0.0, FOLLOW, 1e-3)
    assert out.fault and 'non-finite' in out.fault_reason
    np.testing.assert_array_equal(out.tau, 0.0)
    np.testing.assert_array_equal(ctrl.theta_hat, before)


def test_singular_jacobian_without_damping_is_a_fault_not_a_crash():
    ctrl = controller(damping=DampingSettings(threshold=0.05, max_damping=0.0))
    out = ctrl.step(np.array([0.0, 0.0]), np.zeros(2), np.array([0.3, 0.0]), np.zeros(2),
                    np.zeros(2), 1.0, 0.0, FOLLOW, 1e-3)
    assert out.fault and 'singular' in out.fault_reason
    np.testing.assert_array_equal(out.tau, 0.0)


def test_projection_keeps_theta_hat_in_the_box():
    lower = np.array(DEFAULT_GAINS.theta_lower)
    ctrl = controller(theta_hat0=np.where(np.isfinite(lower), lower, 0.0))
    rng = np.random.default_rng(8)
    for _ in range(200):
        q, dq = state(rng)
        ctrl.step(q, dq * 4.0, rng.uniform(0.2, 0.5, 2), rng.normal(size=2), np.zeros(2),
                  1.0, 0.0, FOLLOW, 1e-2)
        assert np.all(ctrl.theta_hat >= lower)


def test_without_task_the_arm_tracks_the_target_velocity_only():
    ctrl = controller()
    q = np.array([0.2, 1.2])
    out = ctrl.step(q, np.zeros(2), np.array([5.0, 5.0]), np.array([0.1, 0.0]), np.zeros(2),
                    0.0, 0.0, None, 1e-3)
    np.testing.assert_allclose(out.reference.qdot_r,
                               np.linalg.solve(jacobian(q, PARAMS.l1, PARAMS.l2), [0.1, 0.0]))
    assert out.task_gain == 0.0 and out.task_potential == 0.0


@pytest.mark.parametrize(('changes', 'match'), [
    ({'ks': (0.0, 4.0)}, 'ks'),
    ({'kp': -1.0}, 'kp'),
    ({'adaptation': (1.0,) * 6}, 'adaptation'),
    ({'task_gain': 0.0}, 'task_gain'),
    ({'max_task_speed': 0.0}, 'max_task_speed'),
    ({'effort_limit': float('inf')}, 'effort_limit'),
    ({'region_margin': -0.001}, 'region_margin'),
    ({'approach_speed': -0.1}, 'approach_speed'),
    ({'rest_gain': math.nan}, 'rest_gain'),
    ({'rest_gate': 0.0}, 'rest_gate'),
    ({'theta_lower': (1.0,) * 7, 'theta_upper': (0.0,) * 7}, 'theta_lower'),
])
def test_bad_gains_are_rejected(changes, match):
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(DEFAULT_GAINS, **changes)


def test_bad_step_arguments_are_rejected():
    ctrl = controller()
    args = (np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match='dt'):
        ctrl.step(*args, 1.0, 0.0, FOLLOW, 0.0)
    with pytest.raises(ValueError, match='a\\(E, t\\)'):
        ctrl.step(*args, 1.2, 0.0, FOLLOW, 1e-3)
    with pytest.raises(ValueError, match='shape'):
        ctrl.step(np.zeros(3), *args[1:], 1.0, 0.0, FOLLOW, 1e-3)
    with pytest.raises(ValueError, match='theta_hat0'):
        AdaptiveController(DEFAULT_GAINS, np.zeros(6))


# -- the lean step (the node's 1 kHz path) against the reference step -------------------------

FOLLOW_SAFE = TaskShape(1, 1.576, 30.78, 0.183, 0.271)
KEEP_OUT = TaskShape(-1, 40.0, 30.0, 0.05, 0.12)  # S = -1: region r <= d1 or r >= d2
LEAN_SHAPES = (None, FOLLOW, AVOID, FOLLOW_SAFE, KEEP_OUT)


def assert_close(value, expected):
    """Equal to 1e-12 relative to the vector's size: a 2 x 2 product summed in another order
    differs by rounding of its largest entry (qddot_r reaches 1e6 rad/s^2 on these states)."""
    expected = np.asarray(expected, dtype=float)
    scale = max(1.0, float(np.max(np.abs(expected))))
    np.testing.assert_allclose(value, expected, rtol=0.0, atol=1e-12 * scale)


def assert_lean_equals_reference(lean, reference):
    close = {'rtol': 1e-12, 'atol': 1e-12}
    assert lean.fault == reference.fault and lean.fault_reason == reference.fault_reason
    assert_close(lean.tau, reference.tau)
    assert_close(lean.tau_requested, reference.tau_requested)
    assert_close(lean.s, reference.s)
    np.testing.assert_allclose(lean.theta_hat, reference.theta_hat, **close)
    assert lean.torque_limited == reference.torque_limited
    assert lean.task_gain == reference.task_gain
    if reference.fault:
        return
    np.testing.assert_allclose(lean.qdot_r, reference.reference.qdot_r, **close)
    assert lean.distance == pytest.approx(reference.distance, rel=1e-12, abs=1e-12)
    for name in ('lyapunov', 'task_potential', 'lyapunov_rate'):
        value, expected = getattr(lean, name), getattr(reference, name)
        assert (value is None) == (expected is None), name
        if expected is not None:
            assert value == pytest.approx(expected, rel=1e-12, abs=1e-12), name



def test_v_without_its_task_term_plus_task_energy_is_v():
    """The controller publishes its command, then adds a kp Q to V (controller_node). Each
    controller here is new, so its task_energy is task_potential's value (its path of
    distances is tested in test_task_variable)."""
    rng = np.random.default_rng(7)
    for i in range(60):
        whole, split = controller(), controller()
        q, dq = tuple(rng.uniform(-2.0, 2.0, 2)), tuple(rng.normal(0.0, 1.0, 2))
        x_d = tuple(rng.uniform(-0.5, 0.5, 2))
        a, da = float(rng.uniform(0.0, 1.0)), float(rng.normal(0.0, 1.0))
        shape = LEAN_SHAPES[i % len(LEAN_SHAPES)]
        k = float(rng.choice([0.0, 30.0]))
        args = (q, dq, x_d, (0.01, 0.0), (0.0, 0.0), a, da, shape, 1e-3)
        full = whole.step_lean(*args, monitor=True, k=k)
        part = split.step_lean(*args, monitor=True, k=k, with_potential=False)
        if full.fault:
            continue
        v = part.lyapunov + a * split.task_energy(part.distance, shape, k)
        assert v == pytest.approx(full.lyapunov, rel=1e-12, abs=1e-12)
    assert controller().task_energy(0.1, None) == 0.0

@pytest.mark.parametrize('seed', range(4))
def test_lean_step_equals_the_reference_step_on_random_states(seed):
    rng = np.random.default_rng(seed)
    theta0 = THETA * rng.uniform(0.5, 1.5, 7)
    reference, lean = controller(theta_hat0=theta0), controller(theta_hat0=theta0)
    for i in range(300):
        # q2 near 0 or +-pi/2...: the damped pseudo-inverse and its derivative are exercised.
        q = np.array([rng.uniform(-math.pi, math.pi),
                      rng.choice([rng.uniform(-0.4, 0.4), rng.uniform(-2.4, 2.4)])])
        dq = rng.normal(0.0, 1.0, 2)
        tip = np.array([PARAMS.l1 * math.cos(q[0]) + PARAMS.l2 * math.cos(q.sum()),
                        PARAMS.l1 * math.sin(q[0]) + PARAMS.l2 * math.sin(q.sum())])
        # Targets from on the tip (dx = 0 exactly, once in a while) to far outside every region.
        x_d = tip - rng.choice([0.0, 1e-9, 0.02, 0.2, 0.5]) * rng.normal(size=2)
        xdot_d, xddot_d = rng.normal(0.0, 0.1, 2), rng.normal(0.0, 0.5, 2)
        a, da = float(rng.uniform(0.0, 1.0)), float(rng.normal(0.0, 1.0))
        shape = LEAN_SHAPES[i % len(LEAN_SHAPES)]
        k = float(rng.choice([0.0, 0.1, 30.0]))  # the task's K (0: default)
        rest = None if i % 4 == 0 else tip + rng.normal(0.0, 0.1, 2)
        monitor = i % 3 == 0
        truth = THETA if i % 2 else None
        friction = (PARAMS.b1, PARAMS.b2) if i % 2 else None
        expected = reference.step(q, dq, x_d, xdot_d, xddot_d, a, da, shape, 1e-3,
                                  theta_true=truth, friction=friction, monitor=monitor,
                                  k=k, rest=rest)
        out = lean.step_lean(tuple(q), tuple(dq), tuple(x_d), tuple(xdot_d), tuple(xddot_d),
                             a, da, shape, 1e-3, monitor=monitor, theta_true=truth,
                             friction=friction, k=k,
                             rest=None if rest is None else tuple(rest.tolist()))
        assert_lean_equals_reference(out, expected)
    np.testing.assert_allclose(lean.theta_hat, reference.theta_hat, rtol=1e-12, atol=1e-12)


def test_lean_step_faults_like_the_reference():
    args = ((0.0, 0.0), (0.0, 0.0), (0.3, 0.0), (0.0, 0.0), (0.0, 0.0), 1.0, 0.0, FOLLOW, 1e-3)
    undamped = DampingSettings(threshold=0.05, max_damping=0.0)
    expected = controller(damping=undamped).step(*(np.array(v) for v in args[:5]), *args[5:])
    out = controller(damping=undamped).step_lean(*args)
    assert out.fault and 'singular' in out.fault_reason
    assert_lean_equals_reference(out, expected)
    # A non-finite input that slipped past the caller's checks: zero torque, theta_hat kept.
    ctrl = controller(theta_hat0=THETA * 0.7)
    out = ctrl.step_lean((math.nan, 1.0), *args[1:])
    assert out.fault and 'non-finite' in out.fault_reason and out.tau == (0.0, 0.0)
    np.testing.assert_array_equal(ctrl.theta_hat, THETA * 0.7)
