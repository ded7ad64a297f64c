"""`ros2 bag` for environments without rosbag2's command line: info and play.

hri_cli.ros2 (scripts/bin/ros2) runs `main(argv)` for `ros2 bag ...` when no real ros2cli is on
PATH. Bags are read with rosbags (a rosbag2 folder with metadata.yaml, or a bare .mcap/.db3 file):

    ros2 bag info BAG
    ros2 bag play BAG [--rate R] [--topics T ...] [--loop] [--delay S]
                      [--wait-for-all-acked MS] [--qos-profile-overrides-path YAML]

info prints what rosbag2's info prints (Jazzy): Files, Bag size, Storage id, ROS Distro,
Duration, Start, End (local time, to the nanosecond), Messages, one `Topic: NAME | Type: T |
Count: N | Serialization Format: cdr` line per topic (sorted by name, rosbag2's default), and
the service count (this tool plays no services: always 0).

play publishes each message's raw CDR bytes, unchanged, at its recorded time offset from the
start of the bag divided by --rate, through a raw publisher per topic. Each publisher offers
the reliability and durability that the bag's metadata recorded for the topic
(offered_qos_profiles) with a history of the last 10, as rosbag2 does; reliable, volatile,
depth 10 when nothing was recorded or the recorded publishers disagreed.
--qos-profile-overrides-path takes rosbag2's override file, a map from topic name to the
policies to set (history: keep_last | keep_all, depth, reliability: reliable | best_effort,
durability: volatile | transient_local); play refuses any other key or value in one line. A
deeper history lets a reliable subscriber that fell behind get every message (rosbag2's
depth 10 lasts 5 ms at 2 kHz: a message lost on the way is gone before it is asked for
again). A topic whose type
has no Python message class here is skipped with a warning. Like rosbag2, play does not wait
for subscribers: --delay gives them time to appear, --wait-for-all-acked MS waits at the end
until reliable subscribers have acknowledged every message. SIGINT/SIGTERM stop it (exit 0).

The parts without ROS are plain functions, unit-tested without rclpy.init(): the size,
duration and time formats, `format_bag_info`, `playback_qos`, `qos_overrides` and
`playback_offset`.
"""

import argparse
import sys
import time
from dataclasses import dataclass
from datetime import datetime, tzinfo
from pathlib import Path

import yaml
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosReliability
from rosbags.rosbag2 import Reader

from hri_cli.common import (
    ArgumentParser,
    CliError,
    StopRequest,
    command_parser,
    message_class,
    non_negative_float,
    positive_float,
    ros_node,
    run_main,
    tool_node_name,
)

# rosbag2 aligns every value after its longest label, 'Topic information: '.
LABEL_WIDTH = 19
SIZE_UNITS = ('B', 'KiB', 'MiB', 'GiB', 'TiB')
STORAGE_IDS = {'.mcap': 'mcap', '.db3': 'sqlite3'}
# rosbag2's player keeps the last 10 messages per publisher whatever the recording offered.
PLAYBACK_DEPTH = 10
ACK_POLL_PERIOD = 0.1  # s between checks of --wait-for-all-acked, so that Ctrl-C stays prompt


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag as info lists it."""

    name: str
    msgtype: str
    count: int
    serialization_format: str = 'cdr'


@dataclass(frozen=True)
class BagSummary:
    """What info prints about a bag; times in ns since the epoch, sizes in bytes."""

    files: tuple[str, ...]
    size_bytes: int
    storage_id: str
    ros_distro: str
    start_ns: int
    duration_ns: int
    message_count: int
    topics: tuple[TopicSummary, ...]


def format_file_size(size_bytes: int) -> str:
    """rosbag2's size: bytes as an integer, larger units (KiB, MiB, ...) to one decimal."""
    size = float(size_bytes)
    unit = 0
    while size >= 1024 and unit < len(SIZE_UNITS) - 1:
        size /= 1024
        unit += 1
    return f'{size:.{0 if unit == 0 else 1}f} {SIZE_UNITS[unit]}'


def format_seconds(nanoseconds: int) -> str:
    """ns as 'S.NNNNNNNNN' (seconds, nine decimals, exact)."""
    seconds, fraction = divmod(int(nanoseconds), 1_000_000_000)
    return f'{seconds}.{fraction:09d}'


