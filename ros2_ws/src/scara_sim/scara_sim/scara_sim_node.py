"""The `scara_sim` node: a simulated horizontal 2-link SCARA driven by joint commands.

Integrates the arm of `dynamics.py` with RK4 in fixed steps of 1/rate_hz s (default 1 ms).
A stepping thread ticks at rate_hz (it sleeps to the end of each step) and runs the steps
that real time has reached since the last tick (at most `max_catch_up_steps` per tick, the
older ones are dropped and counted), and publishes the state after every step it integrated,
those caught up after a late tick included (simulation.RealTimeStepper). The stepping thread
takes the joint commands received since the last tick itself, at each tick (from the
subscriptions of a second node, `<name>_commands`, that no executor spins); the executor runs
the other callbacks (the wrench, parameters) beside it. A step that fails (a non-finite
state) ends the process with exit code 1 and one error line:

* /joint_states (sensor_msgs/JointState): joint1, joint2; position (rad), velocity (rad/s),
  effort = the drive torque applied (N m, the human's J^T f not included);
* /ee_position (geometry_msgs/PointStamped, frame `base_frame`): forward kinematics (m), of
  the newest state only (once per tick: a late tick's caught-up steps are not repeated here).
The header stamp is the time the state stands for: the ROS time of the first tick plus the
simulated time of that step, which follows real time. With `realtime_priority` > 0 the process
asks for SCHED_FIFO at that priority (hri_core.realtime) and logs once whether it got it; with
`cpu_wakeup_latency` >= 0 it holds a PM QoS request that idle CPUs wake within that many
microseconds (0: they poll).

Inputs (reliable, depth 10); the most recent valid joint command chooses the drive mode:
* /effort_controller/commands (std_msgs/Float64MultiArray [tau1, tau2], N m): clipped at
  effort_limit and applied;
* /velocity_controller/commands (Float64MultiArray [dq1, dq2], rad/s): tracked by the
  drive's internal stiff PI velocity loop (`velocity_kp`, `velocity_ki`; see
  simulation.VelocityLoop), its torque clipped at effort_limit;
* /human/wrench (geometry_msgs/WrenchStamped, frame `base_frame` or empty): force x, y in N
  on the end-effector, applied as J^T f; ignored after `wrench_timeout` s without a new one.
No command for `command_timeout` s: zero torque (logged once, and once when commands
resume). A malformed command or wrench (wrong length, NaN/inf, wrong frame) is rejected
with a throttled warning; the last good one stays in force.
"""

import math
import sys
import threading
import time

import numpy as np
from geometry_msgs.msg import PointStamped, WrenchStamped
from rcl_interfaces.msg import SetParametersResult
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
from hri_core.dynamics import ScaraParameters, forward_kinematics_pair
from hri_core.node_common import (
    CPU_WAKEUP_LATENCY,
    REALTIME_PRIORITY,
    ParameterSpec,
    StartupError,
    declare_parameters,
    float_array_problem,
    hold_wakeup_latency,
    load_defaults,
    request_realtime,
    run_node,
    take_raw,
)
from scara_sim.simulation import (
    FixedStepClock,
    RealTimeStepper,
    ScaraSimulator,
    StepState,
    VelocityLoop,
    joint_command_floats,
)

PACKAGE = 'scara_sim'
NODE_NAME = 'scara_sim'
JOINT_NAMES = ['joint1', 'joint2']
WARN_THROTTLE = 2.0  # s between two warnings about malformed input

