"""Event-based task variable and joint-velocity reference (paper eq. 12, 14, 17, 18).

Task variable (eq. 12)
----------------------
The paper's task variable is a(E, t) dP/d(dx) with dx = x - x_d (m). Learned potentials span
an enormous range: Table I's follow potential has |dP/d(dx)| ~ 1e-11 1/m at 9 mm outside its
region, its avoidance potential ~ 1e100 (the cap of hri_core.potential) just inside.
No single gain maps both to a usable velocity. The task variable used here is therefore the
gradient of a *shaped* potential Q(dx) (`ShapedPotential`) with the same desired region:

    dQ/dr = v_max tanh(k c dP/d(rho) / v_max),  c = d(rho)/dr,  Q = 0 on the region,  (eq. 12')
    delta_eps = dQ/d(dx) = (dQ/dr) e,  e = dx / |dx|,  r = |dx|.

- k (m^2/s) is the task gain (the paper's K of eq. 13, swapped with the task), v_max =
  `max_task_speed` (m/s). Where k |dP/dr| << v_max, Q = k P (the paper's eq. 12 with P scaled
  by k); where it is large, the task velocity saturates at v_max, direction kept.
  `shaped_potential` picks k per task so that every task behaves alike: at `approach_distance`
  from the region's boundary the reference speed is >= tanh(1) v_max = 0.76 v_max, so the arm
  travels at up to v_max and slows down within a few approach distances of the boundary.
- rho(r), a piecewise-linear map of the distance, shrinks the region by `region_margin`:
  P's zero set is reached by a gradient field only asymptotically (P ~ (r - d2)^3), so without
  the margin the arm would stop a fraction of a millimetre outside the learned region forever.
  With it, the arm converges to a point inside the learned region and enters it in finite time.
- Because Q is radial, delta_eps is still the gradient of a potential, so the Lyapunov
  argument of eq. 21, 22 holds with Q in place of P *everywhere*, in and out of saturation
  (see adaptive_law). delta_eps is a velocity (m/s), |a delta_eps| <= v_max.

Joint-velocity reference (eq. 14) and its derivative (eq. 18)
-------------------------------------------------------------
    v_r = xdot_d - a delta_eps,          qdot_r = J+ v_r,
    qddot_r = (dJ+/dt) v_r + J+ (xddot_d - da/dt delta_eps - a H_Q (xdot - xdot_d)),

with xdot = J qdot and H_Q = d(delta_eps)/d(dx) the Hessian of Q, built from P's gradient and
Hessian (hri_core.potential) through the chain rule: the exact time derivative, no
finite difference. J+ is the damped pseudo-inverse

    J+ = J^T (J J^T + lambda^2 I)^-1,
    lambda^2 = lambda_max^2 (1 - w^2 / w0^2)^2 for w < w0, else 0,  w = sqrt(det(J J^T)),

so J+ is the exact inverse away from singularities (w >= w0: eq. 22 holds unchanged) and the
damping grows smoothly (C1 in q) to lambda_max at a singularity, where it bounds the joint
speed by |v_r| / (2 lambda_max). dJ+/dt is differentiated analytically, including
d(lambda^2)/dt, from J and Jdot = hri_core.dynamics.jacobian_derivative.
"""

import math
from dataclasses import dataclass

import numpy as np

from hri_core.dynamics import forward_kinematics, jacobian, jacobian_derivative
from hri_core.potential import TaskShape, potential_gradient, potential_hessian
from hri_core.validation import planar_vector, positive

# Largest |entry| (1/s) of the Hessian of Q. Only a potential that steps within a fraction of
# a micrometre (Table I's avoidance boundary, or dx exactly 0 for it) reaches it; there the
# exact derivative is meaningless for a sampled controller, and the cap keeps qddot_r finite.
MAX_TASK_HESSIAN = 1e6

# tanh argument above which sech^2 underflows to 0 in double precision.
_SECH_LIMIT = 350.0

