"""Print every /hri/controller_state as one JSON line on stdout, for `seconds` seconds.

For tests that cannot listen from their own process: test_two_hosts.py runs it inside a
network namespace (`ip netns exec NS python tests/controller_state_printer.py 60`), where the
test's own rclpy node cannot reach. Uses the ROS environment it is started with
(ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_STATIC_PEERS).
"""

import json
import math
import sys
import time

import rclpy
from hri_interfaces.msg import ControllerState
from rclpy.executors import ExternalShutdownException

from hri_core.node_common import stamp_seconds
from hri_core.topics import MONITOR_QOS


def as_line(msg: ControllerState) -> str:
    values = [msg.distance, msg.weight, *msg.effort]
    return json.dumps({'stamp': stamp_seconds(msg.header.stamp),
                       'status': msg.status, 'task': msg.task, 'distance': msg.distance,
                       'weight': msg.weight, 'effort': list(msg.effort),
                       'finite': all(math.isfinite(v) for v in values)})


def main(seconds: float) -> int:
    rclpy.init()
    node = rclpy.create_node('controller_state_printer')
    node.create_subscription(ControllerState, '/hri/controller_state',
                             lambda msg: print(as_line(msg), flush=True), MONITOR_QOS)
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(float(sys.argv[1]) if len(sys.argv) > 1 else 60.0))
