#!/usr/bin/env python3
"""What the whole-body clearance does on the shipped recorded people (a measurement, not a test).

Each take of data/human-motion/ is placed by recorded_motion.choose_placement with the arm's
reach and its `body_clearance` (BODY_CLEARANCE: the person's hip, torso and head that far from
the base), the person at the take's first frame at least the clearance from the arm at its home
pose (bodies.clear_of_arm: a person does not stand inside the arm), cropped to its first
`--crop` s, and replayed in the pure closed loop (closed_loop.simulate, 1 kHz, the hand at 100
Hz through the glitch filter) with each of Table I's tasks, once with the barrier off (force 0)
and once on (arm_law.ClearanceSettings' defaults), the person's body on it as it was recorded.
Per run:

- trunk: the share of samples (every 10 ms) in which some robot capsule is closer than
  clearance - 3 cm to the head, torso or hip capsules, and the least such distance (m);
- tool-hand: follow's median distance (m) over the samples where the hand is seen, in reach
  and slower than the task speed (run_metrics.considered_samples), and over those of them where
  the hand is also clear of the trunk (a tool-sized ball at the hand at least `clearance`
  from it); and `median_reachable`, over the considered samples every 100 ms in which a pose
  that keeps the law's clearances puts the tool at the hand (`clear_pose_at_hand`) once the
  arm has had the time to come from its start at max_task_speed (the distance at the start
  over that speed: the approach from home is not following); avoid's and follow_safe's share
  of the considered samples closer than d1 - 3 cm;
- the peak |effort| (N m) and the seconds the run took.

`--turns N` places each take N more times, turned about the base's vertical axis by seeded
random angles (`--seed`): the person keeps every distance from the base (so the body
clearance), stands elsewhere round the arm, and a turn that puts them inside the arm at the
start (the same rule) is drawn again. The barrier is then on only.

Run it in the project's environment: `source scripts/env.sh; python bench/bench_body_takes.py
[--robots scara,panda] [--tasks follow,avoid,follow_safe] [--crop 10] [--turns 0 --seed 0]`.
`--json` prints one JSON object.
"""

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from hri_adaptive_controller.arm_law import ArmController, ClearanceSettings
from hri_adaptive_controller.closed_loop import (
    LoopConditions,
    recorded_body,
    recorded_target,
    simulate,
)
from hri_adaptive_controller.joint_limits import clearance_inverse_kinematics
from hri_adaptive_controller.run_metrics import TakeCriteria, considered_samples
from hri_core.bodies import (
    Capsules,
    capsule_distances,
    clear_of_arm,
    human_capsules,
    panda_package_dirs,
    robot_body,
)
from hri_core.human_body import BODY_POINTS, TRUNK, read_recorded_body
from hri_core.potential import TaskShape
from hri_core.recorded_motion import (
    BODY_CLEARANCE,
    Placement,
    ReachAnnulus,
    choose_placement,
    read_vicon_csv,
)
from hri_core.robot_model import robot_model
from hri_core.task_file import load_task_file

ROOT = Path(__file__).resolve().parents[1]
TAKES = sorted((ROOT / 'data' / 'human-motion').glob('*.csv'))
TASKS = ROOT / 'ros2_ws' / 'src' / 'hri_adaptive_controller' / 'tasks'
# The reach annulus choose_placement places the hand path in: the SCARA's (hand_sim's
# default) and the one scripts/demo.py gives the Panda.
REACH = {'scara': ReachAnnulus(0.222, 0.65), 'panda': ReachAnnulus(0.30, 0.75)}
MARGIN = 0.03  # m: "closer than clearance - 3 cm", and avoid's d1 - 3 cm
SAMPLE_EVERY = 10  # steps (10 ms) between the trunk checks
TURN_DRAWS = 50  # turns drawn per placement before giving up on one the start rule accepts
REACHABLE_EVERY = 100  # steps (100 ms) between the reachability checks
AT_HAND = 0.03  # m: a pose whose tool is this near the hand reaches it
CLEAR_SLACK = 0.002  # m: and whose pairs lie at most this inside the law's wanted distance
IK_SEEDS = 4  # random seeds of the reachability check's solve, besides the arm's and home
IK_ITERATIONS = 60  # iterations from each seed


def task(name: str) -> TaskShape:
    record = load_task_file(TASKS / f'{name}.yaml')
    return record.shape


def trunk_capsules(frame: np.ndarray) -> Capsules | None:
    """The head, torso and hip capsules of one frame (K, 3), or None if none is seen."""
    kept = [BODY_POINTS.index(name) for name in TRUNK
            if np.all(np.isfinite(frame[BODY_POINTS.index(name)]))]
    if not kept:
        return None
    return human_capsules([BODY_POINTS[k] for k in kept], frame[kept])


