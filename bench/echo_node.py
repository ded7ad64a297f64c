#!/usr/bin/env python3
"""The transport floor of the loop benchmark: a trivial rclpy echo (a measurement tool).

Subscribes to /bench/ping (sensor_msgs/JointState) and publishes each message unchanged on
/bench/pong at once, with the executor and QoS the controller uses (EventsExecutor driven by
spin_once; reliable, depth 1 in, the command QoS out; the SCHED_FIFO priority and the CPU
wake-up latency given as its arguments): what any rclpy node that answers a 1 kHz
stream costs at least. bench_loop.py starts it with `python bench/echo_node.py` on its own
ROS_DOMAIN_ID and ends it with SIGINT by PID.
"""

import signal
import sys

import rclpy
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import JointState

from hri_core.realtime import hold_cpu_wakeup_latency, request_sched_fifo
from hri_core.topics import COMMAND_QOS, LATEST_SAMPLE_QOS


def main() -> int:
    """argv[1]: SCHED_FIFO priority to ask for, as the controller does (default 0: off);
    argv[2]: CPU wake-up latency to hold, us (default -1: off)."""
    priority = int(sys.argv[1]) if len(sys.argv) > 1 else 0
    wakeup_latency = int(sys.argv[2]) if len(sys.argv) > 2 else -1
    rclpy.init()
    node = rclpy.create_node('bench_echo')
    pong = node.create_publisher(JointState, '/bench/pong', COMMAND_QOS)
    node.create_subscription(JointState, '/bench/ping', pong.publish, LATEST_SAMPLE_QOS)
    executor = EventsExecutor()
    executor.add_node(node)
    print(request_sched_fifo(priority).description, file=sys.stderr, flush=True)
    latency = hold_cpu_wakeup_latency(wakeup_latency)
    print(latency.description, file=sys.stderr, flush=True)
    stopping = []
    signal.signal(signal.SIGINT, lambda *_: stopping.append(True))
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(True))
    while not stopping:
        executor.spin_once(timeout_sec=0.1)
    latency.release()
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
