"""Every robot capsule against every human capsule, compiled (numba): the loop of
`hri_core.bodies.segment_parameters` and `capsule_distances` over each pair at once.

The numpy path in hri_core.bodies is the reference (the same formulas in the same order,
equal to rounding: tested); this one is what runs each control cycle, since the numpy path is
about 60 numpy calls of 0.3-1 µs each for the Panda's 9 capsules against a person's 10.
Compiled on first use and cached beside this module (numba's cache=True; scripts/build.sh
fills the cache). No ROS.
"""

import math

import numpy as np
from numba import njit

TINY = 1e-300  # hri_core.bodies._TINY: a divisor floor, a sphere's zero-length axis


@njit(cache=True)
def _clamp(value: float) -> float:
    return min(max(value, 0.0), 1.0)


@njit(cache=True)
def segment_table(robot_a, robot_axis, human_a, human_axis):
    """(s, t, between, centre) of every pair: s, t (R, H) the closest points' parameters
    along the robot's axes a1 + s d1 (robot_a, robot_axis (R, 3) m) and the person's
    a2 + t d2 (human_a, human_axis (H, 3) m) (Ericson, Real-Time Collision Detection 5.1.9);
    between (R, H, 3) m the vector between those points; centre (R, H) m its length."""
    r, h = robot_a.shape[0], human_a.shape[0]
    s_table = np.empty((r, h))
    t_table = np.empty((r, h))
    between = np.empty((r, h, 3))
    centre = np.empty((r, h))
    for i in range(r):
        d1x, d1y, d1z = robot_axis[i, 0], robot_axis[i, 1], robot_axis[i, 2]
        a1x, a1y, a1z = robot_a[i, 0], robot_a[i, 1], robot_a[i, 2]
        a = max(d1x * d1x + d1y * d1y + d1z * d1z, TINY)
        d1_a1 = d1x * a1x + d1y * a1y + d1z * a1z
        for j in range(h):
            d2x, d2y, d2z = human_axis[j, 0], human_axis[j, 1], human_axis[j, 2]
            a2x, a2y, a2z = human_a[j, 0], human_a[j, 1], human_a[j, 2]
            e = max(d2x * d2x + d2y * d2y + d2z * d2z, TINY)
            d2_a2 = d2x * a2x + d2y * a2y + d2z * a2z
            b = d1x * d2x + d1y * d2y + d1z * d2z
            c = d1_a1 - (d1x * a2x + d1y * a2y + d1z * a2z)
            f = (d2x * a1x + d2y * a1y + d2z * a1z) - d2_a2
            s = _clamp((b * f - c * e) / max(a * e - b * b, TINY))
            t = _clamp((b * s + f) / e)
            s = _clamp((b * t - c) / a)
            bx = (a2x - a1x) + t * d2x - s * d1x
            by = (a2y - a1y) + t * d2y - s * d1y
            bz = (a2z - a1z) + t * d2z - s * d1z
            s_table[i, j], t_table[i, j] = s, t
            between[i, j, 0], between[i, j, 1], between[i, j, 2] = bx, by, bz
            centre[i, j] = math.sqrt(bx * bx + by * by + bz * bz)
    return s_table, t_table, between, centre
