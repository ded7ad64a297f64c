"""The `demonstrator` node: plays the person who demonstrates a behaviour to the robot.

The arm (`robot`, or `urdf_file` and `tool_frame`, as arm_sim's; hri_core.robot_model) sets
the demonstration's dimension: the planar SCARA (`robot:=scara`, the default) is pushed in its
plane, x_r and forces [x, y]; any other arm (`robot:=panda`) in space, x_r [x, y, z] and a 3-D
force at the tool, along a path that rises or falls as x_r lies above or below the tool.
x_r (`reference`) unset: the robot's default (DEFAULT_REFERENCES; a URDF arm needs one given).
x_r and the goal must lie within the arm's reach of its shoulder. A Panda is taught with
arm_sim in teach mode (`teach_mode:=true`: gravity compensated, as in its guiding mode).

1. Waits for /ee_position (geometry_msgs/PointStamped) from the arm; none within
   `wait_timeout` s: one error line, exit code 1.
2. Publishes the reference x_r (`reference`, m, base frame) on /demo/reference
   (PointStamped; z = 0 for the planar arm) at `rate_hz` from then until it exits.
3. After `start_delay` s, pushes the end-effector through /human/wrench
   (geometry_msgs/WrenchStamped, force x, y (, z) in N, base frame) with the hand model of
   `profiles.Demonstration`: a spring-damper (`stiffness`, `damping`, capped at `max_force`)
   toward a set-point moving on a minimum-jerk path at `peak_speed`, plus seeded tremor
   (`tremor_amplitude` N RMS in `tremor_band` Hz, `seed`). `mode: follow` brings the
   end-effector from where it is toward x_r and stops `stop_distance` m from it;
   `mode: avoid` moves it from near x_r straight away to `safe_distance` m (when it starts
   within 5 mm of x_r, along `avoid_direction`; unset: -y).
4. Lets go (zero force) once the end-effector has stayed within `settle_tolerance` of the
   goal for `settle_time` s at a mean speed below `settle_speed` (or `settle_timeout` s after
   the path ends), keeps publishing a zero wrench for `hold_time` s, and exits 0. An
   end-effector that drifts out of `settle_tolerance` while the hand is off is taken again
   (logged) and brought back, until `settle_timeout`.
The loop runs on elapsed time, not on a count of ticks, so that late ticks on a loaded machine
change neither the path nor the dwell nor the hold: the end-effector velocity comes from the
/ee_position stamps (low-passed differences), and each position is extrapolated from its stamp
to the present. If the node is stopped mid-push (or stalls), scara_sim drops the force after
its `wrench_timeout` (0.05 s: 10 periods at the default `rate_hz`).
"""

import sys
import time

import numpy as np
from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from hri_core import topics
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    run_node,
    stamp_seconds,
)
from hri_core.velocity_estimator import VelocityEstimator
from scara_sim.profiles import (
    DEMONSTRATION_MODES,
    Demonstration,
    PushSettings,
    Tremor,
    check_reach,
    demonstration_goal,
    demonstration_points,
)
from scara_sim.sim_node_common import ROBOT_PARAMETERS, robot_from_parameters

