"""Adaptive torque law with the event-based task variable (paper eq. 16-23).

    s = qdot - qdot_r                                                        (eq. 17)
    tau = -Ks s - J^T Kp a delta_eps + Y_d(q, qdot, qdot_r, qddot_r) theta_hat  (eq. 16, 20)
    dtheta_hat/dt = -L Y_d^T s                                               (eq. 19)
    V = 1/2 s^T M s + Kp a Q + 1/2 dtheta^T L^-1 dtheta,  dtheta = theta - theta_hat  (eq. 21)
    dV/dt = -s^T (Ks + F) s - Kp |a delta_eps|^2 + Kp (da/dt) Q               (eq. 22)
            + Kp a delta_eps^T w,   w = v_r + a delta_eps - xdot_d    (avoid tasks only)

qdot_r, qddot_r, delta_eps = K dP/d(dx) under the speed cap and its potential Q come from
task_variable (eq. 12', 14);
Y_d is hri_core.dynamics.regressor (eq. 18). Two deliberate differences from the paper's
text, both needed for eq. 22 to follow from eq. 16-21:

- eq. 16 prints -Kp a delta_eps; the closed loop eq. 20 (and the units: delta_eps is a task
  space quantity, tau a joint torque) needs -J^T Kp a delta_eps, used here.
- With a scalar Kp (N s/m), the potential term of V must be Kp a Q (eq. 21 prints a P, which
  is right only for Kp = 1). Q is task_variable's potential (equal to K P where the task
  speed is below the cap), so eq. 22 holds below and above the cap. An avoid task's return to
  its rest position enters qdot_r only (not the Kp term): it is not a gradient of Q.
- eq. 22 assumes the reference of eq. 14, whose hand-velocity feed-forward cancels xdot_d in
  dQ/dt. An avoid task's reference v_r drops that feed-forward ((1 - a) xdot_d) and adds
  a v_rest, so w = v_r + a delta_eps - xdot_d = -a xdot_d + a v_rest is not zero and dV/dt
  gains Kp a delta_eps^T w = -Kp a^2 delta_eps^T xdot_d (+ Kp a^2 delta_eps^T v_rest, which
  is zero: v_rest fades in only where delta_eps has faded out). A hand reaching in at 0.2 m/s
  makes it about a tenth of dV/dt; the monitor (`predicted_lyapunov_rate`) includes it.
  F = diag(b1, b2), the true viscous friction, only adds dissipation. eq. 22 is exact when J+ is
  the exact inverse (manipulability above the damping threshold); the torque limit and the
  projection of theta_hat are the other places where the argument is not used as is.

Safety: the torque is limited by scaling the whole vector (direction kept) so that
max |tau_i| <= effort_limit, and any non-finite intermediate result gives zero torque and a
fault flag (theta_hat is then left unchanged). theta_hat is integrated with explicit Euler and
projected onto a bounded box of physically plausible values (DEFAULT_THETA_LOWER, _UPPER);
projection onto a convex set that contains the true parameters never increases V. eq. 19 is
paused (a dead zone in state) where its premise fails: scaled by 1 - w near a joint limit (w
the barrier's proximity, joint_limits: at the stop its force is outside the model) and off
while the torque is clamped (the drive does not apply the law's torque); the s-term of V is
then not decreased by the update, and theta_hat stays where it was.

Two paths compute the same step. `AdaptiveController.step` is the general numpy code, the
reference (any caller, every argument checked). `AdaptiveController.step_lean` is the 1 kHz
path of the controller node: the same equations written out in plain floats for the 2-joint
arm (J, J+ and dJ+/dt, the regressor, the torque, the theta_hat update; V and Q only when
asked), with no per-call validation: gains, parameters and the task are checked once when they
are set, the measurements by the node when a message arrives. The unit tests hold the two
equal to 1e-12 on random states; the task's own term is `task_variable.task_term`.

Units: q rad, qdot rad/s, tau N m, x m; theta = [pi1, pi2, pi3 (kg m^2), b1, b2 (N m s/rad),
mlc1, mlc2 (kg m)] as in hri_core.dynamics.dynamic_parameters.
"""

import dataclasses
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from hri_adaptive_controller.joint_limits import (
    JointLimits,
    ReachRound,
    ReachRoundSettings,
    barrier,
    barrier_energy,
    gate_feed_forward,
)
from hri_adaptive_controller.task_variable import (
    DampingSettings,
    JointReference,
    TaskDrives,
    joint_velocity_reference,
    rest_term,
    retreat_term,
    speed_cap,
    task_potential,
    task_term,
)
from hri_core.dynamics import regressor
from hri_core.potential import TaskShape

PARAMETER_COUNT = 7
HAND_RATE = 40.0
"""1/s: the hand-velocity filter of an avoid task's retreat (lag 2 / HAND_RATE = 50 ms)."""
# The hand-velocity filter's omega^2 (1/s^2) and 2 omega (1/s).
_HAND_STIFFNESS, _HAND_DAMPING = HAND_RATE * HAND_RATE, 2.0 * HAND_RATE
FEED_FORWARD_RATIO = 2.0
"""The hand's velocity enters qdot_r (eq. 14) capped at this times max_task_speed."""
PARAMETER_NAMES = ('pi1', 'pi2', 'pi3', 'b1', 'b2', 'mlc1', 'mlc2')

# Box for the projection of theta_hat (physical bounds): inertias positive, friction,
# pi2 = m2 l1 lc2 and the mass moments >= 0; above, what a 2-link arm of this size (links up
# to 0.5 m, up to 10 kg each) can have: pi1 <= 3, pi2, pi3 <= 1 kg m^2, b1, b2 <= 5 N m s/rad,
# mlc1, mlc2 <= 10 kg m (scara_sim's arm: 0.66, 0.19, 0.13, 1.0, 0.5, 1.75, 0.54). A bounded
# box keeps theta_hat bounded whatever the regressor sees (a stop's force, a saturated drive).
DEFAULT_THETA_LOWER = (1e-3, 0.0, 1e-3, 0.0, 0.0, 0.0, 0.0)
DEFAULT_THETA_UPPER = (3.0, 1.0, 1.0, 5.0, 5.0, 10.0, 10.0)


