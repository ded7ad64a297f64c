"""Pure-Python closed loop: event weight + adaptive controller + any arm's dynamics, no ROS.

Each control period dt (s) the loop takes the events due, evaluates a(E, t) (event_weight,
eq. 13), samples the target trajectory, computes the torque of eq. 16 (arm_law.ArmController),
limits its rate (effort_rate, gains.max_effort_rate, as the controller node), advances
theta_hat by eq. 19 unless the limit changed the torque (as the node), and integrates the true
arm (RobotModel.rk4_step of the model's forward dynamics, eq. 15, torque held over the
step). The arm is any RobotModel: the SCARA (the default), the Panda or a URDF arm; the
controller knows a nominal model and starts from a wrong estimate where asked. It is what the
unit tests and the benchmarks run; the ROS nodes run the same library against topics.

Three options bring the topics' timing into the pure loop: `target_period` samples the hand
like hand_sim's /target messages, which the controller sees through its own hold
(target_filter.FilteredHand: velocity estimate, first-order hold, blend), `command_delay`
applies each command that many periods after the state it was computed from (a loop that is
late, as the controller node on a loaded machine), and `control_period` runs the controller
on every so many joint states only (the node takes the newest joint state: on a loaded
machine it computed 2866 commands from 5986 states in one 6 s run of the UR10).

Targets are callables t -> (x_d, xdot_d, xddot_d) in m, m/s, m/s^2 on the arm's task axes
(shapes (k,): 2 for the SCARA, 3 for a spatial arm; a longer point is cut to the task axes);
events are (time in s, task name or None) pairs, the task names keys of `tasks`. An avoid
task (task_variable.open_outward) returns the arm to its rest position: `rest_position`, or
by default where the tool was when the task became active (as the controller node).
"""

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from hri_adaptive_controller.arm_law import (
    ActiveTask,
    ArmController,
    ArmGains,
    HandState,
    default_gains,
)
from hri_adaptive_controller.effort_rate import EffortRateLimiter
from hri_adaptive_controller.event_weight import EventWeightSchedule, quintic_smoothstep
from hri_adaptive_controller.target_filter import FilteredHand, TargetFilterSettings
from hri_adaptive_controller.task_variable import task_potentials
from hri_core.bodies import (
    Capsules,
    RobotBody,
    body_point_velocities,
    capsule_distances,
    human_capsules,
)
from hri_core.potential import TaskShape
from hri_core.robot_model import RobotModel, ScaraModel

TargetSample = tuple[np.ndarray, np.ndarray, np.ndarray]
TargetTrajectory = Callable[[float], TargetSample]
BodyTrajectory = Callable[[float], Capsules | None]

PEAK_RATIO = 1.875  # peak speed of a minimum-jerk move over its mean speed


def _point(value, what: str) -> np.ndarray:
    """`value` as a finite point (k,) m; ValueError with the reason otherwise."""
    point = np.asarray(value, dtype=float)
    if point.ndim != 1 or point.size not in (2, 3) or not np.all(np.isfinite(point)):
        raise ValueError(f'{what} must be 2 or 3 finite values (m), got {value}')
    return point


def still_target(point) -> TargetTrajectory:
    """A target that stays at `point` (k,) m: zero velocity and acceleration."""
    point = _point(point, 'point')
    zero = np.zeros(point.size)
    return lambda t: (point.copy(), zero.copy(), zero.copy())


def minimum_jerk_target(start, end, start_time: float, duration: float) -> TargetTrajectory:
    """A target at `start` (k,) m until start_time (s), then a minimum-jerk move to `end`.

    x_d = start + (end - start) s(u), u = (t - start_time) / duration, s the quintic
    smoothstep: x_d, xdot_d and xddot_d are continuous; peak speed 15/8 |end - start| /
    duration (m/s).
    """
    start, end = _point(start, 'start'), _point(end, 'end')
    if start.size != end.size:
        raise ValueError(f'start and end must have the same size, got {start} and {end}')
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
    """A hand that starts at `start` (k,) m and makes minimum-jerk moves one after another.

    moves: (start time s, end point (k,) m, peak speed m/s) each, in time order, each starting
    where the previous one ended (and not before it ended). Between moves the hand is still.
    """
    point = _point(start, 'start')
    segments = []
    for start_time, end, speed in moves:
        end = _point(end, 'end')
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

    time (N,) s; q, dq (N, n) rad, rad/s; position, target (N, k) m on the task axes; tau
    (N, n) N m (applied); s (N, n) rad/s; distance (N,) m; lyapunov V (N,) J (eq. 21 with the
    true parameters);
    lyapunov_rate (N,) W, eq. 22's prediction; task_potential Q (N,) m^2/s (these three are
    NaN when the run was not monitored, and distance is NaN on a fault); weight a and
    weight_rate da/dt (N,); phase (N,) str; active_task (N,) object (name or None);
    theta_hat (N, p); torque_limited, fault (N,) bool; damping lambda^2 (N,); blend (N,):
    the reach-round's weight sigma in [0, 1] (arm_law's module docstring);
    theta_true (p,); task_gains: k (m^2/s) per task name; body_distance (N,) m: the smallest
    distance between a robot capsule and a human capsule (None without a body).
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
    blend: np.ndarray
    theta_true: np.ndarray
    task_gains: dict
    body_distance: np.ndarray | None = None


