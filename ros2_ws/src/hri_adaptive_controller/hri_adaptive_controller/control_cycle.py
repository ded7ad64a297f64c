"""What the controller does with each input, without ROS: `ControlCycle`.

The controller node (controller_node) reads messages and parameters, publishes and keeps the
timers; everything it decides on an input is here. Each method takes `now`, the caller's
monotonic time (s), and the message stamps (s on the source's clock): the cycle keeps no clock
of its own, so a test drives it on a simulated clock and gets the node's behaviour exactly.
What there is to log is handed to `note` as a Note(level, kind, text): kind None for a line
logged each time it comes (an outage's one warning, a restart), else the kind of a problem the
node throttles (one line per kind every few seconds).

Use, for a joint state:

    command = cycle.joint_state(now, q, dq, stamp, effort)   # None: dropped (noted)
    ... publish command ...
    report = cycle.sent(now, published)   # the ControllerState when due (None otherwise)

and while joint states are missing or stale: `watchdog(now)` every watchdog_period says when
to start calling `hold(now)` every period, which returns the hold's command, () before any
joint state (nothing to send), or None once joint states pace the cycles again; each hold
command is followed by `sent` too.

Safety (the choices are argued in docs/design.md):
- no command before the first joint state (an arm's brakes hold it; the first command then
  starts from the gravity hold where it is, not from zero); older than `joint_state_timeout` (one
  warning per outage, one info line when they resume) the arm is held against gravity at
  the last one, Y(q, 0, 0, 0) theta_hat reached at the effort rate (zero torque would drop
  an arm under gravity; the horizontal SCARA's is zero). A watchdog call more than two
  watchdog periods after the previous one (the node itself starved) starts nothing: the
  joint states may be waiting in its queue, not late. Non-finite joint states are dropped
  (the node drops wrong lengths and unknown names), and so are stamps going backwards;
- a source restart is recognised (hri_core.stamp_gate): joint states or targets whose stamps
  are more than `restart_jump` s behind the last used one are followed once
  `restart_confirm` of them have advanced, and noted;
- no target yet: the arm is held where it is, no task force; non-finite targets, or farther
  than `max_target_distance` from the base, are dropped;
- no TaskState yet means a = 0; none for `task_state_timeout` s (event_manager gone: it
  publishes a heartbeat) fades the task out over `task_fade_time` with eq. 13's C2 ramp (a
  second weight on a, the link's, so no torque step), and TaskStates coming again fade it back
  in; with a = 0 the arm is kept damped (Ks s with qdot_r = J+ xdot_d) but no task force acts;
- a(E, t) is held between TaskStates from their stamps and a TaskState that lands off the
  held value (one after a gap: the event_manager starved on a loaded machine) is blended in
  at `task_fade_time` per unit of a, a missed swap faded out first (signal_hold.
  TaskWeightHold), so a never jumps;
- the hand (target_filter.FilteredHand): its velocity from the /target stamps, held to first
  order between targets (at most MAX_TARGET_EXTRAPOLATION s) and each new one blended in; a
  /target no hand could have reached is held, not followed, and counted (target_glitches),
  a place held samples keep to for 0.2 s re-anchored and glided to; no /target accepted for
  `target_timeout` s fades the task out over `task_fade_time` (status target_lost), and in
  again when the hand returns. a = a_task a_link a_hand, each a C2 ramp;
- the task's K comes with its TaskState (0: hri_core.potential.default_task_gain); an avoid
  task returns the arm to `rest_position`, by default where the tool was when the task became
  active;
- the command's change since the last one is at most the law's max_effort_rate times the time
  between their joint states, at most one period, and (effort mode) it stays within
  `applied_effort_cycles` periods' worth of the effort the joint state reports when that
  effort is a command sent before (effort_rate.CommandEcho); zero torque bypasses the limit;
  theta_hat does not adapt (eq. 19) on a cycle whose command either limit changed;
- with a `separation` (ISO/TS 15066's S_p constants) the task's pull towards the hand is
  capped from each separation (separation_cap), 0 while none is recent; and the point of the
  arm nearest the person (the separation's pair: a link's point and the body's, or the tool
  and the hand) moves towards the person at most at the speed S_p allows,
  (1 + CAP_BAND) times the knee, while the cap acts (ArmController.limit_approach: the
  reference loses the excess along that point's normal, whatever asked for it: the pull,
  the hand's velocity fed forward, the null space, the body's barrier);
- deadline misses: commands sent later than 1.5 periods after their joint state's stamp
  (`sent`'s published time, on the stamps' clock); ControllerState goes out with the first
  cycle after each 1/`state_rate_hz` s, which alone computes V once the command is out.
No ROS import.
"""

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from hri_adaptive_controller.arm_law import ActiveTask, ArmController, ArmOutput, HandState
from hri_adaptive_controller.effort_rate import CommandEcho, EffortRateLimiter
from hri_adaptive_controller.event_weight import (
    PHASE_ACTIVE,
    PHASE_FADING_IN,
    PHASE_FADING_OUT,
    PHASE_IDLE,
    EventWeightSchedule,
    WeightState,
)
from hri_adaptive_controller.separation_cap import SeparationCap
from hri_adaptive_controller.signal_hold import TaskWeightHold
from hri_adaptive_controller.target_filter import FilteredHand, TargetFilterSettings
from hri_adaptive_controller.task_variable import CAP_BAND
from hri_core.bodies import (
    RobotBody,
    body_point_velocities,
    human_capsules,
    seen_body_points,
)
from hri_core.potential import TaskShape
from hri_core.separation import ProtectiveSeparation
from hri_core.stamp_gate import DROPPED, RESTARTED, StampGate
from hri_core.validation import check_frame

