"""Task function y(z) and dynamic potential P(z) of a learned HRI task (paper eq. 1, 2).

    y(z) = S (1 - exp(-a1 (|z|^2 - d1^2))) (1 - exp(-a2 (|z|^2 - d2^2)))      (eq. 1)
    P(z) = max(0, y(z))^N                                                      (eq. 2)

z = dx is the planar position error (m), a1, a2 in 1/m^2, d1, d2 in m. P depends on z only
through u = |z|^2, so with P'(u) = dP/du and P''(u) = d^2P/du^2:

    dP/dz = 2 P'(u) z,    d^2P/dz^2 = 2 P'(u) I + 4 P''(u) z z^T.

Numerics. The factors grow like exp(a d^2): Table I's avoidance row gives P(0) ~ 1e124 and a fit
trial step with a = 1e3, d2 = 2 m gives exp(4000), which overflows a double. Every quantity is
therefore computed as a logarithm of its magnitude plus a sign, using

    f_i = 1 - exp(t_i), t_i = -a_i (u - d_i^2),   log|f_i| = max(t_i, 0) + log(-expm1(-|t_i|)),
    rho_i = f_i'/f_i = a_i / expm1(-t_i),   P' = N P (rho_1 + rho_2),
    P'' = N P [(N-1)(rho_1 + rho_2)^2 + 2 rho_1 rho_2 - a_1 rho_1 - a_2 rho_2],

and only the final magnitude is exponentiated, capped at ``POTENTIAL_CEILING`` (1e100): y and P
are capped at 1e100 in magnitude, the gradient's Euclidean norm at 1e100 (its direction kept), and
the Hessian is scaled as a whole so that no entry exceeds 1e100. A product of two capped values is
still finite (<= 1e200). ``log_potential`` returns the uncapped log P for callers (the fit) that
need exact ratios of huge values. Nothing returned is ever inf or NaN.

The controller calls ``potential_gradient`` and ``potential_hessian`` at 1 kHz for one (2,) vector;
that case runs on plain Python floats (no numpy ufunc overhead).
"""

import math
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np

POTENTIAL_CEILING = 1e100
"""Largest magnitude returned for y, P, |dP/dz| and any Hessian entry (see module docstring)."""

LOG_POTENTIAL_CEILING = math.log(POTENTIAL_CEILING)

_LOG2 = math.log(2.0)
_LOG4 = math.log(4.0)
_NEG_INF = -math.inf


@dataclass(frozen=True)
class TaskShape:
    """Task parameters of eq. 1, 2: the shape of the dynamic potential.

    s: +1 (desired region d1 <= |z| <= d2) or -1 (desired region |z| <= d1 or |z| >= d2);
    a1, a2: steepness, 1/m^2, > 0; d1 <= d2: region boundaries, m, >= 0; n: exponent N >= 3
    (P is then at least twice differentiable).
    Raises ValueError with the reason when a value is invalid.
    """

    s: int
    a1: float
    a2: float
    d1: float
    d2: float
    n: int = 3

    def __post_init__(self):
        for key in ('s', 'n'):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, Integral):
                raise ValueError(f'{key} must be an integer, got {value!r}')
            object.__setattr__(self, key, int(value))
        for key in ('a1', 'a2', 'd1', 'd2'):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, Real):
                raise ValueError(f'{key} must be a real number, got {value!r}')
            if not math.isfinite(value):
                raise ValueError(f'{key} must be finite, got {value!r}')
            object.__setattr__(self, key, float(value))
        if self.s not in (1, -1):
            raise ValueError(f's must be +1 or -1, got {self.s}')
        if self.a1 <= 0.0 or self.a2 <= 0.0:
            raise ValueError(f'a1 and a2 must be > 0, got a1={self.a1}, a2={self.a2}')
        if self.d1 < 0.0 or self.d2 < 0.0:
            raise ValueError(f'd1 and d2 must be >= 0, got d1={self.d1}, d2={self.d2}')
        if self.d1 > self.d2:
            raise ValueError(f'd1 must be <= d2, got d1={self.d1}, d2={self.d2}')
        if self.n < 3:
            raise ValueError(f'n must be >= 3 (P twice differentiable), got {self.n}')


# ---------------------------------------------------------------------------------------------
# Scalar path (one point, plain floats).

