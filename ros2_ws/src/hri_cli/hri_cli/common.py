"""What the `ros2 topic` and `ros2 bag` stand-ins (hri_cli.topic, hri_cli.bag) share.

hri_cli.ros2 (scripts/bin/ros2) hands `ros2 topic ...` and `ros2 bag ...` to those modules
when no real ros2cli is installed. Both follow the same rules, set here:

- `ArgumentParser`: a bad argument is one line on stderr (`PROG: error: ...`) and exit code 2,
  never argparse's multi-line usage block; `UsageError` is the same for arguments that can
  only be checked after parsing (a YAML value, a field path). `CliError` is any other failure:
  its message alone on stderr (as ros2cli prints the string a verb returns), exit code 1.
- `StopRequest`: SIGINT and SIGTERM only set an event that the verb's loops check, so Ctrl-C
  ends echo, hz, pub and play between two steps: exit code 0, no traceback.
- `ros_node`: an rclpy node in a Context of its own, without rclpy's signal handlers (they
  would turn Ctrl-C into an exception inside a wait), with no parameter services and no
  rosout publisher, so the tool adds as little as possible to the graph it inspects.
- `message_class`: the Python class of 'pkg/msg/Name' (or 'pkg/Name'), as ros2cli resolves it
  (hri_core.message_types), its failure a CliError.
"""

import argparse
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from hri_core import message_types

# The highest ROS_DOMAIN_ID whose DDS ports fit in 16 bits (ROS 2's documented limit on
# Linux); Fast DDS ends the process from C++ for a higher one, before Python can report it.
MAX_DOMAIN_ID = 232
# Command-line spellings of the QoS policies, as ros2cli's --qos-* options take them.
RELIABILITY_CHOICES = {
    'system_default': ReliabilityPolicy.SYSTEM_DEFAULT,
    'reliable': ReliabilityPolicy.RELIABLE,
    'best_effort': ReliabilityPolicy.BEST_EFFORT,
}
DURABILITY_CHOICES = {
    'system_default': DurabilityPolicy.SYSTEM_DEFAULT,
    'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
    'volatile': DurabilityPolicy.VOLATILE,
}


class CliError(Exception):
    """A failure reported as one line on stderr with `exit_code` (1 unless told)."""

    def __init__(self, message: str, exit_code: int = 1):
        super().__init__(' '.join(str(message).split()))
        self.exit_code = exit_code


class UsageError(CliError):
    """A bad argument found after parsing: `PROG: error: ...` and exit code 2."""

    def __init__(self, message: str):
        super().__init__(message, exit_code=2)


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors are one line (`PROG: error: MESSAGE`) and exit code 2."""

    def error(self, message: str):
        self.exit(2, f'{self.prog}: error: {" ".join(message.split())} '
                     f'(see {self.prog} --help)\n')


def command_parser(prog: str, summary: str) -> tuple[ArgumentParser, Callable]:
    """The parser of `prog` (e.g. 'ros2 topic') and a function `verb(name, handler, help)`
    that adds one of its sub-verbs and returns that sub-verb's parser."""
    parser = ArgumentParser(prog=prog, description=f"{summary} (no ros2cli here: the "
                                                   "project's stand-in).")
    verbs = parser.add_subparsers(title='Commands', metavar='COMMAND', dest='verb',
                                  required=True)

    def verb(name: str, handler: Callable, help_text: str) -> ArgumentParser:
        sub = verbs.add_parser(name, help=help_text, description=help_text)
        sub.set_defaults(handler=handler, prog=sub.prog)
        return sub

    return parser, verb


def positive_float(text: str) -> float:
    """An argparse type: a float > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not value > 0.0 or value == float('inf'):
        raise argparse.ArgumentTypeError(f'must be a finite number > 0, got {text}')
    return value


def non_negative_float(text: str) -> float:
    """An argparse type: a finite float >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not 0.0 <= value < float('inf'):
        raise argparse.ArgumentTypeError(f'must be a finite number >= 0, got {text}')
    return value


def non_negative_int(text: str) -> int:
    """An argparse type: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an integer: {text!r}') from None
    if value < 0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    value = non_negative_int(text)
    if value == 0:
        raise argparse.ArgumentTypeError('must be >= 1, got 0')
    return value


def add_qos_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """--qos-reliability, --qos-durability and --qos-depth (ros2cli's spellings)."""
    parser.add_argument('--qos-reliability', choices=list(RELIABILITY_CHOICES),
                        help=f'reliability of the {what}')
    parser.add_argument('--qos-durability', choices=list(DURABILITY_CHOICES),
                        help=f'durability of the {what}')
    parser.add_argument('--qos-depth', type=positive_int, metavar='N',
                        help=f'history depth (keep last N) of the {what}')


def qos_from_arguments(args: argparse.Namespace, base: QoSProfile) -> QoSProfile:
    """`base` with what the --qos-* options of `args` set."""
    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=args.qos_depth or base.depth,
                         reliability=base.reliability, durability=base.durability)
    if args.qos_reliability is not None:
        profile.reliability = RELIABILITY_CHOICES[args.qos_reliability]
    if args.qos_durability is not None:
        profile.durability = DURABILITY_CHOICES[args.qos_durability]
    return profile


