"""The same controller on two engines: Table I's tasks (or learned ones) on the Panda in the
pure closed loop, integrated once by the project's own engine and once by MuJoCo (no ROS
import).

`run_scenario(scenario, shapes, engine)` runs one of SCENARIOS, each a still hand placed
from the tool's home position, with the one law at 1 kHz (hri_adaptive_controller.closed_loop;
the controller's model the nominal Panda, theta_hat from it):

* engine `pinocchio`: the arm integrated by closed_loop's RK4 on pinocchio's dynamics of
  the true arm (the URDF's masses and inertias perturbed by +-10 %, seed 0, as arm_sim's),
  with inelastic stops;
* engine `mujoco`: scara_sim.mujoco_simulation.MujocoArmSimulator of the same true arm,
  with MuJoCo's own joint damping and armature (1 N m s/rad, 0.1 kg m^2) and soft limits,
  none of which the controller knows.

Each segment of the scenario (one task from its switch to the next) gives its time to
region: the first time from which the tool stays within the task's desired region (eq. 1;
Table I's follow [0, d2], avoid [d1, d2 = 2 m], follow_safe [d1, d2]) to the segment's end
(None: not in it at the end).
"""

import math
from dataclasses import dataclass

import numpy as np

from hri_adaptive_controller.closed_loop import LoopConditions, simulate, still_target
from hri_bringup.clearance_in_mujoco import PERTURBATION, SEED
from hri_core.potential import TaskShape
from hri_core.robot_model import robot_model
from scara_sim.arm_simulation import true_arm

ENGINES = ('pinocchio', 'mujoco')
SAMPLE_EVERY = 10
"""steps (10 ms) between the distances read for the time to region."""


@dataclass(frozen=True)
class Scenario:
    """A still hand at the tool's home position + `hand_offset` (3,) m and the task
    switches `events` ((time s, task name), the first at 0), run for `seconds` s."""

    hand_offset: tuple[float, float, float]
    events: tuple[tuple[float, str], ...]
    seconds: float


# The follow hand is test_panda_loop's: 0.3 m from the tool, in all three axes.
_FAR = tuple((0.3 * np.array([0.1, 0.25, -0.13]) / np.linalg.norm([0.1, 0.25, -0.13]))
             .tolist())
SCENARIOS = {
    'follow': Scenario(_FAR, ((0.0, 'follow'),), 6.0),
    'avoid': Scenario((0.0, 0.0, 0.05), ((0.0, 'avoid'),), 6.0),  # 5 cm above the tool
    'follow_safe': Scenario(_FAR, ((0.0, 'follow_safe'),), 6.0),
    'sequence': Scenario(_FAR, ((0.0, 'follow'), (5.0, 'avoid'), (9.0, 'follow_safe')), 14.0),
}


@dataclass(frozen=True)
class EngineRun:
    """One scenario on one engine.

    segments: (task, time to region s or None) per segment, in order; final_distance (m):
    the tool's distance from the hand at the end; theta_change: |theta_hat_end - theta_hat_0|
    over |theta_hat_0|; largest_step (N m): the largest change of the applied torque of
    a joint between two 1 ms steps; peak_effort_share: the largest |torque| over its
    joint's effort limit."""

    scenario: str
    engine: str
    segments: tuple[tuple[str, float | None], ...]
    final_distance: float
    theta_change: float
    largest_step: float
    peak_effort_share: float


def in_region(shape: TaskShape, distance: np.ndarray) -> np.ndarray:
    """The task's desired region (eq. 1) as a mask of `distance` (m): d1 <= d <= d2 for
    S = +1, d <= d1 or d >= d2 for S = -1."""
    inside = (distance >= shape.d1) & (distance <= shape.d2)
    return inside if shape.s == 1 else ~inside | (distance == shape.d1) | (
        distance == shape.d2)


def time_to_region(time: np.ndarray, inside: np.ndarray) -> float | None:
    """The first time (s, from time[0]) from which every sample of `inside` is True; None if
    the last sample is outside."""
    if not inside.size or not inside[-1]:
        return None
    outside = np.flatnonzero(~inside)
    first = 0 if outside.size == 0 else int(outside[-1]) + 1
    return float(time[first] - time[0])


def run_scenario(scenario: str, shapes: dict[str, TaskShape], engine: str,
                 task_gains: dict[str, float] | None = None) -> EngineRun:
    """SCENARIOS[scenario] with the task shapes `shapes` (name -> TaskShape) and their gains
    K (`task_gains`, m^2/s per name; a task not in it: the law's default) on `engine` (one
    of ENGINES). ValueError for an unknown scenario, engine or task."""
    if scenario not in SCENARIOS:
        raise ValueError(f'unknown scenario {scenario!r}; known: {sorted(SCENARIOS)}')
    if engine not in ENGINES:
        raise ValueError(f'unknown engine {engine!r}; known: {list(ENGINES)}')
    setup = SCENARIOS[scenario]
    missing = {task for _, task in setup.events} - set(shapes)
    if missing:
        raise ValueError(f'no shape for task(s) {sorted(missing)}')
    model = robot_model('panda')
    arm = true_arm(model, PERTURBATION, SEED)
    hand = model.tool_position(model.home) + np.array(setup.hand_offset)
    plant = None
    if engine == 'mujoco':
        from hri_core.bodies import panda_package_dirs
        from scara_sim.mujoco_simulation import MujocoArmSimulator

        plant = MujocoArmSimulator(arm, model.home, np.zeros(model.dof),
                                   package_dirs=panda_package_dirs())
    tasks = {task: shapes[task] for _, task in setup.events}
    result = simulate(tasks, list(setup.events), still_target(hand), setup.seconds,
                      LoopConditions(arm=arm, model=model, monitor=False, plant=plant,
                                     task_gains=task_gains))
    time = result.time[::SAMPLE_EVERY]
    distance = np.linalg.norm(result.position[::SAMPLE_EVERY] - hand, axis=1)
    ends = [start for start, _ in setup.events[1:]] + [math.inf]
    segments = []
    for (start, task), end in zip(setup.events, ends, strict=True):
        span = (time >= start) & (time < end)
        segments.append((task, time_to_region(time[span],
                                              in_region(tasks[task], distance[span]))))
    theta0 = result.theta_hat[0]
    return EngineRun(scenario, engine, tuple(segments), float(distance[-1]),
                     float(np.linalg.norm(result.theta_hat[-1] - theta0)
                           / np.linalg.norm(theta0)),
                     float(np.abs(np.diff(result.tau, axis=0)).max()),
                     float((np.abs(result.tau) / model.limits.effort).max()))