def _signed_log_sum2(log_a, sign_a, log_b, sign_b):
    """(log|sum|, sign(sum)) of sign_a exp(log_a) + sign_b exp(log_b) (one rounded addition,
    as fsum's). Two terms spelled out: the controller's per-cycle path."""
    top = max(log_a, log_b)
    if top == _NEG_INF:
        return _NEG_INF, 0
    total = sign_a * math.exp(log_a - top) + sign_b * math.exp(log_b - top)
    if total == 0.0:
        return _NEG_INF, 0
    return top + math.log(abs(total)), (1 if total > 0.0 else -1)


def _radial_log_terms(u, shape):
    """Log-magnitudes and signs of P, P'(u), P''(u) at u = |z|^2 (floats; eq. 2).

    Returns (log P, log|P'|, sign P', log|P''|, sign P''); log P = -inf where y <= 0.
    """
    t1 = -shape.a1 * (u - shape.d1 * shape.d1)
    t2 = -shape.a2 * (u - shape.d2 * shape.d2)
    # sign(f_i) = -sign(t_i), so y > 0 iff s sign(t1) sign(t2) > 0.
    if t1 == 0.0 or t2 == 0.0 or ((t1 > 0.0) == (t2 > 0.0)) != (shape.s == 1):
        return _NEG_INF, _NEG_INF, 0, _NEG_INF, 0
    q1 = math.log(-math.expm1(-abs(t1)))
    q2 = math.log(-math.expm1(-abs(t2)))
    log_p = shape.n * (max(t1, 0.0) + q1 + max(t2, 0.0) + q2)
    log_a1 = math.log(shape.a1)
    log_a2 = math.log(shape.a2)
    # log|rho_i| = log a_i - log|expm1(-t_i)|, sign(rho_i) = sign(f_i) = -sign(t_i).
    l1 = log_a1 - max(-t1, 0.0) - q1
    l2 = log_a2 - max(-t2, 0.0) - q2
    s1 = -1 if t1 > 0.0 else 1
    s2 = -1 if t2 > 0.0 else 1
    l_sum, s_sum = _signed_log_sum2(l1, s1, l2, s2)
    # The bracket (n-1)(rho1^2 + rho2^2) + 2n rho1 rho2 - a1 rho1 - a2 rho2 from the logs of
    # its five terms, summed exactly (fsum) after scaling by the largest.
    log_nm1 = math.log(shape.n - 1)
    b1, b2 = log_nm1 + 2.0 * l1, log_nm1 + 2.0 * l2
    b3 = math.log(2 * shape.n) + l1 + l2
    b4, b5 = log_a1 + l1, log_a2 + l2
    top = max(b1, b2, b3, b4, b5)
    total = 0.0 if top == _NEG_INF else math.fsum((
        math.exp(b1 - top), math.exp(b2 - top), s1 * s2 * math.exp(b3 - top),
        -s1 * math.exp(b4 - top), -s2 * math.exp(b5 - top)))
    if total == 0.0:
        l_bracket, s_bracket = _NEG_INF, 0
    else:
        l_bracket, s_bracket = top + math.log(abs(total)), (1 if total > 0.0 else -1)
    log_n = math.log(shape.n)
    return (log_p, log_n + log_p + l_sum, s_sum, log_n + log_p + l_bracket, s_bracket)


def _check_point(dx):
    x, y = float(dx[0]), float(dx[1])
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f'dx must be finite, got {dx!r}')
    return x, y


def _gradient_point(dx, shape):
    x, y = _check_point(dx)
    r = math.hypot(x, y)
    if r == 0.0:
        return np.zeros(2)
    _, l_d1, s_d1, _, _ = _radial_log_terms(r * r, shape)
    if s_d1 == 0:
        return np.zeros(2)
    norm = min(math.exp(min(_LOG2 + l_d1 + math.log(r), LOG_POTENTIAL_CEILING)),
               POTENTIAL_CEILING)
    # Unit vector first: norm / r could overflow for a tiny r.
    return np.array((s_d1 * norm * (x / r), s_d1 * norm * (y / r)))


