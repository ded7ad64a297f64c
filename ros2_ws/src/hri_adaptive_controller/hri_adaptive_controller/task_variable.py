"""Event-based task variable and the terms of the joint-velocity reference (eq. 12, 14, 18).

Task variable (eq. 12, 13)
--------------------------
The task variable is K dP/d(dx) with dx = x - x_d (m) and K the task's own gain (m^2/s; the
learner's `k`, or hri_core.potential.default_task_gain when a task gives none), so the arm
moves at K |dP/dz| m/s: a1, a2 and K shape the motion as the demonstration did. Writing
g(r) = K dP/dr (signed, r = |dx|, e = dx / r), the task velocity is

    delta_eps = Q'(r) e,   Q'(r) = cap(g(r) + f(r) phi(|g| / v_a)),                 (eq. 12')

- cap, the robot-wide speed cap: cap(v) = v for |v| <= v_max (`max_task_speed`), above it
  v_max + b tanh((|v| - v_max) / b) with b = CAP_BAND v_max, signed. Below v_max the task
  speed is K |dP/dz| exactly; above it the cap bends the speed smoothly (C2: cap' = 1 and
  cap'' = 0 at v_max) to at most (1 + CAP_BAND) v_max. The speed is computed from log K +
  log |dP/dr| (hri_core.potential.log_radial_slopes), so Table I's avoid row (P(0) ~ 1e124,
  K ~ 1e-126 m^2/s) is as smooth as any other: K dP/dr is an ordinary number even where P and
  K are not, and nothing is clipped below the cap.
- f(r) phi: the approach term, a floor v_a (`approach_speed`) on the speed towards the region
  where the learned pull alone is weaker (every P of eq. 2 rises from its zero set like
  (r - d)^3, so K dP/dr alone reaches the region only asymptotically, and Table I's follow row
  moves at 0.3 mm/s 6 cm from its region). phi(u) = 1 - s(u), s the quintic smoothstep, so
  the floor is gone where |g| >= v_a; f(r) = +v_a outside d2 and -v_a inside d1 (S = +1),
  fading in over `region_margin` inside the region (and within RADIAL_FADE of dx = 0), so the
  arm crosses the region's boundary at about v_a and stops `region_margin` inside it. Not
  applied across a boundary at or beyond the workspace (d2 >= 2 reach) nor to S = -1 tasks
  (their ridge between the regions has no one direction towards the region). v_a = 0 gives
  Q' = cap(K dP/dr). For a follow-type task (not open outward) v_a is the task's own pull
  K |dP/dr| at APPROACH_REFERENCE outside d2, within [MIN_APPROACH_SPEED, approach_speed]
  (task_approach_speed): the demonstration's pace sets the approach too, so a task learned
  from a demonstration four times slower (K / 4) takes four times as long; avoid tasks keep
  approach_speed (leaving a hand is not slowed by a slow demonstration).

Q'(r) is C2 in r except where the quintic blends meet (C2 too), and its derivative Q'' enters
qddot_r (eq. 18) exactly, so qdot_r and the torque are continuous in time at region entry.
delta_eps is a gradient (of the radial Q = integral of Q'), so eq. 21, 22 hold with Q in place
of P (see arm_law).

Rest position (avoid tasks)
---------------------------
eq. 14 feeds the hand's velocity xdot_d forward in every task: right for following, wrong for
avoiding (the arm then copies a hand that approaches or leaves, and the potential never acts).
A task whose desired region is open outward (S = +1 with d2 >= 2 reach, Table I's avoid row;
or S = -1) is an avoid task: its reference drops xdot_d (weighted by a, so a switch stays
smooth) and adds a return to the rest position x_rest,

    v_rest = w(r) c(x - x_rest),   c(y) = -cap(k_rest |y|) y / |y|,

w(r) the quintic smoothstep from 0 at r = d_in + margin to 1 at d_in + margin + `rest_gate`
(d_in = d1, or d2 for S = -1), so the return acts only once the arm is outside the region's
edge (inside it the potential pushes the arm out alone), and k_rest = `rest_gain` (1/s).

Joint-velocity reference (eq. 14) and its derivative (eq. 18)
-------------------------------------------------------------
    v_r = f xdot_d - a delta_eps + a v_rest,          qdot_r = J+ v_r,
    qddot_r = (dJ+/dt) v_r + J+ (f xddot_d + df/dt xdot_d - da/dt delta_eps
              - a H_Q (xdot - xdot_d) + da/dt v_rest + a dv_rest/dt),

f = 1 for follow tasks (and without a task), f = 1 - a for avoid tasks (v_rest = 0 for
follow tasks); xdot = J qdot; H_Q = d(delta_eps)/d(dx), from Q'' and Q'/r through the chain
rule; dv_rest/dt = c w'(r) e^T (xdot - xdot_d) + w Dc xdot: the exact time derivative, no
finite difference (arm_law puts the terms together for any arm, on its task axes). J+ is
the damped pseudo-inverse (damped_pseudo_inverse)

    J+ = J^T (J J^T + lambda^2 I)^-1,
    lambda^2 = lambda_max^2 (1 - w^2 / w0^2)^2 for w < w0, else 0,  w = sqrt(det(J J^T)),

so J+ is the exact inverse away from singularities (w >= w0: eq. 22 holds unchanged) and the
damping grows smoothly (C1 in q) to lambda_max at a singularity, where it bounds the joint
speed by |v_r| / (2 lambda_max). dJ+/dt is differentiated analytically, including
d(lambda^2)/dt, from J and Jdot (RobotModel.task_kinematics).
"""

