"""Helpers of the fault and bad-input tests: fast raw listening, log lines, floats.

The test's RosProbe spins one Python thread. Deserialising a 1 kHz stream or two there can
put it a second behind on a loaded 2-core machine, which would make every "received within"
check wrong; `RawListener` takes a fast stream as serialised bytes with their arrival time
and decodes them only when the test looks.
"""

import bisect
import copy
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import weakref

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from hri_core.cdr import EFFORT, LayoutReader, joint_state_layout, read_stamp
from hri_core.node_common import stamp_seconds
from tests.common import REPO_ROOT

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
INTAKE_PERIOD = 0.002  # s between two takes of a probe's raw subscriptions
# SCHED_FIFO priority of the sim and the controller in the tests that run them as on a robot's
# computer (the scheduling canaries of the kill test run above it).
REALTIME_PRIORITY = 50
SIM_JOINTS = ('joint1', 'joint2')  # scara_sim's joints, in its order


class ProbeIntake:
    """A node in a RosProbe's context that no executor spins, whose raw subscriptions
    (`RawListener`) a thread drains every INTAKE_PERIOD; one per probe (`of`), ended by
    `close_intake` before the probe closes."""

    _of_probe: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    def __init__(self, probe):
        self.node = Node('test_probe_intake', context=probe.context,
                         use_global_arguments=False, start_parameter_services=False)
        self.listeners: list[RawListener] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @classmethod
    def of(cls, probe) -> 'ProbeIntake':
        if probe not in cls._of_probe:
            cls._of_probe[probe] = cls(probe)
        return cls._of_probe[probe]

    def _run(self) -> None:
        while not self._stop.wait(INTAKE_PERIOD):
            for listener in list(self.listeners):
                listener.drain()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.node.destroy_node()


def close_intake(probe) -> None:
    """End the probe's ProbeIntake, if it has one (before the probe's context shuts down)."""
    intake = ProbeIntake._of_probe.pop(probe, None)
    if intake is not None:
        intake.close()


class RawListener:
    """The serialised messages of one topic: (arrival time (time.monotonic(), s), bytes, time
    the publisher sent it (its source timestamp, system clock, s)) each.

    The messages are taken in bulk every INTAKE_PERIOD by a thread of the probe's own
    (`ProbeIntake`), not one by one by its executor: rclpy's Python executor spent about
    0.2 ms on each, so a test listening to three 1 kHz streams kept 60 % of a core busy
    beside the loop it judged. The arrival time is when the middleware received the message
    (its received timestamp, taken to the monotonic clock), not when the thread took it; the
    times of sending order the messages of two topics as their publishers sent them.
    """

    def __init__(self, probe, topic: str, msg_type, qos: QoSProfile = RELIABLE):
        self.msg_type = msg_type
        self.arrivals: list[tuple[float, bytes, float]] = []
        self.sequence: list[int] = []  # each message's publication sequence number
        # Deep enough for the messages of a thread held back for a second: none is lost.
        profile = copy.copy(qos)
        profile.depth = max(qos.depth, 1000)
        intake = ProbeIntake.of(probe)
        self._subscription = intake.node.create_subscription(
            msg_type, topic, lambda *_: None, profile, raw=True)
        intake.listeners.append(self)

    def drain(self) -> None:
        """Take every message the subscription holds."""
        handle = self._subscription.handle
        offset = time.time() - time.monotonic()
        while True:
            with handle:
                taken = handle.take_message(self.msg_type, True)
            if taken is None:
                return
            data, info = taken
            received = info['received_timestamp']
            arrived = received * 1e-9 - offset if received else time.monotonic()
            self.arrivals.append((arrived, data, info['source_timestamp'] * 1e-9))
            self.sequence.append(info.get('publication_sequence_number') or 0)

    def __len__(self) -> int:
        return len(self.arrivals)

    def sent_times(self) -> np.ndarray:
        """When the publisher sent each message (system clock, s), in arrival order."""
        return np.array([sent for _, _, sent in list(self.arrivals)])

    def last(self):
        """The message that arrived last, decoded (None before the first)."""
        arrivals = self.arrivals
        return deserialize_message(arrivals[-1][1], self.msg_type) if arrivals else None

    def messages(self, since: float = -math.inf, start: int = 0) -> list:
        """The messages that arrived after `since` (monotonic s), from the `start`-th on,
        decoded, in arrival order."""
        return [message for _, message in self.timed(since, start)]

    def timed(self, since: float = -math.inf, start: int = 0) -> list[tuple[float, object]]:
        """(arrival time, message) for the messages that arrived after `since`, from the
        `start`-th on."""
        return [(arrived, deserialize_message(data, self.msg_type))
                for arrived, data, _ in self.arrivals[start:] if arrived > since]


