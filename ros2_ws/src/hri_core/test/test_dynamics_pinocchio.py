"""hri_core.dynamics checked against pinocchio, an independent rigid-body dynamics library.

test_dynamics.py checks the model against its own closed forms (energy, finite differences);
an error shared by the closed forms and their derivation, say a wrong pi2 or a sign in C,
would pass there. Pinocchio computes the same quantities from nothing but the arm's geometry
and link inertias, with its own recursive algorithms, so agreement here means the
hand-derived formulas of dynamics.py are those of the arm they describe. `pinocchio_arm`
builds that arm: two revolute joints about z, joint 2 at l1 along link 1's x axis, each
link's centre of mass at lc along its x axis with mass m and inertia i about z, and a `tip`
frame at l2 along link 2; gravity acts along -y of the arm plane, as in dynamics.py.

Compared on STATE_COUNT seeded random states (q within the simulator's joint limits, joint
velocities of a few rad/s, accelerations up to MAX_ACCELERATION) and several parameter sets:

- M(q) with pin.crba; C(q, dq) element-wise with pin.computeCoriolisMatrix (for this chain
  the project's Christoffel form and pinocchio's matrix coincide), and C dq with the
  non-linear effects of pin.rnea; g(q) with pin.computeGeneralizedGravity for gravity 0 (the
  horizontal SCARA) and non-zero;
- forward kinematics, the Jacobian (LOCAL_WORLD_ALIGNED, rows x and y) and its time
  derivative with pinocchio's frame placement, pin.computeFrameJacobian and
  pin.getFrameJacobianTimeVariation;
- the eq. 18 regressor: Y(q, dq, dq_r, ddq_r) theta with M ddq_r + C(q, dq) dq_r + g
  (+ F dq_r, the viscous friction, which pinocchio does not model) from pinocchio, both from
  crba/computeCoriolisMatrix/computeGeneralizedGravity and from pinocchio's own joint torque
  regressor. Pinocchio's Python bindings have no Slotine-Li regressor, but its torque
  regressor Y_pin(q, v, a) is exact for RNEA, and C(q, dq) is linear in dq with C(q, v) v
  quadratic, so Y_pin(q, 0, ddq_r) + 1/4 [Y_pin(q, dq + dq_r, 0) - Y_pin(q, dq - dq_r, 0)]
  is Y_SL with Y_SL theta_pin = M ddq_r + C(q, dq) dq_r + g. Only the torques are compared:
  theta_pin has 10 inertial parameters a link, the project's theta is the minimal set;
- one rk4_step (both its single-state and its batched path) with an RK4 step written here
  on pinocchio's forward dynamics pin.aba, friction subtracted from the torque.

Every comparison passes when |project - pinocchio| <= TOLERANCE (1 + |pinocchio|) element-wise,
i.e. 1e-9 absolute for entries below 1 and 1e-9 relative above. The last test shows that the
oracle is not vacuous: a 1 % change of one parameter in the pinocchio model puts M far outside
the tolerance.
"""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from hri_core.dynamics import (
    ScaraParameters,
    coriolis_matrix,
    dynamic_parameters,
    forward_kinematics,
    friction_torque,
    gravity_torque,
    jacobian,
    jacobian_derivative,
    mass_matrix,
    regressor,
    rk4_step,
)

TOLERANCE = 1e-9
STATE_COUNT = 50
SEED = 15
# scara_sim/config/scara_sim.yaml: joint_lower_limits and joint_upper_limits (rad).
JOINT_LOWER_LIMITS = np.array([-2.30, -2.46])
JOINT_UPPER_LIMITS = np.array([2.30, 2.46])
MAX_SPEED = 3.0  # rad/s, joint and reference velocities
MAX_ACCELERATION = 10.0  # rad/s^2, reference accelerations
MAX_TORQUE = 20.0  # N m, the simulated drives' effort limit
SIM_STEP = 1e-3  # s, the simulator's 1 kHz step
STANDARD_GRAVITY = 9.81  # m/s^2

PARAMETER_SETS = {
    'horizontal': ScaraParameters(),
    'vertical': ScaraParameters(gravity=STANDARD_GRAVITY),
    'other_arm': ScaraParameters(l1=0.5, l2=0.4, lc1=0.2, lc2=0.35, m1=6.0, m2=1.5, i1=0.1,
                                 i2=0.02, b1=2.0, b2=0.1, gravity=1.62),
}
TIP_FRAME = 'tip'


def link_inertia(mass: float, centre_of_mass: float, inertia_z: float) -> pin.Inertia:
    """Spatial inertia of a link whose centre of mass is `centre_of_mass` m along its x axis.

    `inertia_z` (kg m^2) is the inertia about the z axis through the centre of mass, the only
    one a planar arm about z feels; the link is a slender rod along x (no inertia about x).
    """
    return pin.Inertia(mass, np.array([centre_of_mass, 0.0, 0.0]),
                       np.diag([0.0, inertia_z, inertia_z]))


