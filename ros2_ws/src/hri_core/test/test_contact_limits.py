"""Unit tests of contact_limits: ISO/TS 15066 Table A.2's limits, the person's capsules mapped
onto its regions, and the judge of a contact trace (the transient rule of 0.5 s)."""

import numpy as np
import pytest

from hri_core.bodies import HUMAN_CAPSULES
from hri_core.contact_limits import (
    BODY_PART_REGIONS,
    BODY_PART_SPANS,
    REGION_LIMITS,
    TRANSIENT_CONTACT_TIME,
    judge_contacts,
)

# Table A.2 as the module docstring gives it: (F_s N, least p_s N/cm^2, transient F N).
TABLE_A2 = {
    'skull_and_forehead': (130.0, 110.0, 130.0),
    'face': (65.0, 110.0, 65.0),
    'neck': (150.0, 140.0, 300.0),
    'back_and_shoulders': (210.0, 160.0, 420.0),
    'chest': (140.0, 120.0, 280.0),
    'abdomen': (110.0, 140.0, 220.0),
    'pelvis': (180.0, 210.0, 360.0),
    'upper_arms_and_elbow_joints': (150.0, 190.0, 300.0),
    'lower_arms_and_wrist_joints': (160.0, 180.0, 320.0),
    'hands_and_fingers': (140.0, 190.0, 280.0),
    'thighs_and_knees': (220.0, 220.0, 440.0),
    'lower_legs': (130.0, 210.0, 260.0),
}
REGIONS = list(TABLE_A2)
WITH_TRANSIENT = [r for r in REGIONS if r not in ('skull_and_forehead', 'face')]
STEP = 0.001  # s, a 1 kHz simulator's contact samples


def probe_trace(region: str, profile):
    """A one-part trace ('probe', judged by `region`): profile is [(duration s, force N)],
    each segment sampled every STEP, ending with one 0 N sample (the contact released)."""
    forces = [force for duration, force in profile for _ in range(round(duration / STEP))]
    forces.append(0.0)
    time = STEP * np.arange(len(forces))
    return time, ['probe'] * len(forces), np.array(forces), {'probe': region}


def judged(region: str, profile):
    time, part, force, regions = probe_trace(region, profile)
    result = judge_contacts(time, part, force, part_regions=regions)
    assert list(result) == [region]
    return result[region]


# --- The table -------------------------------------------------------------------------------

@pytest.mark.parametrize('region', REGIONS)
def test_each_region_holds_table_a2(region):
    limit = REGION_LIMITS[region]
    force, pressure, transient = TABLE_A2[region]
    assert (limit.quasi_static_force, limit.quasi_static_pressure) == (force, pressure)
    assert limit.transient_force == transient


def test_the_table_has_the_twelve_regions_and_no_other():
    assert set(REGION_LIMITS) == set(TABLE_A2)


def test_no_transient_contact_on_the_skull_or_the_face_and_twice_elsewhere():
    for region, limit in REGION_LIMITS.items():
        permitted = region not in ('skull_and_forehead', 'face')
        assert limit.transient_permitted is permitted
        factor = 2.0 if permitted else 1.0
        assert limit.transient_pressure == factor * limit.quasi_static_pressure


# --- The person's capsules onto the regions --------------------------------------------------

def test_every_capsule_the_project_makes_has_a_region():
    capsule_names = {name for name, *_ in HUMAN_CAPSULES}
    assert capsule_names == set(BODY_PART_REGIONS) == set(BODY_PART_SPANS)
    assert set(BODY_PART_REGIONS.values()) <= set(REGION_LIMITS)


def test_each_capsule_is_judged_by_the_least_force_of_the_regions_it_spans():
    for part, spanned in BODY_PART_SPANS.items():
        assert set(spanned) <= set(REGION_LIMITS), part
        least = min(REGION_LIMITS[region].quasi_static_force for region in spanned)
        assert REGION_LIMITS[BODY_PART_REGIONS[part]].quasi_static_force == least, part


def test_the_conservative_choices_named_in_the_docstring():
    assert BODY_PART_REGIONS['head'] == 'face'
    assert BODY_PART_REGIONS['torso'] == 'abdomen'
    for side in 'lr':
        assert BODY_PART_REGIONS[f'{side}_shoulder'] == 'chest'
        assert BODY_PART_REGIONS[f'{side}_upper_arm'] == 'upper_arms_and_elbow_joints'
        assert BODY_PART_REGIONS[f'{side}_forearm'] == 'upper_arms_and_elbow_joints'
        assert BODY_PART_REGIONS[f'{side}_hand'] == 'hands_and_fingers'


# --- One trace of each kind per region -------------------------------------------------------

