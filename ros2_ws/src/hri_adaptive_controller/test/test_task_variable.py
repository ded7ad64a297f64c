"""Unit tests of hri_adaptive_controller.task_variable: eq. 12', 14 and the exact qddot_r."""

import math

import numpy as np
import pytest

from hri_adaptive_controller.task_variable import (
    DampingSettings,
    ShapedPotential,
    damped_pseudo_inverse,
    damped_pseudo_inverse_derivative,
    joint_velocity_reference,
    pseudo_inverse_damping,
    radial_potential_slope,
    shaped_potential,
    task_potential,
    task_variable,
)
from hri_core.dynamics import jacobian, jacobian_derivative
from hri_core.potential import TaskShape, potential

L1, L2 = 0.35, 0.30
TABLE_I = {
    'follow': TaskShape(1, 1.291, 13.66, 0.0, 0.041),
    'avoid': TaskShape(1, 0.056, 25.46, 0.183, 2.0),
    'follow_safe': TaskShape(1, 1.576, 30.78, 0.183, 0.271),
}
TRAP = TaskShape(-1, 4.0, 12.0, 0.1, 0.25)  # S = -1: desired region r <= d1 or r >= d2
V_MAX, APPROACH, MARGIN = 0.25, 0.01, 0.002
DAMPING = DampingSettings(threshold=0.05, max_damping=0.15)


def shaped(name, margin=MARGIN):
    return shaped_potential(TABLE_I[name], V_MAX, APPROACH, margin)


def direction(angle):
    return np.array([math.cos(angle), math.sin(angle)])


def test_pseudo_inverse_is_the_inverse_away_from_singularities():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = np.array([rng.uniform(-3, 3), rng.uniform(0.6, 2.4) * rng.choice([-1, 1])])
        jac = jacobian(q, L1, L2)
        pinv, lam2 = damped_pseudo_inverse(jac, DAMPING)
        assert lam2 == 0.0
        np.testing.assert_allclose(pinv, np.linalg.inv(jac), rtol=1e-10, atol=1e-10)


def test_damping_grows_smoothly_towards_the_singularity():
    q2 = np.linspace(0.0, 1.0, 20001)
    lam2 = np.array([pseudo_inverse_damping(jacobian(np.array([0.3, x]), L1, L2), DAMPING)[0]
                     for x in q2])
    # w = l1 l2 |sin q2| < w0 = 0.05 m^2 below q2 = asin(0.05 / 0.105).
    start = math.asin(0.05 / (L1 * L2))
    assert np.all(lam2[q2 > start + 1e-6] == 0.0)
    assert np.all(np.diff(lam2[q2 < start]) < 0.0)
    assert lam2[0] == pytest.approx(DAMPING.max_damping ** 2)
    slope = np.diff(lam2) / np.diff(q2)
    assert np.max(np.abs(np.diff(slope))) < 1e-3  # C1: no kink at the threshold


def test_pseudo_inverse_at_the_singularity_is_finite_and_bounded():
    for q2 in (0.0, 1e-9, -1e-4):
        jac = jacobian(np.array([0.4, q2]), L1, L2)
        pinv, _ = damped_pseudo_inverse(jac, DAMPING)
        assert np.all(np.isfinite(pinv))
        # sigma / (sigma^2 + lambda^2) <= 1 / (2 lambda) in the singular direction.
        assert np.linalg.norm(pinv, 2) <= max(1.0 / (2 * DAMPING.max_damping),
                                              1.0 / np.linalg.svd(jac)[1][0]) + 1e-9


@pytest.mark.parametrize('q_mid', [(0.2, 1.2), (0.5, 0.52), (1.0, 0.3), (-0.7, -0.05)])
def test_pseudo_inverse_derivative_matches_finite_difference(q_mid):
    amplitude, omega = np.array([0.4, 0.15]), np.array([1.3, 2.1])

    def q_of(t):
        return np.asarray(q_mid) + amplitude * np.sin(omega * t)

    def dq_of(t):
        return amplitude * omega * np.cos(omega * t)

    h = 1e-6
    for t in np.linspace(0.0, 3.0, 13):
        jac, jac_dot = jacobian(q_of(t), L1, L2), jacobian_derivative(q_of(t), dq_of(t), L1, L2)
        analytic = damped_pseudo_inverse_derivative(jac, jac_dot, DAMPING)
        numeric = (damped_pseudo_inverse(jacobian(q_of(t + h), L1, L2), DAMPING)[0]
                   - damped_pseudo_inverse(jacobian(q_of(t - h), L1, L2), DAMPING)[0]) / (2 * h)
        scale = max(1.0, float(np.max(np.abs(analytic))))
        assert np.max(np.abs(analytic - numeric)) <= 1e-6 * scale