# Radial integral that gives Q (monitoring only): Gauss-Legendre with 12 nodes on each of 14
# panels whose widths halve towards both ends, where dQ/dr changes steeply (the region's
# boundary; the top of an S = -1 potential, where dQ/dr flips sign).
_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(12)
_PANEL_EDGES = np.concatenate([[0.0], 2.0 ** np.arange(-7, 0), 1.0 - 2.0 ** np.arange(-2, -8, -1),
                               [1.0]])


@dataclass(frozen=True)
class DampingSettings:
    """Damping of the pseudo-inverse near singular configurations.

    threshold: w0 (m^2 for a planar arm), manipulability w = sqrt(det(J J^T)) below which
        damping starts; max_damping: lambda_max (m/rad), damping at w = 0.
    For the default SCARA (l1 = 0.35 m, l2 = 0.30 m), w = 0.105 |sin q2| m^2, so the default
    w0 = 0.05 m^2 damps within 28 deg of the stretched arm (reach > 0.63 m of 0.65 m; the
    folded side is beyond the joint limits). Smaller w0 or lambda_max let J+ and dJ+/dt grow
    so fast near the stretched arm that the 1 kHz loop chatters between torque limits when a
    target is out of reach (seen with w0 = 0.01, 0.03 m^2).
    """

    threshold: float = 0.05
    max_damping: float = 0.15

    def __post_init__(self):
        if not (math.isfinite(self.threshold) and self.threshold > 0.0):
            raise ValueError(f'damping threshold must be finite and > 0, got {self.threshold}')
        if not (math.isfinite(self.max_damping) and self.max_damping >= 0.0):
            raise ValueError(f'max_damping must be finite and >= 0, got {self.max_damping}')


@dataclass(frozen=True)
class ShapedPotential:
    """The shaped potential Q of eq. 12' for one task (see the module docstring).

    shape: the learned task; task_gain: k (m^2/s); max_task_speed: v_max (m/s);
    the radial map that shrinks the desired region by the margin is
    rho = inner_scale r below `split` (m) and rho = outer_scale r + offset (m) above it
    (identity when there is no margin); peak (m): for S = -1, the distance where Q is largest
    (dQ/dr changes sign). Build it with `shaped_potential`.
    """

    shape: TaskShape
    task_gain: float
    max_task_speed: float
    inner_scale: float = 1.0
    outer_scale: float = 1.0
    split: float = 0.0
    offset: float = 0.0
    peak: float = 0.0

    def mapped_radius(self, distance):
        """rho(r) (m): P is evaluated at rho, so Q's zero set is the shrunk region."""
        r = np.asarray(distance, dtype=float)
        return np.where(r >= self.split, self.outer_scale * r + self.offset,
                        self.inner_scale * r)

    def radial_scale(self, distance: float) -> float:
        """d(rho)/dr at r = distance."""
        return self.outer_scale if distance >= self.split else self.inner_scale

    def region(self) -> tuple[float, float]:
        """Boundaries (m) of Q's zero set [d1', d2'] (S = +1; S = -1: r <= d1', r >= d2')."""
        if self.split > 0.0:
            inner = self.shape.d1 / self.inner_scale
        else:
            inner = (self.shape.d1 - self.offset) / self.outer_scale
        return inner, (self.shape.d2 - self.offset) / self.outer_scale


@dataclass(frozen=True)
class TaskVariable:
    """Shaped task variable at one dx (eq. 12').

    distance: |dx| (m); gradient: delta_eps = dQ/d(dx), shape (2,), m/s;
    hessian: d(delta_eps)/d(dx), shape (2, 2), 1/s; radial_slope: dQ/dr (m/s).
    """

    distance: float
    gradient: np.ndarray
    hessian: np.ndarray
    radial_slope: float


@dataclass(frozen=True)
class JointReference:
    """Joint-velocity reference of eq. 14 and its time derivative (eq. 18).

    qdot_r (2,) rad/s; qddot_r (2,) rad/s^2; position x (2,) m and dx = x - x_d (2,) m;
    distance |dx| (m); task_velocity: -a delta_eps (2,) m/s, the task part of v_r;
    weighted_task_variable: a delta_eps (2,) m/s (enters the torque law, eq. 16);
    jacobian J (2, 2) m/rad; pinv J+ (2, 2) rad/m; damping lambda^2 (m^2/rad^2);
    task: the TaskVariable (None when no task is active).
    """

    qdot_r: np.ndarray
    qddot_r: np.ndarray
    position: np.ndarray
    dx: np.ndarray
    distance: float
    task_velocity: np.ndarray
    weighted_task_variable: np.ndarray
    jacobian: np.ndarray
    pinv: np.ndarray
    damping: float
    task: TaskVariable | None




