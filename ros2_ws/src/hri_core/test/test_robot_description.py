"""Unit tests of hri_core.robot_description: the tool frame of a URDF and the batched forward
kinematics, held equal to pinocchio's per-sample forward kinematics."""

import numpy as np
import pytest

from hri_core.dynamics import forward_kinematics
from hri_core.robot_description import (
    ToolKinematics,
    _cos_sin,
    default_tool_frame,
    description_model,
    robot_name,
    urdf_joint_names,
)
from hri_core.robot_model import PANDA_TOOL_FRAME, robot_model, scara_urdf

# A 4-joint arm with joints about unaligned axes, one of them negative, a prismatic joint, a
# turned fixed joint and one end link: what the fast paths for x, y, z axes do not cover.
ODD_ARM = """<?xml version="1.0"?>
<robot name="odd_arm">
  <link name="base"/><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <link name="flange"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/>
    <origin xyz="0 0 0.2" rpy="0 0 0"/><axis xyz="0 0 -1"/>
    <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="a"/><child link="b"/>
    <origin xyz="0.05 0 0.1" rpy="0.3 -0.2 0.1"/><axis xyz="0.6 0 0.8"/>
    <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="j3" type="prismatic"><parent link="b"/><child link="c"/>
    <origin xyz="0 0.3 0" rpy="1.5707963267948966 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-0.2" upper="0.2" effort="50" velocity="0.5"/></joint>
  <joint name="j4" type="revolute"><parent link="c"/><child link="d"/>
    <origin xyz="0.25 0 0" rpy="0 0.7 0"/><axis xyz="1 1 1"/>
    <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="tool" type="fixed"><parent link="d"/><child link="flange"/>
    <origin xyz="0.1 -0.02 0.03" rpy="0.2 0 -1.5707963267948966"/></joint>
</robot>
"""
TWO_ENDS = ODD_ARM.replace('</robot>', '  <link name="camera"/>\n  <joint name="cam" '
                           'type="fixed"><parent link="b"/><child link="camera"/></joint>\n'
                           '</robot>')


def random_joints(model, rng, count):
    return rng.uniform(model.limits.lower, model.limits.upper, size=(count, model.dof))


@pytest.mark.parametrize('urdf, tool', [('panda', PANDA_TOOL_FRAME), (ODD_ARM, 'flange')],
                         ids=['panda', 'odd_arm'])
def test_batched_tool_positions_equal_pinocchios_forward_kinematics(urdf, tool):
    rng = np.random.default_rng(5)
    model = description_model(robot_model('panda').urdf if urdf == 'panda' else urdf)
    assert model.tool_frame == tool
    q = random_joints(model, rng, 500)
    expected = np.array([model.tool_position(row) for row in q])
    np.testing.assert_allclose(ToolKinematics(model).positions(q), expected, rtol=0,
                               atol=1e-12)


def test_the_scara_urdf_gives_the_scaras_forward_kinematics_in_the_plane_z_0():
    rng = np.random.default_rng(6)
    model = description_model(scara_urdf())
    assert (model.name, model.tool_frame, model.joint_names) == ('scara', 'tip',
                                                                 ('joint1', 'joint2'))
    q = rng.uniform(-2.0, 2.0, size=(300, 2))
    points = ToolKinematics(model).positions(q)
    np.testing.assert_allclose(points[:, :2], forward_kinematics(q, 0.35, 0.30), atol=1e-12)
    assert not points[:, 2].any()
    assert model.reach == pytest.approx(0.65)


def test_cos_and_sin_through_the_half_angle_tangent_are_exact_to_a_few_ulps():
    angles = np.random.default_rng(7).uniform(-7.0, 7.0, 100_000)
    angles[:4] = (np.pi, -np.pi, 0.0, np.pi / 2)
    cos, sin = _cos_sin(angles)
    np.testing.assert_allclose(cos, np.cos(angles), rtol=0, atol=1e-15)
    np.testing.assert_allclose(sin, np.sin(angles), rtol=0, atol=1e-15)


def test_the_tool_frame_is_the_known_robots_or_the_one_end_link():
    assert default_tool_frame(robot_model('panda').urdf) == PANDA_TOOL_FRAME
    assert default_tool_frame(scara_urdf()) == 'tip'
    assert default_tool_frame(ODD_ARM) == 'flange'
    with pytest.raises(ValueError, match=r'odd_arm has 2 end links \(flange, camera\): give '
                                         'tool_frame'):
        default_tool_frame(TWO_ENDS)
    assert description_model(TWO_ENDS, 'camera').tool_frame == 'camera'
    assert robot_name(ODD_ARM) == 'odd_arm'
    assert urdf_joint_names(ODD_ARM) == ('j1', 'j2', 'j3', 'j4', 'tool')


@pytest.mark.parametrize('text, reason', [
    ('', 'the URDF is empty'),
    ('<robot name="x"><link', 'not a valid URDF: unclosed token'),
    ('<sdf version="1.6"/>', r'not a valid URDF: its root element is <sdf>, not <robot>'),
])
def test_a_text_that_is_no_urdf_is_refused_in_one_line(text, reason):
    with pytest.raises(ValueError, match=reason) as error:
        description_model(text)
    assert '\n' not in str(error.value)


def test_an_unknown_tool_frame_is_refused_in_one_line():
    with pytest.raises(ValueError, match="no frame 'gripper' in the URDF of odd_arm"):
        description_model(ODD_ARM, 'gripper')


def test_joint_positions_of_the_wrong_shape_or_not_finite_are_refused():
    kinematics = ToolKinematics(description_model(ODD_ARM))
    with pytest.raises(ValueError, match=r'joint positions must be \(N, 4\), got \(3, 2\)'):
        kinematics.positions(np.zeros((3, 2)))
    with pytest.raises(ValueError, match='joint positions must be finite'):
        kinematics.positions(np.full((2, 4), np.nan))
