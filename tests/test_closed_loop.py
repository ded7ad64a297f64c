"""Closed loop on topics: scara_sim + event_manager + controller + hand_sim, Table I's tasks.

The scenario starts the four nodes with `ros2 run` and watches /hri/controller_state (the
distance |x - x_d| between end-effector and hand, the torque) until the behaviour of paper
Section IV-B shows: follow with a safe distance (Fig. 6). Follow (Fig. 4), avoid (Fig. 5) and
the switch follow -> avoid with no torque step: tests/test_task_behaviour.py. And the
controller alone against bad joint states.
"""

import math
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import ControllerState
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_bringup.processes import wait_for
from hri_core.topics import MONITOR_QOS

EFFORT_LIMIT = 20.0  # N m, the controller's default
TOLERANCE = 0.005  # m around the region boundaries

# The 1 kHz closed loop needs the machine to itself (pytest.ini, marker exclusive).
pytestmark = [pytest.mark.integration, pytest.mark.exclusive]


@pytest.fixture
def loop(live_loop, probe):
    """start(task, hand params) -> list of ControllerState; the nodes run until the test ends."""

    def start(task: str, hand: dict, ramp_time: float = 0.5):
        states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
        controller = live_loop({'event_manager': {'initial_task': task, 'ramp_time': ramp_time},
                                'hand_sim': hand})['controller']
        assert wait_for(lambda: states and states[-1].status == 'ok', 30.0), controller.log()
        return states

    return start


def settled_in(states: list, d1: float, d2: float, seconds: float = 1.0) -> bool:
    """The last `seconds` of states (100 Hz) all lie in [d1, d2] (+- TOLERANCE)."""
    recent = states[-int(100 * seconds):]
    return len(recent) >= 50 and all(
        d1 - TOLERANCE <= s.distance <= d2 + TOLERANCE for s in recent)


def assert_commands_safe(states: list) -> None:
    efforts = np.array([list(s.effort) for s in states if len(s.effort) == 2])
    assert np.all(np.isfinite(efforts))
    assert np.max(np.abs(efforts)) <= EFFORT_LIMIT + 1e-9
    assert all(math.isfinite(s.distance) and math.isfinite(s.lyapunov) for s in states)


def test_follow_with_safe_distance_settles_in_the_band(loop):
    # A far hand (0.42 m): the robot follows until it is inside [0.183, 0.271] m.
    states = loop('follow_safe', {'profile': 'waypoints', 'start_delay': 4.0, 'speed': 0.06,
                                  'waypoints': [0.55, 0.0, 0.42, 0.22]})
    assert wait_for(lambda: settled_in(states, 0.183, 0.271), 15.0), states[-1]
    moving_from = len(states)
    # Then the hand comes closer (to 0.1 m of where the robot was): the robot backs off.
    assert wait_for(lambda: len(states) - moving_from > 500
                    and settled_in(states, 0.183, 0.271), 25.0), states[-1]
    assert_commands_safe(states)


def test_bad_joint_states_give_zero_torque_without_crash(nodes, probe):
    """NaN joint states are dropped; without fresh valid ones the torque is zero."""
    states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
    commands = probe.collect('/effort_controller/commands', Float64MultiArray, 10)
    controller = nodes('hri_adaptive_controller', 'controller',
                       params={'joint_state_timeout': 0.05})
    joints = probe.publisher('/joint_states', JointState, 10)
    targets = probe.publisher('/target', PointStamped, 10)
    assert wait_for(lambda: joints.get_subscription_count() > 0, 20.0), controller.log()
    target = PointStamped()
    target.point.x, target.point.y = 0.45, 0.1
    for _ in range(20):
        target.header.stamp = probe.now()
        targets.publish(target)
        bad = JointState(name=['joint1', 'joint2'], position=[math.nan, 1.0],
                         velocity=[0.0, 0.0])
        bad.header.stamp = probe.now()
        joints.publish(bad)
        # The controller keeps only the latest joint state (depth 1): one bad kind at a time.
        time.sleep(0.025)
        short = JointState(name=['joint1'], position=[0.1], velocity=[0.0])
        joints.publish(short)
        time.sleep(0.025)
    assert wait_for(lambda: len(states) > 20, 10.0)
    assert controller.alive()
    assert all(s.status in ('no_joint_states', 'stale_joint_states', 'no_target')
               for s in states[-10:])
    assert commands and all(list(c.data) == [0.0, 0.0] for c in commands[-100:])
    log = controller.log()
    assert 'non-finite' in log and 'Traceback' not in log
    # Valid but then stale joint states: zero torque again after joint_state_timeout.
    good = JointState(name=['joint2', 'joint1'], position=[1.5, 0.0], velocity=[0.0, 0.0])
    good.header.stamp = probe.now()
    joints.publish(good)
    time.sleep(0.5)
    assert states[-1].status in ('stale_joint_states', 'no_task_state')
    assert wait_for(lambda: states[-1].status == 'stale_joint_states', 5.0)
    assert all(list(c.data) == [0.0, 0.0] for c in commands[-50:])
