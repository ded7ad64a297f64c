"""Tests of control_cycle: what the controller does with each input, on a simulated clock.

Each test drives one ControlCycle as the node does (joint states, targets, TaskStates and
the watchdog with the caller's time; `sent` after each command) and checks the behaviour a
user relies on exactly, where the topic-level tests (tests/test_faults.py, test_bad_input.py,
test_recorded_hand.py, test_task_behaviour.py) can only look at it through a loaded machine.
The SCARA wherever gravity does not matter (its law is the cheaper); the Panda for the
gravity hold. The arm stands still: the cycle's decisions are judged, not the arm's motion.
"""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from hri_adaptive_controller import arm_law
from hri_adaptive_controller.arm_law import ArmController, default_gains
from hri_adaptive_controller.control_cycle import (
    INFO,
    WARNING,
    ControlCycle,
    CycleSettings,
    TaskInput,
)
from hri_adaptive_controller.event_weight import EventWeightSchedule, quintic_smoothstep
from hri_adaptive_controller.separation_cap import STANDOFF, pull_speed_knee
from hri_adaptive_controller.task_variable import CAP_BAND
from hri_core.bodies import panda_package_dirs, robot_body
from hri_core.robot_model import robot_model
from hri_core.separation import ProtectiveSeparation

CONFIG = Path(__file__).resolve().parents[1] / 'config'
DEFAULTS = yaml.safe_load((CONFIG / 'controller.yaml').read_text())['controller'][
    'ros__parameters']
DETECTOR = yaml.safe_load((CONFIG / 'event_detector.yaml').read_text())['event_detector'][
    'ros__parameters']
PERIOD = 1e-3  # s: the default rate_hz, 1 kHz
LATENCY = 2e-4  # s from a joint state's stamp to its command's publication
Q_SCARA = (0.3, 1.2)  # rad: the SCARA's still pose
FOLLOW = TaskInput('follow', 1, 1.291, 13.66, 0.0, 0.041, 3, 0.0)
WIDE = TaskInput('wide_follow', 1, 1.291, 13.66, 0.0, 0.08, 3, 0.0)
T0 = 100.0  # s: where the simulated clock starts (monotonic and stamps alike)


@pytest.fixture(scope='module')
def scara():
    return robot_model('scara')


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


class Rig:
    """A ControlCycle driven like the node drives it, on one simulated clock (the joint
    stamps' clock is the same as `now`). `commands` and `reports`: what each cycle sent."""

    def __init__(self, model, gains=None, separation=None, robot_body=None, **values):
        law = ArmController(model, gains or default_gains(model))
        settings = CycleSettings.from_values({**DEFAULTS, **values}, separation=separation)
        self.cycle = ControlCycle(law, settings, robot_body=robot_body)
        self.model = model
        self.now = T0
        self.commands: list[tuple] = []
        self.reports: list = []
        self.last_target = self.last_task_state = None  # stamps of the last ones taken
        self.next_watchdog = T0 + settings.watchdog_period
        self.started: list[float] = []  # when the watchdog started the hold

    @property
    def notes(self):
        return self.cycle.notes

    def tool(self, q) -> np.ndarray:
        return self.model.task_kinematics(np.array(q), np.zeros(len(q)))[0]

    def joint(self, q, dq=None, effort=None, dt=PERIOD):
        """A joint state dt after the last (stamped now); its command (None: dropped)."""
        self.now += dt
        self._watchdogs()
        dq = (0.0,) * len(q) if dq is None else dq
        command = self.cycle.joint_state(self.now, tuple(q), tuple(dq), self.now, effort)
        if command is not None:
            self._sent(command, LATENCY)
        return command

    def idle(self, seconds):
        """No joint states for `seconds`: the node's timers run, the watchdog every
        watchdog_period (which may start the hold at once) and, while the cycle holds, the
        hold every period."""
        for _ in range(int(round(seconds / PERIOD))):
            self.now += PERIOD
            if not self._watchdogs() and self.cycle.holding:
                self.hold_cycle()

    def _watchdogs(self) -> bool:
        """The watchdog calls due by now; whether one started the hold (and ran it)."""
        started = False
        while self.next_watchdog <= self.now + 1e-9:
            at = self.next_watchdog
            self.next_watchdog += self.cycle.settings.watchdog_period
            if self.cycle.watchdog(at):
                self.started.append(at)
                self.hold_cycle()
                started = True
        return started

    def hold_cycle(self):
        """A hold cycle now (the node's hold timer)."""
        command = self.cycle.hold(self.now)
        if command is not None:
            self._sent(command, 0.0)
        return command

    def _sent(self, command, latency):
        self.commands.append(tuple(float(v) for v in command))
        report = self.cycle.sent(self.now, self.now + latency)
        if report is not None:
            self.reports.append(report)

    def target(self, position) -> bool:
        taken = self.cycle.target(self.now, tuple(float(v) for v in position), self.now)
        if taken:
            self.last_target = self.now
        return taken

    def task(self, task=FOLLOW, weight=1.0, rate=0.0, stamp=None) -> bool:
        taken = self.cycle.task_state(self.now, task, self.now if stamp is None else stamp,
                                      weight, rate)
        if taken:
            self.last_task_state = self.now
        return taken

    def run(self, seconds, q, hand=None, task_every=0.1, target_every=0.01):
        """Joint states at 1 kHz for `seconds` at the still pose q, the hand at `hand` (None:
        no target) every target_every s and a TaskState of FOLLOW (a = 1) every task_every s
        (None: none); a per cycle."""
        weights = []
        for i in range(int(round(seconds / PERIOD))):
            if hand is not None and i % int(round(target_every / PERIOD)) == 0:
                self.target(hand)
            if task_every is not None and i % int(round(task_every / PERIOD)) == 0:
                self.task()
            self.joint(q)
            weights.append(self.cycle.weight)
        return weights


