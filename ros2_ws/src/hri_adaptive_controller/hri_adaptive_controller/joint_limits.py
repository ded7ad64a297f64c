"""Joint limits in the control law: a barrier, a feed-forward gate and the reach-round blend.

The paper's controller knows no joint limits. A SCARA's joint 2 stops at about +-141 deg (the
arm folded to r = 0.222 m) and joint 1 at about +-132 deg; a hand that crosses over the base
pulls the arm straight into joint 2's stop, where the reference keeps asking for motion, s
grows and -Ks s pushes the full effort into the stop. Three pieces, no ROS import; the
blend's joint motion and the SCARA's inverse kinematics are plain loops that numba also
compiles for the 1 kHz step (arm_kernels), these being their reference.

Barrier (in V)
--------------
Within `band` rad of a limit a joint-space potential B(q) = sum_i B_i(q_i) rises, with

    dB/dq_i = g_i = kb (w(u_i+) - w(u_i-)),  u_i+ = (q_i - (upper_i - band)) / band,
                                             u_i- = ((lower_i + band) - q_i) / band,

w the quintic smoothstep (0 outside the band, 1 at the limit and beyond), kb =
`barrier_torque` (N m). It enters the law as a task of its own: the torque gets -g and the
task-space reference velocity -J+^T g / Kp (adaptive_law), so that with

    V = 1/2 s^T M s + Kp a Q + B + 1/2 dtheta^T L^-1 dtheta

eq. 22 becomes dV/dt = -s^T (Ks + F) s - Kp |a delta_eps + J+^T g / Kp|^2 + Kp (da/dt) Q
(+ the terms of the hand's motion below). At rest (s = 0) the arm stops where the task's
force J^T Kp a delta_eps and the barrier's g balance; the torque there, -J^T Kp a delta_eps
- g, is zero. kb = 3 N m is above the largest task torque J^T Kp (1 + CAP_BAND) v_max (at
most 1.95 N m on joint 1, 0.9 N m on joint 2 with the default gains), so the balance lies
inside the band, before the stop.

Feed-forward gate
-----------------
The hand's velocity enters qdot_r as J+ xdot_d (eq. 14); a hand moving where the arm cannot
follow would drive the joint into its stop at the hand's speed. Within the band each joint's
feed-forward component towards the limit is scaled by 1 - w(u) S(v / FEED_SPEED) (S the
quintic smoothstep of the component's speed, so the gate is C1 in the velocity), leaving
motion away from the limit alone. This adds to dV/dt the terms Kp a delta_eps^T J dff +
g^T ff', bounded by the hand's speed, zero for a still hand (as the dropped feed-forward of
an avoid task adds -Kp a delta_eps^T xdot_d).

Reach-round
-----------
Where the straight task-space descent is blocked (the segment from the arm to its goal passes
through the hole round the base, a joint sits in its band while the goal is far, or the hand
is out of reach), a joint-space motion towards an inverse-kinematics solution q* of the
goal is blended in with a weight sigma (eq. 13's C2 ramp, event_weight):

    qdot_r = (1 - sigma) qdot_r,task + sigma u,   u = dq_f/dt - cap(k (q - q_f)),

q_f following q* through a slew limit and a critically damped second-order filter (q_f,
d2q_f/dt2 continuous, so u's exact time derivative d2q_f/dt2 - Dcap k (qdot - dq_f/dt) is
continuous and the torque does not step). The goal is the hand's nearest reachable point
(follow tasks) or the point of the region's annulus towards the arm (d1 > 0), projected onto
the reachable
annulus and into the joint box (q* clamped GOAL_MARGIN band inside the limits: the
joint-space straight line stays in the convex box, away from every stop). The task's force
is weighted (1 - sigma) with its Q in V; the joint motion needs no force of its own (V's
s-term converges s, and qdot = qdot_r then moves q to q_f). While sigma ramps, V
gains sigma-rate terms like eq. 22's (da/dt) Q, bounded and over a finite time.
Avoid tasks (open outward) never reach round: they move away from the hand.

Joint speed limit
-----------------
The barrier's push is small (kb, v_B) and acts only within the band: a reference that asks a
joint for more (the task's J+ near the stretched arm, the person's barrier J+ J+^T g_B / Kp
with many pairs close) ran the Panda's joint 2 into its stop at up to 15-22 rad/s. So the
reference, last of all its terms, is held twice, with its exact rate (joint_speed_limit):

- as a whole (its direction kept) within the joint velocity limits V_i: with rho the smooth
  maximum (sum_i |qdot_r,i / V'_i|^p)^(1/p), p = SPEED_NORM, V'_i = speed_scale V_i / (1 +
  CAP_BAND), qdot_r is scaled by cap(rho) / rho (task_variable.speed_cap at 1), so that no
  joint is asked for more than speed_scale V_i;
- per joint towards each limit at b = k (d - STOP_SHARE band), d the distance to that limit
  (k = stop_rate), softly: b + beta tanh((v - b) / beta) above b, beta = STOP_SOFTNESS k band
  (C2 at b): a velocity damper. The reference closes on the stop at most exponentially at
  rate k, asking a deceleration of at most k V_i, which the drives can give, and it rests
  (STOP_SHARE - STOP_SOFTNESS) band off the limit where something insists on going further.

Both only lower |qdot_r| (the damper also turns it round within STOP_SHARE band); far from
the limits and below the speed limit qdot_r is unchanged. Where they act, eq. 22 gains the
terms of the reference's change, as with the feed-forward gate.
"""

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from hri_adaptive_controller.event_weight import EventWeightSchedule, quintic_smoothstep_array
from hri_adaptive_controller.task_variable import SECH_LIMIT, speed_cap

