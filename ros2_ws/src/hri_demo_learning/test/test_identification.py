"""Unit tests of hri_demo_learning.identification: S, d1, d2 from demonstrations (eq. 5, 6)."""

import numpy as np
import pytest

from hri_core.potential import TaskShape, potential
from hri_demo_learning.identification import (
    desired_set,
    identify_task_region,
    normalised_mismatch,
    region_bounds,
)
from hri_demo_learning.task_energy import combine_energy_profiles, demonstration_energy

REFERENCE = np.array([0.45, 0.10])


def minimum_jerk(tau):
    tau = np.clip(tau, 0.0, 1.0)
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)


def demonstrate(rng, start, stop, heading=0.7, rate=500.0, tremor=3e-4, noise=2e-4):
    """Energy profile of a noisy hand push from `start` to `stop` m along a ray from x_r:
    minimum-jerk over 1.5 s after 0.4 s at rest, 1 s at rest after; 8-12 Hz tremor, sensor
    noise and gamma-distributed (uneven) sample intervals."""
    times = np.cumsum(rng.gamma(4.0, 1.0 / (4.0 * rate), size=int(2 * 2.9 * rate)))
    times = times[times <= 2.9]
    distance = start + (stop - start) * minimum_jerk((times - 0.4) / 1.5)
    direction = np.array([np.cos(heading), np.sin(heading)])
    shake = tremor * np.sin(2 * np.pi * rng.uniform(8.0, 12.0, 2) * times[:, None]
                            + rng.uniform(0.0, 2 * np.pi, 2))
    positions = REFERENCE + distance[:, None] * direction + shake
    positions = positions + rng.normal(0.0, noise, positions.shape)
    return demonstration_energy(times, positions, REFERENCE).profile


def identify(profile):
    return identify_task_region(profile.distance, profile.energy, profile.moving)


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_follow_demonstration_gives_the_follow_row(seed):
    # Moved toward x_r and stopped at 0.041 m: Table I's follow row (1, 0, 0.041).
    region = identify(demonstrate(np.random.default_rng(seed), 0.30, 0.041))
    assert region.s == 1
    assert region.d1 == 0.0
    assert region.d2 == pytest.approx(0.041, abs=2e-3)
    assert region.mismatch_positive < region.mismatch_negative


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_avoid_demonstration_gives_the_avoid_row(seed):
    # Moved away from x_r to 0.183 m: Table I's avoid row (1, 0.183, 2).
    region = identify(demonstrate(np.random.default_rng(seed), 0.02, 0.183, heading=2.0))
    assert region.s == 1
    assert region.d1 == pytest.approx(0.183, abs=2e-3)
    assert region.d2 == 2.0


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_shifted_follow_and_avoid_give_the_combined_row(seed):
    # Follow shifted outward by 0.23 m plus avoid (eq. 4): Table I's (1, 0.183, 0.271).
    rng = np.random.default_rng(seed)
    follow = demonstrate(rng, 0.30, 0.041)
    avoid = demonstrate(rng, 0.02, 0.183, heading=2.5)
    region = identify(combine_energy_profiles([follow, avoid], [0.23, 0.0]))
    assert region.s == 1
    assert region.d1 == pytest.approx(0.183, abs=2e-3)
    assert region.d2 == pytest.approx(0.271, abs=2e-3)


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_trapping_demonstrations_give_negative_s(seed):
    # Pushed inward from 0.17 to rest at 0.10 m, and outward from 0.18 to rest at 0.25 m:
    # the band between is to be left, the inside and outside are desired (Fig. 1(d)).
    rng = np.random.default_rng(seed)
    inward = demonstrate(rng, 0.17, 0.10)
    outward = demonstrate(rng, 0.18, 0.25, heading=-1.0)
    region = identify(combine_energy_profiles([inward, outward], [0.0, 0.0]))
    assert region.s == -1
    assert region.d1 == pytest.approx(0.10, abs=2e-3)
    assert region.d2 == pytest.approx(0.25, abs=2e-3)
    assert region.mismatch_positive == np.inf   # S = +1 with (0, 2) is zero on every sample


