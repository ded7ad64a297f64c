"""hri_core.robot_model: the Panda's regressor identity, the generic SCARA against the
analytic one, Jacobian and J'dq against finite differences, and the one-line errors.

States are seeded random: q uniform within the joint limits, velocities and accelerations of
a few rad/s and rad/s^2. TOLERANCE bounds |a - b| <= TOLERANCE (1 + |b|) element-wise.
"""

import dataclasses

import numpy as np
import pytest

from hri_core.dynamics import ScaraParameters
from hri_core.robot_description import robot_name
from hri_core.robot_model import (
    KNOWN_TOOL_FRAMES,
    PANDA_TOOL_FRAME,
    ROBOT_NAMES,
    ROBOTS,
    PinocchioModel,
    RobotModel,
    ScaraModel,
    robot_model,
    scara_urdf,
)

TOLERANCE = 1e-9
STATE_COUNT = 40
SEED = 33
MAX_SPEED = 2.0  # rad/s
MAX_ACCELERATION = 10.0  # rad/s^2
STEP = 1e-6  # s or rad, central differences
DIFFERENCE_TOLERANCE = 1e-7  # central differences: O(STEP^2) truncation, O(eps/STEP) rounding
SCARA_SETS = {
    'horizontal': ScaraParameters(),
    'vertical': ScaraParameters(gravity=9.81),
    'other_arm': ScaraParameters(l1=0.5, l2=0.4, lc1=0.2, lc2=0.35, m1=6.0, m2=1.5, i1=0.1,
                                 i2=0.02, b1=2.0, b2=0.1, gravity=1.62),
}


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


def random_states(model, count=STATE_COUNT, seed=SEED):
    """`count` tuples (q, dq, dq_r, ddq_r), each (n,), q within the joint limits."""
    rng = np.random.default_rng(seed)
    n = model.dof
    for _ in range(count):
        yield (rng.uniform(model.limits.lower, model.limits.upper),
               rng.uniform(-MAX_SPEED, MAX_SPEED, n), rng.uniform(-MAX_SPEED, MAX_SPEED, n),
               rng.uniform(-MAX_ACCELERATION, MAX_ACCELERATION, n))


def assert_close(actual, expected, what, tolerance=TOLERANCE):
    np.testing.assert_allclose(actual, expected, rtol=tolerance, atol=tolerance, err_msg=what)


def model_torque(model, q, dq, dq_r, ddq_r):
    """M ddq_r + C(q, dq) dq_r + F dq_r + g(q) from the model's own matrices."""
    return (model.mass_matrix(q) @ ddq_r + model.coriolis_matrix(q, dq) @ dq_r
            + model.friction_torque(dq_r) + model.gravity_torque(q))


def test_panda_has_seven_joints_and_the_urdf_limits(panda):
    assert panda.joint_names == tuple(f'panda_joint{i}' for i in range(1, 8))
    np.testing.assert_array_equal(panda.limits.effort, [87.0] * 4 + [12.0] * 3)
    assert panda.tool_frame == PANDA_TOOL_FRAME
    assert panda.theta.size == 7 * 10 + 7
    assert np.all(panda.theta >= panda.theta_lower)
    assert np.all(panda.theta <= panda.theta_upper)


def test_panda_regressor_identity(panda):
    """Y theta = M ddq_r + C dq_r + F dq_r + g to 1e-9 on random Panda states, and Y depends
    on dq_r (the C term is not dropped)."""
    for q, dq, dq_r, ddq_r in random_states(panda):
        where = f'q={q}, dq={dq}, dq_r={dq_r}, ddq_r={ddq_r}'
        torque = panda.regressor(q, dq, dq_r, ddq_r) @ panda.theta
        assert_close(torque, model_torque(panda, q, dq, dq_r, ddq_r), f'Y theta at {where}')
    assert not np.allclose(panda.regressor(q, dq, dq_r, ddq_r),
                           panda.regressor(q, 2.0 * dq, dq_r, ddq_r))


