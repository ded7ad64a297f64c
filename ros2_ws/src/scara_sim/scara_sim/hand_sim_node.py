"""The `hand_sim` node: the human hand on /target, from a scripted profile or a recording.

Publishes geometry_msgs/PointStamped (frame `base_frame`, m) on /target at `rate_hz`, the
position of `profiles.hand_position` for the profile named by `profile` (hold, approach,
retreat, back_and_forth, circle, waypoints) and its parameters `start`, `end`, `speed`,
`period`, `radius`, `start_delay`, `waypoints` (with `segment_speeds`, `pauses`, and
`unseen_time` and `repeat`: out of sight after each pass, nothing published, then again from
the first waypoint). `dimension` 2 (the default, the planar
SCARA's) takes the points as [x, y] and publishes z = 0; 3 takes them as [x, y, z] (waypoints
flat in threes) for an arm that reaches in space (`robot:=panda`). The profile's clock starts
when the node does; changing any profile parameter at run time (validated) restarts it (to
switch `dimension`, set it and the points the profile uses in one call).

`profile: recording` replays a Vicon Nexus CSV export (`recording`, hri_core.recorded_motion)
at its recorded pace: the segment `segment`, moved into the base frame by p_base =
Rz(`yaw`) p_room + `translation` (or, with `auto_place`, by the placement that keeps the
person's hip, collar and head `body_clearance` m from the base through the whole take and
its capsules at the first frame `arm_clearance` m from the arm `arm` at its home pose, and,
among those, puts most of the take's horizontal path within the `reach` annulus), its times
multiplied by `time_scale`;
at the end it loops, stops or holds the last frame (`at_end`). Each tick publishes the newest
frame due, stamped with the time it was recorded at (the replay's start plus the frame's
time), x, y and z; a lost frame publishes nothing. A file that cannot be read ends the node
at start with one line and exit code 1 (refused at run time with the reason).

With every /target the node publishes the person on /human/body (hri_interfaces/HumanBody,
REP-155 names, hri_core.human_body): for a recording every segment of that frame, placed as
the hand, a segment lost in it left out; for a scripted profile a standing body whose body
point is at `body_place` [x, y] and `body_height` m, facing `body_yaw` (unset: the base),
whose right wrist is the scripted hand (elbow by two-link inverse kinematics).
"""

import math
import sys
import time
from dataclasses import dataclass, replace

import numpy as np
from geometry_msgs.msg import Point, PointStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node

from hri_core import topics
from hri_core.bodies import clear_of_arm, human_capsules, panda_package_dirs, robot_body
from hri_core.cdr import point_stamped_template
from hri_core.human_body import (
    BODY_POINTS,
    RecordedBody,
    read_recorded_body,
    standing_body,
)
from hri_core.node_common import (
    REALTIME_PRIORITY,
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    request_realtime,
    run_node,
)
from hri_core.recorded_motion import (
    AT_END,
    Placement,
    ReachAnnulus,
    Replay,
    choose_placement,
    read_vicon_csv,
)
from hri_core.robot_model import robot_model
from scara_sim.profiles import (
    HAND_DIMENSIONS,
    HAND_PROFILES,
    HandProfile,
    hand_in_sight,
    hand_position,
)

