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
Avoid tasks (open outward) never reach round: they move away from the hand. Beside a person
(ReachRound.keep_off, set by the caller) q* also keeps every robot-person pair out of the
person's clearance (clearance_inverse_kinematics: the pairs as a second damped least-squares
task), and the caller may slow the joint motion (ReachRound.speed_scale).

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

import numpy as np

from hri_adaptive_controller.event_weight import EventWeightSchedule, quintic_smoothstep_array
from hri_adaptive_controller.task_variable import SECH_LIMIT, norm_cap, speed_cap
from hri_core.robot_model import CLAMP_COST, IK_DAMPING, IK_TOLERANCE
from hri_core.robot_model import IK_ITERATIONS as MODEL_IK_ITERATIONS

GOAL_RATE_STEP = 0.01
"""s: the reach-round's goal velocity is its change for the hand moved on this long at its
velocity (a hand's one frame at 100 Hz; the goal is piecewise smooth in the hand)."""
GOAL_RATE_TIME = 0.05
"""s: the time constant of the first-order filter through which the reach-round's goal
velocity is fed forward."""
GOAL_MARGIN = 1.0
"""The joint goal q* is kept GOAL_MARGIN band inside the limits: the barrier is off there, so
an arm holding q* is not pushed off it (with half a band the Panda, behind its base, ended
0.04 m nearer a person's trunk: docs/design.md)."""
CLEAR_BANDS = 0.5
"""The reach-round hands back at the goal only with its joint goal this many bands inside its
box (ReachRound)."""
IK_CLEARANCE_WEIGHT = 10.0
"""The clearance rows' weight against the goal's in clearance_inverse_kinematics (1: a metre
of shortfall costs as a metre of miss)."""
IK_SETTLED = 1e-4
"""rad: a clearance_inverse_kinematics step this short ends its seed's iterations (a pose
the clearance holds short of its goal)."""
IK_TRAVEL_COST = 10.0
"""Per rad^2 of a clearance_inverse_kinematics result's distance from the first seed (the
arm's joints), against CLAMP_COST per m^2 of its miss and shortfall: a turn round the base
(about 10 rad^2) is taken for 0.3 m nearer the goal, not 0.1 m (at 1 the Panda beside
HumanRobotHandover_0, turned by 91 deg, swung away round its base from a hand 0.35 m off)."""
IK_STEP = 0.2
"""rad: the largest joint step of one clearance_inverse_kinematics iteration (a pair's
normal turns as the links move: a longer step overshoots)."""

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


def redirected_push(gradient, rate, gated, gated_rate, most: float):
    """The person's barrier gradient g (n,) N m and its rate as the reference pushes with it
    once gate_feed_forward has faded the share of the joints within their bands towards
    their stops (gated, gated_rate): the gated push scaled by r = (g . g) / (g . gated), so
    that it moves the arm off the person as fast as the whole push would, along the joints
    still free (g lies along the close pairs' rows n^T J_p: a single pair's distance changes
    at r times the gated push's rate), r capped smoothly at `most`; and its rate. Why: the
    SCARA's link 2, pushed off a person's torso, folded joint 2 into its band, where the
    push kept only joint 1's small share (0.3 of 1.3 N m) and the arm turned away at under
    1 rad/s while the torso closed in (docs/benchmarks.md)."""
    whole = float(gradient @ gradient)
    kept = float(gradient @ gated)
    if kept <= 1e-12 * whole or kept >= whole:
        return gated, gated_rate
    ratio = whole / kept
    ratio_rate = (2.0 * float(gradient @ rate) * kept
                  - whole * (float(rate @ gated) + float(gradient @ gated_rate))) / (kept * kept)
    scale, slope = speed_cap(ratio, most)
    return scale * gated, scale * gated_rate + (slope * ratio_rate) * gated


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


