"""The live view's 3-D scene as plain data: the arm, the hand and the active task's region.

`live_view` draws this at `scene_rate_hz`; the geometry lives here, without ROS or foxglove,
so that it is tested on its own. Everything is in the arm's base frame (m).

Two kinds of arm. With no /robot_description, the planar SCARA, in the plane z = 0 in which it
moves and its task distances are measured:

- the arm (`arm_entity`): link 1 from the base to the elbow and link 2 from the elbow to the
  end-effector (`hri_core.dynamics.forward_kinematics`) as rods, its joints as balls;
- the hand (`hand_entity`): a ball at the /target position;
- the active task's desired region (`region_entity`): rings of radius d1 and d2 around the hand,
  the region between them shaded (for s = -1 the inside of d1 and the outside of d2), in a
  colour that goes from grey to green as the event weight a goes from 0 to 1. A d2 beyond
  `display_radius` (an open region such as avoid's d2 = 2 m) is drawn at that radius, dashed.
  A label names the task, a, the phase and the end-effector's distance to the hand.

`scene_entities` gives the three entities; one with nothing to draw (no joint state, no hand,
no task yet) is returned empty, so that sending it clears what the viewer showed before.
`arm_frames` gives the arm's frames (base -> link1 -> link2 -> tool) for a transform tree.

Any arm that /robot_description describes (`description_arm`: its URDF through
hri_core.robot_model.PinocchioModel), in 3-D (`spatial_scene_entities`):

- the arm (`chain_points`, `chain_entity`): the base, each moving joint's origin and the tool
  point from pinocchio's forward kinematics of the /joint_states positions; a rod for each
  moving joint from its origin to the next one's (the last to the tool point), and a pedestal
  rod from the base to the first joint where they are apart (the Panda: 7 joints, 8 rods); a
  ball at each joint and at the tool (meshes are not drawn);
- the hand: a ball at /target's x, y, z;
- the desired region: translucent spheres of radius d1 and d2 round the hand, with rings of
  those radii at the hand's height, coloured by a as in the plane.
`chain_frames` gives each moving link's frame in the base frame.

Either arm, the two bodies as the whole-body clearance and the ISO/TS 15066 margin see them:
the person of /human/body (`person_capsules`, `person_entity`: hri_core.bodies.human_capsules,
head, torso, shoulders, upper arms, forearms and hands, half DIN 33402-2's 95th-percentile
thicknesses as radii), the robot's capsules (`robot_body_entity`: hri_core.bodies.robot_body,
one per link), each a translucent rod of its diameter with a ball at each end (a sphere: one
ball); and the closest pair (`closest_pair_entity`): a line between the two closest points,
labelled with the link, the body part and the distance (a planar arm's in its plane).
"""

import math
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass

import numpy as np

from hri_core.bodies import Capsules, capsule_distances, human_capsules, seen_body_points
from hri_core.dynamics import forward_kinematics
from hri_core.robot_model import KNOWN_TOOL_FRAMES, ROBOT_NAMES, PinocchioModel

Point = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]  # x, y, z, w

ARM_ENTITY = 'arm'
HAND_ENTITY = 'hand'
REGION_ENTITY = 'task_region'
PERSON_ENTITY = 'person'
ROBOT_BODY_ENTITY = 'robot_body'
CLOSEST_PAIR_ENTITY = 'closest_pair'
# Enough segments for a ring of 0.5 m to look round (1.8 cm chords) at little cost.
RING_SEGMENTS = 96
REGION_SHAPE_INSIDE = 1  # TaskParameters.SHAPE_REGION_INSIDE: desired region d1 <= |z| <= d2
# The tool frame of the arms the suite knows by their URDF's robot name (description_arm):
# hri_core.robot_model.KNOWN_TOOL_FRAMES, from its one table of arms.


@dataclass(frozen=True)
class Rgba:
    """A colour, each channel in [0, 1]."""

    r: float
    g: float
    b: float
    a: float


