"""The controller's speed cap under speed and separation monitoring (ISO/TS 15066, 5.5.4).

With the controller's `separation_speed_limit` on, the task's speed towards the hand is capped
so that the protective separation distance S_p (hri_core.separation) stays within the
measured separation: from each /hri/separation (separation s m, the hand speed v_h m/s the
detector put into S_p: human_speed_used, so its assume_iso_speed holds here too) the arm may
move towards the hand at most

    v_lim = (s - STANDOFF - S_p(v_h, v_r = 0)) / T_r   (ProtectiveSeparation.arm_speed_limit
                                                      with the STANDOFF)

(0 when even a still arm is too close; T_r, T_s, B, C, Z_d, Z_r from event_detector.yaml),
and the cap's knee (task_variable.speed_cap, whose soft band lets the speed reach
(1 + CAP_BAND) times the knee) is v_lim / (1 + CAP_BAND), at most max_task_speed. Only the
task's pull towards the hand (Q' > 0) and an avoid task's return to rest are capped: the
push out of d1, the retreat and the hand's velocity fed forward move the arm with or away
from the hand and keep their caps. The arm itself runs up to 1.25 times its reference (the
Kp term; adaptive_law.DEFAULT_GAINS), which T_r's margin has to cover. The paper has no
such limit; this is the "monitor that acts". While the knee is below max_task_speed, the
point of the arm nearest the person (the separation's pair: a link's point against the body
on a whole-body /hri/separation, else the tool against the hand) also moves towards the
person at most at (1 + CAP_BAND) times the knee, whatever else asks for the motion (the
hand's velocity fed forward, the null space, a barrier): control_cycle gives the law that
point's row n^T J_p and arm_law.ArmController.limit_approach takes the excess out of qdot_r.

The separation is taken LOOKAHEAD s ahead at the measured closing speed (s - LOOKAHEAD
max(v_closing, 0)): between a separation and the arm's response to it lie the detector's
filter and tick (20 + 20 ms) and the arm's own lag behind its reference (tens of ms); without
the look-ahead the arm, pulled at 0.31 m/s, ran up to 0.15 m/s above the limit for 80 ms
once inside the band where the limit acts (tests/test_separation_cap.py).

The knee follows its target at a bounded rate (DROP_RATE down, RISE_RATE up), so the
torque changes gradually: a knee falling from 0.25 m/s to 0 under follow's full pull changed
it by at most 0.31 N m per 1 ms step (through qdot_r and the task term), against 7.7 N m for
the same fall in one step (test_separation_cap), and the continuity bar of 1 N m per cycle.
qddot_r leaves the knee's rate out. A separation heard more than SEPARATION_PERIOD ago
is taken further ahead by its extra age, at the closing speed or the fastest the cap lets
the arm come, whichever is more: a detector held back for 0.1-0.4 s on a loaded machine
left the knee on its last separation while the arm came on (0.056 m/s above the limit, a
fresh clone beside a busy process). A /hri/separation older than STALE_AFTER (or none yet)
counts as a separation that allows no approach: the target is 0 (fail safe: the arm still
follows the hand's own motion, moves away from it and fades as before, but no task pulls it
towards the hand). No ROS import.
"""

import math
from dataclasses import dataclass

from hri_adaptive_controller.task_variable import CAP_BAND
from hri_core.separation import ProtectiveSeparation

DROP_RATE = 10.0
"""m/s^2: how fast the knee falls (0.25 m/s to 0 in 25 ms, a quarter of T_r)."""
RISE_RATE = 0.5
"""m/s^2: how fast it rises again (0 to 0.25 m/s in 0.5 s)."""
LOOKAHEAD = 0.1
"""s: how far ahead the separation is taken at the closing speed (module docstring)."""
STALE_AFTER = 0.5
"""s without a /hri/separation (published at 50 Hz) after which the target knee is 0."""
SEPARATION_PERIOD = 0.02
"""s between two /hri/separation (50 Hz): an older one is taken ahead by its extra age."""
STANDOFF = 0.005
"""m: the arm comes to rest this far outside S_p, not on it. On it (the limit falls to 0 as
the separation comes down to S_p), the detector's below_protective flickered on rounding
(S_p above the separation by 2e-16 to 7e-16 m, from a robot speed of 1e-14 m/s) in 5 of 7
live runs of tests/test_separation_cap.py, and failed one fresh clone's."""


