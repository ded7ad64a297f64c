"""Unit tests of hri_core.human_body: REP-155 points from a Vicon take, the standing body."""

import math
from pathlib import Path

import numpy as np
import pytest

from hri_core.human_body import (
    BODY_POINTS,
    TRUNK,
    VICON_SEGMENTS,
    BodyModel,
    RecordedBody,
    elbow_position,
    read_recorded_body,
    standing_body,
)
from hri_core.recorded_motion import Placement, read_vicon_csv

TAKES = Path(__file__).resolve().parents[4] / 'data' / 'human-motion'


def test_every_rep155_name_maps_to_a_vicon_segment_once():
    assert sorted(VICON_SEGMENTS) == sorted(BODY_POINTS)
    assert len(set(VICON_SEGMENTS.values())) == len(BODY_POINTS)
    assert set(TRUNK) <= set(BODY_POINTS)


def test_a_take_reads_every_segment_placed_like_the_hand():
    placement = Placement((0.3, -0.2, 0.1), 0.7)
    take = TAKES / 'CollaborativeHammering_1.csv'
    body = read_recorded_body(take, placement)
    hand = read_vicon_csv(take, 'right_hand', placement)
    assert body.points.shape == (len(hand.times), len(BODY_POINTS), 3)
    np.testing.assert_array_equal(body.points[:, BODY_POINTS.index('r_wrist')], hand.positions)
    np.testing.assert_array_equal(body.times, hand.times)
    head = read_vicon_csv(take, 'head', placement)
    np.testing.assert_array_equal(body.points[:, BODY_POINTS.index('head')], head.positions)


def test_a_lost_segment_is_left_out_of_its_frame_never_nan():
    body = read_recorded_body(TAKES / 'CollaborativeHammering_1.csv')
    lost_hand = np.flatnonzero(~np.all(np.isfinite(body.points[:, 7]), axis=1))
    assert len(lost_hand) > 0
    names, points = body.frame(int(lost_hand[0]))
    assert 'r_wrist' not in names and len(names) == len(points)
    assert np.all(np.isfinite(points))
    names, points = body.frame(0)
    assert names == BODY_POINTS and points.shape == (9, 3)


def test_the_first_frame_is_the_first_that_sees_a_point():
    points = np.full((3, len(BODY_POINTS), 3), np.nan)
    points[1, BODY_POINTS.index('head')] = (0.1, 0.2, 1.6)
    points[2] = 0.0
    names, seen = RecordedBody(np.arange(3) * 0.01, points, 100.0).first_frame()
    assert names == ('head',) and np.allclose(seen, [[0.1, 0.2, 1.6]])
    names, seen = RecordedBody(np.zeros(1), points[:1], 100.0).first_frame()
    assert names == () and seen.shape == (0, 3)


def test_the_elbow_keeps_both_arm_lengths_within_reach():
    rng = np.random.default_rng(3)
    for _ in range(200):
        shoulder = rng.uniform(-1, 1, 3)
        wrist = shoulder + rng.uniform(-1, 1, 3) * 0.3
        distance = np.linalg.norm(wrist - shoulder)
        if not 0.05 < distance < 0.56:
            continue
        elbow = elbow_position(shoulder, wrist, 0.30, 0.27, [0.0, 0.0, -1.0])
        assert np.linalg.norm(elbow - shoulder) == pytest.approx(0.30, abs=1e-9)
        assert np.linalg.norm(elbow - wrist) == pytest.approx(0.27, abs=1e-9)


def test_out_of_reach_the_arm_points_at_the_wrist():
    elbow = elbow_position([0, 0, 0], [1.0, 0, 0], 0.30, 0.27, [0, 0, -1])
    np.testing.assert_allclose(elbow, [0.30, 0.0, 0.0], atol=1e-12)


def test_the_standing_bodys_right_wrist_is_the_hand_and_it_faces_its_yaw():
    hand = np.array([0.45, 0.05, 0.0])
    points = standing_body([0.85, 0.0], math.pi, -0.35, hand)
    named = dict(zip(BODY_POINTS, points, strict=True))
    np.testing.assert_array_equal(named['r_wrist'], hand)
    np.testing.assert_allclose(named['body'], [0.85, 0.0, -0.35])
    model = BodyModel()
    assert named['head'][2] == pytest.approx(-0.35 + model.trunk + model.neck)
    # facing -x, its right is +y
    assert named['r_shoulder'][1] > 0.0 > named['l_shoulder'][1]
    assert np.linalg.norm(named['r_elbow'] - named['r_shoulder']) == pytest.approx(0.30)


@pytest.mark.parametrize('kwargs, reason', [
    ({'upper_arm': 0.0}, 'upper_arm and forearm must be > 0'),
    ({'trunk': math.nan}, 'trunk must be a finite number >= 0 m'),
])
def test_a_bad_body_model_is_one_line(kwargs, reason):
    with pytest.raises(ValueError, match=reason):
        BodyModel(**kwargs)


def test_a_non_finite_hand_is_refused():
    with pytest.raises(ValueError, match='standing_body needs a finite place'):
        standing_body([0.85, 0.0], 0.0, 0.0, [math.nan, 0.0, 0.0])