PACKAGE = 'scara_sim'
NODE_NAME = 'demonstrator'
# Every parameter is read-only: a demonstration runs once with the values it started with.
PUSH_SETTINGS = {  # PushSettings fields
    'stiffness': ParameterSpec(float, 'hand impedance stiffness (N/m)', 1.0, 5000.0,
                               read_only=True),
    'damping': ParameterSpec(float, 'hand impedance damping (N s/m)', 0.0, 1000.0,
                             read_only=True),
    'max_force': ParameterSpec(float, 'largest force the hand applies (N)', 0.1, 200.0,
                               read_only=True),
    'peak_speed': ParameterSpec(float, 'peak speed of the minimum-jerk path (m/s)', 0.01, 1.0,
                                read_only=True),
    'settle_tolerance': ParameterSpec(float, 'arrived: this close to the goal (m)', 1e-4, 0.1,
                                      read_only=True),
    'settle_speed': ParameterSpec(float, 'arrived: slower than this on average (m/s)', 1e-4,
                                  0.1, read_only=True),
    'settle_time': ParameterSpec(float, 'arrived: within settle_tolerance for this long (s)',
                                 0.0, 10.0, read_only=True),
    'settle_timeout': ParameterSpec(float, 'let go this long after the path ends (s)', 0.1,
                                    60.0, read_only=True),
    'hold_time': ParameterSpec(float, 'zero force for this long before exiting (s)', 0.0,
                               600.0, read_only=True),
}
# x_r when `reference` is unset, per robot: for the SCARA 0.269 m from where its
# end-effector starts (scara_sim's initial_q); for the Panda 0.279 m from its tool at home
# (0.307, 0, 0.487) m, forward, left and 0.19 m lower.
DEFAULT_REFERENCES = {'scara': (0.45, 0.05), 'panda': (0.45, 0.15, 0.30)}
PARAMETERS = {
    **ROBOT_PARAMETERS,
    'mode': ParameterSpec(str, 'follow: toward x_r; avoid: away from x_r',
                          choices=DEMONSTRATION_MODES, read_only=True),
    'reference': ParameterSpec(list, "x_r, the demonstration reference (m): [x, y] for the "
                               "SCARA, [x, y, z] for another arm (unset: the robot's default)",
                               read_only=True, optional=True),
    'stop_distance': ParameterSpec(float, 'follow: stop this far from x_r (m)', 0.001, 2.0,
                                   read_only=True),
    'safe_distance': ParameterSpec(float, 'avoid: move out to this distance from x_r (m)',
                                   0.001, 2.0, read_only=True),
    'avoid_direction': ParameterSpec(list, 'avoid: direction to move when starting '
                                     'within 5 mm of x_r, as many values as x_r (unset: -y)',
                                     read_only=True, optional=True),
    **PUSH_SETTINGS,
    'tremor_amplitude': ParameterSpec(float, 'hand tremor force, RMS per axis (N)', 0.0, 10.0,
                                      read_only=True),
    'tremor_band': ParameterSpec(list, 'hand tremor band [low, high] (Hz)', size=2,
                                 read_only=True),
    'seed': ParameterSpec(int, 'seed of the tremor noise', 0, 2**31 - 1, read_only=True),
    'rate_hz': ParameterSpec(float, 'rate of /human/wrench and /demo/reference (Hz); at '
                             "least 2.5 per scara_sim's wrench_timeout", 50.0, 1000.0,
                             read_only=True),
    'start_delay': ParameterSpec(float, 'wait after hearing the arm before pushing (s)', 0.0,
                                 600.0, read_only=True),
    'wait_timeout': ParameterSpec(float, 'give up when no /ee_position comes (s)', 0.1, 600.0,
                                  read_only=True),
    'velocity_filter_time': ParameterSpec(float, 'time constant of the end-effector velocity '
                                          'filter (s)', 0.001, 1.0, read_only=True),
    'base_frame': ParameterSpec(str, 'frame of /demo/reference and /human/wrench',
                                read_only=True),
}


