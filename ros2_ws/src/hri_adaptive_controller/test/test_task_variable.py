"""Unit tests of hri_adaptive_controller.task_variable: eq. 12', 14 and the exact qddot_r.

The joint-velocity reference (eq. 14) and its exact derivative (eq. 18) are arm_law's for
every arm; they are checked here on the SCARA (hri_core.robot_model.ScaraModel, task axes x,
y), through the law's numpy reference (ArmController(..., compiled=False).command)."""

import copy
import math

import numpy as np
import pytest

from hri_adaptive_controller.arm_law import (
    SCARA_GAINS,
    ActiveTask,
    ArmController,
    HandState,
    task_term,
    task_term_along,
)
from hri_adaptive_controller.task_variable import (
    ANCHOR_SPACING,
    CAP_BAND,
    DampingSettings,
    PotentialAlongPath,
    TaskDrive,
    _approach_floor,
    _approach_floor_values,
    damped_pseudo_inverse,
    norm_cap,
    radial_drive,
    radial_potential_slope,
    rest_term,
    speed_cap,
    task_drive,
    task_potential,
)
from hri_core.potential import TaskShape, default_task_gain, log_potential_slope, potential
from hri_core.robot_model import ScaraModel

SCARA = ScaraModel()
L1, L2 = SCARA.link_lengths
TABLE_I = {
    'follow': TaskShape(1, 1.291, 13.66, 0.0, 0.041),
    'avoid': TaskShape(1, 0.056, 25.46, 0.183, 2.0),
    'follow_safe': TaskShape(1, 1.576, 30.78, 0.183, 0.271),
}
TRAP = TaskShape(-1, 4.0, 12.0, 0.1, 0.25)  # S = -1: desired region r <= d1 or r >= d2
V_MAX, APPROACH_SPEED, MARGIN, REST_GAIN, REACH = 0.25, 0.1, 0.02, 2.0, L1 + L2
DAMPING = SCARA_GAINS.damping
THRESHOLD2, MAX_DAMPING2 = DAMPING.threshold ** 2, DAMPING.max_damping ** 2
# Table I's rows (no K: the default gain), follow with a1, a2 x 4, and the rows the demo
# learned (README's Table I), with their K.
SHAPES = {
    **{name: (shape, 0.0) for name, shape in TABLE_I.items()},
    'follow_x4': (TaskShape(1, 4 * 1.291, 4 * 13.66, 0.0, 0.041), 0.0),
    'learned_follow': (TaskShape(1, 6.028, 1000.0, 0.0, 0.055), 0.1381),
    'learned_avoid': (TaskShape(1, 44.49, 0.001, 0.165, 2.0), 1.502e4),
    'learned_follow_safe': (TaskShape(1, 3.537, 20.1, 0.165, 0.285), 0.08706),
    'trap': (TRAP, 0.0),
}


def drive(name):
    shape, k = SHAPES[name]
    return task_drive(shape, k, V_MAX, REACH, APPROACH_SPEED, MARGIN, REST_GAIN, 0.03)


def direction(angle):
    return np.array([math.cos(angle), math.sin(angle)])


def random_direction(rng, axes):
    """A unit vector (axes,): in the plane by its angle, in 3-D from a normal sample."""
    if axes == 2:
        return direction(rng.uniform(-math.pi, math.pi))
    vector = rng.normal(size=axes)
    return vector / np.linalg.norm(vector)


def radial_slope(dx, task):
    """dQ/dr (m/s) at dx (k,) m: delta_eps along e = dx / |dx| (task_term)."""
    dx = np.asarray(dx, dtype=float)
    return float(task_term(dx, task)[0] @ dx) / float(np.linalg.norm(dx))


def jacobians(q, dq=(0.0, 0.0)):
    """The SCARA's J (2, 2) and dJ/dt at q, dq (the law's task_kinematics)."""
    _, jac, rate = SCARA.task_kinematics(np.asarray(q, dtype=float),
                                         np.asarray(dq, dtype=float))
    return jac, rate


def pseudo_inverse(q, dq=(0.0, 0.0)):
    """(J+, dJ+/dt, lambda^2) of the SCARA at q, dq with its gains' damping."""
    return damped_pseudo_inverse(*jacobians(q, dq), THRESHOLD2, MAX_DAMPING2)


