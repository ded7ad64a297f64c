"""The n-joint law's 1 kHz arithmetic, compiled (numba): arm_law's per-cycle path.

arm_law.ArmController.command spends most of a Panda cycle in small numpy calls (about 1 us
each, some thirty a cycle) around pinocchio's: the damped pseudo-inverse, the reference joint
motion and the torque. These kernels do that arithmetic in compiled loops, the same formulas
in the same order as arm_law's numpy path (`ArmController(..., compiled=False)`), which stays
the reference: test_arm_kernels checks the two agree on random Panda states. Shapes: J, Jdot
(3, n); J+, dJ+/dt (n, 3); q, qdot, qdot_r, qddot_r, s, tau (n,). Units as arm_law's.

Compiled on first use and cached beside this module (numba's cache=True), so a controller
starts from the cache after the first run; scripts/build.sh compiles them once. No ROS import.
"""

import math

import numpy as np
from numba import njit

from hri_adaptive_controller import task_variable


@njit(cache=True, nogil=True)
def damped_pseudo_inverse(jac, rate, threshold2, max_damping2):
    """J+ = J^T (J J^T + lambda^2 I)^-1 (n, 3), dJ+/dt (n, 3) and lambda^2 for a 3-row
    J (3, n) m/rad and Jdot (3, n): lambda^2 = max_damping2 (1 - det(J J^T) / threshold2)^2
    below the threshold (w0^2, m^6), 0 above (task_variable's damping law with w = sqrt(det(J
    J^T))); the rate exact. singular = True (nothing else valid) where the damped Gram matrix
    has no inverse."""
    n = jac.shape[1]
    g00 = g01 = g02 = g11 = g12 = g22 = 0.0
    r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = 0.0
    for j in range(n):
        j0, j1, j2 = jac[0, j], jac[1, j], jac[2, j]
        d0, d1, d2 = rate[0, j], rate[1, j], rate[2, j]
        g00 += j0 * j0
        g01 += j0 * j1
        g02 += j0 * j2
        g11 += j1 * j1
        g12 += j1 * j2
        g22 += j2 * j2
        r00 += d0 * j0
        r01 += d0 * j1
        r02 += d0 * j2
        r10 += d1 * j0
        r11 += d1 * j1
        r12 += d1 * j2
        r20 += d2 * j0
        r21 += d2 * j1
        r22 += d2 * j2
    # dG/dt = Jdot J^T + J Jdot^T, symmetric.
    e00, e01, e02 = 2.0 * r00, r01 + r10, r02 + r20
    e11, e12, e22 = 2.0 * r11, r12 + r21, 2.0 * r22
    # The adjugate of the symmetric G; det(G) = g0 . adj0.
    c00, c01, c02 = g11 * g22 - g12 * g12, g02 * g12 - g01 * g22, g01 * g12 - g02 * g11
    c11, c12, c22 = g00 * g22 - g02 * g02, g01 * g02 - g00 * g12, g00 * g11 - g01 * g01
    ratio = (g00 * c00 + g01 * c01 + g02 * c02) / threshold2
    lam2 = lam2_rate = 0.0
    if ratio < 1.0:
        lam2 = max_damping2 * (1.0 - ratio) ** 2
        trace = (c00 * e00 + c11 * e11 + c22 * e22
                 + 2.0 * (c01 * e01 + c02 * e02 + c12 * e12))  # d det(G)/dt
        lam2_rate = -2.0 * max_damping2 * (1.0 - ratio) * trace / threshold2
        g00, g11, g22 = g00 + lam2, g11 + lam2, g22 + lam2
        c00, c01, c02 = g11 * g22 - g12 * g12, g02 * g12 - g01 * g22, g01 * g12 - g02 * g11
        c11, c12 = g00 * g22 - g02 * g02, g01 * g02 - g00 * g12
        c22 = g00 * g11 - g01 * g01
    det = g00 * c00 + g01 * c01 + g02 * c02
    pinv = np.empty((n, 3))
    pinv_rate = np.empty((n, 3))
    if abs(det) <= 1e-300:
        return pinv, pinv_rate, lam2, True
    inverse = np.empty((3, 3))
    inverse[0, 0], inverse[0, 1], inverse[0, 2] = c00 / det, c01 / det, c02 / det
    inverse[1, 0], inverse[1, 1], inverse[1, 2] = c01 / det, c11 / det, c12 / det
    inverse[2, 0], inverse[2, 1], inverse[2, 2] = c02 / det, c12 / det, c22 / det
    e00, e11, e22 = e00 + lam2_rate, e11 + lam2_rate, e22 + lam2_rate  # d(lambda^2 I)/dt
    gram_rate = np.empty((3, 3))
    gram_rate[0, 0], gram_rate[0, 1], gram_rate[0, 2] = e00, e01, e02
    gram_rate[1, 0], gram_rate[1, 1], gram_rate[1, 2] = e01, e11, e12
    gram_rate[2, 0], gram_rate[2, 1], gram_rate[2, 2] = e02, e12, e22
    for i in range(n):
        for k in range(3):
            pinv[i, k] = (jac[0, i] * inverse[0, k] + jac[1, i] * inverse[1, k]
                          + jac[2, i] * inverse[2, k])
    # dJ+/dt = (Jdot^T - J+ dG/dt) G^-1
    work = np.empty(3)
    for i in range(n):
        for k in range(3):
            work[k] = rate[k, i] - (pinv[i, 0] * gram_rate[0, k] + pinv[i, 1] * gram_rate[1, k]
                                    + pinv[i, 2] * gram_rate[2, k])
        for k in range(3):
            pinv_rate[i, k] = (work[0] * inverse[0, k] + work[1] * inverse[1, k]
                               + work[2] * inverse[2, k])
    return pinv, pinv_rate, lam2, False


