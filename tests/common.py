"""Shared helpers of the topic-level tests: start nodes as processes, listen and publish.

Every node runs as a separate process through `ros2 run` (the project's environment must be
sourced: `scripts/test.sh` does it), on the test's own ROS_DOMAIN_ID, with DDS discovery kept
on loopback. The test side talks to them through an rclpy node in its own Context.
"""

import itertools
import json
import os
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile

REPO_ROOT = Path(__file__).resolve().parents[1]
_domain_counter = itertools.count()
DOMAIN_ID_FIRST, DOMAIN_ID_COUNT = 100, 130
# The xdist controller's PID is the workers' parent: one offset per session.
_session_offset = (os.getppid() if 'PYTEST_XDIST_WORKER' in os.environ else os.getpid()) * 7


def wait_for(condition: Callable[[], bool], timeout: float, period: float = 0.05) -> bool:
    """Poll `condition` until it is true or `timeout` seconds pass; return its last value."""
    deadline = time.monotonic() + timeout
    while True:
        if condition():
            return True
        if time.monotonic() >= deadline:
            return bool(condition())
        time.sleep(period)


def next_domain_id() -> int:
    """A ROS_DOMAIN_ID in 100..229 of this test alone.

    Under pytest-xdist, worker k of n takes the IDs 100 + k + n j, so workers never share one;
    the offset from the session's PID makes two sessions at once unlikely to meet.
    """
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    worker = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw'))
    slots = DOMAIN_ID_COUNT // workers
    slot = (_session_offset + next(_domain_counter)) % slots
    return DOMAIN_ID_FIRST + slot * workers + worker


def node_environment(domain_id: int) -> dict[str, str]:
    """The environment of a node process: this one's, on `domain_id`, discovery on loopback."""
    env = dict(os.environ)
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


def ros2_run_command(package: str, executable: str, params: dict | None = None,
                     remaps: dict | None = None, extra_args: Iterable[str] = ()) -> list[str]:
    """`ros2 run package executable ...` with parameters and remappings as --ros-args."""
    command = ['ros2', 'run', package, executable, *extra_args]
    ros_args = []
    for key, value in (params or {}).items():
        ros_args += ['-p', f'{key}:={format_parameter(value)}']
    for old, new in (remaps or {}).items():
        ros_args += ['-r', f'{old}:={new}']
    if ros_args:
        command += ['--ros-args', *ros_args]
    return command


class NodeProcess:
    """One `ros2 run` process; output goes to a log file; ended by PID, never by name."""

    def __init__(self, package: str, executable: str, domain_id: int,
                 params: dict | None = None, remaps: dict | None = None,
                 extra_args: Iterable[str] = (), log_dir: Path | None = None):
        self.name = f'{package}/{executable}'
        command = ros2_run_command(package, executable, params, remaps, extra_args)
        log_dir = Path(log_dir or tempfile.mkdtemp(prefix='hri-test-'))
        self.log_path = log_dir / f'{executable}-{next(_domain_counter)}.log'
        self._log_file = open(self.log_path, 'wb')  # closed in stop()
        self.command = command
        self.process = subprocess.Popen(
            command, env=node_environment(domain_id), stdout=self._log_file,
            stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.process.pid

    def alive(self) -> bool:
        return self.process.poll() is None

    def send(self, sig: int) -> None:
        if self.alive():
            os.kill(self.process.pid, sig)

    def wait(self, timeout: float) -> int | None:
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, timeout: float = 5.0, sig: int = signal.SIGINT) -> int:
        """Send `sig`, then SIGKILL after `timeout` s; return the exit code."""
        if self.alive():
            self.send(sig)
            if self.wait(timeout) is None:
                self.send(signal.SIGKILL)
                self.process.wait(timeout=5.0)
        self._log_file.close()
        return self.process.returncode

    def log(self) -> str:
        """Everything the process printed so far (also after stop())."""
        if not self._log_file.closed:
            self._log_file.flush()
        return self.log_path.read_text(errors='replace')


def start_node(package: str, executable: str, domain_id: int, params: dict | None = None,
               remaps: dict | None = None, extra_args: Iterable[str] = (),
               log_dir: Path | None = None) -> NodeProcess:
    """Start `ros2 run package executable` with parameters and remappings."""
    return NodeProcess(package, executable, domain_id, params, remaps, extra_args, log_dir)


class RosProbe:
    """An rclpy node of the test, in its own Context on `domain_id`, spun in a thread."""

    def __init__(self, domain_id: int, name: str = 'test_probe'):
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
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
