"""Glitches and dropouts of the hand on /target: jumps no hand can make are held, not followed.

A tracked hand (Vicon, a camera) is not always the hand: a marker swap moves it by metres in
one frame (64 m/s apparent speed in a recorded take), a one-frame glitch by 6 cm (6 m/s), and
the cameras lose it for up to 1.25 s. `TargetFilter` accepts a sample only if a hand could
have got there from the last accepted one (its position p_a, stamp t_a, velocity v_a from the
last two accepted samples), with dt = t - t_a:

    |p - p_a|             <= tolerance + max_speed dt                 (speed bound)
    |p - p_a - v_a dt|    <= tolerance + max_acceleration dt^2        (acceleration bound)

max_speed 5.0 m/s: ISO 13855 takes 2.0 m/s for a hand reaching in, the recorded takes reach
3.1 m/s (tossing a can); 5.0 leaves them margin while a marker swap (tens of m/s) is far out.
max_acceleration 100 m/s^2: the recorded takes' second differences reach 76 m/s^2 at 100 Hz
(hand plus 0.2-0.5 mm of sensor noise); their one-frame glitch is 610 m/s^2. tolerance 0.01 m:
sensor noise and stamp jitter. A sample outside the bounds is held (not given to the hold) and
counted in `glitches`.

A hand that really is elsewhere (a long swap, a real move faster than the bounds) is not
frozen out for ever. Rejected samples that are consistent among themselves (the same bounds,
from one to the next) form a candidate track; a sample nearer the candidate's prediction than
the anchor's goes on with it (a swap lasts frames); once the track has lasted `confirm_time`
(0.2 s) with at least `confirm_samples` samples, the filter re-anchors there (counted in
`reanchors`). The anchor's bounds loosen with the time since it (after a dropout the hand may
be far); once samples have been held since it, a sample more than confirm_time after it must
come through a candidate track, so a stream of garbage never lets one through by chance. The
first sample of a track has no velocity yet: the speed bound alone applies to the next.

A sample that lands far from where the hand was predicted (a re-anchor, the return after a
dropout) is blended in over |p - p_pred| / blend_speed s (at least its message period) rather
than one period, and the velocity estimate starts again from it, so x_d glides there C1
(signal_hold.BlendedHold).

`FilteredHand` is what the controller (and closed_loop) uses in place of signal_hold.HandHold:
the filter, the hold of the accepted samples (first order for at most `max_extrapolation` s),
and the hand's presence weight: 1 while samples are accepted, faded to 0 over `fade_time`
with eq. 13's C2 ramp (event_weight) once none has come for `timeout` s, and back in when
they return. The task weight a is multiplied by it, so a lost hand fades the task out.
Times in s on the samples' clock, positions as tuples of floats in m (any dimension). No ROS.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass

from hri_adaptive_controller.event_weight import (
    PHASE_FADING_OUT,
    PHASE_IDLE,
    EventWeightSchedule,
    WeightState,
)
from hri_adaptive_controller.signal_hold import HandHold
from hri_core.validation import positive

HAND = 'hand'  # the presence schedule's one "task"
STAMP_TOLERANCE = 1e-9  # s: stamps built by adding periods are not exact


@dataclass(frozen=True)
class TargetFilterSettings:
    """Bounds of a hand's motion and what happens past them (module docstring).

    max_speed (m/s), max_acceleration (m/s^2), tolerance (m): the bounds; confirm_time (s),
    confirm_samples: a candidate track of held samples that lasts this long with at least
    this many re-anchors the filter; blend_speed (m/s): pace of the glide to a far sample;
    filter_time (s): the hand velocity estimate's time constant; max_extrapolation (s):
    longest first-order hold between samples; timeout (s): no accepted sample for this long
    fades the hand's presence out over fade_time (s).
    """

    max_speed: float = 5.0
    max_acceleration: float = 100.0
    tolerance: float = 0.01
    confirm_time: float = 0.2
    confirm_samples: int = 3
    blend_speed: float = 1.0
    filter_time: float = 0.05
    max_extrapolation: float = 0.05
    timeout: float = 0.5
    fade_time: float = 1.0

    def __post_init__(self):
        for name, unit in (('max_speed', 'm/s'), ('max_acceleration', 'm/s^2'),
                           ('tolerance', 'm'), ('confirm_time', 's'), ('blend_speed', 'm/s'),
                           ('filter_time', 's'), ('timeout', 's'), ('fade_time', 's')):
            positive(getattr(self, name), name, unit)
        if not (math.isfinite(self.max_extrapolation) and self.max_extrapolation >= 0.0):
            raise ValueError(f'max_extrapolation must be finite and >= 0 s, got '
                             f'{self.max_extrapolation}')
        if int(self.confirm_samples) != self.confirm_samples or self.confirm_samples < 1:
            raise ValueError(f'confirm_samples must be an integer >= 1, got '
                             f'{self.confirm_samples}')


def _norm(values) -> float:
    return math.sqrt(sum(v * v for v in values))


class _Track:
    """The newest sample of a track and its velocity (from the two newest samples)."""

    __slots__ = ('stamp', 'position', 'velocity', 'length', 'since')

    def __init__(self, stamp: float, position: tuple, velocity: tuple | None,
                 length: int = 1, since: float | None = None):
        self.stamp, self.position, self.velocity, self.length = (stamp, position, velocity,
                                                                 length)
        self.since = stamp if since is None else since  # stamp of the track's first sample

    def miss(self, stamp: float, position: tuple, settings: TargetFilterSettings) -> float:
        """How far (m) `position` at `stamp` lies outside what a hand could reach from here
        (<= 0: within the bounds; the speed bound alone while the velocity is unknown)."""
        dt = max(stamp - self.stamp, 0.0)
        jump = _norm([p - a for p, a in zip(position, self.position, strict=True)])
        miss = jump - settings.tolerance - settings.max_speed * dt
        if self.velocity is None:
            return miss
        return max(miss, self.off(stamp, position) - settings.tolerance
                   - settings.max_acceleration * dt * dt)

    def extended(self, stamp: float, position: tuple, max_speed: float) -> '_Track':
        """This track moved on to `position` at `stamp` (velocity capped at max_speed)."""
        dt = stamp - self.stamp
        velocity = (tuple((p - a) / dt for p, a in zip(position, self.position, strict=True))
                    if dt > 0.0 else self.velocity)
        speed = 0.0 if velocity is None else _norm(velocity)
        if speed > max_speed:
            velocity = tuple(v * max_speed / speed for v in velocity)
        return _Track(stamp, position, velocity, self.length + 1, self.since)

    def predicted(self, stamp: float) -> tuple:
        if self.velocity is None:
            return self.position
        dt = max(stamp - self.stamp, 0.0)
        return tuple(a + v * dt for a, v in zip(self.position, self.velocity, strict=True))

    def off(self, stamp: float, position: tuple) -> float:
        """Distance (m) of `position` from this track's prediction at `stamp`."""
        return _norm([p - q for p, q in zip(position, self.predicted(stamp), strict=True)])


