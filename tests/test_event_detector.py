"""Topic-level tests of the event_detector: events from a scripted hand and tool, and the
separation it publishes.

The detector runs alone (with the event_manager where the task switch itself is checked);
the test publishes /target at 100 Hz and /ee_position at 250 Hz from a thread of its own,
stamped with the system clock as hand_sim and scara_sim stamp theirs. No 1 kHz loop runs:
the thresholds are the issue's: a hand reaching in at 0.5 m/s switches to avoid before the
separation falls below avoid's d1; a hand resting on a zone boundary with +-5 mm of noise
fires nothing for 3 s (test_event_rules holds the rules to 10 s of every kind of noise); a
lost hand fires its event once; /hri/separation agrees with the ISO/TS 15066 formula on its
own published speeds within 1 mm.
"""

import math
import threading
import time

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import SeparationState, TaskEvent, TaskParameters, TaskState

from hri_adaptive_controller.closed_loop import path_target
from hri_bringup.processes import paper_tasks_dir, wait_for
from hri_core import topics
from hri_core.node_common import load_defaults, stamp_seconds
from hri_core.task_file import load_task_file
from hri_core.velocity_estimator import VelocityEstimator

pytestmark = pytest.mark.integration

DEFAULTS = load_defaults('hri_adaptive_controller', 'event_detector')
TOOL = np.array([0.35, 0.30])  # m, where scara_sim's end-effector starts
HAND_RATE, TOOL_RATE = 100.0, 250.0  # Hz
READY = 'rule(s):'  # the detector's start line


class Script:
    """Publishes the hand (`hand(t)` -> (2,) or (3,) m, or None: no message) and the tool
    (`tool(t)`) from t = 0 for `duration` s in a thread; `hand_sent` and `tool_sent` hold each
    message's stamp (s) and position."""

    def __init__(self, probe, hand, tool, duration: float, hand_frame=lambda t: 'base'):
        self._hand_pub = probe.publisher(topics.TARGET.name, PointStamped, topics.TARGET.qos)
        self._tool_pub = probe.publisher(topics.EE_POSITION.name, PointStamped,
                                         topics.EE_POSITION.qos)
        self._probe, self._hand, self._tool, self._duration = probe, hand, tool, duration
        self._hand_frame = hand_frame
        self.hand_sent: list[tuple[float, np.ndarray]] = []
        self.tool_sent: list[tuple[float, np.ndarray]] = []
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> 'Script':
        assert wait_for(lambda: self._hand_pub.get_subscription_count() > 0
                        and self._tool_pub.get_subscription_count() > 0, 15.0)
        self._thread.start()
        return self

    def join(self) -> None:
        self._thread.join(self._duration + 10.0)
        assert not self._thread.is_alive()

    def _publish(self, publisher, path, start: float,
                 frame=lambda t: 'base') -> tuple[float, np.ndarray | None]:
        """Publish where `path` is now, stamped now: the stamp is the time the position is
        taken at (a position of one instant stamped a few ms later reads as a velocity
        spike when the thread catches up after a stall)."""
        now = self._probe.now()
        stamp = stamp_seconds(now)
        point = path(stamp - start)
        if point is not None:
            msg = PointStamped()
            msg.header.stamp = now
            msg.header.frame_id = frame(stamp - start)
            msg.point.x, msg.point.y = float(point[0]), float(point[1])
            msg.point.z = float(point[2]) if len(point) > 2 else 0.0
            publisher.publish(msg)
        return stamp, point

    def _run(self) -> None:
        start = stamp_seconds(self._probe.now())
        next_hand = next_tool = 0.0
        while (t := stamp_seconds(self._probe.now()) - start) < self._duration:
            if t >= next_tool:
                stamp, point = self._publish(self._tool_pub, self._tool, start)
                if point is not None:
                    self.tool_sent.append((stamp, np.asarray(point, dtype=float)))
                next_tool += 1.0 / TOOL_RATE
            if t >= next_hand:
                stamp, point = self._publish(self._hand_pub, self._hand, start,
                                             self._hand_frame)
                if point is not None:
                    self.hand_sent.append((stamp, np.asarray(point, dtype=float)))
                next_hand += 1.0 / HAND_RATE
            time.sleep(max(0.0, min(next_hand, next_tool) - t))


