"""The Panda in the live loop: arm_sim robot:=panda at 1 kHz, the event_manager with Table I's
rows, the controller robot:=panda (arm_law) and a probe hand on /target. follow: a still 3-D
hand 0.3 m from the tool; the tool enters the region within 5 s and stays there under gravity
while theta_hat adapts from the URDF's values (the sim's arm is perturbed). avoid: a hand
coming down along z onto the tool at 0.5 m/s; 2 s after it stops the tool is >= d1 - 2 cm
away. follow a moving hand: hand_sim (dimension 3) moves the hand back and forth along a
0.25 m line that drops 0.15 m in z (peak 0.079 m/s); after it has settled the tool stays
within d2 of it (in the follow region). All: every command within the Panda's per-joint
effort limits and at most 1 N m from the one before; no joint within 5 deg of a limit.
The other arms of hri_core.robot_model's table by name (robot:=ur5, ...; the UR5 in the
default run, the others slow): the still hand, as the Panda's follow."""

import math
import threading
import time
from importlib import metadata

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
from tests.fault_tools import (
    REALTIME_PRIORITY,
    RawListener,
    SentCommands,
    effort_change_per_step,
    from_the_first_command,
)

pytestmark = [pytest.mark.integration, pytest.mark.exclusive]  # a 1 kHz loop, timed

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
START_TIMEOUT = 60.0  # s for `ros2 run` to bring a node up (hand_sim took > 15 s under load)
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


def run_panda_loop(nodes, probe, task: str, hand, duration: float, tasks_dir=None,
                   arm=None, sim_only=None, controller_only=None):
    """The loop with `task` (of `tasks_dir`; None: Table I's) faded in and the hand `hand` for
    `duration` s after the first joint state: (joint states, commands, controller states,
    controller). `hand`: a point or a function of time for the probe to publish (see
    publish_hand), or a dict of hand_sim parameters (hand_sim starts once the arm publishes).
    `arm`: the arm parameters of arm_sim and the controller (default robot:=panda);
    `sim_only`: more parameters of arm_sim alone (engine:=mujoco); `controller_only`: of the
    controller alone (clearance).
    The event_manager and the controller start first, so the arm is controlled from its first
    step (a Panda without torque sags). The controller and arm_sim run at SCHED_FIFO where the
    OS grants it, as a 1 kHz loop is deployed (README): beside a busy process at normal
    priority the controller was starved for 0.1-0.3 s while arm_sim applied its last command,
    and the Panda fell onto joint 2's stop."""
    stop, started = threading.Event(), {}
    if not isinstance(hand, dict):
        publish_hand(probe, hand, started, stop)
    try:
        # The 1 kHz streams through the probe's raw intake thread: its Python executor,
        # beside the loop's real-time threads and a busy process, had taken in 42 of the
        # last 10 s's joint states (every 10th) when the run ended.
        states = RawListener(probe, '/joint_states', JointState)
        commands = RawListener(probe, topics.EFFORT_COMMANDS.name, Float64MultiArray)
        reports = probe.collect(topics.CONTROLLER_STATE.name, ControllerState, RELIABLE)
        manager = nodes('hri_adaptive_controller', 'event_manager', params={
            'tasks_dir': str(tasks_dir or paper_tasks_dir()), 'initial_task': task})
        arm = arm or {'robot': 'panda'}
        realtime = {'realtime_priority': REALTIME_PRIORITY}
        controller = nodes('hri_adaptive_controller', 'controller',
                           params={**arm, **realtime, **(controller_only or {})})
        assert controller.wait_for_line('control on each /joint_states', START_TIMEOUT), \
            controller.log()
        assert manager.wait_for_line('task(s) loaded', START_TIMEOUT), manager.log()
        sim = nodes('scara_sim', 'arm_sim', params={**arm, **realtime, **(sim_only or {})})
        assert wait_for(lambda: len(states) > 0, START_TIMEOUT), sim.log()
        # The simulated person at SCHED_FIFO too, below the loop: starved beside a busy
        # process it left 0.37 s gaps in /target, and the hand jumped.
        hand_sim = nodes('scara_sim', 'hand_sim', params={
            'realtime_priority': REALTIME_PRIORITY - 10, **hand}) if isinstance(hand, dict) \
            else None
        if hand_sim is not None:
            assert hand_sim.wait_for_line('hand profile', START_TIMEOUT), hand_sim.log()
        start = started['at'] = time.monotonic()
        assert wait_for(lambda: time.monotonic() - start > duration, duration + 1.0)
        # Every joint state up to now taken in (the intake may be behind on a loaded machine).
        end = time.time()  # the system clock, which the sim's stamps follow
        assert wait_for(lambda: stamp_seconds(states.last()) >= end, 10.0)
        assert hand_sim is None or hand_sim.alive(), hand_sim.log()
        assert 'joint names agree with /robot_description' in controller.log()
    finally:
        stop.set()
    assert controller.alive() and sim.alive()
    return states.messages(), SentCommands(commands), list(reports), controller


