"""The law's 1 kHz arithmetic, compiled (numba): arm_law's per-cycle path, any arm.

arm_law.ArmController.command spends most of a cycle in small numpy calls (about 1 us
each, some thirty a cycle) around pinocchio's: the damped pseudo-inverse, the reference joint
motion and the torque. These kernels do that arithmetic in compiled loops, the same formulas
in the same order as arm_law's numpy path (`ArmController(..., compiled=False)`), which stays
the reference: test_arm_kernels checks the two agree on random states of the SCARA and the
Panda. Shapes: J, Jdot (k, n), k = 2 or 3 task axes; J+, dJ+/dt (n, k); q, qdot, qdot_r,
qddot_r, s, tau (n,). Units as arm_law's.

Compiled on first use and cached beside this module (numba's cache=True), so a controller
starts from the cache after the first run; scripts/build.sh compiles them once. No ROS import.
"""

import math

import numpy as np
from numba import njit

from hri_adaptive_controller import joint_limits, task_variable
from hri_adaptive_controller.joint_limits import SPEED_NORM, STOP_SHARE, STOP_SOFTNESS
from hri_adaptive_controller.task_variable import SECH_LIMIT
from hri_core.capsule_kernels import add_normal_row, chain_frames, placed_capsules, segment_table

# A human capsule's part in the body barrier (arm_law.ArmController._exempt): kept at the
# clearance, left out, or kept at its surface.
KEPT, LEFT_OUT, AT_SURFACE = 0, 1, 2


@njit(cache=True, nogil=True)
def _adjugate(gram, out):
    """out (k, k) = adj(gram) of a symmetric k x k gram, k = 2 or 3; returns det(gram)."""
    if gram.shape[0] == 2:
        out[0, 0], out[0, 1] = gram[1, 1], -gram[0, 1]
        out[1, 0], out[1, 1] = -gram[0, 1], gram[0, 0]
        return gram[0, 0] * gram[1, 1] - gram[0, 1] * gram[0, 1]
    g00, g01, g02 = gram[0, 0], gram[0, 1], gram[0, 2]
    g11, g12, g22 = gram[1, 1], gram[1, 2], gram[2, 2]
    out[0, 0], out[0, 1], out[0, 2] = (g11 * g22 - g12 * g12, g02 * g12 - g01 * g22,
                                       g01 * g12 - g02 * g11)
    out[1, 1], out[1, 2] = g00 * g22 - g02 * g02, g01 * g02 - g00 * g12
    out[2, 2] = g00 * g11 - g01 * g01
    out[1, 0], out[2, 0], out[2, 1] = out[0, 1], out[0, 2], out[1, 2]
    return g00 * out[0, 0] + g01 * out[0, 1] + g02 * out[0, 2]


@njit(cache=True, nogil=True)
def damped_pseudo_inverse(jac, rate, threshold2, max_damping2):
    """task_variable.damped_pseudo_inverse compiled: J+ (n, k), dJ+/dt (n, k) and lambda^2
    for J, Jdot (k, n), k = 2 or 3, and singular = True (nothing else valid) where the
    damped Gram matrix has no inverse."""
    k, n = jac.shape
    gram = np.zeros((k, k))
    gram_rate = np.zeros((k, k))
    for a in range(k):
        for b in range(k):
            total = 0.0
            change = 0.0
            for j in range(n):
                total += jac[a, j] * jac[b, j]
                change += rate[a, j] * jac[b, j]
            gram[a, b] = total
            gram_rate[a, b] += change
            gram_rate[b, a] += change  # dG/dt = Jdot J^T + J Jdot^T
    adjugate = np.empty((k, k))
    det = _adjugate(gram, adjugate)
    ratio = det / threshold2
    lam2 = lam2_rate = 0.0
    if ratio < 1.0:
        lam2 = max_damping2 * (1.0 - ratio) ** 2
        trace = 0.0  # d det(G)/dt = tr(adj(G) dG/dt)
        for a in range(k):
            for b in range(k):
                trace += adjugate[a, b] * gram_rate[b, a]
        lam2_rate = -2.0 * max_damping2 * (1.0 - ratio) * trace / threshold2
        for a in range(k):
            gram[a, a] += lam2
        det = _adjugate(gram, adjugate)
    pinv = np.empty((n, k))
    pinv_rate = np.empty((n, k))
    if abs(det) <= 1e-300:
        return pinv, pinv_rate, lam2, True
    for a in range(k):
        gram_rate[a, a] += lam2_rate  # d(lambda^2 I)/dt
        for b in range(k):
            adjugate[a, b] /= det  # now the inverse
    for i in range(n):
        for b in range(k):
            total = 0.0
            for a in range(k):
                total += jac[a, i] * adjugate[a, b]
            pinv[i, b] = total
    # dJ+/dt = (Jdot^T - J+ dA/dt) A^-1
    work = np.empty(k)
    for i in range(n):
        for b in range(k):
            total = rate[b, i]
            for a in range(k):
                total -= pinv[i, a] * gram_rate[a, b]
            work[b] = total
        for b in range(k):
            total = 0.0
            for a in range(k):
                total += work[a] * adjugate[a, b]
            pinv_rate[i, b] = total
    return pinv, pinv_rate, lam2, False


