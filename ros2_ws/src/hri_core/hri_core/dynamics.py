"""Rigid-body dynamics of a planar 2-link arm: the first two joints of a SCARA.

The model is the paper's eq. 15 with viscous friction added,

    M(q) ddq + C(q, dq) dq + F dq + g(q) = tau,

written linearly in the dynamic parameters (eq. 18),

    M(q) ddq_r + C(q, dq) dq_r + F dq_r + g(q) = Y(q, dq, dq_r, ddq_r) theta,
    theta = [pi1, pi2, pi3, b1, b2, mlc1, mlc2].

C is built from the Christoffel symbols, so that Mdot - 2 C is skew-symmetric (the
paper's 1/2 Mdot + S). The arm is horizontal by default (gravity = 0, so g(q) = 0); a
non-zero `gravity` (m/s^2) acts in the arm plane along -y, which turns the same code into a
vertical 2-link arm. Angles are in rad, lengths in m, torques in N m; q1 is measured from the
base x axis, q2 relative to link 1 (zero when the arm is stretched out).

Every function takes joint vectors of shape (..., 2): a single state or a batch of them.
Nothing here imports ROS; the simulator, the controller and the learner share this module.
"""

import math
from dataclasses import astuple, dataclass

import numpy as np

__all__ = [
    'ScaraParameters',
    'coriolis_matrix',
    'dynamic_parameters',
    'forward_dynamics',
    'forward_kinematics',
    'forward_kinematics_pair',
    'friction_torque',
    'gravity_torque',
    'jacobian',
    'jacobian_derivative',
    'kinetic_energy',
    'mass_matrix',
    'potential_energy',
    'regressor',
    'rk4_step',
]


@dataclass(frozen=True)
class ScaraParameters:
    """Physical parameters of the arm; the defaults are a small industrial SCARA.

    l1, l2: link lengths (m); lc1, lc2: distance of each link's centre of mass from its
    joint (m); m1, m2: link masses (kg; m2 includes the quill and wrist carried by link 2);
    i1, i2: link inertias about the vertical axis through the centre of mass (kg m^2);
    b1, b2: viscous friction of the joints referred to the joint side (N m s/rad);
    gravity: acceleration along -y of the arm plane (m/s^2), 0 for the horizontal SCARA.

    Raises ValueError with the reason when a value is not finite or not physical.
    """

    l1: float = 0.35
    l2: float = 0.30
    lc1: float = 0.175
    lc2: float = 0.18
    m1: float = 4.0
    m2: float = 3.0
    i1: float = 0.045
    i2: float = 0.03
    b1: float = 1.0
    b2: float = 0.5
    gravity: float = 0.0

    def __post_init__(self):
        for name, value in zip(self.__dataclass_fields__, astuple(self), strict=True):
            if not np.isfinite(value):
                raise ValueError(f'ScaraParameters.{name} must be finite, got {value}')
        for name in ('l1', 'l2', 'm1', 'm2', 'i1', 'i2'):
            if getattr(self, name) <= 0.0:
                raise ValueError(f'ScaraParameters.{name} must be > 0, got {getattr(self, name)}')
        for name in ('lc1', 'lc2', 'b1', 'b2'):
            if getattr(self, name) < 0.0:
                raise ValueError(f'ScaraParameters.{name} must be >= 0, got {getattr(self, name)}')
        if self.lc1 > self.l1 or self.lc2 > self.l2:
            raise ValueError(
                f'centre of mass outside its link: lc1={self.lc1} (l1={self.l1}), '
                f'lc2={self.lc2} (l2={self.l2})')


