"""Speed and separation monitoring of ISO/TS 15066 (5.5.4): the protective separation distance.

The hand and the tool are points (positions (2,) m in the base frame, velocities (2,) m/s).
Their separation is |x_h - x_r| (m); the human speed v_h is the hand's velocity along the
separation towards the tool, the robot speed v_r the tool's velocity towards the hand (m/s,
negative when moving away). ISO/TS 15066 eq. 1-2, with constant speeds over the stop:

    S_p = v_h (T_r + T_s) + v_r T_r + B + C + Z_d + Z_r

T_r: reaction time of the system (s); T_s: stopping time of the robot (s); B: its stopping
distance (m); C: intrusion distance, how far a hand reaches beyond its tracked point (m); Z_d,
Z_r: position uncertainty of the human and of the robot (m). v_r enters at max(v_r, 0): a tool
moving away needs no less than a still one. v_h enters at max(v_h, 0) and, unless
`assume_iso_speed` is off, at least at ISO 13855's approach speed K of a hand or an arm:
2.0 m/s within 0.5 m, 1.6 m/s beyond (ISO 13855, 6.2). The paper has no equation for this;
the event_detector publishes it (/hri/separation), the controller's separation_speed_limit
caps its speed by it, and the learner and the demo's report judge the learned d1 by it
(separation_verdict). No ROS import.
"""

import math
from dataclasses import dataclass, fields, replace

import numpy as np


