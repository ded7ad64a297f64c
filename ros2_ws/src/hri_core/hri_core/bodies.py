"""The robot and the person as capsules, their distances, and the point Jacobian to push
the robot through.

No ROS here. A capsule is a segment a-b (m) swept by a ball of radius r (m); a sphere is a
capsule with a = b. Everything is in the robot's base frame.

**The person** (`human_capsules`): capsules between the REP-155 points of a HumanBody
(hri_core.human_body) with `HUMAN_RADII`, half the DIN 33402-2 95th-percentile thicknesses
(as TUM's sara-shield uses them): upper arm 0.20, forearm 0.132, hand 0.206, torso 0.434,
head 0.434 m. `HUMAN_CAPSULES` lists the ten: the head a sphere round `head`, the torso from
`body` to `torso`, a shoulder from `torso` to each shoulder and the upper arm from there to the
elbow (upper-arm radius), the forearm from elbow to wrist, the hand a sphere round the wrist
(the Vicon hand segment's origin). A capsule one of whose points is missing in a message is
left out, but for the torso (`TRUNK_SPHERE`): with one of `body` and `torso` seen, a sphere of
the torso's radius round it.

**The robot** (`robot_body`): one capsule per link, fitted once at start. A URDF arm's from its
collision geometry, loaded through pinocchio with coal (meshes as coal BVH models, boxes,
spheres, cylinders): each link's collision points (mesh vertices, box corners, points on
spheres and cylinders) in its moving joint's frame, the capsule's axis their principal axis,
its radius and ends the least that hold every point. Links on joints that are locked in the
model (a gripper's fingers) join the link they hang from; a link without collision geometry
has no capsule; the base link rides on no joint. The capsule of the link the tool frame hangs
on is the tool's (`RobotBody.tool`). The SCARA's two capsules come from its link lengths (base
to elbow, elbow to tool point) with `SCARA_LINK_RADIUS`; it moves in the plane z = 0 and its
distances are measured in that plane (`RobotBody.planar`: the person's capsules are projected
onto it).

**Distances** (`capsule_distances`): for every robot capsule i (R of them) and every human
capsule j (H), vectorised in numpy: the distance between their surfaces (R, H) m (negative:
they overlap by that much), the closest points on each surface (R, H, 3) m and the unit
normal (R, H, 3) from the robot's point towards the person's. `Distances.closest()` is the
pair with the least distance. Equal to coal's capsule distances (unit test, 1e-9 m).

**Point Jacobian** (`RobotBody.point_jacobian(q, capsule, point)`): J (3, n) with
v_point = J dq (m/s) for a point (3,) m moving with the capsule's link: pinocchio's joint
Jacobian at the joint (the model's `joint_jacobians`: pinocchio's LOCAL_WORLD_ALIGNED one, the
SCARA's in closed form) with the point's offset from the joint, J_v - [p - o]x J_w. Zero for a
capsule on the base. `RobotBody.normal_rows(q, capsules, points, normals)` gives n^T J (m, n)
for m points at once, what a barrier on the distances needs: every joint's Jacobian once (for
a URDF arm one pinocchio pass), then J_v^T n + J_w^T ((p - o) x n) per point.

**The chain** (`RobotBody.chain`, a `Chain`): the arm's joints as placements and axes, from
which hri_core.capsule_kernels places the capsules and forms a point's Jacobian row in compiled
code (column i of a point p on a link below revolute joint i: z_i x (p - o_i), z_i its axis and
o_i its origin in the base frame; of a prismatic joint: z_i), what the law's barrier runs on
each cycle. The pinocchio path above is its reference (equal to rounding: tested).
"""

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import NamedTuple

import numpy as np

from hri_core.robot_model import PinocchioModel, RobotModel, ScaraModel

# m: half of DIN 33402-2's 95th-percentile thickness of each part (sara-shield's table).
HUMAN_RADII = {'upper_arm': 0.20 / 2, 'forearm': 0.132 / 2, 'hand': 0.206 / 2,
               'torso': 0.434 / 2, 'head': 0.434 / 2}