def dynamic_parameters(p: ScaraParameters) -> np.ndarray:
    """The parameter vector theta of the linear-in-parameters model (eq. 18), shape (7,).

    theta = [pi1, pi2, pi3, b1, b2, mlc1, mlc2] with
    pi1 = i1 + i2 + m1 lc1^2 + m2 (l1^2 + lc2^2)  (kg m^2),
    pi2 = m2 l1 lc2  (kg m^2),  pi3 = i2 + m2 lc2^2  (kg m^2),
    b1, b2 (N m s/rad),  mlc1 = m1 lc1 + m2 l1  (kg m),  mlc2 = m2 lc2  (kg m).
    """
    return np.array([
        p.i1 + p.i2 + p.m1 * p.lc1 ** 2 + p.m2 * (p.l1 ** 2 + p.lc2 ** 2),
        p.m2 * p.l1 * p.lc2,
        p.i2 + p.m2 * p.lc2 ** 2,
        p.b1,
        p.b2,
        p.m1 * p.lc1 + p.m2 * p.l1,
        p.m2 * p.lc2,
    ])


def _joint_pair(value, name: str) -> np.ndarray:
    """`value` as a float array of shape (..., 2); ValueError if the last axis is not 2."""
    array = np.asarray(value, dtype=float)
    if array.ndim == 0 or array.shape[-1] != 2:
        raise ValueError(f'{name} must have shape (..., 2), got {array.shape}')
    return array


def _matrix(m11, m12, m21, m22) -> np.ndarray:
    """Stack four broadcastable arrays into matrices of shape (..., 2, 2)."""
    m11, m12, m21, m22 = np.broadcast_arrays(m11, m12, m21, m22)
    return np.stack([np.stack([m11, m12], axis=-1), np.stack([m21, m22], axis=-1)], axis=-2)


def mass_matrix(q, p: ScaraParameters) -> np.ndarray:
    """Inertia matrix M(q) of eq. 15 (kg m^2), shape (..., 2, 2), for q (..., 2) in rad.

    M = [[pi1 + 2 pi2 cos q2, pi3 + pi2 cos q2], [pi3 + pi2 cos q2, pi3]]; symmetric and
    positive definite for every q because i1, i2 > 0.
    """
    q = _joint_pair(q, 'q')
    pi1, pi2, pi3 = dynamic_parameters(p)[:3]
    c2 = np.cos(q[..., 1])
    return _matrix(pi1 + 2.0 * pi2 * c2, pi3 + pi2 * c2, pi3 + pi2 * c2, np.full_like(c2, pi3))


def coriolis_matrix(q, dq, p: ScaraParameters) -> np.ndarray:
    """Centripetal/Coriolis matrix C(q, dq) of eq. 15 (N m s/rad), shape (..., 2, 2).

    Christoffel form, C = pi2 sin q2 [[-dq2, -(dq1 + dq2)], [dq1, 0]], so that C dq is the
    paper's [1/2 Mdot + S] dq and Mdot - 2 C is skew-symmetric. q in rad, dq in rad/s.
    """
    q, dq = _joint_pair(q, 'q'), _joint_pair(dq, 'dq')
    h = dynamic_parameters(p)[1] * np.sin(q[..., 1])
    dq1, dq2 = dq[..., 0], dq[..., 1]
    return _matrix(-h * dq2, -h * (dq1 + dq2), h * dq1, np.zeros_like(h * dq1))


def gravity_torque(q, p: ScaraParameters) -> np.ndarray:
    """Gravity torque g(q) of eq. 15 (N m), shape (..., 2); zero for the horizontal arm.

    g = gravity [mlc1 cos q1 + mlc2 cos(q1 + q2), mlc2 cos(q1 + q2)] for gravity along -y.
    """
    q = _joint_pair(q, 'q')
    mlc1, mlc2 = dynamic_parameters(p)[5:]
    c1, c12 = np.cos(q[..., 0]), np.cos(q[..., 0] + q[..., 1])
    return p.gravity * np.stack([mlc1 * c1 + mlc2 * c12, mlc2 * c12], axis=-1)


def friction_torque(dq, p: ScaraParameters) -> np.ndarray:
    """Viscous friction torque F dq (N m), shape (..., 2), F = diag(b1, b2), dq in rad/s."""
    dq = _joint_pair(dq, 'dq')
    return dq * np.array([p.b1, p.b2])