LATE_FACTOR = 1.5  # a command later than 1.5 periods after its joint state is a deadline miss
WATCHDOG_CHECKS = 4  # watchdog checks per joint_state_timeout
MAX_WEIGHT_EXTRAPOLATION = 0.05  # s: longest first-order hold of a(E, t) between TaskStates
# s: longest first-order hold of the hand between /target messages (100 Hz): a hand at
# 0.5 m/s moves 5 mm between two, which as a staircase steps the task term (and the torque,
# by several N m) at each message.
MAX_TARGET_EXTRAPOLATION = 0.05
LINK = 'task_states'  # the link weight's one task: TaskStates arriving
LINK_DOWN = WeightState(0.0, 0.0, 0.0, PHASE_IDLE, None, None)
INFO, WARNING = 'info', 'warning'


class Note(NamedTuple):
    """A line to log: level INFO or WARNING; kind None (log it) or the kind of problem the
    node throttles; text."""

    level: str
    kind: str | None
    text: str


class TaskInput(NamedTuple):
    """A TaskState's task: name ('' for none), the shape's s, a1, a2, d1, d2, n and the gain
    k (0: the default). Also the key that tells tasks apart."""

    name: str
    s: float
    a1: float
    a2: float
    d1: float
    d2: float
    n: int
    k: float


@dataclass(frozen=True)
class CycleSettings:
    """The cycle's settings (the controller's parameters of the same names; the law's gains,
    max_effort_rate and max_task_speed among them, come with the law). rest_position: an avoid
    task's fixed rest on the task axes (m; None: where the tool was when the task became
    active); separation: S_p's constants for the pull cap (None: no cap); base_frame: the
    frame of the hand and the body (a message in another frame is dropped; '' is taken as
    this one)."""

    rate_hz: float
    state_rate_hz: float
    velocity_mode: bool
    applied_effort_cycles: int
    joint_state_timeout: float
    task_state_timeout: float
    task_fade_time: float
    restart_jump: float
    restart_confirm: int
    max_target_distance: float
    target_max_speed: float
    target_max_acceleration: float
    target_filter_time: float
    target_timeout: float
    rest_position: tuple[float, ...] | None = None
    separation: ProtectiveSeparation | None = None
    body_timeout: float = 0.5
    base_frame: str = 'base'

    @classmethod
    def from_values(cls, values: Mapping, rest_position: tuple[float, ...] | None = None,
                    separation: ProtectiveSeparation | None = None) -> 'CycleSettings':
        """The settings from the controller's parameter values (a dict by name)."""
        return cls(rate_hz=values['rate_hz'], state_rate_hz=values['state_rate_hz'],
                   velocity_mode=values['mode'] == 'velocity',
                   applied_effort_cycles=values['applied_effort_cycles'],
                   joint_state_timeout=values['joint_state_timeout'],
                   task_state_timeout=values['task_state_timeout'],
                   task_fade_time=values['task_fade_time'],
                   restart_jump=values['restart_jump'],
                   restart_confirm=values['restart_confirm'],
                   max_target_distance=values['max_target_distance'],
                   target_max_speed=values['target_max_speed'],
                   target_max_acceleration=values['target_max_acceleration'],
                   target_filter_time=values['target_filter_time'],
                   target_timeout=values['target_timeout'],
                   rest_position=rest_position, separation=separation,
                   base_frame=values['base_frame'])

    @property
    def period(self) -> float:
        """s: one control period, 1 / rate_hz."""
        return 1.0 / self.rate_hz

    @property
    def watchdog_period(self) -> float:
        """s between watchdog calls: joint_state_timeout / WATCHDOG_CHECKS."""
        return self.joint_state_timeout / WATCHDOG_CHECKS

    def hand_settings(self) -> TargetFilterSettings:
        """The hand filter's settings (target_filter)."""
        return TargetFilterSettings(
            max_speed=self.target_max_speed, max_acceleration=self.target_max_acceleration,
            filter_time=self.target_filter_time, max_extrapolation=MAX_TARGET_EXTRAPOLATION,
            timeout=self.target_timeout, fade_time=self.task_fade_time)


