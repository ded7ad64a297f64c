"""`ros2 topic` for environments without ros2cli: list, info, echo, hz and pub.

hri_cli.ros2 (scripts/bin/ros2) runs `main(argv)` for `ros2 topic ...` when no real ros2cli is
on PATH. The common forms behave and print as ros2cli's do:

    ros2 topic list [-t] [-c] [--include-hidden-topics]
    ros2 topic info NAME [-v]
    ros2 topic echo NAME [TYPE] [--once] [--field a.b] [-l N | -f]
    ros2 topic hz NAME [--window N]
    ros2 topic pub NAME TYPE ['YAML'] [--once | -t N] [-r HZ] [-w N]

There is no daemon: each command discovers the graph itself for `--spin-time` s (default 3,
DEFAULT_SPIN_TIME says why); list waits all of it, info, echo and hz only until their topic
is there. echo and hz wait for a topic that is not published yet (one warning on stderr)
and subscribe with the reliability and durability its publishers offer, so that they match
reliable and transient-local publishers alike; hz times the arrivals as the middleware
stamped them (the receive time), so a busy machine delays its output but not its rate. pub
fills the message from a YAML dict (`header: auto` and `stamp: now` give the current time at
each publish, as in ros2cli) and, with --once or --times, first waits for a matching
subscription. SIGINT/SIGTERM end every verb with exit code 0.

The parts that need no running ROS are plain functions, unit-tested without rclpy.init():
`message_to_plain`/`format_echo` (a message as the YAML ros2cli prints: fields in definition
order, nested messages indented, arrays as YAML lists, strings and arrays cut after
`truncate_length` items with '...'), `select_field` (--field), `fill_message` (a YAML dict
into a message, with one-line `FieldError`s), `RateWindow` (hz's statistics), and the list
and info formatting.
"""

import argparse
import array
import re
import sys
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import yaml
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from hri_cli.common import (
    ArgumentParser,
    CliError,
    StopRequest,
    UsageError,
    add_qos_arguments,
    command_parser,
    is_hidden_name,
    message_class,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    qos_from_arguments,
    ros_node,
    run_main,
    tool_node_name,
)
from hri_core import message_types

DEFAULT_TRUNCATE_LENGTH = 128
DEFAULT_WINDOW_SIZE = 10000
# The most seconds of discovery (--spin-time). ros2cli without its daemon gives 0.5 s; with
# Fast DDS's defaults a new participant learned of a running node only at that node's next
# periodic announcement (every 3 s: 0.05 to 2.8 s measured), and config/fastdds.xml's 0.5 s
# period may still be missing from another profile. info, echo and hz stop waiting as soon
# as their topic is there; list once the graph is settled (GraphSettling).
DEFAULT_SPIN_TIME = 3.0
# list: the graph is settled once it has held still this long with another node on it (at
# load 8 on 2 cores one node's endpoints came 0.35 s after the other's) ...
SETTLED_AFTER = 0.6  # s
# ... or, with no other node seen, after this long (discovery here: 0.1 to 0.5 s).
EMPTY_GRAPH_WAIT = 1.5  # s
# What echo and hz subscribe with before adopting their publishers' reliability and
# durability (ros2cli's default profile for them).
SUBSCRIBE_BASE_QOS = qos_profile_sensor_data
# hz counts every message: a queue of 5 overflowed whenever this Python process took a
# 1 kHz stream late (/joint_states measured at 670 Hz), so it keeps a second's worth more.
HZ_BASE_QOS = QoSProfile(depth=1000, reliability=qos_profile_sensor_data.reliability,
                         durability=qos_profile_sensor_data.durability)
PUBLISH_BASE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# hz reports at most once per this many ns of message arrivals.
HZ_REPORT_PERIOD_NS = 1_000_000_000
GRAPH_POLL_PERIOD = 0.05  # s between looks at the graph while waiting for a topic