def regressor(q, dq, dq_r, ddq_r, gravity: float = 0.0) -> np.ndarray:
    """Regressor Y(q, dq, dq_r, ddq_r) of eq. 18, shape (..., 2, 7).

    Y @ dynamic_parameters(p) = M(q) ddq_r + C(q, dq) dq_r + F dq_r + g(q) (N m) for any
    reference velocity dq_r (rad/s) and acceleration ddq_r (rad/s^2). Columns follow theta:
    [pi1, pi2, pi3, b1, b2, mlc1, mlc2]; the last two hold gravity * cos(...) and are zero for
    the horizontal arm. `gravity` (m/s^2) is the same value as ScaraParameters.gravity.
    """
    q, dq = _joint_pair(q, 'q'), _joint_pair(dq, 'dq')
    v, a = _joint_pair(dq_r, 'dq_r'), _joint_pair(ddq_r, 'ddq_r')
    if not np.isfinite(gravity):
        raise ValueError(f'gravity must be finite, got {gravity}')
    q1, q2 = np.broadcast_arrays(q[..., 0], q[..., 1])
    c2, s2 = np.cos(q2), np.sin(q2)
    dq1, dq2 = dq[..., 0], dq[..., 1]
    v1, v2, a1, a2 = v[..., 0], v[..., 1], a[..., 0], a[..., 1]
    g1 = gravity * np.cos(q1)
    g12 = gravity * np.cos(q1 + q2)
    zero = np.zeros(np.broadcast_shapes(q1.shape, dq1.shape, v1.shape, a1.shape))
    row1 = [a1, c2 * (2.0 * a1 + a2) - s2 * (dq2 * v1 + (dq1 + dq2) * v2), a2, v1, zero,
            g1, g12]
    row2 = [zero, c2 * a1 + s2 * dq1 * v1, a1 + a2, zero, v2, zero, g12]
    return np.stack([np.stack(np.broadcast_arrays(*row1), axis=-1),
                     np.stack(np.broadcast_arrays(*row2), axis=-1)], axis=-2)


def forward_kinematics(q, l1: float, l2: float) -> np.ndarray:
    """End-effector position x = [l1 c1 + l2 c12, l1 s1 + l2 s12] (m), shape (..., 2).

    The map behind the paper's J(q) (eq. 14); q (..., 2) in rad, l1, l2 in m, base frame.
    """
    q = _joint_pair(q, 'q')
    q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
    return np.stack([l1 * np.cos(q1) + l2 * np.cos(q12), l1 * np.sin(q1) + l2 * np.sin(q12)],
                    axis=-1)


def forward_kinematics_pair(q1: float, q2: float, l1: float,
                            l2: float) -> tuple[float, float]:
    """forward_kinematics of one joint state in plain floats (m): a 1 kHz publisher's path,
    about 20 times faster than the array version for a single state; q1, q2 in rad."""
    q12 = q1 + q2
    return (l1 * math.cos(q1) + l2 * math.cos(q12), l1 * math.sin(q1) + l2 * math.sin(q12))


def jacobian(q, l1: float, l2: float) -> np.ndarray:
    """Jacobian J(q) = dx/dq of eq. 14 (m/rad), shape (..., 2, 2), for q (..., 2) in rad."""
    q = _joint_pair(q, 'q')
    q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
    s1, c1, s12, c12 = np.sin(q1), np.cos(q1), np.sin(q12), np.cos(q12)
    return _matrix(-l1 * s1 - l2 * s12, -l2 * s12, l1 * c1 + l2 * c12, l2 * c12)


