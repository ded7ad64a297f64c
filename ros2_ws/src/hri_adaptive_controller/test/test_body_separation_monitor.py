"""Unit tests of separation_monitor.BodySeparation: the closest pair of robot and person,
and the speeds of its points along its normal."""

import math

import numpy as np
import pytest

from hri_adaptive_controller.separation_monitor import BodySeparation
from hri_core.bodies import capsule_distances, human_capsules, robot_body
from hri_core.human_body import BODY_POINTS, standing_body
from hri_core.robot_model import robot_model
from hri_core.separation import ProtectiveSeparation

SETTINGS = ProtectiveSeparation(0.1, 0.95, 0.18, 0.1, 0.01, 0.001, 2.0, 1.6, 0.5, False)
MODEL = robot_model('scara')
Q = np.array([0.4, 1.1])


def body(t=0.0, velocity=(0.0, 0.0, 0.0)):
    return standing_body([0.8, 0.35], math.atan2(-0.35, -0.8), -0.35, [0.55, 0.45, 0.0]) \
        + np.asarray(velocity) * t


def monitor():
    return BodySeparation(robot_body(MODEL), SETTINGS, body_timeout=0.3, joint_timeout=0.2)


def test_the_pair_and_both_speeds_along_its_normal():
    separation = monitor()
    dq = np.array([0.3, -0.5])
    velocity = np.array([-0.2, 0.1, 0.0])
    separation.joints(Q, dq, 0.0)
    for k in range(3):
        assert separation.body(BODY_POINTS, body(0.01 * k, velocity), 0.01 * k, 0.01 * k)
    observed = separation.observe(0.03)
    robot = robot_body(MODEL)
    distances = capsule_distances(robot.capsules(Q), human_capsules(BODY_POINTS, body(0.02,
                                                                                      velocity)),
                                  planar=True)
    i, j = distances.closest()
    distance, robot_point, _, normal = distances.pair(i, j)
    assert observed.sample.separation == pytest.approx(max(distance, 0.0))
    assert (observed.robot_link, observed.body_part) == (robot.names[i], 'r_hand')
    assert observed.sample.human_speed == pytest.approx(-velocity @ normal, abs=1e-9)
    robot_velocity = robot.point_jacobian(Q, i, robot_point) @ dq
    assert observed.sample.robot_speed == pytest.approx(robot_velocity @ normal, abs=1e-12)


def test_no_body_a_stale_one_or_an_empty_one_gives_nothing():
    separation = monitor()
    separation.joints(Q, np.zeros(2), 0.0)
    assert separation.observe(0.0) is None
    separation.body(BODY_POINTS, body(), 0.0, 0.0)
    assert separation.observe(0.1) is not None
    assert separation.observe(0.31) is None                       # stale
    separation.body(['l_elbow'], body()[[4]], 0.5, 0.5)           # no capsule of its own
    assert separation.observe(0.5) is None
    assert not separation.body(BODY_POINTS, body(), 0.4, 0.6)     # stamp went back


def test_a_non_finite_body_is_refused_in_one_line():
    separation = monitor()
    points = body()
    points[0, 0] = math.nan
    with pytest.raises(ValueError, match='body points must be finite'):
        separation.body(BODY_POINTS, points, 0.0, 0.0)
