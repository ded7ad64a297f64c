#!/usr/bin/env python3
"""Benchmark of learning from demonstrations (a measurement, not a test; no ROS process).

Three parts, all through the functions the `learner` node uses:

* fixtures: `learning.learn_from_bags` on bags/fixtures/follow, bags/fixtures/avoid and
  follow_safe (both, shifts [0.23, 0.0]) with the paper's Gauss-Newton ('gauss_newton') and
  the default 'trf', side by side in one run: `--repeats` rounds, each running both methods
  on each task (the order of the two alternates between rounds). Reports iterations, final
  cost C (eq. 8), a1, a2, convergence, and the fit time (`fit_task_parameters` alone) and the
  total time (read + energy + identification + fit) as min / median over the rounds.
* scaling: `fit_task_parameters` alone on 10k, 100k and 1M samples of a synthetic profile:
  the follow fixture's energy profile (distance, P_d, moving) resampled by linear interpolation
  over the sample index to N samples (a denser recording of the same demonstration), with S,
  d1, d2 identified once on the fixture's own profile. Both methods, min / median fit time.
* replay: a bag of `--replay-seconds` x 1000 sensor_msgs/JointState (1 kHz) plus
  /demo/reference (geometry_msgs/PointStamped) at 10 Hz, written once into a temporary folder
  with `bag_io.BagWriter`: a synthetic follow demonstration (end-effector at rest at
  (0.35, 0.30) m, a minimum-jerk push in the middle to 0.041 m from x_r = (0.45, 0.05) m,
  rest until the end) through the inverse kinematics of the 2-link arm (l1 0.35 m,
  l2 0.30 m). Then `bag_io.read_demonstration` alone (read time) and `learn_from_bags` with
  the default method (total: read + energy + identification + fit; the fit's own time is
  reported by the fit). The read is measured in a call of its own, before the learning.
  First of all, the `learner` node itself on that bag (`ros2 run hri_demo_learning learner
  ... once:=true`, its own ROS domain, nothing subscribed): wall time from process start to
  exit, figure included (`learner_process_s`).

* panda (`--panda-seconds`, default 1000): the same replay for the 7-joint Panda in 3-D: a bag
  of 1000 s x 1000 sensor_msgs/JointState (the Panda's 7 joints, through its inverse
  kinematics along a straight 3-D push to 0.041 m from x_r), /demo/reference at 10 Hz and the
  URDF on /robot_description, no /ee_position (`synthetic_demonstration`). Then the `learner`
  node on it (`ros2 run hri_demo_learning learner ... once:=true`, its own ROS domain):
  wall time from process start to exit (`learner_process_s`, the bar: <= 15 s), the same for
  the SCARA's replay bag (`scara_learner_process_s`, the bar: <= 10 s), and
  `bag_io.read_demonstration` alone on the Panda bag (`read_s`, forward kinematics through
  the URDF included).

Run it in the project's environment: `source scripts/env.sh; python bench/bench_learning.py`.
`--only-panda` runs the panda part alone.
`--json` prints the figures as one JSON object only.
"""

import argparse
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from hri_core.dynamics import forward_kinematics
from hri_core.robot_model import robot_model
from hri_demo_learning.bag_io import (
    JOINT_STATE,
    JOINT_STATE_TOPIC,
    POINT_STAMPED,
    REFERENCE_TOPIC,
    BagWriter,
    read_demonstration,
)
from hri_demo_learning.identification import identify_task_region
from hri_demo_learning.learning import LearningError, LearningSettings, learn_from_bags
from hri_demo_learning.performance_learning import (
    DEFAULT_MAX_ITERATIONS,
    DEFAULT_TOLERANCE,
    fit_task_parameters,
)
from hri_demo_learning.synthetic_demonstration import (
    JointDemonstration,
    joint_path,
    push_path,
    write_demonstration_bag,
)
from hri_demo_learning.task_energy import DEFAULT_STATIONARY_SPEED

REPO_ROOT = Path(__file__).resolve().parents[1]
FIXTURES = REPO_ROOT / 'bags' / 'fixtures'
METHODS = ('gauss_newton', 'trf')
L1, L2 = 0.35, 0.30  # m, the sim's arm
LEARNER_SETTINGS = LearningSettings(n=3, stationary_speed=DEFAULT_STATIONARY_SPEED,
                                    workspace_radius=2.0, method='trf',
                                    tolerance=DEFAULT_TOLERANCE,
                                    max_iterations=DEFAULT_MAX_ITERATIONS, l1=L1, l2=L2)