def pull_speed_knee(separation: float, human_speed_used: float,
                    settings: ProtectiveSeparation, max_task_speed: float) -> float:
    """The knee (m/s) of the task's speed cap towards the hand at which the arm's speed
    stays at or below the ISO/TS 15066 limit for a hand `separation` m away that S_p counts
    at `human_speed_used` m/s (v_h, >= 0): min(max_task_speed, v_lim / (1 + CAP_BAND)), 0
    where no arm speed keeps STANDOFF outside S_p. A non-finite or negative input gives 0 (the
    safe value)."""
    if not (math.isfinite(separation) and separation >= 0.0
            and math.isfinite(human_speed_used) and human_speed_used >= 0.0):
        return 0.0
    room = separation - STANDOFF - settings.distance(human_speed_used, 0.0)
    if room <= 0.0:
        return 0.0
    if settings.reaction_time == 0.0:
        return max_task_speed
    return min(max_task_speed, room / settings.reaction_time / (1.0 + CAP_BAND))


@dataclass
class SeparationCap:
    """The rate-limited knee of the pull speed cap (module docstring).

    settings: S_p's constants; max_task_speed: the controller's v_max (m/s). `observe` takes
    each /hri/separation, `knee(now)` gives the knee for the control step at monotonic time
    `now` (s). It starts at 0: no approach before the first /hri/separation.
    """

    settings: ProtectiveSeparation
    max_task_speed: float
    heard: float = -math.inf  # monotonic time of the last observe
    value: float = 0.0
    updated: float | None = None
    # The last /hri/separation: separation (m), human_speed_used (m/s), closing speed (m/s).
    observed: tuple[float, float, float] = (math.nan, 0.0, 0.0)

    def observe(self, now: float, separation: float, human_speed_used: float,
                closing_speed: float) -> None:
        """A /hri/separation received at `now` (s): separation (m), human_speed_used (m/s)
        and the measured closing speed (m/s, hand and tool towards each other)."""
        self.observed = (separation, human_speed_used, closing_speed)
        self.heard = now

    def target(self, now: float) -> float:
        """The knee (m/s) the last separation allows at `now` (s): taken LOOKAHEAD s ahead
        at the closing speed, and by its age beyond SEPARATION_PERIOD at that speed or the
        cap's own (1 + CAP_BAND) times the knee, whichever is more (module docstring); 0
        when stale."""
        if self.stale(now):
            return 0.0
        separation, human_speed_used, closing_speed = self.observed
        closing = max(closing_speed, 0.0)  # NaN stays NaN: knee 0
        late = max(now - self.heard - SEPARATION_PERIOD, 0.0)
        ahead = (separation - LOOKAHEAD * closing
                 - late * max(closing, (1.0 + CAP_BAND) * self.value))
        return pull_speed_knee(ahead, human_speed_used, self.settings, self.max_task_speed)

    def stale(self, now: float) -> bool:
        """Whether no /hri/separation came within STALE_AFTER s of `now`."""
        return now - self.heard > STALE_AFTER

    def knee(self, now: float) -> float:
        """The knee (m/s, in [0, max_task_speed]) at `now` (s), moved towards the target by
        at most DROP_RATE or RISE_RATE times the time since the last call."""
        target = self.target(now)
        dt = 0.0 if self.updated is None else max(now - self.updated, 0.0)
        self.updated = now
        if target < self.value:
            self.value = max(target, self.value - DROP_RATE * dt)
        else:
            self.value = min(target, self.value + RISE_RATE * dt)
        return self.value
