"""Topic-level: a real person's hand (Vicon recordings) on the live loop, glitches, bad files.

The live loop (scara_sim, event_manager, controller) runs Table I's follow or avoid while
hand_sim replays a recorded take (data/human-motion) at its recorded pace, placed by its
auto_place so that most of the take's horizontal path lies within the arm's reach. The probe
keeps /joint_states (the applied torque, the arm's position) and /target raw and judges, over
the take's first DURATION s after the first SETTLE s (the arm coming from its start pose, the
task fading in): no traceback; every effort finite and within the limit; the applied torque
changes by at most 2 N m between consecutive joint states (the sim's 1 ms steps, a late
burst of commands included); no effort above 25 % of the
limit for more than 0.5 s; follow: the median distance to the hand <= 0.08 m, avoid: at most
5 % of the samples closer than d1 - 3 cm, both over the samples where the hand is within the
arm's reach and slower than its task speed (run_metrics.take_metrics). The controller's
whole-body clearance is off here (the hand alone); every take runs under `slow`
(scripts/test.sh --all).

Without the 1 kHz loop: a /target with injected jumps against a stand-in arm is held and
counted (ControllerState.target_glitches), a lost hand fades the task out and back in, and a
bad recording ends hand_sim with one line and exit code 1.
"""

import math
import os
import signal
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from hri_interfaces.msg import ControllerState
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_adaptive_controller.run_metrics import TakeCriteria, take_metrics
from hri_adaptive_controller.target_filter import TargetFilter, TargetFilterSettings
from hri_bringup.processes import LIVE_LOOP, wait_for
from hri_core import topics
from hri_core.dynamics import forward_kinematics
from hri_core.node_common import load_defaults, stamp_seconds
from hri_core.recorded_motion import Placement, ReachAnnulus, read_vicon_csv
from tests.common import PAPER_TASKS, REPO_ROOT, call_service, wait_for_service
from tests.fault_tools import RawListener, SentCommands, effort_change_per_step
from tests.test_bad_input import HAND_OFFSET, HAND_PERIOD, StandInArm

pytestmark = pytest.mark.integration

TAKES = REPO_ROOT / 'data' / 'human-motion'
ALL_TAKES = sorted(path.stem for path in TAKES.glob('*.csv'))
# The hard cases among the takes: follow a hand lost for 1.25 s (Hammering) and one at up to
# 3.1 m/s (TossTheCan); avoid a hand picking and placing close to the robot at up to 1.6 m/s
# (PickPlaceCloseHuman) and one with marker swaps (HumanRobotHandover).
# Every take with --all (the pure loop, test_recorded_takes, runs all eight with both tasks in
# the default run); the live loop's recorded person in the default run is test_body_live's,
# with the whole body.
SETTLE = 2.0  # s: the arm comes from its start pose and the task fades in (ramp 0.3 s)
DURATION = 12.0  # s of each take judged, from its first frame (its hard parts: 2-11 s)
CONTROLLER = load_defaults('hri_adaptive_controller', 'controller')
SIM = load_defaults('scara_sim', 'scara_sim')
HAND_SIM = load_defaults('scara_sim', 'hand_sim')
EFFORT_LIMIT = SIM['effort_limit']  # N m
L1, L2 = SIM['l1'], SIM['l2']
REACH = ReachAnnulus(*HAND_SIM['reach'])  # m, what auto_place places the take in
D1 = {'follow': 0.0, 'avoid': 0.183}  # m, Table I
MAX_EFFORT_STEP = 2.0  # N m between consecutive joint states
SIM_STEP = 1.0 / SIM['rate_hz']  # s between the sim's joint states
MAX_HIGH_EFFORT_HOLD = 0.5  # s above 25 % of the limit
FOLLOW_MEDIAN = 0.08  # m
AVOID_CLOSE_FRACTION = 0.05
HAND_GAP = 0.05  # s: a joint state more than this after the newest /target has no hand