def _hessian_point(dx, shape):
    x, y = _check_point(dx)
    r = math.hypot(x, y)
    _, l_d1, s_d1, l_d2, s_d2 = _radial_log_terms(r * r, shape)
    # H = alpha I + beta e e^T with e = z/|z|, alpha = 2 P', beta = 4 P'' |z|^2.
    l_alpha = _LOG2 + l_d1
    l_beta = _LOG4 + l_d2 + 2.0 * math.log(r) if r > 0.0 else _NEG_INF
    top = max(l_alpha, l_beta)
    if top == _NEG_INF:
        return np.zeros((2, 2))
    shift = min(0.0, LOG_POTENTIAL_CEILING - _LOG2 - top)
    alpha = s_d1 * math.exp(l_alpha + shift)
    if r == 0.0:
        hessian = np.array(((alpha, 0.0), (0.0, alpha)))
    else:
        beta = s_d2 * math.exp(l_beta + shift)
        ex, ey = x / r, y / r
        off = beta * ex * ey
        hessian = np.array(((alpha + beta * ex * ex, off), (off, alpha + beta * ey * ey)))
    # exp(log(cap)) may exceed the cap by an ulp: trim.
    return np.clip(hessian, -POTENTIAL_CEILING, POTENTIAL_CEILING)


def log_radial_slopes(distance: float, shape: TaskShape) -> tuple[float, int, float, int]:
    """log|dP/dr|, sign, log|d2P/dr2|, sign of eq. 2 at r = distance (m), uncapped (floats).

    dP/dr = 2 r P'(r^2) (1/m), d2P/dr2 = 2 P'(r^2) + 4 r^2 P''(r^2) (1/m^2), both from
    logarithms, so exact where the capped `potential_gradient` is not (Table I's avoid row:
    |dP/dr| ~ 1e125). A zero value is (-inf, 0). distance must be finite and >= 0 (the
    controller's per-cycle path: no check).
    """
    r = distance
    _, l_d1, s_d1, l_d2, s_d2 = _radial_log_terms(r * r, shape)
    if s_d1 == 0 and s_d2 == 0:
        return _NEG_INF, 0, _NEG_INF, 0
    log_r = math.log(r) if r > 0.0 else _NEG_INF
    l_slope = _LOG2 + log_r + l_d1 if s_d1 != 0 else _NEG_INF
    l_curv, s_curv = _signed_log_sum2(_LOG2 + l_d1, s_d1, _LOG4 + 2.0 * log_r + l_d2, s_d2)
    return l_slope, (s_d1 if l_slope > _NEG_INF else 0), l_curv, s_curv


# ---------------------------------------------------------------------------------------------
# Array path (any leading dimensions).

def _as_distance(distance):
    d = np.asarray(distance, dtype=float)
    if not np.all(np.isfinite(d)):
        raise ValueError('distance must be finite')
    if np.any(d < 0.0):
        raise ValueError('distance must be >= 0 (it is a norm |z|)')
    return d


def _as_displacement(dx):
    z = np.asarray(dx, dtype=float)
    if z.ndim == 0 or z.shape[-1] != 2:
        raise ValueError(f'dx must have shape (..., 2), got {z.shape}')
    if not np.all(np.isfinite(z)):
        raise ValueError('dx must be finite')
    return z


def _log_abs_factors(u, shape):
    """t_i, log|f_i| = log|1 - exp(t_i)| (arrays; -inf where t_i = 0)."""
    t1 = -shape.a1 * (u - shape.d1 ** 2)
    t2 = -shape.a2 * (u - shape.d2 ** 2)
    with np.errstate(divide='ignore'):
        q1 = np.log(-np.expm1(-np.abs(t1)))
        q2 = np.log(-np.expm1(-np.abs(t2)))
    return t1, t2, q1, q2


def _signed_log_sum_array(logs, signs):
    """Signed log sum (_signed_log_sum2) of any number of terms, stacked along axis 0."""
    top = np.max(logs, axis=0)
    safe_top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(invalid='ignore', over='ignore'):
        total = np.sum(signs * np.exp(logs - safe_top), axis=0)
    finite = np.isfinite(top) & (total != 0.0) & np.isfinite(total)
    with np.errstate(divide='ignore', invalid='ignore'):
        log_abs = np.where(finite, safe_top + np.log(np.abs(total)), -np.inf)
    return log_abs, np.where(finite, np.sign(total), 0.0)


