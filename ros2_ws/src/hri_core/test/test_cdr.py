"""Unit tests of hri_core.cdr: its templates and layouts against rclpy's serialiser.

rclpy.serialization needs no rclpy.init(): the reference here is the message type support
itself, the same code every rclpy publisher and subscription runs. A template's message is
compared by what rclpy reads back from it and by its length, not byte for byte: Fast CDR leaves
the alignment padding unset (its bytes vary from message to message), and rclpy's serialiser
gives 4-8 bytes more than the fields of a message with an empty sequence (SLACK).
"""

import math

import pytest
from geometry_msgs.msg import Point, PointStamped
from hri_interfaces.msg import HumanBody
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from hri_core.cdr import (
    EFFORT,
    POSITION,
    VELOCITY,
    LayoutReader,
    float64_array_layout,
    float64_array_template,
    human_body_layout,
    joint_state_layout,
    joint_state_template,
    point_stamped_layout,
    point_stamped_template,
    read_frame,
    read_stamp,
    read_values,
)

JOINTS = ('joint1', 'joint2')
finite = st.floats(allow_nan=False, allow_infinity=False)
any_float = st.floats(allow_nan=True, allow_infinity=True)
stamps = st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 999_999_999))
names = st.text(st.characters(codec='utf-8', exclude_characters='\x00'), max_size=12)
SLACK = 8  # bytes rclpy's serialiser may give beyond a message's fields


def same_length(encoded: bytes, serialized: bytes) -> bool:
    """Whether `encoded` holds the fields of the rclpy-serialized `serialized`: its length,
    or up to SLACK bytes shorter."""
    return 0 <= len(serialized) - len(encoded) <= SLACK


def joint_state(names, position, velocity, effort, stamp=(0, 0), frame_id=''):
    msg = JointState(name=list(names), position=list(position), velocity=list(velocity),
                     effort=list(effort))
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    msg.header.frame_id = frame_id
    return msg


def same_floats(got, expected):
    return all((math.isnan(a) and math.isnan(b)) or a == b for a, b in zip(got, expected,
                                                                         strict=True))


@settings(max_examples=200, deadline=None)
@given(stamp=stamps, values=st.lists(any_float, min_size=6, max_size=6),
       frame_id=names, joint_names=st.lists(names, min_size=2, max_size=2))
def test_rclpy_reads_back_what_the_joint_state_template_writes(stamp, values, frame_id,
                                                          joint_names):
    template = joint_state_template(joint_names, frame_id)
    runs = (values[0:2], values[2:4], values[4:6])
    encoded = template.encode(*runs, stamp=stamp)
    expected = joint_state(joint_names, *runs, stamp=stamp, frame_id=frame_id)
    assert same_length(encoded, serialize_message(expected))
    got = deserialize_message(encoded, JointState)
    assert (got.header, got.name) == (expected.header, expected.name)
    for field, run in zip(('position', 'velocity', 'effort'), runs, strict=True):
        assert same_floats(getattr(got, field), run)


@settings(max_examples=100, deadline=None)
@given(stamp=stamps, point=st.lists(any_float, min_size=3, max_size=3), frame_id=names)
def test_rclpy_reads_back_what_the_point_stamped_template_writes(stamp, point, frame_id):
    msg = PointStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    msg.header.frame_id = frame_id
    msg.point.x, msg.point.y, msg.point.z = point
    encoded = point_stamped_template(frame_id).encode(point, stamp=stamp)
    assert same_length(encoded, serialize_message(msg))
    got = deserialize_message(encoded, PointStamped)
    assert got.header == msg.header
    assert same_floats((got.point.x, got.point.y, got.point.z), point)


@settings(max_examples=100, deadline=None)
@given(values=st.lists(any_float, max_size=7))
def test_rclpy_reads_back_what_the_float64_array_template_writes(values):
    encoded = float64_array_template(len(values)).encode(values)
    assert same_length(encoded, serialize_message(Float64MultiArray(data=values)))
    got = deserialize_message(encoded, Float64MultiArray)
    assert (got.layout.dim, got.layout.data_offset) == ([], 0)
    assert same_floats(got.data, values)


