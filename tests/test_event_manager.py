"""Topic-level tests of the event_manager: loading tasks, switching on events, bad input."""

import math
import time

import pytest
from hri_interfaces.msg import TaskEvent, TaskParameters, TaskState
from rcl_interfaces.srv import SetParameters

from hri_bringup.processes import wait_for
from hri_core.node_common import stamp_seconds
from hri_core.topics import LEARNED_TASKS_QOS, TASK_STATE_QOS
from tests.common import set_parameter, wait_for_service

RAMP_TIME = 0.5

pytestmark = pytest.mark.integration


@pytest.fixture
def manager(live_loop, probe):
    """A running event_manager with Table I's tasks, `follow` faded in, and its state list."""
    states = probe.collect('/hri/task_state', TaskState, TASK_STATE_QOS)
    # The live loop's event_manager alone: Table I's tasks, initial task follow.
    process = live_loop({'event_manager': {'ramp_time': RAMP_TIME}},
                        nodes=['event_manager'])['event_manager']
    assert wait_for(lambda: states and states[-1].phase == 'active', 20.0), process.log()
    events = probe.publisher('/hri/events', TaskEvent, 100)
    assert wait_for(lambda: events.get_subscription_count() > 0, 10.0)
    return process, states, events


def weights_are_continuous(states: list[TaskState], max_rate: float) -> bool:
    """No jump in a(E, t): consecutive samples differ by at most max_rate * dt (+ slack)."""
    for before, after in zip(states, states[1:], strict=False):
        dt = (after.header.stamp.sec - before.header.stamp.sec
              + 1e-9 * (after.header.stamp.nanosec - before.header.stamp.nanosec))
        if abs(after.weight - before.weight) > max_rate * max(dt, 0.0) + 0.02:
            return False
    return True


def test_event_switches_task_through_a_smooth_ramp(manager):
    process, states, events = manager
    start = len(states)
    events.publish(TaskEvent(name='hand_close', task='avoid'))
    assert wait_for(lambda: states[-1].task.name == 'avoid'
                    and states[-1].phase == 'active', 10.0), process.log()
    ramp = states[start:]
    phases = [s.phase for s in ramp]
    assert 'fading_out' in phases and 'fading_in' in phases
    assert min(s.weight for s in ramp) < 0.05
    assert all(0.0 <= s.weight <= 1.0 for s in ramp)
    # eq. 13: bounded rate (quintic smoothstep: 15/8 per ramp_time) and no jump.
    assert max(abs(s.weight_rate) for s in ramp) <= 15.0 / 8.0 / RAMP_TIME * 1.01
    assert weights_are_continuous(ramp, 15.0 / 8.0 / RAMP_TIME)
    # >= 100 Hz during the ramp: 2 ramps of RAMP_TIME s.
    assert len(ramp) >= 100 * 2 * RAMP_TIME * 0.8
    assert ramp[-1].event == 'hand_close'
    assert math.isclose(ramp[-1].task.d1, 0.183)


def heartbeats(states: list, seconds: float) -> list[float]:
    """The stamps (s) of the TaskStates that arrive over the next `seconds` s."""
    start = len(states)
    time.sleep(seconds)
    return [stamp_seconds(s.header.stamp) for s in states[start:]]


def test_heartbeat_follows_heartbeat_period_between_ramps(manager, probe):
    # With nothing to ramp the node's timer runs at heartbeat_period, not publish_rate_hz:
    # a heartbeat_period set at run time takes over at once, and an event still ramps at
    # publish_rate_hz.
    process, states, events = manager
    client = probe.node.create_client(SetParameters, '/event_manager/set_parameters')
    assert wait_for_service(client, 10.0)
    assert set_parameter(client, 'heartbeat_period', 5.0).successful
    assert len(heartbeats(states, 1.0)) <= 1
    assert set_parameter(client, 'heartbeat_period', 0.1).successful
    stamps = heartbeats(states, 1.0)  # not after the 5 s period's next tick
    assert 5 <= len(stamps) <= 12, stamps  # 10 due; a loaded machine delays some
    assert set_parameter(client, 'heartbeat_period', 1.0).successful
    time.sleep(0.2)
    stamps = heartbeats(states, 3.0)
    assert 1 <= len(stamps) <= 4, stamps
    start = len(states)
    events.publish(TaskEvent(name='hand_close', task='avoid'))
    assert wait_for(lambda: states[-1].task.name == 'avoid'
                    and states[-1].phase == 'active', 10.0), process.log()
    assert len(states) - start >= 100 * 2 * RAMP_TIME * 0.8


def test_unknown_task_event_is_ignored(manager):
    process, states, events = manager
    events.publish(TaskEvent(name='bogus', task='no_such_task'))
    assert wait_for(lambda: 'no_such_task' in process.log(), 5.0)
    time.sleep(0.5)
    assert states[-1].task.name == 'follow' and states[-1].phase == 'active'
    assert process.alive()