FLOAT_TYPES = {'float', 'double', 'long double'}
# rclpy checks values in its setters only with ROS_PYTHON_CHECK_FIELDS set, and an
# unchecked value is serialised wrapped or cut: ranges and lengths are checked here.
INTEGER_RANGES = {f'{sign}int{bits}': ((0, 2**bits - 1) if sign else
                                       (-2**(bits - 1), 2**(bits - 1) - 1))
                  for sign in ('', 'u') for bits in (8, 16, 32, 64)}
STRING_TYPES = {'string', 'wstring', 'char', 'wchar'}
HEADER_TYPE = 'std_msgs/Header'
TIME_TYPE = 'builtin_interfaces/Time'
_SEQUENCE_TYPE = re.compile(r'^sequence<(?P<element>.+?)(?:,\s*(?P<bound>\d+))?>$')
_ARRAY_TYPE = re.compile(r'^(?P<element>.+)\[(?P<size>\d+)\]$')
_BOUNDED_STRING = re.compile(r'^(?P<element>w?string)<=\d+$')


# --------------------------------------------------------------------------------------------
# Messages as YAML (echo)


def is_message(value) -> bool:
    return hasattr(value, 'get_fields_and_field_types')


def plain_value(value, truncate_length: int | None = None):
    """A field value as plain Python data (dict, list, str, int, float, bool), as ros2cli
    converts it for YAML: bytes become a string of their characters, numpy numbers Python
    numbers, and strings and arrays longer than `truncate_length` are cut with '...'."""
    if is_message(value):
        return message_to_plain(value, truncate_length)
    if isinstance(value, bytes):
        text = ''.join(chr(byte) for byte in value)
        return plain_value(text, truncate_length)
    if isinstance(value, str):
        if truncate_length is not None and len(value) > truncate_length:
            return value[:truncate_length] + '...'
        return value
    if isinstance(value, (list, tuple, array.array, np.ndarray)):
        items = list(value)
        if truncate_length is not None and len(items) > truncate_length:
            return [plain_value(item, truncate_length)
                    for item in items[:truncate_length]] + ['...']
        return [plain_value(item, truncate_length) for item in items]
    if isinstance(value, np.generic):
        return value.item()
    return value


def message_to_plain(message, truncate_length: int | None = None) -> dict:
    """A message as a dict of its fields in definition order, nested messages as dicts."""
    return {name: plain_value(getattr(message, name), truncate_length)
            for name in message.get_fields_and_field_types()}


def to_yaml(value) -> str:
    """Plain data as block-style YAML, keys in their order, lines never wrapped."""
    return yaml.safe_dump(value, default_flow_style=False, sort_keys=False,
                          allow_unicode=True, width=sys.maxsize)


def format_echo(value, truncate_length: int | None = DEFAULT_TRUNCATE_LENGTH) -> str:
    """What echo prints for one message (or the field --field selected), '---' line included.

    A message is its YAML mapping; an array a YAML list; anything else its str() (as ros2cli
    prints a primitive field)."""
    if is_message(value):
        return to_yaml(message_to_plain(value, truncate_length)) + '---\n'
    if isinstance(value, (list, tuple, array.array, np.ndarray)):
        return to_yaml(plain_value(value, truncate_length)) + '---\n'
    return f'{plain_value(value, truncate_length)}\n---\n'


def parse_field_path(text: str) -> list[str]:
    """--field 'a.b' as ['a', 'b']; UsageError when it names no field at all."""
    path = [part for part in text.split('.') if part]
    if not path:
        raise UsageError(f"Invalid field value '{text}'")
    return path


def select_field(message, path: Sequence[str]):
    """The field `path` (e.g. ['point', 'x']) of `message`; CliError if there is none."""
    value = message
    for depth, name in enumerate(path):
        if not (is_message(value) and name in value.get_fields_and_field_types()):
            owner = '.'.join(path[:depth]) or 'the message'
            raise CliError(f"Invalid field '{'.'.join(path)}': {owner} has no field '{name}'")
        value = getattr(value, name)
    return value


# --------------------------------------------------------------------------------------------
# Messages from YAML (pub)


class FieldError(ValueError):
    """A value of a YAML dict that does not fit the message; one line naming the field."""


