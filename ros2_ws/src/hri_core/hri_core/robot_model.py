"""One interface for every arm the suite drives: kinematics of its tool point and the
linear-in-parameters dynamics of eq. 15 and 18.

`RobotModel` gives, for a serial arm of n joints:

* joint_names (n,); limits: position (rad or m), velocity (rad/s or m/s), effort (N m or N);
* the tool point's position in the base frame, x(q) (3,) in m, its Jacobian J(q) = dx/dq
  (3, n) and the bias J'(q, dq) dq (3,) in m/s^2 (eq. 14 and the reference acceleration of
  eq. 18 need both);
* the terms of eq. 15 with viscous friction, M(q) ddq + C(q, dq) dq + F dq + g(q) = tau:
  M (n, n) kg m^2, C (n, n) with Mdot - 2 C skew-symmetric (Christoffel form), F dq (n,) and
  g(q) (n,) in N m;
* the regressor of eq. 18, Y(q, dq, dq_r, ddq_r) (n, p) with
  Y theta = M ddq_r + C(q, dq) dq_r + F dq_r + g(q), the nominal theta (p,) and a box of
  physically possible values for it (theta_lower, theta_upper), for the projection of the
  adaptive law's estimate;
* reach: an upper bound of the tool point's distance from `shoulder` (3,), the origin of the
  first moving joint, over every configuration (the sum of the chain's fixed joint-to-joint
  distances and the last joint to the tool point; exact for the SCARA, l1 + l2);
* every joint's frame and Jacobian at q (the body capsules ride on them, hri_core.bodies);
* inverse kinematics of the tool point within a joint box (the controller's reach-round:
  damped least squares; the SCARA's two elbows in closed form) and, where known, the hole
  round the base (`folded_reach`: the SCARA's folded arm).

Two implementations:

* `ScaraModel`: the planar SCARA of hri_core.dynamics (analytic, the fast path); its tool
  point moves in the plane z = 0 of the base frame, so J's third row and z are zero.
* `PinocchioModel`: any serial arm from a URDF through pinocchio. Joints that are not between
  the base and the tool frame (a gripper's fingers) are locked at their neutral position, their
  links' inertia carried by the link they hang from. theta stacks each moving link's ten
  inertial parameters (pinocchio's order: m, m c_x, m c_y, m c_z, Ixx, Ixy, Iyy, Ixz, Iyz, Izz,
  the inertia about the joint frame's origin) and then each joint's viscous friction (the
  URDF's <dynamics damping>). The regressor of eq. 18 comes from pinocchio's joint torque
  regressor Y_pin(q, v, a; gravity) (Y_pin theta = RNEA, quadratic in v, linear in a and in
  gravity): because the Christoffel C satisfies C(q, v) w = C(q, w) v,
  Y = 1/4 [Y_pin(q, dq + dq_r, 2 ddq_r; 2 g) - Y_pin(q, dq - dq_r, -2 ddq_r; -2 g)] exactly
  (two calls on two copies of the model with gravity scaled by +-2).

`robot_model(NAME)` builds the arm NAME of the one table ROBOTS: the SCARA (`scara`) and the
arms of the example-robot-data package, each with its URDF and tool frame: `panda` (the
Franka Emika Panda, tool frame `panda_hand_tcp`, the point between the fingertips, fingers
locked closed), `ur3`, `ur5`, `ur10` (Universal Robots, `tool0`), `xarm7` (UFactory,
`link_eef`), `z1` (Unitree, `gripperStator`, the gripper's jaw locked).
`robot_model(urdf_file=PATH, tool_frame=NAME)` builds any other. Every bad input (an unknown
name, an unreadable URDF, an unknown frame, a wrong shape) raises ValueError with a one-line
reason. No ROS import.
"""

import contextlib
import math
import os
import tempfile
from abc import ABC, abstractmethod
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from hri_core import dynamics
from hri_core.dynamics import ScaraParameters

__all__ = [
    'JointLimits',
    'KNOWN_TOOL_FRAMES',
    'KnownRobot',
    'PANDA_TOOL_FRAME',
    'PinocchioModel',
    'ROBOTS',
    'ROBOT_NAMES',
    'RobotModel',
    'ScaraModel',
    'example_robot_urdf_path',
    'folded_reach',
    'generic_model',
    'panda_urdf_path',
    'planar_inverse_kinematics',
    'robot_model',
    'scara_urdf',
]



@dataclass(frozen=True)
class KnownRobot:
    """An arm the suite knows by name: its URDF in example-robot-data's robots folder ('' for
    the analytic SCARA), the frame whose origin is its tool point, the name its URDF gives
    in <robot name=...> (how a /robot_description is recognised), and its home pose (rad;
    None: the middle of its joint limits, PinocchioModel's default)."""

    urdf: str
    tool_frame: str
    urdf_robot_name: str
    home: tuple[float, ...] | None = None