def test_pseudo_inverse_is_the_inverse_away_from_singularities():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = np.array([rng.uniform(-3, 3), rng.uniform(0.6, 2.4) * rng.choice([-1, 1])])
        jac, _ = jacobians(q)
        pinv, _, lam2 = pseudo_inverse(q)
        assert lam2 == 0.0
        np.testing.assert_allclose(pinv, np.linalg.inv(jac), rtol=1e-10, atol=1e-10)


def test_damping_grows_smoothly_towards_the_singularity():
    q2 = np.linspace(0.0, 1.0, 20001)
    lam2 = np.array([pseudo_inverse((0.3, x))[2] for x in q2])
    # w = l1 l2 |sin q2| < w0 = 0.05 m^2 below q2 = asin(0.05 / 0.105).
    start = math.asin(0.05 / (L1 * L2))
    assert np.all(lam2[q2 > start + 1e-6] == 0.0)
    assert np.all(np.diff(lam2[q2 < start]) < 0.0)
    assert lam2[0] == pytest.approx(DAMPING.max_damping ** 2)
    slope = np.diff(lam2) / np.diff(q2)
    assert np.max(np.abs(np.diff(slope))) < 1e-3  # C1: no kink at the threshold


def test_pseudo_inverse_at_the_singularity_is_finite_and_bounded():
    for q2 in (0.0, 1e-9, -1e-4):
        jac, _ = jacobians((0.4, q2))
        pinv, pinv_rate, _ = pseudo_inverse((0.4, q2), (0.3, -0.2))
        assert np.all(np.isfinite(pinv)) and np.all(np.isfinite(pinv_rate))
        # sigma / (sigma^2 + lambda^2) <= 1 / (2 lambda) in the singular direction.
        assert np.linalg.norm(pinv, 2) <= max(1.0 / (2 * DAMPING.max_damping),
                                              1.0 / np.linalg.svd(jac)[1][0]) + 1e-9
    # Without damping the stretched arm (J J^T exactly singular at q = 0) has no
    # pseudo-inverse: refused, not inf.
    jac, rate = jacobians((0.0, 0.0))
    with pytest.raises(ValueError, match='singular Jacobian and no damping'):
        damped_pseudo_inverse(jac, rate, THRESHOLD2, 0.0)


@pytest.mark.parametrize('q_mid', [(0.2, 1.2), (0.5, 0.52), (1.0, 0.3), (-0.7, -0.05)])
def test_pseudo_inverse_derivative_matches_finite_difference(q_mid):
    amplitude, omega = np.array([0.4, 0.15]), np.array([1.3, 2.1])

    def q_of(t):
        return np.asarray(q_mid) + amplitude * np.sin(omega * t)

    def dq_of(t):
        return amplitude * omega * np.cos(omega * t)

    h = 1e-6
    for t in np.linspace(0.0, 3.0, 13):
        _, analytic, _ = pseudo_inverse(q_of(t), dq_of(t))
        numeric = (pseudo_inverse(q_of(t + h))[0] - pseudo_inverse(q_of(t - h))[0]) / (2 * h)
        scale = max(1.0, float(np.max(np.abs(analytic))))
        assert np.max(np.abs(analytic - numeric)) <= 1e-6 * scale


@pytest.mark.parametrize('axes', [2, 3])
@pytest.mark.parametrize('name', sorted(TABLE_I))
def test_task_variable_points_to_the_region_and_is_bounded(name, axes):
    task = drive(name)
    d1, d2 = task.region()
    rng = np.random.default_rng(1)
    for r in np.concatenate([rng.uniform(0.001, 0.9, 200), [0.5 * (d1 + d2)]]):
        e = random_direction(rng, axes)
        gradient, _ = task_term(r * e, task)
        norm = np.linalg.norm(gradient)
        assert norm <= (1.0 + CAP_BAND) * V_MAX * (1 + 1e-12)
        if d1 <= r <= d2:
            assert norm == 0.0
        elif r > d2 and name != 'avoid':  # moving along -gradient brings the arm closer
            assert gradient @ e > 0.0
        elif r < d1:  # too close: -gradient pushes it away
            assert gradient @ e < 0.0


