"""Bad messages, files and parameters on topics: rejected or handled, never a crash or a NaN.

The controller runs against a stand-in arm (the test publishes joint states and the hand at a
fixed pose, the end-effector 0.1 m from the hand), so the ControllerState's distance shows
which joint states and targets it used: a bad message that got through would move it. The
event_manager gets invalid tasks, events for unknown tasks and a burst of 1000 events in one
second under the closed loop; task folders with broken files; nodes get out-of-range
parameters at start and at run time. Every float on /effort_controller/commands,
/hri/task_state and /hri/controller_state is checked to be finite.

The controller alone against NaN and short joint states: zero torque, and again once valid
ones go stale. Covered elsewhere: wrong length and non-finite commands to the sim
(test_scara_sim.py), an invalid task replacing the active one and one unknown-task event
(test_event_manager.py), scara_sim's, the recorder's and the learner's run-time and start
parameters (test_scara_sim.py, test_recorder.py, test_learner.py).
"""

import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import ControllerState, TaskEvent, TaskParameters, TaskState
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.duration import Duration
from rclpy.serialization import serialize_message
from rclpy.time import Time as RosTime
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_bringup.processes import wait_for
from hri_core.dynamics import forward_kinematics
from hri_core.node_common import load_defaults, stamp_seconds
from hri_core.robot_model import robot_model
from hri_core.topics import LEARNED_TASKS_QOS, MONITOR_QOS, TASK_STATE_QOS
from tests.common import PAPER_TASKS, REPO_ROOT, call_service, set_parameter, wait_for_service
from tests.fault_tools import REALTIME_PRIORITY, RELIABLE, RawListener, assert_all_finite

pytestmark = pytest.mark.integration

FOLLOW_BAG = REPO_ROOT / 'bags/fixtures/follow'
CONTROLLER_DEFAULTS = load_defaults('hri_adaptive_controller', 'controller')
EFFORT_LIMIT = float(robot_model('scara').limits.effort.max())  # N m, the SCARA's
Q_ARM = [0.3, 1.2]  # rad: the stand-in arm's pose
Q_WRONG = [1.2, 0.3]  # rad: where a message read in the wrong order would put it
HAND_OFFSET = np.array([0.1, 0.0])  # m from the end-effector
HAND_PERIOD = 0.02  # s: the stand-in's hand at 50 Hz
JOINT_PERIOD = 0.005  # s: its joint states at 200 Hz
MIN_COMMANDS_JUDGED = 20
FOLLOW = TaskParameters(name='follow', s=1, a1=1.291, a2=13.66, d1=0.0, d2=0.041, n=3)


def joint_state(probe, names, position, velocity=None, stamp=None) -> JointState:
    msg = JointState(name=list(names), position=[float(v) for v in position],
                     velocity=[0.0] * len(position) if velocity is None
                     else [float(v) for v in velocity])
    msg.header.stamp = probe.now() if stamp is None else stamp
    return msg


def point(probe, xy, stamp=None) -> PointStamped:
    msg = PointStamped()
    msg.header.frame_id = 'base'
    msg.header.stamp = probe.now() if stamp is None else stamp
    msg.point.x, msg.point.y = float(xy[0]), float(xy[1])
    return msg


class StandInArm:
    """The test's arm at Q_ARM: joint states at 200 Hz, the hand at 50 Hz, from a thread.

    hand_at(k): where hand sample k is (None: none is sent, a lost frame); by default the
    hand stays HAND_OFFSET from the end-effector. Sample k is due HAND_PERIOD k s after the
    start: a thread stalled on a loaded machine sends the sample due when it wakes and leaves
    out those it missed, as a tracker drops frames, so a stretch of samples (a glitch) never
    lasts longer than its own samples' time. `sent`: the index of the newest sample;
    `published`: the indices of those published; `stamps`: their stamps (s)."""

    def __init__(self, probe, hand_at=None):
        self.probe = probe
        self.joints = probe.publisher('/joint_states', JointState, 10)
        self.targets = probe.publisher('/target', PointStamped, 10)
        self.hand = forward_kinematics(np.array(Q_ARM), 0.35, 0.30) + HAND_OFFSET
        self.hand_at = hand_at or (lambda k: self.hand)
        self.sent = -1
        self.published: list[int] = []
        self.stamps: list[float] = []
        self.publishing_joints = threading.Event()
        self.publishing_joints.set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        start = time.monotonic()
        while not self._stop.is_set():
            if self.publishing_joints.is_set():
                self.joints.publish(joint_state(self.probe, ['joint1', 'joint2'], Q_ARM))
            due = int((time.monotonic() - start) / HAND_PERIOD)
            if due > self.sent:
                where = self.hand_at(due)
                if where is not None:
                    msg = point(self.probe, where)
                    self.targets.publish(msg)
                    self.stamps.append(stamp_seconds(msg.header.stamp))
                    self.published.append(due)
                self.sent = due
            time.sleep(JOINT_PERIOD)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