def _sech_squared(x: float) -> float:
    x = abs(x)
    return 0.0 if x > _SECH_LIMIT else 1.0 / math.cosh(x) ** 2


def radial_potential_slope(distance, shape: TaskShape) -> np.ndarray:
    """dP/dr of eq. 2 at r = distance (1/m), shape (...,); capped like potential_gradient."""
    r = np.asarray(distance, dtype=float)
    if not np.all(np.isfinite(r)) or np.any(r < 0.0):
        raise ValueError('distance must be finite and >= 0 m')
    points = np.stack([r, np.zeros_like(r)], axis=-1)
    return potential_gradient(points.reshape(-1, 2), shape)[:, 0].reshape(r.shape)


def _radial_map(shape: TaskShape, region_margin: float) -> dict:
    """ShapedPotential's radial-map fields that shrink the desired region by the margin."""
    if region_margin == 0.0 or shape.d2 <= shape.d1:
        return {}
    if shape.s == 1:
        # Region [d1, d2]: scale r on each side of the middle, where P = 0.
        margin = min(region_margin, 0.25 * (shape.d2 - shape.d1))
        inner = shape.d1 / (shape.d1 + margin) if shape.d1 > 0.0 else 1.0
        return {'inner_scale': inner, 'outer_scale': shape.d2 / (shape.d2 - margin),
                'split': 0.5 * (shape.d1 + shape.d2)}
    # S = -1, region r <= d1 or r >= d2: one affine map with rho(d1 - m) = d1 and
    # rho(d2 + m) = d2; rho(0) stays in [0, d1], where P = 0, so Q is smooth at r = 0.
    if shape.d1 == 0.0:
        return {'outer_scale': shape.d2 / (shape.d2 + region_margin)}
    margin = min(region_margin, 0.25 * shape.d1)
    scale = (shape.d2 - shape.d1) / (shape.d2 - shape.d1 + 2.0 * margin)
    return {'outer_scale': scale, 'offset': shape.d1 - scale * (shape.d1 - margin)}


def _shaped_slope(radii, shaped: ShapedPotential, tanh: bool = True) -> np.ndarray:
    """dQ/dr (m/s) at the radii (n,) m; with tanh=False, d(P(rho))/dr (1/m)."""
    radii = np.asarray(radii, dtype=float)
    scale = np.where(radii >= shaped.split, shaped.outer_scale, shaped.inner_scale)
    slope_p = scale * radial_potential_slope(shaped.mapped_radius(radii), shaped.shape)
    if not tanh:
        return slope_p
    v_max = shaped.max_task_speed
    return v_max * np.tanh(shaped.task_gain * slope_p / v_max)