def test_the_reach_annulus_is_the_sims_arm():
    # inner radius: joint 2 at its limit, |x| = sqrt(l1^2 + l2^2 + 2 l1 l2 cos q2max)
    q2 = SIM['joint_upper_limits'][1]
    inner = math.sqrt(SIM['l1'] ** 2 + SIM['l2'] ** 2 + 2 * SIM['l1'] * SIM['l2'] * math.cos(q2))
    assert REACH.inner == pytest.approx(inner, abs=1e-3)
    assert REACH.outer == pytest.approx(SIM['l1'] + SIM['l2'])


def hand_at(times, hand_times, hand_points) -> np.ndarray:
    """The newest /target at each of `times` (N, 2), NaN where it is older than HAND_GAP
    (a lost frame) or there is none yet."""
    index = np.searchsorted(hand_times, times, side='right') - 1
    hand = hand_points[np.maximum(index, 0)].copy()
    stale = (index < 0) | (times - hand_times[np.maximum(index, 0)] > HAND_GAP)
    hand[stale] = np.nan
    return hand


def replay_take(live_loop, probe, take: str, task: str) -> dict:
    """Run the loop with `take` replayed under `task`; the judged window's figures."""
    joints = RawListener(probe, topics.JOINT_STATES.name, JointState)
    commands = RawListener(probe, topics.EFFORT_COMMANDS.name, Float64MultiArray)
    targets = RawListener(probe, topics.TARGET.name, PointStamped, topics.TARGET.qos)
    states = probe.collect(topics.CONTROLLER_STATE.name, ControllerState,
                           topics.CONTROLLER_STATE.qos)
    loop = live_loop({
        'event_manager': {'initial_task': task, 'ramp_time': 0.3},
        # The hand alone: these figures are the task's. The SCARA measures the person in its
        # plane, where the arm reaching over it covers its links: test_body_live and
        # bench_body_takes judge the whole-body clearance.
        'controller': {'clearance': 0.0},
        'hand_sim': {'profile': 'recording', 'recording': str(TAKES / f'{take}.csv'),
                     'auto_place': True, 'at_end': 'stop'},
    }, nodes=LIVE_LOOP, ready_timeout=30.0)
    assert wait_for(lambda: len(targets) > 0, 20.0), loop['hand_sim'].log()
    begin = deserialize_message(targets.arrivals[0][1], PointStamped).header.stamp
    end = stamp_seconds(begin) + DURATION

    def latest_joint_stamp() -> float:
        return (stamp_seconds(deserialize_message(joints.arrivals[-1][1], JointState)
                              .header.stamp) if joints.arrivals else -math.inf)

    assert wait_for(lambda: latest_joint_stamp() > end, DURATION + 30.0), \
        loop['controller'].log()
    for name, process in loop.items():
        assert process.alive(), process.log()
        assert 'Traceback' not in process.log(), (name, process.log())
    hand_messages = [deserialize_message(data, PointStamped) for _, data, _ in targets.arrivals]
    hand_times = np.array([stamp_seconds(m.header.stamp) for m in hand_messages])
    hand_points = np.array([(m.point.x, m.point.y) for m in hand_messages])
    start = hand_times[0] + SETTLE
    window = [m for m in (deserialize_message(data, JointState) for _, data, _ in
                          list(joints.arrivals)) if start <= stamp_seconds(m.header.stamp) <= end]
    assert len(window) > 500 * (DURATION - SETTLE), len(window)
    t = np.array([stamp_seconds(m.header.stamp) for m in window])
    order = np.argsort(t, kind='stable')
    window = [window[i] for i in order]
    t = t[order]
    q = np.array([m.position[:2] for m in window])
    effort = np.array([m.effort[:2] for m in window])
    tool = forward_kinematics(q, L1, L2)
    criteria = TakeCriteria(d1=D1[task], effort_limit=EFFORT_LIMIT,
                            task_speed=CONTROLLER['max_task_speed'], reach=REACH)
    metrics = take_metrics(t, hand_at(t, hand_times, hand_points), tool, effort, criteria)
    # Pairs of states one sim step apart: a state the probe missed is no step of the drive.
    consecutive = np.diff(t) <= 1.5 * SIM_STEP
    raw_step = float(np.max(np.abs(np.diff(effort, axis=0))[consecutive]))
    per_cycle = effort_change_per_step(window, commands=SentCommands(commands))
    glitches = max((s.target_glitches for s in states), default=0)
    figures = {'take': take, 'task': task, 'median': metrics.follow_median_distance,
               'close': metrics.close_fraction, 'considered': metrics.considered / len(t),
               'hold': metrics.longest_high_effort_hold,
               'raw_step': raw_step, 'consecutive': float(np.mean(consecutive)),
               'cycle_step': per_cycle,
               'glitches': glitches, 'finite': bool(np.all(np.isfinite(effort))),
               'peak': float(np.max(np.abs(effort)))}
    print(f"{take} {task}: median distance {figures['median']:.3f} m, closer than d1 - 3 cm "
          f"{100 * figures['close']:.1f} % of the {100 * figures['considered']:.0f} % samples "
          f"considered; longest high-effort hold {figures['hold']:.3f} s; largest effort "
          f"step {figures['raw_step']:.3f} N m between joint states, {per_cycle:.3f} per "
          f"cycle; peak {figures['peak']:.2f} N m; {glitches} /target glitches held")
    return figures


