#!/usr/bin/env python3
"""Benchmark of the closed loop sim -> controller -> sim on topics (a measurement, not a test).

Starts the live loop (hri_bringup.processes.start_live_loop: `ros2 run` on its own
ROS_DOMAIN_ID, discovery kept on loopback): scara_sim, event_manager (the paper's tasks as
installed with hri_adaptive_controller, initial task follow), controller and hand_sim (a
circle: centre (0.45, 0.1) m, radius 0.05 m, period 8 s), `--rounds` times (below). Once the
controller reports status 'ok' and `--warmup` s more have passed, two windows of
`--duration / --rounds` s each: first the CPU of
every process with nothing of the probe's on the 1 kHz topics (each reader costs its writer a
send per message), with the controller's own figures (its ControllerStates kept as serialized
CDR and read after the run); then a probe (hri_bringup.processes.RosProbe on the
EventsExecutor, raw subscriptions, SCHED_FIFO) subscribes to /joint_states and the commands
and, after `--warmup` s, listens. Reported:

* /joint_states: achieved rate, and the period between messages from their header stamps
  (the simulated time each state stands for) and from their arrival times in the probe's
  callback: median, p99, max in ms; and the simulated time that passed per wall second
  (below 1 when the sim drops steps);
* the controller, from /hri/controller_state (100 Hz): its achieved rate (rate_hz, its own
  1 s windows), its deadline misses over the window (ticks later than 1.5 periods), and
  input_age (command publication time minus the stamp of the joint state used: the
  /joint_states -> controller -> /effort_controller/commands latency) median, p99, max in ms;
* CPU of each node process and of this probe (user + system time over wall time, psutil, % of
  one core) in the first window, and again with the probe attached (`cpu_percent_probed`);
* the share of the CPUs' time the host took in each window (/proc/stat's steal): a vCPU the
  host stops for a millisecond delays the sim's tick or the controller's answer, which no
  scheduling inside the machine can prevent;
* the sim's own count of late ticks and dropped steps over its whole run (its exit line);
* joint state -> command as this probe sees it: for each /joint_states message, the time from
  its arrival to the arrival of the next /effort_controller/commands, median, p99, max;
  deadline misses: states with no command within 1.5 ms; cycles without control: states
  followed by another state before any command.

Alternated with the loop, in the same run, the transport floor: a trivial rclpy echo
(bench/echo_node.py, the controller's executor and QoS; on `--echo-domain-id`, started once and
idle between its windows) answers JointState pings sent at 1 kHz. The run goes in `--rounds`
rounds; in each, for each checkout (`--tree`, repeatable; default this one) in turn (the
order reversed every other round), an echo
window of `--echo-seconds / --rounds` s and right after it that checkout's loop, started for
its windows and stopped after them (a loop paused for the echo instead would outlive Fast
DDS's 3 s lease and lose its matches). The echo's round trip (median, p99, max) and CPU are
reported, and the ratio of the loop's joint state -> command p99 to the echo's round-trip
p99, and of the controller's and the sim's CPU to the echo's, from the windows pooled; and
per round (`rounds`) with the ratio's min / median / max (`latency_p99_ratio_rounds`). A
shared machine's speed changes from hour to hour and from minute to minute (the echo took
20.7 % of a core at 04:00 here, 28-33 % at noon the same day; one echo window measured before
the loop once gave the Panda a p99 ratio of 1.35 and, in another run, 2.6): windows that
alternate see the same host. `--tree PATH` starts that checkout's nodes in the environment its
scripts/env.sh gives (its .venv and install/), with this script's parameters; given twice
(an old and a new main) the figures of each are under `trees`, the first's also at the top.
`--load N` starts N busy processes (normal priority) before both measurements and ends them
after (by PID). The probe and the echo ask for SCHED_FIFO (`--probe-priority`, as the nodes
do) so that a starved probe does not measure its own delays; the probe asks with
SCHED_RESET_ON_FORK, so the nodes it starts do not inherit its priority (before, hand_sim and
the event_manager ran at SCHED_FIFO 50 too, where the loop's threads could not preempt their
100 Hz work). The nodes run as on a machine that runs the loop alone: SCHED_FIFO
(`--realtime-priority`) and idle CPUs kept polling (`--cpu-wakeup-latency`, held by the echo
node too); both at 0 and -1 measure the config defaults.

`--robot panda` runs the same loop with the 7-joint Panda: arm_sim robot:=panda in place of
scara_sim and the controller robot:=panda (arm_law), with a 3-D hand (hand_sim dimension 3:
back and forth between (0.40, 0.10, 0.45) and (0.40, -0.10, 0.30) m, period 10 s); the
event_manager and the controller start first, then the sim, then the hand (as
tests/test_panda_loop.py starts them). The figures are the same, the sim's named arm_sim.
The controller keeps its default whole-body clearance (0.1 m; `--clearance 0` turns it off):
hand_sim's scripted person (its right wrist the hand) comes on /human/body at 100 Hz and
every cycle measures the arm's capsules against the person's.

Every process started is ended (SIGINT, then SIGKILL by PID) in a `finally`; the
`sim_summary` sums the sims of every round (each one's whole run, start included).
Run it in the project's environment: `source scripts/env.sh; python bench/bench_loop.py`.
`--json` prints the figures as one JSON object only.
"""

