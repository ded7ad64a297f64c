"""Every robot capsule against every human capsule, compiled (numba): the loop of
`hri_core.bodies.segment_parameters` and `capsule_distances` over each pair at once; and the
arm's chain (hri_core.bodies.Chain): its joints' frames, its capsules placed by them, a point's
Jacobian row along a normal (what RobotBody.capsules and normal_rows give through pinocchio).

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


@njit(cache=True, nogil=True)
def chain_frames(q, parents, placements, axes, prismatic, index):
    """(rotations (J, 3, 3), origins (J, 3) m): every joint's frame in the base frame at joint
    positions q (n,), the chain of hri_core.bodies.Chain (parents, placements, axes, prismatic,
    index; a parent comes before its children). T_i = T_parent M_i X_i(q), X_i the turn about
    (Rodrigues) or the slide along the joint's axis. Scalar loops: they compile in a fraction
    of the time numba takes over slices and small matrix products."""
    count = parents.shape[0]
    rotations = np.empty((count, 3, 3))
    origins = np.empty((count, 3))
    for r in range(3):
        origins[0, r] = placements[0, r, 3]
        for c in range(3):
            rotations[0, r, c] = placements[0, r, c]
    turn = np.empty((3, 3))
    placed = np.empty((3, 3))
    for i in range(1, count):
        p = parents[i]
        for r in range(3):
            origin = origins[p, r]
            for k in range(3):
                origin += rotations[p, r, k] * placements[i, k, 3]
            origins[i, r] = origin
            for c in range(3):
                total = 0.0
                for k in range(3):
                    total += rotations[p, r, k] * placements[i, k, c]
                placed[r, c] = total
        value = q[index[i]]
        ax, ay, az = axes[i, 0], axes[i, 1], axes[i, 2]
        if prismatic[i]:
            for r in range(3):
                origins[i, r] += value * (placed[r, 0] * ax + placed[r, 1] * ay
                                          + placed[r, 2] * az)
                for c in range(3):
                    rotations[i, r, c] = placed[r, c]
            continue
        cosine, sine = math.cos(value), math.sin(value)
        v = 1.0 - cosine
        turn[0, 0] = cosine + ax * ax * v
        turn[0, 1] = ax * ay * v - az * sine
        turn[0, 2] = ax * az * v + ay * sine
        turn[1, 0] = ay * ax * v + az * sine
        turn[1, 1] = cosine + ay * ay * v
        turn[1, 2] = ay * az * v - ax * sine
        turn[2, 0] = az * ax * v - ay * sine
        turn[2, 1] = az * ay * v + ax * sine
        turn[2, 2] = cosine + az * az * v
        for r in range(3):
            for c in range(3):
                rotations[i, r, c] = (placed[r, 0] * turn[0, c] + placed[r, 1] * turn[1, c]
                                      + placed[r, 2] * turn[2, c])
    return rotations, origins


@njit(cache=True, nogil=True)
def placed_capsules(rotations, origins, joint, local_a, local_b):
    """(a (K, 3) m, axis b - a (K, 3) m): the capsules' ends local_a, local_b (K, 3) m in their
    joints' frames (joint (K,) entries of the chain) placed by chain_frames' frames."""
    count = joint.shape[0]
    a = np.empty((count, 3))
    axis = np.empty((count, 3))
    for k in range(count):
        j = joint[k]
        for r in range(3):
            start = origins[j, r]
            end = origins[j, r]
            for c in range(3):
                start += rotations[j, r, c] * local_a[k, c]
                end += rotations[j, r, c] * local_b[k, c]
            a[k, r] = start
            axis[k, r] = end - start
    return a, axis


@njit(cache=True, nogil=True)
def add_normal_row(rotations, origins, parents, axes, prismatic, index, joint, point, normal,
                   scale, row):
    """row (n,) += scale n^T J_p: J_p (3, n) the Jacobian of `point` (3,) m moving with the
    chain's entry `joint` (the joints from it up to the base move it), n `normal` (3,); column
    i: z_i x (p - o_i) for a revolute joint, z_i for a prismatic one (z_i = R_i axis_i)."""
    i = joint
    while i > 0:
        zx = rotations[i, 0, 0] * axes[i, 0] + rotations[i, 0, 1] * axes[i, 1] \
            + rotations[i, 0, 2] * axes[i, 2]
        zy = rotations[i, 1, 0] * axes[i, 0] + rotations[i, 1, 1] * axes[i, 1] \
            + rotations[i, 1, 2] * axes[i, 2]
        zz = rotations[i, 2, 0] * axes[i, 0] + rotations[i, 2, 1] * axes[i, 1] \
            + rotations[i, 2, 2] * axes[i, 2]
        if prismatic[i]:
            value = normal[0] * zx + normal[1] * zy + normal[2] * zz
        else:
            rx = point[0] - origins[i, 0]
            ry = point[1] - origins[i, 1]
            rz = point[2] - origins[i, 2]
            # n . (z x r) = z . (r x n)
            value = (zx * (ry * normal[2] - rz * normal[1])
                     + zy * (rz * normal[0] - rx * normal[2])
                     + zz * (rx * normal[1] - ry * normal[0]))
        row[index[i]] += scale * value
        i = parents[i]