# (capsule name, from point, to point, radius key); a sphere has from == to.
HUMAN_CAPSULES = (
    ('head', 'head', 'head', 'head'),
    ('torso', 'body', 'torso', 'torso'),
    ('l_shoulder', 'torso', 'l_shoulder', 'upper_arm'),
    ('r_shoulder', 'torso', 'r_shoulder', 'upper_arm'),
    ('l_upper_arm', 'l_shoulder', 'l_elbow', 'upper_arm'),
    ('r_upper_arm', 'r_shoulder', 'r_elbow', 'upper_arm'),
    ('l_forearm', 'l_elbow', 'l_wrist', 'forearm'),
    ('r_forearm', 'r_elbow', 'r_wrist', 'forearm'),
    ('l_hand', 'l_wrist', 'l_wrist', 'hand'),
    ('r_hand', 'r_wrist', 'r_wrist', 'hand'),
)
_BODY_POINT_NAMES = frozenset(point for capsule in HUMAN_CAPSULES for point in capsule[1:3])
# The capsule that becomes a sphere round its one point seen when the other is missing: the
# trunk is what the clearance may never lose (its bar is on head, torso and hip), and a table
# or the robot hides the hips from a tracker more often than any other part. An arm's capsule
# with a point missing is left out: its other end may be anywhere within the segment's length.
TRUNK_SPHERE = 'torso'
SCARA_LINK_RADIUS = 0.05  # m, the SCARA's links (no collision geometry of its own)
MAX_BODY_SPEED = 3.0  # m/s: a body point's speed between two frames is capped here (a glitch)
_TINY = 1e-300  # a divisor floor: degenerate segments (spheres) never divide by zero
_ONES = np.ones(3)
_FLAT = np.array([1.0, 1.0, 0.0])


@dataclass(frozen=True)
class Capsules:
    """K capsules: names (K,), ends a and b (K, 3) m, radius (K,) m; velocity_a and
    velocity_b (K, 3) m/s: how fast each end moves (a person's, from the last two frames;
    None: still). What the distances need of one set alone (axes, their dot products) is
    computed once per set and kept."""

    names: tuple[str, ...]
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray
    velocity_a: np.ndarray | None = None
    velocity_b: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.names)

    @cached_property
    def axis(self) -> np.ndarray:
        """b - a (K, 3) m."""
        return self.b - self.a

    @cached_property
    def stacked(self) -> np.ndarray:
        """[axis; a] (2K, 3) m: one matmul gives every cross dot product of two sets."""
        return np.concatenate((self.axis, self.a))

    @cached_property
    def axis_dots(self) -> tuple[np.ndarray, np.ndarray]:
        """(axis . axis, axis . a) (K,) m^2, each floored at _TINY for the first."""
        axis = self.axis
        return np.maximum((axis * axis) @ _ONES, _TINY), (axis * self.a) @ _ONES

    @cached_property
    def fastest_speed(self) -> float:
        """The fastest speed (m/s) of any capsule end (0.0 when still)."""
        speed = 0.0
        for ends in (self.velocity_a, self.velocity_b):
            if ends is not None and len(ends):
                speed = max(speed, float(np.sqrt((ends * ends).sum(axis=1)).max()))
        return speed

    @cached_property
    def flat(self) -> 'Capsules':
        """The capsules projected onto the plane z = 0."""
        moving = self.velocity_a is not None
        return Capsules(self.names, self.a * _FLAT, self.b * _FLAT, self.radius,
                        self.velocity_a * _FLAT if moving else None,
                        self.velocity_b * _FLAT if moving else None)