@pytest.mark.parametrize('name', sorted(TABLE_I))
def test_task_variable_points_to_the_region_and_is_bounded(name):
    task = shaped(name)
    d1, d2 = task.region()
    rng = np.random.default_rng(1)
    for r in np.concatenate([rng.uniform(0.001, 0.9, 200), [0.5 * (d1 + d2)]]):
        if r > 0.9:
            continue
        e = direction(rng.uniform(-math.pi, math.pi))
        value = task_variable(r * e, task)
        norm = np.linalg.norm(value.gradient)
        assert norm <= V_MAX
        if d1 <= r <= d2:
            assert norm == 0.0
        elif r > d2:  # moving along -gradient brings the arm closer
            assert value.gradient @ e > 0.0
        else:  # too close: -gradient pushes it away
            assert value.gradient @ e < 0.0


@pytest.mark.parametrize('name', sorted(TABLE_I))
def test_task_gain_gives_the_approach_speed(name):
    task = shaped(name)
    d1, d2 = task.region()
    probes = [d2 + APPROACH] if name != 'avoid' else []
    if d1 > 0.0:
        probes.append(d1 - APPROACH)
    for r in probes:
        slope = task_variable(np.array([r, 0.0]), task).radial_slope
        assert abs(slope) >= math.tanh(1.0) * V_MAX * (1 - 1e-9)


def test_region_margin_shrinks_the_zero_set_inside_the_learned_region():
    task = shaped('follow_safe', margin=0.002)
    d1, d2 = task.region()
    assert (d1, d2) == pytest.approx((0.185, 0.269))
    for r, moving in ((0.184, True), (0.186, False), (0.268, False), (0.27, True)):
        slope = task_variable(np.array([0.0, r]), task).radial_slope
        assert (slope != 0.0) == moving
    # The follow region [0, 0.041] has no inner boundary: only d2 moves.
    assert shaped('follow').region() == pytest.approx((0.0, 0.039))
    # S = -1: both parts of the region shrink, and Q is smooth (flat) at r = 0.
    trap = shaped_potential(TRAP, V_MAX, APPROACH, MARGIN)
    assert trap.region() == pytest.approx((0.098, 0.252))
    for r, moving in ((0.0, False), (0.097, False), (0.099, True), (0.251, True),
                      (0.253, False)):
        slope = task_variable(np.array([r, 0.0]), trap).radial_slope
        assert (slope != 0.0) == moving
    assert not task_variable(np.zeros(2), trap).hessian.any()


@pytest.mark.parametrize(('name', 'radii'), [
    ('follow', (0.042, 0.045, 0.06, 0.1, 0.3)),
    ('follow_safe', (0.05, 0.15, 0.18, 0.272, 0.28, 0.35)),
    ('avoid', (0.05, 0.12)),
    ('trap', (0.05, 0.11, 0.2, 0.245)),
])
def test_task_variable_hessian_matches_finite_difference(name, radii):
    task = shaped_potential(TRAP, V_MAX, APPROACH, MARGIN) if name == 'trap' else shaped(name)
    rng = np.random.default_rng(2)
    h = 1e-7
    for r in radii:
        dx = r * direction(rng.uniform(-math.pi, math.pi))
        hessian = task_variable(dx, task).hessian
        numeric = np.column_stack([
            (task_variable(dx + h * unit, task).gradient
             - task_variable(dx - h * unit, task).gradient) / (2 * h) for unit in np.eye(2)])
        scale = max(1.0, float(np.max(np.abs(hessian))))
        assert np.max(np.abs(hessian - numeric)) <= 1e-5 * scale


@pytest.mark.parametrize('name', [*sorted(TABLE_I), 'trap'])
def test_task_potential_integrates_the_radial_slope(name):
    task = shaped_potential(TRAP, V_MAX, APPROACH, MARGIN) if name == 'trap' else shaped(name)
    h = 1e-6
    for r in (0.02, 0.1, 0.17, 0.2, 0.28, 0.4, 0.7):
        numeric = (task_potential(r + h, task) - task_potential(r - h, task)) / (2 * h)
        slope = task_variable(np.array([r, 0.0]), task).radial_slope
        assert numeric == pytest.approx(slope, rel=1e-4, abs=1e-6)
        assert task_potential(r, task) >= 0.0