import dataclasses
import math
import operator
from dataclasses import dataclass

import numpy as np

from hri_adaptive_controller.event_weight import quintic_smoothstep, quintic_smoothstep_array
from hri_core.potential import (
    TaskShape,
    default_task_gain,
    log_potential_slope,
    log_radial_slopes,
    potential_gradient,
    signed_log_potential_slope,
)
from hri_core.validation import positive

# Largest |entry| (1/s) of the Hessian of Q. Only a potential that steps within a fraction of
# a micrometre reaches it; there the exact derivative is meaningless for a sampled controller,
# and the cap keeps qddot_r finite.
MAX_TASK_HESSIAN = 1e6

CAP_BAND = 0.2
"""Soft band of the speed cap above max_task_speed, as a fraction of it: the task speed is
K |dP/dz| up to max_task_speed and never more than (1 + CAP_BAND) max_task_speed."""

APPROACH_REFERENCE = 0.2
"""m outside a follow task's region where its pull sets its approach floor
(task_approach_speed): the distance an approach is measured over, inside the arm's reach."""

MIN_APPROACH_SPEED = 0.01
"""m/s: the least approach floor, whatever the demonstration's pace: at it, 0.2 m take 20 s
(the slowest demonstration the learner accepts still reaches its region; below it, the
arm's friction and a 1 mm hand jitter would set the pace, not the task)."""

RETREAT_REACH = 0.1
"""m outside an avoid task's d1 where its retreat from an approaching hand starts to act."""

RETREAT_SPEED = 0.05
"""m/s: the retreat's smooth positive part of the hand's approach speed is quadratic below."""

RADIAL_FADE = 0.01
"""m: the approach term fades out within this distance of dx = 0, where e = dx/|dx| has no
direction (an inner boundary d1 > 0 pushes the arm out from there)."""

# exp() argument above which a speed counts as infinite (the cap saturates long before).
_LOG_SPEED_LIMIT = 700.0
# tanh argument above which sech^2 underflows to 0 in double precision.
SECH_LIMIT = 350.0

# Radial integral that gives Q (monitoring only): Gauss-Legendre with 12 nodes on each of 14
# panels whose widths halve towards both ends, where dQ/dr changes steeply.
_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(12)
_PANEL_EDGES = np.concatenate([[0.0], 2.0 ** np.arange(-7, 0), 1.0 - 2.0 ** np.arange(-2, -8, -1),
                               [1.0]])
_INTEGRALS_AT_ONCE = 1000
ANCHOR_SPACING = 0.0005
"""m between the anchors of PotentialAlongPath."""
MAX_NEW_PIECES = 8
"""Anchors a PotentialAlongPath call may add (each about 40 us: 0.3 ms at most)."""
_MAX_CHAIN = 50_000  # anchors on one side of a breakpoint (25 m): beyond, task_potential
_PIECE_RULE = tuple(zip(*(values.tolist() for values in np.polynomial.legendre.leggauss(5)),
                        strict=True))


@dataclass(frozen=True)
class DampingSettings:
    """Damping of the pseudo-inverse near singular configurations.

    threshold: w0 (m^2 for a planar arm), manipulability w = sqrt(det(J J^T)) below which
        damping starts; max_damping: lambda_max (m/rad), damping at w = 0.
    For the default SCARA (l1 = 0.35 m, l2 = 0.30 m), w = 0.105 |sin q2| m^2, so the default
    w0 = 0.05 m^2 damps within 28 deg of the stretched arm (reach > 0.63 m of 0.65 m; the
    folded side is beyond the joint limits). Smaller w0 or lambda_max let J+ and dJ+/dt grow
    so fast near the stretched arm that the 1 kHz loop chatters between torque limits when a
    target is out of reach (seen with w0 = 0.01, 0.03 m^2).
    """

    threshold: float = 0.05
    max_damping: float = 0.15

    def __post_init__(self):
        if not (math.isfinite(self.threshold) and self.threshold > 0.0):
            raise ValueError(f'damping threshold must be finite and > 0, got {self.threshold}')
        if not (math.isfinite(self.max_damping) and self.max_damping >= 0.0):
            raise ValueError(f'max_damping must be finite and >= 0, got {self.max_damping}')