GOAL_MARGIN = 0.5
"""The joint goal q* is kept GOAL_MARGIN band inside the limits (where the barrier's weight is
1/2: its force there is below the task's largest)."""

CLAMP_COST = 1000.0
"""Weight of the joint-box clamping against the joint distance when choosing an elbow."""

IK_ITERATIONS = 50
"""Damped least-squares steps of inverse_kinematics_n from each seed."""

IK_DAMPING = 0.05
"""m: the damping of inverse_kinematics_n's steps."""

IK_TOLERANCE = 1e-3
"""m: inverse_kinematics_n stops a seed's iterations this near the goal."""

FEED_SPEED = 0.05
"""rad/s: the feed-forward gate's speed scale (the gate acts fully above it)."""
PUSH_SCALE = 0.1
"""N m: the same gate's scale for the person's barrier torque in the joint bands."""

SPEED_NORM = 8
"""The power p of the joint speed limit's smooth maximum (sum_i |v_i / V_i|^p)^(1/p): at most
7^(1/8) = 1.28 times the largest |v_i / V_i| for seven joints."""

STOP_SHARE = 0.25
"""The stop damper's bound reaches zero this share of the barrier's band inside a limit."""

STOP_SOFTNESS = 0.1
"""The stop damper's soft band (rad/s) as a share of stop_rate band: the bound is exceeded by
less than that (the reference's own rest lies STOP_SOFTNESS band further out)."""


@dataclass(frozen=True)
class ReachRoundSettings:
    """The reach-round blend (module docstring).

    gain k (1/s) and max_speed (rad/s) of the joint motion u; blend_time (s): a full ramp of
    sigma; filter_rate omega (1/s) and slew (rad/s) of q_f; outer_margin (m): the goal is kept
    this far inside the stretched reach; inner_margin (m): and this far outside the folded
    reach; enabled: False leaves sigma at 0.
    """

    gain: float = 4.0
    max_speed: float = 1.0
    blend_time: float = 0.5
    filter_rate: float = 8.0
    slew: float = 1.0
    outer_margin: float = 0.03
    inner_margin: float = 0.01
    enabled: bool = True

    def __post_init__(self):
        for name in ('gain', 'max_speed', 'blend_time', 'filter_rate', 'slew'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'reach-round {name} must be finite and > 0, got {value}')
        for name in ('outer_margin', 'inner_margin'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'reach-round {name} must be finite and >= 0 m, got {value}')


def barrier(q, dq, lower, upper, band: float, barrier_torque: float):
    """The barrier's gradient g = dB/dq (n,) N m, its time derivative (n,) N m/s (the
    diagonal Hessian times qdot) and its proximity near = max_i w(u_i) in [0, 1] (0 outside
    every band, 1 at a limit). q, dq, lower, upper (n,) rad, rad/s; band rad; barrier_torque
    kb N m."""
    if (q >= lower + band).all() and (q <= upper - band).all():
        zero = np.zeros(q.shape)
        return zero, zero, 0.0  # outside every band (the usual case)
    up, dup = quintic_smoothstep_array((q - (upper - band)) / band)
    down, ddown = quintic_smoothstep_array(((lower + band) - q) / band)
    g = barrier_torque * (up - down)
    gd = barrier_torque * (dup + ddown) / band * dq
    return g, gd, float(max(up.max(), down.max()))


