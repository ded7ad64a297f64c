"""The demo on the Panda in 3-D (scripts/demo.py --robot panda, and the short run after the
SCARA's): the same stages on arm_sim robot:=panda, the hands and the tool in space.

Stages: demonstrations pushed by the demonstrator robot:=panda (arm_sim in teach mode,
gravity compensated) and recorded with the Panda's /robot_description; follow, avoid and
follow_safe learned from the bags (the learner's forward kinematics from the bags' URDF: the
bags have no /ee_position); the behaviours with 3-D scripted hands (hand_sim dimension 3) on
the live Panda loop (arm_sim, event_manager, controller robot:=panda); the sequence with the
events from the event_detector in 3-D (dimension 3); a recorded person's hand in 3-D. OUT/
report.md, OUT/metrics.json and OUT/figures/ as the SCARA's, plus figures/paths_3d.png.
The short run (after the SCARA's, to keep the whole demo within 4 minutes) records, learns
and runs the sequence only (which begins under follow: the arm comes to the waiting hand).
"""

import json
import shutil
import time
from dataclasses import asdict

import matplotlib.pyplot as plt
import numpy as np
from demo import (
    LEARNING,
    Demo,
    StageError,
    _or_dash,
    behaviour_table,
    equal_scales,
)

from hri_bringup.processes import READY_LINES, NodeProcess, not_logged, wait_until_logged
from hri_core.recorded_motion import BODY_CLEARANCE, ReachAnnulus
from hri_core.robot_model import robot_model
from hri_demo_learning.bag_io import read_bag

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
            overrides['recorder'] = {**recorder,
                                     'topics': [*recorder['topics'], *self.effort_topics]}
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
                      '| largest command step (N m) |', '|---|---|---|---|---|---|', *rows, '',
                      '![recorded person](figures/recorded_person.png)']
        lines += ['', '## Paths in 3-D', '', '![paths](figures/paths_3d.png)']
        (self.out / 'report.md').write_text('\n'.join(lines) + '\n')
        (self.out / 'metrics.json').write_text(
            json.dumps(self.metrics, indent=2) + '\n')
        print(f'  wrote {self.out / "report.md"}, {self.out / "metrics.json"} and '
              f'{len(list(self.figures.glob("*.png")))} figures')

