"""Unit tests of hri_demo_learning.performance_learning: the fit of a1, a2 (eq. 7-11)."""

import warnings

import numpy as np
import pytest

from hri_core.potential import TaskShape, normalised_potential, potential
from hri_demo_learning.performance_learning import (
    STEEPNESS_BOUNDS,
    FitOptions,
    fit_task_parameters,
    normalised_potential_jacobian,
    task_cost,
)

# Shapes whose a1, a2 are determined by samples on the given distance range (m).
IDENTIFIABLE = {
    'follow': (TaskShape(1, 1.291, 13.66, 0.0, 0.041), 0.0, 0.6),
    'follow_near': (TaskShape(1, 1.291, 13.66, 0.0, 0.041), 0.0, 0.3),
    'follow_safe': (TaskShape(1, 1.576, 30.78, 0.183, 0.271), 0.0, 0.6),
    'avoid_within_0.6': (TaskShape(1, 3.0, 8.0, 0.183, 0.6), 0.0, 0.7),
    'trap': (TaskShape(-1, 4.0, 12.0, 0.1, 0.25), 0.0, 0.4),
}


def samples(name, seed=3, count=400):
    shape, low, high = IDENTIFIABLE[name]
    distance = np.sort(np.random.default_rng(seed).uniform(low, high, count))
    return shape, distance, potential(distance, shape)


@pytest.mark.parametrize('name', sorted(IDENTIFIABLE))
def test_both_methods_recover_the_generating_parameters(name):
    shape, distance, energy = samples(name)
    fits = {method: fit_task_parameters(distance, energy, shape.s, shape.d1, shape.d2,
                                        options=FitOptions(method=method))
            for method in ('trf', 'gauss_newton')}
    for fit in fits.values():
        assert fit.converged, fit.message
        assert fit.a1 == pytest.approx(shape.a1, rel=1e-5)
        assert fit.a2 == pytest.approx(shape.a2, rel=1e-5)
        assert fit.cost < 1e-20
    assert fits['trf'].iterations <= 50
    assert fits['trf'].cost <= fits['gauss_newton'].cost + 1e-20


def test_jacobian_matches_finite_differences():
    for name in sorted(IDENTIFIABLE):
        shape, distance, _ = samples(name)
        _, jacobian = normalised_potential_jacobian(distance, shape)
        for column, key in enumerate(('a1', 'a2')):
            value = getattr(shape, key)
            h = 1e-5 * value
            plus = TaskShape(**{**shape.__dict__, key: value + h})
            minus = TaskShape(**{**shape.__dict__, key: value - h})
            numeric = (normalised_potential(distance, plus)
                       - normalised_potential(distance, minus)) / (2 * h)
            np.testing.assert_allclose(jacobian[:, column], numeric, rtol=1e-5,
                                       atol=1e-7 * np.max(np.abs(numeric)))


def minimum_jerk_push(rng, start, stop, rate=500.0, noise=3e-4):
    """Distance to x_r of a noisy minimum-jerk push (1.5 s, uneven sampling) and its P_d of
    eq. 3, (distance - stop)^2 - T while moving, 0 at rest (0.5 s after the push)."""
    times = np.cumsum(rng.gamma(4.0, 1.0 / (4.0 * rate), size=int(4 * rate)))
    times = times[times <= 2.0]
    tau = np.clip(times / 1.5, 0.0, 1.0)
    distance = start + (stop - start) * tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)
    distance = np.abs(distance + rng.normal(0.0, noise, distance.size))
    moving = times < 1.45
    squared = (distance - stop) ** 2
    energy = np.where(moving, squared - np.min(squared[moving]), 0.0)
    return distance, energy


