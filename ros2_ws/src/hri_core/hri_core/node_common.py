"""What the suite's nodes share (ROS side, not pure): parameters, spinning, a node's life.

Parameters: each node lists its parameters as a table of `ParameterSpec` (type,
description, range); their default values come from the node's `config/<node>.yaml`,
installed in its package's share folder (`load_defaults`): that file is the one source of the
defaults. `declare_parameters` declares each with its default and descriptor, so whatever the
user gives (`--params-file`, `-p`) wins as usual in ROS, also for a node renamed with
`-r __node:=NAME`. It turns rclpy's exceptions into `StartupError` with a one-line reason, so
that a node started with a bad or missing value logs that line and exits non-zero instead of
printing a traceback.

A parameter the node does not declare (a misspelt `-p profil:=circle`, a stale key in a
`--params-file`) is refused at start, naming the nearest declared one
(`unknown_parameters_problem`): ROS itself would ignore it and run on the default. A
`--params-file` that does not exist or is not YAML, or arguments rcl cannot parse, are one
line and exit 1 too (`ros_arguments_problem`, `init_ros`), where rcl raised a 22-line
traceback.

Spinning: `init_ros` starts rclpy without its signal handlers and turns SIGINT and SIGTERM
into a stop request that `spin_until_stopped` checks between callbacks. rclpy's own handlers
shut the context down at once, so a 1 kHz timer callback already running when the signal
comes would publish on a dead context and end the process with a traceback; this way the
node leaves the loop, logs its summary and exits 0.

Summary: when its loop ends, `run_node` logs one line `summary: ...`, what the node did
(messages, cycles, tasks): the text of the node's `summary()` if it has one, else how long it
ran.
"""

import atexit
import contextlib
import difflib
import faulthandler
import gc
import math
import os
import re
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import GenericAlias
from typing import NoReturn

import rclpy
import yaml
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
)
from rclpy._rclpy_pybind11 import RCLError
from rclpy.exceptions import (
    InvalidParameterTypeException,
    ParameterException,
    ParameterUninitializedException,
)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from hri_core.realtime import (
    MAX_PRIORITY,
    MAX_WAKEUP_LATENCY,
    WakeupLatencyRequest,
    hold_cpu_wakeup_latency,
    request_sched_fifo,
)


class StartupError(Exception):
    """A node cannot start; the message is a one-line reason."""


