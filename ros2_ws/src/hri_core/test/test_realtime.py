"""Unit tests of hri_core.realtime: the SCHED_FIFO request (the OS call itself is mocked, so
that the test process keeps its normal scheduling on a shared machine)."""

import errno
import os

import pytest

from hri_core import realtime


def test_priority_zero_turns_it_off_without_an_os_call(monkeypatch):
    def refuse(*args):
        raise AssertionError('no OS call expected')

    monkeypatch.setattr(os, 'sched_setscheduler', refuse)
    result = realtime.request_sched_fifo(0)
    assert not result.granted and 'off' in result.description


@pytest.mark.parametrize('priority', [-1, 100, 1.5, True, '50'])
def test_bad_priorities_are_rejected(priority):
    with pytest.raises(ValueError, match='priority must be an integer in 0..99'):
        realtime.request_sched_fifo(priority)


def test_every_thread_gets_the_policy(monkeypatch):
    calls = []
    monkeypatch.setattr(os, 'sched_setscheduler',
                        lambda tid, policy, param: calls.append(
                            (tid, policy, param.sched_priority)))
    result = realtime.request_sched_fifo(50)
    threads = {int(tid) for tid in os.listdir('/proc/self/task')}
    assert result.granted and result.priority == 50 and 'granted' in result.description
    assert {tid for tid, _, _ in calls} >= threads
    assert {(policy, priority) for _, policy, priority in calls} == {(os.SCHED_FIFO, 50)}


def test_a_refusal_is_reported_and_changes_nothing(monkeypatch):
    def refuse(tid, policy, param):
        raise PermissionError(errno.EPERM, 'Operation not permitted')

    monkeypatch.setattr(os, 'sched_setscheduler', refuse)
    result = realtime.request_sched_fifo(50)
    assert not result.granted
    assert 'refused (Operation not permitted' in result.description
    assert 'default scheduler' in result.description