def _radial_log_terms_array(u, shape):
    """Array version of _radial_log_terms (same outputs, same shapes as u)."""
    t1, t2, q1, q2 = _log_abs_factors(u, shape)
    positive = (t1 != 0.0) & (t2 != 0.0) & (shape.s * np.sign(t1) * np.sign(t2) > 0.0)
    log_p = np.where(positive, shape.n * (np.maximum(t1, 0.0) + q1 + np.maximum(t2, 0.0) + q2),
                     -np.inf)
    log_a1, log_a2 = math.log(shape.a1), math.log(shape.a2)
    # Where t_i = 0 these are +inf; such points are not `positive` and are masked below.
    l1 = np.where(positive, log_a1 - np.maximum(-t1, 0.0) - q1, -np.inf)
    l2 = np.where(positive, log_a2 - np.maximum(-t2, 0.0) - q2, -np.inf)
    s1 = np.where(t1 > 0.0, -1.0, 1.0)
    s2 = np.where(t2 > 0.0, -1.0, 1.0)
    l_sum, s_sum = _signed_log_sum_array(np.stack((l1, l2)), np.stack((s1, s2)))
    log_nm1 = math.log(shape.n - 1)
    l_bracket, s_bracket = _signed_log_sum_array(
        np.stack((log_nm1 + 2.0 * l1, log_nm1 + 2.0 * l2, math.log(2 * shape.n) + l1 + l2,
                  log_a1 + l1, log_a2 + l2)),
        np.stack((np.ones_like(s1), np.ones_like(s1), s1 * s2, -s1, -s2)))
    log_n = math.log(shape.n)
    return log_p, log_n + log_p + l_sum, s_sum, log_n + log_p + l_bracket, s_bracket


def _capped_exp(log_value):
    """exp(log_value) capped at POTENTIAL_CEILING (exp(log(cap)) can exceed it by an ulp)."""
    return np.minimum(np.exp(np.minimum(log_value, LOG_POTENTIAL_CEILING)), POTENTIAL_CEILING)


# ---------------------------------------------------------------------------------------------
# Public API.

def task_function(distance, shape):
    """Task function y of eq. 1 at |z| = distance.

    distance: (...,) m, >= 0; shape: TaskShape. Returns y (...,), dimensionless, with its
    magnitude capped at POTENTIAL_CEILING (1e100). Raises ValueError for negative or non-finite
    distances.
    """
    d = _as_distance(distance)
    t1, t2, q1, q2 = _log_abs_factors(d * d, shape)
    log_abs = np.maximum(t1, 0.0) + q1 + np.maximum(t2, 0.0) + q2
    sign = shape.s * np.sign(t1) * np.sign(t2)
    return sign * _capped_exp(log_abs)


def log_potential(distance, shape):
    """Natural logarithm of the dynamic potential P of eq. 2, uncapped.

    distance: (...,) m, >= 0. Returns log P (...,), -inf where P = 0 (y <= 0), otherwise
    N (log|f1| + log|f2|) computed without overflow for any a, d. Use this, not
    ``potential``, to form ratios such as P / ||P|| (eq. 7) when P may exceed the cap.
    """
    d = _as_distance(distance)
    t1, t2, q1, q2 = _log_abs_factors(d * d, shape)
    positive = (t1 != 0.0) & (t2 != 0.0) & (shape.s * np.sign(t1) * np.sign(t2) > 0.0)
    return np.where(positive, shape.n * (np.maximum(t1, 0.0) + q1 + np.maximum(t2, 0.0) + q2),
                    -np.inf)


def potential(distance, shape):
    """Dynamic potential P = max(0, y)^N of eq. 2 at |z| = distance.

    distance: (...,) m, >= 0. Returns P (...,) >= 0, capped at POTENTIAL_CEILING (1e100);
    never inf or NaN. (Table I's avoidance row has an uncapped P(0) of about 1e124.)
    """
    return _capped_exp(log_potential(distance, shape))


def normalised_potential(distance, shape):
    """Normalised potential P/||P|| over a set of samples (eq. 6, 7).

    distance: (N,) m. Returns (N,), unit Euclidean norm, computed from log P so that it is exact
    even where P exceeds the cap; all zeros when P is zero on every sample.
    """
    log_p = log_potential(distance, shape)
    if not np.any(np.isfinite(log_p)):
        return np.zeros_like(log_p)
    scaled = np.exp(log_p - np.max(log_p))
    return scaled / np.linalg.norm(scaled)


def potential_gradient(dx, shape):
    """Gradient dP/d(dx) = 2 P'(|dx|^2) dx, the task variable delta-epsilon of eq. 12.

    dx: (..., 2) m. Returns (..., 2) in 1/m. Its Euclidean norm is capped at
    POTENTIAL_CEILING (1e100) with the direction kept; it is 0 at dx = 0 (radial symmetry) and
    finite everywhere. A single (2,) input takes a fast scalar path.
    """
    if np.shape(dx) == (2,):
        return _gradient_point(dx, shape)
    z = _as_displacement(dx)
    r = np.hypot(z[..., 0], z[..., 1])
    _, l_d1, s_d1, _, _ = _radial_log_terms_array(r * r, shape)
    with np.errstate(divide='ignore'):
        log_norm = _LOG2 + l_d1 + np.log(r)
    norm = s_d1 * _capped_exp(log_norm)
    safe_r = np.where(r > 0.0, r, 1.0)
    unit = np.where((r > 0.0)[..., None], z / safe_r[..., None], 0.0)
    return norm[..., None] * unit