def along_x(distance: float) -> pin.SE3:
    """The placement `distance` m along the parent's x axis, without rotation."""
    return pin.SE3(np.eye(3), np.array([distance, 0.0, 0.0]))


def pinocchio_arm(p: ScaraParameters) -> tuple[pin.Model, int]:
    """The 2-link arm of `p` as a pinocchio model and the id of its `tip` frame.

    Friction is not part of the model: pinocchio has no joint damping in its dynamics.
    """
    model = pin.Model()
    shoulder = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), 'shoulder')
    model.appendBodyToJoint(shoulder, link_inertia(p.m1, p.lc1, p.i1), pin.SE3.Identity())
    elbow = model.addJoint(shoulder, pin.JointModelRZ(), along_x(p.l1), 'elbow')
    model.appendBodyToJoint(elbow, link_inertia(p.m2, p.lc2, p.i2), pin.SE3.Identity())
    tip = model.addFrame(pin.Frame(TIP_FRAME, elbow, along_x(p.l2), pin.FrameType.OP_FRAME))
    model.gravity = pin.Motion(np.array([0.0, -p.gravity, 0.0]), np.zeros(3))
    return model, tip


def pinocchio_mass_matrix(model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """M(q) from pin.crba, which fills the upper triangle only, made symmetric."""
    upper = np.triu(pin.crba(model, data, q))
    return upper + np.triu(upper, 1).T


def assert_matches(project, reference, what: str) -> None:
    """Assert |project - reference| <= TOLERANCE (1 + |reference|) element-wise."""
    np.testing.assert_allclose(project, reference, rtol=TOLERANCE, atol=TOLERANCE,
                               err_msg=what)


@pytest.fixture(scope='module')
def states():
    """STATE_COUNT seeded random (q, dq, dq_r, ddq_r, tau), each of shape (STATE_COUNT, 2)."""
    rng = np.random.default_rng(SEED)
    shape = (STATE_COUNT, 2)
    return (rng.uniform(JOINT_LOWER_LIMITS, JOINT_UPPER_LIMITS, shape),
            rng.uniform(-MAX_SPEED, MAX_SPEED, shape),
            rng.uniform(-MAX_SPEED, MAX_SPEED, shape),
            rng.uniform(-MAX_ACCELERATION, MAX_ACCELERATION, shape),
            rng.uniform(-MAX_TORQUE, MAX_TORQUE, shape))


@pytest.fixture(params=list(PARAMETER_SETS.values()), ids=list(PARAMETER_SETS))
def params(request) -> ScaraParameters:
    return request.param


def test_mass_matrix_matches_crba(states, params):
    model, _ = pinocchio_arm(params)
    data = model.createData()
    for q in states[0]:
        assert_matches(mass_matrix(q, params), pinocchio_mass_matrix(model, data, q),
                       f'M at q={q}')


def test_coriolis_matrix_matches_pinocchio_element_wise(states, params):
    model, _ = pinocchio_arm(params)
    data = model.createData()
    for q, dq in zip(states[0], states[1], strict=True):
        coriolis = pin.computeCoriolisMatrix(model, data, q, dq).copy()
        assert_matches(coriolis_matrix(q, dq, params), coriolis, f'C at q={q}, dq={dq}')


def test_coriolis_torque_matches_rnea(states, params):
    """C dq against RNEA at zero acceleration minus gravity, not via computeCoriolisMatrix."""
    model, _ = pinocchio_arm(params)
    data = model.createData()
    for q, dq in zip(states[0], states[1], strict=True):
        coriolis_torque = (pin.rnea(model, data, q, dq, np.zeros(2))
                           - pin.computeGeneralizedGravity(model, data, q))
        assert_matches(coriolis_matrix(q, dq, params) @ dq, coriolis_torque,
                       f'C dq at q={q}, dq={dq}')


@pytest.mark.parametrize('gravity', [0.0, STANDARD_GRAVITY, -3.0])
def test_gravity_torque_matches_pinocchio(states, gravity):
    params = ScaraParameters(gravity=gravity)
    model, _ = pinocchio_arm(params)
    data = model.createData()
    for q in states[0]:
        assert_matches(gravity_torque(q, params),
                       pin.computeGeneralizedGravity(model, data, q), f'g at q={q}')


def test_kinematics_match_the_tip_frame(states, params):
    """Tip position, J and dJ/dt; rows x and y of pinocchio's LOCAL_WORLD_ALIGNED frame."""
    model, tip = pinocchio_arm(params)
    data = model.createData()
    world_aligned = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for q, dq in zip(states[0], states[1], strict=True):
        pin.forwardKinematics(model, data, q, dq)
        pin.computeJointJacobians(model, data, q)
        pin.computeJointJacobiansTimeVariation(model, data, q, dq)
        pin.updateFramePlacements(model, data)
        tip_jacobian = pin.getFrameJacobian(model, data, tip, world_aligned)
        tip_jacobian_rate = pin.getFrameJacobianTimeVariation(model, data, tip, world_aligned)
        assert_matches(forward_kinematics(q, params.l1, params.l2),
                       data.oMf[tip].translation[:2], f'tip position at q={q}')
        assert_matches(jacobian(q, params.l1, params.l2), tip_jacobian[:2], f'J at q={q}')
        assert_matches(jacobian_derivative(q, dq, params.l1, params.l2), tip_jacobian_rate[:2],
                       f'dJ/dt at q={q}, dq={dq}')
        assert_matches(jacobian(q, params.l1, params.l2),
                       pin.computeFrameJacobian(model, data, q, tip, world_aligned)[:2],
                       f'J (computeFrameJacobian) at q={q}')


def slotine_li_regressor(model: pin.Model, data: pin.Data, q, dq, dq_r, ddq_r) -> np.ndarray:
    """Pinocchio's Y_SL(q, dq, dq_r, ddq_r), shape (2, 20), from its joint torque regressor.

    Y_SL theta_pin = M ddq_r + C(q, dq) dq_r + g: C(q, v) v is a quadratic form in v whose
    polarisation is C(q, dq) dq_r (the Christoffel form is symmetric in dq and dq_r).
    """
    zero = np.zeros(2)

    def torque_regressor(velocity, acceleration):
        return pin.computeJointTorqueRegressor(model, data, q, velocity, acceleration).copy()

    return torque_regressor(zero, ddq_r) + 0.25 * (torque_regressor(dq + dq_r, zero)
                                                   - torque_regressor(dq - dq_r, zero))


def test_regressor_torque_matches_pinocchio_dynamics(states, params):
    model, _ = pinocchio_arm(params)
    data = model.createData()
    theta = dynamic_parameters(params)
    theta_pin = np.concatenate([inertia.toDynamicParameters() for inertia in model.inertias[1:]])
    for q, dq, dq_r, ddq_r in zip(*states[:4], strict=True):
        project_torque = regressor(q, dq, dq_r, ddq_r, params.gravity) @ theta
        friction = friction_torque(dq_r, params)
        rigid_body_torque = (pinocchio_mass_matrix(model, data, q) @ ddq_r
                             + pin.computeCoriolisMatrix(model, data, q, dq) @ dq_r
                             + pin.computeGeneralizedGravity(model, data, q))
        where = f'q={q}, dq={dq}, dq_r={dq_r}, ddq_r={ddq_r}'
        assert_matches(project_torque, rigid_body_torque + friction, f'Y theta at {where}')
        regressor_torque = slotine_li_regressor(model, data, q, dq, dq_r, ddq_r) @ theta_pin
        assert_matches(project_torque, regressor_torque + friction,
                       f'Y theta against Y_SL theta_pin at {where}')


def pinocchio_rk4_step(model, data, q, dq, tau, dt, p: ScaraParameters):
    """One classical RK4 step of pin.aba with the viscous friction taken off the torque."""
    damping = np.array([p.b1, p.b2])

    def acceleration(position, velocity):
        return pin.aba(model, data, position, velocity, tau - damping * velocity).copy()

    k1q, k1v = dq, acceleration(q, dq)
    k2q = dq + 0.5 * dt * k1v
    k2v = acceleration(q + 0.5 * dt * k1q, k2q)
    k3q = dq + 0.5 * dt * k2v
    k3v = acceleration(q + 0.5 * dt * k2q, k3q)
    k4q = dq + dt * k3v
    k4v = acceleration(q + dt * k3q, k4q)
    return (q + dt / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q),
            dq + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))


