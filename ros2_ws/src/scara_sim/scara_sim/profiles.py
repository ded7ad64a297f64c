"""Scripted human motion: the hand profiles of hand_sim and the demonstrator's push.

The hand (`hand_sim`, topic /target) follows one of the named profiles of `HandProfile`.
The demonstrator plays the person who guides the end-effector during a demonstration (the
data behind the paper's eq. 3): its hand holds the tool through an impedance (a spring and a
damper, `hand_force`) whose set-point follows a minimum-jerk path (`minimum_jerk_segment`)
from where the end-effector starts to the demonstration's goal (`demonstration_goal`), plus
physiological tremor (`Tremor`: band-limited, seeded noise).

The hand profiles are planar by default (`dimension` 2: points [x, y] m, the SCARA's plane)
or in space (`dimension` 3: points [x, y, z] m, every profile's path in 3-D). The
demonstration (its goal, path, force and tremor) is of the arm's dimension: [x, y] for the
planar SCARA (the numbers of the planar demonstration are those it always had), [x, y, z] for
any other arm, whose tool the hand then pushes with a 3-D force along a straight path in
space (not only horizontal: the goal lies on the line through x_r, at any height). Positions
in m in the robot's base frame, times in s, forces in N. No ROS import.
"""

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from hri_core.robot_model import RobotModel
from hri_core.validation import planar_vector, point_vector, positive, spatial_vector

HAND_PROFILES = ('hold', 'approach', 'retreat', 'back_and_forth', 'circle', 'waypoints')
HAND_DIMENSIONS = (2, 3)
# The points each profile moves through (the others it does not use).
PROFILE_POINTS = {'hold': ('start',), 'approach': ('start', 'end'),
                  'retreat': ('start', 'end'), 'back_and_forth': ('start', 'end'),
                  'circle': ('start',), 'waypoints': ()}
DEMONSTRATION_MODES = ('follow', 'avoid')

# Peak speed of a minimum-jerk move over its mean speed: max of 30 s^2 (1 - s)^2 at s = 1/2.
MINIMUM_JERK_PEAK_RATIO = 1.875




