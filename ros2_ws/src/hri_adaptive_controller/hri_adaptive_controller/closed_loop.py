"""Pure-Python closed loop: event weight + adaptive controller + SCARA dynamics, no ROS.

Each control period dt (s) the loop takes the events due, evaluates a(E, t) (event_weight,
eq. 13), samples the target trajectory, computes the torque of eq. 16 (adaptive_law, which also
advances theta_hat by eq. 19), limits its rate (effort_rate, gains.max_effort_rate, as the
controller node) and integrates the true dynamics (hri_core.dynamics.rk4_step, eq. 15, torque
held over the step). It is what the unit tests and the benchmarks run; the ROS nodes run the
same library against topics.

Two options bring the topics' timing into the pure loop: `target_period` samples the hand
like hand_sim's /target messages, which the controller sees through its own hold
(signal_hold.HandHold: velocity estimate, first-order hold, blend), and `command_delay` applies
each command that many periods after the state it was computed from (a loop that is late,
as the controller node on a loaded machine).

Targets are callables t -> (x_d, xdot_d, xddot_d) in m, m/s, m/s^2 (shapes (2,)); events are
(time in s, task name or None) pairs, the task names keys of `tasks`. An avoid task
(task_variable.open_outward) returns the arm to its rest position: `rest_position`, or by
default where the end-effector was when the task became active (as the controller node).
"""

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from hri_adaptive_controller.adaptive_law import (
    DEFAULT_GAINS,
    AdaptiveController,
    ControllerGains,
)
from hri_adaptive_controller.effort_rate import EffortRateLimiter
from hri_adaptive_controller.event_weight import EventWeightSchedule, quintic_smoothstep
from hri_adaptive_controller.joint_limits import JointLimits
from hri_adaptive_controller.target_filter import FilteredHand, TargetFilterSettings
from hri_adaptive_controller.task_variable import pseudo_inverse_damping, task_potentials
from hri_core.dynamics import (
    ScaraParameters,
    dynamic_parameters,
    float_constants,
    forward_kinematics,
    forward_kinematics_pair,
    jacobian,
    rk4_step_floats,
)
from hri_core.potential import TaskShape
from hri_core.validation import planar_vector

TargetSample = tuple[np.ndarray, np.ndarray, np.ndarray]
TargetTrajectory = Callable[[float], TargetSample]

DEFAULT_INITIAL_Q = (0.0, math.pi / 2.0)  # rad: end-effector at (0.35, 0.30) m
PEAK_RATIO = 1.875  # peak speed of a minimum-jerk move over its mean speed



def still_target(point) -> TargetTrajectory:
    """A target that stays at `point` (2,) m: zero velocity and acceleration."""
    point = planar_vector(point, 'point')
    zero = np.zeros(2)
    return lambda t: (point.copy(), zero.copy(), zero.copy())


def minimum_jerk_target(start, end, start_time: float, duration: float) -> TargetTrajectory:
    """A target at `start` (2,) m until start_time (s), then a minimum-jerk move to `end`.

    x_d = start + (end - start) s(u), u = (t - start_time) / duration, s the quintic
    smoothstep: x_d, xdot_d and xddot_d are continuous; peak speed 15/8 |end - start| /
    duration (m/s).
    """
    start, end = planar_vector(start, 'start'), planar_vector(end, 'end')
    if not (math.isfinite(duration) and duration > 0.0):
        raise ValueError(f'duration must be finite and > 0 s, got {duration}')
    if not math.isfinite(start_time):
        raise ValueError(f'start_time must be finite, got {start_time}')
    step = end - start

    def sample(t: float) -> TargetSample:
        s, ds, dds = quintic_smoothstep((t - start_time) / duration)
        return start + s * step, (ds / duration) * step, (dds / duration ** 2) * step

    return sample