def clear_pose_at_hand(law: ArmController, shape, hand: np.ndarray, frame: np.ndarray,
                       q: np.ndarray, rng) -> bool:
    """Whether some pose puts the tool within AT_HAND of `hand` (k,) m while every pair
    keeps the law's clearance (less CLEAR_SLACK) as the law counts its pairs in the task
    `shape` (ArmController.person_keep_off, with no margin beyond the clearance) against the
    person's seen points `frame` (K, 3) m: clearance_inverse_kinematics from the arm's joints
    q (n,), its home and IK_SEEDS random poses (rng) in the joint box."""
    seen = np.all(np.isfinite(frame), axis=1)
    names = [name for name, ok in zip(BODY_POINTS, seen, strict=True) if ok]
    keep_off = (law.person_keep_off(shape, human_capsules(names, frame[seen]), margin=0.0,
                                    hand=hand)
                if names else lambda pose: None)  # no point of the person seen: no pair
    model = law.model
    lower, upper = law.joint_limits
    still = np.zeros(model.dof)
    seeds = np.vstack([q, model.home, rng.uniform(lower, upper, size=(IK_SEEDS, model.dof))])
    for seed in seeds:
        pose = clearance_inverse_kinematics(model, hand, seed[None], lower, upper,
                                            IK_ITERATIONS, keep_off)
        pairs = keep_off(pose)
        if pairs is not None and float(pairs[1].max()) > CLEAR_SLACK:
            continue
        if np.linalg.norm(model.task_kinematics(pose, still)[0] - hand) <= AT_HAND:
            return True
    return False


def placements(robot: str, body, path: Path, turns: int, rng) -> list[tuple[float, Placement]]:
    """(turn in rad, placement) of a take: choose_placement's (turn 0) and `turns` more,
    each turned by a random angle the start rule accepts (module docstring)."""
    recorded = read_recorded_body(path)
    start = clear_of_arm(body, human_capsules(*recorded.first_frame()),
                         ClearanceSettings().clearance)
    chosen = choose_placement(read_vicon_csv(path).positions, REACH[robot],
                              body=recorded.trunk(), clearance=BODY_CLEARANCE[robot],
                              accept=start)
    found = [(0.0, chosen)]
    for _ in range(turns):
        for _ in range(TURN_DRAWS):
            turn = float(rng.uniform(-math.pi, math.pi))
            placement = chosen.turned(turn)
            if start(placement):
                found.append((turn, placement))
                break
    return found


def run(robot: str, body, path: Path, names, crop: float, placement: Placement,
        forces: tuple[float, ...]) -> list[dict]:
    """The rows of one take placed by `placement`: each of the tasks `names` with each
    barrier force (N) of `forces` (module docstring)."""
    model = robot_model(robot)
    clearance = ClearanceSettings().clearance
    tool_radius = float(body.radius[body.names.index(body.tool)])
    motion = read_vicon_csv(path, placement=placement)
    person = read_recorded_body(path, placement=placement)
    keep = motion.times <= crop
    times, hand, points = motion.times[keep], motion.positions[keep], person.points[keep]
    trunks = [trunk_capsules(frame) for frame in points]
    clear_hand = np.zeros(len(times), dtype=bool)
    for k, trunk in enumerate(trunks):
        if trunk is not None and np.all(np.isfinite(hand[k])):
            ball = Capsules(('tool',), hand[k][None], hand[k][None], np.array([tool_radius]))
            clear_hand[k] = capsule_distances(ball, trunk, body.planar).distance.min() \
                >= clearance
    rows = []
    for name in names:
        shape = task(name)
        for force in forces:
            gains = dataclasses.replace(ArmController(model).gains,
                                        body=ClearanceSettings(force=force))
            started = time.perf_counter()
            result = simulate({name: shape}, [(0.0, name)],
                              recorded_target(times, hand[:, :model.task_axes]),
                              float(times[-1]),
                              LoopConditions(arm=model, gains=gains, monitor=False,
                                             target_period=0.01,
                                             body=recorded_body(times, BODY_POINTS, points),
                                             robot_body=body))
            seconds = time.perf_counter() - started
            index = np.clip(np.searchsorted(times, result.time, side='right') - 1, 0,
                            len(times) - 1)
            trunk_distance = np.array([
                capsule_distances(body.capsules(result.q[i], checked=False),
                                  trunks[index[i]], body.planar).distance.min()
                for i in range(0, len(result.time), SAMPLE_EVERY)
                if trunks[index[i]] is not None])
            seen = hand[index, :model.task_axes]
            criteria = TakeCriteria(d1=shape.d1, effort_limit=float(model.limits.effort.min()),
                                    task_speed=gains.max_task_speed, reach=REACH[robot])
            considered = considered_samples(result.time, seen, criteria)
            distance = np.linalg.norm(result.position - seen, axis=1)
            clear = considered & clear_hand[index]
            row = {'robot': robot, 'take': path.stem, 'task': name, 'barrier': force > 0.0,
                   'trunk_close': float(np.mean(trunk_distance < clearance - MARGIN)),
                   'trunk_min': float(trunk_distance.min()),
                   'peak_effort': float(np.max(np.abs(result.tau))),
                   'seconds': round(seconds, 1)}
            if shape.d1 == 0.0:
                row['median'] = float(np.median(distance[considered])) if considered.any() \
                    else None
                row['median_clear'] = float(np.median(distance[clear])) if clear.any() \
                    else None
                if force > 0.0:
                    row.update(reachable_median(model, gains, body, shape, result, seen,
                                                considered, points[index], distance))
            else:
                row['too_close'] = float(np.mean(distance[considered] < shape.d1 - MARGIN)) \
                    if considered.any() else None
            rows.append(row)
    return rows