# The parameter types a table may use, as rclpy's types: `list` is an array of floats.
PARAMETER_TYPES = {
    float: Parameter.Type.DOUBLE,
    int: Parameter.Type.INTEGER,
    str: Parameter.Type.STRING,
    bool: Parameter.Type.BOOL,
    list: Parameter.Type.DOUBLE_ARRAY,
    list[str]: Parameter.Type.STRING_ARRAY,
}


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: its type (float, int, str, bool, list for an array of floats, list[str]
    for an array of strings), description, range [low, high] for numbers, exact size for
    arrays, allowed values for strings, and whether it is read-only at run time.

    Its value is in the node's YAML, except for a parameter that has no default: a `required`
    one (a string or an array) the user must give, not empty; an `optional` one may stay
    unset, and its value is then None. At most one of the two is set."""

    type: type | GenericAlias
    description: str
    low: float | None = None
    high: float | None = None
    size: int | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False
    required: bool = False
    optional: bool = False

    def descriptor(self) -> ParameterDescriptor:
        """The descriptor ROS shows for this parameter (`ros2 param describe`)."""
        descriptor = ParameterDescriptor(description=self.description,
                                         read_only=self.read_only,
                                         type=PARAMETER_TYPES[self.type].value)
        if self.type is float:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high))]
        elif self.type is int:
            descriptor.integer_range = [
                IntegerRange(from_value=int(self.low), to_value=int(self.high))]
        if self.choices:
            descriptor.additional_constraints = f'one of {", ".join(self.choices)}'
        return descriptor

    def missing(self, name: str) -> str:
        """The one-line reason when this (required) parameter `name` has no value."""
        return f'parameter {name} is required: {self.description}'

    def problem(self, value) -> str:
        """Why `value` is not valid beyond its type and range ('' if it is)."""
        if self.type is str and self.choices and value not in self.choices:
            return f'{value!r} is not one of {", ".join(self.choices)}'
        if self.type is list:
            return float_array_problem(value, self.size)
        return ''


REALTIME_PRIORITY = ParameterSpec(int, 'SCHED_FIFO priority to ask for (0: off)',
                                  low=0, high=MAX_PRIORITY, read_only=True)
"""The `realtime_priority` parameter of the nodes of the 1 kHz loop (see request_realtime)."""
CPU_WAKEUP_LATENCY = ParameterSpec(int, 'while the node runs, ask that idle CPUs wake within '
                                   'this many us (/dev/cpu_dma_latency; 0: they poll, -1: '
                                   'off)', low=-1, high=MAX_WAKEUP_LATENCY, read_only=True)
"""The `cpu_wakeup_latency` parameter of the nodes of the 1 kHz loop (see
hold_wakeup_latency)."""


def request_realtime(node: Node, priority: int) -> bool:
    """Ask for SCHED_FIFO at `priority` (hri_core.realtime; 0: off) for the node's process and
    log the outcome once: info when granted or off, a warning when refused. True if granted."""
    scheduling = request_sched_fifo(priority)
    _log_request(node, scheduling.granted or not scheduling.priority, scheduling.description)
    return scheduling.granted


def _log_request(node: Node, as_asked: bool, description: str) -> None:
    """A real-time request's outcome, once: info when granted or off, else a warning."""
    if as_asked:
        node.get_logger().info(description)
    else:
        node.get_logger().warning(description)


def hold_wakeup_latency(node: Node, microseconds: int) -> WakeupLatencyRequest:
    """Ask that idle CPUs wake within `microseconds` (hri_core.realtime; 0: they poll, -1:
    off) and log the outcome once, as request_realtime does. The node keeps the returned
    request for as long as it runs: the request ends with it (or with the process)."""
    request = hold_cpu_wakeup_latency(microseconds)
    _log_request(node, request.granted or microseconds < 0, request.description)
    return request


def declare_parameters(node: Node, specs: dict[str, ParameterSpec],
                       defaults: Mapping[str, object]) -> dict:
    """Declare every parameter of `specs` on `node` with its value in `defaults` (the node's
    YAML, `load_defaults`) as the default; return {name: value}.

    Raises StartupError with a one-line reason for a value of the wrong type, out of range,
    not among the choices, or missing (a `required` one not given or empty), and for a
    parameter given that `specs` does not hold (unknown_parameters_problem): every node
    declares its whole table in this one call, before it starts any work. An unset
    `optional` parameter is None.
    """
    problem = unknown_parameters_problem(
        parameter_overrides(node), [*specs, *declared_parameter_names(node)], node.get_name())
    if problem:
        raise StartupError(problem)
    values = {}
    for name, spec in specs.items():
        if name in defaults:
            default = _as_type(defaults[name], spec)
        elif spec.required or spec.optional:
            default = PARAMETER_TYPES[spec.type]
        else:
            raise StartupError(f'parameter {name} has no default in config/'
                               f'{node.get_name()}.yaml: give it with -p {name}:=VALUE')
        try:
            node.declare_parameter(name, default, spec.descriptor())
            value = node.get_parameter(name).value
        except ParameterUninitializedException:
            if spec.optional:
                values[name] = None
                continue
            raise StartupError(spec.missing(name)) from None
        except InvalidParameterTypeException as error:
            given = parameter_overrides(node).get(name)
            hint = decimal_point_hint(spec, None if given is None else given.value)
            raise StartupError(f'bad parameter {name}: {_reason(error, name)}{hint}') from None
        except ParameterException as error:
            raise StartupError(f'bad parameter {name}: {_reason(error, name)}') from None
        if spec.required and len(value) == 0:
            raise StartupError(spec.missing(name))
        reason = spec.problem(value)
        if reason:
            raise StartupError(f'bad parameter {name}: {reason}')
        values[name] = [float(v) for v in value] if spec.type is list else value
    return values


