"""Learning one task from demonstration bags: the paper's eq. 3-11 chained, without ROS.

`learn_task` is the one entry point (the `learner` node and scripts call it):

1. each bag is read (`bag_io.read_demonstration`): receive times t_i (s, shape (M,)),
   end-effector positions x_i (m, (M, 2)) from /ee_position, else from /joint_states through
   the forward kinematics with the link lengths l1, l2 (m), and the reference x_r (m, (2,)),
   the one in force when the person let go; x_r must not move during the demonstration;
2. its task energy P_d (eq. 3, `task_energy.demonstration_energy`, m^2) against the distance
   |x_i - x_r| (m);
3. the profiles, bag i moved outward by shifts[i] (m), concatenated into one (eq. 4);
4. the task type S and the desired region [d1, d2] (m) identified from it (eq. 5, 6);
5. the steepness a1, a2 (1/m^2) of the potential of eq. 1, 2 with exponent N = n fitted by
   the cost C of eq. 7, 8 (`method` 'trf', or the paper's Gauss-Newton iteration of eq. 9-11,
   'gauss_newton');
6. the task written as `<output_dir>/<task_name>.yaml` (hri_core.task_file) and its Fig. 3-style
   figure as `<task_name>.png` next to it.

`learn_from_bags` runs steps 1-5 alone (nothing written; the benchmark times it). Every input
the task cannot be learned from, or output that cannot be written, raises `LearningError` with
a one-line reason, and then no task file is written.
"""

import math
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hri_core.task_file import TaskRecord, is_safe_task_name, save_task_file
from hri_demo_learning.bag_io import BagError, read_demonstration
from hri_demo_learning.identification import identify_task_region
from hri_demo_learning.performance_learning import METHODS, fit_task_parameters
from hri_demo_learning.task_energy import (
    EnergyProfile,
    combine_energy_profiles,
    demonstration_energy,
)

REFERENCE_TOLERANCE = 1e-3  # m: how far x_r may wander during one demonstration


class LearningError(Exception):
    """The task cannot be learned; the message is a one-line reason."""


@dataclass(frozen=True)
class LearnedTask:
    """A learned task and how it was obtained (the numbers of the learner's summary line).

    task_file and figure are the paths `learn_task` wrote (None from `learn_from_bags`).
    """

    record: TaskRecord
    profile: EnergyProfile  # of the (combined) demonstrations
    method: str
    converged: bool
    fit_message: str
    fit_seconds: float
    total_seconds: float
    task_file: Path | None = None
    figure: Path | None = None


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
    """Learn one task from demonstration bags (eq. 3-11) without writing it.

    One shift (m) per bag. Raises LearningError (one line).
    """
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


def _checked_shifts(shifts: Sequence[float] | None, bag_count: int) -> list[float]:
    """`shifts` as floats, one per bag (None: no shift). Raises LearningError."""
    if shifts is None:
        return [0.0] * bag_count
    if isinstance(shifts, str) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in shifts):
        raise LearningError(f'parameter shifts must be an array of numbers (m), '
                            f'got {shifts!r}')
    values = [float(v) for v in shifts]
    if len(values) != bag_count:
        raise LearningError(f'parameter shifts has {len(values)} values for {bag_count} '
                            'bags: give one shift (m) per bag')
    if not all(math.isfinite(v) for v in values):
        raise LearningError(f'parameter shifts must be finite, got {values}')
    return values


def learn_task(bags: Sequence[str], shifts: Sequence[float] | None, task_name: str,
               output_dir: str | Path, *, n: int, stationary_speed: float,
               workspace_radius: float, method: str, tolerance: float, max_iterations: int,
               l1: float, l2: float) -> LearnedTask:
    """Learn one task from demonstration bags (eq. 3-11) and write its file and figure.

    bags: bag folders or .mcap files; shifts: m, one per bag (None: no shift); task_name: a
    safe file name ('' for the bag names joined by '_'); output_dir: folder of
    `<task_name>.yaml` and `<task_name>.png`, created if missing; n: exponent N of eq. 2;
    stationary_speed: m/s below which a sample is at rest (eq. 3, 5); workspace_radius: m, d2
    of a region open outward; method: one of performance_learning.METHODS; tolerance,
    max_iterations: the fit's stopping rule; l1, l2: m, link lengths for bags with joint
    states only. Returns the LearnedTask with the paths written. Raises LearningError (one
    line) for bad input, a bag it cannot learn from, or an output it cannot write.
    """
    bags = [str(bag) for bag in bags]
    if not bags:
        raise LearningError('parameter bags is required: one or more bag folders or .mcap '
                            'files')
    if not all(bags):
        raise LearningError(f'parameter bags holds an empty path: {bags}')
    shifts = _checked_shifts(shifts, len(bags))
    if method not in METHODS:
        raise LearningError(f'parameter method must be one of {", ".join(METHODS)}, '
                            f'got {method!r}')
    name = task_name or default_task_name(bags)
    if not is_safe_task_name(name):
        raise LearningError(f'parameter task_name {name!r} is not a safe file name '
                            '(1-64 of A-Z a-z 0-9 _ -, not starting with -)')
    learned = learn_from_bags(
        bags, shifts, name, n=n, stationary_speed=stationary_speed,
        workspace_radius=workspace_radius, method=method, tolerance=tolerance,
        max_iterations=max_iterations, l1=l1, l2=l2)
    output_dir = Path(output_dir)
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
        # Imported here: matplotlib costs 0.4 s at start-up, wasted on a bad parameter or bag.
        from hri_demo_learning.figures import plot_task_fit
        figure = plot_task_fit(learned.profile.distance, learned.profile.energy,
                               learned.record.shape, output_dir / f'{name}.png',
                               title=figure_title(name, bags))
        task_file = save_task_file(learned.record, output_dir)
    except (OSError, ValueError) as err:
        raise LearningError(f'cannot write the task into {output_dir}: '
                            f'{_one_line(err)}') from None
    return replace(learned, task_file=task_file, figure=figure)
