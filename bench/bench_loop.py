#!/usr/bin/env python3
"""Benchmark of the closed loop sim -> controller -> sim on topics (a measurement, not a test).

Starts the live loop (hri_bringup.processes.start_live_loop: `ros2 run` on its own
ROS_DOMAIN_ID, discovery kept on loopback): scara_sim, event_manager (the paper's tasks as
installed with hri_adaptive_controller, initial task follow), controller and hand_sim (a
circle: centre (0.45, 0.1) m, radius 0.05 m, period 8 s). Once the controller reports status
'ok' and `--warmup` s more have passed, a probe (hri_bringup.processes.RosProbe) listens for
`--duration` s and reports

* /joint_states: achieved rate, and the period between messages from their header stamps
  (the simulated time each state stands for) and from their receive times (middleware receive
  timestamps): median, p99, max in ms; and the simulated time that passed per wall second
  (below 1 when the sim drops steps);
* the controller, from /hri/controller_state (100 Hz): its achieved rate (rate_hz, its own
  1 s windows), its deadline misses over the window (ticks later than 1.5 periods), and
  input_age (command publication time minus the stamp of the joint state used: the
  /joint_states -> controller -> /effort_controller/commands latency) median, p99, max in ms;
* CPU of each node process and of this probe (user + system time over wall time, psutil, % of
  one core);
* the sim's own count of late ticks and dropped steps over its whole run (its exit line).

Every process started is ended (SIGINT, then SIGKILL by PID) in a `finally`.
Run it in the project's environment: `source scripts/env.sh; python bench/bench_loop.py`.
`--json` prints the figures as one JSON object only.
"""

import argparse
import json
import os
import shutil
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
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from hri_bringup.processes import RosProbe, start_live_loop, wait_for  # noqa: E402
from hri_core.topics import MONITOR_QOS  # noqa: E402

HAND = {'profile': 'circle', 'start': [0.45, 0.1], 'radius': 0.05, 'period': 8.0}
JOINT_STATE_PROBE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
CONTROL_RATE_HZ = 1000.0  # the controller's default rate_hz


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=20.0, help='seconds measured')
    parser.add_argument('--domain-id', type=int, default=90, help='ROS_DOMAIN_ID to use')
    parser.add_argument('--warmup', type=float, default=1.0,
                        help="seconds after the controller's first 'ok' that are not measured")
    parser.add_argument('--startup-timeout', type=float, default=30.0,
                        help="seconds to wait for the controller's status 'ok'")
    parser.add_argument('--json', action='store_true', help='print JSON only')
    return parser.parse_args(argv)


class JointStateTimes:
    """Header stamps and receive times (ns) of /joint_states while `recording` is set."""

    def __init__(self):
        self.stamps: list[int] = []
        self.received: list[int] = []
        self.recording = threading.Event()

    def __call__(self, msg: JointState, info) -> None:
        # Two required arguments: rclpy then passes the MessageInfo (a second argument with a
        # default would make it call with the message only).
        if self.recording.is_set():
            received = info.get('received_timestamp') or time.time_ns()
            self.stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
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


def run(args: argparse.Namespace) -> dict:
    if shutil.which('ros2') is None:
        raise SystemExit('bench_loop: no `ros2` on PATH; run `source scripts/env.sh` first')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    log_dir = Path(tempfile.mkdtemp(prefix='bench-loop-'))
    started = {}
    probe = None
    joint_times = JointStateTimes()
    try:
        probe = RosProbe(args.domain_id, name='bench_loop_probe')
        probe.node.create_subscription(JointState, '/joint_states', joint_times,
                                       JOINT_STATE_PROBE_QOS)
        states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
        started = start_live_loop(args.domain_id, {'hand_sim': HAND}, log_dir=log_dir)
        if not wait_for(lambda: bool(states) and states[-1].status == 'ok',
                        args.startup_timeout):
            last = states[-1].status if states else 'no ControllerState at all'
            raise SystemExit(f"bench_loop: the controller's status is not 'ok' after "
                             f'{args.startup_timeout:g} s ({last}); logs in {log_dir}')
        time.sleep(args.warmup)
        processes = {name: node_process(psutil.Process(node.pid), name)
                     for name, node in started.items()}
        processes['probe'] = psutil.Process()
        cpu_before = {name: cpu_seconds(p) for name, p in processes.items()}
        wall_before = time.monotonic()
        first_state = len(states)
        joint_times.recording.set()
        time.sleep(args.duration)
        joint_times.recording.clear()
        window = states[first_state:]
        cpu_after = {name: cpu_seconds(p) for name, p in processes.items()}
        wall = time.monotonic() - wall_before
        dead = [name for name, node in started.items() if not node.alive()]
        if dead:
            raise SystemExit(f'bench_loop: {", ".join(dead)} ended during the measurement; '
                             f'logs in {log_dir}')
    finally:
        if probe is not None:
            probe.close()
        for node in reversed(list(started.values())):
            node.stop(timeout=10.0)
    stamps, received = np.array(joint_times.stamps), np.array(joint_times.received)
    ok = [s for s in window if s.status == 'ok']
    rates = np.array([s.rate_hz for s in window if s.rate_hz > 0.0])
    misses = window[-1].deadline_misses - window[0].deadline_misses if window else None
    # Simulated time per received wall time: below 1 when the sim drops steps.
    receive_span = float(received.max() - received.min()) if received.size > 1 else 0.0
    realtime = float(stamps.max() - stamps.min()) / receive_span if receive_span else None
    result = {
        'duration_s': round(wall, 3),
        'hand': HAND,
        'joint_states': {
            'messages': int(stamps.size),
            'achieved_rate_hz': round(stamps.size / wall, 1),
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
        'cpu_percent': {name: round(100.0 * (cpu_after[name] - cpu_before[name]) / wall, 1)
                        for name in processes},
        'pids': {name: p.pid for name, p in processes.items()},
        'cpu_count': psutil.cpu_count(),
    }
    match = SUMMARY.search(started['scara_sim'].log())
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