def params_file(tmp_path, rules: str | None = None, **params) -> str:
    """A parameters file for the detector: `rules` (YAML text, default: the default set) and
    other parameters."""
    values = {**params, **({'rules': rules} if rules is not None else {})}
    path = tmp_path / 'event_detector.yaml'
    path.write_text(yaml.safe_dump({'event_detector': {'ros__parameters': values}}))
    return str(path)


def start_detector(nodes, tmp_path, rules: str | None = None, **params):
    process = nodes('hri_adaptive_controller', 'event_detector',
                    params_files=[params_file(tmp_path, rules, **params)])
    assert process.wait_for_line(READY, 20.0), process.log()
    return process


def task_state(probe, name: str):
    """Publish a TaskState with `name` active (as the event_manager would, transient-local)."""
    publisher = probe.publisher(topics.TASK_STATE.name, TaskState, topics.TASK_STATE.qos)
    publisher.publish(TaskState(task=TaskParameters(name=name), weight=1.0,
                                phase=TaskState.PHASE_ACTIVE))
    return publisher


def formula(msg: SeparationState) -> float:
    """S_p of ISO/TS 15066 from the message's own speeds and the detector's defaults."""
    return (msg.human_speed_used * (DEFAULTS['reaction_time'] + DEFAULTS['stopping_time'])
            + max(msg.robot_speed, 0.0) * DEFAULTS['reaction_time']
            + DEFAULTS['stopping_distance'] + DEFAULTS['intrusion_distance']
            + DEFAULTS['human_uncertainty'] + DEFAULTS['robot_uncertainty'])


def crossing_time(sent: list[tuple[float, np.ndarray]], distance: float) -> float:
    """The stamp (s) of the first hand message nearer the tool than `distance` m."""
    return next(stamp for stamp, point in sent if np.linalg.norm(point - TOOL) < distance)


def test_a_hand_reaching_in_at_half_a_metre_a_second_switches_to_avoid_before_d1(
        nodes, probe, tmp_path):
    d1 = load_task_file(paper_tasks_dir() / 'avoid.yaml').d1
    events = probe.collect(topics.EVENTS.name, TaskEvent, topics.EVENTS.qos)
    states = probe.collect(topics.TASK_STATE.name, TaskState, topics.TASK_STATE.qos)
    separation = probe.collect(topics.SEPARATION.name, SeparationState, topics.SEPARATION.qos)
    manager = nodes('hri_adaptive_controller', 'event_manager',
                    params={'tasks_dir': str(paper_tasks_dir()), 'initial_task': 'follow'})
    detector = start_detector(nodes, tmp_path)
    assert wait_for(lambda: states and states[-1].phase == 'active', 20.0), manager.log()
    # The hand waits 0.5 m from the tool for 1 s, then reaches in to 5 cm of it, 0.5 m/s at
    # its peak (a minimum-jerk move), and stays.
    hand = path_target(TOOL + [0.0, -0.5], [(1.0, TOOL + [0.0, -0.05], 0.5)])
    script = Script(probe, lambda t: hand(t)[0], lambda t: TOOL, 4.0).start()
    script.join()
    assert wait_for(lambda: any(s.task.name == 'avoid' and s.phase == 'active'
                                for s in states), 5.0), detector.log()
    # (The hand's messages end with the script: hand_lost may follow 1 s later.)
    assert [(e.name, e.task) for e in events if e.name != 'hand_lost'] == \
        [('hand_reaches_in', 'avoid')], detector.log()
    below_d1 = crossing_time(script.hand_sent, d1)
    event_time = stamp_seconds(events[0].header.stamp)
    switch = next(stamp_seconds(s.header.stamp) for s in states if s.pending_task == 'avoid')
    print(f'reach-in: event {below_d1 - event_time:.3f} s and switch {below_d1 - switch:.3f} s '
          f'before the hand came within d1 = {d1} m')
    assert event_time < below_d1 and switch < below_d1
    # The separation the detector saw when it fired was above d1, and it saw the approach.
    before = [m for m in separation if stamp_seconds(m.header.stamp) <= event_time]
    assert before and before[-1].separation > d1
    assert max(m.human_speed for m in separation) == pytest.approx(0.5, abs=0.05)


