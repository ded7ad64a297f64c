"""Topic-level tests of the `learner` node on the committed demonstration bags (bags/fixtures).

Table I's rows that the simulated demonstrations reproduce: follow S=1, d1=0, d2=0.041 m;
avoid S=1, d1=0.183 m, d2=2 m; follow shifted by 0.23 m combined with avoid: the region
[0.183, 0.271] m. Bags the learner cannot learn from, and bad parameters, end the node with a
non-zero exit and one error line, and leave no task file.
"""

import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from hri_interfaces.msg import TaskParameters
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from hri_bringup.processes import wait_for
from hri_core.task_file import load_task_file
from hri_demo_learning.bag_io import BagWriter, jazzy_typestore, read_bag
from tests.common import REPO_ROOT

pytestmark = pytest.mark.integration

FIXTURES = REPO_ROOT / 'bags' / 'fixtures'
FOLLOW = str(FIXTURES / 'follow')
AVOID = str(FIXTURES / 'avoid')
TASK_QOS = QoSProfile(depth=16, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
TYPES = jazzy_typestore()
POINT_STAMPED = 'geometry_msgs/msg/PointStamped'


def log_of(process) -> str:
    return process.log_path.read_text(errors='replace')


def run_once(nodes, output_dir: Path, **params):
    """Run the learner with once:=true; return (exit code, log)."""
    learner = nodes('hri_demo_learning', 'learner',
                    params={'output_dir': str(output_dir), 'once': True, **params})
    code = learner.wait(30.0)
    return code, log_of(learner)


def assert_learned(code, log, task_file: Path) -> object:
    assert code == 0, log
    assert 'Traceback' not in log
    assert task_file.is_file(), log
    assert task_file.with_suffix('.png').is_file()
    assert task_file.with_suffix('.png').stat().st_size > 10_000
    record = load_task_file(task_file)
    assert record.iterations <= 50
    assert 'learned task' in log and 'iterations=' in log
    return record


def test_stays_up_and_a_late_subscriber_gets_the_task(nodes, probe, tmp_path):
    learner = nodes('hri_demo_learning', 'learner', params={
        'bags': [FOLLOW], 'output_dir': str(tmp_path)})
    assert wait_for(lambda: 'learned task' in log_of(learner), 30.0), log_of(learner)
    assert (tmp_path / 'follow.yaml').is_file()
    time.sleep(1.0)
    assert learner.alive(), log_of(learner)
    received = probe.collect('/hri/task', TaskParameters, TASK_QOS)  # joins after publishing
    assert wait_for(lambda: len(received) == 1, 10.0), 'the late joiner got no task'
    task = received[0]
    assert (task.name, task.s, task.n) == ('follow', 1, 3)
    assert task.d1 == 0.0
    assert task.d2 == pytest.approx(0.041, abs=0.002)
    assert task.a1 > 0 and task.a2 > 0 and task.iterations <= 50
    assert learner.stop() == 0


def test_once_follow_exits_zero_with_yaml_png_and_delivered_task(nodes, probe, tmp_path):
    received = probe.collect('/hri/task', TaskParameters, TASK_QOS)  # matched before learning
    code, log = run_once(nodes, tmp_path, bags=[FOLLOW])
    record = assert_learned(code, log, tmp_path / 'follow.yaml')
    assert (record.s, record.d1) == (1, 0.0)
    assert record.d2 == pytest.approx(0.041, abs=0.002)
    assert wait_for(lambda: len(received) == 1, 5.0), f'not delivered before exit:\n{log}'
    assert received[0].name == 'follow'
    assert received[0].a1 == pytest.approx(record.a1)


def test_once_avoid(nodes, tmp_path):
    code, log = run_once(nodes, tmp_path, bags=[AVOID])
    record = assert_learned(code, log, tmp_path / 'avoid.yaml')
    assert record.s == 1
    assert record.d1 == pytest.approx(0.183, abs=0.002)
    assert record.d2 == 2.0
    # The ISO/TS 15066 verdict on d1 (hri_core.separation.separation_verdict): S_p of a still
    # hand with the arm at 0.25 m/s is 0.316 m with the learner's defaults, above d1.
    assert "task 'avoid': d1 = 0.18" in log and 'with a still hand (not met' in log, log


def test_once_combined_follow_with_a_safe_distance(nodes, tmp_path):
    code, log = run_once(nodes, tmp_path, bags=[FOLLOW, AVOID], shifts=[0.23, 0.0],
                         task_name='follow_safe')
    record = assert_learned(code, log, tmp_path / 'follow_safe.yaml')
    assert record.s == 1
    assert record.d1 == pytest.approx(0.183, abs=0.002)
    assert record.d2 == pytest.approx(0.271, abs=0.002)


def test_once_follow_with_the_papers_gauss_newton(nodes, tmp_path):
    code, log = run_once(nodes, tmp_path, bags=[FOLLOW], method='gauss_newton',
                         task_name='follow_gn')
    record = assert_learned(code, log, tmp_path / 'follow_gn.yaml')
    assert (record.s, record.d1) == (1, 0.0)
    assert record.d2 == pytest.approx(0.041, abs=0.002)
    assert 'gauss_newton' in log


def test_once_from_joint_states_only_uses_the_forward_kinematics(nodes, tmp_path):
    bag = tmp_path / 'follow_joints'
    contents = read_bag(FOLLOW, topics=['/joint_states', '/demo/reference'])
    with BagWriter(bag) as writer:
        for topic, series in contents.topics.items():
            connection = writer.add_topic(topic, series.msgtype)
            for stamp, message in zip(series.timestamps_ns, series.messages, strict=True):
                writer.write(connection, stamp, TYPES.serialize_cdr(message, series.msgtype))
    code, log = run_once(nodes, tmp_path, bags=[str(bag)], l1=0.35, l2=0.30)
    record = assert_learned(code, log, tmp_path / 'follow_joints.yaml')
    assert (record.s, record.d1) == (1, 0.0)
    assert record.d2 == pytest.approx(0.041, abs=0.002)


# ----------------------------------------------------------------------------- bad input


def point_bytes(x: float, y: float) -> bytes:
    msg = TYPES.types[POINT_STAMPED](
        header=TYPES.types['std_msgs/msg/Header'](
            stamp=TYPES.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
            frame_id='base'),
        point=TYPES.types['geometry_msgs/msg/Point'](x=x, y=y, z=0.0))
    return bytes(TYPES.serialize_cdr(msg, POINT_STAMPED))


def write_positions(bag: Path, positions: np.ndarray, reference=(0.45, 0.05)) -> None:
    """A bag of /ee_position at 1 kHz and /demo/reference."""
    with BagWriter(bag) as writer:
        ee = writer.add_topic('/ee_position', POINT_STAMPED)
        ref = writer.add_topic('/demo/reference', POINT_STAMPED)
        writer.write(ref, 10**18, point_bytes(*reference))
        for index, (x, y) in enumerate(positions):
            writer.write(ee, 10**18 + (index + 1) * 10**6, point_bytes(x, y))


def moving_then(rest_seconds: float) -> np.ndarray:
    """3 s toward x_r at about 0.1 m/s, then `rest_seconds` still."""
    t = np.arange(0.0, 3.0, 1e-3)
    path = np.column_stack([0.35 + 0.1 * t / 3.0 * 3.0 * 0.3, 0.30 - 0.08 * t])
    return np.vstack([path, np.repeat(path[-1:], int(rest_seconds * 1000), axis=0)])


def bag_never_at_rest(tmp_path: Path) -> str:
    write_positions(tmp_path / 'never_at_rest', moving_then(0.0))
    return str(tmp_path / 'never_at_rest')


def bag_truncated(tmp_path: Path) -> str:
    bag = shutil.copytree(FOLLOW, tmp_path / 'truncated')
    data = (bag / 'follow.mcap').read_bytes()
    (bag / 'follow.mcap').write_bytes(data[:len(data) // 2])
    return str(bag)


def not_a_bag(tmp_path: Path) -> str:
    (tmp_path / 'notes').mkdir()
    (tmp_path / 'notes' / 'readme.txt').write_text('not a bag')
    return str(tmp_path / 'notes')


# A few representative cases end to end (one line, exit 1, no task file): the reader's, the
# demonstration's and the path's refusals. Every reason the learner gives is checked in the
# pure tests (hri_demo_learning/test/test_learning.py, test_bag_io.py, test_task_energy.py,
# test_bag_fuzz.py); the node passes each on the same way (learner_node: StartupError).
@pytest.mark.parametrize(('make_bag', 'reason'), [
    (bag_never_at_rest, 'no sample at rest after the motion'),
    (bag_truncated, 'is truncated or corrupt'),
    (not_a_bag, 'is not a bag'),
], ids=lambda value: getattr(value, '__name__', None))
def test_bag_it_cannot_learn_from(nodes, tmp_path, make_bag, reason):
    output = tmp_path / 'tasks'
    code, log = run_once(nodes, output, bags=[make_bag(tmp_path)], task_name='bad')
    assert_refused(code, log, output, reason)


# Likewise: a setting out of range and a missing one (all of them: test_learning.py).
@pytest.mark.parametrize(('params', 'reason'), [
    ({'bags': [FOLLOW], 'method': 'newton'}, 'parameter method must be one of'),
    ({}, 'parameter bags is required'),
], ids=['method', 'no-bags'])
def test_bad_parameters(nodes, tmp_path, params, reason):
    output = tmp_path / 'tasks'
    code, log = run_once(nodes, output, **params)
    assert_refused(code, log, output, reason)


def assert_refused(code, log, output: Path, reason: str) -> None:
    assert code not in (None, 0), log
    errors = [line for line in log.splitlines() if 'ERROR' in line]
    assert len(errors) == 1, log
    assert reason in errors[0], log
    assert 'Traceback' not in log
    assert not list(output.glob('*.yaml')) if output.exists() else True
    assert not list(output.glob('*.png')) if output.exists() else True