def field_element_type(field_type: str) -> tuple[str, bool]:
    """(element type, is an array) of a type of get_fields_and_field_types(), e.g.
    'sequence<double>' -> ('double', True), 'string<=8' -> ('string', False)."""
    is_array = False
    for pattern in (_SEQUENCE_TYPE, _ARRAY_TYPE):
        match = pattern.match(field_type)
        if match:
            field_type, is_array = match['element'], True
            break
    bounded = _BOUNDED_STRING.match(field_type)
    return (bounded['element'] if bounded else field_type), is_array


def check_array_length(field_type: str, length: int, where: str) -> None:
    """FieldError unless `length` items fit the array type (a fixed size or a bound)."""
    fixed = _ARRAY_TYPE.match(field_type)
    if fixed and length != int(fixed['size']):
        raise FieldError(f"field '{where}' takes exactly {fixed['size']} items, got {length}")
    sequence = _SEQUENCE_TYPE.match(field_type)
    if sequence and sequence['bound'] and length > int(sequence['bound']):
        raise FieldError(f"field '{where}' takes at most {sequence['bound']} items, "
                         f'got {length}')


def _scalar(type_name: str, value, where: str):
    """`value` converted to what a field of primitive type `type_name` takes."""
    if type_name in FLOAT_TYPES:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise FieldError(f"field '{where}' takes a number, got {value!r}")
        return float(value)
    if type_name in INTEGER_RANGES:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise FieldError(f"field '{where}' takes an integer, got {value!r}")
        low, high = INTEGER_RANGES[type_name]
        if not low <= value <= high:
            raise FieldError(f"field '{where}' takes a {type_name} in [{low}, {high}], "
                             f'got {value}')
        return value
    if type_name == 'boolean':
        if not isinstance(value, bool):
            raise FieldError(f"field '{where}' takes true or false, got {value!r}")
        return value
    if type_name == 'octet':
        if isinstance(value, bytes):
            return value
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
            raise FieldError(f"field '{where}' takes a byte (0 to 255), got {value!r}")
        return bytes([value])
    if type_name in STRING_TYPES:
        if isinstance(value, (dict, list)):
            raise FieldError(f"field '{where}' takes a string, got {value!r}")
        return str(value)
    raise FieldError(f"field '{where}' has a type this tool cannot fill: {type_name}")


def fill_message(message, values: Mapping, prefix: tuple = ()) -> list[tuple]:
    """Set the fields of `message` from a dict (nested dicts for nested messages, lists for
    arrays), as ros2cli's pub does; fields not given keep their defaults.

    `header: auto` and a Time field given as `now` are stamped with the current time at each
    publish: their paths (tuples of field names and list indices, e.g. ('header', 'stamp'))
    are returned for `set_stamps`. A value that does not fit raises FieldError.
    """
    where = '.'.join(str(part) for part in prefix) or 'the message'
    if not isinstance(values, Mapping):
        raise FieldError(f'{where} takes a dictionary of fields, got {values!r}')
    field_types = message.get_fields_and_field_types()
    stamp_paths: list[tuple] = []
    for name, value in values.items():
        path = (*prefix, name)
        dotted = '.'.join(str(part) for part in path)
        if name not in field_types:
            known = ', '.join(field_types) or 'none'
            raise FieldError(f"{where} has no field '{name}' (fields: {known})")
        element_type, is_array = field_element_type(field_types[name])
        nested = '/' in element_type
        try:
            if is_array:
                if not isinstance(value, list):
                    raise FieldError(f"field '{dotted}' takes a list, got {value!r}")
                check_array_length(field_types[name], len(value), dotted)
                if nested:
                    cls = message_types.message_class(element_type)
                    items = []
                    for index, item_values in enumerate(value):
                        item = cls()
                        stamp_paths += fill_message(item, item_values, (*path, index))
                        items.append(item)
                    setattr(message, name, items)
                else:
                    setattr(message, name, [_scalar(element_type, item, f'{dotted}[{index}]')
                                            for index, item in enumerate(value)])
            elif nested:
                if element_type == HEADER_TYPE and value == 'auto':
                    stamp_paths.append((*path, 'stamp'))
                elif element_type == TIME_TYPE and value == 'now':
                    stamp_paths.append(path)
                else:
                    stamp_paths += fill_message(getattr(message, name), value, path)
            else:
                setattr(message, name, _scalar(element_type, value, dotted))
        except FieldError:
            raise
        except (AssertionError, TypeError, ValueError, AttributeError, ImportError) as error:
            # rclpy's setters check ranges and lengths with assertions.
            reason = ' '.join(str(error).split()) or type(error).__name__
            raise FieldError(f"field '{dotted}' cannot take {value!r}: {reason}") from None
    return stamp_paths