import argparse
import contextlib
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT / 'bench'))

import numpy as np  # noqa: E402
import psutil  # noqa: E402
from bench_sim import SUMMARY, node_process, period_statistics  # noqa: E402
from hri_interfaces.msg import ControllerState  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

from hri_bringup.processes import (  # noqa: E402
    LIVE_LOOP_EXECUTABLES,
    READY_LINES,
    RosProbe,
    live_loop_parameters,
    not_logged,
    start_live_loop,
    start_node,
    stop_all,
    wait_for,
    wait_until_logged,
)
from hri_core.cdr import read_stamp  # noqa: E402
from hri_core.realtime import request_sched_fifo  # noqa: E402
from hri_core.topics import COMMAND_QOS, MONITOR_QOS  # noqa: E402

HAND = {'profile': 'circle', 'start': [0.45, 0.1], 'radius': 0.05, 'period': 8.0}
# The Panda's hand: 0.25 m back and forth, 0.15 m down in z, peak 0.079 m/s (its tool starts
# at (0.31, 0, 0.49) m).
PANDA_HAND = {'profile': 'back_and_forth', 'dimension': 3, 'start': [0.40, 0.10, 0.45],
              'end': [0.40, -0.10, 0.30], 'period': 10.0}
SIMS = {'scara': 'scara_sim', 'panda': 'arm_sim'}  # the sim node of each --robot
JOINT_STATE_PROBE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
CONTROL_RATE_HZ = 1000.0  # the controller's default rate_hz
DEADLINE_S = 1.5e-3  # a command later than this after its joint state misses its deadline
ECHO = REPO_ROOT / 'bench' / 'echo_node.py'
BUSY_LOOP = 'while True: pass'


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='seconds measured of each kind (the loop alone, the loop probed, '
                        'the echo), split over --rounds windows')
    parser.add_argument('--rounds', type=int, default=5,
                        help='echo and loop windows, alternated: each loop window follows an '
                        'echo window of its own (default 5: 4 s each with --duration 20)')
    parser.add_argument('--tree', action='append', default=[], metavar='PATH',
                        help='a checkout (set up) whose nodes to run; repeat it to alternate '
                        'several in one run (default: this checkout)')
    parser.add_argument('--domain-id', type=int, default=90, help='ROS_DOMAIN_ID of the loop')
    parser.add_argument('--echo-domain-id', type=int, default=None,
                        help='ROS_DOMAIN_ID of the echo (default: --domain-id + 1)')
    parser.add_argument('--warmup', type=float, default=1.0,
                        help="seconds after the controller's first 'ok' that are not measured")
    parser.add_argument('--startup-timeout', type=float, default=30.0,
                        help="seconds to wait for the controller's status 'ok'")
    parser.add_argument('--echo-seconds', type=float, default=None,
                        help='seconds of the echo floor, split over the rounds (default: '
                        '--duration; 0 skips it)')
    parser.add_argument('--load', type=int, default=0,
                        help='busy processes (normal priority) running during the measurements')
    parser.add_argument('--realtime-priority', type=int, default=50,
                        help="scara_sim's and the controller's realtime_priority (0: off, "
                        'their config default; the bench measures the loop as a machine that '
                        'runs it alone would, with SCHED_FIFO)')
    parser.add_argument('--cpu-wakeup-latency', type=int, default=0,
                        help="scara_sim's and the controller's cpu_wakeup_latency (us; -1: "
                        'off, their config default; 0: idle CPUs poll), which the echo node '
                        'holds too: the loop as a machine that runs it alone would run it')
    parser.add_argument('--probe-priority', type=int, default=50,
                        help='SCHED_FIFO priority of this probe and of the echo node (0: off), '
                        'so that a starved probe does not measure itself')
    parser.add_argument('--robot', choices=tuple(SIMS), default='scara',
                        help='the arm of the loop: scara (scara_sim, the planar law) or panda '
                        '(arm_sim and the controller robot:=panda, a 3-D hand)')
    parser.add_argument('--clearance', type=float, default=None,
                        help="the controller's clearance (m; 0: off; default: the "
                        "controller's, 0.1): every link keeps off the scripted person "
                        "hand_sim publishes on /human/body")
    parser.add_argument('--json', action='store_true', help='print JSON only')
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error('--rounds must be at least 1')
    if args.echo_domain_id is None:
        args.echo_domain_id = args.domain_id + 1
    return args