def smoothstep(u: float) -> float:
    return quintic_smoothstep(u)[0]


def texts(notes, level=None) -> list[str]:
    return [note.text for note in notes if level is None or note.level == level]


def test_no_command_before_any_joint_state_then_the_gravity_hold_at_the_effort_rate(panda):
    rig = Rig(panda)
    # No joint state yet: no command (the arm's brakes hold it), the status reported, one
    # warning however long it lasts.
    rig.idle(0.1)
    assert len(rig.commands) == 100 and set(rig.commands) == {()}
    assert rig.cycle.status == 'no_joint_states'
    assert rig.reports and {r.status for r in rig.reports} == {'no_joint_states'}
    assert texts(rig.notes) == ['no command: no joint states']
    # The first joint state (no target: the arm is held where it is) starts the torque from
    # the gravity hold there, not from zero (the brakes held gravity until now) ...
    leaning = panda.home + np.array([0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0])
    first = np.array(rig.joint(leaning))
    assert np.abs(first - rig.cycle.law.gravity_hold(leaning)).max() <= 1.0 + 1e-12
    assert np.abs(first).max() > 10.0
    # ... two at another pose ramp it at 1 N m per 1 ms cycle, short of that pose's hold ...
    q = panda.home + np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.2, 0.1])
    for _ in range(2):
        assert rig.joint(q) is not None
    assert rig.cycle.status == 'no_target' and not rig.cycle.holding
    ramped = np.array(rig.commands[-1])
    last_state = rig.now
    # ... then they stop: the watchdog (every joint_state_timeout / 4) starts the hold once
    # they are older than joint_state_timeout (0.1 s), not before.
    held_from = len(rig.commands)
    rig.idle(0.2)
    assert len(rig.started) == 1
    assert 0.1 < rig.started[0] - last_state <= 0.1 + rig.cycle.settings.watchdog_period
    held = np.array(rig.commands[held_from:])
    assert len(held) == pytest.approx(round((rig.now - rig.started[0]) / PERIOD), abs=1)
    gravity = rig.cycle.law.gravity_hold(q)
    assert np.abs(gravity - ramped).max() > 4.0  # a hold worth keeping, not yet reached
    steps = np.abs(np.diff(np.vstack([ramped, held]), axis=0))
    assert steps.max() == pytest.approx(1.0)  # the effort rate acts ...
    assert np.all(steps <= 1.0 + 1e-12)       # ... and is kept
    assert not np.any(np.all(held == 0.0, axis=1))  # never zero torque on the way
    assert np.allclose(held[-1], gravity, rtol=0.0, atol=1e-12)
    assert rig.cycle.status == 'stale_joint_states'
    assert rig.reports[-1].status == 'stale_joint_states'
    assert texts(rig.notes, WARNING) == ['no command: no joint states',
                                         'holding against gravity: stale joint states']


def test_joint_states_resuming_end_the_outage_and_each_outage_warns_once(scara):
    rig = Rig(scara)
    hand = rig.tool(Q_SCARA) + np.array([0.1, 0.0])
    rig.run(0.1, Q_SCARA, hand)
    for _ in range(2):  # two outages
        held_from = len(rig.commands)
        rig.idle(0.2)
        assert rig.cycle.holding and rig.cycle.status == 'stale_joint_states'
        # The SCARA is horizontal: its hold is zero torque, at once.
        assert set(rig.commands[held_from:]) == {(0.0, 0.0)}
        resumed_at = len(rig.commands)
        assert resumed_at - held_from >= 75
        rig.run(0.1, Q_SCARA, hand)  # they resume: the law again, from zero at the rate
        assert not rig.cycle.holding and rig.cycle.status == 'ok'
        assert 0.0 < max(map(abs, rig.commands[resumed_at])) <= 1.0 + 1e-12
        assert rig.hold_cycle() is None  # the hold timer stops: joint states pace the cycles
    assert texts(rig.notes) == ['zero torque: stale joint states', 'joint states resumed',
                                'zero torque: stale joint states', 'joint states resumed']
    assert [note.level for note in rig.notes] == [WARNING, INFO, WARNING, INFO]


