"""Unit tests of hri_core.message_types: a message class from its type name. No rclpy.init()."""

import pytest
from geometry_msgs.msg import Point, PointStamped
from hri_interfaces.msg import TaskParameters

from hri_core.message_types import MessageTypeError, message_class, split_message_type


def test_message_types_resolve_with_or_without_msg():
    assert message_class('geometry_msgs/msg/PointStamped') is PointStamped
    assert message_class('geometry_msgs/PointStamped') is PointStamped
    assert message_class('geometry_msgs/Point') is Point
    assert message_class('hri_interfaces/msg/TaskParameters') is TaskParameters
    assert split_message_type('std_msgs/msg/Header') == ('std_msgs', 'Header')


@pytest.mark.parametrize(('name', 'reason'), [
    ('PointStamped', r"^'PointStamped' is not a message type name \(expected pkg/msg/Name\)$"),
    ('geometry_msgs/srv/PointStamped', 'is not a message type name'),
    ('geometry_msgs//PointStamped', 'is not a message type name'),
    ('a/b/c/d', 'is not a message type name'),
    ('', 'is not a message type name'),
    ('no_msgs/msg/Nothing', r"^'no_msgs/msg/Nothing': no message Nothing in a Python package "
                            r'no_msgs$'),
    ('geometry_msgs/msg/Nothing', 'no message Nothing in a Python package geometry_msgs'),
    ('geometry_msgs/msg/_point', r"^'geometry_msgs/msg/_point' is not a message$"),
    ('.x/msg/Y', 'no message Y in a Python package .x'),
])
def test_a_name_that_is_no_message_is_one_line_reason(name, reason):
    with pytest.raises(MessageTypeError, match=reason) as error:
        message_class(name)
    assert '\n' not in str(error.value)
    assert isinstance(error.value, ValueError)
