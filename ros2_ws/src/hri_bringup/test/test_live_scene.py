"""Unit tests of the live view's scene geometry (hri_bringup.live_scene): pure, no ROS.

tests/test_live_view.py runs the live_view node and reads the scene as a Foxglove client.
"""

import math

import numpy as np
import pytest

from hri_bringup import live_scene
from hri_bringup.live_scene import (
    ArmGeometry,
    Rod,
    TaskRegion,
    arm_entity,
    arm_frames,
    arm_points,
    circle_points,
    closest_pair_entity,
    dashes,
    hand_entity,
    joint_angles,
    person_capsules,
    person_entity,
    region_bands,
    region_colours,
    region_entity,
    robot_body_entity,
    rod_pose,
    scene_entities,
)
from hri_core.bodies import HUMAN_CAPSULES, HUMAN_RADII, capsule_distances, robot_body
from hri_core.dynamics import forward_kinematics
from hri_core.human_body import BODY_POINTS, standing_body
from hri_core.robot_model import PANDA_TOOL_FRAME, ScaraModel, panda_urdf_path, scara_urdf

GEOMETRY = ArmGeometry(l1=0.35, l2=0.30)
FOLLOW = TaskRegion('follow', 1, 0.0, 0.041, 1.0, 'active')
FOLLOW_SAFE = TaskRegion('follow_safe', 1, 0.183, 0.271, 1.0, 'active')
AVOID = TaskRegion('avoid', 1, 0.183, 2.0, 1.0, 'active')


def rotate(quaternion, vector) -> np.ndarray:
    """`vector` turned by the unit quaternion (x, y, z, w)."""
    x, y, z, w = quaternion
    u = np.array([x, y, z])
    v = np.asarray(vector, float)
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def radii(points, centre) -> np.ndarray:
    return np.hypot(*(np.asarray(points)[:, :2] - np.asarray(centre[:2])).T)


def test_joint_angles_are_taken_by_name_in_any_order():
    assert joint_angles(['joint2', 'joint1'], [0.5, -0.2], ('joint1', 'joint2')) == (-0.2, 0.5)


@pytest.mark.parametrize(('names', 'positions'), [
    (['joint1'], [0.1]),                     # a joint missing
    (['joint1', 'joint2'], [0.1]),           # fewer positions than names
    (['joint1', 'joint2'], [0.1, math.nan]),  # not finite
])
def test_joint_angles_are_none_for_a_state_that_does_not_give_both(names, positions):
    assert joint_angles(names, positions, ('joint1', 'joint2')) is None


def test_the_arm_ends_where_forward_kinematics_puts_the_end_effector():
    q = (0.4, 1.1)
    base, elbow, tip = arm_points(q, 0.35, 0.30)
    assert base == (0.0, 0.0, 0.0)
    assert math.dist(base, elbow) == pytest.approx(0.35)
    assert math.dist(elbow, tip) == pytest.approx(0.30)
    assert tip[:2] == pytest.approx(tuple(forward_kinematics(q, 0.35, 0.30)))
    # scara_sim's initial_q [0, pi/2]: the end-effector at (0.35, 0.30) m.
    assert arm_points((0.0, math.pi / 2), 0.35, 0.30)[2] == pytest.approx((0.35, 0.30, 0.0))


def test_the_arm_entity_has_two_links_and_three_joints():
    entity = arm_entity((0.0, math.pi / 2), GEOMETRY)
    assert entity.id == live_scene.ARM_ENTITY
    ends = np.array([[rod.start, rod.end] for rod in entity.rods])
    assert ends == pytest.approx(np.array([[(0, 0, 0), (0.35, 0, 0)],
                                           [(0.35, 0, 0), (0.35, 0.30, 0)]]))
    assert len(entity.balls) == 3
    assert entity.balls[-1].centre == pytest.approx((0.35, 0.30, 0.0))


@pytest.mark.parametrize('end', [(0.3, 0.2, 0.0), (0.0, 0.0, 0.5), (0.0, 0.0, -0.5),
                                 (-0.2, 0.1, 0.05)])
def test_a_rod_pose_turns_the_cylinder_axis_onto_the_rod(end):
    start = (0.1, -0.1, 0.0)
    rod = Rod(start, tuple(s + e for s, e in zip(start, end, strict=True)), 0.03,
              live_scene.LINK_COLOUR)
    centre, rotation, length = rod_pose(rod)
    assert length == pytest.approx(np.linalg.norm(end))
    assert np.linalg.norm(rotation) == pytest.approx(1.0)
    assert rotate(rotation, (0, 0, 1)) == pytest.approx(np.asarray(end) / length)
    assert centre == pytest.approx(tuple((np.asarray(rod.start) + rod.end) / 2))