class TargetFilter:
    """The jump gate of the module docstring: `offer` says whether a sample is the hand.

    After each accepted offer, `blend_time` (s) is how long the caller should take to blend
    it in beyond its message period (0 for a sample where it was predicted) and `restarted`
    whether the hand's velocity starts again from it (a re-anchor, or the first sample after
    more than confirm_time without one: a difference across a jump or a dropout is no
    velocity). Counters: glitches (held samples), reanchors.
    """

    def __init__(self, settings: TargetFilterSettings = TargetFilterSettings()):
        self.settings = settings
        self.glitches = 0
        self.reanchors = 0
        self.reset()

    def reset(self) -> None:
        """Forget the anchor (a restarted source); the counters stay."""
        self._anchor: _Track | None = None
        self._candidate: _Track | None = None
        self._held_since_anchor = False
        self.blend_time = 0.0
        self.restarted = False

    def offer(self, stamp: float, position: Sequence[float]) -> bool:
        """A hand sample at `stamp` s: True if it is taken as the hand, False if held."""
        position = tuple(float(v) for v in position)
        s = self.settings
        self.blend_time, self.restarted = 0.0, False
        anchor, candidate = self._anchor, self._candidate
        if anchor is None:
            self._anchor, self._candidate = _Track(stamp, position, None), None
            self._held_since_anchor = False
            return True
        # The anchor's bounds loosen with the time since it: after a dropout (nothing came)
        # a far sample may be the hand, after a stream of held ones it must be confirmed.
        recent = stamp - anchor.stamp <= s.confirm_time or not self._held_since_anchor
        # A sample that goes on with a held jump rather than with the hand is one more of the
        # jump (a marker swap lasts frames), even where the anchor's bounds, loosening with
        # the time since it, would let it pass. Once it must be confirmed, a sample as near
        # the candidate's prediction as the anchor's (within tolerance) goes on with the
        # candidate: the hand back where it was after a stall that split a swap (a tie, a
        # still hand) once restarted the candidate at every sample and was held for ever.
        with_candidate = False
        if candidate is not None and candidate.miss(stamp, position, s) <= 0.0:
            nearer = candidate.off(stamp, position) - anchor.off(stamp, position)
            with_candidate = nearer < 0.0 or (not recent and nearer <= s.tolerance)
        if not with_candidate and recent and anchor.miss(stamp, position, s) <= 0.0:
            far = anchor.off(stamp, position)
            self.blend_time = max(far - s.tolerance, 0.0) / s.blend_speed
            self.restarted = stamp - anchor.stamp > s.confirm_time
            self._anchor, self._candidate = anchor.extended(stamp, position, s.max_speed), None
            self._held_since_anchor = False
            return True
        if with_candidate:
            candidate = candidate.extended(stamp, position, s.max_speed)
        else:
            candidate = _Track(stamp, position, None)
        if (candidate.length < s.confirm_samples
                or stamp - candidate.since < s.confirm_time - STAMP_TOLERANCE):
            self._candidate = candidate
            self._held_since_anchor = True
            self.glitches += 1
            return False
        self.blend_time = anchor.off(stamp, position) / s.blend_speed
        self.restarted = True
        self.reanchors += 1
        self._anchor, self._candidate = candidate, None
        self._held_since_anchor = False
        return True