@dataclass(frozen=True)
class TaskDrive:
    """How one task drives the arm (eq. 12' and the rest position; module docstring).

    shape: the learned task; log_gain: log K (K in m^2/s; a log, since K may lie outside a
    double's range); max_task_speed: v_max (m/s), the cap's knee; approach_speed: v_a (m/s,
    0 = none); margin (m): how far inside the region the approach term reaches (0 when the
    task has no approach term); open_outward: an avoid task (no xdot_d feed-forward, return to
    the rest position); rest_gain k_rest (1/s); rest_gate (m): width of the rest term's gate;
    outer_floor: whether the approach term acts outside d2; pull_limit (m/s, >= 0): the
    cap's knee for a task speed towards the hand (Q' > 0) and for the return to rest, when
    below max_task_speed (the controller's separation_speed_limit; a speed away from the hand
    keeps max_task_speed). Build it with `task_drive`.
    """

    shape: TaskShape
    log_gain: float
    max_task_speed: float
    approach_speed: float = 0.0
    margin: float = 0.0
    open_outward: bool = False
    rest_gain: float = 0.0
    rest_gate: float = 0.01
    outer_floor: bool = False
    pull_limit: float = math.inf

    @property
    def task_gain(self) -> float:
        """K (m^2/s) as a float (0.0 or inf where it leaves a double's range)."""
        return math.exp(min(self.log_gain, _LOG_SPEED_LIMIT))

    def region(self) -> tuple[float, float]:
        """Boundaries (m) of Q's zero set [d1', d2'] (S = +1; S = -1: r <= d1', r >= d2')."""
        inner = self.shape.d1 + self.margin if self.shape.d1 > 0.0 else 0.0
        outer = self.shape.d2 - self.margin if self.outer_floor else self.shape.d2
        return inner, outer

    def rest_gate_start(self) -> float:
        """Distance (m) from the hand where the rest term starts to fade in."""
        edge = self.shape.d1 if self.shape.s == 1 else self.shape.d2
        return edge + self.margin


def open_outward(shape: TaskShape, reach: float) -> bool:
    """Whether a task's desired region is open outward (an avoid task): S = -1 (r >= d2 is in
    the region), or S = +1 with d2 >= 2 reach (m), beyond any hand-to-arm distance."""
    return shape.s == -1 or shape.d2 >= 2.0 * reach


def task_approach_speed(shape: TaskShape, log_gain: float, approach_speed: float) -> float:
    """The approach floor v_a (m/s) of a follow-type task: its own pull K |dP/dr| at
    APPROACH_REFERENCE m outside its region, within [MIN_APPROACH_SPEED, approach_speed].

    The demonstration's pace sets the floor as it sets the pull: a task learned from a
    demonstration n times slower (K / n) approaches n times slower, down to
    MIN_APPROACH_SPEED. log_gain: log K (K in m^2/s).
    """
    log_slope = float(log_potential_slope(np.array([shape.d2 + APPROACH_REFERENCE]),
                                          shape)[0])
    pull = math.exp(min(log_gain + log_slope, _LOG_SPEED_LIMIT))
    return min(approach_speed, max(MIN_APPROACH_SPEED, pull))


def task_drive(shape: TaskShape, k: float, max_task_speed: float, reach: float,
               approach_speed: float = 0.0, region_margin: float = 0.0,
               rest_gain: float = 0.0, rest_gate: float = 0.01) -> TaskDrive:
    """The TaskDrive of a task with gain k (m^2/s; 0 = not given: default_task_gain).

    max_task_speed (m/s) > 0; reach (m) > 0, the arm's reach (l1 + l2); approach_speed (m/s)
    >= 0; region_margin (m) >= 0, at most a quarter of the region's width is used; rest_gain
    (1/s) >= 0; rest_gate (m) > 0. Raises ValueError for bad values or, for k = 0, a potential
    with no slope to take a default gain from.
    """
    v_max = positive(max_task_speed, 'max_task_speed', 'm/s')
    reach = positive(reach, 'reach', 'm')
    gate = positive(rest_gate, 'rest_gate', 'm')
    for name, value in (('k', k), ('approach_speed', approach_speed),
                        ('region_margin', region_margin), ('rest_gain', rest_gain)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f'{name} must be finite and >= 0, got {value}')
    log_gain = math.log(k) if k > 0.0 else default_task_gain(shape, v_max, reach)
    outward = open_outward(shape, reach)
    floor = approach_speed if shape.s == 1 and shape.d2 > shape.d1 else 0.0
    if floor > 0.0 and not outward:
        floor = task_approach_speed(shape, log_gain, floor)
    margin = min(region_margin, 0.25 * (shape.d2 - shape.d1)) if floor > 0.0 else 0.0
    return TaskDrive(shape, log_gain, v_max, floor, margin, outward, rest_gain, gate,
                     outer_floor=floor > 0.0 and not outward)


def gains_drive(gains, shape: TaskShape, k: float, reach: float) -> TaskDrive:
    """task_drive with a controller's task settings: `gains` has task_gain (None: the task's
    own k), max_task_speed, approach_speed, region_margin, rest_gain and rest_gate
    (adaptive_law.ControllerGains, arm_law.ArmGains); reach (m) the arm's."""
    return task_drive(shape, k if gains.task_gain is None else gains.task_gain,
                      gains.max_task_speed, reach, gains.approach_speed, gains.region_margin,
                      gains.rest_gain, gains.rest_gate)