def test_task_potential_is_k_p_below_saturation():
    shape = TABLE_I['follow_safe']
    # k |dP/dr| / v_max <= 1e-4 here, so tanh is linear to 1e-8.
    task = shaped_potential(shape, V_MAX, APPROACH, region_margin=0.0, task_gain=1e-5)
    for r in (0.05, 0.1, 0.3, 0.5):
        assert task_potential(r, task) == pytest.approx(1e-5 * float(potential(r, shape)),
                                                        rel=1e-7)


def test_radial_slope_of_avoidance_is_capped_not_infinite():
    slope = radial_potential_slope(np.array([0.0, 0.05, 0.18, 0.19]), TABLE_I['avoid'])
    assert np.all(np.isfinite(slope))
    assert slope[1] < 0.0 and slope[3] == 0.0


def test_bad_shaping_arguments_are_rejected():
    shape = TABLE_I['follow']
    with pytest.raises(ValueError, match='max_task_speed'):
        shaped_potential(shape, 0.0, APPROACH)
    with pytest.raises(ValueError, match='approach_distance'):
        shaped_potential(shape, V_MAX, -1.0)
    with pytest.raises(ValueError, match='region_margin'):
        shaped_potential(shape, V_MAX, APPROACH, region_margin=-0.1)
    with pytest.raises(ValueError, match='task_gain'):
        shaped_potential(shape, V_MAX, APPROACH, task_gain=float('inf'))
    with pytest.raises(ValueError, match='threshold'):
        DampingSettings(threshold=0.0)
    with pytest.raises(ValueError, match='dx'):
        task_variable(np.array([np.nan, 0.0]), shaped('follow'))


def trajectory(t, q_mid):
    """Smooth joint motion, target motion and weight with exact derivatives."""
    amplitude, omega = np.array([0.3, 0.2]), np.array([1.1, 1.7])
    q = np.asarray(q_mid) + amplitude * np.sin(omega * t)
    dq = amplitude * omega * np.cos(omega * t)
    centre, radius, w = np.array([0.35, 0.25]), 0.05, 0.9
    x_d = centre + radius * direction(w * t)
    xdot_d = radius * w * np.array([-math.sin(w * t), math.cos(w * t)])
    xddot_d = -radius * w * w * direction(w * t)
    weight = 0.5 + 0.45 * math.sin(2.0 * t)
    weight_rate = 0.9 * math.cos(2.0 * t)
    return q, dq, x_d, xdot_d, xddot_d, weight, weight_rate


@pytest.mark.parametrize('name', sorted(TABLE_I))
@pytest.mark.parametrize('q_mid', [(0.3, 1.6), (-0.2, 0.9), (0.8, 0.45)])
def test_qddot_r_matches_finite_difference_of_qdot_r(name, q_mid):
    task = shaped(name)

    def reference(t):
        return joint_velocity_reference(*trajectory(t, q_mid), task, L1, L2, DAMPING)

    h = 1e-6
    checked = 0
    for t in np.linspace(0.0, 4.0, 41):
        ref = reference(t)
        if name == 'avoid' and abs(ref.distance - task.region()[0]) < 1e-3:
            continue  # the avoidance wall: dQ/dr steps within 1e-13 m
        numeric = (reference(t + h).qdot_r - reference(t - h).qdot_r) / (2 * h)
        scale = max(1.0, float(np.max(np.abs(ref.qddot_r))))
        assert np.max(np.abs(ref.qddot_r - numeric)) <= 1e-5 * scale
        checked += 1
    assert checked >= 30


def test_reference_without_a_task_only_follows_the_target():
    q, dq, x_d, xdot_d, xddot_d, weight, rate = trajectory(0.7, (0.3, 1.6))
    ref = joint_velocity_reference(q, dq, x_d, xdot_d, xddot_d, weight, rate, None, L1, L2,
                                   DAMPING)
    np.testing.assert_allclose(ref.qdot_r, np.linalg.solve(jacobian(q, L1, L2), xdot_d))
    assert ref.task is None and np.all(ref.weighted_task_variable == 0.0)


def test_reference_rejects_bad_input():
    args = list(trajectory(0.0, (0.3, 1.6)))
    task = shaped('follow')
    args[5] = 1.5
    with pytest.raises(ValueError, match='weight'):
        joint_velocity_reference(*args, task, L1, L2, DAMPING)
    args[5] = 0.5
    args[0] = np.array([np.inf, 0.0])
    with pytest.raises(ValueError, match='q must be 2 finite values'):
        joint_velocity_reference(*args, task, L1, L2, DAMPING)


def test_shaped_potential_is_hashable_per_task():
    assert isinstance(shaped('follow'), ShapedPotential)
    assert hash(shaped('follow')) == hash(shaped('follow'))
