"""Holds of the controller's sampled inputs between messages, continuous where a message comes.

The controller runs at the joint states' rate (1 kHz) but its other inputs come slower and
irregularly: the hand (/target, 100 Hz) and the task weight a(E, t) of eq. 13 (TaskState,
200 Hz during a ramp, but with gaps of 0.1-0.3 s when the event_manager is starved on a loaded
machine). Each is held to first order from its newest sample's stamp (x + xdot (t - t_s), at
most `max_extrapolation` s). A new sample then lands where the old extrapolation did not: the
hand's velocity estimate lags its acceleration, so each /target moves x_d by about a mm at
0.5 m/s, and a TaskState after a gap moved a from 0.09 to 0.97 in one control cycle (a
19 N m torque step on the topics). `BlendedHold` closes such a gap smoothly instead: at the
first control cycle t0 that sees a new sample, the jump p0 (old extrapolation minus new) and
the rate jump v0 are carried and faded out over a blend time T (each jump its own blend),

    y(t) = y_new(t) + p0 (1 - s(u)) + v0 T h(u),   u = (t - t0) / T,
    s(u) = 10 u^3 - 15 u^4 + 6 u^5,   h(u) = u - 6 u^3 + 8 u^4 - 3 u^5,

s the quintic smoothstep of eq. 13, h the quintic Hermite basis with h(0) = h(1) = 0,
h'(0) = 1, h'(1) = h''(0) = h''(1) = 0: y and dy/dt are continuous at t0 and y meets the new
extrapolation at t0 + T. T = max(blend_time, pace |p0|): each blends over its message period
(the time since the previous one's stamp), the weight also at `pace` s per unit of a (the
controller's task_fade_time), so a TaskState after a gap is closed at the controller's own
fade pace (the blend adds at most 15/8 / pace to da/dt).

`HandHold` is the hand's estimate (VelocityEstimator plus a BlendedHold; xdot_d is the
estimate, the blend moves x_d only); `TaskWeightHold`
is a(E, t) of the task in force: a TaskState naming another task while the held weight is
above zero first fades the old task out (at `pace`), then swaps (the event_manager's swap
happens at a = 0; after a gap the controller may not have seen it). Times in s, values as
tuples of floats. No ROS import.
"""

import math
from collections.abc import Hashable, Sequence

from hri_adaptive_controller.event_weight import quintic_smoothstep
from hri_core.velocity_estimator import VelocityEstimator


def _hermite_slope_basis(u: float) -> tuple[float, float]:
    """h(u) = u - 6 u^3 + 8 u^4 - 3 u^5 and h'(u) on [0, 1] (0 outside)."""
    if u <= 0.0 or u >= 1.0:
        return 0.0, 0.0
    u2 = u * u
    return (u - 6.0 * u2 * u + 8.0 * u2 * u2 - 3.0 * u2 * u2 * u,
            1.0 - 18.0 * u2 + 32.0 * u2 * u - 15.0 * u2 * u2)


def _message_period(previous: float | None, stamp: float, max_hold: float) -> float:
    """Time (s) from the previous sample's stamp to this one's, within [0, max_hold]; 0 for the
    first sample."""
    return 0.0 if previous is None else min(max(stamp - previous, 0.0), max_hold)