def speed_cap(speed: float, v_max: float) -> tuple[float, float]:
    """The smooth cap (value, d/d speed) of a signed speed (m/s): identity for |speed| <=
    v_max, v_max + b tanh((|speed| - v_max) / b) above, b = CAP_BAND v_max (C2 at v_max)."""
    magnitude = abs(speed)
    if magnitude <= v_max:
        return speed, 1.0
    if v_max <= 0.0:  # a zero cap (separation_speed_limit): no speed at all
        return 0.0, 0.0
    band = CAP_BAND * v_max
    x = (magnitude - v_max) / band
    capped = v_max + band * math.tanh(x)
    slope = 0.0 if x > SECH_LIMIT else 1.0 / math.cosh(x) ** 2
    return (capped if speed > 0.0 else -capped), slope


def norm_cap(vector, limit: float) -> tuple[float, float]:
    """speed_cap's smooth cap of the norm of `vector` (k,) at `limit` (its units, > 0), as a
    factor on the vector: (scale, gain), scale = cap(|v|) / |v| (1 at or below the limit)
    and d scale/dt = gain (v . dv/dt) for the vector's rate (gain 0 at or below the limit)."""
    norm2 = float(vector @ vector)
    if norm2 <= limit * limit:
        return 1.0, 0.0
    norm = math.sqrt(norm2)
    capped, slope = speed_cap(norm, limit)
    scale = capped / norm
    return scale, (slope - scale) / norm2


def _approach_floor(r: float, drive: TaskDrive) -> tuple[float, float]:
    """The approach term's f(r) (m/s, signed like dP/dr) and df/dr (1/s)."""
    v_a, margin = drive.approach_speed, drive.margin
    if v_a == 0.0:
        return 0.0, 0.0
    d1, d2 = drive.shape.d1, drive.shape.d2
    if drive.outer_floor and r > d2 - margin:
        s, ds, _ = quintic_smoothstep((r - (d2 - margin)) / margin)
        return v_a * s, v_a * ds / margin
    if d1 > 0.0 and r < d1 + margin:
        s, ds, _ = quintic_smoothstep((d1 + margin - r) / margin)
        c, dc, _ = quintic_smoothstep(r / RADIAL_FADE)
        return -v_a * s * c, -v_a * (c * -ds / margin + s * dc / RADIAL_FADE)
    return 0.0, 0.0


def _approach_floor_values(radii: np.ndarray, drive: TaskDrive) -> np.ndarray:
    """_approach_floor's f(r) (m/s) at each of the radii (numpy; monitoring)."""
    v_a, margin = drive.approach_speed, drive.margin
    floor = np.zeros_like(radii)
    if v_a == 0.0:
        return floor
    d1, d2 = drive.shape.d1, drive.shape.d2
    outer = (radii > d2 - margin) if drive.outer_floor else np.zeros(radii.shape, dtype=bool)
    floor[outer] = v_a * quintic_smoothstep_array((radii[outer] - (d2 - margin)) / margin)[0]
    if d1 > 0.0:
        inner = ~outer & (radii < d1 + margin)
        r = radii[inner]
        floor[inner] = (-v_a * quintic_smoothstep_array((d1 + margin - r) / margin)[0]
                        * quintic_smoothstep_array(r / RADIAL_FADE)[0])
    return floor


def radial_drive(r: float, drive: TaskDrive) -> tuple[float, float]:
    """Q'(r) (m/s) and Q''(r) (1/s) of eq. 12' at r = |dx| (m, finite, >= 0).

    Q' = cap(K dP/dr + f(r) phi(|K dP/dr| / v_a)) (module docstring), from logarithms of K
    and of P's derivatives; Q'' its exact derivative, bounded by MAX_TASK_HESSIAN.
    """
    l_slope, s_slope, l_curv, s_curv = log_radial_slopes(r, drive.shape)
    log_k = drive.log_gain
    pull = s_slope * math.exp(min(log_k + l_slope, _LOG_SPEED_LIMIT)) if s_slope else 0.0
    pull_rate = s_curv * math.exp(min(log_k + l_curv, _LOG_SPEED_LIMIT)) if s_curv else 0.0
    floor, floor_rate = _approach_floor(r, drive)
    if floor != 0.0 or floor_rate != 0.0:
        u = abs(pull) / drive.approach_speed
        s, ds, _ = quintic_smoothstep(u)
        du = (pull_rate if pull >= 0.0 else -pull_rate) / drive.approach_speed
        raw = pull + floor * (1.0 - s)
        raw_rate = pull_rate + floor_rate * (1.0 - s) - floor * ds * (du if ds else 0.0)
    else:
        raw, raw_rate = pull, pull_rate
    # Q' > 0 moves the arm towards the hand: capped at the pull limit (if lower).
    knee = drive.max_task_speed if raw <= 0.0 else min(drive.max_task_speed, drive.pull_limit)
    value, slope = speed_cap(raw, knee)
    rate = slope * raw_rate if slope else 0.0
    return value, min(max(rate, -MAX_TASK_HESSIAN), MAX_TASK_HESSIAN)