@settings(max_examples=200, deadline=None)
@given(data=st.data(), frame_id=names,
       extra=st.lists(names.filter(lambda name: name not in JOINTS), max_size=3, unique=True))
def test_a_joint_state_layout_reads_the_wanted_values_of_any_name_order(data, frame_id, extra):
    joint_names = data.draw(st.permutations([*JOINTS, *extra]))
    count = len(joint_names)
    runs = [data.draw(st.lists(finite, min_size=count, max_size=count)) for _ in range(3)]
    stamp = data.draw(stamps)
    raw = serialize_message(joint_state(joint_names, *runs, stamp=stamp, frame_id=frame_id))
    layout = joint_state_layout(raw, JOINTS, (POSITION, VELOCITY, EFFORT),
                                one_value_per_name=True)
    index = [joint_names.index(joint) for joint in JOINTS]
    assert read_values(raw, layout) == tuple(run[i] for run in runs for i in index)
    assert read_stamp(raw) == stamp
    assert read_frame(raw) == frame_id
    # Another message with the same names and lengths shares the layout.
    other = serialize_message(joint_state(joint_names, *(run[::-1] for run in runs),
                                          frame_id=frame_id))
    assert read_values(other, layout) == tuple(run[::-1][i] for run in runs for i in index)


def test_messages_laid_out_otherwise_do_not_share_a_layout():
    raw = serialize_message(joint_state(JOINTS, [1.0, 2.0], [3.0, 4.0], [5.0, 6.0]))
    layout = joint_state_layout(raw, JOINTS, (POSITION, VELOCITY))
    assert read_values(raw, layout) == (1.0, 2.0, 3.0, 4.0)
    others = (joint_state(JOINTS[::-1], [1.0, 2.0], [3.0, 4.0], [5.0, 6.0]),  # names swapped
              joint_state(('joint1', 'jointX'), [1.0, 2.0], [3.0, 4.0], [5.0, 6.0]),
              joint_state(JOINTS, [1.0, 2.0], [3.0, 4.0], [5.0, 6.0, 7.0]),  # longer
              joint_state(JOINTS, [1.0, 2.0], [3.0, 4.0, 5.0], [6.0]),  # same size
              joint_state(JOINTS, [1.0, 2.0], [3.0, 4.0], [5.0, 6.0], frame_id='a'))
    assert len(serialize_message(others[3])) == len(raw)
    for other in others:
        assert read_values(serialize_message(other), layout) is None
    big_endian = bytearray(raw)
    big_endian[1] = 0
    assert read_values(bytes(big_endian), layout) is None


@pytest.mark.parametrize('msg, reason', [
    (joint_state(('joint1',), [1.0], [2.0], [0.0]), 'a joint missing'),
    (joint_state(JOINTS, [1.0, 2.0], [3.0], [0.0, 0.0]), 'a wanted sequence too short'),
    (joint_state(JOINTS, [1.0, 2.0, 5.0], [3.0, 4.0], [0.0, 0.0]), 'more values than names'),
])
def test_joint_states_without_the_wanted_values_have_no_layout(msg, reason):
    assert joint_state_layout(serialize_message(msg), JOINTS, (POSITION, VELOCITY),
                              one_value_per_name=True) is None, reason


def test_truncated_or_extended_messages_have_no_layout():
    joints = serialize_message(joint_state(JOINTS, [1.0, 2.0], [3.0, 4.0], []))
    point = serialize_message(PointStamped())
    array = serialize_message(Float64MultiArray(data=[1.0, 2.0]))
    for cut in (lambda raw: raw[:-1], lambda raw: raw[:10], lambda raw: raw + b'\x00' * 8,
                lambda raw: b'', lambda raw: b'\x00\x01'):
        assert joint_state_layout(cut(joints), JOINTS) is None
        assert point_stamped_layout(cut(point)) is None
        assert float64_array_layout(cut(array)) is None