def make_profile(moving_distances, rest_distances):
    """A hand-made profile: moving samples with P_d > 0, rest samples with P_d = 0."""
    distance = np.concatenate([moving_distances, rest_distances])
    energy = np.concatenate([np.full(len(moving_distances), 0.01), np.zeros(len(rest_distances))])
    moving = np.concatenate([np.ones(len(moving_distances), bool),
                             np.zeros(len(rest_distances), bool)])
    return distance, energy, moving


def test_region_bounds_open_and_closed_sides():
    rest = [0.20, 0.21, 0.22, 0.20]
    assert region_bounds(*make_profile([0.3, 0.4, 0.5, 0.6], rest)) == (0.0, 0.22)
    assert region_bounds(*make_profile([0.01, 0.05, 0.1, 0.15], rest)) == (0.20, 2.0)
    assert region_bounds(*make_profile([0.01, 0.05, 0.3, 0.4], rest)) == (0.20, 0.22)
    assert region_bounds(*make_profile([0.3, 0.4, 0.5, 0.6], rest),
                         workspace_radius=0.8) == (0.0, 0.22)
    assert region_bounds(*make_profile([0.01, 0.05, 0.1, 0.15], rest),
                         workspace_radius=0.8) == (0.20, 0.8)


def test_motion_within_the_margin_does_not_close_the_region():
    rest = [0.040, 0.041, 0.042, 0.041]
    # The end of the push, 1 mm below the rest samples (tremor), is not evidence of a boundary.
    profile = make_profile([0.039, 0.1, 0.2, 0.3], rest)
    assert region_bounds(*profile) == (0.0, 0.042)
    assert region_bounds(*profile, margin=0.0) == (0.040, 0.042)


def test_desired_set_is_rest_with_zero_energy():
    energy = np.array([0.0, 0.1, 0.0, 0.2])
    moving = np.array([False, False, True, True])
    np.testing.assert_array_equal(desired_set(energy, moving), [True, False, False, False])


def test_normalised_mismatch_is_zero_for_the_generating_shape():
    shape = TaskShape(1, 2.0, 9.0, 0.1, 0.3)
    distance = np.linspace(0.0, 0.6, 200)
    energy = np.where((distance < 0.1) | (distance > 0.3), 1.0, 0.0) * (distance - 0.2) ** 2
    assert normalised_mismatch(distance, energy, shape) > 0.01
    assert normalised_mismatch(distance, potential(distance, shape), shape) < 1e-12
    assert normalised_mismatch(distance, energy, TaskShape(1, 2.0, 9.0, 0.0, 2.0)) == np.inf


def test_normalised_mismatch_does_not_depend_on_the_energy_scale():
    """Energies whose plain norm overflows (a damaged bag's) are measured like any other."""
    distance = np.linspace(0.05, 0.5, 200)
    shape = TaskShape(1, 5.0, 20.0, 0.0, 0.1)
    energy = potential(distance, shape) + 0.01
    expected = normalised_mismatch(distance, energy, shape)
    for scale in (1e-200, 1e200, 1e300):
        with np.errstate(all='raise'):
            assert normalised_mismatch(distance, energy * scale, shape) == pytest.approx(
                expected, rel=1e-12)


def test_unusable_profiles_are_rejected_with_a_reason():
    distance, energy, moving = make_profile([0.3, 0.4, 0.5, 0.6], [0.2, 0.21, 0.22, 0.2])
    with pytest.raises(ValueError, match='no sample at rest'):
        identify_task_region(distance, energy, np.ones_like(moving))
    with pytest.raises(ValueError, match='no sample moving'):
        identify_task_region(distance, np.zeros_like(energy), np.zeros_like(moving))
    with pytest.raises(ValueError, match='too few samples'):
        identify_task_region(distance[:5], energy[:5], moving[:5])
    bad = distance.copy()
    bad[0] = np.nan
    with pytest.raises(ValueError, match='non-finite input'):
        identify_task_region(bad, energy, moving)
    with pytest.raises(ValueError, match='boolean mask'):
        identify_task_region(distance, energy, moving.astype(float))
    with pytest.raises(ValueError, match='energy P_d must be >= 0'):
        identify_task_region(distance, -energy, moving)
    with pytest.raises(ValueError, match='beyond workspace_radius'):
        identify_task_region(distance, energy, moving, workspace_radius=0.1)
    with pytest.raises(ValueError, match=r'must all be \(N,\)'):
        identify_task_region(distance, energy[:-1], moving)
