"""Topic-level tests of the arm_sim node with the Panda: state out at 1 kHz with the URDF's
joint names, /robot_description for late joiners, gravity acting on a zero command and held
by a gravity-compensating one, and one-line exits on bad parameters."""

import threading
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from hri_bringup.processes import wait_for
from hri_core import topics
from hri_core.robot_model import panda_urdf_path, robot_model

pytestmark = pytest.mark.integration

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
START_TIMEOUT = 15.0  # s for `ros2 run` to bring the node up and discovery to match
PANDA_JOINTS = [f'panda_joint{i}' for i in range(1, 8)]
HOLD_RATE = 10.0  # 1/s: the holding command's damping, -HOLD_RATE M(q) dq (each joint's
# velocity decays at this rate whatever its inertia: the Panda's wrist is 100 times lighter)
# Every joint at least 1.5 rad from its stops: the fall before the first command ends on none.
HOLD_POSE = (0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.785)
STOP_MARGIN = 0.05  # rad: a joint this close to a stop might be held by it
COMMAND_PERIOD = 0.005  # s between two commands of the test's own loop


def stamp_seconds(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def start_panda(nodes, probe, **params):
    sim = nodes('scara_sim', 'arm_sim', params={'robot': 'panda', **params})
    states = probe.collect('/joint_states', JointState, RELIABLE)
    assert wait_for(lambda: len(states) > 0, START_TIMEOUT), sim.log()
    return sim, states


@pytest.mark.exclusive  # the receive rate is a timing check
def test_panda_publishes_every_step_with_its_joint_names(nodes, probe):
    sim, states = start_panda(nodes, probe)
    tips = probe.collect('/ee_position', PointStamped, RELIABLE)
    start, first = time.monotonic(), len(states)
    assert wait_for(lambda: len(states) >= first + 2000, 10.0)
    rate = (len(states) - first) / (time.monotonic() - start)
    sample = list(states)[first:]
    assert all(list(msg.name) == PANDA_JOINTS for msg in sample)
    assert all(len(msg.position) == len(msg.velocity) == len(msg.effort) == 7 for msg in sample)
    steps = np.diff([stamp_seconds(msg) for msg in sample])
    assert np.median(steps) == pytest.approx(1e-3, abs=1e-6)
    assert rate > 900.0, rate  # received per second of the test's wall clock
    # /ee_position: the tool point of the joint state of the same stamp.
    model = robot_model('panda')
    by_stamp = {stamp_seconds(msg): msg for msg in sample}
    matched = [(tip, by_stamp[stamp_seconds(tip)]) for tip in list(tips)
               if stamp_seconds(tip) in by_stamp]
    assert len(matched) > 10
    for tip, state in matched[:50]:
        assert tip.header.frame_id == 'base'
        np.testing.assert_allclose([tip.point.x, tip.point.y, tip.point.z],
                                   model.tool_position(state.position), atol=1e-9)
    assert sim.stop() == 0


def test_robot_description_reaches_a_late_joiner(nodes, probe):
    sim, states = start_panda(nodes, probe)
    assert wait_for(lambda: len(states) > 500, 10.0)  # well after the one publication
    descriptions = probe.collect(topics.ROBOT_DESCRIPTION.name, String,
                                 topics.ROBOT_DESCRIPTION.qos)
    assert wait_for(lambda: len(descriptions) > 0, 5.0), sim.log()
    assert descriptions[0].data == panda_urdf_path().read_text()


def joint_positions(states) -> np.ndarray:
    return np.array(states[-1].position)


def test_a_zero_command_lets_the_arm_sag(nodes, probe):
    sim, states = start_panda(nodes, probe, perturbation=0.0)
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    before = joint_positions(states)
    end = time.monotonic() + 0.3
    while time.monotonic() < end:
        publisher.publish(Float64MultiArray(data=[0.0] * 7))
        time.sleep(COMMAND_PERIOD)
    assert np.max(np.abs(joint_positions(states) - before)) > 0.05
    assert list(states[-1].effort) == [0.0] * 7


def test_the_brakes_hold_the_arm_when_its_commands_stop(nodes, probe):
    """Zero torque for 0.3 s (the arm sags), then no command: after command_timeout the
    drive goes back to its brakes, as before its first command, and the arm stands still
    (at zero torque it would fall on: a starved controller let the Panda into joint 2's
    stop); the sim says so once."""
    sim, states = start_panda(nodes, probe, perturbation=0.0, command_timeout=0.1)
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    end = time.monotonic() + 0.3
    while time.monotonic() < end:
        publisher.publish(Float64MultiArray(data=[0.0] * 7))
        time.sleep(COMMAND_PERIOD)
    assert wait_for(lambda: 'braking (the joints held)' in sim.log(), 5.0), sim.log()
    time.sleep(0.2)
    held = joint_positions(states)
    time.sleep(0.5)
    assert np.max(np.abs(joint_positions(states) - held)) < 1e-9
    assert list(states[-1].velocity) == [0.0] * 7
    assert sim.log().count('braking (the joints held)') == 1


def test_a_gravity_compensating_command_holds_the_arm_still(nodes, probe):
    """Commands tau = g(q) - HOLD_RATE M(q) dq from the URDF model (the sim's arm
    unperturbed), sent from before the sim starts: after 1 s the arm moves by less than
    5 mrad in the next second, held by the drives, on no stop. The arm starts in HOLD_POSE and
    falls freely until the first command arrives (discovery: 0-0.3 s seen)."""
    model = robot_model('panda')
    publisher = probe.publisher('/effort_controller/commands', Float64MultiArray, 10)
    states = probe.collect('/joint_states', JointState, RELIABLE)
    stop = threading.Event()

    def hold():
        while not stop.is_set():
            q, dq = np.array(HOLD_POSE), np.zeros(7)
            if states:
                q, dq = np.array(states[-1].position), np.array(states[-1].velocity)
            tau = model.gravity_torque(q) - HOLD_RATE * model.mass_matrix(q) @ dq
            publisher.publish(Float64MultiArray(data=tau.tolist()))
            time.sleep(COMMAND_PERIOD)

    holder = threading.Thread(target=hold, daemon=True)
    holder.start()
    try:
        sim = nodes('scara_sim', 'arm_sim', params={'robot': 'panda', 'perturbation': 0.0,
                                                    'initial_q': list(HOLD_POSE)})
        assert wait_for(lambda: len(states) > 0, START_TIMEOUT), sim.log()
        time.sleep(1.0)
        settled = joint_positions(states)
        time.sleep(1.0)
        drift = np.max(np.abs(joint_positions(states) - settled))
        assert drift < 5e-3, drift
        margin = np.minimum(settled - model.limits.lower, model.limits.upper - settled)
        assert np.all(margin > STOP_MARGIN), margin
        assert np.max(np.abs(states[-1].effort)) > 1.0  # it is held, not resting
    finally:
        stop.set()
        holder.join(timeout=2.0)


@pytest.mark.parametrize(('params', 'reason'), [
    ({'robot': 'kuka'}, "bad parameter robot: 'kuka' is not one of scara, panda, ur3, ur5, "
                        'ur10, xarm7, z1'),
    ({'robot': 'panda', 'tool_frame': 'no_link'}, "no frame 'no_link' in the URDF of panda"),
    ({'urdf_file': '/no/such.urdf', 'tool_frame': 'tip'}, 'cannot read urdf_file'),
    ({'robot': 'panda', 'initial_q': [0.0] * 7}, 'outside the joint limits'),
    ({'robot': 'panda', 'perturbation': 0.9}, 'bad parameter perturbation'),
])
def test_bad_parameters_exit_with_one_line(nodes, params, reason):
    sim = nodes('scara_sim', 'arm_sim', params=params)
    assert sim.wait(15.0) == 1
    log = sim.log()
    assert reason in log, log
    assert 'Traceback' not in log
    assert len([line for line in log.splitlines() if 'ERROR' in line]) == 1, log
