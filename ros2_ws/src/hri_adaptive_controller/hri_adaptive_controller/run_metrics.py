"""Figures of merit of a closed-loop run, from the recorded controller state (no ROS).

A run is the series the controller publishes on /hri/controller_state: times t (N,) s,
distance |x - x_d| (N,) m to the hand, joint torques tau (N, 2) N m. The desired region of a
task is d1 <= distance <= d2 (paper Fig. 2, S = +1). These are what the demo's report and
metrics.json quote for Figs. 4-6: when the robot reached the region, where it settled, and
the largest torque it needed.

A take is a run with a recorded person's hand (issue 32): samples t (N,) s at the joint-state
rate, the hand position (N, 2|3) m held from the latest /target (a NaN row where there was no
hand), the tool position (N, 2) m and the applied effort (N, 2) N m. `take_metrics` gives the
figures its checks bound: how close the arm followed, how often it came too close, the largest
effort step and the longest high-effort hold.
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

from hri_core.recorded_motion import ReachAnnulus


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


@dataclass(frozen=True)
class TakeCriteria:
    """What a take's figures are measured against. d1: the task's inner radius (m);
    effort_limit: per-joint torque limit (N m); task_speed: the arm's task-space speed
    (m/s; a hand faster than it is not one the arm can be asked to keep up with); reach: the
    arm's reach annulus (its radii, m, about the base); avoid_margin: how far inside d1 counts
    as too close (m); high_effort_fraction: share of the limit above which effort is high;
    speed_window: s over which the hand's speed is measured on its cleaned path."""

    d1: float
    effort_limit: float
    task_speed: float
    reach: ReachAnnulus
    avoid_margin: float = 0.03
    high_effort_fraction: float = 0.25
    speed_window: float = 0.15


@dataclass(frozen=True)
class TakeMetrics:
    """follow_median_distance: median |hand - tool| (m) over the considered samples (hand seen,
    inside the reach, slower than the task speed; NaN if none); close_fraction: share of those
    samples closer than d1 - avoid_margin; largest_effort_step: max |tau_i(k+1) - tau_i(k)|
    between consecutive samples (N m); longest_high_effort_hold: longest time (s) any |tau_i|
    stayed above high_effort_fraction * effort_limit; considered: how many samples counted."""

    follow_median_distance: float
    close_fraction: float
    largest_effort_step: float
    longest_high_effort_hold: float
    considered: int


def _times(t) -> np.ndarray:
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0.0):
        raise ValueError('times must be a non-empty, finite, non-decreasing 1-D series')
    return t


def _rows(values, t: np.ndarray, name: str) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if values.ndim != 2 or len(values) != len(t):
        raise ValueError(f'{name} must be ({len(t)}, k), got {values.shape}')
    return values


def hand_speed(t, hand, window: float = 0.15, jump: float = 0.05) -> np.ndarray:
    """Speed (N,) m/s of the hand's horizontal path, robust to lost frames and glitches.

    The seen samples' x, y are compared with their running median over `window` s; a sample
    more than `jump` m from it (a marker swap or one-frame glitch lasting less than half the
    window) is dropped like a lost frame. The speed of each kept sample is its displacement
    across `window` s of kept samples centred on it. Dropped and lost samples get +inf.
    """
    t = _times(t)
    xy = _rows(hand, t, 'hand')[:, :2]
    seen = np.flatnonzero(np.all(np.isfinite(xy), axis=1))
    speed = np.full(len(t), math.inf)
    if len(seen) < 2:
        return speed
    step = float(np.median(np.diff(t[seen]))) or window
    width = max(1, int(round(window / step)) | 1)
    reference = median_filter(xy[seen], size=(width, 1), mode='nearest')
    kept = seen[np.linalg.norm(xy[seen] - reference, axis=1) <= jump]
    if len(kept) < 2:
        return speed
    ts, path = t[kept], xy[kept]
    low = np.searchsorted(ts, ts - 0.5 * window, side='left')
    high = np.searchsorted(ts, ts + 0.5 * window, side='right') - 1
    span = ts[high] - ts[low]
    moved = np.linalg.norm(path[high] - path[low], axis=1)
    speed[kept] = np.where(span > 0.0, moved / np.where(span > 0.0, span, 1.0), 0.0)
    return speed


def considered_samples(t, hand, criteria: TakeCriteria) -> np.ndarray:
    """Mask (N,) of samples where the hand is seen, inside the reach annulus and slower than
    the arm's task speed: where the arm can be asked to be at the hand."""
    t = _times(t)
    xy = _rows(hand, t, 'hand')[:, :2]
    with np.errstate(invalid='ignore'):
        radius = np.hypot(xy[:, 0], xy[:, 1])
        reachable = (radius >= criteria.reach.inner) & (radius <= criteria.reach.outer)
    return reachable & (hand_speed(t, hand, criteria.speed_window) < criteria.task_speed)


def largest_effort_step(effort) -> float:
    """max over joints and consecutive samples of |tau_i(k+1) - tau_i(k)| (N m); 0 if < 2."""
    effort = np.asarray(effort, dtype=float)
    effort = effort.reshape(len(effort), -1)
    if len(effort) < 2:
        return 0.0
    return float(np.max(np.abs(np.diff(effort, axis=0))))


def longest_high_effort_hold(t, effort, threshold: float) -> float:
    """Longest time (s) some |tau_i| stayed above `threshold` (N m): from the first sample
    above to the first sample below again (the run's last sample if it never came down)."""
    t = _times(t)
    high = np.any(np.abs(_rows(effort, t, 'effort')) > threshold, axis=1)
    if not np.any(high):
        return 0.0
    edges = np.diff(np.concatenate([[0], high.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    ends = np.minimum(ends, len(t) - 1)             # first sample below, or the last one
    return float(np.max(t[ends] - t[starts]))


def take_metrics(t, hand, tool, effort, criteria: TakeCriteria) -> TakeMetrics:
    """All of TakeMetrics for one take. t (N,) s; hand (N, 2|3) m with NaN rows where no hand
    was seen; tool (N, 2|3) m; effort (N, n) N m (the applied torque at each sample). The
    distances are in 3-D where both hand and tool are, else in the plane."""
    t = _times(t)
    hand, tool = _rows(hand, t, 'hand'), _rows(tool, t, 'tool')
    effort = _rows(effort, t, 'effort')
    considered = considered_samples(t, hand, criteria)
    axes = min(hand.shape[1], tool.shape[1])
    distance = np.linalg.norm(hand[considered, :axes] - tool[considered, :axes], axis=1)
    close = distance < criteria.d1 - criteria.avoid_margin
    return TakeMetrics(
        follow_median_distance=float(np.median(distance)) if distance.size else math.nan,
        close_fraction=float(np.mean(close)) if distance.size else 0.0,
        largest_effort_step=largest_effort_step(effort),
        longest_high_effort_hold=longest_high_effort_hold(
            t, effort, criteria.high_effort_fraction * criteria.effort_limit),
        considered=int(np.count_nonzero(considered)),
    )