def check_commands_and_limits(model, q, commands: SentCommands,
                              limit_margin: float = LIMIT_MARGIN) -> tuple[float, float]:
    """Every command within the per-joint effort limits and <= MAX_STEP from the one sent
    before it; no joint within limit_margin (rad) of a limit. Returns (largest step N m,
    nearest limit rad)."""
    margin = np.minimum(q - model.limits.lower, model.limits.upper - q)
    sample, joint = np.unravel_index(int(np.argmin(margin)), margin.shape)
    assert margin.min() > limit_margin, (
        f'joint {joint + 1} {np.degrees(margin.min()):.1f} deg from its limit at joint state '
        f'{sample} of {len(q)}: q {np.round(q[sample], 3).tolist()}')
    efforts = commands.data
    assert efforts.shape[1] == model.dof
    assert np.all(np.abs(efforts) <= model.limits.effort + 1e-9)
    # Judged on the pairs sent one after the other, most of them (a probe held back by the
    # loop's real-time threads may miss a few commands).
    assert commands.consecutive.mean() > 0.9, commands.consecutive.mean()
    step = commands.largest_step()
    assert step <= MAX_STEP + 1e-9
    return step, margin.min()


def enters_band_and_stays(model, sample, hand, band: tuple[float, float], enter_time: float,
                          controller):
    """Assert that the tool's distance to the still `hand` (3,) m came within `band` (d1, d2)
    m at most `enter_time` s after the first joint state of `sample` and stayed there.
    Returns (when it entered (s), the states' times (s), their q, the distances (m) from
    then on, every 10th state)."""
    times = np.array([stamp_seconds(msg) for msg in sample]) - stamp_seconds(sample[0])
    q = np.array([msg.position for msg in sample])
    distance = np.linalg.norm(np.array([model.tool_position(row) for row in q[::10]]) - hand,
                              axis=1)
    inside = (distance >= band[0]) & (distance <= band[1])
    assert inside.any(), (f'distances {distance.min():.3f}-{distance.max():.3f} m; '
                          f'{controller.log()[-2000:]}')
    first = int(np.argmax(inside))
    entered = times[::10][first]
    assert entered <= enter_time, entered
    assert inside[first:].all(), distance[first:].max()
    return entered, times, q, distance[first:]


@pytest.mark.slow  # the moving 3-D hand and test_teach_panda's follow run cover it live
def test_the_panda_follows_a_still_3d_hand_and_holds(nodes, probe):
    model = robot_model('panda')
    region = load_task_file(paper_tasks_dir() / 'follow.yaml').d2
    hand = model.tool_position(model.home) + HAND_OFFSET
    sample, efforts, reports, controller = run_panda_loop(nodes, probe, 'follow', hand,
                                                          ENTER_TIME + HOLD_TIME)
    entered, times, q, held = enters_band_and_stays(model, sample, hand, (0.0, region),
                                                    ENTER_TIME, controller)
    assert times[-1] - entered >= HOLD_TIME - 0.5
    step, margin = check_commands_and_limits(model, q, efforts)
    # theta_hat adapts (77 values, from the URDF's).
    thetas = [np.array(msg.theta_hat) for msg in reports if msg.status == 'ok']
    assert len(thetas[-1]) == model.theta.size
    assert np.linalg.norm(thetas[-1] - model.theta) > 1e-3
    print(f'panda follow: in the region {entered:.2f} s after the first state, held '
          f'{times[-1] - entered:.1f} s (farthest {held.max():.4f} m of {region} m); largest '
          f'effort step {step:.3f} N m; nearest limit {np.degrees(margin):.1f} deg; '
          f'{len(sample) / times[-1]:.0f} joint states/s; '
          f'state->command median {1e3 * np.median([m.input_age for m in reports]):.2f} ms, '
          f'{reports[-1].deadline_misses} deadline misses')


def test_the_panda_backs_away_from_a_hand_reaching_in_along_z(nodes, probe):
    """avoid (Table I): the hand waits 0.35 m above the tool, comes down at 0.5 m/s onto the
    tool's start and stops there; 2 s later the tool is at least d1 - 2 cm from it."""
    backs_away_from_a_hand_reaching_in(
        nodes, probe, load_task_file(paper_tasks_dir() / 'avoid.yaml').d1)