@pytest.mark.parametrize('name', [*sorted(TABLE_I), 'follow_x4', 'learned_follow',
                                  'learned_avoid'])
def test_below_the_cap_the_task_speed_is_k_times_the_gradient(name):
    shape, k = SHAPES[name]
    task = task_drive(shape, k, V_MAX, REACH)  # no approach term
    log_k = math.log(k) if k > 0.0 else default_task_gain(shape, V_MAX, REACH)
    assert task.log_gain == log_k
    checked = 0
    for r in np.linspace(0.001, 0.9, 400):
        pull = math.exp(log_k + float(log_potential_slope(r, shape)))
        speed = abs(radial_slope([0.0, r], task))
        if pull <= V_MAX:
            assert speed == pytest.approx(pull, rel=1e-12, abs=1e-300)
            checked += pull > 1e-4
        else:  # above the cap: bent smoothly, never above (1 + CAP_BAND) v_max
            assert V_MAX < speed < pull and speed <= (1.0 + CAP_BAND) * V_MAX * (1 + 1e-12)
    assert checked >= 20
    # With the default approach term, only where the pull is below approach_speed.
    floored = task_drive(shape, k, V_MAX, REACH, APPROACH_SPEED, MARGIN)
    for r in np.linspace(0.001, 0.9, 400):
        pull = math.exp(log_k + float(log_potential_slope(r, shape)))
        if APPROACH_SPEED <= pull <= V_MAX:
            speed = abs(radial_slope([r, 0.0], floored))
            assert speed == pytest.approx(pull, rel=1e-12)


def test_speed_cap_is_smooth_at_its_knee():
    below, slope_below = speed_cap(V_MAX * (1 - 1e-9), V_MAX)
    above, slope_above = speed_cap(V_MAX * (1 + 1e-9), V_MAX)
    assert below == pytest.approx(above, rel=1e-8)
    assert slope_below == 1.0 and slope_above == pytest.approx(1.0, abs=1e-12)
    assert speed_cap(-1e300, V_MAX)[0] == pytest.approx(-(1.0 + CAP_BAND) * V_MAX)
    assert speed_cap(1e300, V_MAX)[1] == 0.0


def test_norm_cap_scales_the_vector_to_speed_caps_norm_with_its_rate():
    rng = np.random.default_rng(7)
    assert norm_cap(np.array([0.1, -0.1, 0.05]), V_MAX) == (1.0, 0.0)
    for _ in range(20):
        v, dv = rng.normal(size=3), rng.normal(size=3)
        scale, gain = norm_cap(v, V_MAX)
        assert scale * np.linalg.norm(v) == pytest.approx(
            speed_cap(float(np.linalg.norm(v)), V_MAX)[0], rel=1e-12)
        h = 1e-6
        numeric = (norm_cap(v + h * dv, V_MAX)[0] - norm_cap(v - h * dv, V_MAX)[0]) / (2 * h)
        assert gain * float(v @ dv) == pytest.approx(numeric, rel=1e-5, abs=1e-9)


def test_table_i_avoid_row_is_finite_and_smooth_despite_p0_of_1e124():
    task = drive('avoid')
    assert task.task_gain < 1e-120  # K = exp(-290) m^2/s: P ~ 1e124, K |dP/dr| ~ 0.3 m/s
    radii = np.linspace(0.0, 0.3, 3001)
    slopes = np.array([radial_drive(float(r), task) for r in radii])
    assert np.all(np.isfinite(slopes))
    assert np.max(np.abs(slopes[:, 0])) <= (1.0 + CAP_BAND) * V_MAX * (1 + 1e-12)
    # No jump anywhere: between samples 0.1 mm apart Q' changes by at most |Q''| 0.1 mm.
    assert np.max(np.abs(np.diff(slopes[:, 0]))) <= 1e-4 * np.max(np.abs(slopes[:, 1])) + 1e-12
    # 1/s: no wall anywhere, the approach term's fade at d1 included (its steepest slope is
    # 15/8 approach_speed / margin = 9.4 1/s).
    assert np.max(np.abs(slopes[:, 1])) < 20.0