def path_target(start, moves: Sequence[tuple[float, Sequence[float], float]]) -> TargetTrajectory:
    """A hand that starts at `start` (2,) m and makes minimum-jerk moves one after another.

    moves: (start time s, end point (2,) m, peak speed m/s) each, in time order, each starting
    where the previous one ended (and not before it ended). Between moves the hand is still.
    """
    point = planar_vector(start, 'start')
    segments = []
    for start_time, end, speed in moves:
        end = planar_vector(end, 'end')
        if not (math.isfinite(speed) and speed > 0.0):
            raise ValueError(f'peak speed must be finite and > 0 m/s, got {speed}')
        duration = max(PEAK_RATIO * float(np.linalg.norm(end - point)) / speed, 1e-9)
        if segments and start_time < segments[-1][0] + segments[-1][1]:
            raise ValueError(f'move at {start_time} s starts before the previous one ends')
        segments.append((start_time, duration, minimum_jerk_target(point, end, start_time,
                                                                   duration)))
        point = end
    hold = still_target(start)

    def sample(t: float) -> TargetSample:
        current = hold
        for start_time, _, move in segments:
            if t >= start_time:
                current = move
        return current(t)

    return sample


@dataclass(frozen=True)
class SimulationResult:
    """Time series of one closed-loop run, one row per control period.

    time (N,) s; q, dq (N, 2) rad, rad/s; position, target (N, 2) m; tau (N, 2) N m (applied);
    s (N, 2) rad/s; distance (N,) m; lyapunov V (N,) J (eq. 21 with the true parameters);
    lyapunov_rate (N,) W, eq. 22's prediction; task_potential Q (N,) m^2/s (these three are
    NaN when the run was not monitored, and distance is NaN on a fault); weight a and
    weight_rate da/dt (N,); phase (N,) str; active_task (N,) object (name or None);
    theta_hat (N, 7); torque_limited, fault (N,) bool; damping lambda^2 (N,);
    theta_true (7,); task_gains: k (m^2/s) per task name.
    """

    time: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    position: np.ndarray
    target: np.ndarray
    tau: np.ndarray
    s: np.ndarray
    distance: np.ndarray
    lyapunov: np.ndarray
    lyapunov_rate: np.ndarray
    task_potential: np.ndarray
    weight: np.ndarray
    weight_rate: np.ndarray
    phase: np.ndarray
    active_task: np.ndarray
    theta_hat: np.ndarray
    torque_limited: np.ndarray
    fault: np.ndarray
    damping: np.ndarray
    theta_true: np.ndarray
    task_gains: dict


@dataclass(frozen=True)
class LoopConditions:
    """Everything about one closed-loop run but its tasks, events, hand and duration.

    params: the true arm (ScaraParameters); theta_hat0 (7,) or None: the controller's initial
    estimate (None: the true parameters); gains: ControllerGains; q0, dq0 (2,): initial joint
    state (rad, rad/s); initial_task: active at t = 0 with a = 1 (or None: idle); ramp_time
    (s) of a full fade; dt (s): control period and integration step; monitor: compute V and Q
    (the radial integral costs about as much as the rest of the step); task_gains: task name
    -> K (m^2/s; missing or 0 = default_task_gain); rest_position (2,) m or None;
    reference_step: run AdaptiveController.step (numpy, 12x slower) instead of step_lean (the
    node's path; the two agree to 1e-12). target_period (s) or None: the controller sees the
    target only every target_period s, as positions (the node's /target), through the node's
    glitch filter and hold (target_filter.FilteredHand with target_filter, its filter_time and
    max_extrapolation set from target_filter_time and max_target_extrapolation), and a is
    multiplied by the hand's presence weight (a lost hand fades the task out); None: the
    exact target. command_delay (periods >= 0): the torque computed from the state at step k acts
    from step k + command_delay on (zero before the first). stops: the arm's joint limits
    (joint_limits.JointLimits, its lower and upper; default scara_sim's), an inelastic stop as
    scara_sim's: a joint at a limit keeps only velocity that leaves it; None: no stops.
    """

    params: ScaraParameters = field(default_factory=ScaraParameters)
    theta_hat0: Sequence[float] | None = None
    gains: ControllerGains = DEFAULT_GAINS
    q0: Sequence[float] = DEFAULT_INITIAL_Q
    dq0: Sequence[float] = (0.0, 0.0)
    initial_task: str | None = None
    ramp_time: float = 1.0
    dt: float = 1e-3
    monitor: bool = True
    task_gains: Mapping[str, float] | None = None
    rest_position: Sequence[float] | None = None
    reference_step: bool = False
    target_period: float | None = None
    target_filter_time: float = 0.05
    max_target_extrapolation: float = 0.05
    command_delay: int = 0
    target_filter: TargetFilterSettings = field(default_factory=TargetFilterSettings)
    stops: JointLimits | None = field(default_factory=JointLimits)


