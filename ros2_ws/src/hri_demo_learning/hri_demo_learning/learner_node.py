"""The `learner` node: demonstration bags in, a learned task (TaskParameters + YAML) out.

Once up, it learns one task with `learning.learn_task` (eq. 3-11, the task gain K and the
reach check; its fit and reading parameters become one `learning.LearningSettings` at start)
from the bags in `bags`, bag i moved outward by `shifts[i]` (eq. 4; with
`combine` false the bags are repetitions of one demonstration, with one averaged x_d), writes
`<output_dir>/<task_name>.yaml` and a figure `<task_name>.png` next to it, publishes the task
on hri_core.topics.TASK (/hri/task, reliable, transient local) and logs one summary line.
Its parameters and their defaults are in config/learner.yaml; `bags` has no default
(required) and `shifts` none either (unset: no shift).

With `once` it exits 0 once the task is saved and delivered: as soon as every matched
subscriber of /hri/task has acknowledged it, or, with none matched, once DISCOVERY_WINDOW s
from its start have passed (time for running subscribers to match; the fit usually takes
longer); it logs a warning if a subscriber has not acknowledged within ACK_TIMEOUT s.
Otherwise it stays up so that late joiners get the task. A bag it cannot learn from, or a bad
parameter, gives one error line and exit code 1, and no task file; so does a demonstration the
model does not describe (fit cost above `max_cost`) or a task whose pull would vanish within the
arm's reach of its region (the reach of the arm on the bag's /robot_description, l1 + l2 for a
bag without one).

A task that keeps the hand at a distance (d1 > 0) gets one more info line: whether d1 >=
ISO/TS 15066's S_p with the arm at `max_task_speed` (the hand at ISO 13855's speed, and
still), and up to what arm speed it would be (hri_core.separation.separation_verdict; S_p's
constants are parameters, the event_detector's defaults). The line only: a task file holds
TaskParameters' keys alone (hri_core.task_file refuses others).

Positions are 3-D. A bag without /ee_position is turned into tool positions through the
forward kinematics of its /robot_description (the URDF, tool link `tool_frame`); a bag recorded
before bags carried their robot, through the SCARA's (`l1`, `l2`); a bag with neither, or whose
joint states name joints its URDF lacks, is refused in one line.
"""

import sys
import time

from hri_interfaces.msg import TaskParameters
from rcl_interfaces.msg import SetParametersResult
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from hri_core import topics
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    run_node,
)
from hri_core.separation import ProtectiveSeparation, separation_verdict
from hri_core.task_message import task_message
from hri_demo_learning.learning import (
    SETTING_RANGES,
    LearningError,
    LearningSettings,
    learn_task,
)
from hri_demo_learning.performance_learning import METHODS

PACKAGE = 'hri_demo_learning'
NODE_NAME = 'learner'
DISCOVERY_WINDOW = 1.0  # s from node start: with `once`, time for running subscribers to match
# (measured here on loopback: 0.9-2.4 s with Fast DDS's defaults, 0.1 s with config/fastdds.xml)
ACK_TIMEOUT = 5.0  # s: with `once`, longest wait for matched subscribers to acknowledge
ACK_POLL = 0.02  # s: how often the `once` wait looks at matches and acknowledgments