def barrier_energy(q, lower, upper, band: float, barrier_torque: float) -> float:
    """B(q) (J) of `barrier`: kb band times the smoothstep's integral over each overlap."""
    total = 0.0
    for u in np.concatenate([(q - (upper - band)) / band, ((lower + band) - q) / band]):
        if u > 0.0:
            v = min(u, 1.0)
            total += barrier_torque * band * (2.5 * v ** 4 - 3.0 * v ** 5 + v ** 6
                                              + max(u - 1.0, 0.0))
    return total


def gate_feed_forward(q, dq, v, rate, lower, upper, band: float, scale: float = FEED_SPEED):
    """The joint feed-forward v (n,) rad/s and its rate (n,) rad/s^2 with each component
    towards a near limit faded out (module docstring); scale: the size of v (its unit) over
    which its sign's smooth switch runs. Also the person's barrier torque -g (N m, scale
    PUSH_SCALE): it pushes no joint into its stop within the joint's band."""
    up, dup = quintic_smoothstep_array((q - (upper - band)) / band)
    down, ddown = quintic_smoothstep_array(((lower + band) - q) / band)
    towards_up, dtu = quintic_smoothstep_array(v / scale)
    towards_down, dtd = quintic_smoothstep_array(-v / scale)
    factor = 1.0 - up * towards_up - down * towards_down
    factor_rate = (-(dup / band * dq) * towards_up - up * dtu / scale * rate
                   + (ddown / band * dq) * towards_down + down * dtd / scale * rate)
    return v * factor, rate * factor + v * factor_rate


def joint_speed_limit(q, dq, qdot_r, qddot_r, lower, upper, speed, stop_rate: float,
                      band: float):
    """The reference joint motion qdot_r, qddot_r (n,) held within what the arm can stop from
    (module docstring, Joint speed limit), with its exact rate; and whether it changed.

    q, dq (n,) rad, rad/s; lower, upper (n,) rad; speed (n,) rad/s: V_i, where the smooth cap
    of the whole vector starts (inf: none for that joint); stop_rate k (1/s) and band (rad)
    of the stop damper. The numpy reference of arm_kernels.joint_speed_limit."""
    ratio = qdot_r / speed
    ratio_rate = qddot_r / speed
    largest = float(np.max(np.abs(ratio)))
    changed = False
    if largest > 0.0:
        # rho = (sum |r_i|^p)^(1/p), taken as largest (sum |r_i / largest|^p)^(1/p).
        scaled = ratio / largest
        rho = largest * float(np.sum(scaled ** SPEED_NORM)) ** (1.0 / SPEED_NORM)
        if rho > 1.0:
            capped, slope = speed_cap(rho, 1.0)
            rho_rate = float(np.sum((ratio / rho) ** (SPEED_NORM - 1) * ratio_rate))
            scale = capped / rho
            scale_rate = (slope * rho - capped) / (rho * rho) * rho_rate
            qddot_r = scale * qddot_r + scale_rate * qdot_r
            qdot_r = scale * qdot_r
            changed = True
    # The stop damper: towards upper, v <= b = k (upper - q - STOP_SHARE band), softly:
    # b + beta tanh((v - b) / beta) above b (C2 at b); towards lower, mirrored.
    softness = STOP_SOFTNESS * stop_rate * band
    stop = STOP_SHARE * band
    up = stop_rate * (upper - q - stop)
    down = stop_rate * (q - lower - stop)
    over_up = qdot_r > up
    over_down = -qdot_r > down
    if over_up.any() or over_down.any():
        bound = np.where(over_up, up, -down)  # the bound crossed, signed as v
        bound_rate = -stop_rate * dq  # d(up)/dt, and d(-down)/dt
        excess = (qdot_r - bound) / softness
        slope = 1.0 / np.cosh(np.minimum(np.abs(excess), SECH_LIMIT)) ** 2
        held = over_up | over_down
        qddot_r = np.where(held, slope * qddot_r + (1.0 - slope) * bound_rate, qddot_r)
        qdot_r = np.where(held, bound + softness * np.tanh(excess), qdot_r)
        changed = True
    return qdot_r, qddot_r, changed


def workspace_radii(l1: float, l2: float, limits) -> tuple[float, float]:
    """(folded, stretched) reach (m) of a planar 2-link arm: the base-to-tip distance at
    joint 2's nearer limit (or |l1 - l2| when joint 2 may fold fully) and l1 + l2. limits:
    lower and upper (2,) rad (hri_core.robot_model.JointLimits)."""
    fold = min(abs(limits.lower[1]), abs(limits.upper[1]), math.pi)
    return math.sqrt(max(l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * math.cos(fold), 0.0)), l1 + l2


