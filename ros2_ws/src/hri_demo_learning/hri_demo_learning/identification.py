"""Identification of the task type S, d1, d2 from a task energy profile (paper eq. 5, 6).

Omega, the desired region seen in the demonstration, is the set of samples at rest (speed below
the stationary speed) with P_d = 0. The rule, made precise so that it gives Table I's rows and
also works for combinations (eq. 4):

1. lo, hi = min and max distance to x_r over Omega (eq. 5).
2. Reading S = +1 (desired region d1 <= |z| <= d2): d1 = lo and d2 = hi, except that the region
   is open inward (d1 = 0) when no moving sample lies below lo, and open outward
   (d2 = workspace_radius) when no moving sample lies beyond hi. A moving sample within
   ``margin`` (m) of Omega's range does not count: it is the tail of the motion blurred by
   sensor noise and tremor, not evidence of a boundary.
   follow (moved toward x_r, stopped at 0.041) -> (0, 0.041); avoid (moved away to 0.183)
   -> (0.183, 2); follow shifted by 0.23 combined with avoid -> (0.183, 0.271).
3. Reading S = -1 (desired region |z| <= d1 or |z| >= d2, open at both ends by nature):
   d1 = lo, d2 = hi as eq. 5 gives them.
4. S by eq. 6: the reading whose normalised potential P/||P|| (initial a1, a2) is closer in
   Euclidean norm to the normalised task energy P_d/||P_d|| over all samples wins (S = +1 on a
   tie). A reading whose P is zero on every sample explains nothing and loses.
   (The paper writes "for all x in Omega"; P_d is 0 on Omega, so the comparison is made over
   all samples of the profile.)
"""

import math
from dataclasses import dataclass

import numpy as np

from hri_core.potential import TaskShape, normalised_potential
from hri_demo_learning.task_energy import normalised_energy

DEFAULT_WORKSPACE_RADIUS = 2.0
"""m: d2 of a desired region that is open outward."""

DEFAULT_INITIAL_STEEPNESS = (1.0, 10.0)
"""(a1, a2) in 1/m^2 for eq. 6's comparison and the fit's start; asymmetric on purpose."""

DEFAULT_BOUNDARY_MARGIN = 0.002
"""m: moving samples closer than this to Omega's range do not close the region."""

MIN_PROFILE_SAMPLES = 8
"""Fewest samples an energy profile may have."""


@dataclass(frozen=True)
class TaskRegion:
    """Identified task type: s (+1/-1), d1, d2 (m), and eq. 6's two mismatches
    ||P_d/||P_d|| - P_s/||P_s|||| for s = +1 (mismatch_positive) and s = -1 (mismatch_negative);
    inf where that P is zero on every sample."""

    s: int
    d1: float
    d2: float
    mismatch_positive: float
    mismatch_negative: float


def _check_profile(distance, energy, moving):
    d = np.asarray(distance, dtype=float)
    e = np.asarray(energy, dtype=float)
    m = np.asarray(moving)
    if d.ndim != 1 or e.shape != d.shape or m.shape != d.shape:
        raise ValueError(f'distance, energy and moving must all be (N,), got {d.shape}, '
                         f'{e.shape}, {m.shape}')
    if d.size < MIN_PROFILE_SAMPLES:
        raise ValueError(f'too few samples: {d.size} (need at least {MIN_PROFILE_SAMPLES})')
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(e))):
        raise ValueError('non-finite input: distance and energy must be finite')
    if np.any(d < 0.0):
        raise ValueError('distance must be >= 0')
    if np.any(e < 0.0):
        raise ValueError('energy P_d must be >= 0 (eq. 3)')
    if m.dtype != bool:
        raise ValueError(f'moving must be a boolean mask, got dtype {m.dtype}')
    return d, e, m


def desired_set(energy, moving):
    """Omega of eq. 5: samples at rest with P_d = 0. energy: (N,), moving: (N,) bool.

    Returns (N,) bool.
    """
    return ~np.asarray(moving, dtype=bool) & (np.asarray(energy, dtype=float) == 0.0)