def shaped_potential(shape: TaskShape, max_task_speed: float, approach_distance: float,
                     region_margin: float = 0.0,
                     task_gain: float | None = None) -> ShapedPotential:
    """Shaped potential Q (eq. 12') of a task, with the task gain k chosen if not given.

    max_task_speed v_max (m/s) > 0; approach_distance (m) > 0; region_margin (m) >= 0: Q's
    zero set is the learned region shrunk by the margin at each boundary (at most a quarter of
    the region's width), so the arm, whose approach to the zero set of a gradient field is
    only asymptotic, enters the learned region in finite time. P is evaluated at a mapped
    radius rho(r): for S = +1, rho = r d2 / (d2 - margin) above the middle of the region and
    r d1 / (d1 + margin) below it (P is zero in between, so Q stays C2); for S = -1, one
    affine map with rho(d1 - margin) = d1, rho(d2 + margin) = d2. task_gain k (m^2/s), or
    None: k = v_max / min |d(P(rho))/dr| over the probes r = d1' -+ approach_distance,
    d2' -+ approach_distance outside Q's zero set, so that the reference speed is
    >= tanh(1) v_max = 0.76 v_max at the approach distance from every boundary.
    Raises ValueError for bad values or when no probe sees a slope.
    """
    v_max = positive(max_task_speed, 'max_task_speed', 'm/s')
    delta = positive(approach_distance, 'approach_distance', 'm')
    if not (math.isfinite(region_margin) and region_margin >= 0.0):
        raise ValueError(f'region_margin must be finite and >= 0 m, got {region_margin}')
    radial_map = _radial_map(shape, region_margin)
    if shape.s == -1 and shape.d2 > shape.d1:
        radial_map['peak'] = _potential_peak(ShapedPotential(shape, 1.0, v_max, **radial_map))
    if task_gain is not None:
        return ShapedPotential(shape, positive(task_gain, 'task_gain', 'm^2/s'), v_max,
                               **radial_map)
    unit = ShapedPotential(shape, 1.0, v_max, **radial_map)
    d1, d2 = unit.region()
    probes = np.array([d1 - delta, d1 + delta, d2 - delta, d2 + delta])
    probes = probes[probes > 0.0]
    slopes = np.abs(_shaped_slope(probes, unit, tanh=False))
    slopes = slopes[(slopes > 0.0) & np.isfinite(slopes)]
    if slopes.size == 0:
        raise ValueError(
            f'the potential is flat within {delta} m of its region boundaries '
            f'(d1={shape.d1}, d2={shape.d2}): no task gain makes it move the arm')
    return ShapedPotential(shape, v_max / float(np.min(slopes)), v_max, **radial_map)


def task_variable(dx, shaped: ShapedPotential) -> TaskVariable:
    """Shaped task variable delta_eps = dQ/d(dx) and its Hessian (eq. 12', 18).

    dx (2,) m. The gradient is (dQ/dr) e with dQ/dr = v_max tanh(k c dP/d(rho) / v_max),
    rho the mapped radius, c = d(rho)/dr; the Hessian is Q'' e e^T + (Q'/r)(I - e e^T) with
    Q'' = k c^2 (d2P/d(rho)2) sech^2(k c dP/d(rho) / v_max), entries bounded by
    MAX_TASK_HESSIAN. Zero on Q's zero set.
    """
    dx = planar_vector(dx, 'dx')
    k, v_max = shaped.task_gain, shaped.max_task_speed
    r = math.hypot(dx[0], dx[1])
    if r == 0.0:
        # Radial symmetry: zero gradient; Hessian Q''(0) I (rho(0) is 0 or inside the region).
        c = shaped.radial_scale(0.0)
        axis = np.array([float(shaped.mapped_radius(0.0)), 0.0])
        argument = k * c * float(potential_gradient(axis, shaped.shape)[0]) / v_max
        curvature = k * c * c * float(potential_hessian(axis, shaped.shape)[0, 0])
        curvature = float(np.clip(curvature * _sech_squared(argument), -MAX_TASK_HESSIAN,
                                  MAX_TASK_HESSIAN))
        return TaskVariable(0.0, np.zeros(2), curvature * np.eye(2), 0.0)
    e = dx / r
    c = shaped.radial_scale(r)
    mapped = float(shaped.mapped_radius(r)) * e
    slope_p = c * float(potential_gradient(mapped, shaped.shape) @ e)
    argument = k * slope_p / v_max
    slope = v_max * math.tanh(argument)
    sech2 = _sech_squared(argument)
    curvature = 0.0
    if sech2 > 0.0:
        curvature_p = c * c * float(e @ potential_hessian(mapped, shaped.shape) @ e)
        curvature = k * curvature_p * sech2
    radial = np.outer(e, e)
    hessian = curvature * radial + (slope / r) * (np.eye(2) - radial)
    hessian = np.clip(hessian, -MAX_TASK_HESSIAN, MAX_TASK_HESSIAN)
    return TaskVariable(r, slope * e, hessian, slope)