def test_approach_term_enters_the_region_and_stops_inside_it():
    task = drive('follow_safe')
    d1, d2 = task.region()
    assert (d1, d2) == pytest.approx((0.183 + MARGIN, 0.271 - MARGIN))
    # At the learned boundaries the arm still moves in at about approach_speed.
    for r in (0.183, 0.271):
        assert abs(radial_slope([0.0, r], task)) == pytest.approx(
            APPROACH_SPEED, rel=0.01)
    for r, moving in ((d1 - 1e-4, True), (d1 + 1e-4, False), (d2 - 1e-4, False),
                      (d2 + 1e-4, True)):
        assert (radial_slope([0.0, r], task) != 0.0) == moving
    # The avoid row's region is open outward: no approach from outside, no floor at 2 m.
    avoid = drive('avoid')
    assert avoid.open_outward and avoid.region()[1] == 2.0
    assert not drive('follow').open_outward
    # S = -1 tasks get no approach term.
    assert task_drive(TRAP, 0.0, V_MAX, REACH, APPROACH_SPEED, MARGIN).approach_speed == 0.0


@pytest.mark.parametrize(('name', 'radii'), [
    ('follow', (0.03, 0.0415, 0.045, 0.06, 0.1, 0.3)),
    ('follow_safe', (0.05, 0.15, 0.18, 0.186, 0.27, 0.272, 0.28, 0.35)),
    ('avoid', (0.005, 0.05, 0.12, 0.185)),
    ('trap', (0.05, 0.11, 0.2, 0.245)),
])
@pytest.mark.parametrize('axes', [2, 3])
def test_task_variable_hessian_matches_finite_difference(name, radii, axes):
    task = drive(name)
    rng = np.random.default_rng(2)
    h = 1e-7
    for r in radii:
        dx = r * random_direction(rng, axes)
        gradient, hessian = task_term(dx, task)
        numeric = np.column_stack([
            (task_term(dx + h * unit, task)[0] - task_term(dx - h * unit, task)[0]) / (2 * h)
            for unit in np.eye(axes)])
        scale = max(1.0, float(np.max(np.abs(hessian))))
        assert np.max(np.abs(hessian - numeric)) <= 1e-5 * scale
        # The control step's path (H_Q u without the matrix) is the same.
        u = rng.normal(size=axes)
        along, hessian_u = task_term_along(dx, u, task)
        np.testing.assert_allclose(along, gradient, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(hessian_u, hessian @ u, rtol=1e-9,
                                   atol=1e-12 * scale * np.linalg.norm(u))


@pytest.mark.parametrize('name', [*sorted(TABLE_I), 'trap'])
def test_task_potential_integrates_the_radial_slope(name):
    task = drive(name)
    h = 1e-6
    for r in (0.02, 0.1, 0.17, 0.2, 0.28, 0.4, 0.7):
        numeric = (task_potential(r + h, task) - task_potential(r - h, task)) / (2 * h)
        slope = radial_slope([r, 0.0], task)
        # Monitoring accuracy: the cap's knee and the approach blends are C2 only, which the
        # fixed Gauss-Legendre panels resolve to a few per cent.
        assert numeric == pytest.approx(slope, rel=3e-2, abs=1e-4)
        assert task_potential(r, task) >= 0.0


def fine_potential(task, r, panel=2e-4):
    """Q at r by a 5-node Gauss-Legendre rule on `panel`-wide panels from the breakpoint."""
    d1, d2 = task.region()
    nodes, weights = np.polynomial.legendre.leggauss(5)

    def integral(start, end):
        edges = np.linspace(start, end, max(1, math.ceil(abs(end - start) / panel)) + 1)
        half, centre = 0.5 * np.diff(edges), 0.5 * (edges[1:] + edges[:-1])
        rule = tuple(zip(nodes, weights, strict=True))
        return sum(h * sum(w * radial_drive(c + h * x, task)[0] for x, w in rule)
                   for h, c in zip(half, centre, strict=True))

    if task.shape.s == 1:
        return 0.0 if d1 <= r <= d2 else abs(integral(d2 if r > d2 else d1, r))
    return 0.0 if r <= d1 else integral(d1, min(r, d2))


def walked(task, distances):
    """A PotentialAlongPath that has seen `distances` in turn, as a controller's V does."""
    along = PotentialAlongPath(task)
    for r in distances:
        along(float(r))
    return along


@pytest.mark.parametrize('name', ['follow', 'avoid', 'learned_follow', 'learned_avoid'])
def test_potential_along_a_path_equals_a_fine_rule(name):
    task = drive(name)
    along = walked(task, np.linspace(0.0, 0.6, 1201))
    rng = np.random.default_rng(5)
    for r in rng.uniform(0.0, 0.6, 4):
        assert along(r) == pytest.approx(fine_potential(task, r), rel=1e-9, abs=1e-12)


@pytest.mark.parametrize('name', sorted(SHAPES))
def test_potential_along_a_path_agrees_with_task_potential(name):
    """Within task_potential's own accuracy (its panels span the whole interval)."""
    task = drive(name)
    distances = np.concatenate([np.linspace(0.0, 0.8, 1601), np.linspace(0.8, 0.0, 1601)])
    along = walked(task, distances)
    values = np.array([along(r) for r in distances[::40]])
    expected = np.array([task_potential(r, task) for r in distances[::40]])
    assert np.all(values >= 0.0) or name == 'trap'
    assert np.max(np.abs(values - expected)) <= 1e-3 * max(np.max(np.abs(expected)), 1e-9)


@pytest.mark.parametrize('name', [*sorted(TABLE_I), 'trap'])
def test_potential_along_a_path_integrates_the_radial_slope(name):
    task = drive(name)
    along = walked(task, np.linspace(0.0, 0.75, 1501))
    h = 1e-6
    for r in (0.02, 0.1, 0.17, 0.2, 0.28, 0.4, 0.7):
        numeric = (along(r + h) - along(r - h)) / (2 * h)
        slope = radial_drive(r, task)[0]
        if task.region()[0] <= r <= task.region()[1] and task.shape.s == 1:
            slope = 0.0  # Q is 0 on its zero set, whatever the approach term there
        assert numeric == pytest.approx(slope, rel=1e-5, abs=1e-7)


def test_potential_along_a_path_on_both_sides_of_a_one_point_region():
    """d1' = d2' (d1 = d2: a region of one radius): the two sides keep anchors of their own."""
    task = task_drive(TaskShape(1, 5.0, 20.0, 0.12, 0.12), 0.0, V_MAX, REACH, APPROACH_SPEED,
                      MARGIN, REST_GAIN, 0.03)
    assert task.region() == (0.12, 0.12)
    distances = np.concatenate([np.linspace(0.3, 0.0, 601), np.linspace(0.0, 0.3, 601)])
    along = walked(task, distances)
    for r in (0.02, 0.08, 0.115, 0.125, 0.2, 0.28):
        assert along(r) == pytest.approx(fine_potential(task, r), rel=1e-9, abs=1e-12)


def test_potential_along_a_path_far_from_its_anchors_is_task_potentials():
    """A distance its anchors do not reach yet (a task just started): task_potential's
    value; the anchors grow towards it, a few per call, until they reach it."""
    task = drive('follow')
    along = PotentialAlongPath(task)
    assert along(0.5) == task_potential(0.5, task)
    for _ in range(int(0.5 / ANCHOR_SPACING)):
        along(0.5)
    assert along(0.5) == pytest.approx(fine_potential(task, 0.5), rel=1e-9)


def test_task_potential_is_k_p_below_the_cap():
    shape = TABLE_I['follow_safe']
    task = task_drive(shape, 1e-5, V_MAX, REACH)  # K |dP/dr| << v_max here
    for r in (0.05, 0.1, 0.3, 0.5):
        assert task_potential(r, task) == pytest.approx(1e-5 * float(potential(r, shape)),
                                                        rel=1e-7)


def test_radial_slope_of_avoidance_is_capped_not_infinite():
    slope = radial_potential_slope(np.array([0.0, 0.05, 0.18, 0.19]), TABLE_I['avoid'])
    assert np.all(np.isfinite(slope))
    assert slope[1] < 0.0 and slope[3] == 0.0


def test_rest_term_returns_to_rest_outside_the_edge_only():
    task = drive('avoid')
    start = task.rest_gate_start()
    assert start == pytest.approx(0.183 + MARGIN)
    still = [0.0, 0.0]
    # Inside the gate's start: no return at all.
    assert rest_term([start - 0.01, 0.0], [0.1, 0.0], still, still, task) is None
    # c(y) = -k_rest y below the cap, weighted by the gate: 1/2 halfway, 1 beyond it.
    for r, gate in ((start + 0.5 * task.rest_gate, 0.5), (start + task.rest_gate + 0.01, 1.0),
                    (0.5, 1.0)):
        velocity, rate = rest_term([r, 0.0], [0.1, 0.0], still, still, task)
        assert velocity == pytest.approx([gate * -REST_GAIN * 0.1, 0.0])
        assert rate == pytest.approx([0.0, 0.0])  # a still arm and hand: no change
    # The same on three task axes.
    velocity, _ = rest_term([0.0, 0.0, 0.5], [0.0, 0.1, 0.0], [0.0] * 3, [0.0] * 3, task)
    assert velocity == pytest.approx([0.0, -REST_GAIN * 0.1, 0.0])
    assert rest_term([0.5, 0.0], [0.1, 0.0], still, still, drive('follow')) is None


def test_bad_task_arguments_are_rejected():
    shape = TABLE_I['follow']
    with pytest.raises(ValueError, match='max_task_speed'):
        task_drive(shape, 0.0, 0.0, REACH)
    with pytest.raises(ValueError, match='approach_speed'):
        task_drive(shape, 0.0, V_MAX, REACH, approach_speed=-1.0)
    with pytest.raises(ValueError, match='region_margin'):
        task_drive(shape, 0.0, V_MAX, REACH, region_margin=-0.1)
    with pytest.raises(ValueError, match='k must be'):
        task_drive(shape, float('inf'), V_MAX, REACH)
    with pytest.raises(ValueError, match='threshold'):
        DampingSettings(threshold=0.0)


HAND_LINE = np.array([-0.03, 0.035])  # m/s: a straight hand's velocity


def trajectory(t, q_mid, straight=False):
    """Smooth joint motion, target motion and weight with exact derivatives: the hand
    circles (0.05 m, 0.9 rad/s) or, straight, passes the circle's centre at t = 1.5 s at a
    constant HAND_LINE."""
    amplitude, omega = np.array([0.3, 0.2]), np.array([1.1, 1.7])
    q = np.asarray(q_mid) + amplitude * np.sin(omega * t)
    dq = amplitude * omega * np.cos(omega * t)
    centre, radius, w = np.array([0.35, 0.25]), 0.05, 0.9
    if straight:
        x_d, xdot_d, xddot_d = centre + (t - 1.5) * HAND_LINE, HAND_LINE.copy(), np.zeros(2)
    else:
        x_d = centre + radius * direction(w * t)
        xdot_d = radius * w * np.array([-math.sin(w * t), math.cos(w * t)])
        xddot_d = -radius * w * w * direction(w * t)
    weight = 0.5 + 0.45 * math.sin(2.0 * t)
    weight_rate = 0.9 * math.cos(2.0 * t)
    return q, dq, x_d, xdot_d, xddot_d, weight, weight_rate


def command(law, t, q_mid, shape, k, dt, rest=None, straight=False):
    """The law's command (its numpy reference: no adaptation) at time t of `trajectory`, the
    task's weight and rate from it; shape None: no task."""
    q, dq, x_d, xdot_d, xddot_d, weight, weight_rate = trajectory(t, q_mid, straight)
    task = None if shape is None else ActiveTask(shape, weight, weight_rate, k)
    return law.command(q, dq, HandState(x_d, xdot_d, xddot_d), task, dt, rest)


@pytest.mark.parametrize('name', [*sorted(TABLE_I), 'trap'])
@pytest.mark.parametrize('q_mid', [(0.3, 1.6), (-0.2, 0.9), (0.8, 0.45)])
def test_qddot_r_matches_finite_difference_of_qdot_r(name, q_mid):
    """The law's qddot_r is the time derivative of its qdot_r along a trajectory of the arm,
    the hand and a(t). The law has state (an avoid task reads the hand's velocity through a
    filter; the reach-round blend): it walks the trajectory at 1 ms from t = -1 s (the
    filter settled), and at each check a copy takes two steps of h on, so that qdot_r at t,
    t + h, t + 2h are the law's own along one path (qddot_r checked at t + h).

    An avoid task's hand moves straight at a constant speed: the filter's estimate is then
    the hand's velocity. (Where the hand turns, the estimate lags it and the law's qddot_r,
    which takes the estimate for dx's rate, differs from d qdot_r/dt by H_Q times the lag,
    as the former adaptive_law's step did: 1.4e-2 rad/s^2 here with a circling hand.)"""
    shape, k = SHAPES[name]
    rest = np.array([0.3, 0.4])
    law = ArmController(SCARA, SCARA_GAINS, compiled=False)
    task = law.drive(shape, k)
    assert task == drive(name)  # the gains' task drive is this file's
    straight = task.open_outward
    h, dt = 1e-6, 1e-3
    checks = set(range(1000, 5001, 100))  # t = 0, 0.1, ..., 4 s
    checked = 0
    for step in range(5001):
        t = -1.0 + step * dt
        out = command(law, t, q_mid, shape, k, dt, rest, straight)
        assert not out.fault
        if step not in checks:
            continue
        ahead = copy.deepcopy(law)
        middle = command(ahead, t + h, q_mid, shape, k, h, rest, straight)
        last = command(ahead, t + 2 * h, q_mid, shape, k, h, rest, straight)
        numeric = (last.qdot_r - out.qdot_r) / (2 * h)
        scale = max(1.0, float(np.max(np.abs(middle.qddot_r))))
        assert np.max(np.abs(middle.qddot_r - numeric)) <= 1e-5 * scale, (t, middle, numeric)
        checked += 1
    assert checked >= 30


def test_reference_without_a_task_only_follows_the_target():
    law = ArmController(SCARA, SCARA_GAINS, compiled=False)
    q, dq, _, xdot_d, xddot_d, _, _ = trajectory(0.7, (0.3, 1.6))
    out = command(law, 0.7, (0.3, 1.6), None, 0.0, 1e-3)
    jac, jac_rate = jacobians(q, dq)
    inverse = np.linalg.inv(jac)
    np.testing.assert_allclose(out.qdot_r, inverse @ xdot_d)
    # d/dt (J^-1 xdot_d) = J^-1 (xddot_d - Jdot J^-1 xdot_d).
    np.testing.assert_allclose(out.qddot_r, inverse @ (xddot_d - jac_rate @ inverse @ xdot_d))
    assert out.task_gain == 0.0 and np.all(out.weighted_task_variable == 0.0)


@pytest.mark.parametrize('compiled', [False, True])
def test_a_non_finite_state_or_hand_gives_a_fault_not_a_reference(compiled):
    """The law's per-cycle inputs are unchecked (the caller checks them where they enter): a
    non-finite joint state or hand ends in a fault, zero torque and theta_hat unchanged."""
    law = ArmController(SCARA, SCARA_GAINS, compiled=compiled)
    theta = law.theta_hat
    q, dq, x_d, xdot_d, xddot_d, weight, rate = trajectory(0.0, (0.3, 1.6))
    task = ActiveTask(TABLE_I['follow'], weight, rate)
    for bad_q, bad_hand in ((np.array([np.inf, 0.0]), x_d), (q, np.array([np.nan, 0.0]))):
        out = law.step(bad_q, dq, HandState(bad_hand, xdot_d, xddot_d), task, 1e-3)
        assert out.fault and out.fault_reason
        assert np.all(out.tau == 0.0) and out.distance is None
        np.testing.assert_array_equal(law.theta_hat, theta)
    assert not law.step(q, dq, HandState(x_d, xdot_d, xddot_d), task, 1e-3).fault


def test_task_drive_is_hashable_per_task():
    assert isinstance(drive('follow'), TaskDrive)
    assert hash(drive('follow')) == hash(drive('follow'))


@pytest.mark.parametrize('name', sorted(SHAPES))
def test_the_monitors_approach_floor_equals_the_control_paths(name):
    task = drive(name)
    radii = np.concatenate([np.linspace(0.0, 0.5, 2001), [task.shape.d1, task.shape.d2]])
    np.testing.assert_array_equal(_approach_floor_values(radii, task),
                                  [_approach_floor(float(r), task)[0] for r in radii])
