"""Unit tests of hri_core.velocity_estimator: low-passed differences of stamped positions."""

import numpy as np
import pytest

from hri_core.velocity_estimator import VelocityEstimator


def test_velocity_estimator_converges_to_the_slope_and_skips_repeated_stamps():
    estimator = VelocityEstimator(time_constant=0.01)
    for k in range(200):
        t = k * 1e-3
        velocity = estimator.update([0.1 * t, -0.2 * t], t)
    np.testing.assert_allclose(velocity, [0.1, -0.2], rtol=1e-6)
    np.testing.assert_array_equal(estimator.update([5.0, 5.0], 0.199), velocity)


def test_velocity_estimator_smooths_a_jump_by_its_time_constant():
    estimator = VelocityEstimator(time_constant=0.05)
    estimator.update([0.0, 0.0], 0.0)
    velocity = estimator.update([0.001, 0.0], 0.001)
    # one step of a first-order filter: dt / (tc + dt) of the raw 1 m/s difference
    np.testing.assert_allclose(velocity, [0.001 / 0.051, 0.0], rtol=1e-12)


def test_velocity_estimator_rejects_bad_input():
    with pytest.raises(ValueError, match='time_constant must be finite and > 0 s'):
        VelocityEstimator(0.0)
    with pytest.raises(ValueError, match=r'position must be 2 finite values \[x, y\] in m'):
        VelocityEstimator(0.01).update([float('nan'), 0.0], 0.0)


def test_velocity_estimator_in_3d():
    estimator = VelocityEstimator(1e-9, dimension=3)
    np.testing.assert_array_equal(estimator.velocity, np.zeros(3))
    estimator.update([0.1, 0.2, 0.3], 1.0)
    velocity = estimator.update([0.1, 0.25, 0.2], 1.5)
    np.testing.assert_allclose(velocity, [0.0, 0.1, -0.2], atol=1e-9)
    with pytest.raises(ValueError, match=r'position must be 3 values \[x, y, z\], got 2'):
        estimator.update([0.1, 0.2], 2.0)
    with pytest.raises(ValueError, match='dimension must be 2 or 3, got 4'):
        VelocityEstimator(0.01, dimension=4)
