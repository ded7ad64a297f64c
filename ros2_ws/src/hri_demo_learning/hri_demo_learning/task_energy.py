"""Task energy P_d of a demonstration (paper eq. 3) and of combined demonstrations (eq. 4).

A demonstration is the end-effector path x_i (m, in 3-D: [x, y, z] in the base frame; a planar
path (N, 2) is the plane z = 0) at times t_i (s) while a person moves the robot by hand, with a
reference position x_r set by that person. Per eq. 3

    P_d,i = ||x_i - x_d||^2 - T   while the hand moves (||dx_i/dt|| > 0),
    P_d,i = 0                      while it is at rest,

with x_d the position where the person stopped moving the robot and T = min ||x_i - x_d||^2.
Made precise here:

* Distances and speeds are Euclidean in 3-D, so a demonstration rotated or tilted in space
  (the same radial profile) gives the same profile, and a planar one (z constant) the same
  numbers as before the pipeline went 3-D.
* Speed is estimated with a smoothing differentiator, not a raw finite difference: the samples
  (uneven rates allowed; duplicate stamps averaged) are resampled linearly to a uniform grid at
  their median interval, differentiated with a Savitzky-Golay filter (cubic, window
  ``smoothing_window`` s) and interpolated back to the sample times.
* Rest is judged against the demonstration's own pace, so that the same path demonstrated
  slowly or briskly gives the same task: a sample is slow when its speed is below
  max(``stationary_speed``, ``rest_fraction`` x the demonstration's peak speed). The floor
  ``stationary_speed`` (0.004 m/s) stays above the speed that sensor noise fakes (0.1 mm of
  position noise at 100 Hz reads as at most 0.0025 m/s); the relative part (5 % of the peak)
  makes a minimum-jerk push leave its last 0.5 mm, whatever its duration, for the rest, where
  an absolute 0.01 m/s would leave 0.4 mm of a 2 s push and 9 mm of a 15 s one.
* The motion runs from the first to the last sample that is not slow. Samples before it (the
  person has not started yet) are dropped, so that the start position is not mistaken for a
  goal; every sample within it counts as moving, also a slow stretch or a pause on the way
  (it is not where the person stopped); the samples after it are the final rest.
* x_d is the mean position of the final rest. For a repeated demonstration the x_d of all
  repetitions are averaged (``repeated_demonstration_energy``).
* T is the minimum of ||x_i - x_d||^2 over the moving samples, so P_d >= 0 everywhere and it
  rises from 0 where the motion ends.

Combinations (eq. 4) are formed on the distance axis |x_i - x_r|: ``combine_energy_profiles``
moves demonstration i's profile outward by its shift C_i (m) and concatenates the samples.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hri_core.validation import positive, spatial_points, spatial_vector

DEFAULT_STATIONARY_SPEED = 0.004
"""m/s: a sample slower than this is at rest (eq. 3's ||dx/dt|| = 0), whatever the pace."""

DEFAULT_REST_FRACTION = 0.05
"""A sample slower than this fraction of the demonstration's peak speed is at rest."""

DEFAULT_SMOOTHING_WINDOW = 0.25
"""s: Savitzky-Golay window of the speed estimate. Its derivative gain is >= 0.94 of the true one
up to 3 Hz (hand motion) and <= 0.125 of it at 8-12 Hz (physiological tremor)."""

MIN_SAMPLES = 8
"""Fewest samples a demonstration may have."""

_SAVGOL_ORDER = 3
_MAX_GRID_POINTS = 2_000_000


@dataclass(frozen=True)
class EnergyProfile:
    """Task energy against distance to the reference: the input of identification and fit.

    distance: (N,) m, |x_i - x_r| (plus the shift C_i in a combination); energy: (N,) m^2, P_d
    (eq. 3, 4); moving: (N,) bool, True for the samples of the motion, False for the final
    rest; speed: (N,) m/s, the smoothed speed (None when not known).
    """

    distance: np.ndarray
    energy: np.ndarray
    moving: np.ndarray
    speed: np.ndarray | None = None


@dataclass(frozen=True)
class TaskEnergy:
    """Task energy of one demonstration (eq. 3), from its first moving sample to its end.

    times: (M,) s; distance: (M,) m to x_r; energy: (M,) m^2, P_d; moving: (M,) bool;
    speed: (M,) m/s, smoothed; target: (3,) m, x_d; offset: m^2, T of eq. 3.
    """

    times: np.ndarray
    distance: np.ndarray
    energy: np.ndarray
    moving: np.ndarray
    speed: np.ndarray
    target: np.ndarray
    offset: float

    @property
    def profile(self):
        """The EnergyProfile (distance, energy, moving) of this demonstration."""
        return EnergyProfile(self.distance, self.energy, self.moving, self.speed)


def _check_demonstration(times, positions):
    t = np.asarray(times, dtype=float)
    x = np.asarray(positions, dtype=float)
    if t.ndim != 1 or x.ndim != 2 or x.shape[0] != t.size or x.shape[1] not in (2, 3):
        raise ValueError(f'times must be (N,) and positions (N, 2) or (N, 3), got {t.shape} '
                         f'and {x.shape}')
    if t.size < MIN_SAMPLES:
        raise ValueError(f'too few samples: {t.size} (need at least {MIN_SAMPLES})')
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
        raise ValueError('non-finite input: times and positions must be finite')
    if np.any(np.diff(t) < 0.0):
        raise ValueError('times must be non-decreasing')
    if t[-1] <= t[0]:
        raise ValueError('the demonstration has zero duration')
    return t, spatial_points(x, 'positions', 'm')


def as_position(point, name: str) -> np.ndarray:
    """A position x_r or x_d as (3,) m; a planar [x, y] is [x, y, 0]."""
    array = np.asarray(point, dtype=float).reshape(-1)
    if array.shape == (2,):
        array = np.append(array, 0.0)
    return spatial_vector(array, name, 'm')


def _check_speed_parameters(stationary_speed, smoothing_window, rest_fraction):
    positive(stationary_speed, 'stationary_speed', 'm/s')
    positive(smoothing_window, 'smoothing_window', 's')
    if not (math.isfinite(rest_fraction) and 0.0 <= rest_fraction < 1.0):
        raise ValueError(f'rest_fraction must be in [0, 1), got {rest_fraction}')


def estimate_speed(times, positions, smoothing_window=DEFAULT_SMOOTHING_WINDOW):
    """Smoothed end-effector speed ||dx/dt|| at each sample (the speed test of eq. 3).

    times: (N,) s, non-decreasing, uneven spacing allowed; positions: (N, 3) m ((N, 2): z = 0).
    Resamples to a uniform grid at the median sample interval, applies a cubic Savitzky-Golay
    differentiator over ``smoothing_window`` s and interpolates back. Returns (N,) m/s.
    """
    t, x = _check_demonstration(times, positions)
    positive(smoothing_window, 'smoothing_window', 's')
    stamps, inverse, counts = np.unique(t, return_inverse=True, return_counts=True)
    mean_x = np.stack([np.bincount(inverse, weights=x[:, k]) / counts for k in range(3)], axis=1)
    duration = stamps[-1] - stamps[0]
    step = max(float(np.median(np.diff(stamps))), duration / (_MAX_GRID_POINTS - 1))
    grid = stamps[0] + step * np.arange(int(math.floor(duration / step)) + 1)
    resampled = np.stack([np.interp(grid, stamps, mean_x[:, k]) for k in range(3)], axis=1)
    window = int(round(smoothing_window / step)) // 2 * 2 + 1
    window = max(window, _SAVGOL_ORDER + 2)
    if window > grid.size:
        window = grid.size if grid.size % 2 else grid.size - 1
    if window <= _SAVGOL_ORDER:
        raise ValueError(f'too few samples on a uniform grid: {grid.size} '
                         f'(need at least {_SAVGOL_ORDER + 1})')
    # Imported here: scipy.signal costs the learner 0.4 s at start-up, wasted on a bad
    # parameter or bag.
    from scipy.signal import savgol_filter
    velocity = savgol_filter(resampled, window, _SAVGOL_ORDER, deriv=1, delta=step, axis=0,
                             mode='interp')
    speed = np.sqrt(np.einsum('ij,ij->i', velocity, velocity))
    # Within half a window of either end the one-sided fit is noisy: hold the speed of the
    # nearest sample whose window is complete.
    half = window // 2
    if grid.size > 2 * half:
        speed[:half] = speed[half]
        speed[grid.size - half:] = speed[grid.size - half - 1]
    return np.interp(t, grid, speed)


def rest_threshold(speed, stationary_speed=DEFAULT_STATIONARY_SPEED,
                   rest_fraction=DEFAULT_REST_FRACTION):
    """Speed (m/s) below which a sample is at rest: max(stationary_speed, rest_fraction x the
    peak of speed (N,) m/s)."""
    return max(stationary_speed, rest_fraction * float(np.max(speed)))


def _demonstration_span(speed, stationary_speed, smoothing_window, rest_fraction):
    """Moving mask (first..last fast sample), first and last index; ValueError without motion
    or final rest."""
    threshold = rest_threshold(speed, stationary_speed, rest_fraction)
    fast = speed > threshold
    if not np.any(fast):
        raise ValueError(f'no sample moving: the speed never exceeds stationary_speed '
                         f'{stationary_speed} m/s')
    first = int(np.argmax(fast))
    last = fast.size - 1 - int(np.argmax(fast[::-1]))
    if last == fast.size - 1:
        raise ValueError(f'no sample at rest after the motion: the demonstration must end with '
                         f'the robot held still (speed < {threshold:.3g} m/s) for at least '
                         f'{smoothing_window} s')
    moving = np.zeros(fast.size, dtype=bool)
    moving[first:last + 1] = True
    return moving, first, last


def rest_position(times, positions, stationary_speed=DEFAULT_STATIONARY_SPEED,
                  smoothing_window=DEFAULT_SMOOTHING_WINDOW, rest_fraction=DEFAULT_REST_FRACTION):
    """Target x_d of eq. 3: mean position of the final rest segment of a demonstration.

    times: (N,) s; positions: (N, 3) m ((N, 2): z = 0). Returns (3,) m. Raises ValueError when
    no sample moves
    or the demonstration does not end at rest.
    """
    _check_speed_parameters(stationary_speed, smoothing_window, rest_fraction)
    t, x = _check_demonstration(times, positions)
    speed = estimate_speed(t, x, smoothing_window)
    _, _, last = _demonstration_span(speed, stationary_speed, smoothing_window, rest_fraction)
    return x[last + 1:].mean(axis=0)


def demonstration_energy(times, positions, reference, stationary_speed=DEFAULT_STATIONARY_SPEED,
                         smoothing_window=DEFAULT_SMOOTHING_WINDOW, target=None,
                         rest_fraction=DEFAULT_REST_FRACTION):
    """Task energy P_d of one demonstration (eq. 3).

    times: (N,) s; positions: (N, 3) m; reference: x_r, (3,) m; stationary_speed: m/s;
    target: x_d, (3,) m, or None to take the mean of the final rest segment; rest_fraction:
    of the peak speed (module docstring).
    Returns a TaskEnergy over the samples from the first moving one to the end.
    Raises ValueError (one-line reason) for too few samples, non-finite input, no sample
    moving, or no rest at the end.
    """
    _check_speed_parameters(stationary_speed, smoothing_window, rest_fraction)
    t, x = _check_demonstration(times, positions)
    x_r = as_position(reference, 'reference')
    speed = estimate_speed(t, x, smoothing_window)
    moving, first, last = _demonstration_span(speed, stationary_speed, smoothing_window,
                                              rest_fraction)
    if target is None:
        x_d = x[last + 1:].mean(axis=0)
    else:
        x_d = as_position(target, 'target')
    t, x, speed, moving = t[first:], x[first:], speed[first:], moving[first:]
    squared = np.sum((x - x_d) ** 2, axis=1)
    offset = float(np.min(squared[moving]))
    energy = np.where(moving, squared - offset, 0.0)
    away = x - x_r
    distance = np.sqrt(np.einsum('ij,ij->i', away, away))
    return TaskEnergy(times=t, distance=distance, energy=energy, moving=moving, speed=speed,
                      target=x_d, offset=offset)


def repeated_demonstration_energy(demonstrations, reference,
                                  stationary_speed=DEFAULT_STATIONARY_SPEED,
                                  smoothing_window=DEFAULT_SMOOTHING_WINDOW,
                                  rest_fraction=DEFAULT_REST_FRACTION):
    """Task energies (eq. 3) of repetitions of one demonstration with a shared, averaged x_d.

    demonstrations: sequence of (times (N_k,) s, positions (N_k, 3) m), all with the same
    reference x_r (3,) m. x_d is the mean of the repetitions' rest positions (paper: "if the
    same demonstration is repeated, the average position can be used").
    Returns a list of TaskEnergy, one per repetition.
    """
    if len(demonstrations) == 0:
        raise ValueError('no demonstrations given')
    targets = [rest_position(t, x, stationary_speed, smoothing_window, rest_fraction)
               for t, x in demonstrations]
    x_d = np.mean(targets, axis=0)
    return [demonstration_energy(t, x, reference, stationary_speed, smoothing_window, x_d,
                                 rest_fraction)
            for t, x in demonstrations]


def combine_energy_profiles(profiles: Sequence, shifts: Sequence[float]):
    """Task energy of a combination of demonstrations (eq. 4).

    profiles: EnergyProfile or TaskEnergy objects; shifts: C_i in m, one per profile: profile
    i is moved outward by C_i along the distance axis (its distances become |x - x_r| + C_i).
    The combined profile is the concatenation of the shifted samples, P_d unchanged (the sum in
    eq. 4 of energies defined on disjoint sample sets). Returns an EnergyProfile.
    Raises ValueError when the counts differ, a shift is non-finite, or a shifted distance
    would be negative.
    """
    if len(profiles) == 0:
        raise ValueError('no energy profiles to combine')
    if len(shifts) != len(profiles):
        raise ValueError(f'one shift per profile needed: {len(profiles)} profiles, '
                         f'{len(shifts)} shifts')
    distances, energies, movings, speeds = [], [], [], []
    for index, (profile, shift) in enumerate(zip(profiles, shifts, strict=True)):
        if not math.isfinite(shift):
            raise ValueError(f'shift {index} must be finite, got {shift}')
        distance = np.asarray(profile.distance, dtype=float) + shift
        if np.any(distance < 0.0):
            raise ValueError(f'shift {index} ({shift} m) moves distances below 0')
        distances.append(distance)
        energies.append(np.asarray(profile.energy, dtype=float))
        movings.append(np.asarray(profile.moving, dtype=bool))
        speeds.append(None if profile.speed is None else np.asarray(profile.speed, dtype=float))
    speed = None if any(v is None for v in speeds) else np.concatenate(speeds)
    return EnergyProfile(np.concatenate(distances), np.concatenate(energies),
                         np.concatenate(movings), speed)


def normalised_energy(energy) -> np.ndarray:
    """P_d / ||P_d|| (eq. 3, 4's profile on the unit sphere): energy (N,) finite, >= 0, not all
    zero (checked by the caller). Scaled by its largest value before the norm, which overflows
    for energies above about 1e154 (a damaged bag's)."""
    e = np.asarray(energy, dtype=float)
    unit = e / np.max(np.abs(e))
    return unit / np.linalg.norm(unit)
