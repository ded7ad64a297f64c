"""The node forker (tests/node_forker.py) gives a forked node what `ros2 run` gives it: the
test's ROS domain, its log, its exit code (a signal's as a negative number), and refuses what
is not a node of the project."""

import signal

import pytest
from geometry_msgs.msg import PointStamped

from hri_bringup.processes import READY_LINES, wait_for
from hri_core.topics import TARGET

pytestmark = pytest.mark.integration


def test_a_forked_node_is_on_the_tests_domain_and_exits_as_ros2_run_would(nodes, probe):
    targets = probe.collect(TARGET.name, PointStamped, TARGET.qos)
    hand = nodes('scara_sim', 'hand_sim', params={'start': [0.2, -0.1]})
    assert hand.wait_for_line(READY_LINES['hand_sim'], 15.0), hand.log()
    assert wait_for(lambda: len(targets) > 5, 15.0), hand.log()
    assert [targets[-1].point.x, targets[-1].point.y] == [0.2, -0.1]
    assert hand.stop(sig=signal.SIGTERM) == 0, hand.log()
    assert 'summary:' in hand.log()
    assert not hand.alive()

    killed = nodes('scara_sim', 'hand_sim')
    assert killed.wait_for_line(READY_LINES['hand_sim'], 15.0), killed.log()
    killed.send(signal.SIGKILL)
    assert killed.wait(5.0) == -signal.SIGKILL

    refused = nodes('scara_sim', 'hand_sim', params={'profile': 'somersault'})
    assert refused.wait(15.0) == 1, refused.log()
    assert 'Traceback' not in refused.log()


def test_what_is_not_a_node_of_the_project_is_refused(node_forker, tmp_path):
    log = (tmp_path / 'x.log').open('wb')
    with pytest.raises(RuntimeError, match='cannot fork scara_sim/no_such_node: no node'):
        node_forker.spawn(['ros2', 'run', 'scara_sim', 'no_such_node'], {}, log)
    with pytest.raises(ValueError, match='not a ros2 run command'):
        node_forker.spawn(['python', '-c', 'pass'], {}, log)
    log.close()
