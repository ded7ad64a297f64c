"""The Panda in the live loop: arm_sim robot:=panda at 1 kHz, the event_manager with Table I's
rows, the controller robot:=panda (arm_law) and a probe hand on /target. follow: a still 3-D
hand 0.3 m from the tool; the tool enters the region within 5 s and stays there under gravity
while theta_hat adapts from the URDF's values (the sim's arm is perturbed). avoid: a hand
coming down along z onto the tool at 0.5 m/s; 2 s after it stops the tool is >= d1 - 2 cm
away. Both: every command within the Panda's per-joint effort limits and at most 1 N m from
the one before; no joint within 5 deg of a limit."""

import math
import threading
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import ControllerState
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_bringup.processes import paper_tasks_dir, wait_for
from hri_core import topics
from hri_core.robot_model import robot_model
from hri_core.task_file import load_task_file

pytestmark = [pytest.mark.integration, pytest.mark.exclusive]  # a 1 kHz loop, timed

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
START_TIMEOUT = 15.0  # s for `ros2 run` to bring a node up
HAND_OFFSET = np.array([0.1, 0.25, -0.13])  # m from the tool's home position, a 3-D step ...
HAND_OFFSET *= 0.3 / np.linalg.norm(HAND_OFFSET)  # ... 0.3 m long
HAND_PERIOD = 0.01  # s: a 100 Hz hand tracker
ENTER_TIME = 5.0  # s from the first joint state
HOLD_TIME = 3.0  # s held in the region after entering (within the run)
MAX_STEP = 1.0  # N m per command per joint (1 ms cycles)
LIMIT_MARGIN = math.radians(5.0)