@pytest.mark.parametrize('region', REGIONS)
def test_a_contact_within_the_quasi_static_limit_passes(region):
    limit = REGION_LIMITS[region].quasi_static_force
    # Two seconds of pressing, rising to the limit itself (permissible) and back.
    result = judged(region, [(0.5, 0.5 * limit), (1.0, limit), (0.5, 0.9 * limit)])
    assert result.passed and result.verdict == 'pass', result.reason
    assert result.peak_force == limit
    assert result.time_above_quasi_static == 0.0
    assert not result.exceeded_transient and not result.held_too_long
    assert 'within' in result.reason


@pytest.mark.parametrize('region', REGIONS)
def test_above_the_quasi_static_limit_for_longer_than_half_a_second_fails(region):
    limit = REGION_LIMITS[region]
    # Just above F_s (and, where transient contact is allowed, well under the transient limit)
    # for 0.6 s.
    result = judged(region, [(0.1, 0.5 * limit.quasi_static_force),
                             (0.6, limit.quasi_static_force + 1.0)])
    assert not result.passed and result.verdict == 'fail'
    assert result.held_too_long
    assert result.longest_above_quasi_static == pytest.approx(0.6)
    assert result.time_above_quasi_static == pytest.approx(0.6)
    if limit.transient_permitted:
        assert not result.exceeded_transient
        assert 'for 0.600 s from 0.100 s' in result.reason
    else:
        assert result.exceeded_transient  # no transient contact: above F_s is above its limit


@pytest.mark.parametrize('region', WITH_TRANSIENT)
def test_a_short_spike_under_the_transient_limit_passes(region):
    limit = REGION_LIMITS[region]
    spike = 0.5 * (limit.quasi_static_force + limit.transient_force)
    result = judged(region, [(0.2, 0.5 * limit.quasi_static_force), (0.05, spike),
                             (0.3, 0.5 * limit.quasi_static_force)])
    assert result.passed, result.reason
    assert result.peak_force == spike and result.peak_time == pytest.approx(0.2)
    assert result.time_above_quasi_static == pytest.approx(0.05)
    assert not result.exceeded_transient and not result.held_too_long
    assert 'transient contact' in result.reason


@pytest.mark.parametrize('region', REGIONS)
def test_a_short_spike_over_the_transient_limit_fails(region):
    limit = REGION_LIMITS[region]
    result = judged(region, [(0.2, 0.5 * limit.quasi_static_force),
                             (0.01, limit.transient_force + 1.0)])
    assert not result.passed and result.exceeded_transient
    assert not result.held_too_long  # released after 0.01 s: the force alone fails it
    assert f'{limit.transient_force:.0f} N' in result.reason


@pytest.mark.parametrize('region', ['skull_and_forehead', 'face'])
def test_no_short_spike_above_the_quasi_static_limit_on_the_head(region):
    limit = REGION_LIMITS[region]
    result = judged(region, [(0.2, 10.0), (0.01, limit.quasi_static_force + 1.0)])
    assert not result.passed and result.exceeded_transient
    assert 'allows no transient contact' in result.reason


# --- The transient rule's edges --------------------------------------------------------------

def test_half_a_second_above_passes_and_a_step_more_fails():
    limit = REGION_LIMITS['chest'].quasi_static_force
    at_limit = judged('chest', [(TRANSIENT_CONTACT_TIME, limit + 10.0)])
    assert at_limit.passed and at_limit.longest_above_quasi_static == pytest.approx(0.5)
    longer = judged('chest', [(TRANSIENT_CONTACT_TIME + 2 * STEP, limit + 10.0)])
    assert not longer.passed and longer.held_too_long


def test_two_short_contacts_are_judged_apart_but_their_time_adds_up():
    limit = REGION_LIMITS['pelvis'].quasi_static_force
    result = judged('pelvis', [(0.4, limit + 20.0), (0.1, limit), (0.4, limit + 20.0)])
    assert result.passed, result.reason  # two contacts of 0.4 s, each released in time
    assert result.time_above_quasi_static == pytest.approx(0.8)
    assert result.longest_above_quasi_static == pytest.approx(0.4)


def test_a_contact_still_above_when_the_trace_ends_fails():
    limit = REGION_LIMITS['neck'].quasi_static_force
    time = np.array([0.0, 0.1, 0.2])
    result = judge_contacts(time, ['probe'] * 3, [0.0, limit + 5.0, limit + 5.0],
                            part_regions={'probe': 'neck'})['neck']
    assert not result.passed and result.held_too_long and not result.exceeded_transient
    assert 'no release seen' in result.reason and 'from 0.100 s' in result.reason


def test_sparse_samples_hold_their_force_until_the_next():
    # Three samples: above F_s at 0 s, released at 0.7 s: held for 0.7 s.
    limit = REGION_LIMITS['lower_legs'].quasi_static_force
    result = judge_contacts([0.0, 0.7, 0.8], ['probe'] * 3, [limit + 1.0, 0.0, 0.0],
                            part_regions={'probe': 'lower_legs'})['lower_legs']
    assert not result.passed and result.longest_above_quasi_static == pytest.approx(0.7)


# --- The person's parts together --------------------------------------------------------------

