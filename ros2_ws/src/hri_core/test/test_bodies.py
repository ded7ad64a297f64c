"""Unit tests of hri_core.bodies: capsule distances against coal, the fitted robot capsules,
the point Jacobian against finite differences, the person's capsules."""

import math

import coal
import numpy as np
import pytest

from hri_core import capsule_kernels
from hri_core.bodies import (
    HUMAN_CAPSULES,
    Capsules,
    capsule_distances,
    fit_capsule,
    human_capsules,
    panda_package_dirs,
    pinocchio_chain,
    robot_body,
    seen_body_points,
)
from hri_core.human_body import BODY_POINTS, standing_body
from hri_core.robot_model import robot_model


@pytest.fixture(scope='module')
def panda():
    model = robot_model('panda')
    return model, robot_body(model, panda_package_dirs())


def coal_capsule(a, b, radius):
    """coal's capsule (along z) and its placement for the segment a-b."""
    length = float(np.linalg.norm(b - a))
    z = np.array([0.0, 0.0, 1.0])
    axis = (b - a) / length if length > 0.0 else z
    v, cosine = np.cross(z, axis), float(z @ axis)
    sine = float(np.linalg.norm(v))
    if sine < 1e-12:
        rotation = np.eye(3) if cosine > 0.0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        rotation = np.eye(3) + k + k @ k * ((1.0 - cosine) / sine ** 2)
    return coal.Capsule(radius, length), coal.Transform3s(rotation, 0.5 * (a + b))


def coal_distance(a1, b1, r1, a2, b2, r2):
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    coal.distance(*coal_capsule(a1, b1, r1), *coal_capsule(a2, b2, r2), request, result)
    return result.min_distance, np.array(result.getNearestPoint1()), \
        np.array(result.getNearestPoint2())


def random_capsules(rng, count, sphere_share=0.2):
    a = rng.uniform(-0.5, 0.5, (count, 3))
    b = a + rng.uniform(-0.4, 0.4, (count, 3))
    spheres = rng.uniform(size=count) < sphere_share
    b[spheres] = a[spheres]
    return Capsules(tuple(f'c{k}' for k in range(count)), a, b, rng.uniform(0.01, 0.1, count))


def test_capsule_distances_equal_coals_on_random_pairs():
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(40):
        robot, human = random_capsules(rng, 9), random_capsules(rng, 10)
        result = capsule_distances(robot, human)
        for i in range(9):
            for j in range(10):
                distance, point1, point2 = coal_distance(robot.a[i], robot.b[i],
                                                         robot.radius[i], human.a[j],
                                                         human.b[j], human.radius[j])
                assert result.distance[i, j] == pytest.approx(distance, abs=1e-9)
                if distance > 1e-6:  # apart: the closest points are coal's too
                    np.testing.assert_allclose(result.robot_point[i, j], point1, atol=1e-9)
                    np.testing.assert_allclose(result.human_point[i, j], point2, atol=1e-9)
                checked += 1
    assert checked == 3600


@pytest.mark.parametrize('planar', [False, True])
def test_the_compiled_distances_equal_the_numpy_reference(planar):
    # Degenerate pairs among them: random_capsules makes some spheres, and the last two
    # human capsules copy robot capsule 0 shifted (parallel axes) and robot capsule 1 (the
    # same axis).
    rng = np.random.default_rng(13)
    shift = np.array([[0.05, -0.02, 0.01], [0.0, 0.0, 0.0]])
    for _ in range(30):
        robot, human = random_capsules(rng, 9), random_capsules(rng, 10)
        human = Capsules(human.names, np.vstack([human.a[:8], robot.a[:2] + shift]),
                         np.vstack([human.b[:8], robot.b[:2] + shift]), human.radius)
        compiled = capsule_distances(robot, human, planar=planar)
        reference = capsule_distances(robot, human, planar=planar, compiled=False)
        np.testing.assert_allclose(compiled.distance, reference.distance, rtol=0, atol=1e-12)
        np.testing.assert_allclose(compiled.normal, reference.normal, rtol=0, atol=1e-9)
        for i, j in ((0, 0), (3, 9), (8, 5)):
            assert compiled.parameters(i, j) == pytest.approx(reference.parameters(i, j),
                                                              abs=1e-9)