def test_panda_regressor_against_rnea(panda):
    """At dq_r = dq the regressor gives pinocchio's inverse dynamics (RNEA) plus friction."""
    import pinocchio as pin

    for q, dq, _, ddq in random_states(panda, count=10):
        expected = pin.rnea(panda.model, panda.data, q, dq, ddq) + panda.damping * dq
        assert_close(panda.regressor(q, dq, dq, ddq) @ panda.theta, expected, f'RNEA at q={q}')


def test_panda_coriolis_makes_mdot_minus_2c_skew(panda):
    for q, dq, _, _ in random_states(panda, count=10):
        mdot = (panda.mass_matrix(q + STEP * dq) - panda.mass_matrix(q - STEP * dq)) / (2 * STEP)
        n = mdot - 2.0 * panda.coriolis_matrix(q, dq)
        assert_close(n + n.T, np.zeros_like(n), f'Mdot - 2C at q={q}', DIFFERENCE_TOLERANCE)


def test_panda_kinetic_energy_is_half_dq_m_dq(panda):
    for q, dq, _, _ in random_states(panda, count=10):
        assert panda.kinetic_energy(q, dq) == pytest.approx(
            0.5 * dq @ panda.mass_matrix(q) @ dq, rel=1e-12)
    with pytest.raises(ValueError, match='dq'):
        panda.kinetic_energy(panda.home, np.full(7, np.nan))


@pytest.mark.parametrize('name', ['panda', 'scara'])
def test_jacobian_matches_finite_differences(name, panda):
    model = panda if name == 'panda' else ScaraModel()
    for q, _, _, _ in random_states(model, count=10):
        columns = [(model.tool_position(q + STEP * e) - model.tool_position(q - STEP * e))
                   / (2 * STEP) for e in np.eye(model.dof)]
        assert_close(model.tool_jacobian(q), np.array(columns).T, f'J at q={q}',
                     DIFFERENCE_TOLERANCE)


@pytest.mark.parametrize('name', ['panda', 'scara'])
def test_acceleration_bias_matches_finite_differences(name, panda):
    """J'(q, dq) dq = d/dt (J(q) dq) at fixed dq along q(t) = q + t dq."""
    model = panda if name == 'panda' else ScaraModel()
    for q, dq, _, _ in random_states(model, count=10):
        rate = (model.tool_jacobian(q + STEP * dq) - model.tool_jacobian(q - STEP * dq)) / (
            2 * STEP)
        assert_close(model.tool_acceleration_bias(q, dq), rate @ dq, f"J'dq at q={q}",
                     DIFFERENCE_TOLERANCE)


@pytest.fixture(params=list(SCARA_SETS.values()), ids=list(SCARA_SETS))
def scara_pair(request):
    """(analytic, generic) models of one SCARA; the generic one from scara_urdf, gravity
    along -y of the arm plane as in hri_core.dynamics."""
    params = request.param
    generic = PinocchioModel(scara_urdf(params), 'tip', name='scara',
                             gravity=(0.0, -params.gravity, 0.0))
    return ScaraModel(params), generic


def test_generic_scara_equals_the_analytic_one(scara_pair):
    analytic, generic = scara_pair
    assert generic.joint_names == analytic.joint_names
    np.testing.assert_array_equal(generic.limits.lower, analytic.limits.lower)
    np.testing.assert_array_equal(generic.limits.effort, analytic.limits.effort)
    assert generic.reach == pytest.approx(analytic.reach, abs=1e-12)
    for q, dq, dq_r, ddq_r in random_states(analytic):
        where = f'q={q}, dq={dq}'
        for method, args in (('tool_position', (q,)), ('tool_jacobian', (q,)),
                             ('tool_acceleration_bias', (q, dq)), ('mass_matrix', (q,)),
                             ('coriolis_matrix', (q, dq)), ('gravity_torque', (q,)),
                             ('friction_torque', (dq,))):
            assert_close(getattr(generic, method)(*args), getattr(analytic, method)(*args),
                         f'{method} at {where}')
        assert_close(generic.regressor(q, dq, dq_r, ddq_r) @ generic.theta,
                     analytic.regressor(q, dq, dq_r, ddq_r) @ analytic.theta,
                     f'Y theta at {where}, dq_r={dq_r}, ddq_r={ddq_r}')


