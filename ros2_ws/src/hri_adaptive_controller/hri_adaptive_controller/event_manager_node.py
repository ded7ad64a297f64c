"""The `event_manager` node: holds the learned tasks and ramps a(E, t) to switch between them.

Tasks come from the YAML files in `tasks_dir` at start and from /hri/task at any time (a task
with a known name replaces the old one; an invalid one is rejected with a warning). A task whose
pull K |dP/dz| would vanish within `reach` (m, the arm's l1 + l2) of its region, i.e. fall
below 5 % of the controller's `max_task_speed` there (`hri_core.potential.reach_shortfall`; a
task without K gets `default_task_gain`), is refused the same way, with a one-line warning
naming it, and the current task is kept: such a task would leave the arm still. An event
on /hri/events names the task to switch to; `EventWeightSchedule` (eq. 13) fades the weight
out, swaps the task while a = 0, and fades it in again. The node publishes TaskState on every
change, at `publish_rate_hz` (>= 100 Hz) during a ramp, and every `heartbeat_period` otherwise;
its timer runs at `publish_rate_hz` only during a ramp (and until `initial_task` starts), at
`heartbeat_period` otherwise, so a node with nothing to ramp wakes twice a second, not 200
times, beside the 1 kHz loop.

Choices (docs/design.md says why):
- `initial_task` fades in from a = 0 (a ramp of `ramp_time`), like any other switch, so a
  robot never starts with the full task force at once. The ramp starts when /hri/task_state
  has its first subscriber (a = 0 until then): started at once, it would be over before a
  controller that matches later hears of it (discovery takes 1-2 s) and the controller would
  jump from a = 0 to 1, e.g. when the event_manager is restarted under a running controller.
- A task that arrives on /hri/task under the active task's name goes through a full switch
  (fade out, swap, fade in): its parameters never change under a nonzero weight.
- An event whose `task` is empty fades out to 'idle' (a = 0: the controller holds still).
- /hri/task_state is reliable and transient-local (depth 1): a controller that starts late
  gets the current state at once.
"""

import sys
import time
from itertools import count
from pathlib import Path

from hri_interfaces.msg import TaskEvent, TaskParameters, TaskState
from rcl_interfaces.msg import SetParametersResult
from rclpy.experimental import EventsExecutor
from rclpy.node import Node

from hri_adaptive_controller.event_weight import (
    PHASE_FADING_IN,
    PHASE_FADING_OUT,
    PHASE_IDLE,
    EventWeightSchedule,
)
from hri_core import topics
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    run_node,
)
from hri_core.paired_clocks import read_together
from hri_core.potential import reach_shortfall
from hri_core.task_file import TaskRecord, load_task_directory
from hri_core.task_message import task_message, task_record

PACKAGE = 'hri_adaptive_controller'
NODE_NAME = 'event_manager'
WARNING_THROTTLE = 1.0  # s between repeats of one kind of warning

PARAMETERS = {
    'tasks_dir': ParameterSpec(str, 'folder of task YAML files loaded at start',
                               read_only=True),
    'initial_task': ParameterSpec(str, 'task faded in at start ("" = start idle, a = 0)',
                                  read_only=True),
    'ramp_time': ParameterSpec(float, 'duration of a full fade 1 -> 0 or 0 -> 1 (s)',
                               low=0.05, high=60.0),
    'publish_rate_hz': ParameterSpec(float, 'TaskState rate during a ramp (Hz)',
                                     low=100.0, high=1000.0, read_only=True),
    'heartbeat_period': ParameterSpec(float, 'TaskState period when nothing changes (s)',
                                      low=0.01, high=60.0),
    'max_task_speed': ParameterSpec(float, "the controller's max_task_speed (m/s), the "
                                    'reference of the reach check', low=1e-3, high=10.0,
                                    read_only=True),
    'reach': ParameterSpec(float, "the arm's reach l1 + l2 (m): a task must pull the arm "
                           'this far outside its region', low=0.01, high=100.0,
                           read_only=True),
}