def test_a_starved_node_does_not_start_an_outage(scara):
    """A watchdog call long after the previous one (the node itself did not run) starts no
    hold: the joint states may be waiting in its queue. Judged at the next call."""
    starved = Rig(scara)
    starved.run(0.5, Q_SCARA)
    starved.now += 0.2  # nothing ran for 0.2 s: twice the joint_state_timeout
    starved.next_watchdog = starved.now  # the watchdog's late turn
    assert not starved._watchdogs() and not starved.cycle.holding
    assert starved.joint(Q_SCARA, dt=1e-4) is not None  # the queued joint state
    starved.run(0.1, Q_SCARA)
    assert not starved.started and starved.cycle.status == 'no_target'
    assert texts(starved.notes) == []
    # The same silence with the watchdog on time: the hold starts.
    on_time = Rig(scara)
    on_time.run(0.5, Q_SCARA)
    on_time.idle(0.2)
    assert len(on_time.started) == 1 and on_time.cycle.status == 'stale_joint_states'


def test_a_lost_hand_fades_the_task_out_and_back_in_with_the_c2_ramp(scara):
    timeout, fade = 0.2, 0.25
    rig = Rig(scara, target_timeout=timeout, task_fade_time=fade)
    hand = rig.tool(Q_SCARA) + np.array([0.1, 0.0])
    assert rig.run(0.3, Q_SCARA, hand)[-1] == 1.0
    last_target = rig.last_target
    # The hand is lost (no /target) for 0.8 s while TaskStates keep coming.
    lost_from = rig.now
    weights, statuses, times = [], [], []
    for _ in range(800):
        if round((rig.now - lost_from) / PERIOD) % 100 == 0:
            rig.task()
        rig.joint(Q_SCARA)
        weights.append(rig.cycle.weight)
        statuses.append(rig.cycle.status)
        times.append(rig.now)
    gone = last_target + timeout  # the ramp starts timeout after the last accepted target
    expected = [1.0 - smoothstep((t - gone) / fade) for t in times]
    assert np.allclose(weights, expected, rtol=0.0, atol=1e-12)
    assert weights[-1] == 0.0 and max(np.abs(np.diff(weights))) <= 15 / 8 / fade * PERIOD
    assert all(s == 'target_lost' for s, t in zip(statuses, times, strict=True) if t > gone)
    assert all(s == 'ok' for s, t in zip(statuses, times, strict=True) if t <= gone)
    # The hand returns: the task fades in from the first accepted target.
    back = rig.now
    weights = rig.run(0.4, Q_SCARA, hand)
    times = [back + (i + 1) * PERIOD for i in range(len(weights))]
    assert np.allclose(weights, [smoothstep((t - back) / fade) for t in times], rtol=0.0,
                       atol=1e-9)
    assert weights[-1] == 1.0 and rig.cycle.status == 'ok'


def test_no_task_state_for_the_timeout_fades_the_task_out_and_task_states_fade_it_in(scara):
    timeout, fade = 0.3, 0.25
    rig = Rig(scara, task_state_timeout=timeout, task_fade_time=fade)
    hand = rig.tool(Q_SCARA) + np.array([0.1, 0.0])
    rig.run(0.2, Q_SCARA, hand)
    last_task_state = rig.last_task_state
    weights, times, statuses = [], [], []
    for i in range(700):  # TaskStates stop, the hand stays
        if i % 10 == 0:
            rig.target(hand)
        rig.joint(Q_SCARA)
        weights.append(rig.cycle.weight)
        times.append(rig.now)
        statuses.append(rig.cycle.status)
    # The first cycle more than task_state_timeout after the last TaskState starts the fade.
    start = next(t for t in times if t - last_task_state > timeout)
    assert start - (last_task_state + timeout) <= PERIOD
    expected = [1.0 - smoothstep((t - start) / fade) if t >= start else 1.0 for t in times]
    assert np.allclose(weights, expected, rtol=0.0, atol=1e-12)
    assert statuses[-1] == 'no_task_state' and weights[-1] == 0.0
    assert texts(rig.notes, WARNING)[-1] == (f'no TaskState for {timeout:g} s: fading the '
                                             f'task out over {fade:g} s')
    assert sum('no TaskState' in text for text in texts(rig.notes)) == 1
    # TaskStates again (a new event_manager): the task fades in from their return.
    back = rig.now
    weights = rig.run(0.4, Q_SCARA, hand, task_every=0.005)
    times = [back + (i + 1) * PERIOD for i in range(len(weights))]
    assert np.allclose(weights, [smoothstep((t - back) / fade) for t in times], rtol=0.0,
                       atol=1e-9)
    assert texts(rig.notes, INFO)[-1] == 'task states resumed: fading the task in'
    assert rig.cycle.status == 'ok' and weights[-1] == 1.0


