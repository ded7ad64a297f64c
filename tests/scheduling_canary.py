"""A scheduling canary: how late this machine lets a real-time thread run, on one CPU.

Run as a process of its own (`python tests/scheduling_canary.py CPU PRIORITY [IN OUT]`):
pinned to CPU, at SCHED_FIFO PRIORITY (above the nodes' own), it sleeps to 1 ms ticks and
notes every wake-up later than LATE_AFTER s. With IN and OUT (pipe file descriptors, the
canaries of the other CPUs in a ring) it also writes its clock to OUT every WAKE_NEXT_EVERY
ticks and notes every such message from IN that woke it later than LATE_AFTER after it was
written: a wake-up sent from another CPU, as a node's thread is woken by the middleware's
receive thread, needs the kernel to interrupt this CPU (an inter-processor interrupt, which a
virtual machine's host delivers), where a timer's wake-up does not.

Nothing in the machine's user space can hold such a thread back, so its lateness is what the
kernel and, on a virtual machine, the host took from that CPU. On SIGTERM or SIGINT it prints
its notes as one JSON object, {"granted": bool, "stalls": [[wake time (system clock, s),
lateness (s)], ...]}, and exits 0. Its first line, "canary up", says it is ticking.
"""

import gc
import json
import os
import select
import signal
import struct
import sys
import time

PERIOD = 1e-3  # s
# Every this many ticks a wake-up for the next canary: each is an interrupt between the
# virtual CPUs, which the host handles, so not at every tick.
WAKE_NEXT_EVERY = 4
LATE_AFTER = 2e-3  # s
STAMP = struct.Struct('d')  # a monotonic time (s), as written to the next canary


def main() -> int:
    cpu, priority = int(sys.argv[1]), int(sys.argv[2])
    incoming, outgoing = (int(sys.argv[3]), int(sys.argv[4])) if len(sys.argv) > 4 else (
        None, None)
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        granted = True
    except OSError:
        granted = False  # the notes then include ordinary scheduling too
    if outgoing is not None:
        os.set_blocking(outgoing, False)  # a stalled neighbour must not stop this one
    watched = [] if incoming is None else [incoming]
    stalls = []
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    gc.disable()  # the loop allocates only its notes: no collector pause counts as a stall
    print('canary up', flush=True)
    pending = b''
    ticks = 0
    tick = time.monotonic()
    while not stop:
        tick += PERIOD
        while (pause := tick - time.monotonic()) > 0.0 and not stop:
            if not watched:
                time.sleep(pause)
                continue
            if not select.select(watched, [], [], pause)[0]:
                continue
            woke = time.monotonic()
            pending += os.read(incoming, 4096)
            whole = len(pending) - len(pending) % STAMP.size
            for (written,) in STAMP.iter_unpack(pending[:whole]):
                if woke - written > LATE_AFTER:
                    stalls.append((time.time() - (time.monotonic() - woke), woke - written))
            pending = pending[whole:]
        late = time.monotonic() - tick
        if late > LATE_AFTER:
            stalls.append((time.time(), late))
            if late > 10 * PERIOD:
                tick = time.monotonic()  # no burst of catch-up ticks after a long stall
        ticks += 1
        if outgoing is not None and ticks % WAKE_NEXT_EVERY == 0:
            try:
                os.write(outgoing, STAMP.pack(time.monotonic()))
            except BlockingIOError:
                pass  # the next canary has not read for seconds: its own notes say so
            except BrokenPipeError:
                outgoing = None  # the next canary has ended
    print(json.dumps({'granted': granted, 'stalls': stalls}), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