def decimal_point_hint(spec: ParameterSpec, given) -> str:
    """The hint for an integer given where `spec` wants a float or an array of floats: the
    value as it is to be written (`given`: the value given, None if unknown)."""
    if spec.type is float:
        example = f'{float(given)!r}' if isinstance(given, int) else '1000.0'
        return f' (write it with a decimal point, e.g. {example})'
    if spec.type is list:
        example = '[20.0, 4.0]'
        if isinstance(given, (list, tuple)) and given and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in given):
            example = f'[{", ".join(repr(float(v)) for v in given)}]'
        return f' (write each value with a decimal point, e.g. {example})'
    return ''


# Parameters rclpy itself may declare on any node (use_sim_time, the type description service
# are declared by every Node; `qos_overrides.<topic>.*` when a publisher allows them); they are
# never the node's unknown parameters.
RESERVED_PARAMETER_PREFIXES = ('qos_overrides.',)
RESERVED_PARAMETERS = ('use_sim_time', 'start_type_description_service')


def parameter_overrides(node: Node) -> dict:
    """{name: Parameter} the user gave the node: `-p`, `--params-file` sections that match
    it. rclpy keeps them in Node._parameter_overrides and has no public getter."""
    return dict(getattr(node, '_parameter_overrides', {}))


def declared_parameter_names(node: Node) -> list[str]:
    """The names of the parameters declared on `node` so far (rclpy's own among them)."""
    return list(node.list_parameters([], 0).names)


def unknown_parameters_problem(given, declared, node_name: str) -> str:
    """The one-line reason for the names in `given` that are not in `declared` (each with the
    nearest declared name, by difflib's similarity), or '' if there is none. rclpy's own
    parameters (RESERVED_PARAMETERS, RESERVED_PARAMETER_PREFIXES) are always allowed.

    Why: rclpy ignores a parameter no one declares, so `-p profil:=circle` started the hold
    profile and exited 0 at the end."""
    known = sorted(set(declared) | set(RESERVED_PARAMETERS))
    unknown = sorted(name for name in given if name not in known
                     and not name.startswith(RESERVED_PARAMETER_PREFIXES))
    if not unknown:
        return ''
    own = [name for name in known if name not in RESERVED_PARAMETERS] or known

    def nearest(name: str) -> str:
        return max(own, key=lambda candidate: (
            difflib.SequenceMatcher(None, name, candidate).ratio(), candidate))

    listed = ', '.join(f'{name} (did you mean {nearest(name)}?)' for name in unknown)
    return (f'unknown parameter{"s" if len(unknown) > 1 else ""} {listed} for {node_name}; '
            'every node\'s parameters: docs/parameters.md')


def _as_type(value, spec: ParameterSpec):
    """A YAML default as the parameter's declared type (1000 for a float is 1000.0), so that
    the parameter gets its declared type; anything else is left for ROS to refuse."""
    if spec.type is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if spec.type is list and isinstance(value, list) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return [float(v) for v in value]
    return value


def _reason(error: ParameterException, name: str) -> str:
    """rclpy's message of a parameter exception without its trailing ': <name>'."""
    message = str(error)
    return message[:-len(f': {name}')] if message.endswith(f': {name}') else message


def float_array_problem(value, size: int | None) -> str:
    """Why `value` is not a valid float array of `size` finite values ('' if it is)."""
    values = list(value)
    if size is not None and len(values) != size:
        return f'expected {size} values, got {len(values)}'
    if not all(math.isfinite(v) for v in values):
        return f'values must be finite, got {values}'
    return ''