def test_invalid_task_is_rejected_and_current_kept(manager, probe):
    process, states, _ = manager
    tasks = probe.publisher('/hri/task', TaskParameters, LEARNED_TASKS_QOS)
    bad = TaskParameters(name='follow', s=0, a1=1.0, a2=1.0, d1=0.0, d2=0.05, n=3)
    tasks.publish(bad)
    inverted = TaskParameters(name='follow', s=1, a1=1.0, a2=1.0, d1=0.3, d2=0.1, n=3)
    tasks.publish(inverted)
    assert wait_for(lambda: process.log().count('rejected') >= 1, 10.0), process.log()
    time.sleep(0.5)
    assert states[-1].task.name == 'follow'
    assert math.isclose(states[-1].task.d2, 0.041)
    assert process.alive()


def test_new_task_on_topic_becomes_switchable(manager, probe):
    process, states, events = manager
    tasks = probe.publisher('/hri/task', TaskParameters, LEARNED_TASKS_QOS)
    tasks.publish(TaskParameters(name='wide_follow', s=1, a1=2.0, a2=20.0, d1=0.0, d2=0.1,
                                 n=3, cost=0.01, iterations=12))
    assert wait_for(lambda: 'wide_follow' in process.log(), 10.0), process.log()
    events.publish(TaskEvent(name='go_wide', task='wide_follow'))
    assert wait_for(lambda: states[-1].task.name == 'wide_follow'
                    and states[-1].phase == 'active', 10.0), process.log()
    assert math.isclose(states[-1].task.d2, 0.1)


def test_events_faster_than_the_ramp_keep_weight_continuous(manager):
    process, states, events = manager
    start = len(states)
    for i in range(200):
        events.publish(TaskEvent(name=f'burst{i}', task=('avoid', 'follow_safe', 'follow')[i % 3]))
        time.sleep(0.002)
    events.publish(TaskEvent(name='last', task='follow_safe'))
    assert wait_for(lambda: states[-1].task.name == 'follow_safe'
                    and states[-1].phase == 'active', 15.0), process.log()
    burst = states[start:]
    assert all(0.0 <= s.weight <= 1.0 and math.isfinite(s.weight_rate) for s in burst)
    # Overlapping ramps may add their rates (event_weight's bound), never jump.
    assert weights_are_continuous(burst, 2 * 15.0 / 8.0 / (RAMP_TIME / 2))
    assert process.alive()


def test_unknown_initial_task_exits_with_reason(live_loop):
    process = live_loop({'event_manager': {'initial_task': 'dance'}},
                        nodes=['event_manager'])['event_manager']
    assert process.wait(20.0) == 1
    log = process.log()
    assert "initial_task 'dance' is not a known task" in log
    assert 'Traceback' not in log


# Follow tasks whose pull dies far from their region (a fit from a demonstration that started
# 0.1 m from x_r, and the demo's follow row with a1 x 10): the arm would never move toward a
# still hand 0.27 m away.
DEAF_FOLLOW = TaskParameters(name='deaf_follow', s=1, a1=1000.0, a2=237.8, d1=0.0, d2=0.033,
                             n=3)
DEAF_FOLLOW_STEEP = TaskParameters(name='follow', s=1, a1=329.7, a2=1000.0, d1=0.0, d2=0.041,
                                   n=3)


def test_a_task_that_does_not_reach_is_refused_and_current_kept(manager, probe):
    process, states, events = manager
    tasks = probe.publisher('/hri/task', TaskParameters, LEARNED_TASKS_QOS)
    tasks.publish(DEAF_FOLLOW)
    assert wait_for(lambda: 'would not move' in process.log(), 10.0), process.log()
    time.sleep(1.1)  # past the warning's throttle
    tasks.publish(DEAF_FOLLOW_STEEP)  # under the active task's name: no switch either
    assert wait_for(lambda: process.log().count('would not move') >= 2, 10.0), process.log()
    warnings = [line for line in process.log().splitlines() if 'would not move' in line]
    assert "task 'deaf_follow' on /hri/task rejected" in warnings[0], warnings
    assert "task 'follow' on /hri/task rejected" in warnings[1], warnings
    assert all("keeping task 'follow'" in line for line in warnings), warnings
    events.publish(TaskEvent(name='go_deaf', task='deaf_follow'))
    assert wait_for(lambda: "unknown task 'deaf_follow'" in process.log(), 5.0), process.log()
    assert states[-1].task.name == 'follow' and states[-1].phase == 'active'
    assert math.isclose(states[-1].task.a1, 1.291)
    assert process.alive()


def test_a_task_file_that_does_not_reach_is_refused_at_start(live_loop, tmp_path):
    tasks = tmp_path / 'tasks'
    tasks.mkdir()
    (tasks / 'deaf_follow.yaml').write_text(
        'name: deaf_follow\ns: 1\na1: 1000.0\na2: 237.8\nd1: 0.0\nd2: 0.033\nn: 3\n'
        'cost: 0.0\niterations: 0\n')
    (tasks / 'follow.yaml').write_text(
        'name: follow\ns: 1\na1: 1.291\na2: 13.66\nd1: 0.0\nd2: 0.041\nn: 3\n'
        'cost: 0.0\niterations: 2468\n')
    process = live_loop({'event_manager': {'tasks_dir': str(tasks), 'initial_task': ''}},
                        nodes=['event_manager'])['event_manager']
    assert wait_for(lambda: 'task(s) loaded' in process.log(), 20.0), process.log()
    log = process.log()
    assert "task 'deaf_follow' from" in log and 'refused' in log, log
    assert '1 task(s) loaded (follow)' in log, log
    assert 'Traceback' not in log
