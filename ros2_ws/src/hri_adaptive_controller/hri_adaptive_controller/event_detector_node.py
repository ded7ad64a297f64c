"""The `event_detector` node: watches the hand and the tool, sends events by rules, and
publishes their separation with the ISO/TS 15066 protective separation distance.

    ros2 run hri_adaptive_controller event_detector [--ros-args --params-file MY.yaml]

Inputs: the hand on /target and the tool on /ee_position (geometry_msgs/PointStamped in the base
frame: x and y, or x, y and z with `dimension` 3 for an arm that moves in space), the current
task on /hri/task_state (the task the event_manager is heading to: its pending task during a
switch). Every 1 / publish_rate_hz s the node takes what has
come (the subscriptions live on an intake node no executor spins, so the 1 kHz tool positions
cost no callback each), estimates both velocities (hri_core.velocity_estimator), and

- runs the rules of parameter `rules` (YAML text; event_rules describes them): each firing
  is a hri_interfaces/TaskEvent on /hri/events (the rule's event name and task) and one log
  line saying why;
- publishes hri_interfaces/SeparationState on /hri/separation (separation, the speeds towards
  each other, S_p of ISO/TS 15066 from the parameters below, and whether the separation is
  below it: hri_core.separation) while both the hand and the tool are known (their newest samples
  no older than input_timeout); nothing otherwise, never a NaN.

The whole body (`robot` set: scara or panda): with a person on /human/body (hri_interfaces/
HumanBody) and the arm's /joint_states, the separation is the least distance between the
robot's capsules and the person's (hri_core.bodies; fitted once at start), the speeds those of
the pair's two closest points along its normal (the robot's through the point Jacobian, the
person's from successive body messages), and the message names the pair (robot_link,
body_part) and its points. Until a body has come, or once the newest is older than
`body_timeout` (one warning; one line when it is back), it falls back to the tool and the
hand with empty names. The rules keep watching the hand and the tool.

A bad rule set or parameter ends the node at start with a one-line reason (exit 1). A hand or
tool position that is not finite or cannot be read is dropped with a throttled warning.
"""

import math
import sys
import time

from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import SeparationState, TaskEvent, TaskState
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from hri_adaptive_controller.event_rules import EventDetector, RuleError, load_rules
from hri_adaptive_controller.separation_monitor import BodySeparation, SeparationMonitor
from hri_core import topics
from hri_core.bodies import panda_package_dirs, robot_body, seen_body_points
from hri_core.cdr import LayoutReader, point3_layout, point_stamped_layout, read_frame, read_stamp
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    run_node,
    take_raw,
)
from hri_core.robot_model import ROBOT_NAMES, robot_model
from hri_core.separation import ProtectiveSeparation
from hri_core.validation import check_frame

PACKAGE = 'hri_adaptive_controller'
NODE_NAME = 'event_detector'
WARNING_THROTTLE = 1.0  # s between repeats of one kind of warning


def _constant(description: str) -> ParameterSpec:
    """A constant of S_p: a time (s) or a length (m) in [0, 10]."""
    return ParameterSpec(float, description, low=0.0, high=10.0, read_only=True)