def test_a_one_percent_heavier_link_breaks_the_scara_match():
    params = SCARA_SETS['horizontal']
    heavier = dataclasses.replace(params, m2=1.01 * params.m2)
    generic = PinocchioModel(scara_urdf(heavier), 'tip')
    q = np.array([0.3, 1.0])
    assert np.max(np.abs(generic.mass_matrix(q) - ScaraModel(params).mass_matrix(q))) > 1e-4


def test_scara_regressor_identity_and_theta_box():
    model = ScaraModel(SCARA_SETS['vertical'])
    for q, dq, dq_r, ddq_r in random_states(model, count=10):
        assert_close(model.regressor(q, dq, dq_r, ddq_r) @ model.theta,
                     model_torque(model, q, dq, dq_r, ddq_r), f'Y theta at q={q}')
    assert np.all(model.theta >= model.theta_lower)


def test_with_inertias_scales_masses_and_damping(panda):
    scales = np.linspace(0.9, 1.1, 7)
    heavier = panda.with_inertias(scales, np.full(7, 0.5))
    masses = heavier.theta[0:70:10]
    np.testing.assert_allclose(masses, scales * panda.theta[0:70:10], rtol=1e-12)
    np.testing.assert_array_equal(heavier.damping, np.full(7, 0.5))
    np.testing.assert_array_equal(panda.damping, np.full(7, 0.003))  # the original is kept
    q, dq, dq_r, ddq_r = next(random_states(panda))
    assert_close(heavier.regressor(q, dq, dq_r, ddq_r) @ heavier.theta,
                 model_torque(heavier, q, dq, dq_r, ddq_r), 'Y theta of the scaled arm')
    with pytest.raises(ValueError, match='link scales must be 7 values > 0'):
        panda.with_inertias(np.zeros(7), np.zeros(7))


@pytest.mark.parametrize(('kwargs', 'reason'), [
    ({'robot': 'kuka'}, "unknown robot 'kuka'; expected one of scara, panda, ur3, ur5, ur10, "
                        'xarm7, z1 or a urdf_file'),
    ({}, 'give either a robot name'),
    ({'robot': 'panda', 'urdf_file': 'x.urdf'}, 'give either a robot name'),
    ({'urdf_file': 'x.urdf'}, 'a urdf_file needs a tool_frame'),
    ({'urdf_file': '/no/such.urdf', 'tool_frame': 'tip'}, 'cannot read urdf_file'),
    ({'robot': 'panda', 'tool_frame': 'no_link'}, "no frame 'no_link' in the URDF of panda"),
    ({'robot': 'scara', 'tool_frame': 'hand'}, "the SCARA's tool frame is 'tip'"),
])
def test_bad_names_give_one_line(kwargs, reason):
    with pytest.raises(ValueError, match=reason) as error:
        robot_model(**kwargs)
    assert '\n' not in str(error.value)


@pytest.mark.parametrize(('text', 'reason'), [
    ('not xml', 'not a valid URDF: '),
    ('<robot name="r"><link name="a"/><joint name="j" type="revolute"><parent link="a"/>'
     '<child link="b"/></joint><link name="b"/></robot>', 'does not specify limits'),
    ('<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="continuous">'
     '<parent link="a"/><child link="b"/></joint></robot>', "joint 'j' .* is not a 1-DoF"),
    ('<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="fixed">'
     '<parent link="a"/><child link="b"/></joint></robot>', 'no moving joint between the base'),
])
def test_bad_urdfs_give_one_line(text, reason, tmp_path):
    path = tmp_path / 'arm.urdf'
    path.write_text(text)
    with pytest.raises(ValueError, match=reason) as error:
        robot_model(urdf_file=str(path), tool_frame='b')
    assert '\n' not in str(error.value)


# Every arm of the table: (joints, the tool frame, the tool at home (m, base frame)).
KNOWN_ARMS = {
    'ur3': (6, 'tool0', (0.457, 0.194, 0.067)),
    'ur5': (6, 'tool0', (0.817, 0.191, -0.005)),
    'ur10': (6, 'tool0', (1.184, 0.256, 0.012)),
    'xarm7': (7, 'link_eef', (0.486, 0.0, 0.755)),
    'z1': (6, 'gripperStator', (0.360, 0.0, 0.492)),  # the gripper's jaw locked
}


