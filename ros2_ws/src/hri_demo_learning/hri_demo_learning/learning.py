"""Learning one task from demonstration bags: the paper's eq. 3-11 chained, without ROS.

`learn_task` is the one entry point (the `learner` node and scripts call it). Its tunables
travel as one `LearningSettings` (the learner node builds it once from its parameters):

1. each bag is read (`bag_io.read_demonstration`): receive times t_i (s, shape (M,)),
   end-effector positions x_i (m, (M, 3), in 3-D) from /ee_position, else from /joint_states
   through the forward kinematics of the arm on the bag's /robot_description (its URDF, tool
   point at `tool_frame`), else (a bag recorded before bags carried their robot) the SCARA's
   with the link lengths l1, l2 (m), and the reference x_r (m, (3,)), the one in force when the
   person let go; x_r must not move during the demonstration;
2. its task energy P_d (eq. 3, `task_energy.demonstration_energy`, m^2) against the distance
   |x_i - x_r| (m); with `combine` false the bags are repetitions of one demonstration, all
   with one x_r, and share one target x_d, the mean of their rest positions (Sec. II-B: "if
   the same demonstration is repeated, the average position can be used");
3. the profiles, bag i moved outward by shifts[i] (m), concatenated into one (eq. 4; shifts
   belong to a combination, so repetitions take none);
4. the task type S and the desired region [d1, d2] (m) identified from it (eq. 5, 6);
5. the steepness a1, a2 (1/m^2) of the potential of eq. 1, 2 with exponent N = n fitted by
   the cost C of eq. 7, 8 (`method` 'trf', or the paper's Gauss-Newton iteration of eq. 9-11,
   'gauss_newton'), a1 capped so that P still pulls `reach` m (the reach of the bag's arm
   from its URDF, the largest over the bags; l1 + l2 for a bag without one) outside the
   region (`performance_learning.reach_steepness_limit`); a cost above `max_cost` means the
   model does not describe the demonstration: refused;
6. the task gain K (m^2/s) fitted to the demonstration's speeds (`task_gain.fit_task_gain`),
   and the task refused if its pull K |dP/dz| falls below 5 % of `max_task_speed` anywhere
   within `reach` of its region (`hri_core.potential.reach_shortfall`);
7. the task written as `<output_dir>/<task_name>.yaml` (hri_core.task_file) and its Fig. 3-style
   figure as `<task_name>.png` next to it.

`learn_from_bags` runs steps 1-6 alone (nothing written; the benchmark times it), and
`learn_from_demonstrations` steps 2-6 on arrays. Every input the task cannot be learned from
(a setting out of its range included), or output that cannot be written, raises
`LearningError` with a one-line reason, and then no task file is written.
"""

import math
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass, fields, replace
from numbers import Integral, Real
from pathlib import Path

import numpy as np

from hri_core.potential import reach_shortfall
from hri_core.task_file import TaskRecord, is_safe_task_name, save_task_file
from hri_demo_learning.bag_io import BagError, read_demonstration
from hri_demo_learning.identification import identify_task_region
from hri_demo_learning.performance_learning import (
    METHODS,
    FitOptions,
    FitResult,
    fit_task_parameters,
    reach_steepness_limit,
)
from hri_demo_learning.task_energy import (
    DEFAULT_REST_FRACTION,
    EnergyProfile,
    as_position,
    combine_energy_profiles,
    demonstration_energy,
)
from hri_demo_learning.task_gain import fit_task_gain

REFERENCE_TOLERANCE = 1e-3  # m: how far x_r may wander during one demonstration (or differ
# between repetitions of one)

DEFAULT_MAX_COST = 0.1
"""Largest fit cost C (eq. 8) a learned task may have. C = 1 - cos of the angle between P_d and
P over the samples (both normalised), so 0.1 is an angle of 26 deg. Good fits of the simulated
demonstrations give 0.001-0.01 and Table I's own a1, a2 score 0.05-0.17 on them; a
demonstration that is no function of the distance to x_r (out and back) gives 0.3 or more."""

