"""Nodes as `ros2 run` processes: start them, see when they are up, end them by PID.

What the topic-level tests, scripts/demo.py, the benchmarks and the `system` node share:

- `NodeProcess` (`start_node`): one `ros2 run PACKAGE EXECUTABLE --ros-args ...` process on a
  given ROS_DOMAIN_ID (or the caller's), DDS discovery kept on loopback, in a session of its
  own (a Ctrl-C in the terminal reaches only the parent, which ends its children itself), its
  stdout and stderr in a log file. Ended by PID, never by name: SIGINT, then SIGKILL after a
  timeout. `stop_all` does that to several processes at once.
- `wait_until_logged`: readiness, when every process has printed its line (`READY_LINES`:
  what each node logs once it is up).
- `start_live_loop`: the live loop (scara_sim, event_manager, controller, hand_sim; the
  recorder on request) with its default parameters and per-node overrides.
- `RosProbe`: an rclpy node in a Context of its own, spun in a thread, to listen and publish.
- `remove_dead_shared_memory`: the Fast DDS shared-memory segments of processes that ended
  without closing them (SIGKILL), which nothing else removes.
"""

import fcntl
import itertools
import json
import os
import re
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path

import rclpy
from ament_index_python.packages import get_package_share_directory
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile

# Log file names stay distinct when one executable is started twice into one folder.
_log_counter = itertools.count()

# The nodes of the live loop by name: (package, executable), in the order they are started.
# The recorder comes before the hand so that a bag holds the hand's whole script, and the
# hand comes last so that its script (start_delay, waypoints) begins with the loop up.
# arm_sim (any arm from its URDF, e.g. robot: panda) stands in for scara_sim; it starts after
# the controller, as an arm under gravity sags while no controller holds it.
LIVE_LOOP_EXECUTABLES: dict[str, tuple[str, str]] = {
    'scara_sim': ('scara_sim', 'scara_sim'),
    'event_manager': ('hri_adaptive_controller', 'event_manager'),
    'controller': ('hri_adaptive_controller', 'controller'),
    'arm_sim': ('scara_sim', 'arm_sim'),
    'event_detector': ('hri_adaptive_controller', 'event_detector'),
    'recorder': ('hri_demo_learning', 'recorder'),
    'hand_sim': ('scara_sim', 'hand_sim'),
}
# What `start_live_loop` starts unless told otherwise (the recorder only with a bag to write).
LIVE_LOOP = ('scara_sim', 'event_manager', 'controller', 'hand_sim')
# What `ros2 run hri_bringup system` starts by default: the live loop, the events coming from
# the event_detector's rules.
SYSTEM_NODES = ('scara_sim', 'event_manager', 'controller', 'event_detector', 'hand_sim')
STACK_DUMP_TIME = 0.5  # s a process that outlived its stop signal gets to write its stacks
# A line each executable logs once it is up (its parameters are read, its loop is running).
READY_LINES: dict[str, str] = {
    'scara_sim': 'simulating at',
    'arm_sim': 'simulating ',
    'hand_sim': 'hand profile',
    'demonstrator': 'demonstration around',
    'recorder': 'recording into',
    'learner': 'learned task',
    'event_manager': 'task(s) loaded',
    'controller': 'control on each /joint_states',
    'event_detector': 'rule(s):',
}


# A Fast DDS shared-memory segment (about 0.5 MB) and its lock file, which its process holds
# locked (flock) while it lives; the file names of Fast DDS 2.x.
_SEGMENT_LOCK = re.compile(r'^fastrtps_[0-9a-f]{16}_el$')


def remove_dead_shared_memory(directory: Path = Path('/dev/shm'), min_age: float = 10.0) -> int:
    """Remove the shared-memory segments whose owner has died; the number removed.

    Every participant creates a segment in `directory` and removes it when it closes; a
    process ended with SIGKILL leaves it behind for good (tens of thousands of them after a
    day of kill tests: half a megabyte of RAM each). A segment counts as dead when nobody holds
    its lock file, as `fastdds shm clean` judges, and the lock file is over `min_age` s old (a
    process that has just created it may not have locked it yet).
    """
    removed = 0
    try:
        names = os.listdir(directory)
    except OSError:
        return 0
    now = time.time()
    for name in names:
        if not _SEGMENT_LOCK.match(name):
            continue
        lock_path = Path(directory) / name
        try:
            if now - lock_path.stat().st_mtime < min_age:
                continue
            with open(lock_path, 'ab') as lock:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                # Unlinked while locked: a process that opens it now gets a new file.
                Path(directory, name[:-len('_el')]).unlink(missing_ok=True)
                lock_path.unlink(missing_ok=True)
            removed += 1
        except OSError:  # locked by a living process, or gone meanwhile
            continue
    return removed