def test_pair_gives_one_pairs_figures_and_closest_the_least():
    rng = np.random.default_rng(5)
    robot, human = random_capsules(rng, 4), random_capsules(rng, 6)
    result = capsule_distances(robot, human)
    i, j = result.closest()
    assert result.distance[i, j] == result.distance.min()
    distance, robot_point, human_point, normal = result.pair(i, j)
    assert distance == result.distance[i, j]
    np.testing.assert_allclose(robot_point, result.robot_point[i, j])
    np.testing.assert_allclose(human_point, result.human_point[i, j])
    np.testing.assert_allclose(normal, result.normal[i, j])
    assert np.linalg.norm(normal) == pytest.approx(1.0)


def test_parallel_and_crossing_centre_lines():
    robot = Capsules(('r',), np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([0.1]))
    parallel = Capsules(('h',), np.array([[0.5, 0.5, 0]]), np.array([[2.0, 0.5, 0]]),
                        np.array([0.1]))
    assert capsule_distances(robot, parallel).distance[0, 0] == pytest.approx(0.3)
    crossing = Capsules(('h',), np.array([[0.5, -1, 0]]), np.array([[0.5, 1, 0]]),
                        np.array([0.1]))
    result = capsule_distances(robot, crossing)
    assert result.distance[0, 0] == pytest.approx(-0.2)
    assert np.linalg.norm(result.normal[0, 0]) == pytest.approx(1.0)


def test_a_planar_arm_measures_in_its_plane():
    robot = Capsules(('r',), np.zeros((1, 3)), np.array([[0.5, 0, 0]]), np.array([0.05]))
    head_high = Capsules(('head',), np.array([[0.8, 0, 1.2]]), np.array([[0.8, 0, 1.2]]),
                         np.array([0.2]))
    assert capsule_distances(robot, head_high, planar=True).distance[0, 0] == \
        pytest.approx(0.8 - 0.5 - 0.05 - 0.2)


def test_the_panda_has_a_capsule_per_link_and_the_hand_is_the_tool(panda):
    _, body = panda
    assert body.names == tuple(f'panda_link{k}' for k in range(8)) + ('panda_hand',)
    assert body.tool == 'panda_hand' and body.joint[0] == 0 and not body.planar
    assert np.all((body.radius > 0.04) & (body.radius < 0.11))


def test_the_fitted_capsules_hold_every_collision_vertex(panda):
    import pinocchio as pin

    model, body = panda
    q = model.home + np.random.default_rng(2).uniform(-0.5, 0.5, model.dof)
    capsules = body.capsules(q)
    full = pin.buildModelFromXML(model.urdf)
    geometry = pin.buildGeomFromUrdfString(full, model.urdf, pin.COLLISION,
                                           package_dirs=list(panda_package_dirs()))
    full_q = np.concatenate([q, np.zeros(full.nq - model.dof)])
    data, geometry_data = full.createData(), pin.GeometryData(geometry)
    pin.updateGeometryPlacements(full, data, geometry, geometry_data, full_q)
    for item, placement in zip(geometry.geometryObjects, geometry_data.oMg, strict=True):
        if not hasattr(item.geometry, 'vertices'):
            continue
        link = item.name.rsplit('_', 1)[0]
        k = body.names.index(link)
        vertices = np.asarray(item.geometry.vertices()) @ placement.rotation.T \
            + placement.translation
        point_capsules = Capsules(('v',) * len(vertices), vertices, vertices,
                                  np.zeros(len(vertices)))
        one = Capsules((link,), capsules.a[k:k + 1], capsules.b[k:k + 1], capsules.radius[k:k + 1])
        assert capsule_distances(one, point_capsules).distance.max() <= 1e-9, link


def test_fit_capsule_holds_its_points_and_refuses_none():
    rng = np.random.default_rng(4)
    points = rng.normal(size=(200, 3)) * (0.2, 0.05, 0.05)
    a, b, radius = fit_capsule(points)
    one = Capsules(('c',), a[None], b[None], np.array([radius]))
    cloud = Capsules(('p',) * 200, points, points, np.zeros(200))
    assert capsule_distances(one, cloud).distance.max() <= 1e-9
    assert np.linalg.norm(b - a) > 0.3  # along x, the long axis
    with pytest.raises(ValueError, match='a capsule needs at least one finite point'):
        fit_capsule(np.zeros((0, 3)))


def finite_difference_check(model, body, q, rng):
    for k in range(len(body.names)):
        capsules = body.capsules(q)
        weight = rng.uniform()
        point = capsules.a[k] + weight * (capsules.b[k] - capsules.a[k])
        jacobian = body.point_jacobian(q, k, point)
        step = 1e-6
        numeric = np.zeros_like(jacobian)
        for joint in range(model.dof):
            dq = np.zeros(model.dof)
            dq[joint] = step
            plus, minus = body.capsules(q + dq), body.capsules(q - dq)
            numeric[:, joint] = ((plus.a[k] + weight * (plus.b[k] - plus.a[k]))
                                 - (minus.a[k] + weight * (minus.b[k] - minus.a[k]))) / (2 * step)
        np.testing.assert_allclose(jacobian, numeric, atol=1e-7, err_msg=body.names[k])