def inverse_kinematics(x1: float, x2: float, near1: float, near2: float, l1: float, l2: float,
                       lower, upper, band: float) -> tuple[float, float]:
    """Joint angles (rad) of a planar 2-link arm that put the tip at (x1, x2) m or nearest to
    it, clamped GOAL_MARGIN band inside the limits lower, upper (2,) rad; of the two elbows,
    the one the box cuts least, then the one nearer to (near1, near2)."""
    r2 = x1 * x1 + x2 * x2
    c2 = (r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    c2 = min(max(c2, -1.0), 1.0)
    margin = GOAL_MARGIN * band
    best_cost, best1, best2 = math.inf, 0.0, 0.0
    for elbow in (1.0, -1.0):
        q2 = elbow * math.acos(c2)
        q1 = math.atan2(x2, x1) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
        # In [-pi, pi]: the nearest writing to a box centred on 0 (atan2, not math.remainder:
        # numba compiles this function, arm_kernels.planar_inverse_kinematics).
        q1 = math.atan2(math.sin(q1), math.cos(q1))
        k1 = min(max(q1, lower[0] + margin), upper[0] - margin)
        k2 = min(max(q2, lower[1] + margin), upper[1] - margin)
        # A solution the box cuts short misses the point: the one that reaches first.
        cost = (CLAMP_COST * ((k1 - q1) ** 2 + (k2 - q2) ** 2)
                + (k1 - near1) ** 2 + (k2 - near2) ** 2)
        if elbow == 1.0 or cost < best_cost:  # (the first kept: a NaN stays a NaN)
            best_cost, best1, best2 = cost, k1, k2
    return best1, best2


def _segment_clearance(x1: float, x2: float, y1: float, y2: float) -> float:
    """Distance (m) from the base (0, 0) to the segment from x to y."""
    d1, d2 = y1 - x1, y2 - x2
    length2 = d1 * d1 + d2 * d2
    t = 0.0 if length2 == 0.0 else min(max(-(x1 * d1 + x2 * d2) / length2, 0.0), 1.0)
    return math.hypot(x1 + t * d1, x2 + t * d2)


class _JointBlend:
    """The reach-round blend's state, for any number of joints: sigma's ramp (with a dwell
    between switches), the slewed and filtered joint goal q_f and the joint motion u
    (module docstring). PlanarReachRound (the SCARA) and ReachRoundN (n joints) decide when
    to blend and where to; `_blend` does the rest, its joint motion through joint_motion
    (compiled: arm_kernels.joint_motion, the same function through numba). `reset` forgets
    the state (the joint goal restarts from the arm's joints at the next update)."""

    NEAR_BARRIER = 0.03  # barrier proximity above which a far goal counts as blocked
    FAR_GOAL = 0.06  # m from the goal: far

    def __init__(self, settings: ReachRoundSettings, compiled: bool = False):
        self.settings = settings
        self._kernels = None  # arm_kernels where compiled
        self._motion = joint_motion
        if compiled:  # imported here: arm_kernels imports this module
            from hri_adaptive_controller import arm_kernels
            self._kernels = arm_kernels
            self._motion = arm_kernels.joint_motion
        self.reset()

    def reset(self) -> None:
        self._time = 0.0
        self._schedule = EventWeightSchedule(self.settings.blend_time)
        self._engaged = False
        self._switched = -math.inf  # time of the last switch
        self._resting = True  # sigma is 0 with no ramp to evaluate
        self._full = False  # sigma is 1 with no ramp to evaluate
        self._filtered = None  # (q_in, q_f, dq_f), arrays (n,)

    @property
    def engaged(self) -> bool:
        """Whether the blend is heading to (or at) the joint-space motion."""
        return self._engaged

    def _blend(self, wanted: bool, joint_goal, q, dq, dt: float):
        """Advance by dt (s) towards `wanted` and return (sigma, dsigma/dt, u, du/dt) with u
        and du/dt arrays (n,), or None while sigma rests at 0. joint_goal: a callable giving
        the joint goal q* (an array (n,), rad), or None to hold q_in where it is; q, dq the
        joints (arrays (n,) of floats)."""
        settings = self.settings
        self._time += dt
        now = self._time
        if wanted != self._engaged and now - self._switched < 0.5 * settings.blend_time:
            wanted = self._engaged  # a dwell: the blend's ramps do not pile up
        if wanted != self._engaged:
            self._engaged, self._switched = wanted, now
            self._schedule.request('round' if wanted else None, now)
            self._resting = self._full = False
        elif self._resting:  # sigma at 0 and staying there: nothing to evaluate
            return None
        if self._engaged and self._full:  # sigma at 1 and staying there
            sigma, sigma_rate = 1.0, 0.0
        else:
            weight = self._schedule.evaluate(now)
            sigma, sigma_rate = weight.weight, weight.rate
            self._full = self._engaged and sigma == 1.0 and sigma_rate == 0.0
        if sigma == 0.0 and sigma_rate == 0.0 and not wanted:
            self._filtered = None
            self._resting = True
            return None
        if self._filtered is None:
            self._filtered = (q.copy(), q.copy(), np.zeros(q.size))
        has_goal = joint_goal is not None
        goal = joint_goal() if has_goal else self._filtered[0]
        q_in, filtered, rate, u, du = self._motion(
            goal, has_goal, *self._filtered, q, dq, dt, settings.slew, settings.filter_rate,
            settings.gain, settings.max_speed)
        self._filtered = (q_in, filtered, rate)
        return sigma, sigma_rate, u, du


def joint_motion(goal, has_goal, q_in, filtered, rate, q, dq, dt, slew, filter_rate, gain,
                 max_speed):
    """One step of the reach-round's joint motion (module docstring), for n joints: q_in
    slewed towards the joint goal (n,) rad at `slew` rad/s (left where it is unless
    has_goal), q_f (`filtered`, rad) and dq_f/dt (`rate`, rad/s) advanced by dt (s) through a
    critically damped second-order filter of rate `filter_rate` (1/s; semi-implicit Euler: its
    acceleration is continuous, as q_in is, so the feed-forward of dq_f steps nothing), and
    u = dq_f/dt - cap(gain e) (rad/s; e = q - q_f, the cap smooth in |e|: max_speed tanh) with
    its exact time derivative du/dt (rad/s^2). Arrays (n,) of floats in and out: returns
    (q_in, q_f, dq_f/dt, u, du/dt), new arrays. Plain loops, so that numba compiles the same
    function (arm_kernels.joint_motion, the controller's; this one is its reference)."""
    n = q.shape[0]
    q_in_out, filtered_out, rate_out = np.empty(n), np.empty(n), np.empty(n)
    acc, e, de = np.empty(n), np.empty(n), np.empty(n)
    step = slew * dt
    stiffness, damping = filter_rate * filter_rate, 2.0 * filter_rate
    norm2 = 0.0
    along = 0.0
    for i in range(n):
        value = q_in[i]
        if has_goal:
            value += min(max(goal[i] - value, -step), step)
        a = stiffness * (value - filtered[i]) - damping * rate[i]
        df = rate[i] + dt * a
        q_in_out[i], acc[i], rate_out[i] = value, a, df
        filtered_out[i] = filtered[i] + dt * df
        e[i] = q[i] - filtered_out[i]
        de[i] = dq[i] - df
        norm2 += e[i] * e[i]
        along += e[i] * de[i]
    u, du = np.empty(n), np.empty(n)
    norm = math.sqrt(norm2)
    raw = gain * norm
    if raw <= 1e-12:
        for i in range(n):
            u[i] = rate_out[i] - gain * e[i]
            du[i] = acc[i] - gain * de[i]
        return q_in_out, filtered_out, rate_out, u, du
    capped = max_speed * math.tanh(raw / max_speed)
    # d capped / d norm; sech^2 is 0 in double precision long before cosh overflows (a state
    # far from its filtered goal, as when a simulated xArm7 diverged, raised OverflowError:
    # no torque).
    slope = 0.0 if raw > SECH_LIMIT * max_speed else gain / math.cosh(raw / max_speed) ** 2
    scale = capped / norm  # u = -scale e
    dscale = (slope - scale) / norm * (along / norm)  # along / norm: d |e| / dt
    for i in range(n):
        u[i] = rate_out[i] - scale * e[i]
        du[i] = acc[i] - (scale * de[i] + dscale * e[i])
    return q_in_out, filtered_out, rate_out, u, du


class PlanarReachRound(_JointBlend):
    """The reach-round blend of a planar 2-link arm (the SCARA): when and where to (module
    docstring), with the hole round its base and its elbow choice (inverse_kinematics).

    model: a planar RobotModel with link_lengths (l1, l2) m; lower, upper (2,) rad; band
    (rad): the barrier's; reach (m): unused (the annulus comes from the link lengths and
    joint 2's limits); compiled: _JointBlend's. `update` runs once per control step with its
    dt.
    """

    BLOCKED_CLEARANCE = 0.02  # m beyond the folded reach: the straight path is blocked
    CLEAR_CLEARANCE = 0.06  # m beyond it: clear again (hysteresis)
    STRAIGHT_TURN = 1.0  # rad of joint 1 the straight descent is trusted with
    STRETCHED = 0.5  # rad of joint 2: nearer the stretched arm (J+ damped), stay in joint space

    def __init__(self, settings: ReachRoundSettings, model, lower, upper, band: float,
                 reach: float, compiled: bool = False):
        self._l1, self._l2 = model.link_lengths
        self._lower, self._upper = tuple(map(float, lower)), tuple(map(float, upper))
        self._band = band
        self._inner, self._outer = workspace_radii(
            self._l1, self._l2, _Box(self._lower, self._upper))
        super().__init__(settings, compiled)
        self._inverse_kinematics = inverse_kinematics
        if self._kernels is not None:
            self._inverse_kinematics = self._kernels.planar_inverse_kinematics
            self._solve(self._outer, 0.0, 0.0, 0.0)  # compiled (or loaded) now, not mid-task

    def _solve(self, g1: float, g2: float, q1: float, q2: float) -> tuple[float, float]:
        return self._inverse_kinematics(g1, g2, q1, q2, self._l1, self._l2, self._lower,
                                        self._upper, self._band)

    def goal(self, x1: float, x2: float, h1: float, h2: float, d1: float, d2: float):
        """The task-space goal (m): the hand h (d1 = 0) or the point of the region's annulus
        towards the arm x, projected onto the reachable annulus."""
        g1, g2 = h1, h2
        if d1 > 0.0:
            e1, e2 = x1 - h1, x2 - h2
            norm = math.hypot(e1, e2)
            if norm > 0.0:
                middle = 0.5 * (d1 + min(d2, d1 + 0.2))
                g1, g2 = h1 + middle * e1 / norm, h2 + middle * e2 / norm
        radius = math.hypot(g1, g2)
        low = self._inner + self.settings.inner_margin
        high = self._outer - self.settings.outer_margin
        if radius > high:
            g1, g2 = g1 * high / radius, g2 * high / radius
        elif radius < low:
            if radius > 1e-9:
                g1, g2 = g1 * low / radius, g2 * low / radius
            else:  # the hand over the base: the point of the inner circle towards the arm
                norm = math.hypot(x1, x2) or 1.0
                g1, g2 = x1 * low / norm, x2 * low / norm
        return g1, g2, radius

    def update(self, q, dq, x, hand, region, near: float, dt: float):
        """Advance by dt (s) and return (sigma, dsigma/dt, u (2,), du/dt (2,)) or None while
        sigma rests at 0. q, dq (2,); x, hand (2,) m: the tip and the target; region (d1, d2)
        m of a follow task, or None (no task, or an avoid task: sigma fades to 0); near: the
        barrier's proximity (barrier())."""
        settings = self.settings
        (q1, q2), (x1, x2) = q.tolist(), x.tolist()
        target = None  # the joint goal, when worked out for the decision below
        if not settings.enabled or region is None:
            wanted = False
            goal = None
        else:
            g1, g2, hand_radius = self.goal(x1, x2, float(hand[0]), float(hand[1]), *region)
            clearance = _segment_clearance(x1, x2, g1, g2)
            distance = math.hypot(g1 - x1, g2 - x2)
            # The whole region out of reach: beyond the stretched arm or inside the hole.
            outside = (hand_radius - region[1] > self._outer - settings.outer_margin
                       or hand_radius + region[1] < self._inner + settings.inner_margin)
            if self._engaged:
                # Stay on the joint-space motion until the arm is at the goal or the straight
                # descent would get there: the path clear of the hole, no joint near a limit,
                # the goal on the arm's elbow and within STRAIGHT_TURN of its joint 1, the arm
                # off the stretched singularity (leaving earlier hands the arm back to the
                # descent that was blocked).
                t1, t2 = self._solve(g1, g2, q1, q2)
                target = (t1, t2)
                straight = (clearance >= self._inner + self.CLEAR_CLEARANCE
                            and near < 0.5 * self.NEAR_BARRIER and t2 * q2 > 0.0
                            and abs(t1 - q1) < self.STRAIGHT_TURN
                            and abs(q2) > self.STRETCHED)
                wanted = (outside or clearance < self._inner + self.BLOCKED_CLEARANCE
                          or (distance > 0.5 * self.FAR_GOAL and not straight))
            else:
                wanted = (clearance < self._inner + self.BLOCKED_CLEARANCE
                          or (near > self.NEAR_BARRIER and distance > self.FAR_GOAL)
                          or outside)
            goal = (g1, g2)
        if goal is None:
            joint_goal = None
        elif target is not None:
            def joint_goal():
                return np.array(target)
        else:
            def joint_goal():
                return np.array(self._solve(goal[0], goal[1], q1, q2))
        return self._blend(wanted, joint_goal, q, dq, dt)


class _Box(NamedTuple):
    lower: tuple[float, ...]
    upper: tuple[float, ...]


def inverse_kinematics_n(model, goal, seeds, lower, upper, iterations: int = IK_ITERATIONS):
    """Joints (n,) rad that put `model`'s tool point at `goal` (3,) m or nearest to it, within
    the box [lower, upper] (n,) rad: damped least squares from each seed (rows of `seeds`,
    (k, n)), clamped into the box at every step; of the results, the one that reaches the
    goal best (CLAMP_COST per m^2 of miss), then the one nearest to the first seed (the
    arm's joints). model: a RobotModel (tool_position, tool_jacobian)."""
    best = None
    first = seeds[0]
    for seed in seeds:
        q = np.clip(seed, lower, upper)
        for _ in range(iterations):
            miss = goal - model.tool_position(q)
            if float(miss @ miss) < IK_TOLERANCE ** 2:
                break
            jac = model.tool_jacobian(q)
            step = jac.T @ np.linalg.solve(jac @ jac.T + IK_DAMPING ** 2 * np.eye(3), miss)
            q = np.clip(q + step, lower, upper)
        miss = goal - model.tool_position(q)
        cost = CLAMP_COST * float(miss @ miss) + float((q - first) @ (q - first))
        if best is None or cost < best[0]:
            best = (cost, q)
    return best[1]


class ReachRoundN(_JointBlend):
    """The reach-round blend for an arm of n joints in 3-D (arm_law.ArmController).

    As ReachRound's, with the model's own inverse kinematics (inverse_kinematics_n) and no
    hole round the base: the blend engages when a joint is in its barrier's band
    (near > NEAR_BARRIER) while the goal is more than FAR_GOAL away, or the whole region lies
    beyond the reach; once engaged, it stays until the tool is within FAR_GOAL / 2 of the
    goal and the joint goal lies CLEAR_BANDS band inside its box (the straight descent, which
    stalled, is not trusted again before). The joint goal is kept a whole band inside the
    limits (the barrier off there), and so is the arm while it holds it. The goal is the
    hand, or the middle of the region's shell towards the arm (d1 > 0), projected into the
    sphere of the attained reach round the shoulder (less outer_margin). The joint goal q*
    is solved on engaging from the arm's joints, from its home pose swung to the goal's
    azimuth about the first joint (for a vertical first axis, the Panda's: a far side
    reached by turning round) and from the arm's joints so swung, the nearest that reaches
    (1.3 ms for the Panda's hand behind its base, 2.6 ms for one out of reach, once); then
    refreshed every IK_PERIOD s from the last q* (IK_REFRESH iterations), so the numerical
    solve stays off most control cycles.

    model: a RobotModel (tool_position, tool_jacobian, home, shoulder); lower, upper (n,)
    rad; band (rad): the barrier's; reach (m): the attained reach round the shoulder;
    compiled: _JointBlend's.
    """

    IK_PERIOD = 0.02  # s between refreshes of the joint goal while engaged
    IK_REFRESH = 5  # iterations of each refresh, from the last joint goal
    CLEAR_BANDS = 0.5  # a joint goal this many bands inside the box hands back to the descent

    def __init__(self, settings: ReachRoundSettings, model, lower, upper, band: float,
                 reach: float, compiled: bool = False):
        self._model, self._band = model, band
        # q* outside the barrier's band (not GOAL_MARGIN band in, as the SCARA's): there the
        # descent, handed the arm back at the goal, is not blocked again (with half a band,
        # the Panda reaching behind its base cycled between the two every 2 s).
        self._box = (np.asarray(lower, dtype=float) + band,
                     np.asarray(upper, dtype=float) - band)
        self._shoulder = np.asarray(model.shoulder, dtype=float)
        self._shoulder_point = tuple(self._shoulder.tolist())
        self._outer = float(reach)
        home = np.clip(model.home, *self._box)
        arm = model.tool_position(home) - self._shoulder
        self._home, self._home_azimuth = home, math.atan2(arm[1], arm[0])
        super().__init__(settings, compiled)

    def reset(self) -> None:
        super().reset()
        self._joint_goal = None  # (time solved, q* (n,))

    def goal(self, x, hand, d1: float, d2: float):
        """The task-space goal (3,) m (the class docstring) and the hand's distance from the
        shoulder (m)."""
        goal = np.array(hand, dtype=float)
        if d1 > 0.0:
            away = x - goal
            norm = math.sqrt(float(away @ away))
            if norm > 0.0:
                goal = goal + 0.5 * (d1 + min(d2, d1 + 0.2)) * away / norm
        radius = float(np.linalg.norm(np.asarray(hand, dtype=float) - self._shoulder))
        arm = goal - self._shoulder
        length = math.sqrt(float(arm @ arm))
        high = self._outer - self.settings.outer_margin
        if length > high:
            goal = self._shoulder + arm * (high / length)
        return goal, radius

    def _solve(self, goal, q, x) -> np.ndarray:
        """q* for `goal` (3,) m from the seeds of the class docstring; q (n,) the arm's
        joints, x (3,) m its tool."""
        arm, tool = goal - self._shoulder, x - self._shoulder
        azimuth = math.atan2(arm[1], arm[0])
        swung_home, swung_arm = self._home.copy(), np.array(q, dtype=float)
        swung_home[0] = math.remainder(self._home[0] + azimuth - self._home_azimuth,
                                        2.0 * math.pi)
        swung_arm[0] += math.remainder(azimuth - math.atan2(tool[1], tool[0]), 2.0 * math.pi)
        return inverse_kinematics_n(self._model, goal, np.array([q, swung_home, swung_arm]),
                                    *self._box)

    def update(self, q, dq, x, hand, region, near: float, dt: float):
        """Advance by dt (s) and return (sigma, dsigma/dt, u (n,), du/dt (n,)) or None while
        sigma rests at 0. q, dq (n,); x, hand (3,) m: the tool and the target; region (d1, d2)
        m of a follow task, or None (no task, or an avoid task: sigma fades to 0); near: the
        barrier's proximity (joint_limits.barrier)."""
        settings = self.settings
        joint_goal = None
        if self._resting and (region is None or not settings.enabled or (
                near <= self.NEAR_BARRIER and math.dist(hand, self._shoulder_point) - region[1]
                <= self._outer - settings.outer_margin)):
            self._time += dt  # resting and nothing to engage it (the usual case): as _blend
            return None
        if not settings.enabled or region is None:
            wanted = False
        else:
            goal, hand_radius = self.goal(x, hand, *region)
            miss = goal - x
            distance = math.sqrt(float(miss @ miss))
            outside = hand_radius - region[1] > self._outer - settings.outer_margin
            if self._engaged:
                # Stay on the joint-space motion until the tool is at the goal with its joint
                # goal clear of the limits (CLEAR_BANDS band beyond the barrier's): the
                # descent handed a pose at the band's edge drifts into it and its push
                # takes the tool off the goal again.
                wanted = (outside or distance > 0.5 * self.FAR_GOAL
                          or not self._clear(self._joint_goal))
            else:
                wanted = (near > self.NEAR_BARRIER and distance > self.FAR_GOAL) or outside
            if wanted:
                def joint_goal():
                    return self._refresh(goal, q, x)
            else:
                self._joint_goal = None
        return self._blend(wanted, joint_goal, q, dq, dt)

    def _clear(self, joint_goal) -> bool:
        """Whether the joint goal (time, q*) lies CLEAR_BANDS band inside the box."""
        if joint_goal is None:
            return False
        q, (low, high) = joint_goal[1], self._box
        margin = self.CLEAR_BANDS * self._band
        return bool(np.all(q >= low + margin) and np.all(q <= high - margin))

    def _refresh(self, goal, q, x) -> np.ndarray:
        """The joint goal q*: solved afresh on engaging, refreshed every IK_PERIOD s."""
        now = self._time
        if self._joint_goal is None:
            self._joint_goal = (now, self._solve(goal, q, x))
        elif now - self._joint_goal[0] >= self.IK_PERIOD:
            last = self._joint_goal[1]
            self._joint_goal = (now, inverse_kinematics_n(
                self._model, goal, last[None, :], *self._box, self.IK_REFRESH))
        return self._joint_goal[1]


def reach_round(settings: ReachRoundSettings, model, lower, upper, band: float,
                reach: float, compiled: bool = False) -> _JointBlend:
    """The reach-round blend for `model`: a planar 2-link arm (task_axes 2, link_lengths) gets
    PlanarReachRound (its hole round the base, its two elbows), any other ReachRoundN (the
    model's numerical inverse kinematics). Arguments as theirs; compiled: the per-cycle
    arithmetic through arm_kernels (numba), as ArmController's."""
    if model.task_axes == 2 and getattr(model, 'link_lengths', None) is not None:
        return PlanarReachRound(settings, model, lower, upper, band, reach, compiled)
    return ReachRoundN(settings, model, lower, upper, band, reach, compiled)
