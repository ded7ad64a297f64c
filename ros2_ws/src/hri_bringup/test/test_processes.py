"""Unit tests of hri_bringup.processes: commands, parameters of the live loop, process ends.

No ROS node runs here: the process tests start small Python scripts with
`NodeProcess.from_command`.
"""

import fcntl
import os
import signal
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip('rclpy')

from hri_bringup.processes import (  # noqa: E402
    LIVE_LOOP,
    LIVE_LOOP_EXECUTABLES,
    READY_LINES,
    NodeProcess,
    format_parameter,
    live_loop_parameters,
    node_environment,
    remove_dead_shared_memory,
    ros2_run_command,
    start_live_loop,
    start_nodes,
    stop_all,
    wait_until_logged,
)

# Prints 'up', then runs until SIGINT, on which it prints 'bye' and exits 0.
POLITE = ("import signal, sys, time\n"
          "signal.signal(signal.SIGINT, lambda *_: (print('bye', flush=True), sys.exit(0)))\n"
          "print('up', flush=True)\n"
          "while True: time.sleep(0.05)\n")
# Ignores SIGINT: only SIGKILL ends it. Writes its stack on SIGUSR1, as run_node's nodes do.
STUBBORN = ("import faulthandler, signal, time\n"
            "faulthandler.register(signal.SIGUSR1, all_threads=True)\n"
            "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
            "print('up', flush=True)\n"
            "while True: time.sleep(0.05)\n")


def script(name: str, code: str, log_dir: Path) -> NodeProcess:
    return NodeProcess.from_command(name, [sys.executable, '-c', code], os.environ, log_dir)


def test_ros2_run_command_puts_parameter_files_before_the_overrides():
    command = ros2_run_command(
        'scara_sim', 'hand_sim', params={'profile': 'hold', 'start': [0.45, 0.1]},
        remaps={'/target': '/hand'}, extra_args=['--extra'],
        params_files=['a.yaml', Path('/tmp/b.yaml')])
    assert command == ['ros2', 'run', 'scara_sim', 'hand_sim', '--extra', '--ros-args',
                       '--params-file', 'a.yaml', '--params-file', '/tmp/b.yaml',
                       '-p', 'profile:=hold', '-p', 'start:=[0.45, 0.1]',
                       '-r', '/target:=/hand']


def test_ros2_run_command_without_arguments_has_no_ros_args():
    assert ros2_run_command('scara_sim', 'scara_sim') == ['ros2', 'run', 'scara_sim',
                                                          'scara_sim']
    assert ros2_run_command('scara_sim', 'scara_sim', params={}, params_files=()) == [
        'ros2', 'run', 'scara_sim', 'scara_sim']


@pytest.mark.parametrize('value, literal', [
    (True, 'true'), (False, 'false'), (3, '3'), (0.5, '0.5'), ('', '""'), ('follow', 'follow'),
    ([0.1, 2.0], '[0.1, 2.0]'), (('a', 'b'), '["a", "b"]'),
])
def test_format_parameter_writes_yaml_literals(value, literal):
    assert format_parameter(value) == literal


