#!/usr/bin/env python3
"""Benchmark of the scara_sim node's real-time behaviour (a measurement, not a test).

Starts `ros2 run scara_sim scara_sim` (with `--robot NAME`: `ros2 run scara_sim arm_sim
--ros-args -p robot:=NAME`, e.g. the Panda) on its own ROS_DOMAIN_ID with discovery kept on
loopback, listens to /joint_states for `--duration` seconds and prints

* the achieved publish rate;
* the period between successive messages from their header stamps (the simulated time each
  state stands for) and from their receive times (middleware receive timestamps): median,
  99th percentile and maximum, in ms;
* the sim process's CPU use (user + system time over wall time, psutil; `ros2 run` may
  exec or fork, so the python process running the node is looked up among the children);
* the sim's own count of late ticks and dropped steps (its exit summary line).

Run it in the project's environment: `source scripts/env.sh; python bench/bench_sim.py`.
`--json` prints the same figures as one JSON object.
"""

import argparse
import json
import os
import re
import shutil
import sys
import tempfile
import threading
import time

import numpy as np
import psutil
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from hri_bringup.processes import RosProbe, start_node
from hri_core.topics import JOINT_STATES

SUMMARY = re.compile(r'(\d+) steps integrated in (\d+) ticks \(([\d.]+) s\): (\d+) late ticks '
                     r'caught up, (\d+) steps dropped')


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=10.0, help='seconds measured')
    parser.add_argument('--domain-id', type=int, default=29, help='ROS_DOMAIN_ID to use')
    parser.add_argument('--rate-hz', type=float, default=1000.0, help="the sim's rate_hz")
    parser.add_argument('--warmup', type=float, default=1.0,
                        help='seconds after the first message that are not measured')
    parser.add_argument('--robot', default='',
                        help='run arm_sim with this robot (scara, panda) instead of scara_sim')
    parser.add_argument('--json', action='store_true', help='print JSON only')
    return parser.parse_args(argv)


def period_statistics(times_ns: np.ndarray) -> dict:
    """Median, p99 and max of the differences of `times_ns`, in ms."""
    periods = np.diff(np.sort(times_ns)) / 1e6
    if periods.size == 0:
        return {'median_ms': None, 'p99_ms': None, 'max_ms': None}
    return {'median_ms': round(float(np.median(periods)), 4),
            'p99_ms': round(float(np.percentile(periods, 99)), 4),
            'max_ms': round(float(periods.max()), 4)}


def node_process(root: psutil.Process, executable: str = 'scara_sim') -> psutil.Process:
    """The python process that runs the node `executable`: `root` or one of its descendants.

    Descendants are tried first: a real ros2cli's `ros2 run` is itself a python process that
    names the executable on its command line and runs the node as a child.
    """
    candidates = [*root.children(recursive=True), root]
    for process in candidates:
        try:
            if any(executable in part for part in process.cmdline()[1:]):
                if 'python' in os.path.basename(process.cmdline()[0]) or process is root:
                    return process
        except psutil.Error:
            continue
    return root


class Listener:
    """A /joint_states subscriber on a RosProbe: header stamps and receive times, while
    `recording`."""

    def __init__(self, domain_id: int):
        self.stamps: list[int] = []
        self.received: list[int] = []
        self.recording = False
        self.first = threading.Event()
        self.probe = RosProbe(domain_id, name='bench_sim_listener')
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.probe.node.create_subscription(JointState, JOINT_STATES.name, self._on_message,
                                            qos)

    def _on_message(self, msg: JointState, info) -> None:
        # `info` must not have a default: rclpy passes the MessageInfo (with the middleware
        # receive timestamp) only to callbacks that cannot be called with the message alone.
        self.first.set()
        if self.recording:
            received = info.get('received_timestamp') or time.time_ns()
            self.stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
            self.received.append(received)

    def close(self) -> None:
        self.probe.close()


def run(args: argparse.Namespace) -> dict:
    if shutil.which('ros2') is None:
        raise SystemExit('bench_sim: no `ros2` on PATH; run `source scripts/env.sh` first')
    executable = 'arm_sim' if args.robot else 'scara_sim'
    params = {'rate_hz': float(args.rate_hz)}
    if args.robot:
        params['robot'] = args.robot
    sim = start_node('scara_sim', executable, args.domain_id, params=params,
                     log_dir=tempfile.mkdtemp(prefix='bench-sim-'))
    listener = Listener(args.domain_id)
    try:
        if not listener.first.wait(timeout=20.0):
            raise SystemExit(f'bench_sim: no /joint_states within 20 s; see {sim.log_path}')
        time.sleep(args.warmup)
        process = node_process(psutil.Process(sim.pid), executable)
        cpu0, wall0 = process.cpu_times(), time.monotonic()
        listener.recording = True
        time.sleep(args.duration)
        listener.recording = False
        cpu1, wall1 = process.cpu_times(), time.monotonic()
    finally:
        listener.close()
        sim.stop(timeout=10.0)
    wall = wall1 - wall0
    cpu = (cpu1.user - cpu0.user) + (cpu1.system - cpu0.system)
    stamps, received = np.array(listener.stamps), np.array(listener.received)
    match = SUMMARY.search(sim.log())
    result = {
        'executable': executable,
        'robot': args.robot or 'scara',
        'duration_s': round(wall, 3),
        'rate_hz_requested': args.rate_hz,
        'messages': int(stamps.size),
        'achieved_rate_hz': round(stamps.size / wall, 1),
        'stamp_period': period_statistics(stamps),
        'receive_period': period_statistics(received),
        'sim_cpu_percent': round(100.0 * cpu / wall, 1),
        'sim_pid': process.pid,
        'cpu_count': psutil.cpu_count(),
        'sim_log': str(sim.log_path),
    }
    if match:
        steps, ticks, seconds, late, dropped = match.groups()
        result['sim_summary'] = {'steps': int(steps), 'ticks': int(ticks),
                                 'sim_time_s': float(seconds), 'late_ticks': int(late),
                                 'dropped_steps': int(dropped)}
    return result


def main(argv=None) -> int:
    args = parse_arguments(argv)
    result = run(args)
    if args.json:
        print(json.dumps(result))
        return 0
    for key in ('stamp_period', 'receive_period'):
        stats = result[key]
        print(f'{key:15s} median {stats["median_ms"]} ms, p99 {stats["p99_ms"]} ms, '
              f'max {stats["max_ms"]} ms')
    print(f'achieved rate   {result["achieved_rate_hz"]} Hz ({result["messages"]} messages in '
          f'{result["duration_s"]} s; requested {result["rate_hz_requested"]} Hz)')
    print(f'sim CPU         {result["sim_cpu_percent"]} % of one core '
          f'(pid {result["sim_pid"]}, {result["cpu_count"]} cores)')
    if 'sim_summary' in result:
        summary = result['sim_summary']
        print(f'sim timing      {summary["steps"]} steps in {summary["ticks"]} ticks, '
              f'{summary["late_ticks"]} late ticks, {summary["dropped_steps"]} dropped steps')
    print(json.dumps(result))
    return 0


if __name__ == '__main__':
    sys.exit(main())
