#!/usr/bin/env python3
"""Benchmark of the closed loop sim -> controller -> sim on topics (a measurement, not a test).

Starts the live loop (hri_bringup.processes.start_live_loop: `ros2 run` on its own
ROS_DOMAIN_ID, discovery kept on loopback): scara_sim, event_manager (the paper's tasks as
installed with hri_adaptive_controller, initial task follow), controller and hand_sim (a
circle: centre (0.45, 0.1) m, radius 0.05 m, period 8 s). Once the controller reports status
'ok' and `--warmup` s more have passed, two windows of `--duration` s each: first the CPU of
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

Before the loop, in the same run, the transport floor: a trivial rclpy echo (bench/echo_node.py,
the controller's executor and QoS) answers JointState pings sent at 1 kHz for `--echo-seconds`;
its round trip (median, p99, max) and CPU are reported, and the ratio of the loop's joint state
-> command p99 to the echo's round-trip p99, and of the controller's and scara_sim's CPU to
the echo's: a shared machine's speed changes from hour to hour (the echo took 20.7 % of a
core at 04:00 here, 28-33 % at noon the same day), which the ratios take out in part.
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

Every process started is ended (SIGINT, then SIGKILL by PID) in a `finally`.
Run it in the project's environment: `source scripts/env.sh; python bench/bench_loop.py`.
`--json` prints the figures as one JSON object only.
"""

import argparse
import json
import os
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
    parser.add_argument('--duration', type=float, default=20.0, help='seconds measured')
    parser.add_argument('--domain-id', type=int, default=90, help='ROS_DOMAIN_ID to use')
    parser.add_argument('--warmup', type=float, default=1.0,
                        help="seconds after the controller's first 'ok' that are not measured")
    parser.add_argument('--startup-timeout', type=float, default=30.0,
                        help="seconds to wait for the controller's status 'ok'")
    parser.add_argument('--echo-seconds', type=float, default=None,
                        help='seconds of the echo floor (default: --duration; 0 skips it)')
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
    parser.add_argument('--json', action='store_true', help='print JSON only')
    return parser.parse_args(argv)


def start_panda_loop(domain_id: int, realtime: dict, log_dir: Path,
                     timeout: float) -> dict:
    """The Panda's loop: event_manager (follow) and controller robot:=panda, then, once both
    are up, arm_sim robot:=panda, then hand_sim in 3-D (PANDA_HAND); `realtime` (the
    scheduling parameters) for the controller and the sim. {name: process}; on any error
    nothing is left running."""
    parameters = live_loop_parameters({'hand_sim': PANDA_HAND,
                                       'controller': {'robot': 'panda', **realtime}})
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


def command_latency(states_ns, commands_ns) -> dict:
    """Joint state -> command as the probe sees it (see the module docstring)."""
    states, commands = np.sort(states_ns), np.sort(commands_ns)
    if states.size == 0 or commands.size == 0:
        return {'states': int(states.size), 'commands': int(commands.size)}
    following = np.searchsorted(commands, states, side='right')
    answered = following < commands.size
    latency = (commands[np.minimum(following, commands.size - 1)] - states) * 1e-9
    next_state = np.append(states[1:], np.iinfo(np.int64).max)
    controlled = answered & (commands[np.minimum(following, commands.size - 1)] < next_state)
    misses = int(np.sum(~answered | (latency > DEADLINE_S)))
    return {'states': int(states.size), 'commands': int(commands.size),
            'latency': spread_ms(latency[answered]),
            'deadline_misses': misses,
            'deadline_miss_percent': round(100.0 * misses / states.size, 3),
            'without_control_percent': round(100.0 * float(np.mean(~controlled)), 3)}


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


