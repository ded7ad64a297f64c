"""Process faults on topics: nodes killed and restarted mid-run, and every node's clean stop.

The closed loop (scara_sim, event_manager, controller, hand_sim) runs with Table I's tasks
while processes are killed with SIGKILL: every peer (sim, hand, recorder, event_manager) is
killed and restarted six times in a row (twenty in the slow tier), and the controller answers
every joint state, commands zero torque within `joint_state_timeout` without the sim and
controls each new sim within a second; without the controller the sim applies zero torque after
`command_timeout`; without the event_manager the controller fades the task out after
`task_state_timeout` and in again when TaskStates return, with no torque step. Every node's
clean stop on SIGINT and SIGTERM: tests/test_node_exit.py.

A recorder killed with SIGKILL keeps a readable bag: tests/test_recorder.py
(test_sigkill_loses_at_most_the_last_second).
"""

import itertools
import math
import signal
import time

import numpy as np
import pytest
from hri_interfaces.msg import ControllerState, TaskState
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hri_bringup.processes import LIVE_LOOP_EXECUTABLES, READY_LINES, wait_for
from hri_core.dynamics import ScaraParameters, kinetic_energy
from hri_core.node_common import load_defaults, stamp_seconds
from hri_core.topics import MONITOR_QOS
from tests.common import PAPER_TASKS
from tests.fault_tools import (
    REALTIME_PRIORITY,
    RawListener,
    SchedulingCanaries,
    SentCommands,
    applied_command_holds,
    assert_all_finite,
    controller_gaps,
    effort_change_per_step,
    lines_after,
    log_time,
    machine_stall,
    sim_joint_efforts,
)

# The 1 kHz closed loop needs the machine to itself (pytest.ini, marker exclusive).
pytestmark = [pytest.mark.integration, pytest.mark.exclusive]

# A hand 0.47 m from the end-effector's start (0.35, 0.30): the arm is still moving seconds
# after the controller is up, so the torque is not zero when a process is killed.
FAR_HAND = {'profile': 'hold', 'start': [0.50, -0.15]}
CONTROLLER_DEFAULTS = load_defaults('hri_adaptive_controller', 'controller')
SIM_DEFAULTS = load_defaults('scara_sim', 'scara_sim')
JOINT_STATE_TIMEOUT = CONTROLLER_DEFAULTS['joint_state_timeout']  # s
COMMAND_TIMEOUT = SIM_DEFAULTS['command_timeout']  # s
# Most steps the sim runs at once after a stall (1 ms each): how far its clock may jump.
MAX_CATCH_UP = SIM_DEFAULTS['max_catch_up_steps'] * 1e-3  # s
TASK_STATE_TIMEOUT = 0.5  # s, set small for the test (default 2 s)
RAMP_TIME = 0.5  # s
HEARTBEAT_PERIOD = 0.1  # s, the event_manager's TaskState period when nothing changes
SLACK = 0.05  # s: a control tick, a ControllerState period (10 ms), latency and jitter
# The restarted event_manager's fade-in, and the largest step of a between two ControllerStates
# during it: 15/8/RESTART_RAMP_TIME * 10 ms = 0.01 when every TaskState (200 Hz) arrives on
# time; the bound allows for the event_manager starved for 0.3 s on a loaded machine.
RESTART_RAMP_TIME = 2.0  # s
MAX_WEIGHT_STEP = 0.3
FADE_JITTER = 0.01  # s, see the fade-out test
TASK_FADE_TIME = 0.5  # s, the controller's fade when TaskStates stop or return (default 1 s)
MAX_EFFORT_STEP = 1.0 + 1e-9  # N m per 1 ms control cycle (the rate limit's own, to an ulp)
RESUME_WITHIN = 1.0  # s from a new sim's ready line to control (the kill test)
# The kill test: each peer killed this many times in a row, DWELL s of running between kills.
# No stretch over MAX_ANSWER (issue 15's 20 ms of sending) in which the sim ran steadily and
# applied one command while the controller sent none (a zero-torque timeout is a command),
# beyond what the machine itself held back a real-time thread on some CPU at that time:
# scheduling canaries (tests/scheduling_canary.py, SCHED_FIFO at CANARY_PRIORITY, above the
# nodes', one per CPU) measure that in the same run, on their timers' wake-ups and on
# wake-ups sent from another CPU. On this 2-core virtual machine such a thread, doing nothing
# but sleep to 1 ms ticks, woke up to 6.7 ms late in 8 s on an otherwise idle machine (the
# host's scheduling: /proc/stat counts about 0.7 % of the time as stolen); a sched_switch
# trace of two failing runs showed the controller's receive thread and the sim's stepping
# thread, woken from the other CPU, runnable for 17-40 ms while that CPU ran ordinary
# processes or idled, and moved between the CPUs at each canary tick. How long the sim applied
# one command is reported, not bounded: it also counts the sim's own stalls.
OTHER_PEERS = ('hand_sim', 'recorder', 'event_manager')
PEERS = ('scara_sim', *OTHER_PEERS)
KILLS = 3  # the default run; KILLS_SLOW under `slow`
KILLS_SLOW = 20
DWELL = 0.15  # s
MAX_ANSWER = 0.02  # s
CANARY_PRIORITY = 60
# A hand circling 0.1 m or less from the arm: the arm follows it, the torque changes every
# cycle and stays far below the effort limit (a clamped torque would look like a held one).
NEAR_CIRCLING_HAND = {'profile': 'circle', 'start': [0.40, 0.25], 'radius': 0.05,
                      'period': 6.0}
