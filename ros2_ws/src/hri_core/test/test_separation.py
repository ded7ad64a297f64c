"""Unit tests of separation: S_p of ISO/TS 15066 against its formula, the speeds of hand and
tool towards each other, and the arm speed that keeps S_p within a distance."""

import math

import numpy as np
import pytest

from hri_core.separation import ProtectiveSeparation, separation_sample, separation_verdict

# A set of constants with distinct values, so that a term mixed up with another shows.
SETTINGS = ProtectiveSeparation(reaction_time=0.1, stopping_time=0.3, stopping_distance=0.05,
                                intrusion_distance=0.02, human_uncertainty=0.004,
                                robot_uncertainty=0.001, near_speed=2.0, far_speed=1.6,
                                near_limit=0.5, assume_iso_speed=False)


def test_protective_distance_is_the_formula():
    rng = np.random.default_rng(7)
    for _ in range(20):
        v_h, v_r = rng.uniform(0.0, 2.0), rng.uniform(0.0, 1.0)
        expected = v_h * (0.1 + 0.3) + v_r * 0.1 + 0.05 + 0.02 + 0.004 + 0.001
        assert SETTINGS.distance(v_h, v_r) == pytest.approx(expected, abs=1e-12)
    # A still pair: the constant terms alone; a robot moving away counts as still.
    assert SETTINGS.distance(0.0, 0.0) == pytest.approx(0.075)
    assert SETTINGS.distance(0.0, -0.5) == pytest.approx(0.075)


def test_iso_13855_speeds_and_the_measured_speed():
    iso = ProtectiveSeparation(**{**SETTINGS.__dict__, 'assume_iso_speed': True})
    assert iso.human_speed_used(0.3, 0.5) == 2.0  # within 0.5 m: K = 2000 mm/s
    assert iso.human_speed_used(0.3, 0.51) == 1.6  # beyond: K = 1600 mm/s
    assert iso.human_speed_used(2.5, 0.2) == 2.5  # a faster measured hand wins
    assert SETTINGS.human_speed_used(0.3, 0.2) == 0.3  # measured speed alone
    assert SETTINGS.human_speed_used(-0.4, 0.2) == 0.0  # a hand moving away: 0


def test_speeds_towards_each_other_along_the_separation():
    # Tool 0.3 m along +x of the hand. The hand comes at 0.5 m/s along x (and 0.2 m/s
    # sideways, which does not count); the tool moves away at 0.1 m/s.
    sample = separation_sample((0.1, 0.2), (0.5, 0.2), (0.4, 0.2), (0.1, 0.3), SETTINGS)
    assert sample.separation == pytest.approx(0.3)
    assert sample.human_speed == pytest.approx(0.5)
    assert sample.robot_speed == pytest.approx(-0.1)
    assert sample.closing_speed == pytest.approx(0.4)
    assert sample.human_speed_used == pytest.approx(0.5)
    assert sample.protective_distance == pytest.approx(0.5 * 0.4 + 0.075)
    assert not sample.below_protective
    # Both move apart: negative speeds; S_p is the constant terms.
    apart = separation_sample((0.0, 0.0), (0.0, -0.2), (0.0, 0.05), (0.0, 0.3), SETTINGS)
    assert (apart.human_speed, apart.robot_speed) == pytest.approx((-0.2, -0.3))
    assert apart.protective_distance == pytest.approx(0.075) and apart.below_protective
    # On top of each other: each speed counts whole, towards the other.
    same = separation_sample((0.2, 0.2), (0.3, 0.4), (0.2, 0.2), (0.0, -0.1), SETTINGS)
    assert (same.separation, same.human_speed, same.robot_speed) == pytest.approx(
        (0.0, 0.5, 0.1))


def test_arm_speed_limit_solves_the_formula_for_the_robot_speed():
    # A still hand: 0.2 m leaves 0.2 - 0.075 m for v_r T_r: 1.25 m/s.
    assert SETTINGS.arm_speed_limit(0.2, human_speed=0.0) == pytest.approx(1.25)
    assert SETTINGS.distance(0.0, 1.25) == pytest.approx(0.2)
    # A hand at 0.3 m/s: 0.2 - 0.075 - 0.3 x 0.4 = 0.005 m: 0.05 m/s.
    assert SETTINGS.arm_speed_limit(0.2, human_speed=0.3) == pytest.approx(0.05)
    # ISO 13855's 2.0 m/s within 0.5 m: 0.875 m at least; no arm speed fits 0.2 m.
    assert SETTINGS.arm_speed_limit(0.2) is None
    assert SETTINGS.arm_speed_limit(1.0) == pytest.approx((1.0 - 1.6 * 0.4 - 0.075) / 0.1)
    instant = ProtectiveSeparation(**{**SETTINGS.__dict__, 'reaction_time': 0.0})
    assert instant.arm_speed_limit(0.2, human_speed=0.0) == math.inf


