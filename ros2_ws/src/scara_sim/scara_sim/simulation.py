"""The simulated SCARA's step logic: command handling, joint limits and real-time stepping.

`ScaraSimulator` advances the arm of `dynamics.py` by fixed steps of `dt` with RK4. In each
step the actuator torque is held constant (zero-order hold, like a drive's current loop):

* effort mode: the commanded torque, clipped at +-effort_limit;
* velocity mode: an internal stiff PI joint-velocity loop (a velocity-controlled drive),
  tau = Kp (dq_cmd - dq) + Ki integral(dq_cmd - dq), clipped at +-effort_limit, with the
  integral frozen while the output saturates in the direction of the error (anti-windup);
* idle: zero torque.

The human's force f (N, base frame) on the end-effector enters as J(q)^T f. After each step
a joint outside its limits is clamped to the limit and its velocity into the limit is zeroed.

`FixedStepClock` maps real elapsed time onto those steps: a tick runs the steps whose end
real time has reached, at most `max_catch_up` (the rest are dropped and counted: the
simulation then lags real time by that much instead of running ever further behind), and
says when the next step ends, the time of the next tick. `RealTimeStepper` puts the two
together and returns the state after every step it integrated, each with the simulated time
it stands for, so that the node publishes every step, those caught up after a late tick
included.

`ScaraSimulator.step` runs at 1 kHz: it computes in plain floats (the scalar RK4 of
hri_core.dynamics) rather than through the array functions below, which are the reference
the unit tests compare it with.

No ROS import: the scara_sim node wires this to topics.
"""

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from hri_core.dynamics import (
    ScaraParameters,
    float_constants,
    jacobian,
    rk4_step_floats,
)

COMMAND_MODES = ('idle', 'effort', 'velocity')


def joint_command_floats(values, size: int = 2) -> tuple[float, ...]:
    """A joint command (N m or rad/s) from a flat sequence, as a tuple of `size` floats: the
    node's path for each message (1 kHz), without numpy.

    Raises ValueError with the reason when the length is not `size` or a value is NaN/inf.
    """
    floats = tuple(map(float, values))
    if len(floats) != size:
        raise ValueError(f'expected {size} values, got {len(floats)}')
    if not all(map(math.isfinite, floats)):
        raise ValueError(f'non-finite value in {list(floats)}')
    return floats


def joint_command_from_values(values, size: int = 2) -> np.ndarray:
    """joint_command_floats of `values` flattened (any nesting), as a float array (size,)."""
    return np.array(joint_command_floats(np.ravel(values), size))


def clip_torque(tau, effort_limit: float) -> np.ndarray:
    """Joint torque tau (..., 2) in N m clipped element-wise to [-effort_limit, effort_limit]."""
    if not (math.isfinite(effort_limit) and effort_limit > 0.0):
        raise ValueError(f'effort_limit must be finite and > 0 N m, got {effort_limit}')
    return np.clip(np.asarray(tau, dtype=float), -effort_limit, effort_limit)


def human_joint_torque(q, force, l1: float, l2: float) -> np.ndarray:
    """Joint torque J(q)^T f (N m), shape (..., 2), of a force f (..., 2) in N at the tip."""
    return np.einsum('...ji,...j->...i', jacobian(q, l1, l2), np.asarray(force, dtype=float))


