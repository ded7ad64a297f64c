"""Tests of the `live_view` node: the Foxglove WebSocket protocol as a client sees it.

The topic-level tests start scara_sim and hand_sim and the live view on port 0 (the server
picks a free one), connect with a `websockets` client as the Foxglove app does (subprotocol
foxglove.sdk.v1, the older foxglove.websocket.v1 offered too), read the server's `serverInfo`
and `advertise`, subscribe to /joint_states and the scene, and decode what arrives: the joint
states' CDR with rclpy, the scene's protobuf with a small wire-format reader guided by the
advertised schema (the protobuf package is not installed). The first two tests need no ROS
process.
"""

import base64
import json
import math
import re
import signal
import socket
import struct
import time

import numpy as np
import pytest
import websockets.exceptions
import websockets.sync.client
from rclpy.serialization import deserialize_message
from rosbags.typesys import get_types_from_msg
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from hri_bringup import live_view_node
from hri_core import topics
from hri_core.node_common import load_defaults
from hri_core.robot_model import robot_model

START_TIMEOUT = 15.0  # s for `ros2 run` to bring the live view up
RECEIVE_TIMEOUT = 10.0  # s for the first joint state and a scene with the arm and the hand
SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']
MESSAGE_DATA_OPCODE = 1
SCENE_TOPIC = '/live_view/scene'


def served_url(view, timeout: float) -> str:
    """The URL a live view started with port 0 serves on, read from its start line. Port 0
    lets the server bind any free port itself: a port probed free beforehand can be taken by
    a test running beside this one before the view binds it."""
    assert view.wait_for_line('live view on ws://127.0.0.1:', timeout), view.log()
    return re.search(r'live view on (ws://127\.0\.0\.1:\d+)', view.log()).group(1)


def varint(data: bytes, offset: int) -> tuple[int, int]:
    """A protobuf varint at `offset`: its value and the offset after it."""
    value = shift = 0
    while True:
        byte = data[offset]
        offset += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, offset


def protobuf_fields(data: bytes) -> list[tuple[int, int | bytes]]:
    """The (field number, value) pairs of a protobuf message, in order: a varint as int,
    anything else as its bytes."""
    fields = []
    offset = 0
    while offset < len(data):
        key, offset = varint(data, offset)
        number, wire_type = key >> 3, key & 7
        if wire_type == 0:
            value, offset = varint(data, offset)
        elif wire_type == 2:
            length, offset = varint(data, offset)
            value, offset = data[offset:offset + length], offset + length
        else:
            size = {1: 8, 5: 4}[wire_type]
            value, offset = data[offset:offset + size], offset + size
        fields.append((number, value))
    return fields


def field_numbers(file_descriptor_set: bytes) -> dict[str, dict[str, int]]:
    """{message name: {field name: number}} of a serialised google.protobuf
    FileDescriptorSet (file = 1; FileDescriptorProto.message_type = 4; DescriptorProto
    name = 1, field = 2; FieldDescriptorProto name = 1, number = 3)."""
    messages = {}
    for number, file_proto in protobuf_fields(file_descriptor_set):
        if number != 1:
            continue
        for kind, message in protobuf_fields(file_proto):
            if kind != 4:
                continue
            parts = protobuf_fields(message)
            name = next(value.decode() for key, value in parts if key == 1)
            fields = {}
            for key, value in parts:
                if key == 2:
                    field = dict(protobuf_fields(value))
                    fields[field[1].decode()] = field[3]
            messages[name] = fields
    return messages


def scene_entities(payload: bytes, schema: dict[str, dict[str, int]]) -> dict[str, dict]:
    """{entity id: {primitive kind: count}} of a foxglove.SceneUpdate in protobuf."""
    entity_fields = schema['SceneEntity']
    number_to_name = {number: name for name, number in entity_fields.items()}
    entities = {}
    for number, entity in protobuf_fields(payload):
        if number != schema['SceneUpdate']['entities']:
            continue
        counts: dict[str, int] = {}
        entity_id = ''
        for key, value in protobuf_fields(entity):
            if key == entity_fields['id']:
                entity_id = value.decode()
            elif number_to_name.get(key) in ('spheres', 'cylinders', 'lines', 'texts'):
                counts[number_to_name[key]] = counts.get(number_to_name[key], 0) + 1
        entities[entity_id] = counts
    return entities


def read_channels(connection, needed: set[str], timeout: float) -> tuple[dict, dict]:
    """The serverInfo message and the advertised channels by topic, once `needed` are in."""
    server_info = None
    channels: dict[str, dict] = {}
    deadline = time.monotonic() + timeout
    while server_info is None or not needed <= set(channels):
        message = connection.recv(timeout=max(0.1, deadline - time.monotonic()))
        if isinstance(message, bytes):
            continue
        document = json.loads(message)
        if document['op'] == 'serverInfo':
            server_info = document
        elif document['op'] == 'advertise':
            channels.update({channel['topic']: channel for channel in document['channels']})
    return server_info, channels


