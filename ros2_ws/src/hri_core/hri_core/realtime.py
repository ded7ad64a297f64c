"""Real-time scheduling of a node's process where the OS allows it (SCHED_FIFO). No ROS import.

A 1 kHz loop that shares its cores with other work keeps its deadlines only if the scheduler
runs it first as soon as its input arrives. Like ros2_control's realtime_tools
(`configure_sched_fifo`), `request_sched_fifo` asks Linux for the SCHED_FIFO policy at a given
priority; unlike it, it applies the policy to every thread of the process, because the
middleware's receive threads, created before the node's code runs, carry the messages the loop
waits for. Threads created afterwards inherit the policy.

Whether it is granted depends on the OS: root or CAP_SYS_NICE, or an RLIMIT_RTPRIO (`ulimit -r`)
at least the priority. Where it is refused, nothing changes and the caller logs the reason;
the kernel's real-time throttling (kernel.sched_rt_runtime_us, 95 % by default) keeps a
runaway SCHED_FIFO thread from starving the rest of the machine.
"""

import os
from dataclasses import dataclass

#: Highest SCHED_FIFO priority on Linux (sched_get_priority_max(SCHED_FIFO)).
MAX_PRIORITY = 99


@dataclass(frozen=True)
class SchedulingResult:
    """Outcome of a request: granted (bool), priority asked for, and a one-line description."""

    granted: bool
    priority: int
    description: str


def request_sched_fifo(priority: int) -> SchedulingResult:
    """Ask for SCHED_FIFO at `priority` (1..99) for every thread of this process; 0: off.

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
    done = 0
    for tid in threads:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
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