def reachable_median(model, gains, body, shape, result, seen, considered, frames,
                     distance) -> dict:
    """median_reachable (module docstring; None without such a sample) and the share of the
    checked samples it is taken over."""
    seen_at = np.flatnonzero(np.isfinite(distance))
    if seen_at.size == 0:
        return {'median_reachable': None, 'reachable_share': 0.0}
    law = ArmController(model, gains, body=body)
    start = float(distance[seen_at[0]])
    settled = result.time >= start / gains.max_task_speed
    rng = np.random.default_rng(0)
    checked = [i for i in range(0, len(result.time), REACHABLE_EVERY)
               if considered[i] and settled[i]]
    kept = [i for i in checked
            if clear_pose_at_hand(law, shape, seen[i], frames[i], result.q[i], rng)]
    return {'median_reachable': float(np.median(distance[kept])) if kept else None,
            'reachable_share': len(kept) / len(checked) if checked else 0.0}


def text(row: dict) -> str:
    reachable = row.get('median_reachable')
    where = ('' if 'reachable_share' not in row else
             f", where a clear pose reaches {'-' if reachable is None else f'{reachable:.3f} m'}"
             f" ({row['reachable_share']:.0%} of the settled samples)")
    figures = (f"median {row['median']:.3f} m, clear of the trunk "
               f"{row['median_clear']:.3f} m{where}"
               if 'median' in row and row['median'] is not None
               and row['median_clear'] is not None else
               f"median {row.get('median')}" if 'median' in row else
               f"closer than d1 - 3 cm {row['too_close']}")
    return (f"{row['robot']:5s} {row['take'][:24]:24s} {row.get('turn', 0):+4d} deg "
            f"{row['task']:11s} "
            f"{'on ' if row['barrier'] else 'off'} trunk < c - 3 cm {row['trunk_close']:.3f} "
            f"(least {row['trunk_min']:+.3f} m); {figures}; peak {row['peak_effort']:.1f} N m; "
            f"{row['seconds']} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--robots', default='scara,panda')
    parser.add_argument('--tasks', default='follow,avoid,follow_safe')
    parser.add_argument('--crop', type=float, default=10.0, help='s of each take')
    parser.add_argument('--turns', type=int, default=0,
                        help='more placements per take, turned about the base (barrier on)')
    parser.add_argument('--seed', type=int, default=0, help="seed of the turns' angles")
    parser.add_argument('--json', action='store_true')
    options = parser.parse_args()
    rows = []
    rng = np.random.default_rng(options.seed)
    for robot in options.robots.split(','):
        # example-robot-data's meshes (every arm's there) resolve in the Panda's folder
        body = robot_body(robot_model(robot), panda_package_dirs())
        for path in TAKES:
            for turn, placement in placements(robot, body, path, options.turns, rng):
                forces = ((0.0, ClearanceSettings().force) if options.turns == 0
                          else (ClearanceSettings().force,))
                for row in run(robot, body, path, options.tasks.split(','), options.crop,
                               placement, forces):
                    row['turn'] = round(math.degrees(turn))
                    rows.append(row)
                    if not options.json:
                        print(text(row), flush=True)
    if options.json:
        print(json.dumps(rows))


if __name__ == '__main__':
    main()