def wait_for(condition: Callable[[], bool], timeout: float, period: float = 0.05) -> bool:
    """Poll `condition` until it is true or `timeout` seconds pass; return its last value."""
    deadline = time.monotonic() + timeout
    while True:
        if condition():
            return True
        if time.monotonic() >= deadline:
            return bool(condition())
        time.sleep(period)


def node_environment(domain_id: int | None = None) -> dict[str, str]:
    """The environment of a node process: this one's, on `domain_id` (None: this process's
    ROS_DOMAIN_ID), discovery on loopback, Python output unbuffered (log lines in order)."""
    env = dict(os.environ)
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PYTHONUNBUFFERED'] = '1'
    return env


def format_parameter(value) -> str:
    """A Python value as a `-p name:=value` literal (YAML)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return json.dumps(list(value))
    if isinstance(value, str):
        return json.dumps(value) if value == '' else value
    return repr(value)


def ros2_run_command(package: str, executable: str, params: Mapping | None = None,
                     remaps: Mapping | None = None, extra_args: Iterable[str] = (),
                     params_files: Sequence[str | Path] = ()) -> list[str]:
    """`ros2 run package executable ...` with parameter files, parameters and remappings as
    --ros-args. The files come first: a `-p` given here wins over a file's value."""
    command = ['ros2', 'run', package, executable, *extra_args]
    ros_args = []
    for path in params_files:
        ros_args += ['--params-file', str(path)]
    for key, value in (params or {}).items():
        ros_args += ['-p', f'{key}:={format_parameter(value)}']
    for old, new in (remaps or {}).items():
        ros_args += ['-r', f'{old}:={new}']
    if ros_args:
        command += ['--ros-args', *ros_args]
    return command


def popen_in_a_session(command: list[str], env: dict[str, str], log_file) -> subprocess.Popen:
    """`command` as a process in a session of its own, its stdout and stderr into
    `log_file` (an open binary file): how a NodeProcess starts by default."""
    return subprocess.Popen(command, env=env, stdout=log_file, stderr=subprocess.STDOUT,
                            start_new_session=True)


# How a NodeProcess starts its command: (command, env, log file) -> an object with Popen's
# pid, poll(), wait(timeout) and returncode.
Spawn = Callable[[list[str], dict[str, str], object], subprocess.Popen]


class NodeProcess:
    """One `ros2 run` process in its own session; its output goes to a log file; ended by
    PID, never by name. `spawn` starts it (default `popen_in_a_session`; the tests fork the
    same node from a parent that has imported it, tests/node_forker.py)."""

    def __init__(self, package: str, executable: str, domain_id: int | None = None,
                 params: Mapping | None = None, remaps: Mapping | None = None,
                 extra_args: Iterable[str] = (), log_dir: Path | None = None,
                 params_files: Sequence[str | Path] = (), spawn: Spawn | None = None):
        command = ros2_run_command(package, executable, params, remaps, extra_args,
                                   params_files)
        self._launch(f'{package}/{executable}', command, node_environment(domain_id), log_dir,
                     executable, spawn or popen_in_a_session)

    @classmethod
    def from_command(cls, name: str, command: Sequence[str], env: Mapping[str, str],
                     log_dir: Path | None = None) -> 'NodeProcess':
        """Any command run and ended like a node (e.g. one wrapped in `ip netns exec`);
        `name` stands for it in messages and in its log file's name."""
        process = cls.__new__(cls)
        process._launch(name, list(command), dict(env), log_dir, name, popen_in_a_session)
        return process

    def _launch(self, name: str, command: list[str], env: dict[str, str],
                log_dir: Path | None, log_stem: str, spawn: Spawn) -> None:
        self.name = name
        self.command = command
        log_dir = Path(log_dir) if log_dir else Path(tempfile.mkdtemp(prefix='hri-nodes-'))
        log_dir.mkdir(parents=True, exist_ok=True)
        stem = re.sub(r'[^\w.-]', '_', log_stem)
        self.log_path = log_dir / f'{stem}-{next(_log_counter)}.log'
        self._log_file = open(self.log_path, 'wb')  # closed in wait_or_kill()
        self._read_offset = 0
        try:
            self.process = spawn(command, env, self._log_file)
        except BaseException:
            self._log_file.close()
            raise

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def returncode(self) -> int | None:
        """The exit code once the process has ended (negative: the signal that ended it)."""
        return self.process.returncode

    def alive(self) -> bool:
        return self.process.poll() is None

    def send(self, sig: int) -> None:
        """Send `sig` if the process still runs: once it has exited and been reaped, its PID
        may already belong to another process."""
        if self.alive():
            os.kill(self.process.pid, sig)

    def wait(self, timeout: float) -> int | None:
        """The exit code, or None if the process still runs after `timeout` s."""
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def wait_or_kill(self, timeout: float) -> int:
        """Wait up to `timeout` s for the exit, then SIGKILL; close the log; the exit code.
        Before the SIGKILL, SIGUSR1: a node of this project (node_common.run_node) then
        writes every thread's Python stack to its log, where why it did not stop can be read
        (a hand_sim once outlived its SIGTERM by 5 s in a fresh-clone run, no trace left)."""
        if self.wait(timeout) is None:
            self.send(signal.SIGUSR1)
            if self.wait(STACK_DUMP_TIME) is None:
                self.send(signal.SIGKILL)
            self.wait(5.0)
        self._log_file.close()
        return self.returncode

    def stop(self, timeout: float = 5.0, sig: int = signal.SIGINT) -> int:
        """Send `sig`, then SIGKILL after `timeout` s; return the exit code."""
        self.send(sig)
        return self.wait_or_kill(timeout)

    def log(self) -> str:
        """Everything the process printed so far (also after stop())."""
        return self.log_path.read_text(errors='replace')

    def wait_for_line(self, text: str, timeout: float) -> bool:
        """True once the log holds `text`; False after `timeout` s or if the process ends
        without having printed it."""
        return wait_until_logged({self: text}, timeout)

    def new_lines(self, final: bool = False) -> list[str]:
        """The lines printed since the previous call: complete lines only, unless `final`
        (the process has ended: its last line may lack a newline)."""
        with open(self.log_path, 'rb') as log:
            log.seek(self._read_offset)
            data = log.read()
        end = len(data) if final else data.rfind(b'\n') + 1
        self._read_offset += end
        return data[:end].decode(errors='replace').splitlines()