def potential_hessian(dx, shape):
    """Hessian d^2P/d(dx)^2 = 2 P' I + 4 P'' dx dx^T (used for q_r double-dot, eq. 18).

    dx: (..., 2) m. Returns (..., 2, 2) in 1/m^2, symmetric. Where an entry would exceed
    POTENTIAL_CEILING (1e100) the whole matrix is scaled down so that none does (eigenvectors
    and the ratio of eigenvalues kept). Finite everywhere, including dx = 0.
    A single (2,) input takes a fast scalar path.
    """
    if np.shape(dx) == (2,):
        return _hessian_point(dx, shape)
    z = _as_displacement(dx)
    r = np.hypot(z[..., 0], z[..., 1])
    _, l_d1, s_d1, l_d2, s_d2 = _radial_log_terms_array(r * r, shape)
    l_alpha = _LOG2 + l_d1
    with np.errstate(divide='ignore'):
        l_beta = _LOG4 + l_d2 + 2.0 * np.log(r)
    l_beta = np.where(r > 0.0, l_beta, -np.inf)
    top = np.maximum(l_alpha, l_beta)
    shift = np.where(np.isfinite(top), np.minimum(0.0, LOG_POTENTIAL_CEILING - _LOG2 - top), 0.0)
    alpha = s_d1 * np.exp(l_alpha + shift)
    beta = s_d2 * np.exp(l_beta + shift)
    safe_r = np.where(r > 0.0, r, 1.0)
    e = np.where((r > 0.0)[..., None], z / safe_r[..., None], 0.0)
    outer = e[..., :, None] * e[..., None, :]
    hessian = alpha[..., None, None] * np.eye(2) + beta[..., None, None] * outer
    return np.clip(hessian, -POTENTIAL_CEILING, POTENTIAL_CEILING)


# ---------------------------------------------------------------------------------------------
# Task gain K and reach (the pull K |dP/dz| a task exerts, in m/s).

PULL_FRACTION = 0.05
"""A task's pull K |dP/dz| below this fraction of min(the controller's max_task_speed, its own
strongest pull within reach) counts as vanished (the reach criterion, `reach_shortfall`)."""

PULL_ONSET = 0.15
"""m: the reach criterion starts this far outside the region. Every P of eq. 2 rises from its
zero set like (r - d)^N, so near the region its pull is weak by construction (the approach,
where the arm slows down; the controller's region margin takes it in); what the criterion
catches is a pull that dies *far* from the region, where P has saturated."""

_REACH_PROBES = 400


def log_potential_slope(distance, shape):
    """log |dP/dr| of eq. 2 at r = distance (m), uncapped; -inf where the slope is 0.

    distance: (...,) m, >= 0. Returns (...,) of log(1/m). dP/dr = 2 r P'(r^2) is |dP/dz|, the
    magnitude of the gradient of the radial potential; computed from logarithms, so it is exact
    where the capped ``potential_gradient`` is not (Table I's avoid row near x_r).
    """
    return signed_log_potential_slope(distance, shape)[0]


def signed_log_potential_slope(distance, shape):
    """(log |dP/dr|, sign of dP/dr) of eq. 2 at r = distance (m), in one evaluation.

    distance: (...,) m, >= 0. Returns two arrays (...,): log(1/m) as ``log_potential_slope``
    (-inf where the slope is 0) and the sign (-1, 0 or +1) of the uncapped dP/dr.
    """
    d = _as_distance(distance)
    _, l_d1, s_d1, _, _ = _radial_log_terms_array(d * d, shape)
    with np.errstate(divide='ignore'):
        log_slope = np.where(d > 0.0, _LOG2 + np.log(np.where(d > 0.0, d, 1.0)) + l_d1,
                             -np.inf)
    return log_slope, np.where(np.isfinite(log_slope), s_d1, 0.0)