RECORDED = ['/joint_states', '/effort_controller/commands', '/hri/controller_state',
            '/hri/task_state', '/target']
STALL = 0.1  # s without a ControllerState (10 ms apart): the controller did not run


def probe_time(probe) -> float:
    """The test's ROS time (system clock, the one the nodes stamp with), s."""
    return stamp_seconds(probe.now())


def start_loop(live_loop, probe, controller_params=None, manager_params=None):
    """The closed loop following FAR_HAND; returns (processes by name, ControllerState list)."""
    states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
    processes = live_loop({
        'event_manager': {'ramp_time': RAMP_TIME, **(manager_params or {})},
        'controller': controller_params,
        'hand_sim': FAR_HAND,
    })
    assert wait_for(lambda: states and states[-1].status == 'ok' and states[-1].weight > 0.99,
                    30.0), processes['controller'].log()
    return processes, states


def zero_for_good(states: list, killed_at: float, safe) -> tuple[float, float, int]:
    """When the controller went safe for good after a kill, from its ControllerStates.

    Returns (delay: stamp of the first state from which on every state is `safe`, minus the
    kill time, s; stall: the longest the controller published nothing after the kill, s;
    held: how many states are safe at the end).
    """
    after = [s for s in list(states) if stamp_seconds(s.header.stamp) > killed_at]
    stamps = [killed_at] + [stamp_seconds(s.header.stamp) for s in after]
    unsafe = [i for i, s in enumerate(after) if not safe(s)]
    first_safe = unsafe[-1] + 1 if unsafe else 0
    assert first_safe < len(after), [(round(t - killed_at, 3), s.status)
                                     for t, s in zip(stamps[1:], after, strict=True)]
    return (stamps[first_safe + 1] - killed_at, max(np.diff(stamps)),
            len(after) - first_safe)


def allowed_delay(timeout: float, stall: float) -> float:
    """How late the controller may go safe: `timeout` after the kill, or, when it stalled
    (published nothing for longer than STALL), `timeout` after it ran again: it then takes
    the last message still queued for it as new (a stall of about 1 s happens now and then
    right after a peer is killed; see the report)."""
    return timeout + SLACK + (stall + timeout if stall > STALL else 0.0)


def assert_zero_torque_without_sim(states: list, killed_at: float, attempt: int) -> None:
    """The controller commanded zero torque within joint_state_timeout of the sim's kill at
    `killed_at` (ROS time, s) and held it (`allowed_delay`); `attempt` names the kill."""
    delay, stall, _ = zero_for_good(
        states, killed_at,
        lambda s: s.status == 'stale_joint_states' and list(s.effort) == [0.0, 0.0])
    assert delay <= allowed_delay(JOINT_STATE_TIMEOUT, stall), (
        attempt, delay, stall, [(round(stamp_seconds(s.header.stamp) - killed_at, 3),
                                 s.status, list(s.effort)) for s in list(states)
                                if stamp_seconds(s.header.stamp) > killed_at - 0.05][:400:4])