# The one table of arms known by name (`robot:=NAME` of arm_sim, the demonstrator and the
# controller). The UR arms are the full-range URDFs (+-2 pi, as the real arms); the
# joint-limited ones (+-pi) are there for urdf_file. Their home is the middle of their limits.
ROBOTS = {
    'scara': KnownRobot('', 'tip', 'scara'),
    # Franka's 'ready' pose: elbow bent, hand down in front of the base.
    'panda': KnownRobot('panda_description/urdf/panda.urdf', 'panda_hand_tcp', 'panda',
                        (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2,
                         math.pi / 4)),
    'ur3': KnownRobot('ur_description/urdf/ur3_robot.urdf', 'tool0', 'ur3'),
    'ur5': KnownRobot('ur_description/urdf/ur5_robot.urdf', 'tool0', 'ur5'),
    'ur10': KnownRobot('ur_description/urdf/ur10_robot.urdf', 'tool0', 'ur10'),
    'xarm7': KnownRobot('xarm_description/urdf/xarm7.urdf', 'link_eef', 'UF_ROBOT'),
    # The gripper's body (a fixed joint on the flange); its jaw is locked.
    'z1': KnownRobot('z1_description/urdf/z1.urdf', 'gripperStator', 'z1_description'),
}
ROBOT_NAMES = tuple(ROBOTS)
#: The tool frame of each known arm by the robot name its URDF gives (robot_description,
#: the live view: a /robot_description's arm without a tool_frame given).
KNOWN_TOOL_FRAMES = {robot.urdf_robot_name: robot.tool_frame for robot in ROBOTS.values()}
PANDA_TOOL_FRAME = ROBOTS['panda'].tool_frame
EXAMPLE_ROBOTS = 'cmeel.prefix/share/example-robot-data/robots'
STANDARD_GRAVITY = (0.0, 0.0, -9.81)  # m/s^2 in the base frame, z up
# theta's box (PinocchioModel): a link's mass at least this fraction of its URDF mass.
MASS_FLOOR = 0.01
IK_ITERATIONS = 50
"""Damped least-squares steps of RobotModel.inverse_kinematics from each seed."""
IK_DAMPING = 0.05
"""m: the damping of those steps."""
IK_TOLERANCE = 1e-3
"""m: a seed's iterations stop this near the goal."""
CLAMP_COST = 1000.0
"""Weight (per m^2 of miss, or rad^2 of the box's cut) of a solution that misses the goal
against its joint distance from the first seed, when the inverse kinematics chooses."""
INERTIA_NAMES = ('m', 'mcx', 'mcy', 'mcz', 'Ixx', 'Ixy', 'Iyy', 'Ixz', 'Iyz', 'Izz')


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits, each (n,): lower, upper positions (rad or m), velocity (rad/s or
    m/s), effort (N m or N). Raises ValueError if the shapes differ or lower > upper."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    def __post_init__(self):
        arrays = [np.array(getattr(self, name), dtype=float)
                  for name in ('lower', 'upper', 'velocity', 'effort')]
        if len({array.shape for array in arrays}) != 1 or arrays[0].ndim != 1:
            raise ValueError(f'joint limits must be 4 vectors of one length, got shapes '
                             f'{[array.shape for array in arrays]}')
        if np.any(np.isnan(np.concatenate(arrays))) or np.any(arrays[0] > arrays[1]):
            raise ValueError(f'joint limits: lower {arrays[0].tolist()} must be <= upper '
                             f'{arrays[1].tolist()}')
        for name, array in zip(('lower', 'upper', 'velocity', 'effort'), arrays, strict=True):
            array.flags.writeable = False
            object.__setattr__(self, name, array)