def _reach_band(shape, reach, onset):
    """(start, end) (m) of the distances the reach criterion checks, or None (see
    `reach_shortfall`)."""
    if shape.s != 1:
        return None
    start, end = shape.d2 + onset, min(shape.d2 + reach, 2.0 * reach)
    return (start, end) if end > start else None


def default_task_gain(shape, max_task_speed, reach, onset=PULL_ONSET):
    """log of the task gain K (m^2/s) of a task that was given none (a file without `k`, k = 0).

    K = max_task_speed / min |dP/dr| over the distances `onset` (m) outside the region's
    boundaries that the arm can be at (<= 2 reach, m): the pull there, at the weaker boundary,
    is max_task_speed (m/s). Returns log K, since K itself may lie outside a double's range for
    a potential as steep as Table I's avoid row. Raises ValueError when P is flat (zero slope)
    at every such distance.
    """
    if shape.s == 1:
        probes = [shape.d2 + onset, shape.d1 - min(onset, 0.5 * shape.d1)]
    else:
        probes = [shape.d1 + min(onset, 0.5 * (shape.d2 - shape.d1)),
                  shape.d2 - min(onset, 0.5 * (shape.d2 - shape.d1))]
    probes = np.array([p for p in probes if 0.0 < p <= 2.0 * reach])
    slopes = log_potential_slope(probes, shape) if probes.size else np.array([])
    slopes = slopes[np.isfinite(slopes)]
    if slopes.size == 0:
        raise ValueError(f'the potential is flat {onset} m from its region boundaries '
                         f'(d1={shape.d1}, d2={shape.d2}): no task gain gives it a pull')
    return math.log(max_task_speed) - float(np.min(slopes))


def reach_shortfall(shape, k, max_task_speed, reach, onset=PULL_ONSET,
                    fraction=PULL_FRACTION):
    """Where a task's pull vanishes within the robot's reach of its region, or None.

    shape: TaskShape; k: task gain K (m^2/s), or 0 for `default_task_gain`; max_task_speed:
    the controller's speed cap (m/s); reach: m, the arm's reach (l1 + l2 for the SCARA);
    onset: m; fraction: dimensionless.
    The criterion (S = +1): over the distances from d2 + onset out to d2 + reach (and no
    further than 2 reach, the farthest the hand can be from an end-effector within reach of
    it, so a region open to the workspace, d2 = 2 m, has nothing to check), the pull
    K |dP/dz| never falls below `fraction` of min(max_task_speed, its largest value there).
    The pull is measured against the task's own speed, not max_task_speed alone, so that a
    task demonstrated slowly (small K) is judged like the same path demonstrated briskly.
    Toward x_r (d1 > 0) P grows like exp(a (d1^2 - r^2)) and cannot saturate; S = -1 tasks
    push the arm off a ridge where the pull is 0 by construction: neither is checked.
    Returns None when the task passes, else a one-line reason naming the nearest distance
    where the pull is too weak.
    """
    if not (math.isfinite(k) and k >= 0.0):
        raise ValueError(f'k must be finite and >= 0 m^2/s, got {k}')
    band = _reach_band(shape, reach, onset)
    if band is None:
        return None
    log_k = math.log(k) if k > 0.0 else default_task_gain(shape, max_task_speed, reach, onset)
    radii = np.linspace(band[0], band[1], _REACH_PROBES)
    log_pull = log_k + log_potential_slope(radii, shape)
    strongest = float(np.max(log_pull))
    if strongest == -math.inf:
        return (f'it has no pull from {band[0]:.3f} to {band[1]:.3f} m from x_r: the arm '
                f'would not move there, within {reach:g} m of the region [{shape.d1:.3f}, '
                f'{shape.d2:.3f}] m')
    floor = math.log(fraction) + min(math.log(max_task_speed), strongest)
    weak = log_pull < floor
    if not np.any(weak):
        return None
    index = int(np.argmax(weak))
    reference = min(math.log(max_task_speed), strongest)

    def speed(log_value):
        return math.exp(min(log_value, 700.0))

    return (f'its pull K |dP/dz| is {speed(log_pull[index]):.2g} m/s at {radii[index]:.3f} m '
            f'from x_r, below {100 * fraction:g} % of {speed(reference):.2g} m/s '
            f'(the smaller of max_task_speed and its strongest pull within reach) with '
            f'{f"K = {k:.4g} m^2/s" if k > 0.0 else "the default K"}: the arm would not move '
            f'there, within {reach:g} m of the region [{shape.d1:.3f}, {shape.d2:.3f}] m')