def judge(figures: dict) -> None:
    assert figures['finite'] and figures['peak'] <= EFFORT_LIMIT + 1e-9, figures
    assert figures['consecutive'] > 0.95, figures  # the probe heard (nearly) every state
    assert figures['raw_step'] <= MAX_EFFORT_STEP + 1e-9, figures
    assert figures['hold'] <= MAX_HIGH_EFFORT_HOLD, figures
    assert figures['considered'] > 0.1, figures       # the take was judged at all
    if figures['task'] == 'follow':
        assert figures['median'] <= FOLLOW_MEDIAN, figures
    else:
        assert figures['close'] <= AVOID_CLOSE_FRACTION, figures


def take_cases():
    return [pytest.param(take, task, marks=[pytest.mark.exclusive, pytest.mark.slow],
                         id=f'{task}-{take}')
            for task in ('follow', 'avoid') for take in ALL_TAKES]


@pytest.mark.parametrize('take, task', take_cases())
def test_a_recorded_person_on_the_live_loop(live_loop, probe, take, task):
    judge(replay_take(live_loop, probe, take, task))


# -- without the 1 kHz loop: the controller on test_bad_input's stand-in arm ------------------
def start_controller(nodes, probe):
    states = probe.collect(topics.CONTROLLER_STATE.name, ControllerState,
                           topics.CONTROLLER_STATE.qos)
    controller = nodes('hri_adaptive_controller', 'controller',
                       params={'joint_state_timeout': 0.2})
    manager = nodes('hri_adaptive_controller', 'event_manager',
                    params={'tasks_dir': str(PAPER_TASKS), 'initial_task': 'follow'})
    return controller, manager, states


def swaps_followed(stand_in, swap_samples, used) -> tuple[list, list]:
    """(the distances of the ControllerStates in `used` that report a target other than the
    stand-in's hand, which a followed swap 1.5 m away shows as; the swap samples the stand-in
    sent after a gap of its own long enough for a hand to cross 1.5 m at the filter's
    max_speed, which the filter rightly takes)."""
    stamps = dict(zip(stand_in.published, stand_in.stamps, strict=True))
    order = sorted(stamps)
    reachable = [k for previous, k in zip(order[:-1], order[1:], strict=True)
                 if k in swap_samples and stamps[k] - stamps[previous]
                 >= (1.5 - 0.01) / TargetFilterSettings().max_speed]
    followed = [s.distance for s in used
                if abs(s.distance - np.linalg.norm(HAND_OFFSET)) >= 0.01]
    return followed, reachable