def defaults_file(package: str, node_name: str) -> Path:
    """The YAML with the defaults of `node_name`: config/<node_name>.yaml in the package's
    share folder. StartupError if it is not installed."""
    try:
        path = Path(get_package_share_directory(package)) / 'config' / f'{node_name}.yaml'
    except PackageNotFoundError:
        raise StartupError(f'package {package} is not installed (source the workspace)') \
            from None
    if not path.is_file():
        raise StartupError(f'the defaults of {node_name} are missing: no {path}')
    return path


def load_defaults(package: str, node_name: str) -> dict:
    """The default parameter values of `node_name` ({name: value}) from its YAML."""
    path = defaults_file(package, node_name)
    try:
        document = yaml.safe_load(path.read_text())
        return dict(document[node_name]['ros__parameters'])
    except (yaml.YAMLError, KeyError, TypeError) as error:
        raise StartupError(f'{path} does not hold {node_name}.ros__parameters: '
                           f'{" ".join(str(error).split())}') from None


def take_raw(subscription) -> Iterator[tuple[bytes, dict]]:
    """Every message a raw subscription holds, oldest first, as (serialized message, message
    info), taken one at a time by the caller's thread: for subscriptions of a node that no
    executor spins (the recorder's intake, scara_sim's commands)."""
    while True:
        with subscription.handle:
            taken = subscription.handle.take_message(subscription.msg_type, True)
        if taken is None:
            return
        yield taken


def stamp_seconds(stamp) -> float:
    """A builtin_interfaces/Time (a header's stamp) in seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def ros_arguments_problem(argv: list[str]) -> str:
    """Why the `--params-file` arguments of the command line `argv` cannot be used (a file
    missing, unreadable or not YAML), or '' if they can. rcl would refuse them with a
    traceback from rclpy.init; this says which file and why in one line."""
    in_ros_args = False
    for index, argument in enumerate(argv):
        if argument == '--ros-args':
            in_ros_args = True
        elif argument == '--':
            in_ros_args = False
        elif in_ros_args and argument == '--params-file':
            if index + 1 >= len(argv):
                return '--params-file needs a file: --params-file PATH'
            path = Path(argv[index + 1])
            try:
                yaml.safe_load(path.read_text())
            except OSError as error:
                return f'cannot read --params-file {path}: {error.strerror or error}'
            except (yaml.YAMLError, UnicodeDecodeError) as error:
                return f'--params-file {path} is not YAML: {" ".join(str(error).split())}'
    return ''


# rcl's error text ends in where in its C sources it was raised (", at /project/src/...").
_RCL_SOURCE_LOCATION = re.compile(r',? at /\S+:\d+')


def rcl_error_line(error: Exception) -> str:
    """rcl's error message in one line, without the C source locations."""
    return ' '.join(_RCL_SOURCE_LOCATION.sub('', str(error)).split())


def init_ros(args=None) -> threading.Event:
    """rclpy.init without rclpy's signal handlers; return the event SIGINT/SIGTERM set.

    Raises StartupError with one line for command-line arguments rcl cannot use (a missing
    --params-file, a malformed -p); rcl's own log line about them is left out."""
    problem = ros_arguments_problem(sys.argv if args is None else list(args))
    if problem:
        raise StartupError(problem)
    held_back = StderrHeldBack()
    try:
        with held_back:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as error:
        held_back.read()  # rcl's own line: the StartupError says it in full
        raise StartupError(f'bad command line: {rcl_error_line(error)}') from None
    sys.stderr.write(held_back.read())
    stop = threading.Event()

    def request_stop(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, request_stop)
    signal.signal(signal.SIGTERM, request_stop)
    return stop


