"""The `learner` node: demonstration bags in, a learned task (TaskParameters + YAML) out.

At start it reads every bag in `bags` (bag_io.read_demonstration: end-effector positions from
/ee_position, else /joint_states through the forward kinematics with `l1`, `l2`; x_r from
/demo/reference), builds each task energy P_d (eq. 3), moves bag i's profile outward by
`shifts[i]` and combines them (eq. 4), identifies S, d1, d2 (eq. 5, 6), fits a1, a2 (eq. 7-11,
`method` 'trf' or the paper's 'gauss_newton'), writes `<output_dir>/<task_name>.yaml` and a
figure `<task_name>.png` next to it, publishes the task on /hri/task (reliable, transient
local, depth 16) and logs one summary line.

With `once` it exits 0 once the task is saved and delivered: it gives running subscribers of
/hri/task DISCOVERY_WINDOW s from its start to match and waits for their acknowledgment;
otherwise it stays up so that late joiners get the task. A bag it cannot learn from, or a bad
parameter, gives one error line and a non-zero exit, and no task file.
"""

import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy
from hri_interfaces.msg import TaskParameters
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException, ParameterUninitializedException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter

from hri_core import topics
from hri_core.task_file import TaskRecord, is_safe_task_name, save_task_file
from hri_core.task_message import task_message
from hri_demo_learning.bag_io import BagError, read_demonstration
from hri_demo_learning.identification import identify_task_region
from hri_demo_learning.performance_learning import (
    DEFAULT_MAX_ITERATIONS,
    DEFAULT_TOLERANCE,
    METHODS,
    fit_task_parameters,
)
from hri_demo_learning.task_energy import (
    DEFAULT_STATIONARY_SPEED,
    EnergyProfile,
    combine_energy_profiles,
    demonstration_energy,
)

NODE_NAME = 'learner'
REFERENCE_TOLERANCE = 1e-3  # m: how far x_r may wander during one demonstration
DISCOVERY_WINDOW = 4.0  # s from node start: with `once`, time for running subscribers to match
# (measured here on loopback: 0.9-2.4 s with Fast DDS's defaults, 0.1 s with config/fastdds.xml)
ACK_TIMEOUT = 5.0  # s: with `once`, longest wait for matched subscribers to acknowledge


class LearningError(Exception):
    """The task cannot be learned; the message is a one-line reason."""


@dataclass(frozen=True)
class LearnedTask:
    """A learned task and how it was obtained (the summary line's numbers)."""

    record: TaskRecord
    profile: EnergyProfile  # of the (combined) demonstrations
    method: str
    converged: bool
    fit_message: str
    fit_seconds: float
    total_seconds: float


def _one_line(text) -> str:
    return ' '.join(str(text).split())


def check_fixed_reference(references: np.ndarray, x_r: np.ndarray, bag) -> None:
    """Raise LearningError if x_r moved during a demonstration (eq. 3 needs one fixed x_r).

    references: (M, 2) m, the reference held at each sample from the first moving one on;
    x_r: (2,) m, the reference used.
    """
    wander = float(np.max(np.hypot(*(references - x_r).T))) if len(references) else 0.0
    if wander > REFERENCE_TOLERANCE:
        raise LearningError(f'bag {bag}: the reference x_r moved by {wander:.3f} m during the '
                            f'demonstration; a demonstration needs one fixed x_r (eq. 3)')


def learn_from_bags(bags: list[str], shifts: list[float], task_name: str, n: int,
                    stationary_speed: float, workspace_radius: float, method: str,
                    tolerance: float, max_iterations: int, l1: float, l2: float) -> LearnedTask:
    """Learn one task from demonstration bags (eq. 3-11). Raises LearningError (one line)."""
    started = time.perf_counter()
    profiles = []
    for bag in bags:
        try:
            demo = read_demonstration(bag, l1=l1, l2=l2)
            x_r = demo.references[-1]  # the reference in force when the person let go
            energy = demonstration_energy(demo.times, demo.positions, x_r,
                                          stationary_speed=stationary_speed)
            check_fixed_reference(demo.references[demo.times >= energy.times[0]], x_r,
                                  demo.path)
        except BagError as err:
            raise LearningError(str(err)) from None
        except ValueError as err:
            raise LearningError(f'bag {bag}: {_one_line(err)}') from None
        profiles.append(energy.profile)
    try:
        profile = combine_energy_profiles(profiles, shifts)
        region = identify_task_region(profile.distance, profile.energy, profile.moving,
                                      workspace_radius=workspace_radius, n=n)
        fit = fit_task_parameters(profile.distance, profile.energy, region.s, region.d1,
                                  region.d2, n=n, method=method, tolerance=tolerance,
                                  max_iterations=max_iterations)
        record = TaskRecord(name=task_name, s=region.s, a1=fit.a1, a2=fit.a2, d1=region.d1,
                            d2=region.d2, n=n, cost=fit.cost, iterations=fit.iterations)
    except ValueError as err:
        raise LearningError(f'cannot learn {task_name!r} from {", ".join(bags)}: '
                            f'{_one_line(err)}') from None
    return LearnedTask(record=record, profile=profile, method=method, converged=fit.converged,
                       fit_message=fit.message, fit_seconds=fit.seconds,
                       total_seconds=time.perf_counter() - started)