def test_a_hand_resting_on_a_zone_boundary_with_5_mm_noise_fires_nothing(nodes, probe, tmp_path):
    # 3 s through the node: its timing and wiring. The rules themselves hold 10 s of every
    # kind of noise in test_event_rules, on a simulated clock.
    boundary = 0.3  # m
    rest_time = 3.0  # s
    rules = DEFAULTS['rules'] + yaml.safe_dump({
        'near': {'kind': 'zone_entered', 'task': 'avoid', 'distance': boundary},
        'away': {'kind': 'zone_left', 'task': 'follow', 'distance': boundary}})
    events = probe.collect(topics.EVENTS.name, TaskEvent, topics.EVENTS.qos)
    separation = probe.collect(topics.SEPARATION.name, SeparationState, topics.SEPARATION.qos)
    task_state(probe, 'follow')  # the default approach rule is armed
    detector = start_detector(nodes, tmp_path, rules)
    rng = np.random.default_rng(35)
    noise = rng.uniform(-0.005, 0.005, size=(int((rest_time + 0.5) * HAND_RATE) + 10, 2))
    rest = TOOL + [boundary, 0.0]
    Script(probe, lambda t: rest + noise[int(t * HAND_RATE)], lambda t: TOOL,
           rest_time + 0.5).start().join()
    time.sleep(0.3)
    seen = np.array([m.separation for m in separation])
    print(f'resting hand: {seen.size} separations in [{seen.min():.4f}, {seen.max():.4f}] m, '
          f'human speed up to {max(abs(m.human_speed) for m in separation):.3f} m/s')
    assert seen.size >= rest_time * 50 * 0.8 and seen.min() < boundary < seen.max()
    assert events == [], detector.log()


def test_a_lost_hand_fires_its_event_once(nodes, probe, tmp_path):
    events = probe.collect(topics.EVENTS.name, TaskEvent, topics.EVENTS.qos)
    task_state(probe, 'follow_safe')
    detector = start_detector(nodes, tmp_path)
    script = Script(probe, lambda t: TOOL + [0.0, -0.25] if t < 1.0 else None,
                    lambda t: TOOL, 4.0).start()
    script.join()
    assert [(e.name, e.task) for e in events] == [('hand_lost', '')], detector.log()
    timeout = load_rules_timeout()
    after = stamp_seconds(events[0].header.stamp) - script.hand_sent[-1][0]
    print(f'hand lost: event {after:.3f} s after the last hand position (timeout {timeout} s)')
    assert timeout <= after <= timeout + 0.2


def load_rules_timeout() -> float:
    return yaml.safe_load(DEFAULTS['rules'])['hand_lost']['timeout']


