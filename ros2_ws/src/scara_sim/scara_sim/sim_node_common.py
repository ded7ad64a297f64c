"""What the simulator nodes (scara_sim, arm_sim) share: real-time stepping, every step
published, joint commands taken by the stepping thread, the command and wrench timeouts, and
the fault handling.

`SteppedSimNode` is a Node whose subclass declares its parameters, builds its simulator
(anything with `dt`, `q`, `dq`, `applied_effort` and `step(mode, command, wrench)`, see
simulation.RealTimeStepper) and then calls `start_stepping_setup`. A stepping thread ticks at
1/dt (it sleeps to the end of each step) and runs the steps that real time has reached since
the last tick (at most `max_catch_up_steps` per tick, the older ones dropped and counted),
publishing the state after every step it integrated on /joint_states, and the tool point of
the newest on /ee_position. The stepping thread takes the joint commands received since the
last tick itself, at each tick, from the subscriptions of a second node `<name>_commands`
that no executor spins; the executor runs the other callbacks (the wrench, parameters) beside
it. A step that fails (a non-finite state) ends the process with exit code 1 and one error
line. No joint command for `command_timeout` s: the drive's mode before its first command,
zero torque or (arm_sim) the brakes (logged once, and once when
commands resume). A malformed command or wrench (wrong length, NaN/inf, wrong frame) is
rejected with a throttled warning; the last good one stays in force.

The subclass gives: `joint_names`, `command_topics` (mode -> Topic),
`stepping_thread_name`, `wrench_values(msg)` (the wrench components its simulator takes),
`tool_point(q)` (x, y, z) in m, and optionally `on_new_mode(mode)`, `before_steps()` (the
stepping thread, each tick before its steps: inputs other than the joint commands) and
`after_steps(states)` (after the tick's states are published: more output of those steps).
"""

import math
import threading
import time
from typing import NoReturn

import numpy as np
from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_core import topics
from hri_core.cdr import (
    LayoutReader,
    float64_array_layout,
    joint_state_template,
    point_stamped_template,
)
from hri_core.node_common import (
    CPU_WAKEUP_LATENCY,
    REALTIME_PRIORITY,
    ParameterSpec,
    hold_wakeup_latency,
    request_realtime,
    run_node,
    take_raw,
)
from hri_core.robot_model import ROBOT_NAMES, RobotModel, robot_model
from hri_core.validation import check_frame
from scara_sim.simulation import (
    FixedStepClock,
    RealTimeStepper,
    StampSlew,
    StepState,
    joint_command_floats,
)

WARN_THROTTLE = 2.0  # s between two warnings about malformed input
CLOCK_READ_LIMIT = 20_000  # ns: a system clock read between two monotonic ones this far apart


def clock_offset() -> int | None:
    """The system clock minus the monotonic one (ns), or None if the process was held up while
    reading them (a stopped or preempted thread would read a drift that is not there)."""
    before = time.monotonic_ns()
    system = time.time_ns()
    after = time.monotonic_ns()
    return None if after - before > CLOCK_READ_LIMIT else system - (before + after) // 2

# Which arm a node simulates or works on (robot_from_parameters).
ROBOT_PARAMETERS = {
    'robot': ParameterSpec(str, 'the arm by name, of hri_core.robot_model.ROBOTS (ignored '
                           'when urdf_file is given)', choices=ROBOT_NAMES, read_only=True),
    'urdf_file': ParameterSpec(str, 'URDF of the arm ("": the robot parameter)',
                               read_only=True),
    'tool_frame': ParameterSpec(str, 'URDF link or frame of the tool point ("": the '
                                "robot's own; required with urdf_file)", read_only=True),
}

# The parameters every simulator node declares: stepping first, the inputs' timing last.
STEPPING_PARAMETERS = {
    'rate_hz': ParameterSpec(float, 'integration step and publish rate (Hz); step = '
                             '1/rate_hz', 1000.0, 10000.0, read_only=True),
    'max_catch_up_steps': ParameterSpec(
        int, 'most steps one timer tick may run to catch up with real time; the rest are '
        'dropped and counted', 1, 10000, read_only=True),
    'realtime_priority': REALTIME_PRIORITY,
    'cpu_wakeup_latency': CPU_WAKEUP_LATENCY,
}
TIMING_PARAMETERS = {
    'command_timeout': ParameterSpec(float, 'no joint command for this long (s): zero torque '
                                     '(arm_sim: its brakes)',
                                     0.005, 60.0),
    'wrench_timeout': ParameterSpec(float, 'no /human/wrench for this long (s): zero force',
                                    0.005, 60.0),
    'base_frame': ParameterSpec(str, 'frame of /ee_position and of /human/wrench',
                                read_only=True),
    'report_period': ParameterSpec(float, 'how often (s) late or dropped steps are reported',
                                   0.1, 3600.0),
}