class StderrHeldBack:
    """Holds back what is written on file descriptor 2 (by C code too) inside the `with`;
    `read()` gives it afterwards. rcl logs 'Failed to parse global arguments' there before
    it raises: on a failure that line is dropped, the StartupError says it in full."""

    def __enter__(self):
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        return self

    def __exit__(self, *exc) -> None:
        os.dup2(self._saved, 2)
        os.close(self._saved)

    def read(self) -> str:
        self._file.seek(0)
        text = self._file.read().decode(errors='replace')
        self._file.close()
        return text


CONTEXT_CHECK_PERIOD = 0.05
"""s between two checks of `rclpy.ok()` in spin_until_stopped."""


def spin_until_stopped(executor, stop: threading.Event,
                       finished: Callable[[], bool] = lambda: False) -> None:
    """Run `executor`'s callbacks until `stop` is set, `finished()` or the context ends.

    The context is checked at most every CONTEXT_CHECK_PERIOD s, not at each callback:
    rclpy.ok() (a lock and the context's handle) took 1.7-7.7 us a call here, and a 1 kHz node
    runs a callback or more per millisecond. A context shut down from elsewhere ends the
    loop within that period, or at once through spin_once's ExternalShutdownException.
    """
    next_check = -math.inf
    while not stop.is_set() and not finished():
        now = time.monotonic()
        if now >= next_check:
            if not rclpy.ok():
                return
            next_check = now + CONTEXT_CHECK_PERIOD
        executor.spin_once(timeout_sec=0.1)


def leave_startup_objects_to_the_collector() -> None:
    """Move every object alive now (the imported modules, message types) out of the garbage
    collector's reach (gc.freeze), after one full collection; run before the node is made.

    A full pass of Python's cyclic collector visits every tracked object: the controller holds
    about 38,500 once up, and a full pass took 14.7 ms (idle machine), a stall of the 1 kHz
    loop whenever the collector's heuristics start one (in 20 kill rounds of the kill test,
    15 commands held over 20 ms, some far from any kill; with the freeze after the node was
    made, one, 57 ms, in a new sim: that collection itself, with its stepping thread already
    running). Frozen, a full pass visits only what was made since: the controller node's
    4,800 objects, 1.3 ms. Objects made later are collected as usual.
    """
    gc.collect()
    gc.freeze()


def run_node(create_node: Callable[[], Node], node_name: str, executor_class=None,
             args=None, exit_code: Callable[[Node], int | None] | None = None,
             on_stop: Callable[[Node], None] | None = None) -> NoReturn:
    """A node's whole life: rclpy up, create the node, spin until SIGINT/SIGTERM (or until
    `exit_code(node)` is not None), clean up, end the process with its exit code
    (end_process).

    A StartupError (bad command-line arguments, a bad or unknown parameter, ...) is logged as
    its one-line reason (ERROR) and the process ends at once with exit code 1, without tearing
    the middleware down: a node that could not start has nothing to save, and that teardown,
    next to many processes starting at once, hung after the error line in 3 of about 30
    fresh-clone test runs (ci16, ci23, ci36; with the half-built node left to the garbage
    collector and with it destroyed before rclpy shut down alike).
    `on_stop(node)` runs before the node is destroyed (closing a file, stopping a thread);
    then the summary line is logged (`log_summary`). `executor_class` defaults to
    SingleThreadedExecutor; the EventsExecutor is driven with spin_once here, because its
    spin() ignores shutdown (docs/design.md).
    """
    logger = rclpy.logging.get_logger(node_name)
    # `kill -USR1 PID` prints every thread's Python stack to stderr (the node's log), even when
    # the process hangs in the middleware with the GIL held: how a stuck node is diagnosed.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        stop = init_ros(args)
    except StartupError as error:
        _exit_at_start(logger, error)
    node = None
    executor = None
    code = 0
    started = time.monotonic()
    try:
        leave_startup_objects_to_the_collector()
        node = create_node()
        # Every node of the suite refuses unknown parameters in declare_parameters, before it
        # starts any work; this catches a node that declares its parameters otherwise.
        problem = unknown_parameters_problem(parameter_overrides(node),
                                             declared_parameter_names(node), node.get_name())
        if problem:
            raise StartupError(problem)
        executor = (executor_class or SingleThreadedExecutor)()
        executor.add_node(node)
        spin_until_stopped(executor, stop,
                           (lambda: exit_code(node) is not None) if exit_code else
                           (lambda: False))
        if exit_code is not None and exit_code(node) is not None:
            code = exit_code(node)
    except StartupError as error:
        _exit_at_start(logger, error)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # The middleware's part of the teardown, each bounded (bounded_teardown); on_stop's
        # own work (closing a bag) is not.
        if executor is not None:
            bounded_teardown(executor.shutdown, 'executor shutdown', logger.warning, code)
        if node is not None:
            if on_stop is not None:
                on_stop(node)
            log_summary(node, time.monotonic() - started)
            bounded_teardown(node.destroy_node, 'node teardown', logger.warning, code)
        bounded_teardown(rclpy.try_shutdown, 'rclpy shutdown', logger.warning, code)
    end_process(code)