@pytest.fixture
def arm(probe):
    stand_in = StandInArm(probe)
    try:
        yield stand_in
    finally:
        stand_in.close()


def start_controller(nodes, probe, **params):
    """The controller on the stand-in arm; returns (process, states, commands)."""
    states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
    commands = RawListener(probe, '/effort_controller/commands', Float64MultiArray)
    controller = nodes('hri_adaptive_controller', 'controller',
                       params={'joint_state_timeout': 0.2, **params})
    assert wait_for(lambda: states and states[-1].status in ('ok', 'no_task_state'), 30.0), \
        controller.log()
    return controller, states, commands


def publish_each(probe, publisher, messages, repeats: int = 10, period: float = 0.01,
                 stamp_back: float = 0.0) -> None:
    """Publish each message `repeats` times, stamped now (the last one `stamp_back` s ago)."""
    for _ in range(repeats):
        for index, message in enumerate(messages):
            stamp = probe.now()
            if index == len(messages) - 1 and stamp_back:
                stamp.sec -= int(math.ceil(stamp_back))
            message.header.stamp = stamp
            publisher.publish(message)
            time.sleep(period)


def assert_used_only_the_arm_pose(states: list) -> None:
    """Every ControllerState computed on the stand-in's pose: distance 0.1 m to the hand."""
    used = [s for s in states if s.status in ('ok', 'no_task_state')]
    assert len(used) > 0.9 * len(states), [s.status for s in states]
    wrong = [s.distance for s in used if abs(s.distance - 0.1) > 1e-9]
    assert not wrong, f'distances that come from a bad message: {wrong[:5]}'


def assert_commands_safe(listener: RawListener) -> None:
    """Every command the probe took is finite and within the effort limit, and there are
    enough of them to say so. How many there are is not the behaviour judged: the controller
    answers each joint state of the stand-in arm, whose thread (in this test process, beside
    other tests) reaches its 200 Hz only on a quiet machine: a fresh-clone run of 2026-12-02
    took exactly 100 commands in one test, where the bound was more than 100."""
    commands = listener.messages()
    assert len(commands) >= MIN_COMMANDS_JUDGED, len(commands)
    assert_all_finite(commands, '/effort_controller/commands')
    assert all(len(c.data) == 2 and max(abs(v) for v in c.data) <= EFFORT_LIMIT + 1e-9
               for c in commands)


def test_bad_joint_states_give_zero_torque_without_crash(nodes, probe):
    """NaN joint states are dropped; before any valid one no command goes out (the arm's
    brakes hold it), after valid ones that went stale the torque is zero (the SCARA's
    gravity hold)."""
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
        joints.publish(serialize_message(bad)[:30])  # bytes no JointState reader can take
        time.sleep(0.025)
    assert wait_for(lambda: len(states) > 20, 10.0)
    assert controller.alive()
    assert all(s.status in ('no_joint_states', 'stale_joint_states', 'no_target')
               for s in states[-10:])
    assert not commands  # no valid joint state yet: nothing commanded
    assert all(s.status == 'no_joint_states' for s in states[-10:])
    log = controller.log()
    assert 'non-finite' in log and 'joint state dropped: unreadable' in log
    assert 'Traceback' not in log
    # Valid but then stale joint states: zero torque again after joint_state_timeout.
    good = JointState(name=['joint2', 'joint1'], position=[1.5, 0.0], velocity=[0.0, 0.0])
    good.header.stamp = probe.now()
    joints.publish(good)
    time.sleep(0.5)
    assert states[-1].status in ('stale_joint_states', 'no_task_state')
    assert wait_for(lambda: states[-1].status == 'stale_joint_states', 5.0)
    assert commands and all(list(c.data) == [0.0, 0.0] for c in commands[-50:])