def set_stamps(message, paths: Iterable[tuple], stamp) -> None:
    """Set each Time field at `paths` (from fill_message) of `message` to `stamp`."""
    for path in paths:
        parent = message
        for part in path[:-1]:
            parent = parent[part] if isinstance(part, int) else getattr(parent, part)
        setattr(parent, path[-1], stamp)


def parse_values(text: str) -> dict:
    """pub's YAML argument as a dict; UsageError (one line) for bad YAML or a non-dict."""
    try:
        values = yaml.safe_load(text)
    except yaml.YAMLError as error:
        problem = getattr(error, 'problem', None) or str(error).splitlines()[0]
        mark = getattr(error, 'problem_mark', None)
        at = f' at column {mark.column + 1}' if mark is not None else ''
        raise UsageError(f'the values are not valid YAML ({problem}{at}): {text!r}') from None
    if not isinstance(values, dict):
        raise UsageError('The passed value needs to be a dictionary in YAML format, '
                         f'got {text!r}')
    return values


# --------------------------------------------------------------------------------------------
# hz


@dataclass(frozen=True)
class RateStatistics:
    """hz's figures over its window: rate in Hz, intervals in s, the number of intervals."""

    rate: float
    min_interval: float
    max_interval: float
    std_dev: float
    window: int

    def format(self) -> str:
        """The two lines ros2cli's hz prints."""
        return (f'average rate: {self.rate:.3f}\n'
                f'\tmin: {self.min_interval:.3f}s max: {self.max_interval:.3f}s '
                f'std dev: {self.std_dev:.5f}s window: {self.window}')


def rate_statistics(intervals_ns: Sequence[int]) -> RateStatistics:
    """Rate (1 / mean interval), min, max and population std dev of intervals in ns."""
    count = len(intervals_ns)
    if count == 0:
        raise ValueError('no intervals: at least two messages are needed for a rate')
    mean = sum(intervals_ns) / count
    std_dev = (sum((interval - mean) ** 2 for interval in intervals_ns) / count) ** 0.5
    return RateStatistics(rate=1e9 / mean if mean > 0 else 0.0,
                          min_interval=min(intervals_ns) * 1e-9,
                          max_interval=max(intervals_ns) * 1e-9,
                          std_dev=std_dev * 1e-9, window=count)


class RateWindow:
    """The intervals between the last `size` arrivals, and when to report them (ros2cli's hz).

    `add(t_ns)` for each message (a clock that goes back starts the window afresh);
    `due()` returns statistics at most once per HZ_REPORT_PERIOD_NS of arrivals (the first
    call with data only starts that count), else None.
    """

    def __init__(self, size: int = DEFAULT_WINDOW_SIZE):
        if size < 1:
            raise ValueError(f'window size must be >= 1, got {size}')
        self._intervals: deque[int] = deque(maxlen=size)
        self._last_arrival_ns: int | None = None
        self._last_report_ns: int | None = None

    def add(self, arrival_ns: int) -> None:
        last = self._last_arrival_ns
        if last is None or arrival_ns < last:
            self._intervals.clear()
            self._last_report_ns = None
        else:
            self._intervals.append(arrival_ns - last)
        self._last_arrival_ns = arrival_ns

    def due(self) -> RateStatistics | None:
        if not self._intervals:
            return None
        if self._last_report_ns is None:
            self._last_report_ns = self._last_arrival_ns
            return None
        if self._last_arrival_ns < self._last_report_ns + HZ_REPORT_PERIOD_NS:
            return None
        self._last_report_ns = self._last_arrival_ns
        return rate_statistics(self._intervals)