def task_term(dx1: float, dx2: float,
              shaped: ShapedPotential) -> tuple[float, float, float, float, float]:
    """`task_variable` for one dx in plain floats, the controller's per-cycle path (eq. 12').

    dx1, dx2: dx (m), finite (checked by the caller at its boundary). Returns (g1, g2, h11,
    h12, h22): delta_eps = dQ/d(dx) (m/s) and the entries of its symmetric Hessian (1/s), equal
    to `task_variable` (its reference) to rounding. The only place the control step evaluates
    the task's potential: a different task term changes this function alone.
    """
    k, v_max, shape = shaped.task_gain, shaped.max_task_speed, shaped.shape
    r = math.hypot(dx1, dx2)
    if r == 0.0:
        task = task_variable((dx1, dx2), shaped)
        hessian = task.hessian
        return 0.0, 0.0, float(hessian[0, 0]), float(hessian[0, 1]), float(hessian[1, 1])
    e1, e2 = dx1 / r, dx2 / r
    if r >= shaped.split:
        c, rho = shaped.outer_scale, shaped.outer_scale * r + shaped.offset
    else:
        c, rho = shaped.inner_scale, shaped.inner_scale * r
    mapped = (rho * e1, rho * e2)
    g1, g2 = potential_gradient(mapped, shape).tolist()
    argument = k * (c * (g1 * e1 + g2 * e2)) / v_max
    slope = v_max * math.tanh(argument)
    sech2 = _sech_squared(argument)
    curvature = 0.0
    if sech2 > 0.0:
        (p11, p12), (p21, p22) = potential_hessian(mapped, shape).tolist()
        curvature_p = c * c * ((e1 * p11 + e2 * p21) * e1 + (e1 * p12 + e2 * p22) * e2)
        curvature = k * curvature_p * sech2
    tangential = slope / r
    h11 = curvature * e1 * e1 + tangential * (1.0 - e1 * e1)
    h12 = curvature * e1 * e2 - tangential * e1 * e2
    h22 = curvature * e2 * e2 + tangential * (1.0 - e2 * e2)
    return (slope * e1, slope * e2, _clip_hessian(h11), _clip_hessian(h12), _clip_hessian(h22))


def _clip_hessian(value: float) -> float:
    return -MAX_TASK_HESSIAN if value < -MAX_TASK_HESSIAN else min(value, MAX_TASK_HESSIAN)


def task_potential(distance: float, shaped: ShapedPotential) -> float:
    """Shaped potential Q at r = distance (m^2/s), the P of eq. 21 for this controller.

    Q(r) is the integral of dQ/dr from the boundary of Q's zero set to r (composite
    Gauss-Legendre, panels refined towards the boundary): for S = +1, from d2' outward or from
    d1' inward, so Q >= 0 and Q = 0 on the (shrunk) region; for S = -1 (region r <= d1' or
    r >= d2'), from d1' (Q is then constant, possibly non-zero, beyond d2'). Equals k P where
    k |dP/dr| << v_max. Used for monitoring V.
    """
    r = float(distance)
    if not (math.isfinite(r) and r >= 0.0):
        raise ValueError(f'distance must be finite and >= 0 m, got {distance}')
    d1, d2 = shaped.region()
    if shaped.shape.s == 1:
        if r > d2:
            return abs(_radial_integral(shaped, d2, r))
        if r < d1:
            return abs(_radial_integral(shaped, d1, r))
        return 0.0
    if r <= d1:
        return 0.0
    if r <= shaped.peak:
        return _radial_integral(shaped, d1, r)
    return (_radial_integral(shaped, d1, shaped.peak)
            + _radial_integral(shaped, shaped.peak, min(r, d2)))


def _potential_peak(shaped: ShapedPotential) -> float:
    """Distance (m) in (d1', d2') where d(P(rho))/dr changes sign (S = -1 potentials)."""
    d1, d2 = shaped.region()
    radii = np.linspace(d1, d2, 513)[1:-1]
    slopes = _shaped_slope(radii, shaped, tanh=False)
    change = np.flatnonzero((slopes[:-1] > 0.0) & (slopes[1:] <= 0.0))
    if change.size == 0:
        return d2
    # Imported here: scipy.optimize costs the controller half a second at start-up, and only
    # S = -1 tasks need it.
    from scipy.optimize import brentq
    return float(brentq(lambda r: float(_shaped_slope(np.array([r]), shaped, tanh=False)[0]),
                        radii[change[0]], radii[change[0] + 1]))


