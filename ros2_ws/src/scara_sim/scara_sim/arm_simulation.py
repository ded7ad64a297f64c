"""A serial arm from its URDF, simulated: the step logic behind the `arm_sim` node.

`ArmSimulator` advances a hri_core.robot_model.PinocchioModel by fixed steps of `dt` with
classical RK4 on pinocchio's forward dynamics (ABA),

    ddq = M(q)^-1 (tau + J6(q)^T w - F dq - C(q, dq) dq - g(q)),

the drive torque tau and the human's wrench w (force in N, torque in N m, base-frame axes,
at the tool point; J6 taken at the start of the step) held over the step (a drive's current
loop). Where the viscous friction is stiff against the arm's inertia (F dt above half the
least eigenvalue of M at the start), F dq is taken out of the RK4 and applied after it,
implicitly: dq <- (M + dt F)^-1 M dq at the step's end. In the RK4 it diverged there: the
xArm7's URDF has 2 N m s/rad on a wrist of 1.4e-4 kg m^2 (F dt 14 times the inertia; the
RK4 is stable below about 2.8), and its state became non-finite within 8 steps. Other arms
keep the friction in the RK4 (4th order; the SCARA's steps equal scara_sim's). The drive
torque is the commanded effort clipped at each joint's effort limit (the URDF's: 87 N m for
the Panda's joints 1-4, 12 N m for 5-7), or zero when idle.

Joint position limits are rigid, inelastic stops (not stiff springs: no stiffness to tune
and no 1 kHz oscillation against the stop). After each step a joint beyond a limit is clamped
to it and loses its velocity into the limit in a plastic impact (the impulse of the stop,
dq -= M^-1 E (E^T M^-1 E)^-1 E^T dq, also changes the other joints' velocities; scara_sim
zeroes the one joint's velocity only). A joint resting on a stop
and pushed into it is locked for the next step: its acceleration is held at zero by the
stop's constraint torque, lambda = (E^T M^-1 E)^-1 E^T ddq_free, so that the stop, not the
rest of the arm, takes the push (ddq = ddq_free - M^-1 E lambda; E selects the locked joints;
M^-1 of the step's start; a stop only pushes, so a joint whose lambda would pull is
released).

Teach mode (`teach_mode`), for demonstrations by hand: the drive adds the arm's own gravity
torque and a joint damping to whatever it is commanded (zero when idle),

    tau = clip(tau_command + g(q) - D_teach dq, -tau_max, tau_max),

so that with no controller the arm floats where it is left and a hand guides it with little
force: a Franka Panda in its guiding mode, whose own controller compensates gravity (libfranka's
torque commands are added to it). g is the simulated arm's own, as the robot's firmware knows
its arm: the URDF's g would leave a 10 % mass error unbalanced (the Panda, seed 0: the tool sank
0.11 m in 1 s). D_teach stands for the joint friction that holds a real arm once let go (the
URDF's 0.003 N m s/rad left the Panda's elbow swinging 2 cm in 2.5 s after a push; 1 N m s/rad,
about the slope at rest of the Panda's identified friction, stopped it within 0.5 mm).

The simulated arm is not the URDF's: `true_arm` scales each link's mass and rotational
inertia (centre of mass kept) by its own factor drawn uniformly from [1 - p, 1 + p] and sets
each joint's viscous friction to `damping` scaled the same way, from a seeded generator, so a
controller that knows only the URDF meets a model error it must adapt to, the same one in
every run of a seed.

No ROS import: the arm_sim node wires this to topics (scara_sim.sim_node_common).
"""

import math
from dataclasses import dataclass, field

import numpy as np

from hri_core.robot_model import PinocchioModel

# 'brake': the joints held still, as a robot's brakes hold it until a controller first commands
# it (arm_sim before its first command); 'idle': zero drive torque; 'effort': the command.
COMMAND_MODES = ('idle', 'effort', 'brake')


def true_arm(model: PinocchioModel, perturbation: float, seed: int,
             damping=None) -> PinocchioModel:
    """The simulated arm: `model` with each link's mass and inertia scaled by a factor in
    [1 - perturbation, 1 + perturbation] and each joint's viscous friction (N m s/rad;
    `damping` (n,), default the URDF's) scaled by another, drawn from
    numpy.random.default_rng(seed) (links first, then joints). 0 <= perturbation < 1."""
    if not (math.isfinite(perturbation) and 0.0 <= perturbation < 1.0):
        raise ValueError(f'perturbation must be in [0, 1), got {perturbation}')
    damping = model.damping if damping is None else np.asarray(damping, dtype=float)
    if damping.shape != (model.dof,) or not np.all(np.isfinite(damping)) or np.any(
            damping < 0.0):
        raise ValueError(f'damping must be {model.dof} finite values >= 0 N m s/rad, got '
                         f'{np.ravel(damping).tolist()}')
    rng = np.random.default_rng(seed)
    link_scales = rng.uniform(1.0 - perturbation, 1.0 + perturbation, model.dof)
    damping_scales = rng.uniform(1.0 - perturbation, 1.0 + perturbation, model.dof)
    return model.with_inertias(link_scales, damping * damping_scales)