DEFAULT_MAX_TASK_SPEED = 0.25
"""m/s: the controller's max_task_speed, the speed the reach criterion is measured against."""

SETTING_RANGES = {
    'n': (3, 15),
    'stationary_speed': (1e-5, 1.0),
    'rest_fraction': (0.0, 0.5),
    'workspace_radius': (0.01, 100.0),
    'tolerance': (1e-15, 1e-2),
    'max_iterations': (1, 100_000),
    'l1': (0.01, 10.0),
    'l2': (0.01, 10.0),
    'max_task_speed': (1e-3, 10.0),
    'max_cost': (1e-6, 2.0),
}
"""[low, high] of each numeric setting of LearningSettings (the learner node's parameter
ranges too: one table for both)."""

INTEGER_SETTINGS = ('n', 'max_iterations')


class LearningError(Exception):
    """The task cannot be learned; the message is a one-line reason."""


@dataclass(frozen=True)
class LearningSettings:
    """The learning pipeline's tunables, in one object (the learner node's parameters).

    n: exponent N of eq. 2; stationary_speed: m/s below which a sample is at rest whatever the
    pace (eq. 3, 5); workspace_radius: m, d2 of a region open outward; method: the fit's solver
    (performance_learning.METHODS); tolerance, max_iterations: the fit's stopping rule; l1, l2:
    m, the SCARA's link lengths for bags with joint states and no /robot_description, and the
    reach l1 + l2 of a bag without one; tool_frame: the tool link of a bag's URDF ('' = the
    robot's own, hri_core.robot_description.default_tool_frame); combine: True for
    eq. 4's combination, False for repetitions of one demonstration (averaged x_d);
    rest_fraction: of the demonstration's peak speed below which a sample is at rest;
    max_task_speed: m/s, the controller's cap, the reference of the reach check; max_cost:
    largest fit cost C (eq. 8). Ranges in SETTING_RANGES. Raises LearningError (one line) for
    a value out of its range or of the wrong type.
    """

    n: int
    stationary_speed: float
    workspace_radius: float
    method: str
    tolerance: float
    max_iterations: int
    l1: float
    l2: float
    combine: bool = True
    tool_frame: str = ''
    rest_fraction: float = DEFAULT_REST_FRACTION
    max_task_speed: float = DEFAULT_MAX_TASK_SPEED
    max_cost: float = DEFAULT_MAX_COST

    def __post_init__(self):
        for name, (low, high) in SETTING_RANGES.items():
            value = getattr(self, name)
            integer = name in INTEGER_SETTINGS
            kind = 'an integer' if integer else 'a number'
            if isinstance(value, bool) or not isinstance(value, Integral if integer else Real) \
                    or not low <= value <= high:
                raise LearningError(f'parameter {name} must be {kind} in [{low:g}, {high:g}], '
                                    f'got {value!r}')
        if self.method not in METHODS:
            raise LearningError(f'parameter method must be one of {", ".join(METHODS)}, '
                                f'got {self.method!r}')
        if not isinstance(self.combine, bool):
            raise LearningError(f'parameter combine must be true or false, '
                                f'got {self.combine!r}')
        if not isinstance(self.tool_frame, str):
            raise LearningError(f'parameter tool_frame must be a link name, '
                                f'got {self.tool_frame!r}')

    @classmethod
    def from_parameters(cls, values: Mapping) -> 'LearningSettings':
        """The settings named in `values` (e.g. the learner's parameters or its YAML), the
        other keys ignored; the defaults of this class for settings `values` lacks."""
        missing = [f.name for f in fields(cls) if f.name not in values
                   and f.default is MISSING]
        if missing:
            raise LearningError(f'settings {", ".join(missing)} are required')
        return cls(**{f.name: values[f.name] for f in fields(cls) if f.name in values})

    @property
    def reach(self) -> float:
        """m: how far outside its region a task must still pull, for a demonstration whose
        bag names no arm (the SCARA's l1 + l2)."""
        return self.l1 + self.l2

    @property
    def fit_options(self) -> FitOptions:
        """The fit's solver, tolerance and iteration cap (its start: the default)."""
        return FitOptions(method=self.method, tolerance=self.tolerance,
                          max_iterations=self.max_iterations)