class SentCommands:
    """A RawListener's Float64MultiArray commands of one publisher: `data` (k, n) in the order
    sent, and which consecutive pairs the publisher sent one after the other (by the DDS
    publication sequence numbers): a probe held back on a loaded machine may miss some, and
    two received commands with one missed between them are not one control cycle apart."""

    def __init__(self, listener: RawListener):
        count = len(listener.arrivals)
        self.data = np.array([list(m.data) for m in listener.messages()[:count]])
        self.sequence = np.array(listener.sequence[:count], dtype=np.int64)
        self.consecutive = np.diff(self.sequence) == 1

    def __len__(self) -> int:
        return len(self.data)

    def rows(self) -> list[tuple]:
        return [tuple(row) for row in self.data]

    def largest_step(self) -> float:
        """The largest change (N m) of any joint between two commands sent one after the
        other (0 for fewer than two)."""
        if not self.consecutive.any():
            return 0.0
        return float(np.abs(np.diff(self.data, axis=0))[self.consecutive].max())


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


def from_the_first_command(joint_states: list) -> list:
    """The joint states from the first one whose effort is not all zero: before it the sim's
    brakes hold the arm (effort 0), and the controller's first command is the gravity hold
    where the arm stands (control_cycle), a step by design: the brakes' torque passes to the
    drive, and the arm, held either way, does not move. The Panda's joint 2 steps by 11-21 N
    m there, in one 1 ms step when the first command answers the first state at once."""
    return next((joint_states[i:] for i, msg in enumerate(joint_states) if any(msg.effort)),
                [])


def effort_change_per_step(joint_states: list, step: float = 1e-3,
                           commands: 'SentCommands | None' = None) -> float:
    """Largest change (N m) of the applied torque per control cycle, on the sim's clock.

    Each change of the torque the sim applied (JointState.effort) is divided by the 1 ms steps
    (`step` s) of the sim's clock since the previous change: a command the controller sends
    late (a busy machine) changes the torque by the sum of the cycles it missed. With
    `commands` (the controller's effort commands as a SentCommands, in the order it sent
    them, with their publication sequence numbers, so a command the probe missed still counts
    as a cycle), a change is divided by the control cycles between the two commands if that is
    more: on a loaded machine the sim took in the commands up to 20 ms late and in a burst,
    applying a 100 ms old command and then one 20 cycles newer (14 N m in 2 steps, measured,
    while every command differed from the one before by at most 1 N m); those cycles ran, the
    drive missed them.
    """
    stamps = np.array([stamp_seconds(m.header.stamp) for m in joint_states])
    efforts = np.array([m.effort for m in joint_states])
    order = np.argsort(stamps, kind='stable')
    stamps, efforts = stamps[order], efforts[order]
    changed = np.flatnonzero(np.any(efforts[1:] != efforts[:-1], axis=1)) + 1
    points = np.concatenate(([0], changed))
    jumps = np.max(np.abs(np.diff(efforts[points], axis=0)), axis=1)
    steps = np.maximum(np.round(np.diff(stamps[points]) / step), 1.0)
    if commands is not None and len(points) > 1:
        cycles = _commands_between([tuple(efforts[i]) for i in points], commands.rows(),
                                   commands.sequence)
        steps = np.maximum(steps, cycles)
    return float(np.max(jumps / steps)) if len(jumps) else 0.0


