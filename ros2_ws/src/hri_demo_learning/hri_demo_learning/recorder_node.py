"""The `recorder` node: writes the demonstration topics into a rosbag2 bag (MCAP storage).

Each topic in `topics` is recorded once it appears on the graph with a publisher: its type
comes from the graph, its QoS matches what the publishers offer (best effort if any publisher
is best effort, transient local if every publisher is), with a KEEP_ALL history so that a
burst never overflows the queue. Subscriptions are raw (CDR bytes, no deserialisation) and sit
on a second node, `recorder_intake`, that no executor spins: every 5 ms a timer takes what
they hold straight from the middleware, each message stamped in the bag with its receive time
from the middleware (the header stamp stays inside the message), without an executor's
per-message work (a single-threaded executor hands over only about 2 kHz here). The
middleware's UDP sockets get the largest receive buffer the OS allows an unprivileged process
(net.core.rmem_max; hri_core.receive_buffers says why). Every
`flush_period` seconds the open MCAP chunk is closed (zstd-compressed with
`compression:=zstd`) and handed to the OS, so a SIGKILL loses at most that much (and the
intake's 5 ms). SIGINT or SIGTERM first write every message still held by the subscriptions
(received and acknowledged to reliable publishers), then close the bag cleanly (MCAP summary
and metadata.yaml), and the node logs one summary line (messages per
topic). An `output` that exists already is refused
(one error line, exit code 1), as is a bad parameter; a bag that cannot be written any more
(disk full) stops the node the same way. The parameters' defaults are in config/recorder.yaml
(`topics`: the names of hri_core.topics.DEMONSTRATION_TOPICS); `output` has none (required).
"""

import sys
import time
from collections.abc import Callable
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidTopicNameException
from rclpy.experimental import EventsExecutor
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

from hri_core.message_types import MessageTypeError, message_class
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    run_node,
    take_raw,
)
from hri_core.receive_buffers import enlarge_udp_receive_buffers, rmem_max
from hri_demo_learning.bag_io import COMPRESSIONS, BagError, BagWriter

PACKAGE = 'hri_demo_learning'
NODE_NAME = 'recorder'
FLUSH_PERIOD_RANGE = (0.05, 1.0)  # s
DISCOVERY_PERIOD = 0.1  # s between looks at the graph for topics not recorded yet
INTAKE_PERIOD = 0.005  # s between takes of what the subscriptions hold