def format_time_point(stamp_ns: int, timezone: tzinfo | None = None) -> str:
    """rosbag2's time point: 'Mon dd YYYY HH:MM:SS.NNNNNNNNN (S.NNNNNNNNN)', day padded with
    a space, in `timezone` (None: local time)."""
    seconds, fraction = divmod(int(stamp_ns), 1_000_000_000)
    moment = datetime.fromtimestamp(seconds, timezone)
    return (f'{moment:%b} {moment.day:2d} {moment:%Y %H:%M:%S}.{fraction:09d} '
            f'({format_seconds(stamp_ns)})')


def _aligned(lines: list[str]) -> str:
    """Lines after the first indented under the label column, as rosbag2 continues a list."""
    if not lines:
        return ''
    return ('\n' + ' ' * LABEL_WIDTH).join(lines)


def format_bag_info(summary: BagSummary, timezone: tzinfo | None = None) -> str:
    """rosbag2's (Jazzy) info text, starting with its empty line; times in `timezone`
    (None: local time)."""
    topics = sorted(summary.topics, key=lambda topic: topic.name)
    topic_lines = [f'Topic: {t.name} | Type: {t.msgtype} | Count: {t.count} | '
                   f'Serialization Format: {t.serialization_format}' for t in topics]
    end_ns = summary.start_ns + summary.duration_ns
    return '\n'.join([
        '',
        f'{"Files:":<{LABEL_WIDTH}}{_aligned(list(summary.files))}',
        f'{"Bag size:":<{LABEL_WIDTH}}{format_file_size(summary.size_bytes)}',
        f'{"Storage id:":<{LABEL_WIDTH}}{summary.storage_id}',
        f'{"ROS Distro:":<{LABEL_WIDTH}}{summary.ros_distro or "unknown"}',
        f'{"Duration:":<{LABEL_WIDTH}}{format_seconds(summary.duration_ns)}s',
        f'{"Start:":<{LABEL_WIDTH}}{format_time_point(summary.start_ns, timezone)}',
        f'{"End:":<{LABEL_WIDTH}}{format_time_point(end_ns, timezone)}',
        f'{"Messages:":<{LABEL_WIDTH}}{summary.message_count}',
        f'{"Topic information:":<{LABEL_WIDTH}}{_aligned(topic_lines)}',
        f'{"Service:":<{LABEL_WIDTH}}0',
        'Service information: ',
    ])


def _one_line(error: BaseException) -> str:
    text = ' '.join(str(error).split())
    return text or type(error).__name__


def open_bag(path: Path) -> Reader:
    """An open rosbags Reader of `path`; CliError (one line) if it is not a readable bag."""
    if not path.exists():
        raise CliError(f'bag path does not exist: {path}')
    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:  # noqa: BLE001 - rosbags raises many types for a bad bag
        raise CliError(f'cannot read bag {path}: {_one_line(error)}') from None
    return reader


def _storage_files(path: Path) -> tuple[list[Path], str]:
    """The storage files of a bag and its storage id (metadata.yaml's, or the suffix's)."""
    if path.is_dir():
        try:
            metadata = yaml.safe_load((path / 'metadata.yaml').read_text())
            information = metadata['rosbag2_bagfile_information']
            names = information['relative_file_paths']
            storage_id = information['storage_identifier']
        except (OSError, yaml.YAMLError, KeyError, TypeError) as error:
            raise CliError(f'cannot read {path / "metadata.yaml"}: {_one_line(error)}'
                           ) from None
        return [path / Path(name).name for name in names], storage_id
    return [path], STORAGE_IDS.get(path.suffix, path.suffix.lstrip('.'))


def read_bag_summary(path: str | Path) -> BagSummary:
    """info's figures of the bag at `path`; CliError (one line) if it cannot be read."""
    path = Path(path)
    reader = open_bag(path)
    try:
        count = reader.message_count
        topics = tuple(TopicSummary(c.topic, c.msgtype, c.msgcount,
                                    getattr(c.ext, 'serialization_format', 'cdr'))
                       for c in reader.connections)
        # rosbags' end_time is one ns past the last message; rosbag2's duration ends on it.
        start_ns = reader.start_time if count else 0
        duration_ns = reader.end_time - 1 - reader.start_time if count else 0
        distro = reader.ros_distro or 'unknown'
    finally:
        reader.close()
    files, storage_id = _storage_files(path)
    size = sum(file.stat().st_size for file in files if file.exists())
    return BagSummary(files=tuple(file.name for file in files), size_bytes=size,
                      storage_id=storage_id, ros_distro=distro, start_ns=start_ns,
                      duration_ns=duration_ns, message_count=count, topics=topics)