@dataclass(frozen=True)
class Demonstration:
    """One demonstration as arrays: times (M,) s, positions (M, 3) m ((M, 2): the plane
    z = 0), reference x_r (3,) m ((2,): z = 0), source (a name for messages, e.g. the bag),
    reach: m, the reach of the arm that made it (None: LearningSettings.reach); references:
    (M, 3) m, the reference held at each sample (a bag's), which must stay at x_r from the
    first moving sample on (None: not checked)."""

    times: np.ndarray
    positions: np.ndarray
    reference: np.ndarray
    source: str
    reach: float | None = None
    references: np.ndarray | None = None


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
    targets: tuple = ()  # x_d (3,) m of each demonstration (all equal with combine false)
    fit: FitResult | None = None
    a1_max: float | None = None  # 1/m^2, the reach's cap on a1 (None: none)


def _one_line(text) -> str:
    return ' '.join(str(text).split())


def check_fixed_reference(references: np.ndarray, x_r: np.ndarray, bag) -> None:
    """Raise LearningError if x_r moved during a demonstration (eq. 3 needs one fixed x_r).

    references: (M, 3) m, the reference held at each sample from the first moving one on;
    x_r: (3,) m, the reference used.
    """
    wander = float(np.max(np.linalg.norm(references - x_r, axis=1))) if len(references) \
        else 0.0
    if wander > REFERENCE_TOLERANCE:
        raise LearningError(f'bag {bag}: the reference x_r moved by {wander:.3f} m during the '
                            f'demonstration; a demonstration needs one fixed x_r (eq. 3)')


def learn_from_demonstrations(demos: Sequence[Demonstration], shifts: list[float],
                              task_name: str, settings: LearningSettings) -> LearnedTask:
    """Learn one task from demonstrations given as arrays (steps 2-6 of the module docstring).

    One shift (m) per demonstration (all 0 with settings.combine false); the task must pull
    the demonstrations' largest reach (settings.reach for one without) m outside its region.
    Raises LearningError (one line).
    """
    started = time.perf_counter()
    sources = ', '.join(demo.source for demo in demos)
    combine, n = settings.combine, settings.n
    reach = max(settings.reach if demo.reach is None else demo.reach for demo in demos)
    max_cost, method = settings.max_cost, settings.method
    if not combine and any(shift != 0.0 for shift in shifts):
        raise LearningError('parameter shifts belongs to a combination (eq. 4): repetitions '
                            '(combine false) share one x_d and take no shift')
    energies = []
    for demo in demos:
        try:
            energy = demonstration_energy(demo.times, demo.positions, demo.reference,
                                          stationary_speed=settings.stationary_speed,
                                          rest_fraction=settings.rest_fraction)
        except ValueError as err:
            raise LearningError(f'bag {demo.source}: {_one_line(err)}') from None
        if demo.references is not None:
            check_fixed_reference(demo.references[demo.times >= energy.times[0]],
                                  as_position(demo.reference, 'reference'), demo.source)
        energies.append(energy)
    if not combine and len(demos) > 1:
        references = np.array([as_position(demo.reference, 'reference') for demo in demos])
        spread = float(np.max(np.linalg.norm(references - references[0], axis=1)))
        if spread > REFERENCE_TOLERANCE:
            raise LearningError(f'repeated demonstrations ({sources}) need one x_r, theirs '
                                f'differ by {spread:.3f} m; learn them as a combination '
                                '(combine true) instead')
        target = np.mean([energy.target for energy in energies], axis=0)
        energies = [demonstration_energy(demo.times, demo.positions, demo.reference,
                                         stationary_speed=settings.stationary_speed,
                                         rest_fraction=settings.rest_fraction, target=target)
                    for demo in demos]
    try:
        profile = combine_energy_profiles([energy.profile for energy in energies], shifts)
        region = identify_task_region(profile.distance, profile.energy, profile.moving,
                                      workspace_radius=settings.workspace_radius, n=n)
        a1_max = reach_steepness_limit(region.s, region.d1, region.d2, reach)
        fit = fit_task_parameters(profile.distance, profile.energy, region.s, region.d1,
                                  region.d2, n=n, options=settings.fit_options, a1_max=a1_max)
        if fit.cost > max_cost and not fit.converged:
            raise ValueError(f'the {method} fit did not converge in {fit.iterations} '
                             f'iterations: cost C = {fit.cost:.3g} > max_cost {max_cost:g} '
                             f'(S={region.s:+d}, d1={region.d1:.3f} m, d2={region.d2:.3f} m); '
                             'raise max_iterations or use method trf')
        if fit.cost > max_cost:
            raise ValueError(f'the potential of eq. 1, 2 does not describe the demonstration: '
                             f'best fit cost C = {fit.cost:.3g} > max_cost {max_cost:g} '
                             f'(S={region.s:+d}, d1={region.d1:.3f} m, d2={region.d2:.3f} m)')
        record = TaskRecord(name=task_name, s=region.s, a1=fit.a1, a2=fit.a2, d1=region.d1,
                            d2=region.d2, n=n, cost=fit.cost, iterations=fit.iterations)
        k = fit_task_gain(profile.distance, profile.speed, profile.moving, record.shape)
        shortfall = reach_shortfall(record.shape, k, settings.max_task_speed, reach)
        if shortfall is not None:
            raise ValueError(f'the task does not reach: {shortfall}')
        record = replace(record, k=k)
    except ValueError as err:
        raise LearningError(f'cannot learn {task_name!r} from {sources}: '
                            f'{_one_line(err)}') from None
    return LearnedTask(record=record, profile=profile, method=method, converged=fit.converged,
                       fit_message=fit.message, fit_seconds=fit.seconds,
                       total_seconds=time.perf_counter() - started,
                       targets=tuple(energy.target for energy in energies), fit=fit,
                       a1_max=a1_max)


