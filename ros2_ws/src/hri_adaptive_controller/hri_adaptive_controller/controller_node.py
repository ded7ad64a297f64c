"""The `controller` node: the adaptive HRI controller of paper eq. 14-19 on topics.

Event-driven: each /joint_states message that arrives is the start of a control cycle. In its
callback the node runs the law (arm_law.ArmController: eq. 16-18, then eq. 19's update once
the command is out) for its arm (`robot` or `urdf_file`: hri_core.robot_model) on that state
with the latest /target (the hand: the centre x_d of the desired region) and /hri/task_state
(active task, a(E, t), da/dt), and publishes the torque, limited to the arm's effort limits
(and `effort_limit` if set) with its direction kept, on /effort_controller/commands (the
interface of ros2_control's JointGroupEffortController): one wake-up per cycle, the command
computed from the newest state; its change since the last command is limited to
`max_effort_rate` times the time between their joint states, at most one period
(effort_rate; after the clamp), and it stays within `applied_effort_cycles` periods' worth of
the effort the joint state reports when that effort is a command it sent
(effort_rate.CommandEcho: a simulator's applied torque), so a late burst of commands cannot
step the drive by more. With `mode: velocity` it publishes the joint-velocity reference
qdot_r of eq. 14 on /velocity_controller/commands instead. theta_hat advances by the time
between the joint states' stamps. ControllerState (distance, V, |s|, a, theta_hat, effort,
deadline misses: commands published later than 1.5 periods of `rate_hz` after the stamp of
their joint state) goes out with the first cycle after each 1/`state_rate_hz` s, which alone
computes V once the cycle's command is out.

A watchdog timer (every joint_state_timeout / 4) notices missing or stale joint states; while
they are, a timer at `rate_hz` publishes the gravity hold at the last joint state (zero for
an arm without gravity, the horizontal SCARA) and ControllerState in place of the cycles that
do not come. With `realtime_priority` > 0 the process asks for SCHED_FIFO at that priority
(hri_core.realtime) and logs once whether it got it; with `cpu_wakeup_latency` >= 0 it holds
a PM QoS request that idle CPUs wake within that many microseconds (0: they poll).

Safety (the choices are argued in docs/design.md):
- zero torque while joint states are missing; older than `joint_state_timeout` (one
  warning per outage, one info line when they resume) the arm is held against gravity at
  the last one, Y(q, 0, 0, 0) theta_hat reached at the effort rate (zero torque would drop
  an arm under gravity; the horizontal SCARA's is zero); invalid joint states (throttled warning:
  non-finite, wrong length, unknown joint names: joints are mapped by name; stamps going
  backwards are dropped), and while there is no valid target yet (non-finite targets, or
  farther than `max_target_distance` from the base, are dropped);
- a source restart is recognised (hri_core.stamp_gate): joint states or targets whose stamps
  are more than `restart_jump` s behind the last used one are followed once
  `restart_confirm` of them have advanced, and logged;
- no TaskState yet means a = 0; none for `task_state_timeout` s (event_manager gone: it
  publishes a heartbeat) fades the task out over `task_fade_time` with eq. 13's C2 ramp (a
  second weight on a, so no torque step), and TaskStates coming again fade it back in; with
  a = 0 the controller keeps the arm damped (Ks s with qdot_r = J+ xdot_d) but no task force
  acts;
- a(E, t) is held between TaskStates from their stamps and a TaskState that lands off the
  held value (one after a gap: the event_manager starved on a loaded machine) is blended in
  at `task_fade_time` per unit of a, a missed swap faded out first (signal_hold.
  TaskWeightHold), so a never jumps;
- the hand's velocity xdot_d is estimated from the /target stamps with a first-order filter
  (`target_filter_time`); its acceleration is taken as 0; between targets the hand is held
  to first order (at most MAX_TARGET_EXTRAPOLATION) and each new /target is blended in over
  its message period (signal_hold.HandHold), so a fast hand does not step the task term;
- a /target no hand could have reached (faster than `target_max_speed`, or off its predicted
  path by more than `target_max_acceleration` allows: a marker swap) is held, not followed,
  and counted in ControllerState.target_glitches; a place held samples keep to for 0.2 s is
  taken as the hand's and glided to (target_filter); no /target accepted for
  `target_timeout` s fades the task out over `task_fade_time` (status target_lost), and in
  again when the hand returns;
- the task's K comes with its TaskState (0: hri_core.potential.default_task_gain); an avoid
  task returns the arm to `rest_position`, by default where the arm was when the task became
  active (task_variable's module docstring);
- with `separation_speed_limit` on, the task's speed towards the hand is capped from each
  /hri/separation so that ISO/TS 15066's S_p stays within the separation, rate-limited, 0
  while /hri/separation is stale (separation_cap; S_p's constants: the event_detector's).
"""

import dataclasses
import math
import sys
import time
from array import array

