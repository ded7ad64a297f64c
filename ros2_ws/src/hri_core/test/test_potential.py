"""Unit tests of hri_core.potential: eq. 1, 2, derivatives and overflow safety."""

import math
import time
from decimal import Decimal, localcontext

import numpy as np
import pytest

from hri_core.potential import (
    POTENTIAL_CEILING,
    TaskShape,
    log_potential,
    normalised_potential,
    potential,
    potential_gradient,
    potential_hessian,
    task_function,
)

TABLE_I = {
    'follow': TaskShape(1, 1.291, 13.66, 0.0, 0.041),
    'avoid': TaskShape(1, 0.056, 25.46, 0.183, 2.0),
    'follow_safe': TaskShape(1, 1.576, 30.78, 0.183, 0.271),
}
TRAP = TaskShape(-1, 4.0, 12.0, 0.1, 0.25)
# Shapes whose P stays well below the cap on |z| <= 0.6 m, for finite-difference checks.
MODERATE = {
    **{k: v for k, v in TABLE_I.items() if k != 'avoid'},
    'trap': TRAP,
    'avoid_small_d2': TaskShape(1, 3.0, 8.0, 0.183, 0.6),
    'n5': TaskShape(1, 3.0, 7.0, 0.1, 0.3, n=5),
}


def decimal_potential(distance, shape):
    """P of eq. 1, 2 in 60-digit decimal arithmetic: the reference value."""
    with localcontext() as context:
        context.prec = 60
        u = Decimal(distance) ** 2
        f1 = 1 - (-Decimal(shape.a1) * (u - Decimal(shape.d1) ** 2)).exp()
        f2 = 1 - (-Decimal(shape.a2) * (u - Decimal(shape.d2) ** 2)).exp()
        y = shape.s * f1 * f2
        return max(Decimal(0), y) ** shape.n


@pytest.mark.parametrize('name', sorted(TABLE_I))
def test_zero_set_is_the_desired_region(name):
    shape = TABLE_I[name]
    distance = np.linspace(0.0, 2.5, 5001)
    off_boundary = (np.abs(distance - shape.d1) > 1e-9) & (np.abs(distance - shape.d2) > 1e-9)
    distance = distance[off_boundary]
    inside = (distance >= shape.d1) & (distance <= shape.d2)
    p = potential(distance, shape)
    assert np.all(p[inside] == 0.0)
    assert np.all(np.isfinite(log_potential(distance[~inside], shape)))
    assert np.all(p[~inside] > 0.0)


def test_zero_set_is_the_complement_for_negative_s():
    distance = np.linspace(0.0, 1.0, 2001)
    inside = (distance > TRAP.d1) & (distance < TRAP.d2)
    p = potential(distance, TRAP)
    assert np.all(p[~inside] == 0.0)
    assert np.all(p[inside] > 0.0)


@pytest.mark.parametrize('name', sorted(TABLE_I))
def test_log_potential_matches_decimal_reference(name):
    shape = TABLE_I[name]
    for distance in (0.0, 0.02, 0.1, 0.15, 0.3, 0.5, 1.0, 1.9, 2.2):
        exact = decimal_potential(distance, shape)
        value = log_potential(distance, shape)
        if exact == 0:
            assert value == -math.inf
        else:
            assert value == pytest.approx(float(exact.ln()), rel=1e-12, abs=1e-12)


def test_avoidance_potential_at_origin_is_capped():
    exact = decimal_potential(0.0, TABLE_I['avoid'])
    assert Decimal('1e124') < exact < Decimal('1e125')   # the paper's "about 1e124"
    assert potential(0.0, TABLE_I['avoid']) == POTENTIAL_CEILING
    assert float(log_potential(0.0, TABLE_I['avoid'])) == pytest.approx(
        float(exact.ln()), rel=1e-12)


def test_task_function_matches_eq_1():
    shape = TABLE_I['follow_safe']
    distance = np.linspace(0.0, 1.0, 101)
    u = distance ** 2
    expected = shape.s * (1 - np.exp(-shape.a1 * (u - shape.d1 ** 2))) * (
        1 - np.exp(-shape.a2 * (u - shape.d2 ** 2)))
    np.testing.assert_allclose(task_function(distance, shape), expected, rtol=1e-12,
                               atol=1e-15)


