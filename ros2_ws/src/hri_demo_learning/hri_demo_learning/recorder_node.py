"""The `recorder` node: writes the demonstration topics into a rosbag2 bag (MCAP storage).

Each topic in `topics` is recorded once it appears on the graph with a publisher: its type
comes from the graph, its QoS matches what the publishers offer (best effort if any publisher
is best effort, transient local if every publisher is), with a KEEP_ALL history so that a
burst never overflows the queue. Subscriptions are raw (CDR bytes, no deserialisation) and
each message is stamped in the bag with its receive time from the middleware (the header
stamp stays inside the message). Every `flush_period` seconds the open MCAP chunk is closed
(zstd-compressed with `compression:=zstd`) and handed to the OS, so a SIGKILL loses at most
that much. SIGINT or SIGTERM close the bag cleanly (MCAP summary and metadata.yaml) and the
node logs one summary line (messages per topic). An `output` that exists already is refused
(one error line, exit code 1), as is a bad parameter.
"""

import importlib
import time
from pathlib import Path

import rclpy
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rcl_interfaces.msg import (
    FloatingPointRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import InvalidTopicNameException, ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.validate_topic_name import validate_topic_name
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from hri_core import topics
from hri_core.node_common import StartupError, init_ros, spin_until_stopped
from hri_demo_learning.bag_io import BagError, BagWriter

NODE_NAME = 'recorder'
DEFAULT_TOPICS = [topic.name for topic in topics.DEMONSTRATION_TOPICS]
FLUSH_PERIOD_RANGE = (0.05, 1.0)  # s
DISCOVERY_PERIOD = 0.1  # s between looks at the graph for topics not recorded yet


def message_class(msgtype: str):
    """The Python class of a ROS message type 'pkg/msg/Name'."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def read_msg_definition(msgtype: str) -> str:
    """The .msg text of 'pkg/msg/Name' from the package's share folder (ament index)."""
    package, kind, name = msgtype.split('/')
    try:
        share = Path(get_package_share_directory(package))
    except PackageNotFoundError:
        raise LookupError(f'package {package} is not installed') from None
    return (share / kind / f'{name}.msg').read_text()


def _qos_time(duration) -> QosTime:
    nanoseconds = int(duration.nanoseconds)
    return QosTime(sec=nanoseconds // 10**9, nsec=nanoseconds % 10**9)


def offered_qos(profile: QoSProfile) -> Qos:
    """A publisher's QoS profile in the form rosbag2 stores in its metadata."""
    return Qos(
        history=QosHistory(int(profile.history)), depth=int(profile.depth),
        reliability=QosReliability(int(profile.reliability)),
        durability=QosDurability(int(profile.durability)),
        deadline=_qos_time(profile.deadline), lifespan=_qos_time(profile.lifespan),
        liveliness=QosLiveliness(int(profile.liveliness)),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


def recording_qos(publisher_profiles: list[QoSProfile]) -> QoSProfile:
    """A subscription QoS that matches every publisher, with a KEEP_ALL history."""
    reliability = (ReliabilityPolicy.BEST_EFFORT
                   if any(p.reliability == ReliabilityPolicy.BEST_EFFORT
                          for p in publisher_profiles)
                   else ReliabilityPolicy.RELIABLE)
    durability = (DurabilityPolicy.TRANSIENT_LOCAL
                  if publisher_profiles and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL
                                                for p in publisher_profiles)
                  else DurabilityPolicy.VOLATILE)
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=reliability,
                      durability=durability)


class Recorder(Node):
    """Records `topics` into the bag `output` until SIGINT/SIGTERM."""

    def __init__(self):
        super().__init__(NODE_NAME)
        try:
            self.declare_parameter('output', '', ParameterDescriptor(
                description='bag folder to create (required); an existing path is refused',
                read_only=True))
            self.declare_parameter('topics', DEFAULT_TOPICS, ParameterDescriptor(
                description='topics to record (each recorded once it has a publisher)',
                type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True))
            self.declare_parameter('compression', 'none', ParameterDescriptor(
                description="MCAP chunk compression: 'none' or 'zstd' (about 3x smaller)",
                read_only=True))
            self.declare_parameter('flush_period', 0.5, ParameterDescriptor(
                description='s between flushes to disk: a SIGKILL loses at most this much',
                floating_point_range=[FloatingPointRange(
                    from_value=FLUSH_PERIOD_RANGE[0], to_value=FLUSH_PERIOD_RANGE[1])]))
        except ParameterException as err:
            raise StartupError(f'bad parameter: {err}') from None
        output = self.get_parameter('output').value
        if not output:
            raise StartupError('parameter output is required: the bag folder to create')
        try:
            names = [self.resolve_topic_name(t) for t in self.get_parameter('topics').value
                     if validate_topic_name(t)]
        except InvalidTopicNameException as err:
            reason = str(err).splitlines()[0].rstrip(': ')
            raise StartupError(f'bad name in parameter topics: {reason}') from None
        if not names:
            raise StartupError('parameter topics is empty: nothing to record')
        self._pending = list(dict.fromkeys(names))
        self._topics = list(self._pending)
        self._recording: dict[str, object] = {}
        self._writer = BagWriter(output, read_definition=read_msg_definition,
                                 compression=self.get_parameter('compression').value).open()
        self._started = time.monotonic()
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._flush_timer = self.create_timer(self.get_parameter('flush_period').value,
                                              self._writer.flush)
        self._discovery_timer = self.create_timer(DISCOVERY_PERIOD, self._discover)
        self.get_logger().info(f'recording into {self._writer.path} '
                               f'(compression {self._writer.compression}): '
                               f'{", ".join(self._topics)}')
        self._discover()

    def _validate_parameters(self, parameters) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name == 'flush_period':
                low, high = FLUSH_PERIOD_RANGE
                value = parameter.value
                if not isinstance(value, float) or not low <= value <= high:
                    return SetParametersResult(
                        successful=False,
                        reason=f'flush_period must be a float in [{low}, {high}] s')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters) -> None:
        for parameter in parameters:
            if parameter.name == 'flush_period':
                self._flush_timer.timer_period_ns = int(parameter.value * 1e9)

    def _discover(self) -> None:
        """Subscribe to every pending topic that now has a publisher."""
        if not self._pending:
            return
        types = dict(self.get_topic_names_and_types())
        for topic in list(self._pending):
            if topic not in types:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue
            msgtype = types[topic][0]
            if len(types[topic]) > 1:
                self.get_logger().warning(f'{topic} has several types {types[topic]}; '
                                          f'recording {msgtype}')
            self._pending.remove(topic)
            self._subscribe(topic, msgtype, [p.qos_profile for p in publishers])
        if not self._pending:
            self._discovery_timer.cancel()

    def _subscribe(self, topic: str, msgtype: str, profiles: list[QoSProfile]) -> None:
        try:
            cls = message_class(msgtype)
        except (ImportError, AttributeError, ValueError) as err:
            self.get_logger().error(f'cannot record {topic}: no Python type {msgtype} ({err})')
            return
        try:
            connection = self._writer.add_topic(topic, msgtype,
                                                [offered_qos(p) for p in profiles])
        except BagError as err:
            self.get_logger().error(f'cannot record {topic}: {err}')
            return
        qos = recording_qos(profiles)
        write = self._writer.write

        def on_message(data: bytes, info: dict) -> None:
            write(connection, info.get('received_timestamp') or time.time_ns(), data)

        self._recording[topic] = self.create_subscription(
            cls, topic, on_message, qos, raw=True)
        self.get_logger().info(
            f'recording {topic} ({msgtype}, {qos.reliability.name.lower()}, '
            f'{qos.durability.name.lower()}, keep_all)')

    def close_bag(self) -> str:
        """Close the bag (MCAP summary, metadata.yaml); return a one-line summary of counts."""
        if not self._writer.is_open:
            return ''
        for subscription in self._recording.values():
            self.destroy_subscription(subscription)
        self._recording.clear()
        counts = self._writer.close()
        elapsed = time.monotonic() - self._started
        per_topic = ', '.join(f'{topic}: {counts[topic]}' for topic in self._topics
                              if topic in counts)
        missing = [topic for topic in self._topics if topic not in counts]
        line = (f'closed bag {self._writer.path}: {sum(counts.values())} messages in '
                f'{elapsed:.1f} s ({per_topic or "no topic seen"})')
        if missing:
            line += f'; never published: {", ".join(missing)}'
        return line

    def destroy_node(self) -> None:
        summary = self.close_bag()
        super().destroy_node()
        if summary:
            # After the node is gone: on SIGINT/SIGTERM the context is already shut down and
            # the node's logger could no longer publish to /rosout.
            rclpy.logging.get_logger(NODE_NAME).info(summary)


def main(args=None):
    # SIGINT/SIGTERM become a stop request handled between callbacks (node_common): rclpy's own
    # handlers shut the context down under a running callback, a traceback and exit 1.
    stop = init_ros(args)
    node = None
    code = 0
    try:
        node = Recorder()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin_until_stopped(executor, stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (StartupError, BagError, OSError) as err:
        rclpy.logging.get_logger(NODE_NAME).error(str(err))
        code = 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    raise SystemExit(main())