def _clearance(clearance: float | None) -> dict:
    """The controller's clearance parameter as given ({} for None: its default)."""
    return {} if clearance is None else {'clearance': clearance}


def start_panda_loop(domain_id: int, realtime: dict, log_dir: Path,
                     timeout: float, clearance: float | None = None) -> dict:
    """The Panda's loop: event_manager (follow) and controller robot:=panda, then, once both
    are up, arm_sim robot:=panda, then hand_sim in 3-D (PANDA_HAND); `realtime` (the
    scheduling parameters) for the controller and the sim; the controller's `clearance` (m;
    None: its default). {name: process}; on any error nothing is left running."""
    parameters = live_loop_parameters({'hand_sim': PANDA_HAND,
                                       'controller': {'robot': 'panda', **realtime,
                                                      **_clearance(clearance)}})
    started = {}
    try:
        for name in ('event_manager', 'controller'):
            package, executable = LIVE_LOOP_EXECUTABLES[name]
            started[name] = start_node(package, executable, domain_id,
                                       params=parameters[name], log_dir=log_dir)
        expected = {process: READY_LINES[name] for name, process in started.items()}
        if not wait_until_logged(expected, timeout):
            late = [name for name, p in started.items() if p in not_logged(expected)]
            raise SystemExit(f'bench_loop: {", ".join(late)} did not start within '
                             f'{timeout:g} s; logs in {log_dir}')
        started['arm_sim'] = start_node('scara_sim', 'arm_sim', domain_id,
                                        params={'robot': 'panda', **realtime}, log_dir=log_dir)
        started['hand_sim'] = start_node('scara_sim', 'hand_sim', domain_id,
                                         params=parameters['hand_sim'], log_dir=log_dir)
    except BaseException:
        stop_all(started.values())
        raise
    return started


class RawMessages:
    """A topic's serialized messages as they arrive (a raw subscription: the probe builds no
    Python message while it measures; with /hri/controller_state's 100 Hz taken as messages the
    probe used 1.9-2.6 % of a core at its SCHED_FIFO priority, raw 1.3-2.0 %, six runs each);
    `messages` deserialises them afterwards."""

    def __init__(self, msg_type):
        self.msg_type = msg_type
        self.raw: list[bytes] = []

    def __call__(self, data: bytes) -> None:
        self.raw.append(data)

    def __len__(self) -> int:
        return len(self.raw)

    def messages(self, start: int = 0, stop: int | None = None) -> list:
        return [deserialize_message(data, self.msg_type) for data in self.raw[start:stop]]


class ArrivalTimes:
    """Arrival times (ns, taken in the callback) of a topic while `recording` is set."""

    def __init__(self, recording: threading.Event):
        self.received: list[int] = []
        self.recording = recording

    def __call__(self, msg: bytes) -> None:
        if self.recording.is_set():
            self.received.append(time.time_ns())


def latency_samples(states_ns, commands_ns) -> dict:
    """Joint state -> command as the probe sees it in one window (see the module docstring):
    the latencies of the answered states (s), the misses and the states without control."""
    states, commands = np.sort(states_ns), np.sort(commands_ns)
    if states.size == 0 or commands.size == 0:
        return {'states': int(states.size), 'commands': int(commands.size),
                'latency_s': np.array([]), 'misses': int(states.size),
                'without_control': int(states.size)}
    following = np.searchsorted(commands, states, side='right')
    answered = following < commands.size
    latency = (commands[np.minimum(following, commands.size - 1)] - states) * 1e-9
    next_state = np.append(states[1:], np.iinfo(np.int64).max)
    controlled = answered & (commands[np.minimum(following, commands.size - 1)] < next_state)
    return {'states': int(states.size), 'commands': int(commands.size),
            'latency_s': latency[answered],
            'misses': int(np.sum(~answered | (latency > DEADLINE_S))),
            'without_control': int(np.sum(~controlled))}


def command_latency(windows: list[dict]) -> dict:
    """latency_samples of several windows, pooled."""
    states = sum(w['states'] for w in windows)
    if states == 0 or not any(w['commands'] for w in windows):
        return {'states': states, 'commands': sum(w['commands'] for w in windows)}
    misses = sum(w['misses'] for w in windows)
    return {'states': states, 'commands': sum(w['commands'] for w in windows),
            'latency': spread_ms(np.concatenate([w['latency_s'] for w in windows])),
            'deadline_misses': misses,
            'deadline_miss_percent': round(100.0 * misses / states, 3),
            'without_control_percent': round(
                100.0 * sum(w['without_control'] for w in windows) / states, 3)}


