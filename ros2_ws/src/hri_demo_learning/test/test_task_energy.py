"""Unit tests of hri_demo_learning.task_energy: speed, P_d (eq. 3) and combinations (eq. 4)."""

import numpy as np
import pytest

from hri_demo_learning.task_energy import (
    DEFAULT_STATIONARY_SPEED,
    EnergyProfile,
    combine_energy_profiles,
    demonstration_energy,
    estimate_speed,
    repeated_demonstration_energy,
    rest_position,
    rest_threshold,
)

REFERENCE = np.array([0.45, 0.10])
HOLD_BEFORE = 0.4  # s at rest before the push
DURATION = 1.5  # s of the push


def minimum_jerk(tau):
    tau = np.clip(tau, 0.0, 1.0)
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)


def synthetic_demonstration(rng, start, stop, heading=0.7, rate=500.0, tremor=3e-4,
                            noise=2e-4, hold_after=1.0):
    """A hand push along a ray from x_r: minimum-jerk from `start` to `stop` m, 8-12 Hz tremor
    of `tremor` m, sensor noise of `noise` m, gamma-distributed (uneven) sample intervals.
    Returns times (N,) s, positions (N, 2) m and the true distance to x_r (N,) m."""
    total = HOLD_BEFORE + DURATION + hold_after
    times = np.cumsum(rng.gamma(4.0, 1.0 / (4.0 * rate), size=int(2 * total * rate)))
    times = times[times <= total]
    distance = start + (stop - start) * minimum_jerk((times - HOLD_BEFORE) / DURATION)
    direction = np.array([np.cos(heading), np.sin(heading)])
    shake = tremor * np.sin(2 * np.pi * rng.uniform(8.0, 12.0, 2) * times[:, None]
                            + rng.uniform(0.0, 2 * np.pi, 2))
    positions = REFERENCE + distance[:, None] * direction + shake
    positions = positions + rng.normal(0.0, noise, positions.shape)
    return times, positions, distance


def true_speed(times, start, stop):
    tau = np.clip((times - HOLD_BEFORE) / DURATION, 0.0, 1.0)
    return np.abs(stop - start) / DURATION * 30.0 * tau ** 2 * (1.0 - tau) ** 2


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_speed_estimate_follows_the_push_and_ignores_tremor(seed):
    rng = np.random.default_rng(seed)
    times, positions, _ = synthetic_demonstration(rng, 0.30, 0.041, tremor=5e-4)
    speed = estimate_speed(times, positions)
    truth = true_speed(times, 0.30, 0.041)
    middle = (times > HOLD_BEFORE + 0.3) & (times < HOLD_BEFORE + DURATION - 0.3)
    assert np.max(np.abs(speed[middle] - truth[middle])) < 0.05 * np.max(truth)
    resting = (times < HOLD_BEFORE - 0.1) | (times > HOLD_BEFORE + DURATION + 0.2)
    # The raw tremor speed is 2 pi f A = 0.025-0.038 m/s: it must be filtered out, below the
    # speed that decides rest for this push (5 % of its peak, 0.0096 m/s).
    assert np.max(speed[resting]) < rest_threshold(speed)


def test_raw_finite_differences_would_see_tremor_as_motion():
    # Guards the premise of the test above: the data are noisy enough to need smoothing.
    rng = np.random.default_rng(1)
    times, positions, _ = synthetic_demonstration(rng, 0.30, 0.041, tremor=5e-4)
    raw = np.hypot(*(np.diff(positions, axis=0) / np.diff(times)[:, None]).T)
    assert np.max(raw[times[1:] < HOLD_BEFORE - 0.1]) > 5 * DEFAULT_STATIONARY_SPEED


@pytest.mark.parametrize(('start', 'stop'), [(0.30, 0.041), (0.02, 0.183)])
def test_demonstration_energy_of_follow_and_avoid(start, stop):
    rng = np.random.default_rng(4)
    times, positions, distance = synthetic_demonstration(rng, start, stop)
    energy = demonstration_energy(times, positions, REFERENCE)
    # The demonstration starts at the push (leading rest dropped) and ends at rest.
    assert abs(energy.times[0] - HOLD_BEFORE) < 0.1
    assert energy.times[-1] == times[-1] and not energy.moving[-1]
    moving_truth = true_speed(energy.times, start, stop) > DEFAULT_STATIONARY_SPEED
    assert np.mean(energy.moving == moving_truth) > 0.97
    # x_d: where the push stopped; T: the smallest squared distance to it while moving.
    assert np.hypot(*(energy.target[:2] - REFERENCE)) == pytest.approx(stop, abs=5e-4)
    assert 0.0 <= energy.offset < 1e-5
    np.testing.assert_allclose(energy.distance, np.hypot(*(positions[-energy.distance.size:]
                                                           - REFERENCE).T))
    assert np.all(energy.energy[~energy.moving] == 0.0)
    assert np.all(energy.energy >= 0.0) and np.min(energy.energy[energy.moving]) == 0.0
    expected = (distance[-energy.distance.size:] - stop) ** 2
    moving = energy.moving
    # Tremor and noise (~1 mm) move (r - stop)^2 by up to 2 (r - stop) 1 mm, about 5e-4 m^2.
    np.testing.assert_allclose(energy.energy[moving], expected[moving], atol=1e-3)
    profile = energy.profile
    assert isinstance(profile, EnergyProfile) and profile.distance is energy.distance