def test_node_environment_sets_the_domain_only_when_given(monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', '7')
    assert node_environment()['ROS_DOMAIN_ID'] == '7'
    env = node_environment(42)
    assert env['ROS_DOMAIN_ID'] == '42'
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert env['PYTHONUNBUFFERED'] == '1'


def test_only_the_unlocked_old_shared_memory_segments_are_removed(tmp_path):
    def segment(name: str, age: float) -> tuple[Path, Path]:
        data, lock = tmp_path / name, tmp_path / f'{name}_el'
        data.write_bytes(b'segment')
        lock.touch()
        then = time.time() - age
        os.utime(lock, (then, then))
        return data, lock

    dead = segment('fastrtps_00000000000000aa', 60.0)
    alive = segment('fastrtps_00000000000000bb', 60.0)
    young = segment('fastrtps_00000000000000cc', 1.0)
    port = segment('fastrtps_port7411', 60.0)  # a port, shared by its users: not a segment
    with open(alive[1], 'ab') as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a living owner holds its lock
        assert remove_dead_shared_memory(tmp_path, min_age=10.0) == 1
    assert not any(path.exists() for path in dead)
    assert all(path.exists() for path in (*alive, *young, *port))
    assert remove_dead_shared_memory(tmp_path / 'missing') == 0


def test_live_loop_parameters_default_to_table_one_and_follow():
    parameters = live_loop_parameters()
    assert set(parameters) == set(LIVE_LOOP_EXECUTABLES)
    manager = parameters['event_manager']
    assert manager['initial_task'] == 'follow'
    assert sorted(p.name for p in Path(manager['tasks_dir']).glob('*.yaml')) == [
        'avoid.yaml', 'follow.yaml', 'follow_safe.yaml']
    assert all(parameters[name] == {} for name in parameters if name != 'event_manager')


def test_live_loop_parameters_merge_overrides_per_node():
    parameters = live_loop_parameters({'event_manager': {'initial_task': 'avoid'},
                                       'hand_sim': {'profile': 'circle'}, 'controller': None})
    assert parameters['event_manager']['initial_task'] == 'avoid'
    assert 'tasks_dir' in parameters['event_manager']  # the other defaults are kept
    assert parameters['hand_sim'] == {'profile': 'circle'}
    assert parameters['controller'] == {}


def test_unknown_node_names_are_refused_before_anything_starts(tmp_path):
    with pytest.raises(ValueError, match='hand_simm'):
        live_loop_parameters({'hand_simm': {}})
    with pytest.raises(ValueError, match='dance'):
        start_nodes(['scara_sim', 'dance'], 0, log_dir=tmp_path)
    with pytest.raises(ValueError, match='dance'):
        start_live_loop(0, nodes=['dance'], log_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_every_live_loop_node_has_a_ready_line():
    assert set(LIVE_LOOP) < set(LIVE_LOOP_EXECUTABLES)
    assert all(executable in READY_LINES for _, executable in LIVE_LOOP_EXECUTABLES.values())


def test_stop_all_ends_the_polite_with_sigint_and_the_stubborn_with_sigkill(tmp_path):
    polite = script('polite', POLITE, tmp_path)
    stubborn = script('stubborn', STUBBORN, tmp_path)
    try:
        assert wait_until_logged({polite: 'up', stubborn: 'up'}, 20.0), (polite.log(),
                                                                         stubborn.log())
        codes = stop_all([polite, stubborn], timeout=1.0)
    finally:
        stop_all([polite, stubborn], timeout=0.0)
    assert codes == {polite: 0, stubborn: -signal.SIGKILL}
    assert 'bye' in polite.log()
    # Why the stubborn one did not stop, in its log: its stack when SIGUSR1 came.
    assert 'most recent call first' in stubborn.log() and 'Current thread' not in polite.log()
    assert polite.log_path.parent == tmp_path and polite.log_path.name.startswith('polite-')


def test_new_lines_returns_each_complete_line_once(tmp_path):
    code = ("import sys, time\n"
            "print('one', flush=True)\n"
            "time.sleep(1.0)\n"
            "print('two', flush=True)\n"
            "sys.stdout.write('three')\n")
    process = script('lines', code, tmp_path)
    try:
        assert process.wait_for_line('one', 20.0), process.log()
        assert process.new_lines() == ['one']
        assert process.new_lines() == []
        assert process.wait(20.0) == 0
        assert process.new_lines() == ['two']  # 'three' has no newline yet
        assert process.new_lines(final=True) == ['three']
    finally:
        process.stop(timeout=1.0)


def test_waiting_for_a_line_ends_when_the_process_exits_without_it(tmp_path):
    process = script('quiet', "print('something else')", tmp_path)
    try:
        assert not wait_until_logged({process: 'never printed'}, 30.0)
        assert process.wait(5.0) == 0  # it returned because the process had ended
        assert not process.wait_for_line('never printed', 30.0)
    finally:
        process.stop(timeout=1.0)