def test_message_definition_holds_every_type_it_uses():
    definition = live_view_node.message_definition('hri_interfaces/msg/TaskState')
    assert definition.startswith('# The active task and the event weight')
    for used in ('hri_interfaces/msg/TaskParameters', 'std_msgs/msg/Header',
                 'builtin_interfaces/msg/Time'):
        assert definition.count(f'{"=" * 80}\nMSG: {used}\n') == 1
    parsed = get_types_from_msg(definition, 'hri_interfaces/msg/TaskState')
    assert {'hri_interfaces/msg/TaskState', 'hri_interfaces/msg/TaskParameters',
            'std_msgs/msg/Header', 'builtin_interfaces/msg/Time'} <= set(parsed)
    assert live_view_node.message_definition('std_msgs/msg/Float64MultiArray').count(
        'MSG: ') == 2  # MultiArrayLayout and MultiArrayDimension


def test_yaml_gives_every_parameter_and_streams_every_topic_of_the_suite():
    defaults = load_defaults('hri_bringup', 'live_view')
    assert set(defaults) == set(live_view_node.PARAMETERS)
    assert defaults['topics'] == [topic.name for topic in vars(topics).values()
                                  if isinstance(topic, topics.Topic)]
    assert defaults['port'] == 8765 and defaults['host'] == '127.0.0.1'


@pytest.mark.integration
def test_streams_the_topics_and_the_scene_to_a_foxglove_client(nodes):
    nodes('scara_sim', 'scara_sim')
    nodes('scara_sim', 'hand_sim', params={'profile': 'circle'})
    view = nodes('hri_bringup', 'live_view', params={'port': 0})
    streamed = len(load_defaults('hri_bringup', 'live_view')['topics'])
    url = served_url(view, START_TIMEOUT)
    assert f'live view on {url} streaming {streamed} topics' in view.log()

    with websockets.sync.client.connect(url, subprotocols=SUBPROTOCOLS,
                                        proxy=None, open_timeout=5.0,
                                        max_queue=1024) as connection:
        assert connection.subprotocol == 'foxglove.sdk.v1'
        server_info, channels = read_channels(
            connection, {'/joint_states', '/target', SCENE_TOPIC}, 5.0)
        print('\nadvertised channels (topic, schemaName, encoding):')
        for topic, channel in sorted(channels.items()):
            print(f'  {topic}  {channel["schemaName"]}  {channel["encoding"]}')
        assert server_info['name'] == 'hri /live_view'
        joint_states = channels['/joint_states']
        assert (joint_states['schemaName'], joint_states['encoding'],
                joint_states['schemaEncoding']) == ('sensor_msgs/msg/JointState', 'cdr',
                                                    'ros2msg')
        assert 'MSG: std_msgs/msg/Header' in joint_states['schema']
        assert channels['/target']['schemaName'] == 'geometry_msgs/msg/PointStamped'
        scene = channels[SCENE_TOPIC]
        assert (scene['schemaName'], scene['encoding']) == ('foxglove.SceneUpdate',
                                                            'protobuf')
        scene_schema = field_numbers(base64.b64decode(scene['schema']))

        connection.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': 1, 'channelId': joint_states['id']}, {'id': 2, 'channelId': scene['id']}]}))
        state = None
        entities: dict[str, dict] = {}
        deadline = time.monotonic() + RECEIVE_TIMEOUT
        while state is None or not {'arm', 'hand', 'person', 'closest_pair'} <= {
                k for k, v in entities.items() if v}:
            frame = connection.recv(timeout=max(0.1, deadline - time.monotonic()))
            if not isinstance(frame, bytes) or frame[0] != MESSAGE_DATA_OPCODE:
                continue
            subscription, stamp_ns = struct.unpack_from('<IQ', frame, 1)
            payload = frame[13:]
            assert stamp_ns > 0
            if subscription == 1:
                state = deserialize_message(payload, JointState)
            elif subscription == 2:
                entities = scene_entities(payload, scene_schema)

        # SIGINT with a client connected: the server closes the connection, the node exits 0.
        view.send(signal.SIGINT)
        with pytest.raises(websockets.exceptions.ConnectionClosed):
            while True:
                connection.recv(timeout=5.0)
        assert view.wait_or_kill(5.0) == 0

    assert list(state.name) == ['joint1', 'joint2']
    assert len(state.position) == 2 and all(math.isfinite(v) for v in state.position)
    assert entities['arm'] == {'spheres': 3, 'cylinders': 2}
    assert entities['hand'] == {'spheres': 1}
    assert entities['task_region'] == {}  # no event_manager: no task to draw
    # hand_sim's standing person: 7 capsules between two points, head and hands balls; the
    # SCARA's two link capsules; the line between their closest points, with its label.
    assert entities['person'] == {'spheres': 17, 'cylinders': 7}
    assert entities['robot_body'] == {'spheres': 4, 'cylinders': 2}
    assert entities['closest_pair'] == {'lines': 1, 'texts': 1}
    assert 'live view stopped' in view.log()
    assert 'Traceback' not in view.log()