class FilteredHand:
    """x_d, xdot_d and the hand's presence weight from raw hand samples (module docstring).

    offer(stamp, position) -> accepted; evaluate(t) -> (x_d, xdot_d) or None before the first
    accepted sample; presence(t) -> WeightState of the hand's presence (weight in [0, 1],
    rate 1/s). Times must not go backwards between presence calls (the controller's joint
    stamps). glitches, reanchors: the filter's counters. dimension: 2 ([x, y]) or 3. A control
    loop (control_cycle, closed_loop) uses it as:

        hand = FilteredHand(TargetFilterSettings(filter_time=..., max_extrapolation=...))
        hand.offer(stamp, (x, y))          # each hand sample; False: held as a glitch
        x_d, xdot_d = hand.evaluate(t)     # each cycle (None before the first sample)
        present = hand.presence(t)         # each cycle: a *= present.weight, and
                                           # da/dt = da_task/dt * w + a_task * present.rate
    """

    def __init__(self, settings: TargetFilterSettings = TargetFilterSettings(),
                 dimension: int = 2):
        self.settings = settings
        self.filter = TargetFilter(settings)
        self._hold = HandHold(settings.filter_time, settings.max_extrapolation, dimension)
        self._presence = EventWeightSchedule(settings.fade_time, HAND)
        self._last_accepted = -math.inf
        self._clock = -math.inf

    @property
    def glitches(self) -> int:
        return self.filter.glitches

    @property
    def reanchors(self) -> int:
        return self.filter.reanchors

    def reset(self) -> None:
        """A restarted source: forget the anchor and the hold (presence and counters stay)."""
        self.filter.reset()
        self._hold.reset()

    def offer(self, stamp: float, position: Sequence[float]) -> bool:
        """A hand sample (position in m, stamp in s): True if taken, False if held."""
        if not self.filter.offer(stamp, position):
            return False
        self._hold.offer(tuple(float(v) for v in position), stamp,
                         blend_time=self.filter.blend_time,
                         restart_velocity=self.filter.restarted)
        self._last_accepted = stamp
        return True

    def evaluate(self, t: float):
        """(x_d, xdot_d) as tuples at t (s), or None before the first accepted sample."""
        return self._hold.evaluate(t)

    def presence(self, t: float) -> WeightState:
        """The hand's presence weight at t (s): faded out after `timeout` s without an
        accepted sample, in again once they come."""
        if t < self._clock - self.settings.timeout:
            # The clock went back (a restarted source with its own clock): start again, with
            # the hand present if its samples are.
            present = abs(t - self._last_accepted) <= self.settings.timeout
            self._presence = EventWeightSchedule(self.settings.fade_time,
                                                 HAND if present else None)
            self._clock = -math.inf
        t = max(t, self._clock)
        state = self._presence.evaluate(self._clock) if self._clock > -math.inf else None
        present = t - self._last_accepted <= self.settings.timeout
        if state is not None and present == (state.phase in (PHASE_FADING_OUT, PHASE_IDLE)):
            # The hand came back, or has been gone for `timeout`: the ramp starts then (not
            # at this call, which may come later), but never before the last call.
            event = self._last_accepted + (0.0 if present else self.settings.timeout)
            self._presence.request(HAND if present else None, min(max(event, self._clock), t))
        self._clock = t
        return self._presence.evaluate(t)
