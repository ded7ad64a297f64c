"""Performance learning: fit the steepness a1, a2 of the potential to the task energy (eq. 7-11).

With S, d1, d2, N fixed by identification, a1 and a2 make the normalised potential match the
normalised task energy over the samples:

    r = P_d/||P_d|| - P/||P||        (eq. 7),      C = 0.5 r^T r        (eq. 8),
    grad C = J_r^T r                 (eq. 9),      A <- A + s,  (J_r^T J_r) s = -J_r^T r
                                                                      (eq. 10, 11).

The Jacobian is analytic. With p = P/||P|| and P = |y|^N on y > 0,

    dp_k/da_i = N p_k (g_ki - sum_j p_j^2 g_ji),
    g_ki = d log|f_i|/d a_i = w_ki / expm1(a_i w_ki),   w_ki = |z_k|^2 - d_i^2,

which stays finite for any a (g -> 1/a_i as a_i w -> 0, -> -w as a_i w -> -inf); P/||P|| itself
is formed from log P (``potential.log_potential``), so trial steps never overflow.

Two solvers, both keeping a1, a2 within ``STEEPNESS_BOUNDS`` = [1e-3, 1e3] 1/m^2 (the model needs
a > 0; the bounds also stop undamped steps from running away). A result on a bound is named in
FitResult.message: the data favour a value beyond it (e.g. a2 -> inf for a follow push).

Reach (the paper: the unsaturated part of P must cover the workspace). Beyond d2 both factors of
eq. 1 saturate toward 1, and P's slope far out is carried by the slower one, of order
a1 exp(-a1 (r^2 - d1^2)). For S = +1, ``reach_steepness_limit`` caps a1 at
ln(1 / PULL_FRACTION) / ((d2 + reach)^2 - d1^2) = 3.0 / ((d2 + reach)^2 - d1^2), so that
factor keeps at least 5 % of its slope out to `reach` (m, l1 + l2) beyond the region; a2 may
stay steep (it shapes the edge). Table I's rows lie within the cap (a1 (d2 + 0.65)^2 = 0.62
for follow, 1.28 for follow_safe, against 3.0); a fit of a follow push from 0.27 m without it
gives a1 = 33, a1 (d2 + 0.65)^2 = 16: no pull beyond 0.5 m.

* ``'trf'`` (default): scipy.optimize.least_squares, trust-region reflective with bounds, on A
  directly. Iterations are its function evaluations (each is one trial step; the Jacobian is
  analytic, so there are no hidden ones). A log parameterisation a = exp(u) was tried and
  rejected: it stretches the flat valley a1 -> 0 of the avoidance shape (Table I's a1 = 0.056
  sits in it); fitting that row's exact P, trf on log a had not converged after 500
  evaluations, trf on a converged in 23.
* ``'gauss_newton'``: the paper's plain iteration (eq. 9-11) on A, solved by least squares
  (lstsq, so a rank-deficient J_r^T J_r does not fail), each iterate projected onto the bounds;
  a parameter on a bound whose descent direction points out of the box is held there and the
  step solved for the other. It stops when ||s|| and ||grad C|| over the free parameters are
  both below the tolerance, or after max_iterations. Undamped, it can jump far from a poor start
  and end on a bound or oscillate; it is kept for comparison with the paper.

With d1 = 0 and a small d2 the model is nearly symmetric in a1 <-> a2 and a solver started on
the diagonal can land on the mirror solution: the default start (1, 10) is asymmetric.
"""

import math
import time
from dataclasses import dataclass

import numpy as np

from hri_core.potential import (
    PULL_FRACTION,
    PULL_ONSET,
    TaskShape,
    log_potential,
    normalised_potential,
)
from hri_demo_learning.identification import DEFAULT_INITIAL_STEEPNESS
from hri_demo_learning.task_energy import normalised_energy

STEEPNESS_BOUNDS = (1e-3, 1e3)
"""1/m^2: lower and upper bound of a1, a2 during the fit."""

DEFAULT_TOLERANCE = 1e-10
"""Stopping tolerance on ||s|| and ||grad C|| (and least_squares's xtol, ftol, gtol)."""

DEFAULT_MAX_ITERATIONS = 200
"""Cap on iterations: trial steps of 'trf', updates of 'gauss_newton'."""

METHODS = ('trf', 'gauss_newton')


def reach_steepness_limit(s, d1, d2, reach):
    """Upper bound on a1 (1/m^2) that keeps P's pull alive out to d2 + reach (m, reach > 0)
    beyond the region (module docstring); None for S = -1, and for a region the arm cannot
    leave outward (d2 + PULL_ONSET beyond 2 reach, e.g. avoid's d2 = 2 m), where nothing
    limits a1."""
    if not (math.isfinite(reach) and reach > 0.0):
        raise ValueError(f'reach must be > 0 m, got {reach}')
    if s != 1 or d2 + PULL_ONSET >= 2.0 * reach:
        return None
    return math.log(1.0 / PULL_FRACTION) / ((d2 + reach) ** 2 - d1 ** 2)