def test_given_target_is_used():
    rng = np.random.default_rng(5)
    times, positions, _ = synthetic_demonstration(rng, 0.30, 0.041)
    target = REFERENCE + np.array([0.01, 0.0])
    energy = demonstration_energy(times, positions, REFERENCE, target=target)
    np.testing.assert_array_equal(energy.target, [*target, 0.0])  # planar: the plane z = 0
    squared = np.sum((positions[-energy.distance.size:] - target) ** 2, axis=1)
    moving = energy.moving
    np.testing.assert_allclose(energy.energy[moving], squared[moving] - energy.offset)


def test_repeated_demonstrations_share_the_averaged_target():
    rng = np.random.default_rng(6)
    demos = [synthetic_demonstration(rng, 0.3, stop)[:2] for stop in (0.035, 0.041, 0.047)]
    energies = repeated_demonstration_energy(demos, REFERENCE)
    rests = [rest_position(t, x) for t, x in demos]
    for energy in energies:
        np.testing.assert_allclose(energy.target, np.mean(rests, axis=0))
    assert np.hypot(*(energies[0].target[:2] - REFERENCE)) == pytest.approx(0.041, abs=5e-4)


def test_uneven_and_duplicate_stamps_are_handled():
    rng = np.random.default_rng(7)
    times, positions, _ = synthetic_demonstration(rng, 0.3, 0.041, rate=200.0)
    times = np.repeat(times, 2)          # every stamp twice
    positions = np.repeat(positions, 2, axis=0)
    keep = rng.random(times.size) > 0.3  # and 30 % of the samples lost
    energy = demonstration_energy(times[keep], positions[keep], REFERENCE)
    assert np.all(np.isfinite(energy.energy)) and np.any(energy.moving)


def test_combination_moves_each_profile_outward_and_concatenates():
    rng = np.random.default_rng(8)
    follow = demonstration_energy(*synthetic_demonstration(rng, 0.30, 0.041)[:2], REFERENCE)
    avoid = demonstration_energy(*synthetic_demonstration(rng, 0.02, 0.183)[:2], REFERENCE)
    combined = combine_energy_profiles([follow, avoid.profile], [0.23, 0.0])
    n = follow.distance.size
    np.testing.assert_allclose(combined.distance[:n], follow.distance + 0.23)
    np.testing.assert_array_equal(combined.distance[n:], avoid.distance)
    np.testing.assert_array_equal(combined.energy, np.concatenate([follow.energy,
                                                                   avoid.energy]))
    np.testing.assert_array_equal(combined.moving, np.concatenate([follow.moving,
                                                                   avoid.moving]))


def test_combination_rejects_bad_shifts():
    profile = EnergyProfile(np.array([0.1, 0.2]), np.array([0.0, 1.0]), np.array([False, True]))
    with pytest.raises(ValueError, match='one shift per profile'):
        combine_energy_profiles([profile, profile], [0.1])
    with pytest.raises(ValueError, match='moves distances below 0'):
        combine_energy_profiles([profile], [-0.15])
    with pytest.raises(ValueError, match='must be finite'):
        combine_energy_profiles([profile], [float('nan')])
    with pytest.raises(ValueError, match='no energy profiles'):
        combine_energy_profiles([], [])


def test_bad_demonstrations_are_rejected_with_a_reason():
    rng = np.random.default_rng(9)
    times, positions, _ = synthetic_demonstration(rng, 0.3, 0.041)
    with pytest.raises(ValueError, match='too few samples'):
        demonstration_energy(times[:5], positions[:5], REFERENCE)
    bad = positions.copy()
    bad[10, 0] = np.nan
    with pytest.raises(ValueError, match='non-finite input'):
        demonstration_energy(times, bad, REFERENCE)
    with pytest.raises(ValueError, match='non-decreasing'):
        demonstration_energy(times[::-1], positions, REFERENCE)
    with pytest.raises(ValueError, match=r'positions \(N, 2\)'):
        demonstration_energy(times, positions[:, :1], REFERENCE)
    still = np.tile(positions[:1], (times.size, 1))
    with pytest.raises(ValueError, match='no sample moving'):
        demonstration_energy(times, still, REFERENCE)
    pushing = times < HOLD_BEFORE + 0.8      # the recording ends during the push
    with pytest.raises(ValueError, match='no sample at rest after the motion'):
        demonstration_energy(times[pushing], positions[pushing], REFERENCE)
    with pytest.raises(ValueError, match='stationary_speed must be finite and > 0'):
        demonstration_energy(times, positions, REFERENCE, stationary_speed=0.0)
    with pytest.raises(ValueError, match='reference must be 3 finite values'):
        demonstration_energy(times, positions, [0.1, np.inf])
    with pytest.raises(ValueError, match='zero duration'):
        demonstration_energy(np.zeros(20), np.zeros((20, 2)), REFERENCE)