@pytest.mark.parametrize('assume_iso_speed', [True, False])
def test_separation_agrees_with_the_formula_on_its_published_speeds(
        nodes, probe, tmp_path, assume_iso_speed):
    separation = probe.collect(topics.SEPARATION.name, SeparationState, topics.SEPARATION.qos)
    start_detector(nodes, tmp_path, assume_iso_speed=assume_iso_speed)
    # The tool comes at 0.25 m/s towards a hand that walks away at 0.1 m/s, then goes back.
    tool = path_target(TOOL, [(0.5, TOOL + [0.0, -0.1], 0.25), (1.4, TOOL, 0.25)])
    hand = path_target(TOOL + [0.0, -0.6], [(0.5, TOOL + [0.0, -0.75], 0.1)])
    script = Script(probe, lambda t: hand(t)[0], lambda t: tool(t)[0], 3.0).start()
    script.join()
    time.sleep(0.2)
    messages = list(separation)
    assert len(messages) >= 3.0 * 50 * 0.7
    worst = max(abs(m.protective_distance - formula(m)) for m in messages)
    for m in messages:
        iso = DEFAULTS['near_speed'] if m.separation <= DEFAULTS['near_limit'] \
            else DEFAULTS['far_speed']
        expected_used = max(m.human_speed, iso if assume_iso_speed else 0.0, 0.0)
        assert m.human_speed_used == pytest.approx(expected_used, abs=1e-9)
        assert m.below_protective == (m.separation < m.protective_distance)
        assert all(map(math.isfinite, (m.separation, m.human_speed, m.robot_speed)))
    print(f'assume_iso_speed {assume_iso_speed}: S_p within {worst * 1e3:.6f} mm of the '
          f'formula over {len(messages)} messages; robot speed up to '
          f'{max(m.robot_speed for m in messages):.3f} m/s, human speed down to '
          f'{min(m.human_speed for m in messages):.3f} m/s')
    assert worst <= 1e-3
    # The speeds are the measured ones: the tool's towards the hand (along -y) as its velocity
    # estimate reads the samples this test sent (a peak of 0.25 m/s when they go out at
    # TOOL_RATE; a stall of this test's thread beside other tests, as in a fresh-clone run,
    # leaves a gap whose difference is the mean speed across it), the hand moving away at up
    # to 0.1 m/s.
    estimator = VelocityEstimator(DEFAULTS['tool_filter_time'])
    sent_peak = max(-estimator.update(point, stamp)[1] for stamp, point in script.tool_sent)
    assert sent_peak > 0.15
    assert max(m.robot_speed for m in messages) == pytest.approx(sent_peak, abs=0.03)
    assert min(m.human_speed for m in messages) == pytest.approx(-0.1, abs=0.02)


def test_in_3d_the_separation_and_the_speeds_are_taken_in_space(nodes, probe, tmp_path):
    """dimension 3 (an arm in space): a hand coming straight down at 0.3 m/s onto a still tool
    under it. The separation is their distance in space (all of it height) and the hand's
    speed towards the tool 0.3 m/s; in the plane both would read 0."""
    separation = probe.collect(topics.SEPARATION.name, SeparationState, topics.SEPARATION.qos)
    start_detector(nodes, tmp_path, dimension=3)
    tool = np.array([0.31, 0.0, 0.49])  # m, the Panda's tool at home

    def hand(t):
        return tool + [0.0, 0.0, 0.5 - 0.3 * min(max(t - 0.5, 0.0), 1.0)]

    Script(probe, hand, lambda t: tool, 2.0).start().join()
    time.sleep(0.2)
    messages = list(separation)
    assert len(messages) >= 2.0 * 50 * 0.7
    assert messages[0].separation == pytest.approx(0.5, abs=0.002)
    assert messages[-1].separation == pytest.approx(0.2, abs=0.002)
    # Mid-descent, 0.33 s and more after the hand set off (3 filter time constants).
    moving = [m for m in messages if 0.25 <= m.separation <= 0.40]
    assert len(moving) >= 5
    assert all(m.human_speed == pytest.approx(0.3, abs=0.03) for m in moving), \
        [round(m.human_speed, 3) for m in moving]