# task_variable.speed_cap itself, compiled: the smooth cap (value, d/d speed) of a signed speed
# (m/s) at v_max (m/s), one source for the SCARA's path and this one.
speed_cap = njit(cache=True, nogil=True)(task_variable.speed_cap)


@njit(cache=True, nogil=True)
def _times(matrix, vector, out):
    """out (n,) = matrix (n, 3) @ vector (3,)."""
    for i in range(matrix.shape[0]):
        out[i] = matrix[i, 0] * vector[0] + matrix[i, 1] * vector[1] + matrix[i, 2] * vector[2]


@njit(cache=True, nogil=True)
def joint_reference(q, dq, jac, rate, pinv, pinv_rate, velocity, acceleration, blend, u, u_rate,
                    home, posture_gain, posture_speed, null_space):
    """qdot_r, qddot_r and s = qdot - qdot_r (n,) each, away from every barrier band (eq. 14,
    17, 18; arm_law's module docstring).

    velocity, acceleration (3,): the task-space reference v (m/s) and its rate, fed forward
    and task terms together. blend (sigma, dsigma/dt, on) of the reach-round with u, u_rate
    (n,) its joint motion (already weighted by a); on = 0.0: no blend (u unused). null_space:
    add N z, z = cap(-k_n (q - home)) (posture_speed per joint) weighted 1 - sigma, with the
    exact dN/dt z + N dz/dt."""
    n = q.shape[0]
    sigma, sigma_rate, on = blend
    qdot_r = np.empty(n)
    qddot_r = np.empty(n)
    work = np.empty(n)
    _times(pinv, velocity, qdot_r)
    _times(pinv_rate, velocity, qddot_r)
    _times(pinv, acceleration, work)
    for i in range(n):
        qddot_r[i] += work[i]
    if on != 0.0:
        scale = 1.0 - sigma
        for i in range(n):
            qddot_r[i] = scale * qddot_r[i] + sigma_rate * (u[i] - qdot_r[i]) + sigma * u_rate[i]
            qdot_r[i] = scale * qdot_r[i] + sigma * u[i]
    if null_space:
        z = np.empty(n)
        z_rate = np.empty(n)
        for i in range(n):
            value, slope = speed_cap(-posture_gain * (q[i] - home[i]), posture_speed)
            z[i] = value
            z_rate[i] = -posture_gain * dq[i] * slope
            if on != 0.0:
                z_rate[i] = (1.0 - sigma) * z_rate[i] - sigma_rate * z[i]
                z[i] = (1.0 - sigma) * z[i]
        # N z = z - J+ (J z); dN/dt z + N dz/dt = dz/dt - dJ+/dt (J z) - J+ (Jdot z + J dz/dt)
        jz = np.zeros(3)
        jz_rate = np.zeros(3)
        for i in range(n):
            for k in range(3):
                jz[k] += jac[k, i] * z[i]
                jz_rate[k] += rate[k, i] * z[i] + jac[k, i] * z_rate[i]
        _times(pinv, jz, work)
        for i in range(n):
            qdot_r[i] += z[i] - work[i]
        _times(pinv_rate, jz, work)
        for i in range(n):
            qddot_r[i] += z_rate[i] - work[i]
        _times(pinv, jz_rate, work)
        for i in range(n):
            qddot_r[i] -= work[i]
    s = np.empty(n)
    for i in range(n):
        s[i] = dq[i] - qdot_r[i]
    return qdot_r, qddot_r, s


@njit(cache=True, nogil=True)
def torque(rigid, theta, qdot_r, qddot_r, s, ks, jac, task_force, barrier, inverse_effort):
    """tau (n,) N m of eq. 16 and its peak share of the effort limits:
    Y_rigid theta_rigid + diag(qdot_r) theta_friction - Ks s - J^T task_force - g_B, with
    rigid (n, p_rigid), theta (p_rigid + n,), task_force (3,) N (Kp (1 - sigma) a delta_eps),
    barrier g_B (n,) N m. peak = max_i |tau_i| / effort_i; NaN where tau or qddot_r is not
    finite (the caller's fault test)."""
    n, split = rigid.shape
    tau = np.empty(n)
    peak = 0.0
    check = 0.0
    for i in range(n):
        total = 0.0
        for j in range(split):
            total += rigid[i, j] * theta[j]
        total += qdot_r[i] * theta[split + i] - ks[i] * s[i]
        total -= jac[0, i] * task_force[0] + jac[1, i] * task_force[1] + jac[2, i] * task_force[2]
        total -= barrier[i]
        tau[i] = total
        share = abs(total) * inverse_effort[i]
        if share > peak:
            peak = share
        check += share + qddot_r[i]
    if not math.isfinite(check):
        peak = math.nan
    return tau, peak