class RobotModel(ABC):
    """Kinematics and dynamics of a serial arm of `dof` joints (see the module docstring).

    Attributes set by the implementations: name, joint_names (tuple of n str), limits
    (JointLimits), parameter_names (p str), theta (p,) nominal parameters, theta_lower and
    theta_upper (p,) the box of physically possible ones, reach (m), shoulder (3,) m,
    urdf (str, the URDF text of the arm, as /robot_description carries it).
    Every method takes single states, joint vectors of shape (n,).
    """

    name: str
    joint_names: tuple[str, ...]
    limits: JointLimits
    parameter_names: tuple[str, ...]
    theta: np.ndarray
    theta_lower: np.ndarray
    theta_upper: np.ndarray
    reach: float
    shoulder: np.ndarray
    urdf: str
    tool_frame: str
    home: np.ndarray

    @property
    def dof(self) -> int:
        """Number of joints n."""
        return len(self.joint_names)

    def joint_vector(self, value, what: str) -> np.ndarray:
        """`value` as a finite float array (n,); ValueError with the reason otherwise."""
        array = np.asarray(value, dtype=float)
        if array.shape != (self.dof,):
            raise ValueError(f'{what} must have shape ({self.dof},), got {array.shape}')
        if not np.all(np.isfinite(array)):
            raise ValueError(f'{what} must be finite, got {array.tolist()}')
        return array

    def joint_position(self, value, what: str) -> np.ndarray:
        """joint_vector(value), also within the joint position limits (rad)."""
        array = self.joint_vector(value, what)
        limits = self.limits
        if np.any(array < limits.lower) or np.any(array > limits.upper):
            raise ValueError(f'{what} {array.tolist()} outside the joint limits '
                             f'{limits.lower.tolist()} .. {limits.upper.tolist()}')
        return array

    @abstractmethod
    def tool_position(self, q) -> np.ndarray:
        """Tool point x(q) in the base frame (3,), m."""

    @abstractmethod
    def tool_jacobian(self, q) -> np.ndarray:
        """J(q) = dx/dq (3, n), m/rad (m/m for a prismatic joint)."""

    @abstractmethod
    def tool_acceleration_bias(self, q, dq) -> np.ndarray:
        """J'(q, dq) dq (3,), m/s^2: the tool's acceleration at ddq = 0."""

    @abstractmethod
    def mass_matrix(self, q) -> np.ndarray:
        """M(q) (n, n), symmetric positive definite."""

    @abstractmethod
    def coriolis_matrix(self, q, dq) -> np.ndarray:
        """C(q, dq) (n, n), Christoffel form (Mdot - 2 C skew-symmetric)."""

    @abstractmethod
    def gravity_torque(self, q) -> np.ndarray:
        """g(q) (n,), N m."""

    @abstractmethod
    def friction_torque(self, dq) -> np.ndarray:
        """Viscous friction F dq (n,), N m."""

    @abstractmethod
    def regressor(self, q, dq, dq_r, ddq_r) -> np.ndarray:
        """Y(q, dq, dq_r, ddq_r) (n, p) of eq. 18: Y theta = M ddq_r + C dq_r + F dq_r + g."""

    # The control law's view: its task axes and the per-cycle calls without checks. -------

    task_axes: int = 3
    """k: the tool point's coordinates the law controls (x, y, z; x, y for a planar arm, whose
    k x n Jacobian is then exact and square)."""

    attained_reach: float | None = None
    """The farthest the tool point gets from `shoulder` within the joint limits (m), where
    the model knows it exactly; None: sampled by the law (arm_law.attained_reach)."""

    @abstractmethod
    def joint_frames(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's frame in the base frame at q (n,) rad, the caller's finite floats:
        rotations (J, 3, 3) and origins (J, 3) m, J = n + 1, index 0 the base's (for the body
        capsules riding on the joints, hri_core.bodies)."""

    @abstractmethod
    def joint_jacobians(self, q, joints) -> dict:
        """For each joint index in `joints` (as joint_frames'), at q (n,) rad (the caller's
        finite floats): (origin (3,) m, J (6, n)), J dq the velocity of that origin (m/s) and
        the joint frame's angular velocity (rad/s), both in the base frame's axes."""

    folded_reach: float = 0.0
    """The nearest the tool point gets to `shoulder` on the task axes within the joint limits
    (m), where the model knows it (the SCARA's folded arm: a hole round its base); 0: none
    known."""

    def inverse_kinematics(self, goal, seeds, lower, upper,
                           iterations: int = IK_ITERATIONS) -> np.ndarray:
        """Joints (n,) rad that put the tool point at `goal` (k,) m on the task axes, or
        nearest to it, within the box [lower, upper] (n,) rad: damped least squares from each
        seed (rows of `seeds`, (s, n) rad), clamped into the box at every step, at most
        `iterations` steps; of the results, the one that reaches the goal best (CLAMP_COST per
        m^2 of miss), then the one nearest to the first seed. Inputs unchecked (the
        controller's reach-round)."""
        damping = IK_DAMPING ** 2 * np.eye(self.task_axes)
        still = np.zeros(self.dof)
        best = None
        first = seeds[0]
        for seed in seeds:
            q = np.clip(seed, lower, upper)
            for step in range(iterations + 1):
                # One kinematics call per pose: its miss decides, and its J takes the step.
                x, jac, _ = self.task_kinematics(q, still)
                miss = goal - x
                if step == iterations or float(miss @ miss) < IK_TOLERANCE ** 2:
                    break
                q = np.clip(q + jac.T @ np.linalg.solve(jac @ jac.T + damping, miss),
                            lower, upper)
            cost = CLAMP_COST * float(miss @ miss) + float((q - first) @ (q - first))
            if best is None or cost < best[0]:
                best = (cost, q)
        return best[1]

    @abstractmethod
    def task_kinematics(self, q, dq) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x (k,) m, J (k, n) and dJ/dt (k, n) on the task axes at q, dq (n,) rad, rad/s:
        finite floats the caller has checked (the 1 kHz path; no checks here)."""

    def regressor_unchecked(self, q, dq, dq_r, ddq_r) -> np.ndarray:
        """regressor() for inputs the caller has checked ((n,) finite floats)."""
        return self.regressor(q, dq, dq_r, ddq_r)

    def forward_dynamics(self, q, dq, tau) -> np.ndarray:
        """ddq (n,) = M^-1 (tau - C dq - F dq - g), rad/s^2; inputs unchecked."""
        bias = self.coriolis_matrix(q, dq) @ dq + self.friction_torque(dq) + self.gravity_torque(q)
        return np.linalg.solve(self.mass_matrix(q), tau - bias)

    def rk4_step(self, q, dq, tau, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(q, qdot) (n,) rad, rad/s after dt (s) under the torque tau (n,) N m held over the
        step: one classical Runge-Kutta step of forward_dynamics (eq. 15), inputs unchecked
        (for tests and pure closed loops)."""
        def derivative(position, velocity):
            return velocity, self.forward_dynamics(position, velocity, tau)

        k1q, k1v = derivative(q, dq)
        k2q, k2v = derivative(q + 0.5 * dt * k1q, dq + 0.5 * dt * k1v)
        k3q, k3v = derivative(q + 0.5 * dt * k2q, dq + 0.5 * dt * k2v)
        k4q, k4v = derivative(q + dt * k3q, dq + dt * k3v)
        return (q + dt / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q),
                dq + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))

    def kinetic_energy(self, q, dq) -> float:
        """1/2 dq^T M(q) dq (J)."""
        dq = np.asarray(dq, dtype=float)
        return 0.5 * float(dq @ self.mass_matrix(q) @ dq)

    @property
    def adaptation_kinds(self) -> tuple[str, ...]:
        """The kinds of parameters the adaptive law gives one rate each (eq. 19's L):
        `adaptation_rates` spreads them over theta."""
        return self.parameter_names

    def adaptation_rates(self, rates) -> np.ndarray:
        """L's diagonal (p,) from one rate per adaptation kind; ValueError if the count
        differs."""
        rates = np.asarray(rates, dtype=float)
        if rates.shape != (len(self.adaptation_kinds),):
            raise ValueError(f'{self.name} takes {len(self.adaptation_kinds)} adaptation rates '
                             f'({", ".join(self.adaptation_kinds)}), got {rates.size}')
        return rates.copy()


# The SCARA --------------------------------------------------------------------------------

# scara_sim's defaults (config/scara_sim.yaml): joint limits and effort limit. The velocity
# limit is the speed range hri_core's dynamics tests cover; scara_sim enforces none.
SCARA_LIMITS = JointLimits(lower=np.array([-2.30, -2.46]), upper=np.array([2.30, 2.46]),
                           velocity=np.array([3.0, 3.0]), effort=np.array([20.0, 20.0]))
# The projection box of the controller's theta_hat: inertias positive, pi2 = m2 l1 lc2,
# friction and the mass moments >= 0.
SCARA_THETA_LOWER = (1e-3, 0.0, 1e-3, 0.0, 0.0, 0.0, 0.0)
# Above, what a 2-link arm of this size (links up to 0.5 m, up to 10 kg each) can have: pi1 <=
# 3, pi2, pi3 <= 1 kg m^2, b1, b2 <= 5 N m s/rad, mlc1, mlc2 <= 10 kg m (scara_sim's arm: 0.66,
# 0.19, 0.13, 1.0, 0.5, 1.75, 0.54). A bounded box keeps the estimate bounded whatever the
# regressor sees (a stop's force, a saturated drive).
SCARA_THETA_UPPER = (3.0, 1.0, 1.0, 5.0, 5.0, 10.0, 10.0)
DEFAULT_SCARA = ScaraParameters()


