"""Task gain K learned from the demonstration's speeds (the K of the paper's eq. 13).

Eq. 7 fits the shape of P only (P/||P||), so how fast the task should move the arm is not in
a1, a2. The controller moves the arm at the task speed K |dP/dz| (m/s, eq. 12, 14 with P scaled
by K). K is chosen so that this speed, at the distances the person moved the robot through,
matches how fast the person moved it there, in least squares over the moving samples:

    K = argmin sum_i (K g_i - v_i)^2 = sum_i g_i v_i / sum_i g_i^2,   g_i = |dP/dr|(r_i),

with r_i = |x_i - x_r| (m), v_i the smoothed speed (m/s, `task_energy.estimate_speed`) and
dP/dr in 1/m, so K is in m^2/s. The slopes g_i can span hundreds of orders of magnitude
(Table I's avoid row), so the sums are formed from log g_i (``potential.log_potential_slope``)
scaled by their largest value: exact where the capped gradient would not be.
"""

import math

import numpy as np

from hri_core.potential import log_potential_slope

_SMALLEST_GAIN = 1e-300
_LARGEST_GAIN = 1e300


def fit_task_gain(distance, speed, moving, shape):
    """Least-squares task gain K (m^2/s) of a demonstration (module docstring).

    distance: (N,) m to x_r; speed: (N,) m/s, >= 0; moving: (N,) bool, the samples used;
    shape: the learned TaskShape. Returns K > 0. Raises ValueError (one-line reason) when no
    moving sample moves, P is flat on every moving sample, or K is outside 1e-300..1e300.
    """
    d = np.asarray(distance, dtype=float)
    v = np.asarray(speed, dtype=float)
    m = np.asarray(moving, dtype=bool)
    if d.ndim != 1 or v.shape != d.shape or m.shape != d.shape:
        raise ValueError(f'distance, speed and moving must all be (N,), got {d.shape}, '
                         f'{v.shape}, {m.shape}')
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(v))) or np.any(v < 0.0):
        raise ValueError('distance and speed must be finite, speed >= 0')
    if not np.any(v[m] > 0.0):
        raise ValueError('no moving sample with a speed: the task gain is unknown')
    log_g = log_potential_slope(d[m], shape)
    if not np.any(np.isfinite(log_g)):
        raise ValueError('P is flat on every moving sample: no task gain can move the arm')
    top = float(np.max(log_g))
    g = np.exp(log_g - top)  # in [0, 1]
    ratio = float(np.dot(g, v[m]) / np.dot(g, g))
    if ratio <= 0.0:
        raise ValueError('the demonstration moved only where P is flat: the task gain is '
                         'unknown')
    log_k = math.log(ratio) - top
    if not (math.log(_SMALLEST_GAIN) <= log_k <= math.log(_LARGEST_GAIN)):
        raise ValueError(f'the task gain K = exp({log_k:.1f}) m^2/s is outside '
                         f'{_SMALLEST_GAIN:g}..{_LARGEST_GAIN:g}: P is too steep or too flat '
                         'to be scaled to the demonstrated speed')
    return math.exp(log_k)


def task_speed(distance, shape, k):
    """Task speed K |dP/dr| (m/s) at r = distance (m), (N,); 0 where P is flat."""
    with np.errstate(over='ignore'):
        return np.exp(np.minimum(math.log(k) + log_potential_slope(distance, shape), 700.0))