def radial_potential_slope(distance, shape: TaskShape) -> np.ndarray:
    """dP/dr of eq. 2 at r = distance (1/m), shape (...,); capped like potential_gradient."""
    r = np.asarray(distance, dtype=float)
    if not np.all(np.isfinite(r)) or np.any(r < 0.0):
        raise ValueError('distance must be finite and >= 0 m')
    points = np.stack([r, np.zeros_like(r)], axis=-1)
    return potential_gradient(points.reshape(-1, 2), shape)[:, 0].reshape(r.shape)


def _rest_gate(r: float, drive: TaskDrive) -> tuple[float, float]:
    """The rest term's gate w(r) and w'(r) (1/m) at r = |x - x_d| (m)."""
    w, dw, _ = quintic_smoothstep((r - drive.rest_gate_start()) / drive.rest_gate)
    return w, dw / drive.rest_gate


def _rest_speed(rho: float, drive: TaskDrive) -> tuple[float, float]:
    """|c(y)| = cap(k_rest rho) (m/s) at rho = |x - x_rest| (m) and the cap's slope."""
    return speed_cap(drive.rest_gain * rho, min(drive.max_task_speed, drive.pull_limit))


def rest_term(dx, y, u, xdot, drive: TaskDrive):
    """An avoid task's return to rest (module docstring) for task vectors of any length m,
    in floats: v_rest = w(r) c(y) and dv_rest/dt = c (grad w . u) + w Dc xdot, each a list of m
    floats (m/s, m/s^2), or None where both are zero (follow tasks; the arm inside the
    gate's start). dx = x - x_d, y = x - x_rest (m), u = xdot - xdot_d, xdot (m/s): sequences
    of m floats."""
    if not drive.open_outward or drive.rest_gain == 0.0:
        return None
    r = math.hypot(*dx)
    w, dw = _rest_gate(r, drive)
    if w == 0.0 and dw == 0.0:
        return None
    rho = math.hypot(*y)
    if rho == 0.0:  # c(y) = -k y near y = 0: c = 0, Dc = -k I
        return [0.0] * len(dx), [-w * drive.rest_gain * v for v in xdot]
    n = [value / rho for value in y]
    speed, slope = _rest_speed(rho, drive)
    radial, tangential = -slope * drive.rest_gain, -speed / rho
    along = (dw / r) * sum(map(operator.mul, dx, u)) if r > 0.0 else 0.0  # grad w . u
    across = (radial - tangential) * sum(map(operator.mul, n, xdot))
    return ([-w * speed * value for value in n],
            [-speed * value * along + w * (across * value + tangential * rate)
             for value, rate in zip(n, xdot, strict=True)])


def _retreat_speed(r: float, c: float, drive: TaskDrive):
    """retreat_term's radial profile: (g, g'(r) 1/m, p(c) m/s, p'(c)) at r = |dx| (m) and
    the hand's approach speed c (m/s), or None where the retreat is zero."""
    shape = drive.shape
    if not drive.open_outward or shape.s != 1 or shape.d1 <= 0.0:
        return None
    if r == 0.0 or r >= shape.d1 + RETREAT_REACH or c <= 0.0:
        return None
    band = RETREAT_SPEED
    p, dp = (c * c / (2.0 * band), c / band) if c < band else (c - 0.5 * band, 1.0)
    # At most 2 v_max, as the follow tasks' feed-forward (adaptive_law.FEED_FORWARD_RATIO).
    p, slope = speed_cap(p, 2.0 * drive.max_task_speed)
    dp *= slope
    g, dg, _ = quintic_smoothstep((shape.d1 + RETREAT_REACH - r) / RETREAT_REACH)
    return g, -dg / RETREAT_REACH, p, dp


def retreat_term(dx, u, velocity, acceleration, drive: TaskDrive):
    """An avoid task's retreat from an approaching hand, v_away = g(r) p(e . xdot_d) e, and
    its time derivative, for task vectors of any length m, in floats: each a list of m floats
    (m/s, m/s^2), or None where both are zero. dx = x - x_d (m), e = dx / r; u = xdot -
    xdot_d, the hand's velocity and acceleration: sequences of m floats.

    p(c) is the smooth positive part of the hand's speed towards the arm (C1: c^2 / (2
    RETREAT_SPEED) up to RETREAT_SPEED, then c - RETREAT_SPEED / 2; capped smoothly at 2
    max_task_speed), g(r) the quintic smoothstep from 1 at r <= d1 to 0 at d1 +
    RETREAT_REACH. The arm backs away as fast as the hand comes (on top of the potential's
    push, which starts only inside d1), so a hand that chases the arm at the arm's own speed
    no longer gains on it."""
    r = math.hypot(*dx)
    if r == 0.0:
        return None
    e = [value / r for value in dx]
    profile = _retreat_speed(r, sum(map(operator.mul, e, velocity)), drive)
    if profile is None:
        return None
    g, dg, p, dp = profile
    radial = sum(map(operator.mul, e, u))  # dr/dt
    de = [(rate - value * radial) / r for rate, value in zip(u, e, strict=True)]  # de/dt
    dc = sum(map(operator.mul, de, velocity)) + sum(map(operator.mul, e, acceleration))
    rate = dg * radial * p + g * dp * dc  # d(g p)/dt
    gp = g * p
    return ([gp * value for value in e],
            [rate * value + gp * change for value, change in zip(e, de, strict=True)])