@dataclass(frozen=True)
class FitResult:
    """Outcome of the fit of a1, a2 (1/m^2): cost C of eq. 8 at the result, iterations used,
    method, converged (a stopping test met before max_iterations), message (solver's reason),
    seconds (wall time) and condition (2-norm condition number of J_r with respect to
    (log a1, log a2) at the result; large means a1 or a2 is poorly determined by the data)."""

    a1: float
    a2: float
    cost: float
    iterations: int
    method: str
    converged: bool
    message: str
    seconds: float = math.nan
    condition: float = math.nan


def _bounds(a1_max):
    """(low (2,), high (2,)) 1/m^2: STEEPNESS_BOUNDS with a1's upper bound lowered to a1_max."""
    low, high = STEEPNESS_BOUNDS
    top = np.array([high, high])
    if a1_max is not None:
        if not (math.isfinite(a1_max) and a1_max > low):
            raise ValueError(f'a1_max must be > {low} 1/m^2, got {a1_max}')
        top[0] = min(high, a1_max)
    return np.array([low, low]), top


@dataclass(frozen=True)
class FitOptions:
    """How the fit of a1, a2 runs: method (one of METHODS: 'trf', damped and bounded, or
    'gauss_newton', the paper's plain eq. 9-11), tolerance (the stop test), max_iterations (cap
    on trial steps of 'trf', updates of 'gauss_newton') and initial, the (a1, a2) start in
    1/m^2 within STEEPNESS_BOUNDS. Raises ValueError (one-line reason) for a value it cannot
    use."""

    method: str = 'trf'
    tolerance: float = DEFAULT_TOLERANCE
    max_iterations: int = DEFAULT_MAX_ITERATIONS
    initial: tuple[float, float] = DEFAULT_INITIAL_STEEPNESS

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f'method must be one of {", ".join(METHODS)}, '
                             f'got {self.method!r}')
        if not (math.isfinite(self.tolerance) and self.tolerance > 0.0):
            raise ValueError(f'tolerance must be > 0, got {self.tolerance}')
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, int) \
                or self.max_iterations < 1:
            raise ValueError(f'max_iterations must be an integer >= 1, '
                             f'got {self.max_iterations!r}')
        a = np.asarray(self.initial, dtype=float)
        low, high = STEEPNESS_BOUNDS
        if a.shape != (2,) or not np.all(np.isfinite(a)) or np.any(a < low) \
                or np.any(a > high):
            raise ValueError(f'initial (a1, a2) must lie in [{low}, {high}], '
                             f'got {self.initial!r}')


DEFAULT_FIT_OPTIONS = FitOptions()


def _check_fit_input(distance, energy, options, bounds):
    """(distance, P_d / ||P_d||, the start (a1, a2) clipped into `bounds`) as arrays."""
    d = np.asarray(distance, dtype=float)
    e = np.asarray(energy, dtype=float)
    if d.ndim != 1 or e.shape != d.shape:
        raise ValueError(f'distance and energy must both be (N,), got {d.shape}, {e.shape}')
    if d.size < 2:
        raise ValueError(f'too few samples to fit two parameters: {d.size}')
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(e))):
        raise ValueError('non-finite input: distance and energy must be finite')
    if np.any(d < 0.0) or np.any(e < 0.0):
        raise ValueError('distance and energy must be >= 0')
    if not np.any(e > 0.0):
        raise ValueError('the task energy P_d is zero on every sample: nothing to fit')
    # A start beyond a lowered bound starts on it.
    return d, normalised_energy(e), np.clip(np.asarray(options.initial, dtype=float), *bounds)


def _log_factor_sensitivity(u, a, d):
    """g = d log|1 - exp(-a w)| / da = w / expm1(a w), w = u - d^2 (1/a at w = 0)."""
    w = u - d * d
    aw = a * w
    with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
        g = w / np.expm1(aw)
    return np.where(np.abs(aw) < 1e-12, 1.0 / a - 0.5 * w, g)


def normalised_potential_jacobian(distance, shape):
    """p = P/||P|| and dp/d(a1, a2): (N,) and (N, 2) in m^2 (analytic; see module docstring)."""
    p = normalised_potential(distance, shape)
    u = np.asarray(distance, dtype=float) ** 2
    jac = np.zeros((p.size, 2))
    positive = p > 0.0
    if not np.any(positive):
        return p, jac
    for column, (a, d) in enumerate(((shape.a1, shape.d1), (shape.a2, shape.d2))):
        g = np.zeros_like(p)
        g[positive] = _log_factor_sensitivity(u[positive], a, d)
        jac[:, column] = shape.n * p * (g - np.dot(p * p, g))
    return p, jac


def task_cost(distance, energy, shape):
    """Cost C = 0.5 ||P_d/||P_d|| - P/||P||||^2 of eq. 7, 8. distance, energy: (N,)."""
    r = normalised_energy(energy) - normalised_potential(distance, shape)
    return 0.5 * float(np.dot(r, r))


