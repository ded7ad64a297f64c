"""The `hand_sim` node: the human hand on /target, from a scripted profile.

Publishes geometry_msgs/PointStamped (frame `base_frame`, m) on /target at `rate_hz`, the
position of `profiles.hand_position` for the profile named by `profile` (hold, approach,
retreat, back_and_forth, circle, waypoints) and its parameters `start`, `end`, `speed`,
`period`, `radius`, `start_delay`, `waypoints`. The profile's clock starts when the node
does; changing any profile parameter at run time (validated) restarts it.
"""

import sys
import time

from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node

from hri_core import topics
from hri_core.cdr import point_stamped_template
from hri_core.node_common import (
    ParameterSpec,
    StartupError,
    declare_parameters,
    load_defaults,
    run_node,
)
from scara_sim.profiles import HAND_PROFILES, HandProfile, hand_position

PACKAGE = 'scara_sim'
NODE_NAME = 'hand_sim'
PARAMETERS = {
    'rate_hz': ParameterSpec(float, 'publish rate of /target (Hz)', 1.0, 1000.0,
                             read_only=True),
    'profile': ParameterSpec(str, 'hand motion: ' + ', '.join(HAND_PROFILES),
                             choices=HAND_PROFILES),
    'start': ParameterSpec(list, 'start point [x, y] (m); centre of the circle',
                           size=2),
    'end': ParameterSpec(list, 'end point [x, y] (m)', size=2),
    'speed': ParameterSpec(float, 'peak speed of approach, retreat and waypoints moves (m/s)',
                           0.001, 5.0),
    'period': ParameterSpec(float, 'cycle time of back_and_forth and circle (s)', 0.1, 3600.0),
    'radius': ParameterSpec(float, 'circle radius (m)', 0.001, 2.0),
    'start_delay': ParameterSpec(float, 'time the hand waits before moving (s)', 0.0, 3600.0),
    'waypoints': ParameterSpec(list,
                               'waypoints profile: flat [x0, y0, x1, y1, ...] (m)'),
    'segment_speeds': ParameterSpec(list, 'waypoints profile: peak speed of each move (m/s); '
                                    'unset: speed', optional=True),
    'pauses': ParameterSpec(list, 'waypoints profile: time at the end of each move (s); '
                            'unset: none', optional=True),
    'base_frame': ParameterSpec(str, 'frame of /target', read_only=True),
}
PROFILE_PARAMETERS = ('profile', 'start', 'end', 'speed', 'period', 'radius', 'start_delay',
                      'waypoints', 'segment_speeds', 'pauses')


class HandSim(Node):
    """Publishes the scripted hand position at rate_hz."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMETERS, load_defaults(PACKAGE, NODE_NAME))
        rate_hz = values['rate_hz']
        self._frame = values['base_frame']
        try:
            self._profile = self._profile_from({})
        except ValueError as error:
            raise StartupError(f'bad parameters: {error}') from None
        self._started = time.monotonic()
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._publisher = self.create_publisher(PointStamped, topics.TARGET.name,
                                                topics.TARGET.qos)
        # Published as serialized CDR from a template: the node's 100 Hz tick runs beside the
        # 1 kHz loop on the same cores, so the less it holds a CPU the better.
        self._template = point_stamped_template(self._frame)
        self.create_timer(1.0 / rate_hz, self._publish)
        self.get_logger().info(f'hand profile {self._describe()} at {rate_hz:g} Hz on '
                               f'{self._publisher.topic_name}')

    def _profile_from(self, overrides: dict) -> HandProfile:
        def value(name):
            if name in overrides:
                return overrides[name]
            try:
                return self.get_parameter(name).value
            except ParameterUninitializedException:  # an optional parameter left unset
                return None

        return HandProfile(
            name=value('profile'), start=tuple(value('start')), end=tuple(value('end')),
            speed=value('speed'), period=value('period'), radius=value('radius'),
            start_delay=value('start_delay'), waypoints=tuple(value('waypoints')),
            segment_speeds=tuple(value('segment_speeds') or ()),
            pauses=tuple(value('pauses') or ()))

    def _describe(self) -> str:
        p = self._profile
        details = {'hold': f'at {list(p.start)}',
                   'approach': f'{list(p.start)} -> {list(p.end)} at {p.speed} m/s',
                   'retreat': f'{list(p.end)} -> {list(p.start)} at {p.speed} m/s',
                   'back_and_forth': f'{list(p.start)} <-> {list(p.end)}, period {p.period} s',
                   'circle': f'centre {list(p.start)}, radius {p.radius} m, '
                             f'period {p.period} s',
                   'waypoints': f'{len(p.waypoints) // 2} points at '
                                f'{list(p.segment_speeds) or p.speed} m/s'
                                + (f', pauses {list(p.pauses)} s' if p.pauses else '')}
        return f'{p.name} ({details[p.name]}, start delay {p.start_delay} s)'

    def _validate_parameters(self, parameters) -> SetParametersResult:
        try:
            self._profile_from({p.name: p.value for p in parameters})
        except (ValueError, TypeError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters) -> None:
        if any(p.name in PROFILE_PARAMETERS for p in parameters):
            self._profile = self._profile_from({})
            self._started = time.monotonic()
            self.get_logger().info(f'hand profile restarted: {self._describe()}')

    def _publish(self) -> None:
        x, y = hand_position(self._profile, time.monotonic() - self._started)
        stamp = self.get_clock().now().seconds_nanoseconds()
        self._publisher.publish(self._template.encode((float(x), float(y), 0.0), stamp=stamp))


def main(args=None):
    # The EventsExecutor: with the SingleThreadedExecutor the 100 Hz publish timer kept the
    # node at 12.0 % of a core, with it 5.8 % (10 s each, idle machine).
    return run_node(HandSim, NODE_NAME, EventsExecutor, args)


if __name__ == '__main__':
    sys.exit(main())