# task_variable.speed_cap itself, compiled: the smooth cap (value, d/d speed) of a signed speed
# (m/s) at v_max (m/s), one source for the SCARA's path and this one.
speed_cap = njit(cache=True, nogil=True)(task_variable.speed_cap)
joint_motion = njit(cache=True, nogil=True)(joint_limits.joint_motion)
reach_goal = njit(cache=True, nogil=True)(joint_limits.reach_goal)


@njit(cache=True, nogil=True)
def _times(matrix, vector, out):
    """out (n,) = matrix (n, k) @ vector (k,)."""
    for i in range(matrix.shape[0]):
        total = 0.0
        for b in range(matrix.shape[1]):
            total += matrix[i, b] * vector[b]
        out[i] = total


@njit(cache=True, nogil=True)
def _less_times(matrix, vector, out):
    """out (n,) -= matrix (n, k) @ vector (k,)."""
    for i in range(matrix.shape[0]):
        total = 0.0
        for b in range(matrix.shape[1]):
            total += matrix[i, b] * vector[b]
        out[i] -= total


@njit(cache=True, nogil=True)
def joint_reference(q, dq, jac, rate, pinv, pinv_rate, velocity, acceleration, blend, u, u_rate,
                    home, posture_gain, posture_speed, null_space, barrier, barrier_rate,
                    posture, posture_rate, kp, push):
    """qdot_r, qddot_r, s = qdot - qdot_r (n,) each and the barrier's task-space velocity
    J+^T g_B / Kp (k,) m/s, outside the joint limits' bands (eq. 14, 17, 18; arm_law's module
    docstring and ArmController._joint_reference, the reference).

    velocity, acceleration (k,): the task-space reference v (m/s) and its rate, fed forward
    and task terms together. blend (sigma, dsigma/dt, on) of the reach-round with u, u_rate
    (n,) its joint motion (already weighted by a); on = 0.0: no blend (u unused). barrier,
    barrier_rate (n,) N m, N m/s: the person's barrier g_B and its rate (zeros: none), taken
    out of qdot_r as J+ J+^T g_B / Kp (kp N s/m). null_space: add N z, z = cap(-k_n (q -
    home)) (posture_speed per joint) weighted 1 - sigma, less push (rad/s per N m) times g_B
    and the posture push `posture` (n,) N m (rate posture_rate), with the exact dN/dt z + N
    dz/dt."""
    n = q.shape[0]
    axes = jac.shape[0]
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
    # J+^T g_B / Kp and its rate (dJ+/dt^T g_B + J+^T dg_B/dt) / Kp, taken out of the
    # reference; zeros, and nothing taken, without a barrier (the usual case).
    barrier_task = np.zeros(axes)
    if np.any(barrier != 0.0) or np.any(barrier_rate != 0.0):
        barrier_task_rate = np.zeros(axes)
        for b in range(axes):
            for i in range(n):
                barrier_task[b] += pinv[i, b] * barrier[i]
                barrier_task_rate[b] += (pinv_rate[i, b] * barrier[i]
                                         + pinv[i, b] * barrier_rate[i])
            barrier_task[b] /= kp
            barrier_task_rate[b] /= kp
        _less_times(pinv, barrier_task, qdot_r)
        _less_times(pinv_rate, barrier_task, qddot_r)
        _less_times(pinv, barrier_task_rate, qddot_r)
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
            z[i] -= push * barrier[i] + push * posture[i]
            z_rate[i] -= push * barrier_rate[i] + push * posture_rate[i]
        # N z = z - J+ (J z); dN/dt z + N dz/dt = dz/dt - dJ+/dt (J z) - J+ (Jdot z + J dz/dt)
        jz = np.zeros(axes)
        jz_rate = np.zeros(axes)
        for i in range(n):
            for b in range(axes):
                jz[b] += jac[b, i] * z[i]
                jz_rate[b] += rate[b, i] * z[i] + jac[b, i] * z_rate[i]
        _times(pinv, jz, work)
        for i in range(n):
            qdot_r[i] += z[i] - work[i]
        _times(pinv_rate, jz, work)
        for i in range(n):
            qddot_r[i] += z_rate[i] - work[i]
        _less_times(pinv, jz_rate, qddot_r)
    s = np.empty(n)
    for i in range(n):
        s[i] = dq[i] - qdot_r[i]
    return qdot_r, qddot_r, s, barrier_task


