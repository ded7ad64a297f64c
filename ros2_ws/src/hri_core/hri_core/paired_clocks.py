"""One instant read on two clocks: a monotonic clock for schedules and the ROS clock for stamps.

No ROS import. A node that evaluates a schedule at `time.monotonic()` and stamps the result
with the ROS clock reads the two clocks one after the other; a process preempted between the
two reads (a loaded machine: milliseconds) stamps the value with a time it does not stand for.
`read_together` reads the second clock between two reads of the first and takes the reading
whose two monotonic reads lie within `tolerance`, trying up to `attempts` times.
"""

from collections.abc import Callable
from typing import TypeVar

Stamp = TypeVar('Stamp')

#: Largest spread (s) of the two monotonic reads around the other clock's read that counts as
#: one instant; a read without preemption takes about a microsecond.
DEFAULT_TOLERANCE = 1e-4
DEFAULT_ATTEMPTS = 5


def read_together(monotonic: Callable[[], float], other: Callable[[], Stamp],
                  tolerance: float = DEFAULT_TOLERANCE,
                  attempts: int = DEFAULT_ATTEMPTS) -> tuple[float, Stamp]:
    """(monotonic time in s, the other clock's reading) of one instant.

    `other` is read between two calls of `monotonic`; the monotonic time returned is their
    midpoint. The first pair within `tolerance` s is returned, else the closest of `attempts`.
    Raises ValueError for a negative tolerance or fewer than one attempt.
    """
    if not tolerance >= 0.0:
        raise ValueError(f'tolerance must be >= 0 s, got {tolerance}')
    if attempts < 1:
        raise ValueError(f'attempts must be >= 1, got {attempts}')
    best = None
    for _ in range(attempts):
        before = monotonic()
        reading = other()
        after = monotonic()
        spread = after - before
        if best is None or spread < best[0]:
            best = (spread, 0.5 * (before + after), reading)
        if spread <= tolerance:
            break
    return best[1], best[2]