def backs_away_from_a_hand_reaching_in(nodes, probe, d1: float, tasks_dir=None,
                                       sim_only=None, margin: float = 0.02) -> np.ndarray:
    """The avoid task of `tasks_dir` (None: Table I's) with d1 (m) on the live Panda loop
    (`sim_only`: more arm_sim parameters, as run_panda_loop's), the hand coming down along z
    onto the tool's start: the tool ends >= d1 - `margin` (m) from it. Returns the joint
    states' q (rad)."""
    model = robot_model('panda')
    start = model.tool_position(model.home)
    height, speed, wait = 0.35, 0.5, 1.5  # m, m/s, s still before it moves

    def hand(elapsed):
        moved = 0.0 if elapsed is None else speed * max(elapsed - wait, 0.0)
        return start + [0.0, 0.0, max(height - moved, 0.0)]

    sample, efforts, _, _ = run_panda_loop(nodes, probe, 'avoid', hand,
                                           wait + height / speed + 2.0, tasks_dir=tasks_dir,
                                           sim_only=sim_only)
    q = np.array([msg.position for msg in sample])
    distance = np.linalg.norm(np.array([model.tool_position(row) for row in q[::10]]) - start,
                              axis=1)
    assert distance.min() < d1  # the tool began within d1 of where the hand comes to rest
    assert distance[-1] >= d1 - margin, distance[-1]
    step, nearest = check_commands_and_limits(model, q, efforts)
    per_cycle = effort_change_per_step(from_the_first_command(sample),
                                       commands=efforts)
    engine = (sim_only or {}).get('engine', 'pinocchio')
    print(f'panda avoid along z ({engine}): tool {distance[-1]:.3f} m from '
          f'the hand 2 s after it stopped (d1 {d1:.3f} m); largest effort step {step:.3f} '
          f'N m, applied {per_cycle:.3f} N m per cycle; nearest limit '
          f'{np.degrees(nearest):.1f} deg')
    assert per_cycle <= MAX_STEP + 1e-9
    return q


# The moving hand: back and forth between two points 0.25 m apart, 0.15 m lower at the far
# end, period 10 s: pi 0.25 / 10 = 0.079 m/s at its fastest, 0.05 m/s on average.
MOVING_HAND = {'profile': 'back_and_forth', 'dimension': 3, 'start': [0.40, 0.10, 0.45],
               'end': [0.40, -0.10, 0.30], 'period': 10.0, 'rate_hz': 100.0}
# s after the first joint state: the 5 s judged hold the far end (5 s) and the fastest pass
# back (7.5 s).
MOVING_RUN = 9.0
SETTLE_TIME = 4.0  # s after the first joint state before the distance is held to the bar


def hand_at(times, hand_times, hand_points) -> np.ndarray:
    """The hand (N, 3) at `times`, interpolated linearly in the hand's stamped messages."""
    order = np.argsort(hand_times)
    return np.column_stack([np.interp(times, hand_times[order], hand_points[order, axis])
                            for axis in range(3)])


def test_the_panda_follows_a_hand_moving_in_3d(nodes, probe):
    """follow (Table I) with hand_sim's 3-D back_and_forth: from SETTLE_TIME s on, the tool
    stays inside the follow region, within d2 = 4.1 cm of the hand, while the hand moves.
    The bar is the task's own region, not a tuned number. Measured (three runs, load
    average 1.6-2.1): the tool 14 cm from the hand at the start is within d2 2.0 s after the
    first joint state, then 2.5-3.2 cm from the hand (median 3.1 cm, farthest 3.23 cm)."""
    model = robot_model('panda')
    region = load_task_file(paper_tasks_dir() / 'follow.yaml').d2
    targets = probe.collect(topics.TARGET.name, PointStamped, topics.TARGET.qos)
    sample, efforts, _, controller = run_panda_loop(nodes, probe, 'follow', MOVING_HAND,
                                                    MOVING_RUN)
    hand_messages = list(targets)
    hand_times = np.array([stamp_seconds(m) for m in hand_messages])
    hand_points = np.array([(m.point.x, m.point.y, m.point.z) for m in hand_messages])
    assert np.ptp(hand_points[:, 2]) > 0.1  # the hand did move in z (hand_sim in 3-D)
    times = np.array([stamp_seconds(msg) for msg in sample])
    q = np.array([msg.position for msg in sample])
    tool = np.array([model.tool_position(row) for row in q[::10]])
    distance = np.linalg.norm(tool - hand_at(times[::10], hand_times, hand_points), axis=1)
    settled = times[::10] - times[0] >= SETTLE_TIME
    assert settled.sum() > 100
    farthest = float(distance[settled].max())
    step, margin = check_commands_and_limits(model, q, efforts)
    per_cycle = effort_change_per_step(from_the_first_command(sample),
                                       commands=efforts)
    print(f'panda follows a moving 3-D hand: tool to hand after {SETTLE_TIME:g} s median '
          f'{np.median(distance[settled]):.4f} m, farthest {farthest:.4f} m '
          f'(d2 {region} m); hand z {hand_points[:, 2].min():.3f}..'
          f'{hand_points[:, 2].max():.3f} m; largest command step {step:.3f} N m, applied '
          f'{per_cycle:.3f} N m per cycle; nearest limit {np.degrees(margin):.1f} deg')
    assert per_cycle <= MAX_STEP + 1e-9
    worst = float((times[::10] - times[0])[settled][int(np.argmax(distance[settled]))])
    hand_gap = float(np.diff(np.sort(hand_times)).max())
    assert farthest <= region, (f'{farthest:.3f} m at {worst:.2f} s; longest /target gap '
                                f'{hand_gap:.3f} s', controller.log()[-2000:])