def test_a_glitch_target_is_held_and_counted_then_a_lasting_jump_is_re_anchored(scara):
    rig = Rig(scara, state_rate_hz=1000.0)  # a report each cycle
    tool = rig.tool(Q_SCARA)
    hand = tool + np.array([0.1, 0.0])
    rig.run(0.2, Q_SCARA, hand)
    assert rig.reports[-1].distance == pytest.approx(0.1, abs=1e-9)
    # One sample 0.3 m off (30 m/s): held, counted, not followed.
    rig.now += PERIOD
    assert not rig.target(hand + np.array([0.0, 0.3]))
    assert rig.cycle.target_glitches == 1
    assert 'no hand can make (1 held so far)' in texts(rig.notes, WARNING)[-1]
    held_from = len(rig.reports)
    rig.run(0.1, Q_SCARA, hand)
    assert all(abs(r.distance - 0.1) < 1e-9 for r in rig.reports[held_from:])
    assert rig.reports[-1].target_glitches == 1
    # The hand is really elsewhere (a long marker swap, 0.2 m along x): held first, then,
    # once the new place has held for confirm_time, re-anchored and glided to.
    moved_from = len(rig.reports)
    moved = hand + np.array([0.2, 0.0])
    rig.run(0.8, Q_SCARA, moved)
    assert rig.cycle.target_reanchors == 1
    assert rig.cycle.target_glitches >= 3
    distances = [r.distance for r in rig.reports[moved_from:]]
    assert distances[:150] == pytest.approx([0.1] * 150, abs=1e-9)  # held for 0.15 s
    assert distances[-1] == pytest.approx(float(np.linalg.norm(moved - tool)), abs=1e-6)
    assert max(np.abs(np.diff(distances))) < 2e-3  # glided, no 0.2 m step


def test_a_burst_of_event_task_states_never_steps_a_beyond_the_ramp(scara):
    """The event_manager ramps a (eq. 13) between two tasks on random events and publishes
    at 200 Hz, but starved, its TaskStates arrive in bursts after gaps of 0.1-0.3 s. The
    controller's a never changes per cycle by more than four full ramps' peak rate (15/8 /
    task_fade_time each) allow: the event_manager's own (up to two ramps in progress for
    random events, event_weight), the hold's blend of the offset a burst lands at (one,
    signal_hold) and of its rate jump. Found: up to 3.7 over 20 seeds; taken as they come,
    the bursts step a by 200-340 ramps' worth."""
    rng = np.random.default_rng(11)
    fade = DEFAULTS['task_fade_time']
    rig = Rig(scara)
    hand = rig.tool(Q_SCARA) + np.array([0.1, 0.0])
    tasks = {'follow': FOLLOW, 'wide_follow': WIDE}
    manager = EventWeightSchedule(fade, 'follow')
    next_event = T0 + rng.uniform(0.1, 0.6)
    queue, deliver_at = [], T0
    weights = []
    for i in range(6000):
        t = T0 + (i + 1) * PERIOD
        if t >= next_event:
            manager.request(str(rng.choice(list(tasks))), t)
            next_event = t + rng.uniform(0.05, 0.8)
        if i % 5 == 0:
            state = manager.evaluate(t)
            queue.append((tasks[state.active_task], t, state.weight, state.rate))
        if i % 10 == 0:
            rig.now = t - PERIOD
            rig.target(hand)
        if t >= deliver_at:
            rig.now = t - PERIOD
            for task, stamp, weight, rate in queue:
                assert rig.task(task, weight, rate, stamp)
            queue = []
            deliver_at = t + (rng.uniform(0.1, 0.3) if rng.random() < 0.3 else 0.0)
        rig.now = t - PERIOD
        rig.joint(Q_SCARA)
        weights.append(rig.cycle.weight)
    steps = np.abs(np.diff(weights))
    ramp_step = 15.0 / 8.0 / fade * PERIOD  # a full ramp's peak step per cycle
    assert max(weights) == 1.0 and min(weights) == 0.0  # the swaps happened
    assert steps.max() <= 4.0 * ramp_step, steps.max() / ramp_step


def test_the_effort_changes_by_at_most_the_rate_times_the_time_between_states(scara):
    """Random states (the law's torque jumping by up to the effort limits) at random
    intervals: each command within max_effort_rate times the time since the last state, at
    most one period's worth, and within the effort limits."""
    rng = np.random.default_rng(5)
    rate = 200.0  # N m/s
    rig = Rig(scara, dataclasses.replace(default_gains(scara), max_effort_rate=rate))
    hand = rig.tool(Q_SCARA) + np.array([0.1, 0.0])
    rig.target(hand)
    rig.task()
    limits = scara.limits.effort
    previous = np.zeros(2)
    limited = 0
    for _ in range(1500):
        dt = float(rng.choice([2e-4, 5e-4, 1e-3, 3e-3]))
        q = np.array(Q_SCARA) + rng.uniform(-0.3, 0.3, 2)
        dq = rng.uniform(-2.0, 2.0, 2)
        command = np.array(rig.joint(q, dq, dt=dt))
        bound = rate * min(dt, PERIOD)
        step = np.abs(command - previous).max()
        assert step <= bound + 1e-9, (step, bound)
        limited += step > bound - 1e-9
        assert np.all(np.abs(command) <= limits + 1e-12)
        previous = command
    assert limited > 500  # the limit acted