TASKS = {
    'follow': ([FIXTURES / 'follow'], [0.0]),
    'avoid': ([FIXTURES / 'avoid'], [0.0]),
    'follow_safe': ([FIXTURES / 'follow', FIXTURES / 'avoid'], [0.23, 0.0]),
}
# Synthetic follow demonstration of the replay bag.
REPLAY_START = np.array([0.35, 0.30])  # m, end-effector at scara_sim's initial_q
REPLAY_REFERENCE = np.array([0.45, 0.05])  # m, x_r (the demonstrator's default)
REPLAY_STOP_DISTANCE = 0.041  # m, where the push ends (Table I's d2 of follow)
REPLAY_PUSH_SECONDS = 4.0  # s, duration of the minimum-jerk push
REPLAY_RATE_HZ = 1000.0
REFERENCE_RATE_HZ = 10.0
EPOCH_NS = 1_700_000_000 * 10**9  # ns, bag time of the first sample
LEARNER_DOMAIN_ID = int(os.environ.get('BENCH_LEARNER_DOMAIN_ID', '94'))  # the node's domain


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3, help='rounds of each measurement')
    parser.add_argument('--sizes', type=int, nargs='+', default=[10_000, 100_000, 1_000_000],
                        help='sample counts of the scaling part')
    parser.add_argument('--replay-seconds', type=float, default=1000.0,
                        help='length of the replay bag at 1 kHz (s); 0 skips the replay part')
    parser.add_argument('--panda-seconds', type=float, default=1000.0,
                        help='length of the Panda replay bag at 1 kHz (s); 0 skips it')
    parser.add_argument('--only-panda', action='store_true',
                        help='run the panda part alone (the learner node on 1M-message bags)')
    parser.add_argument('--json', action='store_true', help='print JSON only')
    return parser.parse_args(argv)


def min_median(values: list[float], digits: int = 4) -> dict:
    return {'min': round(min(values), digits), 'median': round(statistics.median(values), digits)}


def log(text: str) -> None:
    print(f'[bench_learning] {text}', file=sys.stderr, flush=True)


# -- fixtures --------------------------------------------------------------------------------

def bench_fixtures(repeats: int) -> dict:
    """Both methods on each task, side by side, `repeats` rounds (after one warm-up call)."""
    runs = {task: {method: [] for method in METHODS} for task in TASKS}
    bags, shifts = TASKS['follow']  # warm-up (imports, typestore, caches): not measured
    learn_from_bags([str(b) for b in bags], shifts, 'follow', LEARNER_SETTINGS)
    for round_index in range(repeats):
        order = METHODS if round_index % 2 == 0 else METHODS[::-1]
        for task, (bags, shifts) in TASKS.items():
            for method in order:
                try:
                    learned = learn_from_bags([str(b) for b in bags], shifts, task,
                                              replace(LEARNER_SETTINGS, method=method))
                except LearningError as error:  # e.g. Gauss-Newton not converged in time
                    learned = str(error)
                runs[task][method].append(learned)
    result = {}
    for task, by_method in runs.items():
        result[task] = {}
        for method, learned in by_method.items():
            last = learned[-1]
            if isinstance(last, str):
                result[task][method] = {'refused': last}
                continue
            result[task][method] = {
                'iterations': last.record.iterations,
                'cost': float(f'{last.record.cost:.6g}'),
                'converged': last.converged,
                'a1': float(f'{last.record.a1:.6g}'),
                'a2': float(f'{last.record.a2:.6g}'),
                'd1': round(last.record.d1, 4),
                'd2': round(last.record.d2, 4),
                'samples': int(last.profile.distance.size),
                'fit_s': min_median([x.fit_seconds for x in learned if not isinstance(x, str)]),
                'total_s': min_median([x.total_seconds for x in learned
                                       if not isinstance(x, str)]),
            }
    return result


# -- scaling ---------------------------------------------------------------------------------