@njit(cache=True, nogil=True)
def joint_speed_limit(q, dq, qdot_r, qddot_r, lower, upper, speed, stop_rate, band):
    """joint_limits.joint_speed_limit compiled (the reference): (qdot_r, qddot_r (n,) held
    within the joint speed limit and the stop damper, whether they changed); new arrays."""
    n = q.shape[0]
    qdot_r = qdot_r.copy()
    qddot_r = qddot_r.copy()
    changed = False
    largest = 0.0
    for i in range(n):
        largest = max(largest, abs(qdot_r[i] / speed[i]))
    if largest > 0.0:
        total = 0.0
        for i in range(n):
            total += (qdot_r[i] / speed[i] / largest) ** SPEED_NORM
        rho = largest * total ** (1.0 / SPEED_NORM)
        if rho > 1.0:
            capped, slope = speed_cap(rho, 1.0)
            rho_rate = 0.0
            for i in range(n):
                rho_rate += (qdot_r[i] / speed[i] / rho) ** (SPEED_NORM - 1) * (
                    qddot_r[i] / speed[i])
            scale = capped / rho
            scale_rate = (slope * rho - capped) / (rho * rho) * rho_rate
            for i in range(n):
                qddot_r[i] = scale * qddot_r[i] + scale_rate * qdot_r[i]
                qdot_r[i] = scale * qdot_r[i]
            changed = True
    softness = STOP_SOFTNESS * stop_rate * band
    stop = STOP_SHARE * band
    for i in range(n):
        up = stop_rate * (upper[i] - q[i] - stop)
        down = stop_rate * (q[i] - lower[i] - stop)
        if qdot_r[i] > up:
            bound = up
        elif -qdot_r[i] > down:
            bound = -down
        else:
            continue
        excess = (qdot_r[i] - bound) / softness
        slope = 1.0 / math.cosh(min(abs(excess), SECH_LIMIT)) ** 2
        qddot_r[i] = slope * qddot_r[i] + (1.0 - slope) * (-stop_rate * dq[i])
        qdot_r[i] = bound + softness * math.tanh(excess)
        changed = True
    return qdot_r, qddot_r, changed


@njit(cache=True, nogil=True)
def torque(regressor, theta, qddot_r, s, ks, jac, task_force, barrier, inverse_effort):
    """tau (n,) N m of eq. 16 and its peak share of the effort limits:
    Y theta - Ks s - J^T task_force - g_B, with Y (n, p), theta (p,), task_force (k,) N (Kp
    (1 - sigma) a delta_eps), barrier g_B (n,) N m. peak = max_i |tau_i| / effort_i; NaN
    where tau or qddot_r is not finite (the caller's fault test)."""
    n, p = regressor.shape
    axes = jac.shape[0]
    tau = np.empty(n)
    peak = 0.0
    check = 0.0
    for i in range(n):
        total = 0.0
        for j in range(p):
            total += regressor[i, j] * theta[j]
        total -= ks[i] * s[i]
        for b in range(axes):
            total -= jac[b, i] * task_force[b]
        total -= barrier[i]
        tau[i] = total
        share = abs(total) * inverse_effort[i]
        if share > peak:
            peak = share
        check += share + qddot_r[i]
    if not math.isfinite(check):
        peak = math.nan
    return tau, peak