PARAMETERS = {
    'rules': ParameterSpec(str, 'the event rules as YAML text: a mapping rule name -> '
                           'settings (hri_adaptive_controller/event_rules.py)', read_only=True),
    'dimension': ParameterSpec(int, 'coordinates of the positions compared: 2 (x, y: the '
                               'planar SCARA) or 3 (x, y, z: an arm in space)', low=2, high=3,
                               read_only=True),
    'publish_rate_hz': ParameterSpec(float, 'rate of the rules and of /hri/separation (Hz)',
                                     low=1.0, high=500.0, read_only=True),
    'hand_filter_time': ParameterSpec(float, 'time constant of the hand velocity estimate (s)',
                                      low=1e-3, high=2.0, read_only=True),
    'tool_filter_time': ParameterSpec(float, 'time constant of the tool velocity estimate (s)',
                                      low=1e-3, high=2.0, read_only=True),
    'input_timeout': ParameterSpec(float, 'a hand or tool sample older than this counts as '
                                   'absent (s)', low=0.01, high=10.0, read_only=True),
    'reaction_time': _constant('T_r of S_p: the system reaction time (s)'),
    'stopping_time': _constant('T_s of S_p: the arm stopping time under the controller (s)'),
    'stopping_distance': _constant('B of S_p: the arm stopping distance (m)'),
    'intrusion_distance': _constant('C of S_p: how far a hand reaches beyond its tracked '
                                  'point (m)'),
    'human_uncertainty': _constant('Z_d of S_p: position uncertainty of the hand (m)'),
    'robot_uncertainty': _constant('Z_r of S_p: position uncertainty of the tool (m)'),
    'near_speed': ParameterSpec(float, 'ISO 13855 approach speed within near_limit (m/s)',
                                low=1e-3, high=10.0, read_only=True),
    'far_speed': ParameterSpec(float, 'ISO 13855 approach speed beyond near_limit (m/s)',
                               low=1e-3, high=10.0, read_only=True),
    'near_limit': ParameterSpec(float, 'separation up to which near_speed applies (m)',
                                low=1e-3, high=10.0, read_only=True),
    'assume_iso_speed': ParameterSpec(bool, 'v_h of S_p is at least the ISO 13855 speed '
                                      '(false: the measured speed alone)', read_only=True),
    'robot': ParameterSpec(str, 'the arm whose capsules meet the person on /human/body: '
                           + ', '.join(ROBOT_NAMES) + '; "" for the tool and the hand only',
                           choices=('', *ROBOT_NAMES), read_only=True),
    'body_timeout': ParameterSpec(float, 'a /human/body older than this is stale: the '
                                  'separation falls back to the tool and the hand (s)',
                                  low=0.01, high=10.0, read_only=True),
    'base_frame': ParameterSpec(str, 'frame of /target, /ee_position and /human/body, and of '
                                '/hri/separation; a message in another frame is dropped '
                                '("" on a message: taken as this frame)', read_only=True),
    'body_padding': ParameterSpec(float, 'added to every fitted robot capsule radius (m)',
                                  low=0.0, high=0.5, read_only=True),
}