def _radial_slopes(radii, drive: TaskDrive) -> np.ndarray:
    """Q'(r) (m/s) at the radii (n,) m (numpy; monitoring)."""
    radii = np.asarray(radii, dtype=float)
    log_slope, sign = signed_log_potential_slope(radii, drive.shape)
    with np.errstate(over='ignore'):
        pull = sign * np.exp(np.minimum(drive.log_gain + log_slope, _LOG_SPEED_LIMIT))
    if drive.approach_speed == 0.0:
        raw = pull
    else:
        floor = _approach_floor_values(radii, drive)
        raw = pull + floor * (1.0 - quintic_smoothstep_array(np.abs(pull)
                                                            / drive.approach_speed)[0])
    v_max = drive.max_task_speed
    band = CAP_BAND * v_max
    magnitude = np.abs(raw)
    capped = np.where(magnitude <= v_max, magnitude,
                      v_max + band * np.tanh((magnitude - v_max) / band))
    return np.sign(raw) * capped


def task_potential(distance: float, drive: TaskDrive) -> float:
    """Potential Q at r = distance (m^2/s), the P of eq. 21 for this controller.

    Q(r) is the integral of Q' from the boundary of Q's zero set to r (composite
    Gauss-Legendre, panels refined towards the boundary): for S = +1, from d2' outward or from
    d1' inward, so Q >= 0 and Q = 0 on the region; for S = -1 (region r <= d1' or r >= d2'),
    from d1' (Q is then constant, possibly non-zero, beyond d2'). Equals K P where the speed
    is below the cap and the approach term is off. Used for monitoring V.
    """
    r = float(distance)
    if not (math.isfinite(r) and r >= 0.0):
        raise ValueError(f'distance must be finite and >= 0 m, got {distance}')
    return float(task_potentials(np.array([r]), drive)[0])


def task_potentials(distances, drive: TaskDrive) -> np.ndarray:
    """task_potential at each of `distances` (n,) m (finite, >= 0), in one evaluation of Q'
    at every quadrature node: (n,) m^2/s. A closed-loop simulation's whole run at once costs
    about what one distance costs alone."""
    r = np.asarray(distances, dtype=float).reshape(-1)
    if not np.all(np.isfinite(r)) or np.any(r < 0.0):
        raise ValueError('distances must be finite and >= 0 m')
    d1, d2 = drive.region()
    if drive.shape.s == 1:
        start = np.where(r > d2, d2, d1)
        return np.where((r > d2) | (r < d1), np.abs(_radial_integrals(drive, start, r)), 0.0)
    peak = _potential_peak(drive)
    rising = _radial_integrals(drive, np.full(r.shape, d1), np.clip(r, d1, peak))
    falling = _radial_integrals(drive, np.full(r.shape, peak), np.clip(r, peak, d2))
    return np.where(r <= d1, 0.0, rising + np.where(r > peak, falling, 0.0))


class PotentialAlongPath:
    """task_potential for one drive at the distances of a running controller (its V, eq. 21,
    at 100 Hz): Q(r) = Q(anchor) + the integral of Q' from the anchor to r by a 5-node
    Gauss-Legendre rule in floats, 0.05-0.1 ms against 0.25-0.4 ms for task_potential.

    Q is the integral of Q' from a breakpoint (an edge of the zero set d1', d2'; for S = -1
    also the peak of P, where |K dP/dr| in the approach term turns) to r, and Q' may have a
    kink at a breakpoint. The anchors lie every ANCHOR_SPACING m from the breakpoints, their
    values chained piece by piece with the same rule, kept for the next calls: no piece
    crosses a breakpoint. A call extends a chain by at most MAX_NEW_PIECES; one that would
    need more (a distance far from every anchor made so far, as when a task starts) returns
    task_potential's value, and the next calls go on extending it.

    Agreement: to 1e-9 with a 0.2 mm composite rule on the test tasks (test_task_variable).
    Against a 0.1 mm rule, on a steep task (a1 = 300, a2 = 900 1/m^2) the anchors' values
    differed by up to 2e-5 of Q's scale and task_potential's, whose 14 panels are laid over
    the whole interval, by up to 0.5 %.
    """

    def __init__(self, drive: TaskDrive):
        self._drive = drive
        self._s = drive.shape.s
        self._d1, self._d2 = drive.region()
        self._peak = _potential_peak(drive) if self._s == -1 else None
        # The anchors' values on each side of each breakpoint, keyed (breakpoint, direction):
        # [0, Q' integrated over 1, 2, ... pieces]. (d1' = d2' is possible: the side tells.)
        self._chains: dict[tuple[float, float], list[float]] = {}

    def __call__(self, distance: float) -> float:
        """Q at `distance` (m, finite, >= 0; unchecked: the caller's per-cycle path), m^2/s."""
        r, d1, d2 = distance, self._d1, self._d2
        budget = [MAX_NEW_PIECES]
        try:
            if self._s == 1:
                if d1 <= r <= d2:
                    return 0.0
                return abs(self._along(d2, 1.0, r, budget) if r > d2
                           else self._along(d1, -1.0, r, budget))
            if r <= d1:
                return 0.0
            r, peak = min(r, d2), self._peak
            if r <= peak:
                return self._along(d1, 1.0, r, budget)
            return self._along(d1, 1.0, peak, budget) + self._along(peak, 1.0, r, budget)
        except _ChainTooShortError:
            return task_potential(distance, self._drive)

    def _along(self, origin: float, direction: float, r: float, budget: list[int]) -> float:
        """The integral of Q' from the breakpoint `origin` to r, on its `direction` side."""
        chain = self._chains.setdefault((origin, direction), [0.0])
        steps = int((r - origin) * direction / ANCHOR_SPACING)
        if steps >= _MAX_CHAIN:
            raise _ChainTooShortError
        while len(chain) <= steps:
            if budget[0] == 0:
                raise _ChainTooShortError
            budget[0] -= 1
            start = origin + direction * (len(chain) - 1) * ANCHOR_SPACING
            chain.append(chain[-1] + self._piece(start, start + direction * ANCHOR_SPACING))
        return chain[steps] + self._piece(origin + direction * steps * ANCHOR_SPACING, r)

    def _piece(self, start: float, end: float) -> float:
        half, centre = 0.5 * (end - start), 0.5 * (end + start)
        drive = self._drive
        return half * sum(weight * radial_drive(centre + half * node, drive)[0]
                          for node, weight in _PIECE_RULE)