def default_task_name(bags: list[str]) -> str:
    """A task name from the bag names: 'follow' for bags/follow, 'follow_avoid' for two."""
    stems = []
    for bag in bags:
        path = Path(bag.rstrip('/'))
        stems.append(path.stem if path.suffix == '.mcap' else path.name)
    name = re.sub(r'[^A-Za-z0-9_-]', '_', '_'.join(s for s in stems if s)).lstrip('-')
    return name[:64] or 'task'


def figure_title(name: str, bags: list[str]) -> str:
    """The figure's title: the task name, and the bags' names when they differ from it."""
    sources = [Path(b.rstrip('/')).name for b in bags]
    return name if sources == [name] else f'{name} ({", ".join(sources)})'


class Learner(Node):
    """Learns one task from `bags` at start, saves it and publishes it on /hri/task."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self._started = time.monotonic()
        try:
            self._declare_parameters()
        except ParameterException as err:
            raise LearningError(f'bad parameter: {_one_line(err)}') from None
        try:
            bags = [str(b) for b in self.get_parameter('bags').value if str(b)]
        except ParameterUninitializedException:
            bags = []
        p = {name: self.get_parameter(name).value for name in (
            'task_name', 'output_dir', 'n', 'tolerance', 'max_iterations',
            'stationary_speed', 'workspace_radius', 'once', 'method', 'l1', 'l2')}
        if not bags:
            raise LearningError('parameter bags is required: one or more bag folders or '
                                '.mcap files')
        shifts = self.get_parameter('shifts').value
        if shifts is None:
            shifts = [0.0] * len(bags)
        elif isinstance(shifts, (int, float)) and not isinstance(shifts, bool):
            shifts = [shifts]
        elif not isinstance(shifts, (list, tuple)) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in shifts):
            raise LearningError(f'parameter shifts must be an array of numbers (m), '
                                f'got {shifts!r}')
        shifts = [float(v) for v in shifts]
        if len(shifts) != len(bags):
            raise LearningError(f'parameter shifts has {len(shifts)} values for {len(bags)} '
                                'bags: give one shift (m) per bag')
        if not all(math.isfinite(v) for v in shifts):
            raise LearningError(f'parameter shifts must be finite, got {shifts}')
        if p['method'] not in METHODS:
            raise LearningError(f'parameter method must be one of {", ".join(METHODS)}, '
                                f'got {p["method"]!r}')
        name = p['task_name'] or default_task_name(bags)
        if not is_safe_task_name(name):
            raise LearningError(f'parameter task_name {name!r} is not a safe file name '
                                '(1-64 of A-Z a-z 0-9 _ -, not starting with -)')
        self.once = bool(p['once'])
        self.add_on_set_parameters_callback(self._reject_changes)
        self._publisher = self.create_publisher(TaskParameters, topics.TASK.name,
                                                topics.TASK.qos)

        learned = learn_from_bags(
            bags, shifts, name, n=int(p['n']), stationary_speed=p['stationary_speed'],
            workspace_radius=p['workspace_radius'], method=p['method'],
            tolerance=p['tolerance'], max_iterations=int(p['max_iterations']),
            l1=p['l1'], l2=p['l2'])
        output_dir = Path(p['output_dir'])
        try:
            output_dir.mkdir(parents=True, exist_ok=True)
            # Imported here: matplotlib costs 0.4 s at start-up, wasted on a bad parameter
            # or bag.
            from hri_demo_learning.figures import plot_task_fit
            figure = plot_task_fit(learned.profile.distance, learned.profile.energy,
                                   learned.record.shape, output_dir / f'{name}.png',
                                   title=figure_title(name, bags))
            self.task_file = save_task_file(learned.record, output_dir)
        except (OSError, ValueError) as err:
            raise LearningError(f'cannot write the task into {output_dir}: '
                                f'{_one_line(err)}') from None
        self.figure = figure
        self.record = learned.record
        self._publisher.publish(task_message(learned.record, self.get_clock().now().to_msg()))
        r = learned.record
        self.get_logger().info(
            f"learned task '{r.name}' from {len(bags)} bag(s): S={r.s:+d} d1={r.d1:.3f} m "
            f'd2={r.d2:.3f} m a1={r.a1:.4g} a2={r.a2:.4g} 1/m^2 C={r.cost:.3g} '
            f'iterations={r.iterations} ({learned.method}'
            f'{"" if learned.converged else ", not converged"}, fit {learned.fit_seconds:.3f} '
            f's, total {learned.total_seconds:.2f} s) -> {self.task_file}, {figure}')
        if not learned.converged:
            self.get_logger().warning(
                f'the {learned.method} fit did not converge ({_one_line(learned.fit_message)}); '
                'the task was saved but a1, a2 may be poor')

    def _declare_parameters(self) -> None:
        def declare(name, default, description, **ranges):
            self.declare_parameter(name, default, ParameterDescriptor(
                description=description, **ranges))

        self.declare_parameter('bags', Parameter.Type.STRING_ARRAY, ParameterDescriptor(
            description='bag folders or .mcap files of the demonstrations (required)'))
        declare('task_name', '', 'name of the learned task (default: the bag names joined)')
        declare('shifts', None, 'm, one per bag: bag i is moved outward by shifts[i] (eq. 4); '
                'unset: no shift', dynamic_typing=True)
        declare('output_dir', 'tasks/', 'folder of the task YAML file and its figure')
        declare('n', 3, 'exponent N of eq. 2 (>= 3)',
                integer_range=[IntegerRange(from_value=3, to_value=15, step=1)])
        declare('tolerance', DEFAULT_TOLERANCE, 'stopping tolerance of the fit',
                floating_point_range=[FloatingPointRange(from_value=1e-15, to_value=1e-2)])
        declare('max_iterations', DEFAULT_MAX_ITERATIONS, 'cap on the fit iterations',
                integer_range=[IntegerRange(from_value=1, to_value=100000, step=1)])
        declare('stationary_speed', DEFAULT_STATIONARY_SPEED,
                'm/s: a sample slower than this is at rest (eq. 3, 5)',
                floating_point_range=[FloatingPointRange(from_value=1e-5, to_value=1.0)])
        declare('workspace_radius', 2.0, 'm: d2 of a desired region open outward',
                floating_point_range=[FloatingPointRange(from_value=0.01, to_value=100.0)])
        declare('once', False, 'exit 0 after saving and publishing the task')
        declare('method', 'trf', "fit solver: 'trf' (bounded least squares) or 'gauss_newton' "
                "(the paper's eq. 9-11)")
        declare('l1', 0.35, 'm: link 1 length, for bags with joint states only',
                floating_point_range=[FloatingPointRange(from_value=0.01, to_value=10.0)])
        declare('l2', 0.30, 'm: link 2 length, for bags with joint states only',
                floating_point_range=[FloatingPointRange(from_value=0.01, to_value=10.0)])

    def _reject_changes(self, parameters) -> SetParametersResult:
        names = ', '.join(p.name for p in parameters)
        return SetParametersResult(
            successful=False,
            reason=f'the learner learns once at start; restart it to change {names}')

    def deliver(self) -> bool:
        """Make sure subscribers already running get the task before the node exits.

        Waits until DISCOVERY_WINDOW s after the node started for subscribers of /hri/task to
        match (discovery of running nodes takes a moment), then until every matched one has
        acknowledged the task (Fast DDS acknowledges on its heartbeat, up to about 3 s).
        Returns False if a matched subscriber did not acknowledge within ACK_TIMEOUT s.
        """
        while time.monotonic() < self._started + DISCOVERY_WINDOW:
            time.sleep(0.05)
        if self._publisher.get_subscription_count() == 0:
            return True
        return self._publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT))


def main(args=None):
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = Learner()
        if node.once:
            if not node.deliver():
                node.get_logger().warning('a subscriber of /hri/task did not acknowledge the '
                                          f'task within {ACK_TIMEOUT} s')
        else:
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except LearningError as err:
        rclpy.logging.get_logger(NODE_NAME).error(str(err))
        code = 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    raise SystemExit(main())
