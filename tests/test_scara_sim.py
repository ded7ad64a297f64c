"""Topic-level tests of the scara_sim node: state out, commands and the human's force in."""

import math
import random
import re
import signal
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped, WrenchStamped
from rcl_interfaces.srv import SetParameters
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_bringup.processes import wait_for
from hri_core.dynamics import forward_kinematics
from hri_core.node_common import stamp_seconds
from tests.common import set_parameter, wait_for_service
from tests.fault_tools import RawListener, sim_joint_efforts

pytestmark = pytest.mark.integration

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
START_TIMEOUT = 15.0  # s for `ros2 run` to bring the node up and discovery to match


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def start_sim(nodes, probe, **params):
    """Start scara_sim, listen to its state topics, wait for the first message."""
    params.setdefault('command_timeout', 0.3)
    sim = nodes('scara_sim', 'scara_sim', params=params)
    states = probe.collect('/joint_states', JointState, RELIABLE)
    tips = probe.collect('/ee_position', PointStamped, RELIABLE)
    assert wait_for(lambda: len(states) > 0 and len(tips) > 0, START_TIMEOUT), sim.log()
    return sim, states, tips


def publish_for(publisher, message, seconds: float, rate_hz: float = 100.0) -> float:
    """Publish `message` repeatedly at `rate_hz` for `seconds`; return the system time (s)
    of the last publication, the clock of the sim's joint-state stamps."""
    end = time.monotonic() + seconds
    while True:
        publisher.publish(message)
        sent = time.time()
        if time.monotonic() >= end:
            return sent
        time.sleep(1.0 / rate_hz)


def command(values) -> Float64MultiArray:
    return Float64MultiArray(data=[float(v) for v in values])


def test_publishes_stamped_joint_states(nodes, probe):
    sim, states, tips = start_sim(nodes, probe)
    assert wait_for(lambda: len(states) >= 500, 10.0)
    sample = list(states)
    for msg in sample:
        assert list(msg.name) == ['joint1', 'joint2']
        assert len(msg.position) == len(msg.velocity) == len(msg.effort) == 2
        assert all(math.isfinite(v) for v in [*msg.position, *msg.velocity, *msg.effort])
    stamps = np.array([stamp_ns(m) for m in sample])
    assert np.all(np.diff(stamps) > 0)
    # Stamps follow real time: 500+ messages span about as long as they took to arrive.
    span = (stamps[-1] - stamps[0]) / 1e9
    assert 0.3 < span < 5.0
    assert tips[0].header.frame_id == 'base'
    np.testing.assert_allclose(sample[0].position, [0.0, math.pi / 2], atol=1e-6)
    assert sim.alive()
    assert sim.stop(sig=signal.SIGTERM) == 0
    log = sim.log_path.read_text()
    assert 'steps integrated in' in log and 'Traceback' not in log


def test_parameters_change_at_run_time_only_when_valid(nodes, probe):
    sim, states, _ = start_sim(nodes, probe)
    client = probe.node.create_client(SetParameters, '/scara_sim/set_parameters')
    assert wait_for_service(client, 5.0)
    assert set_parameter(client, 'effort_limit', 3.0).successful
    assert not set_parameter(client, 'effort_limit', -1.0).successful
    rejected = set_parameter(client, 'joint_lower_limits', [0.0, 3.0])
    assert not rejected.successful and 'must be below' in rejected.reason
    assert not set_parameter(client, 'rate_hz', 2000.0).successful
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    publish_for(publisher, command([10.0, 0.0]), 0.3)
    assert list(states[-1].effort) == [3.0, 0.0]
    assert sim.stop() == 0


def test_positive_effort_on_joint_one_turns_it_positive(nodes, probe):
    sim, states, _ = start_sim(nodes, probe)
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    q_before = states[-1].position[0]
    publish_for(publisher, command([2.0, 0.0]), 1.0)
    last = states[-1]
    assert last.position[0] > q_before + 0.05, (q_before, last.position[0])
    assert last.velocity[0] > 0.0
    assert list(last.effort) == [2.0, 0.0]