PACKAGE = 'scara_sim'
NODE_NAME = 'hand_sim'
RECORDING = 'recording'
SOURCES = (*HAND_PROFILES, RECORDING)
PARAMETERS = {
    'rate_hz': ParameterSpec(float, 'publish rate of /target (Hz)', 1.0, 1000.0,
                             read_only=True),
    'realtime_priority': REALTIME_PRIORITY,
    'profile': ParameterSpec(str, 'hand motion: ' + ', '.join(SOURCES),
                             choices=SOURCES),
    'start': ParameterSpec(list, 'start point [x, y] ([x, y, z] with dimension 3) (m); '
                           'centre of the circle'),
    'end': ParameterSpec(list, 'end point [x, y] ([x, y, z] with dimension 3) (m)'),
    'speed': ParameterSpec(float, 'peak speed of approach, retreat and waypoints moves (m/s)',
                           0.001, 5.0),
    'period': ParameterSpec(float, 'cycle time of back_and_forth and circle (s)', 0.1, 3600.0),
    'radius': ParameterSpec(float, 'circle radius (m)', 0.001, 2.0),
    'start_delay': ParameterSpec(float, 'time the hand waits before moving (s)', 0.0, 3600.0),
    'waypoints': ParameterSpec(list,
                               'waypoints profile: flat [x0, y0, x1, y1, ...] (m); with '
                               'dimension 3 [x0, y0, z0, x1, y1, z1, ...]'),
    'dimension': ParameterSpec(int, 'points of the scripted profiles: 2 [x, y] (z = 0 '
                               'published) or 3 [x, y, z]', min(HAND_DIMENSIONS),
                               max(HAND_DIMENSIONS)),
    'segment_speeds': ParameterSpec(list, 'waypoints profile: peak speed of each move (m/s); '
                                    'unset: speed', optional=True),
    'pauses': ParameterSpec(list, 'waypoints profile: time at the end of each move (s); '
                            'unset: none', optional=True),
    'unseen_time': ParameterSpec(float, 'waypoints profile: out of sight (nothing published) '
                                 'for this long after each pass (s)', 0.0, 3600.0),
    'repeat': ParameterSpec(bool, 'waypoints profile: pass through the waypoints again after '
                            'each pass and its unseen_time'),
    'base_frame': ParameterSpec(str, 'frame of /target', read_only=True),
    'recording': ParameterSpec(str, 'recording profile: Vicon Nexus CSV export to replay'),
    'segment': ParameterSpec(str, 'recording profile: segment to replay (right_hand, '
                             'left_hand, head, ...)'),
    'translation': ParameterSpec(list, 'recording profile: room-to-base translation [x, y, z] '
                                 '(m), p_base = Rz(yaw) p_room + translation', size=3),
    'yaw': ParameterSpec(float, 'recording profile: room-to-base rotation about z (rad)',
                         -2.0 * math.pi, 2.0 * math.pi),
    'auto_place': ParameterSpec(bool, 'recording profile: place the take so that most of its '
                                'horizontal path is within `reach` (translation, yaw unused)'),
    'reach': ParameterSpec(list, 'recording profile: inner and outer radius of the arm\'s '
                           'reach for auto_place (m)', size=2),
    'time_scale': ParameterSpec(float, 'recording profile: recorded time multiplier (2: half '
                                'speed)', 0.01, 100.0),
    'at_end': ParameterSpec(str, 'recording profile: at the end ' + ' | '.join(AT_END),
                            choices=AT_END),
    'body_clearance': ParameterSpec(float, 'recording profile: auto_place keeps the person\'s '
                                    'hip, collar and head at least this far from the base, '
                                    'horizontally, through the whole take (m; the Panda: '
                                    '0.45)', 0.0, 2.0),
    'arm': ParameterSpec(str, 'recording profile: auto_place keeps the person at the '
                         'take\'s first frame at least arm_clearance from this arm at its '
                         'home pose (a robot name: scara, panda, ...; empty: no such rule)'),
    'arm_clearance': ParameterSpec(float, 'recording profile: the distance (m) of `arm`\'s '
                                   'rule', 0.0, 2.0),
    'body_place': ParameterSpec(list, 'scripted profiles: where the person stands, [x, y] of '
                                'the point between the hips (m) on /human/body', size=2),
    'body_height': ParameterSpec(float, 'scripted profiles: z of the point between the hips '
                                 '(m)', -2.0, 2.0),
    'body_yaw': ParameterSpec(float, 'scripted profiles: the direction the person faces '
                              '(rad about z); unset: towards the base', -2.0 * math.pi,
                              2.0 * math.pi, optional=True),
}
RECORDING_PARAMETERS = ('recording', 'segment', 'translation', 'yaw', 'auto_place', 'reach',
                        'time_scale', 'at_end', 'body_clearance', 'arm', 'arm_clearance')
BODY_PARAMETERS = ('body_place', 'body_height', 'body_yaw')
PROFILE_PARAMETERS = ('profile', 'start', 'end', 'speed', 'period', 'radius', 'start_delay',
                      'waypoints', 'dimension', 'segment_speeds', 'pauses', 'unseen_time',
                      'repeat',
                      *RECORDING_PARAMETERS, *BODY_PARAMETERS)


def _clear_of_arm(arm: str, body: RecordedBody, clearance: float):
    """auto_place's rule that the person at the take's first frame keeps `clearance`
    m from the arm named `arm` at its home pose (arm_sim starts there), or None for ''."""
    if not arm:
        return None
    return clear_of_arm(robot_body(robot_model(arm), panda_package_dirs()),
                        human_capsules(*body.first_frame()), clearance)


@dataclass(frozen=True)
class StandingPlace:
    """Where the scripted profiles' person stands: place (2,) m, height m, yaw rad."""

    place: tuple[float, float]
    height: float
    yaw: float