def test_jumps_on_target_are_held_and_counted(nodes, probe):
    # Every second a marker swap: 3 samples (60 ms) 1.5 m away; the distance the controller
    # reports is to the target it used, so a followed jump would show as ~1.5 m.
    swap_samples = {k for k in range(50, 10_000, 50) for k in (k, k + 1, k + 2)}
    commands = RawListener(probe, topics.EFFORT_COMMANDS.name, Float64MultiArray)
    controller, _, states = start_controller(nodes, probe)
    stand_in = StandInArm(probe)
    far = stand_in.hand + (0.0, 1.5)
    stand_in.hand_at = lambda k: far if k in swap_samples else stand_in.hand
    try:
        # Until a held swap is reported too: on a loaded machine the stand-in's samples come
        # late and the reports later still.
        assert wait_for(lambda: states and states[-1].status == 'ok' and stand_in.sent > 420
                        and states[-1].target_glitches > 0, 30.0), (
            stand_in.sent, states[-1] if states else None, controller.log())
    finally:
        stand_in.close()
    closed = probe.now()
    # Counted once the publisher has stopped: it went on sending until close(), and on a
    # loaded machine (a fresh-clone run) 7 more swap samples went out between a count taken
    # before close() and the close, which the controller rightly held (31 held of "24"). Only
    # the samples published count: a stand-in stalled beside the other tests leaves out
    # those it missed (before, it sent them late, and a swap stretched past the filter's
    # confirm_time was rightly re-anchored: 28 held of "24", the far target followed).
    published = set(stand_in.published)
    sent_swaps = len(swap_samples & published)
    sent_events = len([k for k in range(50, stand_in.sent + 1, 50)
                       if published & {k, k + 1, k + 2}])  # swaps with a sample sent
    # The last samples' verdicts: in a report stamped after the stand-in stopped.
    assert wait_for(lambda: stamp_seconds(states[-1].header.stamp) > stamp_seconds(closed),
                    5.0)
    counted = states[-1].target_glitches
    used = [s for s in states if s.status == 'ok']
    # What the controller's filter holds of the stream as published: every swap sample, and
    # the real hand after a gap longer than confirm_time that follows a held sample, until it
    # is confirmed (26 held of 24 swap samples in one fresh-clone run: this test's publisher
    # stalls beside the other tests, and the controller then kept only the newest /target).
    replayed = TargetFilter()
    for k, stamp in zip(stand_in.published, stand_in.stamps, strict=True):
        replayed.offer(stamp, stand_in.hand_at(k))
    print(f'{sent_swaps} swap samples sent, {counted} held ({replayed.glitches} by the same '
          f'filter); distance to the used target '
          f'{min(s.distance for s in used):.4f}-{max(s.distance for s in used):.4f} m')
    # The controller reads /target in order with a queue of 100 samples (2 s): it sees
    # every one unless its own process stalls longer, and a gap it suffered after a swap
    # holds the real hand until confirmed too, at most confirm_time's worth of samples per
    # swap (32 held of 23 swap samples, 23 replayed, in one fresh-clone run). Every sample
    # it held is counted, no more (a filter that held the real hand for good: hundreds);
    # none it followed (below).
    settings = TargetFilterSettings()
    confirmation = math.ceil(settings.confirm_time / HAND_PERIOD) + 1
    assert 0.5 * sent_events <= counted <= replayed.glitches + confirmation * sent_events, (
        sent_swaps, replayed.glitches, sent_events)
    # No swap followed, unless the stand-in, held up, left a gap before one long enough for a
    # hand to get there (the filter's speed bound: 1.5 m in 0.3 s at 5 m/s; seen once beside
    # a busy process): such a sample is a hand that may really have moved, and is taken.
    followed, reachable = swaps_followed(stand_in, swap_samples, used)
    assert not followed or reachable, (followed[:5], reachable)
    sent = np.array([list(m.data) for m in commands.messages()])
    # Steps into zero torque are the stale-joint-state fallback (this test's own publisher
    # thread can stall under load), not a response to a glitch: left out.
    steps = np.max(np.abs(np.diff(sent, axis=0)), axis=1)[np.any(sent[1:] != 0.0, axis=1)]
    assert len(sent) > 100 and np.max(steps) <= 1.0 + 1e-9
    assert 'target held' in controller.log() and 'Traceback' not in controller.log()