def test_theta_hat_adapts_only_on_cycles_whose_command_no_limit_changed(panda):
    """The Panda's first joint state at a pose leaning out (the command starts from its
    gravity hold), then still at another, the hand 0.2 m away: the commands ramp towards the
    law's torque there (37 N m on joint 2) at 1 N m a cycle, and theta_hat stays while they
    do (eq. 19 would count the torque withheld as a parameter error); once the command is
    the law's, it adapts. The same with the applied band holding the command near an echoed
    effort."""
    rig = Rig(panda)
    q = panda.home + np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.2, 0.1])
    rig.target(rig.tool(q) + np.array([0.0, 0.2, 0.0]))
    rig.task()
    previous = np.array(rig.joint(panda.home + np.array([0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0])))
    limited, free = [], []
    for _ in range(70):
        before = rig.cycle.law.theta_hat.copy()
        command = np.array(rig.joint(q))
        moved = not np.array_equal(rig.cycle.law.theta_hat, before)
        # A command 1 N m from the one before on some joint: the rate limit acted.
        (limited if np.abs(command - previous).max() >= 1.0 - 1e-12 else free).append(moved)
        previous = command
    assert len(limited) > 10 and len(free) > 20
    assert not any(limited) and all(free)
    # The simulator reports a ramp command as applied (a late burst): the band (2 N m around
    # it) moves the command, and theta_hat stays; it adapts again once the states without the
    # echo have ramped the command back to the law's.
    echo = rig.commands[10]  # a ramp command the echo still remembers (64 back)
    assert np.abs(np.array(echo) - previous).max() > 4.0
    before = rig.cycle.law.theta_hat.copy()
    rig.joint(q, effort=echo)
    assert np.array_equal(rig.cycle.law.theta_hat, before)
    for _ in range(40):  # 31 N m back at 1 N m a cycle
        rig.joint(q)
    assert not np.array_equal(rig.cycle.law.theta_hat, before)


def test_a_command_stays_in_the_band_of_an_echoed_applied_effort(scara):
    """A simulator that still applies an old command (a late burst): the commands walk back
    into max_effort_rate * applied_effort_cycles / rate_hz (2 N m) of it at 1 N m a command
    and stay there. A measured effort (never bit for bit a command sent) is not taken for
    one."""
    def ramped():
        rig = Rig(scara)
        for _ in range(12):  # dq = 1 rad/s with no target: Ks s saturates, the ramp runs
            rig.joint(Q_SCARA, (1.0, -1.0))
        return rig

    band = DEFAULTS['max_effort_rate'] * DEFAULTS['applied_effort_cycles'] / DEFAULTS['rate_hz']
    echo = ramped()
    old = echo.commands[2]
    last = np.array(echo.commands[-1])
    assert np.abs(last - np.array(old)).max() > 3.0 * band
    before = last
    for _ in range(12):
        command = np.array(echo.joint(Q_SCARA, (1.0, -1.0), effort=old))
        assert np.abs(command - before).max() <= 1.0 + 1e-12  # a step at the most
        # towards the old command, never away
        assert np.all(np.abs(command - np.array(old)) <= np.abs(before - np.array(old)))
        before = command
    assert np.all(np.abs(command - np.array(old)) <= band + 1e-12)
    measured = ramped()
    command = np.array(measured.joint(Q_SCARA, (1.0, -1.0),
                                      effort=(old[0] + 1e-9, old[1])))
    assert np.abs(command - last).max() == pytest.approx(1.0)  # the ramp goes on
    assert np.abs(command - np.array(old)).max() > 3.0 * band


