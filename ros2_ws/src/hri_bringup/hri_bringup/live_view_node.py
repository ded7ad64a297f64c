"""The `live_view` node: the running system in Foxglove, live, over its WebSocket protocol.

`ros2 run hri_bringup live_view` serves Foxglove's WebSocket protocol on `host`:`port`
(foxglove-sdk, in-process; open ws://localhost:8765 in the Foxglove app or at
app.foxglove.dev) and offers two kinds of channels:

- every topic of `topics` (suite topics of hri_core.topics, by their default names; a remapped
  one is streamed under its remapped name) as it arrives: raw CDR bytes, never deserialised,
  with the type's ros2msg schema (its .msg text and those of the types it uses). Each is
  subscribed with the QoS its publisher offers (hri_core.topics), so the match is certain and
  the transient-local /hri/task_state and /hri/task are delivered at once to a late viewer;
- a 3-D scene on `scene_topic` (foxglove.SceneUpdate) and the arm's frames on
  `transforms_topic` (foxglove.FrameTransforms) at `scene_rate_hz`, from the newest
  /joint_states, /target and /hri/task_state: the arm, the hand and the active task's desired
  region coloured by the event weight (hri_bringup.live_scene has the geometry).
  The arm is the one /robot_description describes (its URDF through pinocchio, tool point at
  `tool_frame` or the known robot's own), drawn in 3-D with the region as spheres round the
  hand; with no /robot_description (or one that cannot be read: one warning), the planar SCARA
  of `joints`, `l1` and `l2`, as scara_sim publishes none. The scene is built in the timer at
  `scene_rate_hz`, never per message: the 1 kHz callbacks only keep the newest bytes.

It logs one line once it serves ('live view on ws://HOST:PORT streaming N topics ...') and
one when it stops. SIGINT or SIGTERM stop the server and end the node with exit code 0; a
port in use, a host that cannot be bound or a bad parameter is one error line and exit 1.
The parameters' defaults are in config/live_view.yaml.
"""

import re
import sys
from pathlib import Path

import foxglove
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.messages import (
    Color,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message

from hri_bringup import live_scene
from hri_core import topics
from hri_core.bodies import panda_package_dirs, robot_body
from hri_core.dynamics import ScaraParameters
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    run_node,
)
from hri_core.robot_model import ScaraModel

PACKAGE = 'hri_bringup'
NODE_NAME = 'live_view'
# Every topic of the suite by its default name: what `topics` may list.
SUITE_TOPICS: dict[str, topics.Topic] = {
    topic.name: topic for topic in vars(topics).values() if isinstance(topic, topics.Topic)}
# What the scene is drawn from, streamed or not.
SCENE_INPUTS = (topics.JOINT_STATES, topics.TARGET, topics.TASK_STATE,
                topics.ROBOT_DESCRIPTION, topics.HUMAN_BODY)
PARAMETERS = {
    'host': ParameterSpec(str, 'address the WebSocket server listens on (127.0.0.1: this '
                          'machine only)', read_only=True),
    'port': ParameterSpec(int, 'TCP port of the WebSocket server (0: any free port)',
                          0, 65535, read_only=True),
    'topics': ParameterSpec(list[str], 'topics to stream, by their default names in '
                            'hri_core.topics (a remapping applies)', read_only=True),
    'scene_topic': ParameterSpec(str, 'channel of the 3-D scene (foxglove.SceneUpdate)',
                                 read_only=True),
    'transforms_topic': ParameterSpec(str, "channel of the arm's frames "
                                      '(foxglove.FrameTransforms)', read_only=True),
    'scene_rate_hz': ParameterSpec(float, 'rate of the scene and the frames (Hz)', 0.5, 100.0,
                                   read_only=True),
    'frame': ParameterSpec(str, 'frame of the scene: the arm base, the frame of /target',
                           read_only=True),
    'joints': ParameterSpec(list[str], 'names of joint 1 and joint 2 in /joint_states',
                            read_only=True),
    'l1': ParameterSpec(float, 'length of link 1 (m), as the robot', 0.01, 10.0,
                        read_only=True),
    'l2': ParameterSpec(float, 'length of link 2 (m), as the robot', 0.01, 10.0,
                        read_only=True),
    'tool_frame': ParameterSpec(str, "the tool point's link in /robot_description's URDF ('': "
                                "the robot's own, for a robot the suite knows)",
                                read_only=True),
    'region_display_radius': ParameterSpec(float, 'a task boundary beyond this distance '
                                           'from the hand is drawn dashed at it (m)',
                                           0.01, 10.0, read_only=True),
}