def body_point_velocities(names, points, before: dict, seconds: float) -> np.ndarray:
    """Each point's velocity (K, 3) m/s from where it was `seconds` s before (`before`: name
    -> point (3,) m of the previous frame): zero for a point not in it or for seconds <= 0,
    each capped at MAX_BODY_SPEED (a faster step is a tracking glitch, not a motion)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) != len(names):
        raise ValueError(f'{len(names)} names for {len(points)} points')
    velocities = np.zeros_like(points)
    if not seconds > 0.0:
        return velocities
    # At once (a body every 10 ms in the controller's one thread: 22 us point by point).
    rows = [k for k, name in enumerate(names) if name in before]
    if rows:
        step = (points[rows] - np.array([before[names[k]] for k in rows])) / seconds
        speed = np.sqrt(np.einsum('ij,ij->i', step, step))
        fast = ~(speed <= MAX_BODY_SPEED)
        if fast.any():
            step[fast] *= (MAX_BODY_SPEED / speed[fast])[:, None]
        velocities[rows] = step
    return velocities


class SeenBody(NamedTuple):
    """A body message's points sorted (seen_body_points): names (K,) and points (K, 3) m of
    the ones the capsules can use; lost: the names whose point is not finite; unknown: the
    names that are no point of HUMAN_CAPSULES (ignored)."""
    names: tuple
    points: np.ndarray
    lost: tuple
    unknown: tuple


def seen_body_points(names, points) -> SeenBody:
    """A body message's points sorted into those the capsules use and those lost or unknown
    (SeenBody). A tracker may mark a joint it lost with NaN where REP-155's publisher leaves
    it out: such a point counts as lost, and the rest of the body stays (dropping the whole
    message would leave the person unguarded for as long as one joint stays occluded). A
    name that is no REP-155 point of the body model ('Head', 'head_1') is set apart for the
    caller to name in a warning rather than ignored in silence. ValueError (one line) where
    the names and points do not pair up."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    names = tuple(names)
    if len(names) != len(points):
        raise ValueError(f'{len(names)} names for {len(points)} points')
    finite = np.all(np.isfinite(points), axis=1)
    known = np.array([name in _BODY_POINT_NAMES for name in names], dtype=bool)
    if finite.all() and known.all():
        return SeenBody(names, points, (), ())
    used = finite & known
    return SeenBody(tuple(name for name, keep in zip(names, used, strict=True) if keep),
                    points[used],
                    tuple(name for name, ok, kind in zip(names, finite, known, strict=True)
                          if kind and not ok),
                    tuple(name for name, kind in zip(names, known, strict=True) if not kind))


