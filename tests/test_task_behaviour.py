"""Topic-level: the learned potential drives the arm (K grad P, avoid, continuity, modes).

Each test runs the live loop (scara_sim, event_manager, controller, hand_sim) on its own
domain, scripts the hand through hand_sim's waypoints and reads the arm from /ee_position,
the torque the sim applied from /joint_states (every 1 ms step), the controller's commands
and the distance from /hri/controller_state; the 1 kHz topics are kept raw and decoded after
the run, so the probe takes little of the machine from the loop. One loop serves several
checks: follow reaches a still hand, tracks it when it moves (Fig. 4), then switches to
avoid. Thresholds are the issue's: effort changes <= 1 N m per 1 ms control cycle; under
avoid, the arm ends at >= d1 - 2 cm within 2 s of a hand that reached in at 0.5 m/s
stopping (backing away as the hand comes), stays within 5 cm of its rest position while the
hand walks 0.2 m away, and is back within 1 cm of it 3 s after the hand has gone; a1, a2 x 4
change the time to region by >= 15 %. The follow_safe band on topics: tests/test_demo.py
(each learned behaviour ends in its region); bad joint states: tests/test_bad_input.py.
"""

import math
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import ControllerState, TaskEvent, TaskState
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_bringup.processes import LIVE_LOOP, paper_tasks_dir, wait_for
from hri_core import topics
from hri_core.node_common import load_defaults
from hri_core.potential import TaskShape, default_task_gain
from tests.common import wait_for_service
from tests.fault_tools import RawListener, SentCommands, effort_change_per_step

pytestmark = [pytest.mark.integration, pytest.mark.exclusive]  # the 1 kHz loop

ARM = np.array([0.35, 0.30])  # m, scara_sim's initial end-effector position
D1_AVOID = 0.183  # m, Table I's avoid row
D2_FOLLOW = 0.041  # m, Table I's follow row
# N m per 1 ms control cycle; the controller's rate limit holds its commands to exactly this,
# and their difference may round above it by an ulp.
MAX_EFFORT_STEP = 1.0 + 1e-9
RAMP = 0.3  # s, event_manager ramp_time
REACH_IN_SPEED = 0.5  # m/s
CONTROLLER = load_defaults('hri_adaptive_controller', 'controller')
EFFORT_LIMIT = load_defaults('scara_sim', 'scara_sim')['effort_limit']  # N m
# Largest change of a between two ControllerStates: per second, eq. 13's ramp (15/8 per
# ramp_time) plus the controller's blend of a TaskState that comes after a gap (at most
# 15/8 per task_fade_time: signal_hold); and once, what the first-order hold between
# TaskStates may be off by when it runs out, 1/2 max|a''| (50 ms)^2, max|a''| = 5.77 /
# ramp_time^2 (the old hold jumped by up to 0.9 here).
WEIGHT_RATE = 15.0 / 8.0 * (1.0 / RAMP + 1.0 / CONTROLLER['task_fade_time'])
WEIGHT_HOLD_ERROR = 0.5 * 5.77 / RAMP ** 2 * 0.05 ** 2