# The .msg field types that are not messages of their own.
PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'})
# Between the definitions of a ros2msg schema, as rosbag2 and the Foxglove bridge write it.
DEFINITION_SEPARATOR = '=' * 80


def read_msg_file(type_name: str) -> str:
    """The .msg text of 'pkg/msg/Name' from the package's share folder (ament index).

    LookupError if the package or the file is not installed."""
    package, kind, name = type_name.split('/')
    try:
        share = Path(get_package_share_directory(package))
    except PackageNotFoundError:
        raise LookupError(f'package {package} is not installed') from None
    path = share / kind / f'{name}.msg'
    if not path.is_file():
        raise LookupError(f'no {path}')
    return path.read_text()


def field_types(text: str, package: str) -> list[str]:
    """The message types ('pkg/msg/Name') of the fields of a .msg text, in order; a bare
    name is of the same package, as rosidl reads it (Header: std_msgs)."""
    found = []
    for line in text.splitlines():
        words = line.split('#', 1)[0].split()
        if len(words) < 2:
            continue
        base = re.sub(r'\[[^\]]*\]$', '', words[0]).split('<=', 1)[0]
        if base in PRIMITIVE_TYPES:
            continue
        parts = base.split('/')
        if len(parts) == 3:
            found.append(base)
        elif len(parts) == 2:
            found.append(f'{parts[0]}/msg/{parts[1]}')
        elif base == 'Header':
            found.append('std_msgs/msg/Header')
        else:
            found.append(f'{package}/msg/{base}')
    return found


def message_definition(type_name: str) -> str:
    """The ros2msg schema of 'pkg/msg/Name' as Foxglove reads it: the type's .msg text, then
    for each type it uses, directly or not, once, a line of 80 '=', 'MSG: pkg/msg/Name' and
    that type's text. LookupError if one of the .msg files is not installed."""
    texts = {type_name: read_msg_file(type_name)}
    order: list[str] = []

    def add_dependencies(name: str) -> None:
        for dependency in field_types(texts[name], name.split('/')[0]):
            if dependency not in texts:
                texts[dependency] = read_msg_file(dependency)
                order.append(dependency)
                add_dependencies(dependency)

    add_dependencies(type_name)
    parts = [texts[type_name].rstrip('\n')]
    parts += [f'{DEFINITION_SEPARATOR}\nMSG: {name}\n{texts[name].rstrip(chr(10))}'
              for name in order]
    return '\n'.join(parts) + '\n'


def topics_problem(names: list[str]) -> str:
    """Why `names` is not a list of suite topics ('' if it is)."""
    unknown = [name for name in names if name not in SUITE_TOPICS]
    if unknown:
        return (f'{", ".join(unknown)} not a topic of the suite (one of '
                f'{", ".join(SUITE_TOPICS)})')
    return ''


def channel_name_problem(name: str) -> str:
    """Why `name` is not a usable channel topic ('' if it is)."""
    if not name.startswith('/') or len(name) < 2 or any(c.isspace() for c in name):
        return f'{name!r} is not an absolute topic name like /live_view/scene'
    return ''


def server_url(host: str, port: int) -> str:
    """ws://HOST:PORT, an IPv6 address in brackets."""
    return f'ws://[{host}]:{port}' if ':' in host else f'ws://{host}:{port}'


def foxglove_colour(colour: live_scene.Rgba) -> Color:
    return Color(r=colour.r, g=colour.g, b=colour.b, a=colour.a)


def foxglove_point(point: live_scene.Point) -> Point3:
    return Point3(x=point[0], y=point[1], z=point[2])