# --------------------------------------------------------------------------------------------
# list, info and the QoS of echo/hz


def format_topic_list(names_and_types: Iterable[tuple[str, Sequence[str]]],
                      show_types: bool = False, include_hidden: bool = False) -> list[str]:
    """list's lines, sorted by name: `NAME` or, with show_types, `NAME [TYPE, ...]`."""
    lines = []
    for name, types in sorted(names_and_types):
        if is_hidden_name(name) and not include_hidden:
            continue
        lines.append(f'{name} [{", ".join(types)}]' if show_types else name)
    return lines


def format_topic_info(types: Sequence[str], publishers: Sequence, subscriptions: Sequence,
                      verbose: bool = False) -> str:
    """info's text: Type, Publisher count, Subscription count; with `verbose` each endpoint
    (its str(), rclpy's TopicEndpointInfo) after its count, blank lines between, as ros2cli."""
    shown_type = types[0] if len(types) == 1 else list(types)
    end = '\n\n' if verbose else '\n'
    text = f'Type: {shown_type}{end}'
    text += f'Publisher count: {len(publishers)}{end}'
    if verbose:
        text += ''.join(f'{endpoint}{end}' for endpoint in publishers)
    text += f'Subscription count: {len(subscriptions)}{end}'
    if verbose:
        text += ''.join(f'{endpoint}{end}' for endpoint in subscriptions)
    return text


def matching_qos(publisher_profiles: Sequence[QoSProfile],
                 base: QoSProfile = SUBSCRIBE_BASE_QOS) -> QoSProfile:
    """`base` made to match every publisher: reliable only if all are, transient local only
    if all are (ros2cli's echo); `base` itself when there is no publisher yet."""
    profile = QoSProfile(history=base.history, depth=base.depth,
                         reliability=base.reliability, durability=base.durability)
    if not publisher_profiles:
        return profile
    profile.reliability = (
        ReliabilityPolicy.RELIABLE
        if all(p.reliability == ReliabilityPolicy.RELIABLE for p in publisher_profiles)
        else ReliabilityPolicy.BEST_EFFORT)
    profile.durability = (
        DurabilityPolicy.TRANSIENT_LOCAL
        if all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publisher_profiles)
        else DurabilityPolicy.VOLATILE)
    return profile


def _qos_options_given(args: argparse.Namespace) -> bool:
    return any(value is not None
               for value in (args.qos_reliability, args.qos_durability, args.qos_depth))


# --------------------------------------------------------------------------------------------
# The verbs


def _resolve_topic(session, name: str) -> str:
    try:
        return session.node.resolve_topic_name(name)
    except Exception as error:  # noqa: BLE001 - rclpy raises several types for a bad name
        reason = (str(error).strip().splitlines() or [type(error).__name__])[0]
        raise UsageError(f"invalid topic name '{name}': {reason}") from None


class GraphSettling:
    """When `ros2 topic list` has seen the graph long enough (no ROS: it is given snapshots).

    `settled(snapshot, now)`: True once the snapshot (anything comparable: the other nodes'
    names and the topics with their types) has held still for SETTLED_AFTER s while it shows
    another node (`has_nodes`), once EMPTY_GRAPH_WAIT s have passed without one, or at
    `spin_time` s whatever it shows. Why: a fixed wait made every list take 3 s where
    discovery takes 0.1 to 0.5 s; endpoints come in over a few polls after their node, so a
    graph is judged complete by holding still, not by being non-empty."""

    def __init__(self, start: float, spin_time: float):
        self._start = start
        self._spin_time = spin_time
        self._snapshot = None
        self._since = start

    def settled(self, snapshot, has_nodes: bool, now: float) -> bool:
        if snapshot != self._snapshot:
            self._snapshot, self._since = snapshot, now
        elapsed = now - self._start
        if elapsed >= self._spin_time:
            return True
        if has_nodes:
            return now - self._since >= SETTLED_AFTER
        return elapsed >= EMPTY_GRAPH_WAIT


