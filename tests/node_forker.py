"""Start node processes without Python's start-up: fork them from a parent that has imported
them once.

`ros2 run` spends about a second of CPU per node on Python's start-up, the imports and the
controller's compiled kernels; the topic-level tests start some 250 nodes, on two cores. Forked
from this parent, which imported every node module and loaded the kernels before any ROS
context existed, a node only creates its context and entities. The child runs the node's own
`main()` (the package's console script, what `ros2 run` calls) with the arguments `ros2 run`
would pass, in the environment `ros2 run` would get, so it is the same node; only the start-up
path differs. The tests that are about `ros2 run` itself (tests/test_node_exit.py,
tests/test_ros2_cli.py, the `system` node's children) still start nodes through it.

Run as `python -u -m tests.node_forker` in the nodes' environment. It prints `ready` once it
has loaded everything, then reads one JSON request per line on stdin:
{"package", "executable", "args", "env", "cwd", "log", "status"}, forks, and answers with
{"pid": PID} (or {"error": reason}) on a line of stdout. The child's output goes to `log`.
Children are reaped as soon as they end, and each one's exit code (negative: the signal that
ended it) is written to its `status` file then, so the caller, which is not the parent, can
wait for it. End of stdin ends the parent, not the children: the caller ends those by PID.
"""

import contextlib
import gc
import importlib
import importlib.metadata
import inspect
import json
import linecache
import os
import select
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

from hri_core.node_common import end_process

# The project's packages whose console scripts (their nodes) the forker starts.
PACKAGES = ('hri_adaptive_controller', 'hri_bringup', 'hri_demo_learning', 'scara_sim')
# The message packages the nodes use: their C type supports load on first use, so the forker
# loads them once for every child.
MESSAGE_MODULES = ('builtin_interfaces.msg', 'geometry_msgs.msg', 'hri_interfaces.msg',
                   'rcl_interfaces.msg', 'rosgraph_msgs.msg', 'sensor_msgs.msg', 'std_msgs.msg')


def node_mains() -> dict[tuple[str, str], object]:
    """{(package, executable): main} of every console script of PACKAGES, imported."""
    mains = {}
    for package in PACKAGES:
        for entry in importlib.metadata.distribution(package).entry_points:
            if entry.group == 'console_scripts':
                mains[package, entry.name] = entry.load()
    return mains


def preload() -> None:
    """What each child would otherwise load in its first second: the message type supports,
    the recorder's message store, the controller's compiled kernels (numba's cache), and the
    source lines rclpy's logger reads (inspect) for the file and line of each call."""
    for name in MESSAGE_MODULES:
        for message in vars(importlib.import_module(name)).values():
            if inspect.isclass(message) and hasattr(message, '_TYPE_SUPPORT'):
                type(message).__import_type_support__()
    # rosbags loads a store's message types on first use: 0.14 s of each recorder's start.
    importlib.import_module('hri_demo_learning.bag_io').jazzy_typestore()
    from hri_adaptive_controller.arm_kernels import warm_up_body_barrier
    from hri_adaptive_controller.arm_law import warm_up_law

    warm_up_body_barrier()
    warm_up_law()
    packages = ('rclpy', 'hri_core', *PACKAGES)
    for module in list(sys.modules.values()):
        path = getattr(module, '__file__', None)
        if path and path.endswith('.py') and module.__name__.split('.')[0] in packages:
            linecache.getlines(path)