def test_the_separation_cap_caps_the_pull_towards_the_hand(scara):
    """Velocity mode: the command is qdot_r, so J qdot_r is the task's reference speed (a
    still hand: the pull alone). Without the cap it pulls at its own speed; with it, no pull
    before a /hri/separation, then at most (1 + CAP_BAND) times the knee S_p allows."""
    separation = ProtectiveSeparation.from_mapping(DETECTOR)
    room = 0.03 * separation.reaction_time * (1.0 + CAP_BAND)  # a knee of 0.03 m/s
    gap = separation.distance(separation.near_speed, 0.0) + STANDOFF + room
    knee = pull_speed_knee(gap, separation.near_speed, separation,
                           DEFAULTS['max_task_speed'])
    assert knee == pytest.approx(0.03)

    def pull_speeds(cap, observe):
        rig = Rig(scara, separation=cap, mode='velocity')
        hand = rig.tool(Q_SCARA) + np.array([-0.15, 0.0])
        speeds = []
        for i in range(400):
            if i % 10 == 0:
                rig.target(hand)
            if i % 100 == 0:
                rig.task()
            if observe and i >= 100 and i % 20 == 0:
                rig.cycle.separation(rig.now, gap, separation.near_speed, 0.0)
            rig.joint(Q_SCARA)
            jac = scara.task_kinematics(np.array(Q_SCARA), np.zeros(2))[1]
            speeds.append(float(np.linalg.norm(jac @ np.array(rig.commands[-1]))))
        return np.array(speeds)

    free = pull_speeds(None, False)
    assert free[-1] > 3.0 * (1.0 + CAP_BAND) * knee
    capped = pull_speeds(separation, True)
    assert np.all(capped[:100] < 1e-9)  # no /hri/separation yet: no pull
    assert capped.max() <= (1.0 + CAP_BAND) * knee + 1e-9
    assert capped[-1] > 0.5 * knee  # and the pull the separation allows
    assert np.all(pull_speeds(separation, False) < 1e-9)


def test_the_cap_holds_the_arm_point_nearest_the_person_from_moving_towards_it(panda):
    """Velocity mode on the Panda (the command is qdot_r), away from its home pose, so the
    null space moves its elbow while the task pulls the tool. A whole-body separation names
    the pair (a point of panda_link4 and the body's point 0.2 m along the direction the
    elbow moves): while the cap acts, that point's speed towards the person, n^T J_p
    qdot_r, stays within what S_p allows, (1 + CAP_BAND) times the knee. With the tool-hand
    pair alone the elbow moves towards the person faster."""
    body = robot_body(panda, panda_package_dirs())
    separation = ProtectiveSeparation.from_mapping(DETECTOR)
    room = 0.03 * separation.reaction_time * (1.0 + CAP_BAND)  # a knee of 0.03 m/s
    gap = separation.distance(separation.near_speed, 0.0) + STANDOFF + room
    limit = (1.0 + CAP_BAND) * pull_speed_knee(gap, separation.near_speed, separation,
                                               DEFAULTS['max_task_speed'])
    q = tuple(panda.home + np.array([0.4, 0.3, -0.4, 0.4, 0.3, -0.3, 0.3]))
    link = body.names.index('panda_link4')
    elbow = body.capsules(q).a[link]
    jacobian = body.point_jacobian(q, link, elbow)

    def elbow_velocities(pair):
        rig = Rig(panda, separation=separation, robot_body=body, mode='velocity')
        hand = rig.tool(q) + np.array([0.0, 0.15, 0.0])
        velocities = []
        for i in range(300):
            if i % 10 == 0:
                rig.target(hand)
            if i % 100 == 0:
                rig.task()
            if i % 20 == 0:
                rig.cycle.separation(rig.now, gap, separation.near_speed, 0.0,
                                     pair and pair())
            rig.joint(q)
            velocities.append(jacobian @ np.array(rig.commands[-1]))
        return np.array(velocities)

    tool_hand = elbow_velocities(None)
    normal = tool_hand[-1] / np.linalg.norm(tool_hand[-1])
    towards = tool_hand @ normal
    assert towards[-1] > 2.0 * limit
    person = elbow + 0.2 * normal
    held = elbow_velocities(lambda: ('panda_link4', tuple(elbow), tuple(person))) @ normal
    assert held.max() <= limit + 1e-9
    assert held[-1] > 0.5 * limit  # it may still come as close as S_p lets it
    rig = Rig(panda, separation=separation, robot_body=body, mode='velocity')
    rig.cycle.separation(rig.now, gap, separation.near_speed, 0.0,
                         ('gripper', tuple(elbow), tuple(person)))
    assert "separation pair on 'gripper', a link the controller does not know" in \
        texts(rig.notes, WARNING)[0]


def test_reports_come_on_the_state_schedule_and_count_late_commands(scara):
    rig = Rig(scara)  # state_rate_hz 100: a report every 10th 1 ms cycle
    hand = rig.tool(Q_SCARA) + np.array([0.1, 0.0])
    rig.target(hand)
    rig.task()
    for i in range(100):
        rig.now += PERIOD
        command = rig.cycle.joint_state(rig.now, Q_SCARA, (0.0, 0.0), rig.now)
        late = 2e-3 if i % 4 == 0 else 1e-3  # over 1.5 periods after the stamp: a miss
        report = rig.cycle.sent(rig.now, rig.now + late)
        assert (report is not None) == (i % 10 == 0)
        if report is not None:
            assert report.effort == command and report.task == 'follow'
            assert report.input_age == pytest.approx(late)
            assert report.lyapunov > 0.0 and report.weight == 1.0 and report.status == 'ok'
            assert report.distance == pytest.approx(0.1, abs=1e-9)
    assert rig.cycle.deadline_misses == 25 and rig.cycle.cycles == 100