def measure_echo(domain_id: int, seconds: float, priority: int, wakeup_latency: int) -> dict:
    """Round trip of JointState pings at 1 kHz through bench/echo_node.py (the floor), which
    asks for SCHED_FIFO at `priority` and holds `wakeup_latency` as the loop's nodes do."""
    env = {**os.environ, 'ROS_DOMAIN_ID': str(domain_id),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    echo = subprocess.Popen([sys.executable, str(ECHO), str(priority), str(wakeup_latency)],
                            env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    probe = None
    round_trips: list[int] = []
    recording = threading.Event()
    try:
        probe = RosProbe(domain_id, name='bench_echo_probe')
        request_sched_fifo(priority, reset_on_fork=True)

        def on_pong(msg, info):
            if recording.is_set():
                sent = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                round_trips.append((info.get('received_timestamp') or time.time_ns()) - sent)

        probe.node.create_subscription(JointState, '/bench/pong', on_pong, COMMAND_QOS)
        ping = probe.publisher('/bench/ping', JointState, JOINT_STATE_PROBE_QOS)
        if not wait_for(lambda: ping.get_subscription_count() > 0, 30.0):
            raise SystemExit('bench_loop: the echo node did not come up in 30 s')
        msg = JointState(name=['joint1', 'joint2'], position=[0.1, 0.2], velocity=[0.0, 0.0],
                         effort=[0.0, 0.0])
        process = psutil.Process(echo.pid)
        start = time.monotonic()
        sent = 0
        cpu_before = wall_before = None
        while True:
            now = time.monotonic()
            if cpu_before is None and now - start >= 1.0:  # 1 s of warm-up
                cpu_before, wall_before = cpu_seconds(process), now
                recording.set()
            if now - start >= 1.0 + seconds:
                break
            stamp = time.time_ns()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
            ping.publish(msg)
            sent += 1
            time.sleep(max(0.0, start + sent * 1e-3 - time.monotonic()))
        recording.clear()
        wall = time.monotonic() - wall_before
        cpu = cpu_seconds(process) - cpu_before
    finally:
        if probe is not None:
            probe.close()
        end_processes([echo])
    trips = np.array(round_trips) * 1e-9
    return {'seconds': round(wall, 3), 'round_trips': int(trips.size),
            'answered_rate_hz': round(trips.size / wall, 1),
            'round_trip': spread_ms(trips), 'cpu_percent': round(100.0 * cpu / wall, 1)}


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


def steal_percent(before: tuple[int, int], after: tuple[int, int]) -> float | None:
    """The share of the CPUs' time the host took between two machine_times (%)."""
    total = after[1] - before[1]
    return round(100.0 * (after[0] - before[0]) / total, 2) if total > 0 else None


def cpu_percent(processes: dict, seconds: float) -> tuple[dict, float, float | None]:
    """({name: % of one core over the next `seconds`}, wall seconds measured, % of the CPUs'
    time the host stole meanwhile)."""
    machine = machine_times()
    before = {name: cpu_seconds(p) for name, p in processes.items()}
    start = time.monotonic()
    time.sleep(seconds)
    after = {name: cpu_seconds(p) for name, p in processes.items()}
    wall = time.monotonic() - start
    return ({name: round(100.0 * (after[name] - before[name]) / wall, 1)
             for name in processes}, wall, steal_percent(machine, machine_times()))


def run(args: argparse.Namespace) -> dict:
    if shutil.which('ros2') is None:
        raise SystemExit('bench_loop: no `ros2` on PATH; run `source scripts/env.sh` first')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    log_dir = Path(tempfile.mkdtemp(prefix='bench-loop-'))
    started = {}
    probe = None
    joint_times = JointStateTimes()
    command_times = ArrivalTimes(joint_times.recording)
    load = start_load(args.load)
    echo_seconds = args.duration if args.echo_seconds is None else args.echo_seconds
    try:
        echo = (measure_echo(args.domain_id, echo_seconds, args.probe_priority,
                             args.cpu_wakeup_latency)
                if echo_seconds > 0 else None)
        # The EventsExecutor and raw subscriptions: a probe that takes little CPU from the
        # loop it measures (with a SingleThreadedExecutor and messages, 81 % of a core).
        probe = RosProbe(args.domain_id, name='bench_loop_probe', executor=EventsExecutor)
        scheduling = request_sched_fifo(args.probe_priority, reset_on_fork=True)
        states = RawMessages(ControllerState)
        probe.node.create_subscription(ControllerState, '/hri/controller_state', states,
                                       MONITOR_QOS, raw=True)

        def status() -> str | None:
            return states.messages(-1)[0].status if len(states) else None

        realtime = {'realtime_priority': args.realtime_priority,
                    'cpu_wakeup_latency': args.cpu_wakeup_latency}
        if args.robot == 'panda':
            started = start_panda_loop(args.domain_id, realtime, log_dir,
                                       args.startup_timeout)
        else:
            overrides = {'hand_sim': HAND, 'scara_sim': realtime, 'controller': realtime}
            started = start_live_loop(args.domain_id, overrides, log_dir=log_dir)
        if not wait_for(lambda: status() == 'ok', args.startup_timeout):
            last = status() or 'no ControllerState at all'
            raise SystemExit(f"bench_loop: the controller's status is not 'ok' after "
                             f'{args.startup_timeout:g} s ({last}); logs in {log_dir}')
        time.sleep(args.warmup)
        processes = {name: node_process(psutil.Process(node.pid), name)
                     for name, node in started.items()}
        processes['probe'] = psutil.Process()
        # CPU first, with nothing of the probe's on the 1 kHz topics: a reader of a topic
        # costs its writer a send per message (a reliable one over UDP: about 13 % of a core
        # at 1 kHz here), which would be charged to the loop.
        first_state = len(states)
        cpu, wall, steal = cpu_percent(processes, args.duration)
        window_end = len(states)
        probe.node.create_subscription(JointState, '/joint_states', joint_times,
                                       JOINT_STATE_PROBE_QOS, raw=True)
        probe.node.create_subscription(Float64MultiArray, '/effort_controller/commands',
                                       command_times, COMMAND_QOS, raw=True)
        time.sleep(args.warmup)
        joint_times.recording.set()
        cpu_probed, probed_wall, steal_probed = cpu_percent(processes, args.duration)
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
        end_processes(load)
    stamps, received = np.array(joint_times.stamps), np.array(joint_times.received)
    window = states.messages(first_state, window_end)
    ok = [s for s in window if s.status == 'ok']
    rates = np.array([s.rate_hz for s in window if s.rate_hz > 0.0])
    misses = window[-1].deadline_misses - window[0].deadline_misses if window else None
    # Simulated time per received wall time: below 1 when the sim drops steps.
    receive_span = float(received.max() - received.min()) if received.size > 1 else 0.0
    realtime = float(stamps.max() - stamps.min()) / receive_span if receive_span else None
    result = {
        'duration_s': round(wall, 3),
        'robot': args.robot,
        'hand': PANDA_HAND if args.robot == 'panda' else HAND,
        'joint_states': {
            'messages': int(stamps.size),
            'achieved_rate_hz': round(stamps.size / probed_wall, 1),
            'sim_realtime_factor': round(realtime, 4) if realtime is not None else None,
            'stamp_period': period_statistics(stamps),
            'receive_period': period_statistics(received),
        },
        'controller': {
            'state_messages': len(window),
            'ok_fraction': round(len(ok) / len(window), 4) if window else None,
            'rate_hz_median': round(float(np.median(rates)), 1) if rates.size else None,
            'rate_hz_min': round(float(rates.min()), 1) if rates.size else None,
            'deadline_misses': misses,
            'deadline_miss_percent': (round(100.0 * misses / (wall * CONTROL_RATE_HZ), 3)
                                      if misses is not None else None),
            'input_age': spread_ms(np.array([s.input_age for s in ok])),
        },
        'cpu_percent': cpu,
        'cpu_percent_probed': cpu_probed,
        'host_steal_percent': steal,
        'host_steal_percent_probed': steal_probed,
        'load_processes': args.load,
        'probe_scheduling': scheduling.description,
        'realtime_priority': args.realtime_priority,
        'cpu_wakeup_latency': args.cpu_wakeup_latency,
        'state_to_command': command_latency(received, np.array(command_times.received)),
        'echo': echo,
        'pids': {name: p.pid for name, p in processes.items()},
        'cpu_count': psutil.cpu_count(),
    }
    loop_p99 = result['state_to_command'].get('latency', {}).get('p99_ms')
    if echo is not None and loop_p99 is not None and echo['round_trip']['p99_ms']:
        result['latency_p99_ratio'] = round(loop_p99 / echo['round_trip']['p99_ms'], 3)
    if echo is not None and echo.get('cpu_percent'):
        result['cpu_vs_echo'] = {name: round(cpu[name] / echo['cpu_percent'], 2)
                                 for name in ('controller', SIMS[args.robot]) if name in cpu}
    match = SUMMARY.search(started[SIMS[args.robot]].log())
    if match:
        steps, ticks, seconds, late, dropped = match.groups()
        result['sim_summary'] = {'steps': int(steps), 'ticks': int(ticks),
                                 'sim_time_s': float(seconds), 'late_ticks': int(late),
                                 'dropped_steps': int(dropped)}
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
        print(f'echo floor       round trip median {trip["median_ms"]} ms, p99 '
              f'{trip["p99_ms"]} ms, max {trip["max_ms"]} ms; echo CPU {echo["cpu_percent"]} %; '
              f'loop p99 / echo p99 = {result.get("latency_p99_ratio")}')
        print('  CPU / echo CPU ' + ', '.join(
            f'{name} {value}' for name, value in result.get('cpu_vs_echo', {}).items()))
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