@dataclass(frozen=True)
class LoopConditions:
    """Everything about one closed-loop run but its tasks, events, hand and duration.

    arm: the true arm the loop integrates (a RobotModel; default the SCARA); model: the
    controller's nominal model (None: the arm's); theta_hat0 (p,) or None: the controller's
    initial estimate (None: the model's nominal theta); gains: ArmGains (None:
    arm_law.default_gains(model)); q0, dq0 (n,) or None: initial joint state (rad, rad/s;
    None: the model's home, at rest); initial_task: active at t = 0 with a = 1 (or None:
    idle); ramp_time (s) of a full fade; dt (s): control period and integration step;
    monitor: compute V and dV/dt (the radial integral of Q is added for all steps at once);
    task_gains: task name -> K (m^2/s; missing or 0 = default_task_gain); rest_position (k,)
    m or None; compiled: the law's compiled kernels (the node's path) or its numpy reference.
    target_period (s) or None: the controller sees the target only every target_period s,
    as positions (the node's /target), through the node's glitch filter and hold
    (target_filter.FilteredHand with target_filter, its filter_time and max_extrapolation set
    from target_filter_time and max_target_extrapolation), and a is multiplied by the hand's
    presence weight (a lost hand fades the task out); None: the exact target. command_delay
    (periods >= 0): the torque computed from the state at step k acts from step k +
    command_delay on (zero before the first). control_period (periods >= 1): the controller
    takes the state of every control_period-th step only and its command holds until the
    next; as the node, theta_hat advances by the time between the states it took and each
    command moves at most one period's worth (effort_rate); the rows of the steps between
    repeat the controller's last outputs (q, dq and the applied tau are the arm's). stops: an
    inelastic stop at the arm's joint limits as the simulators': a joint at a limit keeps only
    velocity that leaves it. body: the person over time (still_body, recorded_body; None:
    none), which the law keeps every robot capsule clear of when robot_body
    (hri_core.bodies.RobotBody of the model) is given; the smallest robot-person distance is
    recorded either way (SimulationResult.body_distance). plant: another engine integrating
    the arm in place of RobotModel.rk4_step and the stops (None: those): an object with
    ArmSimulator's `step(mode, command, wrench)` contract (q, dq and the applied torque as
    tuples after one step of dt) and its `q`, `dq` as the start (q0, dq0 then unused), e.g.
    scara_sim's MujocoArmSimulator; with a body and the plant's `touches_bodies`, each new
    body sample goes to its `set_body(capsules, over=dt)` (the person in its scene).
    """

    arm: RobotModel = field(default_factory=ScaraModel)
    model: RobotModel | None = None
    theta_hat0: Sequence[float] | None = None
    gains: ArmGains | None = None
    q0: Sequence[float] | None = None
    dq0: Sequence[float] | None = None
    initial_task: str | None = None
    ramp_time: float = 1.0
    dt: float = 1e-3
    monitor: bool = True
    task_gains: Mapping[str, float] | None = None
    rest_position: Sequence[float] | None = None
    compiled: bool = True
    target_period: float | None = None
    target_filter_time: float = 0.05
    max_target_extrapolation: float = 0.05
    command_delay: int = 0
    control_period: int = 1
    target_filter: TargetFilterSettings = field(default_factory=TargetFilterSettings)
    stops: bool = True
    body: BodyTrajectory | None = None
    robot_body: RobotBody | None = None
    plant: object | None = None


def still_body(names, points) -> BodyTrajectory:
    """A person standing still: REP-155 body point names (K,) and points (K, 3) m."""
    capsules = human_capsules(names, points)
    return lambda t: capsules