class ScaraModel(RobotModel):
    """The planar 2-link SCARA of hri_core.dynamics: analytic, the fast path.

    params: ScaraParameters (gravity, if any, along -y of the arm plane, as in dynamics.py);
    limits: JointLimits (default: scara_sim's). The tool point is at z = 0.
    """

    def __init__(self, params: ScaraParameters = DEFAULT_SCARA,
                 limits: JointLimits = SCARA_LIMITS):
        if limits.lower.shape != (2,):
            raise ValueError(f'the SCARA has 2 joints, got limits for {limits.lower.size}')
        self.name = 'scara'
        self.params = params
        self.joint_names = ('joint1', 'joint2')
        self.limits = limits
        self.parameter_names = ('pi1', 'pi2', 'pi3', 'b1', 'b2', 'mlc1', 'mlc2')
        self.theta = dynamics.dynamic_parameters(params)
        self.theta_lower = np.array(SCARA_THETA_LOWER)
        self.theta_upper = np.array(SCARA_THETA_UPPER)
        self.reach = params.l1 + params.l2
        self.attained_reach = self.reach  # joint 2 stretches out within its limits
        self.link_lengths = (params.l1, params.l2)
        self.folded_reach = folded_reach(params.l1, params.l2, limits)
        self.task_axes = 2
        self.shoulder = np.zeros(3)
        self.urdf = scara_urdf(params, limits)
        self.tool_frame = 'tip'
        self.home = np.clip([0.0, math.pi / 2], limits.lower, limits.upper)
        self._constants = dynamics.float_constants(params)

    def tool_position(self, q) -> np.ndarray:
        x, y = dynamics.forward_kinematics(self.joint_vector(q, 'q'), self.params.l1,
                                           self.params.l2)
        return np.array([x, y, 0.0])

    def tool_jacobian(self, q) -> np.ndarray:
        planar = dynamics.jacobian(self.joint_vector(q, 'q'), self.params.l1, self.params.l2)
        return np.vstack([planar, np.zeros((1, 2))])

    def tool_acceleration_bias(self, q, dq) -> np.ndarray:
        rate = dynamics.jacobian_derivative(self.joint_vector(q, 'q'),
                                            self.joint_vector(dq, 'dq'), self.params.l1,
                                            self.params.l2)
        return np.append(rate @ dq, 0.0)

    def mass_matrix(self, q) -> np.ndarray:
        return dynamics.mass_matrix(self.joint_vector(q, 'q'), self.params)

    def coriolis_matrix(self, q, dq) -> np.ndarray:
        return dynamics.coriolis_matrix(self.joint_vector(q, 'q'), self.joint_vector(dq, 'dq'),
                                        self.params)

    def gravity_torque(self, q) -> np.ndarray:
        return dynamics.gravity_torque(self.joint_vector(q, 'q'), self.params)

    def friction_torque(self, dq) -> np.ndarray:
        return dynamics.friction_torque(self.joint_vector(dq, 'dq'), self.params)

    def regressor(self, q, dq, dq_r, ddq_r) -> np.ndarray:
        return dynamics.regressor(self.joint_vector(q, 'q'), self.joint_vector(dq, 'dq'),
                                  self.joint_vector(dq_r, 'dq_r'),
                                  self.joint_vector(ddq_r, 'ddq_r'), self.params.gravity)

    def regressor_unchecked(self, q, dq, dq_r, ddq_r) -> np.ndarray:
        """dynamics.regressor of one state in plain floats (the 1 kHz path)."""
        (q1, q2), (w1, w2), (v1, v2), (a1, a2) = q.tolist(), dq.tolist(), dq_r.tolist(), \
            ddq_r.tolist()
        c2, s2 = math.cos(q2), math.sin(q2)
        gravity = self.params.gravity
        g1, g12 = gravity * math.cos(q1), gravity * math.cos(q1 + q2)
        return np.array([
            [a1, c2 * (2.0 * a1 + a2) - s2 * (w2 * v1 + (w1 + w2) * v2), a2, v1, 0.0, g1, g12],
            [0.0, c2 * a1 + s2 * w1 * v1, a1 + a2, 0.0, v2, 0.0, g12]])

    def task_kinematics(self, q, dq):
        """x, y of the tip, J (2, 2) and dJ/dt (hri_core.dynamics), in plain floats."""
        (q1, q2), (w1, w2) = q.tolist(), dq.tolist()
        l1, l2 = self.params.l1, self.params.l2
        s1, c1 = math.sin(q1), math.cos(q1)
        s12, c12 = math.sin(q1 + q2), math.cos(q1 + q2)
        w12 = w1 + w2
        return (np.array((l1 * c1 + l2 * c12, l1 * s1 + l2 * s12)),
                np.array(((-l1 * s1 - l2 * s12, -l2 * s12), (l1 * c1 + l2 * c12, l2 * c12))),
                np.array(((-l1 * c1 * w1 - l2 * c12 * w12, -l2 * c12 * w12),
                          (-l1 * s1 * w1 - l2 * s12 * w12, -l2 * s12 * w12))))

    def forward_dynamics(self, q, dq, tau) -> np.ndarray:
        """dynamics.forward_dynamics of one state, unchecked."""
        return np.array(dynamics.acceleration_floats(*q.tolist(), *dq.tolist(), tau.tolist(),
                                                     self._constants))

    def rk4_step(self, q, dq, tau, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """RobotModel.rk4_step through scara_sim's own step in plain floats
        (dynamics.rk4_step_floats): the same arithmetic, to the bit, in a seventh of the time."""
        q1, q2, v1, v2 = dynamics.rk4_step_floats((*q.tolist(), *dq.tolist()), tau.tolist(), dt,
                                                  self._constants)
        return np.array((q1, q2)), np.array((v1, v2))

    def joint_frames(self, q) -> tuple[np.ndarray, np.ndarray]:
        """RobotModel.joint_frames: the base, joint 1 at the base turned by q1, joint 2 at the
        elbow turned by q1 + q2, both about z."""
        l1 = self.link_lengths[0]
        q1, q12 = float(q[0]), float(q[0]) + float(q[1])
        c1, s1, c12, s12 = math.cos(q1), math.sin(q1), math.cos(q12), math.sin(q12)
        rotations = np.array([np.eye(3), [[c1, -s1, 0.0], [s1, c1, 0.0], [0.0, 0.0, 1.0]],
                              [[c12, -s12, 0.0], [s12, c12, 0.0], [0.0, 0.0, 1.0]]])
        origins = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [l1 * c1, l1 * s1, 0.0]])
        return rotations, origins

    def joint_jacobians(self, q, joints) -> dict:
        """RobotModel.joint_jacobians in closed form (both joints turn about z)."""
        l1 = self.link_lengths[0]
        c1, s1 = math.cos(float(q[0])), math.sin(float(q[0]))
        result = {}
        for joint in joints:
            jacobian = np.zeros((6, 2))
            origin = np.zeros(3)
            if joint >= 1:
                jacobian[5, :joint] = 1.0
            if joint == 2:
                origin[:2] = l1 * c1, l1 * s1
                jacobian[0, 0], jacobian[1, 0] = -l1 * s1, l1 * c1
            result[joint] = (origin, jacobian)
        return result

    def inverse_kinematics(self, goal, seeds, lower, upper,
                           iterations: int = IK_ITERATIONS) -> np.ndarray:
        """RobotModel.inverse_kinematics solved in closed form (planar_inverse_kinematics):
        the elbow nearer to the first seed of those the box cuts least (iterations unused)."""
        l1, l2 = self.link_lengths
        return np.array(planar_inverse_kinematics(
            float(goal[0]), float(goal[1]), float(seeds[0][0]), float(seeds[0][1]), l1, l2,
            lower, upper))


