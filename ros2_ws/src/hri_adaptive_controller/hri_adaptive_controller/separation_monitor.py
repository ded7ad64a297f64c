"""The hand and the tool from their stamped positions, for the event_detector: what its rules
see (event_rules.Observation) and the separation with S_p (hri_core.separation).

Velocities (m/s) from the stamped positions (m) through hri_core.velocity_estimator (low-passed
differences: they trust the stamps, which must be the times the positions were taken at);
times in s. No ROS import.
"""

import math

import numpy as np

from hri_adaptive_controller.event_rules import Observation
from hri_core.separation import ProtectiveSeparation, SeparationSample, separation_sample
from hri_core.velocity_estimator import VelocityEstimator

RESTART_JUMP = 0.5  # s: a stamp this far back is a restarted source, not a late sample


class _TrackedPoint:
    """A point's newest position (d,) m, its receive time and its velocity (d,) m/s from
    stamped samples (VelocityEstimator: low-passed differences; d = 2 or 3)."""

    def __init__(self, filter_time: float, dimension: int = 2):
        self._estimator = VelocityEstimator(filter_time, dimension)
        self.position: np.ndarray | None = None
        self.received: float | None = None
        self._stamp: float | None = None

    def offer(self, position, stamp: float, received: float) -> bool:
        """A sample (d,) m stamped `stamp` s, received at `received` s; False (dropped) if its
        stamp does not advance, unless it is RESTART_JUMP s back: a restarted source, whose
        past is forgotten."""
        if self._stamp is not None and stamp <= self._stamp:
            if stamp > self._stamp - RESTART_JUMP:
                return False
            self._estimator.reset()
        self._estimator.update(position, stamp)
        self.position = np.asarray(position, dtype=float)
        self._stamp, self.received = stamp, received
        return True

    @property
    def velocity(self) -> np.ndarray:
        return self._estimator.velocity


class SeparationMonitor:
    """The hand and the tool from their stamped positions; `observe` gives what the event
    rules see and the separation with S_p.

    settings: the S_p constants; hand_filter_time, tool_filter_time (s): time constants of
    the velocity estimates (hri_core.velocity_estimator); input_timeout (s): a hand (or tool)
    whose newest sample came longer ago than this counts as absent; dimension: 2 (positions
    (x, y), the planar SCARA) or 3 ((x, y, z), an arm in space).
    """

    def __init__(self, settings: ProtectiveSeparation, hand_filter_time: float,
                 tool_filter_time: float, input_timeout: float, dimension: int = 2):
        self.settings = settings
        self._hand = _TrackedPoint(hand_filter_time, dimension)
        self._tool = _TrackedPoint(tool_filter_time, dimension)
        self._timeout = input_timeout

    def hand(self, position, stamp: float, received: float) -> bool:
        """A hand position (d,) m stamped `stamp` s, received at `received` s (the clock of
        `observe`); False if dropped (its stamp does not advance)."""
        return self._hand.offer(position, stamp, received)

    def tool(self, position, stamp: float, received: float) -> bool:
        """A tool position (d,) m stamped `stamp` s, received at `received` s."""
        return self._tool.offer(position, stamp, received)

    def observe(self, now: float) -> tuple[Observation, SeparationSample | None]:
        """What the rules see at `now` s, and the separation sample (None without a recent hand
        and tool sample: the rules then see no hand)."""
        hand, tool = self._hand, self._tool
        since_hand = None if hand.received is None else max(now - hand.received, 0.0)
        if since_hand is None or since_hand > self._timeout or tool.received is None \
                or now - tool.received > self._timeout:
            return Observation(now, None, since_hand=since_hand), None
        sample = separation_sample(hand.position, hand.velocity, tool.position, tool.velocity,
                                   self.settings)
        return Observation(now, sample.separation, sample.human_speed, sample.robot_speed,
                           float(math.hypot(*hand.velocity)), since_hand), sample