@pytest.mark.parametrize(('start', 'stop', 's', 'd1', 'd2'), [
    (0.30, 0.041, 1, 0.0, 0.041),     # follow
    (0.02, 0.183, 1, 0.183, 2.0),     # avoid
])
def test_default_fit_of_a_realistic_push(start, stop, s, d1, d2):
    distance, energy = minimum_jerk_push(np.random.default_rng(21), start, stop)
    default = fit_task_parameters(distance, energy, s, d1, d2)
    plain = fit_task_parameters(distance, energy, s, d1, d2,
                                options=FitOptions('gauss_newton', max_iterations=3000))
    assert default.method == 'trf' and default.converged, default.message
    assert default.iterations <= 50
    assert default.cost <= plain.cost * (1 + 1e-9)
    assert default.cost < 0.01             # P/||P|| follows P_d/||P_d|| closely
    low, high = STEEPNESS_BOUNDS
    assert low <= default.a1 <= high and low <= default.a2 <= high
    assert default.cost <= task_cost(distance, energy,
                                     TaskShape(s, default.a2, default.a1, d1, d2))


def test_plain_gauss_newton_far_from_the_optimum_stays_finite():
    # An undamped step from a poor start jumps to the bounds; nothing may overflow on the way.
    shape, distance, energy = samples('follow_safe')
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        start = (STEEPNESS_BOUNDS[1], STEEPNESS_BOUNDS[0])
        fit = fit_task_parameters(distance, energy, shape.s, shape.d1, shape.d2,
                                  options=FitOptions('gauss_newton', max_iterations=50,
                                                     initial=start))
    assert np.isfinite(fit.cost) and np.isfinite(fit.a1) and np.isfinite(fit.a2)
    assert fit.iterations <= 50


def test_fit_of_the_avoidance_row_reaches_zero_cost():
    # Table I's avoid row: P(0) ~ 1e124, and a1 is barely determined (flat valley a1 -> 0).
    shape = TaskShape(1, 0.056, 25.46, 0.183, 2.0)
    distance = np.sort(np.random.default_rng(5).uniform(0.0, 0.3, 400))
    energy = normalised_potential(distance, shape)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        fit = fit_task_parameters(distance, energy, 1, 0.183, 2.0)
    assert fit.converged and fit.iterations <= 50
    assert fit.cost < 1e-9
    assert fit.a2 == pytest.approx(25.46, rel=0.1)
    assert fit.condition > 1e3


def test_bad_input_is_rejected_with_a_reason():
    shape, distance, energy = samples('follow')
    fit = fit_task_parameters
    with pytest.raises(ValueError, match='zero on every sample: nothing to fit'):
        fit(distance, np.zeros_like(energy), 1, 0.0, 0.041)
    bad = energy.copy()
    bad[3] = np.inf
    with pytest.raises(ValueError, match='non-finite input'):
        fit(distance, bad, 1, 0.0, 0.041)
    with pytest.raises(ValueError, match=r'both be \(N,\)'):
        fit(distance, energy[:-1], 1, 0.0, 0.041)
    with pytest.raises(ValueError, match='P is zero on every sample'):
        fit(distance[distance < 0.04], energy[distance < 0.04] + 1.0, 1, 0.0, 0.041)
    with pytest.raises(ValueError, match='d1 must be <= d2'):
        fit(distance, energy, 1, 0.3, 0.041)
    with pytest.raises(ValueError, match='distance and energy must be >= 0'):
        fit(-distance, energy, 1, 0.0, 0.041)


@pytest.mark.parametrize(('options', 'reason'), [
    ({'method': 'newton'}, r"^method must be one of trf, gauss_newton, got 'newton'$"),
    ({'tolerance': -1.0}, r'^tolerance must be > 0, got -1\.0$'),
    ({'tolerance': float('nan')}, r'^tolerance must be > 0, got nan$'),
    ({'max_iterations': 0}, r'^max_iterations must be an integer >= 1, got 0$'),
    ({'max_iterations': 5.0}, r'^max_iterations must be an integer >= 1, got 5\.0$'),
    ({'initial': (0.0, 10.0)}, r'^initial \(a1, a2\) must lie in \[0\.001, 1000\.0\]'),
    ({'initial': (1.0,)}, r'^initial \(a1, a2\) must lie in'),
], ids=lambda value: next(iter(value)) if isinstance(value, dict) else None)
def test_fit_options_out_of_range_are_refused_in_one_line(options, reason):
    with pytest.raises(ValueError, match=reason):
        FitOptions(**options)
