"""Every node leaves on SIGINT and SIGTERM with exit code 0 within its deadline, with one
summary line of what it did (the recorder closes its bag and counts its messages, the sim
reports its steps, the hand its positions, ...; the controller how long it ran).

Not marked exclusive: the deadline is relative to a bare node's exit measured in the same test,
so a busy machine slows both alike.
"""

import itertools
import signal
import sys
import time

import pytest
from geometry_msgs.msg import PointStamped

from hri_bringup.processes import (
    READY_LINES,
    NodeProcess,
    node_environment,
    start_node,
    wait_for,
    wait_until_logged,
)
from hri_core.node_common import SUMMARY_PREFIX
from hri_demo_learning.bag_io import read_bag
from tests.common import PAPER_TASKS, REPO_ROOT
from tests.fault_tools import RELIABLE

pytestmark = pytest.mark.integration

FOLLOW_BAG = REPO_ROOT / 'bags/fixtures/follow'
STOP_DEADLINE = 2.0  # s from the signal to the process's exit


# Every node's ready line, but the recorder's once it records /joint_states.
NODE_READY_LINES = {**READY_LINES, 'recorder': 'recording /joint_states',
                    'live_view': 'live view on ws://'}
# What each node's summary line says it did (after `summary: `).
SUMMARY_WORDS = {
    'scara_sim': 'steps integrated in', 'arm_sim': 'steps integrated in',
    'hand_sim': 'hand positions published on /target',
    'demonstrator': 'wrench and reference messages published',
    'recorder': 'closed bag', 'learner': "1 task learned: 'follow'",
    'event_manager': 'TaskStates published', 'controller': 'commands computed (',
    'event_detector': 'event(s) sent', 'live_view': 'messages streamed',
    'system': 'nodes run, then stopped; exit codes: hand_sim 0',
}


def summary_lines(log: str, name: str) -> list[str]:
    """The summary lines the node `name` logged itself (not those of a child it echoes)."""
    return [line.split(f'[{name}]: {SUMMARY_PREFIX}', 1)[1] for line in log.splitlines()
            if f'[{name}]: {SUMMARY_PREFIX}' in line]


def assert_one_summary(name: str, log: str) -> str:
    lines = summary_lines(log, name)
    assert len(lines) == 1 and SUMMARY_WORDS[name] in lines[0], (name, log)
    return lines[0]


# A bare node on hri_core's run_node: how long this machine takes, right now, to end a
# Python ROS 2 process on a signal (interpreter and middleware teardown).
REFERENCE_NODE = ('from rclpy.node import Node\n'
                  'from hri_core.node_common import run_node\n'
                  'run_node(lambda: print("reference up", flush=True) or Node("reference"), '
                  '"reference")\n')


def exit_time(process: NodeProcess, sig: int) -> tuple[int | None, float]:
    """Send `sig`; the exit code (None: still running after 5 s) and the seconds it took."""
    process.send(sig)
    sent = time.monotonic()
    code = process.wait(5.0)
    return code, round(time.monotonic() - sent, 2)


