"""Start node processes without Python's start-up: fork them from a parent that has imported
them once.

Killing a peer node many times in a row (tests/test_faults.py) needs a new peer after every
kill. `ros2 run` spends about a second of CPU per process on Python start-up and imports;
forked from this parent, which imported every node module before any ROS context existed, a
node only creates its context and entities: 0.13-0.54 s to its first log line here, one at a
time beside a running loop. The child runs the node's own `main()` with the arguments
`ros2 run` would pass, so it is the same node; only the start-up path differs.

Run as `python -m tests.node_forker` in the nodes' environment (ROS_DOMAIN_ID and all). It
reads one JSON request per line on stdin, [executable, log file, argument, ...], forks, and
answers with the child's PID on a line of stdout. Children are reaped as they end (SIGCHLD
ignored), so a killed child's PID disappears at once. End of stdin ends the parent, not the
children: the caller ends those by PID.
"""

import importlib
import inspect
import json
import linecache
import os
import signal
import sys

# The nodes it can start, by executable name: the module whose main(args) `ros2 run` calls.
NODE_MODULES = {
    'scara_sim': 'scara_sim.scara_sim_node',
    'hand_sim': 'scara_sim.hand_sim_node',
    'event_manager': 'hri_adaptive_controller.event_manager_node',
    'recorder': 'hri_demo_learning.recorder_node',
}
# The message packages the nodes use: their C type supports load on first use, so the forker
# loads them once for every child.
MESSAGE_MODULES = ('builtin_interfaces.msg', 'geometry_msgs.msg', 'hri_interfaces.msg',
                   'rcl_interfaces.msg', 'rosgraph_msgs.msg', 'sensor_msgs.msg', 'std_msgs.msg')


def preload(packages: tuple[str, ...]) -> None:
    """What each child would otherwise load in its first second: the message type supports,
    the recorder's message store, and the source lines rclpy's logger reads (inspect) for the
    file and line of each call from the modules of `packages`."""
    for name in MESSAGE_MODULES:
        for message in vars(importlib.import_module(name)).values():
            if inspect.isclass(message) and hasattr(message, '_TYPE_SUPPORT'):
                type(message).__import_type_support__()
    # rosbags loads a store's message types on first use: 0.14 s of each recorder's start.
    importlib.import_module('hri_demo_learning.bag_io').jazzy_typestore()
    for module in list(sys.modules.values()):
        path = getattr(module, '__file__', None)
        if path and path.endswith('.py') and module.__name__.split('.')[0] in packages:
            linecache.getlines(path)


def run_child(main, executable: str, log_path: str, arguments: list[str]) -> None:
    """In the forked child: a session of its own, no input, output to `log_path`, then the
    node."""
    os.setsid()
    nothing = os.open(os.devnull, os.O_RDONLY)
    os.dup2(nothing, 0)
    os.close(nothing)
    log = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(log, 1)
    os.dup2(log, 2)
    os.close(log)
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    sys.argv = [executable, *arguments]
    code = 1
    try:
        code = main() or 0
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def serve(requests, answers) -> None:
    """Fork one node per request line; answer each with the child's PID (or an error)."""
    mains = {name: importlib.import_module(module).main for name, module in NODE_MODULES.items()}
    preload(('rclpy', 'hri_core', *{module.split('.')[0] for module in NODE_MODULES.values()}))
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)
    for line in requests:
        executable, log_path, *arguments = json.loads(line)
        if executable not in mains:
            print(json.dumps({'error': f'no node {executable!r}'}), file=answers, flush=True)
            continue
        pid = os.fork()
        if pid == 0:
            run_child(mains[executable], executable, log_path, arguments)
        print(json.dumps({'pid': pid}), file=answers, flush=True)


if __name__ == '__main__':
    serve(sys.stdin, sys.stdout)