def _graph_snapshot(session) -> tuple[frozenset, frozenset]:
    """(the other nodes' names, every topic with its types) of the graph as seen now."""
    own = session.node.get_fully_qualified_name()
    nodes = frozenset(
        f'{namespace.rstrip("/")}/{name}'
        for name, namespace in session.node.get_node_names_and_namespaces()) - {own}
    topics = frozenset((name, tuple(types))
                       for name, types in session.node.get_topic_names_and_types())
    return nodes, topics


def _wait_for_settled_graph(session, stop: StopRequest, spin_time: float) -> None:
    settling = GraphSettling(time.monotonic(), spin_time)
    while True:
        nodes, topics = _graph_snapshot(session)
        if settling.settled((nodes, topics), bool(nodes), time.monotonic()) \
                or stop.wait(GRAPH_POLL_PERIOD):
            return


def _discover(stop: StopRequest, spin_time: float,
              found: Callable[[], bool] = lambda: False) -> None:
    """Give discovery up to `spin_time` s, less if `found()` turns true before."""
    deadline = time.monotonic() + spin_time
    while not found():
        remaining = deadline - time.monotonic()
        if remaining <= 0 or stop.wait(min(GRAPH_POLL_PERIOD, remaining)):
            return


def _wait_for_topic_type(session, topic: str, stop: StopRequest, spin_time: float,
                         verb: str) -> str | None:
    """The type of `topic` once it is on the graph (None if stopped first); one warning on
    stderr if it is not there after `spin_time` s of discovery."""
    def types_of_topic() -> list[str]:
        return dict(session.node.get_topic_names_and_types()).get(topic, [])

    _discover(stop, spin_time, lambda: bool(types_of_topic()))
    warned = False
    while not stop.is_set():
        types = types_of_topic()
        if len(types) > 1:
            raise CliError(f"Cannot {verb} topic '{topic}', as it contains more than one "
                           f"type: [{', '.join(types)}]")
        if types:
            return types[0]
        if not warned:
            print(f'WARNING: topic [{topic}] does not appear to be published yet',
                  file=sys.stderr, flush=True)
            warned = True
        stop.wait(GRAPH_POLL_PERIOD)
    return None


def _subscription_qos(session, topic: str, args: argparse.Namespace,
                      base: QoSProfile = SUBSCRIBE_BASE_QOS) -> QoSProfile:
    if _qos_options_given(args):
        return qos_from_arguments(args, base)
    profiles = [info.qos_profile for info in session.node.get_publishers_info_by_topic(topic)]
    return matching_qos(profiles, base)


def list_topics(args: argparse.Namespace, stop: StopRequest) -> int:
    with ros_node(tool_node_name('topic')) as session:
        _wait_for_settled_graph(session, stop, args.spin_time)
        names_and_types = session.node.get_topic_names_and_types()
    lines = format_topic_list(names_and_types, args.show_types, args.include_hidden_topics)
    print(len(lines) if args.count_topics else '\n'.join(lines), flush=True)
    return 0


def topic_info(args: argparse.Namespace, stop: StopRequest) -> int:
    with ros_node(tool_node_name('topic')) as session:
        topic = _resolve_topic(session, args.topic_name)

        def types_of_topic() -> list[str]:
            return dict(session.node.get_topic_names_and_types()).get(topic, [])

        _discover(stop, args.spin_time, lambda: bool(types_of_topic()))
        types = types_of_topic()
        if not types:
            raise CliError(f"Unknown topic '{topic}'")
        text = format_topic_info(types, session.node.get_publishers_info_by_topic(topic),
                                 session.node.get_subscriptions_info_by_topic(topic),
                                 args.verbose)
    print(text, end='', flush=True)
    return 0