def folded_reach(l1: float, l2: float, limits: JointLimits) -> float:
    """The base-to-tip distance (m) of a planar 2-link arm folded to joint 2's nearer limit
    (|l1 - l2| where joint 2 may fold fully)."""
    fold = min(abs(limits.lower[1]), abs(limits.upper[1]), math.pi)
    return math.sqrt(max(l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * math.cos(fold), 0.0))


def planar_inverse_kinematics(x1: float, x2: float, near1: float, near2: float, l1: float,
                              l2: float, lower, upper) -> tuple[float, float]:
    """Joint angles (rad) of a planar 2-link arm that put the tip at (x1, x2) m or nearest to
    it, clamped into the box lower, upper (2,) rad; of the two elbows, the one the box cuts
    least, then the one nearer to (near1, near2) rad. A NaN in gives NaN out."""
    r2 = x1 * x1 + x2 * x2
    c2 = min(max((r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2), -1.0), 1.0)
    best_cost, best1, best2 = math.inf, 0.0, 0.0
    for elbow in (1.0, -1.0):
        q2 = elbow * math.acos(c2)
        q1 = math.remainder(
            math.atan2(x2, x1) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2)),
            2.0 * math.pi)  # in [-pi, pi]: the nearest writing to a box centred on 0
        k1 = min(max(q1, lower[0]), upper[0])
        k2 = min(max(q2, lower[1]), upper[1])
        # A solution the box cuts short misses the point: the one that reaches first.
        cost = (CLAMP_COST * ((k1 - q1) ** 2 + (k2 - q2) ** 2)
                + (k1 - near1) ** 2 + (k2 - near2) ** 2)
        if elbow == 1.0 or cost < best_cost:  # (the first kept: a NaN stays a NaN)
            best_cost, best1, best2 = cost, k1, k2
    return best1, best2


def _scara_link(name: str, mass: float, centre_of_mass: float, inertia: float) -> str:
    """A URDF link whose centre of mass is `centre_of_mass` m along x; `inertia` (kg m^2)
    about each axis through it (only the z axis matters to the planar arm)."""
    centre_of_mass, mass, inertia = float(centre_of_mass), float(mass), float(inertia)
    return (f'  <link name="{name}">\n    <inertial>\n'
            f'      <origin xyz="{centre_of_mass!r} 0 0" rpy="0 0 0"/>\n'
            f'      <mass value="{mass!r}"/>\n'
            f'      <inertia ixx="{inertia!r}" ixy="0" ixz="0" iyy="{inertia!r}" iyz="0" '
            f'izz="{inertia!r}"/>\n    </inertial>\n  </link>\n')


def _scara_joint(index: int, parent: str, offset: float, limits: JointLimits,
                 damping: float) -> str:
    """Revolute joint `index` (1 or 2) about z, `offset` m along the parent's x axis."""
    i = index - 1
    lower, upper, effort, velocity = (float(getattr(limits, name)[i])
                                      for name in ('lower', 'upper', 'effort', 'velocity'))
    return (f'  <joint name="joint{index}" type="revolute">\n'
            f'    <parent link="{parent}"/>\n    <child link="link{index}"/>\n'
            f'    <origin xyz="{offset!r} 0 0" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>\n'
            f'    <limit lower="{lower!r}" upper="{upper!r}" effort="{effort!r}" '
            f'velocity="{velocity!r}"/>\n'
            f'    <dynamics damping="{float(damping)!r}" friction="0"/>\n  </joint>\n')


def scara_urdf(params: ScaraParameters = DEFAULT_SCARA,
               limits: JointLimits = SCARA_LIMITS) -> str:
    """The URDF of the SCARA of `params`: links `base`, `link1`, `link2`, joints `joint1`,
    `joint2` about z (the base frame's z up, the arm in the plane z = 0), the tool frame `tip`
    l2 along link 2. Viscous friction as <dynamics damping>. The URDF has no gravity: with
    the usual gravity along -z the arm is horizontal (params.gravity = 0)."""
    return ('<?xml version="1.0"?>\n<robot name="scara">\n  <link name="base"/>\n'
            + _scara_link('link1', params.m1, params.lc1, params.i1)
            + _scara_link('link2', params.m2, params.lc2, params.i2)
            + '  <link name="tip"/>\n'
            + _scara_joint(1, 'base', 0.0, limits, params.b1)
            + _scara_joint(2, 'link1', float(params.l1), limits, params.b2)
            + '  <joint name="tip_joint" type="fixed">\n    <parent link="link2"/>\n'
            f'    <child link="tip"/>\n    <origin xyz="{float(params.l2)!r} 0 0" rpy="0 0 0"/>\n'
            '  </joint>\n</robot>\n')


# Any URDF through pinocchio ---------------------------------------------------------------

@contextlib.contextmanager
def _stderr_captured(lines: list[str]):
    """Collect what C++ code writes to file descriptor 2 (urdfdom's parse errors) into
    `lines` instead of the terminal: the caller turns it into one line of its own."""
    with tempfile.TemporaryFile(mode='w+b') as sink:
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            lines.extend(line.strip() for line in sink.read().decode(errors='replace')
                         .splitlines() if line.strip())


