"""Topic-level tests of the `recorder` node: lossless 1 kHz recording, crash safety, refusals."""

import signal
import time

import pytest
from geometry_msgs.msg import PointStamped, WrenchStamped
from hri_interfaces.msg import TaskParameters
from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from hri_bringup.processes import wait_for
from hri_core.robot_model import robot_model
from hri_demo_learning.bag_io import read_bag, read_demonstration

pytestmark = pytest.mark.integration

RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# s of 1 kHz publishing: 8,000 messages, enough to fall behind on a loaded machine (longer
# runs and the recorder's rate are bench/bench_recorder.py's).
RUN_TIME = 4.0
# Deep enough to keep every message of the run for repair (a KEEP_ALL writer would block,
# then drop, once its history fills between two acknowledgements).
LOSSLESS = QoSProfile(depth=20_000, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST)


def joint_state(index: int) -> JointState:
    msg = JointState(name=['joint1', 'joint2'], position=[index * 1e-3, -index * 1e-3],
                     velocity=[1.0, -1.0], effort=[0.0, 0.5])
    msg.header.frame_id = str(index)
    return msg


def point(x: float, y: float, frame: str = 'base_link') -> PointStamped:
    msg = PointStamped()
    msg.header.frame_id = frame
    msg.point.x, msg.point.y = x, y
    return msg


def log_of(process) -> str:
    """The process's output so far, also after stop() (which closes NodeProcess's log file)."""
    return process.log_path.read_text(errors='replace')


def wait_subscribed(publishers, recorder, timeout: float = 15.0) -> None:
    assert wait_for(lambda: all(p.get_subscription_count() > 0 for p in publishers), timeout), \
        f'the recorder did not subscribe to every topic; its log:\n{log_of(recorder)}'


def publish_at(rate_hz: float, seconds: float, step) -> int:
    """Call step(i) at rate_hz on an absolute schedule for `seconds`; return the count."""
    period = 1.0 / rate_hz
    start = time.perf_counter()
    count = 0
    while time.perf_counter() - start < seconds:
        step(count)
        count += 1
        delay = start + count * period - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    return count


# The test's publishers are reliable and keep every message for repair, so that nothing is
# lost before the recorder (a shallow or best-effort publisher may drop messages on a loaded
# machine, which is no loss of the recorder's): every message published must be in the bag.
# Robust to load (it waits for the recorder to catch up), so it runs in the parallel phase.
def test_records_every_topic_at_1khz_without_loss(nodes, probe, tmp_path):
    bag = tmp_path / 'demo'
    reference = probe.publisher('/demo/reference', PointStamped, LATCHED)
    reference.publish(point(0.4, 0.1, 'reference'))  # before the recorder: transient local
    recorder = nodes('hri_demo_learning', 'recorder', params={'output': str(bag)})
    joints = probe.publisher('/joint_states', JointState, LOSSLESS)
    positions = probe.publisher('/ee_position', PointStamped, LOSSLESS)
    target = probe.publisher('/target', PointStamped, LOSSLESS)
    wrench = probe.publisher('/human/wrench', WrenchStamped, LOSSLESS)
    wait_subscribed([reference, joints, positions, target, wrench], recorder)
    time.sleep(0.3)

    def step(i: int) -> None:
        joints.publish(joint_state(i))
        positions.publish(point(i * 1e-4, 0.2, str(i)))
        if i % 20 == 0:
            target.publish(point(0.5, i * 1e-5, str(i)))
            message = WrenchStamped()
            message.header.frame_id = str(i)
            message.wrench.force.x = float(i)
            wrench.publish(message)

    published_from = time.time_ns()
    count = publish_at(1000.0, RUN_TIME, step)
    # A starved recorder may lag behind; what it has acknowledged it must write, and it
    # acknowledges everything once it has caught up (the rate is bench_recorder's business).
    for publisher in (joints, positions, target, wrench):
        assert publisher.wait_for_all_acked(Duration(seconds=60.0)), log_of(recorder)
    acknowledged_by = time.time_ns()
    assert recorder.stop(timeout=10.0) == 0, log_of(recorder)
    assert (bag / 'metadata.yaml').is_file()
    contents = read_bag(bag)
    slow = len(range(0, count, 20))
    assert contents.counts() == {'/joint_states': count, '/ee_position': count,
                                 '/demo/reference': 1, '/target': slow, '/human/wrench': slow}
    recorded = contents.topics['/joint_states'].messages
    assert [m.header.frame_id for m in recorded] == [str(i) for i in range(count)]
    assert [list(m.position) for m in recorded[:3]] == [[0.0, -0.0], [1e-3, -1e-3],
                                                        [2e-3, -2e-3]]
    assert list(recorded[-1].name) == ['joint1', 'joint2']
    assert [m.point.x for m in contents.topics['/ee_position'].messages] == \
        [i * 1e-4 for i in range(count)]
    assert contents.topics['/demo/reference'].messages[0].point.x == 0.4
    assert [m.wrench.force.x for m in contents.topics['/human/wrench'].messages] == \
        [float(i) for i in range(0, count, 20)]
    assert contents.topics['/target'].msgtype == 'geometry_msgs/msg/PointStamped'
    stamps = contents.topics['/joint_states'].timestamps_ns
    assert all(b >= a for a, b in zip(stamps, stamps[1:], strict=False))
    # Receive times: after the first message was sent, before the last acknowledgement.
    assert published_from <= stamps[0] and stamps[-1] <= acknowledged_by
    assert f'/joint_states: {count}' in log_of(recorder)