def peer_parameters(name: str, tmp_path, incarnation: int) -> dict:
    """The parameters of a peer of the kill test; each recorder writes a bag of its own."""
    if name == 'event_manager':
        return {'tasks_dir': str(PAPER_TASKS), 'initial_task': 'follow', 'ramp_time': RAMP_TIME}
    if name == 'hand_sim':
        return NEAR_CIRCLING_HAND
    if name == 'recorder':
        return {'output': str(tmp_path / f'bag-{incarnation:02d}'), 'topics': RECORDED}
    return {'realtime_priority': REALTIME_PRIORITY}


def largest_step(stamps: np.ndarray, efforts: np.ndarray) -> float:
    """Largest change of the torque the sims applied per 1 ms step of their clocks (N m),
    from their joint states in the order sent (`sim_joint_efforts`) that the probe got (a
    change across lost ones is spread over their steps)."""
    elapsed = np.diff(stamps)
    same_sim = (elapsed > 0.0) & (elapsed < 0.05)
    changes = np.max(np.abs(np.diff(efforts, axis=0)), axis=1)[same_sim]
    return float(np.max(changes / np.maximum(np.round(elapsed[same_sim] / 1e-3), 1.0),
                        initial=0.0))


@pytest.mark.parametrize('kills', [
    KILLS, pytest.param(KILLS_SLOW, marks=pytest.mark.slow, id=f'{KILLS_SLOW}-kills')])