def _read_urdf(pin, urdf_text: str):
    """pinocchio's model of `urdf_text`; ValueError with urdfdom's first reason if it fails."""
    if not isinstance(urdf_text, str) or not urdf_text.strip():
        raise ValueError('the URDF is empty')
    errors: list[str] = []
    try:
        with _stderr_captured(errors):
            return pin.buildModelFromXML(urdf_text)
    except Exception as error:  # noqa: BLE001 pinocchio raises ValueError or RuntimeError
        reasons = [line.removeprefix('Error:').strip() for line in errors
                   if line.startswith('Error:')]
        reason = reasons[0] if reasons else str(error).splitlines()[0]
        raise ValueError(f'not a valid URDF: {reason}') from None


class PinocchioModel(RobotModel):
    """Any serial arm from its URDF text, through pinocchio (see the module docstring).

    urdf_text: the URDF (str); tool_frame: the name of the link or frame whose origin is the
    tool point; name: what the model is called in messages; gravity: (3,) m/s^2 in the base
    frame (default 9.81 along -z). Raises ValueError with a one-line reason for an unreadable
    URDF, an unknown tool frame, no moving joint before it, or a joint other than a 1-DoF
    revolute or prismatic one (a `continuous` joint included) between the base and the tool.
    """

    def __init__(self, urdf_text: str, tool_frame: str, name: str = 'urdf',
                 gravity=STANDARD_GRAVITY):
        import pinocchio as pin  # a heavy import, only for the models that need it

        self._pin = pin
        full = _read_urdf(pin, urdf_text)
        if not full.existFrame(tool_frame):
            frames = [frame.name for frame in full.frames][1:]
            raise ValueError(f'no frame {tool_frame!r} in the URDF of {name}; its frames: '
                             f'{", ".join(frames[:20])}{" ..." if len(frames) > 20 else ""}')
        chain = set(full.supports[full.frames[_frame_id(pin, full, tool_frame)].parentJoint])
        locked = [joint for joint in range(1, full.njoints) if joint not in chain]
        model = (pin.buildReducedModel(full, locked, _neutral_within_limits(pin, full))
                 if locked else full)
        if model.nv == 0:
            raise ValueError(f'no moving joint between the base and {tool_frame!r} in {name}')
        for joint, joint_name in zip(model.joints[1:], model.names[1:], strict=True):
            if joint.nq != 1 or joint.nv != 1:
                raise ValueError(f'joint {joint_name!r} of {name} ({joint.shortname()}) is not '
                                 'a 1-DoF revolute or prismatic joint with limits')
        gravity = np.array(gravity, dtype=float)
        if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
            raise ValueError(f'gravity must be 3 finite values (m/s^2), got {gravity.tolist()}')
        self.model = model
        self.model.gravity = pin.Motion(gravity, np.zeros(3))
        self.data = model.createData()
        # Two copies for the two-call regressor, with gravity scaled by +2 and -2.
        self._regressor_models = []
        for scale in (2.0, -2.0):
            copy = pin.Model(model)
            copy.gravity = pin.Motion(scale * gravity, np.zeros(3))
            self._regressor_models.append((copy, copy.createData()))
        self.tool_frame = tool_frame
        self.tool_frame_id = _frame_id(pin, model, tool_frame)
        self.name = name
        self.urdf = urdf_text
        self.joint_names = tuple(model.names[1:])
        self.limits = JointLimits(lower=model.lowerPositionLimit.copy(),
                                  upper=model.upperPositionLimit.copy(),
                                  velocity=model.velocityLimit.copy(),
                                  effort=model.effortLimit.copy())
        self.damping = model.damping.copy()
        # '<joint>.<parameter>': the inertial parameters of the link that joint moves.
        self.parameter_names = tuple(
            [f'{joint}.{parameter}' for joint in model.names[1:] for parameter in INERTIA_NAMES]
            + [f'{joint}.damping' for joint in self.joint_names])
        self.theta = np.concatenate(
            [inertia.toDynamicParameters() for inertia in model.inertias[1:]] + [self.damping])
        self.theta_lower, self.theta_upper = self._parameter_box()
        self.shoulder, self.reach = self._reach()
        self.home = _neutral_within_limits(pin, model)
        middle = 0.5 * (self.limits.lower + self.limits.upper)
        bounded = np.isfinite(middle)
        self.home[bounded] = middle[bounded]
        self._world_aligned = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        self._zero = np.zeros(model.nv)

    def _parameter_box(self) -> tuple[np.ndarray, np.ndarray]:
        """theta's box: each mass >= MASS_FLOOR of its URDF value, the diagonal inertias
        Ixx, Iyy, Izz and the friction >= 0; first moments and products of inertia free.
        A box holds every physical theta but not only those (a physical inertia also has a
        positive definite pseudo-inertia matrix, which no box describes)."""
        per_link = len(INERTIA_NAMES)
        lower = np.full(self.theta.size, -math.inf)
        upper = np.full(self.theta.size, math.inf)
        links = self.dof * per_link
        lower[0:links:per_link] = MASS_FLOOR * self.theta[0:links:per_link]
        for diagonal in ('Ixx', 'Iyy', 'Izz'):
            lower[INERTIA_NAMES.index(diagonal):links:per_link] = 0.0
        lower[links:] = 0.0
        return lower, upper

    def _reach(self) -> tuple[np.ndarray, float]:
        """(shoulder, reach): the first joint's origin (3,) m at q = neutral and the sum of
        the fixed distances along the chain from it to the tool point (m)."""
        pin, model, data = self._pin, self.model, self.data
        pin.forwardKinematics(model, data, _neutral_within_limits(pin, model))
        pin.updateFramePlacements(model, data)
        points = [data.oMi[joint].translation.copy() for joint in range(1, model.njoints)]
        points.append(data.oMf[self.tool_frame_id].translation.copy())
        steps = np.diff(np.array(points), axis=0)
        return points[0], float(np.sum(np.linalg.norm(steps, axis=1)))

    def tool_position(self, q) -> np.ndarray:
        pin = self._pin
        pin.forwardKinematics(self.model, self.data, self.joint_vector(q, 'q'))
        return pin.updateFramePlacement(self.model, self.data,
                                        self.tool_frame_id).translation.copy()

    def tool_jacobian(self, q) -> np.ndarray:
        return self._pin.computeFrameJacobian(self.model, self.data, self.joint_vector(q, 'q'),
                                              self.tool_frame_id, self._world_aligned)[:3]

    def tool_wrench_jacobian(self, q) -> np.ndarray:
        """The frame Jacobian (6, n), linear rows then angular, base-frame axes at the tool
        point: J6^T [f; m] is the joint torque of a wrench (N, N m) held at the tool."""
        return self._pin.computeFrameJacobian(self.model, self.data, self.joint_vector(q, 'q'),
                                              self.tool_frame_id, self._world_aligned).copy()

    def tool_acceleration_bias(self, q, dq) -> np.ndarray:
        pin = self._pin
        pin.forwardKinematics(self.model, self.data, self.joint_vector(q, 'q'),
                              self.joint_vector(dq, 'dq'), self._zero)
        return pin.getFrameClassicalAcceleration(self.model, self.data, self.tool_frame_id,
                                                 self._world_aligned).linear.copy()

    def mass_matrix(self, q) -> np.ndarray:
        upper = np.triu(self._pin.crba(self.model, self.data, self.joint_vector(q, 'q')))
        return upper + np.triu(upper, 1).T

    def coriolis_matrix(self, q, dq) -> np.ndarray:
        return self._pin.computeCoriolisMatrix(self.model, self.data, self.joint_vector(q, 'q'),
                                               self.joint_vector(dq, 'dq')).copy()

    def gravity_torque(self, q) -> np.ndarray:
        return self._pin.computeGeneralizedGravity(self.model, self.data,
                                                   self.joint_vector(q, 'q')).copy()

    def friction_torque(self, dq) -> np.ndarray:
        return self.damping * self.joint_vector(dq, 'dq')

    def regressor(self, q, dq, dq_r, ddq_r) -> np.ndarray:
        q, dq = self.joint_vector(q, 'q'), self.joint_vector(dq, 'dq')
        dq_r, ddq_r = self.joint_vector(dq_r, 'dq_r'), self.joint_vector(ddq_r, 'ddq_r')
        return self.regressor_unchecked(q, dq, dq_r, ddq_r)

    def regressor_unchecked(self, q, dq, dq_r, ddq_r) -> np.ndarray:
        """regressor() for inputs the caller has checked ((n,) finite floats): the 1 kHz
        path. Y_pin is quadratic in the velocity and linear in the acceleration and gravity
        together, so the two calls' difference keeps C(q, dq) dq_r, M ddq_r and g(q)."""
        return np.hstack([self.rigid_regressor_unchecked(q, dq, dq_r, ddq_r), np.diag(dq_r)])

    def rigid_regressor_unchecked(self, q, dq, dq_r, ddq_r) -> np.ndarray:
        """The regressor's rigid-body columns (n, 10 n): regressor_unchecked without the
        friction block diag(dq_r), which a caller multiplies as dq_r * theta_friction (the
        1 kHz path: no n x n matrix formed)."""
        (plus, plus_data), (minus, minus_data) = self._regressor_models
        regress = self._pin.computeJointTorqueRegressor
        return 0.25 * (regress(plus, plus_data, q, dq + dq_r, 2.0 * ddq_r)
                       - regress(minus, minus_data, q, dq - dq_r, -2.0 * ddq_r))

    def task_kinematics(self, q, dq):
        """x (3,), J (3, n), dJ/dt (3, n) of the tool point, base-frame axes."""
        pin, model, data, frame = self._pin, self.model, self.data, self.tool_frame_id
        pin.computeJointJacobiansTimeVariation(model, data, q, dq)
        x = pin.updateFramePlacement(model, data, frame).translation.copy()
        jac = pin.getFrameJacobian(model, data, frame, self._world_aligned)[:3]
        rate = pin.getFrameJacobianTimeVariation(model, data, frame, self._world_aligned)[:3]
        return x, jac, rate

    @property
    def adaptation_kinds(self) -> tuple[str, ...]:
        """Each link's ten inertial parameters and its joint's damping: one rate per kind,
        the same for every joint."""
        return (*INERTIA_NAMES, 'damping')

    def adaptation_rates(self, rates) -> np.ndarray:
        rates = super().adaptation_rates(rates)
        per_link = len(INERTIA_NAMES)
        return np.concatenate([np.tile(rates[:per_link], self.dof),
                               np.full(self.dof, rates[per_link])])

    def forward_dynamics(self, q, dq, tau) -> np.ndarray:
        """ddq (n,) = M^-1 (tau - C dq - F dq - g) by pinocchio's ABA; inputs unchecked."""
        return self._pin.aba(self.model, self.data, q, dq, tau - self.damping * dq)

    def joint_frames(self, q) -> tuple[np.ndarray, np.ndarray]:
        """RobotModel.joint_frames through pinocchio (its joint order; 0 the universe)."""
        self._pin.forwardKinematics(self.model, self.data, q)
        # One homogeneous matrix per joint: each attribute access through pinocchio's
        # bindings costs about 1 us.
        placements = self.data.oMi
        frames = np.array([placements[j].homogeneous for j in range(self.model.njoints)])
        return frames[:, :3, :3], frames[:, :3, 3]

    def joint_jacobians(self, q, joints) -> dict:
        """RobotModel.joint_jacobians in one pinocchio pass (computeJointJacobians, then each
        joint's LOCAL_WORLD_ALIGNED Jacobian: the joint origin's velocity and the angular
        velocity in base axes)."""
        pin, model, data = self._pin, self.model, self.data
        pin.computeJointJacobians(model, data, q)
        frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        return {joint: (data.oMi[joint].translation.copy(),
                        pin.getJointJacobian(model, data, joint, frame)) for joint in joints}

    def tool_position_unchecked(self, q) -> np.ndarray:
        """tool_position() for a q the caller has checked ((n,) finite floats)."""
        self._pin.forwardKinematics(self.model, self.data, q)
        return self._pin.updateFramePlacement(self.model, self.data,
                                              self.tool_frame_id).translation.copy()

    def inverse_mass_matrix(self, q) -> np.ndarray:
        """M(q)^-1 (n, n) by pinocchio's computeMinverse; q unchecked."""
        upper = np.triu(self._pin.computeMinverse(self.model, self.data, q))
        return upper + np.triu(upper, 1).T

    def potential_energy(self, q) -> float:
        """Gravitational potential energy (J) whose gradient is g(q)."""
        return float(self._pin.computePotentialEnergy(self.model, self.data,
                                                      self.joint_vector(q, 'q')))

    def kinetic_energy(self, q, dq) -> float:
        """1/2 dq^T M(q) dq (J), by pinocchio's computeKineticEnergy (one pass over the
        chain, no n x n matrix: 1 us against 19 us through mass_matrix on the Panda)."""
        return float(self._pin.computeKineticEnergy(self.model, self.data,
                                                    self.joint_vector(q, 'q'),
                                                    self.joint_vector(dq, 'dq')))

    def with_inertias(self, link_scales, damping) -> 'PinocchioModel':
        """A copy whose link i has its mass and rotational inertia scaled by link_scales[i]
        (centre of mass unchanged) and whose joints have viscous friction `damping` (n,),
        N m s/rad: a perturbed 'true' arm for a simulator. Limits and URDF text stay."""
        scales = np.asarray(link_scales, dtype=float)
        damping = np.asarray(damping, dtype=float)
        if scales.shape != (self.dof,) or np.any(scales <= 0.0) or damping.shape != (
                self.dof,) or np.any(damping < 0.0):
            raise ValueError(f'link scales must be {self.dof} values > 0 and damping '
                             f'{self.dof} values >= 0, got {scales.tolist()}, '
                             f'{damping.tolist()}')
        pin = self._pin
        copy = object.__new__(PinocchioModel)
        copy.__dict__.update(self.__dict__)
        copy.home = self.home.copy()
        copy.model = pin.Model(self.model)
        for joint, scale in enumerate(scales, start=1):
            inertia = copy.model.inertias[joint]
            copy.model.inertias[joint] = pin.Inertia(scale * inertia.mass, inertia.lever,
                                                     scale * inertia.inertia)
        copy.model.damping = damping.copy()
        copy.data = copy.model.createData()
        copy._regressor_models = []
        for scale in (2.0, -2.0):
            twin = pin.Model(copy.model)
            twin.gravity = pin.Motion(scale * copy.model.gravity.linear, np.zeros(3))
            copy._regressor_models.append((twin, twin.createData()))
        copy.damping = damping.copy()
        copy.theta = np.concatenate(
            [inertia.toDynamicParameters() for inertia in copy.model.inertias[1:]] + [damping])
        return copy


