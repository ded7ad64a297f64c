"""A serial arm from its URDF, simulated: the step logic behind the `arm_sim` node.

`ArmSimulator` advances a hri_core.robot_model.PinocchioModel by fixed steps of `dt` with
classical RK4 on pinocchio's forward dynamics (ABA),

    ddq = M(q)^-1 (tau + J6(q)^T w - F dq - C(q, dq) dq - g(q)),

the drive torque tau and the human's wrench w (force in N, torque in N m, base-frame axes,
at the tool point; J6 taken at the start of the step) held over the step (a drive's current
loop). The drive torque is the commanded effort clipped at each joint's effort limit (the
URDF's: 87 N m for the Panda's joints 1-4, 12 N m for 5-7), or zero when idle.

Joint position limits are rigid, inelastic stops (not stiff springs: no stiffness to tune
and no 1 kHz oscillation against the stop). After each step a joint beyond a limit is clamped
to it and loses its velocity into the limit in a plastic impact (the impulse of the stop,
dq -= M^-1 E (E^T M^-1 E)^-1 E^T dq, also changes the other joints' velocities; scara_sim
zeroes the one joint's velocity only). A joint resting on a stop
and pushed into it is locked for the next step: its acceleration is held at zero by the
stop's constraint torque, lambda = (E^T M^-1 E)^-1 E^T ddq_free, so that the stop, not the
rest of the arm, takes the push (ddq = ddq_free - M^-1 E lambda; E selects the locked joints;
a stop only pushes, so a joint whose lambda would pull is released).

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

COMMAND_MODES = ('idle', 'effort')


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


@dataclass
class ArmSimulator:
    """State and fixed-step update of the simulated arm (see the module docstring).

    arm: the true arm (true_arm); q, dq: joint state (n,) in rad and rad/s, q within the
    arm's position limits; dt: the step in s. The effort limits are the arm's
    (arm.limits.effort, finite and > 0).
    """

    arm: PinocchioModel
    q: np.ndarray
    dq: np.ndarray
    dt: float = 1e-3
    applied_effort: np.ndarray = field(default=None)

    def __post_init__(self):
        arm = self.arm
        self.q = arm.joint_vector(self.q, 'initial q')
        self.dq = arm.joint_vector(self.dq, 'initial dq')
        limits = arm.limits
        if np.any(self.q < limits.lower) or np.any(self.q > limits.upper):
            raise ValueError(f'initial q {self.q.tolist()} outside the joint limits '
                             f'{limits.lower.tolist()} .. {limits.upper.tolist()}')
        if not (np.all(np.isfinite(limits.effort)) and np.all(limits.effort > 0.0)):
            raise ValueError(f'effort limits must be finite and > 0, got '
                             f'{limits.effort.tolist()}')
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise ValueError(f'dt must be finite and > 0 s, got {self.dt}')
        self.applied_effort = np.zeros(arm.dof)
        self._no_wrench = (0.0,) * 6

    def actuator_torque(self, mode: str, command) -> np.ndarray:
        """Drive torque (n,) N m for `mode` in COMMAND_MODES: the command clipped at the
        effort limits, or zero."""
        if mode == 'effort':
            effort = self.arm.limits.effort
            return np.clip(np.asarray(command, dtype=float), -effort, effort)
        if mode == 'idle':
            return np.zeros(self.arm.dof)
        raise ValueError(f'unknown command mode {mode!r}; expected one of {COMMAND_MODES}')

    def acceleration(self, q, dq, torque, locked=None) -> np.ndarray:
        """ddq (n,) rad/s^2 of the true arm under the joint torque (n,) N m (friction and
        gravity included), the joints of the index array `locked` held by their stops;
        inputs unchecked (the 1 kHz path)."""
        free = self.arm.forward_dynamics(q, dq, torque)
        if locked is None or not locked.size:
            return free
        inverse = self.arm.inverse_mass_matrix(q)
        constraint = np.linalg.solve(inverse[np.ix_(locked, locked)], free[locked])
        return free - inverse[:, locked] @ constraint

    def _locked_joints(self, torque) -> np.ndarray | None:
        """The joints on a stop that the torque pushes into it (the stop holds them this
        step), or None."""
        lower, upper = self.arm.limits.lower, self.arm.limits.upper
        resting = ((self.q <= lower) & (self.dq <= 0.0)) | ((self.q >= upper) & (self.dq >= 0.0))
        if not resting.any():
            return None
        free = self.acceleration(self.q, self.dq, torque)
        inward = np.where(self.q <= lower, -1.0, 1.0)
        locked = np.flatnonzero(resting & (free * inward > 0.0))
        if locked.size > 1:
            # The constraint torques must push away from each stop; release those that pull.
            inverse = self.arm.inverse_mass_matrix(self.q)
            constraint = np.linalg.solve(inverse[np.ix_(locked, locked)], free[locked])
            locked = locked[constraint * inward[locked] > 0.0]
        return locked

    def step(self, mode: str, command, wrench) -> tuple[tuple[float, ...], ...]:
        """Advance one step of dt with the drive in `mode` and the human's wrench (6,) at the
        tool ((fx, fy, fz) N, (mx, my, mz) N m; shorter: the rest zero). Returns the new q
        (rad), dq (rad/s) and the applied drive torque (N m) as tuples of floats. Raises
        ValueError if the state becomes non-finite (commands are checked where they arrive).
        """
        tau = self.actuator_torque(mode, command)
        torque = tau
        if any(wrench):
            full = np.zeros(6)
            full[:len(wrench)] = wrench
            torque = tau + self.arm.tool_wrench_jacobian(self.q).T @ full
        locked = self._locked_joints(torque)
        q, dq, dt = self.q, self.dq, self.dt
        k1v = self.acceleration(q, dq, torque, locked)
        k2q = dq + 0.5 * dt * k1v
        k2v = self.acceleration(q + 0.5 * dt * dq, k2q, torque, locked)
        k3q = dq + 0.5 * dt * k2v
        k3v = self.acceleration(q + 0.5 * dt * k2q, k3q, torque, locked)
        k4q = dq + dt * k3v
        k4v = self.acceleration(q + dt * k3q, k4q, torque, locked)
        q_next = q + dt / 6.0 * (dq + 2.0 * k2q + 2.0 * k3q + k4q)
        dq_next = dq + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        if not (np.all(np.isfinite(q_next)) and np.all(np.isfinite(dq_next))):
            raise ValueError(f'the simulated state became non-finite (torque {torque.tolist()})')
        # A plastic impact on each stop reached: the joint keeps no velocity into its stop,
        # and the rest of the arm the velocity that the impulse of the stop leaves it.
        lower, upper = self.arm.limits.lower, self.arm.limits.upper
        q_next = np.clip(q_next, lower, upper)
        hit = np.flatnonzero(((q_next <= lower) & (dq_next < 0.0))
                             | ((q_next >= upper) & (dq_next > 0.0)))
        if hit.size:
            inverse = self.arm.inverse_mass_matrix(q_next)
            dq_next -= inverse[:, hit] @ np.linalg.solve(inverse[np.ix_(hit, hit)],
                                                         dq_next[hit])
            dq_next[hit] = 0.0  # exactly, not to rounding
        self.q = q_next
        self.dq = dq_next
        self.applied_effort = tau
        return tuple(self.q.tolist()), tuple(self.dq.tolist()), tuple(tau.tolist())

    def energy(self) -> float:
        """Kinetic plus gravitational potential energy of the true arm (J)."""
        return self.arm.kinetic_energy(self.q, self.dq) + self.arm.potential_energy(self.q)