def start_load(count: int) -> list[subprocess.Popen]:
    """`count` busy processes at normal priority (ended by end_processes)."""
    return [subprocess.Popen([sys.executable, '-c', BUSY_LOOP], stderr=subprocess.DEVNULL)
            for _ in range(count)]


def end_processes(processes) -> None:
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


class EchoFloor:
    """The transport floor: bench/echo_node.py (asking for SCHED_FIFO at `priority` and holding
    `wakeup_latency` as the loop's nodes do) on `domain_id`, started once and kept up for the
    whole run; `window(seconds)` pings it at 1 kHz and returns that window's round trips and
    the echo's CPU. Between windows it idles (spin_once every 0.1 s: no 1 kHz work)."""

    def __init__(self, domain_id: int, priority: int, wakeup_latency: int):
        env = {**os.environ, 'ROS_DOMAIN_ID': str(domain_id),
               'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
        self.echo = subprocess.Popen([sys.executable, str(ECHO), str(priority),
                                      str(wakeup_latency)], env=env,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.probe = None
        self.round_trips: list[int] = []
        self.recording = threading.Event()
        try:
            self.probe = RosProbe(domain_id, name='bench_echo_probe')
            self.probe.node.create_subscription(JointState, '/bench/pong', self._on_pong,
                                                COMMAND_QOS)
            self.ping = self.probe.publisher('/bench/ping', JointState, JOINT_STATE_PROBE_QOS)
            if not wait_for(lambda: self.ping.get_subscription_count() > 0, 30.0):
                raise SystemExit('bench_loop: the echo node did not come up in 30 s')
            self.process = psutil.Process(self.echo.pid)
        except BaseException:
            self.close()
            raise

    def _on_pong(self, msg, info):
        if self.recording.is_set():
            sent = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            self.round_trips.append((info.get('received_timestamp') or time.time_ns()) - sent)

    def window(self, seconds: float, warmup: float = 0.5) -> dict:
        """Pings at 1 kHz for `warmup` + `seconds` s; the round trips (s, an array) and CPU of
        the last `seconds`."""
        msg = JointState(name=['joint1', 'joint2'], position=[0.1, 0.2], velocity=[0.0, 0.0],
                         effort=[0.0, 0.0])
        self.round_trips = []
        start = time.monotonic()
        sent = 0
        cpu_before = wall_before = None
        while True:
            now = time.monotonic()
            if cpu_before is None and now - start >= warmup:
                cpu_before, wall_before = cpu_seconds(self.process), now
                self.recording.set()
            if now - start >= warmup + seconds:
                break
            stamp = time.time_ns()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
            self.ping.publish(msg)
            sent += 1
            time.sleep(max(0.0, start + sent * 1e-3 - time.monotonic()))
        self.recording.clear()
        wall = time.monotonic() - wall_before
        cpu = cpu_seconds(self.process) - cpu_before
        return {'trips_s': np.array(self.round_trips) * 1e-9, 'wall': wall, 'cpu': cpu}

    def close(self) -> None:
        if self.probe is not None:
            self.probe.close()
        end_processes([self.echo])


def echo_figures(windows: list[dict]) -> dict:
    """The echo's figures over `windows` (EchoFloor.window's), their round trips pooled."""
    trips = np.concatenate([w['trips_s'] for w in windows])
    wall = sum(w['wall'] for w in windows)
    return {'seconds': round(wall, 3), 'windows': len(windows), 'round_trips': int(trips.size),
            'answered_rate_hz': round(trips.size / wall, 1),
            'round_trip': spread_ms(trips),
            'cpu_percent': round(100.0 * sum(w['cpu'] for w in windows) / wall, 1)}


class JointStateTimes:
    """Header stamps and receive times (ns) of /joint_states while `recording` is set."""

    def __init__(self):
        self.stamps: list[int] = []
        self.received: list[int] = []
        self.recording = threading.Event()

    def __call__(self, msg: bytes) -> None:
        # The message is its serialized CDR (a raw subscription: no Python message is built,
        # so the probe stays light): the 4-byte encapsulation header, then header.stamp's sec
        # (int32) and nanosec (uint32). The arrival time is taken here: rclpy 7.1's
        # EventsExecutor fails on callbacks that take the MessageInfo ("SystemError: null
        # argument to internal routine"), so the middleware's receive timestamp is not at hand.
        if self.recording.is_set():
            received = time.time_ns()
            sec, nanosec = read_stamp(msg)
            self.stamps.append(sec * 10**9 + nanosec)
            self.received.append(received)


def spread_ms(values_s: np.ndarray) -> dict:
    """Median, p99 and max of `values_s` (s), in ms."""
    if values_s.size == 0:
        return {'median_ms': None, 'p99_ms': None, 'max_ms': None}
    values = values_s * 1e3
    return {'median_ms': round(float(np.median(values)), 4),
            'p99_ms': round(float(np.percentile(values, 99)), 4),
            'max_ms': round(float(values.max()), 4)}


def cpu_seconds(process: psutil.Process) -> float:
    times = process.cpu_times()
    return times.user + times.system


def machine_times() -> tuple[int, int]:
    """(time stolen by the host, all time) of every CPU so far, in clock ticks
    (/proc/stat: user, nice, system, idle, iowait, irq, softirq, steal)."""
    with open('/proc/stat') as stat:
        fields = [int(v) for v in stat.readline().split()[1:9]]
    return fields[7], sum(fields)


def cpu_used(processes: dict, seconds: float) -> tuple[dict, float, tuple[int, int]]:
    """({name: CPU seconds over the next `seconds`}, wall seconds measured, (ticks the host
    stole, all ticks) meanwhile)."""
    machine = machine_times()
    before = {name: cpu_seconds(p) for name, p in processes.items()}
    start = time.monotonic()
    time.sleep(seconds)
    after = {name: cpu_seconds(p) for name, p in processes.items()}
    wall = time.monotonic() - start
    now = machine_times()
    return ({name: after[name] - before[name] for name in processes}, wall,
            (now[0] - machine[0], now[1] - machine[1]))


def pooled_periods(times: list[np.ndarray]) -> dict:
    """period_statistics over several windows (ns): the differences within each, pooled
    (none across two windows, which are seconds apart)."""
    periods = [np.diff(np.sort(t)) for t in times if t.size > 1]
    if not periods:
        return period_statistics(np.array([]))
    return spread_ms(np.concatenate(periods) * 1e-9)


@contextlib.contextmanager
def environment(env: dict | None):
    """os.environ replaced by `env` (None: unchanged) while the block runs: the nodes started
    in it (hri_bringup.processes copies os.environ) run from another checkout."""
    if env is None:
        yield
        return
    saved = dict(os.environ)
    os.environ.clear()
    os.environ.update(env)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved)


def tree_environment(tree: Path) -> dict:
    """The environment `source TREE/scripts/env.sh` gives (its .venv, its install/, its Fast
    DDS profile), taken from a clean shell so that nothing of this checkout's leaks in; the
    tree must have been set up (its scripts/setup.sh)."""
    if not (tree / 'install' / 'setup.bash').is_file() or \
            not (tree / '.venv' / 'bin' / 'python').exists():
        raise SystemExit(f'bench_loop: {tree} is not set up: run its scripts/setup.sh first')
    shell = f'source {shlex.quote(str(tree / "scripts" / "env.sh"))} >/dev/null && env -0'
    clean = {'HOME': os.environ.get('HOME', '/root'), 'PATH': os.defpath.lstrip(':')
             or '/usr/bin:/bin', 'HRI_SKIP_SETUP': '1'}
    output = subprocess.run(['bash', '-c', shell], env=clean, capture_output=True,
                            check=True).stdout.decode()
    env = dict(item.split('=', 1) for item in output.split('\0') if '=' in item)
    env.pop('HRI_SKIP_SETUP', None)
    return env


def loop_window(args: argparse.Namespace, seconds: float, env: dict | None,
                log_dir: Path) -> dict:
    """Start the loop (from `env`'s checkout; None: this one), wait for the controller's 'ok'
    and `--warmup` s, then two windows of `seconds`: the CPU with nothing of the probe's on
    the 1 kHz topics (a reader of a topic costs its writer a send per message, which would be
    charged to the loop), then with the probe's raw subscriptions (after `--warmup` s more)
    the latency; stop the loop. The window's raw figures."""
    started = {}
    probe = None
    joint_times = JointStateTimes()
    command_times = ArrivalTimes(joint_times.recording)
    states = RawMessages(ControllerState)
    try:
        # The EventsExecutor and raw subscriptions: a probe that takes little CPU from the
        # loop it measures (with a SingleThreadedExecutor and messages, 81 % of a core).
        probe = RosProbe(args.domain_id, name='bench_loop_probe', executor=EventsExecutor)
        probe.node.create_subscription(ControllerState, '/hri/controller_state', states,
                                       MONITOR_QOS, raw=True)

        def status() -> str | None:
            return states.messages(-1)[0].status if len(states) else None

        realtime = {'realtime_priority': args.realtime_priority,
                    'cpu_wakeup_latency': args.cpu_wakeup_latency}
        with environment(env):
            if args.robot == 'panda':
                started = start_panda_loop(args.domain_id, realtime, log_dir,
                                           args.startup_timeout, args.clearance)
            else:
                overrides = {'hand_sim': HAND, 'scara_sim': realtime,
                             'controller': {**realtime, **_clearance(args.clearance)}}
                started = start_live_loop(args.domain_id, overrides, log_dir=log_dir)
        if not wait_for(lambda: status() == 'ok', args.startup_timeout):
            last = status() or 'no ControllerState at all'
            raise SystemExit(f"bench_loop: the controller's status is not 'ok' after "
                             f'{args.startup_timeout:g} s ({last}); logs in {log_dir}')
        time.sleep(args.warmup)
        processes = {name: node_process(psutil.Process(node.pid), name)
                     for name, node in started.items()}
        processes['probe'] = psutil.Process()
        first_state = len(states)
        cpu, wall, steal = cpu_used(processes, seconds)
        window_end = len(states)
        probe.node.create_subscription(JointState, '/joint_states', joint_times,
                                       JOINT_STATE_PROBE_QOS, raw=True)
        probe.node.create_subscription(Float64MultiArray, '/effort_controller/commands',
                                       command_times, COMMAND_QOS, raw=True)
        time.sleep(args.warmup)
        joint_times.recording.set()
        cpu_probed, probed_wall, steal_probed = cpu_used(processes, seconds)
        joint_times.recording.clear()
        dead = [name for name, node in started.items() if not node.alive()]
        if dead:
            raise SystemExit(f'bench_loop: {", ".join(dead)} ended during the measurement; '
                             f'logs in {log_dir}')
    finally:
        if probe is not None:
            probe.close()
        for node in reversed(list(started.values())):
            node.stop(timeout=10.0)
    received = np.array(joint_times.received)
    window = {'cpu': cpu, 'wall': wall, 'steal': steal, 'cpu_probed': cpu_probed,
              'probed_wall': probed_wall, 'steal_probed': steal_probed,
              'states': states.messages(first_state, window_end),
              'stamps': np.array(joint_times.stamps), 'received': received,
              'latency': latency_samples(received, np.array(command_times.received)),
              'pids': {name: p.pid for name, p in processes.items()}}
    match = SUMMARY.search(started[SIMS[args.robot]].log())
    if match:
        window['sim_summary'] = [int(v) if v.isdigit() else float(v) for v in match.groups()]
    return window


def percent(numerator: float, denominator: float, digits: int = 1) -> float | None:
    return round(100.0 * numerator / denominator, digits) if denominator > 0 else None


def loop_figures(args: argparse.Namespace, pairs: list[tuple[dict | None, dict]]) -> dict:
    """One checkout's figures from its (echo window, loop window) pairs: the loop's pooled over
    its windows, the echo's over the windows run just before them, the p99 ratio of the pooled
    figures, and each pair's own figures (`rounds`: how far the ratio moves within the run)."""
    loops = [loop for _, loop in pairs]
    echoes = [echo for echo, _ in pairs if echo is not None]
    wall = sum(w['wall'] for w in loops)
    probed_wall = sum(w['probed_wall'] for w in loops)
    names = loops[0]['cpu']
    cpu = {name: percent(sum(w['cpu'][name] for w in loops), wall) for name in names}
    cpu_probed = {name: percent(sum(w['cpu_probed'][name] for w in loops), probed_wall)
                  for name in names}
    window = [state for w in loops for state in w['states']]
    ok = [s for s in window if s.status == 'ok']
    rates = np.array([s.rate_hz for s in window if s.rate_hz > 0.0])
    misses = sum(w['states'][-1].deadline_misses - w['states'][0].deadline_misses
                 for w in loops if w['states'])
    stamps = [w['stamps'] for w in loops]
    received = [w['received'] for w in loops]
    # Simulated time per received wall time: below 1 when the sim drops steps.
    spans = [(float(s.max() - s.min()), float(r.max() - r.min()))
             for s, r in zip(stamps, received, strict=True) if r.size > 1]
    receive_span = sum(r for _, r in spans)
    realtime = sum(s for s, _ in spans) / receive_span if receive_span else None
    messages = sum(s.size for s in stamps)
    result = {
        'duration_s': round(wall, 3),
        'windows': len(loops),
        'window_s': round(wall / len(loops), 3),
        'robot': args.robot,
        'hand': PANDA_HAND if args.robot == 'panda' else HAND,
        'joint_states': {
            'messages': int(messages),
            'achieved_rate_hz': round(messages / probed_wall, 1),
            'sim_realtime_factor': round(realtime, 4) if realtime is not None else None,
            'stamp_period': pooled_periods(stamps),
            'receive_period': pooled_periods(received),
        },
        'controller': {
            'state_messages': len(window),
            'ok_fraction': round(len(ok) / len(window), 4) if window else None,
            'rate_hz_median': round(float(np.median(rates)), 1) if rates.size else None,
            'rate_hz_min': round(float(rates.min()), 1) if rates.size else None,
            'deadline_misses': misses,
            'deadline_miss_percent': round(100.0 * misses / (wall * CONTROL_RATE_HZ), 3),
            'input_age': spread_ms(np.array([s.input_age for s in ok])),
        },
        'cpu_percent': cpu,
        'cpu_percent_probed': cpu_probed,
        'host_steal_percent': percent(sum(w['steal'][0] for w in loops),
                                      sum(w['steal'][1] for w in loops), 2),
        'host_steal_percent_probed': percent(sum(w['steal_probed'][0] for w in loops),
                                             sum(w['steal_probed'][1] for w in loops), 2),
        'load_processes': args.load,
        'realtime_priority': args.realtime_priority,
        'cpu_wakeup_latency': args.cpu_wakeup_latency,
        'state_to_command': command_latency([w['latency'] for w in loops]),
        'echo': echo_figures(echoes) if echoes else None,
        'pids': loops[-1]['pids'],
        'cpu_count': psutil.cpu_count(),
    }
    sim = SIMS[args.robot]
    rounds = []
    for echo, loop in pairs:
        latency = loop['latency']['latency_s']
        entry = {'loop_p99_ms': spread_ms(latency)['p99_ms'],
                 'controller_cpu': percent(loop['cpu']['controller'], loop['wall']),
                 'sim_cpu': percent(loop['cpu'][sim], loop['wall'])}
        if echo is not None and echo['trips_s'].size:
            entry['echo_p99_ms'] = spread_ms(echo['trips_s'])['p99_ms']
            entry['echo_cpu'] = percent(echo['cpu'], echo['wall'])
            if entry['loop_p99_ms'] is not None:
                entry['p99_ratio'] = round(entry['loop_p99_ms'] / entry['echo_p99_ms'], 3)
        rounds.append(entry)
    result['rounds'] = rounds
    loop_p99 = result['state_to_command'].get('latency', {}).get('p99_ms')
    echo = result['echo']
    if echo is not None and loop_p99 is not None and echo['round_trip']['p99_ms']:
        result['latency_p99_ratio'] = round(loop_p99 / echo['round_trip']['p99_ms'], 3)
        ratios = [r['p99_ratio'] for r in rounds if 'p99_ratio' in r]
        if ratios:
            result['latency_p99_ratio_rounds'] = {
                'min': min(ratios), 'median': round(float(np.median(ratios)), 3),
                'max': max(ratios)}
    if echo is not None and echo.get('cpu_percent'):
        result['cpu_vs_echo'] = {name: round(cpu[name] / echo['cpu_percent'], 2)
                                 for name in ('controller', sim) if name in cpu}
    summaries = [w['sim_summary'] for w in loops if 'sim_summary' in w]
    if summaries:
        steps, ticks, seconds, late, dropped = (sum(column) for column
                                                in zip(*summaries, strict=True))
        result['sim_summary'] = {'steps': steps, 'ticks': ticks,
                                 'sim_time_s': round(seconds, 3), 'late_ticks': late,
                                 'dropped_steps': dropped}
    return result


def run(args: argparse.Namespace) -> dict:
    if shutil.which('ros2') is None:
        raise SystemExit('bench_loop: no `ros2` on PATH; run `source scripts/env.sh` first')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    trees = [Path(tree).resolve() for tree in args.tree] or [REPO_ROOT]
    envs = {tree: None if tree == REPO_ROOT else tree_environment(tree) for tree in trees}
    log_dir = Path(tempfile.mkdtemp(prefix='bench-loop-'))
    echo_seconds = args.duration if args.echo_seconds is None else args.echo_seconds
    pairs: dict[Path, list] = {tree: [] for tree in trees}
    load = start_load(args.load)
    echo = None
    try:
        # Before any probe exists: its threads, and those the probes start, inherit it.
        scheduling = request_sched_fifo(args.probe_priority, reset_on_fork=True)
        if echo_seconds > 0:
            echo = EchoFloor(args.echo_domain_id, args.probe_priority,
                             args.cpu_wakeup_latency)
        # Round after round, each checkout's loop window just after an echo window of its
        # own: the host's speed, which moves from minute to minute here, is then the same
        # for both sides of each ratio.
        # The order of the checkouts turns round from one round to the next: with one
        # order, the second's state -> command median read 10-20 us more whichever it was.
        for round_index in range(args.rounds):
            for tree in trees if round_index % 2 == 0 else trees[::-1]:
                floor = echo.window(echo_seconds / args.rounds) if echo else None
                pairs[tree].append((floor, loop_window(args, args.duration / args.rounds,
                                                       envs[tree], log_dir)))
    finally:
        if echo is not None:
            echo.close()
        end_processes(load)
    figures = {}
    for tree in trees:
        figures[str(tree)] = {**loop_figures(args, pairs[tree]), 'tree': str(tree),
                              'probe_scheduling': scheduling.description}
    result = dict(figures[str(trees[0])])
    result['rounds_run'] = args.rounds
    if len(trees) > 1:
        result['trees'] = figures
    shutil.rmtree(log_dir, ignore_errors=True)  # kept (and named) only when the run failed
    return result


def print_report(result: dict) -> None:
    joints, controller = result['joint_states'], result['controller']
    print(f'/joint_states    {joints["achieved_rate_hz"]} Hz received ({joints["messages"]} in '
          f'{result["duration_s"]} s; sim time / wall time {joints["sim_realtime_factor"]})')
    for key in ('stamp_period', 'receive_period'):
        stats = joints[key]
        print(f'  {key:15s} median {stats["median_ms"]} ms, p99 {stats["p99_ms"]} ms, '
              f'max {stats["max_ms"]} ms')
    age = controller['input_age']
    print(f'controller       rate {controller["rate_hz_median"]} Hz median, '
          f'{controller["rate_hz_min"]} min; {controller["deadline_misses"]} deadline misses '
          f'({controller["deadline_miss_percent"]} %); status ok '
          f'{controller["ok_fraction"]}')
    print(f'  input_age      median {age["median_ms"]} ms, p99 {age["p99_ms"]} ms, '
          f'max {age["max_ms"]} ms')
    print('CPU              ' + ', '.join(f'{name} {value} %'
                                          for name, value in result['cpu_percent'].items())
          + f' (% of one core; {result["cpu_count"]} cores)')
    print('  probe attached ' + ', '.join(f'{name} {value} %' for name, value
                                          in result['cpu_percent_probed'].items()))
    print(f'host steal       {result["host_steal_percent"]} % of the CPUs\' time, '
          f'{result["host_steal_percent_probed"]} % with the probe attached')
    link = result['state_to_command']
    if 'latency' in link:
        lat = link['latency']
        print(f'state -> command median {lat["median_ms"]} ms, p99 {lat["p99_ms"]} ms, max '
              f'{lat["max_ms"]} ms (probe); deadline misses {link["deadline_miss_percent"]} %, '
              f'without control {link["without_control_percent"]} % of {link["states"]} states')
    echo = result['echo']
    if echo is not None:
        trip = echo['round_trip']
        spread = result.get('latency_p99_ratio_rounds')
        print(f'echo floor       round trip median {trip["median_ms"]} ms, p99 '
              f'{trip["p99_ms"]} ms, max {trip["max_ms"]} ms; echo CPU {echo["cpu_percent"]} %; '
              f'loop p99 / echo p99 = {result.get("latency_p99_ratio")} pooled'
              + (f', {spread["min"]}-{spread["max"]} over the rounds (median '
                 f'{spread["median"]})' if spread else ''))
        print('  CPU / echo CPU ' + ', '.join(
            f'{name} {value}' for name, value in result.get('cpu_vs_echo', {}).items()))
    print(f'windows          {result["rounds_run"]} rounds of an echo window then a loop window '
          f'per checkout, {result["window_s"]} s each; {result["tree"]}')
    for tree, figures in result.get('trees', {}).items():
        latency = figures['state_to_command'].get('latency', {})
        print(f'  {tree}: p99 {latency.get("p99_ms")} ms, ratio '
              f'{figures.get("latency_p99_ratio")} ({figures.get("latency_p99_ratio_rounds")}), '
              f'controller {figures["cpu_percent"].get("controller")} %')
    print(f'load processes   {result["load_processes"]}')
    if 'sim_summary' in result:
        summary = result['sim_summary']
        print(f'sim timing       {summary["steps"]} steps in {summary["ticks"]} ticks, '
              f'{summary["late_ticks"]} late ticks, {summary["dropped_steps"]} dropped steps '
              '(whole run)')


def main(argv=None) -> int:
    args = parse_arguments(argv)
    result = run(args)
    if args.json:
        print(json.dumps(result))
    else:
        print_report(result)
    return 0


if __name__ == '__main__':
    sys.exit(main())