class DriveTorques:
    """The drive of a simulated arm, one for both engines (ArmSimulator here,
    mujoco_simulation.MujocoArmSimulator): the command clipped at the effort limits, teach
    mode's gravity compensation and damping, the human's wrench at the tool. Uses the
    engine's arm, q, dq, teach_mode, teach_damping and _effort / _least_effort (the arm's
    effort limits, + and -)."""

    def actuator_torque(self, mode: str, command) -> np.ndarray:
        """Drive torque (n,) N m for `mode` in COMMAND_MODES: the command clipped at the
        effort limits, or zero."""
        if mode == 'effort':  # np.minimum/maximum: a third of np.clip's time on 7 values
            return np.minimum(np.maximum(np.array(command, dtype=float), self._least_effort),
                              self._effort)
        if mode == 'idle':
            return np.zeros(self.arm.dof)
        raise ValueError(f'unknown command mode {mode!r}; expected one of {COMMAND_MODES}')

    def guided_torque(self, tau: np.ndarray) -> np.ndarray:
        """Teach mode's drive torque (n,) N m: `tau` plus the arm's gravity torque at the
        step's start minus teach_damping dq, clipped at the effort limits."""
        total = tau + self.arm.gravity_torque(self.q) - self.teach_damping * self.dq
        return np.minimum(np.maximum(total, self._least_effort), self._effort)

    def drive_torques(self, mode: str, command, wrench) -> tuple[np.ndarray, np.ndarray]:
        """(the drive's torque (n,) N m, the joint torque (n,) N m with the human's wrench
        (6,) at the tool ((fx, fy, fz) N, (mx, my, mz) N m; shorter: the rest zero)) for a
        step in `mode` other than 'brake'."""
        tau = self.actuator_torque(mode, command)
        if self.teach_mode:
            tau = self.guided_torque(tau)
        if not any(wrench):
            return tau, tau
        full = np.zeros(6)
        full[:len(wrench)] = wrench
        return tau, tau + self.arm.tool_wrench_jacobian(self.q).T @ full


