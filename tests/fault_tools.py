"""Helpers of the fault and bad-input tests: fast raw listening, log lines, floats.

The test's RosProbe spins one Python thread. Deserialising a 1 kHz stream or two there can
put it a second behind on a loaded 2-core machine, which would make every "received within"
check wrong; `RawListener` takes a fast stream as serialised bytes with their arrival time
and decodes them only when the test looks.
"""

import math
import time

import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from hri_core.node_common import stamp_seconds

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


class RawListener:
    """The serialised messages of one topic with their arrival times (time.monotonic())."""

    def __init__(self, probe, topic: str, msg_type, qos: QoSProfile = RELIABLE):
        self.msg_type = msg_type
        self.arrivals: list[tuple[float, bytes]] = []
        probe.node.create_subscription(
            msg_type, topic, lambda data: self.arrivals.append((time.monotonic(), data)),
            qos, raw=True)

    def __len__(self) -> int:
        return len(self.arrivals)

    def messages(self, since: float = -math.inf) -> list:
        """The messages that arrived after `since` (monotonic s), decoded, in arrival order."""
        return [message for _, message in self.timed(since)]

    def timed(self, since: float = -math.inf) -> list[tuple[float, object]]:
        """(arrival time, message) for the messages that arrived after `since`."""
        return [(arrived, deserialize_message(data, self.msg_type))
                for arrived, data in list(self.arrivals) if arrived > since]


def log_time(line: str) -> float:
    """The ROS time (s) of a log line '[LEVEL] [seconds.nanoseconds] [node]: ...'."""
    fields = line.split('] [')
    try:
        return float(fields[1])
    except (IndexError, ValueError):
        return -math.inf


def lines_after(process, after: float, text: str) -> list[str]:
    """The lines of the process's log stamped after `after` (ROS time, s) that hold `text`."""
    return [line for line in process.log().splitlines()
            if text in line and log_time(line) > after]


def floats_of(msg) -> list[float]:
    """Every float in a ROS message, nested messages and arrays included."""
    values = []
    for name, kind in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if hasattr(value, 'get_fields_and_field_types'):
            values += floats_of(value)
        elif kind in ('double', 'float'):
            values.append(value)
        elif kind.startswith(('sequence<double', 'double[', 'sequence<float', 'float[')):
            values += [float(v) for v in value]
        elif kind.startswith('sequence<') and len(value) and \
                hasattr(value[0], 'get_fields_and_field_types'):
            values += [v for item in value for v in floats_of(item)]
    return values


def assert_all_finite(messages: list, topic: str) -> None:
    """Every float of every message is finite (the topic names the failure)."""
    bad = [m for m in messages if not all(math.isfinite(v) for v in floats_of(m))]
    assert not bad, f'non-finite values on {topic}: {bad[:3]}'


def effort_change_per_step(joint_states: list, step: float = 1e-3) -> float:
    """Largest change (N m) of the applied torque per `step` s of the sim's clock.

    A command the controller sends late (a busy machine) changes the torque by the sum of the
    cycles it missed: each change is divided by the steps since the previous change.
    """
    stamps = np.array([stamp_seconds(m.header.stamp) for m in joint_states])
    efforts = np.array([m.effort for m in joint_states])
    order = np.argsort(stamps, kind='stable')
    stamps, efforts = stamps[order], efforts[order]
    changed = np.flatnonzero(np.any(efforts[1:] != efforts[:-1], axis=1)) + 1
    points = np.concatenate(([0], changed))
    jumps = np.max(np.abs(np.diff(efforts[points], axis=0)), axis=1)
    steps = np.maximum(np.round(np.diff(stamps[points]) / step), 1.0)
    return float(np.max(jumps / steps)) if len(jumps) else 0.0