def reach_goal(tool, hand, d1: float, d2: float, centre, high: float, low: float):
    """The reach-round's task-space goal and what its decisions measure (ReachRound), for k
    task axes: the hand (d1 = 0) or the point of the region's shell towards the tool, d1 +
    (min(d2, d1 + 0.2) - d1) / 2 from the hand, moved into the shell round `centre` between
    `low` and `high` (m; the goal on the hand's ray, or towards the tool for a hand at the
    centre). tool, hand, centre (k,) m. Returns (goal (k,) m, its distance from the tool,
    its distance from the centre before it was moved into the shell, the centre's from the
    segment tool-goal), all m. Plain loops, so that numba compiles the same function
    (arm_kernels.reach_goal, the controller's)."""
    k = tool.shape[0]
    goal = np.empty(k)
    away2 = 0.0
    for i in range(k):
        goal[i] = hand[i]
        away2 += (tool[i] - hand[i]) ** 2
    if d1 > 0.0 and away2 > 0.0:
        scale = 0.5 * (d1 + min(d2, d1 + 0.2)) / math.sqrt(away2)
        for i in range(k):
            goal[i] += scale * (tool[i] - hand[i])
    length2 = 0.0
    for i in range(k):
        length2 += (goal[i] - centre[i]) ** 2
    length = math.sqrt(length2)
    unmoved = length
    if length > high or length < low:
        radius = high if length > high else low
        if length <= 1e-9:  # at the centre: the shell's point towards the tool
            tool2 = 0.0
            for i in range(k):
                goal[i] = tool[i]
                tool2 += (tool[i] - centre[i]) ** 2
            length = math.sqrt(tool2) if tool2 > 0.0 else 1.0
        scale = radius / length
        for i in range(k):
            goal[i] = centre[i] + (goal[i] - centre[i]) * scale
    span2 = along = 0.0
    for i in range(k):
        span2 += (goal[i] - tool[i]) ** 2
        along += (centre[i] - tool[i]) * (goal[i] - tool[i])
    t = 0.0 if span2 == 0.0 else min(max(along / span2, 0.0), 1.0)
    clearance2 = 0.0
    for i in range(k):
        clearance2 += (tool[i] + t * (goal[i] - tool[i]) - centre[i]) ** 2
    return goal, math.sqrt(span2), unmoved, math.sqrt(clearance2)


def joint_motion(goal, has_goal, q_in, filtered, rate, q, dq, dt, slew, filter_rate, gain,
                 max_speed, goal_rate):
    """One step of the reach-round's joint motion (module docstring), for n joints: q_in
    slewed towards the joint goal (n,) rad at `slew` rad/s (left where it is unless
    has_goal), q_f (`filtered`, rad) and dq_f/dt (`rate`, rad/s) advanced by dt (s) through a
    critically damped second-order filter of rate `filter_rate` (1/s; semi-implicit Euler: its
    acceleration is continuous, as q_in is, so the feed-forward of dq_f steps nothing) whose
    damping acts on dq_f/dt - goal_rate ((n,) rad/s: the goal's own velocity, fed forward: a
    goal moving at goal_rate is tracked without the filter's lag of 2 / filter_rate s), and
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
        a = stiffness * (value - filtered[i]) + damping * (goal_rate[i] - rate[i])
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


def clearance_inverse_kinematics(model, goal, seeds, lower, upper, iterations: int,
                                 keep_off) -> np.ndarray:
    """Joints (n,) rad that bring the tool point nearest `goal` (k,) m on the task axes while
    every robot-person pair keeps its clearance, within the box [lower, upper] (n,) rad:
    RobotModel.inverse_kinematics' damped least squares with the person's pairs as a second,
    weighted task. keep_off(q) -> (rows (m, n) m/rad, shortfall (m,) m) or None: each close
    pair's row n^T J_p (the speed of the robot's closest point towards the person per unit
    joint speed: the pair's distance changes at -R_k dq) and how far the pair lies inside
    the distance wanted (> 0: inside). Each step solves

        min |J dq - miss|^2 + W^2 sum_k (R_k dq + shortfall_k)^2 + lambda^2 |dq|^2

    over the pairs inside (shortfall_k > 0; W = IK_CLEARANCE_WEIGHT, lambda the model's
    IK_DAMPING: R_k dq = -shortfall_k moves pair k out by its shortfall), its length capped
    at IK_STEP, and clamps into the box; a seed stops after `iterations` steps, at the goal
    (IK_TOLERANCE) with every pair out, or at a step below IK_SETTLED. Of the seeds' results
    (rows of `seeds`, (s, n) rad) the one of least CLAMP_COST (miss^2 + W^2 sum
    shortfall^2) + IK_TRAVEL_COST |q - seeds[0]|^2. Why: a pose from the goal alone drove
    the Panda's links into a person holding out their hand, so the reach-round stood down
    while the person's barrier held the arm, and the learned task's pull near the hand
    (about 1 N) rested in the barrier's bands 0.17-0.47 m short (docs/design.md)."""
    solve = clearance_inverse_kinematics_steps(model, goal, seeds, lower, upper, iterations,
                                               keep_off)
    while True:
        try:
            next(solve)
        except StopIteration as done:
            return done.value