class EventManager(Node):
    """Task store and event-weight schedule, published as TaskState."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        self._heartbeat_period = values['heartbeat_period']
        self._max_task_speed = values['max_task_speed']
        self._reach = values['reach']
        self._revisions = count()
        # Schedule keys are (name, revision): a new revision of the active task is a switch.
        self._tasks: dict[str, tuple[str, int]] = {}
        self._records: dict[tuple[str, int], TaskRecord] = {}
        if not Path(values['tasks_dir']).is_dir():
            self.get_logger().warning(f'tasks_dir {values["tasks_dir"]!r} is not a folder: no '
                                      'task loaded at start (tasks can still come on /hri/task)')
        loaded, rejected = load_task_directory(values['tasks_dir'])
        for path, reason in rejected:
            self.get_logger().warning(f'task file {path} rejected: {reason}')
        for record in loaded.values():
            shortfall = self._reach_shortfall(record)
            if shortfall is not None:
                self.get_logger().warning(f'task {record.name!r} from {values["tasks_dir"]} '
                                          f'refused: {shortfall}')
                continue
            self._store(record)
        initial = values['initial_task']
        if initial and initial not in self._tasks:
            known = ', '.join(sorted(self._tasks)) or 'none'
            raise StartupError(f'initial_task {initial!r} is not a known task '
                               f'(loaded from {values["tasks_dir"]}: {known})')
        self._schedule = EventWeightSchedule(values['ramp_time'])
        self._event_name = 'initial_task' if initial else ''
        self._initial_task = initial  # requested once /hri/task_state has a subscriber
        self._last_published = None
        self._last_publish_time = -float('inf')
        # What the node did, for its summary line at the stop.
        self._counts = dict.fromkeys(('tasks received', 'tasks rejected', 'events',
                                      'events ignored', 'switches', 'states published'), 0)

        self._state_publisher = self.create_publisher(TaskState, topics.TASK_STATE.name,
                                                      topics.TASK_STATE.qos)
        self.create_subscription(TaskParameters, topics.TASK.name, self._on_task,
                                 topics.TASK.qos)
        self.create_subscription(TaskEvent, topics.EVENTS.name, self._on_event,
                                 topics.EVENTS.qos)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self._ramp_period = 1.0 / values['publish_rate_hz']
        self._timer_period = self._ramp_period
        self._timer = self.create_timer(self._timer_period, self._publish)
        self.get_logger().info(
            f'{len(self._tasks)} task(s) loaded ({", ".join(sorted(self._tasks)) or "none"}); '
            f'initial task {initial or "none (idle)"}; ramp_time {values["ramp_time"]:g} s')

    def _store(self, record: TaskRecord) -> tuple[str, int]:
        key = (record.name, next(self._revisions))
        self._tasks[record.name] = key
        self._records[key] = record
        return key

    def _reach_shortfall(self, record: TaskRecord) -> str | None:
        """Why the task's pull vanishes within reach of its region (one line), or None."""
        try:
            return reach_shortfall(record.shape, record.k, self._max_task_speed, self._reach)
        except ValueError as error:
            return str(error)

    def _on_task(self, msg: TaskParameters) -> None:
        self._counts['tasks received'] += 1
        try:
            record = task_record(msg)
            shortfall = self._reach_shortfall(record)
            if shortfall is not None:
                raise ValueError(shortfall)
        except ValueError as error:
            current = self._schedule.evaluate(time.monotonic()).active_task
            keeping = f'task {current[0]!r}' if current else 'no task'
            self.get_logger().warning(
                f'task {msg.name!r} on /hri/task rejected: {error}; keeping {keeping}',
                throttle_duration_sec=WARNING_THROTTLE)
            self._counts['tasks rejected'] += 1
            return
        replaced = record.name in self._tasks
        key = self._store(record)
        self.get_logger().info(
            f'task {record.name!r} {"replaced" if replaced else "added"}: s={record.s} '
            f'd1={record.d1:.3f} d2={record.d2:.3f} a1={record.a1:.4g} a2={record.a2:.4g} '
            f'K={record.k:.4g}{" (default)" if record.k == 0.0 else ""}')
        state = self._schedule.evaluate(time.monotonic())
        if replaced and record.name in (_name(state.active_task), _name(state.pending_task)):
            self._switch(key, f'task_updated:{record.name}')

    def _on_event(self, msg: TaskEvent) -> None:
        self._counts['events'] += 1
        if msg.task and msg.task not in self._tasks:
            self.get_logger().warning(
                f'event {msg.name!r} names unknown task {msg.task!r}; ignored '
                f'(known: {", ".join(sorted(self._tasks)) or "none"})',
                throttle_duration_sec=WARNING_THROTTLE)
            self._counts['events ignored'] += 1
            return
        self._switch(self._tasks[msg.task] if msg.task else None, msg.name)

    def _switch(self, key, event_name: str) -> None:
        self._initial_task = ''  # an event before any subscriber overrides initial_task
        before = self._schedule.evaluate(time.monotonic())
        after = self._schedule.request(key, time.monotonic())
        if (after.phase, after.pending_task) != (before.phase, before.pending_task):
            self._counts['switches'] += 1
            self._event_name = event_name
            self.get_logger().info(
                f'event {event_name!r}: {_name(before.active_task) or "idle"} -> '
                f'{_name(after.pending_task) or _name(after.active_task) or "idle"} '
                f'({after.phase})')
        self._publish()

    def _validate_parameters(self, parameters) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name == 'ramp_time':
                state = self._schedule.evaluate(time.monotonic())
                if state.phase in (PHASE_FADING_IN, PHASE_FADING_OUT):
                    return SetParametersResult(
                        successful=False, reason='ramp_time cannot change during a ramp')
                self._schedule = EventWeightSchedule(parameter.value, state.active_task)
            elif parameter.name == 'heartbeat_period':
                self._heartbeat_period = parameter.value
                if self._timer_period != self._ramp_period:
                    self._pace(ramping=False)
        return SetParametersResult(successful=True)

    def _pace(self, ramping: bool) -> None:
        """Run the timer at publish_rate_hz while `ramping`, else at heartbeat_period."""
        period = self._ramp_period if ramping else self._heartbeat_period
        if period != self._timer_period:
            self._timer.timer_period_ns = round(period * 1e9)
            self._timer.reset()  # the next tick one new period from now
            self._timer_period = period

    def _publish(self) -> None:
        # The stamp is the time a is evaluated at (the controller holds a from the stamps): read
        # as one instant (paired_clocks), not after the message is built, which a loaded
        # machine may delay.
        now, stamp = read_together(time.monotonic, self.get_clock().now)
        if self._initial_task and self._state_publisher.get_subscription_count() > 0:
            self._schedule.request(self._tasks[self._initial_task], now)
            self._initial_task = ''
        state = self._schedule.evaluate(now)
        ramping = state.phase in (PHASE_FADING_IN, PHASE_FADING_OUT)
        self._pace(ramping or bool(self._initial_task))
        summary = (state.phase, state.active_task, state.pending_task)
        # A heartbeat is due a ramp period early at most: the slow timer's ticks come one
        # heartbeat_period after the last, give or take the timer's jitter.
        if not ramping and summary == self._last_published \
                and now - self._last_publish_time < self._heartbeat_period - self._ramp_period:
            return
        msg = TaskState(weight=state.weight, weight_rate=state.rate, phase=state.phase,
                        event=self._event_name, pending_task=_name(state.pending_task))
        msg.header.stamp = stamp.to_msg()
        if state.active_task is not None:
            msg.task = task_message(self._records[state.active_task])
        if state.phase == PHASE_IDLE:
            msg.weight, msg.weight_rate = 0.0, 0.0
        self._state_publisher.publish(msg)
        self._counts['states published'] += 1
        self._last_published = summary
        self._last_publish_time = now


    def summary(self) -> str:
        """One line on what the node did (run_node logs it at the stop)."""
        counts = self._counts
        state = self._schedule.evaluate(time.monotonic())
        return (f'{len(self._tasks)} task(s) held ({", ".join(sorted(self._tasks)) or "none"});'
                f' {counts["tasks received"]} received on /hri/task '
                f'({counts["tasks rejected"]} rejected), {counts["events"]} event(s) '
                f'({counts["events ignored"]} ignored), {counts["switches"]} switch(es), '
                f'{counts["states published"]} TaskStates published; active task '
                f'{_name(state.active_task) or "none"} at a = {state.weight:.2f}')


def _name(key) -> str:
    return key[0] if key else ''


def main(args=None):
    # The EventsExecutor: a 200 Hz publish timer alone kept a SingleThreadedExecutor at
    # about 20 % of a core with nothing to publish.
    return run_node(EventManager, NODE_NAME, EventsExecutor, args)


if __name__ == '__main__':
    sys.exit(main())