def foxglove_pose(position: live_scene.Point,
                  rotation: live_scene.Quaternion = (0.0, 0.0, 0.0, 1.0)) -> Pose:
    return Pose(position=Vector3(x=position[0], y=position[1], z=position[2]),
                orientation=Quaternion(x=rotation[0], y=rotation[1], z=rotation[2],
                                       w=rotation[3]))


def foxglove_entity(entity: live_scene.Entity, frame: str, stamp: Timestamp) -> SceneEntity:
    """A live_scene entity as a foxglove SceneEntity in `frame`."""
    cylinders = []
    for rod in entity.rods:
        centre, rotation, length = live_scene.rod_pose(rod)
        cylinders.append(CylinderPrimitive(
            pose=foxglove_pose(centre, rotation),
            size=Vector3(x=rod.diameter, y=rod.diameter, z=length),
            bottom_scale=1.0, top_scale=1.0, color=foxglove_colour(rod.colour)))
    spheres = [SpherePrimitive(pose=foxglove_pose(ball.centre),
                               size=Vector3(x=ball.diameter, y=ball.diameter, z=ball.diameter),
                               color=foxglove_colour(ball.colour))
               for ball in entity.balls]
    lines = [LinePrimitive(type=(LinePrimitiveLineType.LineList if line.dashed
                                 else LinePrimitiveLineType.LineLoop),
                           pose=foxglove_pose((0.0, 0.0, 0.0)), thickness=line.thickness,
                           points=[foxglove_point(p) for p in line.points],
                           color=foxglove_colour(line.colour))
             for line in entity.lines]
    triangles = [TriangleListPrimitive(pose=foxglove_pose((0.0, 0.0, 0.0)),
                                       points=[foxglove_point(p) for p in surface.points],
                                       color=foxglove_colour(surface.colour))
                 for surface in entity.triangles]
    texts = [TextPrimitive(pose=foxglove_pose(label.position), billboard=True,
                           font_size=label.size, color=foxglove_colour(label.colour),
                           text=label.text)
             for label in entity.labels]
    return SceneEntity(timestamp=stamp, frame_id=frame, id=entity.id, cylinders=cylinders,
                       spheres=spheres, lines=lines, triangles=triangles, texts=texts)