def test_the_panda_is_held_against_gravity_while_its_joint_states_are_stale(nodes, probe):
    """An arm under gravity is not dropped when its joint states stop: after
    joint_state_timeout the controller commands the gravity torque at the last joint state
    with its theta_hat (eq. 18 at rest) within the effort limits, reached at most 1 N m a
    command, never zero."""
    model = robot_model('panda')
    states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
    commands = probe.collect('/effort_controller/commands', Float64MultiArray, RELIABLE)
    controller = nodes('hri_adaptive_controller', 'controller',
                       params={'robot': 'panda', 'joint_state_timeout': 0.05})
    joints = probe.publisher('/joint_states', JointState, 10)
    assert wait_for(lambda: joints.get_subscription_count() > 0, 20.0), controller.log()
    q = model.home + np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.2, 0.1])
    for _ in range(40):  # 0.2 s of a still arm at 200 Hz: no target, the arm is held
        msg = JointState(name=list(model.joint_names), position=q.tolist(),
                         velocity=[0.0] * model.dof)
        msg.header.stamp = probe.now()
        joints.publish(msg)
        time.sleep(0.005)
    held_from = len(commands)
    assert wait_for(lambda: len(states) > 0 and states[-1].status == 'stale_joint_states',
                    5.0), controller.log()
    # theta_hat adapted while the states came (the null space pulled towards home): the
    # hold is the gravity of the estimate the controller reports, not the URDF's.
    zero = np.zeros(model.dof)
    gravity = model.regressor(q, zero, zero, zero) @ np.array(states[-1].theta_hat)
    assert np.abs(gravity).max() > 5.0  # a hold worth keeping
    # Scaled as a whole into the effort limits where it exceeds one (the wrist's 12 N m:
    # 12.03 N m of gravity with the estimate one loaded run had adapted to).
    gravity = gravity / max(1.0, float(np.max(np.abs(gravity) / model.limits.effort)))
    assert wait_for(lambda: np.allclose(commands[-1].data, gravity, atol=1e-6), 5.0), (
        list(commands[-1].data), gravity.tolist())
    # The report comes on its own schedule: the one after the command reached the hold says so
    # (on a loaded machine the last report received was still the first stale cycle's).
    assert wait_for(lambda: np.allclose(states[-1].effort, gravity, atol=1e-6), 5.0), (
        list(states[-1].effort), gravity.tolist())
    held = np.array([c.data for c in list(commands)[held_from:]])
    assert np.all(np.isfinite(held)) and np.all(np.abs(held) <= model.limits.effort + 1e-9)
    assert not np.any(np.all(held == 0.0, axis=1))  # never zero torque on the way
    assert np.abs(np.diff(held, axis=0)).max() <= 1.0 + 1e-9
    assert 'holding against gravity: stale joint states' in controller.log()
    assert 'Traceback' not in controller.log()