def resampled_profile(distance: np.ndarray, energy: np.ndarray, moving: np.ndarray,
                      samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The profile linearly interpolated over its sample index to `samples` samples."""
    index = np.arange(distance.size, dtype=float)
    wanted = np.linspace(0.0, distance.size - 1.0, samples)
    nearest = np.rint(wanted).astype(int)
    return np.interp(wanted, index, distance), np.interp(wanted, index, energy), moving[nearest]


def bench_scaling(sizes: list[int], repeats: int) -> dict:
    bags, shifts = TASKS['follow']
    learned = learn_from_bags([str(b) for b in bags], shifts, 'follow', LEARNER_SETTINGS)
    profile = learned.profile
    region = identify_task_region(profile.distance, profile.energy, profile.moving,
                                  workspace_radius=LEARNER_SETTINGS.workspace_radius,
                                  n=LEARNER_SETTINGS.n)
    result = {'profile': 'follow fixture, resampled', 'source_samples': int(profile.distance.size),
              's': region.s, 'd1': round(region.d1, 4), 'd2': round(region.d2, 4), 'sizes': {}}
    for size in sizes:
        distance, energy, _ = resampled_profile(profile.distance, profile.energy,
                                                profile.moving, size)
        fits = {method: [] for method in METHODS}
        for round_index in range(repeats):
            order = METHODS if round_index % 2 == 0 else METHODS[::-1]
            for method in order:
                options = replace(LEARNER_SETTINGS, method=method).fit_options
                fits[method].append(fit_task_parameters(
                    distance, energy, region.s, region.d1, region.d2, n=LEARNER_SETTINGS.n,
                    options=options))
        result['sizes'][str(size)] = {
            method: {'fit_s': min_median([f.seconds for f in runs]),
                     'iterations': runs[-1].iterations,
                     'cost': float(f'{runs[-1].cost:.6g}'),
                     'converged': runs[-1].converged}
            for method, runs in fits.items()}
        log(f'scaling: {size} samples done')
    return result


# -- replay ----------------------------------------------------------------------------------

def inverse_kinematics(points: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """Joint angles (N, 2) in rad reaching `points` (N, 2) in m, elbow angle q2 >= 0."""
    x, y = points[:, 0], points[:, 1]
    cos_q2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    if np.any(np.abs(cos_q2) > 1.0):
        raise ValueError('a point of the synthetic demonstration is out of reach')
    q2 = np.arccos(cos_q2)
    q1 = np.arctan2(y, x) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    return np.stack([q1, q2], axis=1)


def follow_demonstration(seconds: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) s and end-effector positions (N, 2) m: rest, a push in the middle, rest."""
    times = np.arange(int(round(seconds * rate_hz))) / rate_hz
    offset = REPLAY_START - REPLAY_REFERENCE
    goal = REPLAY_REFERENCE + offset / np.linalg.norm(offset) * REPLAY_STOP_DISTANCE
    begin = 0.5 * (seconds - REPLAY_PUSH_SECONDS)
    tau = np.clip((times - begin) / REPLAY_PUSH_SECONDS, 0.0, 1.0)
    blend = tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)  # minimum jerk
    return times, REPLAY_START + blend[:, None] * (goal - REPLAY_START)


def joint_state_template(typestore) -> tuple[bytes, dict[str, int]]:
    """CDR bytes of one JointState (names joint1, joint2) and the byte offsets of its fields.

    Every message of the replay bag has this layout; only the stamp and the six doubles differ,
    so the messages are made by writing those into copies of the template.
    """
    msg_types = typestore.types
    markers = {'sec': 0x5EC0_5EC0, 'nanosec': 0x0A05_EC00}
    doubles = {f'{field}{k}': 1.0e-3 * (7 + 11 * i + 3 * k) + 0.123456789
               for i, field in enumerate(('position', 'velocity', 'effort')) for k in range(2)}
    header = msg_types['std_msgs/msg/Header'](
        stamp=msg_types['builtin_interfaces/msg/Time'](sec=markers['sec'],
                                                       nanosec=markers['nanosec']),
        frame_id='')
    msg = msg_types[JOINT_STATE](
        header=header, name=['joint1', 'joint2'],
        position=np.array([doubles['position0'], doubles['position1']]),
        velocity=np.array([doubles['velocity0'], doubles['velocity1']]),
        effort=np.array([doubles['effort0'], doubles['effort1']]))
    data = bytes(typestore.serialize_cdr(msg, JOINT_STATE))
    offsets = {}
    for key, value in markers.items():
        offsets[key] = data.index(struct.pack('<I', value))
    for key, value in doubles.items():
        offsets[key] = data.index(struct.pack('<d', value))
    return data, offsets