def echo(args: argparse.Namespace, stop: StopRequest) -> int:
    field_path = parse_field_path(args.field) if args.field is not None else None
    truncate_length = None if args.full_length else args.truncate_length
    cls = message_class(args.message_type) if args.message_type else None
    with ros_node(tool_node_name('topic')) as session:
        topic = _resolve_topic(session, args.topic_name)
        if cls is None:
            type_name = _wait_for_topic_type(session, topic, stop, args.spin_time, 'echo')
            if type_name is None:
                return 0
            cls = message_class(type_name)
        printed = 0

        def on_message(message) -> None:
            nonlocal printed
            if args.once and printed:
                return
            value = select_field(message, field_path) if field_path else message
            sys.stdout.write(format_echo(value, truncate_length))
            sys.stdout.flush()
            printed += 1

        session.node.create_subscription(cls, topic, on_message,
                                         _subscription_qos(session, topic, args))
        while not stop.is_set() and not (args.once and printed):
            session.spin_once(0.1)
    return 0


def hz(args: argparse.Namespace, stop: StopRequest) -> int:
    window = RateWindow(args.window)
    with ros_node(tool_node_name('topic')) as session:
        topic = _resolve_topic(session, args.topic_name)
        type_name = _wait_for_topic_type(session, topic, stop, args.spin_time, 'measure')
        if type_name is None:
            return 0
        cls = message_class(type_name)

        def on_message(data: bytes, info: dict) -> None:
            # The middleware's receive stamp: a backlog taken late keeps its true spacing.
            window.add(info.get('received_timestamp') or time.time_ns())

        session.node.create_subscription(
            cls, topic, on_message, _subscription_qos(session, topic, args, HZ_BASE_QOS),
            raw=True)
        while not stop.is_set():
            session.spin_once(0.1)
            statistics = window.due()
            if statistics is not None:
                print(statistics.format(), flush=True)
    return 0


def pub(args: argparse.Namespace, stop: StopRequest) -> int:
    cls = message_class(args.message_type)
    message = cls()
    try:
        stamp_paths = fill_message(message, parse_values(args.values))
    except FieldError as error:
        raise UsageError(f'Failed to populate field: {error}') from None
    times = 1 if args.once else args.times
    wanted_subscriptions = args.wait_matching_subscriptions
    if wanted_subscriptions is None:
        wanted_subscriptions = 1 if times else 0
    qos = qos_from_arguments(args, PUBLISH_BASE_QOS)
    with ros_node(args.node_name or tool_node_name('pub')) as session:
        topic = _resolve_topic(session, args.topic_name)
        publisher = session.node.create_publisher(cls, topic, qos)
        if wanted_subscriptions:
            print(f'Waiting for at least {wanted_subscriptions} matching subscription(s)...',
                  flush=True)
            while publisher.get_subscription_count() < wanted_subscriptions:
                if stop.wait(0.1):
                    return 0
        print('publisher: beginning loop', flush=True)
        period = 1.0 / args.rate
        count = 0
        next_publish = time.monotonic()
        while not stop.is_set():
            if stamp_paths:
                set_stamps(message, stamp_paths, session.node.get_clock().now().to_msg())
            count += 1
            if args.print and count % args.print == 0:
                print(f'publishing #{count}: {message!r}\n', flush=True)
            publisher.publish(message)
            if times and count >= times:
                # Give a reliable subscriber time to take the last message.
                stop.wait(args.keep_alive)
                break
            next_publish += period
            stop.wait(next_publish - time.monotonic())
    return 0


def _add_discovery_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--spin-time', type=non_negative_float, default=DEFAULT_SPIN_TIME,
                        help='the most seconds to wait for discovery; less once the topic '
                             'is found (list: once the graph has settled) '
                             '(default: %(default)s)')
    parser.add_argument('--no-daemon', action='store_true',
                        help='accepted for ros2cli compatibility: there is no daemon here')