def test_a_renamed_sim_takes_its_commands_as_name_commands(nodes, probe):
    """The stepping thread takes the commands from the subscriptions of a second node, which
    is named after the sim's own (renamed) name, not given it."""
    sim = nodes('scara_sim', 'scara_sim', params={'command_timeout': 0.3},
                remaps={'__node': 'arm'})
    states = probe.collect('/joint_states', JointState, RELIABLE)
    assert wait_for(lambda: len(states) > 0, START_TIMEOUT), sim.log()
    assert wait_for(lambda: {'arm', 'arm_commands'} <= set(probe.node.get_node_names()),
                    START_TIMEOUT), probe.node.get_node_names()
    subscribers = probe.node.get_subscriptions_info_by_topic('/effort_controller/commands')
    assert [info.node_name for info in subscribers] == ['arm_commands']
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    publish_for(publisher, command([1.5, -0.5]), 0.5)
    assert list(states[-1].effort) == [1.5, -0.5]


def test_effort_is_clipped_at_the_effort_limit(nodes, probe):
    sim, states, _ = start_sim(nodes, probe, effort_limit=5.0)
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    publish_for(publisher, command([50.0, -50.0]), 0.5)
    assert list(states[-1].effort) == [5.0, -5.0]


def test_command_timeout_zeroes_the_torque_and_says_so(nodes, probe):
    sim, states, _ = start_sim(nodes, probe, command_timeout=0.3)
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    last_sent = publish_for(publisher, command([1.0, 0.5]), 0.6)
    assert wait_for(lambda: list(states[-1].effort) == [0.0, 0.0], 3.0)
    # Stamps, not the test's own timing: a starved test process only makes the gap longer.
    # The sim receives the last command after it was sent, so the torque holds at least
    # command_timeout from then (1 ms: one step's stamp).
    first_zero = next(stamp_seconds(state.header.stamp) for state in states
                      if stamp_seconds(state.header.stamp) > last_sent
                      and list(state.effort) == [0.0, 0.0])
    assert first_zero - last_sent >= 0.3 - 1e-3
    publish_for(publisher, command([1.0, 0.5]), 0.3)
    assert wait_for(lambda: 'commands resumed' in sim.log(), 3.0), sim.log()
    log = sim.log()
    assert 'no joint command for 0.3 s: applying zero torque' in log
    assert 'effort commands resumed' in log


def test_malformed_commands_are_rejected_and_the_last_good_one_kept(nodes, probe):
    sim, states, _ = start_sim(nodes, probe, command_timeout=2.0)
    effort = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    wrench = probe.publisher('/human/wrench', WrenchStamped, 10)
    publish_for(effort, command([1.5, 0.0]), 0.3)
    bad_wrench = WrenchStamped()
    bad_wrench.header.frame_id = 'base'
    bad_wrench.wrench.force.x = float('inf')
    for bad in ([1.0], [float('nan'), 0.0], [1.0, 2.0, 3.0], [float('inf'), 0.0]):
        effort.publish(command(bad))
        wrench.publish(bad_wrench)
        time.sleep(0.05)
    time.sleep(0.3)
    assert sim.alive()
    last = states[-1]
    assert list(last.effort) == [1.5, 0.0]
    assert all(math.isfinite(v) for v in [*last.position, *last.velocity])
    assert wait_for(lambda: 'rejected effort command' in sim.log(), 2.0), sim.log()
    log = sim.log()
    assert 'rejected /human/wrench' in log
    assert 'Traceback' not in log


def test_ee_position_is_the_forward_kinematics_of_the_joint_states(nodes, probe):
    sim, states, tips = start_sim(nodes, probe)
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    publish_for(publisher, command([1.0, -0.5]), 0.5)
    by_stamp = {stamp_ns(m): m for m in list(states)}
    pairs = [(by_stamp[stamp_ns(t)], t) for t in list(tips) if stamp_ns(t) in by_stamp]
    assert len(pairs) > 100
    q = np.array([s.position for s, _ in pairs])
    tip = np.array([[t.point.x, t.point.y] for _, t in pairs])
    np.testing.assert_allclose(tip, forward_kinematics(q, 0.35, 0.30), atol=1e-12)
    assert np.ptp(tip[:, 0]) > 1e-3  # the arm moved while we compared


def test_velocity_command_is_tracked_by_the_internal_loop(nodes, probe):
    sim, states, _ = start_sim(nodes, probe)
    publisher = probe.publisher('/velocity_controller/commands', Float64MultiArray, 10)
    publish_for(publisher, command([0.3, -0.2]), 1.0)
    np.testing.assert_allclose(states[-1].velocity, [0.3, -0.2], atol=0.02)
    # The most recent interface wins: an effort command takes over from velocity.
    effort = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    publish_for(effort, command([0.0, 0.0]), 0.3)
    assert list(states[-1].effort) == [0.0, 0.0]


