"""The main job: paper Section IV in simulation, every node started with `ros2 run`.

Stages (each prints what it does; a failing stage is named and the exit code is non-zero):
  1. record a following and an avoidance demonstration (scara_sim + demonstrator + recorder);
  2. learn `follow`, `avoid` and their combination `follow_safe` (shifts [0.23, 0]) from the bags;
  3. run the three behaviours closed-loop with a scripted hand, each recorded to a bag;
  4. run follow -> avoid -> follow_safe, the events detected by the event_detector from a hand
     that reaches in, rests and withdraws (no timer sends one), recorded;
  5. a recorded person (a Vicon take, data/human-motion) as the hand, from follow, the tasks
     switched by the event_detector;
  6. write OUT/report.md, OUT/figures/*.png and OUT/metrics.json.
Then (not with --quick) a short run of the Panda in 3-D into OUT/panda/ (PandaDemo, below:
demonstrations, learning, the event sequence); --robot panda runs every stage on the Panda
alone, and after the recorded person two recorded people beside it in MuJoCo with the
whole-body clearance off and on (OUT/panda/mujoco.md, in-process: about 20 s); --robot scara
the SCARA alone.
Run through scripts/demo.sh, which sets the project up and sources its environment first.
Every process is started on this run's own ROS domain (HRI_DEMO_DOMAIN_ID, not ROS_DOMAIN_ID:
see --help), discovery on loopback, and ended by PID when its stage ends or fails.
"""

import argparse
import json
import os
import shutil
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path

import matplotlib

matplotlib.use('Agg')  # before pyplot is imported: figures go to files, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hri_adaptive_controller.run_metrics import (  # noqa: E402
    TakeCriteria,
    largest_effort_step,
    longest_high_effort_hold,
    run_metrics,
    take_metrics,
)
from hri_bringup.clearance_in_mujoco import TakeRun, region_text, run_take  # noqa: E402
from hri_bringup.engines_compared import (  # noqa: E402
    ENGINES,
    SCENARIOS,
    EngineRun,
    run_scenario,
)
from hri_bringup.processes import (  # noqa: E402
    LIVE_LOOP,
    READY_LINES,
    NodeProcess,
    NodesNotReadyError,
    not_logged,
    paper_tasks_dir,
    start_live_loop,
    start_node,
    stop_all,
    wait_until_logged,
)
from hri_core.bodies import (  # noqa: E402
    capsule_distances,
    human_capsules,
    panda_package_dirs,
    robot_body,
)
from hri_core.node_common import load_defaults  # noqa: E402
from hri_core.potential import TaskShape  # noqa: E402
from hri_core.recorded_motion import BODY_CLEARANCE, ReachAnnulus  # noqa: E402
from hri_core.robot_model import robot_model  # noqa: E402
from hri_core.separation import ProtectiveSeparation, separation_verdict  # noqa: E402
from hri_core.task_file import TaskRecord, load_task_file  # noqa: E402
from hri_demo_learning.bag_io import read_bag  # noqa: E402
from hri_demo_learning.figures import plot_task_fit  # noqa: E402
from hri_demo_learning.learning import (  # noqa: E402
    LearningError,
    LearningSettings,
    learn_from_bags,
)
from hri_demo_learning.performance_learning import fit_task_parameters, task_cost  # noqa: E402
from scara_sim.profiles import HandProfile, waypoint_schedule  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[1]
PAPER_TABLE_I = {
    'follow': {'s': 1, 'd1': 0.0, 'd2': 0.041, 'a1': 1.291, 'a2': 13.66, 'iterations': 2468},
    'avoid': {'s': 1, 'd1': 0.183, 'd2': 2.0, 'a1': 0.056, 'a2': 25.46, 'iterations': 2146},
    'follow_safe': {'s': 1, 'd1': 0.183, 'd2': 0.271, 'a1': 1.576, 'a2': 30.78,
                    'iterations': 1628},
}
# Where the demonstrations happen: the sim starts with the end-effector at (0.35, 0.30) m.
# The simulated person stops at distances of its own, not Table I's (0.041, 0.183 m): the
# learned d1, d2 must come from the demonstration.
DEMONSTRATIONS = {
    'follow': {'mode': 'follow', 'reference': [0.45, 0.05], 'stop_distance': 0.055},
    'avoid': {'mode': 'avoid', 'reference': [0.355, 0.295], 'safe_distance': 0.165},
}
GAUSS_NEWTON_MAX_UPDATES = 5000  # the paper's iteration counts are about 2000
# --quick: the comparison's Gauss-Newton stops sooner (its 5000 updates took 6 s of CPU for
# follow_safe, a third of the learning stage).
QUICK_GAUSS_NEWTON_MAX_UPDATES = 1000
LEARNING = {
    'follow': (['follow'], [0.0]),
    'avoid': (['avoid'], [0.0]),
    'follow_safe': (['follow', 'avoid'], [0.23, 0.0]),
}
# Scripted hands of the three behaviours (scara_sim hand_sim parameters), as in Figs. 4-6.
BEHAVIOURS = {
    # The hand waits 0.2 m away, then moves off: the robot comes to it and follows.
    'follow': {'profile': 'waypoints', 'start_delay': 4.0, 'speed': 0.08,
               'waypoints': [0.45, 0.15, 0.30, 0.45, 0.30, 0.45]},
    # As Fig. 5: the hand reaches in fast (0.5 m/s) from 0.30 m to 0.08 m of the end-effector,
    # well inside d1, and stays 3 s: the potential pushes the robot out past d1; then the hand
    # leaves and the robot returns to where it was (its rest position).
    'avoid': {'profile': 'waypoints', 'start_delay': 1.0, 'speed': 0.25,
              'waypoints': [0.35, 0.0, 0.35, 0.22, 0.35, -0.05],
              'segment_speeds': [0.5, 0.25], 'pauses': [3.0, 0.0]},
    # As Fig. 6: the hand starts 7 cm from the end-effector, inside d1 (the robot backs off
    # to the safe distance), then walks off 0.3 m and the robot follows it (eq. 14 feeds the
    # hand's velocity forward, the potential holds the distance in the band).
    'follow_safe': {'profile': 'waypoints', 'start_delay': 3.0, 'speed': 0.1,
                    'waypoints': [0.40, 0.25, 0.55, 0.0, 0.60, -0.05]},
}
# --quick: the same paths at QUICK_SPEED_UP times the speed, the hand still for at most
# QUICK_START_DELAY s first (the robot reaches a still hand in about 0.5 s, once the task has
# faded in over 1 s), and each run ends QUICK_SETTLE s after its hand stops (1 s to settle, then
# the 2 s window whose median distance the metrics judge).
QUICK_SPEED_UP = 2.0
QUICK_START_DELAY = 1.0  # s
QUICK_SETTLE = 3.0  # s
QUICK_PAUSE = 2.0  # s, longest pause of a hand at a waypoint
# --quick demonstrations: the human pushes sooner and holds still 1.5 s (the learner needs the
# final rest, not its length).
QUICK_DEMONSTRATION = {'start_delay': 0.5, 'hold_time': 1.5}
# The closed loop's sim and controller ask for SCHED_FIFO at this priority, as on a robot's
# computer; where the OS refuses, each logs so once and runs as before. At normal priority,
# beside the recorder and this script, the controller's rate was 388-782 Hz (median of each
# run's second half) in one --quick run on this 2-core machine.
LOOP_PRIORITY = 50
# s the recorder has to write its bag and exit once stopped: a Panda run's 1 kHz topics on
# this loaded 2-core machine, with the loop at SCHED_FIFO, took longer than 5 s once.
RECORDER_STOP_TIMEOUT = 20.0
MAX_DOMAIN_ID = 232  # the highest ROS_DOMAIN_ID whose Fast DDS ports fit below 65536
# The sequence's hand: it waits 0.6 m from the arm, which comes to it under follow; it reaches
# in to 0.3 m from the arm's start at 0.5 m/s (the event_detector's rule hand_reaches_in:
# avoid), rests 5 s (hand_rests, after 3 s still: follow_safe) and withdraws at 0.1 m/s. The
# detector runs its default rules (config/event_detector.yaml); no timer sends an event.
SEQUENCE_HAND = {'profile': 'waypoints', 'start_delay': 0.8, 'speed': 0.1,
                 'waypoints': [0.35, -0.30, 0.35, 0.0, 0.55, -0.15],
                 'segment_speeds': [0.5, 0.1], 'pauses': [5.0, 0.0]}
SEQUENCE_SETTLE = 4.0  # s after the hand stops
# --quick: the hand rests 4 s (hand_rests fires after 3 s), withdraws twice as fast and the
# run ends 3 s after it stops (1 s to settle, then the 2 s window the final metrics judge).
QUICK_SEQUENCE_REST = 4.0  # s
QUICK_SEQUENCE_SETTLE = 3.0  # s
RUN_TOPICS = ['/hri/controller_state', '/hri/task_state', '/target', '/ee_position',
              '/effort_controller/commands']
SEQUENCE_TOPICS = [*RUN_TOPICS, '/hri/events', '/hri/separation']
# The recorded person's run also records the person's body and the arm's joints: the report
# measures the robot's capsules against the person's (hri_core.bodies) every BODY_STEP s.
PERSON_TOPICS = ['/human/body', '/joint_states']
TRUNK_CAPSULES = ('head', 'torso')  # hri_core.bodies: the torso runs from the hip up
BODY_STEP = 0.01  # s
BODY_MAX_AGE = 0.05  # s: an older /human/body is no body at that time (a lost frame)
# Stage 5: a person's right hand recorded with a Vicon tracker, replayed by hand_sim at its
# recorded pace and placed by its auto_place, from the learned follow, the tasks switched by
# the event_detector's default rules. The first RECORDED_SETTLE s after each switch are left
# out of the figures (the task fades in).
RECORDED_TAKE = REPO_ROOT / 'data' / 'human-motion' / 'TossTheCan_0.csv'
# The Panda in MuJoCo (hri_bringup.clearance_in_mujoco): two takes in which the placed person
# stands close to the arm (a handover; an inspection at the chest), each task with the
# whole-body clearance off and then on.
MUJOCO_TAKES = ('HumanRobotHandover_0', 'ObjectInspection_0')
MUJOCO_TASKS = ('follow', 'avoid')
RECORDED_SECONDS = 20.0  # s, within the take's 21 s: no loop's wrap
QUICK_RECORDED_SECONDS = 8.0  # s: the avoid task from about 2 s, judged from 4 s
RECORDED_SETTLE = 2.0  # s


def _or_dash(value: float | None, spec: str, instead: str = '—') -> str:
    """`value` formatted with `spec`, or `instead` (an em dash) where it is None or not a
    number (no samples)."""
    return format(value, spec) if value is not None and np.isfinite(value) else instead


def hand_profile(hand: dict) -> HandProfile:
    """The HandProfile of a waypoints hand of BEHAVIOURS (its points in 2-D or 3-D)."""
    return HandProfile(name='waypoints', waypoints=tuple(hand['waypoints']),
                       speed=hand['speed'], start_delay=hand['start_delay'],
                       segment_speeds=tuple(hand.get('segment_speeds', ())),
                       pauses=tuple(hand.get('pauses', ())),
                       dimension=hand.get('dimension', 2))


def hand_stops_at(hand: dict) -> float:
    """Time (s from hand_sim's start) at which a waypoints hand reaches its last point."""
    return waypoint_schedule(hand_profile(hand))[-1][1]


def effort_steps(bag: Path) -> tuple[float, float]:
    """(first command, largest change between two consecutive control cycles after it), N m.

    The first non-zero command is the controller starting on the first hand message with the
    task already in force: a step from zero torque, reported apart. After it, steps are taken
    between /effort_controller/commands received at most 1.5 ms apart (a command that came
    late on a loaded machine, after missed cycles, is not a step of the control law).
    """
    contents = read_bag(bag, topics=['/effort_controller/commands'])
    commands = contents.topics.get('/effort_controller/commands')
    if commands is None or len(commands.messages) < 2:
        return float('nan'), float('nan')
    efforts = np.array([list(m.data) for m in commands.messages])
    moving = np.flatnonzero(np.any(efforts != 0.0, axis=1))
    if moving.size == 0:
        return 0.0, 0.0
    first = int(moving[0])
    times = commands.times()[first:]
    steps = np.max(np.abs(np.diff(efforts[first:], axis=0)), axis=1)
    consecutive = np.diff(times) <= 1.5e-3
    largest = float(np.max(steps[consecutive])) if np.any(consecutive) else float('nan')
    return float(np.max(np.abs(efforts[first]))), largest