@pytest.mark.exclusive  # the 1 kHz loop
def test_on_the_live_loop_a_reaching_hand_switches_to_avoid_before_d1(live_loop, probe):
    """The whole loop with the detector: the arm comes under follow to a hand 0.6 m away,
    which reaches in at 0.5 m/s 0.3 s later (hand_sim); the switch to avoid starts before the
    separation the detector publishes falls below avoid's d1, if it ever does. (A hand that
    reaches in later, when the arm has come nearer, leaves less time: 0.8 s later, 0.07 s in
    the pure closed loop, the detector's latency being the velocity estimate's.)"""
    d1 = load_task_file(paper_tasks_dir() / 'avoid.yaml').d1
    events = probe.collect(topics.EVENTS.name, TaskEvent, topics.EVENTS.qos)
    states = probe.collect(topics.TASK_STATE.name, TaskState, topics.TASK_STATE.qos)
    separation = probe.collect(topics.SEPARATION.name, SeparationState, topics.SEPARATION.qos)
    loop = live_loop({'hand_sim': {
        'profile': 'waypoints', 'start_delay': 0.3, 'speed': 0.1,
        'waypoints': [0.35, -0.30, 0.35, 0.0], 'segment_speeds': [0.5], 'pauses': [2.0]}},
        nodes=['scara_sim', 'event_manager', 'controller', 'event_detector', 'hand_sim'],
        ready_timeout=30.0)
    assert wait_for(lambda: any(s.task.name == 'avoid' and s.phase == 'active'
                                for s in states), 20.0), loop['event_detector'].log()
    assert [(e.name, e.task) for e in events][:1] == [('hand_reaches_in', 'avoid')]
    event_time = stamp_seconds(events[0].header.stamp)
    switch = next(stamp_seconds(s.header.stamp) for s in states if s.pending_task == 'avoid')
    closest = min(m.separation for m in separation)
    below = [stamp_seconds(m.header.stamp) for m in separation if m.separation < d1]
    at_event = [m.separation for m in separation
                if stamp_seconds(m.header.stamp) <= event_time][-1]
    print(f'live loop: event at separation {at_event:.3f} m, switch {switch - event_time:.3f} s '
          f'after it; closest {closest:.3f} m (d1 {d1} m)'
          + (f', first below d1 {below[0] - switch:.3f} s after the switch' if below else ''))
    assert at_event > d1
    assert not below or switch < below[0]


def test_a_bad_rule_ends_the_detector_with_one_line(nodes, tmp_path):
    process = nodes('hri_adaptive_controller', 'event_detector', params_files=[params_file(
        tmp_path, 'near: {kind: zone_entered, task: avoid, distance: -0.3}\n')])
    assert process.wait(20.0) == 1, process.log()
    log = process.log()
    assert "bad parameter rules: rule 'near': distance must be a number > 0 (m), got -0.3" \
        in log, log
    assert 'Traceback' not in log


def test_non_finite_positions_and_other_frames_are_dropped_with_a_warning(
        nodes, probe, tmp_path):
    separation = probe.collect(topics.SEPARATION.name, SeparationState, topics.SEPARATION.qos)
    detector = start_detector(nodes, tmp_path)
    # Every tenth hand and tool position is NaN or infinite; every tenth hand, five after,
    # is 0.1 m from the tool in a camera's frame, which the detector does not transform.
    bad = (math.nan, math.inf)

    def hand(t):
        if int(t * 100) % 10 == 5:
            return TOOL + [0.0, -0.1]
        return (bad[int(t * 100) % 2], 0.0) if int(t * 100) % 10 == 0 else TOOL + [0.0, -0.3]

    def hand_frame(t):
        return 'camera' if int(t * 100) % 10 == 5 else 'base'

    def tool(t):
        return (0.0, bad[int(t * 250) % 2]) if int(t * 250) % 10 == 0 else TOOL

    Script(probe, hand, tool, 2.0, hand_frame).start().join()
    time.sleep(0.2)
    assert len(separation) >= 2.0 * 50 * 0.7
    assert all(m.separation == pytest.approx(0.3, abs=1e-6) and math.isfinite(m.human_speed)
               and math.isfinite(m.protective_distance) and m.header.frame_id == 'base'
               for m in separation)
    log = detector.log()
    assert 'target dropped: non-finite position' in log, log
    assert 'ee_position dropped: non-finite position' in log, log
    assert "target dropped: frame 'camera' is not base_frame 'base'" in log, log
    assert log.count('dropped') <= 3 * 3, log  # throttled: once a second each
    assert detector.alive()