class HandSim(Node):
    """Publishes the scripted or recorded hand position at rate_hz."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        rate_hz = values['rate_hz']
        self._frame = values['base_frame']
        try:
            self._source, self._body = self._source_from({})
        except ValueError as error:
            what = 'recording' if values['profile'] == RECORDING else 'parameters'
            raise StartupError(f'bad {what}: {error}') from None
        self._restart_clock()
        self._published = 0  # hand positions, for the summary line at the stop
        self._node_started = time.monotonic()
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._publisher = self.create_publisher(PointStamped, topics.TARGET.name,
                                                topics.TARGET.qos)
        self._body_publisher = self.create_publisher(topics.HUMAN_BODY.type,
                                                     topics.HUMAN_BODY.name,
                                                     topics.HUMAN_BODY.qos)
        # Published as serialized CDR from a template: the node's 100 Hz tick runs beside the
        # 1 kHz loop on the same cores, so the less it holds a CPU the better.
        self._template = point_stamped_template(self._frame)
        self.create_timer(1.0 / rate_hz, self._publish)
        # Asked for once the set-up (a recording's placement: seconds of CPU) is done; below
        # the 1 kHz loop's priority, which a profile changed at run time must not hold up.
        request_realtime(self, values['realtime_priority'])
        self.get_logger().info(f'hand profile {self._describe()} at {rate_hz:g} Hz on '
                               f'{self._publisher.topic_name}, the body on '
                               f'{self._body_publisher.topic_name} ({self._describe_body()})')

    def _restart_clock(self) -> None:
        self._started = time.monotonic()
        self._started_ns = self.get_clock().now().nanoseconds
        self._last_frame_time = None  # the recorded time of the last frame published

    def _source_from(self, overrides: dict
                     ) -> tuple[HandProfile | Replay, RecordedBody | StandingPlace]:
        def value(name):
            if name in overrides:
                return overrides[name]
            try:
                return self.get_parameter(name).value
            except ParameterUninitializedException:  # an optional parameter left unset
                return None

        if value('profile') == RECORDING:
            return self._replay_from(value)
        place = tuple(float(v) for v in value('body_place'))
        if not all(math.isfinite(v) for v in place):
            raise ValueError(f'body_place must be finite, got {list(place)}')
        yaw = value('body_yaw')
        if yaw is None:
            if math.hypot(*place) == 0.0:
                raise ValueError('body_place [0, 0] is the base itself: set body_yaw or '
                                 'stand elsewhere')
            yaw = math.atan2(-place[1], -place[0])
        return HandProfile(
            name=value('profile'), start=tuple(value('start')), end=tuple(value('end')),
            speed=value('speed'), period=value('period'), radius=value('radius'),
            start_delay=value('start_delay'), waypoints=tuple(value('waypoints')),
            segment_speeds=tuple(value('segment_speeds') or ()),
            pauses=tuple(value('pauses') or ()), unseen_time=value('unseen_time'),
            repeat=value('repeat'), dimension=value('dimension')), \
            StandingPlace(place, float(value('body_height')), float(yaw))

    @staticmethod
    def _replay_from(value) -> tuple[Replay, RecordedBody]:
        """The replay the recording parameters ask for; ValueError with the reason."""
        if not value('recording'):
            raise ValueError('profile recording needs the parameter recording (a Vicon CSV '
                             'export)')
        motion = read_vicon_csv(value('recording'), value('segment'),
                                time_scale=value('time_scale'))
        body = read_recorded_body(value('recording'), time_scale=value('time_scale'))
        if value('auto_place'):
            inner, outer = value('reach')
            placement = choose_placement(motion.positions, ReachAnnulus(inner, outer),
                                         body=body.trunk(), clearance=value('body_clearance'),
                                         accept=_clear_of_arm(value('arm'), body,
                                                              value('arm_clearance')))
        else:
            placement = Placement(tuple(float(v) for v in value('translation')),
                                  float(value('yaw')))
        placed = placement.apply(body.points.reshape(-1, 3)).reshape(body.points.shape)
        return (Replay(replace(motion, positions=placement.apply(motion.positions)),
                       value('at_end'), placement), replace(body, points=placed))

    def _describe(self) -> str:
        p = self._source
        if isinstance(p, Replay):
            m = p.motion
            where = p.placement
            return (f'recording ({self.get_parameter("recording").value}, {m.segment}, '
                    f'{len(m.times)} frames over {m.times[-1]:.1f} s, '
                    f'{100.0 * (1.0 - m.valid.mean()):.1f} % lost; translation '
                    f'{[round(v, 3) for v in where.translation]} m, yaw {where.yaw:.3f} rad, '
                    f'trunk at least {self._trunk_clearance():.3f} m from the base; '
                    f'at end {p.at_end})')
        details = {'hold': f'at {list(p.start)}',
                   'approach': f'{list(p.start)} -> {list(p.end)} at {p.speed} m/s',
                   'retreat': f'{list(p.end)} -> {list(p.start)} at {p.speed} m/s',
                   'back_and_forth': f'{list(p.start)} <-> {list(p.end)}, period {p.period} s',
                   'circle': f'centre {list(p.start)}, radius {p.radius} m, '
                             f'period {p.period} s',
                   'waypoints': f'{len(p.waypoints) // p.dimension} points at '
                                f'{list(p.segment_speeds) or p.speed} m/s'
                                + (f', pauses {list(p.pauses)} s' if p.pauses else '')}
        return (f'{p.name} ({details[p.name]}, start delay {p.start_delay} s, '
                f'{p.dimension}-D)')

    def _describe_body(self) -> str:
        body = self._body
        if isinstance(body, RecordedBody):
            return 'every segment of the take'
        return (f'standing at {list(body.place)} m, height {body.height} m, facing '
                f'{body.yaw:.3f} rad')

    def _trunk_clearance(self) -> float:
        """The least horizontal distance (m) of the replayed take's trunk from the base."""
        trunk = self._body.trunk()
        trunk = trunk[np.all(np.isfinite(trunk), axis=1)]
        return float(np.min(np.hypot(trunk[:, 0], trunk[:, 1]))) if len(trunk) else math.inf

    def _validate_parameters(self, parameters) -> SetParametersResult:
        if not parameters:  # an empty request (a client's handshake): nothing to check
            return SetParametersResult(successful=True)
        try:
            self._source_from({p.name: p.value for p in parameters})
        except (ValueError, TypeError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters) -> None:
        if any(p.name in PROFILE_PARAMETERS for p in parameters):
            self._source, self._body = self._source_from({})
            self._restart_clock()
            self.get_logger().info(f'hand profile restarted: {self._describe()}; body '
                                   f'{self._describe_body()}')

    def _publish(self) -> None:
        if isinstance(self._source, Replay):
            self._publish_frame()
            return
        since = time.monotonic() - self._started
        if not hand_in_sight(self._source, since):
            return  # out of sight: neither the hand nor the body
        position = hand_position(self._source, since).tolist()
        if len(position) == 2:
            position.append(0.0)  # the planar arm's plane
        now = self.get_clock().now()
        stamp = now.seconds_nanoseconds()
        self._publisher.publish(self._template.encode(tuple(position), stamp=stamp))
        where = self._body
        self._publish_body(BODY_POINTS, standing_body(where.place, where.yaw, where.height,
                                                      position), stamp)
        self._published += 1

    def _publish_body(self, names, points, stamp: tuple[int, int]) -> None:
        """names (K,) and points (K, 3) m on /human/body, stamped (sec, nanosec); nothing
        for K = 0."""
        if not len(names):
            return
        msg = topics.HUMAN_BODY.type()
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
        msg.header.frame_id = self._frame
        msg.names = list(names)
        msg.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in points]
        self._body_publisher.publish(msg)

    def _publish_frame(self) -> None:
        """The newest recorded frame due, once, stamped when it was recorded; nothing for a
        lost frame."""
        started = self._started_ns
        due = self._source.due((self.get_clock().now().nanoseconds - started) * 1e-9)
        if due is None or due[1] == self._last_frame_time:
            return
        index, frame_time = due
        self._last_frame_time = frame_time
        motion = self._source.motion
        stamp = started + int(round(frame_time * 1e9))
        stamp = (stamp // 1_000_000_000, stamp % 1_000_000_000)
        if motion.valid[index]:
            x, y, z = motion.positions[index]
            self._publisher.publish(self._template.encode((float(x), float(y), float(z)),
                                                          stamp=stamp))
            self._published += 1
        self._publish_body(*self._body.frame(index), stamp)

    def summary(self) -> str:
        """One line on what the node did (run_node logs it at the stop)."""
        what = ('recording' if isinstance(self._source, Replay)
                else f'profile {self._source.name}')
        return (f'{self._published} hand positions published on {self._publisher.topic_name} '
                f'in {time.monotonic() - self._node_started:.1f} s ({what})')


def main(args=None):
    # The EventsExecutor: with the SingleThreadedExecutor the 100 Hz publish timer kept the
    # node at 12.0 % of a core, with it 5.8 % (10 s each, idle machine).
    return run_node(HandSim, NODE_NAME, EventsExecutor, args)


if __name__ == '__main__':
    sys.exit(main())