def test_the_point_jacobian_matches_finite_differences_on_the_panda(panda):
    model, body = panda
    rng = np.random.default_rng(8)
    for _ in range(5):
        finite_difference_check(model, body, model.home + rng.uniform(-0.6, 0.6, model.dof),
                                rng)


@pytest.mark.parametrize('robot', ['panda', 'scara'])
def test_normal_rows_are_the_point_jacobians_along_the_normals(robot, panda):
    """normal_rows(q, capsules, points, normals) row k = n_k^T point_jacobian(q, k, p_k),
    every capsule (the Panda's base link included: a zero row)."""
    model, body = panda if robot == 'panda' else (robot_model('scara'),
                                                  robot_body(robot_model('scara')))
    rng = np.random.default_rng(10)
    q = model.home + rng.uniform(-0.5, 0.5, model.dof)
    capsules = np.arange(len(body.names)).repeat(2)
    points = rng.normal(size=(capsules.size, 3))
    normals = rng.normal(size=(capsules.size, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    expected = [n @ body.point_jacobian(q, k, p)
                for k, p, n in zip(capsules, points, normals, strict=True)]
    np.testing.assert_allclose(body.normal_rows(q, capsules, points, normals), expected,
                               atol=1e-12)


@pytest.mark.parametrize('robot', ['panda', 'scara'])
def test_the_chain_places_the_capsules_and_forms_the_rows_as_pinocchio(robot, panda):
    """The compiled chain (capsule_kernels, which RobotBody.capsules runs on) on random
    configurations within the limits gives the capsules' ends from the model's joint frames
    and normal_rows' rows (pinocchio's, the SCARA's closed form) to 1e-12."""
    model, body = panda if robot == 'panda' else (robot_model('scara'),
                                                  robot_body(robot_model('scara')))
    rng = np.random.default_rng(12)
    joints = np.array(body.joint, dtype=np.int64)
    for _ in range(20):
        q = rng.uniform(model.limits.lower, model.limits.upper)
        rotations, origins = capsule_kernels.chain_frames(q, *body.chain)
        a, axis = capsule_kernels.placed_capsules(rotations, origins, joints, body.local_a,
                                                  body.local_b)
        # The model's own frames (pinocchio's, the SCARA's closed form) are the oracle.
        frames, places = model.joint_frames(q)
        expected_a = np.einsum('kij,kj->ki', frames[joints], body.local_a) + places[joints]
        expected_b = np.einsum('kij,kj->ki', frames[joints], body.local_b) + places[joints]
        np.testing.assert_allclose(a, expected_a, atol=1e-12)
        np.testing.assert_allclose(axis, expected_b - expected_a, atol=1e-12)
        np.testing.assert_allclose(body.capsules(q).b, expected_b, atol=1e-12)
        points = rng.normal(size=(joints.size, 3))
        normals = rng.normal(size=(joints.size, 3))
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        rows = np.zeros((joints.size, model.dof))
        for k in range(joints.size):
            capsule_kernels.add_normal_row(rotations, origins, body.chain.parents,
                                           body.chain.axes, body.chain.prismatic,
                                           body.chain.index, joints[k], points[k], normals[k],
                                           1.0, rows[k])
        np.testing.assert_allclose(
            rows, body.normal_rows(q, range(joints.size), points, normals), atol=1e-12)


def test_a_chain_holds_revolute_and_prismatic_joints_only():
    """A prismatic joint slides its child along the axis; a spherical joint has no chain (the
    barrier then takes pinocchio's path)."""
    import pinocchio as pin

    slide = pin.Model()
    joint = slide.addJoint(0, pin.JointModelPX(), pin.SE3(np.eye(3), np.array([0, 0, 0.5])),
                           'slide')
    chain = pinocchio_chain(slide)
    rotations, origins = capsule_kernels.chain_frames(np.array([0.25]), *chain)
    np.testing.assert_allclose(origins[joint], [0.25, 0.0, 0.5])
    row = np.zeros(1)
    capsule_kernels.add_normal_row(rotations, origins, chain.parents, chain.axes,
                                   chain.prismatic, chain.index, joint, np.zeros(3),
                                   np.array([0.6, 0.8, 0.0]), 1.0, row)
    np.testing.assert_allclose(row, [0.6])
    ball = pin.Model()
    ball.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), 'ball')
    assert pinocchio_chain(ball) is None