import numpy as np
from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import ControllerState, SeparationState, TaskState
from rcl_interfaces.msg import SetParametersResult
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from hri_adaptive_controller.arm_law import (
    ActiveTask,
    ArmController,
    ArmGains,
    HandState,
    default_gains,
)
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
from hri_core import topics
from hri_core.cdr import (
    EFFORT,
    POSITION,
    VELOCITY,
    LayoutReader,
    float64_array_template,
    joint_state_layout,
    point3_layout,
    point_stamped_layout,
    read_stamp,
)
from hri_core.node_common import (
    CPU_WAKEUP_LATENCY,
    REALTIME_PRIORITY,
    ParameterSpec,
    StartupError,
    declare_parameters,
    hold_wakeup_latency,
    load_defaults,
    request_realtime,
    run_node,
    stamp_seconds,
)
from hri_core.potential import TaskShape
from hri_core.robot_description import urdf_joint_names
from hri_core.robot_model import ROBOT_NAMES, RobotModel, robot_model
from hri_core.separation import ProtectiveSeparation
from hri_core.stamp_gate import DROPPED, RESTARTED, StampGate

PACKAGE = 'hri_adaptive_controller'
NODE_NAME = 'controller'
WARNING_THROTTLE = 2.0  # s between repeats of one warning
LATE_FACTOR = 1.5  # a command later than 1.5 periods after its joint state is a deadline miss
WATCHDOG_CHECKS = 4  # watchdog checks per joint_state_timeout
MAX_WEIGHT_EXTRAPOLATION = 0.05  # s: longest first-order hold of a(E, t) between TaskStates
# s: longest first-order hold of the hand between /target messages (100 Hz): a hand at
# 0.5 m/s moves 5 mm between two, which as a staircase steps the task term (and the torque,
# by several N m) at each message.
MAX_TARGET_EXTRAPOLATION = 0.05
LINK = 'task_states'  # the link weight's one task: TaskStates arriving
LINK_DOWN = WeightState(0.0, 0.0, 0.0, PHASE_IDLE, None, None)

PARAMETERS = {
    'robot': ParameterSpec(str, 'the arm (hri_core.robot_model); ignored when urdf_file is given',
                           choices=ROBOT_NAMES, read_only=True),
    'urdf_file': ParameterSpec(str, 'URDF of another arm ("": the robot parameter)',
                               read_only=True),
    'tool_frame': ParameterSpec(str, 'URDF link or frame of the tool point ("": the robot\'s '
                                'own; required with urdf_file)', read_only=True),
    'home_position': ParameterSpec(
        list, 'the joint posture the null space of a redundant arm pulls towards (rad, one '
        "per joint, within the limits); unset: the robot's home (the Panda's ready pose; a "
        "URDF arm's: the middle of its joint limits)", optional=True, read_only=True),
    'ks': ParameterSpec(list, 'diagonal of Ks, one per joint (N m s/rad); unset: the '
                        "robot's (arm_law.ROBOT_GAINS; another arm's from its effort limits "
                        'and inertias, arm_law.default_arm_ks)', optional=True),
    'adaptation_gain': ParameterSpec(
        list, "diagonal of L (eq. 19), one rate per kind of the robot's parameters (the "
        "SCARA's 7: pi1, pi2, pi3, b1, b2, mlc1, mlc2; a URDF arm's m, mcx, mcy, mcz, Ixx, "
        "Ixy, Iyy, Ixz, Iyz, Izz, damping, every joint alike); unset: the robot's",
        optional=True),
    'theta_hat0': ParameterSpec(list, "initial theta_hat, one per parameter of the robot's "
                                "model; unset: the robot's initial_estimate share of its "
                                'nominal values (arm_law.ArmGains)', optional=True,
                                read_only=True),
    'rate_hz': ParameterSpec(float, 'expected /joint_states rate, which paces control; '
                             'deadlines and the zero-torque rate (Hz)', low=10.0, high=2000.0,
                             read_only=True),
    'realtime_priority': REALTIME_PRIORITY,
    'cpu_wakeup_latency': CPU_WAKEUP_LATENCY,
    'state_rate_hz': ParameterSpec(float, 'ControllerState rate (Hz)', low=1.0, high=1000.0,
                                   read_only=True),
    'mode': ParameterSpec(str, 'effort: torques (eq. 16); velocity: qdot_r (eq. 14)',
                          choices=('effort', 'velocity'), read_only=True),
    'kp': ParameterSpec(float, 'task gain Kp (N s/m)', low=0.001, high=1000.0),
    'max_task_speed': ParameterSpec(float,
                                    'largest task-space reference speed (m/s)',
                                    low=0.01, high=2.0),
    'approach_speed': ParameterSpec(float, 'most the approach floor may be (m/s; 0: none); '
                                    "the floor is the task's own pull 0.2 m from its region",
                                    low=0.0, high=2.0),
    'region_margin': ParameterSpec(float, 'how far inside the learned region the approach '
                                   'speed fades out (m)', low=0.0, high=0.1),
    'rest_gain': ParameterSpec(float, 'avoid tasks: rate of the return to the rest position '
                               '(1/s)', low=0.0, high=100.0),
    'rest_gate': ParameterSpec(float, "avoid tasks: the return fades in over this distance "
                               "outside the region's edge (m)", low=0.001, high=1.0),
    'rest_position': ParameterSpec(list, 'avoid tasks: rest position on the task axes (m: '
                                   '[x, y] for a planar arm, [x, y, z] otherwise); unset: '
                                   'where the arm was when the task became active',
                                   optional=True),
    'effort_limit': ParameterSpec(float, "a cap on every joint's torque limit (N m; 0: the "
                                  "robot's own limits alone)", low=0.0, high=500.0),
    'max_effort_rate': ParameterSpec(float, 'largest torque change per joint, per second of '
                                     'the joint states\' clock (N m/s; 1000: 1 N m per 1 ms '
                                     'cycle)', low=1.0, high=1e6),
    'applied_effort_cycles': ParameterSpec(int, 'each command also stays within '
                                           'max_effort_rate times this many control periods '
                                           'of the effort the joint state reports, when that '
                                           'is a command this node sent (a simulator echoing '
                                           'the torque it applies; a measured torque is left '
                                           'alone), whichever command of a late burst the '
                                           'drive takes; 0: off', low=0, high=100),
    'joint_state_timeout': ParameterSpec(float, 'joint states older than this: the arm is '
                                         'held against gravity (s)',
                                         low=0.002, high=10.0),
    'task_state_timeout': ParameterSpec(float, 'no TaskState for this long: the task fades '
                                        'out over task_fade_time (s)', low=0.1, high=3600.0),
    'task_fade_time': ParameterSpec(float, 'a full fade of the task when TaskStates stop or '
                                    'return (s, the C2 ramp of eq. 13)', low=0.01, high=60.0),
    'restart_jump': ParameterSpec(float, 'stamps this far behind the last used one start a '
                                  'candidate source restart (s)', low=0.001, high=3600.0),
    'restart_confirm': ParameterSpec(int, 'advancing messages that confirm a source restart',
                                     low=1, high=1000),
    'target_filter_time': ParameterSpec(float, 'time constant of the hand velocity estimate (s)',
                                        low=0.001, high=5.0, read_only=True),
    'max_target_distance': ParameterSpec(float, 'targets farther than this from the base are '
                                         'dropped (m)', low=0.1, high=100.0),
    'joint_limit_band': ParameterSpec(float, 'the barrier and the feed-forward gate act this '
                                      'near a joint limit (rad)', low=0.01, high=1.0),
    'barrier_torque': ParameterSpec(float, "the barrier's torque at a joint limit (N m; above "
                                    "the task's largest)", low=0.0, high=100.0),
    'separation_speed_limit': ParameterSpec(
        bool, "cap the task's speed towards the hand from /hri/separation so that ISO/TS "
        "15066's S_p stays within the separation (separation_cap; no approach while "
        '/hri/separation is stale)', read_only=True),
    'reach_round': ParameterSpec(bool, 'blend in a joint-space motion where the straight '
                                 'task-space descent is blocked or the hand out of reach'),
    'target_max_speed': ParameterSpec(float, 'a /target implying a faster hand is held as a '
                                      'glitch (m/s)', low=0.1, high=100.0, read_only=True),
    'target_max_acceleration': ParameterSpec(float, 'a /target off the predicted hand path by '
                                             'more than this allows is held as a glitch '
                                             '(m/s^2)', low=1.0, high=1e4, read_only=True),
    'target_timeout': ParameterSpec(float, 'no /target accepted for this long: the task fades '
                                    'out over task_fade_time (s)', low=0.01, high=3600.0,
                                    read_only=True),
}
GAIN_PARAMETERS = ('ks', 'kp', 'adaptation_gain', 'max_task_speed', 'approach_speed',
                   'region_margin', 'effort_limit', 'max_effort_rate', 'applied_effort_cycles',
                   'rest_gain', 'rest_gate', 'joint_limit_band', 'barrier_torque', 'reach_round')