def playback_qos(offered: list[Qos]) -> QoSProfile:
    """The QoS a topic is played with, from the offers recorded for it (rosbag2's rule).

    When every recorded publisher offered the same reliability and durability, those (a
    system-default or unknown value stays reliable / volatile); otherwise, or with nothing
    recorded, reliable and volatile. The history is always the last PLAYBACK_DEPTH."""
    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PLAYBACK_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
    if not offers_agree(offered):
        return profile
    reliability, durability = offered[0].reliability, offered[0].durability
    if reliability == QosReliability.BEST_EFFORT:
        profile.reliability = ReliabilityPolicy.BEST_EFFORT
    if durability == QosDurability.TRANSIENT_LOCAL:
        profile.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return profile


QOS_OVERRIDE_VALUES = {
    'history': {'keep_last': HistoryPolicy.KEEP_LAST, 'keep_all': HistoryPolicy.KEEP_ALL},
    'reliability': {'reliable': ReliabilityPolicy.RELIABLE,
                    'best_effort': ReliabilityPolicy.BEST_EFFORT},
    'durability': {'volatile': DurabilityPolicy.VOLATILE,
                   'transient_local': DurabilityPolicy.TRANSIENT_LOCAL},
}


def qos_overrides(document) -> dict[str, dict]:
    """rosbag2's QoS override file (parsed YAML) as {topic: {policy name: value}}, the values
    being rclpy's policies and the depth an int >= 1; ValueError names the first bad entry."""
    if not isinstance(document, dict):
        raise ValueError('the file must map topic names to QoS policies')
    overrides = {}
    for topic, policies in document.items():
        if not isinstance(topic, str) or not isinstance(policies, dict):
            raise ValueError(f'{topic!r}: expected a topic name mapped to QoS policies')
        chosen = {}
        for name, value in policies.items():
            if name == 'depth':
                if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                    raise ValueError(f'{topic}: depth must be an integer >= 1, got {value!r}')
                chosen[name] = value
            elif name in QOS_OVERRIDE_VALUES:
                allowed = QOS_OVERRIDE_VALUES[name]
                if value not in allowed:
                    raise ValueError(f'{topic}: {name} must be one of {", ".join(allowed)}, '
                                     f'got {value!r}')
                chosen[name] = allowed[value]
            else:
                raise ValueError(f'{topic}: unsupported QoS policy {name!r} (supported: depth, '
                                 f'{", ".join(QOS_OVERRIDE_VALUES)})')
        overrides[topic] = chosen
    return overrides


def read_qos_overrides(path: str) -> dict[str, dict]:
    """`qos_overrides` of the YAML file at `path`; CliError in one line if it is unusable."""
    try:
        return qos_overrides(yaml.safe_load(Path(path).read_text()))
    except OSError as error:
        raise CliError(f'cannot read QoS overrides {path}: {error.strerror or error}') from None
    except yaml.YAMLError as error:
        raise CliError(f'QoS overrides {path} are not YAML: {_one_line(error)}') from None
    except ValueError as error:
        raise CliError(f'QoS overrides {path}: {error}') from None


def offers_agree(offered: list[Qos]) -> bool:
    """Whether there are recorded offers and they all have one reliability and durability."""
    return len({(q.reliability, q.durability) for q in offered}) == 1


def playback_offset(stamp_ns: int, bag_start_ns: int, rate: float) -> float:
    """Seconds from the start of playback to a message's publication at `rate` (2: twice as
    fast): its offset from the bag's start divided by the rate."""
    if not rate > 0:
        raise ValueError(f'rate must be > 0, got {rate}')
    return (stamp_ns - bag_start_ns) * 1e-9 / rate


def bag_info(args: argparse.Namespace, stop: StopRequest) -> int:
    print(format_bag_info(read_bag_summary(args.bag_path)), flush=True)
    return 0


