"""Unit tests of the `ros2 topic` stand-in (hri_cli.topic) without ROS.

Nothing here calls rclpy.init(): the tests cover the plain functions (a message as YAML,
--field, a YAML dict into a message, hz's statistics, the list/info text) and pub and echo
failing before they would start ROS. tests/test_ros2_cli.py runs the commands against live
nodes.
"""

import signal

import pytest

pytest.importorskip('rclpy')
pytest.importorskip('rosbags')

from builtin_interfaces.msg import Time  # noqa: E402
from geometry_msgs.msg import PointStamped, Polygon, PoseWithCovariance  # noqa: E402
from rclpy.qos import (  # noqa: E402
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Byte, Int8, String, UInt8  # noqa: E402

from hri_cli import topic  # noqa: E402
from hri_cli.common import (  # noqa: E402
    CliError,
    UsageError,
)
from hri_cli.topic import (  # noqa: E402
    EMPTY_GRAPH_WAIT,
    HZ_BASE_QOS,
    SETTLED_AFTER,
    FieldError,
    GraphSettling,
    RateWindow,
    check_array_length,
    field_element_type,
    fill_message,
    format_echo,
    format_topic_info,
    format_topic_list,
    matching_qos,
    message_to_plain,
    parse_field_path,
    parse_values,
    rate_statistics,
    select_field,
    set_stamps,
)


def point_stamped(x: float = 0.4, y: float = 0.1, frame: str = 'base') -> PointStamped:
    message = PointStamped()
    message.header.stamp.sec, message.header.stamp.nanosec = 12, 500
    message.header.frame_id = frame
    message.point.x, message.point.y = x, y
    return message


# --------------------------------------------------------------------------------------------
# echo: messages as YAML


def test_a_nested_message_is_indented_yaml_in_field_order_ending_with_the_separator():
    assert format_echo(point_stamped()) == (
        'header:\n'
        '  stamp:\n'
        '    sec: 12\n'
        '    nanosec: 500\n'
        '  frame_id: base\n'
        'point:\n'
        '  x: 0.4\n'
        '  y: 0.1\n'
        '  z: 0.0\n'
        '---\n')


def test_arrays_are_yaml_lists_and_empty_values_are_written_as_ros2cli_writes_them():
    message = JointState(name=['joint1', 'joint2'], position=[0.5, -1e-05])
    assert format_echo(message) == (
        'header:\n'
        '  stamp:\n'
        '    sec: 0\n'
        '    nanosec: 0\n'
        "  frame_id: ''\n"
        'name:\n'
        '- joint1\n'
        '- joint2\n'
        'position:\n'
        '- 0.5\n'
        '- -1.0e-05\n'
        'velocity: []\n'
        'effort: []\n'
        '---\n')


def test_arrays_of_messages_are_yaml_lists_of_mappings():
    polygon = Polygon()
    fill_message(polygon, {'points': [{'x': 1.0}, {'y': 2.0}]})
    assert format_echo(polygon) == ('points:\n'
                                    '- x: 1.0\n  y: 0.0\n  z: 0.0\n'
                                    '- x: 0.0\n  y: 2.0\n  z: 0.0\n'
                                    '---\n')


def test_fixed_size_numpy_arrays_become_plain_numbers():
    plain = message_to_plain(PoseWithCovariance(covariance=[float(i) for i in range(36)]))
    assert plain['covariance'] == [float(i) for i in range(36)]
    assert all(type(value) is float for value in plain['covariance'])
    assert plain['pose']['orientation'] == {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0}


def test_long_arrays_and_strings_are_cut_after_the_truncate_length():
    message = JointState(name=['abcdef'], position=[1.0, 2.0, 3.0, 4.0])
    plain = message_to_plain(message, truncate_length=3)
    assert plain['position'] == [1.0, 2.0, 3.0, '...']
    assert plain['name'] == ['abc...']
    assert message_to_plain(message)['position'] == [1.0, 2.0, 3.0, 4.0]


def test_a_byte_field_is_printed_as_its_character():
    assert format_echo(Byte(data=b'A')) == 'data: A\n---\n'


def test_a_selected_primitive_field_is_printed_as_ros2cli_prints_it():
    message = point_stamped()
    assert format_echo(select_field(message, parse_field_path('point.x'))) == '0.4\n---\n'
    assert format_echo(select_field(message, ['header', 'frame_id'])) == 'base\n---\n'


def test_a_selected_array_or_message_field_is_yaml():
    message = JointState(position=[1.5, 2.5])
    assert format_echo(select_field(message, ['position'])) == '- 1.5\n- 2.5\n---\n'
    assert format_echo(select_field(point_stamped(), ['point'])) == (
        'x: 0.4\ny: 0.1\nz: 0.0\n---\n')


def test_an_unknown_field_is_a_one_line_error_naming_the_path():
    with pytest.raises(CliError, match=r"Invalid field 'point\.w': point has no field 'w'"):
        select_field(point_stamped(), ['point', 'w'])
    with pytest.raises(CliError, match=r"Invalid field 'x\.y': the message has no field 'x'"):
        select_field(point_stamped(), ['x', 'y'])
    with pytest.raises(CliError, match=r"point\.x has no field 'y'"):
        select_field(point_stamped(), ['point', 'x', 'y'])


def test_a_field_path_without_a_name_is_a_usage_error():
    assert parse_field_path('.point..x.') == ['point', 'x']
    with pytest.raises(UsageError, match=r"Invalid field value '\.\.'"):
        parse_field_path('..')


# --------------------------------------------------------------------------------------------
# pub: a YAML dict into a message


@pytest.mark.parametrize(('field_type', 'expected'), [
    ('double', ('double', False)),
    ('sequence<double>', ('double', True)),
    ('sequence<geometry_msgs/Point32, 4>', ('geometry_msgs/Point32', True)),
    ('double[36]', ('double', True)),
    ('string<=8', ('string', False)),
    ('sequence<string<=8>', ('string', True)),
    ('std_msgs/Header', ('std_msgs/Header', False)),
])
def test_field_element_type(field_type, expected):
    assert field_element_type(field_type) == expected


def test_array_lengths_are_checked_against_fixed_sizes_and_bounds():
    check_array_length('double[3]', 3, 'f')
    check_array_length('sequence<double, 2>', 2, 'f')
    check_array_length('sequence<double>', 1000, 'f')
    with pytest.raises(FieldError, match=r"field 'f' takes exactly 3 items, got 2"):
        check_array_length('double[3]', 2, 'f')
    with pytest.raises(FieldError, match=r"field 'f' takes at most 2 items, got 3"):
        check_array_length('sequence<double, 2>', 3, 'f')


def test_nested_values_fill_the_message_and_integers_become_floats():
    message = PointStamped()
    assert fill_message(message, parse_values('{point: {x: 1, y: 0.1}, '
                                              'header: {frame_id: base}}')) == []
    assert (message.point.x, message.point.y, message.point.z) == (1.0, 0.1, 0.0)
    assert message.header.frame_id == 'base'


def test_arrays_of_primitives_and_of_messages_are_filled_from_lists():
    joints = JointState()
    fill_message(joints, {'name': ['joint1', 'joint2'], 'position': [1, 2.5]})
    assert list(joints.name) == ['joint1', 'joint2']
    assert list(joints.position) == [1.0, 2.5]
    polygon = Polygon()
    fill_message(polygon, {'points': [{'x': 1.0}, {'y': 2}]})
    assert [(p.x, p.y) for p in polygon.points] == [(1.0, 0.0), (0.0, 2.0)]


def test_a_scalar_given_for_a_string_field_becomes_its_text():
    message = String()
    fill_message(message, parse_values('data: 123'))
    assert message.data == '123'


def test_header_auto_and_time_now_are_stamped_at_each_publish():
    message = PointStamped()
    paths = fill_message(message, parse_values('{header: auto, point: {x: 0.4}}'))
    assert paths == [('header', 'stamp')]
    set_stamps(message, paths, Time(sec=7, nanosec=9))
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (7, 9)
    assert message.header.frame_id == ''
    message = PointStamped()
    assert fill_message(message, {'header': {'stamp': 'now'}}) == [('header', 'stamp')]


def test_an_unknown_field_names_the_fields_there_are():
    with pytest.raises(FieldError, match=r"the message has no field 'pont' \(fields: header, "
                                         r'point\)'):
        fill_message(PointStamped(), {'pont': {'x': 1.0}})
    with pytest.raises(FieldError, match=r"point has no field 'w' \(fields: x, y, z\)"):
        fill_message(PointStamped(), {'point': {'w': 1.0}})


@pytest.mark.parametrize(('message', 'values', 'reason'), [
    (PointStamped(), {'point': {'x': 'far'}}, r"field 'point\.x' takes a number, got 'far'"),
    (PointStamped(), {'point': 3}, r'point takes a dictionary of fields, got 3'),
    (JointState(), {'position': 1.0}, r"field 'position' takes a list, got 1\.0"),
    (JointState(), {'position': [1.0, 'a']}, r"field 'position\[1\]' takes a number"),
    (Int8(), {'data': 300}, r"field 'data' takes a int8 in \[-128, 127\], got 300"),
    (UInt8(), {'data': -1}, r"field 'data' takes a uint8 in \[0, 255\], got -1"),
    (PoseWithCovariance(), {'covariance': [1.0] * 3},
     r"field 'covariance' takes exactly 36 items, got 3"),
    (Int8(), {'data': True}, r"field 'data' takes an integer, got True"),
    (Polygon(), {'points': [{'x': 1.0}, 5]}, r'points\.1 takes a dictionary of fields'),
])
def test_a_value_that_does_not_fit_is_a_one_line_field_error(message, values, reason):
    with pytest.raises(FieldError, match=reason) as raised:
        fill_message(message, values)
    assert '\n' not in str(raised.value)


def test_values_that_are_not_a_yaml_dict_are_usage_errors():
    with pytest.raises(UsageError, match=r'the values are not valid YAML \(.*\): '):
        parse_values('{point: {x: [}}')
    with pytest.raises(UsageError, match='needs to be a dictionary in YAML format'):
        parse_values('- 1\n- 2')
    with pytest.raises(UsageError, match='needs to be a dictionary in YAML format'):
        parse_values('')



# --------------------------------------------------------------------------------------------
# hz


def test_rate_statistics_are_ros2cli_figures_and_lines():
    statistics = rate_statistics([10_000_000, 30_000_000])
    assert statistics.rate == pytest.approx(50.0)
    assert statistics.std_dev == pytest.approx(0.01)
    assert statistics.format() == ('average rate: 50.000\n'
                                   '\tmin: 0.010s max: 0.030s std dev: 0.01000s window: 2')
    with pytest.raises(ValueError, match='at least two messages'):
        rate_statistics([])


def test_the_window_reports_once_per_second_of_arrivals():
    window = RateWindow()
    assert window.due() is None
    reports = []
    for index in range(302):  # 3 s at 100 Hz
        window.add(index * 10_000_000)
        statistics = window.due()
        if statistics is not None:
            reports.append((index, statistics))
    # The first arrival with an interval starts the count; a report each 1 s after it.
    assert [index for index, _ in reports] == [101, 201, 301]
    assert all(s.rate == pytest.approx(100.0) for _, s in reports)
    assert [s.window for _, s in reports] == [101, 201, 301]


def test_the_window_keeps_the_last_intervals_and_restarts_when_the_clock_goes_back():
    window = RateWindow(size=5)
    for index in range(200):
        window.add(index * 20_000_000)
        window.due()
    window.add(10**10)
    assert window.due().window == 5
    window.add(0)  # earlier than the last arrival: a new start
    assert window.due() is None
    with pytest.raises(ValueError, match='window size must be >= 1'):
        RateWindow(size=0)


# --------------------------------------------------------------------------------------------
# list, info, QoS


def test_topic_list_is_sorted_with_types_in_brackets_and_hides_hidden_topics():
    graph = [('/target', ['geometry_msgs/msg/PointStamped']),
             ('/_hidden/x', ['std_msgs/msg/String']),
             ('/joint_states', ['sensor_msgs/msg/JointState']),
             ('/mixed', ['a/msg/A', 'b/msg/B'])]
    assert format_topic_list(graph) == ['/joint_states', '/mixed', '/target']
    assert format_topic_list(graph, show_types=True) == [
        '/joint_states [sensor_msgs/msg/JointState]', '/mixed [a/msg/A, b/msg/B]',
        '/target [geometry_msgs/msg/PointStamped]']
    assert '/_hidden/x' in format_topic_list(graph, include_hidden=True)


def test_topic_info_counts_and_verbose_endpoints():
    assert format_topic_info(['geometry_msgs/msg/PointStamped'], ['p'], []) == (
        'Type: geometry_msgs/msg/PointStamped\nPublisher count: 1\nSubscription count: 0\n')
    assert format_topic_info(['a/msg/A'], ['pub1', 'pub2'], ['sub1'], verbose=True) == (
        'Type: a/msg/A\n\nPublisher count: 2\n\npub1\n\npub2\n\n'
        'Subscription count: 1\n\nsub1\n\n')
    assert format_topic_info(['a/msg/A', 'b/msg/B'], [], []).startswith(
        "Type: ['a/msg/A', 'b/msg/B']\n")


def test_echo_and_hz_match_what_every_publisher_offers():
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    assert matching_qos([]) == qos_profile_sensor_data
    profile = matching_qos([reliable])
    assert (profile.reliability, profile.durability) == (ReliabilityPolicy.RELIABLE,
                                                         DurabilityPolicy.VOLATILE)
    assert profile.depth == qos_profile_sensor_data.depth
    profile = matching_qos([reliable, best_effort])
    assert profile.reliability == ReliabilityPolicy.BEST_EFFORT
    profile = matching_qos([latched])
    assert (profile.reliability, profile.durability) == (ReliabilityPolicy.RELIABLE,
                                                         DurabilityPolicy.TRANSIENT_LOCAL)
    assert matching_qos([latched, reliable]).durability == DurabilityPolicy.VOLATILE
    # hz keeps its deep queue whatever the publishers offer.
    assert matching_qos([reliable], HZ_BASE_QOS).depth == 1000




# --------------------------------------------------------------------------------------------
# Parsers and verbs that stop before ROS starts


def test_bad_pub_values_exit_2_and_an_unknown_type_exits_1_before_ros_starts(capsys):
    handler = signal.getsignal(signal.SIGINT)
    assert topic.main(['pub', '/x', 'std_msgs/msg/String', '{data: [}']) == 2
    assert capsys.readouterr().err.startswith(
        'ros2 topic pub: error: the values are not valid YAML')
    assert topic.main(['pub', '/x', 'std_msgs/msg/String', '{dat: a}']) == 2
    assert capsys.readouterr().err == ("ros2 topic pub: error: Failed to populate field: "
                                       "the message has no field 'dat' (fields: data)\n")
    assert topic.main(['pub', '/x', 'no_msgs/msg/None', '{}']) == 1
    assert capsys.readouterr().err.startswith('The passed message type is invalid')
    assert topic.main(['echo', '/x', '--field', '.']) == 2
    assert capsys.readouterr().err == "ros2 topic echo: error: Invalid field value '.'\n"
    # The verbs hand Ctrl-C back to the caller when they end.
    assert signal.getsignal(signal.SIGINT) is handler


# list's wait: the graph settled


def settle(snapshots: list[tuple[float, object, bool]], spin_time: float = 3.0) -> float:
    """The time (s) GraphSettling calls the graph settled, fed (time, snapshot, has_nodes)
    every 50 ms from `snapshots` (each holds from its time until the next's)."""
    settling = GraphSettling(0.0, spin_time)
    now = 0.0
    while now <= spin_time + 0.05:
        current = [row for row in snapshots if row[0] <= now][-1]
        if settling.settled(current[1], current[2], now):
            return round(now, 2)
        now += 0.05
    raise AssertionError('never settled')


def test_list_returns_once_the_graph_holds_still_with_nodes_on_it():
    # One node's topics at 0.25 s, the other's at 0.6 s (0.35 s later, as seen at load 8):
    # settled SETTLED_AFTER after the last change, not at the first pause.
    seen = [(0.0, 'own', False), (0.25, 'one node', True), (0.6, 'both nodes', True)]
    assert settle(seen) == round(0.6 + SETTLED_AFTER, 2)


def test_list_of_an_empty_graph_waits_a_little_and_a_busy_one_at_most_spin_time():
    assert settle([(0.0, 'own', False)]) == EMPTY_GRAPH_WAIT
    changing = [(0.05 * k, k, True) for k in range(100)]  # a new topic every poll
    assert settle(changing, spin_time=2.0) == 2.0
    assert settle([(0.0, 'own', False)], spin_time=0.0) == 0.0
