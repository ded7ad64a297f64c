"""Figures of merit of a closed-loop run, from the recorded controller state (no ROS).

A run is the series the controller publishes on /hri/controller_state: times t (N,) s,
distance |x - x_d| (N,) m to the hand, joint torques tau (N, 2) N m. The desired region of a
task is d1 <= distance <= d2 (paper Fig. 2, S = +1). These are what the demo's report and
metrics.json quote for Figs. 4-6: when the robot reached the region, where it settled, and
the largest torque it needed.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RunMetrics:
    """time_to_region: s from `start` until the distance entered the region for good (None if
    it never did); steady_distance: median distance over the final window (m);
    in_region_at_end: whether the final window's median lies in the region (with tolerance);
    peak_torque: max |tau_i| over the run (N m); final_peak_torque: max |tau_i| over the
    final window (N m), which goes to 0 once the task is met (paper Fig. 4)."""

    time_to_region: float | None
    steady_distance: float
    in_region_at_end: bool
    peak_torque: float
    final_peak_torque: float


def _series(t, distance) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=float)
    distance = np.asarray(distance, dtype=float)
    if t.ndim != 1 or t.shape != distance.shape or t.size == 0:
        raise ValueError(f'need matching non-empty 1-D times and distances, got {t.shape} '
                         f'and {distance.shape}')
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(distance))):
        raise ValueError('times and distances must be finite')
    return t, distance


def in_region(distance, d1: float, d2: float, tolerance: float = 0.0) -> np.ndarray:
    """Boolean mask (N,) of samples with d1 - tolerance <= distance <= d2 + tolerance (m)."""
    distance = np.asarray(distance, dtype=float)
    return (distance >= d1 - tolerance) & (distance <= d2 + tolerance)


def time_to_region(t, distance, d1: float, d2: float, start: float | None = None,
                   tolerance: float = 0.0) -> float | None:
    """Time (s) from `start` (default t[0]) to the first sample after which the distance stays
    in [d1, d2] (+- tolerance, m) to the end of the run; None if the last sample is outside."""
    t, distance = _series(t, distance)
    start = float(t[0]) if start is None else float(start)
    after = t >= start
    inside = in_region(distance, d1, d2, tolerance) & after
    if not inside[-1]:
        return None
    outside = np.flatnonzero(~inside & after)
    first = int(outside[-1]) + 1 if outside.size else int(np.flatnonzero(after)[0])
    return max(0.0, float(t[first]) - start)


def steady_distance(t, distance, window: float) -> float:
    """Median distance (m) over the last `window` seconds of the run."""
    t, distance = _series(t, distance)
    return float(np.median(distance[t >= t[-1] - window]))


def run_metrics(t, distance, tau, d1: float, d2: float, start: float | None = None,
                window: float = 2.0, tolerance: float = 0.005) -> RunMetrics:
    """All of RunMetrics for one run; `tolerance` (m) widens the region for the checks."""
    t, distance = _series(t, distance)
    tau = np.asarray(tau, dtype=float).reshape(len(t), -1)
    final = t >= t[-1] - window
    steady = steady_distance(t, distance, window)
    return RunMetrics(
        time_to_region=time_to_region(t, distance, d1, d2, start, tolerance),
        steady_distance=steady,
        in_region_at_end=bool(in_region(steady, d1, d2, tolerance)),
        peak_torque=float(np.max(np.abs(tau))) if tau.size else 0.0,
        final_peak_torque=float(np.max(np.abs(tau[final]))) if tau.size else 0.0,
    )