def start_node(package: str, executable: str, domain_id: int | None = None,
               params: Mapping | None = None, remaps: Mapping | None = None,
               extra_args: Iterable[str] = (), log_dir: Path | None = None,
               params_files: Sequence[str | Path] = (),
               spawn: Spawn | None = None) -> NodeProcess:
    """Start `ros2 run package executable` with parameter files, parameters and remappings
    (`spawn`: NodeProcess's)."""
    return NodeProcess(package, executable, domain_id, params, remaps, extra_args, log_dir,
                       params_files, spawn)


def stop_all(processes: Iterable[NodeProcess], timeout: float = 5.0,
             sig: int = signal.SIGINT) -> dict[NodeProcess, int]:
    """Send `sig` to every process at once, SIGKILL those still running `timeout` s later;
    return each one's exit code."""
    processes = list(processes)
    for process in processes:
        process.send(sig)
    deadline = time.monotonic() + timeout
    return {process: process.wait_or_kill(max(0.0, deadline - time.monotonic()))
            for process in processes}


def not_logged(expected: Mapping[NodeProcess, str]) -> list[NodeProcess]:
    """The processes whose log does not hold their line of `expected` (yet)."""
    return [process for process, line in expected.items() if line not in process.log()]


def wait_until_logged(expected: Mapping[NodeProcess, str], timeout: float) -> bool:
    """True once every process of `expected` has printed its line; False after `timeout` s,
    or as soon as a process that has not printed its line has exited (it never will)."""
    deadline = time.monotonic() + timeout
    while True:
        missing = not_logged(expected)
        if not missing:
            return True
        if time.monotonic() >= deadline or not all(p.alive() for p in missing):
            return not not_logged(expected)
        time.sleep(0.05)


class NodesNotReadyError(TimeoutError):
    """Live-loop nodes did not log their READY_LINES line in time (they have been stopped)."""

    def __init__(self, late: list[str], timeout: float):
        super().__init__(f'{", ".join(late)} did not start within {timeout:g} s')
        self.late = late


def paper_tasks_dir() -> Path:
    """Table I's task files as installed with hri_adaptive_controller (share/.../tasks)."""
    return Path(get_package_share_directory('hri_adaptive_controller')) / 'tasks'


def check_live_loop_names(names: Iterable[str]) -> None:
    """ValueError naming every one of `names` that is not a live-loop node."""
    unknown = sorted(set(names) - set(LIVE_LOOP_EXECUTABLES))
    if unknown:
        raise ValueError(f'no live-loop node {", ".join(unknown)} '
                         f'(nodes: {", ".join(LIVE_LOOP_EXECUTABLES)})')