def clearance_inverse_kinematics_steps(model, goal, seeds, lower, upper, iterations: int,
                                       keep_off):
    """clearance_inverse_kinematics one iteration at a time: a generator that yields (None)
    after each damped least-squares step and returns the joints (its StopIteration's value),
    the same arithmetic to the bit. The reach-round's refresh advances it
    ReachRound.IK_STEPS_PER_CYCLE steps a control cycle, so that no cycle carries a whole
    solve."""
    damping = IK_DAMPING ** 2 * np.eye(model.dof)
    still = np.zeros(model.dof)
    weight2 = IK_CLEARANCE_WEIGHT ** 2
    best, first = None, seeds[0]
    for seed in seeds:
        q = np.clip(seed, lower, upper)
        for step in range(iterations + 1):
            x, jac, _ = model.task_kinematics(q, still)
            miss = goal - x
            pairs = keep_off(q)
            inside = 0.0
            normal = jac.T @ jac + damping
            pull = jac.T @ miss
            if pairs is not None:
                rows, shortfall = pairs
                held = shortfall > 0.0
                if held.any():
                    rows, shortfall = rows[held], shortfall[held]
                    inside = float(shortfall @ shortfall)
                    normal += weight2 * (rows.T @ rows)
                    pull -= weight2 * (rows.T @ shortfall)
            if step == iterations or (inside == 0.0 and float(miss @ miss) < IK_TOLERANCE ** 2):
                break
            dq = np.linalg.solve(normal, pull)
            length = float(np.sqrt(dq @ dq))
            if length < IK_SETTLED:
                break
            if length > IK_STEP:
                dq *= IK_STEP / length
            q = np.clip(q + dq, lower, upper)
            yield
        cost = CLAMP_COST * (float(miss @ miss) + weight2 * inside) + IK_TRAVEL_COST * float(
            (q - first) @ (q - first))
        if best is None or cost < best[0]:
            best = (cost, q)
    return best[1]


def _solved_later(solve, *args):
    """`solve(*args)` as a generator that runs it whole at its second step (its
    StopIteration's value): a solve without steps of its own, run after the command
    (ReachRound.advance takes IK_STEPS_PER_CYCLE >= 2 steps a cycle). The Panda's plain
    engaging solve took 0.9-1.8 ms, a whole control period or more, inside the command."""
    yield
    return solve(*args)


def _det(square: np.ndarray) -> float:
    """det of a 2 x 2 or 3 x 3 matrix (a square task Jacobian)."""
    if square.shape == (2, 2):
        (a, b), (c, d) = square.tolist()
        return a * d - b * c
    return float(np.linalg.det(square))