def test_controller_maps_joints_by_name_and_drops_bad_joint_states(nodes, probe, arm):
    controller, states, commands = start_controller(nodes, probe)
    first = len(states)
    names = ['joint1', 'joint2']
    bad = [
        joint_state(probe, names, [math.nan, Q_WRONG[1]]),
        joint_state(probe, names, Q_WRONG, velocity=[math.inf, 0.0]),
        joint_state(probe, names, [-math.inf, Q_WRONG[1]]),
        joint_state(probe, names, Q_WRONG[:1]),                        # 2 names, 1 position
        joint_state(probe, names, Q_WRONG, velocity=[0.0]),            # 1 velocity
        joint_state(probe, names, [*Q_WRONG, 0.0]),                    # 3 positions
        joint_state(probe, ['shoulder', 'elbow'], Q_WRONG),            # unknown names
        joint_state(probe, ['joint1', 'joint1'], Q_WRONG),             # joint2 missing
        joint_state(probe, ['joint1', 'joint3'], Q_WRONG),
        joint_state(probe, [], []),
        joint_state(probe, names, Q_WRONG),                            # stamped 1 s back
    ]
    publish_each(probe, arm.joints, bad, stamp_back=1.0)
    # Joints are taken by name: reordered, or among other joints, they give the same pose.
    arm.publishing_joints.clear()
    time.sleep(0.05)
    reordered_from = len(states)
    for i in range(100):
        order = (['joint2', 'joint1'], [Q_ARM[1], Q_ARM[0]]) if i % 2 else \
            (['gripper', 'joint2', 'joint0', 'joint1'], [0.7, Q_ARM[1], -2.0, Q_ARM[0]])
        arm.joints.publish(joint_state(probe, *order))
        time.sleep(0.005)
    reordered = states[reordered_from:]
    arm.publishing_joints.set()
    time.sleep(0.3)
    window = states[first:]
    assert len(reordered) > 20
    # Reordered joints are used (no_task_state: pose known, no task). A stall of this test's
    # publisher on a loaded machine may leave a few cycles with stale joint states, never
    # most: a controller that dropped the reordered messages would be stale after 0.2 s.
    statuses = [s.status for s in reordered]
    assert set(statuses) <= {'no_task_state', 'stale_joint_states'}, statuses
    assert statuses.count('no_task_state') >= 0.8 * len(statuses), statuses
    assert_used_only_the_arm_pose(window)
    assert_all_finite(states, '/hri/controller_state')
    assert_commands_safe(commands)
    assert controller.alive()
    log = controller.log()
    for reason in ('non-finite position or velocity', 'positions', 'lack joint1, joint2',
                   'stamp went back'):
        assert reason in log, (reason, log)
    warnings = [line for line in log.splitlines() if 'WARN' in line]
    assert len(warnings) < 15, warnings  # throttled: a few lines, not one per message
    assert 'Traceback' not in log


def test_controller_follows_a_restarted_joint_state_source(nodes, probe, arm):
    # The stand-in arm stops; a new source starts with stamps 30 s behind its last ones (a
    # simulator whose clock starts again). The first restart_confirm - 1 of them are dropped
    # as stale, then the controller follows the new source: it uses the new pose (distance
    # to the hand no longer 0.1 m).
    controller, states, commands = start_controller(nodes, probe)
    arm.publishing_joints.clear()
    time.sleep(0.05)
    behind = RosTime.from_msg(probe.now()) - Duration(seconds=30.0)
    restarted_from = len(states)
    for i in range(60):
        stamp = (behind + Duration(nanoseconds=5_000_000 * i)).to_msg()
        arm.joints.publish(joint_state(probe, ['joint1', 'joint2'], Q_WRONG, stamp=stamp))
        time.sleep(0.005)
    assert wait_for(lambda: 'joint states restarted' in controller.log(), 5.0), \
        controller.log()
    new_pose = [s for s in states[restarted_from:] if s.status in ('ok', 'no_task_state')
                and abs(s.distance - 0.1) > 1e-6]
    assert len(new_pose) >= 5, [(s.status, s.distance) for s in states[restarted_from:]]
    # Before the restart was confirmed the stale states were dropped (one throttled warning).
    assert 'stamp went back' in controller.log()
    arm.publishing_joints.set()  # the old source again: far ahead, used at once
    time.sleep(0.5)
    assert_all_finite(states, '/hri/controller_state')
    assert_commands_safe(commands)
    assert controller.alive()