def stamp(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


class Streams:
    """What the probe hears: commands, end-effector, hand, controller state, task state."""

    def __init__(self, probe):
        self.joints = RawListener(probe, topics.JOINT_STATES.name, JointState)
        self.commands = RawListener(probe, topics.EFFORT_COMMANDS.name, Float64MultiArray)
        self.raw_ee = RawListener(probe, topics.EE_POSITION.name, PointStamped,
                                  topics.EE_POSITION.qos)
        self.ee = []  # decoded by arm()
        self.hand = probe.collect(topics.TARGET.name, PointStamped, topics.TARGET.qos)
        self.states = probe.collect(topics.CONTROLLER_STATE.name, ControllerState,
                                    topics.CONTROLLER_STATE.qos)
        self.tasks = probe.collect(topics.TASK_STATE.name, TaskState, topics.TASK_STATE.qos)

    def arm(self, start=-math.inf, end=math.inf) -> tuple[np.ndarray, np.ndarray]:
        """Times (N,) s and end-effector positions (N, 2) m stamped in [start, end]."""
        arrivals = list(self.raw_ee.arrivals)
        self.ee += [deserialize_message(data, PointStamped)  # only the new ones
                    for _, data, _ in arrivals[len(self.ee):]]
        rows = np.array([(stamp(m), m.point.x, m.point.y) for m in self.ee]).reshape(-1, 3)
        rows = rows[(rows[:, 0] >= start) & (rows[:, 0] <= end)]
        return rows[:, 0], rows[:, 1:]

    def hand_path(self) -> tuple[np.ndarray, np.ndarray]:
        rows = np.array([(stamp(m), m.point.x, m.point.y) for m in list(self.hand)])
        return rows[:, 0], rows[:, 1:]

    def distance(self, start=-math.inf, end=math.inf) -> tuple[np.ndarray, np.ndarray]:
        rows = np.array([(stamp(m), m.distance) for m in list(self.states)
                         if m.status == 'ok' and start <= stamp(m) <= end]).reshape(-1, 2)
        return rows[:, 0], rows[:, 1]

    def effort_steps(self, since: float = -math.inf, start: float = -math.inf,
                     end: float = math.inf) -> float:
        """Largest change (N m) of the torque the sim applied per control cycle on its clock,
        from the joint states that arrived after `since` (monotonic s): a command the
        controller sends late on a loaded machine carries several cycles' change, which is
        the scheduler's, not the control law's; a drive that took in the commands late
        and skipped some did not see the cycles between (tests.fault_tools.
        effort_change_per_step). start, end: the states' stamps (s) to keep."""
        states = [m for _, m in self.joints.timed(since) if start <= stamp(m) <= end]
        assert len(states) >= 100, len(states)
        return effort_change_per_step(states, commands=SentCommands(self.commands))

    def assert_commands_safe(self) -> None:
        """Every ControllerState finite, its torque within the limit."""
        states = list(self.states)
        efforts = np.array([list(s.effort) for s in states if len(s.effort) == 2])
        assert np.all(np.isfinite(efforts)) and np.max(np.abs(efforts)) <= EFFORT_LIMIT + 1e-9
        assert all(math.isfinite(s.distance) and math.isfinite(s.lyapunov) for s in states)

    def latest(self) -> float:
        """The newest end-effector stamp (s)."""
        return stamp(deserialize_message(self.raw_ee.arrivals[-1][1], PointStamped))


def hand_stops(times, points, after=-math.inf) -> list[tuple[float, float]]:
    """(start, end) stamps of the hand's moves after `after` s (speed above 1 mm/s). A still
    spell shorter than 0.3 s does not split a move (the scripts pause for 0.5 s or more; a
    hand_sim that is late on a loaded machine does not), and a "move" of less than 1 cm is
    none."""
    speed = np.linalg.norm(np.diff(points, axis=0), axis=1) / np.maximum(np.diff(times), 1e-6)
    moving = np.concatenate([[False], speed > 1e-3, [False]])
    edges = np.flatnonzero(np.diff(moving.astype(int)))
    moves = [[a, min(b, len(times) - 1)] for a, b in zip(edges[::2], edges[1::2], strict=True)]
    merged = []
    for move in moves:
        if merged and times[move[0]] - times[merged[-1][1]] < 0.3:
            merged[-1][1] = move[1]
        else:
            merged.append(move)
    return [(times[a], times[b]) for a, b in merged
            if times[a] >= after and np.linalg.norm(points[b] - points[a]) >= 0.01]


# Under slow: the default run has avoid on the live loop in two recorded takes, the Panda's
# reach-in along z and the demo, and this script in the pure loop (test_closed_loop).
@pytest.mark.slow
def test_avoid_backs_away_returns_to_rest_and_never_copies_the_hand(live_loop, probe):
    streams = Streams(probe)
    # Outside d1, the hand walks 0.2 m away at 0.1 m/s; then it reaches in at 0.5 m/s to
    # 8 cm of the arm's rest position, stays 2.5 s and leaves.
    points = [ARM + [0.0, -0.22], ARM + [0.0, -0.42], ARM + [0.0, -0.08], ARM + [0.0, -0.45]]
    loop = live_loop({
        'event_manager': {'initial_task': 'avoid', 'ramp_time': RAMP},
        'hand_sim': {'profile': 'waypoints', 'start_delay': 1.0,
                     'waypoints': np.concatenate(points).tolist(),
                     'segment_speeds': [0.1, REACH_IN_SPEED, 0.3], 'pauses': [0.5, 2.5, 0.0]},
    }, ready_timeout=30.0)
    assert wait_for(lambda: len(streams.hand) > 10, 20.0), loop['hand_sim'].log()
    # The whole script (1 + 3.75 + 0.5 + 1.28 + 2.5 + 2.31 s) and 3.2 s after the hand is gone.
    begin = stamp(streams.hand[0])
    assert wait_for(lambda: streams.raw_ee.arrivals and streams.latest() > begin + 14.6,
                    40.0), loop['controller'].log()
    times, hand = streams.hand_path()
    walk, reach, leave = hand_stops(times, hand)[:3]
    _, rest_positions = streams.arm(begin, walk[0])
    rest = rest_positions[-1]
    assert np.linalg.norm(rest - ARM) < 0.01
    # The hand walks away: the arm stays (it does not copy the hand's velocity).
    _, arm = streams.arm(walk[0], reach[0])
    assert np.max(np.linalg.norm(arm - rest, axis=1)) <= 0.05
    # The hand reached in to the arm's edge (the arm backs away as fast as the hand comes:
    # task_variable.retreat_term; before, the hand got 5 cm inside d1); within 2 s of it
    # stopping the arm is at >= d1 - 2 cm.
    _, near = streams.distance(reach[0], leave[0])
    assert np.min(near) < D1_AVOID + 0.03
    _, settled = streams.distance(reach[1] + 2.0, leave[0])
    assert settled.size and np.min(settled) >= D1_AVOID - 0.02
    _, pushed = streams.arm(reach[0], leave[0])
    assert np.max(np.linalg.norm(pushed - rest, axis=1)) > 0.05  # the potential pushed it
    # 3 s after the hand has gone, the arm is back within 1 cm of its rest position.
    _, back = streams.arm(leave[1] + 3.0)
    steps = streams.effort_steps()
    reach_steps = streams.effort_steps(start=reach[0], end=leave[0])
    print(f'avoid: arm within {np.max(np.linalg.norm(arm - rest, axis=1)):.3f} m of rest while '
          f'the hand walked off; closest {np.min(near):.3f} m; from 2 s after the stop '
          f'>= {np.min(settled):.3f} m; pushed {np.max(np.linalg.norm(pushed - rest, axis=1)):.3f}'
          f' m; 3 s after the hand left within {np.max(np.linalg.norm(back - rest, axis=1)):.4f}'
          f' m of rest; largest effort step {steps:.3f} N m per cycle over the run (start '
          f'included), {reach_steps:.3f} from the reach-in to the hand leaving')
    assert back.size and np.max(np.linalg.norm(back - rest, axis=1)) <= 0.01
    assert steps <= MAX_EFFORT_STEP
    streams.assert_commands_safe()


def follow_x4_task(folder: Path) -> Path:
    """Table I's tasks plus `follow_x4`: Table I's follow row with a1, a2 x 4 and the same K
    (the follow row's default gain, written out)."""
    for name in ('follow', 'avoid'):
        (folder / f'{name}.yaml').write_text((paper_tasks_dir() / f'{name}.yaml').read_text())
    record = yaml.safe_load((paper_tasks_dir() / 'follow.yaml').read_text())
    shape = TaskShape(record['s'], record['a1'], record['a2'], record['d1'], record['d2'])
    k = math.exp(default_task_gain(shape, 0.25, 0.65))
    (folder / 'follow.yaml').write_text(yaml.safe_dump({**record, 'k': k}))
    (folder / 'follow_x4.yaml').write_text(yaml.safe_dump({
        **record, 'name': 'follow_x4', 'a1': 4 * record['a1'], 'a2': 4 * record['a2'],
        'k': k}))
    return folder


def time_to_region(streams, since: float) -> tuple[float, float]:
    """(s from the arm's first move after `since` to the region d <= d2, distance before the
    move in m), from the controller's distance to the hand: the first move is the first
    state 2 mm closer than the first one."""
    stamps, distance = streams.distance(since)
    first = int(np.argmax(distance <= distance[0] - 0.002))
    inside = np.flatnonzero(distance <= D2_FOLLOW)
    assert first > 0 and inside.size
    return float(stamps[inside[0]] - stamps[first]), float(distance[0])


def start_loop_then_hand(live_loop, streams, overrides: dict) -> dict:
    """The live loop with `overrides`, hand_sim started last: the probe (`streams`) hears the
    controller before the hand appears, so the arm moves once the hand is there and the
    distance it starts from is read off the first ControllerStates (a probe that matched
    late on a loaded machine once saw the first at 0.23 m). Returns the loop's processes,
    once the controller reports ok."""
    loop = live_loop(overrides, nodes=[name for name in LIVE_LOOP if name != 'hand_sim'],
                     ready_timeout=30.0)
    assert wait_for(lambda: streams.states, 20.0), loop['controller'].log()
    loop.update(live_loop(overrides, nodes=['hand_sim']))
    assert wait_for(lambda: streams.states and streams.states[-1].status == 'ok', 20.0), \
        loop['controller'].log()
    return loop


def follow_from_a_quarter_metre(live_loop, streams, tasks_dir, task, mode='effort'):
    """Start the loop with `task` fading in and the hand still 0.25 m from the arm; return
    (loop, (time from the arm's first move to the region, distance then)) once it is
    inside."""
    overrides = {
        'event_manager': {'tasks_dir': str(tasks_dir), 'initial_task': task, 'ramp_time': RAMP},
        'controller': {'mode': mode},
        'hand_sim': {'profile': 'hold', 'start': (ARM + [0.0, -0.25]).tolist()},
    }
    loop = start_loop_then_hand(live_loop, streams, overrides)
    start = stamp(streams.states[0])
    assert wait_for(lambda: streams.states[-1].distance <= D2_FOLLOW - 0.005, 10.0), \
        loop['controller'].log()
    return loop, time_to_region(streams, start)


def settled_in(states: list, low: float, high: float, seconds: float = 1.0) -> bool:
    """The last `seconds` of ControllerStates (100 Hz) lie within [low, high] +- 5 mm."""
    recent = [s for s in states[-int(100 * seconds):] if s.status == 'ok']
    return len(recent) >= 50 and all(low - 0.005 <= s.distance <= high + 0.005 for s in recent)


def test_follow_reaches_and_tracks_the_hand_a1_a2_act_and_the_switch_to_avoid_is_smooth(
        live_loop, probe, tmp_path):
    tasks = follow_x4_task(tmp_path)
    streams = Streams(probe)
    events = probe.publisher(topics.EVENTS.name, TaskEvent, 10)
    loop, (follow_time, follow_from) = follow_from_a_quarter_metre(live_loop, streams, tasks,
                                                                   'follow')
    # Fig. 4: once the arm is in its region, the hand walks 0.15 m at up to 0.1 m/s (hand_sim's
    # profile changed at run time, from where the hand is); the arm follows and settles in
    # the region again, where the task force, and so the torque, goes to ~0.
    hand = probe.node.create_client(SetParametersAtomically, '/hand_sim/set_parameters_atomically')
    assert wait_for_service(hand, 10.0)
    walk = {'waypoints': [*(ARM + [0.0, -0.25]), *(ARM + [0.12, -0.34])], 'speed': 0.1,
            'start_delay': 0.2, 'profile': 'waypoints'}
    future = hand.call_async(SetParametersAtomically.Request(parameters=[
        Parameter(name, value=value).to_parameter_msg() for name, value in walk.items()]))
    assert wait_for(future.done, 10.0) and future.result().result.successful, future.result()
    assert wait_for(lambda: len(hand_stops(*streams.hand_path())) == 1
                    and streams.hand_path()[0][-1] > hand_stops(*streams.hand_path())[0][1] + 1.5
                    and settled_in(streams.states, 0.0, D2_FOLLOW), 15.0), streams.states[-1]
    (moved_from, moved_to), = hand_stops(*streams.hand_path())
    _, tracking = streams.distance(moved_from, math.inf)
    assert np.max(tracking) < 0.15  # followed, not left behind
    torque_at_rest = max(abs(e) for s in streams.states[-50:] for e in s.effort)
    assert torque_at_rest < 0.5
    # follow -> avoid (Table I's rows): the arm leaves through d1 at speed, no effort step.
    assert wait_for(lambda: events.get_subscription_count() > 0, 10.0)
    switch, switch_from = time.monotonic(), len(streams.states)
    events.publish(TaskEvent(name='hand_too_close', task='avoid'))
    assert wait_for(lambda: streams.states[-1].task == 'avoid'
                    and streams.states[-1].distance >= D1_AVOID - 0.02, 6.0), \
        loop['controller'].log()
    wait_for(lambda: False, 0.5)
    switch_step = streams.effort_steps(switch)
    # a(E, t) goes through eq. 13's ramps (out, swap, in) without a jump.
    controlled = [s for s in streams.states[switch_from:] if s.status == 'ok']
    weights = np.array([s.weight for s in controlled])
    # The joint states' stamps a was evaluated at (the state's own stamp is its publish time).
    stamps = np.array([stamp(s) - s.input_age for s in controlled])
    assert weights.min() < 0.05 and weights.max() > 0.95
    weight_steps = np.abs(np.diff(weights)) - WEIGHT_RATE * np.diff(stamps)
    streams.assert_commands_safe()
    for process in loop.values():
        process.stop()
    # The same K, a1 and a2 x 4, in a loop of its own.
    streams = Streams(probe)
    _, (steeper_time, steeper_from) = follow_from_a_quarter_metre(live_loop, streams, tasks,
                                                                  'follow_x4')
    print(f'follow: tracked the walking hand within {np.max(tracking):.3f} m, torque '
          f'{torque_at_rest:.3f} N m at rest; follow -> avoid: largest effort step '
          f'{switch_step:.3f} N m per cycle, a beyond its ramp by at most '
          f'{np.max(weight_steps):.3f}; time to region from {follow_from:.3f} m: follow '
          f'{follow_time:.3f} s, follow_x4 {steeper_time:.3f} s (from {steeper_from:.3f} m)')
    assert switch_step <= MAX_EFFORT_STEP
    assert np.all(weight_steps <= WEIGHT_HOLD_ERROR), np.round(np.sort(weight_steps)[-5:], 3)
    assert follow_from == pytest.approx(0.25, abs=0.02)
    assert steeper_from == pytest.approx(0.25, abs=0.02)
    assert abs(follow_time - steeper_time) >= 0.15 * max(follow_time, steeper_time), \
        (follow_time, steeper_time)


def test_velocity_mode_follows_and_avoids(live_loop, probe, tmp_path):
    streams = Streams(probe)
    events = probe.publisher(topics.EVENTS.name, TaskEvent, 10)
    loop, _ = follow_from_a_quarter_metre(live_loop, streams, paper_tasks_dir(), 'follow',
                                          mode='velocity')
    assert wait_for(lambda: events.get_subscription_count() > 0, 10.0)
    events.publish(TaskEvent(name='hand_too_close', task='avoid'))
    assert wait_for(lambda: streams.states[-1].task == 'avoid'
                    and streams.states[-1].distance >= D1_AVOID - 0.02, 6.0), \
        loop['controller'].log()