class TaskDrives:
    """The task drives of a controller (arm_law.ArmController derives from it): one TaskDrive
    per task shape and gain, the pull limit of limit_pull_speed, and the task's share of V.

    gains: the controller's gains (task_gain, max_task_speed, approach_speed, region_margin,
    rest_gain, rest_gate, kp; gains_drive); reach (m): the arm's, for the default gain and the
    open-outward rule.
    """

    def __init__(self, gains, reach: float):
        self._gains = gains
        self._task_reach = float(reach)
        self._drives: dict[tuple[TaskShape, float], TaskDrive] = {}
        self._potentials: dict[tuple[TaskShape, float], PotentialAlongPath] = {}
        self._pull_limit = math.inf  # limit_pull_speed
        self._limited_drive: tuple[TaskDrive, float, TaskDrive] | None = None

    def drive(self, shape: TaskShape | None, k: float = 0.0) -> TaskDrive | None:
        """The TaskDrive (eq. 12') of the task `shape` with gain k (m^2/s; 0 = not given), or
        None without a task (cached). Raises ValueError for a k < 0 or a potential with no
        slope to take a default gain from."""
        if shape is None:
            return None
        key = (shape, k)
        drive = self._drives.get(key)
        if drive is None:
            drive = self._drives[key] = gains_drive(self._gains, shape, k, self._task_reach)
        return drive

    def limit_pull_speed(self, limit: float) -> None:
        """From the next step on, cap the task's speed towards the hand and the return to rest
        at `limit` m/s (the cap's knee, TaskDrive.pull_limit; inf: none, 0: no such speed at
        all), below max_task_speed. Speeds away from the hand (an avoid task's push out of d1
        and its retreat) and the hand's velocity fed forward keep their caps. The caller
        changes it gradually: qddot_r leaves out its rate of change. task_energy (the node's
        V) stays that of the unlimited task."""
        if not (limit >= 0.0):  # also NaN
            raise ValueError(f'pull speed limit must be >= 0 m/s, got {limit}')
        self._pull_limit = float(limit)

    def _control_drive(self, shape: TaskShape | None, k: float) -> TaskDrive | None:
        """drive(shape, k) with the pull limit of limit_pull_speed (the last one kept)."""
        drive = self.drive(shape, k)
        limit = self._pull_limit
        if drive is None or limit >= drive.max_task_speed:
            return drive
        last = self._limited_drive
        if last is None or last[0] is not drive or last[1] != limit:
            last = self._limited_drive = (drive, limit,
                                          dataclasses.replace(drive, pull_limit=limit))
        return last[2]

    def task_energy(self, distance: float, shape: TaskShape | None, k: float = 0.0) -> float:
        """kp Q(distance) (J per unit of a): the task's part of V (eq. 21) that the
        controllers' steps leave out, for a caller that adds a kp Q once the cycle's command
        is out. Q along the controller's path of distances (PotentialAlongPath, one per task:
        0.05-0.1 ms a call, against 0.25-0.4 ms for task_potential, which it agrees with to
        the latter's accuracy). distance m, finite and >= 0; 0 without a task."""
        drive = self.drive(shape, k)
        if drive is None:
            return 0.0
        key = (shape, k)
        potential = self._potentials.get(key)
        if potential is None:
            potential = self._potentials[key] = PotentialAlongPath(drive)
        return self._gains.kp * potential(distance)

    def task_gain(self, shape: TaskShape | None, k: float = 0.0) -> float:
        """Task gain K (m^2/s) used for `shape` with gain k (0 for no task)."""
        drive = self.drive(shape, k)
        return 0.0 if drive is None else drive.task_gain