def end_process(code: int) -> NoReturn:
    """End the process with `code` as the interpreter would, but for tearing its modules
    down: the exit functions run (atexit: the libraries' and the node's), the streams are
    flushed, then os._exit. Why: `ros2 run hri_bringup system` stopped by SIGINT logged its
    summary with every child's exit code 0, then did not exit within 30 s (1 of about 20
    fresh-clone test runs); all that was left was the interpreter's teardown of its modules,
    which collects the middleware's objects with them. The nodes the tests fork ended this
    way from the start (tests/node_forker.py) and never hung there."""
    with contextlib.suppress(BaseException):
        atexit._run_exitfuncs()
    with contextlib.suppress(BaseException):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)


def _exit_at_start(logger, error: StartupError) -> None:
    """Log a node's StartupError as its one line and end the process with exit code 1."""
    logger.error(str(error))
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(1)


SUMMARY_PREFIX = 'summary: '
"""What the summary line of every node begins with (after the logger's [name]: )."""


def log_summary(node: Node, elapsed: float) -> None:
    """Log the node's one summary line: `summary: ` and the text of its `summary()` (what it
    did: messages, cycles, tasks), or how long it ran (`elapsed` s) if it has none. A failing
    summary() is an error line, never a traceback on the way out."""
    summary = getattr(node, 'summary', None)
    if not callable(summary):
        node.get_logger().info(f'{SUMMARY_PREFIX}ran {elapsed:.1f} s')
        return
    try:
        text = summary()
    except Exception as error:  # noqa: BLE001 - the node is stopping: say it, exit cleanly
        node.get_logger().error(f'{SUMMARY_PREFIX}none ({type(error).__name__}: {error})')
        return
    node.get_logger().info(f'{SUMMARY_PREFIX}{text}')


TEARDOWN_TIMEOUT = 3.0
"""s a step of a stopping node's middleware teardown may take before the process ends without
it (bounded_teardown); below the 5 s its stoppers wait before SIGKILL."""


def bounded_teardown(step: Callable[[], object], what: str, warn: Callable[[str], None],
                     code: int, timeout: float = TEARDOWN_TIMEOUT) -> None:
    """Run `step` (a teardown call into the middleware); if it has not returned after
    `timeout` s, `warn` one line and end the process with `code` (os._exit), the node's own
    work already done. Why: Fast DDS's teardown hung now and then in fresh-clone test runs (a
    node that could not start, 3 of about 30 runs; a hand_sim stopped by SIGTERM outlived its
    stopper's 5 s), and the stopper's SIGKILL then turned a clean stop into exit code -9."""
    def give_up() -> None:
        warn(f'{what} did not return within {timeout:g} s (the middleware hung): exiting '
             'without it')
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)

    timer = threading.Timer(timeout, give_up)
    timer.daemon = True
    timer.start()
    try:
        step()
    finally:
        timer.cancel()