XARM7 = 'cmeel.prefix/share/example-robot-data/robots/xarm_description/urdf/xarm7.urdf'


@pytest.mark.slow
def test_an_arm_given_by_its_urdf_file_follows_a_still_hand(nodes, probe):
    """The xArm7 of example-robot-data through urdf_file and tool_frame alone (no gains of
    its own; friction stiff against its wrist): the tool enters follow's region around a
    still hand 0.3 m away within ENTER_TIME and stays; commands within its limits."""
    path = str(metadata.distribution('example-robot-data').locate_file(XARM7))
    model = robot_model(urdf_file=path, tool_frame='link_eef')
    region = load_task_file(paper_tasks_dir() / 'follow.yaml').d2
    inward = np.array([-0.2, 0.15, 0.15]) / np.linalg.norm([-0.2, 0.15, 0.15])
    hand = model.tool_position(model.home) + 0.3 * inward
    sample, efforts, _, controller = run_panda_loop(
        nodes, probe, 'follow', hand, ENTER_TIME + 1.0,
        arm={'urdf_file': path, 'tool_frame': 'link_eef'})
    entered, _, q, held = enters_band_and_stays(model, sample, hand, (0.0, region),
                                                ENTER_TIME, controller)
    step, margin = check_commands_and_limits(model, q, efforts)
    print(f'xArm7 follow: in the region {entered:.2f} s after the first state, farthest '
          f'{held.max():.4f} m of {region} m; largest effort step {step:.3f} N m; nearest '
          f'limit {np.degrees(margin):.1f} deg')


# The arms of hri_core.robot_model.ROBOTS besides the Panda, all slow: `robot:=NAME` end to
# end is the default run's Panda tests (robot:=panda, by name, through the same table), and
# each UR's table entry and derived gains follow a still hand in the pure loop (test_arm_law).
KNOWN_ARMS = [pytest.param(name, marks=pytest.mark.slow)
              for name in ('ur3', 'ur5', 'ur10', 'xarm7', 'z1')]


@pytest.mark.parametrize('robot', KNOWN_ARMS)
def test_an_arm_known_by_name_follows_a_still_hand(nodes, probe, robot):
    """arm_sim and the controller with robot:=NAME alone (URDF, tool frame and gains from the
    table and the URDF): the tool enters follow's region around a still hand 0.3 m away (as
    the xArm7's above) within ENTER_TIME and stays; commands within the limits."""
    model = robot_model(robot)
    region = load_task_file(paper_tasks_dir() / 'follow.yaml').d2
    inward = np.array([-0.2, 0.15, 0.15]) / np.linalg.norm([-0.2, 0.15, 0.15])
    hand = model.tool_position(model.home) + 0.3 * inward
    sample, efforts, _, controller = run_panda_loop(nodes, probe, 'follow', hand,
                                                    ENTER_TIME + 1.0, arm={'robot': robot})
    entered, _, q, held = enters_band_and_stays(model, sample, hand, (0.0, region),
                                                ENTER_TIME, controller)
    step, margin = check_commands_and_limits(model, q, efforts)
    print(f'{robot} follow: in the region {entered:.2f} s after the first state, farthest '
          f'{held.max():.4f} m of {region} m; largest effort step {step:.3f} N m; nearest '
          f'limit {np.degrees(margin):.1f} deg')