def model_from(values: dict) -> RobotModel:
    """The arm's model: urdf_file with tool_frame, else robot; its home pose home_position if
    set. ValueError with the reason."""
    if values['urdf_file']:
        model = robot_model(urdf_file=values['urdf_file'], tool_frame=values['tool_frame'])
    else:
        model = robot_model(values['robot'], tool_frame=values['tool_frame'])
    if values.get('home_position') is not None:
        model.home = model.joint_position(values['home_position'], 'home_position')
    return model


def gains_from(values: dict, model: RobotModel) -> ArmGains:
    """The law's gains for `model` from parameter values: ks and adaptation_gain if set, else
    the robot's (arm_law.default_gains); the task, speed, rate-limit and barrier parameters
    from the values. ValueError with the reason if invalid."""
    robot = default_gains(model)
    ks, adaptation = values.get('ks'), values.get('adaptation_gain')
    if ks is not None and len(ks) != model.dof:
        raise ValueError(f'ks must have {model.dof} values for {model.name}, got {len(ks)}')
    if adaptation is not None and len(adaptation) != len(model.adaptation_kinds):
        raise ValueError(f'adaptation_gain must have {len(model.adaptation_kinds)} values for '
                         f'{model.name} ({", ".join(model.adaptation_kinds)}), got '
                         f'{len(adaptation)}')
    return dataclasses.replace(
        robot, ks=robot.ks if ks is None else tuple(ks), kp=values['kp'],
        adaptation=robot.adaptation if adaptation is None else tuple(adaptation),
        approach_speed=values['approach_speed'], region_margin=values['region_margin'],
        max_task_speed=values['max_task_speed'], rest_gain=values['rest_gain'],
        rest_gate=values['rest_gate'], max_effort_rate=values['max_effort_rate'],
        effort_limit=values['effort_limit'] or None, limit_band=values['joint_limit_band'],
        barrier_torque=values['barrier_torque'],
        reach_round=dataclasses.replace(robot.reach_round, enabled=values['reach_round']))


