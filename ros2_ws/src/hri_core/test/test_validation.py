"""Unit tests of hri_core.validation's 3-vector checks (positions travel in 3-D)."""

import numpy as np
import pytest

from hri_core.validation import check_frame, spatial_points, spatial_vector


def test_spatial_vector_takes_three_finite_values():
    np.testing.assert_array_equal(spatial_vector([[0.1], [0.2], [0.3]], 'x_r', 'm'),
                                  [0.1, 0.2, 0.3])
    for bad in ([0.1, 0.2], [0.1, 0.2, np.nan], [0.0, 0.0, 0.0, 1.0]):
        with pytest.raises(ValueError, match=r'x_r must be 3 finite values \[x, y, z\] in m'):
            spatial_vector(bad, 'x_r', 'm')


def test_spatial_points_put_planar_points_in_the_plane_z_0():
    planar = np.random.default_rng(3).uniform(-1.0, 1.0, (5, 2))
    points = spatial_points(planar, 'positions', 'm')
    np.testing.assert_array_equal(points, np.column_stack([planar, np.zeros(5)]))
    spatial = np.ones((4, 3))
    np.testing.assert_array_equal(spatial_points(spatial, 'positions'), spatial)
    with pytest.raises(ValueError, match=r'positions must be \(N, 3\) points'):
        spatial_points(np.ones((4, 4)), 'positions')
    with pytest.raises(ValueError, match=r'positions must be finite \(m\)'):
        spatial_points(np.full((2, 3), np.inf), 'positions', 'm')


def test_a_frame_is_the_base_frame_or_unset():
    check_frame('base', 'base')
    check_frame('', 'base')  # a bare publisher's: taken as the base frame
    with pytest.raises(ValueError, match="^frame 'camera' is not base_frame 'base'$"):
        check_frame('camera', 'base')
    with pytest.raises(ValueError, match="^frame 'base' is not base_frame 'world'$"):
        check_frame('base', 'world')