def generic_model(model: RobotModel) -> 'PinocchioModel':
    """`model` itself if it is a PinocchioModel, else the PinocchioModel of its URDF and tool
    frame (the SCARA's, horizontal: gravity along -z), with its home pose."""
    if isinstance(model, PinocchioModel):
        return model
    generic = PinocchioModel(model.urdf, model.tool_frame, name=model.name)
    generic.home = np.array(model.home)
    return generic


def _frame_id(pin, model, name: str) -> int:
    """The id of the frame `name`: its link's (BODY) frame where a joint has the same name
    (the Z1's gripperStator), else the one frame of that name."""
    if model.existFrame(name, pin.FrameType.BODY):
        return model.getFrameId(name, pin.FrameType.BODY)
    return model.getFrameId(name)


def _neutral_within_limits(pin, model) -> np.ndarray:
    """pinocchio's neutral configuration clipped into the joint limits (a gripper's fingers
    at their closed stop)."""
    return np.clip(pin.neutral(model), model.lowerPositionLimit, model.upperPositionLimit)


# Names ------------------------------------------------------------------------------------

def example_robot_urdf_path(robot: str) -> Path:
    """The URDF of the known arm `robot` (ROBOTS) in the example-robot-data package: in the
    Python environment (the PyPI wheel, a data-only package: its files sit under the
    environment's cmeel.prefix/share) or else in the ament index (the ROS package of an apt
    install). ValueError if neither."""
    relative = f'{EXAMPLE_ROBOTS}/{ROBOTS[robot].urdf}'
    candidates = []
    try:
        candidates.append(Path(metadata.distribution('example-robot-data')
                               .locate_file(relative)))
    except metadata.PackageNotFoundError:
        pass
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory('example-robot-data'))
                          / relative.split('example-robot-data/', 1)[1])
    except (ImportError, LookupError):
        pass
    for path in candidates:
        if path.is_file():
            return path
    raise ValueError(f'robot {robot} needs the example-robot-data package (requirements.lock);'
                     f' no URDF at {", ".join(map(str, candidates)) or "any known place"}')


