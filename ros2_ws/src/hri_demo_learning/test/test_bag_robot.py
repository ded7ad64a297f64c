"""Unit tests of bags that carry their robot: /robot_description (the URDF) with /joint_states.

The tool path comes from the bag's URDF (pinocchio, batched) where the bag has no
/ee_position; a bag with neither, joint states that name joints the URDF lacks, or an
unreadable URDF are refused in one line; a scripted Panda follow learns to Table I's follow.
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from hri_core.cdr import joint_state_template, point_stamped_template
from hri_core.dynamics import forward_kinematics
from hri_core.robot_model import robot_model, scara_urdf
from hri_demo_learning.bag_io import BagError, BagWriter, read_demonstration
from hri_demo_learning.learning import LearningError, LearningSettings, learn_from_bags
from hri_demo_learning.synthetic_demonstration import (
    JointDemonstration,
    joint_path,
    push_path,
    write_demonstration_bag,
)

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'learner.yaml'
PANDA = robot_model('panda')
SETTINGS = LearningSettings.from_parameters(
    yaml.safe_load(CONFIG.read_text())['learner']['ros__parameters'])
T0 = 1_700_000_000 * 10**9  # ns
STRING = 'std_msgs/msg/String'


def random_panda_path(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(PANDA.limits.lower, PANDA.limits.upper, size=(count, PANDA.dof))


def write_bag(path, names, q, urdfs=(), ee=None, reference=(0.4, 0.1, 0.5)) -> None:
    """/robot_description (each of `urdfs`), /joint_states of `names` (q (N, len(names))),
    /demo/reference once, /ee_position (ee (N, 3)) if given; 1 kHz."""
    joints = joint_state_template(names)
    point = point_stamped_template('base')
    with BagWriter(path) as writer:
        if urdfs:
            description = writer.add_topic('/robot_description', STRING)
            for text in urdfs:
                writer.write(description, T0, writer.typestore.serialize_cdr(
                    writer.typestore.types[STRING](data=text), STRING))
        states = writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState')
        references = writer.add_topic('/demo/reference', 'geometry_msgs/msg/PointStamped')
        writer.write(references, T0, point.encode(list(reference), stamp=(0, 0)))
        tool = None if ee is None else writer.add_topic('/ee_position',
                                                        'geometry_msgs/msg/PointStamped')
        zeros = [0.0] * len(names)
        for index, row in enumerate(q):
            stamp = T0 + index * 10**6
            writer.write(states, stamp, joints.encode(list(row), zeros, zeros, stamp=(0, 0)))
            if tool is not None:
                writer.write(tool, stamp, point.encode(list(ee[index]), stamp=(0, 0)))


def test_positions_come_from_the_bags_urdf_through_pinocchio(tmp_path):
    q = random_panda_path(300, seed=1)
    write_bag(tmp_path / 'panda', PANDA.joint_names, q, urdfs=[PANDA.urdf])
    demo = read_demonstration(tmp_path / 'panda')
    assert (demo.position_source, demo.robot) == ('/joint_states', 'panda')
    assert demo.kinematics == 'the URDF of panda, tool frame panda_hand_tcp'
    assert demo.reach == pytest.approx(PANDA.reach)
    expected = np.array([PANDA.tool_position(row) for row in q])
    np.testing.assert_allclose(demo.positions, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(demo.references, np.tile([0.4, 0.1, 0.5], (300, 1)))
    slow = read_demonstration(tmp_path / 'panda', fast=False)  # rosbags deserialises each
    np.testing.assert_array_equal(slow.positions, demo.positions)


def test_joint_states_in_another_order_with_the_fingers_read_the_same(tmp_path):
    q = random_panda_path(50, seed=2)
    names = ['panda_finger_joint1', *PANDA.joint_names[::-1]]
    fingers = np.full((50, 1), 0.02)
    write_bag(tmp_path / 'panda', names, np.hstack([fingers, q[:, ::-1]]), urdfs=[PANDA.urdf])
    demo = read_demonstration(tmp_path / 'panda')
    np.testing.assert_allclose(demo.positions, [PANDA.tool_position(row) for row in q],
                               atol=1e-12)


def test_the_tool_frame_setting_picks_another_link(tmp_path):
    q = random_panda_path(20, seed=3)
    write_bag(tmp_path / 'panda', PANDA.joint_names, q, urdfs=[PANDA.urdf])
    flange = read_demonstration(tmp_path / 'panda', tool_frame='panda_link8')
    tcp = read_demonstration(tmp_path / 'panda')
    gap = np.linalg.norm(tcp.positions - flange.positions, axis=1)
    np.testing.assert_allclose(gap, 0.1034, atol=1e-4)  # panda_hand_tcp: 10.34 cm on


def test_the_scara_urdf_gives_the_same_positions_as_l1_l2(tmp_path):
    q = np.random.default_rng(4).uniform(-2.0, 2.0, size=(100, 2))
    write_bag(tmp_path / 'with_urdf', ['joint1', 'joint2'], q, urdfs=[scara_urdf()])
    write_bag(tmp_path / 'without', ['joint1', 'joint2'], q)
    with_urdf = read_demonstration(tmp_path / 'with_urdf')
    without = read_demonstration(tmp_path / 'without')
    assert (with_urdf.robot, without.robot, without.reach) == ('scara', '', None)
    np.testing.assert_allclose(with_urdf.positions, without.positions, atol=1e-12)
    np.testing.assert_allclose(without.positions[:, :2], forward_kinematics(q, 0.35, 0.30))


def test_ee_position_wins_over_the_urdf_which_still_gives_the_reach(tmp_path):
    q = random_panda_path(30, seed=5)
    ee = np.random.default_rng(6).uniform(-0.5, 0.5, size=(30, 3))
    write_bag(tmp_path / 'panda', PANDA.joint_names, q, urdfs=[PANDA.urdf], ee=ee)
    demo = read_demonstration(tmp_path / 'panda')
    assert (demo.position_source, demo.kinematics, demo.robot) == ('/ee_position', '',
                                                                   'panda')
    np.testing.assert_array_equal(demo.positions, ee)  # x, y and z
    assert demo.reach == pytest.approx(PANDA.reach)


def refused(bag, reason: str) -> None:
    with pytest.raises(BagError, match=reason) as error:
        read_demonstration(bag)
    assert '\n' not in str(error.value)
    with pytest.raises(LearningError, match=reason):
        learn_from_bags([str(bag)], [0.0], 'task', SETTINGS)


def test_a_bag_with_neither_ee_position_nor_robot_description_is_refused(tmp_path):
    write_bag(tmp_path / 'bare', PANDA.joint_names, random_panda_path(20, seed=7))
    refused(tmp_path / 'bare', r'has neither /ee_position nor /robot_description: the '
                               r'positions of its joints \(panda_joint1, .*\) cannot be turned')


def test_joint_states_that_name_joints_the_urdf_lacks_are_refused(tmp_path):
    names = [*PANDA.joint_names, 'elbow_camera_tilt']
    write_bag(tmp_path / 'other', names, np.zeros((20, 8)), urdfs=[PANDA.urdf])
    refused(tmp_path / 'other', r'/joint_states names joints its URDF \(panda\) lacks: '
                                'elbow_camera_tilt')


def test_joint_states_without_a_joint_of_the_chain_are_refused(tmp_path):
    write_bag(tmp_path / 'short', PANDA.joint_names[:6], np.zeros((20, 6)), urdfs=[PANDA.urdf])
    refused(tmp_path / 'short', '/joint_states lacks joints of panda between its base and '
                                'panda_hand_tcp: panda_joint7')


@pytest.mark.parametrize('urdfs, reason', [
    (['<robot name="x"><link'], 'the URDF on /robot_description: not a valid URDF'),
    ([PANDA.urdf, scara_urdf()], 'carries 2 different URDFs on /robot_description'),
    ([PANDA.urdf.replace('panda_hand_tcp', 'tcp_moved')],
     "the URDF on /robot_description: no frame 'panda_hand_tcp' in the URDF of panda"),
], ids=['not_a_urdf', 'two_urdfs', 'no_tool_frame'])
def test_a_urdf_it_cannot_use_is_refused(tmp_path, urdfs, reason):
    write_bag(tmp_path / 'bad', PANDA.joint_names, np.zeros((20, 7)), urdfs=urdfs)
    refused(tmp_path / 'bad', reason)


def test_a_scripted_panda_follow_in_3d_learns_table_ones_follow(tmp_path):
    times = np.arange(0.0, 5.5, 2e-3)
    start = PANDA.tool_position(PANDA.home)
    reference = start + np.array([0.12, 0.15, -0.18])  # x_r below, beside and ahead
    away = (start - reference) / np.linalg.norm(start - reference)
    points = push_path(times, start, reference + 0.041 * away, 1.0, 3.0)
    q = joint_path(PANDA, points, PANDA.home)
    write_demonstration_bag(tmp_path / 'follow', JointDemonstration(
        PANDA.joint_names, times, q, reference, urdf=PANDA.urdf))
    demo = read_demonstration(tmp_path / 'follow')
    np.testing.assert_allclose(demo.positions, points, atol=1e-8)  # the IK's tolerance
    record = learn_from_bags([str(tmp_path / 'follow')], [0.0], 'follow', SETTINGS).record
    assert (record.s, record.d1) == (1, 0.0)
    assert record.d2 == pytest.approx(0.041, abs=0.002)
    assert record.k > 0.0