PARAMETERS = {
    'bags': ParameterSpec(list[str], 'one or more bag folders or .mcap files',
                          required=True),
    'shifts': ParameterSpec(list, 'm, one per bag: bag i is moved outward by shifts[i] '
                            '(eq. 4); unset: no shift', optional=True),
    'task_name': ParameterSpec(str, 'name of the learned task ("" = the bag names joined)'),
    'output_dir': ParameterSpec(str, 'folder of the task YAML file and its figure'),
    'n': ParameterSpec(int, 'exponent N of eq. 2', *SETTING_RANGES['n']),
    'tolerance': ParameterSpec(float, 'stopping tolerance of the fit',
                               *SETTING_RANGES['tolerance']),
    'max_iterations': ParameterSpec(int, 'cap on the fit iterations',
                                    *SETTING_RANGES['max_iterations']),
    'stationary_speed': ParameterSpec(float, 'a sample slower than this is at rest whatever '
                                      'the pace (m/s, eq. 3, 5)',
                                      *SETTING_RANGES['stationary_speed']),
    'rest_fraction': ParameterSpec(float, 'a sample slower than this fraction of the '
                                   "demonstration's peak speed is at rest",
                                   *SETTING_RANGES['rest_fraction']),
    'combine': ParameterSpec(bool, 'true: the bags are combined by eq. 4 (shifts); false: '
                             'they repeat one demonstration and share its averaged x_d'),
    'max_cost': ParameterSpec(float, 'largest fit cost C (eq. 8) of a task it publishes',
                              *SETTING_RANGES['max_cost']),
    'max_task_speed': ParameterSpec(float, "the controller's max_task_speed (m/s), the "
                                    'reference of the reach check',
                                    *SETTING_RANGES['max_task_speed']),
    'workspace_radius': ParameterSpec(float, 'd2 of a desired region open outward (m)',
                                      *SETTING_RANGES['workspace_radius']),
    'once': ParameterSpec(bool, 'exit 0 after saving and delivering the task'),
    'method': ParameterSpec(str, 'fit solver: ' + ', '.join(METHODS) + " (trf: bounded least "
                            "squares; gauss_newton: the paper's eq. 9-11)"),
    'l1': ParameterSpec(float, "the SCARA's link 1 (m), for bags with joint states and no "
                        '/robot_description', *SETTING_RANGES['l1']),
    'l2': ParameterSpec(float, "the SCARA's link 2 (m), for bags with joint states and no "
                        '/robot_description', *SETTING_RANGES['l2']),
    # ISO/TS 15066 S_p's constants (hri_core.separation.ProtectiveSeparation), for the verdict
    # on a learned d1 > 0; the same names and defaults as the event_detector's.
    'reaction_time': ParameterSpec(float, 'S_p verdict: T_r, reaction time (s)', 0.0, 10.0),
    'stopping_time': ParameterSpec(float, "S_p verdict: T_s, the arm's stopping time (s)",
                                   0.0, 10.0),
    'stopping_distance': ParameterSpec(float, "S_p verdict: B, the arm's stopping distance (m)",
                                       0.0, 5.0),
    'intrusion_distance': ParameterSpec(float, "S_p verdict: C, a hand's reach beyond its "
                                        'tracked point (m)', 0.0, 5.0),
    'human_uncertainty': ParameterSpec(float, "S_p verdict: Z_d, the hand's position "
                                       'uncertainty (m)', 0.0, 5.0),
    'robot_uncertainty': ParameterSpec(float, "S_p verdict: Z_r, the tool's position "
                                       'uncertainty (m)', 0.0, 5.0),
    'near_speed': ParameterSpec(float, "S_p verdict: ISO 13855's hand speed within near_limit "
                                '(m/s)', 0.01, 10.0),
    'far_speed': ParameterSpec(float, "S_p verdict: ISO 13855's hand speed beyond near_limit "
                               '(m/s)', 0.01, 10.0),
    'near_limit': ParameterSpec(float, 'S_p verdict: the distance the two speeds change at (m)',
                                0.01, 10.0),
    'tool_frame': ParameterSpec(str, "the tool link of a bag's URDF, for bags with joint "
                                "states only ('' = the robot's own, or the URDF's one end "
                                'link)'),
}