def test_the_human_force_moves_the_end_effector(nodes, probe):
    sim, _, tips = start_sim(nodes, probe)
    publisher = probe.publisher('/human/wrench', WrenchStamped, 10)
    push = WrenchStamped()
    push.header.frame_id = 'base'
    push.wrench.force.x = 5.0
    x_before = tips[-1].point.x
    publish_for(publisher, push, 0.5)
    assert tips[-1].point.x > x_before + 0.01


def test_a_held_back_sim_publishes_every_step_and_none_before_its_time(nodes, probe):
    # Held back 40 times for 0.3-3 ms at random phases of its 1 ms ticks, the sim owes one
    # or more steps at its next tick. It publishes every step (stamps 1 ms of sim time
    # apart, none missing but those it reports dropped after a stall beyond
    # max_catch_up_steps) and none before real time has reached the end of that step: a
    # step is stamped with the time it stands for, which is never after it was sent.
    listener = RawListener(probe, '/joint_states', JointState)
    sim = nodes('scara_sim', 'scara_sim')
    assert wait_for(lambda: len(listener) >= 300, START_TIMEOUT), sim.log()
    rng = random.Random(4)
    for _ in range(40):
        sim.send(signal.SIGSTOP)
        try:
            time.sleep(rng.uniform(0.3e-3, 3e-3))
        finally:
            sim.send(signal.SIGCONT)
        time.sleep(rng.uniform(2e-3, 6e-3))
    count = len(listener)
    assert wait_for(lambda: len(listener) >= count + 100, 10.0), sim.log()
    sent, stamps, _ = sim_joint_efforts(listener)
    ahead = stamps - sent
    assert ahead.max() < 1e-4, f'{np.sum(ahead >= 1e-4)} states stamped ahead, by up to ' \
        f'{ahead.max() * 1e3:.2f} ms'
    steps = np.round(np.diff(stamps) / 1e-3)
    np.testing.assert_allclose(np.diff(stamps), steps * 1e-3, atol=2e-5)
    assert steps.min() == 1
    assert sim.stop() == 0
    dropped = re.findall(r'(\d+) steps dropped$', sim.log(), re.MULTILINE)  # the summary last
    assert dropped and steps.sum() - steps.size <= int(dropped[-1]), sim.log()


def test_out_of_range_parameter_exits_with_one_line(nodes):
    sim = nodes('scara_sim', 'scara_sim', params={'rate_hz': 10.0})
    assert sim.wait(15.0) == 1
    log = sim.log()
    assert 'bad parameter rate_hz' in log
    assert 'Traceback' not in log


def test_hand_sim_publishes_its_profile_on_target(nodes, probe):
    hand = nodes('scara_sim', 'hand_sim',
                 params={'profile': 'circle', 'start': [0.3, 0.2], 'radius': 0.05,
                         'period': 2.0})
    targets = probe.collect('/target', PointStamped, RELIABLE)
    assert wait_for(lambda: len(targets) >= 100, START_TIMEOUT), hand.log()
    sample = list(targets)
    points = np.array([[t.point.x, t.point.y] for t in sample])
    np.testing.assert_allclose(np.linalg.norm(points - [0.3, 0.2], axis=1), 0.05, atol=1e-9)
    assert np.ptp(points[:, 0]) > 0.02  # it goes round
    assert all(t.header.frame_id == 'base' for t in sample)
    stamps = np.array([stamp_ns(t) for t in sample]) / 1e9
    assert np.median(np.diff(stamps)) == pytest.approx(0.01, rel=0.2)


def test_hand_sim_moves_through_3d_waypoints(nodes, probe):
    """dimension 3: the waypoints are [x, y, z] and /target carries the height."""
    targets = probe.collect('/target', PointStamped, RELIABLE)
    hand = nodes('scara_sim', 'hand_sim',
                 params={'profile': 'waypoints', 'dimension': 3, 'speed': 0.5,
                         'start_delay': 1.0, 'waypoints': [0.3, 0.0, 0.8, 0.3, 0.0, 0.6]})
    # still 1 s, then the move takes 1.875 x 0.2 m / 0.5 m/s = 0.75 s; then the hand stays
    assert wait_for(lambda: len(targets) >= 200, START_TIMEOUT), hand.log()
    points = np.array([[t.point.x, t.point.y, t.point.z] for t in list(targets)])
    np.testing.assert_allclose(points[:, :2], [[0.3, 0.0]] * len(points), atol=1e-12)
    assert points[0, 2] == pytest.approx(0.8, abs=0.01)
    np.testing.assert_allclose(points[-1], [0.3, 0.0, 0.6], atol=1e-9)
    assert '3-D) at 100 Hz' in hand.log()