def clamp_to_joint_limits(q, dq, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """Clamp q (2,) rad into [lower, upper]; zero dq (2,) rad/s where it points outward.

    Returns new arrays (q, dq). A joint at or beyond a limit keeps only velocity that leaves
    the limit: an inelastic stop.
    """
    q = np.asarray(q, dtype=float)
    dq = np.asarray(dq, dtype=float)
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    at_lower = q <= lower
    at_upper = q >= upper
    q_new = np.clip(q, lower, upper)
    dq_new = np.where((at_lower & (dq < 0.0)) | (at_upper & (dq > 0.0)), 0.0, dq)
    return q_new, dq_new


@dataclass
class VelocityLoop:
    """Per-joint PI velocity loop of a velocity-controlled drive (gains per joint).

    kp (2,) in N m s/rad, ki (2,) in N m/rad, effort_limit in N m. The defaults of the node
    (kp = [80, 20], ki = [800, 200]) give every closed-loop mode of the default arm a
    bandwidth of at least about 50 rad/s: a hand on the tool barely deflects it.
    """

    kp: np.ndarray
    ki: np.ndarray
    effort_limit: float
    integral: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def __post_init__(self):
        self.kp = np.asarray(self.kp, dtype=float)
        self.ki = np.asarray(self.ki, dtype=float)
        for name, gain in (('kp', self.kp), ('ki', self.ki)):
            if gain.shape != (2,) or not np.all(np.isfinite(gain)) or np.any(gain < 0.0):
                raise ValueError(f'velocity loop {name} must be 2 finite values >= 0, '
                                 f'got {gain.tolist()}')
        clip_torque(0.0, self.effort_limit)  # validates the limit

    def reset(self) -> None:
        """Forget the integral (on switching to velocity mode)."""
        self.integral = np.zeros(2)

    def torque(self, dq_command, dq, dt: float) -> np.ndarray:
        """Drive torque (2,) in N m for the velocity command and measured velocity (rad/s)."""
        error = np.asarray(dq_command, dtype=float) - np.asarray(dq, dtype=float)
        integral = self.integral + error * dt
        raw = self.kp * error + self.ki * integral
        tau = clip_torque(raw, self.effort_limit)
        # Conditional integration: keep the new integral only where it does not push
        # further into saturation.
        winding = (raw != tau) & (np.sign(error) == np.sign(raw))
        self.integral = np.where(winding, self.integral, integral)
        return tau


@dataclass
class ScaraSimulator:
    """State and fixed-step update of the simulated arm (see the module docstring).

    q, dq: joint state (2,) in rad and rad/s; lower, upper: joint limits (2,) in rad;
    effort_limit in N m; dt in s; velocity_loop used in velocity mode.
    """

    params: ScaraParameters
    q: np.ndarray
    dq: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    effort_limit: float
    velocity_loop: VelocityLoop
    dt: float = 1e-3
    applied_effort: np.ndarray = field(default_factory=lambda: np.zeros(2))
    _constants: tuple = field(default=(None, ()), init=False, repr=False)
    # (lower, upper, their four floats): the limits as floats while the arrays stay the same.
    _limits: tuple = field(default=(None, None), init=False, repr=False)

    def __post_init__(self):
        self.q = joint_command_from_values(self.q)
        self.dq = joint_command_from_values(self.dq)
        self.lower = joint_command_from_values(self.lower)
        self.upper = joint_command_from_values(self.upper)
        if np.any(self.lower >= self.upper):
            raise ValueError(f'joint lower limits {self.lower.tolist()} must be below the '
                             f'upper limits {self.upper.tolist()}')
        if np.any(self.q < self.lower) or np.any(self.q > self.upper):
            raise ValueError(f'initial q {self.q.tolist()} outside the joint limits '
                             f'{self.lower.tolist()} .. {self.upper.tolist()}')
        clip_torque(0.0, self.effort_limit)
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise ValueError(f'dt must be finite and > 0 s, got {self.dt}')

    def actuator_torque(self, mode: str, command) -> np.ndarray:
        """Drive torque (2,) in N m for `mode` in COMMAND_MODES and its command values."""
        if mode == 'effort':
            return clip_torque(command, self.effort_limit)
        if mode == 'velocity':
            return self.velocity_loop.torque(command, self.dq, self.dt)
        if mode == 'idle':
            return np.zeros(2)
        raise ValueError(f'unknown command mode {mode!r}; expected one of {COMMAND_MODES}')

    def step(self, mode: str, command, force) -> tuple[tuple[float, float], ...]:
        """Advance one step of dt with the drive in `mode` and the human force (2,) in N.

        The same equations as human_joint_torque, hri_core.dynamics.rk4_step and
        clamp_to_joint_limits, in plain floats. Returns the new q (rad), dq (rad/s) and
        applied_effort (N m) as pairs of floats, the values of the arrays it sets. Raises
        ValueError if the state becomes non-finite (a command or force is checked where it
        arrives).
        """
        if mode == 'effort':
            limit = self.effort_limit
            t1, t2 = (min(max(float(value), -limit), limit) for value in command)
        elif mode == 'idle':
            t1 = t2 = 0.0
        else:
            t1, t2 = self.actuator_torque(mode, command).tolist()
        params = self.params
        if self._constants[0] is not params:  # the node may swap the parameters at run time
            self._constants = (params, float_constants(params))
        q1, q2 = self.q.tolist()
        v1, v2 = self.dq.tolist()
        f1, f2 = force
        l1, l2 = params.l1, params.l2
        s1, c1 = math.sin(q1), math.cos(q1)
        s12, c12 = math.sin(q1 + q2), math.cos(q1 + q2)
        # tau + J^T f
        torque = (t1 + (-l1 * s1 - l2 * s12) * f1 + (l1 * c1 + l2 * c12) * f2,
                  t2 - l2 * s12 * f1 + l2 * c12 * f2)
        q1, q2, v1, v2 = rk4_step_floats((q1, q2, v1, v2), torque, self.dt,
                                         self._constants[1])
        if not math.isfinite(q1 + q2 + v1 + v2):
            raise ValueError(f'the simulated state became non-finite (torque {torque})')
        if self._limits[0] is not self.lower or self._limits[1] is not self.upper:
            self._limits = (self.lower, self.upper, *self.lower.tolist(), *self.upper.tolist())
        _, _, low1, low2, high1, high2 = self._limits
        # An inelastic stop: a joint at a limit keeps only velocity that leaves it.
        if q1 <= low1:
            q1, v1 = low1, max(v1, 0.0)
        elif q1 >= high1:
            q1, v1 = high1, min(v1, 0.0)
        if q2 <= low2:
            q2, v2 = low2, max(v2, 0.0)
        elif q2 >= high2:
            q2, v2 = high2, min(v2, 0.0)
        self.q, self.dq = np.array((q1, q2)), np.array((v1, v2))
        self.applied_effort = np.array((t1, t2))
        return (q1, q2), (v1, v2), (t1, t2)


class StepState(NamedTuple):
    """The arm after one integrated step: sim_time (s since the clock's start) it stands for,
    q (rad), dq (rad/s), effort (N m, the drive torque applied): pairs of floats. A
    NamedTuple: one is made per 1 ms step."""

    sim_time: float
    q: tuple[float, float]
    dq: tuple[float, float]
    effort: tuple[float, float]


EARLY_TOLERANCE = 0.05  # of a step: a tick this much before a step's end still runs it


@dataclass
class FixedStepClock:
    """How many fixed steps of `dt` s each tick must run to keep up with real time.

    Sim time 0 is the first tick at `start` (s, any monotonic clock); step k ends at
    start + k dt. A tick at time `now` owes the steps that have ended by then (up to
    EARLY_TOLERANCE of a step early) and were not accounted for, and `next_step_end` is when
    the next one ends: ticks at those times run one step each, a tick up to a step late runs
    its one step late, and a tick later than that runs the steps it owes at once, a burst
    (a late tick). No step runs before its time: with the nearest step instead (rounding), a
    tick 0.5-1 ms late ran two steps, the second stamped up to 0.5 ms ahead of real time, and
    the next tick none. At most `max_catch_up` steps run; the older ones are dropped (counted)
    and real time moves on without them.
    """

    dt: float
    max_catch_up: int
    start: float
    accounted: int = 0
    integrated: int = 0
    dropped: int = 0
    ticks: int = 0
    late_ticks: int = 0
    idle_ticks: int = 0
    longest_catch_up: int = 0  # most steps owed at one tick since start_window()

    def __post_init__(self):
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise ValueError(f'dt must be finite and > 0 s, got {self.dt}')
        if self.max_catch_up < 1:
            raise ValueError(f'max_catch_up must be >= 1 step, got {self.max_catch_up}')

    def steps_due(self, now: float) -> int:
        """Steps to integrate at a tick at time `now` (s); updates the counters."""
        self.ticks += 1
        owed = int(math.floor((now - self.start) / self.dt + EARLY_TOLERANCE)) - self.accounted
        if owed <= 0:
            self.idle_ticks += 1
            return 0
        if owed > 1:
            self.late_ticks += 1
        self.longest_catch_up = max(self.longest_catch_up, owed)
        steps = min(owed, self.max_catch_up)
        self.dropped += owed - steps
        self.accounted += owed
        self.integrated += steps
        return steps

    @property
    def next_step_end(self) -> float:
        """When the step after the last one accounted for ends (s, the time base of
        `start`): the time of the next tick."""
        return self.start + (self.accounted + 1) * self.dt

    def start_window(self) -> None:
        """Start a new window of `longest_catch_up` (a report period)."""
        self.longest_catch_up = 0

    @property
    def sim_time(self) -> float:
        """Real time (s since `start`) that the state after the last tick stands for."""
        return self.accounted * self.dt


STAMP_SLEW = 0.01  # of a step: how far the stamps may move at one tick against the steps
STAMP_DEADBAND = 50_000  # ns of drift left alone


@dataclass
class StampSlew:
    """What to add to the stamps (start + simulated time) so that they follow the system clock.

    The sim's time is the monotonic clock's (FixedStepClock); its stamps are the system clock
    at the first tick plus that time. When the system clock is slewed against the monotonic
    one (time synchronisation; measured here once: 5 ms/s for 20 s), those stamps fall behind
    every other node's, which stamp with the system clock: the hand, read at the joint
    states' stamps, was then 98 ms old, and the Panda's tool fell out of its follow region
    (0.066 m against 0.056 m) behind a hand at 0.08 m/s. `update(drift_ns, steps)` takes
    the system clock's drift since the start (ns: its offset from the monotonic clock now
    minus at the start) and the steps of this tick, and returns the correction (ns): it
    follows the drift beyond STAMP_DEADBAND by at most STAMP_SLEW of a step per tick that
    runs steps, so the stamps stay a whole number of steps apart within that fraction and
    never go back (a clock step is caught up gradually).
    """

    dt_ns: int
    correction: int = 0

    def update(self, drift_ns: int, steps: int) -> int:
        error = drift_ns - self.correction
        if abs(error) > STAMP_DEADBAND and steps > 0:
            bound = int(STAMP_SLEW * self.dt_ns)
            self.correction += max(-bound, min(bound, error))
        return self.correction


@dataclass
class RealTimeStepper:
    """A ScaraSimulator kept in step with real time by a FixedStepClock.

    `advance(now, inputs)` integrates the steps due at `now` (s, the clock's time base) and
    returns one StepState per integrated step, in order, each stamped with its own simulated
    time: the caller publishes every one, including those caught up after a late tick. Steps
    dropped beyond `max_catch_up` are skipped in time and not returned. `inputs(t)` gives the
    (mode, command, force) of the step that ends at time `t` (the clock's time base): a
    timeout is judged per step, so steps caught up after a stall that end before a command
    expired still apply it, and those after do not, whenever the tick comes.
    """

    sim: ScaraSimulator
    clock: FixedStepClock

    def advance(self, now: float,
                inputs: Callable[[float], tuple[str, object, object]]) -> list[StepState]:
        steps = self.clock.steps_due(now)
        if steps == 0:
            return []
        sim, dt, start = self.sim, self.sim.dt, self.clock.start
        first = self.clock.accounted - steps + 1  # index of the first integrated step
        states = []
        for k in range(steps):
            states.append(StepState((first + k) * dt,
                                    *sim.step(*inputs(start + (first + k) * dt))))
        return states