def human_capsules(names, points, radii=None, velocities=None) -> Capsules:
    """The person's capsules (HUMAN_CAPSULES) from REP-155 names (K,) and points (K, 3) m;
    radii: {part: m} overriding HUMAN_RADII; velocities (K, 3) m/s of the points (None:
    still), the capsules' ends move with them. A capsule with a point missing is left out
    (the torso's: a sphere round the point seen, TRUNK_SPHERE). ValueError (one line) for
    non-finite points (a message's lost ones are left out first: seen_body_points), repeated
    names or a bad radius."""
    merged = HUMAN_RADII
    if radii:
        merged = {**HUMAN_RADII, **radii}
        for part, value in merged.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f'radius of {part} must be a finite number >= 0 m, got '
                                 f'{value!r}')
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    names = tuple(names)
    if len(names) != len(points):
        raise ValueError(f'{len(names)} names for {len(points)} points')
    kept, start, end, radius = _capsule_plan(names, tuple(merged.items()))
    if not np.all(np.isfinite(points)):
        raise ValueError('body points must be finite')
    if not kept:
        return Capsules((), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    moving = None
    if velocities is not None:
        moving = np.asarray(velocities, dtype=float).reshape(-1, 3)
        if moving.shape != points.shape or not np.all(np.isfinite(moving)):
            raise ValueError('body point velocities must be finite, one per point')
    return Capsules(kept, points[start], points[end], radius.copy(),
                    None if moving is None else moving[start],
                    None if moving is None else moving[end])


@lru_cache(maxsize=64)
def _capsule_plan(names: tuple, radii: tuple) -> tuple:
    """human_capsules' capsules for the point names `names` (K,) with the radii (part, m)
    pairs: (capsule names, start and end point indices, radii (C,) m); the same for every
    frame of a body (a body every 10 ms). ValueError for repeated names."""
    if len(set(names)) != len(names):
        raise ValueError(f'repeated body point names: {", ".join(names)}')
    where = {name: k for k, name in enumerate(names)}
    radius_of = dict(radii)
    kept = []
    for name, start, end, part in HUMAN_CAPSULES:
        if start not in where or end not in where:
            if name != TRUNK_SPHERE or (start not in where and end not in where):
                continue
            start = end = start if start in where else end
        kept.append((name, where[start], where[end], radius_of[part]))
    return (tuple(k[0] for k in kept), np.array([k[1] for k in kept], dtype=np.int64),
            np.array([k[2] for k in kept], dtype=np.int64),
            np.array([k[3] for k in kept], dtype=float))


class Distances:
    """Every robot capsule (R) against every human capsule (H), m.

    distance (R, H): between the surfaces (< 0: overlap depth); robot_point and human_point
    (R, H, 3): the closest points on each surface; normal (R, H, 3): the unit vector from the
    robot's centre line towards the person's (the direction the distance grows along). The
    distances are computed at once; the (R, H, 3) arrays when first asked for (`pair(i, j)`
    gives one pair's without them)."""

    def __init__(self, robot: 'Capsules', human: 'Capsules', s, t, between, centre):
        self.robot, self.human = robot, human
        self._s, self._t, self._between, self._centre = s, t, between, centre
        self.distance = centre - robot.radius[:, None] - human.radius

    def closest(self) -> tuple[int, int]:
        """(i, j): the robot and human capsule of the least distance. ValueError if empty."""
        if self.distance.size == 0:
            raise ValueError('no capsule pair to compare')
        i, j = np.unravel_index(int(np.argmin(self.distance)), self.distance.shape)
        return int(i), int(j)

    @cached_property
    def normal(self) -> np.ndarray:
        centre, between = self._centre, self._between
        if centre.min() >= 1e-12:
            return between / centre[..., None]
        return np.array([[self._pair_normal(i, j) for j in range(centre.shape[1])]
                         for i in range(centre.shape[0])]).reshape(between.shape)

    @cached_property
    def robot_point(self) -> np.ndarray:
        robot = self.robot
        return (robot.a[:, None, :] + self._s[..., None] * robot.axis[:, None, :]
                + robot.radius[:, None, None] * self.normal)

    @cached_property
    def human_point(self) -> np.ndarray:
        human = self.human
        return human.a + self._t[..., None] * human.axis - human.radius[:, None] * self.normal

    def _pair_normal(self, i: int, j: int) -> np.ndarray:
        """The normal of pair (i, j) (3,): along the centre lines' closest points, or where
        they meet between the segments' midpoints, or +z if those meet too."""
        if self._centre[i, j] >= 1e-12:
            return self._between[i, j] / self._centre[i, j]
        robot, human = self.robot, self.human
        between = 0.5 * (human.a[j] + human.b[j] - robot.a[i] - robot.b[i])
        length = float(np.linalg.norm(between))
        return between / length if length >= 1e-12 else np.array([0.0, 0.0, 1.0])

    def parameters(self, i: int, j: int) -> tuple[float, float]:
        """(s, t) in [0, 1] of pair (i, j): where its closest points lie along the robot's
        capsule (a + s (b - a)) and the person's (a + t (b - a))."""
        return float(self._s[i, j]), float(self._t[i, j])

    def robot_points_and_normals(self, i, j) -> tuple[np.ndarray, np.ndarray]:
        """(robot_point (m, 3) m, normal (m, 3)) of the pairs (i[k], j[k]) (m,) each: what
        `pair` gives of each, at once."""
        centre = self._centre[i, j]
        if centre.size and centre.min() >= 1e-12:
            normal = self._between[i, j] / centre[:, None]
        else:
            normal = np.array([self._pair_normal(a, b) for a, b in zip(
                np.asarray(i).tolist(), np.asarray(j).tolist(), strict=True)]).reshape(-1, 3)
        robot = self.robot
        point = (robot.a[i] + self._s[i, j][:, None] * robot.axis[i]
                 + robot.radius[i][:, None] * normal)
        return point, normal

    def closing_speeds(self, i, j, normals) -> np.ndarray:
        """How fast (m,) m/s the person's closest point of each pair (i[k], j[k]) moves towards
        the robot along the pair's normal (m, 3): -n . v_h, v_h that point's velocity
        (Capsules' velocities; zeros for a still person)."""
        human = self.human
        if human.velocity_a is None:
            return np.zeros(len(normals))
        t = self._t[i, j][:, None]
        velocity = (1.0 - t) * human.velocity_a[j] + t * human.velocity_b[j]
        return -(normals * velocity) @ _ONES

    def pair(self, i: int, j: int) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(distance m, robot_point (3,) m, human_point (3,) m, normal (3,)) of pair (i, j)."""
        robot, human = self.robot, self.human
        normal = self._pair_normal(i, j)
        robot_point = robot.a[i] + self._s[i, j] * robot.axis[i] + robot.radius[i] * normal
        human_point = human.a[j] + self._t[i, j] * human.axis[j] - human.radius[j] * normal
        return float(self.distance[i, j]), robot_point, human_point, normal


def segment_parameters(robot: 'Capsules', human: 'Capsules') -> tuple[np.ndarray, np.ndarray]:
    """The closest points' parameters s, t in [0, 1] (R, H) of the robot's axes a1 + s d1
    (R of them) and the person's a2 + t d2 (H) (Ericson, Real-Time Collision Detection
    5.1.9, vectorised: s of the infinite lines clamped, t from it clamped, then s again from
    the clamped t, which leaves an interior solution as it is). A zero-length segment (a
    sphere) takes parameter 0; for parallel segments s starts at an end and the two steps
    after it still find the least distance."""
    r, h = len(robot), len(human)
    products = robot.stacked @ human.stacked.T                          # (2R, 2H)
    b = products[:r, :h]                                                # d1.d2
    a, d1_a1 = robot.axis_dots
    e, d2_a2 = human.axis_dots
    a = a[:, None]
    c = d1_a1[:, None] - products[:r, h:]                               # d1.(a1 - a2)
    f = products[r:, :h] - d2_a2                                        # d2.(a1 - a2)
    s = (b * f - c * e) / np.maximum(a * e - b * b, _TINY)
    np.minimum(np.maximum(s, 0.0, out=s), 1.0, out=s)
    t = (b * s + f) / e
    np.minimum(np.maximum(t, 0.0, out=t), 1.0, out=t)
    s = (b * t - c) / a
    np.minimum(np.maximum(s, 0.0, out=s), 1.0, out=s)
    return s, t


def clear_of_arm(body: 'RobotBody', person: Capsules, clearance: float, q=None):
    """A placement rule (recorded_motion.choose_placement's `accept`): True where the person's
    capsules `person` (room frame, e.g. the whole person at a take's first frame), placed by
    the Placement, keep at least `clearance` m from every capsule of the robot `body` at q
    (n,) rad (None: its model's home, where arm_sim starts), measured as the body measures
    (a planar arm in its plane). A person cannot stand where the arm is: placed there, the
    arm starts inside their clearance."""
    if not (math.isfinite(clearance) and clearance >= 0.0):
        raise ValueError(f'clearance must be a finite number >= 0 m, got {clearance}')
    arm = body.capsules(body.model.home if q is None else q)

    def accept(placement) -> bool:
        if len(person) == 0 or len(arm) == 0:
            return True
        placed = Capsules(person.names, placement.apply(person.a), placement.apply(person.b),
                          person.radius)
        return bool(capsule_distances(arm, placed, body.planar).distance.min() >= clearance)

    return accept


def capsule_distances(robot: Capsules, human: Capsules, planar: bool = False,
                      compiled: bool = True) -> Distances:
    """Every robot capsule against every human capsule (module docstring): shapes (R, H) and
    (R, H, 3), m. planar: measure in the plane z = 0 (a planar arm): the human capsules'
    ends are projected onto it (z = 0) before the distance is taken. Pass the same human
    Capsules object each cycle: what it needs of the person alone is computed once.
    compiled: through hri_core.capsule_kernels (numba; imported at the first call), else
    through numpy (the reference the kernel is tested against)."""
    if planar:
        human = human.flat
    if compiled:
        from hri_core.capsule_kernels import segment_table
        s, t, between, centre = segment_table(robot.a, robot.axis, human.a, human.axis)
        return Distances(robot, human, s, t, between, centre)
    s, t = segment_parameters(robot, human)
    between = ((human.a - robot.a[:, None, :]) + t[..., None] * human.axis
               - s[..., None] * robot.axis[:, None, :])
    centre = np.sqrt((between * between) @ _ONES)
    return Distances(robot, human, s, t, between, centre)


def fit_capsule(points) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule (a (3,), b (3,), radius) m holding every point of `points` (M, 3) m: its axis
    the points' principal axis through the centre of their least enclosing circle across it
    (Nelder-Mead on the largest radial distance), its radius that distance, its ends the
    least that keep every point within the radius of the segment."""
    from scipy.optimize import minimize  # only at start

    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0 or not np.all(np.isfinite(points)):
        raise ValueError('a capsule needs at least one finite point')
    centroid = points.mean(axis=0)
    centred = points - centroid
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    axis = axes[0] if len(axes) else np.array([0.0, 0.0, 1.0])
    across = np.linalg.svd(np.eye(3) - np.outer(axis, axis))[0][:, :2]   # (3, 2)
    flat = centred @ across                                              # (M, 2)

    def widest(centre):
        return float(np.max(np.hypot(*(flat - centre).T)))

    centre = minimize(widest, 0.5 * (flat.min(axis=0) + flat.max(axis=0)),
                      method='Nelder-Mead', options={'xatol': 1e-7, 'fatol': 1e-9}).x
    radial = np.hypot(*(flat - centre).T)
    radius = float(np.max(radial))
    along = centred @ axis
    slack = np.sqrt(np.maximum(radius ** 2 - radial ** 2, 0.0))
    # A point at axial position u is within the radius of the segment [low, high] when
    # low - slack <= u <= high + slack: the shortest segment that holds every point.
    low, high = float(np.min(along + slack)), float(np.max(along - slack))
    if low > high:  # a short blob: every point within the radius of one point
        low = high = 0.5 * (low + high)
    origin = centroid + across @ centre
    return origin + low * axis, origin + high * axis, radius


def _shape_points(geometry, coal) -> np.ndarray:
    """Points (M, 3) in a coal shape's own frame whose capsule holds the shape: a mesh's
    vertices, a box's corners, points round a sphere or a cylinder, a capsule's ends padded."""
    if hasattr(geometry, 'vertices'):
        return np.asarray(geometry.vertices(), dtype=float).reshape(-1, 3)
    if isinstance(geometry, coal.Box):
        half = np.asarray(geometry.halfSide, dtype=float)
        return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
    angles = np.linspace(0.0, 2.0 * math.pi, 32, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    if isinstance(geometry, coal.Sphere):
        r = geometry.radius
        return np.vstack([r * ring, r * ring[:, [0, 2, 1]], r * ring[:, [2, 0, 1]]])
    if isinstance(geometry, coal.Cylinder | coal.Capsule):
        r, half = geometry.radius, geometry.halfLength
        if isinstance(geometry, coal.Capsule):
            half = half + r
        return np.vstack([r * ring + (0, 0, half), r * ring - (0, 0, half)])
    raise ValueError(f'collision shape {type(geometry).__name__} is not supported')


class Chain(NamedTuple):
    """The arm's joints as a tree, what the compiled barrier places the capsules and forms
    their point Jacobians from (hri_core.capsule_kernels.chain_frames). J entries, entry 0
    the base (fixed): parents (J,) the parent entry of each (-1 for the base); placements
    (J, 4, 4) each joint's placement in its parent's frame at q = 0 (m); axes (J, 3) its unit
    axis in its own frame; prismatic (J,) True where it slides along the axis (m), False where
    it turns about it (rad); index (J,) its entry in q (-1 for the base)."""

    parents: np.ndarray
    placements: np.ndarray
    axes: np.ndarray
    prismatic: np.ndarray
    index: np.ndarray


# pinocchio's one-degree-of-freedom joints a Chain holds: revolute about x, y, z or an axis,
# prismatic along them.
_REVOLUTE = {'JointModelRX': (1.0, 0.0, 0.0), 'JointModelRY': (0.0, 1.0, 0.0),
             'JointModelRZ': (0.0, 0.0, 1.0)}
_PRISMATIC = {'JointModelPX': (1.0, 0.0, 0.0), 'JointModelPY': (0.0, 1.0, 0.0),
              'JointModelPZ': (0.0, 0.0, 1.0)}


def pinocchio_chain(model) -> Chain | None:
    """The Chain of a pinocchio model, or None if a joint is not one a Chain holds (a
    spherical, planar or free joint, a continuous joint's (cos, sin) pair): the barrier then
    takes pinocchio's own path."""
    parents, placements, axes = [-1], [np.eye(4)], [(0.0, 0.0, 1.0)]
    prismatic, index = [False], [-1]
    for i in range(1, model.njoints):
        joint = model.joints[i]
        kind = joint.shortname()
        if joint.nq != 1 or joint.nv != 1:
            return None
        if kind in _REVOLUTE or kind in _PRISMATIC:
            axis = _REVOLUTE.get(kind) or _PRISMATIC[kind]
        elif kind in ('JointModelRevoluteUnaligned', 'JointModelPrismaticUnaligned'):
            axis = tuple(np.asarray(joint.extract().axis, dtype=float).tolist())
        else:
            return None
        parents.append(int(model.parents[i]))
        placements.append(np.asarray(model.jointPlacements[i].homogeneous, dtype=float))
        axes.append(axis)
        prismatic.append(kind.startswith('JointModelP'))
        index.append(int(joint.idx_q))
    return Chain(np.array(parents, dtype=np.int64), np.array(placements),
                 np.array(axes, dtype=float), np.array(prismatic, dtype=np.bool_),
                 np.array(index, dtype=np.int64))


class RobotBody:
    """The robot's capsules (module docstring) in its moving joints' frames.

    names (K,): link names; tool: the name of the tool's capsule; joint (K,): the model's
    joint each rides on (0: the base); local_a, local_b (K, 3) m in that joint's frame;
    radius (K,) m; planar: measured in the plane z = 0. `capsules(q)` places them for joint
    positions q (n,) rad; `point_jacobian(q, k, point)` gives J (3, n); `normal_rows` n^T J
    of many points at once. chain: its joints as a Chain (None: not one a Chain holds), for
    the compiled barrier."""

    def __init__(self, model: RobotModel, names, joint, local_a, local_b, radius, tool: str,
                 planar: bool, chain: Chain | None = None):
        self.model = model
        self.names = tuple(names)
        self.joint = tuple(int(j) for j in joint)
        self.local_a = np.asarray(local_a, dtype=float).reshape(-1, 3)
        self.local_b = np.asarray(local_b, dtype=float).reshape(-1, 3)
        self.radius = np.asarray(radius, dtype=float)
        self.tool = tool
        self.planar = planar
        self.chain = chain
        self._joints = np.array(self.joint, dtype=np.int64)

    def capsules(self, q, checked: bool = True) -> Capsules:
        """The capsules in the base frame at joint positions q (n,) rad (checked: finite and
        within the joint limits; unchecked: the caller's finite (n,) floats, the 1 kHz path)."""
        q = self.model.joint_position(q, 'q') if checked else np.asarray(q, dtype=float)
        if self.chain is not None:  # compiled on the chain: 3-4 us against 13-18 us
            from hri_core import capsule_kernels

            rotations, origins = capsule_kernels.chain_frames(q, *self.chain)
            a, axis = capsule_kernels.placed_capsules(rotations, origins, self._joints,
                                                      self.local_a, self.local_b)
            return Capsules(self.names, a, a + axis, self.radius)
        rotations, origins = self.model.joint_frames(q)
        rotations, origins = rotations[self._joints], origins[self._joints]
        a = np.einsum('kij,kj->ki', rotations, self.local_a) + origins
        b = np.einsum('kij,kj->ki', rotations, self.local_b) + origins
        return Capsules(self.names, a, b, self.radius)

    def point_jacobian(self, q, capsule: int, point, checked: bool = True) -> np.ndarray:
        """J (3, n), m/rad: the velocity (m/s) of `point` (3,) m in the base frame, moving
        with capsule `capsule`'s link, is J dq (q checked as in `capsules`)."""
        q = self.model.joint_position(q, 'q') if checked else np.asarray(q, dtype=float)
        point = np.asarray(point, dtype=float).reshape(3)
        joint = self.joint[capsule]
        if joint == 0:
            return np.zeros((3, self.model.dof))
        origin, jacobian = self.model.joint_jacobians(q, (joint,))[joint]
        (rx, ry, rz) = (point - origin).tolist()
        cross = np.array([[0.0, -rz, ry], [rz, 0.0, -rx], [-ry, rx, 0.0]])
        return jacobian[:3] - cross @ jacobian[3:]  # v_o + w x (p - o)

    def normal_rows(self, q, capsules, points, normals) -> np.ndarray:
        """n_k^T J_k (m, n), m/rad: the speed (m/s) along the unit normal n_k (m, 3) of each
        point p_k (m, 3) m moving with capsule capsules[k] (m,) is row k times dq; the
        caller's finite (n,) q (unchecked: the 1 kHz path). The same as normal @
        point_jacobian(q, k, p) per point, with each joint's Jacobian once."""
        q = np.asarray(q, dtype=float)
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        normals = np.asarray(normals, dtype=float).reshape(-1, 3)
        joints = [self.joint[int(k)] for k in capsules]
        taken = self.model.joint_jacobians(q, {joint for joint in joints if joint != 0})
        rows = np.zeros((len(joints), q.size))
        for k, joint in enumerate(joints):
            if joint == 0:
                continue  # the base: still
            origin, jacobian = taken[joint]
            # v_p = J_v dq + w x (p - o), so n . v_p = (J_v^T n + J_w^T ((p - o) x n)) . dq;
            # the cross product in floats (numpy's np.cross costs 15 us for two 3-vectors).
            (rx, ry, rz), (nx, ny, nz) = (points[k] - origin).tolist(), normals[k].tolist()
            rows[k] = np.array([nx, ny, nz, ry * nz - rz * ny, rz * nx - rx * nz,
                                rx * ny - ry * nx]) @ jacobian
        return rows


def _scara_body(model: ScaraModel, radius: float) -> RobotBody:
    l1, l2 = model.params.l1, model.params.l2
    elbow = np.eye(4)
    elbow[0, 3] = l1  # the elbow joint l1 along the upper link; both turn about z
    chain = Chain(np.array([-1, 0, 1], dtype=np.int64), np.array([np.eye(4), np.eye(4), elbow]),
                  np.array([[0.0, 0.0, 1.0]] * 3), np.zeros(3, dtype=np.bool_),
                  np.array([-1, 0, 1], dtype=np.int64))
    return RobotBody(model, ('link1', 'link2'), (1, 2),
                     [[0, 0, 0], [0, 0, 0]], [[l1, 0, 0], [l2, 0, 0]], (radius, radius),
                     tool='link2', planar=True, chain=chain)


def _urdf_body(model: PinocchioModel, package_dirs, padding: float) -> RobotBody:
    """One capsule per link of a URDF arm from its collision geometry (module docstring)."""
    import coal
    import pinocchio as pin

    full = pin.buildModelFromXML(model.urdf)
    try:
        geometry = pin.buildGeomFromUrdfString(full, model.urdf, pin.COLLISION,
                                               package_dirs=[str(d) for d in package_dirs])
    except (ValueError, RuntimeError) as error:
        raise ValueError(f'cannot load the collision geometry of {model.name}: '
                         f'{str(error).splitlines()[0]}') from None
    reduced = model.model
    kept = set(reduced.names)

    def owner(frame_id: int) -> str:
        """The link a collision body belongs to: its own, or, on a locked joint, the first
        link up the tree whose joint the model keeps."""
        frame = full.frames[frame_id]
        while frame.parentJoint != 0 and full.names[frame.parentJoint] not in kept:
            frame = full.frames[frame.parentFrame]
            while frame.type != pin.FrameType.BODY:
                frame = full.frames[frame.parentFrame]
        return frame.name

    clouds: dict[str, list[np.ndarray]] = {}
    for item in geometry.geometryObjects:
        link = full.frames[item.parentFrame]
        relative = link.placement.inverse() * item.placement        # shape in its link frame
        points = _shape_points(item.geometry, coal) * np.asarray(item.meshScale)
        if not reduced.existFrame(link.name):
            raise ValueError(f'link {link.name!r} of {model.name} is not in its model')
        in_joint = reduced.frames[reduced.getFrameId(link.name)].placement * relative
        moved = points @ in_joint.rotation.T + in_joint.translation
        clouds.setdefault(owner(item.parentFrame), []).append(moved)
    if not clouds:
        raise ValueError(f'the URDF of {model.name} has no collision geometry')
    index = model.tool_frame_id  # the tool's capsule: the first link up from the tool frame
    while reduced.frames[index].name not in clouds and index != 0:
        index = reduced.frames[index].parentFrame
    tool = reduced.frames[index].name if index != 0 else ''
    names, joints, ends_a, ends_b, radii = [], [], [], [], []
    for link, parts in clouds.items():
        a, b, radius = fit_capsule(np.vstack(parts))
        names.append(link)
        joints.append(reduced.frames[reduced.getFrameId(link)].parentJoint)
        ends_a.append(a)
        ends_b.append(b)
        radii.append(radius + padding)
    if not tool:  # no link up from the tool has geometry: the last capsule's
        tool = names[int(np.argmax(joints))]
    return RobotBody(model, names, joints, ends_a, ends_b, radii, tool=tool, planar=False,
                     chain=pinocchio_chain(reduced))


def robot_body(model: RobotModel, package_dirs=(), padding: float = 0.0,
               scara_radius: float = SCARA_LINK_RADIUS) -> RobotBody:
    """The robot's capsules (module docstring). package_dirs: folders that hold the URDF's
    `package://` meshes (for the Panda: `panda_package_dirs()`); padding (m) added to every
    fitted radius; scara_radius (m) of the SCARA's links. ValueError with a one-line reason
    (no collision geometry, a mesh that cannot be found, a shape not supported)."""
    for name, value in (('padding', padding), ('scara_radius', scara_radius)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
            raise ValueError(f'{name} must be a finite number >= 0 m, got {value!r}')
    if isinstance(model, ScaraModel):
        return _scara_body(model, scara_radius + padding)
    if not isinstance(model, PinocchioModel):
        raise ValueError(f'no body for a robot model of type {type(model).__name__}')
    return _urdf_body(model, package_dirs, padding)


def panda_package_dirs() -> tuple[str, ...]:
    """The folder in which the Panda's `package://example-robot-data/...` meshes resolve."""
    from hri_core.robot_model import panda_urdf_path

    return (str(panda_urdf_path().parents[4]),)