def test_sigkill_loses_at_most_the_last_second(nodes, probe, tmp_path):
    bag = tmp_path / 'killed'
    reference = probe.publisher('/demo/reference', PointStamped, LATCHED)
    reference.publish(point(0.4, 0.1))
    recorder = nodes('hri_demo_learning', 'recorder', params={
        'output': str(bag), 'topics': ['/joint_states', '/ee_position', '/demo/reference']})
    joints = probe.publisher('/joint_states', JointState, RELIABLE)
    positions = probe.publisher('/ee_position', PointStamped, RELIABLE)
    wait_subscribed([reference, joints, positions], recorder)
    time.sleep(0.3)
    sent_at: list[float] = []
    killed: list[float] = []

    # The kill comes 3.5 s after the first message, however many a loaded machine let this
    # process send by then.
    def step(i: int) -> None:
        sent_at.append(time.monotonic())
        joints.publish(joint_state(i))
        positions.publish(point(0.3 + i * 1e-4, 0.2, str(i)))
        if not killed and sent_at[-1] - sent_at[0] >= 3.5:
            recorder.send(signal.SIGKILL)
            killed.append(time.monotonic())

    publish_at(1000.0, 3.7, step)
    if not killed:  # a stall of this process spanned the 3.5 s mark and the loop's end
        recorder.send(signal.SIGKILL)
        killed.append(time.monotonic())
    killed_at = killed[0]
    assert recorder.wait(5.0) == -signal.SIGKILL
    assert not (bag / 'metadata.yaml').exists()
    contents = read_bag(bag)
    assert contents.recovered
    frames = [int(m.header.frame_id) for m in contents.topics['/joint_states'].messages]
    assert frames == list(range(len(frames)))  # nothing lost before the tail
    last_kept = frames[-1]
    assert killed_at - sent_at[last_kept] <= 1.0, (
        f'lost {killed_at - sent_at[last_kept]:.2f} s before the kill')
    demo = read_demonstration(bag)
    assert demo.recovered
    assert demo.position_source == '/ee_position'
    assert demo.times[-1] >= 3.5 - 1.0 - 0.1
    assert tuple(demo.references[-1]) == (0.4, 0.1, 0.0)