def _rest_range(distance, energy, moving):
    omega = desired_set(energy, moving)
    if not np.any(omega):
        raise ValueError('no sample at rest with P_d = 0: the desired region is unknown')
    if not np.any(moving):
        raise ValueError('no sample moving: the demonstration shows no behaviour')
    return float(distance[omega].min()), float(distance[omega].max())


def region_bounds(distance, energy, moving, workspace_radius=DEFAULT_WORKSPACE_RADIUS,
                  margin=DEFAULT_BOUNDARY_MARGIN):
    """d1, d2 (m) of the S = +1 reading: eq. 5 with the open-region rule (module docstring).

    distance: (N,) m; energy: (N,) P_d; moving: (N,) bool; workspace_radius: m; margin: m.
    Returns (d1, d2). Raises ValueError with the reason for unusable input.
    """
    d, e, m = _check_profile(distance, energy, moving)
    lo, hi = _rest_range(d, e, m)
    _check_workspace(workspace_radius, margin, hi)
    d1 = lo if np.any(m & (d < lo - margin)) else 0.0
    d2 = hi if np.any(m & (d > hi + margin)) else float(workspace_radius)
    return d1, d2


def _check_workspace(workspace_radius, margin, hi):
    if not (math.isfinite(workspace_radius) and workspace_radius > 0.0):
        raise ValueError(f'workspace_radius must be > 0 m, got {workspace_radius}')
    if not (math.isfinite(margin) and margin >= 0.0):
        raise ValueError(f'margin must be >= 0 m, got {margin}')
    if hi > workspace_radius:
        raise ValueError(f'the robot rested at {hi:.3f} m from x_r, beyond workspace_radius '
                         f'{workspace_radius} m')


def normalised_mismatch(distance, energy, shape):
    """Euclidean distance between P_d/||P_d|| and P/||P|| over the samples (eq. 6's measure).

    distance: (N,) m; energy: (N,) P_d, not all zero; shape: TaskShape of P. Returns a float
    in [0, 2], or inf when P is zero on every sample. P/||P|| is formed in log space, so it is
    exact even where P exceeds the potential's cap.
    """
    e = np.asarray(energy, dtype=float)
    if not np.all(np.isfinite(e)):
        raise ValueError('non-finite task energy P_d')
    if not np.any(e != 0.0):
        raise ValueError('the task energy P_d is zero on every sample')
    p = normalised_potential(distance, shape)
    if not np.any(p > 0.0):
        return math.inf
    return float(np.linalg.norm(normalised_energy(e) - p))


def identify_task_region(distance, energy, moving, workspace_radius=DEFAULT_WORKSPACE_RADIUS,
                         n=3, initial=DEFAULT_INITIAL_STEEPNESS, margin=DEFAULT_BOUNDARY_MARGIN):
    """Task type S, d1, d2 of an energy profile (eq. 5, 6 and the rule in the module docstring).

    distance: (N,) m to x_r; energy: (N,) P_d; moving: (N,) bool; workspace_radius: m; n: N of
    eq. 2; initial: (a1, a2) 1/m^2 of eq. 6's comparison; margin: m.
    Returns a TaskRegion. Raises ValueError (one-line reason) for: too few samples, non-finite
    input, no sample at rest, no sample moving, or no reading that explains the profile.
    """
    d, e, m = _check_profile(distance, energy, moving)
    lo, hi = _rest_range(d, e, m)
    d1_pos, d2_pos = region_bounds(d, e, m, workspace_radius, margin)
    if not np.any(e > 0.0):
        raise ValueError('the task energy P_d is zero on every sample')
    a1, a2 = initial
    positive = normalised_mismatch(d, e, TaskShape(1, a1, a2, d1_pos, d2_pos, n))
    negative = normalised_mismatch(d, e, TaskShape(-1, a1, a2, lo, hi, n))
    if math.isinf(positive) and math.isinf(negative):
        raise ValueError('neither S = +1 nor S = -1 gives a potential that is nonzero on the '
                         'samples')
    if positive <= negative:
        return TaskRegion(1, d1_pos, d2_pos, positive, negative)
    return TaskRegion(-1, lo, hi, positive, negative)
