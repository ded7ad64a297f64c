"""A scheduling canary: how late this machine lets a real-time thread run, on one CPU.

Run as a process of its own (`python tests/scheduling_canary.py CPU PRIORITY`): pinned to CPU,
at SCHED_FIFO PRIORITY (above the nodes' own), it sleeps to 1 ms ticks and notes every wake-up
later than LATE_AFTER s. Nothing in the machine's user space can hold such a thread back, so
its lateness is what the kernel and, on a virtual machine, the host took from that CPU (a
vCPU the host does not run stops every thread on it). On SIGTERM or SIGINT it prints its
notes as one JSON object, {"granted": bool, "stalls": [[wake time (system clock, s),
lateness (s)], ...]}, and exits 0. Its first line, "canary up", says it is ticking.
"""

import gc
import json
import os
import signal
import sys
import time

PERIOD = 1e-3  # s
LATE_AFTER = 2e-3  # s


def main() -> int:
    cpu, priority = int(sys.argv[1]), int(sys.argv[2])
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        granted = True
    except OSError:
        granted = False  # the notes then include ordinary scheduling too
    stalls = []
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    gc.disable()  # the loop allocates only its notes: no collector pause counts as a stall
    print('canary up', flush=True)
    tick = time.monotonic()
    while not stop:
        tick += PERIOD
        pause = tick - time.monotonic()
        if pause > 0.0:
            time.sleep(pause)
        late = time.monotonic() - tick
        if late > LATE_AFTER:
            stalls.append((time.time(), late))
            if late > 10 * PERIOD:
                tick = time.monotonic()  # no burst of catch-up ticks after a long stall
    print(json.dumps({'granted': granted, 'stalls': stalls}), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