def minimum_jerk(s) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-jerk time scaling: (10 s^3 - 15 s^4 + 6 s^5, its ds-derivative).

    s is normalised time (any shape), clipped to [0, 1]; the value runs 0 -> 1 with zero
    velocity and acceleration at both ends (Flash and Hogan's model of a reaching hand).
    """
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s ** 3 * (10.0 + s * (-15.0 + 6.0 * s)), 30.0 * s ** 2 * (1.0 - s) ** 2


def minimum_jerk_duration(distance: float, peak_speed: float) -> float:
    """Duration (s) of a minimum-jerk move of `distance` m whose peak speed is `peak_speed`."""
    positive(peak_speed, 'peak_speed', 'm/s')
    if not (math.isfinite(distance) and distance >= 0.0):
        raise ValueError(f'distance must be finite and >= 0 m, got {distance}')
    return MINIMUM_JERK_PEAK_RATIO * distance / peak_speed


def same_dimension(first, second, first_name: str, second_name: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Two points (m) of one dimension, 2 or 3 (validation.point_vector each); ValueError
    naming both if their dimensions differ."""
    first, second = point_vector(first, first_name, 'm'), point_vector(second, second_name, 'm')
    if first.shape != second.shape:
        raise ValueError(f'{first_name} and {second_name} must both be [x, y] or both '
                         f'[x, y, z], got {first.size} and {second.size} values')
    return first, second


def minimum_jerk_segment(start, end, t, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Position (..., d) in m and velocity (..., d) in m/s of a minimum-jerk move.

    Moves from `start` (d,) to `end` (d,) (d = 2 or 3, the same for both) over `duration` s,
    starting at t = 0; before that it is at `start`, after it at `end`. t may be a scalar or
    an array of shape (...). A zero duration jumps at t = 0.
    """
    start, end = same_dimension(start, end, 'start', 'end')
    t = np.asarray(t, dtype=float)
    if not (math.isfinite(duration) and duration >= 0.0):
        raise ValueError(f'duration must be finite and >= 0 s, got {duration}')
    if duration == 0.0:
        fraction, rate = (t >= 0.0).astype(float), np.zeros_like(t)
    else:
        fraction, ds = minimum_jerk(t / duration)
        rate = ds / duration
    delta = end - start
    return start + fraction[..., None] * delta, rate[..., None] * delta


@dataclass(frozen=True)
class HandProfile:
    """A scripted hand motion (see `hand_position`).

    name: one of HAND_PROFILES. dimension: 2 (points [x, y] m, the plane of the planar arm)
    or 3 (points [x, y, z] m). start, end: points of that dimension where the profile uses
    them (PROFILE_POINTS; an unused one may be [x, y] or [x, y, z]). speed: peak speed of the
    minimum-jerk moves of approach, retreat and waypoints (m/s). period: cycle time of
    back_and_forth and circle (s). radius: of the circle (m), centred on `start`, horizontal
    (at the height of `start` in 3-D). start_delay: time (s) the hand waits at its initial
    point. waypoints: flat [x0, y0, x1, y1, ...] (or [x0, y0, z0, x1, y1, z1, ...] in 3-D)
    (m), at least two points; segment_speeds: peak speed (m/s) of each waypoints move (one per
    move; empty: `speed` for all); pauses: time (s) the hand stays at each waypoint after the
    first before it moves on (one per move; empty: none). unseen_time: after each pass through
    the waypoints (the last move and its pause) the hand is out of sight this long (s; 0:
    never); repeat: then the pass starts again from the first waypoint (else the hand stays
    at the last one).
    """

    name: str = 'hold'
    start: tuple[float, ...] = (0.45, 0.05)
    end: tuple[float, ...] = (0.30, 0.30)
    speed: float = 0.15
    period: float = 8.0
    radius: float = 0.08
    start_delay: float = 0.0
    waypoints: tuple[float, ...] = field(default=())
    segment_speeds: tuple[float, ...] = field(default=())
    pauses: tuple[float, ...] = field(default=())
    unseen_time: float = 0.0
    repeat: bool = False
    dimension: int = 2

    def __post_init__(self):
        if self.name not in HAND_PROFILES:
            raise ValueError(f'unknown hand profile {self.name!r}; expected one of '
                             f'{", ".join(HAND_PROFILES)}')
        if self.dimension not in HAND_DIMENSIONS:
            raise ValueError(f'dimension must be 2 ([x, y]) or 3 ([x, y, z]), got '
                             f'{self.dimension}')
        point = planar_vector if self.dimension == 2 else spatial_vector
        for name in ('start', 'end'):
            if name not in PROFILE_POINTS[self.name]:  # unused: any finite point
                point_vector(getattr(self, name), name, 'm')
                continue
            try:
                point(getattr(self, name), name, 'm')
            except ValueError as error:
                raise ValueError(f'{error} (dimension is {self.dimension})') from None
        positive(self.speed, 'speed', 'm/s')
        positive(self.period, 'period', 's')
        positive(self.radius, 'radius', 'm')
        if not (math.isfinite(self.start_delay) and self.start_delay >= 0.0):
            raise ValueError(f'start_delay must be finite and >= 0 s, got {self.start_delay}')
        if not (math.isfinite(self.unseen_time) and self.unseen_time >= 0.0):
            raise ValueError(f'unseen_time must be finite and >= 0 s, got {self.unseen_time}')
        if (self.unseen_time > 0.0 or self.repeat) and self.name != 'waypoints':
            raise ValueError(f'unseen_time and repeat are for the waypoints profile, not '
                             f'{self.name}')
        if self.name == 'waypoints':
            d = self.dimension
            points = np.asarray(self.waypoints, dtype=float)
            if points.ndim != 1 or points.size < 2 * d or points.size % d:
                shape = '[x0, y0, x1, y1, ...]' if d == 2 else '[x0, y0, z0, x1, y1, z1, ...]'
                raise ValueError(f'waypoints must be a flat list {shape} of at least two '
                                 f'points, got {len(self.waypoints)} values')
            if not np.all(np.isfinite(points)):
                raise ValueError('waypoints must be finite')
            moves = points.size // d - 1
            for name, values in (('segment_speeds', self.segment_speeds),
                                 ('pauses', self.pauses)):
                if values and len(values) != moves:
                    raise ValueError(f'{name} must have one value per move ({moves}), got '
                                     f'{len(values)}')
            if not all(math.isfinite(v) and v > 0.0 for v in self.segment_speeds):
                raise ValueError('segment_speeds must be finite and > 0 m/s')
            if not all(math.isfinite(v) and v >= 0.0 for v in self.pauses):
                raise ValueError('pauses must be finite and >= 0 s')

    def points(self) -> np.ndarray:
        """The waypoints as (k, dimension) m."""
        return np.asarray(self.waypoints, dtype=float).reshape(-1, self.dimension)


def _waypoint_position(points: np.ndarray, t: float, speeds, pauses) -> np.ndarray:
    """Position along minimum-jerk moves between successive points (k, d): move i at peak
    speed speeds[i], then a pause of pauses[i] s at its end."""
    for a, b, speed, pause in zip(points[:-1], points[1:], speeds, pauses, strict=True):
        duration = minimum_jerk_duration(float(np.linalg.norm(b - a)), speed)
        if t <= duration:
            return minimum_jerk_segment(a, b, t, duration)[0]
        t -= duration + pause
        if t <= 0.0:
            return b.copy()
    return points[-1].copy()


def _pass_time(profile: HandProfile) -> float:
    """Duration (s) of one pass through the waypoints: every move and its pause."""
    schedule = waypoint_schedule(profile)
    pauses = profile.pauses or (0.0,) * len(schedule)
    return schedule[-1][1] + pauses[-1] - profile.start_delay


def _waypoint_time(profile: HandProfile, tau: float) -> tuple[float, bool]:
    """(time into the current pass, whether the hand is in sight) at tau s after start_delay
    (waypoints: a pass, then unseen_time out of sight, repeated if `repeat`)."""
    passing = _pass_time(profile)
    cycle = passing + profile.unseen_time
    if profile.repeat and cycle > 0.0:
        tau = math.fmod(tau, cycle)
    return tau, not (passing <= tau < cycle)


def hand_in_sight(profile: HandProfile, t: float) -> bool:
    """Whether the hand is in sight at t (s since the profile started): False only in the
    waypoints profile's unseen_time after each pass."""
    if profile.name != 'waypoints' or profile.unseen_time == 0.0:
        return True
    return _waypoint_time(profile, max(0.0, t - profile.start_delay))[1]


def waypoint_schedule(profile: HandProfile) -> list[tuple[float, float]]:
    """(start, end) times (s since the profile started) of each waypoints move."""
    points = profile.points()
    moves = len(points) - 1
    speeds = profile.segment_speeds or (profile.speed,) * moves
    pauses = profile.pauses or (0.0,) * moves
    t, schedule = profile.start_delay, []
    for a, b, speed, pause in zip(points[:-1], points[1:], speeds, pauses, strict=True):
        duration = minimum_jerk_duration(float(np.linalg.norm(b - a)), speed)
        schedule.append((t, t + duration))
        t += duration + pause
    return schedule


def hand_position(profile: HandProfile, t: float) -> np.ndarray:
    """Hand position (dimension,) in m at time t (s) since the profile started.

    hold: stays at `start`. approach: minimum-jerk move start -> end at peak speed `speed`,
    then stays at `end`. retreat: the same move backwards, end -> start. back_and_forth:
    start -> end -> start ... as start + (end - start) (1 - cos(2 pi t / period)) / 2.
    circle: centre `start`, `radius`, counter-clockwise seen from above (+z), one turn per
    `period`, beginning at start + [radius, 0(, 0)]; in 3-D at the height of `start`.
    waypoints: minimum-jerk moves through the points, then stays at the last (with `repeat`,
    after unseen_time s out of sight the moves start again from the first; hand_in_sight says
    when the hand is out of sight). Before `start_delay` the hand stays where the profile
    begins.
    """
    if not math.isfinite(t):
        raise ValueError(f't must be finite, got {t}')
    tau = max(0.0, t - profile.start_delay)
    start, end = np.asarray(profile.start, float), np.asarray(profile.end, float)
    if profile.name == 'hold':
        return start.copy()
    if profile.name in ('approach', 'retreat'):
        a, b = (start, end) if profile.name == 'approach' else (end, start)
        duration = minimum_jerk_duration(float(np.linalg.norm(b - a)), profile.speed)
        return minimum_jerk_segment(a, b, tau, duration)[0]
    if profile.name == 'back_and_forth':
        return start + (end - start) * 0.5 * (1.0 - math.cos(2.0 * math.pi * tau / profile.period))
    if profile.name == 'circle':
        angle = 2.0 * math.pi * tau / profile.period
        offset = np.zeros(profile.dimension)
        offset[:2] = math.cos(angle), math.sin(angle)
        return start + profile.radius * offset
    points = profile.points()
    moves = len(points) - 1
    if profile.repeat:
        tau = _waypoint_time(profile, tau)[0]
    return _waypoint_position(points, tau, profile.segment_speeds or (profile.speed,) * moves,
                              profile.pauses or (0.0,) * moves)


def demonstration_goal(mode: str, start, reference, stop_distance: float,
                       safe_distance: float, fallback_direction=(0.0, -1.0),
                       min_direction_distance: float = 0.005) -> np.ndarray:
    """Where the demonstrator brings the end-effector (d,) in m, base frame (d = 2 or 3, the
    dimension of `start` and `reference`).

    follow: onto the segment from `start` to the reference x_r, `stop_distance` m short of
    x_r (the paper's following behaviour stops near the target: d2 of Table I). avoid: along
    the ray from x_r through `start` out to `safe_distance` m from x_r (Table I's d1).
    When `start` is within `min_direction_distance` m of x_r the direction is
    `fallback_direction` instead. Raises ValueError when the move would not be toward x_r
    (follow) or away from it (avoid).
    """
    start, reference = same_dimension(start, reference, 'start', 'reference')
    positive(stop_distance, 'stop_distance', 'm')
    positive(safe_distance, 'safe_distance', 'm')
    offset = start - reference
    distance = float(np.linalg.norm(offset))
    if distance >= min_direction_distance:
        direction = offset / distance
    else:
        fallback = point_vector(fallback_direction, 'fallback_direction', 'm')
        if fallback.shape != start.shape:
            raise ValueError(f'fallback_direction must have {start.size} values, like start, '
                             f'got {fallback.size}')
        norm = float(np.linalg.norm(fallback))
        if norm == 0.0:
            raise ValueError('fallback_direction must not be zero')
        direction = fallback / norm
    if mode == 'follow':
        if distance <= stop_distance:
            raise ValueError(f'follow: the end-effector starts {distance:.3f} m from x_r, '
                             f'already within stop_distance {stop_distance:.3f} m')
        return reference + stop_distance * direction
    if mode == 'avoid':
        if distance >= safe_distance:
            raise ValueError(f'avoid: the end-effector starts {distance:.3f} m from x_r, '
                             f'already beyond safe_distance {safe_distance:.3f} m')
        return reference + safe_distance * direction
    raise ValueError(f'unknown demonstration mode {mode!r}; expected one of '
                     f'{", ".join(DEMONSTRATION_MODES)}')


def demonstration_dimension(arm: RobotModel) -> int:
    """The arm's task axes: 2 for a planar arm (the SCARA: its tool moves in the plane z =
    0), 3 for any other."""
    return arm.task_axes


def check_reach(arm: RobotModel, point, what: str) -> None:
    """ValueError unless `point` ((2,) or (3,) m, base frame) lies within the arm's reach of
    its shoulder (RobotModel.reach, an upper bound: a point within it may still be out of
    the arm's joint limits)."""
    point = point_vector(point, what, 'm')
    distance = float(np.linalg.norm(point - arm.shoulder[:point.size]))
    if distance > arm.reach:
        raise ValueError(f'{what} {np.round(point, 4).tolist()} m is {distance:.3f} m from the '
                         f'shoulder of {arm.name}, beyond its reach {arm.reach:.3f} m')


def demonstration_points(arm: RobotModel, reference, avoid_direction,
                         default_reference=None) -> tuple[np.ndarray, np.ndarray]:
    """x_r and the avoid direction of a demonstration on `arm`, each of its dimension
    (demonstration_dimension): `reference` (None: `default_reference`, which None makes a
    missing value) within the arm's reach, `avoid_direction` not zero (None: -y).
    ValueError with the reason."""
    dimension = demonstration_dimension(arm)
    shape = '[x, y]' if dimension == 2 else '[x, y, z]'
    if reference is None:
        if default_reference is None:
            raise ValueError(f'reference (x_r, {shape} m) must be given for {arm.name}')
        reference = default_reference
    reference = point_vector(reference, 'reference', 'm')
    if reference.size != dimension:
        raise ValueError(f'{arm.name} moves in {dimension}-D: reference must be {shape} (m), '
                         f'got {reference.size} values')
    check_reach(arm, reference, 'reference')
    if avoid_direction is None:
        direction = np.zeros(dimension)
        direction[1] = -1.0
        return reference, direction
    direction = point_vector(avoid_direction, 'avoid_direction')
    if direction.size != dimension or not np.any(direction):
        raise ValueError(f'avoid_direction must be {dimension} values, not all zero, like '
                         f'reference, got {direction.tolist()}')
    return reference, direction


def hand_force(setpoint, setpoint_velocity, position, velocity, stiffness: float,
               damping: float, max_force: float) -> np.ndarray:
    """Force (..., d) in N of a hand holding the tool: K (x_s - x) + D (v_s - v), capped.

    The arm's impedance of a person guiding a robot: set-point x_s (m) and its velocity
    v_s (m/s), end-effector position x (m) and velocity v (m/s), stiffness K (N/m) and
    damping D (N s/m). The force's magnitude is capped at `max_force` N, direction kept.
    """
    positive(stiffness, 'stiffness', 'N/m')
    if not (math.isfinite(damping) and damping >= 0.0):
        raise ValueError(f'damping must be finite and >= 0 N s/m, got {damping}')
    positive(max_force, 'max_force', 'N')
    force = (stiffness * (np.asarray(setpoint, float) - np.asarray(position, float))
             + damping * (np.asarray(setpoint_velocity, float) - np.asarray(velocity, float)))
    if not np.all(np.isfinite(force)):
        raise ValueError('hand force inputs must be finite')
    magnitude = np.linalg.norm(force, axis=-1, keepdims=True)
    return force * np.minimum(1.0, max_force / np.maximum(magnitude, 1e-300))


class Tremor:
    """Physiological hand tremor: white noise through a band-pass, `axes` axes (2: the planar
    arm's x, y; 3: x, y, z), seeded.

    Each axis is Gaussian white noise through a 4th-order Butterworth band-pass
    [low, high] Hz sampled at `rate_hz`, scaled so that its stationary RMS is `amplitude` N.
    Streaming: `sample()` returns the next (axes,) value, `at(t)` the value at time t; the same
    seed gives the same sequence.
    """

    def __init__(self, amplitude: float, band: tuple[float, float], rate_hz: float,
                 seed: int, axes: int = 2):
        if not (math.isfinite(amplitude) and amplitude >= 0.0):
            raise ValueError(f'tremor amplitude must be finite and >= 0 N, got {amplitude}')
        if axes not in (2, 3):
            raise ValueError(f'tremor axes must be 2 or 3, got {axes}')
        low, high = float(band[0]), float(band[1])
        rate_hz = positive(rate_hz, 'rate_hz', 'Hz')
        if not (0.0 < low < high < 0.5 * rate_hz):
            raise ValueError(f'tremor band must satisfy 0 < low < high < rate/2 = '
                             f'{0.5 * rate_hz} Hz, got [{low}, {high}]')
        # Imported here: scipy.signal costs about a second at start-up, and of the nodes
        # using this module only the demonstrator has a tremor.
        from scipy import signal
        self._sosfilt = signal.sosfilt
        self._sos = signal.butter(2, [low, high], btype='bandpass', fs=rate_hz, output='sos')
        impulse = np.zeros(int(20 * rate_hz))
        impulse[0] = 1.0
        noise_gain = float(np.sqrt(np.sum(self._sosfilt(self._sos, impulse) ** 2)))
        self._scale = amplitude / noise_gain
        self._rng = np.random.default_rng(seed)
        self.axes = axes
        self._state = np.zeros((self._sos.shape[0], 2, axes))  # (sections, 2, axes)
        self._rate_hz = rate_hz
        self._samples = 0
        self._last = np.zeros(axes)

    def sample(self) -> np.ndarray:
        """The next tremor force (axes,) in N."""
        out, self._state = self._sosfilt(self._sos, self._rng.standard_normal((1, self.axes)),
                                          axis=0, zi=self._state)
        self._samples += 1
        self._last = self._scale * out[-1]
        return self._last

    def at(self, t: float) -> np.ndarray:
        """The tremor force (axes,) in N at time t (s since the first sample): the filter runs
        every sample period up to t, so late or missed calls keep the tremor's band and RMS
        in time; the sequence in time is the one `sample()` gives when called at rate_hz."""
        due = math.floor(t * self._rate_hz) + 1 - self._samples
        if due > 0:
            out, self._state = self._sosfilt(self._sos,
                                              self._rng.standard_normal((due, self.axes)),
                                              axis=0, zi=self._state)
            self._samples += due
            self._last = self._scale * out[-1]
        return self._last


@dataclass(frozen=True)
class PushSettings:
    """How the demonstrator's hand pushes (see `Demonstration`).

    stiffness (N/m) and damping (N s/m) of the hand's impedance, max_force (N), peak_speed
    of the set-point's minimum-jerk path (m/s); arrived: within settle_tolerance (m) of the
    goal without a break for settle_time (s), at a mean speed over that time below
    settle_speed (m/s);
    settle_timeout (s) after the path ends before letting go anyway (and the last moment the
    hand takes the tool again), hold_time (s) the hand stays off (zero force) with the
    end-effector still within settle_tolerance before the demonstration is done.
    """

    stiffness: float = 300.0
    damping: float = 40.0
    max_force: float = 30.0
    peak_speed: float = 0.15
    settle_tolerance: float = 0.002
    settle_speed: float = 0.002
    settle_time: float = 0.2
    settle_timeout: float = 5.0
    hold_time: float = 3.0

    def __post_init__(self):
        for name in ('stiffness', 'max_force', 'peak_speed', 'settle_tolerance',
                     'settle_speed', 'settle_timeout'):
            positive(getattr(self, name), name, '')
        for name in ('damping', 'settle_time', 'hold_time'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')


# Oldest position (s) the hand extrapolates to the present; an older one is used as it is.
MAX_POSITION_AGE = 0.1


class Demonstration:
    """The demonstrator's push from `start` to `goal`, as a force for each moment.

    Phases: 'pushing' while the set-point runs its minimum-jerk path (duration from
    `peak_speed`); 'settling' with the set-point at the goal until the end-effector has been
    within settle_tolerance of it for settle_time s, moving on average slower than
    settle_speed over that time (or
    settle_timeout passes after the path's end); then the hand lets go: 'holding' (zero
    force) for hold_time; then 'done'. An end-effector that drifts out of settle_tolerance
    while the hand is off is taken again ('settling', counted in `regrasps`) until
    settle_timeout. The force is `hand_force` plus `tremor` (None: no tremor) while the hand
    holds the tool.

    Every decision uses the time t given to `update`, never a count of calls: a caller whose
    calls come late (a loaded machine) gets the same path, dwell and hold in time.
    """

    def __init__(self, start, goal, settings: PushSettings, tremor: 'Tremor | None' = None):
        self.start, self.goal = same_dimension(start, goal, 'start', 'goal')
        if tremor is not None and tremor.axes != self.start.size:
            raise ValueError(f'the tremor has {tremor.axes} axes, the demonstration '
                             f'{self.start.size}')
        self.settings = settings
        self.tremor = tremor
        self.duration = minimum_jerk_duration(float(np.linalg.norm(self.goal - self.start)),
                                              settings.peak_speed)
        self.phase = 'pushing'
        self.released_at: float | None = None
        self.settle_timed_out = False
        self.regrasps = 0
        self._window: deque[tuple[float, np.ndarray]] = deque()  # (t, position) within

    def _point(self, value, name: str, unit: str) -> np.ndarray:
        """`value` as a point of the demonstration's dimension; ValueError otherwise."""
        point = point_vector(value, name, unit)
        if point.shape != self.start.shape:
            raise ValueError(f'{name} must have {self.start.size} values, like start, got '
                             f'{point.size}')
        return point

    def _arrived(self, t: float, position: np.ndarray, within: bool) -> bool:
        """Whether the end-effector has stayed within settle_tolerance for settle_time s and
        moved on average slower than settle_speed over that time.

        The mean over the window, not the instantaneous speed: the tremor alone shakes the
        held arm at about 1-2 mm/s (10 Hz), while what the arm keeps after the hand lets go
        is its slow drift, which the mean measures.
        """
        s = self.settings
        if not within:
            self._window.clear()
            return False
        self._window.append((t, position))
        while len(self._window) > 1 and t - self._window[1][0] >= s.settle_time:
            self._window.popleft()
        since, first = self._window[0]
        if t - since < s.settle_time:
            return False
        if t == since:  # settle_time 0: a single sample within tolerance is enough
            return True
        return bool(np.linalg.norm(position - first) / (t - since) <= s.settle_speed)

    def update(self, t: float, position, velocity, age: float = 0.0) -> np.ndarray:
        """Force (d,) in N at time t (s since the push began) for the measured end-effector
        position (d,) in m and velocity (d,) in m/s (d: the dimension of start), measured `age`
        s before t; advances the phase.

        The position is extrapolated to t with the velocity (an age up to
        MAX_POSITION_AGE s): a position that arrives late would otherwise make the hand's
        spring and damper lag behind the arm and overshoot.
        """
        s = self.settings
        position = self._point(position, 'position', 'm')
        velocity = self._point(velocity, 'velocity', 'm/s')
        if not (math.isfinite(age) and age >= 0.0):
            raise ValueError(f'age must be finite and >= 0 s, got {age}')
        position = position + velocity * min(age, MAX_POSITION_AGE)
        within = bool(np.linalg.norm(position - self.goal) <= s.settle_tolerance)
        timed_out = t >= self.duration + s.settle_timeout
        if self.phase == 'pushing' and t >= self.duration:
            self.phase = 'settling'
        if self.phase == 'holding' and not within and not timed_out \
                and not self.settle_timed_out:
            self.phase, self.released_at, self.regrasps = 'settling', None, self.regrasps + 1
        if self.phase == 'settling':
            arrived = self._arrived(t, position, within)
            if arrived or timed_out:
                self.settle_timed_out = not arrived
                self.phase, self.released_at = 'holding', t
                self._window.clear()
        if self.phase == 'holding' and t >= self.released_at + s.hold_time:
            self.phase = 'done'
        if self.phase in ('holding', 'done'):
            return np.zeros(self.start.size)
        setpoint, setpoint_velocity = minimum_jerk_segment(self.start, self.goal, t,
                                                           self.duration)
        force = hand_force(setpoint, setpoint_velocity, position, velocity, s.stiffness,
                           s.damping, s.max_force)
        return force if self.tremor is None else force + self.tremor.at(t)