def build_parser() -> ArgumentParser:
    """`ros2 topic` and its sub-verbs."""
    parser, verb = command_parser('ros2 topic', 'Various topic related sub-commands')

    listing = verb('list', list_topics, 'Output a list of available topics')
    listing.add_argument('-t', '--show-types', action='store_true',
                         help='additionally show the topic type')
    listing.add_argument('-c', '--count-topics', action='store_true',
                         help='only display the number of topics discovered')
    listing.add_argument('--include-hidden-topics', action='store_true',
                         help='consider hidden topics as well')
    _add_discovery_arguments(listing)

    info = verb('info', topic_info, 'Print information about a topic')
    info.add_argument('topic_name', help="name of the topic (e.g. '/joint_states')")
    info.add_argument('-v', '--verbose', action='store_true',
                      help='details of every publisher and subscription (QoS included)')
    _add_discovery_arguments(info)

    echoing = verb('echo', echo, 'Output messages from a topic')
    echoing.add_argument('topic_name', help="name of the topic (e.g. '/target')")
    echoing.add_argument('message_type', nargs='?',
                         help="its type (e.g. 'geometry_msgs/msg/PointStamped'); without it "
                              'the type is taken from the graph, once the topic appears')
    echoing.add_argument('--once', action='store_true',
                         help='print the first message received and exit')
    echoing.add_argument('--field', metavar='FIELD',
                         help="echo one field; '.' selects sub-fields (e.g. point.x)")
    echoing.add_argument('-l', '--truncate-length', type=non_negative_int,
                         default=DEFAULT_TRUNCATE_LENGTH,
                         help='cut strings and arrays after this many elements with '
                              "'...' (default: %(default)s)")
    echoing.add_argument('-f', '--full-length', action='store_true',
                         help='print strings and arrays in full')
    add_qos_arguments(echoing, 'subscription (default: what the publishers offer)')
    _add_discovery_arguments(echoing)

    rate = verb('hz', hz, 'Print the average publishing rate to screen')
    rate.add_argument('topic_name', help="name of the topic (e.g. '/joint_states')")
    rate.add_argument('-w', '--window', type=positive_int, default=DEFAULT_WINDOW_SIZE,
                      help='window size, in # of messages, for calculating the rate '
                           '(default: %(default)s)')
    add_qos_arguments(rate, 'subscription (default: what the publishers offer)')
    _add_discovery_arguments(rate)

    publishing = verb('pub', pub, 'Publish a message to a topic')
    publishing.add_argument('topic_name', help="name of the topic (e.g. '/target')")
    publishing.add_argument('message_type',
                            help="type of the message (e.g. 'geometry_msgs/msg/PointStamped')")
    publishing.add_argument('values', nargs='?', default='{}',
                            help="the fields in YAML (e.g. '{point: {x: 0.4, y: 0.1}}'); "
                                 "'header: auto' and 'stamp: now' give the current time; "
                                 'fields left out keep their defaults')
    publishing.add_argument('-r', '--rate', type=positive_float, default=1.0, metavar='N',
                            help='publishing rate in Hz (default: 1)')
    publishing.add_argument('-p', '--print', type=non_negative_int, default=1, metavar='N',
                            help='print every N-th published message, 0 for none '
                                 '(default: 1)')
    count = publishing.add_mutually_exclusive_group()
    count.add_argument('-1', '--once', action='store_true',
                       help='publish one message and exit')
    count.add_argument('-t', '--times', type=non_negative_int, default=0, metavar='N',
                       help='publish N messages and exit (0: until Ctrl-C)')
    publishing.add_argument('-w', '--wait-matching-subscriptions', type=non_negative_int,
                            metavar='N',
                            help='wait for N matching subscriptions before publishing '
                                 '(default: 1 with --once or --times, else 0)')
    publishing.add_argument('--keep-alive', type=non_negative_float, default=0.1, metavar='S',
                            help='seconds to stay up after the last message (default: 0.1)')
    publishing.add_argument('-n', '--node-name', help='name of the publishing node')
    add_qos_arguments(publishing, 'publisher (default: reliable, volatile, depth 10)')
    return parser


def main(argv: list[str] | None = None) -> int:
    """`ros2 topic ARGS`: run the sub-verb; return the exit code."""
    return run_main(build_parser(), sys.argv[1:] if argv is None else argv, StopRequest())