def panda_urdf_path() -> Path:
    """The Panda's URDF (example_robot_urdf_path)."""
    return example_robot_urdf_path('panda')


def robot_model(robot: str = '', urdf_file: str = '', tool_frame: str = '') -> RobotModel:
    """The model of `robot` (one of ROBOT_NAMES) or of the URDF file `urdf_file` with its tool
    point at `tool_frame` (required with urdf_file; for a known arm it may replace the
    table's). Exactly one of robot and urdf_file. ValueError with the reason."""
    if bool(robot) == bool(urdf_file):
        raise ValueError('give either a robot name '
                         f'({", ".join(ROBOT_NAMES)}) or a urdf_file, not both or neither')
    if robot == 'scara':
        if tool_frame not in ('', 'tip'):
            raise ValueError(f"the SCARA's tool frame is 'tip', not {tool_frame!r}")
        return ScaraModel()
    if robot in ROBOTS:
        known = ROBOTS[robot]
        model = PinocchioModel(example_robot_urdf_path(robot).read_text(),
                               tool_frame or known.tool_frame, name=robot)
        if known.home is not None:
            model.home = np.array(known.home)
        return model
    if robot:
        raise ValueError(f'unknown robot {robot!r}; expected one of {", ".join(ROBOT_NAMES)} '
                         'or a urdf_file')
    if not tool_frame:
        raise ValueError('a urdf_file needs a tool_frame (the link whose origin is the tool)')
    try:
        text = Path(urdf_file).read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f'cannot read urdf_file {urdf_file!r}: {error.strerror or error}'
                         ) from None
    return PinocchioModel(text, tool_frame, name=Path(urdf_file).stem)