def jacobian_derivative(q, dq, l1: float, l2: float) -> np.ndarray:
    """Time derivative dJ/dt along the motion (m/s), shape (..., 2, 2).

    Used for dJ+/dt in the reference acceleration of eq. 18; q in rad, dq in rad/s.
    """
    q, dq = _joint_pair(q, 'q'), _joint_pair(dq, 'dq')
    q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
    w1, w12 = dq[..., 0], dq[..., 0] + dq[..., 1]
    s1, c1, s12, c12 = np.sin(q1), np.cos(q1), np.sin(q12), np.cos(q12)
    return _matrix(-l1 * c1 * w1 - l2 * c12 * w12, -l2 * c12 * w12,
                   -l1 * s1 * w1 - l2 * s12 * w12, -l2 * s12 * w12)


def forward_dynamics(q, dq, tau, p: ScaraParameters) -> np.ndarray:
    """Joint acceleration ddq = M^-1 (tau - C dq - F dq - g) (rad/s^2), shape (..., 2).

    Solves eq. 15 (with friction) for ddq; q in rad, dq in rad/s, tau (..., 2) in N m.
    """
    q, dq, tau = _joint_pair(q, 'q'), _joint_pair(dq, 'dq'), _joint_pair(tau, 'tau')
    rhs = (tau - np.einsum('...ij,...j->...i', coriolis_matrix(q, dq, p), dq)
           - friction_torque(dq, p) - gravity_torque(q, p))
    m = mass_matrix(q, p)
    det = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]
    return np.stack([m[..., 1, 1] * rhs[..., 0] - m[..., 0, 1] * rhs[..., 1],
                     m[..., 0, 0] * rhs[..., 1] - m[..., 1, 0] * rhs[..., 0]], axis=-1) / det[
        ..., None]


def rk4_step(q, dq, tau, dt: float, p: ScaraParameters) -> tuple[np.ndarray, np.ndarray]:
    """One classical Runge-Kutta (4th order) step of eq. 15 with tau held over the step.

    q (..., 2) rad, dq (..., 2) rad/s, tau (..., 2) N m, dt > 0 in s. Returns the new
    (q, dq). The local error is O(dt^5), the global error O(dt^4). A single state (shape
    (2,)) takes a scalar path about ten times faster than the batched one (the simulator
    steps at 1 kHz); both evaluate the same equations. Raises ValueError for a non-positive
    or non-finite dt or a non-finite state or torque.
    """
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be a finite positive step in s, got {dt}')
    q, dq, tau = _joint_pair(q, 'q'), _joint_pair(dq, 'dq'), _joint_pair(tau, 'tau')
    for name, value in (('q', q), ('dq', dq), ('tau', tau)):
        if not np.all(np.isfinite(value)):
            raise ValueError(f'{name} must be finite, got {value}')
    if q.shape == dq.shape == tau.shape == (2,):
        state = rk4_step_floats((*q.tolist(), *dq.tolist()), tau.tolist(), dt,
                                float_constants(p))
        return np.array(state[:2]), np.array(state[2:])
    k1q, k1v = dq, forward_dynamics(q, dq, tau, p)
    k2q = dq + 0.5 * dt * k1v
    k2v = forward_dynamics(q + 0.5 * dt * k1q, k2q, tau, p)
    k3q = dq + 0.5 * dt * k2v
    k3v = forward_dynamics(q + 0.5 * dt * k2q, k3q, tau, p)
    k4q = dq + dt * k3v
    k4v = forward_dynamics(q + dt * k3q, k4q, tau, p)
    q_next = q + dt / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q)
    dq_next = dq + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    return q_next, dq_next


def float_constants(p: ScaraParameters) -> tuple[float, ...]:
    """The constants rk4_step_floats takes, as Python floats: (pi1, pi2, pi3 in kg m^2,
    b1, b2 in N m s/rad, gravity * mlc1, gravity * mlc2 in N m) of dynamic_parameters."""
    pi1, pi2, pi3, b1, b2, mlc1, mlc2 = dynamic_parameters(p).tolist()
    return pi1, pi2, pi3, b1, b2, p.gravity * mlc1, p.gravity * mlc2