def test_parts_of_one_region_are_judged_each_and_reported_together():
    # Both hands touched at once, interleaved; the left one held too long, the right not.
    time = np.arange(0.0, 1.0, 0.01)
    n = len(time)
    left = np.where(time < 0.9, 150.0, 0.0)     # above 140 N for 0.9 s
    right = np.where(time < 0.3, 200.0, 0.0)    # above for 0.3 s, under 280 N
    result = judge_contacts(np.concatenate([time, time]), ['l_hand'] * n + ['r_hand'] * n,
                            np.concatenate([left, right]))
    assert list(result) == ['hands_and_fingers']
    hands = result['hands_and_fingers']
    assert hands.parts == ('l_hand', 'r_hand')
    assert hands.peak_force == 200.0 and hands.peak_part == 'r_hand'
    assert hands.time_above_quasi_static == pytest.approx(0.9 + 0.3)
    assert not hands.passed and 'l_hand above' in hands.reason


def test_each_region_of_a_whole_body_trace_gets_its_own_verdict():
    time = [0.0, 0.0, 0.0, 0.2, 0.2, 0.2]
    part = ['head', 'torso', 'r_forearm'] * 2
    force = [70.0, 100.0, 200.0, 0.0, 0.0, 0.0]     # head over 65 N; torso within 110 N
    result = judge_contacts(time, part, force)
    assert list(result) == ['face', 'abdomen', 'upper_arms_and_elbow_joints']
    assert [result[r].passed for r in result] == [False, True, True]
    assert result['face'].exceeded_transient


def test_an_empty_trace_judges_nothing():
    assert judge_contacts([], [], []) == {}


def test_time_above_the_limit_is_the_sum_of_the_held_samples_on_random_traces():
    rng = np.random.default_rng(20160215)
    limit = REGION_LIMITS['thighs_and_knees'].quasi_static_force
    for _ in range(50):
        steps = rng.uniform(0.001, 0.05, 60)
        time = np.cumsum(steps) - steps[0]
        force = rng.uniform(0.0, 1.5 * limit, 60)
        result = judge_contacts(time, ['probe'] * 60, force,
                                part_regions={'probe': 'thighs_and_knees'})['thighs_and_knees']
        expected = sum(time[k + 1] - time[k] for k in range(59) if force[k] > limit)
        assert result.time_above_quasi_static == pytest.approx(expected, abs=1e-12)
        assert result.peak_force == force.max()
        assert result.exceeded_transient is bool(force.max() > 2.0 * limit)
        # The verdict follows its two findings, whatever the trace.
        assert result.passed is not (result.exceeded_transient or result.held_too_long)


# --- Bad input -------------------------------------------------------------------------------

@pytest.mark.parametrize('time, part, force, match', [
    ([0.0, 0.1], ['head', 'head'], [1.0, np.nan], r'forces must be finite, got nan N at sample 1'),
    ([0.0, 0.1], ['head', 'head'], [1.0, np.inf], r'forces must be finite'),
    ([0.0, 0.1], ['head', 'head'], [1.0, -0.5], r'normal forces must be >= 0 N, got -0.5 N'),
    ([0.0, 0.1], ['head', 'nose'], [1.0, 1.0], r"unknown body part 'nose' \(known: head, "),
    ([0.0, 0.1, 0.1], ['head'] * 3, [1.0] * 3, r"times of body part 'head' must increase: "
                                               r'0\.1 s follows 0\.1 s'),
    ([0.2, 0.1], ['head'] * 2, [1.0] * 2, r"must increase: 0\.1 s follows 0\.2 s"),
    ([0.0, 0.1], ['head'] * 3, [1.0] * 2, r'2 times, 3 body parts and 2 forces'),
    ([0.0, 0.1], ['head'] * 2, [1.0], r'2 times, 2 body parts and 1 forces'),
    ([0.0, np.nan], ['head'] * 2, [1.0] * 2, r'times must be finite'),
    ([[0.0, 0.1]], ['head'], [1.0], r'must be 1-D arrays'),
    ([0.0], 'head', [1.0], r'part must be a sequence of body part names'),
])
def test_bad_input_is_a_one_line_value_error(time, part, force, match):
    with pytest.raises(ValueError, match=match) as error:
        judge_contacts(time, part, force)
    assert '\n' not in str(error.value)


def test_a_part_map_onto_an_unknown_region_is_refused():
    with pytest.raises(ValueError, match=r"unknown body region 'elbow'"):
        judge_contacts([0.0], ['probe'], [1.0], part_regions={'probe': 'elbow'})


def test_times_of_different_parts_may_repeat_and_interleave():
    # Not an error: two parts at one instant, and one part's samples after another's.
    result = judge_contacts([0.5, 0.0, 0.5, 1.0], ['l_hand', 'r_hand', 'r_hand', 'l_hand'],
                            [10.0, 10.0, 0.0, 0.0])
    assert result['hands_and_fingers'].passed