def test_controller_drops_bad_targets_and_task_states(nodes, probe, arm):
    controller, states, commands = start_controller(nodes, probe, max_target_distance=1.0)
    task_states = probe.publisher('/hri/task_state', TaskState, TASK_STATE_QOS)
    good_task = TaskState(task=FOLLOW, weight=1.0, weight_rate=0.0, phase='active')
    stop = threading.Event()

    def keep_task_state() -> None:  # a valid TaskState at 20 Hz, as an event_manager would
        while not stop.is_set():
            good_task.header.stamp = probe.now()
            task_states.publish(good_task)
            time.sleep(0.05)

    feeder = threading.Thread(target=keep_task_state, daemon=True)
    feeder.start()
    try:
        assert wait_for(lambda: states[-1].status == 'ok' and states[-1].weight == 1.0, 10.0), \
            states[-1]
        first = len(states)
        bad_targets = [point(probe, [math.nan, 0.2]), point(probe, [0.3, math.inf]),
                       point(probe, [1.5, 0.0]),  # beyond max_target_distance
                       point(probe, [-0.2, 0.1])]  # stamped 5 s back
        publish_each(probe, arm.targets, bad_targets, stamp_back=5.0)
        # Bytes no PointStamped reader can take, as a raw publisher may send them. The
        # stand-in's hand shares the topic: a controller held up beside a busy process past
        # its /target queue missed both for later hand samples (a fresh-clone run, when the
        # queue held one), so they go again until it has said why it dropped them.
        unreadable = (serialize_message(point(probe, [0.3, 0.1]))[:20], b'\x00\x01\x00\x00')
        deadline = time.monotonic() + 5.0
        while ('target dropped: unreadable' not in controller.log()
               and time.monotonic() < deadline):
            for data in unreadable:
                arm.targets.publish(data)
                time.sleep(0.01)

        def task(**fields) -> TaskParameters:
            values = {'name': 'follow', 's': 1, 'a1': 1.291, 'a2': 13.66, 'd1': 0.0,
                      'd2': 0.041, 'n': 3, **fields}
            return TaskParameters(**values)

        bad_states = [TaskState(task=FOLLOW, weight=math.nan, phase='active'),
                      TaskState(task=FOLLOW, weight=1.5, phase='active'),
                      TaskState(task=FOLLOW, weight=-0.1, phase='active'),
                      TaskState(task=FOLLOW, weight=0.5, weight_rate=math.inf,
                                phase='fading_in'),
                      TaskState(task=task(name='broken', s=0), weight=0.5, phase='active'),
                      TaskState(task=task(name='broken', a1=-1.0), weight=0.5, phase='active'),
                      TaskState(task=task(name='broken', d1=0.3, d2=0.1), weight=0.5,
                                phase='active'),
                      TaskState(task=task(name='broken', n=2), weight=0.5, phase='active'),
                      TaskState(task=task(name='broken', a2=math.nan), weight=0.5,
                                phase='active')]
        publish_each(probe, task_states, bad_states)
        time.sleep(0.3)
    finally:
        stop.set()
        feeder.join(timeout=2.0)
    window = states[first:]
    assert_used_only_the_arm_pose(window)
    # Bad targets and task states change nothing: every controlled cycle keeps the good task
    # (a few cycles may find the joint states stale when this machine is loaded).
    statuses = [s.status for s in window]
    assert set(statuses) <= {'ok', 'stale_joint_states'}, statuses
    assert statuses.count('ok') >= 0.9 * len(statuses), statuses
    assert all(s.weight == 1.0 and s.task == 'follow' for s in window if s.status == 'ok'), \
        {(s.status, s.weight, s.task) for s in window}
    assert_all_finite(states, '/hri/controller_state')
    assert_commands_safe(commands)
    assert controller.alive()
    log = controller.log()
    for reason in ('target dropped: non-finite', 'farther than max_target_distance',
                   'target dropped: unreadable',
                   'target dropped: stamp did not advance', 'task state dropped: weight',
                   "task state dropped: task 'broken'"):
        assert reason in log, (reason, log)
    assert 'Traceback' not in log


INVALID_TASKS = {
    's_two': {'s': 2}, 's_zero': {'s': 0}, 'a1_zero': {'a1': 0.0}, 'a2_negative': {'a2': -1.0},
    'd1_above_d2': {'d1': 0.3, 'd2': 0.1}, 'd1_negative': {'d1': -0.1}, 'n_two': {'n': 2},
    'a1_nan': {'a1': math.nan}, 'd2_inf': {'d2': math.inf}, 'cost_negative': {'cost': -1.0},
}