def robot_from_parameters(values: dict) -> RobotModel:
    """The arm of the ROBOT_PARAMETERS in `values` (hri_core.robot_model.robot_model);
    ValueError with the reason."""
    if values['urdf_file']:
        return robot_model(urdf_file=values['urdf_file'], tool_frame=values['tool_frame'])
    return robot_model(values['robot'], tool_frame=values['tool_frame'])


def _taken_by_the_stepping_thread(data: bytes) -> None:
    """The command subscriptions' callback, never called: no executor spins their node."""


class SteppedSimNode(Node):
    """A simulator node stepping in real time (see the module docstring)."""

    joint_names: tuple[str, ...] = ()
    command_topics: dict = {}
    stepping_thread_name = 'sim_steps'
    # The drive's mode until the first command: 'idle' (zero torque) or 'brake' (the joints
    # held, as a robot's brakes hold it until its controller first commands it).
    initial_mode = 'idle'

    def read_stepping_settings(self, values: dict) -> None:
        """The settings every simulator node declares, from its declared `values`."""
        self._max_catch_up = values['max_catch_up_steps']
        self._command_timeout = values['command_timeout']
        self._wrench_timeout = values['wrench_timeout']
        self._frame = values['base_frame']
        self._report_period = values['report_period']

    def apply_timing_parameters(self, parameters) -> None:
        """After a parameter change: the timeouts and report period of TIMING_PARAMETERS
        from their current values, and one line naming what changed."""
        self._command_timeout = self.get_parameter('command_timeout').value
        self._wrench_timeout = self.get_parameter('wrench_timeout').value
        self._report_period = self.get_parameter('report_period').value
        self.get_logger().info('parameters changed: ' + ', '.join(
            f'{p.name}={p.value}' for p in parameters))

    def wrench_values(self, msg: WrenchStamped) -> tuple:
        """The components of the wrench the simulator takes (checked: finite)."""
        raise NotImplementedError

    def tool_point(self, q) -> tuple[float, float, float]:
        """The tool point (x, y, z) in m of joint positions q."""
        raise NotImplementedError

    def on_new_mode(self, mode: str) -> None:
        """Called from the stepping thread when a command switches the drive to `mode`."""

    def before_steps(self) -> None:
        """Called from the stepping thread at each tick before its steps run."""

    def after_steps(self, states: list) -> None:
        """Called from the stepping thread after the tick's `states` (StepState, one per step
        integrated, oldest first) are published."""

    def start_stepping_setup(self, sim, values: dict, startup_line: str) -> None:
        """Publishers, subscriptions and the stepping thread for `sim`; `startup_line` is
        logged before the real-time requests of `values` are made."""
        self._sim = sim
        joints = len(self.joint_names)
        self._no_wrench = (0.0,) * len(self.wrench_values(WrenchStamped()))
        # (mode, command, receive time) and (wrench, receive time): each replaced whole by
        # the executor's callbacks and read by the stepping thread.
        self._drive = (self.initial_mode, np.zeros(joints), time.monotonic())
        self._timed_out = False
        self._hand_force = (self._no_wrench, -math.inf)
        self.failure = None  # the one-line reason the stepping stopped, if it did
        self._stepper: RealTimeStepper | None = None
        self._stamp0 = 0
        # The stamps follow the system clock where it drifts from the monotonic one
        # (StampSlew), measured from the clocks' offset at the first tick (ns; None: not
        # followed: the node runs on ROS time, which the stamps take as it is, or the clocks
        # could not be read).
        self._stamp_slew = StampSlew(round(sim.dt * 1e9))
        self._clock_offset0: int | None = None
        self._reported = (0, 0, 0)
        self._last_report = time.monotonic()

        self._joint_pub = self.create_publisher(JointState, topics.JOINT_STATES.name,
                                                topics.JOINT_STATES.qos)
        self._ee_pub = self.create_publisher(PointStamped, topics.EE_POSITION.name,
                                             topics.EE_POSITION.qos)
        # The 1 kHz messages as raw CDR (hri_core.cdr): commands read at fixed offsets while
        # their layout holds, states written from templates.
        self._command_readers = {mode: LayoutReader(float64_array_layout)
                                 for mode in self.command_topics}
        # The joint commands are taken by the stepping thread at each tick, in arrival order,
        # not by the executor: a 1 kHz callback woke the executor's thread for each command
        # and passed the GIL between it and the stepping thread. Their subscriptions belong
        # to a node of their own, `<name>_commands`, that no executor spins.
        # Its name as a local remapping: a global `-r __node:=NAME` would otherwise give it the
        # name of this node too.
        commands_name = f'{self.get_name()}_commands'
        self._command_node = Node(commands_name, namespace=self.get_namespace(),
                                  context=self.context, start_parameter_services=False,
                                  cli_args=['--ros-args', '-r', f'__node:={commands_name}'])
        self._command_subscriptions = tuple(
            (mode, self._command_node.create_subscription(
                Float64MultiArray, topic.name, _taken_by_the_stepping_thread, topic.qos,
                raw=True))
            for mode, topic in self.command_topics.items())
        self.create_subscription(WrenchStamped, topics.HUMAN_WRENCH.name, self._on_wrench,
                                 topics.HUMAN_WRENCH.qos)
        self._joint_template = joint_state_template(list(self.joint_names))
        self._ee_template = point_stamped_template(self._frame)
        # The steps run in a thread of their own that sleeps to each tick (absolute times, so
        # the ticks do not drift): an rclpy timer on the EventsExecutor cost 12 % of a core at
        # 1 kHz alone and came late behind the command callbacks; this thread, 5 %.
        self._stopping = threading.Event()
        self._stepping = threading.Thread(target=self._step_in_real_time,
                                          name=self.stepping_thread_name, daemon=True)
        self.get_logger().info(startup_line)
        request_realtime(self, values['realtime_priority'])
        self._wakeup_latency = hold_wakeup_latency(self, values['cpu_wakeup_latency'])
        # The first tick once the executor runs, as with the timer before: the process's own
        # set-up after this (the executor, its entities) could keep a running stepping thread
        # from its ticks, and a stall of over max_catch_up_steps drops steps, after which the
        # stamps lag real time for good.
        self._start_timer = self.create_timer(0.0, self._start_stepping)

    def _start_stepping(self) -> None:
        self._start_timer.cancel()
        if not self._stepping.is_alive() and not self._stopping.is_set():
            self._stepping.start()

    # Inputs -------------------------------------------------------------------------------

    def _take_commands(self) -> None:
        """Every joint command received since the last tick, in order (stepping thread)."""
        for mode, subscription in self._command_subscriptions:
            for data, _ in take_raw(subscription):
                self._on_command_data(mode, data)

    def _on_command_data(self, mode: str, data: bytes) -> None:
        """A command as serialized CDR: its values read at fixed offsets while the layout of
        the messages holds, else through rclpy's deserialiser."""
        values = self._command_readers[mode].read(data)
        if values is None:
            try:
                values = deserialize_message(data, Float64MultiArray).data
            except Exception as error:  # noqa: BLE001 any bytes may come from a raw publisher
                self.get_logger().warning(f'rejected {mode} command: unreadable ({error})',
                                          throttle_duration_sec=WARN_THROTTLE)
                return
        self._accept_command(mode, values)

    def _accept_command(self, mode: str, data) -> None:
        try:
            command = joint_command_floats(data, len(self.joint_names))
        except ValueError as error:
            self.get_logger().warning(f'rejected {mode} command: {error}',
                                      throttle_duration_sec=WARN_THROTTLE)
            return
        if mode != self._drive[0]:
            self.on_new_mode(mode)
        if self._timed_out:
            self.get_logger().info(f'{mode} commands resumed')
            self._timed_out = False
        self._drive = (mode, command, time.monotonic())

    def _on_wrench(self, msg: WrenchStamped) -> None:
        frame = msg.header.frame_id
        try:
            check_frame(frame, self._frame)
            wrench = self.wrench_values(msg)
        except ValueError as error:
            self.get_logger().warning(f'rejected /human/wrench: {error}',
                                      throttle_duration_sec=WARN_THROTTLE)
            return
        self._hand_force = (wrench, time.monotonic())

    # Stepping ---------------------------------------------------------------------------

    def _inputs(self, t: float):
        """The drive mode, command and hand wrench in force at `t` (monotonic s), the end of
        a step: a command older than command_timeout or a wrench older than wrench_timeout
        is no longer applied."""
        force, force_time = self._hand_force
        if t - force_time > self._wrench_timeout:
            force = self._no_wrench
        mode, command, command_time = self._drive
        if mode == 'brake':  # no command yet: held as the subclass's initial_mode says
            return mode, None, force
        if t - command_time > self._command_timeout:
            # The drive goes back to what it did before its first command: arm_sim's brakes
            # hold the joints (a Panda at zero torque falls: a controller starved for 0.3 s
            # on a loaded machine let it into joint 2's stop), scara_sim's horizontal arm and
            # an arm in teach mode get zero torque.
            if not self._timed_out:
                action = ('braking (the joints held)' if self.initial_mode == 'brake'
                          else 'applying zero torque')
                self.get_logger().info(
                    f'no joint command for {self._command_timeout:g} s: {action}')
                self._timed_out = True
            return self.initial_mode, None, force
        return mode, command, force

    def _step_in_real_time(self) -> None:
        """The stepping thread: a tick every dt s until stop_stepping; a tick that fails
        ends the stepping with its reason in `failure` (the process then exits non-zero)."""
        while not self._stopping.is_set():
            try:
                self._on_tick()
            except Exception as error:  # noqa: BLE001 one line, then the process ends
                self.failure = f'simulation stopped: {error}'
                self.get_logger().error(self.failure)
                return
            delay = self._stepper.clock.next_step_end - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)

    def stop_stepping(self) -> None:
        """End the stepping thread (before the node's publishers go)."""
        self._stopping.set()
        if self._stepping.is_alive() and self._stepping is not threading.current_thread():
            self._stepping.join(timeout=1.0)

    def destroy_node(self):
        self.stop_stepping()
        self._command_node.destroy_node()
        return super().destroy_node()

    def _on_tick(self) -> None:
        now_ns = time.monotonic_ns()
        now = now_ns * 1e-9
        if self._stepper is None:
            self._stepper = RealTimeStepper(self._sim, FixedStepClock(
                self._sim.dt, self._max_catch_up, now))
            for _ in range(0 if self.get_clock().ros_time_is_active else 10):
                self._clock_offset0 = clock_offset()
                if self._clock_offset0 is not None:
                    break
            # The first stamp is the system time of the clock's start (`now`), not a read
            # after it: held up between the two (a loaded machine), every stamp ran that far
            # ahead of the time it was sent (378 states by up to 0.57 ms).
            self._stamp0 = (self.get_clock().now().nanoseconds if self._clock_offset0 is None
                            else now_ns + self._clock_offset0)
            sim = self._sim
            state = StepState(0.0, tuple(sim.q.tolist()), tuple(sim.dq.tolist()),
                              tuple(sim.applied_effort.tolist()))
            self._publish_joint_state(state)
            self._publish_tip(state)
            return
        self._take_commands()
        self.before_steps()
        states = self._stepper.advance(now, self._inputs)
        offset = None if self._clock_offset0 is None else clock_offset()
        if offset is not None:
            self._stamp_slew.update(offset - self._clock_offset0, len(states))
        for state in states:
            self._publish_joint_state(state)
        if states:
            self._publish_tip(states[-1])
            self.after_steps(states)
        if now - self._last_report >= self._report_period:
            self._report(now)

    def stamp_of(self, state: StepState) -> tuple[int, int]:
        """(sec, nanosec) of the time `state` stands for (as its /joint_states carries)."""
        return self._stamp(state)

    def _stamp(self, state: StepState) -> tuple[int, int]:
        """(sec, nanosec) of the time `state` stands for."""
        return divmod(self._stamp0 + self._stamp_slew.correction
                      + round(state.sim_time * 1e9), 10 ** 9)

    def _publish_joint_state(self, state: StepState) -> None:
        self._joint_pub.publish(self._joint_template.encode(
            state.q, state.dq, state.effort, stamp=self._stamp(state)))

    def _publish_tip(self, state: StepState) -> None:
        self._ee_pub.publish(self._ee_template.encode(self.tool_point(state.q),
                                                      stamp=self._stamp(state)))

    def _report(self, now: float) -> None:
        """Log late ticks and dropped steps since the last report, if there were any."""
        clock = self._stepper.clock
        late, dropped, ticks = (clock.late_ticks - self._reported[0],
                                clock.dropped - self._reported[1],
                                clock.ticks - self._reported[2])
        if late or dropped:
            self.get_logger().info(
                f'timing over {now - self._last_report:.1f} s: {ticks} ticks, {late} late '
                f'(caught up; at most {clock.longest_catch_up} steps at one tick), '
                f'{dropped} steps dropped (> {self._max_catch_up} per tick)')
        self._reported = (clock.late_ticks, clock.dropped, clock.ticks)
        clock.start_window()
        self._last_report = now

    def summary(self) -> str:
        """One line on the whole run's timing (run_node logs it at the stop)."""
        if self._stepper is None:
            return 'no step run'
        clock = self._stepper.clock
        return (f'{clock.integrated} steps integrated in {clock.ticks} ticks '
                f'({clock.sim_time:.1f} s): {clock.late_ticks} late ticks caught up, '
                f'{clock.dropped} steps dropped')




def run_sim_node(node_class, node_name: str, args=None) -> NoReturn:
    """run_node for a SteppedSimNode: the EventsExecutor (for the few callbacks, at a
    fraction of the CPU of the SingleThreadedExecutor, bench/bench_sim.py), exit code 1
    after a failed step, the timing summary on the way out."""
    return run_node(node_class, node_name, EventsExecutor, args,
                    exit_code=lambda node: None if node.failure is None else 1,
                    on_stop=SteppedSimNode.stop_stepping)