def _wait_for_acknowledgements(publishers, timeout_ms: int, stop: StopRequest) -> None:
    """Wait until reliable subscribers acknowledged everything; 0 ms: without a limit."""
    deadline = time.monotonic() + timeout_ms * 1e-3 if timeout_ms > 0 else None
    step = Duration(nanoseconds=int(ACK_POLL_PERIOD * 1e9))
    for publisher in publishers:
        if publisher.qos_profile.reliability != ReliabilityPolicy.RELIABLE:
            continue
        while not stop.is_set() and not publisher.wait_for_all_acked(step):
            if deadline is not None and time.monotonic() >= deadline:
                return


def bag_play(args: argparse.Namespace, stop: StopRequest) -> int:
    path = Path(args.bag_path)
    overrides = (read_qos_overrides(args.qos_profile_overrides_path)
                 if args.qos_profile_overrides_path else {})
    reader = open_bag(path)
    try:
        wanted = set(args.topics) if args.topics else None
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not connections:
            if wanted is None:
                return 0
            raise CliError(f'bag {path} has none of the topics {", ".join(args.topics)}')
        with ros_node(tool_node_name('bag_play')) as session:
            by_topic = {}
            publisher_of = {}
            for connection in connections:
                if connection.topic not in by_topic:
                    try:
                        cls = message_class(connection.msgtype)
                    except CliError as error:
                        print(f"Ignoring topic '{connection.topic}': {error}", file=sys.stderr)
                        continue
                    offered = list(getattr(connection.ext, 'offered_qos_profiles', []))
                    if len(offered) > 1 and not offers_agree(offered):
                        print(f"Topic '{connection.topic}' was recorded from publishers with "
                              'different QoS: playing it reliable, volatile',
                              file=sys.stderr)
                    qos = playback_qos(offered)
                    for name, value in overrides.get(connection.topic, {}).items():
                        setattr(qos, name, value)
                    by_topic[connection.topic] = session.node.create_publisher(
                        cls, connection.topic, qos)
                publisher_of[connection.id] = by_topic[connection.topic]
            playable = [c for c in connections if c.id in publisher_of]
            while playable and not stop.is_set():
                if args.delay and stop.wait(args.delay):
                    break
                playback_start = time.monotonic()
                for connection, stamp, data in reader.messages(playable):
                    delay = (playback_start + playback_offset(stamp, reader.start_time, args.rate)
                             - time.monotonic())
                    if (delay > 0 and stop.wait(delay)) or stop.is_set():
                        break
                    publisher_of[connection.id].publish(bytes(data))
                if not args.loop:
                    break
            if args.wait_for_all_acked >= 0 and not stop.is_set():
                _wait_for_acknowledgements(by_topic.values(), args.wait_for_all_acked, stop)
    finally:
        reader.close()
    return 0


def build_parser() -> ArgumentParser:
    """`ros2 bag` and its sub-verbs."""
    parser, verb = command_parser('ros2 bag', 'Various rosbag related sub-commands')

    info = verb('info', bag_info, 'Print information about a bag to the screen')
    info.add_argument('bag_path', help='bag folder (with metadata.yaml) or .mcap/.db3 file')

    play = verb('play', bag_play, 'Play back ROS data from a bag')
    play.add_argument('bag_path', help='bag folder (with metadata.yaml) or .mcap/.db3 file')
    play.add_argument('-r', '--rate', type=positive_float, default=1.0,
                      help='rate at which to play back messages; valid range > 0.0 '
                           '(default: %(default)s)')
    play.add_argument('--topics', nargs='+', metavar='TOPIC',
                      help='topics to replay, separated by spaces (default: all)')
    play.add_argument('-l', '--loop', action='store_true',
                      help='enables loop playback when playing a bag file')
    play.add_argument('-d', '--delay', type=non_negative_float, default=0.0,
                      help='sleep duration before play (each loop), in seconds')
    play.add_argument('--wait-for-all-acked', type=int, default=-1, metavar='TIMEOUT',
                      help='wait up to TIMEOUT ms at the end until reliable subscribers '
                           'acknowledged every message; 0 waits without a limit; negative '
                           '(default) does not wait')
    play.add_argument('--qos-profile-overrides-path', metavar='YAML', default='',
                      help='YAML mapping topic names to the QoS policies (history, depth, '
                           'reliability, durability) to play them with')
    return parser


def main(argv: list[str] | None = None) -> int:
    """`ros2 bag ARGS`: run the sub-verb; return the exit code."""
    return run_main(build_parser(), sys.argv[1:] if argv is None else argv, StopRequest())