def live_loop_parameters(overrides: Mapping[str, Mapping | None] | None = None
                         ) -> dict[str, dict]:
    """The parameters of every live-loop node: the loop's defaults updated by
    `overrides[name]`. By default the event_manager loads Table I's tasks and fades `follow`
    in; every other node keeps its own defaults."""
    overrides = dict(overrides or {})
    check_live_loop_names(overrides)
    parameters: dict[str, dict] = {name: {} for name in LIVE_LOOP_EXECUTABLES}
    parameters['event_manager'] = {'tasks_dir': str(paper_tasks_dir()),
                                   'initial_task': 'follow'}
    for name, values in overrides.items():
        parameters[name].update(values or {})
    return parameters


def start_nodes(names: Iterable[str], domain_id: int | None,
                params: Mapping[str, Mapping | None] | None = None,
                log_dir: Path | None = None,
                params_files: Sequence[str | Path] = (),
                spawn: Spawn | None = None) -> dict[str, NodeProcess]:
    """Start the live-loop nodes `names` (in LIVE_LOOP_EXECUTABLES' order) with
    `params[name]` and the parameter files; return {name: process}. `spawn`: NodeProcess's.

    ValueError for a name that is not a live-loop node. If one fails to start, those
    already started are stopped before the error is raised."""
    wanted = set(names)
    check_live_loop_names(wanted)
    started: dict[str, NodeProcess] = {}
    try:
        for name, (package, executable) in LIVE_LOOP_EXECUTABLES.items():
            if name in wanted:
                started[name] = start_node(package, executable, domain_id,
                                           params=(params or {}).get(name), log_dir=log_dir,
                                           params_files=params_files, spawn=spawn)
    except BaseException:
        stop_all(started.values())
        raise
    return started


def start_live_loop(domain_id: int | None,
                    overrides: Mapping[str, Mapping | None] | None = None,
                    log_dir: Path | None = None, record: str | Path | None = None,
                    nodes: Iterable[str] = LIVE_LOOP,
                    ready_timeout: float | None = None,
                    spawn: Spawn | None = None) -> dict[str, NodeProcess]:
    """Start the live loop on `domain_id`; return {node name: process}.

    `overrides` maps a node name (LIVE_LOOP_EXECUTABLES) to parameters that replace the
    loop's defaults (`live_loop_parameters`). With `record` (a bag folder to create) the
    recorder records into it too; its other parameters come from `overrides['recorder']`.
    `nodes` picks the nodes (default LIVE_LOOP). Without `ready_timeout` all start at once
    and the caller waits for what it needs; with it the hand starts last, once every other
    node has logged its READY_LINES line, and NodesNotReadyError is raised (everything stopped)
    if one has not within `ready_timeout` s. `spawn`: NodeProcess's. On any error nothing is
    left running.
    """
    names = [*nodes, *(['recorder'] if record is not None else [])]
    parameters = live_loop_parameters(overrides)
    if record is not None:
        parameters['recorder']['output'] = str(record)
    if ready_timeout is None:
        return start_nodes(names, domain_id, parameters, log_dir, spawn=spawn)
    processes = start_nodes([name for name in names if name != 'hand_sim'], domain_id,
                            parameters, log_dir, spawn=spawn)
    try:
        expected = {process: READY_LINES[LIVE_LOOP_EXECUTABLES[name][1]]
                    for name, process in processes.items()}
        if not wait_until_logged(expected, ready_timeout):
            late = not_logged(expected)
            raise NodesNotReadyError([name for name, process in processes.items()
                                      if process in late], ready_timeout)
        if 'hand_sim' in names:
            processes.update(start_nodes(['hand_sim'], domain_id, parameters, log_dir,
                                         spawn=spawn))
    except BaseException:
        stop_all(processes.values())
        raise
    return processes


class RosProbe:
    """An rclpy node of the caller, in its own Context on `domain_id`, spun in a thread.

    `executor` is its executor class: SingleThreadedExecutor, or the EventsExecutor for a
    probe of 1 kHz streams (a fraction of the CPU per message; benchmarks).
    """

    def __init__(self, domain_id: int, name: str = 'test_probe',
                 executor: type = SingleThreadedExecutor):
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = executor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.02)

    def collect(self, topic: str, msg_type, qos: QoSProfile | int = 10) -> list:
        """Subscribe to `topic`; return the list its messages are appended to."""
        received: list = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def publisher(self, topic: str, msg_type, qos: QoSProfile | int = 10):
        return self.node.create_publisher(msg_type, topic, qos)

    def now(self):
        return self.node.get_clock().now().to_msg()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