def test_each_peer_killed_repeatedly_the_controller_answers_every_joint_state(
        nodes, probe, tmp_path, kills):
    """Hand, recorder and event_manager (at once), then the sim, each killed with SIGKILL and
    restarted `kills` times in a row around the real controller, which runs with the sim at
    SCHED_FIFO (as on a robot's computer). Once the loop is up the controller answers the
    joint states of a steadily running sim without a gap over MAX_ANSWER beyond what the
    machine held back a real-time thread at the time (`controller_gaps`, `machine_stall`);
    without the sim it commands zero torque within joint_state_timeout; a new sim gets
    commands within RESUME_WITHIN of its ready line. Like every node of the tests the peers
    are forked (tests/node_forker.py): the same nodes, started without Python's start-up, which
    here is what lets a peer come back within RESUME_WITHIN.
    """
    states = probe.collect('/hri/controller_state', ControllerState, MONITOR_QOS)
    joints = RawListener(probe, '/joint_states', JointState)
    commands = RawListener(probe, '/effort_controller/commands', Float64MultiArray)
    canaries = SchedulingCanaries(CANARY_PRIORITY)
    peers = {}
    logs = {}
    incarnations = itertools.count()
    events = []  # (system time, what happened): where a late answer falls, in its message

    def fork(*names: str) -> None:
        for name in names:
            peers[name] = nodes(*LIVE_LOOP_EXECUTABLES[name],
                                params=peer_parameters(name, tmp_path, next(incarnations)))
            logs[name] = peers[name].log_path
        events.append((time.time(), f'fork {", ".join(names)}'))

    def ready_times(*names: str) -> list[float]:
        """The time of each one's ready line (ROS clock, s), once all have logged it."""
        ready = {}

        def all_ready() -> bool:
            for name in set(names) - set(ready):
                lines = [line for line in logs[name].read_text().splitlines()
                         if READY_LINES[name] in line] if logs[name].exists() else []
                if lines:
                    ready[name] = log_time(lines[0])
            return len(ready) == len(names)

        assert wait_for(all_ready, 10.0, period=0.01), (set(names) - set(ready), [
            logs[name].read_text() for name in names if logs[name].exists()])
        return [ready[name] for name in names]

    def kill(*names: str) -> None:
        events.append((time.time(), f'kill {", ".join(names)}'))
        for name in names:
            peers[name].send(signal.SIGKILL)
        assert all(peers[name].wait(5.0) is not None for name in names), names

    try:
        fork(*PEERS)
        ready_times(*PEERS)
        controller = nodes('hri_adaptive_controller', 'controller',
                           params={'realtime_priority': REALTIME_PRIORITY})
        assert wait_for(lambda: states and states[-1].status == 'ok'
                        and states[-1].weight > 0.99, 30.0), controller.log()
        # Judged from here: the controller's own start (it discovers every peer at once) is
        # not a peer's kill; its first 0.2 s once showed a 21 ms gap.
        loop_up = time.time()
        resumed = []
        for kill_round in range(kills):
            kill(*OTHER_PEERS)
            fork(*OTHER_PEERS)
            time.sleep(DWELL)
            killed_at = probe_time(probe)
            kill('scara_sim')
            assert wait_for(lambda: states[-1].status == 'stale_joint_states', 10.0), states[-1]
            time.sleep(DWELL)
            # Zero torque within joint_state_timeout of the kill, held while the sim is gone.
            assert_zero_torque_without_sim(states, killed_at, kill_round)
            heard = len(joints)
            fork('scara_sim')
            sim_up, = ready_times('scara_sim')

            def first_controlled(heard=heard, killed_at=killed_at) -> float | None:
                """Stamp of the new sim's first joint state with a command of the controller
                in it."""
                _, stamps, efforts = sim_joint_efforts(joints, heard)
                controlled = np.flatnonzero((stamps > killed_at) & np.any(efforts, axis=1))
                return float(stamps[controlled[0]]) if len(controlled) else None

            assert wait_for(lambda: first_controlled() is not None, 10.0), \
                (kill_round, controller.log()[-2000:])
            resumed.append(first_controlled() - sim_up)
            time.sleep(DWELL)
            ready_times(*OTHER_PEERS)  # each one up before its next kill
        sent, stamps, efforts = sim_joint_efforts(joints)  # decoded once, for all three
        # Read once: the gaps and their diagnosis see the same commands.
        command_times = commands.sent_times()
        answers = controller_gaps(sent, efforts, command_times, 0.005, since=loop_up)
        stalls = canaries.stalls()
        excused = [machine_stall(stalls, at, at + span) for at, span, _ in answers]
        late = [(*gap, excuse) for gap, excuse in zip(answers, excused, strict=True)
                if gap[1] > MAX_ANSWER + excuse]
        holds = applied_command_holds(sent, stamps, efforts, 0.0)

        def around(at: float, span: float) -> dict:
            """What the probe had of both streams near a gap, for its diagnosis."""
            held = (sent >= at - 0.005) & (sent <= at + span + 0.005)
            near = (command_times >= at - 0.03) & (command_times <= at + span + 0.03)
            return {'applied': np.unique(efforts[held], axis=0).round(4).tolist(),
                    'commands (ms after the gap began)': sorted(
                        round(float(t - at) * 1e3, 1) for t in command_times[near])}

        print(f'{kills} kills of each peer; control resumed {max(resumed):.3f} s at most after '
              f'a new sim\'s ready line (median {np.median(resumed):.3f}); '
              f'{len(joints)} joint states, {len(commands)} commands; the controller\'s '
              f'longest gap {max((span for _, span, _ in answers), default=0.0) * 1e3:.0f} ms '
              f'({len(late)} over {MAX_ANSWER * 1e3:.0f} ms and the machine\'s stall then); '
              f'the canaries\' longest stall {np.max(stalls[:, 1], initial=0.0) * 1e3:.1f} ms '
              f'({len(stalls)} over 2 ms; their SCHED_FIFO '
              f'{"granted" if canaries.granted else "refused"}); longest command held by the sim '
              f'{max((span for _, span, _ in holds), default=0.0) * 1e3:.0f} ms; largest change '
              f'of the applied torque per 1 ms step {largest_step(stamps, efforts):.2f} N m')
        if answers:
            at, span, _ = max(answers, key=lambda gap: gap[1])
            print('the longest gap:', around(at, span))
        assert max(resumed) <= RESUME_WITHIN, resumed
        assert late == [], [(round(at - events[0][0], 3), round(span, 3), round(excuse, 4), [
            (round(t - at, 3), what) for t, what in events if -1.0 < t - at < 0.5],
            around(at, span)) for at, span, _, excuse in late[:20]]
        log = controller.log()
        assert log.count('joint states resumed') >= kills, log
        assert 'Traceback' not in log
        assert_all_finite(states, '/hri/controller_state')
        assert controller.alive()
    finally:
        canaries.close()