class ReachRound:
    """The reach-round blend of any arm (arm_law.ArmController): when to blend, and where to
    (module docstring).

    The goal is the hand (d1 = 0) or the middle of the region's shell towards the arm, kept in
    the shell round the model's shoulder between its folded reach (RobotModel.folded_reach:
    the SCARA's hole round its base; 0 for a model that knows none) plus inner_margin and the
    attained reach less outer_margin. The blend engages when the straight path to the goal
    passes within BLOCKED_CLEARANCE beyond the hole, when a joint sits in its barrier's band
    (near > NEAR_BARRIER) while the goal is more than FAR_GOAL away, or when the region lies
    out of the shell (the goal, before it is moved into the shell, more than d2 beyond it).
    Once engaged it stays, unless the region is out of the shell or the path blocked, until

    - the tool is within FAR_GOAL / 2 of the goal with the joint goal CLEAR_BANDS band inside
      its box (a pose handed back at the band's edge drifts into it, and the barrier's push
      takes the tool off the goal again), or
    - the straight descent can be trusted, which only an arm with as many joints as task axes
      allows (the SCARA: its inverse kinematics has branches, the elbows, which the sign of
      det J tells apart): the joint goal on the arm's branch and within STRAIGHT_TURN of its
      first joint, the path CLEAR_CLEARANCE beyond the hole, no joint near a limit, and J+
      undamped at the arm (off the stretched arm: leaving earlier hands the arm back to the
      descent that was blocked). A redundant arm's descent, which stalled, is not trusted
      before the goal.

    The joint goal q* comes from the model's inverse kinematics (RobotModel.inverse_kinematics:
    the SCARA's two elbows in closed form, damped least squares otherwise) within the joint box
    GOAL_MARGIN band inside the limits. It is solved on engaging from the arm's joints, from its
    home pose swung to the goal's azimuth about the first joint (for a vertical first axis, the
    Panda's: a far side reached by turning round) and from the arm's joints so swung, the
    nearest that reaches (0.9-1.1 ms for the Panda's hand behind its base, 0.26 ms for one
    out of reach, once); then refreshed every IK_PERIOD s from the arm's joints and from the
    last q* (IK_REFRESH iterations each; for an arm with as many joints as task axes whose
    last q* is held at an edge of its box while it misses the goal by more than FAR_GOAL,
    from the home pose swung to the goal's azimuth too: the way round through the free
    range), the nearest to the arm that reaches (the SCARA: the elbow
    nearer to the arm's), so that the numerical solve stays off most control cycles; a
    clearance-aware solve (keep_off set), the engaging one too, runs IK_STEPS_PER_CYCLE of its
    iterations a cycle, the last q* kept until it ends (on engaging, none: the blend holds the
    joints where they were, about 30 cycles with sigma still near 0). For a caller that runs
    the solves after its command (`advance`), the model's plain solve runs there too, whole,
    its q* taken by the next cycle. While sigma ramps down, q* keeps following the goal; it
    is forgotten once sigma rests.

    model: a RobotModel; lower, upper (n,) rad; band (rad): the barrier's; reach (m): the
    attained reach round the shoulder; damping_threshold w0 (m^k): J+ is undamped where
    sqrt(det(J J^T)) >= w0 (task_variable.damped_pseudo_inverse); compiled: the joint
    motion through arm_kernels.joint_motion (numba), else through joint_motion (its
    reference). `update` runs once per control step with its dt; `reset` forgets the state
    (the joint goal restarts from the arm's joints at the next update).
    """

    NEAR_BARRIER = 0.03  # barrier proximity above which a far goal counts as blocked
    FAR_GOAL = 0.06  # m from the goal: far

    BLOCKED_CLEARANCE = 0.02  # m beyond the hole: the straight path is blocked
    CLEAR_CLEARANCE = 0.06  # m beyond it: clear again (hysteresis)
    STRAIGHT_TURN = 1.0  # rad of the first joint the straight descent is trusted with
    IK_PERIOD = 0.02  # s between refreshes of the joint goal
    IK_REFRESH = 5  # iterations of each refresh, from the arm's joints and the last joint goal
    IK_ITERATIONS = 20  # iterations of a clearance-aware solve on engaging, from each seed
    # Iterations of a clearance-aware refresh per control cycle: the refresh (up to 12
    # iterations, about 0.5 ms for the Panda beside a person) spread over the cycles after
    # its IK_PERIOD, so that no cycle carries it whole (whole, every twentieth cycle took
    # 0.45-0.7 ms in-process against a median of 0.14 ms).
    IK_STEPS_PER_CYCLE = 2

    def __init__(self, settings: ReachRoundSettings, model, lower, upper, band: float,
                 reach: float, damping_threshold: float, compiled: bool = False):
        self._model, self._band = model, band
        axes = model.task_axes
        margin = GOAL_MARGIN * band
        self._box = (np.asarray(lower, dtype=float) + margin,
                     np.asarray(upper, dtype=float) - margin)
        self._centre = np.array(model.shoulder[:axes], dtype=float)
        self._centre_point = tuple(self._centre.tolist())
        self._inner = float(model.folded_reach)
        # The goal's shell (no hole: from the shoulder on).
        self._high = float(reach) - settings.outer_margin
        self._low = self._inner + settings.inner_margin if self._inner > 0.0 else 0.0
        self._square = model.dof == axes
        self._still = np.zeros(model.dof)
        clear = CLEAR_BANDS * band
        self._clear_box = ((self._box[0] + clear).tolist(), (self._box[1] - clear).tolist())
        self._undamped2 = damping_threshold * damping_threshold
        home = np.clip(model.home, *self._box)
        arm = model.tool_position(home)[:2] - model.shoulder[:2]
        self._home, self._home_azimuth = home, math.atan2(arm[1], arm[0])
        self.settings = settings
        # keep_off(q) -> (rows, shortfall) or None: the person's pairs the joint goal keeps
        # clear (clearance_inverse_kinematics); None: the goal alone (the caller sets it).
        self.keep_off = None
        # (0, 1]: the share of the settings' slew and max_speed the joint motion uses (the
        # caller lowers it near a person).
        self.speed_scale = 1.0
        # Whether the caller runs the solves' steps after its command (`advance`): set by the
        # first call, after which update only takes their results.
        self._defers = False
        self._motion, self._goal = joint_motion, reach_goal
        if compiled:  # imported here: arm_kernels imports this module
            from hri_adaptive_controller import arm_kernels
            self._motion, self._goal = arm_kernels.joint_motion, arm_kernels.reach_goal
            self._goal(self._centre, self._centre, 0.0, 0.0, self._centre, 1.0, 0.0)  # loaded
        self.reset()

    def reset(self) -> None:
        self._time = 0.0
        self._schedule = EventWeightSchedule(self.settings.blend_time)
        self._engaged = False
        self._switched = -math.inf  # time of the last switch
        self._resting = True  # sigma is 0 with no ramp to evaluate
        self._full = False  # sigma is 1 with no ramp to evaluate
        self._filtered = None  # (q_in, q_f, dq_f), arrays (n,)
        # (n,) rad/s: the share of the joint goal's velocity fed forward into its filter
        # (joint_motion), restarted with it.
        self._fed_rate = self._still
        # (time solved, q* (n,), whether q* is clear of the limits, det J at q* (an arm with
        # as many joints as task axes; else 0))
        self._joint_goal = None
        # m: how far the joint goal's nearest pair lies inside keep_off's distance (0: clear
        # or no keep_off), as of the last solve.
        self.goal_shortfall = 0.0
        # A solve under way (a clearance-aware one's steps; with `advance`, the model's own,
        # whole): (time started, its generator), or None; with `advance`, its joints (n,)
        # once it has ended, until update takes them.
        self._pending = None
        self._done = None

    @property
    def engaged(self) -> bool:
        """Whether the blend is heading to (or at) the joint-space motion."""
        return self._engaged

    def _blend(self, wanted: bool, joint_goal, q, dq, dt: float, goal_rate=None):
        """Advance by dt (s) towards `wanted` and return (sigma, dsigma/dt, u, du/dt) with u
        and du/dt arrays (n,), or None while sigma rests at 0. joint_goal: a callable giving
        the joint goal q* (an array (n,), rad), or None to hold q_in where it is; q, dq the
        joints (arrays (n,) of floats); goal_rate (n,) rad/s: the joint goal's velocity (None:
        a still goal)."""
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
            self._fed_rate = self._still
        goal = None if joint_goal is None else joint_goal()
        has_goal = goal is not None  # None: no goal yet (the engaging solve under way)
        if not has_goal:
            goal = self._filtered[0]
        scale = self.speed_scale
        # The goal's velocity steps where the hand crosses the shell's edge or stops: its
        # share fed forward is filtered (first order, GOAL_RATE_TIME), so that the filter's
        # acceleration, and so the torque, does not step (4.2 N m in one cycle unfiltered).
        fed_goal_rate = self._still
        if has_goal and goal_rate is not None:
            # Capped as the motion's correction is: J+ of the hand's velocity near a
            # singular pose asked the Panda's joints for 2.2 rad/s, into its effort limits.
            capped, _ = norm_cap(goal_rate, scale * settings.max_speed)
            fed_goal_rate = capped * goal_rate
        fed = self._fed_rate
        fed = fed + (1.0 - math.exp(-dt / GOAL_RATE_TIME)) * (fed_goal_rate - fed)
        self._fed_rate = fed
        q_in, filtered, rate, u, du = self._motion(
            goal, has_goal, *self._filtered, q, dq, dt, scale * settings.slew,
            settings.filter_rate, settings.gain, scale * settings.max_speed, fed)
        self._filtered = (q_in, filtered, rate)
        return sigma, sigma_rate, u, du

    def update(self, q, dq, x, jac, hand, region, near: float, dt: float,
               hand_velocity=None, pinv=None):
        """Advance by dt (s) and return (sigma, dsigma/dt, u (n,), du/dt (n,)) or None while
        sigma rests at 0. q, dq (n,); x, hand (k,) m: the tool and the target on the task
        axes; jac (k, n): the task Jacobian at q; region (d1, d2) m of a follow task, or None
        (no task, or an avoid task: sigma fades to 0); near: the barrier's proximity
        (barrier()); hand_velocity (k,) m/s and pinv (n, k), J+ at q: the goal moves with
        the hand, and its velocity (the goal's change for the hand moved on by GOAL_RATE_STEP
        s: none where the hand leaves the shell outwards) is fed forward through J+ to the
        joint goal's filter (None: a still goal)."""
        settings = self.settings
        if region is None or not settings.enabled:
            if self._resting:
                self._time += dt  # as _blend
                return None
            blend = self._blend(False, None, q, dq, dt)
            if blend is None:
                self._forget_goal()  # the next engagement solves afresh
            return blend
        d1, d2 = region
        hole = self._inner > 0.0
        if (self._resting and not hole and near <= self.NEAR_BARRIER
                and math.dist(hand.tolist(), self._centre_point) - d2 <= self._high):
            self._time += dt  # resting, no hole and nothing to engage it (the usual case)
            return None
        goal, distance, radius, clearance = self._goal(
            x, hand, d1, d2, self._centre, self._high, self._low)
        goal_rate = None
        if hand_velocity is not None:
            ahead = self._goal(x, hand + GOAL_RATE_STEP * hand_velocity, d1, d2, self._centre,
                               self._high, self._low)[0]
            goal_rate = pinv @ ((ahead - goal) / GOAL_RATE_STEP)
        outside = radius - d2 > self._high or radius + d2 < self._low
        blocked = hole and clearance < self._inner + self.BLOCKED_CLEARANCE
        path_clear = not hole or clearance >= self._inner + self.CLEAR_CLEARANCE
        if self._engaged:
            target = self._refresh(goal, q, x)
            # While the engaging solve is under way (target None) the blend stays on.
            settled = (target is not None and distance <= 0.5 * self.FAR_GOAL
                       and self._joint_goal[2])
            wanted = outside or blocked or not (
                settled or (target is not None and path_clear
                            and self._straight(q, jac, target, near)))

            def joint_goal():
                return target
        else:
            wanted = blocked or (near > self.NEAR_BARRIER and distance > self.FAR_GOAL) or outside

            def joint_goal():
                return self._refresh(goal, q, x)
        blend = self._blend(wanted, joint_goal, q, dq, dt, goal_rate)
        if blend is None:
            self._forget_goal()
        return blend

    def _forget_goal(self) -> None:
        """Forget the joint goal and any solve under way: the next engagement solves afresh."""
        self._joint_goal = None
        self._pending = self._done = None
        self.goal_shortfall = 0.0

    def _straight(self, q, jac, target, near: float) -> bool:
        """Whether the straight descent is trusted (the class docstring; the path's clearance
        checked by the caller)."""
        if not self._square or near >= 0.5 * self.NEAR_BARRIER:
            return False
        if abs(float(target[0]) - float(q[0])) >= self.STRAIGHT_TURN:
            return False
        det = _det(jac)
        return det * self._joint_goal[3] > 0.0 and det * det >= self._undamped2

    def _seeds(self, goal, q, x) -> np.ndarray:
        """The engaging solve's seeds (3, n) for `goal` (k,) m (the class docstring); q (n,)
        the arm's joints, x (k,) m its tool point."""
        (c1, c2), home = self._centre[:2].tolist(), self._home
        azimuth = math.atan2(goal[1] - c2, goal[0] - c1)
        swung_home, swung_arm = home.copy(), np.array(q, dtype=float)
        swung_home[0] = math.remainder(home[0] + azimuth - self._home_azimuth, 2.0 * math.pi)
        swung_arm[0] += math.remainder(azimuth - math.atan2(x[1] - c2, x[0] - c1),
                                       2.0 * math.pi)
        return np.array([q, swung_home, swung_arm])

    def _refresh_seeds(self, goal, q, x, last) -> np.ndarray:
        """A refresh's seeds (class docstring): the arm's joints and the last joint goal
        `last` (n,); for an arm with as many joints as task axes whose last goal is held at
        an edge of its box while it misses `goal` by more than FAR_GOAL, also the home pose
        swung to the goal's azimuth. Why: a hand that passed behind the SCARA's base (joint
        1's dead zone) to the far side left the solves from the arm's joints and the last
        goal clamped at joint 1's stop, the way round through the free range never tried; a
        redundant arm's solves move through its null space, and there the swung seed took
        the Panda's arm on long swings away from hands it was near."""
        pair = np.array([q, last])
        if not self._square:
            return pair
        lower, upper = self._box
        if not np.any((last <= lower) | (last >= upper)):
            return pair
        reached = self._model.task_kinematics(last, self._still)[0]
        if math.dist(reached.tolist(), goal.tolist()) <= self.FAR_GOAL:
            return pair
        return np.array([q, last, self._seeds(goal, q, x)[1]])

    def _refresh(self, goal, q, x) -> np.ndarray | None:
        """The joint goal q*: solved afresh on engaging, refreshed every IK_PERIOD s (a
        clearance-aware solve, on engaging too, over the cycles it takes, from its start:
        None until an engaging one ends); with it whether it lies CLEAR_BANDS band inside its
        box and, for an arm with as many joints as task axes, det J there (its branch)."""
        now = solved = self._time
        last = self._joint_goal
        target = None
        if self._pending is None:
            if last is not None and now - last[0] < self.IK_PERIOD:
                return last[1]
            if last is None:  # engaging: the plain solve takes its model's default iterations
                seeds = self._seeds(goal, q, x)
                iterations, plain = self.IK_ITERATIONS, MODEL_IK_ITERATIONS
            else:
                seeds = self._refresh_seeds(goal, q, x, last[1])
                iterations = plain = self.IK_REFRESH
            if self.keep_off is not None:
                self._pending = (now, clearance_inverse_kinematics_steps(
                    self._model, goal, seeds, *self._box, iterations, self.keep_off))
            elif self._defers:  # the model's own solve, whole, after the command
                self._pending = (now, _solved_later(self._model.inverse_kinematics, goal,
                                                    seeds, *self._box, plain))
            else:
                target = self._model.inverse_kinematics(goal, seeds, *self._box, plain)
        if target is None:
            solved, target = self._pending[0], self._take()
            if target is None:
                return None if last is None else last[1]
        clear = all(low <= v <= high for v, low, high in zip(
            target.tolist(), *self._clear_box, strict=True))
        pairs = None if self.keep_off is None else self.keep_off(target)
        self.goal_shortfall = 0.0 if pairs is None else max(float(pairs[1].max()), 0.0)
        branch = (_det(self._model.task_kinematics(target, self._still)[1]) if self._square
                  else 0.0)
        self._joint_goal = (solved, target, clear, branch)
        return target

    def advance(self) -> None:
        """Advance the solve under way by IK_STEPS_PER_CYCLE iterations, for a caller that
        runs this after sending its command: the next update takes the joints of a solve
        that has ended. From the first call on, update no longer advances the solves
        itself, and the model's plain solve (no keep_off) runs here too, so that their cost
        (about 0.1 ms a cycle for the SCARA beside a person; 0.9-1.8 ms once for the Panda
        engaging without one) stays off the joint state -> command latency."""
        self._defers = True
        if self._pending is not None and self._done is None:
            try:
                self._done = self._advance()
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):
                # Dropped (inside `command` it would have been a fault): the last joint goal
                # stays and the next refresh solves afresh.
                self._pending = None

    def _take(self):
        """The joints (n,) of the solve under way once it has ended (the solve then over),
        else None: advanced here unless the caller advances it (`advance`)."""
        if self._defers:
            target, self._done = self._done, None
        else:
            target = self._advance()
        if target is not None:
            self._pending = None
        return target

    def _advance(self):
        """The solve under way advanced by IK_STEPS_PER_CYCLE iterations: its joints (n,)
        once done, else None."""
        solve = self._pending[1]
        for _ in range(self.IK_STEPS_PER_CYCLE):
            try:
                next(solve)
            except StopIteration as done:
                return done.value
        return None
