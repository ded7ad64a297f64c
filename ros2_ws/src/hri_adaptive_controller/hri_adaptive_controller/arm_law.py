"""The adaptive law of eq. 12-19 for every arm: one law over hri_core's RobotModel.

The law works on the model's task axes (RobotModel.task_axes, k): x, y for a planar arm (the
SCARA: its 2 x 2 Jacobian is exact and square, so eq. 20-22 keep their exact form and theta
keeps the paper's 7 parameters), x, y, z otherwise (the Panda's 7 joints, any URDF arm).
Shapes: q, qdot (n,) rad, rad/s; x, x_d (k,) m; J (k, n) m/rad; theta (p,); tau (n,) N m.

    delta_eps = Q'(r) e,  r = |x - x_d|, e = (x - x_d) / r                           (eq. 12')
    v_task = f xdot_d - a delta_eps + a (v_rest + v_away)               (eq. 14, task space)
    qdot_r = (1 - sigma) J+ v_task + sigma a u - J+ J+^T g_B / Kp + N z             (eq. 14)
    qddot_r = d/dt of qdot_r, exact: dJ+/dt, dN/dt = -(dJ+/dt J + J+ Jdot), dsigma/dt, du/dt
    dv_task/dt = f xddot_d + df/dt xdot_d - da/dt delta_eps - a H_Q (xdot - xdot_d) + ...
                                                                                     (eq. 18)
    s = qdot - qdot_r                                                                (eq. 17)
    tau = -Ks s - (1 - sigma) J^T Kp a delta_eps - g_B + Y(q, qdot, qdot_r, qddot_r) theta_hat
                                                                                     (eq. 16)
    dtheta_hat/dt = -L Y^T s, projected onto the model's box                         (eq. 19)

Q'(r), Q''(r): task_variable.radial_drive, the SCARA's own radial task term (speed cap
max_task_speed, approach floor, Hessian bound), in 3-D: H_Q = Q'' e e^T + Q'/r (I - e e^T)
(the analytic Hessian of Q, so qddot_r is exact). The drive is task_variable.task_drive
with the model's attained reach. f = 1 for follow tasks, 1 - a for avoid tasks (open outward: the
hand's velocity is not fed forward); the feed-forward is capped at FEED_FORWARD_RATIO v_max
with task_variable.speed_cap. Y is the model's eq. 18 regressor with gravity and viscous
friction (Y theta = M qddot_r + C qdot_r + F qdot_r + g): theta_hat adapts the gravity too,
from whatever start.

Two deliberate differences from the paper's text, both needed for eq. 22 to follow from eq.
16-21: eq. 16 prints -Kp a delta_eps, where the closed loop eq. 20 (and the units: delta_eps
is a task-space velocity, tau a joint torque) needs -J^T Kp a delta_eps; and with a scalar
Kp (N s/m) the potential term of V is Kp a Q (eq. 21 prints a P, right only for Kp = 1).

Null space (redundant arms, n > k): z = cap(-k_n (q - q_home)) - v_B g_B / kb moves the
joints towards the model's home pose and away from the joint limits. J N = J - J J+ J = 0
wherever J+ is the exact inverse (manipulability above the damping threshold), so the tool's
velocity and eq. 20-22 do not see z: with V = 1/2 s^T M s + Kp a Q + B + 1/2 dtheta^T L^-1
dtheta (B the barrier's energy),

    dV/dt = -s^T (Ks + F) s - Kp |v_e|^2 + Kp (da/dt) Q + Kp v_e^T w
            + g_B^T N z_post - (v_B / kb) g_B^T N g_B + (feed-forward gate terms),
    v_e = (1 - sigma) a delta_eps + J+^T g_B / Kp (w: avoid tasks, below; sigma: reach-round),

the posture term g_B^T N z_post is non-zero only within a barrier band (g_B = 0 elsewhere),
and the last one is <= 0 (N symmetric, idempotent). Joint-limit barrier: joint_limits'
barrier for every joint: near a limit the torque
gets -g_B and the reference the task-space share of it, the feed-forward towards the limit
is gated, and eq. 19 pauses by 1 - near. Per-joint effort limits: tau is scaled as a whole so
that every |tau_i| <= effort_i (direction kept); eq. 19 pauses while it is, and while the
caller's effort rate limit holds the command off the law's torque (`adapt(applied=False)`).
A non-finite result gives zero torque and fault=True, theta_hat unchanged.

Joint speed limit (joint_limits' module docstring): last of all, qdot_r is scaled as a whole
within the joint velocity limits (gains.speed_scale of them) and each joint's motion towards
a limit is held at stop_rate times its distance less a share of the band (a velocity damper),
with their exact rate in qddot_r: no term of the reference asks a joint for more than it can
stop from before its limit.

Speed and separation monitoring (`limit_approach`, the separation cap's): where the row
n^T J_p of the arm's point nearest the person takes qdot_r towards the person faster than
the limit, qdot_r loses the excess along that row (the least joint motion that does it);
qddot_r leaves the change out, as it does the pull limit's.

Approach damper (the whole-body clearance's hard floor, `body_damper`): for every robot-human
pair within clearance + influence (not the exempted hand), the reference's speed of the
robot's closest point towards the person, n^T J_p qdot_r, is held at or below k (d - d_stop)
(k = body.stop_rate, d_stop = clearance - body.stop_depth; a retreat of at most max_speed
where d < d_stop) less the person's approach speed times the pair's barrier weight share,
softly (DAMPER_SOFTNESS), all pairs at once by the least joint motion (a small active-set
projection), after limit_approach and before the joint speed limit. The barrier's soft push
(5 N) alone gave way where the person stepped towards the arm faster than its 0.5 m/s push
retreats (the SCARA's handovers: the torso 0.58 m/s towards link2). It only lowers the
reference's approach speed, as limit_approach does: qddot_r leaves the change out, and V's
argument gains the terms of the reference's change, as with the joint speed limit.

Avoid tasks (open outward; task_variable's module docstring): the reference drops the hand's
velocity (f = 1 - a), reads it through a filter (filter_hand_velocity, HAND_RATE), and adds the
return to the rest position v_rest = w(r) c(x - x_rest) (task_variable.rest_term; x_rest the
caller's, by default where the tool is) and the retreat from an approaching hand v_away = g(r) p(e
. xdot_d) e (retreat_term), each with its exact rate. eq. 22 then gains Kp v_e^T w with v_e = (1
- sigma) a delta_eps + J+^T g_B / Kp and w = f xdot_f + a (v_rest + v_away) - xdot_d
(ArmOutput.reference_offset; `lyapunov_rate` is the prediction, the monitor's).

Reach-round (follow tasks): where a joint sits in its barrier band while the goal is far
(the straight descent stalls: the Panda leaning back to a hand behind its base stopped 14 cm
short) or the region lies beyond the reach (for a planar arm also: the straight path
crosses the hole round its base), joint_limits.ReachRound's blend brings in the joint
motion u towards an inverse-kinematics pose with sigma (a C2 ramp, slewed goal filter and
capped u), weighted by a as the task's pull; the task's force is weighted 1 - sigma and
so is the posture pull of the null space (the barrier's push is not). Beside a person the
pose keeps every robot-person pair IK_CLEARANCE_MARGIN beyond the clearance
(joint_limits.clearance_inverse_kinematics, the pairs from the compiled barrier), on every
arm: the person's barrier holding the arm short of a far goal engages the blend as a
joint's barrier does (its gate above REACH_ROUND_BODY_GATE), its joint motion slowed with
the gate (PERSON_ROUND_SPEED), and it stands down while the person's barrier holds the arm
and its pose could not be cleared (GOAL_SHORTFALL): held against the barrier short of a
pose in the person, sigma stayed at 1 for good. The damper and the barrier's torque stay
whole either way.
No ROS import.
"""

import dataclasses
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from hri_adaptive_controller.event_weight import quintic_smoothstep
from hri_adaptive_controller.joint_limits import (
    PUSH_SCALE,
    ReachRound,
    ReachRoundSettings,
    barrier,
    barrier_energy,
    gate_feed_forward,
    joint_speed_limit,
    redirected_push,
)
from hri_adaptive_controller.task_variable import (
    CAP_BAND,
    MAX_TASK_HESSIAN,
    DampingSettings,
    TaskDrive,
    TaskDrives,
    damped_pseudo_inverse,
    norm_cap,
    radial_drive,
    rest_term,
    retreat_term,
    speed_cap,
    task_potential,
)
from hri_core.bodies import Capsules, RobotBody, capsule_distances
from hri_core.potential import TaskShape
from hri_core.robot_model import RobotModel

REACH_ROUND_BODY_GATE = 0.1
"""The person's barrier gate (BodyBarrier.gate) above which the reach-round engages (as a
joint's barrier engages it), or stands down while its pose could not be cleared (module
docstring)."""
IK_CLEARANCE_MARGIN = 0.03
"""m: the reach-round's pose keeps every robot-person pair this far beyond the
clearance (joint_limits.clearance_inverse_kinematics), inside the barrier's band but off its
damper's stop."""
GOAL_SHORTFALL = 0.06
"""m: the reach-round stands down while the person's barrier holds the arm and its last pose
lies this far inside IK_CLEARANCE_MARGIN beyond the clearance (within the clearance less 3
cm: a pose the solve could not clear)."""
PERSON_ROUND_SPEED = 0.25
"""The share of the reach-round's slew and joint speed (ReachRoundSettings) left with the
person's barrier gate at 1 (1 - (1 - this) gate): at 1 rad/s a joint the Panda's gripper,
swinging to a new pose, reached 0.013 m from a torso in HumanRobotHandover_0 before the
damper and the barrier stopped it."""
REDIRECT_MOST = 10.0
"""The most the person's push in the reference is scaled up by when joints within their bands
leave it to the others (joint_limits.redirected_push); the push's cap (ClearanceSettings.
max_speed) and the joints' speed limits bound it before this (30 gave the same runs)."""
FEED_FORWARD_RATIO = 2.0
"""The hand's velocity enters qdot_r (eq. 14) capped at this times max_task_speed."""
TRACKED_HAND_MARGIN = 0.05
"""m: /target is the hand of the person's side whose tracked capsules (hand, forearm) it lies
nearest, within this of their surface (ArmController.tracked_side): a tracker's hand point
(the palm, a marker on the glove) some centimetres off its wrist, 10-20 ms between a /target
and a /human/body of a hand moving at up to 3 m/s."""
HAND_RATE = 40.0
"""1/s: the hand-velocity filter of an avoid task's retreat (lag 2 / HAND_RATE = 50 ms)."""
# The hand-velocity filter's omega^2 (1/s^2) and 2 omega (1/s).
_HAND_STIFFNESS, _HAND_DAMPING = HAND_RATE * HAND_RATE, 2.0 * HAND_RATE