def recorded_body(times, names, points) -> BodyTrajectory:
    """A recorded person: the latest frame at or before t of `points` (N, K, 3) m at `times`
    (N,) s, named `names` (K,), its points' velocities from the frame before
    (bodies.body_point_velocities, as the controller takes them from two /human/body
    messages); a point lost in a frame (NaN) is left out of it (and with it its capsules),
    as hand_sim's /human/body leaves it out."""
    times = np.asarray(times, dtype=float)
    points = np.asarray(points, dtype=float)
    cache: dict[int, Capsules] = {}

    def sample(t: float) -> Capsules:
        index = max(int(np.searchsorted(times, t, side='right')) - 1, 0)
        if index not in cache:
            cache.clear()
            seen = np.all(np.isfinite(points[index]), axis=1)
            kept = [n for n, k in zip(names, seen, strict=True) if k]
            before = {} if index == 0 else {
                name: point for name, point in zip(names, points[index - 1], strict=True)
                if np.all(np.isfinite(point))}
            cache[index] = human_capsules(kept, points[index][seen], velocities=(
                body_point_velocities(kept, points[index][seen], before,
                                      float(times[index] - times[max(index - 1, 0)]))))
        return cache[index]

    return sample


def recorded_target(times, positions) -> TargetTrajectory:
    """A recorded hand: the latest sample at or before t of `positions` (N, k) m at `times`
    (N,) s (increasing); a lost frame (a NaN row) stays NaN, and the loop's hold
    (LoopConditions.target_period) then offers nothing, like hand_sim publishing nothing.
    Before the first sample, the first; velocity and acceleration are not known (NaN)."""
    times = np.asarray(times, dtype=float)
    xy = np.array(positions, dtype=float)
    if times.ndim != 1 or len(times) != len(xy) or len(times) == 0:
        raise ValueError(f'need matching non-empty times and positions, got {times.shape} '
                         f'and {xy.shape}')
    seen = np.flatnonzero(np.all(np.isfinite(xy), axis=1))
    if seen.size == 0:
        raise ValueError('the recorded hand is never seen')
    xy[:seen[0]] = xy[seen[0]]  # before the hand is first seen: where it is first seen
    unknown = np.full(xy.shape[1], math.nan)

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
        if int(c.control_period) != c.control_period or c.control_period < 1:
            raise ValueError(f'control_period must be an integer >= 1, got {c.control_period}')
        self.arm = arm = c.arm
        model = arm if c.model is None else c.model
        n, self.axes = arm.dof, model.task_axes
        self.theta_true = arm.theta.copy()
        self.gains = gains = default_gains(model) if c.gains is None else c.gains
        self.controller = ArmController(model, gains, c.theta_hat0, compiled=c.compiled,
                                        body=c.robot_body)
        self.controller.finish_cycle()  # its solves after each command, as the node's
        self.conditions, self.tasks, self.target = c, tasks, target
        self.hand = None if c.target_period is None else FilteredHand(dataclasses.replace(
            c.target_filter, filter_time=c.target_filter_time,
            max_extrapolation=c.max_target_extrapolation), self.axes)
        self.presence = None
        self.next_target = 0.0
        self.limiter = EffortRateLimiter(gains.max_effort_rate, n)
        self.in_flight = [np.zeros(n)] * int(c.command_delay)
        self.command = np.zeros(n)  # the controller's last command, held between its cycles
        self.pending_events = sorted(events, key=lambda event: event[0])
        self.event_index = 0
        self.schedule = EventWeightSchedule(c.ramp_time, c.initial_task)
        self.friction = arm.friction_torque(np.ones(n))  # viscous: F's diagonal
        if c.plant is not None:
            self.q, self.dq = np.array(c.plant.q, dtype=float), np.array(c.plant.dq, dtype=float)
        else:
            self.q = model.home.copy() if c.q0 is None else arm.joint_vector(c.q0, 'q0')
            self.dq = np.zeros(n) if c.dq0 is None else arm.joint_vector(c.dq0, 'dq0')
        self.plant_body = None  # the body sample the plant was last given
        self.lower, self.upper = arm.limits.lower, arm.limits.upper
        self.gains_k = dict(c.task_gains or {})
        self.fixed_rest = (None if c.rest_position is None
                           else _point(c.rest_position, 'rest')[:self.axes])
        self.rest, self.rest_task = self.fixed_rest, None
        steps = int(round(duration / c.dt))
        self.time = np.arange(steps) * c.dt
        self.rows = {name: np.zeros((steps, n)) for name in ('q', 'dq', 'tau', 's')}
        self.rows.update({name: np.zeros((steps, self.axes)) for name in ('position', 'target')})
        self.scalars = {name: np.zeros(steps) for name in
                        ('distance', 'lyapunov', 'lyapunov_rate', 'task_potential', 'weight',
                         'weight_rate', 'damping', 'blend')}
        self.theta_hat = np.zeros((steps, self.theta_true.size))
        self.body_distance = None if c.body is None else np.full(steps, np.inf)
        self.torque_limited = np.zeros(steps, dtype=bool)
        self.fault = np.zeros(steps, dtype=bool)
        self.phase = np.empty(steps, dtype=object)
        self.active_task = np.empty(steps, dtype=object)
        self.drives = np.full(steps, None, dtype=object)  # each step's task drive (monitor)

    def _hand_at(self, t: float) -> TargetSample:
        """The target as the controller sees it at t (s): exact, or through the node's
        hold."""
        x_d, xdot_d, xddot_d = (value[:self.axes] for value in self.target(t))
        hand = self.hand
        if hand is not None:
            if t >= self.next_target - 1e-9 * self.conditions.dt:
                if np.all(np.isfinite(x_d)):  # a lost frame: nothing
                    hand.offer(float(t), tuple(x_d.tolist()))
                self.next_target += self.conditions.target_period
            held = hand.evaluate(float(t))
            if held is None:  # no hand accepted yet: where the first sample is
                held = (tuple(x_d.tolist()), (0.0,) * self.axes)
            self.presence = hand.presence(float(t))
            x_d, xdot_d, xddot_d = np.array(held[0]), np.array(held[1]), np.zeros(self.axes)
        return x_d, xdot_d, xddot_d

    def step(self, i: int, t: float) -> None:
        """Control period i at time t (s): on the controller's cycles events, a(E, t), the law,
        the rate limit and eq. 19; the record of row i; and the arm's RK4 step over dt with the
        applied torque."""
        c = self.conditions
        if i % c.control_period == 0:
            self._control(i, t)
        else:
            self._repeat(i)
        self.in_flight.append(self.command)
        applied = self.in_flight.pop(0)
        self.rows['q'][i], self.rows['dq'][i], self.rows['tau'][i] = self.q, self.dq, applied
        q, dq, dt = self.q, self.dq, c.dt
        if c.plant is not None:
            self.q, self.dq = self._plant_step(t, applied)
            return
        q_next, dq_next = self.arm.rk4_step(q, dq, applied, dt)
        if not (np.all(np.isfinite(q_next)) and np.all(np.isfinite(dq_next))):
            raise ValueError(f'the arm\'s state became non-finite at t = {t:.3f} s')
        if c.stops:  # the simulators' inelastic stop (simulation.clamp_to_joint_limits)
            low, high = q_next <= self.lower, q_next >= self.upper
            if low.any() or high.any():
                dq_next = np.where((low & (dq_next < 0.0)) | (high & (dq_next > 0.0)), 0.0,
                                   dq_next)
                q_next = np.clip(q_next, self.lower, self.upper)
        self.q, self.dq = q_next, dq_next

    def _plant_step(self, t: float, applied: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The plant's step over dt with the applied torque, the person moved in its scene
        first when the body has a new sample."""
        c = self.conditions
        if c.body is not None and getattr(c.plant, 'touches_bodies', False):
            human = c.body(t)
            if human is not self.plant_body:
                c.plant.set_body(human, over=c.dt)
                self.plant_body = human
        q, dq, _ = c.plant.step('effort', tuple(applied.tolist()), (0.0,) * 6)
        return np.array(q), np.array(dq)

    def _control(self, i: int, t: float) -> None:
        """The controller's cycle at step i, time t (s): its command (self.command) and the
        record of its outputs in row i."""
        c, controller = self.conditions, self.controller
        dt, q, dq = c.dt, self.q, self.dq
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
            self.rest = (self.fixed_rest if self.fixed_rest is not None
                         else controller.model.task_kinematics(q, dq)[0])
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
        task = None if shape is None else ActiveTask(shape, weight.weight, weight.rate, k)
        human = None if c.body is None else c.body(t)
        # theta_hat advances by the time between the states the controller took (the node's
        # stamp difference).
        out = controller.command(q, dq, HandState(x_d, xdot_d, xddot_d), task,
                                 dt * c.control_period, self.rest,
                                 human if c.robot_body is not None else None)
        if human is not None and len(human) and c.robot_body is not None:
            body = c.robot_body
            self.body_distance[i] = float(capsule_distances(
                body.capsules(q, checked=False), human, planar=body.planar).distance.min())
        # The rate limit after the clamp, one period's worth per command; a fault's zero torque
        # bypasses it (as in the node).
        if out.fault:
            self.limiter.reset()
            command = np.zeros(q.size)
        else:
            command, limited = self.limiter.limit(tuple(out.tau.tolist()), dt)
            command = np.array(command)
            # eq. 19 only for a torque the arm gets, as the node (ArmController.adapt); a
            # non-finite update leaves theta_hat as it was (the node warns).
            controller.adapt(applied=not limited)
            if c.monitor:
                # V and dV/dt without the task's Q: added for all steps at once (result()).
                self.scalars['lyapunov'][i] = controller.lyapunov(out, q, task, self.arm,
                                                                  with_task=False)
                self.scalars['lyapunov_rate'][i] = controller.lyapunov_rate(
                    out, task, self.friction, with_task=False)
                if task is not None:
                    self.drives[i] = controller.drive(shape, k)
        controller.finish_cycle()  # as the node, after its command
        self.command = command
        self._record(i, out, weight, x_d)

    def _repeat(self, i: int) -> None:
        """Row i between the controller's cycles: its outputs of the last cycle (row i - 1)."""
        for rows in (self.rows, self.scalars):
            for values in rows.values():
                values[i] = values[i - 1]
        for values in (self.theta_hat, self.torque_limited, self.fault, self.phase,
                       self.active_task, self.drives, self.body_distance):
            if values is not None:
                values[i] = values[i - 1]

    def _record(self, i: int, out, weight, x_d) -> None:
        rows, scalars = self.rows, self.scalars
        rows['target'][i], rows['s'][i] = x_d, out.s
        if not out.fault:
            rows['position'][i] = out.position
            scalars['damping'][i] = out.damping
            scalars['blend'][i] = out.blend
        else:
            scalars['lyapunov'][i] = scalars['lyapunov_rate'][i] = np.nan
        if not self.conditions.monitor:
            scalars['lyapunov'][i] = scalars['lyapunov_rate'][i] = np.nan
            scalars['task_potential'][i] = np.nan
        scalars['distance'][i] = np.nan if out.distance is None else out.distance
        scalars['weight'][i], scalars['weight_rate'][i] = weight.weight, weight.rate
        self.theta_hat[i] = out.theta_hat
        self.torque_limited[i], self.fault[i] = out.torque_limited, out.fault
        self.phase[i], self.active_task[i] = weight.phase, weight.active_task

    def truncate(self, steps: int) -> None:
        """Keep the first `steps` rows of every recorded series (a run ended early)."""
        self.time = self.time[:steps]
        for rows in (self.rows, self.scalars):
            for name, values in rows.items():
                rows[name] = values[:steps]
        for name in ('theta_hat', 'body_distance', 'torque_limited', 'fault', 'phase',
                     'active_task', 'drives'):
            values = getattr(self, name)
            if values is not None:
                setattr(self, name, values[:steps])

    def result(self) -> SimulationResult:
        """The recorded run, with the task terms of V and dV/dt for all its steps at once."""
        scalars, drives, kp = self.scalars, self.drives, self.gains.kp
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
            theta_true=self.theta_true, body_distance=self.body_distance,
            task_gains={name: self.controller.task_gain(shape, self.gains_k.get(name, 0.0))
                        for name, shape in self.tasks.items()})


def simulate(tasks: Mapping[str, TaskShape], events: Sequence[tuple[float, str | None]],
             target: TargetTrajectory, duration: float,
             conditions: LoopConditions = LoopConditions(),
             until: Callable[[float, float], bool] | None = None) -> SimulationResult:
    """Run the closed loop for `duration` s with control period and integration step
    conditions.dt (s).

    tasks: task name -> TaskShape; events: (time s, task name or None) that switch tasks
    through a(E, t) (eq. 13); target: t -> (x_d, xdot_d, xddot_d); conditions: the arm, the
    gains and the loop's timing (LoopConditions). until: (t s, the step's task distance m)
    -> True ends the run after that step, its result holding the steps run (e.g. once the
    arm is in its region).
    Raises ValueError for unknown task names or bad values.
    """
    run = _Run(tasks, events, target, duration, conditions)
    distance = run.scalars['distance']
    for i, t in enumerate(run.time):
        run.step(i, t)
        if until is not None and until(t, distance[i]):
            run.truncate(i + 1)
            break
    return run.result()
