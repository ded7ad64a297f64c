#!/usr/bin/env python3
"""Benchmark of the `recorder` node: messages lost and CPU used at a steady JointState rate.

Publishes sensor_msgs/JointState at `--rate` Hz (default 1000) for `--seconds` (default 60)
from this process, with a sequence number in header.frame_id, while `ros2 run
hri_demo_learning recorder` records the topic into a fresh bag. Then stops the recorder with
SIGINT, reads the bag back and reports messages published vs recorded (and which sequence
numbers are missing), the recorder's CPU use while recording (psutil, % of one core), and the
bag size. Run from `source scripts/env.sh`:

    python bench/bench_recorder.py --seconds 60 [--json]
"""

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

import psutil
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from hri_bringup.processes import RosProbe, start_node, wait_for
from hri_demo_learning.bag_io import read_bag

TOPIC = '/bench/joint_states'


def publish_steadily(publisher, rate_hz: float, seconds: float) -> tuple[int, float]:
    """Publish JointState at `rate_hz` for `seconds` (absolute schedule, no catch-up burst)."""
    msg = JointState(name=['joint1', 'joint2'])
    period = 1.0 / rate_hz
    count = 0
    start = time.perf_counter()
    deadline = start
    while True:
        now = time.perf_counter()
        if now - start >= seconds:
            break
        msg.header.frame_id = str(count)
        msg.position = [count * 1e-3, 0.5]
        msg.velocity = [0.0, 0.0]
        msg.effort = [0.0, 0.0]
        publisher.publish(msg)
        count += 1
        deadline += period
        delay = deadline - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    return count, time.perf_counter() - start


def run(seconds: float, rate_hz: float, domain_id: int, workdir: Path) -> dict:
    bag = workdir / 'bench_bag'
    recorder = start_node('hri_demo_learning', 'recorder', domain_id,
                          params={'output': str(bag), 'topics': [TOPIC]}, log_dir=workdir)
    probe = RosProbe(domain_id, name='bench_publisher')
    try:
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        publisher = probe.publisher(TOPIC, JointState, qos)
        if not wait_for(lambda: publisher.get_subscription_count() > 0, timeout=20.0):
            raise RuntimeError(f'the recorder never subscribed; its log:\n{recorder.log()}')
        time.sleep(0.5)
        process = psutil.Process(recorder.pid)
        cpu_before = process.cpu_times()
        wall_before = time.monotonic()
        published, elapsed = publish_steadily(publisher, rate_hz, seconds)
        cpu_after = process.cpu_times()
        wall = time.monotonic() - wall_before
        time.sleep(2.0)  # let the recorder drain its queue
        recorder.send(signal.SIGINT)
        code = recorder.wait(15.0)
    finally:
        probe.close()
        recorder.stop()
    contents = read_bag(bag)
    messages = contents.topics[TOPIC].messages if TOPIC in contents.topics else []
    sequence = {int(m.header.frame_id) for m in messages}
    missing = sorted(set(range(published)) - sequence)
    used = (cpu_after.user - cpu_before.user) + (cpu_after.system - cpu_before.system)
    size = sum(f.stat().st_size for f in bag.iterdir())
    return {
        'seconds': seconds,
        'rate_hz': rate_hz,
        'achieved_rate_hz': published / elapsed,
        'published': published,
        'recorded': len(messages),
        'lost': published - len(sequence),
        'loss_percent': 100.0 * (published - len(sequence)) / max(published, 1),
        'first_missing': missing[:10],
        'duplicates': len(messages) - len(sequence),
        'recorder_cpu_percent': 100.0 * used / wall,
        'recorder_exit_code': code,
        'bag_bytes': size,
        'bag_bytes_per_message': size / max(len(messages), 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=60.0, help='publishing time, s')
    parser.add_argument('--rate', type=float, default=1000.0, help='publishing rate, Hz')
    parser.add_argument('--domain-id', type=int, default=91,
                        help='ROS_DOMAIN_ID to use (scripts/bench.sh: BENCH_DOMAIN_BASE + 1)')
    parser.add_argument('--json', action='store_true', help='print the result as JSON')
    args = parser.parse_args()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    with tempfile.TemporaryDirectory(prefix='bench-recorder-') as workdir:
        result = run(args.seconds, args.rate, args.domain_id, Path(workdir))
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"published {result['published']} JointState at "
              f"{result['achieved_rate_hz']:.1f} Hz for {args.seconds:g} s; recorded "
              f"{result['recorded']}, lost {result['lost']} "
              f"({result['loss_percent']:.3f} %); recorder CPU "
              f"{result['recorder_cpu_percent']:.1f} % of a core; bag "
              f"{result['bag_bytes'] / 1e6:.2f} MB; recorder exit code "
              f"{result['recorder_exit_code']}")
    return 0 if result['lost'] == 0 and result['recorder_exit_code'] == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