ARM_PARAMETERS = {  # ScaraParameters fields; every one may change at run time
    'l1': ParameterSpec(float, 'length of link 1 (m)', 0.05, 2.0),
    'l2': ParameterSpec(float, 'length of link 2 (m)', 0.05, 2.0),
    'lc1': ParameterSpec(float, 'joint 1 to the centre of mass of link 1 (m)', 0.0, 2.0),
    'lc2': ParameterSpec(float, 'joint 2 to the centre of mass of link 2 and its load (m)',
                         0.0, 2.0),
    'm1': ParameterSpec(float, 'mass of link 1 (kg)', 0.01, 100.0),
    'm2': ParameterSpec(float, 'mass of link 2 with quill and tool (kg)', 0.01, 100.0),
    'i1': ParameterSpec(float, 'inertia of link 1 about its centre of mass (kg m^2)',
                        1e-5, 10.0),
    'i2': ParameterSpec(float, 'inertia of link 2 about its centre of mass (kg m^2)',
                        1e-5, 10.0),
    'b1': ParameterSpec(float, 'viscous friction of joint 1 (N m s/rad)', 0.0, 100.0),
    'b2': ParameterSpec(float, 'viscous friction of joint 2 (N m s/rad)', 0.0, 100.0),
    'gravity': ParameterSpec(float, 'gravity along -y of the arm plane (m/s^2); 0: horizontal',
                             -20.0, 20.0),
}
ARRAY_PARAMETERS = {
    'joint_lower_limits': ParameterSpec(list, 'lower joint limits (rad)', size=2),
    'joint_upper_limits': ParameterSpec(list, 'upper joint limits (rad)', size=2),
    'velocity_kp': ParameterSpec(list,
                                 'velocity-mode PI loop: proportional gains (N m s/rad)',
                                 size=2),
    'velocity_ki': ParameterSpec(list,
                                 'velocity-mode PI loop: integral gains (N m/rad)', size=2),
}
PARAMETERS = {
    'rate_hz': ParameterSpec(float, 'integration step and publish rate (Hz); step = '
                             '1/rate_hz', 1000.0, 10000.0, read_only=True),
    'max_catch_up_steps': ParameterSpec(
        int, 'most steps one timer tick may run to catch up with real time; the rest are '
        'dropped and counted', 1, 10000, read_only=True),
    'realtime_priority': REALTIME_PRIORITY,
    'cpu_wakeup_latency': CPU_WAKEUP_LATENCY,
    **ARM_PARAMETERS,
    **ARRAY_PARAMETERS,
    'initial_q': ParameterSpec(list, 'joint positions at start (rad)', size=2,
                               read_only=True),
    'effort_limit': ParameterSpec(float, 'drive torque limit of each joint (N m)', 0.1, 1000.0),
    'command_timeout': ParameterSpec(float, 'no joint command for this long (s): zero torque',
                                     0.005, 60.0),
    'wrench_timeout': ParameterSpec(float, 'no /human/wrench for this long (s): zero force',
                                    0.005, 60.0),
    'base_frame': ParameterSpec(str, 'frame of /ee_position and of /human/wrench',
                                read_only=True),
    'report_period': ParameterSpec(float, 'how often (s) late or dropped steps are reported',
                                   0.1, 3600.0),
}


def _taken_by_the_stepping_thread(data: bytes) -> None:
    """The command subscriptions' callback, never called: no executor spins their node."""