def test_event_manager_rejects_invalid_tasks_and_events_for_unknown_tasks(nodes, probe):
    states = probe.collect('/hri/task_state', TaskState, TASK_STATE_QOS)
    manager = nodes('hri_adaptive_controller', 'event_manager', params={
        'tasks_dir': str(PAPER_TASKS), 'initial_task': 'follow', 'ramp_time': 0.3})
    assert wait_for(lambda: states and states[-1].phase == 'active', 20.0), manager.log()
    tasks = probe.publisher('/hri/task', TaskParameters, LEARNED_TASKS_QOS)
    events = probe.publisher('/hri/events', TaskEvent, 100)
    assert wait_for(lambda: tasks.get_subscription_count() > 0
                    and events.get_subscription_count() > 0, 10.0)
    first = len(states)
    for name, fields in INVALID_TASKS.items():
        values = {'name': name, 's': 1, 'a1': 1.0, 'a2': 10.0, 'd1': 0.0, 'd2': 0.05, 'n': 3,
                  'cost': 0.0, 'iterations': 1, **fields}
        tasks.publish(TaskParameters(**values))
    for name in ('', '../escape', 'a b'):
        tasks.publish(TaskParameters(name=name, s=1, a1=1.0, a2=10.0, d1=0.0, d2=0.05, n=3))
    time.sleep(0.5)
    # None was stored: an event for any of them is an event for an unknown task.
    for name in [*INVALID_TASKS, 'no_such_task', '../escape']:
        events.publish(TaskEvent(name=f'go_{name}', task=name))
        time.sleep(0.01)
    time.sleep(0.5)
    window = states[first:]
    assert window and all(s.phase == 'active' and s.task.name == 'follow' and s.weight == 1.0
                          for s in window), {(s.phase, s.task.name) for s in window}
    assert_all_finite(states, '/hri/task_state')
    assert manager.alive()
    log = manager.log()
    assert 'on /hri/task rejected' in log and 'names unknown task' in log
    assert 'Traceback' not in log
    # A valid task still gets in after all that.
    tasks.publish(TaskParameters(name='s_two', s=-1, a1=1.0, a2=10.0, d1=0.0, d2=0.05, n=3))
    assert wait_for(lambda: "task 's_two' added" in manager.log(), 5.0), manager.log()


@pytest.mark.exclusive
def test_a_burst_of_1000_events_in_one_second_under_the_closed_loop(live_loop, probe):
    task_states = probe.collect('/hri/task_state', TaskState, TASK_STATE_QOS)
    states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
    commands = RawListener(probe, '/effort_controller/commands', Float64MultiArray)
    ramp_time = 0.5
    # The sim and the controller at SCHED_FIFO, as on a robot's computer: the burst and the
    # event_manager's backlog load both cores, and at normal priority the joint states then
    # stopped for over joint_state_timeout now and then, also after the burst (ci80). What is
    # judged here is the handling of the events.
    realtime = {'realtime_priority': REALTIME_PRIORITY}
    processes = live_loop({'event_manager': {'ramp_time': ramp_time},
                           'hand_sim': {'profile': 'circle', 'period': 4.0},
                           'scara_sim': realtime, 'controller': realtime})
    manager, controller = processes['event_manager'], processes['controller']
    assert wait_for(lambda: states and states[-1].status == 'ok', 30.0), controller.log()
    events = probe.publisher('/hri/events', TaskEvent, RELIABLE)
    assert wait_for(lambda: events.get_subscription_count() > 0, 10.0)
    first_state, first_task_state = len(states), len(task_states)
    names = ('avoid', 'follow_safe', 'follow', 'unknown', 'avoid', '')
    started = time.monotonic()
    for i in range(1000):
        events.publish(TaskEvent(name=f'burst{i}', task=names[i % len(names)]))
        time.sleep(max(0.0, started + (i + 1) / 1000.0 - time.monotonic()))
    burst_seconds = time.monotonic() - started
    events.publish(TaskEvent(name='last', task='follow_safe'))
    assert wait_for(lambda: task_states[-1].task.name == 'follow_safe'
                    and task_states[-1].phase == 'active'
                    and states[-1].task == 'follow_safe' and states[-1].weight == 1.0, 20.0), \
        (task_states[-1], states[-1], manager.log())
    print(f'1000 events in {burst_seconds:.2f} s')
    assert burst_seconds < 2.5  # 1 s when the test process is not starved
    burst = task_states[first_task_state:]
    assert all(0.0 <= s.weight <= 1.0 for s in burst)
    stamps = np.array([stamp_seconds(s.header.stamp) for s in burst])
    weights = np.array([s.weight for s in burst])
    # Overlapping ramps add their rates (event_weight's bound: 2 x 15/8 per ramp_time/2).
    assert np.all(np.abs(np.diff(weights)) <= 2 * 15 / 8 / (ramp_time / 2) * np.diff(stamps)
                  + 0.02)
    assert all(0.0 <= s.weight <= 1.0 for s in states[first_state:])
    assert_all_finite(task_states, '/hri/task_state')
    assert_all_finite(states, '/hri/controller_state')
    assert_commands_safe(commands)
    # No fault; on a loaded machine the 1 kHz joint states may pause for longer than the
    # controller's joint_state_timeout now and then (the burst itself loads both cores: 55 of
    # 158 states were stale once in a fresh-clone run): zero torque for that long, as it
    # should, and control back once the burst is over.
    # The same for the hand: once (a fresh-clone run) the controller reported target_lost for
    # 18 of 311 states, no /target accepted within target_timeout (0.5 s) of the joint states'
    # stamps while the burst loaded both cores; the task fades out then, as it should.
    statuses = [s.status for s in states[first_state:]]
    print(f'controller status during the burst: { {k: statuses.count(k) for k in set(statuses)} }')
    assert set(statuses) <= {'ok', 'stale_joint_states', 'target_lost'}, \
        (set(statuses), controller.log()[-3000:])
    settled = len(states)
    assert wait_for(lambda: len(states) > settled + 50, 10.0)
    after = [s.status for s in states[settled:]]
    assert all(status == 'ok' for status in after), (len(after), [
        (i, status) for i, status in enumerate(after) if status != 'ok'])
    assert manager.alive() and controller.alive()
    assert 'Traceback' not in manager.log() + controller.log()


