"""What the whole-body clearance buys, measured in a second engine: recorded people beside the
Panda in MuJoCo, their contacts judged against ISO/TS 15066 (no ROS import).

`run_take(take, task, clearance)` replays the first `seconds` of a shipped take
(data/human-motion/*.csv) beside the Panda, placed as hand_sim's auto_place places it
(recorded_motion.choose_placement with the Panda's reach and BODY_CLEARANCE['panda']), in the
pure closed loop (hri_adaptive_controller.closed_loop: the one law at 1 kHz, the hand through
the node's glitch filter at 100 Hz, the person's capsules from the recording) with MuJoCo as
the plant (scara_sim.mujoco_simulation.MujocoArmSimulator: the URDF's masses perturbed by
+-10 % (seed 0), MuJoCo's own joint damping and armature, the person's capsules as mocap
bodies that push the arm). `clearance` False: the law's whole-body barrier off (force 0);
True: on (arm_law.ClearanceSettings' defaults). Each step's arm-person contacts, summed per
body part, make the contact trace that hri_core.contact_limits.judge_contacts judges against
Table A.2, region by region.

The controller's model is the nominal Panda and knows neither MuJoCo's damping and armature
nor the perturbation; the person is kinematic (a recording), so a contact pushes the arm, never
the person.
"""

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hri_adaptive_controller.arm_law import ArmController, ClearanceSettings
from hri_adaptive_controller.closed_loop import (
    LoopConditions,
    recorded_body,
    recorded_target,
    simulate,
)
from hri_core.bodies import capsule_distances, panda_package_dirs, robot_body
from hri_core.contact_limits import RegionJudgement, judge_contacts
from hri_core.human_body import BODY_POINTS, read_recorded_body
from hri_core.potential import TaskShape
from hri_core.recorded_motion import (
    BODY_CLEARANCE,
    ReachAnnulus,
    choose_placement,
    read_vicon_csv,
)
from hri_core.robot_model import robot_model
from scara_sim.arm_simulation import true_arm
from scara_sim.mujoco_simulation import MujocoArmSimulator

PANDA_REACH = ReachAnnulus(0.30, 0.75)
"""m: the reach the take's hand path is placed in (the Panda demo's)."""
PERTURBATION, SEED = 0.1, 0
"""The simulated arm's mass and inertia error (+-10 %, arm_sim's default) and its seed."""
SAMPLE_EVERY = 10
"""steps (10 ms) between the whole-body distance samples."""


@dataclass(frozen=True)
class TakeRun:
    """One take, task and clearance setting in MuJoCo.

    time (N,) s of each step; force (N,) N: the sum of every arm-person contact's normal
    force at each step; part_peaks: body part -> its peak force (N, summed over a step's
    contacts on it) for each part touched; contact_steps: steps with any contact;
    judgements: Table A.2 region -> RegionJudgement; least_distance (m): the smallest
    robot-person capsule distance (every 10 ms; < 0 overlapping); trunk_touched: a contact on
    the head or the torso; tool_hand_median (m): the tool's median distance from the hand
    after the first second; peak_effort (N m): the largest |torque| applied."""

    take: str
    task: str
    clearance: bool
    time: np.ndarray
    force: np.ndarray
    part_peaks: dict
    contact_steps: int
    judgements: dict
    least_distance: float
    trunk_touched: bool
    tool_hand_median: float
    peak_effort: float

    @property
    def passed(self) -> bool:
        """Every touched region within Table A.2 and no contact on the head or the torso."""
        return not self.trunk_touched and all(j.passed for j in self.judgements.values())


def contact_trace(steps: list, dt: float) -> tuple[np.ndarray, list, np.ndarray]:
    """(time (M,) s, part (M,), force (M,) N) for judge_contacts from the plant's contacts,
    one tuple of Contacts per step (step k ends at (k + 1) dt): one sample per step and body
    part, its contacts' forces summed."""
    times, parts, forces = [], [], []
    for k, contacts in enumerate(steps):
        summed: dict[str, float] = {}
        for contact in contacts:
            summed[contact.body_part] = summed.get(contact.body_part, 0.0) + contact.normal_force
        for part, force in summed.items():
            times.append((k + 1) * dt)
            parts.append(part)
            forces.append(force)
    return np.array(times), parts, np.array(forces)


def run_take(take: Path, task: str, shape: TaskShape, clearance: bool,
             seconds: float = 10.0) -> TakeRun:
    """The first `seconds` (at most 10: the plant keeps 10,000 steps of contacts) of `take`
    with `task` (its TaskShape) and the whole-body clearance on or off (module docstring)."""
    if not 0.0 < seconds <= 10.0:
        raise ValueError(f'seconds must be in (0, 10], got {seconds}')
    model = robot_model('panda')
    folders = panda_package_dirs()
    body = robot_body(model, folders)
    recorded = read_recorded_body(take)
    placement = choose_placement(read_vicon_csv(take).positions, PANDA_REACH,
                                 body=recorded.trunk(), clearance=BODY_CLEARANCE['panda'])
    motion = read_vicon_csv(take, placement=placement)
    person = read_recorded_body(take, placement=placement)
    keep = motion.times <= seconds
    times, hand, points = motion.times[keep], motion.positions[keep], person.points[keep]
    arm = true_arm(model, PERTURBATION, SEED)
    plant = MujocoArmSimulator(arm, model.home, np.zeros(model.dof), package_dirs=folders)
    gains = dataclasses.replace(ArmController(model).gains, body=ClearanceSettings(
        force=ClearanceSettings().force if clearance else 0.0))
    result = simulate({task: shape}, [(0.0, task)], recorded_target(times, hand),
                      seconds, LoopConditions(arm=arm, model=model, gains=gains, monitor=False,
                                              target_period=0.01, body=recorded_body(
                                                  times, BODY_POINTS, points),
                                              robot_body=body, plant=plant))
    steps = plant.take_contacts()
    trace = contact_trace(steps, plant.dt)
    force = np.array([sum(c.normal_force for c in contacts) for contacts in steps])
    part_peaks: dict[str, float] = {}
    for part, value in zip(trace[1], trace[2].tolist(), strict=True):
        part_peaks[part] = max(part_peaks.get(part, 0.0), value)
    index = np.clip(np.searchsorted(times, result.time, side='right') - 1, 0, len(times) - 1)
    least = min(
        float(capsule_distances(body.capsules(result.q[i], checked=False),
                                recorded_body(times, BODY_POINTS, points)(result.time[i]),
                                body.planar).distance.min())
        for i in range(0, len(result.time), SAMPLE_EVERY))
    seen = hand[index]
    tool_hand = np.linalg.norm(result.position - seen, axis=1)
    later = (result.time >= 1.0) & np.all(np.isfinite(seen), axis=1)
    trunk = {'head', 'torso'} & set(part_peaks)
    return TakeRun(take.stem, task, clearance, (np.arange(len(steps)) + 1) * plant.dt, force,
                   part_peaks, int(np.count_nonzero(force > 0.0)),
                   judge_contacts(*trace) if len(trace[0]) else {}, least, bool(trunk),
                   float(np.median(tool_hand[later])) if later.any() else float('nan'),
                   float(np.max(np.abs(result.tau))))


def region_text(judgement: RegionJudgement) -> str:
    """One region's judgement in a line: region, peak force and part, verdict and why."""
    return (f'{judgement.region}: peak {judgement.peak_force:.0f} N ({judgement.peak_part}), '
            f'{judgement.verdict}: {judgement.reason}')