def _radial_integral(shaped: ShapedPotential, start: float, end: float) -> float:
    """Integral of dQ/dr from `start` (a boundary of the zero set) to `end` (m^2/s)."""
    edges = start + (end - start) * _PANEL_EDGES
    half = 0.5 * np.diff(edges)
    centre = 0.5 * (edges[1:] + edges[:-1])
    radii = centre[:, None] + half[:, None] * _GAUSS_NODES[None, :]
    slopes = _shaped_slope(radii.ravel(), shaped).reshape(radii.shape)
    return float(np.sum(half[:, None] * _GAUSS_WEIGHTS[None, :] * slopes))


def _gram_damping(gram: np.ndarray, settings: DampingSettings) -> tuple[float, float]:
    """(lambda^2, d(lambda^2)/d(w^2)) from the Gram matrix J J^T (2, 2)."""
    w2 = gram[0, 0] * gram[1, 1] - gram[0, 1] * gram[1, 0]
    threshold2 = settings.threshold ** 2
    ratio = w2 / threshold2
    if ratio >= 1.0:
        return 0.0, 0.0
    lam2 = settings.max_damping ** 2
    return lam2 * (1.0 - ratio) ** 2, -2.0 * lam2 * (1.0 - ratio) / threshold2


def _inverse_2x2(matrix: np.ndarray) -> np.ndarray:
    det = matrix[0, 0] * matrix[1, 1] - matrix[0, 1] * matrix[1, 0]
    if abs(det) <= 1e-300:
        raise ValueError('singular Jacobian and no damping (max_damping = 0)')
    return np.array([[matrix[1, 1], -matrix[0, 1]], [-matrix[1, 0], matrix[0, 0]]]) / det


def _checked_jacobian(jac) -> np.ndarray:
    jac = np.asarray(jac, dtype=float)
    if jac.ndim != 2 or jac.shape[0] != 2 or not np.all(np.isfinite(jac)):
        raise ValueError(f'jacobian must be a finite (2, n) array, got {jac}')
    return jac


def pseudo_inverse_damping(jac, settings: DampingSettings) -> tuple[float, float]:
    """Damping lambda^2 of the pseudo-inverse and d(lambda^2)/d(w^2), w^2 = det(J J^T).

    jac (2, n) in m/rad. lambda^2 = lambda_max^2 (1 - w^2/w0^2)^2 below w0, 0 above
    (C1 across w0). Returns (lambda^2 in m^2/rad^2, d(lambda^2)/d(w^2) in rad^2/m^2).
    """
    jac = _checked_jacobian(jac)
    return _gram_damping(jac @ jac.T, settings)


def damped_pseudo_inverse(jac, settings: DampingSettings) -> tuple[np.ndarray, float]:
    """Damped pseudo-inverse J+ = J^T (J J^T + lambda^2 I)^-1 of eq. 14.

    jac (2, n) in m/rad. Returns (J+ of shape (n, 2) in rad/m, lambda^2 in m^2/rad^2). Equal to
    the exact inverse for a square J with w >= threshold. Raises ValueError for a non-finite J
    or a singular J with max_damping = 0.
    """
    jac = _checked_jacobian(jac)
    gram = jac @ jac.T
    lam2, _ = _gram_damping(gram, settings)
    return jac.T @ _inverse_2x2(gram + lam2 * np.eye(2)), lam2


def damped_pseudo_inverse_derivative(jac, jac_dot, settings: DampingSettings) -> np.ndarray:
    """Exact time derivative dJ+/dt of the damped pseudo-inverse (rad/(m s)), shape (n, 2).

    With A = J J^T + lambda^2 I: dJ+/dt = Jdot^T A^-1 - J^T A^-1 Adot A^-1, where
    Adot = Jdot J^T + J Jdot^T + d(lambda^2)/dt I and d(lambda^2)/dt = d(lambda^2)/d(w^2)
    tr(adj(J J^T) (Jdot J^T + J Jdot^T)). jac, jac_dot (2, n): J (m/rad), dJ/dt (m/(rad s)).
    """
    return _pseudo_inverse_and_derivative(jac, jac_dot, settings)[2]