def test_the_frames_chain_to_the_end_effector():
    q = (0.7, -1.2)
    frames = arm_frames(q, 0.35, 0.30, 'base')
    assert [(f.parent, f.child) for f in frames] == [('base', 'link1'), ('link1', 'link2'),
                                                     ('link2', 'tool')]
    position = np.zeros(3)
    for frame in reversed(frames):  # the tool's origin, expressed in each parent in turn
        position = rotate(frame.rotation, position) + frame.translation
    assert position[:2] == pytest.approx(forward_kinematics(q, 0.35, 0.30))


def test_circle_points_lie_on_the_circle_and_dashes_pair_them():
    loop = circle_points((0.4, 0.1, 0.0), 0.2, 8)
    assert radii(loop, (0.4, 0.1)) == pytest.approx([0.2] * 8)
    pairs = dashes(loop)
    assert len(pairs) == 8 and pairs[:4] == (loop[0], loop[1], loop[2], loop[3])


def test_bands_are_the_desired_region_within_the_display_radius():
    assert region_bands(1, 0.183, 0.271, 0.5) == ((0.183, 0.271),)
    assert region_bands(1, 0.183, 2.0, 0.5) == ((0.183, 0.5),)      # open region: capped
    assert region_bands(-1, 0.1, 0.3, 0.5) == ((0.0, 0.1), (0.3, 0.5))
    assert region_bands(-1, 0.1, 2.0, 0.5) == ((0.0, 0.1),)          # outside d2 not shown


def test_the_region_colour_follows_the_event_weight():
    faded_ring, faded_shading = region_colours(0.0)
    full_ring, full_shading = region_colours(1.0)
    half_ring, _ = region_colours(0.5)
    assert faded_ring.a < half_ring.a < full_ring.a == 1.0
    assert faded_shading.a < full_shading.a
    active = live_scene.REGION_ACTIVE_COLOUR
    assert (full_ring.r, full_ring.g, full_ring.b) == pytest.approx(
        (active.r, active.g, active.b))
    assert region_colours(math.nan) == region_colours(0.0)
    assert region_colours(3.0) == region_colours(1.0)


def test_rings_of_radius_d1_and_d2_surround_the_hand():
    hand = (0.45, 0.05)
    entity = region_entity(hand, FOLLOW_SAFE, (0.35, 0.30, 0.0), display_radius=0.5)
    assert [radii(line.points, hand) for line in entity.lines] == [
        pytest.approx([0.183] * live_scene.RING_SEGMENTS),
        pytest.approx([0.271] * live_scene.RING_SEGMENTS)]
    assert not any(line.dashed for line in entity.lines)
    shaded = radii(entity.triangles[0].points, hand)
    assert shaded.min() == pytest.approx(0.183) and shaded.max() == pytest.approx(0.271)
    distance = math.dist((0.35, 0.30), hand)
    assert entity.labels[0].text == f'follow_safe  a = 1.00 (active)  |x - x_h| = {distance:.3f} m'


def test_follow_has_no_inner_ring_and_a_disc_up_to_d2():
    entity = region_entity((0.45, 0.05), FOLLOW, None, display_radius=0.5)
    assert len(entity.lines) == 1
    shaded = radii(entity.triangles[0].points, (0.45, 0.05))
    assert shaded.min() == pytest.approx(0.0, abs=1e-12)
    assert shaded.max() == pytest.approx(0.041)
    assert entity.labels[0].text == 'follow  a = 1.00 (active)'


def test_an_open_region_is_drawn_dashed_at_the_display_radius():
    entity = region_entity((0.0, 0.0), AVOID, None, display_radius=0.5)
    inner, outer = entity.lines
    assert not inner.dashed and outer.dashed
    assert radii(outer.points, (0.0, 0.0)) == pytest.approx([0.5] * len(outer.points))


@pytest.mark.parametrize('region', [
    TaskRegion('broken', 1, math.nan, 0.1, 1.0, 'active'),
    TaskRegion('broken', 1, -0.1, 0.1, 1.0, 'active'),
    None,
])
def test_no_region_is_drawn_without_a_task_or_with_bad_boundaries(region):
    assert region_entity((0.4, 0.0), region, None, 0.5).is_empty()