def recorded_target(times, positions) -> TargetTrajectory:
    """A recorded hand: the latest sample at or before t of `positions` (N, 2|3) m at `times`
    (N,) s (increasing); a lost frame (a NaN row) stays NaN, and the loop's hold
    (LoopConditions.target_period) then offers nothing, like hand_sim publishing nothing.
    Before the first sample, the first; velocity and acceleration are not known (NaN)."""
    times = np.asarray(times, dtype=float)
    xy = np.asarray(positions, dtype=float)[:, :2].copy()
    if times.ndim != 1 or len(times) != len(xy) or len(times) == 0:
        raise ValueError(f'need matching non-empty times and positions, got {times.shape} '
                         f'and {xy.shape}')
    seen = np.flatnonzero(np.all(np.isfinite(xy), axis=1))
    if seen.size == 0:
        raise ValueError('the recorded hand is never seen')
    xy[:seen[0]] = xy[seen[0]]  # before the hand is first seen: where it is first seen
    unknown = np.full(2, math.nan)

    def sample(t: float) -> TargetSample:
        index = max(int(np.searchsorted(times, t, side='right')) - 1, 0)
        return xy[index].copy(), unknown.copy(), unknown.copy()

    return sample


class _Run:
    """The state of one closed-loop run and its recorded series; `step` is one period."""

    def __init__(self, tasks: Mapping[str, TaskShape], events, target: TargetTrajectory,
                 duration: float, conditions: LoopConditions):
        c = conditions
        if not (math.isfinite(duration) and duration > 0.0):
            raise ValueError(f'duration must be finite and > 0 s, got {duration}')
        if not (math.isfinite(c.dt) and 0.0 < c.dt <= duration):
            raise ValueError(f'dt must be finite and in (0, duration] s, got {c.dt}')
        params = c.params
        self.theta_true = theta_true = dynamic_parameters(params)
        theta_hat0 = theta_true if c.theta_hat0 is None else c.theta_hat0
        for _, name in events:
            if name is not None and name not in tasks:
                raise ValueError(f'event names unknown task {name!r}; known: {sorted(tasks)}')
        if c.initial_task is not None and c.initial_task not in tasks:
            raise ValueError(f'initial_task {c.initial_task!r} is not one of {sorted(tasks)}')
        if c.target_period is not None and not (math.isfinite(c.target_period)
                                                and c.target_period > 0):
            raise ValueError(
                f'target_period must be None or finite and > 0 s, got {c.target_period}')
        if int(c.command_delay) != c.command_delay or c.command_delay < 0:
            raise ValueError(f'command_delay must be an integer >= 0, got {c.command_delay}')
        self.conditions, self.tasks, self.target = c, tasks, target
        self.hand = None if c.target_period is None else FilteredHand(dataclasses.replace(
            c.target_filter, filter_time=c.target_filter_time,
            max_extrapolation=c.max_target_extrapolation))
        self.presence = None
        self.next_target = 0.0
        self.limiter = EffortRateLimiter(c.gains.max_effort_rate)
        self.in_flight = [np.zeros(2)] * int(c.command_delay)
        self.pending_events = sorted(events, key=lambda event: event[0])
        self.event_index = 0
        self.schedule = EventWeightSchedule(c.ramp_time, c.initial_task)
        self.controller = AdaptiveController(c.gains, theta_hat0, params.l1, params.l2,
                                             params.gravity)
        self.friction = (params.b1, params.b2)
        # The arm's state in plain floats, stepped by hri_core's scalar RK4 (as scara_sim).
        self.q = tuple(planar_vector(c.q0, 'q0').tolist())
        self.dq = tuple(planar_vector(c.dq0, 'dq0').tolist())
        self.constants = float_constants(params)
        self.gains_k = dict(c.task_gains or {})
        self.fixed_rest = (None if c.rest_position is None
                           else planar_vector(c.rest_position, 'rest'))
        self.rest, self.rest_task = self.fixed_rest, None

        steps = int(round(duration / c.dt))
        self.time = np.arange(steps) * c.dt
        self.rows = {name: np.zeros((steps, 2)) for name in
                     ('q', 'dq', 'position', 'target', 'tau', 's')}
        self.scalars = {name: np.zeros(steps) for name in
                        ('distance', 'lyapunov', 'lyapunov_rate', 'task_potential', 'weight',
                         'weight_rate', 'damping')}
        self.theta_hat = np.zeros((steps, theta_true.size))
        self.torque_limited = np.zeros(steps, dtype=bool)
        self.fault = np.zeros(steps, dtype=bool)
        self.phase = np.empty(steps, dtype=object)
        self.active_task = np.empty(steps, dtype=object)
        self.drives = np.full(steps, None, dtype=object)  # the lean path's drive per step

    def _hand_at(self, t: float) -> TargetSample:
        """The target as the controller sees it at t (s): exact, or through HandHold."""
        x_d, xdot_d, xddot_d = self.target(t)
        hand = self.hand
        if hand is not None:
            if t >= self.next_target - 1e-9 * self.conditions.dt:
                if math.isfinite(x_d[0]) and math.isfinite(x_d[1]):  # a lost frame: nothing
                    hand.offer(float(t), tuple(x_d.tolist()))
                self.next_target += self.conditions.target_period
            held = hand.evaluate(float(t))
            if held is None:  # no hand accepted yet: where the first sample is
                held = (tuple(x_d.tolist()), (0.0, 0.0))
            self.presence = hand.presence(float(t))
            x_d, xdot_d, xddot_d = np.array(held[0]), np.array(held[1]), np.zeros(2)
        return x_d, xdot_d, xddot_d

    def step(self, i: int, t: float) -> None:
        """Control period i at time t (s): events, a(E, t), the law, the rate limit, the
        record of row i, and the arm's RK4 step over dt with the applied torque."""
        c = self.conditions
        dt, params, q, dq = c.dt, c.params, self.q, self.dq
        pending = self.pending_events
        while self.event_index < len(pending) and pending[self.event_index][0] <= t:
            event_time, name = pending[self.event_index]
            self.schedule.request(name, max(event_time, 0.0))
            self.event_index += 1
        weight = self.schedule.evaluate(t)
        name = weight.active_task
        shape = None if name is None else self.tasks[name]
        if name != self.rest_task:  # a task became active: its rest position is here
            self.rest_task = name
            self.rest = self.fixed_rest if self.fixed_rest is not None else forward_kinematics(
                np.array(q), params.l1, params.l2)
        rest = self.rest
        x_d, xdot_d, xddot_d = self._hand_at(t)
        presence = self.presence
        if presence is not None and presence.weight < 1.0:
            # a times the hand's presence (as the node): both C2 ramps, so is their product.
            weight = weight._replace(
                weight=weight.weight * presence.weight,
                rate=weight.rate * presence.weight + weight.weight * presence.rate)
            if weight.weight == 0.0:
                shape = None
        k = self.gains_k.get(name, 0.0)
        if c.reference_step:
            out = self.controller.step(
                np.array(q), np.array(dq), x_d, xdot_d, xddot_d, weight.weight, weight.rate,
                shape, dt, theta_true=self.theta_true, friction=self.friction,
                monitor=c.monitor, k=k, rest=rest)
        else:
            # Q for the whole run at once after the loop (task_potentials): one quadrature per
            # step cost about as much as the rest of the step.
            out = self.controller.step_lean(
                q, dq, tuple(x_d.tolist()),
                tuple(xdot_d.tolist()), tuple(xddot_d.tolist()), weight.weight, weight.rate,
                shape, dt, monitor=c.monitor, theta_true=self.theta_true,
                friction=self.friction, k=k,
                rest=None if rest is None else tuple(rest.tolist()), with_potential=False)
            if c.monitor and not out.fault and shape is not None:
                self.drives[i] = self.controller.drive(shape, k)
        # The rate limit after the clamp; a fault's zero torque bypasses it (as in the node).
        if out.fault:
            self.limiter.reset()
            command = np.zeros(2)
        else:
            command = np.array(self.limiter.limit(tuple(out.tau.tolist()) if isinstance(
                out.tau, np.ndarray) else out.tau, dt)[0])
        self.in_flight.append(command)
        applied = self.in_flight.pop(0)
        self._record(i, out, weight, x_d, applied)
        state = rk4_step_floats((*q, *dq), applied.tolist(), dt, self.constants)
        if not all(map(math.isfinite, state)):
            raise ValueError(f'the arm\'s state became non-finite at t = {t:.3f} s: {state}')
        q1, q2, w1, w2 = state
        stops = c.stops
        if stops is not None:  # scara_sim's inelastic stop (simulation.clamp_to_joint_limits)
            (low1, low2), (high1, high2) = stops.lower, stops.upper
            if q1 <= low1 or q1 >= high1:
                w1 = 0.0 if (q1 <= low1 and w1 < 0.0) or (q1 >= high1 and w1 > 0.0) else w1
                q1 = min(max(q1, low1), high1)
            if q2 <= low2 or q2 >= high2:
                w2 = 0.0 if (q2 <= low2 and w2 < 0.0) or (q2 >= high2 and w2 > 0.0) else w2
                q2 = min(max(q2, low2), high2)
        self.q, self.dq = (q1, q2), (w1, w2)

    def _record(self, i: int, out, weight, x_d, applied) -> None:
        c, q, rows, scalars = self.conditions, self.q, self.rows, self.scalars
        params = c.params
        rows['q'][i], rows['dq'][i], rows['target'][i] = q, self.dq, x_d
        rows['tau'][i], rows['s'][i] = applied, out.s
        if not out.fault:
            rows['position'][i] = forward_kinematics_pair(*q, params.l1, params.l2)
            scalars['damping'][i] = (pseudo_inverse_damping(jacobian(q, params.l1, params.l2),
                                                            c.gains.damping)[0]
                                     if c.reference_step else out.damping)
        scalars['distance'][i] = np.nan if out.distance is None else out.distance
        for name, value in (('lyapunov', out.lyapunov), ('lyapunov_rate', out.lyapunov_rate),
                            ('task_potential', out.task_potential)):
            scalars[name][i] = np.nan if value is None else value
        if c.monitor and not c.reference_step and not out.fault:
            scalars['task_potential'][i] = 0.0  # the task's Q is added after the loop
        scalars['weight'][i], scalars['weight_rate'][i] = weight.weight, weight.rate
        self.theta_hat[i] = out.theta_hat
        self.torque_limited[i], self.fault[i] = out.torque_limited, out.fault
        self.phase[i], self.active_task[i] = weight.phase, weight.active_task

    def result(self) -> SimulationResult:
        """The recorded run, with the task terms of V and dV/dt for all its steps at once."""
        scalars, drives, kp = self.scalars, self.drives, self.conditions.gains.kp
        for drive in set(drives[drives != None]):  # noqa: E711 (elementwise)
            steps_of = np.flatnonzero(drives == drive)
            potential = task_potentials(scalars['distance'][steps_of], drive)
            scalars['task_potential'][steps_of] = potential
            scalars['lyapunov'][steps_of] += kp * scalars['weight'][steps_of] * potential
            scalars['lyapunov_rate'][steps_of] += (kp * scalars['weight_rate'][steps_of]
                                                   * potential)
        return SimulationResult(
            time=self.time, **self.rows, **scalars, phase=self.phase,
            active_task=self.active_task, theta_hat=self.theta_hat,
            torque_limited=self.torque_limited, fault=self.fault,
            theta_true=self.theta_true,
            task_gains={name: self.controller.task_gain(shape, self.gains_k.get(name, 0.0))
                        for name, shape in self.tasks.items()})


def simulate(tasks: Mapping[str, TaskShape], events: Sequence[tuple[float, str | None]],
             target: TargetTrajectory, duration: float,
             conditions: LoopConditions = LoopConditions()) -> SimulationResult:
    """Run the closed loop for `duration` s with control period and integration step
    conditions.dt (s).

    tasks: task name -> TaskShape; events: (time s, task name or None) that switch tasks
    through a(E, t) (eq. 13); target: t -> (x_d, xdot_d, xddot_d); conditions: the arm, the
    gains and the loop's timing (LoopConditions).
    Raises ValueError for unknown task names or bad values.
    """
    run = _Run(tasks, events, target, duration, conditions)
    for i, t in enumerate(run.time):
        run.step(i, t)
    return run.result()