@pytest.mark.parametrize('name', list(KNOWN_ARMS))
def test_every_arm_of_the_table_loads_by_its_name(name):
    dof, tool_frame, tool_at_home = KNOWN_ARMS[name]
    model = robot_model(name)
    assert (model.name, model.dof, model.tool_frame) == (name, dof, tool_frame)
    np.testing.assert_allclose(model.tool_position(model.home), tool_at_home, atol=1e-3)
    assert model.reach > np.linalg.norm(model.tool_position(model.home) - model.shoulder)
    # A /robot_description of it is recognised by its URDF's robot name.
    assert KNOWN_TOOL_FRAMES[robot_name(model.urdf)] == tool_frame


def test_the_table_names_every_arm_once_with_its_urdf():
    assert ROBOT_NAMES == ('scara', 'panda', *KNOWN_ARMS)
    assert all(ROBOTS[name].urdf for name in ROBOT_NAMES if name != 'scara')


def test_urdf_file_loads_like_the_name(panda, tmp_path):
    path = tmp_path / 'panda.urdf'
    path.write_text(panda.urdf)
    same = robot_model(urdf_file=str(path), tool_frame=PANDA_TOOL_FRAME)
    q = np.array([0.1, -0.5, 0.2, -2.0, 0.3, 1.5, 0.7])
    np.testing.assert_array_equal(same.tool_position(q), panda.tool_position(q))
    assert same.name == 'panda'


def test_wrong_shapes_and_non_finite_states(panda):
    with pytest.raises(ValueError, match=r'q must have shape \(7,\)'):
        panda.tool_position(np.zeros(6))
    with pytest.raises(ValueError, match='dq_r must be finite'):
        panda.regressor(np.zeros(7), np.zeros(7), np.full(7, np.nan), np.zeros(7))


def test_reach_bounds_the_tool_distance_from_the_shoulder(panda):
    """No configuration within the limits puts the tool beyond `reach` from `shoulder`; the
    bound is the chain's length, within 20 % of the farthest of 5000 random poses (0.95 m
    against 1.09 m for the Panda; exact, l1 + l2, for the SCARA)."""
    rng = np.random.default_rng(SEED)
    for model in (panda, ScaraModel()):
        distances = [np.linalg.norm(model.tool_position(
            rng.uniform(model.limits.lower, model.limits.upper)) - model.shoulder)
            for _ in range(5000)]
        assert max(distances) <= model.reach
        assert max(distances) >= 0.8 * model.reach
    np.testing.assert_allclose(panda.shoulder, [0.0, 0.0, 0.333], atol=1e-12)
    stretched = ScaraModel().tool_position(np.zeros(2))
    assert np.linalg.norm(stretched) == pytest.approx(ScaraModel().reach, abs=1e-12)


def test_the_scaras_folded_reach_is_the_hole_round_its_base():
    scara = ScaraModel()
    assert scara.folded_reach == pytest.approx(0.2223, abs=1e-4)
    rng = np.random.default_rng(SEED)
    poses = rng.uniform(scara.limits.lower, scara.limits.upper, (5000, 2))
    nearest = min(np.linalg.norm(scara.tool_position(q)) for q in poses)
    assert scara.folded_reach <= nearest <= scara.folded_reach + 0.01