class Learner(Node):
    """Learns one task from `bags` once up, saves it and publishes it on /hri/task."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self._started = time.monotonic()
        self._values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        try:
            self._settings = LearningSettings.from_parameters(self._values)
        except LearningError as error:
            raise StartupError(str(error)) from None
        try:
            self._separation = ProtectiveSeparation.from_mapping(
                {**self._values, 'assume_iso_speed': True})
        except ValueError as error:
            raise StartupError(f'bad S_p constants: {error}') from None
        self.exit_code: int | None = None  # set when a `once` run is over
        self._learned = None  # the LearnedTask, for the summary line
        self._delivered: bool | None = None  # whether every subscriber acknowledged it
        self.add_on_set_parameters_callback(self._reject_changes)
        self._publisher = self.create_publisher(TaskParameters, topics.TASK.name,
                                                topics.TASK.qos)
        # Learning takes a second or more: it runs in the executor's first turn, so that a
        # stop request before it is honoured and its failure ends the node like a bad
        # parameter does (run_node logs the StartupError).
        self._learn_timer = self.create_timer(0.0, self._learn)

    def _learn(self) -> None:
        self._learn_timer.cancel()
        values = self._values
        try:
            learned = learn_task(values['bags'], values['shifts'], values['task_name'],
                                 values['output_dir'], self._settings)
        except LearningError as error:
            raise StartupError(str(error)) from None
        task = learned.record
        self._learned = learned
        self._publisher.publish(task_message(task, self.get_clock().now().to_msg()))
        self.get_logger().info(
            f"learned task '{task.name}' from {len(values['bags'])} bag(s): S={task.s:+d} "
            f'd1={task.d1:.3f} m d2={task.d2:.3f} m a1={task.a1:.4g} a2={task.a2:.4g} 1/m^2 '
            f'K={task.k:.4g} m^2/s '
            f'C={task.cost:.3g} iterations={task.iterations} ({learned.method}'
            f'{"" if learned.converged else ", not converged"}, fit {learned.fit_seconds:.3f} '
            f's, total {learned.total_seconds:.2f} s) -> {learned.task_file}, {learned.figure}')
        if task.d1 > 0.0:
            verdict = separation_verdict(task.d1, values['max_task_speed'], self._separation)
            self.get_logger().info(f"task '{task.name}': {verdict.summary()}")
        if not learned.converged:
            self.get_logger().warning(
                f'the {learned.method} fit did not converge '
                f'({" ".join(learned.fit_message.split())}); '
                'the task was saved but a1, a2 may be poor')
        if values['once']:
            self._delivered = self.deliver()
            if not self._delivered:
                self.get_logger().warning('a subscriber of /hri/task did not acknowledge the '
                                          f'task within {ACK_TIMEOUT} s')
            self.exit_code = 0

    def summary(self) -> str:
        """One line on what the node did (run_node logs it at the stop)."""
        learned = self._learned
        if learned is None:
            return 'no task learned (stopped before learning was done)'
        delivery = {None: 'published on /hri/task (transient local)',
                    True: 'published on /hri/task and delivered',
                    False: 'published on /hri/task, not acknowledged by every subscriber'}
        return (f"1 task learned: '{learned.record.name}' from {len(self._values['bags'])} "
                f'bag(s), {delivery[self._delivered]}; saved to {learned.task_file}')

    def _reject_changes(self, parameters) -> SetParametersResult:
        names = ', '.join(p.name for p in parameters)
        return SetParametersResult(
            successful=False,
            reason=f'the learner learns once at start; restart it to change {names}')

    def deliver(self) -> bool:
        """Make sure subscribers already running get the task before the node exits.

        Returns True as soon as every matched subscriber of /hri/task has acknowledged the
        task, or when none has matched DISCOVERY_WINDOW s after the node started (discovery
        of running nodes takes a moment); False if a matched subscriber did not acknowledge
        within ACK_TIMEOUT s.
        """
        give_up = time.monotonic() + ACK_TIMEOUT
        while True:
            if self._publisher.get_subscription_count() > 0:
                if self._publisher.wait_for_all_acked(Duration(seconds=ACK_POLL)):
                    return True
            elif time.monotonic() >= self._started + DISCOVERY_WINDOW:
                return True
            else:
                time.sleep(ACK_POLL)
            if time.monotonic() >= give_up:
                return False


def main(args=None):
    return run_node(Learner, NODE_NAME, SingleThreadedExecutor, args,
                    exit_code=lambda node: node.exit_code)


if __name__ == '__main__':
    sys.exit(main())