class _ChainTooShortError(Exception):
    """PotentialAlongPath: the anchors do not reach the distance yet."""


def _potential_peak(drive: TaskDrive) -> float:
    """Distance (m) in (d1, d2) where dP/dr changes sign (S = -1 potentials)."""
    d1, d2 = drive.region()
    radii = np.linspace(d1, d2, 513)[1:-1]
    slopes = radial_potential_slope(radii, drive.shape)
    change = np.flatnonzero((slopes[:-1] > 0.0) & (slopes[1:] <= 0.0))
    if change.size == 0:
        return d2
    # Imported here: scipy.optimize costs the controller half a second at start-up, and only
    # S = -1 tasks need it.
    from scipy.optimize import brentq
    return float(brentq(lambda r: float(radial_potential_slope(np.array([r]),
                                                               drive.shape)[0]),
                        radii[change[0]], radii[change[0] + 1]))


def _radial_integrals(drive: TaskDrive, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Integrals of Q' from each `start` (a boundary of the zero set) to its `end` (n,), m^2/s."""
    if start.size > _INTEGRALS_AT_ONCE:  # bounds the temporaries (168 nodes per integral)
        return np.concatenate([
            _radial_integrals(drive, start[i:i + _INTEGRALS_AT_ONCE],
                              end[i:i + _INTEGRALS_AT_ONCE])
            for i in range(0, start.size, _INTEGRALS_AT_ONCE)])
    edges = start[:, None] + (end - start)[:, None] * _PANEL_EDGES[None, :]
    half = 0.5 * np.diff(edges, axis=1)
    centre = 0.5 * (edges[:, 1:] + edges[:, :-1])
    radii = centre[:, :, None] + half[:, :, None] * _GAUSS_NODES[None, None, :]
    slopes = _radial_slopes(radii.ravel(), drive).reshape(radii.shape)
    return np.sum(half[:, :, None] * _GAUSS_WEIGHTS[None, None, :] * slopes, axis=(1, 2))


def _adjugate(gram: np.ndarray) -> np.ndarray:
    """The adjugate of a symmetric k x k matrix, k = 2 or 3 (adj(G) G = det(G) I)."""
    if gram.shape == (2, 2):
        (g00, g01), (_, g11) = gram.tolist()
        return np.array([[g11, -g01], [-g01, g00]])
    if gram.shape == (3, 3):
        (g00, g01, g02), (_, g11, g12), (_, _, g22) = gram.tolist()
        c00, c01, c02 = g11 * g22 - g12 * g12, g02 * g12 - g01 * g22, g01 * g12 - g02 * g11
        c11, c12, c22 = g00 * g22 - g02 * g02, g01 * g02 - g00 * g12, g00 * g11 - g01 * g01
        return np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]])
    raise ValueError(f'the damped pseudo-inverse takes a 2- or 3-row Jacobian, got {gram.shape}')


def damped_pseudo_inverse(jac, rate, threshold2: float, max_damping2: float):
    """Damped least squares, the one home of J+ (eq. 14) and its exact rate (eq. 18).

    jac J (k, n) m/rad and rate dJ/dt (k, n), k = 2 or 3 task axes; threshold2 w0^2 (m^4 for
    k = 2, m^6 for k = 3); max_damping2 lambda_max^2. With G = J J^T and w^2 = det(G):

        lambda^2 = lambda_max^2 (1 - w^2 / w0^2)^2 below w0, 0 above (C1 across w0),
        J+ = J^T (G + lambda^2 I)^-1,
        dJ+/dt = (Jdot^T - J+ dA/dt) A^-1, A = G + lambda^2 I,
        dA/dt = Jdot J^T + J Jdot^T + d(lambda^2)/dt I, d det(G)/dt = tr(adj(G) dG/dt).

    Returns (J+ (n, k) rad/m, dJ+/dt (n, k), lambda^2). J+ is the exact inverse of a square
    J with w >= w0 (eq. 22 then holds unchanged). Raises ValueError where A has no inverse
    (a singular J and max_damping = 0). The numpy reference of arm_kernels'."""
    gram = jac @ jac.T
    gram_rate = rate @ jac.T
    gram_rate = gram_rate + gram_rate.T
    adjugate = _adjugate(gram)
    ratio = float(np.sum(gram[0] * adjugate[0])) / threshold2
    lam2 = lam2_rate = 0.0
    if ratio < 1.0:
        lam2 = max_damping2 * (1.0 - ratio) ** 2
        lam2_rate = (-2.0 * max_damping2 * (1.0 - ratio) * float(np.sum(adjugate * gram_rate))
                     / threshold2)
        gram = gram + lam2 * np.eye(gram.shape[0])
        adjugate = _adjugate(gram)
    det = float(np.sum(gram[0] * adjugate[0]))
    if abs(det) <= 1e-300:
        raise ValueError('singular Jacobian and no damping (max_damping = 0)')
    inverse = adjugate / det
    pinv = jac.T @ inverse
    pinv_rate = (rate.T - pinv @ (gram_rate + lam2_rate * np.eye(gram.shape[0]))) @ inverse
    return pinv, pinv_rate, lam2