class ScaraSim(Node):
    """Integrates the arm and publishes its state at rate_hz."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        rate_hz = values['rate_hz']
        self._max_catch_up = values['max_catch_up_steps']
        initial_q = values['initial_q']
        self._effort_limit = values['effort_limit']
        self._command_timeout = values['command_timeout']
        self._wrench_timeout = values['wrench_timeout']
        self._frame = values['base_frame']
        self._report_period = values['report_period']
        try:
            params, limits, loop = self._model_from({})
            self._sim = ScaraSimulator(
                params=params, q=np.array(initial_q), dq=np.zeros(2), lower=limits[0],
                upper=limits[1], effort_limit=self._effort_limit, velocity_loop=loop,
                dt=1.0 / rate_hz)
        except ValueError as error:
            raise StartupError(f'bad parameters: {error}') from None
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # (mode, command, receive time) and (force, receive time): each replaced whole by the
        # executor's callbacks and read by the stepping thread.
        self._drive = ('idle', np.zeros(2), time.monotonic())
        self._timed_out = False
        self._hand_force = (np.zeros(2), -math.inf)
        self.failure = None  # the one-line reason the stepping stopped, if it did
        self._stepper: RealTimeStepper | None = None
        self._stamp0 = 0
        self._reported = (0, 0, 0)
        self._last_report = time.monotonic()

        self._joint_pub = self.create_publisher(JointState, topics.JOINT_STATES.name,
                                                topics.JOINT_STATES.qos)
        self._ee_pub = self.create_publisher(PointStamped, topics.EE_POSITION.name,
                                             topics.EE_POSITION.qos)
        # The 1 kHz messages as raw CDR (hri_core.cdr): commands read at fixed offsets while
        # their layout holds, states written from templates.
        self._command_readers = {mode: LayoutReader(float64_array_layout)
                                 for mode in ('effort', 'velocity')}
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
            for mode, topic in (('effort', topics.EFFORT_COMMANDS),
                                ('velocity', topics.VELOCITY_COMMANDS)))
        self.create_subscription(WrenchStamped, topics.HUMAN_WRENCH.name, self._on_wrench,
                                 topics.HUMAN_WRENCH.qos)
        self._joint_template = joint_state_template(JOINT_NAMES)
        self._ee_template = point_stamped_template(self._frame)
        # The steps run in a thread of their own that sleeps to each tick (absolute times, so
        # the ticks do not drift): an rclpy timer on the EventsExecutor cost 12 % of a core at
        # 1 kHz alone and came late behind the command callbacks; this thread, 5 %.
        self._stopping = threading.Event()
        self._stepping = threading.Thread(target=self._step_in_real_time,
                                          name='scara_sim_steps', daemon=True)
        self.get_logger().info(
            f'simulating at {rate_hz:g} Hz (RK4, dt {1e3 / rate_hz:g} ms) from q = '
            f'{np.round(self._sim.q, 4).tolist()} rad; effort limit {self._effort_limit:g} '
            f'N m, command timeout {self._command_timeout:g} s')
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

    # Parameters -------------------------------------------------------------------------

    def _model_from(self, overrides: dict):
        """ScaraParameters, joint limits and velocity loop from current params + overrides."""
        def value(name):
            return overrides[name] if name in overrides else self.get_parameter(name).value

        params = ScaraParameters(**{name: float(value(name)) for name in ARM_PARAMETERS})
        limits = (np.array(value('joint_lower_limits'), float),
                  np.array(value('joint_upper_limits'), float))
        if np.any(limits[0] >= limits[1]):
            raise ValueError(f'joint_lower_limits {limits[0].tolist()} must be below '
                             f'joint_upper_limits {limits[1].tolist()}')
        loop = VelocityLoop(kp=value('velocity_kp'), ki=value('velocity_ki'),
                            effort_limit=float(value('effort_limit')))
        return params, limits, loop

    def _validate_parameters(self, parameters) -> SetParametersResult:
        overrides = {p.name: p.value for p in parameters}
        for name in ARRAY_PARAMETERS:
            if name in overrides:
                reason = float_array_problem(overrides[name], 2)
                if reason:
                    return SetParametersResult(successful=False, reason=f'{name}: {reason}')
        try:
            self._model_from(overrides)
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters) -> None:
        params, limits, loop = self._model_from({})
        sim = self._sim
        sim.params, sim.lower, sim.upper = params, limits[0], limits[1]
        loop.integral = sim.velocity_loop.integral
        sim.velocity_loop = loop
        self._effort_limit = sim.effort_limit = self.get_parameter('effort_limit').value
        self._command_timeout = self.get_parameter('command_timeout').value
        self._wrench_timeout = self.get_parameter('wrench_timeout').value
        self._report_period = self.get_parameter('report_period').value
        self.get_logger().info('parameters changed: ' + ', '.join(
            f'{p.name}={p.value}' for p in parameters))

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
            command = joint_command_floats(data)
        except ValueError as error:
            self.get_logger().warning(f'rejected {mode} command: {error}',
                                      throttle_duration_sec=WARN_THROTTLE)
            return
        if mode == 'velocity' and self._drive[0] != 'velocity':
            self._sim.velocity_loop.reset()
        if self._timed_out:
            self.get_logger().info(f'{mode} commands resumed')
            self._timed_out = False
        self._drive = (mode, command, time.monotonic())

    def _on_wrench(self, msg: WrenchStamped) -> None:
        frame = msg.header.frame_id
        try:
            if frame not in ('', self._frame):
                raise ValueError(f'frame {frame!r} is not {self._frame!r}')
            force = joint_command_floats((msg.wrench.force.x, msg.wrench.force.y))
        except ValueError as error:
            self.get_logger().warning(f'rejected /human/wrench: {error}',
                                      throttle_duration_sec=WARN_THROTTLE)
            return
        self._hand_force = (force, time.monotonic())

    # Stepping ---------------------------------------------------------------------------

    def _inputs(self, t: float):
        """The drive mode, command and hand force in force at `t` (monotonic s), the end of
        a step: a command older than command_timeout or a force older than wrench_timeout
        is no longer applied."""
        force, force_time = self._hand_force
        if t - force_time > self._wrench_timeout:
            force = (0.0, 0.0)
        mode, command, command_time = self._drive
        if t - command_time > self._command_timeout:
            if not self._timed_out:
                self.get_logger().info(
                    f'no joint command for {self._command_timeout:g} s: applying zero torque')
                self._timed_out = True
            return 'idle', None, force
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
        now = time.monotonic()
        if self._stepper is None:
            self._stepper = RealTimeStepper(self._sim, FixedStepClock(
                self._sim.dt, self._max_catch_up, now))
            self._stamp0 = self.get_clock().now().nanoseconds
            sim = self._sim
            state = StepState(0.0, tuple(sim.q.tolist()), tuple(sim.dq.tolist()),
                              tuple(sim.applied_effort.tolist()))
            self._publish_joint_state(state)
            self._publish_tip(state)
            return
        self._take_commands()
        states = self._stepper.advance(now, self._inputs)
        for state in states:
            self._publish_joint_state(state)
        if states:
            self._publish_tip(states[-1])
        if now - self._last_report >= self._report_period:
            self._report(now)

    def _stamp(self, state: StepState) -> tuple[int, int]:
        """(sec, nanosec) of the time `state` stands for."""
        return divmod(self._stamp0 + round(state.sim_time * 1e9), 10 ** 9)

    def _publish_joint_state(self, state: StepState) -> None:
        self._joint_pub.publish(self._joint_template.encode(
            state.q, state.dq, state.effort, stamp=self._stamp(state)))

    def _publish_tip(self, state: StepState) -> None:
        params = self._sim.params
        x, y = forward_kinematics_pair(*state.q, params.l1, params.l2)
        self._ee_pub.publish(self._ee_template.encode((x, y, 0.0), stamp=self._stamp(state)))

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
        """One line on the whole run's timing."""
        if self._stepper is None:
            return 'no step run'
        clock = self._stepper.clock
        return (f'{clock.integrated} steps integrated in {clock.ticks} ticks '
                f'({clock.sim_time:.1f} s): {clock.late_ticks} late ticks caught up, '
                f'{clock.dropped} steps dropped')


def _stop(node: ScaraSim) -> None:
    node.stop_stepping()
    node.get_logger().info(node.summary())


def main(args=None):
    # The EventsExecutor (for the command callbacks) at a fraction of the CPU of the
    # SingleThreadedExecutor (bench/bench_sim.py).
    return run_node(ScaraSim, NODE_NAME, EventsExecutor, args,
                    exit_code=lambda node: None if node.failure is None else 1, on_stop=_stop)


if __name__ == '__main__':
    sys.exit(main())