def test_controller_killed_sim_applies_zero_torque_after_command_timeout(live_loop, probe):
    processes, _ = start_loop(live_loop, probe)
    joints = RawListener(probe, '/joint_states', JointState)
    # Some seconds of joint states before the kill: the sim's clock is read off them below.
    assert wait_for(lambda: len(joints.arrivals) > 2000, 10.0)
    assert any(e != 0.0 for e in joints.messages()[-1].effort)
    sim = processes['scara_sim']
    processes['controller'].send(signal.SIGKILL)
    killed_at, killed_mono = probe_time(probe), time.monotonic()
    assert processes['controller'].wait(5.0) == -signal.SIGKILL
    assert wait_for(lambda: lines_after(sim, killed_at, 'applying zero torque'), 5.0), \
        sim.log()
    time.sleep(1.0)
    # The last command stays in force until the timeout, then the torque is zero for good.
    after = joints.messages(since=killed_mono)
    efforts = [list(m.effort) for m in after]
    assert [0.0, 0.0] in efforts, efforts[::50]
    first_zero = efforts.index([0.0, 0.0])
    again = [(i, e) for i, e in enumerate(efforts[first_zero:]) if e != [0.0, 0.0]]
    assert again == [], (f'torque again {len(again)} states after the first zero, at', again[:5])
    assert len(efforts) - first_zero > 300
    assert all(math.isfinite(v) for m in after for v in [*m.position, *m.velocity])
    # Friction brakes the free arm: its kinetic energy falls.
    energy = [kinetic_energy(np.array(m.position), np.array(m.velocity), ScaraParameters())
              for m in (after[first_zero], after[-1])]
    assert energy[1] <= energy[0] + 1e-12, energy
    # On the sim's clock (its stamps: a stalled sim neither moves the arm nor ages the
    # command; wall time would count the stall), the torque falls to zero COMMAND_TIMEOUT after
    # the sim took the last command, which may be before the kill (a controller starved just
    # before it), and at most that long after the kill. The last command is read off the
    # efforts: the first joint state that applied it. The kill on the sim's clock comes from
    # the stamps and arrival times in the 3 s before it, the least transport delay being the
    # best estimate (over 3 s: this process may itself stall).
    zero_stamp = stamp_seconds(after[first_zero].header.stamp)
    timeline = joints.timed(since=killed_mono - 3.0)
    applied = [m for _, m in timeline if stamp_seconds(m.header.stamp) < zero_stamp]
    first = len(applied) - 1
    while first > 0 and list(applied[first - 1].effort) == list(applied[-1].effort):
        first -= 1
    took_last_command = stamp_seconds(applied[first].header.stamp)
    before = [(killed_at + arrived - killed_mono - stamp_seconds(m.header.stamp))
              for arrived, m in timeline if arrived <= killed_mono]
    killed_on_sim_clock = killed_at - min(before)
    in_force, after_kill = zero_stamp - took_last_command, zero_stamp - killed_on_sim_clock
    print(f'zero torque {in_force:.3f} s after the last command, {after_kill:.3f} s after the '
          'kill (sim clock)')
    assert in_force > COMMAND_TIMEOUT - SLACK, in_force
    assert after_kill < COMMAND_TIMEOUT + MAX_CATCH_UP + SLACK, after_kill
    assert lines_after(sim, killed_at, f'no joint command for {COMMAND_TIMEOUT:g} s: '
                       'applying zero torque')
    assert sim.alive()