@dataclass(frozen=True)
class ClearanceSettings:
    """How the law keeps every robot capsule off every human capsule (module docstring).

    clearance (m, >= 0): the distance the barrier holds; influence (m, > 0): it starts this
    far beyond for a still person, and further by reaction_time (s, >= 0) times the speed
    (m/s) at which the person's closest point comes towards the robot, up to max_influence
    (m, >= influence); force (N, >= 0): its push at the clearance (0: off); fade_in (s,
    >= 0): a body that comes after none (at the start, or back after a loss) is met with the
    force faded in over this time (eq. 13's quintic ramp; 0: at once); max_speed (m/s, > 0):
    the barrier's task-space velocity J+^T g / Kp in the reference is capped at this plus the
    person's fastest speed (smoothly; the torque keeps g whole); posture_influence (m,
    >= 0): a redundant arm's posture (its null space, which leaves the tool where the task
    puts it) is pushed off the person from this far beyond the clearance (0: not), with
    posture_force (N, >= 0) at the clearance (the same band's shape as the barrier's); tracked:
    the human capsules of the tracked hand (/target), which the arm may reach in a task whose
    region reaches into the hand's clearance (a follow task whose d1, measured between the
    tool's and the hand's points, is below the clearance plus the hand's and the tool's
    capsule radii); tracked_arm: the rest of that arm, kept at its capsules' surface (not the
    clearance) in such a task. Both are named for the right side; the law takes the side
    whose hand holds /target (ArmController.tracked_side: the left's names mirrored, l_ for
    r_), and neither where no hand of the person does. stop_rate k (1/s, >= 0; 0: off) and
    stop_depth (m, >= 0): the approach damper (body_damper): within clearance + influence of
    a pair the reference's speed of the robot's point towards the person is held at or below
    k (d - (clearance - stop_depth)) (where that is negative, a retreat of at most max_speed,
    faded in as the force) less the person's approach speed times the pair's barrier weight
    share."""

    clearance: float = 0.10
    # 0.10 m for a still person: 0.03 let the tool nearer the hand (follow's median on the
    # recorded people 0.13-0.28 m against 0.18-0.43 m) but put HumanRobotHandover_0's arm
    # within clearance - 3 cm of the torso in 9.3 % of the samples (0 % with 0.10 m).
    # A person coming at 0.3 m/s widens it to the most, 0.19 m.
    influence: float = 0.10
    reaction_time: float = 0.3
    max_influence: float = 0.19
    # 5 N at the clearance: above the task's largest pull, Kp (1 + CAP_BAND) v_max = 3 N, so
    # the two balance before the clearance; its reference, 5 N / Kp = 0.5 m/s away, matches
    # the hand's largest feed-forward. 10 N drove the SCARA into its effort limits.
    force: float = 5.0
    # 0.3 s: a person over the SCARA's links at the start (the demo's, in its plane) drove the
    # arm to its 20 N m limit within 20 ms; faded in over 0.3 s, 2.4 N m in the first 50 ms.
    # Longer fades and lower caps leave an arm that starts inside a person there longer
    # (docs/design.md).
    fade_in: float = 0.3
    # 0.5 m/s, the push of one pair at the clearance (force / Kp): a person over the SCARA's
    # link1 with the arm stretched asked 1.5-1.8 m/s of the tool through J+, 13-15 rad/s of
    # a joint, at the 20 N m limit for 0.3 s (0.75 m/s: still 33 ms at the limit).
    max_speed: float = 0.5
    posture_influence: float = 0.10
    # 5 N over 0.10 m. 20 N over 0.40 m swung the Panda's elbow off the person's arm and
    # brought follow to the hand on the two handovers (median 0.031, 0.067 m against 0.18
    # m), but the gripper then pressed the recorded hand in MuJoCo at up to 497 N (Table
    # A.2's hands: 280 N) (docs/design.md).
    posture_force: float = 5.0
    tracked: tuple[str, ...] = ('r_forearm', 'r_hand')
    tracked_arm: tuple[str, ...] = ('r_upper_arm',)
    stop_rate: float = 5.0
    stop_depth: float = 0.01

    def __post_init__(self):
        if not (math.isfinite(self.clearance) and self.clearance >= 0.0):
            raise ValueError(f'clearance must be finite and >= 0 m, got {self.clearance}')
        if not (math.isfinite(self.influence) and self.influence > 0.0):
            raise ValueError(f'influence must be finite and > 0 m, got {self.influence}')
        if not (math.isfinite(self.max_influence) and self.max_influence >= self.influence):
            raise ValueError(f'max_influence must be finite and >= influence '
                             f'({self.influence} m), got {self.max_influence}')
        if not (math.isfinite(self.reaction_time) and self.reaction_time >= 0.0):
            raise ValueError(f'reaction_time must be finite and >= 0 s, got '
                             f'{self.reaction_time}')
        if not (math.isfinite(self.posture_influence) and self.posture_influence >= 0.0):
            raise ValueError(f'posture_influence must be finite and >= 0 m, got '
                             f'{self.posture_influence}')
        if not (math.isfinite(self.posture_force) and self.posture_force >= 0.0):
            raise ValueError(f'posture_force must be finite and >= 0 N, got '
                             f'{self.posture_force}')
        if not (math.isfinite(self.force) and self.force >= 0.0):
            raise ValueError(f'clearance force must be finite and >= 0 N, got {self.force}')
        if not (math.isfinite(self.max_speed) and self.max_speed > 0.0):
            raise ValueError(f'clearance max_speed must be finite and > 0 m/s, got '
                             f'{self.max_speed}')
        if not (math.isfinite(self.fade_in) and self.fade_in >= 0.0):
            raise ValueError(f'clearance fade_in must be finite and >= 0 s, got {self.fade_in}')
        for name in ('stop_rate', 'stop_depth'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'clearance {name} must be finite and >= 0, got {value}')


class BodyBarrier(NamedTuple):
    """The whole-body barrier at one state: g (n,) N m = dU/dq, its rate (n,) N m/s, U (J),
    and the nearest robot-human pair: its distance (m; inf without a body), the robot and
    human capsules' names; posture (n,) N m and its rate: the push on a redundant arm's
    posture (None: none), which the law takes through its null space only; gate in [0, 1)
    and its rate (1/s): 1 - prod(1 - w_k) over the pairs' barrier weights w_k / force, how
    far some pair is into its band (the hand's velocity is fed forward times 1 - gate);
    rows (m, n) m/rad, gaps (m,) m, approach (m,) m/s: the approach damper's pairs (within
    clearance + influence; body_damper), their rows n^T J_p, distances and the person's
    approach speeds times the pairs' weight shares (None: no pair)."""

    gradient: np.ndarray | None
    rate: np.ndarray | None
    energy: float
    distance: float
    pair: tuple[str, str]
    posture: np.ndarray | None = None
    posture_rate: np.ndarray | None = None
    gate: float = 0.0
    gate_rate: float = 0.0
    rows: np.ndarray | None = None
    gaps: np.ndarray | None = None
    approach: np.ndarray | None = None


NO_BODY = BodyBarrier(None, None, 0.0, math.inf, ('', ''))