def stamp_seconds(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def publish_hand(probe, position, started: dict, stop: threading.Event) -> threading.Thread:
    """The hand on /target at 100 Hz, stamped with the probe's clock: `position` (3,) m, or a
    function of the time (s) since started['at'] (monotonic; None before) giving it."""
    publisher = probe.publisher(topics.TARGET.name, PointStamped, topics.TARGET.qos)

    def where():
        if not callable(position):
            return position
        at = started.get('at')
        return position(None if at is None else time.monotonic() - at)

    def run():
        while not stop.is_set():
            msg = PointStamped()
            msg.header.stamp = probe.now()
            msg.header.frame_id = 'base'
            msg.point.x, msg.point.y, msg.point.z = (float(v) for v in where())
            publisher.publish(msg)
            stop.wait(HAND_PERIOD)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def run_panda_loop(nodes, probe, task: str, hand, duration: float, tasks_dir=None):
    """The loop with `task` (of `tasks_dir`; None: Table I's) faded in and the hand `hand`
    (see publish_hand) for `duration` s after the first joint state: (joint states, commands,
    controller states, controller, sim). The event_manager and the controller start first,
    so the arm is controlled from its first step (a Panda without torque sags)."""
    stop, started = threading.Event(), {}
    publish_hand(probe, hand, started, stop)
    try:
        states = probe.collect('/joint_states', JointState, RELIABLE)
        commands = probe.collect(topics.EFFORT_COMMANDS.name, Float64MultiArray, RELIABLE)
        reports = probe.collect(topics.CONTROLLER_STATE.name, ControllerState, RELIABLE)
        manager = nodes('hri_adaptive_controller', 'event_manager', params={
            'tasks_dir': str(tasks_dir or paper_tasks_dir()), 'initial_task': task})
        controller = nodes('hri_adaptive_controller', 'controller',
                           params={'robot': 'panda'})
        assert controller.wait_for_line('control on each /joint_states', START_TIMEOUT), \
            controller.log()
        assert manager.wait_for_line('task(s) loaded', START_TIMEOUT), manager.log()
        sim = nodes('scara_sim', 'arm_sim', params={'robot': 'panda'})
        assert wait_for(lambda: len(states) > 0, START_TIMEOUT), sim.log()
        start = started['at'] = time.monotonic()
        assert wait_for(lambda: time.monotonic() - start > duration, duration + 1.0)
        assert 'joint names agree with /robot_description' in controller.log()
    finally:
        stop.set()
    assert controller.alive() and sim.alive()
    return list(states), np.array([msg.data for msg in list(commands)]), list(reports), \
        controller


def check_commands_and_limits(model, q, efforts) -> tuple[float, float]:
    """Every command within the per-joint effort limits and <= MAX_STEP from the one before;
    no joint within LIMIT_MARGIN of a limit. Returns (largest step N m, nearest limit rad)."""
    margin = np.minimum(q - model.limits.lower, model.limits.upper - q)
    assert margin.min() > LIMIT_MARGIN, np.degrees(margin.min())
    assert efforts.shape[1] == model.dof
    assert np.all(np.abs(efforts) <= model.limits.effort + 1e-9)
    step = np.abs(np.diff(efforts, axis=0)).max()
    assert step <= MAX_STEP + 1e-9
    return step, margin.min()


def test_the_panda_follows_a_still_3d_hand_and_holds(nodes, probe):
    model = robot_model('panda')
    region = load_task_file(paper_tasks_dir() / 'follow.yaml').d2
    hand = model.tool_position(model.home) + HAND_OFFSET
    sample, efforts, reports, controller = run_panda_loop(nodes, probe, 'follow', hand,
                                                          ENTER_TIME + HOLD_TIME)
    first = stamp_seconds(sample[0])
    times = np.array([stamp_seconds(msg) for msg in sample]) - first
    q = np.array([msg.position for msg in sample])
    tool = np.array([model.tool_position(row) for row in q[::10]])
    distance = np.linalg.norm(tool - hand, axis=1)
    inside = distance <= region
    assert inside.any(), f'closest {distance.min():.3f} m; {controller.log()[-2000:]}'
    entered = times[::10][int(np.argmax(inside))]
    assert entered <= ENTER_TIME, entered
    assert inside[int(np.argmax(inside)):].all(), distance[int(np.argmax(inside)):].max()
    assert times[-1] - entered >= HOLD_TIME - 0.5
    step, margin = check_commands_and_limits(model, q, efforts)
    # theta_hat adapts (77 values, from the URDF's).
    thetas = [np.array(msg.theta_hat) for msg in reports if msg.status == 'ok']
    assert len(thetas[-1]) == model.theta.size
    assert np.linalg.norm(thetas[-1] - model.theta) > 1e-3
    print(f'panda follow: in the region {entered:.2f} s after the first state, held '
          f'{times[-1] - entered:.1f} s (farthest {distance[int(np.argmax(inside)):].max():.4f} '
          f'm of {region} m); largest effort step {step:.3f} N m; nearest limit '
          f'{np.degrees(margin):.1f} deg; {len(sample) / times[-1]:.0f} joint states/s; '
          f'state->command median {1e3 * np.median([m.input_age for m in reports]):.2f} ms, '
          f'{reports[-1].deadline_misses} deadline misses')


def test_the_panda_backs_away_from_a_hand_reaching_in_along_z(nodes, probe):
    """avoid (Table I): the hand waits 0.35 m above the tool, comes down at 0.5 m/s onto the
    tool's start and stops there; 2 s later the tool is at least d1 - 2 cm from it."""
    model = robot_model('panda')
    d1 = load_task_file(paper_tasks_dir() / 'avoid.yaml').d1
    start = model.tool_position(model.home)
    height, speed, wait = 0.35, 0.5, 1.5  # m, m/s, s still before it moves

    def hand(elapsed):
        moved = 0.0 if elapsed is None else speed * max(elapsed - wait, 0.0)
        return start + [0.0, 0.0, max(height - moved, 0.0)]

    sample, efforts, _, _ = run_panda_loop(nodes, probe, 'avoid', hand,
                                           wait + height / speed + 2.0)
    q = np.array([msg.position for msg in sample])
    distance = np.linalg.norm(np.array([model.tool_position(row) for row in q[::10]]) - start,
                              axis=1)
    assert distance.min() < d1  # the hand did reach in (to where the tool started)
    assert distance[-1] >= d1 - 0.02, distance[-1]
    step, margin = check_commands_and_limits(model, q, efforts)
    print(f'panda avoid along z: tool {distance[-1]:.3f} m from the hand 2 s after it '
          f'stopped (d1 {d1} m); largest effort step {step:.3f} N m; nearest limit '
          f'{np.degrees(margin):.1f} deg')
