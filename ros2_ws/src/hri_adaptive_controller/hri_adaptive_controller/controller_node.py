"""The `controller` node: the adaptive HRI controller of paper eq. 14-19 on topics.

Event-driven: each /joint_states message that arrives is the start of a control cycle. The
node reads the messages (the 1 kHz ones, /joint_states and /target, as raw CDR at fixed
offsets: hri_core.cdr; joints mapped by name, wrong lengths and unknown names dropped) and
hands each input, with time.monotonic(), to control_cycle.ControlCycle, which decides the
rest: the law (arm_law.ArmController) for the arm `robot` or `urdf_file`, the holds, fades,
filters and limits, the gravity hold of stale joint states and what ControllerState reports
(its module docstring lists them, docs/design.md argues them). The node publishes the cycle's
torque on /effort_controller/commands (ros2_control's JointGroupEffortController; with
`mode: velocity` qdot_r of eq. 14 on /velocity_controller/commands) and its reports on
/hri/controller_state, stamped with the commands' publication time on the node's clock (which
also judges deadlines against the joint states' stamps). A watchdog timer (every
joint_state_timeout / 4) asks the cycle whether joint states are missing or stale; while they
are, a timer at `rate_hz` runs the cycle's hold in place of the cycles that do not come. The
cycle's notes are logged, a repeated kind of problem at most once per WARNING_THROTTLE s.
The parameters' table: controller_parameters (re-exported here).

With `realtime_priority` > 0 the process asks for SCHED_FIFO at that priority
(hri_core.realtime); with `cpu_wakeup_latency` >= 0 it holds a PM QoS request that idle CPUs
wake within that many microseconds (0: they poll). With `separation_speed_limit` on,
/hri/separation caps the task's speed towards the hand (S_p's constants: the
event_detector's).
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

from hri_adaptive_controller.arm_law import ArmController
from hri_adaptive_controller.control_cycle import (
    INFO,
    WARNING,
    ControlCycle,
    CycleReport,
    CycleSettings,
    Note,
    TaskInput,
)
from hri_adaptive_controller.controller_parameters import (  # noqa: F401 (re-exported)
    GAIN_PARAMETERS,
    PARAMETERS,
    gains_from,
    initial_estimate,
    model_from,
    rest_position_from,
    robot_body_from,
)
from hri_core import topics
from hri_core.cdr import (
    EFFORT,
    POSITION,
    VELOCITY,
    LayoutReader,
    float64_array_template,
    human_body_layout,
    joint_state_layout,
    point3_layout,
    point_stamped_layout,
    read_frame,
    read_stamp,
)
from hri_core.node_common import (
    StartupError,
    declare_parameters,
    hold_wakeup_latency,
    load_defaults,
    request_realtime,
    run_node,
    stamp_seconds,
)
from hri_core.robot_description import urdf_joint_names
from hri_core.separation import ProtectiveSeparation

PACKAGE = 'hri_adaptive_controller'
NODE_NAME = 'controller'
WARNING_THROTTLE = 2.0  # s between repeats of one kind of warning


class Controller(Node):
    """Adaptive torque controller between joint states, target, task state and commands."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self._values = values = declare_parameters(self, PARAMETERS,
                                                   load_defaults(PACKAGE, NODE_NAME))
        try:
            model = model_from(values)
            gains = gains_from(values, model)
            body, problem = robot_body_from(values, model)
            # The law keeps clear of the person with a clearance; the cap uses the body alone.
            law = ArmController(model, gains, initial_estimate(values, model, gains),
                                body=body if values['clearance'] > 0.0 else None)
            # ISO/TS 15066 speed cap with S_p's constants from the detector's YAML.
            separation = (ProtectiveSeparation.from_mapping(
                load_defaults(PACKAGE, 'event_detector'))
                if values['separation_speed_limit'] else None)
            settings = CycleSettings.from_values(values, rest_position_from(values, model),
                                                 separation)
        except ValueError as error:
            raise StartupError(f'bad controller parameters: {error}') from None
        if problem:
            self.get_logger().warning(f'whole-body clearance and separation pairs off: {problem}')
        self._cycle = ControlCycle(law, settings, self._log, body)
        self._joint_names = model.joint_names
        self._dof, self._axes = model.dof, model.task_axes
        self._joint_index = (None, None)  # (names of the last joint state, indices of ours)
        self._warned: dict[str, float] = {}
        self._system_clock = not self.get_clock().ros_time_is_active
        # The 1 kHz messages as raw CDR (hri_core.cdr): joint states read at fixed offsets
        # while their layout holds, commands written from a template.
        self._joint_reader = LayoutReader(lambda data: joint_state_layout(
            data, self._joint_names, (POSITION, VELOCITY, EFFORT), one_value_per_name=True)
            or joint_state_layout(data, self._joint_names, (POSITION, VELOCITY),
                                  one_value_per_name=True))
        self._command_template = float64_array_template(self._dof)
        # The hand's coordinates on the task axes: x, y for a planar arm; x, y, z otherwise.
        self._target_reader = LayoutReader(point_stamped_layout if self._axes == 2
                                           else point3_layout)
        command = topics.VELOCITY_COMMANDS if settings.velocity_mode else topics.EFFORT_COMMANDS
        self._command_pub = self.create_publisher(command.type, command.name, command.qos)
        self._state_pub = self.create_publisher(
            ControllerState, topics.CONTROLLER_STATE.name, topics.CONTROLLER_STATE.qos)
        # Only the newest joint state matters: each joint state starts a cycle.
        self.create_subscription(JointState, topics.JOINT_STATES.name, self._on_joint_state_data,
                                 topics.LATEST_SAMPLE_QOS, raw=True)
        # Every hand position, in order: the glitch filter judges each against the one before,
        # and a sample lost to a stalled executor leaves a gap after which the real hand is
        # held until confirmed (a held count above the swap samples sent, in one CI run).
        # Raw: a position landing just before a joint state delays that cycle by its callback,
        # which a Python message made 3 times longer.
        self.create_subscription(PointStamped, topics.TARGET.name, self._on_target_data,
                                 topics.TARGET.qos, raw=True)
        self.create_subscription(TaskState, topics.TASK_STATE.name, self._on_task_state,
                                 topics.TASK_STATE.qos)
        # The arm a simulator or robot_state_publisher describes, checked once it comes.
        self.create_subscription(String, topics.ROBOT_DESCRIPTION.name,
                                 self._on_robot_description, topics.ROBOT_DESCRIPTION.qos)
        if law.body is not None:  # the person's body points, kept clear of by every link
            # Raw: a body comes with each hand position (100 Hz), and a joint state landing
            # during its callback waits for it (20 us of rclpy's deserialiser saved).
            self._body_reader = LayoutReader(human_body_layout)
            self.create_subscription(topics.HUMAN_BODY.type, topics.HUMAN_BODY.name,
                                     self._on_body_data, topics.HUMAN_BODY.qos, raw=True)
        if separation is not None:
            self.create_subscription(SeparationState, topics.SEPARATION.name,
                                     self._on_separation, topics.SEPARATION.qos)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.create_timer(settings.watchdog_period, self._watchdog)
        # The hold cycles at the control rate while joint states are missing or stale; running
        # from the start, since none has arrived yet.
        self._hold_timer = self.create_timer(settings.period, self._hold_cycle)
        self.get_logger().info(
            f'{values["mode"]} control on each /joint_states (expected at '
            f'{values["rate_hz"]:g} Hz) on {self._command_pub.topic_name}; {model.name} '
            f'({self._dof} joints, tool {model.tool_frame!r}): ks={list(law.gains.ks)} '
            f'kp={law.gains.kp:g} effort limits {law.effort_limits.tolist()} N m')
        request_realtime(self, values['realtime_priority'])
        self._wakeup_latency = hold_wakeup_latency(self, values['cpu_wakeup_latency'])

    def _log(self, note: Note) -> None:
        """Log a note of the cycle (or the node's own), a `kind` of problem at most once per
        WARNING_THROTTLE s."""
        if note.kind is not None:
            now = time.monotonic()
            if now - self._warned.get(note.kind, -math.inf) < WARNING_THROTTLE:
                return
            self._warned[note.kind] = now
        if note.level == INFO:  # one call site per severity: rclpy's logger demands it
            self.get_logger().info(note.text)
        else:
            self.get_logger().warning(note.text)

    def _on_body_data(self, data: bytes) -> None:
        """A HumanBody as serialized CDR: read at fixed offsets (hri_core.cdr), else through
        rclpy's deserialiser."""
        values = self._body_reader.read(data)
        if values is None:
            msg = self._deserialize(data, topics.HUMAN_BODY.type, 'body')
            if msg is not None:
                self._body(stamp_seconds(msg.header.stamp), msg.names,
                           [(p.x, p.y, p.z) for p in msg.points], msg.header.frame_id)
            return
        sec, nanosec = read_stamp(data)
        self._body(sec + 1e-9 * nanosec, self._body_reader.layout.names,
                   np.reshape(values, (-1, 3)), read_frame(data))

    def _body(self, stamp: float, names, points, frame: str) -> None:
        self._cycle.body(time.monotonic(), names, points, stamp if stamp > 0.0 else None, frame)

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

    # -- inputs ------------------------------------------------------------------------------
    def _deserialize(self, data: bytes, msg_type, what: str):
        """`data` as a `msg_type` message through rclpy's deserialiser, or None with a
        throttled warning that the `what` was dropped (any bytes may come from a raw
        publisher)."""
        try:
            return deserialize_message(data, msg_type)
        except Exception as error:  # noqa: BLE001 whatever the deserialiser raises
            self._log(Note(WARNING, f'{what}_cdr', f'{what} dropped: unreadable ({error})'))
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
            self._log(Note(WARNING, 'joint_state_size',
                           f'joint state dropped: {len(names)} names, {len(position)} '
                           f'positions, {len(velocity)} velocities'))
            return
        known, index = self._joint_index
        if names != known:
            try:
                index = tuple(names.index(joint) for joint in self._joint_names)
            except ValueError:
                self._log(Note(WARNING, 'joint_state_names',
                               f'joint state dropped: names {list(names)} lack '
                               f'{", ".join(self._joint_names)}'))
                return
            self._joint_index = (list(names), index)
        effort = (tuple(msg.effort[i] for i in index) if len(msg.effort) == len(names)
                  else None)
        self._accept_joint_state(tuple(position[i] for i in index),
                                 tuple(velocity[i] for i in index),
                                 msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, effort)

    def _accept_joint_state(self, q: tuple, dq: tuple, stamp: float,
                            effort: tuple | None = None) -> None:
        """A control cycle on q (rad), dq (rad/s), stamp (s) and the effort the drive reports
        (N m; None: the message has none), unless the cycle drops the state."""
        now = time.monotonic()
        command = self._cycle.joint_state(now, q, dq, stamp, effort)
        if command is None:
            return
        if not self._hold_timer.is_canceled():
            self._hold_timer.cancel()
        self._send(now, command)

    def _on_target_data(self, data: bytes) -> None:
        """A hand position as serialized CDR: read at fixed offsets (hri_core.cdr), else
        through rclpy's deserialiser."""
        values = self._target_reader.read(data)
        if values is None:
            msg = self._deserialize(data, PointStamped, 'target')
            if msg is not None:
                point = msg.point
                self._cycle.target(time.monotonic(), (point.x, point.y, point.z)[:self._axes],
                                   stamp_seconds(msg.header.stamp), msg.header.frame_id)
            return
        sec, nanosec = read_stamp(data)
        self._cycle.target(time.monotonic(), values, sec + 1e-9 * nanosec, read_frame(data))

    def _on_task_state(self, msg: TaskState) -> None:
        task = msg.task
        self._cycle.task_state(
            time.monotonic(),
            TaskInput(task.name, task.s, task.a1, task.a2, task.d1, task.d2, task.n, task.k),
            stamp_seconds(msg.header.stamp), msg.weight, msg.weight_rate)

    def _on_separation(self, msg: SeparationState) -> None:
        robot, body = msg.robot_point, msg.body_point
        self._cycle.separation(time.monotonic(), msg.separation, msg.human_speed_used,
                               msg.human_speed + msg.robot_speed,
                               (msg.robot_link, (robot.x, robot.y, robot.z),
                                (body.x, body.y, body.z)))

    def _validate_parameters(self, parameters) -> SetParametersResult:
        changed = {p.name: p.value for p in parameters if p.name in GAIN_PARAMETERS}
        if not changed:
            return SetParametersResult(successful=True)
        values = {**self._values, **changed}
        try:
            model = self._cycle.law.model
            law = ArmController(model, gains_from(values, model), self._cycle.law.theta_hat,
                                body=self._cycle.law.body)
        except (ValueError, TypeError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        self._values = values
        self._cycle.retune(law, dataclasses.replace(
            self._cycle.settings, applied_effort_cycles=values['applied_effort_cycles']))
        self.get_logger().info(f'gains changed: {changed}')
        return SetParametersResult(successful=True)

    # -- the watchdog, the hold and the outputs ----------------------------------------------
    def _watchdog(self) -> None:
        """Start the hold cycles once joint states are missing or stale."""
        if self._cycle.watchdog(time.monotonic()):
            self._hold_timer.reset()
            self._hold_cycle()

    def _hold_cycle(self) -> None:
        now = time.monotonic()
        command = self._cycle.hold(now)
        if command is None:
            self._hold_timer.cancel()  # joint states are back: they pace the cycles
            return
        self._send(now, command)

    def _send(self, now: float, command: tuple) -> None:
        """Publish the cycle's command (none if empty: no joint state yet), then the
        ControllerState when the cycle has one."""
        if command:
            self._command_pub.publish(self._command_template.encode(command))
        # One read of the clock for input_age and the ControllerState's stamp: the stamp minus
        # input_age is then exactly the stamp of the joint state the cycle ran on. The node's
        # clock is the system clock unless ROS time is active (use_sim_time): time.time_ns()
        # reads that in 0.1 us, against 4 us for get_clock().now().
        published = time.time_ns() if self._system_clock else self.get_clock().now().nanoseconds
        report = self._cycle.sent(now, published * 1e-9)
        if report is not None:
            self._state_pub.publish(self._state_message(report, published))
            # use_sim_time may change at run time: looked at again at each ControllerState.
            self._system_clock = not self.get_clock().ros_time_is_active

    def summary(self) -> str:
        """One line on what the node did (run_node logs it at the stop)."""
        cycle = self._cycle
        return (f'{cycle.cycles} commands computed ({cycle.deadline_misses} deadline misses); '
                f'{cycle.target_glitches} /target samples held as glitches, '
                f'{cycle.target_reanchors} re-anchored; last status {cycle.status}')

    @staticmethod
    def _state_message(report: CycleReport, published: int) -> ControllerState:
        # The arrays as array('d'): rosidl's setters check a list element by element (77
        # values of the Panda's theta_hat), an array('d') not at all.
        msg = ControllerState(
            distance=report.distance, lyapunov=float(report.lyapunov),
            sliding_norm=report.sliding_norm, weight=report.weight,
            theta_hat=array('d', report.theta_hat.tobytes()),
            effort=array('d', np.asarray(report.effort, dtype=float).tobytes()),
            deadline_misses=report.deadline_misses, rate_hz=report.rate_hz, task=report.task,
            saturated=report.saturated, input_age=report.input_age, status=report.status,
            target_glitches=report.target_glitches)
        msg.header.stamp = Time(nanoseconds=published).to_msg()
        return msg


def main(args=None):
    # The control steps run without np.errstate (4 us a cycle, arm_law) and check their
    # results for finiteness instead: floating-point warnings would only add stderr lines
    # for a state far out of range, which then ends as a fault (zero torque).
    np.seterr(all='ignore')
    # The 1 kHz cycles: the EventsExecutor at a fraction of the CPU.
    return run_node(Controller, NODE_NAME, EventsExecutor, args)


if __name__ == '__main__':
    sys.exit(main())