@pytest.mark.first
def test_every_node_exits_cleanly_on_a_signal(nodes, probe, ros_domain, tmp_path):
    # Both signals take one path (hri_core.node_common.init_ros); the nodes get them in turn.
    # Deadline: STOP_DEADLINE, or 3 times what a bare node takes to exit measured just
    # before, whichever is longer (a busy machine slows every interpreter's teardown alike).
    # As a user starts them (`ros2 run`), not forked as in the other tests: the exit is the
    # process's whole way out.
    def run(package, executable, **kwargs):
        return nodes(package, executable, ros2_run=True, **kwargs)

    bag = tmp_path / 'bag'
    processes = {
        'scara_sim': run('scara_sim', 'scara_sim'),
        # The Panda beside it, on topics of its own (the SCARA's loop stays as it is).
        'arm_sim': run('scara_sim', 'arm_sim', params={'robot': 'panda'}, remaps={
            topic: f'/panda{topic}' for topic in ('/joint_states', '/effort_controller/commands',
                                                  '/ee_position', '/human/wrench',
                                                  '/robot_description')}),
        'hand_sim': run('scara_sim', 'hand_sim', params={'profile': 'circle'}),
        # x_r away from hand_sim's circle (0.08 m round [0.45, 0.05], the default x_r): the
        # arm following the hand passed within stop_distance of the centre at the
        # demonstrator's check, and it refused and exited before its signal.
        'demonstrator': run('scara_sim', 'demonstrator',
                              params={'hold_time': 600.0, 'reference': [0.30, 0.30]}),
        'recorder': run('hri_demo_learning', 'recorder', params={'output': str(bag)}),
        'learner': run('hri_demo_learning', 'learner', params={
            'bags': [str(FOLLOW_BAG)], 'task_name': 'follow', 'output_dir': str(tmp_path)}),
        'event_manager': run('hri_adaptive_controller', 'event_manager', params={
            'tasks_dir': str(PAPER_TASKS), 'initial_task': 'follow'}),
        'controller': run('hri_adaptive_controller', 'controller'),
        'event_detector': run('hri_adaptive_controller', 'event_detector'),
        'live_view': run('hri_bringup', 'live_view', params={'port': 0}),
    }
    reference = NodeProcess.from_command(
        'reference', [sys.executable, '-c', REFERENCE_NODE], node_environment(ros_domain),
        tmp_path)
    signals = dict(zip(processes, itertools.cycle((signal.SIGINT, signal.SIGTERM))))
    targets = probe.collect('/target', PointStamped, RELIABLE)
    try:  # the reference is no fixture's: ended here whatever fails
        assert wait_until_logged({processes[name]: NODE_READY_LINES[name]
                                  for name in processes}, 40.0), {
            name: process.log() for name, process in processes.items()
            if NODE_READY_LINES[name] not in process.log()}
        assert wait_for(lambda: len(targets) > 10, 10.0)
        assert reference.wait_for_line('reference up', 10.0), reference.log()
        time.sleep(1.0)  # every node in its loop, messages flowing
        reference_code, reference_time = exit_time(reference, signal.SIGINT)
        assert reference_code == 0, reference.log()
    finally:
        reference.stop()
    deadline = max(STOP_DEADLINE, 3.0 * reference_time)
    results = {}
    for name, process in processes.items():
        assert process.alive(), (name, process.log())
        results[name] = exit_time(process, signals[name])
    print({name: f'{signals[name].name}: exit {code} in {elapsed} s'
           for name, (code, elapsed) in results.items()},
          f'bare node {reference_time:.2f} s, deadline {deadline:.1f} s')
    slow_or_failed = {name: result for name, result in results.items()
                      if result[0] != 0 or result[1] > deadline}
    assert not slow_or_failed, {name: processes[name].log() for name in slow_or_failed}
    for name, process in processes.items():
        assert 'Traceback' not in process.log(), (name, process.log())
        print(f'{name}: {assert_one_summary(name, process.log())}')
    assert (bag / 'metadata.yaml').is_file()
    counts = read_bag(bag).counts()
    assert counts['/joint_states'] > 500 and counts['/target'] > 10, counts
    assert 'closed bag' in processes['recorder'].log()
    assert 'steps integrated in' in processes['scara_sim'].log()


def test_the_system_and_its_nodes_each_log_one_summary_line(ros_domain, tmp_path):
    # The system stops its children with SIGTERM; it is stopped here with SIGTERM too.
    config = tmp_path / 'hand.yaml'
    config.write_text(f'system:\n  ros__parameters:\n    nodes: [hand_sim]\n'
                      f'    log_dir: {tmp_path / "logs"}\n')
    system = start_node('hri_bringup', 'system', ros_domain, params={'config': str(config)},
                        log_dir=tmp_path)
    try:
        assert system.wait_for_line('all 1 nodes ready', 40.0), system.log()
        system.send(signal.SIGTERM)
        assert system.wait(20.0) == 0, system.log()
    finally:
        system.stop(timeout=20.0)
    log = system.log()
    assert 'Traceback' not in log, log
    print(f'system: {assert_one_summary("system", log)}; '
          f'hand_sim: {assert_one_summary("hand_sim", log)}')
