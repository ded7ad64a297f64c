#!/usr/bin/env python3
"""Benchmark of the whole-body distances in-process (a measurement, not a test).

Times `hri_core.bodies.capsule_distances` for the Panda's capsules (robot_body, fitted from
example-robot-data's collision meshes) against the ten capsules of a standing person
(hri_core.human_body.standing_body), on seeded random configurations (q uniform within home
+- 0.6 rad) and hands (0.3-0.7 m in front of the base), each call timed alone with
time.perf_counter_ns after a warm-up: the distances (R, H) alone, with the closest
pair's points and normal (`Distances.pair`), and with every pair's points; beside it the
placing of the capsules
(`RobotBody.capsules(q)`)
and one point Jacobian; the law's whole barrier with its rate (arm_law.body_barrier: every
pair within clearance + influence pushed through its point's Jacobian, at q and at q + h qdot,
qdot uniform in +-0.5 rad/s; the posture push on), with the count of such pairs, through
pinocchio and numpy (the reference) and compiled on the arm's chain as the law runs it
(ArmController.whole_body_barrier); and the cost of one small numpy
ufunc call
(x * x on a (9, 10) array) as the host's yardstick: a loaded host slows every numpy call
alike, so compare the ratio. Reported: median, p99 in µs, and the load average.

Run it in the project's environment: `source scripts/env.sh; python bench/bench_bodies.py`.
`--json` prints the figures as one JSON object only.
"""

import argparse
import dataclasses
import json
import os
import time

import numpy as np

from hri_adaptive_controller.arm_law import (
    PANDA_GAINS,
    ArmController,
    ClearanceSettings,
    body_barrier,
)
from hri_core.bodies import (
    Capsules,
    capsule_distances,
    human_capsules,
    panda_package_dirs,
    robot_body,
)
from hri_core.human_body import BODY_POINTS, standing_body
from hri_core.robot_model import robot_model


def timed(call, arguments, warm_up: int = 500) -> np.ndarray:
    """Each call of `call(*args)` for args in `arguments`, timed alone (µs)."""
    for args in arguments[:warm_up]:
        call(*args)
    times = np.empty(len(arguments))
    for k, args in enumerate(arguments):
        start = time.perf_counter_ns()
        call(*args)
        times[k] = (time.perf_counter_ns() - start) * 1e-3
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--calls', type=int, default=20000)
    parser.add_argument('--seed', type=int, default=7)
    parser.add_argument('--json', action='store_true')
    options = parser.parse_args()
    rng = np.random.default_rng(options.seed)
    model = robot_model('panda')
    body = robot_body(model, panda_package_dirs())
    configurations = model.home + rng.uniform(-0.6, 0.6, (200, model.dof))
    robots = [body.capsules(q) for q in configurations]
    humans = []
    for _ in range(200):
        hand = np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.3, 0.3), rng.uniform(0.1, 0.6)])
        humans.append(human_capsules(BODY_POINTS, standing_body(
            [hand[0] + 0.45, hand[1] - 0.15], np.pi, 0.0, hand)))
    pairs = [(robots[k % 200], humans[(7 * k) % 200]) for k in range(options.calls)]
    figures = {'robot_capsules': len(robots[0]), 'human_capsules': len(humans[0])}
    # A fresh robot Capsules each call, as each cycle's q gives (its own terms are computed
    # in the call); the person's is one object per body message, reused.
    def cycle(robot, human):
        return capsule_distances(Capsules(robot.names, robot.a, robot.b, robot.radius), human)

    def cycle_with_pair(robot, human):
        distances = cycle(robot, human)
        return distances.pair(*distances.closest())

    def cycle_all_points(robot, human):
        distances = cycle(robot, human)
        return distances.robot_point, distances.human_point

    distances = timed(cycle, pairs)
    with_pair = timed(cycle_with_pair, pairs)
    all_points = timed(cycle_all_points, pairs)
    placing = timed(body.capsules, [(configurations[k % 200],) for k in range(5000)])
    jacobian = timed(body.point_jacobian, [(configurations[k % 200], 5, robots[k % 200].a[5])
                                           for k in range(5000)])
    velocities = rng.uniform(-0.5, 0.5, (200, model.dof))
    settings = ClearanceSettings()
    states = [(body, configurations[k % 200], velocities[k % 200], humans[(7 * k) % 200],
               settings, None, True) for k in range(2000)]
    barrier = timed(body_barrier, states, warm_up=200)
    law = ArmController(model, dataclasses.replace(PANDA_GAINS, body=settings), body=body)
    compiled = timed(law.whole_body_barrier, [(q, dq, human, None)
                                              for _, q, dq, human, *_ in states], warm_up=200)
    reach = settings.clearance + settings.influence
    figures['barrier_close_pairs_median'] = float(np.median([
        np.sum(capsule_distances(body.capsules(q), human).distance < reach)
        for _, q, _, human, *_ in states]))
    x = rng.uniform(size=(9, 10))
    yardstick = timed(np.multiply, [(x, x)] * 20000)
    for name, values in (('capsule_distances', distances),
                         ('distances_closest_pair', with_pair),
                         ('distances_all_points', all_points), ('robot_capsules_at_q', placing),
                         ('point_jacobian', jacobian), ('body_barrier', barrier),
                         ('body_barrier_compiled', compiled), ('numpy_multiply_9x10', yardstick)):
        figures[f'{name}_median_us'] = round(float(np.median(values)), 2)
        figures[f'{name}_p99_us'] = round(float(np.percentile(values, 99)), 2)
    figures['load_average_1min'] = os.getloadavg()[0]
    if options.json:
        print(json.dumps(figures))
        return
    print(f"Panda {figures['robot_capsules']} capsules x person "
          f"{figures['human_capsules']} capsules, load average {figures['load_average_1min']}")
    for name in ('capsule_distances', 'distances_closest_pair', 'distances_all_points',
                 'robot_capsules_at_q', 'point_jacobian', 'body_barrier',
                 'body_barrier_compiled', 'numpy_multiply_9x10'):
        print(f"  {name:22s} median {figures[f'{name}_median_us']:8.2f} us   "
              f"p99 {figures[f'{name}_p99_us']:8.2f} us")
    print(f"  body_barrier's close pairs: median {figures['barrier_close_pairs_median']:g}")


if __name__ == '__main__':
    main()
