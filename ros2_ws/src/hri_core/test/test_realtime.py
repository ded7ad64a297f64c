"""Unit tests of hri_core.realtime: the SCHED_FIFO request (the OS call itself is mocked, or
made in a child process, so that the test process keeps its normal scheduling on a shared
machine) and the CPU wake-up latency request (written to a file of the test's own in place of
/dev/cpu_dma_latency)."""

import errno
import gc
import os
import struct
import subprocess
import sys

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


def test_reset_on_fork_is_asked_for_with_the_policy(monkeypatch):
    calls = []
    monkeypatch.setattr(os, 'sched_setscheduler',
                        lambda tid, policy, param: calls.append(policy))
    assert realtime.request_sched_fifo(50, reset_on_fork=True).granted
    assert set(calls) == {os.SCHED_FIFO | os.SCHED_RESET_ON_FORK}


CHILD_POLICY = """
import os, subprocess, sys
from hri_core import realtime
result = realtime.request_sched_fifo(10, reset_on_fork=sys.argv[1] == 'reset')
if not result.granted:
    print('refused')
    sys.exit(0)
child = subprocess.run([sys.executable, '-c', 'import os; print(os.sched_getscheduler(0))'],
                       capture_output=True, text=True, check=True)
print(os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK, child.stdout.strip())
"""


@pytest.mark.parametrize('mode', ['reset', 'inherit'])
def test_processes_started_after_a_reset_on_fork_request_run_at_the_default_policy(mode):
    # In a child process of its own, so that this test process keeps its normal scheduling.
    result = subprocess.run([sys.executable, '-c', CHILD_POLICY, mode], capture_output=True,
                            text=True, timeout=30, check=True)
    if result.stdout.strip() == 'refused':
        pytest.skip('SCHED_FIFO is not granted here (needs CAP_SYS_NICE or ulimit -r)')
    own, started = (int(value) for value in result.stdout.split())
    assert own == os.SCHED_FIFO
    assert started == (os.SCHED_OTHER if mode == 'reset' else os.SCHED_FIFO)


def test_a_refusal_is_reported_and_changes_nothing(monkeypatch):
    def refuse(tid, policy, param):
        raise PermissionError(errno.EPERM, 'Operation not permitted')

    monkeypatch.setattr(os, 'sched_setscheduler', refuse)
    result = realtime.request_sched_fifo(50)
    assert not result.granted
    assert 'refused (Operation not permitted' in result.description
    assert 'default scheduler' in result.description


def open_descriptors() -> int:
    return len(os.listdir('/proc/self/fd'))


def test_a_wakeup_latency_is_written_as_the_kernel_reads_it_and_held(tmp_path):
    device = tmp_path / 'cpu_dma_latency'
    device.write_bytes(b'')
    before = open_descriptors()
    request = realtime.hold_cpu_wakeup_latency(0, str(device))
    assert request.granted and request.microseconds == 0
    assert 'idle CPUs poll' in request.description
    assert struct.unpack('=i', device.read_bytes()) == (0,)  # a native 32-bit integer
    assert open_descriptors() == before + 1  # the kernel holds the request while it is open
    request.release()
    request.release()
    assert open_descriptors() == before


def test_a_wakeup_latency_request_ends_with_its_object(tmp_path):
    device = tmp_path / 'cpu_dma_latency'
    device.write_bytes(b'')
    before = open_descriptors()
    request = realtime.hold_cpu_wakeup_latency(20, str(device))
    assert 'within 20 us' in request.description
    del request
    gc.collect()
    assert open_descriptors() == before


def test_minus_one_turns_the_wakeup_latency_off_without_opening_anything(tmp_path):
    request = realtime.hold_cpu_wakeup_latency(-1, str(tmp_path / 'absent'))
    assert not request.granted and 'off' in request.description


def test_a_wakeup_latency_refusal_is_reported_and_changes_nothing(tmp_path):
    before = open_descriptors()
    request = realtime.hold_cpu_wakeup_latency(0, str(tmp_path / 'absent'))
    assert not request.granted
    assert 'refused' in request.description and 'No such file' in request.description
    assert open_descriptors() == before


@pytest.mark.parametrize('microseconds', [-2, realtime.MAX_WAKEUP_LATENCY + 1, 0.5, True, '0'])
def test_bad_wakeup_latencies_are_rejected(microseconds):
    with pytest.raises(ValueError, match=r'wake-up latency must be an integer in -1\.\.'):
        realtime.hold_cpu_wakeup_latency(microseconds)


def test_a_failed_write_is_refused_and_closes_what_it_opened():
    before = open_descriptors()
    request = realtime.hold_cpu_wakeup_latency(0, '/dev/full')  # opens, then ENOSPC on write
    assert not request.granted and 'refused' in request.description
    assert open_descriptors() == before