class Demonstrator(Node):
    """Waits for the arm, pushes it along the demonstration, lets go, holds, finishes."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        try:
            self._arm = robot_from_parameters(values)
            self._reference, self._avoid_direction = demonstration_points(
                self._arm, values['reference'], values['avoid_direction'],
                DEFAULT_REFERENCES.get('' if values['urdf_file'] else values['robot']))
        except ValueError as error:
            raise StartupError(f'bad parameters: {error}') from None
        self._dimension = self._reference.size
        self._mode = values['mode']
        self._stop_distance = values['stop_distance']
        self._safe_distance = values['safe_distance']
        self._start_delay = values['start_delay']
        self._wait_timeout = values['wait_timeout']
        self._frame = values['base_frame']
        rate_hz = values['rate_hz']
        settings = {name: values[name] for name in PUSH_SETTINGS}
        try:
            self._settings = PushSettings(**settings)
            amplitude = values['tremor_amplitude']
            self._tremor = (Tremor(amplitude, tuple(values['tremor_band']), rate_hz,
                                   values['seed'], axes=self._dimension)
                            if amplitude > 0.0 else None)
            self._velocity = VelocityEstimator(values['velocity_filter_time'],
                                               dimension=self._dimension)
        except ValueError as error:
            raise StartupError(f'bad parameters: {error}') from None

        self.exit_code: int | None = None
        self._position: np.ndarray | None = None
        self._stamp = 0.0  # s, of self._position
        self._demonstration: Demonstration | None = None
        self._created = time.monotonic()
        self._heard_at: float | None = None
        self._push_start = 0.0
        self._peak_speed = 0.0
        self._positions_heard = 0  # /ee_position messages, for the summary line
        self._published = 0  # wrench and reference pairs
        self._wrench_pub = self.create_publisher(WrenchStamped, topics.HUMAN_WRENCH.name,
                                                 topics.HUMAN_WRENCH.qos)
        self._reference_pub = self.create_publisher(PointStamped, topics.DEMO_REFERENCE.name,
                                                    topics.DEMO_REFERENCE.qos)
        # The push loop needs fresh positions, not every one: best effort is enough.
        self.create_subscription(PointStamped, topics.EE_POSITION.name, self._on_position,
                                 qos_profile_sensor_data)
        self._wrench = WrenchStamped()
        self._wrench.header.frame_id = self._frame
        self._reference_msg = PointStamped()
        self._reference_msg.header.frame_id = self._frame
        point = self._reference_msg.point
        point.x, point.y, point.z = (*self._reference.tolist(), 0.0)[:3]
        self.create_timer(1.0 / rate_hz, self._on_tick)
        self.get_logger().info(
            f'{self._mode} demonstration around x_r = {self._reference.tolist()} m '
            f'({self._arm.name}, {self._dimension}-D): waiting for /ee_position (up to '
            f'{self._wait_timeout:g} s)')

    def _on_position(self, msg: PointStamped) -> None:
        position = np.array((msg.point.x, msg.point.y, msg.point.z)[:self._dimension])
        if not np.all(np.isfinite(position)):
            self.get_logger().warning('ignored a non-finite /ee_position',
                                      throttle_duration_sec=2.0)
            return
        stamp = stamp_seconds(msg.header.stamp)
        self._velocity.update(position, stamp)
        self._position, self._stamp = position, stamp
        self._positions_heard += 1

    def _on_tick(self) -> None:
        if self.exit_code is not None:
            return
        now = time.monotonic()
        if self._heard_at is None:
            if self._position is None:
                if now - self._created > self._wait_timeout:
                    self.get_logger().error(
                        f'no /ee_position within {self._wait_timeout:g} s: is scara_sim '
                        'running on this ROS_DOMAIN_ID?')
                    self.exit_code = 1
                return
            self._heard_at = now
            self.get_logger().info(f'end-effector at {np.round(self._position, 4).tolist()} '
                                   f'm; pushing in {self._start_delay:g} s')
        force = np.zeros(self._dimension)
        if self._demonstration is None and now - self._heard_at >= self._start_delay:
            if not self._begin(now):
                return
        if self._demonstration is not None:
            force = self._push(now)
        self._publish(force)

    def _begin(self, now: float) -> bool:
        """Plan the push from the current end-effector position; False if impossible."""
        try:
            goal = demonstration_goal(self._mode, self._position, self._reference,
                                      self._stop_distance, self._safe_distance,
                                      self._avoid_direction)
            check_reach(self._arm, goal, 'the goal')
        except ValueError as error:
            self.get_logger().error(f'cannot demonstrate: {error}')
            self.exit_code = 1
            return False
        self._demonstration = Demonstration(self._position, goal, self._settings, self._tremor)
        self._push_start = now
        self.get_logger().info(
            f'pushing from {np.round(self._position, 4).tolist()} to '
            f'{np.round(goal, 4).tolist()} m ({np.linalg.norm(goal - self._position):.3f} m '
            f'in {self._demonstration.duration:.2f} s, peak {self._settings.peak_speed:g} m/s)')
        return True

    def _push(self, now: float) -> np.ndarray:
        demo = self._demonstration
        before, regrasps = demo.phase, demo.regrasps
        age = max(0.0, self.get_clock().now().nanoseconds * 1e-9 - self._stamp)
        force = demo.update(now - self._push_start, self._position, self._velocity.velocity,
                            age)
        if demo.phase == 'pushing':
            self._peak_speed = max(self._peak_speed, float(np.linalg.norm(
                self._velocity.velocity)))
        distance = float(np.linalg.norm(self._position - self._reference))
        if demo.regrasps != regrasps:
            self.get_logger().info(
                f'took hold again: the end-effector drifted to {distance:.4f} m from x_r, '
                f'{np.linalg.norm(self._position - demo.goal) * 1e3:.1f} mm from the goal')
        if before != 'holding' and demo.phase in ('holding', 'done'):
            text = (f'at {distance:.4f} m from x_r; peak speed while pushing '
                    f'{self._peak_speed:.3f} m/s; holding still for '
                    f'{self._settings.hold_time:g} s')
            # One call site per severity: rclpy refuses a call site whose severity changes
            # (a ValueError that ended the node when a re-grasp let go a second time).
            if demo.settle_timed_out:
                self.get_logger().warning(f'let go (settle timeout: not arrived) {text}')
            else:
                self.get_logger().info(f'let go (arrived) {text}')
        if demo.phase == 'done':
            self.get_logger().info(f'demonstration done: end-effector {distance:.4f} m from '
                                   'x_r')
            self.exit_code = 0
        return force

    def _publish(self, force: np.ndarray) -> None:
        stamp = self.get_clock().now().to_msg()
        self._reference_msg.header.stamp = stamp
        self._reference_pub.publish(self._reference_msg)
        self._wrench.header.stamp = stamp
        push = self._wrench.wrench.force
        push.x, push.y = float(force[0]), float(force[1])
        if self._dimension == 3:
            push.z = float(force[2])
        self._wrench_pub.publish(self._wrench)
        self._published += 1

    def summary(self) -> str:
        """One line on what the node did (run_node logs it at the stop)."""
        demo = self._demonstration
        if demo is None:
            where = 'never pushed' if self._heard_at is not None else 'never heard the arm'
        else:
            where = (f'phase {demo.phase}, end-effector '
                     f'{float(np.linalg.norm(self._position - self._reference)):.4f} m from x_r')
        return (f'{self._mode} demonstration: {self._published} wrench and reference messages '
                f'published, {self._positions_heard} /ee_position heard; {where}')


def main(args=None):
    # /ee_position comes at 1 kHz: the EventsExecutor takes it at a fraction of the CPU.
    return run_node(Demonstrator, NODE_NAME, EventsExecutor, args,
                    exit_code=lambda node: node.exit_code)


if __name__ == '__main__':
    sys.exit(main())