def _pseudo_inverse_and_derivative(jac, jac_dot, settings: DampingSettings):
    """(J+, lambda^2, dJ+/dt) in one pass (see damped_pseudo_inverse_derivative)."""
    jac = _checked_jacobian(jac)
    jac_dot = np.asarray(jac_dot, dtype=float)
    if jac_dot.shape != jac.shape or not np.all(np.isfinite(jac_dot)):
        raise ValueError(f'jacobian derivative must be finite with shape {jac.shape}')
    gram = jac @ jac.T
    lam2, dlam2_dw2 = _gram_damping(gram, settings)
    a_inv = _inverse_2x2(gram + lam2 * np.eye(2))
    pinv = jac.T @ a_inv
    gram_dot = jac_dot @ jac.T + jac @ jac_dot.T
    # d det(G)/dt = tr(adj(G) dG/dt) for a 2 x 2 G.
    w2_dot = (gram[1, 1] * gram_dot[0, 0] + gram[0, 0] * gram_dot[1, 1]
              - gram[0, 1] * gram_dot[1, 0] - gram[1, 0] * gram_dot[0, 1])
    a_dot = gram_dot + (dlam2_dw2 * w2_dot) * np.eye(2)
    return pinv, lam2, jac_dot.T @ a_inv - pinv @ a_dot @ a_inv


def joint_velocity_reference(q, dq, x_d, xdot_d, xddot_d, weight: float, weight_rate: float,
                             shaped: ShapedPotential | None, l1: float, l2: float,
                             damping: DampingSettings = DampingSettings()) -> JointReference:
    """qdot_r of eq. 14 and its exact time derivative qddot_r (eq. 18).

    q, dq (2,): joint positions (rad) and velocities (rad/s); x_d, xdot_d, xddot_d (2,): the
    target (centre of the desired region) in m, m/s, m/s^2; weight a(E, t) in [0, 1] and
    weight_rate da/dt (1/s) from event_weight; shaped: the active task's ShapedPotential, or
    None (no task: the reference only follows xdot_d); l1, l2 link lengths (m); damping of J+.
    Raises ValueError for non-finite inputs or a weight outside [0, 1].
    """
    q, dq = planar_vector(q, 'q'), planar_vector(dq, 'dq')
    x_d, xdot_d = planar_vector(x_d, 'x_d', 'm'), planar_vector(xdot_d, 'xdot_d', 'm/s')
    xddot_d = planar_vector(xddot_d, 'xddot_d', 'm/s^2')
    if not (math.isfinite(weight) and 0.0 <= weight <= 1.0):
        raise ValueError(f'weight a(E, t) must be in [0, 1], got {weight}')
    if not math.isfinite(weight_rate):
        raise ValueError(f'weight_rate must be finite, got {weight_rate}')
    jac = jacobian(q, l1, l2)
    jac_dot = jacobian_derivative(q, dq, l1, l2)
    pinv, lam2, pinv_dot = _pseudo_inverse_and_derivative(jac, jac_dot, damping)
    x = forward_kinematics(q, l1, l2)
    dx = x - x_d
    distance = float(math.hypot(dx[0], dx[1]))
    if shaped is None:
        task = None
        weighted = np.zeros(2)
        weighted_dot = np.zeros(2)
    else:
        task = task_variable(dx, shaped)
        weighted = weight * task.gradient
        relative_velocity = jac @ dq - xdot_d
        weighted_dot = weight_rate * task.gradient + weight * (task.hessian @ relative_velocity)
    v_r = xdot_d - weighted
    v_r_dot = xddot_d - weighted_dot
    qdot_r = pinv @ v_r
    qddot_r = pinv_dot @ v_r + pinv @ v_r_dot
    return JointReference(
        qdot_r=qdot_r, qddot_r=qddot_r, position=x, dx=dx, distance=distance,
        task_velocity=-weighted, weighted_task_variable=weighted, jacobian=jac, pinv=pinv,
        damping=lam2, task=task)