@pytest.mark.integration
def test_a_port_in_use_or_a_bad_parameter_is_one_error_line_and_exit_1(nodes):
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        in_use = nodes('hri_bringup', 'live_view', params={'port': port})
        unknown_topic = nodes('hri_bringup', 'live_view',
                              params={'port': 0, 'topics': ['/joint_states', '/nope']})
        assert in_use.wait(START_TIMEOUT) == 1
        assert unknown_topic.wait(START_TIMEOUT) == 1
    for process, reason in ((in_use, f'cannot serve on ws://127.0.0.1:{port}: '),
                            (unknown_topic, 'bad parameter topics: /nope not a topic')):
        log = process.log()
        errors = [line for line in log.splitlines() if '[ERROR]' in line]
        assert len(errors) == 1 and reason in errors[0], log
        assert 'Traceback' not in log


@pytest.mark.integration
def test_draws_the_arm_of_the_robot_description_in_3d(nodes):
    """Beside arm_sim robot:=panda the scene's arm is the URDF's chain: a rod for each of its 7
    joints and the pedestal from the base to joint 1 (0.333 m up), a ball at each joint and
    the tool; the hand, in 3-D, with the task region as spheres (task_region stays empty
    without an event_manager)."""
    panda = robot_model('panda')
    nodes('scara_sim', 'arm_sim', params={'robot': 'panda', 'teach_mode': True})
    nodes('scara_sim', 'hand_sim', params={'profile': 'circle'})
    view = nodes('hri_bringup', 'live_view', params={'port': 0})
    url = served_url(view, START_TIMEOUT)
    with websockets.sync.client.connect(url, subprotocols=SUBPROTOCOLS,
                                        proxy=None, open_timeout=5.0,
                                        max_queue=1024) as connection:
        _, channels = read_channels(connection, {SCENE_TOPIC, '/robot_description'}, 5.0)
        scene = channels[SCENE_TOPIC]
        scene_schema = field_numbers(base64.b64decode(scene['schema']))
        connection.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': 1, 'channelId': scene['id']}]}))
        entities: dict[str, dict] = {}
        deadline = time.monotonic() + 2 * RECEIVE_TIMEOUT  # the Panda's URDF loads first
        while entities.get('arm', {}).get('cylinders', 0) <= 2 or not entities.get('hand') \
                or not entities.get('robot_body'):
            frame = connection.recv(timeout=max(0.1, deadline - time.monotonic()))
            if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA_OPCODE:
                entities = scene_entities(frame[13:], scene_schema)
    pedestal = 1 if np.linalg.norm(panda.shoulder) > 0.0 else 0
    assert entities['arm'] == {'cylinders': panda.dof + pedestal, 'spheres': panda.dof + 1}
    assert (panda.dof, pedestal) == (7, 1)
    assert entities['hand'] == {'spheres': 1}
    assert entities['task_region'] == {}
    # The Panda's capsules, fitted from its collision meshes: link0-link7 and the hand.
    assert entities['robot_body'] == {'cylinders': 9, 'spheres': 18}
    assert "drawing panda of /robot_description: 7 joints, tool 'panda_hand_tcp'" in view.log()
    assert 'Traceback' not in view.log()


@pytest.mark.integration
def test_a_robot_description_it_cannot_read_is_one_warning_and_the_scara_is_drawn(nodes,
                                                                                  probe):
    nodes('scara_sim', 'scara_sim')
    broken = probe.publisher(topics.ROBOT_DESCRIPTION.name, String,
                             topics.ROBOT_DESCRIPTION.qos)
    broken.publish(String(data='<robot name="arm"><link name="a"/></robot>'))
    view = nodes('hri_bringup', 'live_view', params={'port': 0})
    assert view.wait_for_line('cannot draw the arm of /robot_description', START_TIMEOUT), \
        view.log()
    with websockets.sync.client.connect(served_url(view, START_TIMEOUT), subprotocols=SUBPROTOCOLS,
                                        proxy=None, open_timeout=5.0,
                                        max_queue=1024) as connection:
        _, channels = read_channels(connection, {SCENE_TOPIC}, 5.0)
        scene = channels[SCENE_TOPIC]
        scene_schema = field_numbers(base64.b64decode(scene['schema']))
        connection.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': 1, 'channelId': scene['id']}]}))
        entities: dict[str, dict] = {}
        deadline = time.monotonic() + RECEIVE_TIMEOUT
        while not entities.get('arm'):
            frame = connection.recv(timeout=max(0.1, deadline - time.monotonic()))
            if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA_OPCODE:
                entities = scene_entities(frame[13:], scene_schema)
    assert entities['arm'] == {'spheres': 3, 'cylinders': 2}  # the planar SCARA
    warnings = [line for line in view.log().splitlines() if '[WARN]' in line]
    assert len(warnings) == 1, view.log()
    assert ("robot 'arm' is not one the suite knows (scara, panda, ur3, ur5, ur10, xarm7, "
            'z1): give tool_frame') in warnings[0]
    assert 'Traceback' not in view.log()