@njit(cache=True, nogil=True)
def adapt(regressor, s, rates, pace, theta, lower, upper):
    """eq. 19's Euler step of theta_hat (p,): theta - pace L Y^T s, projected onto the box
    [lower, upper] (p,); Y (n, p), s (n,) rad/s, L = diag(rates), pace (s). Returns the new
    theta and whether it is finite (if not, the caller keeps the old one)."""
    n, p = regressor.shape
    out = np.empty(p)
    total = 0.0
    for j in range(p):
        change = 0.0
        for i in range(n):
            change += regressor[i, j] * s[i]
        value = theta[j] - pace * rates[j] * change
        value = max(value, lower[j])
        value = min(value, upper[j])
        out[j] = value
        total += value
    return out, math.isfinite(total)


@njit(cache=True, nogil=True)
def _smoothstep_weight(distance, reach, width, force):
    """arm_law._smoothstep_energy compiled: (weight N, energy J) of one pair's band."""
    u = (reach - distance) / width
    if u <= 0.0:
        return 0.0, 0.0
    v = min(u, 1.0)
    return (force * v * v * v * (10.0 - 15.0 * v + 6.0 * v * v),
            force * width * (v ** 4 * (2.5 - 3.0 * v + v * v) + max(u - 1.0, 0.0)))


@njit(cache=True, nogil=True)
def _body_gradient(q, parents, placements, axes, prismatic, index, joint, local_a, local_b,
                   radius, human_a, human_axis, human_radius, human_va, human_vb, part,
                   settings, posture, collect):
    """arm_law._body_gradient compiled, on the robot's chain (hri_core.bodies.Chain: parents,
    placements, axes, prismatic, index; the capsules' joint (K,), ends local_a, local_b (K, 3)
    m and radius (K,) m) and the person's capsules (human_a, human_axis (H, 3) m, radius (H,)
    m, end velocities human_va, human_vb (H, 3) m/s; part (H,): KEPT, LEFT_OUT or AT_SURFACE).
    settings: (clearance, influence, reaction_time, max_influence, force, posture_influence,
    posture_force).
    Returns (g (n,) N m, U J, the posture push (n,) N m, whether some pair pushes the posture,
    the least distance m, its robot and human capsules, the gate, and where `collect`, the
    approach damper's pairs (those within clearance + influence, in (robot, human) order):
    their rows n^T J_p (m, n), distances (m,) m and approach speeds (m,) m/s (empty arrays
    without `collect`)."""
    (clearance, influence, reaction_time, max_influence, force, posture_influence,
     posture_force) = settings
    rotations, origins = chain_frames(q, parents, placements, axes, prismatic, index)
    a, axis = placed_capsules(rotations, origins, joint, local_a, local_b)
    s, t, between, centre = segment_table(a, axis, human_a, human_axis)
    n = q.shape[0]
    gradient, push = np.zeros(n), np.zeros(n)
    pairs = a.shape[0] * human_a.shape[0] if collect else 0
    rows, gaps, approach = np.zeros((pairs, n)), np.empty(pairs), np.empty(pairs)
    count = 0
    normal, point = np.empty(3), np.empty(3)
    reach = clearance + (max(max_influence, posture_influence) if posture else max_influence)
    least, nearest_i, nearest_j = np.inf, 0, 0
    energy, free, pushed = 0.0, 1.0, False
    for i in range(a.shape[0]):
        for j in range(human_a.shape[0]):
            if part[j] == LEFT_OUT:
                continue
            distance = centre[i, j] - radius[i] - human_radius[j]
            if distance < least:
                least, nearest_i, nearest_j = distance, i, j
            if part[j] == AT_SURFACE:
                distance += clearance
            if not distance < reach:
                continue
            if centre[i, j] >= 1e-12:
                for c in range(3):
                    normal[c] = between[i, j, c] / centre[i, j]
            else:  # the centre lines meet: between the segments' midpoints, or +z
                length = 0.0
                for c in range(3):
                    normal[c] = 0.5 * (2.0 * human_a[j, c] + human_axis[j, c]
                                       - 2.0 * a[i, c] - axis[i, c])
                    length += normal[c] * normal[c]
                length = math.sqrt(length)
                if length >= 1e-12:
                    for c in range(3):
                        normal[c] /= length
                else:
                    normal[0], normal[1], normal[2] = 0.0, 0.0, 1.0
            closing = 0.0
            for c in range(3):
                point[c] = a[i, c] + s[i, j] * axis[i, c] + radius[i] * normal[c]
                closing -= normal[c] * ((1.0 - t[i, j]) * human_va[j, c]
                                        + t[i, j] * human_vb[j, c])
            width = min(influence + reaction_time * max(closing, 0.0), max_influence)
            weight, pair_energy = _smoothstep_weight(distance, clearance + width, width, force)
            energy += pair_energy
            free *= 1.0 - weight / force
            posture_weight = 0.0
            if posture and posture_influence > 0.0:
                posture_weight = _smoothstep_weight(distance, clearance + posture_influence,
                                                    posture_influence, posture_force)[0]
            if weight > 0.0:
                add_normal_row(rotations, origins, parents, axes, prismatic, index, joint[i],
                               point, normal, weight, gradient)
            if posture_weight > 0.0:
                pushed = True
                add_normal_row(rotations, origins, parents, axes, prismatic, index, joint[i],
                               point, normal, posture_weight, push)
            if collect and distance < clearance + influence:
                add_normal_row(rotations, origins, parents, axes, prismatic, index, joint[i],
                               point, normal, 1.0, rows[count])
                gaps[count] = distance
                approach[count] = weight / force * max(closing, 0.0) if force > 0.0 else 0.0
                count += 1
    return (gradient, energy, push, pushed, least, nearest_i, nearest_j, 1.0 - free,
            rows[:count], gaps[:count], approach[:count])


