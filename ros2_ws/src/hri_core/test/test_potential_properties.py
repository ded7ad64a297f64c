"""Property tests of hri_core.potential: finite for any valid task and any distance, and
TaskShape accepts exactly the valid parameter sets."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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

# Steepness from a barely-there 1e-6 to 1e4 1/m^2 (the fit's bounds are 1e-3..1e3), distances
# from 0 to 10 m (the workspace is under 1 m): exp(a d^2) reaches exp(1e6), far past a double.
steepness = st.floats(1e-6, 1e4)
boundary = st.floats(0.0, 10.0)
distance = st.floats(0.0, 20.0)


@st.composite
def task_shapes(draw):
    d1, d2 = sorted((draw(boundary), draw(boundary)))
    return TaskShape(draw(st.sampled_from((1, -1))), draw(steepness), draw(steepness), d1, d2,
                     draw(st.integers(3, 15)))


@settings(max_examples=300, deadline=None)
@given(shape=task_shapes(), r=distance, angle=st.floats(0.0, 2.0 * math.pi))
def test_potential_and_its_derivatives_are_finite_everywhere(shape, r, angle):
    dx = np.array([r * math.cos(angle), r * math.sin(angle)])
    y = task_function(r, shape)
    p = potential(r, shape)
    gradient = potential_gradient(dx, shape)
    hessian = potential_hessian(dx, shape)
    batch_gradient = potential_gradient(dx[None, :], shape)[0]
    for value in (y, p, gradient, hessian, batch_gradient):
        assert np.all(np.isfinite(value))
    assert 0.0 <= p <= POTENTIAL_CEILING
    assert abs(y) <= POTENTIAL_CEILING
    assert np.linalg.norm(gradient) <= POTENTIAL_CEILING * (1.0 + 1e-12)
    assert np.max(np.abs(hessian)) <= POTENTIAL_CEILING
    assert np.allclose(hessian, hessian.T, rtol=1e-12, atol=0.0)
    log_p = log_potential(r, shape)
    assert not np.isnan(log_p)
    assert p == 0.0 or np.isfinite(log_p)


@settings(max_examples=100, deadline=None)
@given(shape=task_shapes(), distances=st.lists(distance, min_size=1, max_size=50))
def test_normalised_potential_is_finite_with_unit_or_zero_norm(shape, distances):
    values = normalised_potential(np.array(distances), shape)
    assert np.all(np.isfinite(values))
    norm = np.linalg.norm(values)
    assert norm == 0.0 or math.isclose(norm, 1.0, rel_tol=1e-9)


def is_valid(s, a1, a2, d1, d2, n) -> bool:
    """The definition of a valid task (eq. 1, 2), written out independently of TaskShape."""
    def integer(value):
        return isinstance(value, int) and not isinstance(value, bool)

    def real(value):
        return isinstance(value, (int, float)) and not isinstance(value, bool) \
            and math.isfinite(value)

    return (integer(s) and s in (1, -1) and integer(n) and n >= 3
            and all(real(v) for v in (a1, a2, d1, d2))
            and a1 > 0 and a2 > 0 and 0 <= d1 <= d2)


any_number = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 20), st.booleans(),
    st.none(), st.text(max_size=3), st.sampled_from((0.0, -0.0, 1e-300, 3, -1, 1)))


@settings(max_examples=500, deadline=None)
@given(s=any_number, a1=any_number, a2=any_number, d1=any_number, d2=any_number, n=any_number)
def test_task_shape_accepts_exactly_the_valid_parameter_sets(s, a1, a2, d1, d2, n):
    if is_valid(s, a1, a2, d1, d2, n):
        shape = TaskShape(s, a1, a2, d1, d2, n)
        assert (shape.s, shape.n) == (s, n)
        assert (shape.a1, shape.a2, shape.d1, shape.d2) == (a1, a2, d1, d2)
    else:
        with pytest.raises(ValueError, match='must be'):
            TaskShape(s, a1, a2, d1, d2, n)