def test_from_mapping_takes_the_constants_and_names_a_missing_one():
    values = {**SETTINGS.__dict__, 'publish_rate_hz': 50.0}
    assert ProtectiveSeparation.from_mapping(values) == SETTINGS
    del values['stopping_time']
    with pytest.raises(KeyError, match='stopping_time'):
        ProtectiveSeparation.from_mapping(values)


@pytest.mark.parametrize(('change', 'message'), [
    ({'stopping_time': -0.1}, 'stopping_time must be a finite number >= 0, got -0.1'),
    ({'reaction_time': math.inf}, 'reaction_time must be a finite number >= 0'),
    ({'near_speed': 0.0}, 'near_speed must be a finite number > 0, got 0.0'),
    ({'stopping_distance': '0.1'}, "stopping_distance must be a finite number >= 0, got '0.1'"),
])
def test_bad_constants_are_refused(change, message):
    with pytest.raises(ValueError, match=message):
        ProtectiveSeparation(**{**SETTINGS.__dict__, **change})


def test_verdict_against_the_formula():
    iso = ProtectiveSeparation(**{**SETTINGS.__dict__, 'assume_iso_speed': True})
    d1, speed = 0.6, 0.25
    verdict = separation_verdict(d1, speed, iso)
    constant = 0.05 + 0.02 + 0.004 + 0.001  # B + C + Z_d + Z_r
    # Beyond 0.5 m the hand counts at 1.6 m/s: S_p = 1.6 (0.1 + 0.3) + 0.25 x 0.1 + ...
    assert verdict.protective_distance == pytest.approx(1.6 * 0.4 + 0.025 + constant)
    assert verdict.protective_distance_still_hand == pytest.approx(0.025 + constant)
    assert not verdict.meets and verdict.meets_still_hand
    assert verdict.arm_speed_limit is None  # 1.6 x 0.4 + 0.075 > 0.6 m even for a still arm
    assert verdict.arm_speed_limit_still_hand == pytest.approx((d1 - constant) / 0.1)
    assert verdict.metrics()['arm_speed_limit_still_hand_m_s'] == \
        verdict.arm_speed_limit_still_hand
    assert 'not met' in verdict.summary() and 'no arm speed' in verdict.summary()


def test_verdict_at_its_own_limit_is_met():
    d1 = 0.3
    limit = separation_verdict(d1, 0.0, SETTINGS).arm_speed_limit_still_hand
    at_limit = separation_verdict(d1, limit, SETTINGS)
    assert at_limit.protective_distance_still_hand == pytest.approx(d1)
    assert not separation_verdict(d1, limit + 0.01, SETTINGS).meets_still_hand


@pytest.mark.parametrize('d1, speed, match', [(0.0, 0.25, 'd1 must be'),
                                              (math.nan, 0.25, 'd1 must be'),
                                              (0.2, -0.1, 'arm_speed must be')])
def test_verdict_refuses_bad_values(d1, speed, match):
    with pytest.raises(ValueError, match=match):
        separation_verdict(d1, speed, SETTINGS)


def test_the_pair_sample_takes_the_speeds_along_the_normal():
    from hri_core.separation import pair_separation_sample

    settings = ProtectiveSeparation(0.1, 0.95, 0.18, 0.1, 0.01, 0.001, 2.0, 1.6, 0.5, False)
    normal = np.array([1.0, 0.0, 0.0])  # from the robot's point towards the person's
    sample = pair_separation_sample(0.3, normal, [0.2, 0.5, 0.0], [-0.4, 0.0, 1.0], settings)
    assert sample.separation == 0.3
    assert sample.robot_speed == pytest.approx(0.2) and sample.human_speed == pytest.approx(0.4)
    assert sample.protective_distance == pytest.approx(0.4 * 1.05 + 0.2 * 0.1 + 0.291)
    overlapping = pair_separation_sample(-0.02, normal, [0, 0, 0], [0, 0, 0], settings)
    assert overlapping.separation == 0.0 and overlapping.below_protective