@njit(cache=True, nogil=True)
def body_barrier(q, dq, step, parents, placements, axes, prismatic, index, joint, local_a,
                 local_b, radius, human_a, human_axis, human_radius, human_va, human_vb, part,
                 settings, posture):
    """arm_law.body_barrier compiled (arguments as _body_gradient's; step: BODY_RATE_STEP s):
    (g, its rate, U, the posture push, its rate, whether g and the push are there, the least
    distance and its pair's capsules, the gate and its rate, the approach damper's rows,
    distances and approach speeds), the rates the forward difference along q + step dq."""
    gradient, energy, push, pushed, least, i, j, gate, rows, gaps, approach = _body_gradient(
        q, parents, placements, axes, prismatic, index, joint, local_a, local_b, radius,
        human_a, human_axis, human_radius, human_va, human_vb, part, settings, posture, True)
    n = q.shape[0]
    if energy <= 0.0 and not pushed:
        return (gradient, np.zeros(n), 0.0, push, np.zeros(n), False, False, least, i, j, 0.0,
                0.0, rows, gaps, approach)
    ahead, _, push_ahead, _, _, _, _, gate_ahead, _, _, _ = _body_gradient(
        q + step * dq, parents, placements, axes, prismatic, index, joint, local_a, local_b,
        radius, human_a, human_axis, human_radius, human_va, human_vb, part, settings, posture,
        False)
    return (gradient, (ahead - gradient) / step, energy, push, (push_ahead - push) / step,
            energy > 0.0, pushed, least, i, j, gate, (gate_ahead - gate) / step, rows, gaps,
            approach)


@njit(cache=True, nogil=True)
def _passive_solve(gram, c, passive):
    """z (p,) solving gram[P, P] z = c[P] for the passive set P (its indices, p of them) by
    Cholesky (gram carries arm_law.DAMPER_RIDGE on its diagonal: positive definite)."""
    count = passive.shape[0]
    a = np.empty((count, count))
    z = np.empty(count)
    for i in range(count):
        z[i] = c[passive[i]]
        for j in range(count):
            a[i, j] = gram[passive[i], passive[j]]
    for j in range(count):
        total = a[j, j]
        for k in range(j):
            total -= a[j, k] * a[j, k]
        a[j, j] = math.sqrt(max(total, 1e-300))
        for i in range(j + 1, count):
            total = a[i, j]
            for k in range(j):
                total -= a[i, k] * a[j, k]
            a[i, j] = total / a[j, j]
    for i in range(count):
        total = z[i]
        for k in range(i):
            total -= a[i, k] * z[k]
        z[i] = total / a[i, i]
    for i in range(count - 1, -1, -1):
        total = z[i]
        for k in range(i + 1, count):
            total -= a[k, i] * z[k]
        z[i] = total / a[i, i]
    return z


