#!/usr/bin/env python3
"""Benchmark of one control step in-process (a measurement, not a test).

Times `AdaptiveController.step_lean` (the controller's per-cycle path, plain floats) and the
numpy reference `AdaptiveController.step` on the same seeded random states, for each task
installed with hri_adaptive_controller (tasks/*.yaml): q uniform in the arm's usual range,
dq normal (0.5 rad/s), the hand from on the tip to 0.3 m away, a uniform in [0, 1]; the
controller's own call (with_potential=False: V's task term is added only with each
ControllerState), monitor=True on every 10th call as at 100 Hz ControllerState. Each call is
timed alone with time.perf_counter_ns; reported per task: median, p99 and max in µs for both,
and the reference's median over the lean step's.

`--robot panda` times, beside the SCARA's, the Panda's step (arm_law.ArmController.step with
the controller's default gains, `--calls` per task) as the controller calls it: q uniform
within home +- 0.6 rad (inside the joint limits), dq normal (0.5 rad/s), the hand from on the
tool to 0.3 m away in 3-D with a velocity normal (0.1 m/s), a uniform in [0, 1]; on every
10th call also V without its task term (ArmController.lyapunov), as the controller does for
its 100 Hz ControllerState. The compiled step (arm_kernels, the controller's) and numpy's
(`compiled=False`, the reference) are timed interleaved, 100 calls each in turn; reported:
both, and numpy's median over the compiled one's.

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

from hri_adaptive_controller.adaptive_law import AdaptiveController
from hri_core.dynamics import ScaraParameters, dynamic_parameters
from hri_core.potential import TaskShape
from hri_core.task_file import load_task_file

STATE_PERIOD = 10  # calls between two with monitor=True (ControllerState at 100 Hz)


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--calls', type=int, default=20000,
                        help='lean steps timed per task (the reference: a tenth)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the random states')
    parser.add_argument('--robot', choices=('scara', 'panda'), default='scara',
                        help="panda: the Panda's n-joint step too (beside the SCARA's)")
    parser.add_argument('--json', action='store_true', help='print JSON only')
    return parser.parse_args(argv)


def installed_tasks() -> dict[str, tuple[TaskShape, float]]:
    """{name: (shape, K)} of the tasks installed with hri_adaptive_controller."""
    folder = Path(get_package_share_directory('hri_adaptive_controller')) / 'tasks'
    tasks = {}
    for path in sorted(folder.glob('*.yaml')):
        record = load_task_file(path)
        tasks[path.stem] = (TaskShape(record.s, record.a1, record.a2, record.d1, record.d2,
                                      record.n), record.k)
    return tasks


def random_states(count: int, rng: np.random.Generator, params: ScaraParameters) -> list:
    """`count` argument tuples (q, dq, x_d, xdot_d, xddot_d, a, da) as float tuples."""
    states = []
    for _ in range(count):
        q = (float(rng.uniform(-1.0, 1.0)), float(rng.uniform(0.7, 2.2)))
        tip = (params.l1 * math.cos(q[0]) + params.l2 * math.cos(q[0] + q[1]),
               params.l1 * math.sin(q[0]) + params.l2 * math.sin(q[0] + q[1]))
        offset = rng.uniform(0.0, 0.3) * rng.normal(size=2) / math.sqrt(2.0)
        states.append((q, tuple(rng.normal(0.0, 0.5, 2).tolist()),
                       (tip[0] - float(offset[0]), tip[1] - float(offset[1])),
                       tuple(rng.normal(0.0, 0.1, 2).tolist()), (0.0, 0.0),
                       float(rng.uniform(0.0, 1.0)), 0.0))
    return states


def spread_us(times_ns: list[int]) -> dict:
    values = np.array(times_ns) / 1e3
    return {'median_us': round(float(np.median(values)), 2),
            'p99_us': round(float(np.percentile(values, 99)), 2),
            'max_us': round(float(values.max()), 2)}


def time_task(shape: TaskShape, k: float, states: list, params: ScaraParameters) -> dict:
    theta0 = dynamic_parameters(params)
    lean = AdaptiveController(theta_hat0=theta0, l1=params.l1, l2=params.l2)
    reference = AdaptiveController(theta_hat0=theta0, l1=params.l1, l2=params.l2)
    lean_ns, reference_ns = [], []
    clock = time.perf_counter_ns
    for i, state in enumerate(states):
        monitor = i % STATE_PERIOD == 0
        start = clock()
        lean.step_lean(*state, shape, 1e-3, monitor=monitor, k=k, with_potential=False)
        lean_ns.append(clock() - start)
    for i, state in enumerate(states[:max(1, len(states) // 10)]):
        state = tuple(np.array(v) for v in state[:5]) + state[5:]
        start = clock()
        reference.step(*state, shape, 1e-3, monitor=i % STATE_PERIOD == 0, k=k)
        reference_ns.append(clock() - start)
    result = {'lean': spread_us(lean_ns), 'reference': spread_us(reference_ns)}
    result['reference_over_lean'] = round(result['reference']['median_us']
                                          / result['lean']['median_us'], 2)
    return result


def panda_states(count: int, rng: np.random.Generator, model) -> list:
    """`count` (q, dq, HandState, a) of the Panda (see the module docstring)."""
    from hri_adaptive_controller.arm_law import HandState

    low = np.maximum(model.home - 0.6, model.limits.lower + 0.1)
    high = np.minimum(model.home + 0.6, model.limits.upper - 0.1)
    states = []
    for _ in range(count):
        q = rng.uniform(low, high)
        offset = rng.uniform(0.0, 0.3) * rng.normal(size=3) / math.sqrt(3.0)
        hand = HandState(model.tool_position(q) - offset, rng.normal(0.0, 0.1, 3), np.zeros(3))
        states.append((q, rng.normal(0.0, 0.5, model.dof), hand, float(rng.uniform(0.0, 1.0))))
    return states


def time_panda_task(shape: TaskShape, k: float, states: list, model) -> dict:
    """The Panda's step for one task, timed per call (spread_us), with its V every 10th: the
    compiled step (arm_kernels, the controller's) and numpy's (`compiled=False`), the two
    interleaved in blocks of 100 calls so that both see the same machine."""
    from hri_adaptive_controller.arm_law import ActiveTask, ArmController
    from hri_adaptive_controller.controller_node import arm_gains_from
    from hri_core.node_common import load_defaults

    values = {'arm_ks': None, 'arm_adaptation_gain': None,
              **load_defaults('hri_adaptive_controller', 'controller')}
    laws = {flag: ArmController(model, arm_gains_from(values, model), compiled=flag)
            for flag in (True, False)}
    step_ns = {True: [], False: []}
    clock = time.perf_counter_ns
    for block in range(0, len(states), 100):
        for flag, arm in laws.items():
            for i, (q, dq, hand, weight) in enumerate(states[block:block + 100], block):
                start = clock()
                output = arm.step(q, dq, hand, ActiveTask(shape, weight, 0.0, k), 1e-3)
                if i % STATE_PERIOD == 0 and not output.fault:
                    arm.lyapunov(output, q, None)
                step_ns[flag].append(clock() - start)
    step, numpy_step = spread_us(step_ns[True]), spread_us(step_ns[False])
    return {'step': step, 'numpy_step': numpy_step,
            'numpy_over_compiled': round(numpy_step['median_us'] / step['median_us'], 2)}


def run(args: argparse.Namespace) -> dict:
    params = ScaraParameters()
    rng = np.random.default_rng(args.seed)
    states = random_states(args.calls, rng, params)
    tasks = {name: time_task(shape, k, states, params)
             for name, (shape, k) in installed_tasks().items()}
    result = {'calls': args.calls, 'tasks': tasks}
    if args.robot == 'panda':
        from hri_core.robot_model import robot_model

        model = robot_model('panda')
        arm_states = panda_states(args.calls, np.random.default_rng(args.seed), model)
        result['panda'] = {name: time_panda_task(shape, k, arm_states, model)
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
    for name, r in result['tasks'].items():
        lean, ref = r['lean'], r['reference']
        print(f"{name}: step_lean median {lean['median_us']} / p99 {lean['p99_us']} / max "
              f"{lean['max_us']} us; reference step median {ref['median_us']} us "
              f"({r['reference_over_lean']} x)")
    for name, r in result.get('panda', {}).items():
        step = r['step']
        print(f"{name}: panda step median {step['median_us']} / p99 {step['p99_us']} / max "
              f"{step['max_us']} us; numpy's median {r['numpy_step']['median_us']} us "
              f"({r['numpy_over_compiled']} x)")
    return 0


if __name__ == '__main__':
    sys.exit(main())