def write_replay_bag(path: Path, seconds: float) -> dict:
    """Write the synthetic follow demonstration bag; return what was written and how fast."""
    started = time.perf_counter()
    times, points = follow_demonstration(seconds, REPLAY_RATE_HZ)
    q = inverse_kinematics(points, L1, L2)
    tip = forward_kinematics(q, L1, L2)
    if not np.allclose(tip, points, atol=1e-9):
        raise RuntimeError('inverse kinematics does not reproduce the demonstration')
    dq = np.gradient(q, times, axis=0)
    stamps_ns = EPOCH_NS + np.rint(times * 1e9).astype(np.int64)
    with BagWriter(path) as writer:
        template, offsets = joint_state_template(writer.typestore)
        rows = np.tile(np.frombuffer(template, dtype=np.uint8), (times.size, 1))
        rows[:, offsets['sec']:offsets['sec'] + 4] = (
            (stamps_ns // 10**9).astype('<u4').view(np.uint8).reshape(-1, 4))
        rows[:, offsets['nanosec']:offsets['nanosec'] + 4] = (
            (stamps_ns % 10**9).astype('<u4').view(np.uint8).reshape(-1, 4))
        for field, values in (('position', q), ('velocity', dq), ('effort', np.zeros_like(q))):
            for k in range(2):
                start = offsets[f'{field}{k}']
                rows[:, start:start + 8] = values[:, k].astype('<f8').view(np.uint8).reshape(-1, 8)
        check = writer.typestore.deserialize_cdr(rows[-1].tobytes(), JOINT_STATE)
        if not (np.allclose(check.position, q[-1]) and check.header.stamp.nanosec
                == int(stamps_ns[-1] % 10**9)):
            raise RuntimeError('the JointState template does not round-trip')
        msg_types = writer.typestore.types
        joints = writer.add_topic(JOINT_STATE_TOPIC, JOINT_STATE)
        reference = writer.add_topic(REFERENCE_TOPIC, POINT_STAMPED)
        every = int(round(REPLAY_RATE_HZ / REFERENCE_RATE_HZ))
        for index in range(times.size):
            stamp = int(stamps_ns[index])
            if index % every == 0:
                point = msg_types[POINT_STAMPED](
                    header=msg_types['std_msgs/msg/Header'](
                        stamp=msg_types['builtin_interfaces/msg/Time'](
                            sec=stamp // 10**9, nanosec=stamp % 10**9),
                        frame_id='base'),
                    point=msg_types['geometry_msgs/msg/Point'](
                        x=float(REPLAY_REFERENCE[0]), y=float(REPLAY_REFERENCE[1]), z=0.0))
                writer.write(reference, stamp,
                             writer.typestore.serialize_cdr(point, POINT_STAMPED))
            writer.write(joints, stamp, rows[index].data)
        counts = writer.counts
    size = sum(f.stat().st_size for f in path.iterdir())
    return {'joint_states': counts[JOINT_STATE_TOPIC], 'references': counts[REFERENCE_TOPIC],
            'bag_mb': round(size / 1e6, 1),
            'write_s': round(time.perf_counter() - started, 2)}


def bench_replay(seconds: float) -> dict:
    with tempfile.TemporaryDirectory(prefix='bench-learning-') as workdir:
        bag = Path(workdir) / 'replay_follow'
        log(f'replay: writing {int(seconds * REPLAY_RATE_HZ)} joint states into {bag}')
        result = {'seconds': seconds, 'rate_hz': REPLAY_RATE_HZ, 'method': 'trf',
                  **write_replay_bag(bag, seconds)}
        log(f'replay: written in {result["write_s"]} s; the learner node on it')
        result['learner_process_s'], _ = learner_node_seconds(bag, Path(workdir) / 'tasks')
        log(f'replay: learner node {result["learner_process_s"]} s; reading')
        started = time.perf_counter()
        demo = read_demonstration(bag, l1=L1, l2=L2)
        result['read_s'] = round(time.perf_counter() - started, 2)
        result['position_source'] = demo.position_source
        del demo
        log(f'replay: read in {result["read_s"]} s; learning')
        learned = learn_from_bags([str(bag)], [0.0], 'follow', LEARNER_SETTINGS)
    record = learned.record
    result.update({
        'learn_total_s': round(learned.total_seconds, 2),
        'fit_s': round(learned.fit_seconds, 3),
        'profile_samples': int(learned.profile.distance.size),
        'iterations': record.iterations, 'cost': float(f'{record.cost:.6g}'),
        'converged': learned.converged, 's': record.s, 'd1': round(record.d1, 4),
        'd2': round(record.d2, 4), 'a1': float(f'{record.a1:.6g}'),
        'a2': float(f'{record.a2:.6g}'),
    })
    return result


# -- panda: the learner node on a 1M-message bag of the 7-joint arm, in 3-D --------------------

PANDA_OFFSET = np.array([0.12, 0.15, -0.18])  # m, x_r from the tool at the Panda's home pose


def write_panda_bag(path: Path, seconds: float) -> dict:
    """A follow demonstration of the Panda: at rest at its home pose, a 4 s minimum-jerk push
    in the middle along a straight 3-D line to 0.041 m from x_r, at rest until the end; 1 kHz
    joint states (inverse kinematics of the push), x_r at 10 Hz, the URDF; no /ee_position."""
    started = time.perf_counter()
    panda = robot_model('panda')
    times = np.arange(int(round(seconds * REPLAY_RATE_HZ))) / REPLAY_RATE_HZ
    start = panda.tool_position(panda.home)
    reference = start + PANDA_OFFSET
    goal = reference - PANDA_OFFSET / np.linalg.norm(PANDA_OFFSET) * REPLAY_STOP_DISTANCE
    begin = 0.5 * (seconds - REPLAY_PUSH_SECONDS)
    points = push_path(times, start, goal, begin, REPLAY_PUSH_SECONDS)
    q = np.tile(panda.home, (times.size, 1))
    pushing = np.flatnonzero((times >= begin) & (times <= begin + REPLAY_PUSH_SECONDS))
    q[pushing] = joint_path(panda, points[pushing], panda.home)
    q[pushing[-1] + 1:] = q[pushing[-1]]
    counts = write_demonstration_bag(path, JointDemonstration(
        panda.joint_names, times, q, reference, urdf=panda.urdf,
        reference_period=int(round(REPLAY_RATE_HZ / REFERENCE_RATE_HZ)), start_ns=EPOCH_NS))
    size = sum(f.stat().st_size for f in path.iterdir())
    return {'joint_states': counts['/joint_states'], 'joints': panda.dof,
            'bag_mb': round(size / 1e6, 1), 'write_s': round(time.perf_counter() - started, 2)}


def learner_node_seconds(bag: Path, output_dir: Path) -> tuple[float, str]:
    """Wall time (s) of the learner node on `bag` with once:=true from process start to exit,
    and its summary line; its own ROS domain; ended by PID if it overruns 300 s."""
    command = ['ros2', 'run', 'hri_demo_learning', 'learner', '--ros-args',
               '-p', f'bags:=[{bag}]', '-p', 'once:=true', '-p', 'task_name:=follow',
               '-p', f'output_dir:={output_dir}']
    environment = {**os.environ, 'ROS_DOMAIN_ID': str(LEARNER_DOMAIN_ID)}
    started = time.perf_counter()
    process = subprocess.Popen(command, env=environment, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    try:
        output, _ = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    elapsed = time.perf_counter() - started
    if process.returncode != 0:
        raise RuntimeError(f'learner exited {process.returncode}: {output.strip()[-300:]}')
    summary = next((line for line in output.splitlines() if 'learned task' in line), '')
    return round(elapsed, 2), summary.split(': ', 1)[-1]


def bench_panda(seconds: float, scara_seconds: float) -> dict:
    with tempfile.TemporaryDirectory(prefix='bench-learning-panda-') as workdir:
        bag = Path(workdir) / 'panda_follow'
        log(f'panda: writing {int(seconds * REPLAY_RATE_HZ)} joint states into {bag}')
        result = {'seconds': seconds, **write_panda_bag(bag, seconds)}
        log(f'panda: written in {result["write_s"]} s; the learner node on it')
        result['learner_process_s'], result['summary'] = learner_node_seconds(
            bag, Path(workdir) / 'tasks')
        log(f'panda: learner node {result["learner_process_s"]} s; reading alone')
        started = time.perf_counter()
        demo = read_demonstration(bag)
        result['read_s'] = round(time.perf_counter() - started, 2)
        result['kinematics'] = demo.kinematics
        del demo
        if scara_seconds > 0:
            scara = Path(workdir) / 'scara_follow'
            log(f'panda: the SCARA bag of {int(scara_seconds * REPLAY_RATE_HZ)} joint states')
            write_replay_bag(scara, scara_seconds)
            result['scara_learner_process_s'], result['scara_summary'] = learner_node_seconds(
                scara, Path(workdir) / 'scara_tasks')
    return result


def run(args: argparse.Namespace) -> dict:
    if args.repeats < 1:
        raise SystemExit('bench_learning: --repeats must be >= 1')
    result = {'repeats': args.repeats}
    if args.only_panda:
        result['panda'] = bench_panda(args.panda_seconds, args.replay_seconds)
        return result
    log('fixtures')
    result['fixtures'] = bench_fixtures(args.repeats)
    log('scaling')
    result['scaling'] = bench_scaling(args.sizes, args.repeats)
    if args.replay_seconds > 0:
        result['replay'] = bench_replay(args.replay_seconds)
    if args.panda_seconds > 0:
        result['panda'] = bench_panda(args.panda_seconds, args.replay_seconds)
    return result


def print_panda(r: dict) -> None:
    print(f'panda: {r["joint_states"]} joint states of {r["joints"]} joints ({r["bag_mb"]} MB, '
          f'URDF, no /ee_position; written in {r["write_s"]} s): learner node '
          f'{r["learner_process_s"]} s start to exit (bar 15 s), read {r["read_s"]} s '
          f'({r["kinematics"]})')
    print(f'  {r["summary"]}')
    if 'scara_learner_process_s' in r:
        print(f'  SCARA replay bag: learner node {r["scara_learner_process_s"]} s start to exit '
              '(bar 10 s)')


def print_table(result: dict) -> None:
    if 'fixtures' not in result:
        print_panda(result['panda'])
        return
    print(f'fixtures (learn_from_bags, {result["repeats"]} rounds; time min/median)')
    print(f'  {"task":12s} {"method":13s} {"iter":>5s} {"cost":>10s} {"conv":>5s} '
          f'{"fit s":>17s} {"total s":>15s}')
    for task, by_method in result['fixtures'].items():
        for method, r in by_method.items():
            if 'refused' in r:
                print(f'  {task:12s} {method:13s} refused: {r["refused"]}')
                continue
            print(f'  {task:12s} {method:13s} {r["iterations"]:5d} {r["cost"]:10.4g} '
                  f'{"yes" if r["converged"] else "no":>5s} '
                  f'{r["fit_s"]["min"]:8.4f}/{r["fit_s"]["median"]:.4f} '
                  f'{r["total_s"]["min"]:7.3f}/{r["total_s"]["median"]:.3f}')
    scaling = result['scaling']
    print(f'fit time vs samples ({scaling["profile"]}; min/median s)')
    for size, by_method in scaling['sizes'].items():
        cells = ', '.join(f'{m} {r["fit_s"]["min"]:.4f}/{r["fit_s"]["median"]:.4f} '
                          f'({r["iterations"]} it)' for m, r in by_method.items())
        print(f'  {int(size):>9d}: {cells}')
    if 'replay' in result:
        r = result['replay']
        print(f'replay of {r["joint_states"]} joint states ({r["bag_mb"]} MB, written in '
              f'{r["write_s"]} s): learner node {r["learner_process_s"]} s start to exit, '
              f'read {r["read_s"]} s, learn_from_bags {r["learn_total_s"]} s '
              f'(fit {r["fit_s"]} s, {r["iterations"]} it), d2 {r["d2"]} m')
    if 'panda' in result:
        print_panda(result['panda'])


def main(argv=None) -> int:
    args = parse_arguments(argv)
    result = run(args)
    if args.json:
        print(json.dumps(result))
    else:
        print_table(result)
    return 0


if __name__ == '__main__':
    sys.exit(main())