def test_sigterm_closes_the_bag_and_custom_types_are_recorded(nodes, probe, tmp_path):
    bag = tmp_path / 'tasks'
    task = probe.publisher('/hri/task', TaskParameters, QoSProfile(
        depth=16, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    recorder = nodes('hri_demo_learning', 'recorder', params={
        'output': str(bag), 'topics': ['/hri/task'], 'flush_period': 0.2})
    wait_subscribed([task], recorder)
    time.sleep(0.3)
    for index in range(5):
        task.publish(TaskParameters(name=f'task{index}', s=1, a1=1.5, a2=2.5, d1=0.1,
                                    d2=0.2 + index, n=3, cost=1e-3, iterations=index))
    time.sleep(1.0)
    assert recorder.stop(timeout=10.0, sig=signal.SIGTERM) == 0, log_of(recorder)
    assert (bag / 'metadata.yaml').is_file()
    messages = read_bag(bag).topics['/hri/task'].messages
    assert [m.name for m in messages] == [f'task{i}' for i in range(5)]
    assert [m.d2 for m in messages] == [0.2 + i for i in range(5)]
    assert 'closed bag' in log_of(recorder)


def test_records_the_robot_description_published_before_it_started(nodes, probe, tmp_path):
    """The bag carries its robot: the URDF latched on /robot_description (as arm_sim and
    robot_state_publisher publish it, once) reaches a recorder started after it, by default."""
    panda = robot_model('panda')
    bag = tmp_path / 'panda'
    description = probe.publisher('/robot_description', String, LATCHED)
    description.publish(String(data=panda.urdf))
    reference = probe.publisher('/demo/reference', PointStamped, LATCHED)
    reference.publish(point(0.4, 0.1, 'base'))
    recorder = nodes('hri_demo_learning', 'recorder', params={'output': str(bag)})
    joints = probe.publisher('/joint_states', JointState, LOSSLESS)
    wait_subscribed([description, reference, joints], recorder)
    time.sleep(0.3)
    for index in range(50):
        joints.publish(JointState(name=list(panda.joint_names), position=list(panda.home),
                                  velocity=[0.0] * 7, effort=[0.0] * 7))
        time.sleep(0.002 if index else 0.0)
    assert joints.wait_for_all_acked(Duration(seconds=30.0)), log_of(recorder)
    assert recorder.stop(timeout=10.0) == 0, log_of(recorder)
    assert 'recording /robot_description (std_msgs/msg/String, reliable, transient_local' in \
        log_of(recorder)
    contents = read_bag(bag)
    assert contents.counts() == {'/robot_description': 1, '/demo/reference': 1,
                                 '/joint_states': 50}
    assert contents.topics['/robot_description'].messages[0].data == panda.urdf
    demo = read_demonstration(bag)  # no /ee_position: the tool path through the bag's URDF
    assert (demo.position_source, demo.robot) == ('/joint_states', 'panda')
    assert demo.positions[0].tolist() == pytest.approx(panda.tool_position(panda.home).tolist(),
                                                       abs=1e-12)


def test_refuses_to_overwrite_an_existing_output(nodes, tmp_path):
    bag = tmp_path / 'taken'
    bag.mkdir()
    (bag / 'keep.txt').write_text('precious')
    recorder = nodes('hri_demo_learning', 'recorder', params={'output': str(bag)})
    code = recorder.wait(20.0)
    log = log_of(recorder)
    assert code not in (None, 0), log
    errors = [line for line in log.splitlines() if 'ERROR' in line]
    assert len(errors) == 1 and 'exists already; refusing to overwrite' in errors[0], log
    assert 'Traceback' not in log
    assert sorted(p.name for p in bag.iterdir()) == ['keep.txt']
    assert (bag / 'keep.txt').read_text() == 'precious'


@pytest.mark.parametrize(('params', 'reason'), [
    ({}, 'parameter output is required'),
    ({'flush_period': 5.0}, 'flush_period out of range'),
    ({'topics': ['bad topic']}, 'bad name in parameter topics'),
])
def test_bad_parameters_give_one_line_and_non_zero_exit(nodes, tmp_path, params, reason):
    if params:
        params = {'output': str(tmp_path / 'bag'), **params}
    recorder = nodes('hri_demo_learning', 'recorder', params=params)
    code = recorder.wait(20.0)
    log = log_of(recorder)
    assert code not in (None, 0), log
    assert reason in log
    assert 'Traceback' not in log
    assert not (tmp_path / 'bag').exists()