@settings(max_examples=100, deadline=None)
@given(values=st.lists(any_float, max_size=5),
       dims=st.lists(st.tuples(names, st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1)),
                     max_size=2),
       data_offset=st.integers(0, 2**32 - 1))
def test_a_float64_array_layout_reads_every_value_whatever_the_array_layout(values, dims,
                                                                          data_offset):
    msg = Float64MultiArray(data=values)
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in dims]
    msg.layout.data_offset = data_offset
    raw = serialize_message(msg)
    layout = float64_array_layout(raw)
    assert same_floats(deserialize_message(raw, Float64MultiArray).data, values)
    if layout is None:  # rclpy gave bytes beyond the fields: the full deserialiser's case
        assert not values
        return
    assert same_floats(read_values(raw, layout), values)
    # Another length: not this layout.
    shorter = serialize_message(Float64MultiArray(data=values[:-1]))
    assert read_values(shorter, layout) is None


def test_a_layout_reader_follows_a_stream_whose_layout_changes():
    found = []

    def find(data):
        found.append(len(data))
        return joint_state_layout(data, JOINTS, (POSITION,))

    reader = LayoutReader(find)
    zeros = [0.0, 0.0]
    first = serialize_message(joint_state(JOINTS, [1.0, 2.0], zeros, zeros))
    assert reader.read(first) == (1.0, 2.0)
    assert reader.read(serialize_message(joint_state(JOINTS, [3.0, 4.0], zeros, zeros))) == \
        (3.0, 4.0)
    assert len(found) == 1  # the layout is found once while the messages keep it
    swapped = serialize_message(joint_state(JOINTS[::-1], [5.0, 6.0], zeros, zeros))
    assert reader.read(swapped) == (6.0, 5.0)
    assert reader.read(serialize_message(joint_state(('joint1',), [7.0], [0.0], [0.0]))) is None
    assert reader.read(swapped) == (6.0, 5.0)  # the last layout found is kept
    assert len(found) == 3


def human_body(names, points, stamp=(0, 0), frame_id='base'):
    msg = HumanBody(names=list(names), points=[Point(x=x, y=y, z=z) for x, y, z in points])
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    msg.header.frame_id = frame_id
    return msg


@settings(max_examples=200, deadline=None)
@given(data=st.data(), frame_id=names, stamp=stamps,
       body_names=st.lists(names, min_size=1, max_size=10, unique=True))
def test_a_human_body_layout_reads_every_point_and_the_names(data, frame_id, stamp,
                                                             body_names):
    points = [data.draw(st.tuples(any_float, any_float, any_float)) for _ in body_names]
    raw = serialize_message(human_body(body_names, points, stamp, frame_id))
    reader = LayoutReader(human_body_layout)
    assert same_floats(reader.read(raw), [v for point in points for v in point])
    assert reader.layout.names == tuple(body_names)
    assert read_stamp(raw) == stamp
    assert read_frame(raw) == frame_id
    # The next frame of the same body shares the layout; other names or a point more do not
    # (an empty body, with the serialiser's slack bytes, goes to the deserialiser).
    moved = [(x + 1.0, y, z) for x, y, z in points]
    layout = reader.layout

    def read(names, points):
        return read_values(serialize_message(human_body(names, points, frame_id=frame_id)),
                           layout)
    assert same_floats(read(body_names, moved), [v for point in moved for v in point])
    assert read([name + 'x' for name in body_names], points) is None
    assert read([*body_names, '_'], [*points, (0.0, 0.0, 0.0)]) is None


def test_a_human_body_with_a_point_for_other_than_each_name_has_no_layout():
    raw = serialize_message(human_body(['head', 'torso'], [(1.0, 2.0, 3.0)]))
    assert human_body_layout(raw) is None
    whole = serialize_message(human_body(['head'], [(1.0, 2.0, 3.0)]))
    assert human_body_layout(whole[:-8]) is None
    assert human_body_layout(whole + bytes(8)) is None