@dataclass
class ArmSimulator(DriveTorques):
    """State and fixed-step update of the simulated arm (see the module docstring).

    arm: the true arm (true_arm); q, dq: joint state (n,) in rad and rad/s, q within the
    arm's position limits; dt: the step in s. The effort limits are the arm's
    (arm.limits.effort, finite and > 0). teach_mode: gravity compensated and damped by
    teach_damping (N m s/rad, >= 0) for teaching by hand (module docstring).
    """

    # No person in this engine's scene: the node neither feeds it /human/body nor publishes
    # contacts (mujoco_simulation.MujocoArmSimulator does both).
    touches_bodies = False

    arm: PinocchioModel
    q: np.ndarray
    dq: np.ndarray
    dt: float = 1e-3
    applied_effort: np.ndarray = field(default=None)
    teach_mode: bool = False
    teach_damping: float = 1.0

    def __post_init__(self):
        arm = self.arm
        self.q = arm.joint_position(self.q, 'initial q')
        self.dq = arm.joint_vector(self.dq, 'initial dq')
        limits = arm.limits
        if not (np.all(np.isfinite(limits.effort)) and np.all(limits.effort > 0.0)):
            raise ValueError(f'effort limits must be finite and > 0, got '
                             f'{limits.effort.tolist()}')
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise ValueError(f'dt must be finite and > 0 s, got {self.dt}')
        if not (math.isfinite(self.teach_damping) and self.teach_damping >= 0.0):
            raise ValueError(f'teach_damping must be finite and >= 0 N m s/rad, got '
                             f'{self.teach_damping}')
        self.applied_effort = np.zeros(arm.dof)
        # Stiff friction apart (module docstring): the RK4 then runs on the arm without it.
        self._friction = np.asarray(arm.damping, dtype=float).copy()
        least_inertia = float(np.linalg.eigvalsh(arm.mass_matrix(self.q)).min())
        self._stiff = bool(np.max(self.dt * self._friction) > 0.5 * least_inertia)
        self._rigid = (arm.with_inertias(np.ones(arm.dof), np.zeros(arm.dof)) if self._stiff
                       else arm)
        self._lower, self._upper = limits.lower, limits.upper
        self._effort, self._least_effort = limits.effort, -limits.effort

    def acceleration(self, q, dq, torque, stops=None) -> np.ndarray:
        """ddq (n,) rad/s^2 of the true arm under the joint torque (n,) N m (gravity
        included; the friction is applied after the step, `step`), with the joints that
        `stops` (from _stops_holding) names held by their stops; inputs unchecked (the 1 kHz
        path)."""
        free = self._rigid.forward_dynamics(q, dq, torque)
        if stops is None:
            return free
        locked, coupling, block_inverse = stops
        return free - coupling @ (block_inverse @ free[locked])

    def _stops_holding(self, torque):
        """The joints on a stop that the torque pushes into it, held by the stop this step:
        (their indices, M^-1 E, (E^T M^-1 E)^-1) with M^-1 at the step's start (M changes
        little in a step, and the clamp after it keeps the joint on its stop), or None."""
        q, dq, lower, upper = self.q, self.dq, self._lower, self._upper
        on_lower, on_upper = q <= lower, q >= upper
        if not (on_lower.any() or on_upper.any()):
            return None
        resting = (on_lower & (dq <= 0.0)) | (on_upper & (dq >= 0.0))
        free = self.acceleration(q, dq, torque)
        inward = np.where(on_lower, -1.0, 1.0)
        locked = np.flatnonzero(resting & (free * inward > 0.0))
        if not locked.size:
            return None
        inverse = self.arm.inverse_mass_matrix(q)
        block_inverse = np.linalg.inv(inverse[np.ix_(locked, locked)])
        if locked.size > 1:
            # The constraint torques must push away from each stop; release those that pull.
            pushing = (block_inverse @ free[locked]) * inward[locked] > 0.0
            if not pushing.all():
                locked = locked[pushing]
                if not locked.size:
                    return None
                block_inverse = np.linalg.inv(inverse[np.ix_(locked, locked)])
        return locked, inverse[:, locked], block_inverse

    def step(self, mode: str, command, wrench) -> tuple[tuple[float, ...], ...]:
        """Advance one step of dt with the drive in `mode` and the human's wrench (6,) at the
        tool ((fx, fy, fz) N, (mx, my, mz) N m; shorter: the rest zero). Returns the new q
        (rad), dq (rad/s) and the applied drive torque (N m) as tuples of floats. Raises
        ValueError if the state becomes non-finite (commands are checked where they arrive).
        """
        if mode == 'brake':
            self.dq = np.zeros(self.arm.dof)
            self.applied_effort = np.zeros(self.arm.dof)
            return tuple(self.q.tolist()), tuple(self.dq.tolist()), tuple(
                self.applied_effort.tolist())
        tau, torque = self.drive_torques(mode, command, wrench)
        stops = self._stops_holding(torque)
        q, dq, dt = self.q, self.dq, self.dt
        half = 0.5 * dt
        k1v = self.acceleration(q, dq, torque, stops)
        k2q = dq + half * k1v
        k2v = self.acceleration(q + half * dq, k2q, torque, stops)
        k3q = dq + half * k2v
        k3v = self.acceleration(q + half * k2q, k3q, torque, stops)
        k4q = dq + dt * k3v
        k4v = self.acceleration(q + dt * k3q, k4q, torque, stops)
        sixth = dt / 6.0
        q_next = q + sixth * (dq + 2.0 * (k2q + k3q) + k4q)
        dq_next = dq + sixth * (k1v + 2.0 * (k2v + k3v) + k4v)
        # One sum: NaN or inf anywhere in the state makes it non-finite.
        if not math.isfinite(float(q_next.sum() + dq_next.sum())):
            raise ValueError(f'the simulated state became non-finite (torque {torque.tolist()})')
        if self._stiff:
            inertia = self._rigid.mass_matrix(q_next)
            dq_next = np.linalg.solve(inertia + np.diag(dt * self._friction), inertia @ dq_next)
        lower, upper = self._lower, self._upper
        below, above = q_next <= lower, q_next >= upper
        if below.any() or above.any():
            # A plastic impact on each stop reached: the joint keeps no velocity into its
            # stop, the rest of the arm the velocity that the stop's impulse leaves it.
            q_next = np.minimum(np.maximum(q_next, lower), upper)
            hit = np.flatnonzero((below & (dq_next < 0.0)) | (above & (dq_next > 0.0)))
            if hit.size:
                inverse = self.arm.inverse_mass_matrix(q_next)
                dq_next -= inverse[:, hit] @ np.linalg.solve(inverse[np.ix_(hit, hit)],
                                                             dq_next[hit])
                dq_next[hit] = 0.0  # exactly, not to rounding
        self.q = q_next
        self.dq = dq_next
        self.applied_effort = tau
        return tuple(q_next.tolist()), tuple(dq_next.tolist()), tuple(tau.tolist())

    def energy(self) -> float:
        """Kinetic plus gravitational potential energy of the true arm (J)."""
        return self.arm.kinetic_energy(self.q, self.dq) + self.arm.potential_energy(self.q)
