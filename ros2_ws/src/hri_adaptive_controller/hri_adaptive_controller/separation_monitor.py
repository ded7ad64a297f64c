"""The hand and the tool from their stamped positions, for the event_detector: what its rules
see (event_rules.Observation) and the separation with S_p (hri_core.separation); and the
whole body (`BodySeparation`): the robot's capsules against the person's (hri_core.bodies),
the closest pair and S_p along its normal.

Velocities (m/s) from the stamped positions (m) through hri_core.velocity_estimator (low-passed
differences: they trust the stamps, which must be the times the positions were taken at);
times in s. No ROS import.
"""

import math
from dataclasses import dataclass

import numpy as np

from hri_adaptive_controller.event_rules import Observation
from hri_core.bodies import HUMAN_CAPSULES, RobotBody, capsule_distances, human_capsules
from hri_core.separation import (
    ProtectiveSeparation,
    SeparationSample,
    pair_separation_sample,
    separation_sample,
)
from hri_core.velocity_estimator import VelocityEstimator

RESTART_JUMP = 0.5  # s: a stamp this far back is a restarted source, not a late sample
CAPSULE_ENDS = {capsule[0]: capsule for capsule in HUMAN_CAPSULES}


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


@dataclass(frozen=True)
class BodySample:
    """The whole-body separation at one instant: `sample` (S_p along the closest pair),
    robot_link and body_part (the pair's capsule names), robot_point and body_point (3,) m
    (the closest points on their surfaces)."""

    sample: SeparationSample
    robot_link: str
    body_part: str
    robot_point: np.ndarray
    body_point: np.ndarray


class BodySeparation:
    """The robot's capsules (hri_core.bodies.RobotBody) against the person's from
    /human/body: the closest pair, and the speeds of its two points along its normal.

    The robot's closest point moves with its link: v_r = J_p(q) dq (the point Jacobian at
    the newest joint state q (n,) rad, dq (n,) rad/s). The person's closest point lies at
    t in [0, 1] between its capsule's two body points, whose velocities (m/s) come from the
    two newest body messages that both hold the point (difference over their stamps; 0 for
    a point seen once): v_h = (1 - t) v_start + t v_end. body_timeout, joint_timeout (s): a
    body or joint state older than this (by receive time) is not used. No ROS import.
    """

    def __init__(self, robot: RobotBody, settings: ProtectiveSeparation, body_timeout: float,
                 joint_timeout: float, radii=None):
        self.robot, self.settings = robot, settings
        self._body_timeout, self._joint_timeout = body_timeout, joint_timeout
        self._radii = radii
        self._points: dict[str, np.ndarray] = {}
        self._velocities: dict[str, np.ndarray] = {}
        self._previous: dict[str, tuple[float, np.ndarray]] = {}
        self._human = None
        self._body_stamp: float | None = None
        self.body_received: float | None = None
        self._q = self._dq = None
        self._joints_received: float | None = None

    def body(self, names, points, stamp: float, received: float) -> bool:
        """A body message: names (K,), points (K, 3) m, stamped `stamp` s, received at
        `received` s. False (dropped) if its stamp does not advance, or for bad points
        (ValueError's reason is the caller's to log: raised for non-finite points)."""
        if self._body_stamp is not None and stamp <= self._body_stamp:
            if stamp > self._body_stamp - RESTART_JUMP:
                return False
            self._previous.clear()  # a restarted source: its past is forgotten
        human = human_capsules(names, points, self._radii)
        velocities = {}
        for name, point in zip(names, np.asarray(points, dtype=float).reshape(-1, 3),
                               strict=True):
            before = self._previous.get(name)
            velocities[name] = ((point - before[1]) / (stamp - before[0])
                                if before is not None and stamp > before[0] else np.zeros(3))
            self._previous[name] = (stamp, point)
        self._human, self._velocities = human, velocities
        self._points = dict(zip(names, np.asarray(points, dtype=float).reshape(-1, 3),
                                strict=True))
        self._body_stamp, self.body_received = stamp, received
        return True

    def joints(self, q, dq, received: float) -> None:
        """The newest joint state: q (n,) rad, dq (n,) rad/s, received at `received` s."""
        self._q, self._dq, self._joints_received = np.asarray(q, float), \
            np.asarray(dq, float), received

    def body_fresh(self, now: float) -> bool:
        """A body came within body_timeout of `now` (s)."""
        return self.body_received is not None and now - self.body_received <= self._body_timeout

    def observe(self, now: float) -> BodySample | None:
        """The closest pair at `now` s, or None without a fresh body with a capsule, or
        without a fresh joint state."""
        if not self.body_fresh(now) or self._human is None or len(self._human) == 0 \
                or self._joints_received is None \
                or now - self._joints_received > self._joint_timeout:
            return None
        robot = self.robot
        distances = capsule_distances(robot.capsules(self._q), self._human, robot.planar)
        i, j = distances.closest()
        distance, robot_point, body_point, normal = distances.pair(i, j)
        robot_velocity = robot.point_jacobian(self._q, i, robot_point) @ self._dq
        part = self._human.names[j]
        _, start, end, _ = CAPSULE_ENDS[part]
        _, t = distances.parameters(i, j)
        human_velocity = (1.0 - t) * self._velocities[start] + t * self._velocities[end]
        if robot.planar:
            human_velocity = human_velocity * (1.0, 1.0, 0.0)
        sample = pair_separation_sample(distance, normal, robot_velocity, human_velocity,
                                        self.settings)
        return BodySample(sample, robot.names[i], part, robot_point, body_point)
