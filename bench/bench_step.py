#!/usr/bin/env python3
"""Benchmark of one control step in-process (a measurement, not a test).

Times the law's step (arm_law.ArmController.step with the robot's own gains, as the
controller calls it) on seeded random states, for each task installed with
hri_adaptive_controller (tasks/*.yaml): q uniform within the arm's usual range (home +- 0.6
rad, inside the joint limits), dq normal (0.5 rad/s), the hand from on the tool to 0.3 m
away on the task axes with a velocity normal (0.1 m/s), a uniform in [0, 1]; on every 10th
call also V without its task term (ArmController.lyapunov), as the controller does for its
100 Hz ControllerState. The compiled step (arm_kernels, the controller's) and numpy's
(`compiled=False`, the reference) are timed interleaved, 100 calls each in turn, each call
alone with time.perf_counter_ns; reported per robot and task: median, p99 and max in µs for
both, and numpy's median over the compiled one's.

`--robot scara` (the default) times the SCARA; `--robot panda` the Panda beside the SCARA.
Run it in the project's environment: `source scripts/env.sh; python bench/bench_step.py`.
`--json` prints the figures as one JSON object only.
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from ament_index_python.packages import get_package_share_directory

from hri_adaptive_controller.arm_law import ActiveTask, ArmController, HandState
from hri_core.potential import TaskShape
from hri_core.robot_model import robot_model
from hri_core.task_file import load_task_file

STATE_PERIOD = 10  # calls between two with monitor=True (ControllerState at 100 Hz)


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--calls', type=int, default=20000,
                        help='steps timed per task, robot and path (compiled, numpy)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the random states')
    parser.add_argument('--robot', choices=('scara', 'panda'), default='scara',
                        help="panda: the Panda's step too (beside the SCARA's)")
    parser.add_argument('--json', action='store_true', help='print JSON only')
    return parser.parse_args(argv)


def installed_tasks() -> dict[str, tuple[TaskShape, float]]:
    """{name: (shape, K)} of the tasks installed with hri_adaptive_controller."""
    folder = Path(get_package_share_directory('hri_adaptive_controller')) / 'tasks'
    tasks = {}
    for path in sorted(folder.glob('*.yaml')):
        record = load_task_file(path)
        tasks[path.stem] = (record.shape, record.k)
    return tasks


def spread_us(times_ns: list[int]) -> dict:
    values = np.array(times_ns) / 1e3
    return {'median_us': round(float(np.median(values)), 2),
            'p99_us': round(float(np.percentile(values, 99)), 2),
            'max_us': round(float(values.max()), 2)}


def random_states(count: int, rng: np.random.Generator, model) -> list:
    """`count` (q, dq, HandState, a) of `model` (see the module docstring)."""
    low = np.maximum(model.home - 0.6, model.limits.lower + 0.1)
    high = np.minimum(model.home + 0.6, model.limits.upper - 0.1)
    axes = model.task_axes
    states = []
    for _ in range(count):
        q = rng.uniform(low, high)
        dq = rng.normal(0.0, 0.5, model.dof)
        offset = rng.uniform(0.0, 0.3) * rng.normal(size=axes) / math.sqrt(axes)
        hand = HandState(model.task_kinematics(q, dq)[0] - offset, rng.normal(0.0, 0.1, axes),
                         np.zeros(axes))
        states.append((q, dq, hand, float(rng.uniform(0.0, 1.0))))
    return states


def time_task(shape: TaskShape, k: float, states: list, model) -> dict:
    """The step for one task, timed per call (spread_us), with its V every 10th: the
    compiled step (arm_kernels, the controller's) and numpy's (`compiled=False`), the two
    interleaved in blocks of 100 calls so that both see the same machine."""
    laws = {flag: ArmController(model, compiled=flag) for flag in (True, False)}
    step_ns = {True: [], False: []}
    clock = time.perf_counter_ns
    for block in range(0, len(states), 100):
        for flag, law in laws.items():
            for i, (q, dq, hand, weight) in enumerate(states[block:block + 100], block):
                start = clock()
                output = law.step(q, dq, hand, ActiveTask(shape, weight, 0.0, k), 1e-3)
                if i % STATE_PERIOD == 0 and not output.fault:
                    law.lyapunov(output, q, None)
                step_ns[flag].append(clock() - start)
    step, numpy_step = spread_us(step_ns[True]), spread_us(step_ns[False])
    return {'step': step, 'numpy_step': numpy_step,
            'numpy_over_compiled': round(numpy_step['median_us'] / step['median_us'], 2)}


def run(args: argparse.Namespace) -> dict:
    robots = ('scara', 'panda') if args.robot == 'panda' else ('scara',)
    result = {'calls': args.calls, 'robots': {}}
    for robot in robots:
        model = robot_model(robot)
        states = random_states(args.calls, np.random.default_rng(args.seed), model)
        result['robots'][robot] = {name: time_task(shape, k, states, model)
                                   for name, (shape, k) in installed_tasks().items()}
    return result


def main(argv=None) -> int:
    args = parse_arguments(argv)
    if args.calls < 10:
        print('bench_step: --calls must be at least 10', file=sys.stderr)
        return 2
    result = run(args)
    if args.json:
        print(json.dumps(result))
        return 0
    for robot, tasks in result['robots'].items():
        for name, r in tasks.items():
            step = r['step']
            print(f"{robot} {name}: step median {step['median_us']} / p99 {step['p99_us']} / "
                  f"max {step['max_us']} us; numpy's median {r['numpy_step']['median_us']} "
                  f"us ({r['numpy_over_compiled']} x)")
    return 0


if __name__ == '__main__':
    sys.exit(main())