def test_bad_inputs_are_dropped_with_the_lines_the_logs_are_searched_for(scara):
    rig = Rig(scara, max_target_distance=1.0)
    rig.now += 1.0
    assert rig.cycle.joint_state(rig.now, (float('nan'), 0.0), (0.0, 0.0), rig.now) is None
    assert rig.joint(Q_SCARA) is not None
    assert rig.cycle.joint_state(rig.now, Q_SCARA, (0.0, 0.0), rig.now - 0.1) is None
    assert not rig.target((float('nan'), 0.0))
    assert not rig.target((1.0, 0.5))
    assert rig.target((0.4, 0.1)) and not rig.target((0.4, 0.1))  # the same stamp
    assert not rig.task(weight=1.5)
    assert not rig.task(FOLLOW._replace(name='broken', a1=-1.0))
    assert [(note.kind, note.text.split(':')[0]) for note in rig.notes] == [
        ('joint_state_non_finite', 'joint state dropped'),
        ('joint_state_stamp', 'joint state dropped'),
        ('target_non_finite', 'target dropped'), ('target_far', 'target dropped'),
        ('target_stamp', 'target dropped'), ('task_state_weight', 'task state dropped'),
        ('task_state_task', 'task state dropped')]
    assert 'stamp went back 0.1000 s' in rig.notes[1].text
    assert 'farther than max_target_distance 1 m' in rig.notes[3].text
    assert "task state dropped: task 'broken'" in rig.notes[6].text


def test_a_body_moves_at_the_speed_of_its_stamped_frames_and_a_gap_leaves_it_still(scara):
    """Two /human/body frames 10 ms apart by their stamps (received 30 ms apart): the head
    comes at 0.5 m/s, which the law's band widens with; after a gap longer than
    body_timeout the next frame is still; a glitch of 1 m in 10 ms is capped at 3 m/s."""
    rig = Rig(scara)
    cycle, timeout = rig.cycle, rig.cycle.settings.body_timeout
    assert cycle.body(T0, ['head'], [(1.0, 0.0, 1.0)], stamp=50.0)
    assert cycle.body(T0 + 0.03, ['head'], [(0.995, 0.0, 1.0)], stamp=50.01)
    np.testing.assert_allclose(cycle._body_at(T0 + 0.03).velocity_a, [[-0.5, 0.0, 0.0]])
    assert cycle.body(T0 + 0.04 + timeout, ['head'], [(0.99, 0.0, 1.0)],
                      stamp=50.02 + timeout)
    np.testing.assert_allclose(cycle._body_at(T0 + 0.04 + timeout).velocity_a, [[0, 0, 0]])
    assert cycle.body(T0 + 0.05 + timeout, ['head'], [(1.99, 0.0, 1.0)],
                      stamp=50.03 + timeout)
    assert np.linalg.norm(cycle._body_at(T0 + 0.05 + timeout).velocity_a) == \
        pytest.approx(3.0)
    assert not cycle.body(T0 + 0.06 + timeout, ['head', 'head'], [(1.0, 0.0, 1.0)] * 2)


def test_the_work_a_command_does_not_wait_for_is_done_off_its_path(scara, monkeypatch):
    """A new body's arrays for the compiled barrier are built when it comes
    (ArmController.take_person), and the law's finish_cycle (the reach-round's solve steps)
    runs in `sent`, after each law cycle's command: the joint state -> command path does
    neither (20-40 us and about 0.1 ms of some cycles, in-process)."""
    calls = {'arrays': 0, 'finish': 0}
    person_arrays, finish = arm_law._person_arrays, ArmController.finish_cycle

    def counted_arrays(*args):
        calls['arrays'] += 1
        return person_arrays(*args)

    def counted_finish(self):
        calls['finish'] += 1
        finish(self)

    monkeypatch.setattr(arm_law, '_person_arrays', counted_arrays)
    monkeypatch.setattr(ArmController, 'finish_cycle', counted_finish)
    body = robot_body(scara)
    rig = Rig(scara)
    rig.cycle = ControlCycle(ArmController(scara, default_gains(scara), body=body),
                             rig.cycle.settings, rig.cycle.notes.append, body)
    names = ['head', 'torso', 'r_shoulder', 'r_elbow', 'r_wrist', 'body']
    q = np.array(Q_SCARA)
    for i in range(40):
        if i % 10 == 0:
            hand = rig.tool(q) + [0.05, 0.0]
            rig.target(hand)
            rig.task()
            built = calls['arrays']
            # The person's right wrist holds /target: follow exempts that hand.
            person = [(0.7, 0.05 * i / 10, z) for z in (1.6, 1.3, 1.4, 1.1)]
            person += [(*hand, 0.9), (0.7, 0.05 * i / 10, 0.9)]
            assert rig.cycle.body(rig.now, names, person, rig.now)
            assert calls['arrays'] == built + 1  # built as it comes
        built, finished = calls['arrays'], calls['finish']
        command = rig.cycle.joint_state(rig.now + 1e-3, tuple(q), (0.0, 0.0),
                                        rig.now + 1e-3)
        rig.now += 1e-3
        assert command is not None and rig.cycle.status == 'ok'
        # Built in the first cycle only: the task's exemption was not known before it.
        assert calls['arrays'] == built + (i == 0) and calls['finish'] == finished
        rig.cycle.sent(rig.now, rig.now + LATENCY)
        assert calls['finish'] == finished + 1