@njit(cache=True, nogil=True)
def body_damper(qdot_r, rows, gaps, approach, rate, stop, floor, softness, ridge):
    """arm_law.body_damper compiled (the reference, the same active-set steps): (qdot_r (n,)
    with each pair's approach speed held, whether it changed); a new array where it did."""
    m, n = rows.shape
    c = np.empty(m)
    over = False
    for k in range(m):
        bound = max(rate * (gaps[k] - stop), floor) - approach[k]
        speed, norm = 0.0, 0.0
        for i in range(n):
            speed += rows[k, i] * qdot_r[i]
            norm += rows[k, i] * rows[k, i]
        excess = speed - bound
        if norm <= 1e-18:
            c[k] = -1.0  # a point the joints do not move along n: no bound
        elif excess > 0.0:
            over = True
            c[k] = excess - softness * math.tanh(excess / softness)
        else:
            c[k] = excess
    if not over:
        return qdot_r, False
    gram = np.empty((m, m))
    for k in range(m):
        for j in range(k + 1):
            total = 0.0
            for i in range(n):
                total += rows[k, i] * rows[j, i]
            gram[k, j] = total
            gram[j, k] = total
        gram[k, k] += ridge
    multipliers = np.zeros(m)
    passive = np.zeros(m, dtype=np.bool_)
    for _ in range(3 * m + 3):
        best, largest = -1, 1e-12
        for k in range(m):
            if passive[k]:
                continue
            w = c[k]
            for j in range(m):
                w -= gram[k, j] * multipliers[j]
            if w > largest:
                best, largest = k, w
        if best < 0:
            break
        passive[best] = True
        for _ in range(3 * m + 3):
            index = np.nonzero(passive)[0]
            z = _passive_solve(gram, c, index)
            if np.all(z > 0.0):
                multipliers[:] = 0.0
                for p in range(index.shape[0]):
                    multipliers[index[p]] = z[p]
                break
            alpha = 1.0
            for p in range(index.shape[0]):
                if z[p] <= 0.0:
                    k = index[p]
                    alpha = min(alpha, multipliers[k] / (multipliers[k] - z[p]))
            for p in range(index.shape[0]):
                k = index[p]
                multipliers[k] += alpha * (z[p] - multipliers[k])
                if multipliers[k] <= 1e-15:
                    multipliers[k] = 0.0
                    passive[k] = False
    x = qdot_r.copy()
    for k in range(m):
        if multipliers[k] != 0.0:
            for i in range(n):
                x[i] -= multipliers[k] * rows[k, i]
    return x, True


def warm_up_body_barrier() -> None:
    """Compile body_barrier (or load it from numba's cache) with the argument types
    ArmController.whole_body_barrier gives it, on a one-joint arm far from a one-capsule
    person: scripts/build.sh runs this beside the law's other kernels."""
    parents, index = np.array([-1, 0], dtype=np.int64), np.array([-1, 0], dtype=np.int64)
    placements = np.array([np.eye(4), np.eye(4)])
    axes = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    prismatic = np.zeros(2, dtype=np.bool_)
    ends = np.zeros((1, 3))
    far = np.full((1, 3), 1e3)
    body_barrier(np.zeros(1), np.zeros(1), 1e-6, parents, placements, axes, prismatic, index,
                 np.array([1], dtype=np.int64), ends, ends.copy(), np.ones(1), far,
                 np.zeros((1, 3)), np.ones(1), np.zeros((1, 3)), np.zeros((1, 3)),
                 np.zeros(1, dtype=np.int64), (0.1, 0.1, 0.3, 0.19, 5.0, 0.1, 5.0), False)
    body_damper(np.zeros(1), np.zeros((1, 1)), np.zeros(1), np.zeros(1), 5.0, 0.09, -0.5,
                0.02, 1e-6)
