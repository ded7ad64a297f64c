"""Event-based weight a(E, t) of eq. 13: fade out, swap the task, fade in.

When an event asks for another task, the weight a(E, t) that multiplies the task
variable (eq. 12) falls smoothly from 1 to 0 (f_dec), the task is swapped while
a = 0, and a rises smoothly from 0 to 1 again (f_inc). The paper asks for a(E, t)
to be at least twice differentiable with a bounded rate, so that eq. 23 bounds
the Lyapunov function during the switch.

`EventWeightSchedule` is a pure state machine: the caller passes the time (s) to
every call, so it runs the same under a wall clock, a simulated clock or a test.

Shape of a ramp
---------------
A ramp that starts at rest (phase 'active' or 'idle', or the fade-in that follows
a swap) is the quintic smoothstep from the current value a0 to the target c:

    a(t) = c + (1 - s(u)) (a0 - c),   s(u) = 10 u^3 - 15 u^4 + 6 u^5,
    u = (t - t0) / T,                 T = max(ramp_time |c - a0|, min_ramp_time),

the quintic Hermite from (a0, 0, 0) to (c, 0, 0). An event that arrives during a
ramp starts a new ramp from the *current trajectory*, not from a frozen copy of
its value: the new segment blends the old trajectory a_old(t) (which keeps
running to its own end, then stays at its end value) into the new target,

    a(t) = c + (1 - s(u)) (a_old(t) - c).

Since s, s' and s'' vanish at u = 0, a, da/dt and d2a/dt2 are continuous at the
event (no jump); since s = 1 and s' = s'' = 0 at u = 1, the ramp ends exactly at c
with zero rate and acceleration. a(t) is a convex combination of values in
[0, 1], so it stays in [0, 1] for every sequence of events, without clipping
(the result is clipped only against floating-point round-off). A plain quintic
Hermite from the current (a, da/dt, d2a/dt2) to (c, 0, 0) cannot promise that: for
events that arrive mid-ramp it overshoots [0, 1] for some event times, whatever
its duration within [min_ramp_time, 4 ramp_time].

Rate bound
----------
For a ramp from rest, max |da/dt| = 15/8 |c - a0| / T <= 15 / (8 ramp_time):
a full fade (1 -> 0 or 0 -> 1) takes ramp_time, a partial one proportionally
less, but never less than min_ramp_time. During a blend,
|da/dt| <= s'(u) |a_old - c| + (1 - s(u)) |da_old/dt|, so with n ramps in progress
|da/dt| <= n 15 / (8 min_ramp_time) (n - 1 is the number of events within the
last ramp_time). With the default min_ramp_time = ramp_time / 2, random event
sequences (events every 0.01 to 1 ramp_time) stay below 2 * 15 / (8 ramp_time).

Event rules (the latest event wins)
-----------------------------------
- 'active' with task A, event B != A: fade out, pending B, then swap to B and
  fade in. Event A: nothing happens.
- 'fading_out' (pending B): an event C != A only replaces the pending task; an
  event A cancels the swap and fades back in from the current trajectory.
- 'fading_in' to A: an event C != A fades out from the current trajectory,
  then swaps to C. Event A: nothing happens.
- 'idle' (no task, a = 0): an event A makes A active and fades in.
- An event naming no task (None) fades out and ends in 'idle'.
"""

import math
from collections.abc import Hashable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

PHASE_ACTIVE = 'active'
PHASE_FADING_OUT = 'fading_out'
PHASE_FADING_IN = 'fading_in'
PHASE_IDLE = 'idle'

# Peak of ds/du for the quintic smoothstep s(u) (at u = 1/2): max |da/dt| of a
# full ramp is SMOOTHSTEP_PEAK_SLOPE / ramp_time.
SMOOTHSTEP_PEAK_SLOPE = 15.0 / 8.0

# Default shortest ramp, as a fraction of ramp_time (see the rate bound above).
DEFAULT_MIN_RAMP_FRACTION = 0.5

# Tolerance (s) when checking that the clock does not run backwards.
_TIME_TOLERANCE = 1e-9


def quintic_smoothstep(u: float) -> tuple[float, float, float]:
    """Return s(u), ds/du, d2s/du2 of the quintic smoothstep (eq. 13's f_inc).

    s(u) = 10 u^3 - 15 u^4 + 6 u^5 on [0, 1], 0 below, 1 above: C2 on the whole
    line, with s' = s'' = 0 at both ends. u is dimensionless.
    """
    if u <= 0.0:
        return 0.0, 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0, 0.0
    v = 1.0 - u
    value = u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)
    slope = 30.0 * u * u * v * v
    curvature = 60.0 * u * v * (1.0 - 2.0 * u)
    return value, slope, curvature


def quintic_smoothstep_array(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """quintic_smoothstep's s(u) and ds/du per element of the array u (numpy)."""
    u = np.clip(u, 0.0, 1.0)
    v = 1.0 - u
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u), 30.0 * u * u * v * v


class WeightState(NamedTuple):
    """The event weight at one instant (eq. 13); a NamedTuple (the controller makes one each
    cycle).

    weight: a(E, t) in [0, 1]; rate: da/dt (1/s); acceleration: d2a/dt2 (1/s^2);
    phase: 'active', 'fading_out', 'fading_in' or 'idle'; active_task: the task
    that a(E, t) currently weights (None when idle); pending_task: the task that
    becomes active when the fade-out ends (None if none, or if it ends idle).
    """

    weight: float
    rate: float
    acceleration: float
    phase: str
    active_task: Hashable | None
    pending_task: Hashable | None