def test_every_entity_is_sent_even_empty_so_that_the_viewer_clears_it():
    arm, hand, region = scene_entities(None, None, None, GEOMETRY, 0.5)
    assert [arm.id, hand.id, region.id] == ['arm', 'hand', 'task_region']
    assert arm.is_empty() and hand.is_empty() and region.is_empty()
    arm, hand, region = scene_entities((0.0, 1.0), (0.45, 0.05), FOLLOW, GEOMETRY, 0.5)
    assert not (arm.is_empty() or hand.is_empty() or region.is_empty())
    assert hand_entity((math.inf, 0.0)).is_empty()


def test_the_person_is_drawn_as_the_clearances_capsules():
    points = standing_body([0.8, 0.0], math.pi, -0.35, [0.45, 0.05, 0.0])
    person = person_entity(BODY_POINTS, points)
    spheres = [name for name, start, end, _ in HUMAN_CAPSULES if start == end]
    assert len(person.rods) == len(HUMAN_CAPSULES) - len(spheres)         # 7 segments
    assert len(person.balls) == 2 * len(person.rods) + len(spheres)       # 17
    where = dict(zip(BODY_POINTS, points, strict=True))
    head = [ball for ball in person.balls if ball.centre == tuple(where['head'])]
    assert head and head[0].diameter == pytest.approx(2.0 * HUMAN_RADII['head'])
    torso = [rod for rod in person.rods
             if {rod.start, rod.end} == {tuple(where['body']), tuple(where['torso'])}]
    assert torso and torso[0].diameter == pytest.approx(2.0 * HUMAN_RADII['torso'])
    assert all(part.colour.a < 1.0 for part in (*person.rods, *person.balls))


@pytest.mark.parametrize(('names', 'points'), [
    ((), []),                                                   # no body yet
    (('head', 'head'), [[0.5, 0.0, 0.4], [0.5, 0.0, 0.4]]),     # a repeated name
    (('head',), [[math.nan, 0.0, 0.4]]),                        # not finite
])
def test_no_person_is_drawn_without_a_usable_body(names, points):
    assert person_entity(names, points).is_empty()


def test_the_robot_body_and_the_closest_pair_are_the_clearances():
    scara = ScaraModel()
    body = robot_body(scara)
    robot = body.capsules(scara.home)
    drawn = robot_body_entity(robot)
    assert len(drawn.rods) == 2 and len(drawn.balls) == 4
    assert [rod.diameter for rod in drawn.rods] == pytest.approx(2.0 * robot.radius)
    person = person_capsules(BODY_POINTS, standing_body([0.8, 0.0], math.pi, -0.35,
                                                        [0.45, 0.05, 0.0]))
    pair = closest_pair_entity(robot, person, planar=True)
    expected = capsule_distances(robot, person, planar=True)
    i, j = expected.closest()
    distance, robot_point, person_point, _ = expected.pair(i, j)
    (line,), (label,) = pair.lines, pair.labels
    np.testing.assert_allclose(line.points, [robot_point, person_point])
    assert label.text == f'{robot.names[i]} - {person.names[j]}: {distance:.3f} m'
    assert closest_pair_entity(robot, None, planar=True).is_empty()
    assert robot_body_entity(None).is_empty()


# Any arm from its URDF, in 3-D ----------------------------------------------------------------

@pytest.fixture(scope='module')
def panda():
    return live_scene.description_arm(panda_urdf_path().read_text())


def test_the_description_names_its_arm_and_tool(panda):
    assert panda.name == 'panda' and panda.tool_frame == PANDA_TOOL_FRAME
    assert panda.joint_names == tuple(f'panda_joint{i}' for i in range(1, 8))
    assert live_scene.description_arm(scara_urdf()).tool_frame == 'tip'
    assert live_scene.description_arm(panda.urdf, 'panda_link8').tool_frame == 'panda_link8'
    unknown = scara_urdf().replace('<robot name="scara">', '<robot name="arm">')
    with pytest.raises(ValueError, match="robot 'arm' is not one the suite knows"):
        live_scene.description_arm(unknown)
    with pytest.raises(ValueError, match='not a valid URDF'):
        live_scene.description_arm('<robot name="x"')
    with pytest.raises(ValueError, match="no frame 'nope'"):
        live_scene.description_arm(panda.urdf, 'nope')


def test_chain_points_run_from_the_base_through_each_joint_to_the_tool(panda):
    rng = np.random.default_rng(11)
    for _ in range(5):
        q = rng.uniform(panda.limits.lower, panda.limits.upper)
        points = live_scene.chain_points(panda, q)
        assert len(points) == 1 + 7 + 1
        assert points[0] == (0.0, 0.0, 0.0)
        assert points[1] == pytest.approx(tuple(panda.shoulder))  # joint 1 does not move
        assert points[-1] == pytest.approx(tuple(panda.tool_position(q)), abs=1e-12)
    with pytest.raises(ValueError, match=r'q must have shape \(7,\)'):
        live_scene.chain_points(panda, [0.0, 0.0])