def central_gradient(z, shape, h=1e-6):
    return np.array([(potential(np.hypot(*(z + h * e)), shape)
                      - potential(np.hypot(*(z - h * e)), shape)) / (2 * h)
                     for e in np.eye(2)])


@pytest.mark.parametrize('name', sorted(MODERATE))
def test_gradient_matches_finite_differences(name):
    shape = MODERATE[name]
    rng = np.random.default_rng(11)
    points = rng.uniform(-0.6, 0.6, (60, 2))
    gradients = potential_gradient(points, shape)
    scale = np.max(np.abs(gradients))
    assert scale > 0.0
    for z, gradient in zip(points, gradients, strict=True):
        np.testing.assert_allclose(gradient, central_gradient(z, shape), rtol=1e-5,
                                   atol=1e-7 * scale)


@pytest.mark.parametrize('name', sorted(MODERATE))
def test_hessian_matches_finite_differences(name):
    shape = MODERATE[name]
    rng = np.random.default_rng(12)
    points = rng.uniform(-0.6, 0.6, (60, 2))
    hessians = potential_hessian(points, shape)
    scale = np.max(np.abs(hessians))
    h = 1e-6
    for z, hessian in zip(points, hessians, strict=True):
        numeric = np.stack([(potential_gradient(z + h * e, shape)
                             - potential_gradient(z - h * e, shape)) / (2 * h)
                            for e in np.eye(2)], axis=1)
        np.testing.assert_allclose(hessian, numeric, rtol=1e-5, atol=1e-7 * scale)
        np.testing.assert_allclose(hessian, hessian.T, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize('shape', [*TABLE_I.values(), TRAP, TaskShape(1, 1e3, 1e3, 0.183, 2.0)])
def test_single_point_and_array_paths_agree(shape):
    rng = np.random.default_rng(13)
    points = np.concatenate([rng.uniform(-2.0, 2.0, (40, 2)), np.zeros((1, 2))])
    gradients = potential_gradient(points, shape)
    hessians = potential_hessian(points, shape)
    for z, gradient, hessian in zip(points, gradients, hessians, strict=True):
        np.testing.assert_allclose(potential_gradient(z, shape), gradient, rtol=1e-12, atol=0)
        np.testing.assert_allclose(potential_hessian(z, shape), hessian, rtol=1e-12, atol=0)


def grid_with_origin_and_rim():
    axis = np.linspace(-2.0, 2.0, 81)
    square = np.stack(np.meshgrid(axis, axis), axis=-1).reshape(-1, 2)
    angles = np.linspace(0.0, 2.0 * np.pi, 37)
    rim = 2.0 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    tiny = np.array([[1e-300, 0.0], [0.0, 1e-160], [1e-8, -1e-8]])
    return np.concatenate([square, rim, tiny, np.zeros((1, 2))])


EXTREME_SHAPES = [
    *TABLE_I.values(), TRAP,
    TaskShape(1, 1e3, 1e3, 0.183, 2.0), TaskShape(1, 1e-3, 1e3, 0.0, 2.0),
    TaskShape(-1, 1e3, 1e-3, 0.0, 2.0), TaskShape(-1, 1e3, 1e3, 0.0, 0.0),
    TaskShape(1, 1e3, 1e3, 0.0, 0.0, n=9),
]


@pytest.mark.parametrize('shape', EXTREME_SHAPES)
def test_nothing_overflows_on_the_workspace(shape):
    points = grid_with_origin_and_rim()
    distance = np.hypot(points[:, 0], points[:, 1])
    with np.errstate(over='raise', invalid='raise'):
        values = [task_function(distance, shape), potential(distance, shape),
                  potential_gradient(points, shape), potential_hessian(points, shape)]
    for value in values:
        assert np.all(np.isfinite(value))
        assert np.max(np.abs(value)) <= POTENTIAL_CEILING
    assert np.all(np.linalg.norm(values[2], axis=-1) <= POTENTIAL_CEILING * (1 + 1e-12))
    for z in np.concatenate([points[::97], points[-4:]]):
        assert np.all(np.isfinite(potential_gradient(z, shape)))
        assert np.all(np.isfinite(potential_hessian(z, shape)))


@pytest.mark.parametrize('shape', EXTREME_SHAPES)
def test_gradient_at_origin_is_zero_and_hessian_isotropic(shape):
    np.testing.assert_array_equal(potential_gradient(np.zeros(2), shape), np.zeros(2))
    hessian = potential_hessian(np.zeros(2), shape)
    assert np.all(np.isfinite(hessian))
    assert hessian[0, 1] == 0.0 and hessian[0, 0] == hessian[1, 1]


def test_capped_gradient_keeps_its_direction():
    # Inside the avoidance region P falls with |z|: the gradient points back toward x_r.
    z = np.array([0.03, 0.04])
    gradient = potential_gradient(z, TABLE_I['avoid'])
    assert np.linalg.norm(gradient) == pytest.approx(POTENTIAL_CEILING, rel=1e-12)
    np.testing.assert_allclose(gradient / np.linalg.norm(gradient), -z / np.linalg.norm(z),
                               rtol=1e-12)


def test_normalised_potential_is_exact_beyond_the_cap():
    distance = np.array([0.0, 0.1, 0.18, 0.3])
    shape = TABLE_I['avoid']
    exact = [decimal_potential(d, shape) for d in distance]
    norm = sum(value ** 2 for value in exact).sqrt()
    expected = [float(value / norm) for value in exact]
    np.testing.assert_allclose(normalised_potential(distance, shape), expected, rtol=1e-10)
    assert np.all(normalised_potential(np.array([0.01, 0.03]), TABLE_I['follow']) == 0.0)


@pytest.mark.parametrize(('kwargs', 'reason'), [
    ({'s': 0}, 's must be'),
    ({'s': True}, 's must be an integer'),
    ({'a1': 0.0}, 'a1 and a2 must be > 0'),
    ({'a2': -1.0}, 'a1 and a2 must be > 0'),
    ({'a1': math.nan}, 'a1 must be finite'),
    ({'d1': -0.1}, 'd1 and d2 must be >= 0'),
    ({'d1': 0.3, 'd2': 0.2}, 'd1 must be <= d2'),
    ({'d2': math.inf}, 'd2 must be finite'),
    ({'n': 2}, 'n must be >= 3'),
    ({'n': 3.0}, 'n must be an integer'),
])
def test_task_shape_rejects_invalid_parameters(kwargs, reason):
    values = {'s': 1, 'a1': 1.0, 'a2': 2.0, 'd1': 0.1, 'd2': 0.2, 'n': 3, **kwargs}
    with pytest.raises(ValueError, match=reason):
        TaskShape(**values)


def test_task_shape_accepts_numpy_scalars():
    shape = TaskShape(np.int64(-1), np.float64(1.0), np.float32(2.0), 0, 1, np.int8(4))
    assert (type(shape.s), type(shape.a2), type(shape.d1), type(shape.n)) == (
        int, float, float, int)


def test_bad_inputs_are_rejected():
    shape = TABLE_I['follow']
    with pytest.raises(ValueError, match='distance must be >= 0'):
        potential(np.array([0.1, -0.1]), shape)
    with pytest.raises(ValueError, match='distance must be finite'):
        log_potential(np.array([np.nan]), shape)
    with pytest.raises(ValueError, match=r'dx must have shape \(\.\.\., 2\)'):
        potential_gradient(np.zeros((4, 3)), shape)
    with pytest.raises(ValueError, match='dx must be finite'):
        potential_hessian(np.array([np.inf, 0.0]), shape)
    with pytest.raises(ValueError, match='dx must be finite'):
        potential_gradient(np.array([[np.nan, 0.0]]), shape)


def test_leading_dimensions_are_kept():
    shape = TABLE_I['follow_safe']
    points = np.random.default_rng(14).uniform(-0.5, 0.5, (3, 4, 2))
    assert potential_gradient(points, shape).shape == (3, 4, 2)
    assert potential_hessian(points, shape).shape == (3, 4, 2, 2)
    assert potential(np.hypot(points[..., 0], points[..., 1]), shape).shape == (3, 4)


def test_single_point_path_is_cheap():
    # The controller evaluates gradient and Hessian once per 1 kHz tick.
    shape = TABLE_I['avoid']
    z = np.array([0.1, 0.05])
    samples = []
    for _ in range(2000):
        start = time.perf_counter()
        potential_gradient(z, shape)
        potential_hessian(z, shape)
        samples.append(time.perf_counter() - start)
    assert np.median(samples) < 100e-6


# -- reach (hri_core.potential.reach_shortfall) --------------------------------------------

from hri_core.potential import (  # noqa: E402
    default_task_gain,
    log_potential_slope,
    reach_shortfall,
    signed_log_potential_slope,
)

REACH = 0.65  # m, l1 + l2 of the sim's arm
V_MAX = 0.25  # m/s, the controller's max_task_speed


@pytest.mark.parametrize('name', sorted(TABLE_I))
def test_table_one_rows_reach_with_the_default_gain(name):
    assert reach_shortfall(TABLE_I[name], 0.0, V_MAX, REACH) is None


@pytest.mark.parametrize(('a1', 'a2', 'd2'), [(1000.0, 237.8, 0.033), (329.7, 1000.0, 0.041)])
@pytest.mark.parametrize('k', [0.0, 0.01, 1.0, 1e4])
def test_deaf_follow_rows_do_not_reach_with_any_gain(a1, a2, d2, k):
    reason = reach_shortfall(TaskShape(1, a1, a2, 0.0, d2), k, V_MAX, REACH)
    assert reason is not None and 'the arm would not move there' in reason


def test_the_reach_verdict_does_not_depend_on_a_slow_gain():
    # The demo's follow row (a1 capped by the workspace): a demonstration 10 times slower
    # gives a 10 times smaller K and the same verdict.
    shape = TaskShape(1, 6.27, 1000.0, 0.0, 0.041)
    assert reach_shortfall(shape, 0.1, V_MAX, REACH) is None
    assert reach_shortfall(shape, 0.01, V_MAX, REACH) is None


def test_a_region_open_to_the_workspace_has_nothing_to_check():
    assert reach_shortfall(TaskShape(1, 33.0, 1e-3, 0.183, 2.0), 1e-9, V_MAX, REACH) is None


def test_log_slope_is_exact_where_the_gradient_is_capped():
    avoid = TABLE_I['avoid']
    log_slope = log_potential_slope(np.array([0.05, 0.1]), avoid)
    assert np.all(log_slope > math.log(POTENTIAL_CEILING))
    moderate = TABLE_I['follow']
    r = np.array([0.1, 0.3, 0.5])
    gradient = np.abs(potential_gradient(np.stack([r, 0 * r], axis=1), moderate)[:, 0])
    np.testing.assert_allclose(np.exp(log_potential_slope(r, moderate)), gradient, rtol=1e-9)


@pytest.mark.parametrize('name', sorted(TABLE_I))
def test_signed_log_slope_has_the_gradients_sign(name):
    shape = TABLE_I[name]
    r = np.linspace(0.0, 0.8, 801)
    gradient = potential_gradient(np.stack([r, 0 * r], axis=1), shape)[:, 0]
    log_slope, sign = signed_log_potential_slope(r, shape)
    np.testing.assert_array_equal(log_slope, log_potential_slope(r, shape))
    nonzero = gradient != 0.0
    np.testing.assert_array_equal(sign[nonzero], np.sign(gradient[nonzero]))
    assert np.all(sign[np.isinf(log_slope)] == 0.0)


def test_default_gain_makes_the_pull_max_task_speed_at_the_onset():
    follow = TABLE_I['follow']
    log_k = default_task_gain(follow, V_MAX, REACH)
    pull = math.exp(log_k + float(log_potential_slope(follow.d2 + 0.15, follow)))
    assert pull == pytest.approx(V_MAX)