def _condition(jacobian, a):
    singular = np.linalg.svd(jacobian * a, compute_uv=False)
    return float(singular[0] / singular[-1]) if singular[-1] > 0.0 else math.inf


def _fit_trust_region(d, target, shape_at, a0, bounds, options):
    """`shape_at(a)`: the TaskShape with steepness a = (a1, a2), the rest fixed."""
    def residual(a):
        return target - normalised_potential(d, shape_at(a))

    def jacobian(a):
        return -normalised_potential_jacobian(d, shape_at(a))[1]

    # Imported here: scipy.optimize costs the learner 0.4 s at start-up, wasted on a bad
    # parameter or bag.
    from scipy.optimize import least_squares
    result = least_squares(residual, a0, jac=jacobian, bounds=bounds, method='trf',
                           xtol=options.tolerance, ftol=options.tolerance,
                           gtol=options.tolerance, max_nfev=options.max_iterations)
    a = np.clip(result.x, *bounds)
    return a, int(result.nfev), result.status > 0, result.message


def _blocked(gradient, a, bounds):
    """Coordinates on a bound whose descent direction (-gradient) points out of the box."""
    low, high = bounds
    return ((a <= low) & (gradient > 0.0)) | ((a >= high) & (gradient < 0.0))


def _fit_gauss_newton(d, target, shape_at, a0, bounds, options):
    """`shape_at(a)`: the TaskShape with steepness a = (a1, a2), the rest fixed."""
    low, high = bounds
    tolerance, max_iterations = options.tolerance, options.max_iterations
    a = a0.copy()
    message = f'max_iterations ({max_iterations}) reached'
    converged = False
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        p, jac = normalised_potential_jacobian(d, shape_at(a))
        j_r = -jac
        gradient = j_r.T @ (target - p)                                  # eq. 9
        free = ~_blocked(gradient, a, bounds)
        step = np.zeros(2)
        if np.any(free):
            j_free = j_r[:, free]
            step[free] = np.linalg.lstsq(j_free.T @ j_free, -gradient[free],
                                         rcond=None)[0]                  # eq. 11
        a_next = np.clip(a + step, low, high)                            # eq. 10, projected
        step_norm = float(np.linalg.norm(a_next - a))
        gradient_norm = float(np.linalg.norm(gradient[free]))
        a = a_next
        if step_norm < tolerance and gradient_norm < tolerance:
            converged = True
            message = '||s|| and ||grad C|| below tolerance'
            break
    return a, iterations, converged, message


def _bound_note(a, bounds):
    """Message suffix naming the parameters that ended on a bound (within 1e-6 relative)."""
    low, high = bounds
    at_low = a <= low * (1.0 + 1e-6)
    at_high = a >= high * (1.0 - 1e-6)
    notes = [f'a{k + 1} at its {"lower" if at_low[k] else "upper"} bound '
             f'{low[k] if at_low[k] else high[k]:.4g}'
             for k in range(a.size) if at_low[k] or at_high[k]]
    return f' ({"; ".join(notes)}: the data favour a value beyond it)' if notes else ''


def fit_task_parameters(distance, energy, s, d1, d2, n=3, options=DEFAULT_FIT_OPTIONS,
                        a1_max=None):
    """Fit a1, a2 of eq. 1, 2 to the task energy by minimising C (eq. 7-11).

    distance: (N,) m to x_r; energy: (N,) P_d (eq. 3 or 4), not all zero; s, d1, d2 from
    identification; n: N of eq. 2; options: a FitOptions (method, tolerance, max_iterations,
    initial); a1_max: upper bound of a1 below STEEPNESS_BOUNDS' (1/m^2, e.g.
    `reach_steepness_limit`), None for none. Returns a FitResult. Raises ValueError (one-line
    reason) for unusable input.
    """
    bounds = _bounds(a1_max)
    d, target, a0 = _check_fit_input(distance, energy, options, bounds)

    def shape_at(a):
        return TaskShape(s, a[0], a[1], d1, d2, n)

    # The support of P (where P > 0) depends on s, d1, d2 only, not on a1, a2.
    if not np.any(np.isfinite(log_potential(d, shape_at(a0)))):
        raise ValueError(f'P is zero on every sample for S={s}, d1={d1}, d2={d2}: no a1, a2 '
                         'can fit the task energy')
    start = time.perf_counter()
    solve = _fit_gauss_newton if options.method == 'gauss_newton' else _fit_trust_region
    a, iterations, converged, message = solve(d, target, shape_at, a0, bounds, options)
    seconds = time.perf_counter() - start
    shape = TaskShape(s, float(a[0]), float(a[1]), d1, d2, n)
    _, jac = normalised_potential_jacobian(d, shape)
    return FitResult(a1=shape.a1, a2=shape.a2, cost=task_cost(d, target, shape),
                     iterations=iterations, method=options.method, converged=bool(converged),
                     message=message + _bound_note(a, bounds), seconds=seconds,
                     condition=_condition(jac, a))