@dataclass(frozen=True)
class ProtectiveSeparation:
    """The constants of S_p (module docstring).

    reaction_time T_r (s), stopping_time T_s (s), stopping_distance B (m), intrusion_distance
    C (m), human_uncertainty Z_d (m), robot_uncertainty Z_r (m), all finite and >= 0;
    near_speed and far_speed: ISO 13855's K (m/s, > 0) within and beyond near_limit (m, > 0);
    assume_iso_speed: v_h is at least that K (else the measured speed alone).
    Raises ValueError with a one-line reason for a value out of range.
    """

    reaction_time: float
    stopping_time: float
    stopping_distance: float
    intrusion_distance: float
    human_uncertainty: float
    robot_uncertainty: float
    near_speed: float
    far_speed: float
    near_limit: float
    assume_iso_speed: bool

    def __post_init__(self):
        for field in fields(self):
            value = getattr(self, field.name)
            if field.type is bool:
                continue
            positive = field.name in ('near_speed', 'far_speed', 'near_limit')
            if not (isinstance(value, int | float) and not isinstance(value, bool)
                    and math.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
                raise ValueError(f'{field.name} must be a finite number '
                                 f'{"> 0" if positive else ">= 0"}, got {value!r}')

    @classmethod
    def from_mapping(cls, values) -> 'ProtectiveSeparation':
        """The constants named by this class's fields, taken from `values` (a mapping that may
        hold more, e.g. the event_detector's parameters); KeyError names a missing one."""
        return cls(**{field.name: values[field.name] for field in fields(cls)})

    def iso_human_speed(self, separation: float) -> float:
        """ISO 13855's approach speed K (m/s) of a hand at `separation` m from the tool."""
        return self.near_speed if separation <= self.near_limit else self.far_speed

    def human_speed_used(self, human_speed: float, separation: float) -> float:
        """v_h of S_p (m/s): the measured speed towards the tool (m/s), at least 0 and, with
        assume_iso_speed, at least ISO 13855's K at this separation (m)."""
        floor = self.iso_human_speed(separation) if self.assume_iso_speed else 0.0
        return max(human_speed, floor, 0.0)

    def distance(self, human_speed_used: float, robot_speed: float) -> float:
        """S_p (m) for v_h = human_speed_used (m/s, >= 0) and the tool's speed towards the
        hand robot_speed (m/s; taken at max(v_r, 0))."""
        return (human_speed_used * (self.reaction_time + self.stopping_time)
                + max(robot_speed, 0.0) * self.reaction_time + self.stopping_distance
                + self.intrusion_distance + self.human_uncertainty + self.robot_uncertainty)

    def arm_speed_limit(self, separation: float, human_speed: float | None = None
                        ) -> float | None:
        """The highest speed v_r (m/s) of the tool towards the hand at which S_p <= separation
        (m), for a hand coming at ISO 13855's speed at this separation (human_speed None) or
        at `human_speed` m/s (taken as human_speed_used takes a measured one).
        None if no speed does (S_p of a still tool is above the separation); inf if any does
        (T_r = 0 and the still tool's S_p fits). T_s and B stay at their values (measured at
        the arm's peak speed: a slower arm stops sooner, so this is conservative)."""
        v_h = self.iso_human_speed(separation) if human_speed is None \
            else self.human_speed_used(human_speed, separation)
        room = separation - self.distance(v_h, 0.0)
        if room < 0.0:
            return None
        return math.inf if self.reaction_time == 0.0 else room / self.reaction_time


@dataclass(frozen=True)
class SeparationSample:
    """Hand and tool at one instant: separation (m), human_speed and robot_speed (m/s, towards
    each other along the separation; negative when moving apart), human_speed_used (m/s, v_h
    of S_p), protective_distance S_p (m), below_protective (separation < S_p)."""

    separation: float
    human_speed: float
    robot_speed: float
    human_speed_used: float
    protective_distance: float

    @property
    def below_protective(self) -> bool:
        return self.separation < self.protective_distance

    @property
    def closing_speed(self) -> float:
        """How fast the separation shrinks (m/s): human_speed + robot_speed."""
        return self.human_speed + self.robot_speed


def separation_sample(hand, hand_velocity, tool, tool_velocity,
                      settings: ProtectiveSeparation) -> SeparationSample:
    """The separation of hand and tool and S_p: positions (2,) m, velocities (2,) m/s.

    On a zero separation the direction between them is undefined: both speeds are then the
    magnitudes of the velocities (each counts as moving towards the other).
    """
    offset = np.asarray(tool, dtype=float) - np.asarray(hand, dtype=float)
    separation = float(math.hypot(*offset))
    hand_velocity = np.asarray(hand_velocity, dtype=float)
    tool_velocity = np.asarray(tool_velocity, dtype=float)
    if separation > 0.0:
        towards_tool = offset / separation
        human_speed = float(hand_velocity @ towards_tool)
        robot_speed = 0.0 - float(tool_velocity @ towards_tool)  # 0.0, not -0.0
    else:
        human_speed = float(math.hypot(*hand_velocity))
        robot_speed = float(math.hypot(*tool_velocity))
    used = settings.human_speed_used(human_speed, separation)
    return SeparationSample(separation, human_speed, robot_speed, used,
                            settings.distance(used, robot_speed))


@dataclass(frozen=True)
class SeparationVerdict:
    """Whether a task that keeps the hand at d1 > 0 keeps ISO/TS 15066's S_p (m, m/s).

    d1: the task's inner boundary; arm_speed: the arm's speed towards the hand (its
    max_task_speed); protective_distance, protective_distance_still_hand: S_p at that speed
    for a hand at ISO 13855's speed at d1 and for a still hand; arm_speed_limit,
    arm_speed_limit_still_hand: the highest arm speed at which d1 >= S_p for each (None: no
    speed, not even a still arm; inf: any)."""

    d1: float
    arm_speed: float
    protective_distance: float
    protective_distance_still_hand: float
    arm_speed_limit: float | None
    arm_speed_limit_still_hand: float | None

    @property
    def meets(self) -> bool:
        """d1 >= S_p with the hand at ISO 13855's speed."""
        return self.d1 >= self.protective_distance

    @property
    def meets_still_hand(self) -> bool:
        """d1 >= S_p with a still hand."""
        return self.d1 >= self.protective_distance_still_hand

    def metrics(self) -> dict:
        """The verdict as a flat mapping with units in its keys (reports, YAML)."""
        return {'d1_m': self.d1, 'arm_speed_m_s': self.arm_speed,
                'protective_distance_m': self.protective_distance,
                'protective_distance_still_hand_m': self.protective_distance_still_hand,
                'arm_speed_limit_m_s': self.arm_speed_limit,
                'arm_speed_limit_still_hand_m_s': self.arm_speed_limit_still_hand}

    def summary(self) -> str:
        """One line: S_p and the arm speed for d1 >= S_p, hand at ISO speed and still."""
        def limit(value):
            return 'no arm speed' if value is None else f'arm speed <= {value:.2f} m/s'
        return (f'd1 = {self.d1:.3f} m vs ISO/TS 15066 S_p at arm speed {self.arm_speed:g} '
                f'm/s: {self.protective_distance:.3f} m with the hand at ISO 13855 speed '
                f'({"met" if self.meets else "not met"}; met at '
                f'{limit(self.arm_speed_limit)}), {self.protective_distance_still_hand:.3f} m '
                f'with a still hand ({"met" if self.meets_still_hand else "not met"}; met at '
                f'{limit(self.arm_speed_limit_still_hand)})')


def separation_verdict(d1: float, arm_speed: float,
                       settings: ProtectiveSeparation) -> SeparationVerdict:
    """The SeparationVerdict of a task with inner boundary d1 (m, > 0) for an arm moving
    towards the hand at arm_speed (m/s, >= 0). Raises ValueError for values out of range."""
    for name, value, floor in (('d1', d1, '> 0'), ('arm_speed', arm_speed, '>= 0')):
        if not (isinstance(value, int | float) and math.isfinite(value)
                and (value > 0.0 if floor == '> 0' else value >= 0.0)):
            raise ValueError(f'{name} must be a finite number {floor}, got {value!r}')
    iso = settings.iso_human_speed(d1)
    return SeparationVerdict(
        d1=float(d1), arm_speed=float(arm_speed),
        protective_distance=settings.distance(iso, arm_speed),
        protective_distance_still_hand=settings.distance(0.0, arm_speed),
        arm_speed_limit=settings.arm_speed_limit(d1),
        # A still hand whatever assume_iso_speed says (with it, 0 m/s would be raised to K).
        arm_speed_limit_still_hand=replace(settings, assume_iso_speed=False).arm_speed_limit(
            d1, 0.0))


def pair_separation_sample(distance: float, normal, robot_velocity, human_velocity,
                           settings: ProtectiveSeparation) -> SeparationSample:
    """S_p for the closest pair of the robot's and the person's capsules (hri_core.bodies):
    distance between their surfaces (m; below 0, overlapping, taken as 0), normal (3,) the
    unit vector from the robot's closest point towards the person's, robot_velocity and
    human_velocity (3,) m/s of those two points. The speeds are taken along the normal:
    human_speed = -v_h . n (towards the robot), robot_speed = v_r . n (towards the person)."""
    normal = np.asarray(normal, dtype=float)
    separation = max(float(distance), 0.0)
    human_speed = 0.0 - float(np.asarray(human_velocity, dtype=float) @ normal)
    robot_speed = float(np.asarray(robot_velocity, dtype=float) @ normal)
    used = settings.human_speed_used(human_speed, separation)
    return SeparationSample(separation, human_speed, robot_speed, used,
                            settings.distance(used, robot_speed))