BAD_TASK_FILES = {
    'not_yaml.yaml': 'name: [unclosed\ns: 1\n',
    'missing_keys.yaml': 'name: missing_keys\ns: 1\na1: 1.0\n',
    'bad_s.yaml': 'name: bad_s\ns: 2\na1: 1.0\na2: 10.0\nd1: 0.0\nd2: 0.05\nn: 3\ncost: 0.0\n'
                  'iterations: 1\n',
    'bad_region.yaml': 'name: bad_region\ns: 1\na1: 1.0\na2: 10.0\nd1: 0.3\nd2: 0.05\nn: 3\n'
                       'cost: 0.0\niterations: 1\n',
    'bad_a.yaml': 'name: bad_a\ns: 1\na1: -1.0\na2: 10.0\nd1: 0.0\nd2: 0.05\nn: 3\n'
                  'cost: 0.0\niterations: 1\n',
    'bad_n.yaml': 'name: bad_n\ns: 1\na1: 1.0\na2: 10.0\nd1: 0.0\nd2: 0.05\nn: 2\n'
                  'cost: 0.0\niterations: 1\n',
    'other_name.yaml': (PAPER_TASKS / 'avoid.yaml').read_text(),
    'a_list.yaml': '- 1\n- 2\n',
    'empty.yaml': '',
}


def test_event_manager_skips_bad_task_files_and_starts_with_the_good_ones(nodes, probe,
                                                                          tmp_path):
    folder = tmp_path / 'tasks'
    folder.mkdir()
    for name in ('follow', 'follow_safe'):
        (folder / f'{name}.yaml').write_text((PAPER_TASKS / f'{name}.yaml').read_text())
    for name, text in BAD_TASK_FILES.items():
        (folder / name).write_text(text)
    (folder / 'binary.yaml').write_bytes(b'\xff\xfe\x00garbage')
    states = probe.collect('/hri/task_state', TaskState, TASK_STATE_QOS)
    manager = nodes('hri_adaptive_controller', 'event_manager',
                    params={'tasks_dir': str(folder), 'initial_task': 'follow'})
    nowhere = nodes('hri_adaptive_controller', 'event_manager',
                    params={'tasks_dir': str(tmp_path / 'missing')},
                    remaps={'__node': 'event_manager_nowhere'})
    assert wait_for(lambda: any(s.task.name == 'follow' and s.phase == 'active'
                                for s in states), 30.0), manager.log()
    log = manager.log()
    rejected = [line for line in log.splitlines() if 'WARN' in line and 'rejected' in line]
    assert sorted(Path(line.split('task file ')[1].split(' rejected')[0]).name
                  for line in rejected) == sorted([*BAD_TASK_FILES, 'binary.yaml']), log
    assert '2 task(s) loaded (follow, follow_safe)' in log
    assert 'Traceback' not in log
    assert wait_for(lambda: 'task(s) loaded' in nowhere.log(), 20.0), nowhere.log()
    assert nowhere.alive()
    assert '0 task(s) loaded' in nowhere.log() and 'WARN' in nowhere.log()