def _commands_between(applied: list, commands: list, sequence) -> np.ndarray:
    """For each pair of consecutive applied torques, how many commands the controller sent
    from the first to the second (by the commands' publication `sequence` numbers; 1 where
    either is not found in order: the sim's own zero torque, or a command sent before the
    listener heard any)."""
    indices: dict[tuple, list[int]] = {}
    for i, command in enumerate(commands):
        indices.setdefault(command, []).append(i)
    where = []
    start = 0
    for value in applied:
        found = indices.get(value, [])
        k = bisect.bisect_left(found, start)
        index = found[k] if k < len(found) else None
        where.append(index)
        if index is not None:
            start = index
    return np.array([max(sequence[b] - sequence[a], 1) if a is not None and b is not None
                     and b > a else 1 for a, b in zip(where[:-1], where[1:], strict=True)],
                    dtype=float)


class SchedulingCanaries:
    """tests/scheduling_canary.py on every CPU this test may use, at SCHED_FIFO `priority`
    (above the nodes'), in a ring that wakes each from the CPU before it: how long the machine
    itself held a real-time thread back, on a timer's wake-up or another CPU's, and when.
    `stalls` ends them and returns their notes; `close` ends any left, by PID."""

    def __init__(self, priority: int):
        cpus = sorted(os.sched_getaffinity(0))
        # Pipe i carries canary i's ticks to canary i + 1 (a single CPU: no ring).
        pipes = [os.pipe() for _ in cpus] if len(cpus) > 1 else []
        self._processes = []
        try:
            for index, cpu in enumerate(cpus):
                ends = [] if not pipes else [pipes[index - 1][0], pipes[index][1]]
                self._processes.append(subprocess.Popen(
                    [sys.executable, str(REPO_ROOT / 'tests' / 'scheduling_canary.py'),
                     str(cpu), str(priority), *map(str, ends)],
                    stdout=subprocess.PIPE, text=True, pass_fds=ends))
        except BaseException:
            self.close()  # the canaries already started end with it
            raise
        finally:
            for pipe in pipes:
                for end in pipe:
                    os.close(end)
        for process in self._processes:
            line = process.stdout.readline()
            if line.strip() != 'canary up':
                self.close()
                raise RuntimeError(f'scheduling canary did not start: {line!r}')

    def stalls(self) -> np.ndarray:
        """(n, 2): each late wake-up's time (system clock, s) and lateness (s), of all CPUs.
        Sets `granted`: whether every canary ran at SCHED_FIFO (if not, the notes include
        ordinary scheduling delays too)."""
        notes = []
        for process in self._processes:
            process.send_signal(signal.SIGTERM)
        self.granted = True
        for process in self._processes:
            output, _ = process.communicate(timeout=5.0)
            report = json.loads(output)
            notes.extend(report['stalls'])
            self.granted = self.granted and report['granted']
        return np.array(sorted(notes), dtype=float).reshape(-1, 2)

    def close(self) -> None:
        for process in self._processes:
            if process.poll() is None:
                process.kill()
                process.wait()
            if process.stdout is not None:
                process.stdout.close()


def machine_stall(stalls: np.ndarray, start: float, end: float) -> float:
    """Longest stall (s) of the canaries (`SchedulingCanaries.stalls`) that overlaps the time
    from `start` to `end` (system clock, s); 0 if none does."""
    if stalls.size == 0:
        return 0.0
    wake, late = stalls[:, 0], stalls[:, 1]
    overlapping = (wake - late < end) & (wake > start)
    return float(np.max(late[overlapping], initial=0.0))