def test_a_failure_after_the_command_is_a_warning_and_a_failed_solve_is_dropped(scara):
    """What runs after the command (ArmController.finish_cycle) cannot stop the node: an
    error there is a throttled warning, the next cycles run; a reach-round solve whose
    arithmetic fails is dropped there (the last joint goal stays), as a fault would have
    dropped it inside the command."""
    rig = Rig(scara)
    rig.run(0.02, Q_SCARA, hand=rig.tool(Q_SCARA) + [0.05, 0.0])
    law = rig.cycle.law

    def failing_solve():
        for _ in range(law._reach.IK_STEPS_PER_CYCLE):
            yield
        raise np.linalg.LinAlgError('Singular matrix')

    law._reach._pending = (0.0, failing_solve())
    law.finish_cycle()
    assert law._reach._pending is not None  # its first steps, not yet failed
    law.finish_cycle()
    assert law._reach._pending is None

    def broken():
        raise RuntimeError('broken')

    law.finish_cycle = broken
    rig.run(0.005, Q_SCARA, hand=rig.tool(Q_SCARA) + [0.05, 0.0])
    assert texts(rig.notes, WARNING)[-1] == \
        "work after the command failed: RuntimeError('broken')"
    assert rig.cycle.status == 'ok' and len(rig.commands) == 25


def test_a_body_point_sent_as_nan_is_lost_and_the_rest_of_the_body_kept(scara):
    """A tracker that marks an occluded joint with NaN: the torso's capsule stays (the message
    is not dropped), the head's is gone, a warning names it; the head back in the next frame
    comes still, not at a speed from the NaN. A name it does not know is named too."""
    rig = Rig(scara)
    cycle = rig.cycle
    names = ['head', 'torso', 'body']
    standing = [(1.0, 0.0, 1.6), (1.0, 0.0, 1.3), (1.0, 0.0, 0.9)]
    assert cycle.body(T0, names, standing, stamp=50.0)
    assert cycle.body(T0 + 0.01, names, [(float('nan'), 0.0, 1.6), *standing[1:]], stamp=50.01)
    assert cycle._body_at(T0 + 0.01).names == ('torso',)
    assert texts(rig.notes, WARNING)[-1] == 'body points not finite, taken as lost: head'
    assert cycle.body(T0 + 0.02, names, standing, stamp=50.02)
    human = cycle._body_at(T0 + 0.02)
    assert human.names == ('head', 'torso')
    np.testing.assert_array_equal(human.velocity_a, np.zeros((2, 3)))
    # A name that is no REP-155 point: named in a warning, the rest kept.
    assert cycle.body(T0 + 0.03, ['Head', *names[1:]], standing, stamp=50.03)
    assert cycle._body_at(T0 + 0.03).names == ('torso',)
    assert texts(rig.notes, WARNING)[-1].startswith('body points ignored: Head (not REP-155')


def test_a_hand_or_body_in_another_frame_is_dropped_with_its_frame_named(scara):
    """The controller transforms nothing: a /target or /human/body in a frame other than
    base_frame would be followed or kept clear of at the wrong place, so it is dropped with
    a warning naming both frames; an unset frame is taken as the base frame."""
    rig = Rig(scara, base_frame='world')
    cycle = rig.cycle
    assert not cycle.target(T0, (0.4, 0.3), 50.0, 'camera')
    assert texts(rig.notes, WARNING)[-1] == \
        "target dropped: frame 'camera' is not base_frame 'world'"
    assert cycle.target(T0, (0.4, 0.3), 50.0, 'world')
    assert cycle.target(T0 + 0.01, (0.4, 0.3), 50.01, '')
    standing = [(1.0, 0.0, 1.3), (1.0, 0.0, 0.9)]
    assert not cycle.body(T0, ['torso', 'body'], standing, 50.0, 'base')
    assert texts(rig.notes, WARNING)[-1] == \
        "body dropped: frame 'base' is not base_frame 'world'"
    assert cycle._body_at(T0) is None
    assert cycle.body(T0, ['torso', 'body'], standing, 50.0, 'world')
    assert cycle._body_at(T0).names == ('torso',)