def equal_scales(axis) -> None:
    """One scale on the three axes of 3-D axes (a path along one axis is not magnified);
    nothing for a plane (its aspect is set equal already)."""
    if not hasattr(axis, 'get_zlim3d'):
        return
    limits = np.array([axis.get_xlim3d(), axis.get_ylim3d(), axis.get_zlim3d()])
    centres, half = limits.mean(axis=1), np.ptp(limits, axis=1).max() / 2.0
    axis.set_xlim3d(centres[0] - half, centres[0] + half)
    axis.set_ylim3d(centres[1] - half, centres[1] + half)
    axis.set_zlim3d(centres[2] - half, centres[2] + half)


def efforts(states) -> np.ndarray:
    """The efforts of ControllerState messages (N, joints) N m; zeros where one has none."""
    joints = max((len(m.effort) for m in states), default=2)
    return np.array([list(m.effort) or [0.0] * joints for m in states]).reshape(-1, joints)


def compare_with_paper(name: str, bags: list[str], shifts: list[float], figures: Path,
                       gauss_newton_updates: int) -> dict:
    """Table I's columns for one task: the learner's fit again in-process (same defaults),
    the paper's a1, a2 scored on the same demonstration, the paper's Gauss-Newton
    iteration run on it (at most `gauss_newton_updates` updates), and the figure overlaying
    P_d, the learned P and the paper's."""
    defaults = LearningSettings.from_parameters(load_defaults('hri_demo_learning', 'learner'))
    settings = replace(defaults, method='trf')
    learned = learn_from_bags(bags, shifts, name, settings)
    record, profile = learned.record, learned.profile
    paper = PAPER_TABLE_I[name]
    paper_here = TaskShape(record.s, paper['a1'], paper['a2'], record.d1, record.d2,
                           record.n)
    gauss_newton = fit_task_parameters(
        profile.distance, profile.energy, record.s, record.d1, record.d2, n=record.n,
        options=replace(settings, method='gauss_newton',
                        max_iterations=gauss_newton_updates).fit_options,
        a1_max=learned.a1_max)
    paper_row = TaskShape(paper['s'], paper['a1'], paper['a2'], paper['d1'], paper['d2'],
                          record.n)
    plot_task_fit(profile.distance, profile.energy, record.shape,
                  figures / f'fit_{name}.png',
                  title=f'{name}: demonstration, learned P and the paper\'s P',
                  reference=(paper_row, f"paper's P (Table I: d1={paper['d1']}, "
                                        f"d2={paper['d2']}, a1={paper['a1']}, "
                                        f"a2={paper['a2']})"))
    return {
        'paper_cost': task_cost(profile.distance, profile.energy, paper_here),
        'gauss_newton_updates': gauss_newton.iterations,
        'gauss_newton_converged': gauss_newton.converged,
        'gauss_newton_cost': gauss_newton.cost,
        'gauss_newton_a': [gauss_newton.a1, gauss_newton.a2],
        'trf_evaluations': learned.fit.iterations,
        'a1_max': learned.a1_max,
    }


def engine_run(job: tuple) -> EngineRun:
    """One of the engine comparison's runs (a process of its pool): (scenario, engine, the
    folder of the learned tasks), each task's K as learned (0: the law's default)."""
    scenario, engine, tasks_dir = job
    shapes, gains = {}, {}
    for task in ('follow', 'avoid', 'follow_safe'):
        record = load_task_file(Path(tasks_dir) / f'{task}.yaml')
        shapes[task] = record.shape
        if record.k > 0.0:
            gains[task] = record.k
    return run_scenario(scenario, shapes, engine, gains)


def mujoco_take(job: tuple) -> TakeRun:
    """One of the MuJoCo stage's runs (a process of its pool): (take, task, clearance, s)."""
    take, task, clearance, seconds = job
    shape = load_task_file(paper_tasks_dir() / f'{task}.yaml').shape
    return run_take(REPO_ROOT / 'data' / 'human-motion' / f'{take}.csv', task, shape,
                    clearance, seconds)


