"""What the suite's nodes share (ROS side, not pure): parameters, spinning, a node's life.

Parameters: each node lists its parameters as a table of `ParameterSpec` (default,
description, range); `declare_parameters` declares them all with descriptors and turns
rclpy's exceptions into `StartupError` with a one-line reason, so that a node started with a
bad value logs that line and exits non-zero instead of printing a traceback. The package's
config/*.yaml files are checked against the tables (test/test_config.py).

Spinning: `init_ros` starts rclpy without its signal handlers and turns SIGINT and SIGTERM
into a stop request that `spin_until_stopped` checks between callbacks. rclpy's own handlers
shut the context down at once, so a 1 kHz timer callback already running when the signal
comes would publish on a dead context and end the process with a traceback; this way the
node leaves the loop, logs its summary and exits 0.
"""

import math
import signal
import threading
from collections.abc import Callable
from dataclasses import dataclass

import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)
from rclpy.exceptions import InvalidParameterTypeException, ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


class StartupError(Exception):
    """A node cannot start; the message is a one-line reason."""


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: its default (its type sets the parameter type: float, int, str, bool,
    list of float), description, range [low, high] for numbers, exact size for arrays,
    allowed values for strings, and whether it is read-only at run time."""

    default: float | int | str | bool | list
    description: str
    low: float | None = None
    high: float | None = None
    size: int | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False


def declare_parameters(node: Node, specs: dict[str, ParameterSpec]) -> dict:
    """Declare every parameter of `specs` on `node`; return {name: value}."""
    values = {}
    for name, spec in specs.items():
        default = spec.default
        if isinstance(default, bool):
            values[name] = declare_bool(node, name, default, spec.description, spec.read_only)
        elif isinstance(default, int):
            values[name] = declare_integer(node, name, default, spec.description, spec.low,
                                           spec.high, spec.read_only)
        elif isinstance(default, float):
            values[name] = declare_float(node, name, default, spec.description, spec.low,
                                         spec.high, spec.read_only)
        elif isinstance(default, str):
            values[name] = declare_string(node, name, default, spec.description,
                                          spec.choices, spec.read_only)
        else:
            values[name] = declare_float_array(node, name, default, spec.description,
                                               spec.size, spec.read_only)
    return values


def _reason(error: ParameterException, name: str) -> str:
    """rclpy's message of a parameter exception without its trailing ': <name>'."""
    message = str(error)
    return message[:-len(f': {name}')] if message.endswith(f': {name}') else message


def _declare(node: Node, name: str, default, descriptor: ParameterDescriptor):
    try:
        return node.declare_parameter(name, default, descriptor).value
    except InvalidParameterTypeException as error:
        hint = ' (write it with a decimal point, e.g. 1000.0)' if isinstance(default, float) \
            else ''
        raise StartupError(f'bad parameter {name}: {_reason(error, name)}{hint}') from None
    except ParameterException as error:
        raise StartupError(f'bad parameter {name}: {_reason(error, name)}') from None


def declare_float(node: Node, name: str, default: float, description: str, low: float,
                  high: float, read_only: bool = False) -> float:
    """Declare a double parameter in [low, high]; return its value."""
    return _declare(node, name, float(default), ParameterDescriptor(
        description=description, read_only=read_only,
        floating_point_range=[FloatingPointRange(from_value=low, to_value=high)]))


def declare_integer(node: Node, name: str, default: int, description: str, low: int,
                    high: int, read_only: bool = False) -> int:
    """Declare an integer parameter in [low, high]; return its value."""
    return _declare(node, name, int(default), ParameterDescriptor(
        description=description, read_only=read_only,
        integer_range=[IntegerRange(from_value=low, to_value=high)]))


def declare_string(node: Node, name: str, default: str, description: str,
                   choices: tuple[str, ...] = (), read_only: bool = False) -> str:
    """Declare a string parameter, one of `choices` when given; return its value."""
    value = _declare(node, name, default, ParameterDescriptor(
        description=description, read_only=read_only, type=ParameterType.PARAMETER_STRING))
    if choices and value not in choices:
        raise StartupError(f'bad parameter {name}: {value!r} is not one of '
                           f'{", ".join(choices)}')
    return value


def declare_bool(node: Node, name: str, default: bool, description: str,
                 read_only: bool = False) -> bool:
    """Declare a bool parameter; return its value."""
    return _declare(node, name, bool(default), ParameterDescriptor(
        description=description, read_only=read_only, type=ParameterType.PARAMETER_BOOL))


def declare_float_array(node: Node, name: str, default: list[float], description: str,
                        size: int | None = None, read_only: bool = False) -> list[float]:
    """Declare a double-array parameter of finite values (exactly `size` if given)."""
    value = _declare(node, name, [float(v) for v in default], ParameterDescriptor(
        description=description, read_only=read_only,
        type=ParameterType.PARAMETER_DOUBLE_ARRAY))
    reason = float_array_problem(value, size)
    if reason:
        raise StartupError(f'bad parameter {name}: {reason}')
    return [float(v) for v in value]


def float_array_problem(value, size: int | None) -> str:
    """Why `value` is not a valid float array of `size` finite values ('' if it is)."""
    values = list(value)
    if size is not None and len(values) != size:
        return f'expected {size} values, got {len(values)}'
    if not all(math.isfinite(v) for v in values):
        return f'values must be finite, got {values}'
    return ''


def init_ros(args=None) -> threading.Event:
    """rclpy.init without rclpy's signal handlers; return the event SIGINT/SIGTERM set."""
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()

    def request_stop(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, request_stop)
    signal.signal(signal.SIGTERM, request_stop)
    return stop


def spin_until_stopped(executor, stop: threading.Event,
                       finished: Callable[[], bool] = lambda: False) -> None:
    """Run `executor`'s callbacks until `stop` is set, `finished()` or the context ends."""
    while not stop.is_set() and not finished() and rclpy.ok():
        executor.spin_once(timeout_sec=0.1)


def run_node(create_node: Callable[[], Node], node_name: str, executor_class=None,
             args=None, exit_code: Callable[[Node], int | None] | None = None,
             on_stop: Callable[[Node], None] | None = None) -> int:
    """A node's whole life: rclpy up, create the node, spin until SIGINT/SIGTERM (or until
    `exit_code(node)` is not None), clean up; return the process exit code.

    A StartupError is logged as its one-line reason and gives exit code 1. `on_stop(node)`
    runs before the node is destroyed (a summary line, closing a file). `executor_class`
    defaults to SingleThreadedExecutor; the EventsExecutor is driven with spin_once here,
    because its spin() ignores shutdown (notes/measured-limits.md).
    """
    stop = init_ros(args)
    node = None
    executor = None
    code = 0
    try:
        node = create_node()
        executor = (executor_class or SingleThreadedExecutor)()
        executor.add_node(node)
        spin_until_stopped(executor, stop,
                           (lambda: exit_code(node) is not None) if exit_code else
                           (lambda: False))
        if exit_code is not None and exit_code(node) is not None:
            code = exit_code(node)
    except StartupError as error:
        rclpy.logging.get_logger(node_name).fatal(str(error))
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            if on_stop is not None:
                on_stop(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return code