@dataclass(frozen=True)
class ArmGains:
    """Gains of the n-joint law (module docstring).

    ks: diagonal of Ks (n values, N m s/rad, > 0); kp: Kp (N s/m, > 0); adaptation: L's rate for
    each kind of parameter the model names (RobotModel.adaptation_kinds: the SCARA's 7 parameters;
    a URDF arm's m, mcx, ..., Izz, damping, the same for every joint; >= 0; units of theta^2 per N
    m s); task_gain: K (m^2/s) for every task, or None for each task's own K (0 =
    default_task_gain); approach_speed, region_margin, max_task_speed, rest_gain, rest_gate: the
    approach floor, the speed cap and an avoid task's return to rest (task_variable.task_drive);
    effort_scale (0, 1]: the fraction of the model's per-joint effort limits the law may use;
    max_effort_rate (N m/s): the callers' rate limit (effort_rate); effort_limit (N m) or None: a
    cap on every joint's effort limit besides the model's; initial_estimate (> 0): the share of the
    model's nominal theta a controller node starts its estimate from when given none; damping: J+
    damping (threshold w0: m^2 for a 2-row J, m^3 for 3); posture_gain k_n (1/s, >= 0) and
    posture_speed (rad/s, > 0): the null-space pull towards home, each joint's speed capped
    smoothly; limit_band (rad, > 0), barrier_torque kb (N m, >= 0): the barrier; limit_speed v_B
    (rad/s, >= 0): the null-space push off a limit; speed_scale (0, 1]: the share of the
    model's joint velocity limits the reference may ask for, stop_rate k (1/s, > 0): how
    fast the reference may close on a joint limit (joint_limits' Joint speed limit); body:
    the whole-body clearance (ClearanceSettings). Raises ValueError with the reason for a
    value out of range.
    """

    ks: tuple[float, ...]
    kp: float
    adaptation: tuple[float, ...]
    task_gain: float | None = None
    approach_speed: float = 0.1
    region_margin: float = 0.02
    max_task_speed: float = 0.25
    effort_scale: float = 1.0
    rest_gain: float = 2.0
    rest_gate: float = 0.03
    max_effort_rate: float = 1000.0
    damping: DampingSettings = field(default_factory=lambda: DampingSettings(0.02, 0.05))
    posture_gain: float = 1.0
    posture_speed: float = 0.3
    limit_band: float = 0.15
    barrier_torque: float = 3.0
    limit_speed: float = 0.3
    speed_scale: float = 1.0
    stop_rate: float = 5.0
    reach_round: ReachRoundSettings = field(default_factory=ReachRoundSettings)
    effort_limit: float | None = None
    initial_estimate: float = 1.0
    body: ClearanceSettings = field(default_factory=ClearanceSettings)

    def __post_init__(self):
        ks = np.asarray(self.ks, dtype=float)
        if ks.ndim != 1 or ks.size == 0 or not np.all(np.isfinite(ks)) or np.any(ks <= 0.0):
            raise ValueError(f'ks must be finite values > 0 N m s/rad, got {self.ks}')
        rates = np.asarray(self.adaptation, dtype=float)
        if rates.ndim != 1 or not np.all(np.isfinite(rates)) or np.any(rates < 0.0):
            raise ValueError(f'adaptation must be finite values >= 0, got {self.adaptation}')
        if self.effort_limit is not None and not (
                math.isfinite(self.effort_limit) and self.effort_limit > 0.0):
            raise ValueError(f'effort_limit must be None or finite and > 0 N m, '
                             f'got {self.effort_limit}')
        if self.task_gain is not None and not (
                math.isfinite(self.task_gain) and self.task_gain > 0.0):
            raise ValueError(f'task_gain must be None or finite and > 0, got {self.task_gain}')
        for name in ('kp', 'max_task_speed', 'rest_gate', 'max_effort_rate', 'posture_speed',
                     'limit_band', 'effort_scale', 'initial_estimate', 'speed_scale',
                     'stop_rate'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        for name in ('effort_scale', 'speed_scale'):
            if getattr(self, name) > 1.0:
                raise ValueError(f'{name} must be <= 1, got {getattr(self, name)}')
        for name in ('approach_speed', 'region_margin', 'rest_gain', 'posture_gain',
                     'barrier_torque', 'limit_speed'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')


# The SCARA's gains (robot_model('scara'): l1 = 0.35 m, l2 = 0.30 m, 4 kg + 3 kg, M(q) about
# [[0.66, 0.13], [0.13, 0.13]] kg m^2 at q2 = 90 deg), tuned in the pure closed loop
# (closed_loop.simulate) on Table I's three tasks. The paper's Ks = 0.01 I, Kp = 5 I were for
# its own robot (and its own scaling of P) and do not transfer.
SCARA_GAINS = ArmGains(
    # Ks: ks1 / M11 ~ ks2 / M22 ~ 30 1/s: s decays in ~35 ms, fast against the task motion
    # (hundreds of ms), slow against the 1 kHz loop.
    ks=(20.0, 4.0),
    # Kp (N s/m): weight of the task term J^T Kp a delta_eps: Kp v_max = 2.5 N at full speed
    # (<= 1.6 N m). The arm runs faster than the reference by about Kp |J|^2 / ks; with this
    # Kp at most 1.25 v_max (a still target).
    kp=10.0,
    # L, scaled to each column of Y (accelerations ~ 1-10 rad/s^2 for the inertias,
    # velocities ~ 1 rad/s for the friction): following a hand that circles (0.1 m, 3 s)
    # from a 30-100 % wrong theta_hat(0), the inertias and frictions come within 16 % in 20
    # s, with no torque peak above the start-up one; 10x smaller rates leave them 40-100 % off
    # after 20 s. The gravity moments (zero columns for the horizontal arm) keep a small rate.
    adaptation=(5.0, 2.0, 1.0, 20.0, 10.0, 0.1, 0.1),
    # J+ damping from 28 deg of the stretched arm on, up to lambda = 0.15 m: joint speeds stay
    # below 3 rad/s and torques below 10 N m when the target is out of reach.
    damping=DampingSettings(threshold=0.05, max_damping=0.15),
    # The barrier acts 0.1 rad from a limit with 3 N m there: above the largest task torque
    # J^T Kp (1 + CAP_BAND) v_max (1.95 N m on joint 1, 0.9 N m on joint 2).
    limit_band=0.1,
    barrier_torque=3.0,
    # The node's estimate starts at 0.6 of the nominal theta: scara_sim runs the nominal arm,
    # and a start at the truth would show nothing of eq. 19.
    initial_estimate=0.6,
)

# The Panda's gains (robot_model('panda'): M's diagonal at home 0.53, 1.55, 0.98, 0.96, 0.04,
# 0.05, 0.007 kg m^2; gravity up to 22 N m on joint 4). Ks / M ~ 30-60 1/s on the big joints
# (s decays in 20-35 ms) and below 2 / dt on the wrist (1 kHz Euler-stable); kp as the SCARA's.
# L: masses and first moments carry the gravity (Y's columns ~ 10 N m per kg or kg m at
# s ~ 0.1 rad/s), so they adapt fastest; the rotational inertias and friction slowly.
PANDA_GAINS = ArmGains(
    ks=(30.0, 40.0, 30.0, 30.0, 3.0, 3.0, 0.6),
    kp=10.0,
    adaptation=(2.0, 2.0, 2.0, 2.0, 0.05, 0.05, 0.05, 0.05, 0.05, 0.05, 0.5),
)

ROBOT_GAINS = {'scara': SCARA_GAINS, 'panda': PANDA_GAINS}
"""Gains tuned for a named robot (RobotModel.name); any other arm: default_gains."""


def warm_up_law() -> None:
    """Compile the law's per-cycle kernels and the capsule distances (or load them from
    numba's cache): an ArmController of each robot of ROBOT_GAINS, and the SCARA's capsules
    against a standing person. scripts/build.sh runs it beside
    arm_kernels.warm_up_body_barrier, so that no controller or test compiles them at its
    start; the tests' node forker runs both before it forks."""
    from hri_core.bodies import human_capsules, robot_body
    from hri_core.human_body import BODY_POINTS, standing_body
    from hri_core.robot_model import robot_model

    for robot, gains in ROBOT_GAINS.items():
        ArmController(robot_model(robot), gains)
    scara = robot_model('scara')
    capsule_distances(robot_body(scara).capsules(scara.home), human_capsules(
        BODY_POINTS, standing_body([0.8, 0.0], 3.1, 0.0, [0.4, 0.0, 0.0])))


def sampled_configurations(model: RobotModel, samples: int) -> np.ndarray:
    """`samples` joint configurations (samples, n) rad drawn uniformly within the model's
    joint limits (+-pi where a limit is unbounded) from a generator seeded with 0: the same
    configurations for every call with the same model."""
    lower = np.where(np.isfinite(model.limits.lower), model.limits.lower, -math.pi)
    upper = np.where(np.isfinite(model.limits.upper), model.limits.upper, math.pi)
    return np.random.default_rng(0).uniform(lower, upper, (samples, model.dof))


# A URDF arm's Ks: each joint's share of the Panda's (40 N m s/rad per 87 N m of effort limit),
# at most KS_RATE times the least inertia that joint moves. Ks / M is how fast s decays (1/s);
# the Panda's gains have 26-86 1/s. The effort share alone gave the UR3's and UR10's wrists
# (0.5-8 g m^2 against 54 N m) Ks dt / M = 3-47 at 1 kHz: s overshot each cycle and the arm
# spun through its limits.
KS_RATE = 60.0  # 1/s
KS_PER_EFFORT = 40.0 / 87.0  # s/rad
# A URDF arm's adaptation rates L: a tenth of the Panda's. With the Panda's own, the UR3 and
# the UR10 (example-robot-data) ran away from a still hand 0.3 m off in the pure loop (0.90
# and 1.72 m away after 4 s, theta_hat wound up); with a tenth each enters follow's region in
# 1.46 and 1.41 s, and the UR5 and the Z1 do as before (1.59-1.61 s). Any L > 0 keeps V
# non-increasing; a smaller one only adapts more slowly.
ADAPTATION_SCALE = 0.1
INERTIA_SAMPLES = 200  # seeded configurations over which each joint's least inertia is taken


def default_arm_ks(model: RobotModel, samples: int = INERTIA_SAMPLES) -> tuple[float, ...]:
    """Ks (n,) N m s/rad for an arm without gains of its own: min(KS_PER_EFFORT effort_i,
    KS_RATE min_q M_ii(q)) over the home pose and `samples` seeded configurations within the
    joint limits (the inertia a joint moves changes with the outer joints)."""
    least = np.diag(model.mass_matrix(model.home)).copy()
    for q in sampled_configurations(model, samples):
        least = np.minimum(least, np.diag(model.mass_matrix(q)))
    return tuple(float(v) for v in np.minimum(KS_PER_EFFORT * model.limits.effort,
                                              KS_RATE * least))


def default_gains(model: RobotModel) -> ArmGains:
    """The gains for `model`: its own (ROBOT_GAINS) where tuned for it, else PANDA_GAINS'
    with Ks from its effort limits and link inertias (default_arm_ks) and ADAPTATION_SCALE
    times its adaptation rates."""
    gains = ROBOT_GAINS.get(model.name)
    if gains is not None and len(gains.ks) == model.dof and len(gains.adaptation) == len(
            model.adaptation_kinds):
        return gains
    return dataclasses.replace(PANDA_GAINS, ks=default_arm_ks(model), adaptation=tuple(
        ADAPTATION_SCALE * rate for rate in PANDA_GAINS.adaptation))


class HandState(NamedTuple):
    """The hand (target) on the model's task axes: x_d (k,) m, xdot_d (k,) m/s, xddot_d (k,)
    m/s^2."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class ActiveTask(NamedTuple):
    """The task in force: its learned shape, its gain k (m^2/s, 0 = default), its event weight
    a in [0, 1] and da/dt (1/s)."""

    shape: TaskShape
    weight: float
    weight_rate: float = 0.0
    k: float = 0.0


class ArmOutput(NamedTuple):
    """One step of `ArmController.step`.

    tau (n,) N m, the command (zeros on a fault); tau_requested (n,) before the effort limit;
    s (n,) rad/s; qdot_r, qddot_r (n,); position x (k,) m; distance |x - x_d| (m, None on a
    fault); task_gain K (m^2/s); theta_hat (p,) used for this step; torque_limited, fault;
    fault_reason; damping lambda^2; near: the barrier's proximity in [0, 1]; barrier_gradient
    g_B (n,) N m; weighted_task_variable a delta_eps (k,) m/s; lyapunov: V (J) or part of it,
    where a caller fills it in (None from step); blend: the reach-round weight sigma in
    [0, 1]; barrier_task_velocity J+^T g_B / Kp (k,) m/s (None off the bands), which with
    (1 - sigma) a delta_eps makes eq. 22's v_e; reference_offset w (k,) m/s: what the
    reference adds to the hand's velocity besides the task term (eq. 22's avoid term); body:
    the whole-body barrier (BodyBarrier; NO_BODY without a person).
    """

    tau: np.ndarray
    tau_requested: np.ndarray
    s: np.ndarray
    qdot_r: np.ndarray
    qddot_r: np.ndarray
    position: np.ndarray | None
    distance: float | None
    task_gain: float
    theta_hat: np.ndarray
    torque_limited: bool
    fault: bool
    fault_reason: str = ''
    damping: float = 0.0
    near: float = 0.0
    barrier_gradient: np.ndarray | None = None
    weighted_task_variable: np.ndarray | None = None
    lyapunov: float | None = None
    blend: float = 0.0
    barrier_task_velocity: np.ndarray | None = None
    reference_offset: np.ndarray | None = None
    body: BodyBarrier = NO_BODY


def task_term(dx: np.ndarray, drive: TaskDrive) -> tuple[np.ndarray, np.ndarray]:
    """delta_eps = Q'(r) e (k,) m/s and its Hessian H_Q (k, k) 1/s at dx = x - x_d (k,) m,
    from task_variable.radial_drive (eq. 12'); entries bounded by MAX_TASK_HESSIAN."""
    r = math.sqrt(float(dx @ dx))
    slope, curvature = radial_drive(r, drive)
    if r == 0.0:
        return np.zeros(dx.size), curvature * np.eye(dx.size)
    e = dx / r
    tangential = slope / r
    hessian = (curvature - tangential) * np.outer(e, e)
    hessian[np.diag_indices(dx.size)] += tangential
    if curvature > MAX_TASK_HESSIAN or tangential > MAX_TASK_HESSIAN or (
            curvature < -MAX_TASK_HESSIAN or tangential < -MAX_TASK_HESSIAN):
        hessian = np.clip(hessian, -MAX_TASK_HESSIAN, MAX_TASK_HESSIAN)
    return slope * e, hessian


def task_term_along(dx: np.ndarray, u: np.ndarray,
                    drive: TaskDrive) -> tuple[np.ndarray, np.ndarray]:
    """task_term's delta_eps (k,) m/s and H_Q u (k,) m/s^2 for u (k,) m/s: the control
    step's path, in plain floats where no entry of H_Q needs its bound (|Q''|, |Q'/r| <=
    MAX_TASK_HESSIAN: then every entry is, H_Q being a blend of the two), else through
    task_term's bounded matrix."""
    r = math.sqrt(float(dx @ dx))
    slope, curvature = radial_drive(r, drive)
    if r == 0.0:
        return np.zeros(dx.size), curvature * u
    tangential = slope / r
    if not (-MAX_TASK_HESSIAN <= curvature <= MAX_TASK_HESSIAN
            and -MAX_TASK_HESSIAN <= tangential <= MAX_TASK_HESSIAN):
        gradient, hessian = task_term(dx, drive)
        return gradient, hessian @ u
    # H_Q u = (Q'' - Q'/r) (e . u) e + Q'/r u, e = dx / r: two array expressions.
    along = (curvature - tangential) * float(dx @ u) / (r * r)
    return (slope / r) * dx, along * dx + tangential * u


def predicted_lyapunov_rate(s, weighted_task_variable, weight_rate: float,
                            task_potential_value: float, ks, kp: float, friction,
                            reference_offset) -> float:
    """dV/dt (W) of eq. 22 with the avoid task's term (module docstring):

        -s^T (Ks + F) s - Kp |v_e|^2 + Kp (da/dt) Q + Kp v_e^T w.

    s (n,) rad/s; weighted_task_variable v_e (k,) m/s; weight_rate da/dt (1/s);
    task_potential_value Q (m^2/s); ks (n,) N m s/rad; kp N s/m; friction diag F (n,);
    reference_offset w (k,) m/s: what the reference adds to the hand's velocity besides the
    task term (0 for follow tasks and without a task)."""
    s = np.asarray(s, dtype=float)
    damping = np.asarray(ks, dtype=float) + np.asarray(friction, dtype=float)
    task = np.asarray(weighted_task_variable, dtype=float)
    offset = np.asarray(reference_offset, dtype=float)
    return float(-np.sum(damping * s * s) - kp * (task @ task)
                 + kp * weight_rate * task_potential_value + kp * (task @ offset))


def filter_hand_velocity(state: tuple, xdot_d, dt: float) -> tuple:
    """The hand's velocity through a critically damped second-order filter (HAND_RATE),
    advanced by dt (s): state and result (v_1 .. v_k, dv_1/dt .. dv_k/dt) m/s, m/s^2
    (floats), xdot_d (k,) m/s. The estimate steps at each /target; an avoid task's retreat
    acts on this one, whose rate is continuous, so the torque does not step with the
    messages. A non-finite result restarts the filter at zero."""
    m = len(state) // 2
    out = list(state)
    for i in range(m):  # a plain loop: 1.3 us, against 5.8 us for tuples built from zips
        v, a = state[i], state[m + i]
        a = a + dt * (_HAND_STIFFNESS * (xdot_d[i] - v) - _HAND_DAMPING * a)
        out[i], out[m + i] = v + dt * a, a
    if not all(map(math.isfinite, out)):
        return (0.0,) * (2 * m)
    return tuple(out)


REACH_SAMPLES = 2000
"""Joint configurations sampled (seeded, uniform within the limits) for `attained_reach`."""


def attained_reach(model: RobotModel, samples: int = REACH_SAMPLES) -> float:
    """The farthest the tool point gets from the model's shoulder (m): the model's own
    attained_reach where it knows it, else the farthest over `samples` seeded random
    configurations within the joint limits: the reach the task drive works with.
    model.reach is an upper bound (the chain's lengths added), for the Panda 1.09 m against
    0.95 m attained; with it, Table I's avoid row (d2 = 2.0 m) would not count as open
    outward (d2 >= 2 reach, task_variable.open_outward) and the arm would copy the hand."""
    if model.attained_reach is not None:
        return float(model.attained_reach)
    farthest = 0.0
    for q in sampled_configurations(model, samples):
        farthest = max(farthest, float(np.linalg.norm(model.tool_position(q) - model.shoulder)))
    return farthest


BODY_RATE_STEP = 1e-6
"""s: the body barrier's rate is the forward difference of its gradient along q + h qdot (a
directional derivative at a still body: the closest points and normals move with q). It
is within 1.2e-5 of the rate's size of a central difference (20 random Panda states, joint
speeds up to 1 rad/s), which cost a third evaluation of every close pair."""


def _smoothstep_energy(distance: float, reach: float, width: float,
                       force: float) -> tuple[float, float]:
    """One pair's barrier weight (N: dU/dd = -weight) and energy (J) for a band of `width`
    m ending at `reach` m: u = (reach - d) / width, v = min(u, 1), weight = force w(v) (w the
    quintic smoothstep), energy = force width (2.5 v^4 - 3 v^5 + v^6 + max(u - 1, 0))."""
    u = (reach - distance) / width
    if u <= 0.0:
        return 0.0, 0.0
    v = min(u, 1.0)
    return (force * v * v * v * (10.0 - 15.0 * v + 6.0 * v * v),
            force * width * (v ** 4 * (2.5 - 3.0 * v + v * v) + max(u - 1.0, 0.0)))


def _body_gradient(body: RobotBody, q, human: Capsules, settings: ClearanceSettings,
                   exempt, posture: bool):
    """(g = dU/dq (n,) N m or None where no pair is within its band, U (J), the posture
    push (n,) N m or None, the nearest pair's distance (m) and indices) for the robot
    `body` at q (n,) rad and the person's capsules `human`; exempt: (human capsules every
    robot capsule leaves out, human capsules it keeps at their surface instead of the
    clearance) (index lists), or None; posture: the arm is redundant (the push is wanted).

    Per pair, U = the barrier energy of _smoothstep_energy over the band from clearance + i
    to clearance, i = min(influence + reaction_time c, max_influence), c the speed (m/s) at
    which the person's closest point comes towards the robot (0 for a still person, so U is
    then a function of q alone); dU/dd = -weight, dd/dq = -n^T J_p, n the unit normal from
    the robot's closest point towards the person's, J_p that point's Jacobian
    (RobotBody.normal_rows gives n^T J_p of every close pair at once), so g = sum weight
    J_p^T n. The posture push is the same sum over the wider band posture_influence, with
    no energy: the law puts it through its null space only. Last, the approach damper's pairs
    (within clearance + influence, in (robot, human) order; None: none): (their rows n^T J_p
    (m, n), distances (m,) m, the person's approach speeds max(c, 0) times weight / force
    (m,) m/s)."""
    distances = capsule_distances(body.capsules(q, checked=False), human, planar=body.planar)
    table = distances.distance
    if exempt is not None:
        table = table.copy()
        table[:, exempt[0]] = math.inf
    nearest = divmod(int(np.argmin(table)), table.shape[1])
    least = float(table[nearest])
    if exempt is not None and exempt[1]:
        table[:, exempt[1]] += settings.clearance  # held at their surface
    clearance = settings.clearance
    reach = clearance + (max(settings.max_influence, settings.posture_influence) if posture
                         else settings.max_influence)
    robot_index, human_index = np.nonzero(table < reach)
    if robot_index.size == 0:
        return None, 0.0, None, least, nearest, 0.0, None
    points, normals = distances.robot_points_and_normals(robot_index, human_index)
    closing = distances.closing_speeds(robot_index, human_index, normals).tolist()
    # The few close pairs' weights and energy in floats (numpy's per-call cost dominates).
    weights, pushes, energy, force, free = [], [], 0.0, settings.force, 1.0
    gaps, approach, damped = [], [], []
    for k, distance in enumerate(table[robot_index, human_index].tolist()):
        width = min(settings.influence + settings.reaction_time * max(closing[k], 0.0),
                    settings.max_influence)
        weight, pair_energy = _smoothstep_energy(distance, clearance + width, width, force)
        weights.append(weight)
        energy += pair_energy
        free *= 1.0 - weight / force
        if posture and settings.posture_influence > 0.0:
            pushes.append(_smoothstep_energy(distance, clearance + settings.posture_influence,
                                             settings.posture_influence,
                                             settings.posture_force)[0])
        if distance < clearance + settings.influence:
            damped.append(k)
            gaps.append(distance)
            approach.append(weight / force * max(closing[k], 0.0) if force > 0.0 else 0.0)
    rows = body.normal_rows(q, robot_index, points, normals)
    gradient = np.array(weights) @ rows if energy > 0.0 else None
    push = np.array(pushes) @ rows if pushes and max(pushes) > 0.0 else None
    damper = (rows[damped], np.array(gaps), np.array(approach)) if damped else None
    return gradient, energy, push, least, nearest, 1.0 - free, damper


def body_barrier(body: RobotBody, q, dq, human: Capsules, settings: ClearanceSettings,
                 exempt=None, posture: bool = False) -> BodyBarrier:
    """The whole-body barrier (BodyBarrier) at q, dq (n,) with the person `human` held where
    it is: g, U and the posture push of _body_gradient, their rates along the motion
    (BODY_RATE_STEP), the nearest pair. posture: compute the posture push (a redundant
    arm)."""
    if len(human) == 0:
        return NO_BODY
    gradient, energy, push, distance, (i, j), gate, damper = _body_gradient(
        body, q, human, settings, exempt, posture)
    pair = (body.names[i], human.names[j])
    rows, gaps, approach = (None, None, None) if damper is None else damper
    if gradient is None and push is None:
        return BodyBarrier(None, None, 0.0, distance, pair, rows=rows, gaps=gaps,
                           approach=approach)
    h = BODY_RATE_STEP
    ahead, _, push_ahead, _, _, gate_ahead, _ = _body_gradient(body, q + h * dq, human,
                                                               settings, exempt, posture)
    zero = np.zeros(q.size)
    rate = None if gradient is None else ((zero if ahead is None else ahead) - gradient) / h
    push_rate = None if push is None else (
        (zero if push_ahead is None else push_ahead) - push) / h
    return BodyBarrier(gradient, rate, energy, distance, pair, push, push_rate, gate,
                       (gate_ahead - gate) / h, rows, gaps, approach)


DAMPER_SOFTNESS = 0.02
"""m/s: the approach damper's soft band: a pair's bound b is exceeded by less than this
(b + DAMPER_SOFTNESS tanh((v - b) / DAMPER_SOFTNESS) above b, C2 at b), so a pair held
rests DAMPER_SOFTNESS / stop_rate inside its stop (4 mm at 5 1/s)."""
DAMPER_RIDGE = 1e-6
"""m^2/rad^2: added to the diagonal of the approach damper's Gram matrix R R^T (entries
0.01-1): more pairs than joints (the SCARA's two) or two of one link's pairs with one normal
leave it singular; with 1e-10 the compiled and numpy multipliers parted by 1e-6 of the
torque. The targets are then met to the ridge times the multipliers (below 1e-4 m/s)."""


def body_damper(qdot_r, rows, gaps, approach, rate: float, stop: float, floor: float,
                softness: float = DAMPER_SOFTNESS, ridge: float = DAMPER_RIDGE):
    """qdot_r (n,) with each close pair's approach held (the velocity damper of the whole-body
    clearance, like joint_limits' stop damper and limit_approach): pair k's row r_k = n^T J_p
    (rows (m, n) m/rad) may take the reference towards the person at most at
    b_k = max(rate (gaps_k - stop), floor) - approach_k m/s (gaps (m,) m, approach (m,) m/s,
    rate 1/s, stop m, floor m/s <= 0), softly: at t_k = b_k + softness tanh((v_k - b_k) /
    softness) where v_k = r_k qdot_r is above b_k (so qdot_r does not step where a pair
    starts to hold it), t_k = b_k elsewhere. qdot_r then moves by the least joint motion
    that brings every r_k x within t_k: x = qdot_r - R^T lambda, lambda >= 0 the
    multipliers of min |x - qdot_r|^2 subject to R x <= t (Lawson and Hanson's active set on
    the dual, min 1/2 lambda^T (R R^T + ridge I) lambda - lambda^T (R qdot_r - t), exact in
    a few steps for the few pairs a cycle has; the projection is continuous in qdot_r, the
    rows and the bounds, so the torque does not step). Returns (qdot_r, whether it changed);
    the numpy reference of arm_kernels.body_damper."""
    speeds = rows @ qdot_r
    norms = np.einsum('ij,ij->i', rows, rows)
    bounds = np.maximum(rate * (gaps - stop), floor) - approach
    excess = speeds - bounds
    over = (excess > 0.0) & (norms > 1e-18)
    if not over.any():
        return qdot_r, False
    # c = R qdot_r - t: the excess over each target (-1 for a row of norm 0: no bound)
    c = np.where(over, excess - softness * np.tanh(np.where(over, excess, 0.0) / softness),
                 excess)
    c = np.where(norms > 1e-18, c, -1.0)
    m = len(c)
    gram = rows @ rows.T + ridge * np.eye(m)
    multipliers = np.zeros(m)
    passive = np.zeros(m, dtype=bool)
    for _ in range(3 * m + 3):
        w = c - gram @ multipliers
        w[passive] = -np.inf
        best = int(np.argmax(w))
        if not w[best] > 1e-12:
            break
        passive[best] = True
        for _ in range(3 * m + 3):
            index = np.nonzero(passive)[0]
            z = np.linalg.solve(gram[np.ix_(index, index)], c[index])
            if np.all(z > 0.0):
                multipliers[:] = 0.0
                multipliers[index] = z
                break
            low = z <= 0.0
            alpha = min(1.0, float(np.min(multipliers[index][low]
                                          / (multipliers[index][low] - z[low]))))
            multipliers[index] += alpha * (z - multipliers[index])
            gone = index[multipliers[index] <= 1e-15]
            multipliers[gone] = 0.0
            passive[gone] = False
    return qdot_r - multipliers @ rows, True


def _on_side(names, side: str) -> tuple[str, ...]:
    """Capsule names of the right side (r_...) on `side` ('r_' or 'l_'); others as they are."""
    return tuple(side + name[2:] if name.startswith('r_') else name for name in names)


def _exempt_key(exempt) -> tuple | None:
    """An exemption ((hand capsules), (arm capsules)) or None as a comparable value."""
    return None if exempt is None else (tuple(exempt[0]), tuple(exempt[1]))


def _person_arrays(human: Capsules, exempt, planar: bool) -> tuple:
    """The person's capsules as arm_kernels.body_barrier takes them: (a (H, 3) m, axis
    (H, 3) m, radius (H,) m, end velocities (H, 3) m/s each (zeros for a still person), each
    capsule's part (H,): KEPT, LEFT_OUT (exempt[0]) or AT_SURFACE (exempt[1])), projected
    onto z = 0 for a planar arm."""
    from hri_adaptive_controller.arm_kernels import AT_SURFACE, KEPT, LEFT_OUT

    if planar:
        human = human.flat
    part = np.full(len(human), KEPT, dtype=np.int64)
    if exempt is not None:
        part[list(exempt[1])] = AT_SURFACE
        part[list(exempt[0])] = LEFT_OUT
    still = np.zeros((len(human), 3))
    return (np.ascontiguousarray(human.a), np.ascontiguousarray(human.axis), human.radius,
            still if human.velocity_a is None else human.velocity_a,
            still if human.velocity_b is None else human.velocity_b, part)


class ArmController(TaskDrives):
    """The adaptive law for the arm `model` (any RobotModel: the SCARA, the Panda, a URDF).

    gains: ArmGains (len(ks) = model.dof, one adaptation rate per model.adaptation_kinds;
    default_gains(model) has them); theta_hat0 (p,): the initial estimate (default: the
    model's nominal theta), projected onto the model's box. compiled: the per-cycle
    arithmetic through arm_kernels (numba), else through numpy (the reference the kernels are
    tested against; the same results to rounding). body: the robot's capsules
    (hri_core.bodies.RobotBody) for the whole-body clearance, or None.
    """

    def __init__(self, model: RobotModel, gains: ArmGains | None = None, theta_hat0=None,
                 compiled: bool = True, body: RobotBody | None = None):
        self.model = model
        # The robot as capsules (hri_core.bodies.robot_body) for the whole-body clearance;
        # None: the law keeps off no person's body (the tool-hand task alone).
        self.body = body
        self._tool_capsule = None if body is None else body.names.index(body.tool)
        self._body_time = 0.0  # s the law has had a body without a break (its force fades in)
        self._body_joints = None if body is None else np.array(body.joint, dtype=np.int64)
        self._body_inputs = None  # the last person's arrays for the compiled barrier
        self._last_exempt = (None, None, None)  # _exempt's last (drive, person, answer)
        self._person_task = (None, False)  # (drive, avoid) the last cycle's barrier took
        # The side ('r_' or 'l_') whose hand /target last lay on, kept while that hand is out
        # of sight (an occluded wrist does not move the exemption), and the last /target (k,)
        # m (tracked_side).
        self._tracked_side = None
        self._hand_position = None
        gains = default_gains(model) if gains is None else gains
        n, axes = model.dof, model.task_axes
        if n < axes:
            raise ValueError(f'{model.name} has {n} joints: a law on {axes} task axes needs at '
                             f'least {axes}')
        if len(gains.ks) != n:
            raise ValueError(f'ks must have {n} values for {model.name}, got {gains.ks}')
        super().__init__(gains, attained_reach(model))
        self._rates = model.adaptation_rates(gains.adaptation)
        self._axes = axes
        limits = model.limits
        self._lower = np.where(np.isfinite(limits.lower), limits.lower, -1e9)
        self._upper = np.where(np.isfinite(limits.upper), limits.upper, 1e9)
        if np.any(self._upper - self._lower <= 2.0 * gains.limit_band):
            raise ValueError(f'every joint range of {model.name} must be wider than '
                             f'2 limit_band ({gains.limit_band} rad)')
        self._effort = gains.effort_scale * limits.effort
        if gains.effort_limit is not None:
            self._effort = np.minimum(self._effort, gains.effort_limit)
        if not np.all(self._effort > 0.0):
            raise ValueError(f'{model.name} has a joint without an effort limit > 0: '
                             f'{limits.effort.tolist()}')
        self._inverse_effort = 1.0 / self._effort
        # Where the joint speed limit's smooth cap starts: speed_scale of the velocity limits
        # less its soft band, so that no joint's reference exceeds the limit (inf: a joint
        # without one).
        velocity = np.asarray(limits.velocity, dtype=float)
        self._speed = np.where(np.isfinite(velocity) & (velocity > 0.0),
                               gains.speed_scale * velocity / (1.0 + CAP_BAND), np.inf)
        # Where no barrier acts (the barrier's bands start here): checked first each step, in
        # floats (two numpy comparisons cost more for a few joints).
        self._inner = tuple(zip((self._lower + gains.limit_band).tolist(),
                                (self._upper - gains.limit_band).tolist(), strict=True))
        self._ks = np.asarray(gains.ks, dtype=float)
        self._home = np.clip(model.home, self._lower + gains.limit_band,
                             self._upper - gains.limit_band)
        self._threshold2 = gains.damping.threshold ** 2
        self._max_damping2 = gains.damping.max_damping ** 2
        self._feed_speed = FEED_FORWARD_RATIO * gains.max_task_speed
        self._last: tuple = (None, 0.0, None)
        self._approach = None  # limit_approach: (row (n,), allowed m/s, |row|^2) or None
        # The per-cycle arithmetic compiled (arm_kernels; numba, imported here so that a
        # reference-only user does not load it), or numpy's (the reference).
        self._compiled = compiled
        self._zero_joints = np.zeros(n)
        self._zero_task = np.zeros(axes)
        self._null_space = n > axes
        self._posture = (float(gains.posture_gain), float(gains.posture_speed))
        if compiled:
            from hri_adaptive_controller import arm_kernels
            self._kernels = arm_kernels
            self._load_kernels()
        self._reach = ReachRound(gains.reach_round, model, self._lower, self._upper,
                                 gains.limit_band, self._task_reach, gains.damping.threshold,
                                 compiled)
        self.reset(model.theta if theta_hat0 is None else theta_hat0)

    def _load_kernels(self) -> None:
        """Call each kernel once with the argument types `command` gives them, so that numba
        compiles them (or loads them from its cache) now and not at the first cycle."""
        n, kernels = self.model.dof, self._kernels
        zeros_k, zeros_n = self._zero_task, self._zero_joints
        jac = np.zeros((self._axes, n))
        pinv, pinv_rate, *_ = kernels.damped_pseudo_inverse(jac, jac, 1.0, 0.0)
        kernels.joint_reference(zeros_n, zeros_n, jac, jac, pinv, pinv_rate, zeros_k, zeros_k,
                                (0.0, 0.0, 0.0), zeros_n, zeros_n, zeros_n, *self._posture,
                                True, zeros_n, zeros_n, zeros_n, zeros_n, 1.0, 0.0)
        kernels.joint_speed_limit(zeros_n, zeros_n, zeros_n, zeros_n, self._lower, self._upper,
                                  self._speed, 1.0, 1.0)
        p = self.model.theta.size
        kernels.torque(np.zeros((n, p)), np.zeros(p), zeros_n, zeros_n, zeros_n, jac, zeros_k,
                       zeros_n, zeros_n)
        kernels.adapt(np.zeros((n, p)), zeros_n, np.zeros(p), 0.0, np.zeros(p),
                      self.model.theta_lower, self.model.theta_upper)
        kernels.joint_motion(zeros_n, True, zeros_n, zeros_n, zeros_n, zeros_n, zeros_n, 1e-3,
                             1.0, 1.0, 1.0, 1.0, zeros_n)
        if self.body is not None and self.body.chain is not None:
            far = Capsules(('far',), np.full((1, 3), 1e3), np.full((1, 3), 1e3), np.ones(1))
            self.whole_body_barrier(self.model.home.astype(float), zeros_n, far, None)
        if self.body is not None:
            # Not at the person's first approach: compiling it then held a cycle for seconds.
            kernels.body_damper(zeros_n, np.zeros((1, n)), np.ones(1), np.zeros(1), 1.0, 0.0,
                                -1.0, DAMPER_SOFTNESS, DAMPER_RIDGE)

    @property
    def gains(self) -> ArmGains:
        """The controller's gains."""
        return self._gains

    @property
    def theta_hat(self) -> np.ndarray:
        """The current estimate (p,), a copy."""
        return self._theta.copy()

    @property
    def adaptation_rates(self) -> np.ndarray:
        """L's diagonal (p,), a copy."""
        return self._rates.copy()

    @property
    def effort_limits(self) -> np.ndarray:
        """The per-joint effort limits the law keeps to (n,) N m."""
        return self._effort.copy()

    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """The joint position limits the law keeps off (lower, upper) (n,) rad, copies."""
        return self._lower.copy(), self._upper.copy()

    def reset(self, theta_hat0) -> None:
        """Restart the estimate at theta_hat0 (p,), projected onto the model's box."""
        theta = np.asarray(theta_hat0, dtype=float)
        if theta.shape != self.model.theta.shape or not np.all(np.isfinite(theta)):
            raise ValueError(f'theta_hat0 must be {self.model.theta.size} finite values, '
                             f'got shape {theta.shape}')
        self._theta = np.clip(theta, self.model.theta_lower, self.model.theta_upper)
        self._pending = None  # theta_hat's update from the last `command`, for `adapt`
        self._reach.reset()
        self._hand_velocity = (0.0,) * (2 * self._axes)
        self._body_time = 0.0

    @property
    def reaching_round(self) -> bool:
        """Whether the reach-round blend is heading to (or at) the joint-space motion."""
        return self._reach.engaged

    @property
    def reach(self) -> float:
        """The attained reach (m) the task drives work with (attained_reach)."""
        return self._task_reach

    def drive(self, shape: TaskShape | None, k: float = 0.0) -> TaskDrive | None:
        """TaskDrives.drive with the attained reach, the last task's drive kept at hand (the
        cache's hashing of a TaskShape costs 5 us a cycle)."""
        if shape is not None and shape is self._last[0] and k == self._last[1]:
            return self._last[2]
        drive = super().drive(shape, k)
        if drive is not None:
            self._last = (shape, k, drive)
        return drive

    def lyapunov(self, output: ArmOutput, q, task: ActiveTask | None, true_model=None,
                 with_task: bool = True) -> float:
        """V of eq. 21 with the barriers (J): 1/2 s^T M s + Kp a Q + B + U (+ 1/2 dtheta^T L^-1
        dtheta with the true model's theta, in simulation). M from true_model if given,
        else from the nominal model. with_task=False leaves out Kp a Q (for a caller that
        adds it later, for many steps at once)."""
        q = np.asarray(q, dtype=float)
        model = self.model if true_model is None else true_model
        value = model.kinetic_energy(q, output.s)  # 1/2 s^T M s
        drive = None if task is None or not with_task else self.drive(task.shape, task.k)
        if drive is not None and output.distance is not None:
            value += self._gains.kp * task.weight * task_potential(output.distance, drive)
        value += barrier_energy(q, self._lower, self._upper, self._gains.limit_band,
                                self._gains.barrier_torque)
        value += output.body.energy  # the whole-body barrier's U
        if true_model is not None:
            active = self._rates > 0.0
            error = true_model.theta - output.theta_hat
            value += 0.5 * float(np.sum(error[active] ** 2 / self._rates[active]))
        return value

    def lyapunov_rate(self, output: ArmOutput, task: ActiveTask | None,
                      friction=None, with_task: bool = True) -> float:
        """dV/dt of eq. 22 predicted from a step's output (W; not a fault's), the monitor:

            -s^T (Ks + F) s - Kp |v_e|^2 + Kp (da/dt) Q + Kp v_e^T w,

        v_e = (1 - sigma) a delta_eps + J+^T g_B / Kp, w the output's reference_offset (the
        avoid task's term); friction F (n,) N m s/rad (simulation; default none);
        with_task=False leaves out Kp (da/dt) Q. Not in it: the barrier band's and the
        feed-forward gate's terms, and the reach-round blend's sigma-rate terms (module
        docstring); exact where J+ is (damping 0), off the bands and the blend."""
        drive = None if task is None or not with_task else self.drive(task.shape, task.k)
        potential = (0.0 if drive is None or output.distance is None
                     else task_potential(output.distance, drive))
        effective = (1.0 - output.blend) * output.weighted_task_variable
        if output.barrier_task_velocity is not None:
            effective = effective + output.barrier_task_velocity
        return predicted_lyapunov_rate(
            output.s, effective,
            0.0 if task is None else task.weight_rate, potential, self._ks, self._gains.kp,
            self._zero_joints if friction is None else friction, output.reference_offset)

    def _joint_reference(self, joints, jacobians, feed, task, blend, barrier_state,
                         posture=(None, None)):
        """qdot_r, qddot_r (n,) and the barrier's task-space velocity (k,) or None, in numpy:
        the reference of arm_kernels.joint_reference and the path within a barrier band.
        joints (q, dq); jacobians (J, Jdot, J+, dJ+/dt); feed (ff, dff/dt) and task (v, dv/dt)
        (k,) each; blend (sigma, dsigma/dt, a u, d(a u)/dt) or None; barrier_state (near,
        g_B, dg_B/dt), g_B None outside every band; posture (the body barrier's posture
        push (n,) N m, its rate) or Nones."""
        (q, dq), (jac, jac_rate, pinv, pinv_rate) = joints, jacobians
        (ff, ff_rate), (velocity, rate), (near, g_b, g_b_rate) = feed, task, barrier_state
        gains = self._gains
        if near == 0.0:
            # J+ (ff + v) and its rate in two products each (the usual case).
            both = ff + velocity
            qdot_r = pinv @ both
            qddot_r = pinv_rate @ both + pinv @ (ff_rate + rate)
        else:
            joint_ff, joint_ff_rate = gate_feed_forward(
                q, dq, pinv @ ff, pinv_rate @ ff + pinv @ ff_rate, self._lower,
                self._upper, gains.limit_band)
            qdot_r = joint_ff + pinv @ velocity
            qddot_r = joint_ff_rate + pinv_rate @ velocity + pinv @ rate
        if blend is not None:
            sigma, sigma_rate, u, u_rate = blend
            qddot_r = ((1.0 - sigma) * qddot_r + sigma_rate * (u - qdot_r) + sigma * u_rate)
            qdot_r = (1.0 - sigma) * qdot_r + sigma * u
            blend = (sigma, sigma_rate)
        barrier_task = None
        if g_b is not None:
            # The barriers' task-space velocity J+^T g_B / Kp and its rate.
            barrier_task = (pinv.T @ g_b) / gains.kp
            barrier_task_rate = (pinv_rate.T @ g_b + pinv.T @ g_b_rate) / gains.kp
            qdot_r = qdot_r - pinv @ barrier_task
            qddot_r = qddot_r - pinv_rate @ barrier_task - pinv @ barrier_task_rate
        if self._null_space:
            z, z_rate = self._null_velocity(q, dq, g_b, g_b_rate, blend, posture)
            # N z = z - J+ (J z), dN/dt z + N dz/dt as products with vectors: no n x n
            # matrix is formed.
            jz = jac @ z
            qdot_r = qdot_r + (z - pinv @ jz)
            qddot_r = qddot_r + (z_rate - pinv_rate @ jz - pinv @ (jac_rate @ z + jac @ z_rate))
        return qdot_r, qddot_r, barrier_task

    def _null_velocity(self, q, dq, barrier_gradient, barrier_rate, blend,
                       posture=(None, None)):
        """z (n,) rad/s and dz/dt: towards home (each joint capped at posture_speed; weighted
        1 - sigma while the reach-round blend moves the joints, blend = (sigma, dsigma/dt)),
        off the joint limits and the person (the barriers' g_B), and off the person from
        further (the body barrier's posture push, posture = (push, its rate) or Nones), the
        pushes at v_B / kb (rad/s per N m) (module docstring)."""
        gains = self._gains
        z = -gains.posture_gain * (q - self._home)
        z_rate = -gains.posture_gain * dq
        values = z.tolist()
        if max(map(abs, values)) > gains.posture_speed:
            capped = [speed_cap(value, gains.posture_speed) for value in values]
            z = np.array([value for value, _ in capped])
            z_rate = z_rate * np.array([slope for _, slope in capped])
        if blend is not None:
            sigma, sigma_rate = blend
            z, z_rate = (1.0 - sigma) * z, (1.0 - sigma) * z_rate - sigma_rate * z
        if gains.barrier_torque > 0.0:
            push = gains.limit_speed / gains.barrier_torque
            if barrier_gradient is not None:
                z = z - push * barrier_gradient
                z_rate = z_rate - push * barrier_rate
            if posture[0] is not None:
                z = z - push * posture[0]
                z_rate = z_rate - push * posture[1]
        return z, z_rate

    def _feed_forward(self, velocity, acceleration):
        """The hand's velocity fed forward, capped at FEED_FORWARD_RATIO v_max (the smooth cap
        of task_variable, C2: the arm is not asked to keep up with a hand faster than it may
        move; a toss at 3 m/s saturated the drives for 0.4 s), and its rate (k,) each."""
        scale, gain = norm_cap(velocity, self._feed_speed)
        if scale == 1.0:
            return velocity, acceleration
        scale_rate = gain * float(velocity @ acceleration)
        return scale * velocity, scale * acceleration + scale_rate * velocity

    def step(self, q, dq, hand: HandState, task: ActiveTask | None, dt: float,
             rest=None, human: Capsules | None = None) -> ArmOutput:
        """The torque at (q, dq) (n,) for the hand and task, and theta_hat advanced by dt (s).

        rest (k,) m: an avoid task's rest position (None: where the tool is, so no return). human:
        the person's capsules (hri_core.bodies.human_capsules; None: no body), which every robot
        capsule keeps `gains.body.clearance` from. Inputs are finite and of the right shapes (the
        caller checks them where they enter); a non-finite result still gives zero torque and
        fault=True, theta_hat unchanged. `command` then `adapt`, in one call.
        """
        output = self.command(q, dq, hand, task, dt, rest, human)
        if not output.fault and not self.adapt():
            return self._fault('non-finite torque or parameter update')
        return output

    def command(self, q, dq, hand: HandState, task: ActiveTask | None, dt: float,
                rest=None, human: Capsules | None = None) -> ArmOutput:
        """step's torque (eq. 14-18), with theta_hat's update (eq. 19) kept for `adapt`: a
        controller sends the torque first (the update serves the next cycle only)."""
        self._pending = None
        gains = self._gains
        theta = self._theta
        q = np.asarray(q, dtype=float)
        dq = np.asarray(dq, dtype=float)
        drive = None if task is None else self._control_drive(task.shape, task.k)
        k = 0.0 if drive is None else drive.task_gain
        self._hand_velocity = filter_hand_velocity(self._hand_velocity,
                                                   hand.velocity.tolist(), dt)
        # No np.errstate here (4 us a cycle): overflow and invalid values end in the finite
        # checks below, which turn them into a fault.
        try:
            x, jac, jac_rate = self.model.task_kinematics(q, dq)
            if self._compiled:
                pinv, pinv_rate, lam2, singular = self._kernels.damped_pseudo_inverse(
                    jac, jac_rate, self._threshold2, self._max_damping2)
                if singular:
                    raise ValueError('singular Jacobian and no damping (max_damping = 0)')
            else:
                pinv, pinv_rate, lam2 = damped_pseudo_inverse(jac, jac_rate, self._threshold2,
                                                              self._max_damping2)
            xdot = jac @ dq
            hand_velocity, hand_acceleration = hand.velocity, hand.acceleration
            dx = x - hand.position
            distance = math.sqrt(float(dx @ dx))
            a, da = (0.0, 0.0) if drive is None else (task.weight, task.weight_rate)
            avoid = drive is not None and drive.open_outward
            if avoid:
                # An avoid task reads the hand's velocity through the filter (its rate is
                # continuous; the estimate steps at each /target).
                axes = self._axes
                hand_velocity = np.array(self._hand_velocity[:axes])
                hand_acceleration = np.array(self._hand_velocity[axes:])
            task_velocity, task_rate = self._task_velocity(
                drive, (a, da), (x, dx, xdot), (hand_velocity, hand_acceleration),
                x if rest is None else rest)
            weighted = task_velocity[2]
            feed, feed_rate = (1.0 - a, -da) if avoid else (1.0, 0.0)
            ff, ff_rate = self._feed_forward(
                feed * hand_velocity, feed * hand_acceleration + feed_rate * hand_velocity)
            hand_feed = ff
            if all(low <= value <= high for value, (low, high) in zip(q.tolist(), self._inner,
                                                                       strict=True)):
                g_b = g_b_rate = None  # outside every band (the usual case)
                near = 0.0
            else:
                g_b, g_b_rate, near = barrier(q, dq, self._lower, self._upper,
                                              gains.limit_band, gains.barrier_torque)
            # g_ref: the barriers' gradient as the reference takes it (the person's capped).
            body, g_ref, g_ref_rate = NO_BODY, g_b, g_b_rate
            fade = self._body_fade(human, dt)
            exempt = None
            self._hand_position = hand.position
            if fade > 0.0:
                exempt = self._exempt(drive, avoid, human)
                self._person_task = (drive, avoid)
                body = self.whole_body_barrier(q, dq, human, exempt, fade)
                if body.gradient is not None:
                    gradient, rate = body.gradient, body.rate
                    pushed, pushed_rate = gradient, rate
                    if near > 0.0:
                        # Within a joint's band the person's push does not drive it into its
                        # stop (torque -g; the joint barrier's kb is 3 N m, several pairs on
                        # the SCARA's link2 more): that share fades out as the feed-forward's.
                        torque, torque_rate = gate_feed_forward(
                            q, dq, -gradient, -rate, self._lower, self._upper,
                            gains.limit_band, PUSH_SCALE)
                        gradient, rate = -torque, -torque_rate
                        # The reference pushes as hard along the joints still free (the
                        # torque, in V, keeps the gated g).
                        pushed, pushed_rate = redirected_push(
                            body.gradient, body.rate, gradient, rate, REDIRECT_MOST)
                    # The person's barrier joins the joint limits' (one g_B in V and eq. 22).
                    g_b = gradient if g_b is None else g_b + gradient
                    g_b_rate = rate if g_b_rate is None else g_b_rate + rate
                    push, push_rate = self._capped_push(pushed, pushed_rate, pinv, pinv_rate,
                                                        human)
                    g_ref = push if g_ref is None else g_ref + push
                    g_ref_rate = push_rate if g_ref_rate is None else g_ref_rate + push_rate
                    # Within the barrier's band the hand's velocity is not fed forward: a
                    # hand drawn back to the chest at 0.5 m/s would cancel its 0.5 m/s push.
                    keep, keep_rate = 1.0 - body.gate, -body.gate_rate
                    ff, ff_rate = keep * ff, keep * ff_rate + keep_rate * ff
            # The reach-round's pose keeps the person's clearance (keep_off): its blend
            # engages where the person's barrier holds the arm short of a far goal, as a
            # joint's barrier does (the learned task's pull near the hand, about 1 N, left
            # the Panda resting in the bands 0.17-0.47 m short), slower the nearer the
            # person, and stands down while its pose is not clear (GOAL_SHORTFALL): a pose
            # that ignored the person pulled the arm into the barrier for good (sigma 1, the
            # task's force 0).
            knows_person = fade > 0.0
            self._reach.keep_off = self._keep_off(human, exempt) if knows_person else None
            round_person = knows_person and self._reach.goal_shortfall <= GOAL_SHORTFALL
            self._reach.speed_scale = (1.0 - (1.0 - PERSON_ROUND_SPEED) * body.gate
                                       if knows_person else 1.0)
            held = body.gate > REACH_ROUND_BODY_GATE
            region = (None if drive is None or avoid or (held and not round_person)
                      else (drive.shape.d1, drive.shape.d2))
            # The pose moves with the hand: the hand's velocity as fed forward (capped; not
            # gated by the person's band, which the pose keeps clear of).
            blend = self._reach.update(q, dq, x, jac, hand.position, region,
                                       max(near, body.gate) if held and round_person else near,
                                       dt, hand_feed, pinv)
            scale = 1.0
            if blend is not None:
                # eq. 14 blended with the joint motion a u, weighted as the task's pull.
                sigma, sigma_rate, u, u_rate = blend
                blend = (sigma, sigma_rate, a * u, da * u + a * u_rate)
                scale = 1.0 - sigma
            barrier_task = None
            if near == 0.0 and self._compiled:
                # Outside the joint limits' bands (the usual case), compiled: J+ (ff + v), the
                # blend, the person's barrier and N z in one call.
                if blend is None:
                    on, u, u_rate = (0.0, 0.0, 0.0), self._zero_joints, self._zero_joints
                else:
                    on, u, u_rate = (blend[0], blend[1], 1.0), blend[2], blend[3]
                zero = self._zero_joints
                qdot_r, qddot_r, s, barrier_task = self._kernels.joint_reference(
                    q, dq, jac, jac_rate, pinv, pinv_rate, ff + task_velocity[0],
                    ff_rate + task_rate, on, u, u_rate, self._home, *self._posture,
                    self._null_space, zero if g_ref is None else g_ref,
                    zero if g_ref is None else g_ref_rate,
                    zero if body.posture is None else body.posture,
                    zero if body.posture is None else body.posture_rate, gains.kp,
                    gains.limit_speed / gains.barrier_torque if gains.barrier_torque > 0.0
                    else 0.0)
                if g_ref is None:
                    barrier_task = None
            else:
                qdot_r, qddot_r, barrier_task = self._joint_reference(
                    (q, dq), (jac, jac_rate, pinv, pinv_rate), (ff, ff_rate),
                    (task_velocity[0], task_rate), blend, (near, g_ref, g_ref_rate),
                    (body.posture, body.posture_rate))
                s = dq - qdot_r
            if self._approach is not None:
                qdot_r = self._limited_approach(qdot_r)
                s = dq - qdot_r
            if body.rows is not None and gains.body.stop_rate > 0.0:
                # The person's approach damper (body_damper): no close pair's point is asked
                # towards the person faster than it can stop from before the clearance.
                settings = gains.body
                qdot_r, damped = (self._kernels.body_damper if self._compiled else body_damper)(
                    qdot_r, body.rows, body.gaps, body.approach, settings.stop_rate,
                    settings.clearance - settings.stop_depth, -fade * settings.max_speed,
                    DAMPER_SOFTNESS, DAMPER_RIDGE)
                if damped:
                    s = dq - qdot_r
            # Last: no term asks a joint for more than its speed limit or for more than it
            # can stop from before its limit (joint_limits' Joint speed limit).
            qdot_r, qddot_r, held = (self._kernels.joint_speed_limit if self._compiled
                                     else joint_speed_limit)(
                q, dq, qdot_r, qddot_r, self._lower, self._upper, self._speed,
                gains.stop_rate, gains.limit_band)
            if held:
                s = dq - qdot_r
            regressor = self.model.regressor_unchecked(q, dq, qdot_r, qddot_r)  # eq. 18
            task_force = (gains.kp * scale) * weighted
            if self._compiled:
                tau_requested, peak = self._kernels.torque(
                    regressor, theta, qddot_r, s, self._ks, jac, task_force,
                    self._zero_joints if g_b is None else g_b, self._inverse_effort)
            else:
                tau_requested = regressor @ theta - self._ks * s - jac.T @ task_force
                if g_b is not None:
                    tau_requested -= g_b
                peak = float((np.abs(tau_requested) * self._inverse_effort).max())
                peak += 0.0 * float(qddot_r.sum())  # NaN or inf in either: not finite
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as error:
            return self._fault(f'step failed: {error!r}')
        if not math.isfinite(peak):
            return self._fault('non-finite torque or parameter update')
        limited = peak > 1.0
        tau = tau_requested / peak if limited else tau_requested.copy()
        # eq. 19, paused where its premise fails: near a limit (the stop's force is outside
        # the model) and while the torque is clamped (the arm does not get the law's torque).
        pace = 0.0 if limited else dt * (1.0 - near)
        if pace > 0.0:
            self._pending = (regressor, s, pace)
        # eq. 22's avoid term: w = f xdot_f + a (v_rest + v_away) - xdot_d (the feed-forward
        # as the reference has it, capped; xdot_f the filtered hand velocity of an avoid task).
        offset = ff + task_velocity[1] - hand.velocity
        if g_b is None:
            g_b = self._zero_joints
        return ArmOutput(tau, tau_requested, s, qdot_r, qddot_r, x, distance, k, theta,
                         limited, False, '', lam2, near, g_b, weighted,
                         blend=0.0 if blend is None else blend[0],
                         barrier_task_velocity=barrier_task, reference_offset=offset, body=body)

    def limit_approach(self, row, allowed: float) -> None:
        """From the next step on, hold the reference's speed along `row` at or below `allowed`
        m/s (ISO/TS 15066 speed and separation monitoring: the separation cap's limit for the
        point of the arm nearest the person). row (n,) m/rad: n^T J_p, the joint-space row of
        that point's velocity along the unit normal n towards the person (J_p its point
        Jacobian at q); None: no limit. qdot_r loses the least joint motion that brings it
        within the limit, qdot_r - (row qdot_r - allowed) row^T / |row|^2, and nothing
        where it is within; qddot_r leaves the change out (as the pull limit's), and the
        caller changes `allowed` gradually. A row of norm below 1e-9 (a point the joints do
        not move along n) is no limit."""
        if row is None:
            self._approach = None
            return
        if not (allowed >= 0.0):  # also NaN
            raise ValueError(f'approach speed limit must be >= 0 m/s, got {allowed}')
        row = np.asarray(row, dtype=float)
        if row.shape != (self.model.dof,) or not np.all(np.isfinite(row)):
            raise ValueError(f'approach row must be {self.model.dof} finite values, got {row}')
        norm2 = float(row @ row)
        self._approach = (row, float(allowed), norm2) if norm2 > 1e-18 else None

    def _limited_approach(self, qdot_r: np.ndarray) -> np.ndarray:
        """qdot_r (n,) with its speed along the approach row held at the limit
        (limit_approach)."""
        row, allowed, norm2 = self._approach
        excess = float(row @ qdot_r) - allowed
        if excess <= 0.0:
            return qdot_r
        return qdot_r - (excess / norm2) * row

    def _capped_push(self, gradient, rate, pinv, pinv_rate,
                     human: Capsules) -> tuple[np.ndarray, np.ndarray]:
        """The person's barrier g (n,) N m and its rate as the reference takes them: scaled
        so that its task-space velocity w = J+^T g / Kp (m/s) is at most gains.body.max_speed
        plus the fastest speed of the person's capsule ends (m/s; 0 for a still person) in
        norm (norm_cap: speed_cap's smooth cap of |w|), and the scale's rate with it. The
        torque keeps g whole. Why: near a stretched arm J+ is large, and a push on a link
        near the base (the SCARA's link1 under a person's arm) asked 1.5-1.8 m/s of the
        tool, 13-15 rad/s of a joint; a person who moves may still be left at their own speed
        and more (docs/design.md)."""
        gains = self._gains
        w = (pinv.T @ gradient) / gains.kp
        scale, gain = norm_cap(w, gains.body.max_speed + human.fastest_speed)
        if scale == 1.0:
            return gradient, rate
        w_rate = (pinv_rate.T @ gradient + pinv.T @ rate) / gains.kp
        scale_rate = gain * float(w @ w_rate)
        return scale * gradient, scale * rate + scale_rate * gradient

    def _body_fade(self, human: Capsules | None, dt: float) -> float:
        """The barrier's force fraction in [0, 1] this cycle: eq. 13's quintic ramp over
        gains.body.fade_in s of the time the law has had a body without a break (dt s counted
        for this cycle); 0 without a body, a robot body or a force."""
        settings = self._gains.body
        if human is None or len(human) == 0 or self.body is None or settings.force <= 0.0:
            self._body_time = 0.0
            return 0.0
        self._body_time += dt
        if self._body_time >= settings.fade_in:
            return 1.0
        return quintic_smoothstep(self._body_time / settings.fade_in)[0]

    def _keep_off(self, human: Capsules, exempt, margin: float = IK_CLEARANCE_MARGIN):
        """The reach-round's keep_off for the person `human` (exempt as _exempt gives it):
        q (n,) rad -> (rows n^T J_p (m, n) m/rad, shortfall (m,) m) of the pairs within the
        approach damper's reach (clearance + influence), shortfall = clearance + margin (m)
        - distance (their surfaces', the tracked arm's at its surface as in the barrier), or
        None without such a pair."""
        wanted = self._gains.body.clearance + margin
        still = self._zero_joints

        def keep_off(q):
            pairs = self.whole_body_barrier(q, still, human, exempt)
            if pairs.rows is None:
                return None
            return pairs.rows, wanted - pairs.gaps

        return keep_off

    def person_keep_off(self, shape: TaskShape | None, human: Capsules, margin: float,
                        hand=None):
        """_keep_off in the task `shape` (None: no task) for the person `human` with the hand
        (/target) at `hand` (k,) m (None: the last the law was given), with the task's
        exemption, its pairs wanted `margin` (m) beyond the clearance: "is there a pose here
        that keeps the law's clearances" asked as the law asks it."""
        drive = self.drive(shape)
        avoid = drive is not None and drive.open_outward
        return self._keep_off(human, self._exempt(drive, avoid, human, hand), margin)

    def _exempt(self, drive, avoid: bool, human: Capsules, hand=None):
        """(the tracked hand's capsules, the rest of its arm's) where the task's region
        reaches into the hand's clearance (a follow task whose d1, a distance between the
        tool's and the hand's points, is below the clearance plus the tool's and the hand's
        capsule radii: the barrier would hold the tool outside the learned region's inner
        edge; there the learned task governs how near the arm comes to the hand; Table I's
        follow_safe, d1 0.183 m, against 0.10 + 0.05 + 0.103 m on the SCARA), else None:
        every robot capsule leaves
        out the first and keeps the second at their surface, not the clearance. Not the
        tool's capsule alone: the links next to it are within the clearance of a hand held
        at the tool (the Panda's link7 beside its hand; the SCARA's elbow 0.3 m from its tip,
        with the hand's 0.1 m radius), so a handover would be refused; nor the clearance from
        the upper arm, whose capsule (0.10 m radius) lies 0.12-0.17 m from the recorded hands
        (docs/design.md). The tracked hand is the one /target lies on (tracked_side), at
        `hand` (k,) m, or where the law was last given it."""
        if hand is not None:  # else the last /target the law was given (tracked_side)
            self._hand_position = np.asarray(hand, dtype=float)
        if drive is None or avoid:
            return None
        # The same task and body message as the last cycle's give the same answer (about 10
        # us a cycle saved).
        last = self._last_exempt
        if last[0] is drive and last[1] is human:
            return last[2]
        exempt = self._exempt_parts(drive, human)
        self._last_exempt = (drive, human, exempt)
        return exempt

    def _exempt_parts(self, drive, human: Capsules):
        """_exempt's answer for a follow task's drive and the person `human`: the capsules
        of the side tracked_side gives."""
        settings = self._gains.body
        side = self.tracked_side(human)
        if side is None:
            return None
        tracked, tracked_arm = (_on_side(settings.tracked, side),
                                _on_side(settings.tracked_arm, side))
        hand = [j for j, name in enumerate(human.names) if name in tracked]
        hand_radius = float(human.radius[hand].max()) if hand else 0.0
        reach = settings.clearance + hand_radius + float(self.body.radius[self._tool_capsule])
        if drive.shape.d1 >= reach:
            return None
        arm = [j for j, name in enumerate(human.names) if name in tracked_arm]
        return (hand, arm) if hand or arm else None

    def tracked_side(self, human: Capsules) -> str | None:
        """The side ('r_' or 'l_') of the person `human` whose hand is the tracked one: the
        side of the tracked capsules (ClearanceSettings.tracked, mirrored for the left) whose
        surface lies nearest the last /target the law was given, if within
        TRACKED_HAND_MARGIN of it; else the last side found while that side's are out of
        sight (an occluded wrist and forearm does not move the exemption); else None (the
        target is no hand of this person, or none has come yet: every capsule keeps the
        clearance). Measured in the task axes (a planar arm's plane)."""
        hand = self._hand_position
        if hand is None:
            return None
        right = self._gains.body.tracked
        names = right + _on_side(right, 'l_')
        seen = [j for j, name in enumerate(human.names) if name in names]
        if seen:
            point = np.zeros((1, 3))
            point[0, :len(hand)] = hand
            # /target as a capsule of no length or radius: its distance to each surface.
            surface = capsule_distances(Capsules(('target',), point, point, np.zeros(1)),
                                        human, planar=len(hand) < 3).distance[0, seen]
            nearest = int(np.argmin(surface))
            if surface[nearest] <= TRACKED_HAND_MARGIN:
                self._tracked_side = human.names[seen[nearest]][:2]
                return self._tracked_side
        last = self._tracked_side
        if last is not None and any(human.names[j].startswith(last) for j in seen):
            self._tracked_side = None  # the last side's hand is in sight, off the target
        return self._tracked_side

    def take_person(self, human: Capsules) -> None:
        """Ready the person `human` (a new body message) for the cycles to come: the task's
        exemption and the compiled barrier's arrays, as the last cycle's task has them, built
        now, off the joint state -> command path (20-40 us of the first cycle after each
        body message otherwise). A task changed since is built in its cycle as before."""
        if not self._compiled or self.body is None or self.body.chain is None or not len(human):
            return
        exempt = self._exempt(*self._person_task, human)
        self._body_inputs = (human, exempt, _person_arrays(human, exempt, self.body.planar))

    def whole_body_barrier(self, q, dq, human: Capsules, exempt=None,
                           fade: float = 1.0) -> BodyBarrier:
        """body_barrier (a BodyBarrier) of this law's body and settings at q, dq (n,) for the
        person `human`, exempt as _exempt gives it, the force times fade (in (0, 1]);
        compiled on the body's chain (arm_kernels.body_barrier: 16 us median for the Panda
        against 225 us, benchmarks.md) where the law is compiled and the body has a chain,
        else body_barrier itself, the reference. The person's arrays are built once per
        Capsules object (a body message) and exemption."""
        settings = self._gains.body
        if fade < 1.0:
            settings = dataclasses.replace(settings, force=settings.force * fade)
        if not self._compiled or self.body.chain is None or len(human) == 0:
            return body_barrier(self.body, q, dq, human, settings, exempt, self._null_space)
        inputs = self._body_inputs
        if inputs is None or inputs[0] is not human or (
                inputs[1] is not exempt and _exempt_key(inputs[1]) != _exempt_key(exempt)):
            inputs = self._body_inputs = (human, exempt,
                                          _person_arrays(human, exempt, self.body.planar))
        body = self.body
        (gradient, rate, energy, push, push_rate, pulled, pushed, distance, i, j, gate,
         gate_rate, rows, gaps, approach) = self._kernels.body_barrier(
            q, dq, BODY_RATE_STEP, *body.chain, self._body_joints, body.local_a, body.local_b,
            body.radius, *inputs[2],
            (settings.clearance, settings.influence, settings.reaction_time,
             settings.max_influence, settings.force, settings.posture_influence,
             settings.posture_force),
            self._null_space)
        pair = (body.names[i], human.names[j])
        if gaps.size == 0:
            rows = gaps = approach = None
        if not (pulled or pushed):
            return BodyBarrier(None, None, 0.0, distance, pair, rows=rows, gaps=gaps,
                               approach=approach)
        return BodyBarrier(gradient if pulled else None, rate if pulled else None, energy,
                           distance, pair, push if pushed else None,
                           push_rate if pushed else None, gate, gate_rate, rows, gaps, approach)

    def gravity_hold(self, q) -> np.ndarray:
        """The torque (n,) N m that holds the arm at q (n,) rad against gravity with theta_hat:
        Y(q, 0, 0, 0) theta_hat (eq. 18 at rest), scaled as a whole into the effort limits;
        zeros if not finite (and for an arm without gravity, the horizontal SCARA). What a
        controller sends while its joint states are stale: zero torque would drop an arm
        under gravity (the Panda's joint 2 holds about 29 N m)."""
        zero = self._zero_joints
        try:
            regressor = self.model.regressor_unchecked(np.asarray(q, dtype=float), zero, zero,
                                                       zero)
        except (ValueError, ArithmeticError):
            return zero.copy()
        tau = regressor @ self._theta
        peak = float((np.abs(tau) * self._inverse_effort).max())
        if not math.isfinite(peak):
            return zero.copy()
        return tau / peak if peak > 1.0 else tau

    def adapt(self, applied: bool = True) -> bool:
        """Advance theta_hat by the last `command`'s update, eq. 19 (once; none after a fault,
        a clamped torque or within a barrier band): theta - pace L Y^T s projected onto the
        model's box. False, theta_hat unchanged, if the update is not finite.

        applied: whether the drives get the command's torque. False (the caller's effort rate
        limit changed it) drops the update, as a clamped torque does: s then grows from the
        torque the limit withheld, not from theta_hat's error, and eq. 19 would wind theta_hat
        up on it. The UR10 starting under gravity (115 N m on its shoulder, reached at 1 N m
        a command, a command every other cycle on a loaded machine) took its wrist's inertia
        from 5e-4 past 0.01 kg m^2 within 0.11 s that way (0.5-1.4 kg m^2 later), and the
        wrist oscillated and spun through its limits."""
        if self._pending is None:
            return True
        regressor, s, pace = self._pending
        self._pending = None
        if not applied:
            return True
        if self._compiled:
            theta_next, finite = self._kernels.adapt(regressor, s, self._rates, pace, self._theta,
                                                     self.model.theta_lower,
                                                     self.model.theta_upper)
            if finite:
                self._theta = theta_next
            return finite
        # In place in one new array (np.clip costs 3 us more than the two ufuncs; NaN passes
        # both, caught by the sum).
        theta_next = regressor.T @ s  # Y^T s
        theta_next *= self._rates
        theta_next *= -pace
        theta_next += self._theta
        np.maximum(theta_next, self.model.theta_lower, out=theta_next)
        np.minimum(theta_next, self.model.theta_upper, out=theta_next)
        if not math.isfinite(float(theta_next.sum())):
            return False
        self._theta = theta_next
        return True

    def finish_cycle(self) -> None:
        """The cycle's work that its torque does not wait for, for a caller to run after
        sending the command (after `adapt`): the reach-round's solve steps
        (ReachRound.advance), whose joint goal the next cycles take. A caller that never
        calls this has them run inside `command`; one that calls it once before its first
        command has every solve run here."""
        self._reach.advance()

    def _task_velocity(self, drive, weight, motion, hand, rest):
        """The task's share of v_r, -a delta_eps + a (v_rest + v_away), and its rate (eq.
        12', 14, 18; task_variable.rest_term and retreat_term for avoid tasks).

        weight (a, da/dt); motion (x, dx = x - x_d, xdot) (k,) each; hand (xdot_d, xddot_d) as
        the reference reads them; rest (k,) m. Returns ((v, a (v_rest + v_away), a delta_eps),
        dv/dt), each (k,)."""
        if drive is None:
            zero = self._zero_task
            return (zero, zero, zero), zero
        (a, da), (x, dx, xdot), (hand_velocity, hand_acceleration) = weight, motion, hand
        u = xdot - hand_velocity
        slope, hessian_u = task_term_along(dx, u, drive)
        weighted = a * slope
        velocity, rate = -weighted, -(da * slope + a * hessian_u)
        away = self._zero_task
        if drive.open_outward:
            floats = [v.tolist() for v in (dx, x - rest, u, xdot, hand_velocity,
                                            hand_acceleration)]
            term, term_rate = np.zeros(self._axes), np.zeros(self._axes)
            for part in (rest_term(*floats[:4], drive),
                         retreat_term(floats[0], floats[2], *floats[4:], drive)):
                if part is not None:
                    term, term_rate = term + part[0], term_rate + part[1]
            away = a * term
            velocity, rate = velocity + away, rate + da * term + a * term_rate
        return (velocity, away, weighted), rate

    def _fault(self, reason: str) -> ArmOutput:
        zero = np.zeros(self.model.dof)
        return ArmOutput(zero, zero.copy(), zero.copy(), zero.copy(), zero.copy(), None, None,
                         0.0, self._theta.copy(), False, True, reason)
