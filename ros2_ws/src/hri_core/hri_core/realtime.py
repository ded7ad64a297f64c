"""Real-time set-up of a node's process where the OS allows it: SCHED_FIFO and the CPU wake-up
latency. No ROS import.

A 1 kHz loop that shares its cores with other work keeps its deadlines only if the scheduler
runs it first as soon as its input arrives. Like ros2_control's realtime_tools
(`configure_sched_fifo`), `request_sched_fifo` asks Linux for the SCHED_FIFO policy at a given
priority; unlike it, it applies the policy to every thread of the process, because the
middleware's receive threads, created before the node's code runs, carry the messages the loop
waits for. Threads and processes created afterwards inherit the policy, unless the request
sets SCHED_RESET_ON_FORK (`reset_on_fork`): a process that starts others, such as a benchmark
that starts the nodes it measures, should not hand its priority to them.

Whether it is granted depends on the OS: root or CAP_SYS_NICE, or an RLIMIT_RTPRIO (`ulimit -r`)
at least the priority. Where it is refused, nothing changes and the caller logs the reason;
the kernel's real-time throttling (kernel.sched_rt_runtime_us, 95 % by default) keeps a
runaway SCHED_FIFO thread from starving the rest of the machine.

`hold_cpu_wakeup_latency` is the other half of a real-time set-up, as cyclictest and rtla do
it and as Red Hat's real-time guide tells an application to: a request through the kernel's
PM QoS interface (/dev/cpu_dma_latency) that an idle CPU wake within so many microseconds,
held while the file stays open. With 0 an idle CPU polls instead of halting. The loop hands
each message from one thread to another, and a thread woken on a CPU that halted, above all
on a virtual machine whose host must resume the vCPU, then runs its code much slower
(docs/design.md, "SCHED_FIFO and CPU wake-up latency", has the figures). The kernel drops
the request when the process ends, however it ends; the price is power (and, on a virtual
machine, host CPU) while it is held.
"""

import os
import struct
import weakref
from dataclasses import dataclass

#: Highest SCHED_FIFO priority on Linux (sched_get_priority_max(SCHED_FIFO)).
MAX_PRIORITY = 99


@dataclass(frozen=True)
class SchedulingResult:
    """Outcome of a request: granted (bool), priority asked for, and a one-line description."""

    granted: bool
    priority: int
    description: str


def request_sched_fifo(priority: int, reset_on_fork: bool = False) -> SchedulingResult:
    """Ask for SCHED_FIFO at `priority` (1..99) for every thread of this process; 0: off.

    reset_on_fork: the processes (and threads) these threads start afterwards begin at the
    default policy instead of inheriting SCHED_FIFO (Linux's SCHED_RESET_ON_FORK), for a
    process that starts others, such as a benchmark's probe that starts the nodes it measures.

    Returns a SchedulingResult; never raises for a refusal (the process then runs unchanged
    with its threads' previous policy). Raises ValueError for a priority outside 0..99.
    """
    if isinstance(priority, bool) or not isinstance(priority, int) or not (
            0 <= priority <= MAX_PRIORITY):
        raise ValueError(f'real-time priority must be an integer in 0..{MAX_PRIORITY}, '
                         f'got {priority!r}')
    if priority == 0:
        return SchedulingResult(False, 0, 'real-time scheduling off (priority 0)')
    if not hasattr(os, 'sched_setscheduler'):
        return SchedulingResult(False, priority, 'SCHED_FIFO not available on this OS; '
                                'running with the default scheduler')
    try:
        threads = sorted(int(tid) for tid in os.listdir('/proc/self/task'))
    except OSError:
        threads = [0]  # no /proc: the calling thread only
    param = os.sched_param(priority)
    policy = os.SCHED_FIFO | (os.SCHED_RESET_ON_FORK if reset_on_fork else 0)
    done = 0
    for tid in threads:
        try:
            os.sched_setscheduler(tid, policy, param)
            done += 1
        except ProcessLookupError:
            continue  # the thread ended meanwhile
        except OSError as error:
            if done == 0:
                return SchedulingResult(
                    False, priority,
                    f'SCHED_FIFO priority {priority} refused ({error.strerror}: needs '
                    'CAP_SYS_NICE or `ulimit -r` >= the priority); running with the default '
                    'scheduler')
            return SchedulingResult(
                True, priority, f'SCHED_FIFO priority {priority} granted to {done} of '
                f'{len(threads)} threads ({error.strerror} for the others)')
    return SchedulingResult(True, priority,
                            f'SCHED_FIFO priority {priority} granted ({done} threads)')


#: The kernel's PM QoS interface for the CPU wake-up latency (Linux's pm_qos_interface).
CPU_DMA_LATENCY = '/dev/cpu_dma_latency'
#: Longest wake-up latency one may ask for here (1 s, in µs); -1 turns the request off.
MAX_WAKEUP_LATENCY = 1_000_000


class WakeupLatencyRequest:
    """A held PM QoS request (`hold_cpu_wakeup_latency`): granted (bool), microseconds asked
    for, a one-line description. `release()` (or the object's collection, or the process's end)
    drops it."""

    def __init__(self, granted: bool, microseconds: int, description: str,
                 fd: int | None = None):
        self.granted = granted
        self.microseconds = microseconds
        self.description = description
        self._release = weakref.finalize(self, os.close, fd) if fd is not None else None

    def release(self) -> None:
        """Drop the request (idempotent)."""
        if self._release is not None:
            self._release()


def hold_cpu_wakeup_latency(microseconds: int,
                            path: str = CPU_DMA_LATENCY) -> WakeupLatencyRequest:
    """Ask that idle CPUs wake within `microseconds` (0: they poll) while the returned request
    is held; -1: off.

    Never raises for a refusal (no such file, no permission: it needs root, or write access
    to `path`); the description then says why and nothing changes. Raises ValueError for a
    value outside -1..MAX_WAKEUP_LATENCY.
    """
    if isinstance(microseconds, bool) or not isinstance(microseconds, int) or not (
            -1 <= microseconds <= MAX_WAKEUP_LATENCY):
        raise ValueError(f'CPU wake-up latency must be an integer in -1..{MAX_WAKEUP_LATENCY} '
                         f'us, got {microseconds!r}')
    if microseconds < 0:
        return WakeupLatencyRequest(False, microseconds, 'CPU wake-up latency request off (-1)')
    fd = None
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CLOEXEC)
        os.write(fd, struct.pack('=i', microseconds))
    except OSError as error:
        if fd is not None:
            os.close(fd)
        return WakeupLatencyRequest(
            False, microseconds, f'CPU wake-up latency {microseconds} us refused ({path}: '
            f'{error.strerror}; needs root or write access); idle CPUs sleep as configured')
    how = 'idle CPUs poll' if microseconds == 0 else f'idle CPUs wake within {microseconds} us'
    return WakeupLatencyRequest(True, microseconds,
                                f'CPU wake-up latency {microseconds} us held ({how})', fd)