@dataclass(frozen=True)
class ControllerGains:
    """Gains of eq. 14-19 and the safety limits.

    ks: diagonal of Ks (N m s/rad), > 0; kp: scalar Kp (N s/m), >= 0; adaptation: diagonal of
    L (7 values, >= 0; units of theta^2 per N m s); task_gain: K (m^2/s) for every task, or
    None for each task's own K (0 = default_task_gain); approach_speed v_a (m/s, >= 0) and
    region_margin (m, >= 0): the approach term of task_variable; max_task_speed: v_max (m/s),
    the speed cap's knee; rest_gain (1/s, >= 0) and rest_gate (m, > 0): an avoid task's return
    to rest; damping: pseudo-inverse damping; effort_limit (N m); max_effort_rate (N m/s,
    > 0): the rate limit the callers apply after the clamp (effort_rate; not the law's own);
    theta_lower, theta_upper: projection box for theta_hat (7 values each).
    Raises ValueError with the reason for a value out of range.
    """

    ks: tuple[float, float]
    kp: float
    adaptation: tuple[float, ...]
    task_gain: float | None
    approach_speed: float
    region_margin: float
    max_task_speed: float
    effort_limit: float
    rest_gain: float = 2.0
    rest_gate: float = 0.03
    max_effort_rate: float = 1000.0
    damping: DampingSettings = field(default_factory=DampingSettings)
    theta_lower: tuple[float, ...] = DEFAULT_THETA_LOWER
    theta_upper: tuple[float, ...] = DEFAULT_THETA_UPPER
    joint_limits: JointLimits | None = field(default_factory=JointLimits)
    reach_round: ReachRoundSettings = field(default_factory=ReachRoundSettings)

    def __post_init__(self):
        ks = np.asarray(self.ks, dtype=float)
        if ks.shape != (2,) or not np.all(np.isfinite(ks)) or np.any(ks <= 0.0):
            raise ValueError(f'ks must be 2 finite values > 0 N m s/rad, got {self.ks}')
        if not (math.isfinite(self.kp) and self.kp >= 0.0):
            raise ValueError(f'kp must be finite and >= 0 N s/m, got {self.kp}')
        gains = np.asarray(self.adaptation, dtype=float)
        if (gains.shape != (PARAMETER_COUNT,) or not np.all(np.isfinite(gains))
                or np.any(gains < 0.0)):
            raise ValueError(
                f'adaptation must be {PARAMETER_COUNT} finite values >= 0, got {self.adaptation}')
        if self.task_gain is not None and not (
                math.isfinite(self.task_gain) and self.task_gain > 0.0):
            raise ValueError(f'task_gain must be None or finite and > 0, got {self.task_gain}')
        for name in ('max_task_speed', 'effort_limit', 'rest_gate', 'max_effort_rate'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        for name in ('approach_speed', 'region_margin', 'rest_gain'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')
        lower = np.asarray(self.theta_lower, dtype=float)
        upper = np.asarray(self.theta_upper, dtype=float)
        if lower.shape != (PARAMETER_COUNT,) or upper.shape != (PARAMETER_COUNT,):
            raise ValueError(f'theta_lower and theta_upper must have {PARAMETER_COUNT} values')
        if np.any(np.isnan(lower)) or np.any(np.isnan(upper)) or np.any(lower > upper):
            raise ValueError('theta_lower must be <= theta_upper (no NaN)')


# Default gains for the default SCARA of scara_sim (l1 = 0.35 m, l2 = 0.30 m, 4 kg + 3 kg,
# M(q) about [[0.66, 0.13], [0.13, 0.13]] kg m^2 at q2 = 90 deg), tuned in the pure closed loop
# (closed_loop.simulate) on Table I's three tasks. The paper's Ks = 0.01 I, Kp = 5 I were for
# its own robot (and its own scaling of P) and do not transfer.
DEFAULT_GAINS = ControllerGains(
    # Ks: sliding-variable damping. With M above, ks1 / M11 ~ ks2 / M22 ~ 30 1/s: s decays in
    # ~35 ms, fast against the task motion (hundreds of ms), slow against the 1 kHz loop.
    ks=(20.0, 4.0),
    # Kp (N s/m): weight of the task term J^T Kp a delta_eps. delta_eps is a velocity (m/s), so
    # Kp v_max = 2.5 N at full speed (<= 1.6 N m). The term drives s, so the arm runs faster
    # than the reference by about Kp |J|^2 / ks; with this Kp, at most 1.25 v_max (measured
    # for a still target). It still adds the -Kp |a delta_eps|^2 term of eq. 22.
    kp=10.0,
    # L: adaptation rates, scaled to each column of Y_d (accelerations ~ 1-10 rad/s^2 for the
    # inertias, velocities ~ 1 rad/s for the friction). Following a hand that circles (0.1 m,
    # 3 s period) from a 30-100 % wrong theta_hat(0), the inertias and frictions come within
    # 16 % in 20 s, with no torque peak above the start-up one; 10x smaller rates leave them
    # 40-100 % off after 20 s, 2-2.5x larger ones bring them within 1 %. This middle ground
    # keeps theta_hat from chasing every transient of s (and, on a real arm, sensor noise).
    # The gravity moments (zero columns for the horizontal arm) keep a small rate.
    adaptation=(5.0, 2.0, 1.0, 20.0, 10.0, 0.1, 0.1),
    # K: each task's own (the learner's k; Table I's rows, which have none, get
    # hri_core.potential.default_task_gain): a1, a2 and K set the speed where K |dP/dz|
    # exceeds approach_speed; nearer the region the approach floor below sets it.
    task_gain=None,
    # Approach floor: where the learned pull K |dP/dz| is below the floor, the arm still moves
    # towards the region at the floor's speed and enters it. The floor is the task's own pull
    # 0.2 m out (task_variable.task_approach_speed), at most approach_speed = 0.1 m/s and at
    # least 0.01 m/s: a demonstration n times slower approaches n times slower (K / 4: 3.98x
    # the time from 0.25 m, pure loop), and Table I's rows (pull far above 0.1 m/s there) keep
    # 0.1 m/s. Without a floor (P rises from its region like (r - d)^3) the arm creeps towards
    # the boundary forever (Table I's follow row moves at 0.3 mm/s 6 cm from its region); with
    # it, it stops region_margin inside the region.
    # 0.1 m/s: faster than a hand reaching in at 0.06 m/s, so avoid keeps its distance; in the
    # pure closed loop follow enters its region 2.0 s after the event (0.05 m/s: 3.1 s).
    # Set approach_speed to 0 for K |dP/dz| alone.
    approach_speed=0.1,
    # Region margin: 2 cm (at most a quarter of the region's width), the length over which the
    # floor fades out inside the region. The fade's jerk grows with the crossing speed squared
    # over the margin squared: a hand reaching in at 0.5 m/s steps the torque between two 1 ms
    # cycles by 2.4 N m with 5 mm, 0.79 N m with 1 cm, 0.25 N m with 2 cm (Table I's avoid
    # row, pure closed loop); on a loaded machine the node misses cycles, and two cycles' worth
    # of change then come in one command, so the margin matters on the topics.
    region_margin=0.02,
    # v_max: a speed that is safe near a person (ISO/TS 15066 reduced-speed practice).
    max_task_speed=0.25,
    # effort_limit: the simulated drives' limit (scara_sim effort_limit: 20 N m).
    effort_limit=20.0,
    # Avoid tasks return to rest at rest_gain 2 1/s (1/e in 0.5 s, capped like the task speed)
    # once the arm is rest_gate 3 cm outside the region's edge; nearer the hand, the potential
    # alone acts.
    rest_gain=2.0,
    rest_gate=0.03,
    # Torque rate limit (effort_rate, after the clamp): 1000 N m/s = 1 N m per 1 ms cycle, the
    # continuity bar of the torque. The law stays below it in the pure closed loop (at most
    # 0.25 N m per cycle, Table I's and the demo's rows); on the topics it catches what a
    # loaded machine adds (a command computed late carries several cycles' change).
    max_effort_rate=1000.0,
    # J+ damping from 28 deg of the stretched arm on, up to lambda = 0.15 m: joint speeds stay
    # below 3 rad/s and torques below 10 N m when the target is out of reach (see
    # DampingSettings); the task region of the demos lies well inside.
    damping=DampingSettings(threshold=0.05, max_damping=0.15),
)


@dataclass(frozen=True)
class ControlOutput:
    """Result of one controller step.

    tau (2,) N m, the command (zeros on a fault); tau_requested (2,) N m, before the limit;
    s (2,) rad/s (eq. 17); distance |x - x_d| (m); lyapunov V (eq. 21; J); task_potential Q
    (m^2/s); lyapunov_rate: dV/dt of eq. 22 predicted from the current state (W), with the
    friction passed to step (none by default); these three are None when not monitored, and
    distance is None on a fault. theta_hat (7,) used for this step; reference: the
    JointReference (None on a fault); task_gain k (m^2/s, 0 without a task); torque_limited,
    fault (bool); fault_reason (str).
    """

    tau: np.ndarray
    tau_requested: np.ndarray
    s: np.ndarray
    distance: float | None
    lyapunov: float | None
    task_potential: float | None
    lyapunov_rate: float | None
    theta_hat: np.ndarray
    reference: JointReference | None
    task_gain: float
    torque_limited: bool
    fault: bool
    fault_reason: str = ''


class LeanOutput(NamedTuple):
    """Result of `AdaptiveController.step_lean` (plain floats; the fields of ControlOutput).
    A NamedTuple, made once per control cycle: 0.6 us against 3 us for a frozen dataclass.

    tau, tau_requested (2,) N m; s (2,) rad/s; qdot_r (2,) rad/s (eq. 14; the velocity-mode
    command); distance |x - x_d| (m; None on a fault); lyapunov V (J), task_potential Q
    (m^2/s), lyapunov_rate (W): None unless monitored; theta_hat (7,) used for this step;
    task_gain k (m^2/s); torque_limited, fault (bool); fault_reason (str); damping: lambda^2
    of the pseudo-inverse J+ (m^2/rad^2; 0 on a fault).
    """

    tau: tuple[float, float]
    tau_requested: tuple[float, float]
    s: tuple[float, float]
    qdot_r: tuple[float, float]
    distance: float | None
    lyapunov: float | None
    task_potential: float | None
    lyapunov_rate: float | None
    theta_hat: tuple[float, ...]
    task_gain: float
    torque_limited: bool
    fault: bool
    fault_reason: str = ''
    damping: float = 0.0


def limit_torque(tau, effort_limit: float) -> tuple[np.ndarray, bool]:
    """Scale tau (n,) N m as a whole so that max |tau_i| <= effort_limit (N m).

    Keeps the direction of the torque vector. Returns (limited torque, whether it was scaled).
    """
    tau = np.asarray(tau, dtype=float)
    if not (math.isfinite(effort_limit) and effort_limit > 0.0):
        raise ValueError(f'effort_limit must be finite and > 0 N m, got {effort_limit}')
    peak = float(np.max(np.abs(tau)))
    if peak <= effort_limit:
        return tau.copy(), False
    return tau * (effort_limit / peak), True


def adaptive_torque(s, jac, weighted_task_variable, regressor_matrix, theta_hat, ks,
                    kp: float) -> np.ndarray:
    """tau = -Ks s - J^T Kp a delta_eps + Y_d theta_hat (eq. 16, with J^T as in eq. 20).

    s (2,) rad/s; jac (2, 2) m/rad; weighted_task_variable a delta_eps (2,) m/s;
    regressor_matrix Y_d (2, 7); theta_hat (7,); ks (2,) N m s/rad; kp N s/m. Returns (2,) N m.
    """
    return (-np.asarray(ks) * np.asarray(s) - kp * (np.asarray(jac).T @ weighted_task_variable)
            + np.asarray(regressor_matrix) @ np.asarray(theta_hat))


def parameter_update_rate(regressor_matrix, s, adaptation) -> np.ndarray:
    """dtheta_hat/dt = -L Y_d^T s (eq. 19), shape (7,); L = diag(adaptation), s (2,) rad/s."""
    return -np.asarray(adaptation) * (np.asarray(regressor_matrix).T @ np.asarray(s))


def mass_matrix_from_parameters(q, theta, gravity: float = 0.0) -> np.ndarray:
    """Inertia matrix M(q) (kg m^2), (2, 2), implied by a parameter vector theta (7,).

    Column j is Y_d(q, 0, 0, e_j) theta minus the gravity term: the model of eq. 18 itself,
    so an estimate theta_hat gives the controller's own M_hat(q).
    """
    theta = np.asarray(theta, dtype=float)
    accelerations = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    torques = regressor(q, np.zeros(2), np.zeros(2), accelerations, gravity) @ theta
    return (torques[1:] - torques[0]).T


def lyapunov(s, q, weight: float, task_potential_value: float, kp: float, theta_hat,
             adaptation, theta_true=None, gravity: float = 0.0) -> float:
    """Lyapunov-like function V of eq. 21 (J), with Kp a Q as its potential term.

    s (2,) rad/s; q (2,) rad; weight a in [0, 1]; task_potential_value Q (m^2/s, from
    task_variable.task_potential); kp N s/m; theta_hat (7,); adaptation diag L (7,).
    theta_true (7,) is known only in simulation: with it, V uses the true M(q) and adds
    1/2 dtheta^T L^-1 dtheta (over parameters with L_i > 0); without it (a real robot), V is
    1/2 s^T M_hat s + Kp a Q with M_hat from theta_hat (an estimate of V without its
    parameter-error term).
    """
    theta_hat = np.asarray(theta_hat, dtype=float)
    s = np.asarray(s, dtype=float)
    theta_model = theta_hat if theta_true is None else np.asarray(theta_true, dtype=float)
    inertia = mass_matrix_from_parameters(q, theta_model, gravity)
    value = 0.5 * float(s @ inertia @ s) + kp * weight * task_potential_value
    if theta_true is not None:
        gains = np.asarray(adaptation, dtype=float)
        active = gains > 0.0
        error = theta_model - theta_hat
        value += 0.5 * float(np.sum(error[active] ** 2 / gains[active]))
    return value


def predicted_lyapunov_rate(s, weighted_task_variable, weight_rate: float,
                            task_potential_value: float, ks, kp: float,
                            friction=(0.0, 0.0), reference_offset=(0.0, 0.0)) -> float:
    """dV/dt (W) of eq. 22 with the avoid task's term (module docstring):

        -s^T (Ks + F) s - Kp |a delta_eps|^2 + Kp (da/dt) Q + Kp (a delta_eps)^T w.

    s (2,) rad/s; weighted_task_variable a delta_eps (2,) m/s; weight_rate da/dt (1/s);
    task_potential_value Q (m^2/s); ks (2,) N m s/rad; kp N s/m; friction diag F (2,);
    reference_offset w = v_r + a delta_eps - xdot_d (2,) m/s: what the reference adds to
    the hand's velocity besides the task term (0 for follow tasks and without a task,
    -a xdot_d + a v_rest for an avoid task).
    """
    s = np.asarray(s, dtype=float)
    damping = np.asarray(ks, dtype=float) + np.asarray(friction, dtype=float)
    task = np.asarray(weighted_task_variable, dtype=float)
    offset = np.asarray(reference_offset, dtype=float)
    return float(-np.sum(damping * s * s) - kp * (task @ task)
                 + kp * weight_rate * task_potential_value + kp * (task @ offset))


def filter_hand_velocity(state: tuple, xdot_d, dt: float) -> tuple:
    """The hand's velocity through a critically damped second-order filter (HAND_RATE),
    advanced by dt (s): state and result (v_1 .. v_m, dv_1/dt .. dv_m/dt) m/s, m/s^2 (floats;
    m = 2 for the SCARA, 3 for arm_law), xdot_d (m,) m/s. The estimate steps at each /target;
    the avoid tasks' retreat (task_variable.retreat_term) acts on this one, whose rate is
    continuous, so the torque does not step with the messages. A non-finite result restarts
    the filter at zero."""
    m = len(state) // 2
    out = list(state)
    for i in range(m):  # a plain loop: 1.3 us, against 5.8 us for tuples built from zips
        v, a = state[i], state[m + i]
        a = a + dt * (_HAND_STIFFNESS * (xdot_d[i] - v) - _HAND_DAMPING * a)
        out[i], out[m + i] = v + dt * a, a
    if not all(map(math.isfinite, out)):
        return (0.0,) * (2 * m)
    return tuple(out)


class AdaptiveController(TaskDrives):
    """The adaptive controller of eq. 16-19 with its parameter estimate theta_hat.

    gains: ControllerGains; theta_hat0 (7,): initial estimate (projected onto the gains' box);
    l1, l2: link lengths (m); gravity (m/s^2, 0 for the horizontal SCARA).
    """

    def __init__(self, gains: ControllerGains = DEFAULT_GAINS, theta_hat0=None,
                 l1: float = 0.35, l2: float = 0.30, gravity: float = 0.0) -> None:
        if theta_hat0 is None:
            raise ValueError('theta_hat0 (7 initial parameter estimates) is required')
        for name, value in (('l1', l1), ('l2', l2)):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0 m, got {value}')
        if not math.isfinite(gravity):
            raise ValueError(f'gravity must be finite, got {gravity}')
        super().__init__(gains, float(l1) + float(l2))
        self._l1, self._l2, self._gravity = float(l1), float(l2), float(gravity)
        self._lower = np.asarray(gains.theta_lower, dtype=float)
        self._upper = np.asarray(gains.theta_upper, dtype=float)
        self._ks = np.asarray(gains.ks, dtype=float)
        self._adaptation = np.asarray(gains.adaptation, dtype=float)
        # The lean step's constants as Python floats.
        self._ks_floats = tuple(self._ks.tolist())
        self._adaptation_floats = tuple(self._adaptation.tolist())
        self._box = tuple(zip(gains.theta_lower, gains.theta_upper, strict=True))
        self._threshold2 = gains.damping.threshold ** 2
        self._feed_speed = FEED_FORWARD_RATIO * gains.max_task_speed
        self._max_damping2 = gains.damping.max_damping ** 2
        # Joint limits (joint_limits): the barrier needs Kp > 0 (its reference is g / Kp).
        self._limits = gains.joint_limits if gains.kp > 0.0 else None
        self._reach = (None if self._limits is None
                       else ReachRound(gains.reach_round, self._limits, self._l1, self._l2))
        self.reset(theta_hat0)

    @property
    def gains(self) -> ControllerGains:
        """The controller's gains."""
        return self._gains

    @property
    def theta_hat(self) -> np.ndarray:
        """Current parameter estimate (7,), a copy."""
        return np.array(self._theta)

    def reset(self, theta_hat0) -> None:
        """Restart the estimate at theta_hat0 (7,), projected onto the box."""
        theta = np.asarray(theta_hat0, dtype=float)
        if theta.shape != (PARAMETER_COUNT,) or not np.all(np.isfinite(theta)):
            raise ValueError(f'theta_hat0 must be {PARAMETER_COUNT} finite values, got {theta}')
        self._theta_hat = np.clip(theta, self._lower, self._upper)
        self._theta = tuple(self._theta_hat.tolist())
        if self._reach is not None:
            self._reach.reset()
        self._hand_velocity = (0.0, 0.0, 0.0, 0.0)

    @property
    def reaching_round(self) -> bool:
        """Whether the reach-round blend is heading to (or at) the joint-space motion."""
        return self._reach is not None and self._reach.engaged

    def _smooth_hand_velocity(self, xdot_d, dt: float):
        """filter_hand_velocity advanced by dt: (v1, v2, dv1/dt, dv2/dt)."""
        self._hand_velocity = filter_hand_velocity(self._hand_velocity, xdot_d, dt)
        return self._hand_velocity

    def _limited_reference(self, state, hand, drive, weight, pinvs, feed, task, dt: float):
        """qdot_r, qddot_r with the joint limits (joint_limits): the barrier, the gated
        feed-forward and the reach-round blend; one code for step and step_lean.

        state (q1, q2, dq1, dq2, x1, x2); hand x_d (2,) m; drive: the TaskDrive or None;
        weight (a, da/dt): the task's event weight, which scales the reach-round's joint
        motion as it scales the task's pull (a task fading out stops reaching round too);
        pinvs (J+, dJ+/dt), each as (11, 12, 21, 22); feed: the feed-forward f xdot_d and
        its rate (4,), task: the task velocity -a delta_eps + a v_rest and its rate (4,), m/s
        and m/s^2; dt (s) advances the reach-round state. Returns (qr1, qr2, ar1, ar2, c, g1,
        g2, near): c = 1 - sigma weights the task's force; g the barrier's gradient (N m);
        near its proximity.
        """
        (p11, p12, p21, p22), (r11, r12, r21, r22) = pinvs
        ff1, ff2, zf1, zf2 = feed
        vt1, vt2, zt1, zt2 = task
        speed = math.hypot(ff1, ff2)
        if speed > self._feed_speed:
            # The hand's velocity fed forward at most FEED_FORWARD_RATIO v_max (the smooth
            # cap of task_variable, C2): the arm is not asked to keep up with a hand faster
            # than it may move (a toss at 3 m/s saturated the drives for 0.4 s).
            capped, slope = speed_cap(speed, self._feed_speed)
            ratio = capped / speed
            n1, n2 = ff1 / speed, ff2 / speed
            along = (n1 * zf1 + n2 * zf2) * (slope - ratio)
            ff1, ff2, zf1, zf2 = (ratio * ff1, ratio * ff2, ratio * zf1 + n1 * along,
                                  ratio * zf2 + n2 * along)
        f1, f2 = p11 * ff1 + p12 * ff2, p21 * ff1 + p22 * ff2
        fa1 = r11 * ff1 + r12 * ff2 + (p11 * zf1 + p12 * zf2)
        fa2 = r21 * ff1 + r22 * ff2 + (p21 * zf1 + p22 * zf2)
        t1, t2 = p11 * vt1 + p12 * vt2, p21 * vt1 + p22 * vt2
        ta1 = r11 * vt1 + r12 * vt2 + (p11 * zt1 + p12 * zt2)
        ta2 = r21 * vt1 + r22 * vt2 + (p21 * zt1 + p22 * zt2)
        limits = self._limits
        if limits is None:
            return f1 + t1, f2 + t2, fa1 + ta1, fa2 + ta2, 1.0, 0.0, 0.0, 0.0
        q1, q2, w1, w2, x1, x2 = state
        g1, g2, gd1, gd2, near = barrier(q1, q2, w1, w2, limits)
        if near > 0.0:
            f1, f2, fa1, fa2 = gate_feed_forward(q1, q2, w1, w2, f1, f2, fa1, fa2, limits)
        region = (None if drive is None or drive.open_outward
                  else (drive.shape.d1, drive.shape.d2))
        sigma, sigma_rate, u1, u2, ud1, ud2 = self._reach.update(
            q1, q2, w1, w2, x1, x2, hand, region, near, dt)
        if sigma != 0.0 or sigma_rate != 0.0:
            # The joint motion a u, weighted as the task's pull is: d(a u)/dt = da u + a du.
            a, da = weight
            u1, u2, ud1, ud2 = a * u1, a * u2, da * u1 + a * ud1, da * u2 + a * ud2
        c = 1.0 - sigma
        qr1, qr2 = f1 + t1, f2 + t2
        ar1 = c * (fa1 + ta1) + sigma_rate * (u1 - qr1) + sigma * ud1
        ar2 = c * (fa2 + ta2) + sigma_rate * (u2 - qr2) + sigma * ud2
        qr1, qr2 = c * qr1 + sigma * u1, c * qr2 + sigma * u2
        if g1 != 0.0 or g2 != 0.0 or gd1 != 0.0 or gd2 != 0.0:
            # The barrier's task-space velocity -J+^T g / Kp, through J+ like the task's.
            inv_kp = 1.0 / self._gains.kp
            y1, y2 = (p11 * g1 + p21 * g2) * inv_kp, (p12 * g1 + p22 * g2) * inv_kp
            yd1 = (r11 * g1 + r21 * g2 + p11 * gd1 + p21 * gd2) * inv_kp
            yd2 = (r12 * g1 + r22 * g2 + p12 * gd1 + p22 * gd2) * inv_kp
            qr1 -= p11 * y1 + p12 * y2
            qr2 -= p21 * y1 + p22 * y2
            ar1 -= r11 * y1 + r12 * y2 + (p11 * yd1 + p12 * yd2)
            ar2 -= r21 * y1 + r22 * y2 + (p21 * yd1 + p22 * yd2)
        return qr1, qr2, ar1, ar2, c, g1, g2, near

    def step(self, q, dq, x_d, xdot_d, xddot_d, a: float, da: float,
             shape: TaskShape | None, dt: float, theta_true=None,
             friction=None, monitor: bool = True, k: float = 0.0,
             rest=None) -> ControlOutput:
        """Torque for the state (q, dq) and advance theta_hat by dt (eq. 16-19).

        q, dq (2,) rad, rad/s; x_d, xdot_d, xddot_d (2,) m, m/s, m/s^2: the target; a, da:
        a(E, t) and da/dt (1/s); shape: active task or None; dt (s) > 0: time to the next
        step (for the Euler step of eq. 19). theta_true (7,) and friction diag F (2,) are for
        simulation monitoring only (V with its parameter term; eq. 22's prediction). k: the
        task's gain K (m^2/s, 0 = not given); rest (2,) m: an avoid task's rest position
        (None: no return). monitor=False skips V and Q (saves the radial integral).
        Non-finite measurements or results give zero torque and fault=True; bad arguments
        raise ValueError.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'dt must be finite and > 0 s, got {dt}')
        if not (math.isfinite(a) and 0.0 <= a <= 1.0):
            raise ValueError(f'a(E, t) must be in [0, 1], got {a}')
        theta_hat = np.array(self._theta)
        shaped = self._control_drive(shape, k)
        k = 0.0 if shaped is None else shaped.task_gain
        measurements = [np.asarray(v, dtype=float) for v in (q, dq, x_d, xdot_d, xddot_d)]
        if any(m.shape != (2,) for m in measurements):
            raise ValueError('q, dq, x_d, xdot_d, xddot_d must each have shape (2,)')
        if not all(np.all(np.isfinite(m)) for m in measurements) or not math.isfinite(da):
            return self._fault(theta_hat, k, 'non-finite joint state, target or da/dt')
        q, dq, x_d, xdot_d, xddot_d = measurements
        gains = self._gains
        hand = self._smooth_hand_velocity(tuple(xdot_d.tolist()), dt)
        hand_velocity = xdot_d  # the measured one, which moves the task's potential
        if shaped is not None and shaped.open_outward:  # as step_lean
            xdot_d, xddot_d = np.array(hand[:2]), np.array(hand[2:])
        try:
            with np.errstate(all='ignore'):
                reference = joint_velocity_reference(
                    q, dq, x_d, xdot_d, xddot_d, a, da, shaped, self._l1, self._l2,
                    gains.damping, rest)
        except ValueError as error:
            return self._fault(theta_hat, k, str(error))
        task_velocity, task_rate = reference.task_velocity, reference.task_rate
        if shaped is not None and shaped.open_outward:
            xv1, xv2 = (reference.jacobian @ dq).tolist()
            (dx1, dx2), (hv1, hv2, ha1, ha2) = reference.dx.tolist(), hand
            e1, e2, de1, de2 = retreat_term(dx1, dx2, xv1 - hv1, xv2 - hv2, hv1, hv2, ha1,
                                            ha2, shaped)
            task_velocity = task_velocity + a * np.array([e1, e2])
            task_rate = task_rate + da * np.array([e1, e2]) + a * np.array([de1, de2])
        with np.errstate(all='ignore'):
            floats = [float(v) for v in (*q, *dq, *reference.position)]
            qr1, qr2, ar1, ar2, scale, g1, g2, near = self._limited_reference(
                floats, tuple(x_d.tolist()), shaped, (a, da),
                (tuple(reference.pinv.ravel().tolist()),
                 tuple(reference.pinv_rate.ravel().tolist())),
                (*reference.feed_forward.tolist(), *reference.feed_forward_rate.tolist()),
                (*task_velocity.tolist(), *task_rate.tolist()), dt)
            qdot_r, qddot_r = np.array([qr1, qr2]), np.array([ar1, ar2])
            barrier_gradient = np.array([g1, g2])
            s = dq - qdot_r
            y_d = regressor(q, dq, qdot_r, qddot_r, self._gravity)
            tau_requested = adaptive_torque(s, reference.jacobian,
                                            scale * reference.weighted_task_variable, y_d,
                                            theta_hat, self._ks, gains.kp) - barrier_gradient
        if not (np.all(np.isfinite(tau_requested)) and np.all(np.isfinite(qddot_r))):
            return self._fault(theta_hat, k, 'non-finite torque or parameter update')
        tau, limited = limit_torque(tau_requested, gains.effort_limit)
        # eq. 19, paused at a limit and while clamped (as step_lean).
        pace = 0.0 if limited else dt * (1.0 - near)
        with np.errstate(all='ignore'):
            theta_next = np.clip(
                theta_hat + pace * parameter_update_rate(y_d, s, self._adaptation),
                self._lower, self._upper)
        if not np.all(np.isfinite(theta_next)):
            return self._fault(theta_hat, k, 'non-finite torque or parameter update')
        self._theta = tuple(theta_next.tolist())
        reference = dataclasses.replace(reference, qdot_r=qdot_r, qddot_r=qddot_r)
        q_value = v_value = v_rate = None
        if monitor:
            q_value = 0.0 if shaped is None else task_potential(reference.distance, shaped)
            v_value = lyapunov(s, q, a, q_value, gains.kp, theta_hat, self._adaptation,
                               theta_true, self._gravity)
            # With the barrier (joint_limits): B in V, and the task's and the barrier's
            # task-space velocity together in eq. 22's Kp |.|^2 term.
            effective = scale * reference.weighted_task_variable
            if self._limits is not None:
                v_value += barrier_energy(floats[0], floats[1], self._limits)
                effective = effective + reference.pinv.T @ barrier_gradient / gains.kp
            # w = v_r + a delta_eps - xdot_d: a v_rest and the retreat (in task_velocity),
            # and f xdot_f - xdot_d, f = 1 - a, for an avoid task, whose reference drops the
            # feed-forward and reads the hand's velocity through its filter (xdot_f).
            offset = task_velocity + reference.weighted_task_variable
            if shaped is not None and shaped.open_outward:
                offset = offset + (1.0 - a) * xdot_d - hand_velocity
            v_rate = predicted_lyapunov_rate(
                s, effective, da, q_value, self._ks, gains.kp,
                (0.0, 0.0) if friction is None else friction, offset)
        return ControlOutput(
            tau=tau, tau_requested=tau_requested, s=s, distance=reference.distance,
            lyapunov=v_value, task_potential=q_value, lyapunov_rate=v_rate,
            theta_hat=theta_hat, reference=reference, task_gain=k, torque_limited=limited,
            fault=False)

    def step_lean(self, q, dq, x_d, xdot_d, xddot_d, a: float, da: float,
                  shape: TaskShape | None, dt: float, monitor: bool = False,
                  theta_true=None, friction=None, k: float = 0.0,
                  rest=None, with_potential: bool = True) -> LeanOutput:
        """`step` for the 2-joint arm in plain floats, without per-call checks.

        Same arguments and equations as `step`; q, dq, x_d, xdot_d, xddot_d are pairs of
        finite floats (rad, rad/s, m, m/s, m/s^2), a in [0, 1], da finite, dt > 0 s: the
        caller checks them where they enter (the node, when a message arrives). A non-finite
        result still gives zero torque and fault=True, theta_hat unchanged.
        with_potential=False (with monitor): task_potential is None, and V and dV/dt leave out
        their task terms kp a Q and kp da Q, for a caller that adds them for many steps at
        once (`closed_loop.simulate`, with task_variable.task_potentials).
        """
        q1, q2 = q
        w1, w2 = dq
        l1, l2 = self._l1, self._l2
        hand = self._smooth_hand_velocity(xdot_d, dt)
        # Kinematics: x, J, dJ/dt (hri_core.dynamics.forward_kinematics, jacobian, ...).
        s1, c1 = math.sin(q1), math.cos(q1)
        s12, c12 = math.sin(q1 + q2), math.cos(q1 + q2)
        w12 = w1 + w2
        j11, j12 = -l1 * s1 - l2 * s12, -l2 * s12
        j21, j22 = l1 * c1 + l2 * c12, l2 * c12
        d11, d12 = -l1 * c1 * w1 - l2 * c12 * w12, -l2 * c12 * w12
        d21, d22 = -l1 * s1 * w1 - l2 * s12 * w12, -l2 * s12 * w12
        # Damped pseudo-inverse J+ = J^T A^-1, A = J J^T + lambda^2 I, and dJ+/dt.
        g11, g12, g22 = j11 * j11 + j12 * j12, j11 * j21 + j12 * j22, j21 * j21 + j22 * j22
        ratio = (g11 * g22 - g12 * g12) / self._threshold2
        if ratio >= 1.0:
            lam2 = dlam2 = 0.0
        else:
            lam2 = self._max_damping2 * (1.0 - ratio) ** 2
            dlam2 = -2.0 * self._max_damping2 * (1.0 - ratio) / self._threshold2
        a11, a22 = g11 + lam2, g22 + lam2
        det = a11 * a22 - g12 * g12
        theta = self._theta
        drive = None if shape is None else self._control_drive(shape, k)
        k = 0.0 if drive is None else drive.task_gain
        if abs(det) <= 1e-300:
            return self._lean_fault(theta, k, 'singular Jacobian and no damping '
                                    '(max_damping = 0)')
        i11, i12, i22 = a22 / det, -g12 / det, a11 / det  # A^-1 (symmetric)
        p11, p12 = j11 * i11 + j21 * i12, j11 * i12 + j21 * i22
        p21, p22 = j12 * i11 + j22 * i12, j12 * i12 + j22 * i22
        # dG/dt = dJ J^T + J dJ^T (symmetric); d det(G)/dt = tr(adj(G) dG/dt).
        e11 = 2.0 * (d11 * j11 + d12 * j12)
        e12 = d11 * j21 + d12 * j22 + j11 * d21 + j12 * d22
        e22 = 2.0 * (d21 * j21 + d22 * j22)
        lam2_dot = dlam2 * (g22 * e11 + g11 * e22 - 2.0 * g12 * e12)
        f11, f22 = e11 + lam2_dot, e22 + lam2_dot  # dA/dt
        # B = dA/dt A^-1; dJ+/dt = dJ^T A^-1 - J+ B.
        b11, b12 = f11 * i11 + e12 * i12, f11 * i12 + e12 * i22
        b21, b22 = e12 * i11 + f22 * i12, e12 * i12 + f22 * i22
        r11 = d11 * i11 + d21 * i12 - (p11 * b11 + p12 * b21)
        r12 = d11 * i12 + d21 * i22 - (p11 * b12 + p12 * b22)
        r21 = d12 * i11 + d22 * i12 - (p21 * b11 + p22 * b21)
        r22 = d12 * i12 + d22 * i22 - (p21 * b12 + p22 * b22)
        # Task velocity a delta_eps, the avoid task's return a v_rest and their time
        # derivatives (eq. 12', 14, 18; task_variable.joint_velocity_reference).
        xd1, xd2 = x_d
        vd1, vd2 = hv1, hv2 = xdot_d  # hv: the measured hand velocity, for the monitor
        ad1, ad2 = xddot_d
        if drive is not None and drive.open_outward:
            # An avoid task reads the hand's velocity through the filter (its rate is
            # continuous): the estimate steps at each /target, and the arm, kept outside d1
            # by the retreat, sits where the rest term's rate reads it.
            vd1, vd2, ad1, ad2 = hand
        x1, x2 = l1 * c1 + l2 * c12, l1 * s1 + l2 * s12
        dx1, dx2 = x1 - xd1, x2 - xd2
        distance = math.hypot(dx1, dx2)
        feed, feed_rate = 1.0, 0.0
        o1 = o2 = p1 = p2 = 0.0  # a v_rest and its time derivative
        if drive is None:
            m1 = m2 = n1 = n2 = 0.0
        elif not math.isfinite(distance):  # the potential's code refuses a non-finite dx
            return self._lean_fault(theta, k, 'non-finite joint state or target')
        else:
            t1, t2, h11, h12, h22 = task_term(dx1, dx2, drive)
            xv1, xv2 = j11 * w1 + j12 * w2, j21 * w1 + j22 * w2
            u1, u2 = xv1 - vd1, xv2 - vd2
            m1, m2 = a * t1, a * t2
            n1 = da * t1 + a * (h11 * u1 + h12 * u2)
            n2 = da * t2 + a * (h12 * u1 + h22 * u2)
            if drive.open_outward:
                feed, feed_rate = 1.0 - a, -da
                rx1, rx2 = (x1, x2) if rest is None else rest
                r1, r2, cr1, cr2, gw1, gw2, b11, b12, b22 = rest_term(
                    dx1, dx2, x1 - rx1, x2 - rx2, drive)
                along = gw1 * u1 + gw2 * u2
                e1, e2, de1, de2 = retreat_term(dx1, dx2, u1, u2, vd1, vd2, ad1, ad2, drive)
                r1, r2 = r1 + e1, r2 + e2
                o1, o2 = a * r1, a * r2
                p1 = da * r1 + a * (cr1 * along + (b11 * xv1 + b12 * xv2) + de1)
                p2 = da * r2 + a * (cr2 * along + (b12 * xv1 + b22 * xv2) + de2)
        qr1, qr2, ar1, ar2, scale, gb1, gb2, near = self._limited_reference(
            (q1, q2, w1, w2, x1, x2), x_d, drive, (a, da),
            ((p11, p12, p21, p22), (r11, r12, r21, r22)),
            (feed * vd1, feed * vd2, feed * ad1 + feed_rate * vd1, feed * ad2 + feed_rate * vd2),
            (o1 - m1, o2 - m2, p1 - n1, p2 - n2), dt)
        # Regressor Y_d (eq. 18; hri_core.dynamics.regressor), torque (eq. 16), update (eq. 19).
        sn1, sn2 = w1 - qr1, w2 - qr2
        cq2, sq2 = math.cos(q2), math.sin(q2)
        y12 = cq2 * (2.0 * ar1 + ar2) - sq2 * (w2 * qr1 + w12 * qr2)
        y22 = cq2 * ar1 + sq2 * w1 * qr1
        y23 = ar1 + ar2
        gravity = self._gravity
        gc1, gc12 = gravity * c1, gravity * c12
        th1, th2, th3, th4, th5, th6, th7 = theta
        ks1, ks2 = self._ks_floats
        kp = self._gains.kp
        kc = kp * scale
        tau1 = (-ks1 * sn1 - kc * (j11 * m1 + j21 * m2) - gb1
                + (ar1 * th1 + y12 * th2 + ar2 * th3 + qr1 * th4 + gc1 * th6 + gc12 * th7))
        tau2 = (-ks2 * sn2 - kc * (j12 * m1 + j22 * m2) - gb2
                + (y22 * th2 + y23 * th3 + qr2 * th5 + gc12 * th7))
        peak = max(abs(tau1), abs(tau2))
        limit = self._gains.effort_limit
        limited = peak > limit
        # eq. 19, paused where its premise fails: at a limit (the stop's force is outside
        # the model) and while the torque is clamped (the arm does not get the law's torque).
        pace = 0.0 if limited else dt * (1.0 - near)
        rates = (ar1 * sn1, y12 * sn1 + y22 * sn2, ar2 * sn1 + y23 * sn2, qr1 * sn1,
                 qr2 * sn2, gc1 * sn1, gc12 * (sn1 + sn2))
        theta_next = []
        for value, rate, gain, (low, high) in zip(theta, rates, self._adaptation_floats,
                                                  self._box, strict=True):
            value = value - pace * (gain * rate)
            theta_next.append(low if value < low else high if value > high else value)
        isfinite = math.isfinite
        if not (isfinite(tau1) and isfinite(tau2) and isfinite(ar1) and isfinite(ar2)
                and all(map(isfinite, theta_next))):
            return self._lean_fault(theta, k, 'non-finite torque or parameter update')
        tau = (tau1 * (limit / peak), tau2 * (limit / peak)) if limited else (tau1, tau2)
        self._theta = tuple(theta_next)
        q_value = v_value = v_rate = None
        if monitor:
            q_value = (task_potential(distance, drive) if with_potential and drive is not None
                       else 0.0)
            model = theta if theta_true is None else tuple(float(v) for v in theta_true)
            mi1, mi2, mi3 = model[0], model[1], model[2]
            m11, m12 = mi1 + 2.0 * mi2 * cq2, mi3 + mi2 * cq2
            v_value = (0.5 * (sn1 * (m11 * sn1 + m12 * sn2) + sn2 * (m12 * sn1 + mi3 * sn2))
                       + kp * a * q_value)
            e1, e2 = kc * m1, kc * m2  # Kp (the task's and the barrier's velocity)
            if self._limits is not None:
                v_value += barrier_energy(q1, q2, self._limits)
                e1 += p11 * gb1 + p21 * gb2
                e2 += p12 * gb1 + p22 * gb2
            if theta_true is not None:
                v_value += 0.5 * sum((true - hat) ** 2 / gain for true, hat, gain in zip(
                    model, theta, self._adaptation_floats, strict=True) if gain > 0.0)
            f1, f2 = (0.0, 0.0) if friction is None else friction
            # eq. 22 and the avoid task's Kp a delta_eps^T w, w = feed xdot_f + a v_rest - xdot_d
            # (a v_rest with the retreat; xdot_f the filtered hand velocity the reference read).
            ow1, ow2 = feed * vd1 + o1 - hv1, feed * vd2 + o2 - hv2
            v_rate = (-((ks1 + f1) * sn1 * sn1 + (ks2 + f2) * sn2 * sn2)
                      - (e1 * e1 + e2 * e2) / kp + kp * da * q_value
                      + (e1 * ow1 + e2 * ow2))
        return LeanOutput(tau, (tau1, tau2), (sn1, sn2), (qr1, qr2), distance, v_value,
                          q_value if with_potential else None, v_rate, theta, k, limited,
                          False, damping=lam2)

    def _lean_fault(self, theta, k: float, reason: str) -> LeanOutput:
        zero = (0.0, 0.0)
        return LeanOutput(zero, zero, zero, zero, None, None, None, None, theta, k, False,
                          True, reason)

    def _fault(self, theta_hat, k: float, reason: str) -> ControlOutput:
        zero = np.zeros(2)
        return ControlOutput(
            tau=zero, tau_requested=zero.copy(), s=zero.copy(), distance=None,
            lyapunov=None, task_potential=None, lyapunov_rate=None,
            theta_hat=theta_hat, reference=None, task_gain=k, torque_limited=False,
            fault=True, fault_reason=reason)