class BlendedHold:
    """First-order hold of a sampled vector, continuous (C1) across new samples.

    max_extrapolation (s, >= 0): longest first-order hold after a sample's stamp (then the
    value stays, rate 0); pace (s per unit of offset, >= 0): the least blend time per unit of
    the largest offset component (module docstring).
    """

    def __init__(self, max_extrapolation: float, pace: float = 0.0):
        if not (math.isfinite(max_extrapolation) and max_extrapolation >= 0.0):
            raise ValueError(f'max_extrapolation must be finite and >= 0 s, got '
                             f'{max_extrapolation}')
        if not (math.isfinite(pace) and pace >= 0.0):
            raise ValueError(f'pace must be finite and >= 0 s, got {pace}')
        self._max_hold = float(max_extrapolation)
        self._pace = float(pace)
        self.reset()

    def reset(self) -> None:
        """Forget every sample (the next one is taken as it is, no blend)."""
        self._sample = None  # (stamp, value, rate)
        self._pending = None  # (stamp, value, rate, blend_time), not yet seen by evaluate
        self._blends = []  # (start, duration, p0, v0) of each jump still being closed

    @property
    def empty(self) -> bool:
        """Whether no sample has been offered since the last reset."""
        return self._sample is None and self._pending is None

    def offer(self, stamp: float, value: Sequence[float], rate: Sequence[float],
              blend_time: float = 0.0) -> None:
        """A new sample: `value` (n,) at `stamp` s, changing at `rate` (n,) per s; a jump it
        makes is blended over at least `blend_time` s. The latest offer before an evaluate
        wins. The caller checks the numbers are finite."""
        self._pending = (float(stamp), tuple(value), tuple(rate), max(float(blend_time), 0.0))

    def evaluate(self, t: float, blend_rate: bool = True
                 ) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """(value, rate) held at time t (s), or None before the first sample. blend_rate=False:
        the rate without the blends' own (the extrapolation's rate alone)."""
        if self._pending is None and not self._blends:  # the common case: one call per cycle
            return None if self._sample is None else self._extrapolation(t)
        if self._pending is not None:
            stamp, value, rate, blend_time = self._pending
            self._pending = None
            old = self._extrapolation(t) if self._sample is not None else None
            self._sample = (stamp, value, rate)
            if old is not None:
                # Each jump gets a blend of its own, so a running one keeps its progress (one
                # restarted at every sample would never finish while samples come faster).
                new = self._extrapolation(t)
                p0 = tuple(a - b for a, b in zip(old[0], new[0], strict=True))
                v0 = tuple(a - b for a, b in zip(old[1], new[1], strict=True))
                duration = max(blend_time, self._pace * max(map(abs, p0), default=0.0))
                if duration > 0.0 and (any(p0) or any(v0)):
                    self._blends.append((t, duration, p0, v0))
        if self._sample is None:
            return None
        value, rate = self._extrapolation(t)
        if not self._blends:
            return value, rate
        out, out_rate = list(value), list(rate)
        running = []
        for blend in self._blends:
            start, duration, p0, v0 = blend
            u = (t - start) / duration
            if u >= 1.0:
                continue
            running.append(blend)
            s, ds, _ = quintic_smoothstep(u) if u > 0.0 else (0.0, 0.0, 0.0)
            h, dh = _hermite_slope_basis(u) if u > 0.0 else (0.0, 1.0)
            for i in range(len(out)):
                out[i] += p0[i] * (1.0 - s) + v0[i] * duration * h
                if blend_rate:
                    out_rate[i] += -p0[i] * ds / duration + v0[i] * dh
        self._blends = running
        return tuple(out), tuple(out_rate)

    def _extrapolation(self, t: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The newest sample held to first order at t (no blend)."""
        stamp, value, rate = self._sample
        # Backwards too: a sample stamped after t (its source's clock runs ahead of the joint
        # states' by their latency) is taken back to t, so old and new compare at one time.
        max_hold = self._max_hold
        held = t - stamp
        if -max_hold < held < max_hold:
            rate_out = rate
        else:  # held no further than max_hold, and no longer moving
            held = max_hold if held > 0.0 else -max_hold
            rate_out = tuple([0.0] * len(rate))
        return tuple([v + r * held for v, r in zip(value, rate, strict=True)]), rate_out


class HandHold:
    """The hand x_d (m) and xdot_d (m/s) at any time from its stamped positions (/target).

    xdot_d: VelocityEstimator(filter_time); between messages the hand is held to first order
    for at most max_extrapolation s, and the jump a new message makes is blended over its
    message period (the time since the previous one, at most max_extrapolation).
    dimension: 2 (the planar hand, [x, y]) or 3 ([x, y, z]).
    """

    def __init__(self, filter_time: float, max_extrapolation: float, dimension: int = 2):
        self._velocity = VelocityEstimator(filter_time, dimension)
        self._hold = BlendedHold(max_extrapolation)
        self._max_hold = max_extrapolation
        self._stamp = None

    def reset(self) -> None:
        """A restarted source: forget the velocity and the held samples."""
        self._velocity.reset()
        self._hold.reset()
        self._stamp = None

    def offer(self, position: Sequence[float], stamp: float, blend_time: float = 0.0,
              restart_velocity: bool = False) -> None:
        """A hand position (dimension,) m stamped `stamp` s (later than the previous one); its
        jump is blended over at least `blend_time` s (a far sample: target_filter);
        restart_velocity: the velocity estimate starts again from this sample (a re-anchor:
        the difference to the old place is no velocity)."""
        if restart_velocity:
            self._velocity.reset()
        velocity = self._velocity.update(position, stamp).tolist()
        period = max(_message_period(self._stamp, stamp, self._max_hold), blend_time)
        self._stamp = stamp
        self._hold.offer(stamp, position, velocity, period)

    def evaluate(self, t: float):
        """(x_d, xdot_d) as float pairs at t (s), or None before the first position. xdot_d is
        the velocity estimate (0 once the hold has run out), not the blend's rate: a 1 mm blend
        over 10 ms would feed 0.19 m/s forward and, through the task's Hessian in qddot_r,
        step the torque (0.66 N m per cycle, against 0.25 without that rate)."""
        return self._hold.evaluate(t, blend_rate=False)


class TaskWeightHold:
    """a(E, t) of the task in force, held between TaskStates (module docstring).

    pace (s): blend time per unit of a (the controller's task_fade_time); max_extrapolation
    (s): longest first-order hold after a TaskState's stamp. Tasks are told apart by a
    hashable key; each offer carries an opaque payload (the task itself) returned with it.
    """

    def __init__(self, pace: float, max_extrapolation: float):
        self._hold = BlendedHold(max_extrapolation, pace)
        self._max_hold = max_extrapolation
        self._stamp = None  # of the latest TaskState of the task in force
        self._key = self._payload = None
        self._next = None  # (key, payload, stamp, weight, rate) of another task, waiting
        self._fading_out = False  # the task in force fades out for the one waiting

    def reset(self) -> None:
        """Forget the task in force and its weight: the next TaskState is taken as it is, not
        blended from the held weight (for TaskStates that return after the link to their
        source was down, while a = 0 anyway)."""
        self._hold.reset()
        self._stamp = None
        self._key = self._payload = None
        self._next = None
        self._fading_out = False

    def offer(self, key: Hashable, payload, stamp: float, weight: float, rate: float) -> None:
        """A TaskState: the task `key` (with `payload`) at weight a in [0, 1] and rate da/dt
        (1/s), stamped `stamp` s."""
        if self._hold.empty or key == self._key:
            # On time, a TaskState lands close to the hold: blended over its period, so that
            # da/dt changes smoothly too (it feeds qddot_r, eq. 18).
            period = _message_period(self._stamp, stamp, self._max_hold)
            self._key, self._payload, self._next = key, payload, None
            self._fading_out, self._stamp = False, stamp
            self._hold.offer(stamp, (weight,), (rate,), period)
        else:
            self._next = (key, payload, stamp, weight, rate)

    def evaluate(self, t: float) -> tuple[Hashable, object, float, float] | None:
        """(key, payload, a, da/dt) of the task in force at t (s); None before any offer."""
        if self._next is not None:
            held = self._hold.evaluate(t)
            if held is None or held[0][0] <= 0.0:  # the old task is out: swap
                key, payload, stamp, weight, rate = self._next
                self._next, self._fading_out = None, False
                self._key, self._payload, self._stamp = key, payload, stamp
                self._hold.offer(stamp, (weight,), (rate,))
            elif not self._fading_out:
                # Fade the old task out first, from where it is, at the hold's pace.
                self._fading_out = True
                self._hold.offer(t, (0.0,), (0.0,))
        held = self._hold.evaluate(t)
        if held is None:
            return None
        (weight,), (rate,) = held
        if weight <= 0.0:
            weight, rate = 0.0, 0.0
        elif weight >= 1.0:
            weight, rate = 1.0, 0.0
        return self._key, self._payload, weight, rate