def initial_estimate(values: dict, model: RobotModel, gains: ArmGains):
    """theta_hat(0) (p,): theta_hat0 if set, else the gains' initial_estimate share of the
    model's nominal theta. ValueError with the reason."""
    theta = values.get('theta_hat0')
    if theta is None:
        return gains.initial_estimate * model.theta
    if len(theta) != model.theta.size:
        raise ValueError(f'theta_hat0 must have {model.theta.size} values for {model.name} '
                         f'({", ".join(model.parameter_names[:8])}'
                         f'{" ..." if model.theta.size > 8 else ""}), got {len(theta)}')
    return np.array(theta, dtype=float)


def rest_position_from(values: dict, model: RobotModel) -> tuple[float, ...] | None:
    """The fixed rest position of avoid tasks (m, one per task axis of `model`), or None when
    unset. ValueError with the reason."""
    fixed = values.get('rest_position')
    if fixed is None:
        return None
    axes = model.task_axes
    if len(fixed) != axes:
        raise ValueError(f'rest_position must have {axes} values '
                         f'{["[x, y]", "[x, y, z]"][axes - 2]} (m) for {model.name}, got '
                         f'{len(fixed)}')
    return tuple(float(v) for v in fixed)


class Controller(Node):
    """Adaptive torque controller between joint states, target, task state and commands."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self._values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        values = self._values
        try:
            model = model_from(values)
            gains = gains_from(values, model)
            self._law = ArmController(model, gains, initial_estimate(values, model, gains))
            self._joint_names = model.joint_names
            # An avoid task's rest position: the parameter, or where the arm was when the
            # task (its name and shape) became active; _rest_key is the task it was taken for.
            self._fixed_rest = rest_position_from(values, model)
        except ValueError as error:
            raise StartupError(f'bad controller parameters: {error}') from None
        self._dof = len(self._joint_names)
        self._period = 1.0 / values['rate_hz']
        self._late = LATE_FACTOR * self._period
        self._state_period = 1.0 / values['state_rate_hz']
        self._next_state = -math.inf  # monotonic time the next ControllerState is due
        self._velocity_mode = values['mode'] == 'velocity'
        self._q = self._dq = None  # (n,) tuples of floats, checked finite on arrival
        self._joint_index = (None, None)  # (names of the last joint state, indices of ours)
        self._joint_time = -math.inf  # monotonic receive time of the latest joint state
        self._joint_stamp = -math.inf
        self._joint_gate = StampGate(values['restart_jump'], values['restart_confirm'],
                                     strict=False)
        self._target = None  # the latest hand position on the task axes, m
        self._target_gate = StampGate(values['restart_jump'], values['restart_confirm'])
        self._hand = FilteredHand(TargetFilterSettings(
            max_speed=values['target_max_speed'],
            max_acceleration=values['target_max_acceleration'],
            filter_time=values['target_filter_time'],
            max_extrapolation=MAX_TARGET_EXTRAPOLATION, timeout=values['target_timeout'],
            fade_time=values['task_fade_time']), model.task_axes)
        self._task_state: TaskState | None = None
        self._task_time = -math.inf
        # a(E, t) of the task in force; its payload: (shape or None, k).
        self._weights = TaskWeightHold(values['task_fade_time'], MAX_WEIGHT_EXTRAPOLATION)
        self._limiter = EffortRateLimiter(values['max_effort_rate'], self._dof)
        # The effort (N m) the latest joint state reports, when it is a command this node sent
        # (a simulator's applied torque; a measured torque never matches).
        self._applied = None
        self._echo = CommandEcho()
        self._set_applied_band(values)
        # The link to the event_manager as a second weight on a (1 while TaskStates come):
        # None until the first TaskState, which is used at once, as before.
        self._link: EventWeightSchedule | None = None
        self._shape_key = None
        self._task_payload = None  # (shape or None, k) of the latest TaskState's task
        self._rate_limited = False  # whether max_effort_rate acted on the last command
        self._rest = self._fixed_rest
        self._rest_array = None  # (rest, the same as an array): built once per rest position
        self._hold = None  # the torque of a stale-joint-state outage (_zero_cycle), N m
        self._rest_key = None
        self._cycles = 0
        self._misses = 0
        self._window = (time.monotonic(), 0)
        self._rate = 0.0
        self._status = 'starting'
        self._weight = 0.0
        self._warned: dict[str, float] = {}
        self._input_age = 0.0
        self._system_clock = not self.get_clock().ros_time_is_active
        self._cycle_task = (None, 0.0)  # (shape, k) of the last control step's task
        # The 1 kHz messages as raw CDR (hri_core.cdr): joint states read at fixed offsets
        # while their layout holds, commands written from a template.
        self._joint_reader = LayoutReader(lambda data: joint_state_layout(
            data, self._joint_names, (POSITION, VELOCITY, EFFORT), one_value_per_name=True)
            or joint_state_layout(data, self._joint_names, (POSITION, VELOCITY),
                                  one_value_per_name=True))
        self._command_template = float64_array_template(self._dof)
        # The hand's coordinates on the task axes: x, y for a planar arm; x, y, z otherwise.
        self._target_reader = LayoutReader(point_stamped_layout if model.task_axes == 2
                                           else point3_layout)

        command = topics.VELOCITY_COMMANDS if self._velocity_mode else topics.EFFORT_COMMANDS
        self._command_pub = self.create_publisher(command.type, command.name, command.qos)
        topic = self._command_pub.topic_name
        self._state_pub = self.create_publisher(
            ControllerState, topics.CONTROLLER_STATE.name, topics.CONTROLLER_STATE.qos)
        # Only the newest joint state and hand position matter: each joint state starts a cycle.
        self.create_subscription(JointState, topics.JOINT_STATES.name, self._on_joint_state_data,
                                 topics.LATEST_SAMPLE_QOS, raw=True)
        # /target raw too: a hand position that lands just before a joint state delays that
        # cycle by its callback, which a Python message made 3 times longer.
        self.create_subscription(PointStamped, topics.TARGET.name, self._on_target_data,
                                 topics.LATEST_SAMPLE_QOS, raw=True)
        self.create_subscription(TaskState, topics.TASK_STATE.name, self._on_task_state,
                                 topics.TASK_STATE.qos)
        # The arm a simulator or robot_state_publisher describes, checked once it comes.
        self.create_subscription(String, topics.ROBOT_DESCRIPTION.name,
                                 self._on_robot_description, topics.ROBOT_DESCRIPTION.qos)
        # ISO/TS 15066 speed cap (separation_cap), with S_p's constants from the detector's YAML.
        self._separation_cap = None
        if values['separation_speed_limit']:
            self._separation_cap = SeparationCap(ProtectiveSeparation.from_mapping(
                load_defaults(PACKAGE, 'event_detector')), values['max_task_speed'])
            self.create_subscription(SeparationState, topics.SEPARATION.name,
                                     self._on_separation, topics.SEPARATION.qos)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self._watchdog_period = values['joint_state_timeout'] / WATCHDOG_CHECKS
        self._watchdog_time = time.monotonic()  # when the watchdog last ran
        self.create_timer(self._watchdog_period, self._watchdog)
        # Zero torque at the control rate while joint states are missing or stale; running
        # from the start, since none has arrived yet.
        self._zero_timer = self.create_timer(self._period, self._zero_cycle)
        law = self._law
        gains = (f'{model.name} ({self._dof} joints, tool {model.tool_frame!r}): '
                 f'ks={list(law.gains.ks)} kp={law.gains.kp:g} effort limits '
                 f'{law.effort_limits.tolist()} N m')
        self.get_logger().info(
            f'{values["mode"]} control on each /joint_states (expected at '
            f'{values["rate_hz"]:g} Hz) on {topic}; {gains}')
        request_realtime(self, values['realtime_priority'])
        self._wakeup_latency = hold_wakeup_latency(self, values['cpu_wakeup_latency'])

    def _on_robot_description(self, msg: String) -> None:
        """One line when the published arm lacks a joint the controller drives."""
        try:
            names = urdf_joint_names(msg.data)
        except ValueError as error:
            self.get_logger().warning(f'/robot_description unreadable: {error}')
            return
        missing = [name for name in self._joint_names if name not in names]
        if missing:
            self.get_logger().warning(
                f'/robot_description has no joint {", ".join(missing)} of the controller\'s '
                f'arm ({", ".join(self._joint_names)}): check robot / urdf_file')
        else:
            self.get_logger().info('joint names agree with /robot_description')

    # -- inputs ----------------------------------------------------------------------------
    def _warn(self, kind: str, text: str) -> None:
        """Log `text`, at most once per WARNING_THROTTLE s for each `kind` of problem."""
        now = time.monotonic()
        if now - self._warned.get(kind, -math.inf) >= WARNING_THROTTLE:
            self._warned[kind] = now
            self.get_logger().warning(text)

    def _deserialize(self, data: bytes, msg_type, what: str):
        """`data` as a `msg_type` message through rclpy's deserialiser, or None with a
        throttled warning that the `what` was dropped (any bytes may come from a raw
        publisher)."""
        try:
            return deserialize_message(data, msg_type)
        except Exception as error:  # noqa: BLE001 whatever the deserialiser raises
            self._warn(f'{what}_cdr', f'{what} dropped: unreadable ({error})')
            return None

    def _on_joint_state_data(self, data: bytes) -> None:
        """A joint state as serialized CDR: read at fixed offsets while the layout of the
        messages holds (names, lengths, frame_id), else through rclpy's deserialiser and
        _on_joint_state's checks."""
        values = self._joint_reader.read(data)
        if values is None:
            msg = self._deserialize(data, JointState, 'joint state')
            if msg is not None:
                self._on_joint_state(msg)
            return
        sec, nanosec = read_stamp(data)
        n = self._dof
        self._accept_joint_state(values[0:n], values[n:2 * n], sec + 1e-9 * nanosec,
                                 values[2 * n:] or None)

    def _on_joint_state(self, msg: JointState) -> None:
        """A joint state whose layout is not the fast path's: checked field by field."""
        names = msg.name
        position, velocity = msg.position, msg.velocity
        if len(position) != len(names) or len(velocity) != len(names):
            self._warn('joint_state_size',
                       f'joint state dropped: {len(names)} names, {len(position)} '
                       f'positions, {len(velocity)} velocities')
            return
        known, index = self._joint_index
        if names != known:
            try:
                index = tuple(names.index(joint) for joint in self._joint_names)
            except ValueError:
                self._warn('joint_state_names',
                           f'joint state dropped: names {list(names)} lack '
                           f'{", ".join(self._joint_names)}')
                return
            self._joint_index = (list(names), index)
        effort = (tuple(msg.effort[i] for i in index) if len(msg.effort) == len(names)
                  else None)
        self._accept_joint_state(tuple(position[i] for i in index),
                                 tuple(velocity[i] for i in index),
                                 msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, effort)

    def _accept_joint_state(self, q: tuple, dq: tuple, stamp: float,
                            effort: tuple | None = None) -> None:
        """Start a cycle on joint positions q (rad), velocities dq (rad/s), stamp (s) and
        the effort the drive applies (N m; None: the message has none)."""
        if not math.isfinite(sum(q) + sum(dq)):
            self._warn('joint_state_non_finite',
                       'joint state dropped: non-finite position or velocity')
            return
        previous = self._joint_stamp
        verdict = self._joint_gate.offer(stamp)
        if verdict == DROPPED:
            self._warn('joint_state_stamp', 'joint state dropped: stamp went back '
                       f'{self._joint_gate.behind(stamp):.4f} s')
            return
        now = time.monotonic()
        if verdict == RESTARTED:
            self.get_logger().info(f'joint states restarted {previous - stamp:.3f} s behind '
                                   'the last one: following the new source')
            previous = stamp  # theta_hat's dt from the receive times for this one
        # theta_hat advances by the time between the states (receive times if the stamps
        # stand still), bounded to 10 periods after a gap.
        dt = stamp - previous if stamp > previous else now - self._joint_time
        self._q, self._dq = q, dq
        self._applied = self._echo.applied(effort)
        self._joint_stamp, self._joint_time = stamp, now
        if not self._zero_timer.is_canceled():
            self._zero_timer.cancel()
        self._cycle(now, min(max(dt, 1e-6), 10.0 * self._period), stamp)

    def _on_target_data(self, data: bytes) -> None:
        """A hand position as serialized CDR: x, y read at fixed offsets (hri_core.cdr), else
        through rclpy's deserialiser."""
        values = self._target_reader.read(data)
        if values is None:
            msg = self._deserialize(data, PointStamped, 'target')
            if msg is not None:
                point = msg.point
                self._accept_target((point.x, point.y, point.z)[:self._law.model.task_axes],
                                    stamp_seconds(msg.header.stamp))
            return
        sec, nanosec = read_stamp(data)
        self._accept_target(values, sec + 1e-9 * nanosec)

    def _accept_target(self, position: tuple, stamp: float) -> None:
        """A hand position on the task axes ((x, y) for a planar arm, else (x, y, z); m), stamped
        `stamp` (s), checked before it is used."""
        if not math.isfinite(sum(position)):
            self._warn('target_non_finite', 'target dropped: non-finite position')
            return
        if math.hypot(*position) > self._values['max_target_distance']:
            self._warn('target_far',
                       f'target dropped: {[round(v, 3) for v in position]} is farther than '
                       f'max_target_distance {self._values["max_target_distance"]:g} m')
            return
        verdict = self._target_gate.offer(stamp)
        if verdict == DROPPED:
            self._warn('target_stamp', 'target dropped: stamp did not advance')
            return
        if verdict == RESTARTED:
            self.get_logger().info('targets restarted behind the last one: following the new '
                                   'source')
            self._hand.reset()
        if not self._hand.offer(stamp, position):
            self._warn('target_glitch', f'target held: a jump to '
                       f'{[round(v, 3) for v in position]} no hand can make '
                       f'({self._hand.glitches} held so far)')
            return
        self._target = tuple(position)  # plain floats: what the per-cycle step computes with

    def _on_task_state(self, msg: TaskState) -> None:
        if not (math.isfinite(msg.weight) and 0.0 <= msg.weight <= 1.0
                and math.isfinite(msg.weight_rate)):
            self._warn('task_state_weight',
                       f'task state dropped: weight {msg.weight}, rate {msg.weight_rate}')
            return
        key = (msg.task.name, msg.task.s, msg.task.a1, msg.task.a2, msg.task.d1, msg.task.d2,
               msg.task.n, msg.task.k)
        if key != self._shape_key:
            shape = None
            if msg.task.name:
                try:
                    shape = TaskShape(msg.task.s, msg.task.a1, msg.task.a2, msg.task.d1,
                                      msg.task.d2, msg.task.n)
                    self._law.drive(shape, msg.task.k)  # checks K (or its default) once
                except ValueError as error:
                    self._warn('task_state_task',
                               f'task state dropped: task {msg.task.name!r}: {error}')
                    return
            self._shape_key, self._task_payload = key, (shape, msg.task.k)
        self._task_state = msg
        self._task_time = now = time.monotonic()
        link = None if self._link is None else self._link.evaluate(now).phase
        if link == PHASE_IDLE:
            # TaskStates return after the link was down (a = 0): their weight is taken as it
            # is. Blended from the weight held since the last ones (1 when the old
            # event_manager was killed, the new one's ramp starting at 0), the task weight
            # fell while the link faded in: a rose to 0.8 and fell back to 0.05 in 30 ms.
            self._weights.reset()
        self._weights.offer(key, self._task_payload, stamp_seconds(msg.header.stamp),
                            msg.weight, msg.weight_rate)
        if self._link is None:
            self._link = EventWeightSchedule(self._values['task_fade_time'], LINK)
        elif link in (PHASE_FADING_OUT, PHASE_IDLE):
            self.get_logger().info('task states resumed: fading the task in')
            self._link.request(LINK, now)

    def _on_separation(self, msg: SeparationState) -> None:
        self._separation_cap.observe(time.monotonic(), msg.separation, msg.human_speed_used,
                                     msg.human_speed + msg.robot_speed)

    def _validate_parameters(self, parameters) -> SetParametersResult:
        changed = {p.name: p.value for p in parameters if p.name in GAIN_PARAMETERS}
        if not changed:
            return SetParametersResult(successful=True)
        values = {**self._values, **changed}
        try:
            model = self._law.model
            law = ArmController(model, gains_from(values, model), self._law.theta_hat)
        except (ValueError, TypeError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        self._values, self._law = values, law
        self._limiter.max_rate = values['max_effort_rate']
        self._set_applied_band(values)
        if self._separation_cap is not None:
            self._separation_cap.max_task_speed = values['max_task_speed']
        self.get_logger().info(f'gains changed: {changed}')
        return SetParametersResult(successful=True)

    def _set_applied_band(self, values: dict) -> None:
        """The applied-effort band (N m, 0: off) and the effort box it is centred in."""
        self._applied_band = (values['max_effort_rate'] * values['applied_effort_cycles']
                              / values['rate_hz'])
        self._effort_box = tuple(self._law.effort_limits.tolist())

    # -- control cycles ----------------------------------------------------------------------
    def _watchdog(self) -> None:
        """Start the zero-torque (gravity-hold) cycles once joint states are missing or
        stale."""
        now = time.monotonic()
        previous, self._watchdog_time = self._watchdog_time, now
        if now - previous > 2.0 * self._watchdog_period:
            # The node itself did not run for a while (a starved process, measured: 100 ms
            # on a loaded machine): the joint states may be waiting in its queue, not late.
            # Judged at the next check, once they had their turn; zero torque dropped a
            # Panda's gravity hold (22 N m) for nothing.
            return
        if (now - self._joint_time > self._values['joint_state_timeout']
                and self._zero_timer.is_canceled()):
            self._zero_timer.reset()
            self._zero_cycle()

    def _zero_cycle(self) -> None:
        now = time.monotonic()
        if now - self._joint_time <= self._values['joint_state_timeout']:
            self._zero_timer.cancel()  # joint states are back: they pace the cycles
            return
        status = 'no_joint_states' if self._q is None else 'stale_joint_states'
        if status != self._status:  # once per outage, as scara_sim's command timeout
            # An arm under gravity is held where its last joint state put it (gravity with
            # theta_hat, reached at the effort rate): zero torque dropped the Panda's 29 N m
            # on joint 2 at once, and it fell into its joint limits while a loaded machine
            # held the sim back for 0.1 s. Velocity commands get zero. Worked out once: q and
            # theta_hat stand still until a joint state comes.
            self._hold = None
            if self._q is not None and not self._velocity_mode:
                hold = self._law.gravity_hold(np.array(self._q))
                self._hold = tuple(hold.tolist()) if np.any(hold) else None
            action = 'zero torque' if self._hold is None else 'holding against gravity'
            self.get_logger().warning(f'{action}: {status.replace("_", " ")}')
        self._status = status
        self._weight = 0.0
        self._publish_command(now, None, None, hold=self._hold)

    def _cycle(self, now: float, dt: float, stamp: float) -> None:
        """One control cycle on the joint state just received (stamp in s)."""
        if self._status == 'stale_joint_states':
            self.get_logger().info('joint states resumed')
        output = self._step(now, dt, monitor=now >= self._next_state)
        self._publish_command(now, output, stamp, dt)
        if output is not None and not self._law.adapt():
            # theta_hat stays; the next cycle's torque is computed with it as before.
            self._warn('adaptation', 'parameter update dropped: not finite')

    def _publish_command(self, now: float, output, stamp: float | None,
                         dt: float = 0.0, hold: tuple | None = None) -> None:
        """Send the law's `output` (None: no law torque; `hold` (n,) N m if given, else zero
        torque) and, when due, the ControllerState."""
        self._cycles += 1
        self._rate_limited = False
        if output is None and hold is not None:
            # From the last command at the effort rate (the drive's reported effort is as
            # stale as the joint state).
            command, self._rate_limited = self._limiter.limit(hold, self._period)
        elif output is None:
            command = (0.0,) * self._dof
            self._limiter.reset()  # zero torque at once (safety), the next change from zero
        elif self._velocity_mode:
            command = output.qdot_r
        else:
            # At most one period's worth per command, and near what the drive applies (see
            # effort_rate).
            applied = self._applied if self._applied_band > 0.0 else None
            if applied is not None:
                applied = tuple(min(max(v, -limit), limit)
                                for v, limit in zip(applied, self._effort_box, strict=True))
            command, self._rate_limited = self._limiter.limit(
                output.tau, min(dt, self._period), applied, self._applied_band)
        self._command_pub.publish(self._command_template.encode(command))
        if self._applied_band > 0.0 and not self._velocity_mode:  # velocities echo nothing
            self._echo.sent(tuple(command))
        # One read of the clock for input_age and the ControllerState's stamp: the stamp minus
        # input_age is then exactly the stamp of the joint state the cycle ran on, and the
        # cycle's own time lies between the two. The node's clock is the system clock unless
        # ROS time is active (use_sim_time): time.time_ns() reads that in 0.1 us, against 4 us
        # for get_clock().now().
        published = time.time_ns() if self._system_clock else self.get_clock().now().nanoseconds
        if stamp is not None:
            self._input_age = published * 1e-9 - stamp
            if self._input_age > self._late:
                self._misses += 1
        if now >= self._next_state:
            # On a fixed schedule, whatever the rate of the cycles; no catching up.
            due = self._next_state + self._state_period
            self._next_state = due if due > now else now + self._state_period
            self._publish_state(now, output, command, published)
            # use_sim_time may change at run time: looked at again at each ControllerState.
            self._system_clock = not self.get_clock().ros_time_is_active

    def _link_state(self, now: float) -> WeightState:
        """The link weight at `now` (monotonic s): the first cycle more than
        task_state_timeout s after the last TaskState starts its fade-out."""
        if self._link is None:
            return LINK_DOWN
        state = self._link.evaluate(now)
        if (now - self._task_time > self._values['task_state_timeout']
                and state.phase in (PHASE_ACTIVE, PHASE_FADING_IN)):
            self.get_logger().warning(
                f'no TaskState for {self._values["task_state_timeout"]:g} s: fading the task '
                f'out over {self._values["task_fade_time"]:g} s')
            state = self._link.request(None, now)
        return state

    def _step(self, now: float, dt: float, monitor: bool):
        self._weight = 0.0  # no task force acts unless the step below runs
        if self._target is None:
            self._status = 'no_target'
            # An arm under gravity is held where it is (no task, no hand motion) rather than
            # let fall.
            return self._arm_step(None, 0.0, 0.0, None, dt)
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
                if self._fixed_rest is None:
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
        if self._separation_cap is not None:
            self._law.limit_pull_speed(self._separation_cap.knee(now))
        return self._arm_step((target, target_velocity), weight, rate,
                              None if shape is None else (shape, k), dt)

    def _step_failed(self, error: Exception) -> None:
        """A control step that raised: zero torque (None) and a throttled warning."""
        self._status = f'fault: {type(error).__name__}'
        self._warn('internal', f'zero torque: control step failed: {error!r}')

    def _checked(self, output):
        """`output`, or None (zero torque, a throttled warning) if the law flagged a fault."""
        if output.fault:
            self._status = f'fault: {output.fault_reason}'
            self._warn('fault', f'zero torque: {output.fault_reason}')
            return None
        return output

    def _arm_step(self, hand, weight: float, rate: float, task, dt: float):
        """arm_law's command: hand (x_d, xdot_d) tuples on the task axes or None (held where
        the tool is), task (shape, k) or None. The ArmOutput, or None on a fault.
        What the torque does not need waits until it is sent: theta_hat's update (_cycle) and
        V (_publish_state: 1/2 s^T M s and the barrier's energy, every 10th cycle)."""
        arm = self._law
        q, dq = np.array(self._q), np.array(self._dq)
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
            # The torque only: theta_hat's update (eq. 19) waits until it is sent (_cycle).
            output = arm.command(q, dq, HandState(position, velocity, np.zeros(velocity.size)),
                                 active, dt, self._rest_array[1])
        except Exception as error:  # noqa: BLE001 a robot command must stay safe
            return self._step_failed(error)
        return self._checked(output)

    def _tool_position(self) -> np.ndarray:
        """The tool on the task axes (m) at the last joint state."""
        q = np.array(self._q)
        return self._law.model.task_kinematics(q, np.zeros(q.size))[0]

    def _publish_state(self, now: float, output, command, published: int) -> None:
        started, ticks = self._window
        if now - started >= 1.0:
            self._rate = (self._cycles - ticks) / (now - started)
            self._window = (now, self._cycles)
        # The arrays as array('d') from their bytes: rosidl's setters check a list element by
        # element (77 values of the Panda's theta_hat), an array('d') not at all.
        msg = ControllerState(deadline_misses=self._misses, rate_hz=self._rate,
                              input_age=self._input_age, target_glitches=self._hand.glitches,
                              status=self._status,
                              effort=array('d', np.asarray(command, dtype=float).tobytes()),
                              theta_hat=array('d', self._law.theta_hat.tobytes()))
        msg.header.stamp = Time(nanoseconds=published).to_msg()
        if self._task_state is not None:
            msg.task = self._task_state.task.name
        if output is not None:
            msg.distance = float(output.distance)
            try:
                output = output._replace(lyapunov=self._law.lyapunov(output, self._q, None))
            except Exception as error:  # noqa: BLE001 monitoring must not stop control
                self._warn('lyapunov', f'V not reported: {error!r}')
            if output.lyapunov is not None:
                try:
                    task = self._weight * self._law.task_energy(output.distance,
                                                                *self._cycle_task)
                except Exception as error:  # noqa: BLE001 monitoring must not stop control
                    self._warn('lyapunov', f'V reported without its task term: {error!r}')
                    task = 0.0
                msg.lyapunov = output.lyapunov + task
            msg.sliding_norm = math.hypot(*output.s)
            msg.weight = self._weight
            msg.saturated = bool(output.torque_limited or self._rate_limited)
        elif self._q is not None and self._target is not None:
            msg.distance = float(np.linalg.norm(self._tool_position() - np.array(self._target)))
        self._state_pub.publish(msg)


def main(args=None):
    # The control steps run without np.errstate (4 us a cycle, arm_law) and check their
    # results for finiteness instead: floating-point warnings would only add stderr lines
    # for a state far out of range, which then ends as a fault (zero torque).
    np.seterr(all='ignore')
    # The 1 kHz cycles: the EventsExecutor at a fraction of the CPU.
    return run_node(Controller, NODE_NAME, EventsExecutor, args)


if __name__ == '__main__':
    sys.exit(main())