def test_the_scaras_capsules_and_its_analytic_jacobian():
    model = robot_model('scara')
    body = robot_body(model)
    assert body.names == ('link1', 'link2') and body.tool == 'link2' and body.planar
    q = np.array([0.4, 1.1])
    capsules = body.capsules(q)
    np.testing.assert_allclose(capsules.b[1], model.tool_position(q), atol=1e-12)
    rng = np.random.default_rng(9)
    for _ in range(5):
        finite_difference_check(model, body, rng.uniform(-2.0, 2.0, 2), rng)


def test_the_persons_capsules_leave_out_what_is_missing():
    points = standing_body([0.8, 0.0], math.pi, 0.0, [0.45, 0.0, 0.3])
    full = human_capsules(BODY_POINTS, points)
    assert full.names == tuple(c[0] for c in HUMAN_CAPSULES) and len(full) == 10
    np.testing.assert_allclose(full.radius[full.names.index('torso')], 0.217)
    keep = [k for k, name in enumerate(BODY_POINTS) if name != 'r_elbow']
    partial = human_capsules([BODY_POINTS[k] for k in keep], points[keep])
    assert 'r_upper_arm' not in partial.names and 'r_forearm' not in partial.names
    assert 'r_hand' in partial.names and len(partial) == 8
    assert len(human_capsules([], np.zeros((0, 3)))) == 0


@pytest.mark.parametrize('names, points, reason', [
    (['head'], [[math.nan, 0.0, 0.0]], 'body points must be finite'),
    (['head', 'head'], [[0.0, 0, 0], [1.0, 0, 0]], 'repeated body point names'),
    (['head'], [[0.0, 0, 0], [1.0, 0, 0]], '1 names for 2 points'),
])
def test_bad_body_points_are_one_line(names, points, reason):
    with pytest.raises(ValueError, match=reason):
        human_capsules(names, points)


def test_the_torso_with_one_of_its_points_lost_is_a_sphere_round_the_other():
    # As in PickPlaceCloseHuman_2 (74 frames with one of hip and collar lost) and TossTheCan_0
    # (12): the trunk is kept, where an arm's capsule with a point lost is left out.
    collar, hip = [1.0, 0.0, 1.3], [1.0, 0.0, 0.9]
    for names, points, centre in ((['torso'], [collar], collar), (['body'], [hip], hip)):
        trunk = human_capsules(names, points)
        assert trunk.names == ('torso',)
        np.testing.assert_array_equal(trunk.a, [centre])
        np.testing.assert_array_equal(trunk.b, [centre])
        np.testing.assert_allclose(trunk.radius, [0.217])
    assert human_capsules(['head'], [[1.0, 0.0, 1.6]]).names == ('head',)
    assert human_capsules(['r_elbow'], [[1.0, 0.2, 1.1]]).names == ()


def test_a_body_points_nan_are_lost_points_and_the_rest_is_kept():
    names = ['head', 'torso', 'body', 'r_wrist']
    points = [[1.0, 0.0, 1.6], [1.0, 0.0, 1.3], [1.0, 0.0, 0.9], [math.nan, 0.5, 1.0]]
    seen, kept, lost, unknown = seen_body_points(names, points)
    assert (seen, lost, unknown) == (('head', 'torso', 'body'), ('r_wrist',), ())
    np.testing.assert_array_equal(kept, np.array(points[:3]))
    assert human_capsules(seen, kept).names == ('head', 'torso')
    everything = seen_body_points(names[:3], points[:3])
    assert everything.names == tuple(names[:3]) and everything.lost == ()
    # Names that are no REP-155 body point: set apart to be named, not silently dropped.
    other = seen_body_points(['Head', 'torso', 'head_1'], [[1.0, 0, 1.6], [1.0, 0, 1.3],
                                                           [math.nan, 0, 0]])
    assert (other.names, other.lost, other.unknown) == (('torso',), (), ('Head', 'head_1'))
    with pytest.raises(ValueError, match='4 names for 3 points'):
        seen_body_points(names, points[:3])


def test_fastest_speed_is_the_fastest_capsule_end():
    points = [[0.5, 0.0, 0.0], [0.8, 0.0, 0.0]]
    still = human_capsules(['r_elbow', 'r_wrist'], points)
    assert still.fastest_speed == 0.0
    moving = human_capsules(['r_elbow', 'r_wrist'], points,
                            velocities=[[0.0, 0.3, 0.0], [0.0, 0.0, -1.2]])
    assert moving.fastest_speed == pytest.approx(1.2)