def message_class(type_name: str) -> type:
    """The Python class of a message type 'pkg/msg/Name' or 'pkg/Name'.

    CliError('The passed message type is invalid: ...') when it cannot be imported.
    """
    try:
        return message_types.message_class(type_name)
    except message_types.MessageTypeError as error:
        raise CliError(f'The passed message type is invalid: {error}') from None


def is_hidden_name(name: str) -> bool:
    """Whether a topic name is hidden (a token starts with '_'), as ros2cli decides."""
    return any(token.startswith('_') for token in name.split('/'))


class StopRequest:
    """Set by SIGINT or SIGTERM between `install()` and `uninstall()`; a verb's loops poll it."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self._event = threading.Event()
        self._previous_handlers: dict = {}

    def install(self) -> 'StopRequest':
        def request_stop(signum, frame):
            self._event.set()

        for signum in self.SIGNALS:
            self._previous_handlers[signum] = signal.signal(signum, request_stop)
        return self

    def uninstall(self) -> None:
        """Put back the handlers `install` replaced (a caller in the same process, e.g. a
        test, keeps its own Ctrl-C)."""
        for signum, handler in self._previous_handlers.items():
            signal.signal(signum, handler)
        self._previous_handlers.clear()

    def is_set(self) -> bool:
        return self._event.is_set()

    def wait(self, seconds: float) -> bool:
        """Sleep `seconds` unless stopped first; True if a stop was requested."""
        return self._event.wait(max(0.0, seconds))


class RosSession:
    """A node and its executor in a Context of their own (see `ros_node`)."""

    def __init__(self, context: Context, node: Node, executor: SingleThreadedExecutor):
        self.context = context
        self.node = node
        self.executor = executor

    def spin_once(self, timeout: float = 0.1) -> None:
        self.executor.spin_once(timeout_sec=timeout)


def check_domain_id(text: str) -> None:
    """CliError unless ROS_DOMAIN_ID's value `text` is empty or 0 to MAX_DOMAIN_ID."""
    value = text.strip()
    if value and not (value.isdigit() and int(value) <= MAX_DOMAIN_ID):
        raise CliError(f'ROS_DOMAIN_ID={text} cannot be used: DDS takes a domain ID from 0 '
                       f'to {MAX_DOMAIN_ID}')


@contextlib.contextmanager
def ros_node(name: str) -> Iterator[RosSession]:
    """rclpy up on the environment's ROS_DOMAIN_ID, one node `name`; all torn down at exit.

    CliError (one line) if rclpy cannot start, e.g. for a ROS_DOMAIN_ID the middleware
    refuses.
    """
    check_domain_id(os.environ.get('ROS_DOMAIN_ID', ''))
    context = Context()
    try:
        rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node(name, context=context, start_parameter_services=False,
                                 enable_rosout=False)
    except Exception as error:  # noqa: BLE001 - rclpy raises its RCLError and others here
        rclpy.try_shutdown(context=context)
        first_line = (str(error).strip().splitlines() or [type(error).__name__])[0]
        raise CliError(f'cannot start ROS 2: {first_line}') from None
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield RosSession(context, node, executor)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def tool_node_name(verb: str) -> str:
    """A hidden node name (leading '_') of this process, like ros2cli's own nodes."""
    return f'_ros2cli_{verb}_{os.getpid()}'


def run_main(parser: argparse.ArgumentParser, argv: list[str], stop: StopRequest) -> int:
    """Parse `argv`, run the chosen verb, report a CliError; return the exit code.

    Each sub-verb's parser sets `handler` (called as handler(args, stop)) and `prog` (its
    name in error lines) as defaults.
    """
    args = parser.parse_args(argv)
    stop.install()
    try:
        return args.handler(args, stop) or 0
    except UsageError as error:
        print(f'{args.prog}: error: {error}', file=sys.stderr)
        return error.exit_code
    except CliError as error:
        print(str(error), file=sys.stderr)
        return error.exit_code
    except BrokenPipeError:
        # `ros2 topic echo ... | head`: the reader left. Point stdout at /dev/null so that
        # the interpreter's final flush does not fail a second time.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        stop.uninstall()