def learn_from_bags(bags: list[str], shifts: list[float], task_name: str,
                    settings: LearningSettings) -> LearnedTask:
    """Learn one task from demonstration bags (eq. 3-11, K, reach) without writing it.

    One shift (m) per bag; the reach is that of the bags' arms (settings.l1 + settings.l2 for
    a bag that names none). Raises LearningError (one line).
    """
    started = time.perf_counter()
    demos = []
    for bag in bags:
        try:
            demo = read_demonstration(bag, l1=settings.l1, l2=settings.l2,
                                      tool_frame=settings.tool_frame)
        except BagError as err:
            raise LearningError(str(err)) from None
        # x_r: the reference in force when the person let go (checked fixed while moving).
        demos.append(Demonstration(demo.times, demo.positions, demo.references[-1],
                                   str(bag), demo.reach, demo.references))
    learned = learn_from_demonstrations(demos, shifts, task_name, settings)
    return replace(learned, total_seconds=time.perf_counter() - started)


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
               output_dir: str | Path, settings: LearningSettings) -> LearnedTask:
    """Learn one task from demonstration bags (eq. 3-11) and write its file and figure.

    bags: bag folders or .mcap files; shifts: m, one per bag (None: no shift); task_name: a
    safe file name ('' for the bag names joined by '_'); output_dir: folder of
    `<task_name>.yaml` and `<task_name>.png`, created if missing; settings: the fit and
    reading settings (LearningSettings). Returns the LearnedTask with the paths written.
    Raises LearningError (one line) for bad input, a bag it cannot learn from, or an output it
    cannot write.
    """
    bags = [str(bag) for bag in bags]
    if not bags:
        raise LearningError('parameter bags is required: one or more bag folders or .mcap '
                            'files')
    if not all(bags):
        raise LearningError(f'parameter bags holds an empty path: {bags}')
    shifts = _checked_shifts(shifts, len(bags))
    name = task_name or default_task_name(bags)
    if not is_safe_task_name(name):
        raise LearningError(f'parameter task_name {name!r} is not a safe file name '
                            '(1-64 of A-Z a-z 0-9 _ -, not starting with -)')
    learned = learn_from_bags(bags, shifts, name, settings)
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