class EventDetectorNode(Node):
    """Rules on the hand and the tool -> /hri/events; their separation -> /hri/separation."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        try:
            rules = load_rules(values['rules'])
        except RuleError as error:
            raise StartupError(f'bad parameter rules: {error}') from None
        settings = ProtectiveSeparation.from_mapping(values)
        self._detector = EventDetector(rules)
        self._monitor = SeparationMonitor(settings, values['hand_filter_time'],
                                          values['tool_filter_time'], values['input_timeout'],
                                          values['dimension'])
        self._dimension = values['dimension']
        self._body = None
        if values['robot']:
            try:
                model = robot_model(values['robot'])
                body = robot_body(model, panda_package_dirs() if values['robot'] == 'panda'
                                  else (), values['body_padding'])
            except ValueError as error:
                raise StartupError(f'bad parameter robot: {error}') from None
            self._body = BodySeparation(body, settings, values['body_timeout'],
                                        values['input_timeout'])
            self._joint_index = None
        self._body_state = 'none'  # none (never had one), fresh, stale
        self._current_task: str | None = None
        self._frame = values['base_frame']
        self._tool_reader = LayoutReader(point_stamped_layout if self._dimension == 2
                                         else point3_layout)
        self._last_warning: dict[str, float] = {}
        # What the node did, for its summary line at the stop.
        self._counts = dict.fromkeys(('hand', 'tool', 'events', 'separations', 'closer'), 0)

        self._event_pub = self.create_publisher(TaskEvent, topics.EVENTS.name,
                                                topics.EVENTS.qos)
        self._separation_pub = self.create_publisher(
            SeparationState, topics.SEPARATION.name, topics.SEPARATION.qos)
        self.create_subscription(TaskState, topics.TASK_STATE.name, self._on_task_state,
                                 topics.TASK_STATE.qos)
        # The positions on a node no executor spins, taken each tick (as the recorder's
        # intake): 1000 tool positions a second would otherwise be 1000 callbacks. Its topic
        # names are this node's, remappings applied.
        self._intake = Node(f'{NODE_NAME}_intake', context=self.context,
                            use_global_arguments=False, start_parameter_services=False)
        self._hand_sub = self._intake.create_subscription(
            PointStamped, self.resolve_topic_name(topics.TARGET.name), lambda _: None,
            topics.TARGET.qos, raw=True)
        self._tool_sub = self._intake.create_subscription(
            PointStamped, self.resolve_topic_name(topics.EE_POSITION.name), lambda _: None,
            topics.EE_POSITION.qos, raw=True)
        if self._body is not None:
            self._body_sub = self._intake.create_subscription(
                topics.HUMAN_BODY.type, self.resolve_topic_name(topics.HUMAN_BODY.name),
                lambda _: None, topics.HUMAN_BODY.qos, raw=True)
            self._joint_sub = self._intake.create_subscription(
                JointState, self.resolve_topic_name(topics.JOINT_STATES.name), lambda _: None,
                topics.LATEST_SAMPLE_QOS, raw=True)
        self.create_timer(1.0 / values['publish_rate_hz'], self._tick)
        listed = ', '.join(f'{rule.name} ({rule.kind} -> {rule.task or "none"})'
                           for rule in rules)
        self.get_logger().info(
            f'{len(rules)} rule(s): {listed or "none"}'
            f'; /hri/separation at {values["publish_rate_hz"]:g} Hz, S_p = v_h '
            f'({settings.reaction_time:g} + {settings.stopping_time:g}) + v_r '
            f'{settings.reaction_time:g} + {settings.stopping_distance:g} + '
            f'{settings.intrusion_distance:g} + {settings.human_uncertainty:g} + '
            f'{settings.robot_uncertainty:g} m'
            + (f'; whole body: {values["robot"]} ({len(self._body.robot.names)} capsules, '
               f'tool {self._body.robot.tool}) against /human/body'
               if self._body is not None else ''))

    def _warn(self, kind: str, text: str) -> None:
        """`text` as a warning, at most once per WARNING_THROTTLE s for each `kind`."""
        now = time.monotonic()
        if now - self._last_warning.get(kind, -math.inf) >= WARNING_THROTTLE:
            self._last_warning[kind] = now
            self.get_logger().warning(text)

    def _in_base_frame(self, frame: str, what: str) -> bool:
        """Whether a `what` message's frame is base_frame (or unset); else a throttled
        warning: the detector transforms nothing."""
        try:
            check_frame(frame, self._frame)
        except ValueError as error:
            self._warn(f'{what}_frame', f'{what} dropped: {error}')
            return False
        return True

    def _on_task_state(self, msg: TaskState) -> None:
        """The current task: where the event_manager is heading ('' = no task). While it
        fades out, that is the pending task ('' when the switch is to no task)."""
        if msg.phase == TaskState.PHASE_FADING_OUT:
            self._current_task = msg.pending_task
        elif msg.phase == TaskState.PHASE_IDLE:
            self._current_task = ''
        else:
            self._current_task = msg.task.name

    def _take_hand(self, now: float) -> None:
        for data, _ in take_raw(self._hand_sub):
            try:
                msg = deserialize_message(data, PointStamped)
            except Exception as error:  # noqa: BLE001 whatever the deserialiser raises
                self._warn('hand_cdr', f'target dropped: unreadable ({error})')
                continue
            point = (msg.point.x, msg.point.y, msg.point.z)[:self._dimension]
            if not self._in_base_frame(msg.header.frame_id, 'target'):
                continue
            if not all(math.isfinite(v) for v in point):
                self._warn('hand_non_finite', 'target dropped: non-finite position')
                continue
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            self._monitor.hand(point, stamp, now)
            self._counts['hand'] += 1

    def _take_tool(self, now: float) -> None:
        for data, _ in take_raw(self._tool_sub):
            values = self._tool_reader.read(data)
            if values is None:
                try:
                    msg = deserialize_message(data, PointStamped)
                except Exception as error:  # noqa: BLE001 whatever the deserialiser raises
                    self._warn('tool_cdr', f'ee_position dropped: unreadable ({error})')
                    continue
                values = (msg.point.x, msg.point.y, msg.point.z)[:self._dimension]
                stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                frame = msg.header.frame_id
            else:
                sec, nanosec = read_stamp(data)
                stamp = sec + 1e-9 * nanosec
                frame = read_frame(data)
            if not self._in_base_frame(frame, 'ee_position'):
                continue
            if not all(math.isfinite(v) for v in values):
                self._warn('tool_non_finite', 'ee_position dropped: non-finite position')
                continue
            self._monitor.tool(values, stamp, now)
            self._counts['tool'] += 1

    def _take_body(self, now: float) -> None:
        for data, _ in take_raw(self._body_sub):
            try:
                msg = deserialize_message(data, topics.HUMAN_BODY.type)
                if not self._in_base_frame(msg.header.frame_id, 'human body'):
                    continue
                seen = seen_body_points(msg.names, [(p.x, p.y, p.z) for p in msg.points])
                stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                self._body.body(seen.names, seen.points, stamp, now)
            except Exception as error:  # noqa: BLE001 the deserialiser's or ours (ValueError)
                self._warn('body_bad', f'human body dropped: {error}')
                continue
            if seen.lost:
                self._warn('body_lost', f'human body points not finite, taken as lost: '
                           f'{", ".join(seen.lost)}')
            if seen.unknown:
                self._warn('body_unknown', f'human body points ignored: '
                           f'{", ".join(seen.unknown)} (not REP-155 body point names)')
        latest = None
        for data, _ in take_raw(self._joint_sub):
            latest = data
        if latest is None:
            return
        try:
            msg = deserialize_message(latest, JointState)
        except Exception as error:  # noqa: BLE001 whatever the deserialiser raises
            self._warn('joints_cdr', f'joint state dropped: unreadable ({error})')
            return
        names = self._body.robot.model.joint_names
        try:
            index = [list(msg.name).index(name) for name in names]
            q = [msg.position[k] for k in index]
            dq = [msg.velocity[k] if len(msg.velocity) > k else 0.0 for k in index]
        except (ValueError, IndexError):
            self._warn('joints_names', f'joint state dropped: it lacks {", ".join(names)}')
            return
        if not all(math.isfinite(v) for v in (*q, *dq)):
            self._warn('joints_non_finite', 'joint state dropped: non-finite values')
            return
        self._body.joints(q, dq, now)

    def _body_sample(self, now: float):
        """The whole-body sample, or None (fall back to tool and hand); a stale body is told
        once, its return once."""
        if self._body is None:
            return None
        self._take_body(now)
        fresh = self._body.body_fresh(now)
        if fresh and self._body_state != 'fresh':
            self.get_logger().info('human body on /human/body: separation over the whole body')
            self._body_state = 'fresh'
        elif not fresh and self._body_state == 'fresh':
            self.get_logger().warning('human body stale (none for body_timeout): separation '
                                      'of the tool and the hand until it is back')
            self._body_state = 'stale'
        return self._body.observe(now) if fresh else None

    def _tick(self) -> None:
        now = time.monotonic()
        self._take_hand(now)
        self._take_tool(now)
        observation, sample = self._monitor.observe(now)
        body = self._body_sample(now)
        stamp = self.get_clock().now().to_msg()
        for firing in self._detector.update(observation, self._current_task):
            rule = firing.rule
            event = TaskEvent(name=rule.event, task=rule.task)
            event.header.stamp = stamp
            self._event_pub.publish(event)
            self._counts['events'] += 1
            self.get_logger().info(
                f'event {rule.event!r} -> task {rule.task or "none"!r} (rule {rule.name}, task '
                f'{self._current_task!r}): {firing.reason}')
        if body is not None:
            sample = body.sample
        if sample is None:
            return
        msg = SeparationState(separation=sample.separation, human_speed=sample.human_speed,
                              robot_speed=sample.robot_speed,
                              human_speed_used=sample.human_speed_used,
                              protective_distance=sample.protective_distance,
                              below_protective=sample.below_protective)
        if body is not None:
            msg.robot_link, msg.body_part = body.robot_link, body.body_part
            msg.robot_point.x, msg.robot_point.y, msg.robot_point.z = map(float,
                                                                          body.robot_point)
            msg.body_point.x, msg.body_point.y, msg.body_point.z = map(float, body.body_point)
        msg.header.stamp = stamp
        msg.header.frame_id = self._frame
        self._separation_pub.publish(msg)
        self._counts['separations'] += 1
        self._counts['closer'] += bool(sample.below_protective)

    def summary(self) -> str:
        """One line on what the node did (run_node logs it at the stop)."""
        counts = self._counts
        return (f'{counts["events"]} event(s) sent; {counts["hand"]} hand and {counts["tool"]} '
                f'tool positions taken; {counts["separations"]} separations published, '
                f'{counts["closer"]} of them below the protective distance')

    def destroy_node(self):
        self._intake.destroy_node()
        return super().destroy_node()


def main(args=None):
    return run_node(EventDetectorNode, NODE_NAME, EventsExecutor, args)


if __name__ == '__main__':
    sys.exit(main())