def run_child(main, request: dict, closing: list[int]) -> None:
    """In the forked child: the request's environment and folder, a session of its own, no
    input, output to its log, then the node; exits with what `ros2 run` would have."""
    for fd in closing:
        os.close(fd)
    gc.enable()
    signal.set_wakeup_fd(-1)
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    os.setsid()
    os.environ.clear()
    os.environ.update(request['env'])
    os.chdir(request['cwd'])
    nothing = os.open(os.devnull, os.O_RDONLY)
    os.dup2(nothing, 0)
    os.close(nothing)
    log = os.open(request['log'], os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(log, 1)
    os.dup2(log, 2)
    os.close(log)
    sys.argv = [request['executable'], *request['args']]
    code = 1
    try:
        code = main() or 0
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
        if not isinstance(exit_.code, int | None):
            print(exit_.code, file=sys.stderr)
    except BaseException:  # noqa: BLE001 - printed as the interpreter would, then exit 1
        traceback.print_exc()
    finally:
        # The interpreter's own way out, but for tearing down the modules (as run_node's).
        end_process(code)


def write_status(path: str, code: int) -> None:
    """`code` into `path`, whole or not at all (a reader never sees half a number)."""
    with open(path + '.tmp', 'w') as stream:
        stream.write(f'{code}\n')
    os.replace(path + '.tmp', path)


def serve(requests_fd: int, answers) -> None:
    """Fork one node per request line; answer each with the child's PID (or an error); write
    each child's exit code to its status file as soon as it ends."""
    # What the children share with this parent stays shared (Python's advice for fork
    # without exec): no collection here leaves holes in its pages, and the objects it made are
    # frozen, so the children's collections never write to them (each write copies a page of
    # the parent's 270 MB). A node's start to its ready line: 0.1 s of CPU with this, 0.15 s
    # without.
    gc.disable()
    mains = node_mains()
    preload()
    gc.freeze()
    wake_read, wake_write = os.pipe()
    os.set_blocking(wake_write, False)
    signal.set_wakeup_fd(wake_write)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # wakes the select below
    status_of: dict[int, str] = {}
    # HRI_NODE_CPU_LOG: a file each child's CPU time (s) and status file are appended to as
    # it ends (which test's nodes cost what; the status file's path holds the test's name).
    cpu_log = os.environ.get('HRI_NODE_CPU_LOG')
    print('ready', file=answers, flush=True)
    pending = b''
    while True:
        readable, _, _ = select.select([requests_fd, wake_read], [], [], 1.0)
        if wake_read in readable:
            os.read(wake_read, 4096)
        while status_of:
            try:
                pid, status, usage = os.wait4(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            if pid in status_of:
                if cpu_log:
                    with open(cpu_log, 'a') as stream:
                        stream.write(f'{usage.ru_utime + usage.ru_stime:.3f} '
                                     f'{status_of[pid]}\n')
                write_status(status_of.pop(pid), os.waitstatus_to_exitcode(status))
        if requests_fd not in readable:
            continue
        data = os.read(requests_fd, 65536)
        if not data:
            # The caller is gone: its children stay theirs to end; stop reaping.
            return
        pending += data
        *lines, pending = pending.split(b'\n')
        for line in filter(None, lines):
            request = json.loads(line)
            main = mains.get((request['package'], request['executable']))
            if main is None:
                print(json.dumps({'error': f'no node {request["package"]}/'
                                           f'{request["executable"]}'}),
                      file=answers, flush=True)
                continue
            pid = os.fork()
            if pid == 0:
                run_child(main, request, [requests_fd, wake_read, wake_write])
            status_of[pid] = request['status']
            print(json.dumps({'pid': pid}), file=answers, flush=True)


# ------------------------------------------------------------------- the tests' side


class ForkedChild:
    """A node the forker started, with what NodeProcess uses of a Popen: pid, poll(),
    wait(timeout) and returncode (read from its status file once the forker has reaped it)."""

    def __init__(self, pid: int, command: list[str], status: Path):
        self.pid = pid
        self.args = command
        self.returncode: int | None = None
        self._status = status

    def poll(self) -> int | None:
        if self.returncode is None:
            with contextlib.suppress(FileNotFoundError):
                self.returncode = int(self._status.read_text())
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(self.args, timeout)
            time.sleep(0.005)
        return self.returncode


class NodeForker:
    """This module as a process of the tests (one per pytest process): `spawn` is a
    hri_bringup.processes Spawn that forks the node of a `ros2 run` command from it.
    `close` ends the forker; the nodes are ended by PID by whoever started them."""

    def __init__(self, cwd: Path):
        self._process = subprocess.Popen(
            [sys.executable, '-u', '-m', 'tests.node_forker'], cwd=cwd,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self._ready = False

    def spawn(self, command: list[str], env: dict[str, str], log_file) -> ForkedChild:
        """Fork the node of `command` (`ros2 run PACKAGE EXECUTABLE ARGS...`) in `env`, its
        output into `log_file`'s path."""
        if command[:2] != ['ros2', 'run'] or len(command) < 4:
            raise ValueError(f'not a ros2 run command: {command}')
        if not self._ready:
            # Its first line once it has loaded everything (seconds on a busy machine).
            line = self._process.stdout.readline()
            if line.strip() != 'ready':
                raise RuntimeError(f'the node forker did not start: {line!r}')
            self._ready = True
        status = Path(f'{log_file.name}.exit')
        request = {'package': command[2], 'executable': command[3], 'args': command[4:],
                   'env': env, 'cwd': os.getcwd(), 'log': log_file.name, 'status': str(status)}
        self._process.stdin.write(json.dumps(request) + '\n')
        self._process.stdin.flush()
        answer = json.loads(self._process.stdout.readline() or '{"error": "forker gone"}')
        if 'pid' not in answer:
            raise RuntimeError(f'cannot fork {command[2]}/{command[3]}: {answer["error"]}')
        return ForkedChild(answer['pid'], command, status)

    def close(self) -> None:
        self._process.stdin.close()
        try:
            self._process.wait(5.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._process.stdout.close()


if __name__ == '__main__':
    serve(sys.stdin.fileno(), sys.stdout)