LINK_COLOUR = Rgba(0.30, 0.50, 0.80, 1.0)
JOINT_COLOUR = Rgba(0.20, 0.20, 0.25, 1.0)
TOOL_COLOUR = Rgba(1.00, 0.55, 0.10, 1.0)
HAND_COLOUR = Rgba(0.90, 0.25, 0.25, 1.0)
PERSON_COLOUR = Rgba(0.95, 0.75, 0.55, 0.4)  # translucent: the arm shows through
ROBOT_BODY_COLOUR = Rgba(0.30, 0.50, 0.80, 0.25)  # round the drawn links
CLOSEST_PAIR_COLOUR = Rgba(1.0, 0.85, 0.1, 1.0)
# The region's colour at a = 0 (task faded out) and a = 1 (task in force).
REGION_IDLE_COLOUR = Rgba(0.55, 0.55, 0.55, 1.0)
REGION_ACTIVE_COLOUR = Rgba(0.10, 0.75, 0.25, 1.0)
LABEL_COLOUR = Rgba(1.0, 1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Rod:
    """A cylinder of `diameter` from `start` to `end` (a link)."""

    start: Point
    end: Point
    diameter: float
    colour: Rgba


@dataclass(frozen=True)
class Ball:
    """A sphere of `diameter` at `centre`."""

    centre: Point
    diameter: float
    colour: Rgba


@dataclass(frozen=True)
class Lines:
    """Lines `thickness` wide through `points`: a closed loop, or with `dashed` separate
    segments between consecutive pairs of points."""

    points: tuple[Point, ...]
    thickness: float
    colour: Rgba
    dashed: bool = False


@dataclass(frozen=True)
class Triangles:
    """A surface: every three consecutive points are a triangle."""

    points: tuple[Point, ...]
    colour: Rgba


@dataclass(frozen=True)
class Label:
    """Text at `position`, facing the viewer, `size` m high."""

    position: Point
    text: str
    size: float
    colour: Rgba


@dataclass(frozen=True)
class Entity:
    """What replaces the viewer's entity of the same id; all empty clears it."""

    id: str
    rods: tuple[Rod, ...] = ()
    balls: tuple[Ball, ...] = ()
    lines: tuple[Lines, ...] = ()
    triangles: tuple[Triangles, ...] = ()
    labels: tuple[Label, ...] = ()

    def is_empty(self) -> bool:
        return not (self.rods or self.balls or self.lines or self.triangles or self.labels)


@dataclass(frozen=True)
class TaskRegion:
    """The active task as /hri/task_state gives it: its shape s, boundaries d1, d2 (m), the
    event weight a in [0, 1] and the switching phase."""

    name: str
    shape: int
    d1: float
    d2: float
    weight: float
    phase: str


@dataclass(frozen=True)
class Frame:
    """A child frame's pose in its parent: a translation (m) and a rotation."""

    parent: str
    child: str
    translation: Point
    rotation: Quaternion


@dataclass(frozen=True)
class ArmGeometry:
    """Link lengths (m) and how thick the arm is drawn."""

    l1: float = 0.35
    l2: float = 0.30
    link_diameter: float = 0.03
    joint_diameter: float = 0.05


def joint_angles(names, positions, wanted: tuple[str, ...]) -> tuple[float, ...] | None:
    """The positions (rad) of the joints named `wanted` in a joint state, or None if one is
    missing or not finite (a joint state of another robot, a broken message)."""
    index = {name: i for i, name in enumerate(names)}
    if any(name not in index or index[name] >= len(positions) for name in wanted):
        return None
    angles = tuple(float(positions[index[name]]) for name in wanted)
    return angles if all(math.isfinite(angle) for angle in angles) else None


def arm_points(q: tuple[float, float], l1: float, l2: float) -> tuple[Point, Point, Point]:
    """The base, the elbow and the end-effector (m) for joint angles q (rad)."""
    elbow = (l1 * math.cos(q[0]), l1 * math.sin(q[0]), 0.0)
    tip_x, tip_y = forward_kinematics(q, l1, l2)
    return (0.0, 0.0, 0.0), elbow, (float(tip_x), float(tip_y), 0.0)


def yaw_quaternion(angle: float) -> Quaternion:
    """The rotation by `angle` (rad) about z."""
    return (0.0, 0.0, math.sin(angle / 2.0), math.cos(angle / 2.0))


def rod_pose(rod: Rod) -> tuple[Point, Quaternion, float]:
    """Where a cylinder along its own z axis must be put to draw `rod`: its centre, the
    rotation taking z onto the rod's direction, and its length."""
    start, end = np.asarray(rod.start, float), np.asarray(rod.end, float)
    axis = end - start
    length = float(np.linalg.norm(axis))
    centre = tuple(float(v) for v in (start + end) / 2.0)
    if length == 0.0:
        return centre, (0.0, 0.0, 0.0, 1.0), 0.0
    direction = axis / length
    # The shortest rotation from z to `direction`: about z x direction by their angle, as
    # the half-way quaternion (1 + z.d, z x d) normalised.
    cross = np.cross((0.0, 0.0, 1.0), direction)
    w = 1.0 + direction[2]
    if w < 1e-9:  # pointing down -z: half a turn about x
        return centre, (1.0, 0.0, 0.0, 0.0), length
    norm = math.sqrt(w * w + float(cross @ cross))
    rotation = (float(cross[0]) / norm, float(cross[1]) / norm, float(cross[2]) / norm,
                w / norm)
    return centre, rotation, length


def circle_points(centre: Point, radius: float, segments: int = RING_SEGMENTS
                  ) -> tuple[Point, ...]:
    """`segments` points evenly around a circle in the plane z = centre's z."""
    cx, cy, cz = centre
    return tuple((cx + radius * math.cos(2 * math.pi * k / segments),
                  cy + radius * math.sin(2 * math.pi * k / segments), cz)
                 for k in range(segments))


def dashes(loop: tuple[Point, ...]) -> tuple[Point, ...]:
    """Every other chord of a closed loop, as pairs of points (start, end) of each dash."""
    count = len(loop)
    return tuple(point for k in range(0, count - count % 2, 2)
                 for point in (loop[k], loop[(k + 1) % count]))


def annulus_triangles(centre: Point, inner: float, outer: float,
                      segments: int = RING_SEGMENTS) -> tuple[Point, ...]:
    """Triangles covering the ring between radii `inner` and `outer` (a disc if inner = 0)."""
    inside = circle_points(centre, inner, segments)
    outside = circle_points(centre, outer, segments)
    points: list[Point] = []
    for k in range(segments):
        n = (k + 1) % segments
        points += [inside[k], outside[k], outside[n]]
        if inner > 0.0:
            points += [inside[k], outside[n], inside[n]]
    return tuple(points)


def region_bands(shape: int, d1: float, d2: float, display_radius: float
                 ) -> tuple[tuple[float, float], ...]:
    """The desired region as bands (inner, outer radius, m) within `display_radius`:
    d1 <= |z| <= d2 for s = +1; |z| <= d1 and d2 <= |z| for s = -1."""
    if shape == REGION_SHAPE_INSIDE:
        bands = ((d1, d2),)
    else:
        bands = ((0.0, d1), (d2, display_radius))
    return tuple((inner, min(outer, display_radius)) for inner, outer in bands
                 if min(outer, display_radius) > inner)


def blend(low: Rgba, high: Rgba, fraction: float, alpha: float) -> Rgba:
    """The colour `fraction` of the way from `low` to `high`, with opacity `alpha`."""
    return Rgba(low.r + (high.r - low.r) * fraction, low.g + (high.g - low.g) * fraction,
                low.b + (high.b - low.b) * fraction, alpha)


def clamped_weight(weight: float) -> float:
    """The event weight in [0, 1]; a value that is not finite counts as 0 (task not in force)."""
    return min(1.0, max(0.0, weight)) if math.isfinite(weight) else 0.0


def region_colours(weight: float) -> tuple[Rgba, Rgba]:
    """The rings' and the shading's colour for event weight a: grey and faint at a = 0,
    green and clear at a = 1, so a task fading in or out is seen doing so."""
    a = clamped_weight(weight)
    ring = blend(REGION_IDLE_COLOUR, REGION_ACTIVE_COLOUR, a, 0.35 + 0.65 * a)
    shading = blend(REGION_IDLE_COLOUR, REGION_ACTIVE_COLOUR, a, 0.05 + 0.20 * a)
    return ring, shading


def arm_entity(q: tuple[float, float] | None, geometry: ArmGeometry) -> Entity:
    """The arm at joint angles q (rad); empty without them."""
    if q is None:
        return Entity(ARM_ENTITY)
    base, elbow, tip = arm_points(q, geometry.l1, geometry.l2)
    return chain_entity((base, base, elbow, tip), geometry)  # joint 1 sits on the base


def chain_entity(points: tuple[Point, ...] | None, geometry: ArmGeometry) -> Entity:
    """An arm through `points`: the base, each joint's origin, the tool point (chain_points).
    A rod from each joint to the next (the last to the tool), a pedestal rod from the base to
    the first joint if they are apart; a ball at each joint (the first larger) and at the
    tool. Empty without points."""
    if points is None:
        return Entity(ARM_ENTITY)
    base, joints, tool = points[0], points[1:-1], points[-1]
    ends = (*joints, tool)
    rods = tuple(Rod(start, end, geometry.link_diameter, LINK_COLOUR)
                 for start, end in zip(ends[:-1], ends[1:], strict=True))
    if math.dist(base, joints[0]) > 0.0:
        rods = (Rod(base, joints[0], geometry.link_diameter, LINK_COLOUR), *rods)
    balls = tuple(Ball(joint, geometry.joint_diameter * (1.4 if k == 0 else 1.0),
                       JOINT_COLOUR) for k, joint in enumerate(joints))
    return Entity(ARM_ENTITY, rods=rods,
                  balls=(*balls, Ball(tool, geometry.joint_diameter * 0.8, TOOL_COLOUR)))


def spatial(point) -> Point:
    """(x, y) or (x, y, z) as (x, y, z): a planar point lies in the plane z = 0."""
    return (float(point[0]), float(point[1]), float(point[2]) if len(point) > 2 else 0.0)


def hand_entity(hand: tuple[float, ...] | None, diameter: float = 0.06) -> Entity:
    """The hand at (x, y) or (x, y, z) (m); empty without it."""
    if hand is None or not all(math.isfinite(v) for v in hand):
        return Entity(HAND_ENTITY)
    return Entity(HAND_ENTITY, balls=(Ball(spatial(hand), diameter, HAND_COLOUR),))


def capsules_entity(entity_id: str, capsules: Capsules | None, colour: Rgba) -> Entity:
    """Capsules as rods of their diameter with a ball at each end (a sphere: one ball);
    empty without any."""
    if capsules is None:
        return Entity(entity_id)
    rods, balls = [], []
    for a, b, radius in zip(capsules.a, capsules.b, capsules.radius, strict=True):
        start, end, diameter = spatial(a), spatial(b), 2.0 * float(radius)
        balls.append(Ball(start, diameter, colour))
        if start != end:
            rods.append(Rod(start, end, diameter, colour))
            balls.append(Ball(end, diameter, colour))
    return Entity(entity_id, rods=tuple(rods), balls=tuple(balls))


def person_capsules(names, points) -> Capsules | None:
    """The person's capsules from REP-155 body point names (K,) and points (K, 3) m
    (/human/body); None without a body, or for one the capsules refuse. Non-finite points
    are lost ones (seen_body_points): the rest is drawn."""
    try:
        capsules = human_capsules(*seen_body_points(names, points)[:2])
    except ValueError:
        return None
    return capsules if len(capsules) else None


def person_entity(names, points) -> Entity:
    """The person of /human/body as capsules (module docstring); empty without one."""
    return capsules_entity(PERSON_ENTITY, person_capsules(names, points), PERSON_COLOUR)


def robot_body_entity(capsules: Capsules | None) -> Entity:
    """The robot's capsules at its joint state (RobotBody.capsules); empty without them."""
    return capsules_entity(ROBOT_BODY_ENTITY, capsules, ROBOT_BODY_COLOUR)


def closest_pair_entity(robot: Capsules | None, person: Capsules | None,
                        planar: bool) -> Entity:
    """A line between the robot's and the person's closest points, labelled 'link - part:
    distance m' (planar: measured, and drawn, in the plane z = 0); empty without both."""
    if robot is None or person is None or not len(robot) or not len(person):
        return Entity(CLOSEST_PAIR_ENTITY)
    distances = capsule_distances(robot, person, planar)
    i, j = distances.closest()
    distance, robot_point, person_point, _ = distances.pair(i, j)
    start, end = spatial(robot_point), spatial(person_point)
    middle = tuple((a + b) / 2.0 for a, b in zip(start, end, strict=True))
    return Entity(CLOSEST_PAIR_ENTITY,
                  lines=(Lines((start, end), 0.006, CLOSEST_PAIR_COLOUR, dashed=True),),
                  labels=(Label((middle[0], middle[1], middle[2] + 0.04),
                                f'{robot.names[i]} - {person.names[j]}: {distance:.3f} m',
                                0.025, CLOSEST_PAIR_COLOUR),))


def region_label(region: TaskRegion, distance: float | None) -> str:
    """'follow  a = 0.73 (fading_in)  |x - x_h| = 0.120 m'."""
    text = f'{region.name}  a = {clamped_weight(region.weight):.2f} ({region.phase})'
    if distance is not None:
        text += f'  |x - x_h| = {distance:.3f} m'
    return text


def region_entity(hand: tuple[float, ...] | None, region: TaskRegion | None,
                  tip: Point | None, display_radius: float, ring_thickness: float = 0.005,
                  spheres: bool = False) -> Entity:
    """The task's desired region around the hand ((x, y) or (x, y, z) m): rings of radius d1
    and d2 at the hand's height, and the region shaded in the plane (spheres False) or as
    translucent spheres of radius d1 and d2 (spheres True, within display_radius). Empty
    without a hand, a task, or with boundaries that are not finite and >= 0."""
    if hand is None or region is None or not all(math.isfinite(v) for v in hand):
        return Entity(REGION_ENTITY)
    d1, d2 = region.d1, region.d2
    if not (math.isfinite(d1) and math.isfinite(d2) and d1 >= 0.0 and d2 >= 0.0):
        return Entity(REGION_ENTITY)
    centre = spatial(hand)
    ring_colour, shading_colour = region_colours(region.weight)
    lines = []
    for radius in (d1, d2):
        if radius <= 0.0:
            continue  # d1 = 0 (follow): the region reaches the hand, no inner boundary
        loop = circle_points(centre, min(radius, display_radius))
        # A boundary beyond the display radius is not where it is drawn: dashed says so.
        beyond = radius > display_radius
        lines.append(Lines(dashes(loop) if beyond else loop, ring_thickness, ring_colour,
                           dashed=beyond))
    triangles, balls = (), ()
    if spheres:
        balls = tuple(Ball(centre, 2.0 * min(radius, display_radius), shading_colour)
                      for radius in (d1, d2) if radius > 0.0)
    else:
        triangles = tuple(Triangles(annulus_triangles(centre, inner, outer), shading_colour)
                          for inner, outer in region_bands(region.shape, d1, d2,
                                                           display_radius))
    distance = None if tip is None else math.dist(spatial(tip), centre)
    label_height = min(max(d2, 0.05), display_radius)
    label = Label((centre[0], centre[1] + label_height, centre[2] + 0.05),
                  region_label(region, distance), 0.03, LABEL_COLOUR)
    return Entity(REGION_ENTITY, balls=balls, lines=tuple(lines), triangles=triangles,
                  labels=(label,))


def scene_entities(q: tuple[float, float] | None, hand: tuple[float, ...] | None,
                   region: TaskRegion | None, geometry: ArmGeometry,
                   display_radius: float) -> tuple[Entity, Entity, Entity]:
    """The arm, the hand and the task region: each empty where its input is missing."""
    tip = None if q is None else arm_points(q, geometry.l1, geometry.l2)[2]
    planar_hand = None if hand is None else (hand[0], hand[1])  # the plane's task distances
    return (arm_entity(q, geometry), hand_entity(planar_hand),
            region_entity(planar_hand, region, tip, display_radius))


def spatial_scene_entities(points: tuple[Point, ...] | None, hand: Point | None,
                           region: TaskRegion | None, geometry: ArmGeometry,
                           display_radius: float) -> tuple[Entity, Entity, Entity]:
    """The arm through `points` (chain_points), the hand (x, y, z) and the task region as
    spheres round it: each empty where its input is missing."""
    tip = None if points is None else points[-1]
    return (chain_entity(points, geometry), hand_entity(hand),
            region_entity(hand, region, tip, display_radius, spheres=True))


def arm_frames(q: tuple[float, float], l1: float, l2: float, base_frame: str
               ) -> tuple[Frame, Frame, Frame]:
    """The arm's frames: link1 turned by q1 at the base, link2 turned by q2 at the elbow
    (l1 along link1's x), the tool at the end of link 2 (l2 along link2's x)."""
    return (Frame(base_frame, 'link1', (0.0, 0.0, 0.0), yaw_quaternion(q[0])),
            Frame('link1', 'link2', (l1, 0.0, 0.0), yaw_quaternion(q[1])),
            Frame('link2', 'tool', (l2, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))


def description_arm(urdf_text: str, tool_frame: str = '') -> PinocchioModel:
    """The arm of a /robot_description's URDF, its tool point at `tool_frame` ('': the tool
    frame of the robot its URDF names, if the suite knows it: KNOWN_TOOL_FRAMES). ValueError
    with a one-line reason for a URDF that cannot be read or a tool frame not known."""
    try:
        name = ElementTree.fromstring(urdf_text).get('name', '')
    except ElementTree.ParseError as error:
        raise ValueError(f'not a valid URDF: {error}') from None
    frame = tool_frame or KNOWN_TOOL_FRAMES.get(name, '')
    if not frame:
        raise ValueError(f'robot {name!r} is not one the suite knows '
                         f'({", ".join(ROBOT_NAMES)}): give tool_frame')
    return PinocchioModel(urdf_text, frame, name=name or 'urdf')


def chain_points(arm: PinocchioModel, q) -> tuple[Point, ...]:
    """The base frame's origin, each moving joint's origin and the tool point (m, base frame)
    at joint positions q (n,) in arm.joint_names order (ValueError if not n finite values)."""
    import pinocchio as pin  # installed with hri_core; imported where the arm needs it

    q = arm.joint_vector(q, 'q')
    pin.forwardKinematics(arm.model, arm.data, q)
    tool = pin.updateFramePlacement(arm.model, arm.data, arm.tool_frame_id).translation
    joints = [arm.data.oMi[joint].translation for joint in range(1, arm.model.njoints)]
    return ((0.0, 0.0, 0.0), *(spatial(point) for point in joints), spatial(tool))


def chain_frames(arm: PinocchioModel, q, base_frame: str) -> tuple[Frame, ...]:
    """Each moving link's frame (named as in the URDF) in `base_frame` at joint positions q,
    and the tool frame, for a transform tree; ValueError as chain_points."""
    import pinocchio as pin

    q = arm.joint_vector(q, 'q')
    pin.forwardKinematics(arm.model, arm.data, q)
    pin.updateFramePlacements(arm.model, arm.data)
    frames = []
    for frame_id, frame in enumerate(arm.model.frames):
        moving_link = frame.type == pin.FrameType.BODY and frame.parentJoint > 0 and \
            frame.placement.isIdentity()
        if moving_link or frame_id == arm.tool_frame_id:
            placement = arm.data.oMf[frame_id]
            x, y, z, w = pin.Quaternion(placement.rotation).coeffs()
            frames.append(Frame(base_frame, frame.name, spatial(placement.translation),
                                (float(x), float(y), float(z), float(w))))
    return tuple(frames)