def test_a_swap_just_after_the_controller_stalled_is_held(nodes, probe):
    """The controller's process stopped (SIGSTOP) for 0.6 s while the hand goes on at 50 Hz,
    the stop ending just after a marker swap begins (3 samples 1.5 m away): the samples sent
    meanwhile wait in its /target queue (2 s deep), so the swap is judged against the hand
    just before it and held. With a queue of 10 (0.2 s) the samples before the swap were
    lost and the swap, the first sample after a gap a hand could have crossed, was taken
    (7.6 s of reports 1.5 m off, the filter blending back). Six stops, started 19-24
    samples before a swap: the swap's first sample is the oldest kept by a queue of 10."""
    period = 60  # samples (1.2 s) between swaps
    swap_samples = {k for k in range(period, 10_000, period) for k in (k, k + 1, k + 2)}
    controller, _, states = start_controller(nodes, probe)
    stand_in = StandInArm(probe)
    far = stand_in.hand + (0.0, 1.5)
    stand_in.hand_at = lambda k: far if k in swap_samples else stand_in.hand
    try:
        assert wait_for(lambda: states and states[-1].status == 'ok', 30.0), controller.log()
        for offset in range(19, 25):  # samples before a swap at which the stop starts
            start = ((stand_in.sent + offset) // period + 1) * period - offset
            assert wait_for(lambda start=start: stand_in.sent >= start, 5.0, period=0.001)
            os.kill(controller.pid, signal.SIGSTOP)
            try:
                time.sleep(0.6)
            finally:
                os.kill(controller.pid, signal.SIGCONT)
        last = stand_in.sent
        assert wait_for(lambda: states[-1].status == 'ok' and stand_in.sent > last + 25, 10.0)
    finally:
        stand_in.close()
    # No swap followed, unless this test's own publisher, held up, left a gap before one long
    # enough for a hand to cross (as in the test above).
    followed, reachable = swaps_followed(stand_in, swap_samples,
                                         [s for s in states if s.status == 'ok'])
    assert not followed or reachable, (len(followed), reachable)
    assert states[-1].target_glitches >= 3, states[-1].target_glitches


def test_a_lost_hand_fades_the_task_out_and_in_again(nodes, probe):
    # The hand is lost for 2.5 s (125 samples at 50 Hz) once the controller follows it: timed
    # from the stand-in's start, the loss once fell before a loaded machine had the
    # event_manager's task to the controller, and no fade was seen.
    controller, _, states = start_controller(nodes, probe)
    stand_in = StandInArm(probe)
    lost_from = math.inf
    stand_in.hand_at = lambda k: None if lost_from <= k < lost_from + 125 else stand_in.hand
    try:
        assert wait_for(lambda: states and states[-1].status == 'ok'
                        and states[-1].weight == 1.0, 30.0), controller.log()
        lost_from = stand_in.sent + 5
        assert wait_for(lambda: any(s.status == 'target_lost' for s in states), 30.0), \
            controller.log()
        lost = next(i for i, s in enumerate(states) if s.status == 'target_lost')
        assert wait_for(lambda: states[-1].status == 'ok' and states[-1].weight == 1.0, 10.0)
    finally:
        stand_in.close()
    weights = np.array([s.weight for s in states[lost:]])
    print(f'hand lost: a fell to {min(weights):.3f}, back to {weights[-1]:.3f}')
    assert min(weights) == 0.0
    # A ramp, not a step: between the joint states two reports ran on (their stamps less
    # input_age), a moves no faster than the fade's quintic allows, 15/8 per task_fade_time
    # (0.019 between reports 10 ms apart). Judged against the time between them: a loaded
    # machine once spaced two reports about 90 ms apart, and a moved 0.169 between them.
    # 1e-5 for the times' rounding (input_age is a difference of epoch seconds: 0.24 us).
    ran_at = np.array([stamp_seconds(s.header.stamp) - s.input_age for s in states[lost:]])
    allowed = 15.0 / 8.0 / CONTROLLER['task_fade_time'] * np.diff(ran_at) + 1e-5
    steps = np.abs(np.diff(weights))
    worst = int(np.argmax(steps - allowed))
    assert np.all(steps <= allowed), (steps[worst], np.diff(ran_at)[worst])
    assert 'Traceback' not in controller.log()


def test_hand_sim_replays_a_take_at_its_pace_in_the_base_frame(nodes, probe):
    # Hammering slowed down by a quarter: frames 12.5 ms apart on the replay's clock; the
    # cameras lost the hand in frames 202-400 (but 276): nothing is published for them.
    take, scale = TAKES / 'CollaborativeHammering_1.csv', 1.25
    placement = Placement((0.1, -0.2, -0.5), 0.7)
    motion = read_vicon_csv(take, placement=placement, time_scale=scale)
    targets = RawListener(probe, topics.TARGET.name, PointStamped, topics.TARGET.qos)
    hand = nodes('scara_sim', 'hand_sim', params={
        'profile': 'recording', 'recording': str(take), 'translation': [0.1, -0.2, -0.5],
        'yaw': 0.7, 'time_scale': scale, 'at_end': 'stop'})

    def replayed() -> float:
        if not targets.arrivals:
            return 0.0
        first, last = (deserialize_message(targets.arrivals[i][1], PointStamped)
                       for i in (0, -1))
        return stamp_seconds(last.header.stamp) - stamp_seconds(first.header.stamp)

    # Past frame 400 (5 s on the replay's clock).
    assert wait_for(lambda: replayed() > 5.3, 30.0), hand.log()
    messages = [deserialize_message(data, PointStamped) for _, data, _ in targets.arrivals]
    points = np.array([(m.point.x, m.point.y, m.point.z) for m in messages])
    # The probe may have matched after the first frames: which frame the first one heard is
    first = int(np.nanargmin(np.linalg.norm(motion.positions - points[0], axis=1)))
    t = np.array([stamp_seconds(m.header.stamp) for m in messages])
    t += motion.times[first] - t[0]
    index = np.round(t / (scale / motion.rate_hz)).astype(int)
    np.testing.assert_allclose(t, motion.times[index], atol=1e-6)   # stamped when recorded
    np.testing.assert_allclose(points, motion.positions[index], atol=1e-9)
    assert motion.valid[index].all()                                # nothing for a lost frame
    due = np.count_nonzero(motion.valid[first:index[-1] + 1])
    print(f'{len(messages)} of {due} seen frames published in {t[-1]:.2f} s')
    assert len(messages) >= 0.9 * due and np.all(np.diff(index) > 0)
    assert set(range(202, 401)) - {276} <= set(range(index[-1])) - set(index)


def test_a_bad_recording_ends_hand_sim_with_one_line(nodes, tmp_path):
    bad = tmp_path / 'take.csv'
    bad.write_text('Objects\n100\n,,Global Angle head:head,,,,,\n')
    processes = [nodes('scara_sim', 'hand_sim', params={'profile': 'recording',
                                                        'recording': str(bad)}),
                 nodes('scara_sim', 'hand_sim', params={'profile': 'recording',
                                                        'recording': str(tmp_path / 'no.csv')},
                       remaps={'__node': 'hand_sim_nowhere'})]
    for process, reason in zip(processes, ("no segment 'right_hand'", 'cannot read no.csv'),
                               strict=True):
        assert process.wait(30.0) == 1, process.log()
        lines = [line for line in process.log().splitlines() if line.strip()]
        assert len(lines) == 1 and 'ERROR' in lines[0] and reason in lines[0], lines


def test_hand_sim_takes_a_recording_at_run_time_and_refuses_a_bad_one(nodes, probe, tmp_path):
    bad = tmp_path / 'take.csv'
    bad.write_text('Objects\n100\n')
    hand = nodes('scara_sim', 'hand_sim')
    client = probe.node.create_client(SetParametersAtomically,
                                      '/hand_sim/set_parameters_atomically')
    assert wait_for_service(client, 20.0), hand.log()

    def set_all(**values):
        return call_service(client, SetParametersAtomically.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()
        ])).result

    refused = set_all(profile='recording')
    assert not refused.successful and 'needs the parameter recording' in refused.reason
    refused = set_all(profile='recording', recording=str(bad))
    assert not refused.successful and 'ends before its segment-name line' in refused.reason
    assert set_all(profile='recording', recording=str(TAKES / 'TossTheCan_0.csv'),
                   auto_place=True).successful
    assert wait_for(lambda: 'hand profile restarted: recording' in hand.log(), 10.0), hand.log()
    assert hand.alive() and 'Traceback' not in hand.log()