# One bad value per node at start: (package, executable, parameters, expected in the line).
BAD_START_PARAMETERS = [
    ('scara_sim', 'scara_sim', {'effort_limit': -5.0}, 'effort_limit'),
    ('scara_sim', 'scara_sim', {'joint_lower_limits': [0.0, 3.0]}, 'must be below'),
    ('scara_sim', 'hand_sim', {'rate_hz': -10.0}, 'rate_hz'),
    ('scara_sim', 'demonstrator', {'stiffness': -1.0}, 'stiffness'),
    ('hri_demo_learning', 'recorder', {'flush_period': -0.5}, 'flush_period'),
    ('hri_demo_learning', 'learner', {'bags': [str(FOLLOW_BAG)], 'max_iterations': -1},
     'max_iterations'),
    ('hri_adaptive_controller', 'event_manager', {'ramp_time': -1.0}, 'ramp_time'),
    ('hri_adaptive_controller', 'event_manager', {'publish_rate_hz': 10.0}, 'publish_rate_hz'),
    ('hri_adaptive_controller', 'controller', {'kp': -1.0}, 'kp'),
    ('hri_adaptive_controller', 'controller', {'effort_limit': -5.0}, 'effort_limit'),
    ('hri_adaptive_controller', 'controller', {'ks': [-1.0, 4.0]}, 'ks'),
    ('hri_adaptive_controller', 'controller', {'rate_hz': 100}, 'decimal point'),
]


def test_out_of_range_parameters_are_refused_at_start_with_one_line(nodes, tmp_path):
    started = []
    for index, (package, executable, params, reason) in enumerate(BAD_START_PARAMETERS):
        if executable == 'recorder':
            params = {'output': str(tmp_path / f'bag{index}'), **params}
        if executable == 'learner':
            params = {'output_dir': str(tmp_path / 'tasks'), 'once': True, **params}
        started.append((nodes(package, executable, params=params), params, reason))
    failures = []
    for process, params, reason in started:
        code = process.wait(40.0)
        log = process.log()
        lines = [line for line in log.splitlines() if line.strip()]
        problems = [line for line in lines if 'ERROR' in line or 'FATAL' in line]
        if code in (None, 0) or 'Traceback' in log or len(problems) != 1 \
                or reason not in problems[0]:
            failures.append((process.name, params, code, log))
        else:
            print(f'{process.name} {params}: exit {code}: {problems[0]}')
    assert not failures, failures
    assert not list(tmp_path.glob('bag*')) and not (tmp_path / 'tasks').exists()


def test_out_of_range_parameters_are_refused_at_run_time(nodes, probe):
    controller = nodes('hri_adaptive_controller', 'controller')
    manager = nodes('hri_adaptive_controller', 'event_manager',
                    params={'tasks_dir': str(PAPER_TASKS)})
    clients = {name: probe.node.create_client(SetParameters, f'/{name}/set_parameters')
               for name in ('controller', 'event_manager')}
    for client in clients.values():
        assert wait_for_service(client, 30.0), (controller.log(), manager.log())
    refused = {
        'controller': [('kp', -1.0), ('effort_limit', -5.0), ('ks', [1.0]), ('ks', [-1.0, 4.0]),
                       ('adaptation_gain', [-1.0] * 7), ('max_task_speed', 0.0),
                       ('kp', math.nan), ('kp', 'fast'), ('rate_hz', 500.0)],
        'event_manager': [('ramp_time', 100.0), ('ramp_time', -1.0), ('ramp_time', 0.01),
                          ('heartbeat_period', 0.0), ('publish_rate_hz', 50.0)],
    }
    for node, changes in refused.items():
        for name, value in changes:
            result = set_parameter(clients[node], name, value)
            assert not result.successful, (node, name, value)
            assert result.reason, (node, name, value)
            print(f'{node} {name}={value!r} refused: {result.reason}')
    getter = probe.node.create_client(GetParameters, '/controller/get_parameters')
    assert wait_for_service(getter, 10.0)
    values = call_service(getter, GetParameters.Request(names=['kp', 'effort_limit'])).values
    # Unchanged by the refusals (effort_limit 0: no cap on the robot's own limits).
    assert [values[0].double_value, values[1].double_value] == [10.0, 0.0]
    # Valid values still go through.
    assert set_parameter(clients['controller'], 'kp', 5.0).successful
    assert set_parameter(clients['controller'], 'effort_limit', 10.0).successful
    assert set_parameter(clients['event_manager'], 'ramp_time', 2.0).successful
    for process in (controller, manager):
        assert process.alive()
        assert 'Traceback' not in process.log()
    assert 'gains changed' in controller.log()