@pytest.mark.parametrize('dt', [SIM_STEP, 1e-2])
def test_rk4_step_matches_an_rk4_step_of_aba(states, params, dt):
    model, _ = pinocchio_arm(params)
    data = model.createData()
    q, dq, tau = states[0], states[1], states[4]
    batch_q, batch_dq = rk4_step(q, dq, tau, dt, params)
    for i in range(STATE_COUNT):
        expected_q, expected_dq = pinocchio_rk4_step(model, data, q[i], dq[i], tau[i], dt,
                                                     params)
        single_q, single_dq = rk4_step(q[i], dq[i], tau[i], dt, params)
        where = f'q={q[i]}, dq={dq[i]}, tau={tau[i]}, dt={dt}'
        assert_matches(single_q, expected_q, f'q after one step (single state) at {where}')
        assert_matches(single_dq, expected_dq, f'dq after one step (single state) at {where}')
        assert_matches(batch_q[i], expected_q, f'q after one step (batch) at {where}')
        assert_matches(batch_dq[i], expected_dq, f'dq after one step (batch) at {where}')


@pytest.mark.parametrize('field', ['m2', 'lc2', 'i1'])
def test_a_one_percent_parameter_change_breaks_the_mass_matrix_match(states, field):
    params = PARAMETER_SETS['horizontal']
    perturbed = dataclasses.replace(params, **{field: getattr(params, field) * 1.01})
    model, _ = pinocchio_arm(perturbed)
    data = model.createData()
    mismatch = max(np.max(np.abs(mass_matrix(q, params) - pinocchio_mass_matrix(model, data, q)))
                   for q in states[0])
    assert mismatch > 1e3 * TOLERANCE