def test_the_panda_is_drawn_as_a_pedestal_and_a_rod_per_joint(panda):
    points = live_scene.chain_points(panda, panda.home)
    entity = live_scene.chain_entity(points, GEOMETRY)
    assert len(entity.rods) == 7 + 1 and len(entity.balls) == 7 + 1
    assert entity.rods[0].start == (0.0, 0.0, 0.0) and entity.rods[0].end == points[1]
    for rod, following in zip(entity.rods[:-1], entity.rods[1:], strict=True):
        assert rod.end == following.start  # one unbroken chain
    assert entity.rods[-1].end == points[-1] == entity.balls[-1].centre
    assert entity.balls[-1].colour == live_scene.TOOL_COLOUR
    assert live_scene.chain_entity(None, GEOMETRY).is_empty()


@pytest.mark.parametrize('q', [(0.0, math.pi / 2), (0.7, -1.2)])
def test_the_scara_from_its_urdf_is_drawn_as_the_planar_scara(q):
    generic = live_scene.description_arm(scara_urdf())
    spatial = live_scene.chain_entity(live_scene.chain_points(generic, q), GEOMETRY)
    planar = arm_entity(q, GEOMETRY)
    assert len(spatial.rods) == len(planar.rods) == 2
    for mine, theirs in zip(spatial.rods + spatial.balls, planar.rods + planar.balls,
                            strict=True):
        assert type(mine) is type(theirs)
        for field in ('start', 'end', 'centre'):
            if hasattr(mine, field):
                assert getattr(mine, field) == pytest.approx(getattr(theirs, field),
                                                             abs=1e-12)


def test_the_region_in_3d_is_spheres_of_d1_and_d2_round_the_hand():
    hand = (0.4, 0.1, 0.35)
    entity = region_entity(hand, FOLLOW_SAFE, (0.4, 0.3, 0.35), 0.5, spheres=True)
    assert [ball.diameter for ball in entity.balls] == pytest.approx([2 * 0.183, 2 * 0.271])
    assert all(ball.centre == hand for ball in entity.balls)
    assert all(ball.colour == region_colours(1.0)[1] for ball in entity.balls)
    assert not entity.triangles
    for ring, radius in zip(entity.lines, (0.183, 0.271), strict=True):
        points = np.array(ring.points)
        assert radii(points, hand) == pytest.approx([radius] * len(points))
        assert points[:, 2] == pytest.approx(0.35)  # at the hand's height
    assert '|x - x_h| = 0.200 m' in entity.labels[0].text  # distance in space
    faded = region_entity(hand, TaskRegion('avoid', 1, 0.183, 2.0, 0.0, 'fading_out'),
                          None, 0.5, spheres=True)
    assert [ball.diameter for ball in faded.balls] == pytest.approx([0.366, 1.0])  # capped
    assert all(ball.colour == region_colours(0.0)[1] for ball in faded.balls)
    assert len(region_entity(hand, FOLLOW, None, 0.5, spheres=True).balls) == 1  # d1 = 0


def test_the_spatial_scene_has_the_arm_the_hand_and_the_region(panda):
    points = live_scene.chain_points(panda, panda.home)
    hand = (0.5, 0.2, 0.4)
    arm, hand_ball, region = live_scene.spatial_scene_entities(points, hand, FOLLOW_SAFE,
                                                               GEOMETRY, 0.5)
    assert [arm.id, hand_ball.id, region.id] == ['arm', 'hand', 'task_region']
    assert len(arm.rods) == 8 and hand_ball.balls[0].centre == hand
    assert len(region.balls) == 2
    assert all(e.is_empty() for e in live_scene.spatial_scene_entities(
        None, None, None, GEOMETRY, 0.5))


def test_the_chain_frames_place_each_link_and_the_tool(panda):
    frames = live_scene.chain_frames(panda, panda.home, 'base')
    names = [frame.child for frame in frames]
    assert names[:7] == [f'panda_link{i}' for i in range(1, 8)] and names[-1] == PANDA_TOOL_FRAME
    assert all(frame.parent == 'base' for frame in frames)
    assert frames[-1].translation == pytest.approx(tuple(panda.tool_position(panda.home)))
    assert all(np.linalg.norm(frame.rotation) == pytest.approx(1.0) for frame in frames)