@dataclass(frozen=True)
class _Ramp:
    """One blend segment: from the trajectory below it to `target`."""

    start: float
    duration: float
    target: float

    @property
    def end(self) -> float:
        return self.start + self.duration


class EventWeightSchedule:
    """Clock-injected state machine for the event weight a(E, t) of eq. 13.

    ramp_time: duration (s) of a full fade 1 -> 0 or 0 -> 1, > 0.
    initial_task: task active at the start with a = 1 (phase 'active'), or None
        to start 'idle' with a = 0.
    min_ramp_time: shortest ramp (s), in (0, ramp_time]; default ramp_time / 2.
    Tasks are any hashable values compared with ==; None means "no task".
    Times are seconds on any clock, and must not decrease between calls.
    """

    def __init__(self, ramp_time: float, initial_task: Hashable | None = None,
                 min_ramp_time: float | None = None) -> None:
        if not np.isfinite(ramp_time) or ramp_time <= 0.0:
            raise ValueError(f'ramp_time must be finite and > 0 s, got {ramp_time}')
        if min_ramp_time is None:
            min_ramp_time = DEFAULT_MIN_RAMP_FRACTION * ramp_time
        if not np.isfinite(min_ramp_time) or not 0.0 < min_ramp_time <= ramp_time:
            raise ValueError(
                f'min_ramp_time must be in (0, ramp_time={ramp_time}] s, got {min_ramp_time}')
        self._ramp_time = float(ramp_time)
        self._min_ramp_time = float(min_ramp_time)
        self._base = 1.0 if initial_task is not None else 0.0
        self._ramps: list[_Ramp] = []
        self._active = initial_task
        self._pending: Hashable | None = None
        self._phase = PHASE_ACTIVE if initial_task is not None else PHASE_IDLE
        self._last_time: float | None = None

    @property
    def ramp_time(self) -> float:
        """Duration (s) of a full fade."""
        return self._ramp_time

    @property
    def min_ramp_time(self) -> float:
        """Shortest ramp (s)."""
        return self._min_ramp_time

    def request(self, task: Hashable | None, now: float) -> WeightState:
        """Handle an event asking for `task` (None: no task) at time `now` (s).

        Applies the rules in the module docstring and returns the state at `now`.
        """
        self._advance(now)
        if self._phase == PHASE_IDLE:
            if task is not None:
                self._active = task
                self._start_ramp(1.0, now)
                self._phase = PHASE_FADING_IN
        elif self._phase == PHASE_FADING_OUT:
            if task == self._active:
                self._pending = None
                self._start_ramp(1.0, now)
                self._phase = PHASE_FADING_IN
            else:
                self._pending = task
        elif task != self._active:
            # 'active' or 'fading_in' to another task.
            self._pending = task
            self._start_ramp(0.0, now)
            self._phase = PHASE_FADING_OUT
        return self._state(now)

    def evaluate(self, now: float) -> WeightState:
        """Advance the schedule to time `now` (s) and return a(E, t) and its phase."""
        self._advance(now)
        return self._state(now)

    def _start_ramp(self, target: float, now: float) -> None:
        current, _, _ = self._weight_derivatives(now)
        duration = max(self._ramp_time * abs(target - current), self._min_ramp_time)
        self._ramps.append(_Ramp(float(now), duration, target))

    def _advance(self, now: float) -> None:
        if not math.isfinite(now):
            raise ValueError(f'time must be finite, got {now}')
        if self._last_time is not None and now < self._last_time - _TIME_TOLERANCE:
            raise ValueError(
                f'time went backwards: {now} s after {self._last_time} s')
        if self._last_time is None or now > self._last_time:
            self._last_time = float(now)
        while self._ramps:
            # A finished ramp (and everything below it) is constant from its end on.
            finished = [i for i, ramp in enumerate(self._ramps) if ramp.end <= now]
            if not finished:
                break
            last = finished[-1]
            self._base = self._ramps[last].target
            top_finished = last == len(self._ramps) - 1
            end_time = self._ramps[last].end
            del self._ramps[:last + 1]
            if top_finished:
                self._finish_top_ramp(end_time)

    def _finish_top_ramp(self, end_time: float) -> None:
        if self._phase == PHASE_FADING_IN:
            self._phase = PHASE_ACTIVE
            return
        # Fade-out finished: swap the task while a = 0 (eq. 13), then fade in.
        self._active = self._pending
        self._pending = None
        if self._active is None:
            self._phase = PHASE_IDLE
        else:
            self._ramps.append(_Ramp(end_time, self._ramp_time, 1.0))
            self._phase = PHASE_FADING_IN

    def _weight_derivatives(self, now: float) -> tuple[float, float, float]:
        value, rate, acceleration = self._base, 0.0, 0.0
        for ramp in self._ramps:
            s, ds, dds = quintic_smoothstep((now - ramp.start) / ramp.duration)
            ds /= ramp.duration
            dds /= ramp.duration ** 2
            offset = value - ramp.target
            acceleration = (1.0 - s) * acceleration - 2.0 * ds * rate - dds * offset
            rate = (1.0 - s) * rate - ds * offset
            value = ramp.target + (1.0 - s) * offset
        return value, rate, acceleration

    def _state(self, now: float) -> WeightState:
        value, rate, acceleration = self._weight_derivatives(now)
        return WeightState(
            weight=min(max(float(value), 0.0), 1.0),  # np.clip costs 10 us on a float
            rate=float(rate),
            acceleration=float(acceleration),
            phase=self._phase,
            active_task=self._active,
            pending_task=self._pending,
        )