def sim_joint_efforts(listener: RawListener, start: int = 0
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times sent, stamps, applied efforts) of the raw JointStates in `listener` from the
    `start`-th on (s, s, N m by joint1, joint2), in the order they were sent: read at the CDR
    offsets of the sim's layout (hri_core.cdr), a message of another layout decoded in
    full."""
    reader = LayoutReader(lambda data: joint_state_layout(data, SIM_JOINTS, (EFFORT,)))
    sent_times, stamps, efforts = [], [], []
    for _, data, sent in listener.arrivals[start:]:
        values = reader.read(data)
        if values is None:
            message = deserialize_message(data, listener.msg_type)
            values = tuple(message.effort[:2])
            stamp = stamp_seconds(message.header.stamp)
        else:
            sec, nanosec = read_stamp(data)
            stamp = sec + nanosec * 1e-9
        sent_times.append(sent)
        stamps.append(stamp)
        efforts.append(values)
    order = np.argsort(sent_times, kind='stable')
    return (np.array(sent_times)[order], np.array(stamps)[order],
            np.array(efforts).reshape(-1, 2)[order])


def equal_effort_runs(efforts: np.ndarray) -> list[tuple[int, int]]:
    """(first, end) index ranges of the consecutive rows of `efforts` (N, 2) that are equal."""
    if len(efforts) == 0:
        return []
    changes = np.flatnonzero(np.any(efforts[1:] != efforts[:-1], axis=1)) + 1
    return list(zip(np.concatenate(([0], changes)).tolist(),
                    np.concatenate((changes, [len(efforts)])).tolist(), strict=True))


def applied_command_holds(sent: np.ndarray, stamps: np.ndarray, efforts: np.ndarray,
                          longer_than: float) -> list[tuple[float, float, float]]:
    """Where the sim applied one non-zero command for longer than `longer_than` s in real
    time, from its joint states (`sim_joint_efforts`).

    The sim applies the newest command to each 1 ms step, so a controller that computes every
    cycle changes the effort of (almost) every step. A run of equal efforts is a hold when it
    spans more than `longer_than` s both by its stamps (sim clock) and by when they were sent:
    a sim that stalled and caught up applies one command to many steps at once, and sends
    them in a burst. Zero torque (a documented timeout, or no controller yet) is not a hold.
    Returns (first stamp, stamp span, span of sending) per hold.
    """
    holds = []
    for first, end in equal_effort_runs(efforts):
        last = end - 1
        stamp_span = stamps[last] - stamps[first]
        if np.any(efforts[first]) and stamp_span > longer_than and \
                sent[last] - sent[first] > longer_than:
            holds.append((float(stamps[first]), float(stamp_span),
                          float(sent[last] - sent[first])))
    return holds


def controller_gaps(sent: np.ndarray, efforts: np.ndarray,
                    command_sent: np.ndarray, longer_than: float, since: float = -math.inf,
                    steady: float = 0.008) -> list[tuple[float, float, float]]:
    """Where the sim, running steadily, applied one non-zero command to the joint states
    it sent over more than `longer_than` s while the controller sent no command at all.

    From the sim's joint states (`sim_joint_efforts`, in the order sent) and the times the
    controller sent its commands (`RawListener.sent_times`, their source timestamps: the
    probe's own delays and its order of taking do not count). A run of equal applied efforts
    is judged only where the sim sent a joint state at least every `steady` s (the probe loses
    messages of the 1 kHz streams now and then): a sim that stalled holds its last command
    however the controller runs.
    A command the controller sent inside the run, which the sim did not apply, is not the
    controller's gap. The span is the time from sending the run's first joint state to
    sending its last: the controller cannot answer a state before it is sent, and a sim that
    was held back and caught up sends many steps (their stamps 1 ms apart) with one command
    at once. Only runs that start after `since` (system clock, s) are judged.
    Returns (time the run's first joint state was sent, the span of sending, longest spacing of
    its joint states) per gap.
    """
    command_sent = np.sort(command_sent)
    gaps = []
    for first, end in equal_effort_runs(efforts):
        span = sent[end - 1] - sent[first]
        if sent[first] < since or not np.any(efforts[first]) or span <= longer_than:
            continue
        spacing = float(np.max(np.diff(sent[first:end])))
        answered = np.searchsorted(command_sent, sent[end - 1]) - \
            np.searchsorted(command_sent, sent[first], side='right')
        if spacing <= steady and answered == 0:
            gaps.append((float(sent[first]), float(span), spacing))
    return gaps