@dataclass
class CycleReport:
    """What a ControllerState reports (its fields of the same names; 0 where not known)."""

    deadline_misses: int
    rate_hz: float
    input_age: float
    target_glitches: int
    status: str
    effort: tuple[float, ...]
    theta_hat: np.ndarray
    task: str = ''
    distance: float = 0.0
    lyapunov: float = 0.0
    sliding_norm: float = 0.0
    weight: float = 0.0
    saturated: bool = False


class ControlCycle:
    """The controller's decisions on each input (module docstring).

    law: the ArmController (its gains' max_effort_rate and max_task_speed are the cycle's);
    settings: CycleSettings; note: called with each Note (default: appended to `notes`);
    robot_body: the arm's capsules, whose link names a separation's pair gives (default: the
    law's; None: a pair naming a link is not limited, the tool-hand pair is).
    `holding`: whether the caller is to run the hold cycles (True from the start: no joint
    state yet).
    """

    def __init__(self, law: ArmController, settings: CycleSettings,
                 note: Callable[[Note], None] | None = None,
                 robot_body: RobotBody | None = None):
        self.notes: list[Note] = []
        self._note = note or self.notes.append
        self.law = law
        self.settings = settings
        dof = law.model.dof
        self._dof = dof
        self._q = self._dq = None  # (n,) tuples of floats, checked finite on arrival
        self._joint_time = -math.inf  # `now` of the latest joint state
        self._joint_stamp = -math.inf
        self._joint_gate = StampGate(settings.restart_jump, settings.restart_confirm,
                                     strict=False)
        self._target = None  # the latest accepted hand position on the task axes, m
        self._target_gate = StampGate(settings.restart_jump, settings.restart_confirm)
        self._hand = FilteredHand(settings.hand_settings(), law.model.task_axes)
        self._task_name = ''  # of the latest TaskState
        self._task_time = -math.inf  # `now` of the latest TaskState
        # a(E, t) of the task in force; its payload: (shape or None, k).
        self._weights = TaskWeightHold(settings.task_fade_time, MAX_WEIGHT_EXTRAPOLATION)
        # The link to the event_manager as a second weight on a (1 while TaskStates come):
        # None until the first TaskState, which is used at once.
        self._link: EventWeightSchedule | None = None
        self._shape_key = None
        self._task_payload = None  # (shape or None, k) of the latest TaskState's task
        self._limiter = EffortRateLimiter(law.gains.max_effort_rate, dof)
        # The effort (N m) the latest joint state reports, when it is a command sent before
        # (a simulator's applied torque; a measured torque never matches).
        self._applied = None
        self._echo = CommandEcho()
        self._cap = None
        if settings.separation is not None:
            self._cap = SeparationCap(settings.separation, law.gains.max_task_speed)
        self._robot_body = law.body if robot_body is None else robot_body
        # The latest separation's closest pair: (robot capsule index, or None for the tool
        # and the hand; the robot's point (3,) m; the unit normal (3,) towards the person).
        self._pair = None
        self._rest = settings.rest_position
        self._human = None  # the person's capsules (body) and when they came
        self._human_points = ({}, -math.inf)  # the last body's points by name, its stamp
        self._human_time = None
        self._rest_key = None  # the task the rest position was taken for
        self._rest_array = None  # (rest, the same as an array): built once per rest position
        self._hold = None  # the torque of a stale-joint-state outage, N m
        self.holding = True  # whether hold cycles run (none before the first joint state)
        self._watchdog_time = None  # `now` of the last watchdog call
        self._rate_limited = False  # whether a limit acted on the last command
        self._sent = None  # (output, command, stamp) of the command the caller is sending
        self._cycle_task = (None, 0.0)  # (shape, k) of the last control step's task
        self._status = 'starting'
        self._weight = 0.0
        self._cycles = 0
        self._misses = 0
        self._window = None  # (now, cycles) at the start of the rate window
        self._rate = 0.0
        self._input_age = 0.0
        self._next_state = -math.inf  # `now` the next report is due
        self._retune_band()
        law.finish_cycle()  # the law's solves run after the commands (`sent`) from the first

    # -- state the node and the tests read -----------------------------------------------
    @property
    def status(self) -> str:
        """'ok', or why no task force acts ('no_target', 'stale_joint_states', ...)."""
        return self._status

    @property
    def weight(self) -> float:
        """a used by the last cycle (0 when no task force acted)."""
        return self._weight

    @property
    def cycles(self) -> int:
        """Commands computed since the start (law and hold cycles)."""
        return self._cycles

    @property
    def deadline_misses(self) -> int:
        return self._misses

    @property
    def target_glitches(self) -> int:
        return self._hand.glitches

    @property
    def target_reanchors(self) -> int:
        return self._hand.reanchors

    @property
    def rest_position(self) -> tuple[float, ...] | None:
        """An avoid task's rest position in force (m on the task axes)."""
        return self._rest

    def retune(self, law: ArmController, settings: CycleSettings | None = None) -> None:
        """New gains at run time: a law with the same model (and the theta_hat reached) and,
        if given, settings whose applied_effort_cycles takes effect (the node changes no
        other setting at run time)."""
        self.law = law
        law.finish_cycle()  # its solves after the commands, as the law it replaces
        if settings is not None:
            self.settings = settings
        self._limiter.max_rate = law.gains.max_effort_rate
        if self._cap is not None:
            self._cap.max_task_speed = law.gains.max_task_speed
        self._retune_band()

    def _retune_band(self) -> None:
        """The applied-effort band (N m, 0: off) and the effort box it is centred in."""
        settings = self.settings
        self._applied_band = (self.law.gains.max_effort_rate * settings.applied_effort_cycles
                              / settings.rate_hz)
        self._effort_box = tuple(self.law.effort_limits.tolist())

    def _warn(self, kind: str | None, text: str) -> None:
        self._note(Note(WARNING, kind, text))

    def _info(self, text: str) -> None:
        self._note(Note(INFO, None, text))

    # -- inputs ------------------------------------------------------------------------------
    def joint_state(self, now: float, q: tuple, dq: tuple, stamp: float,
                    effort: tuple | None = None) -> tuple | None:
        """A joint state (q rad, dq rad/s, one per joint of the law's model in its order;
        stamp s; the effort the drive reports, N m, or None) received at `now`: the command
        of its cycle (n,), or None if the state is dropped. Follow with `sent`."""
        if not math.isfinite(sum(q) + sum(dq)):
            self._warn('joint_state_non_finite',
                       'joint state dropped: non-finite position or velocity')
            return None
        previous = self._joint_stamp
        verdict = self._joint_gate.offer(stamp)
        if verdict == DROPPED:
            self._warn('joint_state_stamp', 'joint state dropped: stamp went back '
                       f'{self._joint_gate.behind(stamp):.4f} s')
            return None
        if verdict == RESTARTED:
            self._info(f'joint states restarted {previous - stamp:.3f} s behind the last '
                       'one: following the new source')
            previous = stamp  # theta_hat's dt from the receive times for this one
        # theta_hat advances by the time between the states (receive times if the stamps
        # stand still), bounded to 10 periods after a gap.
        dt = stamp - previous if stamp > previous else now - self._joint_time
        dt = min(max(dt, 1e-6), 10.0 * self.settings.period)
        first = self._q is None
        self._q, self._dq = tuple(q), tuple(dq)
        if first and not self.settings.velocity_mode:
            # No command went out before this (hold sends none before the first joint
            # state): the arm's brakes held it against gravity, so the torque starts from the
            # gravity hold where it is, not from zero. From zero, at 1 N m a command, a loaded
            # machine that halved the controller's rate let the Panda fall 0.7 rad into joint
            # 4's limit in 0.27 s.
            self._limiter.reset(self.law.gravity_hold(np.array(self._q)).tolist())
        self._applied = self._echo.applied(effort)
        self._joint_stamp, self._joint_time = stamp, now
        self.holding = False
        if self._status == 'stale_joint_states':
            self._info('joint states resumed')
        output = self._step(now, dt)
        return self._command(output, stamp, dt)

    def _in_base_frame(self, frame: str, what: str) -> bool:
        """Whether a `what` message's frame is the base frame (or unset); else a throttled
        warning: the controller transforms nothing, so a point in another frame would be
        followed or kept clear of at the wrong place."""
        try:
            check_frame(frame, self.settings.base_frame)
        except ValueError as error:
            self._warn(f'{what}_frame', f'{what} dropped: {error}')
            return False
        return True

    def target(self, now: float, position: tuple, stamp: float, frame: str = '') -> bool:
        """A hand position on the task axes ((x, y) for a planar arm, else (x, y, z); m)
        in `frame` stamped `stamp` s, received at `now` (judged by its stamp): whether it was
        taken."""
        if not self._in_base_frame(frame, 'target'):
            return False
        if not math.isfinite(sum(position)):
            self._warn('target_non_finite', 'target dropped: non-finite position')
            return False
        limit = self.settings.max_target_distance
        if math.hypot(*position) > limit:
            self._warn('target_far', f'target dropped: {[round(v, 3) for v in position]} is '
                       f'farther than max_target_distance {limit:g} m')
            return False
        verdict = self._target_gate.offer(stamp)
        if verdict == DROPPED:
            self._warn('target_stamp', 'target dropped: stamp did not advance')
            return False
        if verdict == RESTARTED:
            self._info('targets restarted behind the last one: following the new source')
            self._hand.reset()
        if not self._hand.offer(stamp, position):
            self._warn('target_glitch', f'target held: a jump to '
                       f'{[round(v, 3) for v in position]} no hand can make '
                       f'({self._hand.glitches} held so far)')
            return False
        self._target = tuple(position)  # plain floats: what the per-cycle step computes with
        return True

    def task_state(self, now: float, task: TaskInput, stamp: float, weight: float,
                   weight_rate: float) -> bool:
        """A TaskState (its task, stamp s, a and da/dt 1/s) received at `now`: whether it
        was taken."""
        if not (math.isfinite(weight) and 0.0 <= weight <= 1.0 and math.isfinite(weight_rate)):
            self._warn('task_state_weight',
                       f'task state dropped: weight {weight}, rate {weight_rate}')
            return False
        if task != self._shape_key:
            shape = None
            if task.name:
                try:
                    shape = TaskShape(task.s, task.a1, task.a2, task.d1, task.d2, task.n)
                    self.law.drive(shape, task.k)  # checks K (or its default) once
                except ValueError as error:
                    self._warn('task_state_task',
                               f'task state dropped: task {task.name!r}: {error}')
                    return False
            self._shape_key, self._task_payload = task, (shape, task.k)
        self._task_name = task.name
        self._task_time = now
        link = None if self._link is None else self._link.evaluate(now).phase
        if link == PHASE_IDLE:
            # TaskStates return after the link was down (a = 0): their weight is taken as it
            # is. Blended from the weight held since the last ones (1 when the old
            # event_manager was killed, the new one's ramp starting at 0), the task weight
            # fell while the link faded in: a rose to 0.8 and fell back to 0.05 in 30 ms.
            self._weights.reset()
        self._weights.offer(task, self._task_payload, stamp, weight, weight_rate)
        if self._link is None:
            self._link = EventWeightSchedule(self.settings.task_fade_time, LINK)
        elif link in (PHASE_FADING_OUT, PHASE_IDLE):
            self._info('task states resumed: fading the task in')
            self._link.request(LINK, now)
        return True

    def body(self, now: float, names, points, stamp: float | None = None,
             frame: str = '') -> bool:
        """The person's body points (REP-155 names (K,), points (K, 3) m in `frame`, which
        must be the base frame) received at `now`, stamped `stamp` (s; None: now): their
        capsules
        (hri_core.bodies.human_capsules), moving at the velocities from the body before (its
        stamp's difference; still after a gap longer than body_timeout), are what the law
        keeps clear of until body_timeout s without a body. A non-finite point counts as lost
        and a name that is no REP-155 body point is ignored (a throttled warning names each),
        the rest of the body kept. False (the body dropped, a throttled warning) for a bad
        message."""
        if not self._in_base_frame(frame, 'body'):
            return False
        stamp = now if stamp is None else stamp
        try:
            names, points, lost, unknown = seen_body_points(names, points)
            before, then = self._human_points
            seconds = stamp - then if stamp - then <= self.settings.body_timeout else 0.0
            velocities = body_point_velocities(names, points, before, seconds)
            self._human = human_capsules(names, points, velocities=velocities)
            self.law.take_person(self._human)
        except ValueError as error:
            self._warn('body', f'body dropped: {error}')
            return False
        if lost:
            self._warn('body_lost', f'body points not finite, taken as lost: {", ".join(lost)}')
        if unknown:
            self._warn('body_unknown', f'body points ignored: {", ".join(unknown)} (not '
                       'REP-155 names: head, torso, l_/r_shoulder, l_/r_elbow, l_/r_wrist, body)')
        self._human_points = (dict(zip(names, points, strict=True)), stamp)
        if self._human_time is not None and now - self._human_time > self.settings.body_timeout:
            self._info('the body is back: keeping clear of it again')
        self._human_time = now
        return True

    def _body_at(self, now: float):
        """The person's capsules while fresh, else None (one warning when they go stale)."""
        if self._human is None:
            return None
        if now - self._human_time > self.settings.body_timeout:
            self._warn(None, f'no body for {self.settings.body_timeout:g} s: the tool-hand '
                       'task alone keeps the distance')
            self._human = None
            return None
        return self._human

    def separation(self, now: float, separation: float, human_speed_used: float,
                   closing_speed: float, pair: tuple | None = None) -> None:
        """A separation (m), the hand speed S_p counted (m/s) and the closing speed (m/s),
        received at `now`; ignored without a cap. pair: (robot link name, its point (3,) m,
        the body's point (3,) m) of a whole-body separation; None or a link '' for the tool
        and the hand."""
        if self._cap is None:
            return
        self._cap.observe(now, separation, human_speed_used, closing_speed)
        self._pair = self._closest_pair(separation, pair)

    def _closest_pair(self, separation: float, pair: tuple | None):
        """The pair the approach limit holds (the `_pair` layout), or None where it cannot be
        placed (a warning, throttled as every note of its kind, for a link the robot body
        does not know: the tool and the hand stand in)."""
        if pair is None or not pair[0]:
            return (None, None, None)
        link, robot_point, body_point = pair
        body = self._robot_body
        if body is None or link not in body.names:
            self._warn('pair', f'separation pair on {link!r}, a link the controller does not '
                       'know: the tool and the hand are limited instead')
            return (None, None, None)
        robot_point = np.asarray(robot_point, dtype=float)
        towards = np.asarray(body_point, dtype=float) - robot_point
        if body.planar:
            towards[2] = 0.0
        length = math.sqrt(float(towards @ towards))
        if not (length > 1e-9 and math.isfinite(separation)):
            return None  # touching: no direction to hold
        # Overlapping capsules (a negative separation) have their surface points crossed.
        sign = 1.0 if separation >= 0.0 else -1.0
        return (body.names.index(link), robot_point, sign * towards / length)

    def _approach_row(self, now: float, knee: float):
        """n^T J_p (n,) of the pair's robot point at the latest joint state (m/rad), or None
        while the cap lets the task run at full speed, or there is no fresh pair."""
        if self._pair is None or self._cap.stale(now) \
                or knee >= self.law.gains.max_task_speed:
            return None
        index, point, normal = self._pair
        q = np.array(self._q)
        if index is None:
            if self._target is None:
                return None
            x, jac, _ = self.law.model.task_kinematics(q, np.zeros(q.size))
            towards = np.array(self._target) - x
            length = math.sqrt(float(towards @ towards))
            return None if length <= 1e-9 else (towards / length) @ jac
        return normal @ self._robot_body.point_jacobian(q, index, point, checked=False)

    # -- the watchdog and the hold -----------------------------------------------------------
    def watchdog(self, now: float) -> bool:
        """A watchdog check at `now` (every watchdog_period): True when the hold cycles are to
        start (joint states missing or older than joint_state_timeout)."""
        previous, self._watchdog_time = self._watchdog_time, now
        if previous is not None and now - previous > 2.0 * self.settings.watchdog_period:
            # The node itself did not run for a while (a starved process, measured: 100 ms
            # on a loaded machine): the joint states may be waiting in its queue, not late.
            # Judged at the next check, once they had their turn; zero torque dropped a
            # Panda's gravity hold (22 N m) for nothing.
            return False
        if now - self._joint_time > self.settings.joint_state_timeout and not self.holding:
            self.holding = True
            return True
        return False

    def hold(self, now: float) -> tuple | None:
        """A hold cycle at `now` (every period while holding): its command, the gravity hold
        at the last joint state (zero in velocity mode and for an arm without gravity), ()
        before any joint state (send nothing), or None when joint states are fresh again (stop
        the hold cycles). Follow a command, () included, with `sent`."""
        if now - self._joint_time <= self.settings.joint_state_timeout:
            self.holding = False  # joint states are back: they pace the cycles
            return None
        if self._q is None:
            # No joint state yet: no command (an empty one; the report still comes). An arm's
            # brakes (arm_sim's, a real arm's) hold it until its first command, which then
            # starts from the gravity hold (joint_state); a zero command now would release
            # them into a fall.
            if self._status != 'no_joint_states':
                self._warn(None, 'no command: no joint states')
            self._status = 'no_joint_states'
            self._weight = 0.0
            self._rate_limited = False
            self._sent = (None, (), None)
            return ()
        status = 'stale_joint_states'
        if status != self._status:  # once per outage, as scara_sim's command timeout
            # An arm under gravity is held where its last joint state put it (gravity with
            # theta_hat, reached at the effort rate): zero torque dropped the Panda's 29 N m
            # on joint 2 at once, and it fell into its joint limits while a loaded machine
            # held the sim back for 0.1 s. Velocity commands get zero. Worked out once: q and
            # theta_hat stand still until a joint state comes.
            self._hold = None
            if self._q is not None and not self.settings.velocity_mode:
                hold = self.law.gravity_hold(np.array(self._q))
                self._hold = tuple(hold.tolist()) if np.any(hold) else None
            action = 'zero torque' if self._hold is None else 'holding against gravity'
            self._warn(None, f'{action}: {status.replace("_", " ")}')
        self._status = status
        self._weight = 0.0
        return self._command(None, None, hold=self._hold)

    # -- the command and what follows it -----------------------------------------------------
    def _command(self, output: ArmOutput | None, stamp: float | None, dt: float = 0.0,
                 hold: tuple | None = None) -> tuple:
        """The command for the law's `output` (None: no law torque; `hold` (n,) N m if given,
        else zero torque)."""
        self._cycles += 1
        self._rate_limited = False
        period = self.settings.period
        if output is None and hold is not None:
            # From the last command at the effort rate (the drive's reported effort is as
            # stale as the joint state).
            command, self._rate_limited = self._limiter.limit(hold, period)
        elif output is None:
            command = (0.0,) * self._dof
            self._limiter.reset()  # zero torque at once (safety), the next change from zero
        elif self.settings.velocity_mode:
            command = tuple(output.qdot_r.tolist())
        else:
            # At most one period's worth per command, and near what the drive applies (see
            # effort_rate).
            applied = self._applied if self._applied_band > 0.0 else None
            if applied is not None:
                applied = tuple(min(max(v, -limit), limit)
                                for v, limit in zip(applied, self._effort_box, strict=True))
            command, self._rate_limited = self._limiter.limit(
                output.tau, min(dt, period), applied, self._applied_band)
        self._sent = (output, command, stamp)
        return command

    def sent(self, now: float, published: float) -> CycleReport | None:
        """The command just returned went out at `published` (s, on the joint stamps' clock)
        at `now`: deadline miss, the command's echo, the report when due (V computed now,
        after the command), then theta_hat's update (eq. 19) of a law cycle, unless a limit
        held the command off the law's torque."""
        if self._sent is None:
            return None
        output, command, stamp = self._sent
        self._sent = None
        if self._applied_band > 0.0 and not self.settings.velocity_mode and command:
            self._echo.sent(command)  # velocities echo nothing
        if stamp is not None:
            self._input_age = published - stamp
            if self._input_age > LATE_FACTOR * self.settings.period:
                self._misses += 1
        report = None
        if now >= self._next_state:
            # On a fixed schedule, whatever the rate of the cycles; no catching up.
            state_period = 1.0 / self.settings.state_rate_hz
            due = self._next_state + state_period
            self._next_state = due if due > now else now + state_period
            report = self._report(now, output, command)
        # eq. 19 only for a torque the drives get: the rate limit or the applied band acting
        # (the gravity ramp at start, a loaded machine's skipped cycles) would otherwise count
        # the torque withheld as a parameter error (ArmController.adapt).
        if output is not None and not self.law.adapt(applied=not self._rate_limited):
            # theta_hat stays; the next cycle's torque is computed with it as before.
            self._warn('adaptation', 'parameter update dropped: not finite')
        try:
            self.law.finish_cycle()
        except Exception as error:  # noqa: BLE001 the node runs on whatever the law raises
            self._warn('internal', f'work after the command failed: {error!r}')
        return report

    def _report(self, now: float, output: ArmOutput | None, command: tuple) -> CycleReport:
        if self._window is None:
            self._window = (now, self._cycles - 1)
        started, ticks = self._window
        if now - started >= 1.0:
            self._rate = (self._cycles - ticks) / (now - started)
            self._window = (now, self._cycles)
        report = CycleReport(deadline_misses=self._misses, rate_hz=self._rate,
                             input_age=self._input_age, target_glitches=self._hand.glitches,
                             status=self._status, effort=command,
                             theta_hat=self.law.theta_hat, task=self._task_name)
        if output is not None:
            report.distance = float(output.distance)
            try:
                output = output._replace(lyapunov=self.law.lyapunov(output, self._q, None))
            except Exception as error:  # noqa: BLE001 monitoring must not stop control
                self._warn('lyapunov', f'V not reported: {error!r}')
            if output.lyapunov is not None:
                try:
                    task = self._weight * self.law.task_energy(output.distance,
                                                               *self._cycle_task)
                except Exception as error:  # noqa: BLE001 monitoring must not stop control
                    self._warn('lyapunov', f'V reported without its task term: {error!r}')
                    task = 0.0
                report.lyapunov = output.lyapunov + task
            report.sliding_norm = math.hypot(*output.s)
            report.weight = self._weight
            report.saturated = bool(output.torque_limited or self._rate_limited)
        elif self._q is not None and self._target is not None:
            report.distance = float(np.linalg.norm(self._tool_position()
                                                   - np.array(self._target)))
        return report

    # -- the control step --------------------------------------------------------------------
    def _link_state(self, now: float) -> WeightState:
        """The link weight at `now`: the first cycle more than task_state_timeout s after the
        last TaskState starts its fade-out."""
        if self._link is None:
            return LINK_DOWN
        state = self._link.evaluate(now)
        settings = self.settings
        if (now - self._task_time > settings.task_state_timeout
                and state.phase in (PHASE_ACTIVE, PHASE_FADING_IN)):
            self._warn(None, f'no TaskState for {settings.task_state_timeout:g} s: fading the '
                       f'task out over {settings.task_fade_time:g} s')
            state = self._link.request(None, now)
        return state

    def _step(self, now: float, dt: float) -> ArmOutput | None:
        self._weight = 0.0  # no task force acts unless the step below runs
        if self._target is None:
            self._status = 'no_target'
            # An arm under gravity is held where it is (no task, no hand motion) rather than
            # let fall.
            return self._arm_step(None, 0.0, 0.0, None, dt, self._body_at(now))
        link = self._link_state(now)
        # a of the task in force, held between TaskStates from their stamps to the joint
        # state's (a TaskState delivered late would otherwise step a by its delay times
        # da/dt), blended where a TaskState lands off the hold (signal_hold).
        held = self._weights.evaluate(self._joint_stamp)
        shape = k = None
        if held is not None:
            key, (shape, k), task_weight, task_rate = held
        # The hand's presence (target_filter): faded out while no /target is accepted.
        hand = self._hand.presence(self._joint_stamp)
        if shape is None or link.weight == 0.0 or hand.weight == 0.0:
            weight, rate, shape = 0.0, 0.0, None
        else:
            # a = a_task * a_link * a_hand: continuous ramps, so is their product.
            weight = task_weight * link.weight * hand.weight
            rate = (task_rate * link.weight * hand.weight
                    + task_weight * link.rate * hand.weight
                    + task_weight * link.weight * hand.rate)
            if self._rest_key != key:
                self._rest_key = key
                if self.settings.rest_position is None:
                    self._rest = tuple(self._tool_position().tolist())
        self._status = 'ok' if link.phase in (PHASE_ACTIVE, PHASE_FADING_IN) else 'no_task_state'
        if hand.phase in (PHASE_FADING_OUT, PHASE_IDLE):
            self._status = 'target_lost'
        self._weight = weight
        # The hand where it is at the joint state's time, from the stamps (receive times would
        # add the callbacks' delays, 2.5 mm per 5 ms at 0.5 m/s).
        target, target_velocity = self._hand.evaluate(self._joint_stamp)
        k = 0.0 if shape is None else k
        self._cycle_task = (shape, k)
        if self._cap is not None:
            knee = self._cap.knee(now)
            self.law.limit_pull_speed(knee)
            self.law.limit_approach(self._approach_row(now, knee), (1.0 + CAP_BAND) * knee)
        return self._arm_step((target, target_velocity), weight, rate,
                              None if shape is None else (shape, k), dt, self._body_at(now))

    def _arm_step(self, hand, weight: float, rate: float, task, dt: float, human=None):
        """arm_law's command: hand (x_d, xdot_d) tuples on the task axes or None (held where
        the tool is), task (shape, k) or None. The ArmOutput, or None (zero torque, a throttled
        warning) on a fault. What the torque does not need waits until it is sent (`sent`):
        theta_hat's update and V."""
        try:
            if hand is None:
                position = self._tool_position()
                velocity = np.zeros(position.size)
            else:
                position, velocity = np.array(hand[0]), np.array(hand[1])
            active = None if task is None else ActiveTask(task[0], weight, rate, task[1])
            if self._rest_array is None or self._rest_array[0] != self._rest:
                self._rest_array = (self._rest, None if self._rest is None
                                    else np.array(self._rest))
            output = self.law.command(np.array(self._q), np.array(self._dq),
                                      HandState(position, velocity, np.zeros(velocity.size)),
                                      active, dt, self._rest_array[1], human)
        except Exception as error:  # noqa: BLE001 a robot command must stay safe
            self._status = f'fault: {type(error).__name__}'
            self._warn('internal', f'zero torque: control step failed: {error!r}')
            return None
        if output.fault:
            self._status = f'fault: {output.fault_reason}'
            self._warn('fault', f'zero torque: {output.fault_reason}')
            return None
        return output

    def _tool_position(self) -> np.ndarray:
        """The tool on the task axes (m) at the last joint state."""
        q = np.array(self._q)
        return self.law.model.task_kinematics(q, np.zeros(q.size))[0]