def test_event_manager_killed_fades_the_task_out_then_in_when_task_states_return(
        live_loop, nodes, probe):
    processes, states = start_loop(
        live_loop, probe, controller_params={'task_state_timeout': TASK_STATE_TIMEOUT,
                                             'task_fade_time': TASK_FADE_TIME},
        manager_params={'heartbeat_period': HEARTBEAT_PERIOD})
    joints = RawListener(probe, '/joint_states', JointState)
    commands = RawListener(probe, '/effort_controller/commands', Float64MultiArray)
    task_states = RawListener(probe, '/hri/task_state', TaskState)
    assert wait_for(lambda: len(joints) > 100 and len(task_states) > 0, 10.0)
    processes['event_manager'].send(signal.SIGKILL)
    killed_at = probe_time(probe)
    assert processes['event_manager'].wait(5.0) == -signal.SIGKILL
    # The controller's timeout runs from the last TaskState it got: the last one sent, which a
    # busy machine may have held back for longer than a heartbeat period before the kill.
    last_task_state = max(sent for sent in task_states.sent_times() if sent < killed_at)
    def faded_out(state) -> bool:
        return state.status == 'no_task_state' and state.weight == 0.0

    # Half a second of ControllerStates (100 Hz) at a = 0 after the fade, however late it ends
    # on a busy machine.
    assert wait_for(lambda: sum(1 for _ in itertools.takewhile(
        faded_out, reversed(list(states)))) > 50, 15.0), states[-1]
    after = [s for s in list(states) if stamp_seconds(s.header.stamp) > killed_at]
    delay, stall, held = zero_for_good(states, killed_at, faded_out)
    faded = TASK_STATE_TIMEOUT + TASK_FADE_TIME
    assert delay <= allowed_delay(faded, stall), (delay, stall)
    assert delay >= last_task_state - killed_at + faded - SLACK, (delay, stall)
    assert held > 50
    # The fade is eq. 13's ramp, seen in the ControllerStates (10 ms apart, further on a busy
    # machine): between two of them a changes by at most the quintic ramp's steepest slope
    # (15/8 per fade time) times the time between the cycles they come from. A cycle's time
    # lies between the stamp of the joint state it ran on (the state's stamp minus its
    # input_age, both from one clock read) and the state's stamp, so that time is at most the
    # stamps' difference plus the earlier state's input_age (large only where the controller
    # was held up), plus FADE_JITTER for the sim's stamps. A jump (a from 1 to 0 in a cycle)
    # is far outside.
    fading = [s for s in after if s.status == 'no_task_state']
    weights_out = np.array([s.weight for s in fading])
    assert np.count_nonzero((weights_out > 0.05) & (weights_out < 0.95)) >= 10, weights_out
    apart = np.diff([stamp_seconds(s.header.stamp) for s in fading])
    ages = np.array([s.input_age for s in fading[:-1]])
    allowed = 15.0 / 8.0 / TASK_FADE_TIME * (apart + ages + FADE_JITTER)
    assert np.all(np.abs(np.diff(weights_out)) <= allowed), (apart, ages, weights_out)
    # Until the timeout the last TaskState stays in force (a = 1, follow).
    before_timeout = [s for s in after if stamp_seconds(s.header.stamp)
                      < last_task_state + TASK_STATE_TIMEOUT - SLACK]
    assert all(s.status == 'ok' and s.weight > 0.99 for s in before_timeout), (
        round(last_task_state - killed_at, 3), [
            (round(stamp_seconds(s.header.stamp) - killed_at, 3), s.status, s.weight)
            for s in before_timeout if not (s.status == 'ok' and s.weight > 0.99)][:20])

    restart_from = len(states)
    restarted_at = probe_time(probe)
    manager = nodes('hri_adaptive_controller', 'event_manager', params={
        'tasks_dir': str(PAPER_TASKS), 'initial_task': 'follow',
        'ramp_time': RESTART_RAMP_TIME, 'heartbeat_period': HEARTBEAT_PERIOD})
    assert wait_for(lambda: states[-1].status == 'ok' and states[-1].weight == 1.0, 30.0), \
        (states[-1], manager.log())
    resumed = [s for s in states[restart_from:] if s.status == 'ok']
    # The new event_manager fades the task in from a = 0 (no jump from 0 to 1): the controller
    # goes through the ramp, in steps as fine as the TaskStates it gets.
    weights = np.array([s.weight for s in resumed])
    assert weights[0] < 0.2, weights
    assert np.count_nonzero((weights > 0.05) & (weights < 0.95)) >= 5, weights
    assert np.max(np.abs(np.diff(weights))) < MAX_WEIGHT_STEP, weights
    fade_start = next(s for s in after if s.status == 'no_task_state')
    print(f'distance to the hand {after[0].distance:.3f} m at the kill, '
          f'{fade_start.distance:.3f} m when the fade-out began; '
          f'a = 0 from {delay:.3f} s after the kill (controller stalled {stall:.3f} s); '
          f'the fade-in seen in '
          f'{np.count_nonzero(np.diff(weights))} steps, the largest '
          f'{np.max(np.abs(np.diff(weights))):.3f}')
    assert_all_finite(states, '/hri/controller_state')
    assert processes['controller'].alive()
    # No torque step through the fade-out, from before the kill until the new event_manager
    # starts: the torque the sim applied, per control cycle on its clock (commands it took
    # in late and skipped count as the cycles they were: tests.fault_tools).
    # Selected by the sim's stamps: a busy test process takes its messages in late.
    assert wait_for(lambda: stamp_seconds(joints.last().header.stamp) > restarted_at, 10.0)
    fade_out = [m for m in joints.messages() if stamp_seconds(m.header.stamp) < restarted_at]
    assert len(fade_out) > 1000
    steps = effort_change_per_step(fade_out, commands=SentCommands(commands))
    print(f'largest effort change per control cycle through the fade-out: {steps:.3f} N m')
    assert steps <= MAX_EFFORT_STEP, steps