class LiveView(Node):
    """Streams the suite's topics and the 3-D scene to Foxglove clients until stopped."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        self._check(values)
        self._frame = values['frame']
        self._joints = tuple(values['joints'])
        self._geometry = live_scene.ArmGeometry(l1=values['l1'], l2=values['l2'])
        # The planar SCARA's capsules (hri_core.bodies: from the link lengths alone; the
        # centres of mass, which they do not use, put mid-link), drawn while no
        # /robot_description names another arm; that arm's are fitted when its description
        # comes.
        l1, l2 = values['l1'], values['l2']
        self._scara_body = robot_body(ScaraModel(ScaraParameters(l1=l1, l2=l2, lc1=l1 / 2,
                                                                 lc2=l2 / 2)))
        self._tool_frame = values['tool_frame']
        # The arm of the newest /robot_description: (its bytes, the model or None), and its
        # capsules (or None).
        self._description: tuple[bytes, object] | None = None
        self._described_body = None
        self._display_radius = values['region_display_radius']
        # A channel logs to the server of its context only: a context of the node's own keeps
        # another server in the same process (a test) from seeing these channels.
        self._foxglove_context = foxglove.Context()
        streamed = list(dict.fromkeys(values['topics']))
        try:
            channels = {name: self._ros_channel(SUITE_TOPICS[name]) for name in streamed}
        except LookupError as error:
            raise StartupError(f'cannot describe a topic type: {error}') from None
        # Messages streamed per channel, for the summary line.
        self._streamed = {channel.topic(): 0 for channel in channels.values()}
        # The newest serialised scene input by default topic name; deserialised per frame.
        self._latest: dict[str, bytes] = {}
        self._decoded: dict[str, tuple[bytes, object]] = {}
        for topic in {**{name: SUITE_TOPICS[name] for name in streamed},
                      **{topic.name: topic for topic in SCENE_INPUTS}}.values():
            self.create_subscription(topic.type, topic.name,
                                     self._receiver(topic, channels.get(topic.name)),
                                     topic.qos, raw=True)
        self._scene_channel = SceneUpdateChannel(values['scene_topic'],
                                                 context=self._foxglove_context)
        self._transforms_channel = FrameTransformsChannel(values['transforms_topic'],
                                                          context=self._foxglove_context)
        self.create_timer(1.0 / values['scene_rate_hz'], self._publish_scene)
        # Last, so that nothing after it can fail and leave the server running.
        try:
            self._server = foxglove.start_server(
                name=f'hri {self.get_fully_qualified_name()}', host=values['host'],
                port=values['port'], context=self._foxglove_context)
        except RuntimeError as error:
            reason = str(error).removeprefix('FoxgloveError: ')
            raise StartupError(f'cannot serve on {server_url(values["host"], values["port"])}'
                               f': {reason}') from None
        self.url = server_url(values['host'], self._server.port)
        self.get_logger().info(
            f'live view on {self.url} streaming {len(streamed)} topics; scene on '
            f'{values["scene_topic"]} at {values["scene_rate_hz"]:g} Hz')

    @staticmethod
    def _check(values: dict) -> None:
        """StartupError for a parameter whose value its type and range let through."""
        problems = {'topics': topics_problem(values['topics']),
                    'scene_topic': channel_name_problem(values['scene_topic']),
                    'transforms_topic': channel_name_problem(values['transforms_topic'])}
        for name in ('scene_topic', 'transforms_topic'):
            if values[name] in SUITE_TOPICS:
                problems[name] = f'{values[name]} is a topic of the suite'
        if values['scene_topic'] == values['transforms_topic']:
            problems['transforms_topic'] = 'must differ from scene_topic'
        if len(values['joints']) != 2:
            problems['joints'] = f'expected 2 names, got {len(values["joints"])}'
        if not values['host'].strip():
            problems['host'] = 'empty'
        for name, problem in problems.items():
            if problem:
                raise StartupError(f'bad parameter {name}: {problem}')

    def _ros_channel(self, topic: topics.Topic) -> foxglove.Channel:
        """A channel of raw CDR messages of `topic` under its resolved (remapped) name."""
        schema = foxglove.Schema(name=topic.type_name, encoding='ros2msg',
                                 data=message_definition(topic.type_name).encode())
        return foxglove.Channel(self.resolve_topic_name(topic.name), message_encoding='cdr',
                                schema=schema, context=self._foxglove_context)

    def _receiver(self, topic: topics.Topic, channel: foxglove.Channel | None):
        """The raw callback of `topic`: forward the bytes as they are (if streamed), keep the
        newest of a scene input."""
        keep = topic.name in {scene_input.name for scene_input in SCENE_INPUTS}
        latest = self._latest
        streamed = self._streamed
        channel_topic = None if channel is None else channel.topic()

        def on_message(data: bytes) -> None:
            if channel is not None:
                channel.log(data)
                streamed[channel_topic] += 1
            if keep:
                latest[topic.name] = data

        return on_message

    def _newest(self, topic: topics.Topic):
        """The newest message of a scene input, deserialised once; None before the first."""
        data = self._latest.get(topic.name)
        if data is None:
            return None
        cached = self._decoded.get(topic.name)
        if cached is None or cached[0] is not data:
            cached = (data, deserialize_message(data, topic.type))
            self._decoded[topic.name] = cached
        return cached[1]

    def _described_arm(self):
        """The arm of the newest /robot_description (a PinocchioModel), built once per new
        description; None without one or for one that cannot be read (warned once)."""
        data = self._latest.get(topics.ROBOT_DESCRIPTION.name)
        if data is None:
            return None
        if self._description is None or self._description[0] is not data:
            arm = body = None
            try:
                arm = live_scene.description_arm(self._newest(topics.ROBOT_DESCRIPTION).data,
                                                 self._tool_frame)
                self.get_logger().info(f'drawing {arm.name} of /robot_description: '
                                       f'{arm.dof} joints, tool {arm.tool_frame!r}')
            except ValueError as error:
                self.get_logger().warning(f'cannot draw the arm of /robot_description '
                                          f'({error}); drawing the planar SCARA')
            if arm is not None:
                try:  # example-robot-data's meshes resolve in the Panda's folder
                    body = robot_body(arm, panda_package_dirs())
                except ValueError as error:
                    self.get_logger().warning(f'cannot draw the capsules of {arm.name} '
                                              f'({error})')
            self._description = (data, arm)
            self._described_body = body
        return self._description[1]

    def _scene_inputs(self, joint_names: tuple[str, ...]):
        """Positions of `joint_names`, hand (x, y, z) and task region from the newest inputs
        (None if none)."""
        state = self._newest(topics.JOINT_STATES)
        q = None if state is None else live_scene.joint_angles(state.name, state.position,
                                                              joint_names)
        target = self._newest(topics.TARGET)
        hand = None if target is None else (target.point.x, target.point.y, target.point.z)
        task_state = self._newest(topics.TASK_STATE)
        region = None
        if (task_state is not None and task_state.task.name
                and task_state.phase != task_state.PHASE_IDLE):
            task = task_state.task
            region = live_scene.TaskRegion(task.name, task.s, task.d1, task.d2,
                                           task_state.weight, task_state.phase)
        return q, hand, region

    def _publish_scene(self) -> None:
        arm = self._described_arm()
        q, hand, region = self._scene_inputs(self._joints if arm is None else arm.joint_names)
        now = self.get_clock().now().nanoseconds
        stamp = Timestamp(now // 10**9, now % 10**9)
        if arm is None:
            entities = live_scene.scene_entities(q, hand, region, self._geometry,
                                                 self._display_radius)
            frames = None if q is None else live_scene.arm_frames(
                q, self._geometry.l1, self._geometry.l2, self._frame)
        else:
            points = None if q is None else live_scene.chain_points(arm, q)
            entities = live_scene.spatial_scene_entities(points, hand, region, self._geometry,
                                                         self._display_radius)
            frames = None if q is None else live_scene.chain_frames(arm, q, self._frame)
        entities = (*entities, *self._body_entities(arm, q))
        self._scene_channel.log(
            SceneUpdate(entities=[foxglove_entity(e, self._frame, stamp) for e in entities]),
            log_time=now)
        if frames is not None:
            self._transforms_channel.log(FrameTransforms(transforms=[
                FrameTransform(timestamp=stamp, parent_frame_id=f.parent,
                               child_frame_id=f.child,
                               translation=Vector3(x=f.translation[0], y=f.translation[1],
                                                   z=f.translation[2]),
                               rotation=Quaternion(x=f.rotation[0], y=f.rotation[1],
                                                   z=f.rotation[2], w=f.rotation[3]))
                for f in frames]), log_time=now)

    def _body_entities(self, arm, q) -> tuple:
        """The person, the robot's capsules at q and their closest pair (live_scene)."""
        message = self._newest(topics.HUMAN_BODY)
        person = None if message is None else live_scene.person_capsules(
            message.names, [(p.x, p.y, p.z) for p in message.points])
        body = self._scara_body if arm is None else self._described_body
        robot = None
        if body is not None and q is not None:
            try:
                robot = body.capsules(q)
            except ValueError:  # a joint state outside the model's limits: not drawn
                robot = None
        planar = body is not None and body.planar
        return (live_scene.capsules_entity(live_scene.PERSON_ENTITY, person,
                                           live_scene.PERSON_COLOUR),
                live_scene.robot_body_entity(robot),
                live_scene.closest_pair_entity(robot, person, planar))

    def close(self) -> None:
        """Stop the server (clients see the connection close)."""
        self._server.stop()

    def summary(self) -> str:
        """One line on what was streamed (run_node logs it at the stop)."""
        per_topic = ', '.join(f'{name}: {count}' for name, count in self._streamed.items()
                              if count)
        return (f'live view stopped: {sum(self._streamed.values())} messages streamed '
                f'({per_topic or "no topic seen"})')


def main(args=None):
    # /joint_states, /ee_position and the commands come at 1 kHz: the EventsExecutor takes
    # them at a fraction of the single-threaded executor's CPU.
    return run_node(LiveView, NODE_NAME, EventsExecutor, args, on_stop=LiveView.close)


if __name__ == '__main__':
    sys.exit(main())
