"""Unit tests of what the `ros2 topic` and `ros2 bag` stand-ins share (hri_cli.common):
the one-line parser errors and exit codes, the domain ID check and the message classes.
No rclpy.init().
"""

import re

import pytest

pytest.importorskip('rclpy')
pytest.importorskip('rosbags')

from geometry_msgs.msg import PointStamped  # noqa: E402

from hri_cli import bag, topic  # noqa: E402
from hri_cli.common import (  # noqa: E402
    CliError,
    check_domain_id,
    message_class,
)


def test_a_domain_id_dds_cannot_take_is_refused_in_one_line():
    for usable in ('', '0', '42', ' 232'):
        check_domain_id(usable)
    for unusable in ('233', '-1', 'x'):
        with pytest.raises(CliError, match=f'ROS_DOMAIN_ID={unusable} cannot be used: DDS '
                                           'takes a domain ID from 0 to 232'):
            check_domain_id(unusable)


def test_message_types_resolve_with_or_without_msg():
    assert message_class('geometry_msgs/msg/PointStamped') is PointStamped
    assert message_class('geometry_msgs/PointStamped') is PointStamped
    for name in ('geometry_msgs/msg/Nothing', 'no_such_msgs/msg/Thing', 'PointStamped',
                 'geometry_msgs/srv/PointStamped'):
        with pytest.raises(CliError, match='The passed message type is invalid'):
            message_class(name)


# One-line parser errors, for both verbs


@pytest.mark.parametrize(('module', 'argv'), [
    (topic, ['--help']), (topic, ['list', '-h']), (topic, ['info', '--help']),
    (topic, ['echo', '--help']), (topic, ['hz', '--help']),
    (topic, ['pub', '--help']), (bag, ['--help']), (bag, ['info', '--help']),
    (bag, ['play', '-h']),
])
def test_every_verb_and_sub_verb_has_help(module, argv, capsys):
    with pytest.raises(SystemExit) as exited:
        module.build_parser().parse_args(argv)
    assert exited.value.code == 0
    assert capsys.readouterr().out.startswith('usage: ros2 ')


@pytest.mark.parametrize(('module', 'argv', 'error'), [
    (topic, [], r'^ros2 topic: error: the following arguments are required: COMMAND'),
    (topic, ['lst'], r"^ros2 topic: error: argument COMMAND: invalid choice: 'lst'"),
    (topic, ['hz'], r'^ros2 topic hz: error: the following arguments are required'),
    (topic, ['hz', '/x', '--window', '0'], r'^ros2 topic hz: error: argument -w/--window'),
    (topic, ['pub', '/x', 'std_msgs/msg/String', '-r', '0'], r'-r/--rate: must be'),
    (topic, ['pub', '/x', 'a/msg/A', '--once', '-t', '3'], r'not allowed with argument'),
    (topic, ['echo', '/x', '--bogus'], r'^ros2 topic: error: unrecognized arguments'),
    (bag, ['record'], r"^ros2 bag: error: argument COMMAND: invalid choice: 'record'"),
    (bag, ['play', 'bag', '--rate', 'fast'], r"-r/--rate: not a number: 'fast'"),
])
def test_bad_arguments_are_one_line_and_exit_code_2(module, argv, error, capsys):
    with pytest.raises(SystemExit) as exited:
        module.main(argv)
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert err.rstrip().endswith('--help)')
    assert re.search(error, err), err