@pytest.mark.parametrize('name', ['scara', 'generic_scara', 'panda'])
def test_inverse_kinematics_reaches_what_the_box_allows_nearest_the_seed(name, panda):
    """Goals the box reaches are reached (within 1 cm: the reach-round's goal counts as
    reached at 3 cm; 5.4 mm the worst here, a pose near the Panda's base), within the box;
    the SCARA's closed form takes, of its two elbows, the one nearer to the seed."""
    model = {'scara': ScaraModel(), 'panda': panda,
             'generic_scara': PinocchioModel(scara_urdf(ScaraParameters()), 'tip')}[name]
    axes = model.task_axes
    lower, upper = model.limits.lower + 0.05, model.limits.upper - 0.05
    rng = np.random.default_rng(SEED)
    for _ in range(20):
        pose = rng.uniform(lower, upper)
        goal = model.tool_position(pose)[:axes]
        seed = np.clip(pose + rng.normal(scale=0.3, size=model.dof), lower, upper)
        q = model.inverse_kinematics(goal, np.array([seed, model.home]), lower, upper)
        assert np.all((q >= lower) & (q <= upper))
        assert np.linalg.norm(model.tool_position(q)[:axes] - goal) <= 0.01
        if name == 'scara' and abs(pose[1]) > 0.3:
            np.testing.assert_allclose(q, pose, atol=1e-9)  # the seed's elbow, exactly
    if name != 'scara':
        return  # (the reach-round asks the numerical solve for goals within reach only)
    # Out of reach: the closed form stretches the arm towards it.
    towards = np.array([1.0, 1.0, 0.0])[:axes] / np.sqrt(2.0)
    far = model.inverse_kinematics(model.shoulder[:axes] + 2.0 * towards,
                                   np.array([model.home]), lower, upper)
    direction = model.tool_position(far)[:axes] - model.shoulder[:axes]
    assert direction @ towards / np.linalg.norm(direction) == pytest.approx(1.0)
    assert np.linalg.norm(direction) == pytest.approx(model.reach)


def test_the_scaras_inverse_kinematics_takes_the_elbow_the_box_allows():
    scara = ScaraModel()
    lower, upper = scara.limits.lower, np.array([scara.limits.upper[0], 0.5])
    pose = np.array([0.3, -1.2])  # the only elbow within the box's joint 2 <= 0.5
    goal = scara.tool_position(pose)[:2]
    q = scara.inverse_kinematics(goal, np.array([[0.0, 1.2]]), lower, upper)
    np.testing.assert_allclose(q, pose, atol=1e-9)
    assert np.all(np.isnan(scara.inverse_kinematics(
        np.array([np.nan, 0.2]), np.array([[0.0, 1.0]]), lower, upper)))


def test_panda_theta_box_is_the_documented_one(panda):
    """Masses >= 1 % of the URDF's, diagonal inertias and friction >= 0, the rest free."""
    names = panda.parameter_names
    for name, low, high in zip(names, panda.theta_lower, panda.theta_upper, strict=True):
        assert high == np.inf, name
        kind = name.rsplit('.', 1)[1]
        if kind == 'm':
            assert low == pytest.approx(0.01 * panda.theta[names.index(name)]), name
        elif kind in ('Ixx', 'Iyy', 'Izz', 'damping'):
            assert low == 0.0, name
        else:
            assert low == -np.inf, name
    assert names[0] == 'panda_joint1.m' and names[-1] == 'panda_joint7.damping'


def test_without_example_robot_data_the_panda_is_one_line(monkeypatch):
    from importlib import metadata

    from hri_core import robot_model as module

    def missing(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(module.metadata, 'distribution', missing)
    monkeypatch.setenv('AMENT_PREFIX_PATH', '/nonexistent')
    with pytest.raises(ValueError, match='robot panda needs the example-robot-data package'):
        robot_model('panda')


def test_the_scaras_float_rk4_step_is_the_models_to_the_bit():
    # ScaraModel.rk4_step takes scara_sim's float step for speed; it must be the same step.
    rng = np.random.default_rng(SEED)
    model = ScaraModel()
    for _ in range(STATE_COUNT):
        q = rng.uniform(model.limits.lower, model.limits.upper)
        dq, tau = rng.uniform(-MAX_SPEED, MAX_SPEED, 2), rng.uniform(-20.0, 20.0, 2)
        fast, generic = model.rk4_step(q, dq, tau, 1e-3), RobotModel.rk4_step(model, q, dq,
                                                                               tau, 1e-3)
        for mine, theirs in zip(fast, generic, strict=True):
            assert mine.shape == theirs.shape == (2,)
            assert np.array_equal(mine, theirs)
