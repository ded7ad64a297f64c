"""Topic-level tests of the `learner` node on bags that carry their robot, in 3-D.

A Panda demonstration written with rosbags (the Panda's URDF on /robot_description and its 7
joints on /joint_states only, no /ee_position; a scripted push along a straight 3-D line
through the Panda's inverse kinematics) is learned to the expected task through the URDF's
forward kinematics; a bag with neither /ee_position nor /robot_description, or whose joint
states name joints its URDF lacks, is refused with one error line and a non-zero exit.
"""

from pathlib import Path

import numpy as np
import pytest

from hri_core.robot_model import robot_model
from hri_demo_learning.synthetic_demonstration import (
    JointDemonstration,
    joint_path,
    push_path,
    write_demonstration_bag,
)
from tests.test_learner import assert_learned, assert_refused, run_once

pytestmark = pytest.mark.integration

PANDA = robot_model('panda')
OFFSET = np.array([0.12, 0.15, -0.18])  # m, x_r from the tool at the home pose: below, beside
PUSHES = {'follow': (0.27, 0.041), 'avoid': (0.05, 0.183)}  # m from x_r: start, stop


def panda_bag(folder: Path, behaviour: str, urdf: str = PANDA.urdf,
              joint_names: tuple[str, ...] = ()) -> str:
    """A 5.5 s Panda demonstration at 500 Hz: 1 s at rest, a 3 s push along the line from x_r
    through the home pose's tool point (from `start` to `stop` m from x_r), at rest after."""
    times = np.arange(0.0, 5.5, 2e-3)
    home = PANDA.tool_position(PANDA.home)
    reference = home + OFFSET
    away = -OFFSET / np.linalg.norm(OFFSET)
    start, stop = PUSHES[behaviour]
    points = push_path(times, reference + start * away, reference + stop * away, 1.0, 3.0)
    first = joint_path(PANDA, points[:1], PANDA.home)[0]
    bag = folder / behaviour
    # Other joint names with the same values: the joint states of another arm.
    write_demonstration_bag(bag, JointDemonstration(
        joint_names or PANDA.joint_names, times, joint_path(PANDA, points, first), reference,
        urdf=urdf))
    return str(bag)


@pytest.mark.parametrize('behaviour', ['follow', 'avoid'])
def test_a_panda_bag_of_joint_states_and_its_urdf_learns_its_task(nodes, tmp_path, behaviour):
    bag = panda_bag(tmp_path, behaviour)
    output = tmp_path / 'tasks'
    code, log = run_once(nodes, output, bags=[bag])
    record = assert_learned(code, log, output / f'{behaviour}.yaml')
    assert record.s == 1
    if behaviour == 'follow':
        assert record.d1 == 0.0
        assert record.d2 == pytest.approx(0.041, abs=0.002)
    else:
        assert record.d1 == pytest.approx(0.183, abs=0.002)
        assert record.d2 == 2.0
    assert record.k > 0.0


def test_a_bag_with_neither_ee_position_nor_robot_description_is_refused(nodes, tmp_path):
    bag = panda_bag(tmp_path, 'follow', urdf='')
    output = tmp_path / 'tasks'
    code, log = run_once(nodes, output, bags=[bag])
    assert_refused(code, log, output, 'has neither /ee_position nor /robot_description')


def test_joint_states_that_name_joints_its_urdf_lacks_are_refused(nodes, tmp_path):
    names = tuple(f'arm_joint{index}' for index in range(1, 8))
    bag = panda_bag(tmp_path, 'follow', joint_names=names)
    output = tmp_path / 'tasks'
    code, log = run_once(nodes, output, bags=[bag])
    assert_refused(code, log, output, '/joint_states names joints its URDF (panda) lacks: '
                                      'arm_joint1')