PARAMETERS = {
    'output': ParameterSpec(str, 'the bag folder to create (an existing path is refused)',
                            read_only=True, required=True),
    'topics': ParameterSpec(list[str], 'topics to record (each recorded once it has a '
                            'publisher)', read_only=True),
    'compression': ParameterSpec(str, 'MCAP chunk compression: none or zstd (about 3x '
                                 'smaller)', choices=COMPRESSIONS, read_only=True),
    'flush_period': ParameterSpec(float, 's between flushes to disk: a SIGKILL loses at most '
                                  'this much', *FLUSH_PERIOD_RANGE),
}


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
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        try:
            names = [self.resolve_topic_name(t) for t in values['topics']
                     if validate_topic_name(t)]
        except InvalidTopicNameException as err:
            reason = str(err).splitlines()[0].rstrip(': ')
            raise StartupError(f'bad name in parameter topics: {reason}') from None
        self._pending = list(dict.fromkeys(names))
        self._topics = list(self._pending)
        self._recording: dict[str, object] = {}
        self._on_message: dict[str, Callable[[bytes, dict], None]] = {}
        self.exit_code: int | None = None  # 1 once the bag cannot be written any more
        try:
            self._writer = BagWriter(values['output'], read_definition=read_msg_definition,
                                     compression=values['compression']).open()
        except BagError as err:
            raise StartupError(str(err)) from None
        self._started = time.monotonic()
        # The subscriptions live on a node no executor spins: the intake timer takes their
        # messages with the middleware's receive time (take_message), which the EventsExecutor
        # of these wheels cannot hand to a callback (one taking message info crashes it), and
        # without the executor's per-message work.
        self._intake = Node(f'{NODE_NAME}_intake', context=self.context,
                            use_global_arguments=False, start_parameter_services=False)
        # The middleware's sockets hold 0.2 MB by default: a recorder that falls behind on a
        # loaded machine lost runs of 1 kHz messages in the kernel (hri_core.receive_buffers).
        most = rmem_max()
        sockets, size = enlarge_udp_receive_buffers(most)
        self.get_logger().info(f'UDP receive buffers: {size} B on {sockets} sockets '
                               f'(net.core.rmem_max {most} B)')
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._flush_timer = self.create_timer(values['flush_period'], self._flush)
        self._discovery_timer = self.create_timer(DISCOVERY_PERIOD, self._discover)
        self._intake_timer = self.create_timer(INTAKE_PERIOD, self.drain)
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
        except MessageTypeError as err:
            self.get_logger().error(f'cannot record {topic}: {err}')
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
            try:
                write(connection, info.get('received_timestamp') or time.time_ns(), data)
            except OSError as err:
                self._stop_on_write_error(err)

        subscription = self._intake.create_subscription(cls, topic, on_message, qos, raw=True)
        self._recording[topic] = subscription
        self._on_message[topic] = on_message
        self.get_logger().info(
            f'recording {topic} ({msgtype}, {qos.reliability.name.lower()}, '
            f'{qos.durability.name.lower()}, keep_all)')

    def _flush(self) -> None:
        try:
            self._writer.flush()
        except OSError as err:
            self._stop_on_write_error(err)

    def _stop_on_write_error(self, error: OSError) -> None:
        """A bag that cannot be written any more (disk full): one error line, exit code 1."""
        if self.exit_code is None:
            self.get_logger().error(f'cannot write bag {self._writer.path}: '
                                    f'{error.strerror or error}; stopping')
            self.exit_code = 1

    def drain(self) -> int:
        """Write every message the subscriptions hold (received by the middleware, which
        the reliable publishers count as delivered); return how many."""
        drained = 0
        for topic, subscription in self._recording.items():
            if self.exit_code is not None:
                break
            on_message = self._on_message[topic]
            for taken in take_raw(subscription):
                on_message(*taken)
                drained += 1
                if self.exit_code is not None:
                    break
        return drained

    def close_bag(self) -> None:
        """Write what is still queued, close the bag (MCAP summary, metadata.yaml) and keep
        the one-line summary of counts for `summary` (run_node logs it next)."""
        drained = self.drain()
        for subscription in self._recording.values():
            self._intake.destroy_subscription(subscription)
        self._recording.clear()
        self._intake.destroy_node()
        try:
            counts = self._writer.close()
        except OSError as err:
            self.get_logger().error(f'cannot close bag {self._writer.path}: '
                                    f'{err.strerror or err}')
            self._summary = f'bag {self._writer.path} not closed: {err.strerror or err}'
            return
        elapsed = time.monotonic() - self._started
        per_topic = ', '.join(f'{topic}: {counts[topic]}' for topic in self._topics
                              if topic in counts)
        missing = [topic for topic in self._topics if topic not in counts]
        line = (f'closed bag {self._writer.path}: {sum(counts.values())} messages in '
                f'{elapsed:.1f} s ({per_topic or "no topic seen"}; {drained} of them still '
                'queued at the stop)')
        if missing:
            line += f'; never published: {", ".join(missing)}'
        self._summary = line

    def summary(self) -> str:
        """The line close_bag made: what went into the bag."""
        return getattr(self, '_summary', f'bag {self._writer.path} not closed')


def main(args=None):
    # The EventsExecutor: a SingleThreadedExecutor hands over only about 2 kHz of messages on
    # this machine, so at the 2 kHz of /joint_states and /ee_position a loaded machine left it
    # seconds behind what it had received, and a SIGKILL lost those on top of flush_period.
    return run_node(Recorder, NODE_NAME, EventsExecutor, args,
                    exit_code=lambda node: node.exit_code, on_stop=Recorder.close_bag)


if __name__ == '__main__':
    sys.exit(main())