def behaviour_table(behaviours: dict) -> list[str]:
    """The report's table of the behaviours' closed-loop runs (metrics['behaviours'])."""
    lines = ['| task | region (m) | reached | time to region (s) | steady distance (m) '
             '| peak torque (N m) | final torque (N m) | largest step (N m) '
             '| controller rate (Hz) | deadline misses | cycles without control |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    for name, m in behaviours.items():
        ttr = '-' if m['time_to_region'] is None else f'{m["time_to_region"]:.2f}'
        lines.append(f'| {name} | [{m["d1"]:.3f}, {m["d2"]:.3f}] | '
                     f'{"yes" if m["in_region_at_end"] else "no"} | {ttr} | '
                     f'{m["steady_distance"]:.3f} | {m["peak_torque"]:.2f} | '
                     f'{m["final_peak_torque"]:.3f} | {m["max_effort_step"]:.3f} | '
                     f'{m["controller_rate_hz"]:.0f} | '
                     f'{m["deadline_misses"]} | {100 * m["control_dropout_fraction"]:.1f} % |')
    return lines


class StageError(Exception):
    """A stage failed; the message says why."""


class Demo:
    """Runs the stages, keeping every process it starts so it can end them by PID.

    The SCARA's demo; PandaDemo (the Panda's profile, below) overrides the class settings and
    the hooks (`start_teach_sim`, `loop_overrides`, `learn`, `write_report`) for the Panda in
    3-D."""

    robot = 'scara'
    dimension = 2  # coordinates of the hand and the tool: the SCARA moves in the plane
    sim_node = 'scara_sim'  # the live loop's simulator (hri_bringup.processes)
    demonstrations = DEMONSTRATIONS
    learning = LEARNING
    behaviours = BEHAVIOURS
    sequence_hand = SEQUENCE_HAND
    settle_after_hand: float | None = None  # s a run goes on after its hand stops (None: 25 s)

    def __init__(self, out: Path, quick: bool, domain_id: int):
        self.out = out
        self.quick = quick
        self.gauss_newton_updates = (QUICK_GAUSS_NEWTON_MAX_UPDATES if quick
                                     else GAUSS_NEWTON_MAX_UPDATES)
        self.domain_id = domain_id
        self.logs = out / 'logs'
        self.bags = out / 'bags'
        self.tasks = out / 'tasks'
        self.figures = out / 'figures'
        self.running: list[NodeProcess] = []
        self.metrics: dict = {'quick': quick, 'learning': {}, 'behaviours': {}}
        self._last_progress = ('', -1)

    # -- processes ---------------------------------------------------------------------
    def start(self, package: str, executable: str, domain: int | None = None,
              **params) -> NodeProcess:
        """Start a node on `domain` (default: the demo's) with `params`."""
        process = start_node(package, executable,
                             self.domain_id if domain is None else domain, params=params,
                             log_dir=self.logs)
        self.running.append(process)
        return process

    def stop(self, *processes: NodeProcess, timeout: float = 5.0) -> None:
        """Stop `processes` together (SIGINT to all, then the waits up to `timeout` s); each
        must exit 0."""
        codes = stop_all(processes, timeout=timeout)
        for process in processes:
            self.running.remove(process)
        failed = [f'{p.name} exited {code} when stopped; log {p.log_path}'
                  for p, code in codes.items() if code != 0]
        if failed:
            raise StageError('; '.join(failed))

    def stop_all(self) -> None:
        for process in list(self.running):
            process.stop(timeout=3.0)
        self.running.clear()

    def progress(self, label: str, fraction: float) -> None:
        """A bar redrawn in place on a terminal; a line per 10 % into a log or a pipe."""
        fraction = min(max(fraction, 0.0), 1.0)
        width = 30
        filled = int(round(width * fraction))
        line = f'    {label:<28} [{"#" * filled}{"." * (width - filled)}] {100 * fraction:5.1f} %'
        if sys.stdout.isatty():
            print(f'\r{line}', end='', flush=True)
        elif (label, int(10 * fraction)) != self._last_progress:
            self._last_progress = (label, int(10 * fraction))
            print(line, flush=True)

    def progress_done(self, label: str) -> None:
        """The bar at 100 %, and the terminal's line ended."""
        self.progress(label, 1.0)
        if sys.stdout.isatty():
            print()

    def run_for(self, seconds: float, label: str, watch: list[NodeProcess],
                on_tick=None) -> None:
        started = time.monotonic()
        while (elapsed := time.monotonic() - started) < seconds:
            for process in watch:
                if not process.alive():
                    print()
                    raise StageError(f'{process.name} died (exit {process.process.returncode});'
                                     f' log {process.log_path}')
            if on_tick is not None:
                on_tick(elapsed)
            self.progress(label, elapsed / seconds)
            time.sleep(0.1)
        self.progress_done(label)

    # -- stage 1 -----------------------------------------------------------------------
    def record_demonstrations(self) -> None:
        # The demonstrations are independent: each runs on a domain of its own (the demo's
        # domain and the ones after it), side by side.
        sessions = {}
        for offset, (name, demo) in enumerate(self.demonstrations.items()):
            bag = self.bags / name
            shutil.rmtree(bag, ignore_errors=True)
            stop = demo.get('stop_distance', demo.get('safe_distance'))
            print(f'  demonstration {name!r}: human pushes the arm ({demo["mode"]}), '
                  f'x_r = {demo["reference"]}, stops {stop} m from it')
            self.metrics.setdefault('demonstrations', {})[name] = demo
            domain = self.domain_id + offset
            sim = self.start_teach_sim(domain)
            recorder = self.start('hri_demo_learning', 'recorder', domain=domain,
                                  output=str(bag), **self.recorder_parameters())
            self.before_demonstrator(sim, recorder)
            human = self.start('scara_sim', 'demonstrator', domain=domain, **demo,
                               **self.demonstrator_parameters())
            sessions[name] = (bag, sim, recorder, human)
        started = time.monotonic()
        label = f'{", ".join(sessions)}: demonstrating'
        while any(human.alive() for *_, human in sessions.values()):
            if time.monotonic() - started > 90.0:
                raise StageError('the demonstrators did not finish in 90 s')
            self.progress(label, min((time.monotonic() - started) / 15, 0.99))
            time.sleep(0.2)
        self.progress_done(label)
        for name, (bag, sim, recorder, human) in sessions.items():
            if human.process.returncode != 0:
                raise StageError(f'demonstrator {name} exited {human.process.returncode}; '
                                 f'log {human.log_path}')
            self.running.remove(human)
            self.stop(recorder)
            self.stop(sim)
            print(f'    bag {bag}: {read_bag(bag).counts()}')

    def start_teach_sim(self, domain: int) -> NodeProcess:
        """The simulator a demonstration pushes, on `domain`."""
        return self.start('scara_sim', 'scara_sim', domain=domain)

    def recorder_parameters(self) -> dict:
        """The demonstration recorder's parameters besides its output (its defaults)."""
        return {}

    def before_demonstrator(self, sim: NodeProcess, recorder: NodeProcess) -> None:
        """Called before each demonstrator starts (the SCARA's nodes are up at once)."""

    def demonstrator_parameters(self) -> dict:
        """The demonstrator's parameters besides the demonstration's own."""
        return QUICK_DEMONSTRATION if self.quick else {}

    # -- stage 2 -----------------------------------------------------------------------
    def learn(self) -> None:
        # The learners are independent: they run side by side, and beside them (in two worker
        # processes) the in-process fits behind the Table I comparison, which need only the bags.
        learners = self.start_learners()
        with ProcessPoolExecutor(max_workers=2) as pool:
            comparisons = {name: pool.submit(compare_with_paper, name,
                                             [str(self.bags / b) for b in bags], shifts,
                                             self.figures, self.gauss_newton_updates)
                           for name, (bags, shifts) in self.learning.items()}
            self._collect_learned(learners, comparisons)

    def start_learners(self, **params) -> dict[str, NodeProcess]:
        """A learner (once) per task of `learning`, side by side, with `params` besides."""
        return {name: self.start('hri_demo_learning', 'learner',
                                 bags=[str(self.bags / b) for b in bags], shifts=shifts,
                                 task_name=name, output_dir=str(self.tasks), once=True,
                                 **params)
                for name, (bags, shifts) in self.learning.items()}

    def learned(self, name: str, learner: NodeProcess) -> TaskRecord:
        """The task `learner` wrote, once it has exited 0."""
        code = learner.wait(120.0)
        self.running.remove(learner)
        if code != 0:
            learner.stop()
            raise StageError(f'learner {name} exited {code}; log {learner.log_path}')
        return load_task_file(self.tasks / f'{name}.yaml')

    def _collect_learned(self, learners: dict, comparisons: dict) -> None:
        for name, learner in learners.items():
            record = self.learned(name, learner)
            summary = [line for line in learner.log().splitlines() if 'learned' in line]
            print(f'  {name}: S={record.s:+d} d1={record.d1:.3f} d2={record.d2:.3f} '
                  f'a1={record.a1:.4g} a2={record.a2:.4g} C={record.cost:.3g} '
                  f'iterations={record.iterations}')
            if summary:
                print(f'    {summary[-1].split("]: ", 1)[-1]}')
            self.metrics['learning'][name] = asdict(record)
            try:
                self.metrics.setdefault('table_i', {})[name] = comparisons[name].result()
            except LearningError as error:
                raise StageError(f'{name}: the learner learned it, the same fit in-process '
                                 f'did not: {error}') from None

    # -- stages 3, 4 and 5 -------------------------------------------------------------
    def closed_loop(self, run: str, initial_task: str, hand: dict, seconds: float,
                    detector: bool = False) -> Path:
        """Run the live loop (with the event_detector: `detector`) for `seconds` s, recorded
        into bags/run_<run>; the bag's path."""
        bag = self.bags / f'run_{run}'
        shutil.rmtree(bag, ignore_errors=True)
        # The hand starts last, once the others are up, so its script begins with the loop
        # running.
        try:
            loop = start_live_loop(
                self.domain_id, self.loop_overrides(initial_task, hand, detector),
                log_dir=self.logs, record=bag, ready_timeout=30.0,
                nodes=[*(self.sim_node if n == 'scara_sim' else n for n in LIVE_LOOP),
                       *(['event_detector'] if detector else [])])
        except NodesNotReadyError as error:
            raise StageError(f'{error}; logs in {self.logs}') from None
        self.running.extend(loop.values())
        # The run's time counts from the hand's first move: on a loaded machine (the loop at
        # SCHED_FIFO on both cores) `ros2 run` took up to 17 s to bring hand_sim up, and the
        # run was over before the hand had published.
        if not loop['hand_sim'].wait_for_line(READY_LINES['hand_sim'], 30.0):
            raise StageError(f'hand_sim did not start within 30 s; log '
                             f'{loop["hand_sim"].log_path}')
        self.run_for(seconds, f'{run}: running', list(loop.values()))
        # The hand first, then the recorder: the bag ends with the loop still running; then
        # the loop's nodes together.
        # The recorder may take a while to write what it holds on a loaded machine.
        self.stop(loop['hand_sim'])
        self.stop(loop['recorder'], timeout=RECORDER_STOP_TIMEOUT)
        self.stop(*(process for name, process in loop.items()
                    if name not in ('hand_sim', 'recorder')))
        return bag

    def loop_overrides(self, initial_task: str, hand: dict, detector: bool) -> dict:
        """The live loop's parameters (hri_bringup.processes.start_live_loop's overrides)."""
        return {
            'event_manager': {'tasks_dir': str(self.tasks), 'initial_task': initial_task,
                              'ramp_time': 1.0},
            'recorder': {'topics': list(dict.fromkeys(
                [*(SEQUENCE_TOPICS if detector else RUN_TOPICS),
                 *(PERSON_TOPICS if hand.get('profile') == 'recording' else [])]))},
            'hand_sim': hand,
            'scara_sim': {'realtime_priority': LOOP_PRIORITY},
            'controller': {'realtime_priority': LOOP_PRIORITY},
        }

    def hand_reach(self) -> ReachAnnulus:
        """The reach hand_sim's auto_place puts a recorded person's path in."""
        return ReachAnnulus(*load_defaults('scara_sim', 'hand_sim')['reach'])

    def body_clearance(self) -> float:
        """How far (m) hand_sim's auto_place keeps the recorded person's trunk from the base."""
        return BODY_CLEARANCE['scara']

    def points(self, messages) -> np.ndarray:
        """PointStamped messages as (N, dimension) m."""
        return np.array([(m.point.x, m.point.y, m.point.z)[:self.dimension]
                         for m in messages]).reshape(-1, self.dimension)

    def path_axis(self, figure, *position):
        """The subplot of the paths: a plane for the SCARA, 3-D axes for an arm in space."""
        if self.dimension == 2:
            axis = figure.add_subplot(*position)
            axis.set_aspect('equal', adjustable='datalim')
        else:
            axis = figure.add_subplot(*position, projection='3d')
            axis.set_zlabel('z (m)')
        axis.set_xlabel('x (m)')
        axis.set_ylabel('y (m)')
        return axis

    def run_behaviours(self) -> None:
        for task, hand in self.behaviours.items():
            seconds = 25.0 if self.settle_after_hand is None \
                else hand_stops_at(hand) + self.settle_after_hand
            if self.quick:
                hand = {**hand, 'speed': hand['speed'] * QUICK_SPEED_UP,
                        'start_delay': min(hand['start_delay'], QUICK_START_DELAY)}
                if 'pauses' in hand:  # long enough to see the arm settle outside d1
                    hand['pauses'] = [min(p, QUICK_PAUSE) for p in hand['pauses']]
                seconds = hand_stops_at(hand) + QUICK_SETTLE
            speeds = hand.get('segment_speeds') or f'{hand["speed"]:.3f}'
            print(f'  behaviour {task!r}: hand {hand["profile"]} {hand["waypoints"]} at '
                  f'{speeds} m/s after {hand["start_delay"]:.1f} s; {seconds:.0f} s')
            bag = self.closed_loop(task, task, hand, seconds)
            self.behaviour_report(task, bag)

    def run_sequence(self) -> None:
        hand = self.sequence_hand
        settle = SEQUENCE_SETTLE
        if self.quick:
            reach_in, withdraw = hand['segment_speeds']
            hand = {**hand, 'pauses': [min(hand['pauses'][0], QUICK_SEQUENCE_REST),
                                       *hand['pauses'][1:]],
                    'segment_speeds': [reach_in, withdraw * QUICK_SPEED_UP]}
            settle = QUICK_SEQUENCE_SETTLE
        seconds = hand_stops_at(hand) + settle
        print(f'  sequence follow -> avoid -> follow_safe, events from the event_detector: '
              f'hand {hand["waypoints"]} at {hand["segment_speeds"]} m/s, '
              f'resting {hand["pauses"][0]:g} s; {seconds:.0f} s')
        bag = self.closed_loop('sequence', 'follow', hand, seconds, detector=True)
        self.sequence_report(bag)

    def run_recorded_person(self) -> None:
        seconds = QUICK_RECORDED_SECONDS if self.quick else RECORDED_SECONDS
        reach = self.hand_reach()
        hand = {'profile': 'recording', 'recording': str(RECORDED_TAKE), 'auto_place': True,
                'at_end': 'loop', 'reach': [reach.inner, reach.outer],
                'body_clearance': self.body_clearance(), 'arm': self.robot}
        print(f'  a recorded person ({RECORDED_TAKE.stem}, Vicon, 100 Hz) as the hand for '
              f'{seconds:.0f} s, from follow; the event_detector switches the tasks')
        bag = self.closed_loop('recorded_person', 'follow', hand, seconds, detector=True)
        self.recorded_person_report(bag)

    # -- stage 6 -----------------------------------------------------------------------
    effort_topics: list[str] = []  # what effort_shares reads from a run's bag besides commands

    def effort_shares(self, contents: dict, times, commands):
        """The commands (N, n) N m at `times` (s) as fractions of each joint's effort limit,
        for the recorded person's high-effort hold: the SCARA's (horizontal, no gravity)
        over its model's effort limits."""
        return commands / robot_model('scara').limits.effort

    def recorded_person_report(self, bag: Path) -> None:
        """Figures of the recorded person's run per task the controller ran
        (run_metrics.take_metrics), the detected events, and its figure: hand and arm paths,
        distance, effort."""
        topics = list(dict.fromkeys(['/target', '/ee_position', '/effort_controller/commands',
                                     '/hri/controller_state', *self.effort_topics,
                                     *PERSON_TOPICS, '/hri/separation', '/hri/events']))
        contents = read_bag(bag, topics=topics).topics
        for topic in topics[:-2]:
            if topic not in contents or not contents[topic].messages:
                raise StageError(f'no {topic} in {bag}')

        def stamped(topic):
            messages = contents[topic].messages
            return (np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                              for m in messages]), self.points(messages))

        hand_t, hand_xy = stamped('/target')
        arm_t, arm_xy = stamped('/ee_position')
        command_t = contents['/effort_controller/commands'].times()
        commands = np.array([list(m.data) for m in contents['/effort_controller/commands']
                             .messages])
        shares = self.effort_shares(contents, command_t, commands)
        states = contents['/hri/controller_state'].messages
        state_t = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in states])
        state_task = np.array([m.task for m in states])
        # The task the controller ran at each arm sample, and when it began running it.
        at_state = np.clip(np.searchsorted(state_t, arm_t, side='right') - 1, 0, len(states) - 1)
        arm_task = state_task[at_state]
        changes = np.flatnonzero(arm_task[1:] != arm_task[:-1]) + 1
        switches = arm_t[changes]
        segment = np.zeros(arm_t.size, dtype=int)  # which run of one task each sample is in
        segment[changes] = 1
        began = arm_t[np.concatenate(([0], changes))][np.cumsum(segment)]
        events = [(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, m.name, m.task)
                  for m in (contents['/hri/events'].messages if '/hri/events' in contents
                            else [])]
        # The hand as the controller had it at each arm sample: the newest /target, none
        # where that is more than 50 ms old (a frame the cameras lost).
        newest = np.searchsorted(hand_t, arm_t, side='right') - 1
        hand_at_arm = hand_xy[np.maximum(newest, 0)].copy()
        hand_at_arm[(newest < 0) | (arm_t - hand_t[np.maximum(newest, 0)] > 0.05)] = np.nan
        controller = load_defaults('hri_adaptive_controller', 'controller')
        reach = self.hand_reach()
        t0 = hand_t[0]
        summary = {'take': RECORDED_TAKE.stem,
                   'target_glitches': int(max(m.target_glitches for m in states)),
                   'events': [{'t': round(t - t0, 2), 'event': name, 'task': task}
                              for t, name, task in events]}
        for t, name, task in events:
            print(f'    event {name!r} -> {task or "none"} at {t - t0:.2f} s')
        settled = arm_t >= np.maximum(began, hand_t[0]) + RECORDED_SETTLE
        for task in ('follow', 'avoid', 'follow_safe'):
            inside = (arm_task == task) & settled
            if np.count_nonzero(inside) < 100:
                continue
            record = load_task_file(self.tasks / f'{task}.yaml')
            # The commands as fractions of their joints' limits (effort_limit 1): take_metrics
            # wants one per arm sample.
            criteria = TakeCriteria(d1=record.d1, effort_limit=1.0,
                                    task_speed=controller['max_task_speed'], reach=reach)
            nearest = np.clip(np.searchsorted(command_t, arm_t[inside]), 0, len(command_t) - 1)
            metrics = take_metrics(arm_t[inside], hand_at_arm[inside], arm_xy[inside],
                                   shares[nearest], criteria)
            # Every command sent while the task ran, not only those nearest an arm sample:
            # steps between consecutive commands of each stretch of the task.
            edges = np.diff(np.concatenate(([0], inside.astype(np.int8), [0])))
            stretches = [np.arange(np.searchsorted(command_t, arm_t[start]),
                                   np.searchsorted(command_t, arm_t[end - 1], side='right'))
                         for start, end in zip(np.flatnonzero(edges == 1),
                                               np.flatnonzero(edges == -1), strict=True)]
            window = np.zeros(command_t.size, dtype=bool)
            window[np.concatenate(stretches)] = True
            summary[task] = {
                **asdict(metrics), 'd1': record.d1, 'seconds': float(np.sum(inside) * 1e-3),
                'largest_effort_step': max(largest_effort_step(commands[stretch])
                                           for stretch in stretches),
                'longest_high_effort_hold': longest_high_effort_hold(
                    command_t[window], shares[window], criteria.high_effort_fraction)}
            m = summary[task]
            # Distances are judged only where the arm can be asked to be at the hand: in a
            # short run a task may hold none of those samples (the toss's fast reach-in under
            # follow in --quick), and its median is no number.
            judged = (f'median distance {m["follow_median_distance"]:.3f} m, closer than '
                      f'd1 - 3 cm {100 * m["close_fraction"]:.1f} % (of the samples with the '
                      f'hand in reach and slower than {criteria.task_speed} m/s)'
                      if m['considered'] else
                      f'no distance judged: the hand was out of reach or faster than '
                      f'{criteria.task_speed} m/s throughout its {m["seconds"]:.1f} s')
            print(f'    {task}: {judged}; longest hold above 25 % of the effort limit '
                  f'{m["longest_high_effort_hold"]:.2f} s; largest command step '
                  f'{m["largest_effort_step"]:.3f} N m')
        print(f'    /target jumps held: {summary["target_glitches"]}')
        body_t, body_least, whole_body = self.whole_body(contents)
        summary['whole_body'] = whole_body
        print(f'    whole body: the least robot-person distance {whole_body["least"]:.3f} m '
              f'({whole_body["least_pair"]}), to head and torso '
              f'{_or_dash(whole_body["trunk_least"], ".3f")} m ({whole_body["trunk_pair"]}); '
              f'below S_p {whole_body["below_protective"]:.1f} s of '
              f'{whole_body["seconds"]:.1f} s (tool and hand)')
        self.metrics['recorded_person'] = summary
        figure = plt.figure(figsize=(11, 6))
        plane = self.path_axis(figure, 1, 2, 2)
        distance_axis = figure.add_subplot(2, 2, 1)
        effort_axis = figure.add_subplot(2, 2, 3, sharex=distance_axis)
        colours = {'follow': 'tab:blue', 'avoid': 'tab:purple', 'follow_safe': 'tab:green'}
        plane.plot(*hand_xy.T, '.', color='tab:orange', markersize=1.5,
                   label='hand (recorded)')
        for task, colour in colours.items():
            path = np.where((arm_task == task)[:, None], arm_xy, np.nan)
            if np.any(arm_task == task):
                plane.plot(*path.T, color=colour, label=f'arm, {task}')
        if self.dimension == 2:
            for radius in (reach.inner, reach.outer):
                plane.add_patch(plt.Circle((0.0, 0.0), radius, fill=False, linestyle=':',
                                           color='grey'))
            plane.plot(0.0, 0.0, 'k+')
            plane.set_title(f'{RECORDED_TAKE.stem}: paths (dotted: the reach)')
        else:
            plane.plot(0.0, 0.0, 0.0, 'k+')
            plane.set_title(f'{RECORDED_TAKE.stem}: paths in 3-D (+: the base)')
        plane.legend(loc='best', fontsize=8)
        equal_scales(plane)
        distance = np.linalg.norm(hand_at_arm - arm_xy, axis=1)
        distance_axis.plot(arm_t - t0, distance, color='k', linewidth=0.8, label='tool - hand')
        distance_axis.plot(body_t - t0, body_least[:, 0], color='tab:red', linewidth=0.8,
                           label='whole body: least capsule distance')
        distance_axis.plot(body_t - t0, body_least[:, 1], color='tab:brown', linewidth=0.8,
                           linestyle='--', label='head and torso: least distance')
        for t in switches:
            distance_axis.axvline(t - t0, color='grey', linestyle='--')
        avoid_d1 = load_task_file(self.tasks / 'avoid.yaml').d1
        distance_axis.axhline(avoid_d1, color='tab:purple', linestyle=':', label='avoid d1')
        distance_axis.set_ylabel('|hand - arm| (m)')
        distance_axis.set_title('distance to the hand (dashed: a detected switch)')
        distance_axis.legend(loc='upper right', fontsize=8)
        for joint in range(commands.shape[1]):
            effort_axis.plot(command_t - t0, commands[:, joint], label=f'tau{joint + 1}',
                             linewidth=0.8)
        effort_axis.set_xlim(0.0, float(arm_t[-1] - t0))   # from the first hand sample
        effort_axis.set_xlabel('t (s)')
        effort_axis.set_ylabel('torque (N m)')
        effort_axis.legend(loc='upper right', fontsize=8, ncol=1 + commands.shape[1] // 4)
        figure.tight_layout()
        figure.savefig(self.figures / 'recorded_person.png', dpi=110)
        plt.close(figure)

    def whole_body(self, contents: dict) -> tuple[np.ndarray, np.ndarray, dict]:
        """The robot's capsules against the recorded person's (hri_core.bodies) every
        BODY_STEP s of the run's joint states, with the newest /human/body no older than
        BODY_MAX_AGE: (times (M,) s, least distance (M, 2) m to the whole body and to its
        trunk (head, torso, hip), NaN without one; a summary: the least distances and their
        pairs, the three pairs most often closest, the time below S_p on
        /hri/separation)."""
        model = robot_model(self.robot)
        body = robot_body(model, panda_package_dirs())
        states = contents['/joint_states'].messages
        people = contents['/human/body'].messages
        state_t = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                            for m in states])
        person_t = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                             for m in people])
        order = {name: k for k, name in enumerate(states[0].name)}
        joints = [order[name] for name in model.joint_names]
        picked = np.flatnonzero(np.diff(np.floor(state_t / BODY_STEP), prepend=-1.0) > 0)
        least = np.full((picked.size, 2), np.nan)
        pairs: dict[str, int] = {}
        capsules: dict = {}
        best = [(np.inf, ''), (np.inf, '')]
        for k, index in enumerate(picked):
            newest = int(np.searchsorted(person_t, state_t[index], side='right')) - 1
            if newest < 0 or state_t[index] - person_t[newest] > BODY_MAX_AGE:
                continue
            if newest not in capsules:
                capsules.clear()
                message = people[newest]
                capsules[newest] = human_capsules(message.names,
                                                  [(p.x, p.y, p.z) for p in message.points])
            human = capsules[newest]
            if not len(human):
                continue
            q = np.array(states[index].position)[joints]
            distances = capsule_distances(body.capsules(q, checked=False), human, body.planar)
            i, j = distances.closest()
            pair = f'{body.names[i]} - {human.names[j]}'
            pairs[pair] = pairs.get(pair, 0) + 1
            trunk = [j for j, name in enumerate(human.names) if name in TRUNK_CAPSULES]
            found = [(i, j)]
            if trunk:
                table = distances.distance[:, trunk]
                r, t = np.unravel_index(int(np.argmin(table)), table.shape)
                found.append((int(r), trunk[t]))
            for column, (r, t) in enumerate(found):
                least[k, column] = distances.distance[r, t]
                if least[k, column] < best[column][0]:
                    best[column] = (float(least[k, column]),
                                    f'{body.names[r]} - {human.names[t]}')
        measured = int(np.count_nonzero(np.isfinite(least[:, 0])))
        if not measured:
            raise StageError('no joint state with a /human/body to measure the whole body at')
        separations = (contents['/hri/separation'].messages
                       if '/hri/separation' in contents else [])
        below = sum(1 for m in separations if m.below_protective)
        rate = load_defaults('hri_adaptive_controller', 'event_detector')['publish_rate_hz']
        ranked = sorted(pairs.items(), key=lambda item: -item[1])[:3]
        # No head or torso in any frame (a take without those segments): no figure for them.
        trunk = best[1] if np.isfinite(best[1][0]) else (None, 'none seen')
        summary = {'least': best[0][0], 'least_pair': best[0][1],
                   'trunk_least': trunk[0], 'trunk_pair': trunk[1], 'measured': measured,
                   'closest_pairs': [{'pair': pair, 'share': round(count / measured, 3)}
                                     for pair, count in ranked],
                   'below_protective': below / rate, 'seconds': len(separations) / rate}
        return state_t[picked], least, summary

    def whole_body_lines(self, person: dict) -> list[str]:
        """The report's lines on the whole body in the recorded person's run."""
        body = person['whole_body']
        closest = ', '.join(f"{p['pair']} ({100 * p['share']:.0f} %)"
                            for p in body['closest_pairs'])
        clearance = load_defaults('hri_adaptive_controller', 'controller')['clearance']
        setting = f'{clearance:g} m' if clearance > 0.0 else 'off'
        return ['', f"The whole body (the arm's capsules against the person's, every "
                f"{BODY_STEP * 1000:.0f} ms of joint states; the controller's clearance "
                f"{setting}, its default; the tracked hand's own capsules count here, though "
                f"a follow task may reach them): the least distance {body['least']:.3f} m "
                f"({body['least_pair']}; below 0: overlapping), to the head and torso "
                f"{_or_dash(body['trunk_least'], '.3f')} m ({body['trunk_pair']}); the pairs "
                'most often '
                f"closest: {closest}. Below ISO/TS 15066's S_p (tool and hand, /hri/separation): "
                f"{body['below_protective']:.1f} s of {body['seconds']:.1f} s. The figure's "
                'red lines are the whole-body and the head-and-torso least distances beside the '
                'tool-hand distance.']

    def controller_series(self, bag: Path) -> dict:
        contents = read_bag(bag, topics=['/hri/controller_state', '/hri/task_state'])
        states = contents.topics.get('/hri/controller_state')
        if states is None or not states.messages:
            raise StageError(f'no /hri/controller_state in {bag}')
        # The run starts when the controller first controls (joint states, hand and task known).
        first = next((i for i, m in enumerate(states.messages) if m.status == 'ok'), None)
        if first is None:
            raise StageError(f'the controller never reached status ok in {bag}; statuses: '
                             f'{sorted({m.status for m in states.messages})}')
        messages = states.messages[first:]
        t = states.times()[first:]
        ok = np.array([m.status == 'ok' for m in messages])
        return {
            'ok': ok,
            'control_dropout_fraction': float(1.0 - np.mean(ok)),
            't': t - float(t[0]),
            't0': float(t[0]),  # bag time (s since the epoch) of t = 0
            'distance': np.array([m.distance for m in messages]),
            'effort': efforts(messages),
            'weight': np.array([m.weight for m in messages]),
            'lyapunov': np.array([m.lyapunov for m in messages]),
            'task': [m.task for m in messages],
            'deadline_misses': int(messages[-1].deadline_misses),
            'rate_hz': float(np.median([m.rate_hz for m in messages[len(messages) // 2:]])),
        }

    def behaviour_report(self, task: str, bag: Path) -> None:
        record = load_task_file(self.tasks / f'{task}.yaml')
        series = self.controller_series(bag)
        metrics = run_metrics(series['t'], series['distance'], series['effort'], record.d1,
                              record.d2, window=2.0)
        start_step, step = effort_steps(bag)
        self.metrics['behaviours'][task] = {
            **asdict(metrics), 'd1': record.d1, 'd2': record.d2, 'max_effort_step': step,
            'start_effort_step': start_step,
            'control_dropout_fraction': series['control_dropout_fraction'],
            'controller_rate_hz': series['rate_hz'],
            'deadline_misses': series['deadline_misses'],
        }
        reached = 'reached' if metrics.in_region_at_end else 'DID NOT reach'
        ttr = ('-' if metrics.time_to_region is None else f'{metrics.time_to_region:.2f} s')
        print(f'    {reached} [{record.d1:.3f}, {record.d2:.3f}] m: time to region {ttr}, '
              f'steady distance {metrics.steady_distance:.3f} m, peak torque '
              f'{metrics.peak_torque:.2f} N m, largest step between cycles {step:.3f} N m '
              f'(first command {start_step:.2f} N m), '
              f'controller {series["rate_hz"]:.0f} Hz, {series["deadline_misses"]} deadline '
              'misses')
        figure = plt.figure(figsize=(11, 5))
        top = figure.add_subplot(2, 2, 1)
        bottom = figure.add_subplot(2, 2, 3, sharex=top)
        plane = self.path_axis(figure, 1, 2, 2)
        for joint in range(series['effort'].shape[1]):
            top.plot(series['t'], series['effort'][:, joint], label=f'tau{joint + 1}')
        top.set_ylabel('torque (N m)')
        top.legend(loc='upper right', ncol=1 + series['effort'].shape[1] // 4,
                   fontsize=None if self.dimension == 2 else 'small')
        top.set_title(f'{task}: torque and distance to the hand (cf. paper Figs. 4-6)')
        bottom.axhspan(record.d1, min(record.d2, 0.6), color='tab:green', alpha=0.2,
                       label='desired region')
        bottom.plot(series['t'], series['distance'], color='k', label='|x - x_d|')
        bottom.set_ylim(0.0, max(0.45, float(np.max(series['distance'])) * 1.05))
        bottom.set_xlabel('t (s)')
        bottom.set_ylabel('distance (m)')
        bottom.legend(loc='upper right')
        paths = read_bag(bag, topics=['/target', '/ee_position']).topics
        for topic, label, colour in (('/target', 'hand', 'tab:orange'),
                                     ('/ee_position', 'end-effector', 'tab:blue')):
            if topic in paths and paths[topic].messages:
                xy = self.points(paths[topic].messages)
                plane.plot(*xy.T, color=colour, label=label)
                plane.plot(*xy[0], 'o', color=colour)
                plane.plot(*xy[-1], 's', color=colour)
        plane.set_title('paths (o start, square end)' if self.dimension == 2
                        else 'paths in 3-D (o start, square end)')
        plane.legend(loc='best')
        equal_scales(plane)
        figure.tight_layout()
        figure.savefig(self.figures / f'behaviour_{task}.png', dpi=110)
        plt.close(figure)

    def detected_events(self, bag: Path, t0: float) -> tuple[list[dict], dict]:
        """The events of the bag's /hri/events ({'time_s', 'event', 'task'}, t from `t0`)
        and its /hri/separation as arrays: t (s from t0), separation, S_p as published (ISO
        13855 hand speed) and S_p of the measured speeds (m)."""
        contents = read_bag(bag, topics=['/hri/events', '/hri/separation']).topics
        events = []
        if '/hri/events' in contents:
            series = contents['/hri/events']
            events = [{'time_s': float(t - t0), 'event': m.name, 'task': m.task}
                      for t, m in zip(series.times(), series.messages, strict=True)]
        if '/hri/separation' not in contents or not contents['/hri/separation'].messages:
            raise StageError(f'no /hri/separation in {bag}: did the event_detector run?')
        series = contents['/hri/separation']
        constants = load_defaults('hri_adaptive_controller', 'event_detector')
        fixed = sum(constants[name] for name in ('stopping_distance', 'intrusion_distance',
                                                 'human_uncertainty', 'robot_uncertainty'))
        stop = constants['reaction_time'] + constants['stopping_time']
        messages = series.messages
        separation = {
            't': series.times() - t0,
            'separation': np.array([m.separation for m in messages]),
            'protective': np.array([m.protective_distance for m in messages]),
            'measured': np.array([max(m.human_speed, 0.0) * stop + max(m.robot_speed, 0.0)
                                  * constants['reaction_time'] + fixed for m in messages]),
        }
        return events, separation

    def sequence_report(self, bag: Path) -> None:
        series = self.controller_series(bag)
        events, separation = self.detected_events(bag, series['t0'])
        figure, axes = plt.subplots(4, 1, sharex=True, figsize=(7, 8.5))
        # Cycles without control (stale input under load) are gaps, not a = 0.
        axes[0].plot(series['t'], np.where(series['ok'], series['weight'], np.nan),
                     color='tab:purple')
        axes[0].set_ylabel('a(E, t)')
        axes[0].set_title('follow -> avoid -> follow_safe, events detected from the hand')
        regions = {name: load_task_file(self.tasks / f'{name}.yaml')
                   for name in ('follow', 'avoid', 'follow_safe')}
        # The band follows the task in force at each controller state.
        lower = np.array([regions[n].d1 if n in regions else np.nan for n in series['task']])
        upper = np.array([min(regions[n].d2, 0.6) if n in regions else np.nan
                          for n in series['task']])
        axes[1].fill_between(series['t'], lower, upper, color='tab:green', alpha=0.2,
                             label='desired region of the active task')
        axes[1].plot(series['t'], series['distance'], color='k')
        axes[1].set_ylim(0.0, 0.7)
        axes[1].set_ylabel('distance (m)')
        axes[2].plot(separation['t'], separation['separation'], color='k',
                     label='separation')
        axes[2].plot(separation['t'], separation['protective'], color='tab:red',
                     label='S_p, ISO 13855 hand speed')
        axes[2].plot(separation['t'], separation['measured'], color='tab:orange',
                     label='S_p, measured speeds')
        axes[2].set_yscale('log')
        axes[2].set_ylabel('m (ISO/TS 15066)')
        axes[2].legend(loc='upper right', fontsize='small')
        axes[3].semilogy(series['t'], np.maximum(series['lyapunov'], 1e-12), color='tab:red')
        axes[3].set_ylabel('V (eq. 21)')
        axes[3].set_xlabel('t (s)')
        for event in events:
            for axis in axes:
                axis.axvline(event['time_s'], color='tab:blue', linestyle='--', linewidth=1)
            axes[0].annotate(f"{event['event']}\n-> {event['task'] or 'none'}",
                             (event['time_s'], 0.5), xytext=(3, 0),
                             textcoords='offset points', fontsize='small', color='tab:blue')
        axes[1].legend(loc='upper right')
        figure.tight_layout()
        figure.savefig(self.figures / 'sequence.png', dpi=110)
        plt.close(figure)
        weight = series['weight'][series['ok']]
        jumps = float(np.max(np.abs(np.diff(weight)))) if weight.size > 1 else 0.0
        final = load_task_file(self.tasks / 'follow_safe.yaml')
        metrics = run_metrics(series['t'], series['distance'], series['effort'], final.d1,
                              final.d2, window=2.0)
        for event in events:
            nearest = int(np.argmin(np.abs(separation['t'] - event['time_s'])))
            event['separation_m'] = float(separation['separation'][nearest])
        self.metrics['sequence'] = {
            'events': events,
            'separation_min_m': float(np.min(separation['separation'])),
            'protective_distance_m': [float(np.min(separation['protective'])),
                                      float(np.max(separation['protective']))],
            'protective_distance_measured_m': [float(np.min(separation['measured'])),
                                               float(np.max(separation['measured']))],
            'below_protective_fraction': float(np.mean(
                separation['separation'] < separation['protective'])),
            'below_measured_fraction': float(np.mean(
                separation['separation'] < separation['measured'])),
            'max_effort_step': effort_steps(bag)[1],
            'weight_min': float(np.min(weight)), 'weight_max': float(np.max(weight)),
            'largest_weight_step': jumps, 'final': asdict(metrics),
            'deadline_misses': series['deadline_misses'],
            'control_dropout_fraction': series['control_dropout_fraction'],
            'tasks_seen': sorted(set(series['task']) - {''}),
        }
        for event in events:
            print(f"    t = {event['time_s']:.2f} s: event {event['event']!r} -> task "
                  f"{event['task'] or 'none'!r} at separation {event['separation_m']:.3f} m")
        print(f'    a(E,t) in [{np.min(weight):.3f}, {np.max(weight):.3f}], largest step '
              f'between samples {jumps:.4f}; final distance {metrics.steady_distance:.3f} m; '
              f'closest {self.metrics["sequence"]["separation_min_m"]:.3f} m')

    def separation_verdicts(self) -> list[str]:
        """The report's lines on ISO/TS 15066 for each learned task that keeps the hand at
        d1 > 0: is d1 >= S_p with the arm at its max_task_speed, and up to what arm speed it
        would be, for a hand at ISO 13855's speed and for a still hand (metrics too)."""
        constants = load_defaults('hri_adaptive_controller', 'event_detector')
        settings = ProtectiveSeparation.from_mapping(constants)
        speed = load_defaults('hri_adaptive_controller', 'controller')['max_task_speed']
        verdicts = {name: separation_verdict(learned['d1'], speed, settings).metrics()
                    for name, learned in self.metrics['learning'].items()
                    if learned['d1'] > 0.0}
        self.metrics['separation_verdicts'] = verdicts

        def limit(value):
            return 'none (a still arm is too close already)' if value is None \
                else f'{value:.2f} m/s'

        lines = ['', '## Speed and separation (ISO/TS 15066)', '',
                 f'S_p = v_h (T_r + T_s) + v_r T_r + B + C + Z_d + Z_r with T_r = '
                 f'{settings.reaction_time:g} s, T_s = {settings.stopping_time:g} s and B = '
                 f'{settings.stopping_distance:g} m (the arm\'s stop from its peak task speed '
                 f'through the 1 s fade of a(E, t), measured in the pure closed loop), C = '
                 f'{settings.intrusion_distance:g} m, Z_d + Z_r = '
                 f'{settings.human_uncertainty + settings.robot_uncertainty:g} m; the arm at '
                 f'its max_task_speed {speed:g} m/s.', '',
                 '| task | d1 (m) | S_p, hand at ISO 13855 speed (m) | d1 >= S_p | arm speed '
                 'for d1 >= S_p | S_p, still hand (m) | d1 >= S_p | arm speed for d1 >= S_p |',
                 '|---|---|---|---|---|---|---|---|']
        for name, v in verdicts.items():
            lines.append(
                f"| {name} | {v['d1_m']:.3f} | {v['protective_distance_m']:.3f} | "
                f"{'yes' if v['d1_m'] >= v['protective_distance_m'] else 'no'} | "
                f"{limit(v['arm_speed_limit_m_s'])} | "
                f"{v['protective_distance_still_hand_m']:.3f} | "
                f"{'yes' if v['d1_m'] >= v['protective_distance_still_hand_m'] else 'no'} | "
                f"{limit(v['arm_speed_limit_still_hand_m_s'])} |")
        return lines

    def write_report(self) -> None:
        lines = ['# HRI control through demonstration: simulation report', '',
                 f'Run of `scripts/demo.sh{" --quick" if self.quick else ""}` on '
                 f'{time.strftime("%Y-%m-%d %H:%M")}.', '',
                 '## What was demonstrated', '']
        for name, demo in self.metrics.get('demonstrations', {}).items():
            if demo['mode'] == 'follow':
                lines.append(f'- `{name}`: the simulated person pushed the arm from its start '
                             f'toward x_r = {demo["reference"]} m and let go '
                             f'{demo["stop_distance"]} m from it.')
            else:
                lines.append(f'- `{name}`: the simulated person pushed the arm from next to '
                             f'x_r = {demo["reference"]} m straight away and let go '
                             f'{demo["safe_distance"]} m from it.')
        lines += ['- `follow_safe`: no demonstration of its own; eq. 4 combines the two, '
                  'follow shifted out by 0.23 m.', '',
                  'These stopping distances are not Table I\'s (0.041 m, 0.183 m): the '
                  'learned d1, d2 below come from the demonstrations.', '',
                  '## What was learned (cf. paper Table I)', '',
                  '| task | | S | d1 (m) | d2 (m) | K (m^2/s) | a1 | a2 | cost C '
                  '| C of Table I\'s a1, a2 | Gauss-Newton updates | trf evaluations |',
                  '|---|---|---|---|---|---|---|---|---|---|---|---|']
        for name, learned in self.metrics['learning'].items():
            paper = PAPER_TABLE_I[name]
            row = self.metrics.get('table_i', {}).get(name, {})
            updates = row.get('gauss_newton_updates', '-')
            if row and not row['gauss_newton_converged']:
                updates = f'{updates} (not converged, C = {row["gauss_newton_cost"]:.3g})'
            paper_cost = f'{row["paper_cost"]:.3g}' if row else '-'
            lines.append(f'| {name} | learned here | {learned["s"]:+d} | {learned["d1"]:.3f} | '
                         f'{learned["d2"]:.3f} | {learned["k"]:.4g} | {learned["a1"]:.4g} | '
                         f'{learned["a2"]:.4g} | {learned["cost"]:.3g} | {paper_cost} | '
                         f'{updates} | {row.get("trf_evaluations", "-")} |')
            lines.append(f'| | paper | {paper["s"]:+d} | {paper["d1"]:.3f} | {paper["d2"]:.3f} |'
                         f' - | {paper["a1"]} | {paper["a2"]} | - | - | {paper["iterations"]} '
                         '| - |')
        lines += ['', 'Columns. K: the task gain, fitted so that K |dP/dz| matches the '
                  'demonstrated speed (least squares over the moving samples); the paper gives '
                  'no value. cost C: eq. 8 of the learned a1, a2. C of Table I\'s a1, a2: eq. 8 '
                  'of the paper\'s a1, a2 with the learned S, d1, d2, on the same '
                  'demonstration. Gauss-Newton updates: the paper\'s iteration (eq. 9-11, the '
                  'paper\'s "Iteration" column) run on the same demonstration from the same '
                  f'start, capped at {self.gauss_newton_updates}. trf evaluations: the default '
                  'solver\'s (scipy least_squares) evaluations, the count in the task file.', '',
                  'Eq. 7 fits the *shape* of P to the normalised task energy, so a1, a2 need '
                  'not equal the paper\'s: they depend on how the demonstrator moved, and a1 is '
                  'capped so that P still pulls within the arm\'s reach (l1 + l2) of the '
                  'region. S, d1 and d2 fix the task type.', '']
        lines += [f'![fit {n}](figures/fit_{n}.png)' for n in LEARNING]
        lines += ['', '## Behaviours, closed loop on the simulated SCARA', '',
                  *behaviour_table(self.metrics['behaviours'])]
        lines += ['', 'Largest step: the largest change of the commanded torque between two '
                  'consecutive 1 kHz control cycles (commands received at most 1.5 ms apart; '
                  'the bar is 1 N m), after the first command. The first command is a step '
                  'from zero of its own: the controller starts on the first hand message with '
                  'the task already faded in (' + ', '.join(
                      f'{name} {m["start_effort_step"]:.2f} N m'
                      for name, m in self.metrics['behaviours'].items()) + ').', '',
                  'Cycles without control: controller states whose status was not ok '
                  '(joint states older than joint_state_timeout when the machine is loaded); '
                  'the torque is zero in them.', '',
                  'Times count from the first control cycle with joint states, hand and '
                  'task known; the hand starts moving a few seconds later (scripts/demo.py, '
                  'BEHAVIOURS).', '']
        lines += [f'![{n}](figures/behaviour_{n}.png)' for n in self.metrics['behaviours']]
        if 'sequence' in self.metrics:
            seq = self.metrics['sequence']
            lines += ['', '## Sequential task with events (eq. 12, 13)', '',
                      'The event_detector sent every event (its default rules, '
                      'config/event_detector.yaml) from a hand that reached in at 0.5 m/s, '
                      'rested 5 s and withdrew at 0.1 m/s; no timer sent one. Events: '
                      + ', '.join(f"{e['event']} -> {e['task'] or 'none'} at "
                                  f"{e['time_s']:.2f} s (separation {e['separation_m']:.3f} m)"
                                  for e in seq['events']) + '.',
                      f'Separation of hand and tool: at least {seq["separation_min_m"]:.3f} m. '
                      'ISO/TS 15066 protective separation distance S_p with ISO 13855\'s hand '
                      f'speed: {seq["protective_distance_m"][0]:.2f}-'
                      f'{seq["protective_distance_m"][1]:.2f} m (below it '
                      f'{100 * seq["below_protective_fraction"]:.0f} % of the time); with the '
                      f'measured speeds: {seq["protective_distance_measured_m"][0]:.2f}-'
                      f'{seq["protective_distance_measured_m"][1]:.2f} m (below it '
                      f'{100 * seq["below_measured_fraction"]:.0f} % of the time). T_s and B '
                      'are the arm\'s stop through a 1 s fade of a(E, t).',
                      f'a(E, t) stayed in [{seq["weight_min"]:.3f}, {seq["weight_max"]:.3f}]; '
                      f'largest change between two controlled cycles: '
                      f'{seq["largest_weight_step"]:.4f}; largest torque step between two '
                      f'consecutive control cycles: {seq["max_effort_step"]:.3f} N m. Final '
                      f'distance {seq["final"]["steady_distance"]:.3f} m.', '',
                      '![sequence](figures/sequence.png)']
        lines += self.separation_verdicts()
        if 'recorded_person' in self.metrics:
            person = self.metrics['recorded_person']
            rows = [f"| {task} | {person[task]['seconds']:.1f} | "
                    f"{_or_dash(person[task]['follow_median_distance'], '.3f', 'none judged')} | "
                    f"{100 * person[task]['close_fraction']:.1f} % | "
                    f"{person[task]['longest_high_effort_hold']:.2f} | "
                    f"{person[task]['largest_effort_step']:.3f} |"
                    for task in ('follow', 'avoid', 'follow_safe') if task in person]
            detected = ', '.join(f"{e['event']} -> {e['task'] or 'none'} at {e['t']:.1f} s"
                                 for e in person['events']) or 'none'
            lines += ['', '## A recorded person as the hand', '',
                      f"The right hand of a person tossing a can ({person['take']}, recorded "
                      'with a Vicon tracker at 100 Hz, data/human-motion), replayed on /target '
                      'at its recorded pace and placed so that most of its path lies within '
                      'the arm\'s reach; the learned follow at first, the tasks switched by the '
                      f'event_detector. Detected events: {detected}. /target jumps held as '
                      f"glitches: {person['target_glitches']}.",
                      '', '| task | time run (s) | median distance (m) | closer than d1 - 3 cm '
                      '| longest hold above 25 % of the effort limit (s) | largest command step '
                      '(N m) |', '|---|---|---|---|---|---|', *rows, '',
                      'Distances over the samples where the hand was within reach and slower '
                      'than the arm\'s task speed (max_task_speed), from '
                      f'{RECORDED_SETTLE:.0f} s after each task began; the median distance '
                      'is the figure of merit for follow, the share closer than d1 - 3 cm for '
                      'avoid.', *self.whole_body_lines(person), '',
                      '![recorded person](figures/recorded_person.png)']
        steps = {name: m['max_effort_step'] for name, m in self.metrics['behaviours'].items()}
        if 'sequence' in self.metrics:
            steps['sequence'] = self.metrics['sequence']['max_effort_step']
        lines += ['', '## Closing note: torque continuity', '',
                  'Largest change of the commanded torque between two consecutive 1 kHz '
                  'control cycles, after the first command: ' + ', '.join(
                      f'{name} {value:.3f} N m' for name, value in steps.items())
                  + ' (bar: 1 N m; measured on the topics, so a loaded machine adds to '
                  "them; the controller's max_effort_rate keeps each command within 1 N m of "
                  'the one before). The pure closed loop (test_closed_loop.py) gives at most '
                  "0.25 N m for Table I's rows and the learned rows at region entry, switches "
                  'and task-state timeouts, from the control law alone.']
        (self.out / 'report.md').write_text('\n'.join(lines) + '\n')
        (self.out / 'metrics.json').write_text(json.dumps(self.metrics, indent=2) + '\n')
        print(f'  wrote {self.out / "report.md"}, {self.out / "metrics.json"} and '
              f'{len(list(self.figures.glob("*.png")))} figures')


# -- the Panda's profile ----------------------------------------------------------------------
# The demo on the Panda in 3-D (scripts/demo.py --robot panda, and the short run after the
# SCARA's): the same stages on arm_sim robot:=panda, the hands and the tool in space.
#
# Stages: demonstrations pushed by the demonstrator robot:=panda (arm_sim in teach mode,
# gravity compensated) and recorded with the Panda's /robot_description; follow, avoid and
# follow_safe learned from the bags (the learner's forward kinematics from the bags' URDF: the
# bags have no /ee_position); the behaviours with 3-D scripted hands (hand_sim dimension 3) on
# the live Panda loop (arm_sim, event_manager, controller robot:=panda); the sequence with the
# events from the event_detector in 3-D (dimension 3); a recorded person's hand in 3-D. OUT/
# report.md, OUT/metrics.json and OUT/figures/ as the SCARA's, plus figures/paths_3d.png.
# The short run (after the SCARA's, to keep the whole demo within 4 minutes) records, learns
# and runs the sequence only (which begins under follow: the arm comes to the waiting hand).

# The Panda's tool starts at (0.307, 0, 0.487) m (its home pose). The demonstrations: follow
# towards the demonstrator's default Panda x_r, below and beside the tool; avoid from 6 mm of
# the tool. The person stops at distances of their own (learned d1, d2 come from them).
PANDA_DEMONSTRATIONS = {
    'follow': {'mode': 'follow', 'reference': [0.45, 0.15, 0.30], 'stop_distance': 0.055},
    'avoid': {'mode': 'avoid', 'reference': [0.31, 0.004, 0.49], 'safe_distance': 0.165},
}
# The person's pace (the demonstrator's test pace): the push starts 0.5 s after the recorder
# is up, at 0.2 m/s peak, and the person holds still 1 s after letting go.
PANDA_DEMONSTRATOR = {'robot': 'panda', 'start_delay': 0.5, 'hold_time': 1.0, 'damping': 80.0,
                      'peak_speed': 0.15}
# What a Panda's demonstration bag holds: its joint states and URDF, not the tool's position
# (a real Panda publishes none): the learner computes it with the URDF's forward kinematics.
PANDA_DEMONSTRATION_TOPICS = ['/joint_states', '/robot_description', '/demo/reference',
                              '/human/wrench']
# avoid's region is open outward: its d2 stands for "anywhere farther". The learner caps a1 of
# a region the arm can leave outward (d2 + 0.15 m within 2 x reach); the Panda's reach bound
# is 1.09 m, so the default 2 m would count as a region the arm leaves. 2.5 m > 2 x 1.09 m: no
# separation of a hand and the Panda's tool both within reach lies beyond it.
PANDA_WORKSPACE_RADIUS = 2.5  # m
# Scripted 3-D hands (hand_sim, dimension 3), as the SCARA's BEHAVIOURS in space.
PANDA_BEHAVIOURS = {
    # The hand waits 0.2 m from the tool, then moves off up and across, then down.
    'follow': {'profile': 'waypoints', 'dimension': 3, 'start_delay': 3.0, 'speed': 0.08,
               'waypoints': [0.40, 0.15, 0.40, 0.30, 0.30, 0.55, 0.45, 0.15, 0.35]},
    # The hand comes down at 0.5 m/s from 0.3 m above the tool to 6 cm above it, rests 3 s,
    # and leaves up and sideways: the tool backs away past d1, then returns to rest.
    'avoid': {'profile': 'waypoints', 'dimension': 3, 'start_delay': 1.0, 'speed': 0.25,
              'waypoints': [0.307, 0.0, 0.79, 0.307, 0.0, 0.55, 0.307, -0.30, 0.75],
              'segment_speeds': [0.5, 0.25], 'pauses': [3.0, 0.0]},
    # The hand starts 7 cm from the tool (inside d1), then walks off 0.25 m, down and across.
    'follow_safe': {'profile': 'waypoints', 'dimension': 3, 'start_delay': 2.0,
                    'speed': 0.1, 'waypoints': [0.37, 0.0, 0.52, 0.45, 0.20, 0.40]},
}
# The sequence's hand: it waits 0.32 m from the tool for 4.5 s (the arm comes to it under
# follow in about 4 s),
# reaches in towards the tool's start at 0.5 m/s (hand_reaches_in: avoid), rests 5 s
# (hand_rests: follow_safe) and withdraws at 0.1 m/s; the event_detector in 3-D.
PANDA_SEQUENCE_HAND = {'profile': 'waypoints', 'dimension': 3, 'start_delay': 4.5,
                       'speed': 0.1,
                       'waypoints': [0.40, -0.25, 0.35, 0.33, 0.0, 0.45, 0.55, -0.15, 0.35],
                       'segment_speeds': [0.5, 0.1], 'pauses': [5.0, 0.0]}
# Where auto_place puts the recorded person's horizontal path: round the Panda's base, within
# its horizontal reach at the take's heights (0.15-0.90 m, kept as recorded).
PANDA_HAND_REACH = ReachAnnulus(0.30, 0.75)
PANDA_SETTLE = 4.0  # s a full run goes on after its hand stops
READY_TIMEOUT = 20.0  # s: the Panda's model takes a second to load in each node


class PandaDemo(Demo):
    """The demo's stages on the Panda in 3-D; `short`: no behaviour runs of their own and no
    recorded person, the sequence only."""

    robot = 'panda'
    dimension = 3
    sim_node = 'arm_sim'
    demonstrations = PANDA_DEMONSTRATIONS
    learning = LEARNING
    behaviours = PANDA_BEHAVIOURS
    sequence_hand = PANDA_SEQUENCE_HAND
    settle_after_hand = PANDA_SETTLE

    def __init__(self, out, quick: bool, domain_id: int, short: bool = False):
        super().__init__(out, quick or short, domain_id)
        self.short = short
        self.metrics['robot'] = 'panda'
        self.metrics['short'] = short

    def stages(self) -> list[tuple[str, callable]]:
        """(label, stage) in order; the short run leaves out the behaviours' own runs and
        the recorded person."""
        stages = [('record demonstrations in 3-D', self.record_demonstrations),
                  ('learn tasks from the bags (their URDF)', self.learn)]
        if not self.short:
            stages.append(('run the behaviours closed-loop', self.run_behaviours))
        stages.append(('sequential task with events in 3-D', self.run_sequence))
        if not self.short:
            stages.append(('a recorded person in 3-D', self.run_recorded_person))
            stages.append(('recorded people in MuJoCo, the clearance off and on; the '
                           'engines compared',
                           self.run_mujoco_takes))
        stages.append(('write the report', self.write_report))
        return [(f'panda {i}/{len(stages)} {label}', stage)
                for i, (label, stage) in enumerate(stages, 1)]

    # -- hooks of Demo ------------------------------------------------------------------
    def start_teach_sim(self, domain: int) -> NodeProcess:
        return self.start('scara_sim', 'arm_sim', domain=domain, robot='panda',
                          teach_mode=True)

    def before_demonstrator(self, sim: NodeProcess, recorder: NodeProcess) -> None:
        """The Panda's sim and the recorder up first: the bag holds the push from its start
        and the /robot_description."""
        expected = {sim: READY_LINES['arm_sim'], recorder: READY_LINES['recorder']}
        if not wait_until_logged(expected, READY_TIMEOUT):
            late = ', '.join(f'{p.name} (log {p.log_path})' for p in not_logged(expected))
            raise StageError(f'not up in {READY_TIMEOUT:g} s: {late}')

    def demonstrator_parameters(self) -> dict:
        return PANDA_DEMONSTRATOR

    def recorder_parameters(self) -> dict:
        return {'topics': PANDA_DEMONSTRATION_TOPICS}

    def loop_overrides(self, initial_task: str, hand: dict, detector: bool) -> dict:
        """The SCARA's, with arm_sim and the controller on the Panda, the detector in 3-D."""
        overrides = super().loop_overrides(initial_task, hand, detector)
        overrides['arm_sim'] = {**overrides.pop('scara_sim'), 'robot': 'panda'}
        overrides['controller']['robot'] = 'panda'
        overrides['event_detector'] = {'dimension': 3}
        if hand.get('profile') == 'recording':  # effort_shares takes the joints from the bag
            recorder = overrides['recorder']
            overrides['recorder'] = {**recorder, 'topics': list(dict.fromkeys(
                [*recorder['topics'], *self.effort_topics]))}
        return overrides

    def hand_reach(self) -> ReachAnnulus:
        return PANDA_HAND_REACH

    def body_clearance(self) -> float:
        return BODY_CLEARANCE['panda']

    effort_topics = ['/joint_states']

    def effort_shares(self, contents: dict, times, commands):
        """The Panda's commands less its URDF's gravity torque at the nearest joint state,
        over each joint's limit (87 / 12 N m): holding itself up takes 23-29 N m on joints
        2 and 4, a quarter of their limit or more, which is no effort the task asks for."""
        model = robot_model('panda')
        states = contents['/joint_states'].messages
        state_t = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                            for m in states])
        nearest = np.clip(np.searchsorted(state_t, times), 0, len(states) - 1)
        gravity = np.array([model.gravity_torque(np.array(states[i].position))
                            for i in nearest])
        return (commands - gravity) / model.limits.effort

    def learn(self) -> None:
        """The three learners side by side, from the bags' URDF; each one's figure of the
        fit is figures/fit_<task>.png. (No Table I comparison: Table I is the SCARA's.)"""
        learners = self.start_learners(workspace_radius=PANDA_WORKSPACE_RADIUS)
        for name, learner in learners.items():
            record = self.learned(name, learner)
            shutil.copy(self.tasks / f'{name}.png', self.figures / f'fit_{name}.png')
            print(f'  {name}: S={record.s:+d} d1={record.d1:.3f} d2={record.d2:.3f} '
                  f'a1={record.a1:.4g} a2={record.a2:.4g} K={record.k:.4g} '
                  f'C={record.cost:.3g} iterations={record.iterations}')
            self.metrics['learning'][name] = asdict(record)

    # -- the report -------------------------------------------------------------------
    def paths_figure(self) -> None:
        """figures/paths_3d.png: the hand's and the tool's paths of every run, in 3-D."""
        runs = [*self.metrics['behaviours'], *(['sequence'] if 'sequence' in self.metrics
                                               else [])]
        figure = plt.figure(figsize=(max(4.2 * len(runs), 6.0), 4.4))
        for index, run in enumerate(runs, 1):
            axis = self.path_axis(figure, 1, len(runs), index)
            paths = read_bag(self.bags / f'run_{run}', topics=['/target', '/ee_position'])
            for topic, label, colour in (('/target', 'hand', 'tab:orange'),
                                         ('/ee_position', 'tool', 'tab:blue')):
                if topic in paths.topics and paths.topics[topic].messages:
                    xyz = self.points(paths.topics[topic].messages)
                    axis.plot(*xyz.T, color=colour, label=label)
                    axis.plot(*xyz[0], 'o', color=colour)
                    axis.plot(*xyz[-1], 's', color=colour)
            axis.set_title(run)
            equal_scales(axis)
            axis.legend(loc='upper left', fontsize='small')
        figure.suptitle('Panda: hand and tool paths in 3-D\n(o start, square end)')
        figure.tight_layout()
        figure.savefig(self.figures / 'paths_3d.png', dpi=100)
        plt.close(figure)

    def run_mujoco_takes(self) -> None:
        """MUJOCO_TAKES beside the Panda in MuJoCo, Table I's MUJOCO_TASKS, the whole-body
        clearance off and then on (hri_bringup.clearance_in_mujoco, in-process, two at a
        time): OUT/mujoco.md with the contacts, the parts touched, the peak force per Table
        A.2 region and its verdict, and figures/mujoco_contacts.png, the contact force over
        time of both runs; then the learned tasks on both engines (engine_lines)."""
        seconds = 5.0 if self.quick else 10.0
        jobs = [(take, task, clearance, seconds) for take in MUJOCO_TAKES
                for task in MUJOCO_TASKS for clearance in (False, True)]
        self.progress('MuJoCo runs', 0.0)
        with ProcessPoolExecutor(max_workers=2) as pool:
            runs = list(pool.map(mujoco_take, jobs))
        self.progress_done('MuJoCo runs')
        figure, axes = plt.subplots(len(MUJOCO_TAKES), len(MUJOCO_TASKS), sharex=True,
                                    figsize=(11, 6), squeeze=False)
        rows, metrics = [], []
        for run in runs:
            axis = axes[MUJOCO_TAKES.index(run.take)][MUJOCO_TASKS.index(run.task)]
            axis.plot(run.time, run.force, label=f'clearance {"on" if run.clearance else "off"}',
                      color='tab:green' if run.clearance else 'tab:red')
            axis.set_title(f'{run.take}, {run.task}', fontsize=9)
            axis.set_ylabel('contact force (N)')
            axis.legend(fontsize=8)
            regions = '; '.join(region_text(j) for j in run.judgements.values()) or 'none'
            parts = ', '.join(f'{part} {peak:.0f} N' for part, peak in
                              sorted(run.part_peaks.items())) or 'none'
            rows.append(f'| {run.take} | {run.task} | {"on" if run.clearance else "off"} | '
                        f'{run.contact_steps} | {parts} | {regions} | '
                        f'{run.least_distance:+.3f} | {run.tool_hand_median:.3f} | '
                        f'{"pass" if run.passed else "fail"} |')
            metrics.append({'take': run.take, 'task': run.task, 'clearance': run.clearance,
                            'contact_steps': run.contact_steps, 'part_peaks_n': run.part_peaks,
                            'least_distance_m': run.least_distance,
                            'trunk_touched': run.trunk_touched,
                            'tool_hand_median_m': run.tool_hand_median,
                            'peak_effort_nm': run.peak_effort, 'passed': run.passed})
        for axis in axes[-1]:
            axis.set_xlabel('time (s)')
        figure.tight_layout()
        figure.savefig(self.figures / 'mujoco_contacts.png', dpi=110)
        plt.close(figure)
        self.metrics['mujoco'] = metrics
        lines = ['# What the whole-body clearance buys, in MuJoCo', '',
                 f'The first {seconds:g} s of {" and ".join(MUJOCO_TAKES)} (Vicon, 100 Hz), '
                 'placed round the Panda as hand_sim\'s auto_place places them, in the pure '
                 'closed loop (the one law at 1 kHz) with MuJoCo as the engine: the URDF\'s '
                 'masses +-10 %, MuJoCo\'s own joint damping and armature, the person\'s '
                 'capsules in its scene as mocap bodies. Table I\'s tasks; the whole-body '
                 'clearance off (force 0), then on (0.10 m). Contacts are summed per body '
                 'part and step and judged against ISO/TS 15066 Table A.2 '
                 '(hri_core.contact_limits); "pass" needs every region within its limits and '
                 'no contact on the head or the torso. Least distance: robot to person '
                 'capsules every 10 ms (< 0: overlapping).', '',
                 '| take | task | clearance | steps with contact | peak force per part | '
                 'Table A.2 regions | least distance (m) | tool-hand median (m) | verdict |',
                 '|---|---|---|---|---|---|---|---|---|', *rows, '',
                 '![contact force](figures/mujoco_contacts.png)']
        (self.out / 'mujoco.md').write_text('\n'.join(lines + self.engine_lines()) + '\n')
        print(f'  wrote {self.out / "mujoco.md"}')

    def engine_lines(self) -> list[str]:
        """The learned tasks on the Panda on both engines (hri_bringup.engines_compared, a
        still hand): the report's section, and metrics['engines']."""
        jobs = [(scenario, engine, str(self.tasks)) for scenario in SCENARIOS
                for engine in ENGINES]
        self.progress('engines compared', 0.0)
        with ProcessPoolExecutor(max_workers=2) as pool:
            runs = {(run.scenario, run.engine): run for run in pool.map(engine_run, jobs)}
        self.progress_done('engines compared')
        rows, metrics = [], []
        for scenario in SCENARIOS:
            ours, theirs = runs[scenario, 'pinocchio'], runs[scenario, 'mujoco']
            for (task, a), (_, b) in zip(ours.segments, theirs.segments, strict=True):
                ratio = '—' if a is None or b is None or a == 0.0 else f'{b / a:.2f}'
                rows.append(f'| {scenario} | {task} | {_or_dash(a, ".2f")} | '
                            f'{_or_dash(b, ".2f")} | {ratio} |')
            for run in (ours, theirs):
                metrics.append({'scenario': scenario, 'engine': run.engine,
                                'segments': [list(seg) for seg in run.segments],
                                'final_distance_m': run.final_distance,
                                'theta_change': run.theta_change,
                                'largest_step_nm': run.largest_step,
                                'peak_effort_share': run.peak_effort_share})
        self.metrics['engines'] = metrics
        worst = max(m['largest_step_nm'] for m in metrics)
        least = min(m['theta_change'] for m in metrics)
        return ['', '## The same controller, the two engines', '',
                'The learned tasks (their K) on the Panda in the pure closed loop, a still hand '
                '(0.3 m from the tool for follow, follow_safe and the sequence, 5 cm above it '
                'for avoid; the sequence switches to avoid at 5 s and to follow_safe at 9 s), '
                'integrated by the project\'s engine (RK4 on pinocchio\'s dynamics, as '
                'arm_sim\'s default) and by MuJoCo (its own damping and armature). Time to '
                'region: from the task\'s switch to the time from which the tool stays in the '
                'task\'s region. Every run: the applied torque changed by at most '
                f'{worst:.3f} N m per 1 ms step; theta_hat moved by at least {100 * least:.2f} % '
                'of its start.', '',
                '| scenario | task | time to region, pinocchio (s) | time to region, MuJoCo '
                '(s) | MuJoCo / pinocchio |', '|---|---|---|---|---|', *rows]

    def behaviour_lines(self) -> list[str]:
        """The report's section on the behaviours' own runs."""
        lines = ['', '## Behaviours, closed loop on the simulated Panda', '',
                 *behaviour_table(self.metrics['behaviours'])]
        return lines + ['', 'Torque per joint (tau1-tau7), distance and the 3-D paths; steps '
                        'as in the SCARA\'s report (between consecutive 1 kHz commands).', '',
                        *[f'![{n}](figures/behaviour_{n}.png)'
                          for n in self.metrics['behaviours']]]

    def write_report(self) -> None:
        self.paths_figure()
        model = robot_model('panda')
        run = '`scripts/demo.sh --robot panda`' if not self.short else \
            '`scripts/demo.sh` (the short Panda run after the SCARA)'
        lines = ['# HRI control through demonstration on the Panda, in 3-D', '',
                 f'Run of {run} on {time.strftime("%Y-%m-%d %H:%M")}. The Panda (7 joints, '
                 f'franka_description URDF, reach bound {model.reach:.2f} m) in arm_sim at '
                 '1 kHz; hands, tool and distances in 3-D.' + (
                     ' Short run: the event sequence only, which begins under follow (the '
                     'whole demo stays within 4 minutes); `scripts/demo.sh --robot panda` '
                     'runs every stage.' if self.short else ''), '',
                 '## What was demonstrated', '']
        for name, demo in self.metrics.get('demonstrations', {}).items():
            stop = demo.get('stop_distance', demo.get('safe_distance'))
            lines.append(f'- `{name}`: the simulated person pushed the Panda\'s tool in 3-D '
                         f'({demo["mode"]}, x_r = {demo["reference"]} m) and let go {stop} m '
                         'from x_r; the bag holds /joint_states and /robot_description, no '
                         '/ee_position: the learner computed the tool\'s path with the '
                         'URDF\'s forward kinematics.')
        lines += ['- `follow_safe`: eq. 4 combines the two, follow shifted out by 0.23 m.', '',
                  '## What was learned', '',
                  f'avoid\'s open region: workspace_radius {PANDA_WORKSPACE_RADIUS} m '
                  f'(> 2 x the reach bound, {2 * model.reach:.2f} m), so a1 is not capped.', '',
                  '| task | S | d1 (m) | d2 (m) | K (m^2/s) | a1 | a2 | cost C | trf '
                  'evaluations |', '|---|---|---|---|---|---|---|---|---|']
        for name, m in self.metrics['learning'].items():
            lines.append(f'| {name} | {m["s"]:+d} | {m["d1"]:.3f} | {m["d2"]:.3f} | '
                         f'{m["k"]:.4g} | {m["a1"]:.4g} | {m["a2"]:.4g} | {m["cost"]:.3g} | '
                         f'{m["iterations"]} |')
        lines += ['', *[f'![fit {n}](figures/fit_{n}.png)' for n in self.metrics['learning']]]
        if self.metrics['behaviours']:
            lines += self.behaviour_lines()
        if 'sequence' in self.metrics:
            seq = self.metrics['sequence']
            lines += ['', '## Sequential task with events, in 3-D', '',
                      'The event_detector (dimension 3) sent every event from a 3-D hand that '
                      'reached in at 0.5 m/s, rested 5 s and withdrew at 0.1 m/s. Events: '
                      + (', '.join(f"{e['event']} -> {e['task'] or 'none'} at "
                                   f"{e['time_s']:.2f} s (separation {e['separation_m']:.3f} m)"
                                   for e in seq['events']) or 'none') + '.',
                      f'Tasks run: {", ".join(seq["tasks_seen"])}. a(E, t) in '
                      f'[{seq["weight_min"]:.3f}, {seq["weight_max"]:.3f}], largest change '
                      f'between controlled cycles {seq["largest_weight_step"]:.4f}; largest '
                      f'torque step {seq["max_effort_step"]:.3f} N m; closest separation '
                      f'{seq["separation_min_m"]:.3f} m; final distance '
                      f'{seq["final"]["steady_distance"]:.3f} m (in the region: '
                      f'{"yes" if seq["final"]["in_region_at_end"] else "no"}).', '',
                      '![sequence](figures/sequence.png)']
        if 'recorded_person' in self.metrics:
            person = self.metrics['recorded_person']
            detected = ', '.join(f"{e['event']} -> {e['task'] or 'none'} at {e['t']:.1f} s"
                                 for e in person['events']) or 'none'
            rows = [f"| {task} | {person[task]['seconds']:.1f} | "
                    f"{_or_dash(person[task]['follow_median_distance'], '.3f')} | "
                    f"{100 * person[task]['close_fraction']:.1f} % | "
                    f"{person[task]['longest_high_effort_hold']:.2f} | "
                    f"{person[task]['largest_effort_step']:.3f} |"
                    for task in ('follow', 'avoid', 'follow_safe') if task in person]
            lines += ['', '## A recorded person as the hand, in 3-D', '',
                      f"The right hand of {person['take']} (Vicon, 100 Hz) at its recorded "
                      'heights, placed round the Panda\'s base; the tasks switched by the '
                      f'event_detector in 3-D. Detected events: {detected}.', '',
                      '| task | time run (s) | median 3-D distance (m) | closer than d1 - 3 cm '
                      '| longest hold above 25 % of a joint\'s limit, gravity left out (s) '
                      '| largest command step (N m) |', '|---|---|---|---|---|---|', *rows,
                      *self.whole_body_lines(person), '',
                      '![recorded person](figures/recorded_person.png)']
        if 'mujoco' in self.metrics:
            runs = self.metrics['mujoco']
            failed = {on: sum(not m['passed'] for m in runs if m['clearance'] == on)
                      for on in (False, True)}
            each = {on: sum(m['clearance'] == on for m in runs) for on in (False, True)}
            lines += ['', '## Recorded people in MuJoCo, the clearance off and on', '',
                      f'Without the whole-body clearance {failed[False]} of {each[False]} '
                      'runs touched the head or torso or went past a Table A.2 limit; with '
                      f'it, {failed[True]} of {each[True]}: [mujoco.md](mujoco.md).']
        lines += ['', '## Paths in 3-D', '', '![paths](figures/paths_3d.png)']
        (self.out / 'report.md').write_text('\n'.join(lines) + '\n')
        (self.out / 'metrics.json').write_text(
            json.dumps(self.metrics, indent=2) + '\n')
        print(f'  wrote {self.out / "report.md"}, {self.out / "metrics.json"} and '
              f'{len(list(self.figures.glob("*.png")))} figures')


def main() -> int:
    highest = MAX_DOMAIN_ID - (len(DEMONSTRATIONS) - 1)
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog=f'ROS domain: HRI_DEMO_DOMAIN_ID=N (0 to {highest}; default 60 + PID % 40) runs '
        f'the demo on domains N to N + {len(DEMONSTRATIONS) - 1}. ROS_DOMAIN_ID is not used: '
        'the demo keeps to domains of its own so that nodes you run do not meet it; to watch '
        'it with `ros2 topic echo`, set ROS_DOMAIN_ID=N in that shell.')
    parser.add_argument('--quick', action='store_true', help='shorter closed-loop runs')
    parser.add_argument('--robot', choices=('scara', 'panda'),
                        help='one robot only: scara, or panda (every stage, in OUT/panda/); '
                        'default: the SCARA, then a short Panda run (--quick: the SCARA only)')
    parser.add_argument('--out', type=Path, default=REPO_ROOT / 'report',
                        help='output folder (default: report/)')
    args = parser.parse_args()
    domain_text = os.environ.get('HRI_DEMO_DOMAIN_ID', str(60 + os.getpid() % 40))
    # The demonstrations run side by side on this domain and the ones after it.
    if not (domain_text.isdigit() and int(domain_text) <= highest):
        print(f'[demo] HRI_DEMO_DOMAIN_ID must be an integer from 0 to {highest}, got '
              f'{domain_text!r}', file=sys.stderr)
        return 2
    domain = int(domain_text)
    ignored = (f'; ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]} is not used'
               if os.environ.get('ROS_DOMAIN_ID') and 'HRI_DEMO_DOMAIN_ID' not in os.environ
               else '')
    print(f'[demo] ROS domain {domain} (HRI_DEMO_DOMAIN_ID{ignored})', flush=True)
    out = args.out.resolve()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    robots = [args.robot] if args.robot else ['scara'] if args.quick else ['scara', 'panda']
    runs = []
    if 'scara' in robots:
        demo = Demo(out, args.quick, domain)
        runs.append((demo, [
            ('1/6 record demonstrations', demo.record_demonstrations),
            ('2/6 learn tasks from the bags', demo.learn),
            ('3/6 run the behaviours closed-loop', demo.run_behaviours),
            ('4/6 sequential task with events', demo.run_sequence),
            ('5/6 a recorded person, tasks switched by the event_detector',
             demo.run_recorded_person),
            ('6/6 write the report', demo.write_report),
        ]))
    if 'panda' in robots:
        panda = PandaDemo(out / 'panda', args.quick, domain, short=args.robot is None)
        runs.append((panda, panda.stages()))
    for demo, _ in runs:
        for sub in ('logs', 'bags', 'tasks', 'figures'):
            (demo.out / sub).mkdir(parents=True, exist_ok=True)
    # SIGTERM ends the run like Ctrl-C: processes stopped, non-zero exit.
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    started = time.monotonic()
    current = ''
    try:
        for demo, stages in runs:
            robot_started = time.monotonic()
            for current, stage in stages:
                print(f'[demo] stage {current} ({time.monotonic() - started:.0f} s elapsed)',
                      flush=True)
                stage()
            print(f'[demo] {demo.robot}: {time.monotonic() - robot_started:.0f} s',
                  flush=True)
    except (StageError, ValueError) as error:
        print(f'\n[demo] FAILED in stage {current}: {error}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'\n[demo] interrupted in stage {current}', file=sys.stderr)
        return 130
    finally:
        for demo, _ in runs:
            demo.stop_all()
    if robots == ['scara', 'panda']:
        with (out / 'report.md').open('a') as report:
            report.write('\n## The Panda in 3-D\n\nA short Panda run (the event sequence '
                         'in 3-D, from follow): [panda/report.md](panda/report.md); '
                         '`scripts/demo.sh --robot panda` runs every stage on it.\n')
    print(f'[demo] done in {time.monotonic() - started:.0f} s: '
          + ', '.join(str(demo.out / 'report.md') for demo, _ in runs))
    return 0


if __name__ == '__main__':
    sys.exit(main())