def acceleration_floats(q1, q2, v1, v2, tau, k) -> tuple[float, float]:
    """forward_dynamics of one state in plain floats (rad/s^2): q1, q2 rad, v1, v2 rad/s, tau
    (2,) N m; k from float_constants."""
    pi1, pi2, pi3, b1, b2, gm1, gm2 = k
    c2, s2 = math.cos(q2), math.sin(q2)
    h = pi2 * s2
    g12 = gm2 * math.cos(q1 + q2)
    r1 = tau[0] + h * (2.0 * v1 * v2 + v2 * v2) - b1 * v1 - gm1 * math.cos(q1) - g12
    r2 = tau[1] - h * v1 * v1 - b2 * v2 - g12
    m11, m12 = pi1 + 2.0 * pi2 * c2, pi3 + pi2 * c2
    det = m11 * pi3 - m12 * m12
    return (pi3 * r1 - m12 * r2) / det, (m11 * r2 - m12 * r1) / det


def rk4_step_floats(state, tau, dt, k) -> tuple[float, float, float, float]:
    """rk4_step of one state in plain floats, for callers that step at 1 kHz and check their
    inputs where they enter: state (q1, q2 in rad, dq1, dq2 in rad/s), tau (2,) N m held over
    the step, dt > 0 s, k = float_constants(p). Returns the new (q1, q2, dq1, dq2); no checks
    (a non-finite result is the caller's to catch)."""
    q1, q2, v1, v2 = state
    a1, a2 = acceleration_floats(q1, q2, v1, v2, tau, k)
    h = 0.5 * dt
    b1v1, b1v2 = v1 + h * a1, v2 + h * a2
    b1a1, b1a2 = acceleration_floats(q1 + h * v1, q2 + h * v2, b1v1, b1v2, tau, k)
    c1v1, c1v2 = v1 + h * b1a1, v2 + h * b1a2
    c1a1, c1a2 = acceleration_floats(q1 + h * b1v1, q2 + h * b1v2, c1v1, c1v2, tau, k)
    d1v1, d1v2 = v1 + dt * c1a1, v2 + dt * c1a2
    d1a1, d1a2 = acceleration_floats(q1 + dt * c1v1, q2 + dt * c1v2, d1v1, d1v2, tau, k)
    w = dt / 6.0
    return (q1 + w * (v1 + 2.0 * b1v1 + 2.0 * c1v1 + d1v1),
            q2 + w * (v2 + 2.0 * b1v2 + 2.0 * c1v2 + d1v2),
            v1 + w * (a1 + 2.0 * b1a1 + 2.0 * c1a1 + d1a1),
            v2 + w * (a2 + 2.0 * b1a2 + 2.0 * c1a2 + d1a2))


def kinetic_energy(q, dq, p: ScaraParameters) -> float | np.ndarray:
    """Kinetic energy 1/2 dq^T M(q) dq (J); a float for one state, shape (...) for a batch."""
    q, dq = _joint_pair(q, 'q'), _joint_pair(dq, 'dq')
    energy = 0.5 * np.einsum('...i,...ij,...j->...', dq, mass_matrix(q, p), dq)
    return float(energy) if np.ndim(energy) == 0 else energy


def potential_energy(q, p: ScaraParameters) -> float | np.ndarray:
    """Gravitational potential energy (J) whose gradient is g(q); zero for the horizontal arm.

    V = gravity [mlc1 sin q1 + mlc2 sin(q1 + q2)], the heights of the centres of mass times
    their masses, for gravity along -y. A float for one state, shape (...) for a batch.
    """
    q = _joint_pair(q, 'q')
    mlc1, mlc2 = dynamic_parameters(p)[5:]
    energy = p.gravity * (mlc1 * np.sin(q[..., 0]) + mlc2 * np.sin(q[..., 0] + q[..., 1]))
    return float(energy) if np.ndim(energy) == 0 else energy
