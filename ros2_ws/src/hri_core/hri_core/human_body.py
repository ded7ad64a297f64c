"""A person's body as named points: REP-155's frame names, from a Vicon take or a standing
body model whose right wrist is a scripted hand.

No ROS here. A body at one instant is `names` (K,) and `points` (K, 3) m in the robot's base
frame; a point not seen is left out, never NaN. The names are REP-155's (ROS4HRI) body frames
without their `_<id>` suffix, and the Vicon segments of data/human-motion map onto them:

    REP-155     Vicon segment     where
    head        head              the head's centre
    torso       collar            the top of the sternum (the torso's upper end)
    l_shoulder  left_shoulder     the shoulder joint
    r_shoulder  right_shoulder
    l_elbow     left_elbow        the elbow joint
    r_elbow     right_elbow
    l_wrist     left_hand         the hand segment's origin (Vicon tracks the hand, REP-155
    r_wrist     right_hand        names the wrist; the hand capsule is a sphere there)
    body        hip               between the hips (REP-155's body frame)

`TRUNK` (body, torso, head) is what a placement keeps away from the robot's base. The standing
body (`standing_body`) has the proportions of `BodyModel` (m), faces along `yaw` (rad, its x
axis, z up, y to its left), its `body` point at (x, y, height); its right arm reaches the
given wrist by two-link inverse kinematics (`elbow_position`), its left arm hangs.
"""

import math
from dataclasses import dataclass

import numpy as np

from hri_core.recorded_motion import Placement, read_vicon_segments

BODY_POINTS = ('head', 'torso', 'l_shoulder', 'r_shoulder', 'l_elbow', 'r_elbow', 'l_wrist',
               'r_wrist', 'body')
VICON_SEGMENTS = {'head': 'head', 'torso': 'collar', 'l_shoulder': 'left_shoulder',
                  'r_shoulder': 'right_shoulder', 'l_elbow': 'left_elbow',
                  'r_elbow': 'right_elbow', 'l_wrist': 'left_hand', 'r_wrist': 'right_hand',
                  'body': 'hip'}
TRUNK = ('body', 'torso', 'head')
HAND_POINT = 'r_wrist'  # the tracked hand (/target) of a take replayed with right_hand
AS_RECORDED = Placement()  # the room frame itself


@dataclass(frozen=True)
class RecordedBody:
    """A take's body: times (N,) s from the first frame (time-scaled), points (N, 9, 3) m in
    the base frame in BODY_POINTS order, a NaN row where that point was lost."""

    times: np.ndarray
    points: np.ndarray
    rate_hz: float

    def frame(self, index: int) -> tuple[tuple[str, ...], np.ndarray]:
        """The names (K,) and points (K, 3) m seen in frame `index` (K may be 0)."""
        points = self.points[index]
        seen = np.all(np.isfinite(points), axis=1)
        return tuple(name for name, ok in zip(BODY_POINTS, seen, strict=True) if ok), \
            points[seen]

    def first_frame(self) -> tuple[tuple[str, ...], np.ndarray]:
        """frame() of the first frame that sees any point: names (K,), points (K, 3) m (K = 0
        if no frame does)."""
        seen = np.flatnonzero(np.all(np.isfinite(self.points), axis=2).any(axis=1))
        return self.frame(int(seen[0])) if len(seen) else ((), np.zeros((0, 3)))

    def trunk(self) -> np.ndarray:
        """Every frame's body, torso and head stacked: (3 N, 3) m, NaN rows where lost."""
        indices = [BODY_POINTS.index(name) for name in TRUNK]
        return self.points[:, indices, :].reshape(-1, 3)


def read_recorded_body(path, placement: Placement = AS_RECORDED,
                       time_scale: float = 1.0) -> RecordedBody:
    """Every BODY_POINTS point of a Vicon Nexus CSV export (hri_core.recorded_motion),
    placed by `placement`, times multiplied by `time_scale`; a segment the file does not have is
    lost in every frame (NaN). ValueError with a one-line reason (as read_vicon_csv) for a
    file that is no such export or has none of the nine segments."""
    motions = read_vicon_segments(path, [VICON_SEGMENTS[name] for name in BODY_POINTS],
                                  placement, time_scale, optional=True)
    first = next(iter(motions.values()))
    lost = np.full((len(first.times), 3), math.nan)
    points = np.stack([motions[VICON_SEGMENTS[name]].positions
                       if VICON_SEGMENTS[name] in motions else lost for name in BODY_POINTS],
                      axis=1)
    return RecordedBody(first.times, points, first.rate_hz)


@dataclass(frozen=True)
class BodyModel:
    """Proportions of the standing body (m): upper_arm (shoulder to elbow) and forearm (elbow
    to wrist) lengths, shoulder_half_width (torso point to each shoulder, sideways),
    shoulder_drop (shoulders below the torso point), trunk (body point up to the torso point)
    and neck (torso point up to the head's centre). Defaults: an adult of about 1.75 m
    (DIN 33402-2's median man: upper arm 0.30, forearm 0.27, shoulder breadth 0.38 m)."""

    upper_arm: float = 0.30
    forearm: float = 0.27
    shoulder_half_width: float = 0.19
    shoulder_drop: float = 0.03
    trunk: float = 0.50
    neck: float = 0.25

    def __post_init__(self):
        for name, value in vars(self).items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f'body model {name} must be a finite number >= 0 m, '
                                 f'got {value!r}')
        if self.upper_arm <= 0.0 or self.forearm <= 0.0:
            raise ValueError('body model upper_arm and forearm must be > 0 m')


def elbow_position(shoulder, wrist, upper_arm: float, forearm: float, pole) -> np.ndarray:
    """The elbow (3,) m of a two-link arm from `shoulder` (3,) to `wrist` (3,) m with link
    lengths upper_arm, forearm (m), bent towards `pole` (3,), a direction (e.g. down and out).

    Within reach the elbow is at upper_arm from the shoulder and forearm from the wrist, in
    the plane of the shoulder-wrist line and the pole. Beyond reach the arm points straight
    at the wrist (elbow on that line at upper_arm; the wrist is still the given point); closer
    than |upper_arm - forearm| the elbow folds back along the pole. A zero shoulder-wrist
    distance or a pole along that line takes the pole (or -z) itself as the bend.
    """
    shoulder, wrist = np.asarray(shoulder, float), np.asarray(wrist, float)
    offset = wrist - shoulder
    distance = float(np.linalg.norm(offset))
    pole = np.asarray(pole, float)
    if distance < 1e-9:
        norm = float(np.linalg.norm(pole))
        return shoulder + upper_arm * (pole / norm if norm > 0.0 else np.array([0, 0, -1.0]))
    along = offset / distance
    side = pole - (pole @ along) * along
    if float(np.linalg.norm(side)) < 1e-9:  # pole along the arm: any perpendicular
        side = np.cross(along, [0.0, 0.0, 1.0])
        if float(np.linalg.norm(side)) < 1e-9:
            side = np.array([1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    reach = min(max(distance, abs(upper_arm - forearm)), upper_arm + forearm)
    a = (upper_arm ** 2 - forearm ** 2 + reach ** 2) / (2.0 * reach)
    h = math.sqrt(max(upper_arm ** 2 - a ** 2, 0.0))
    return shoulder + a * along + h * side


def standing_body(place, yaw: float, height: float, right_wrist,
                  model: BodyModel = BodyModel()) -> np.ndarray:
    """The standing body's points (9, 3) m in BODY_POINTS order: its body point at
    (place[0], place[1], height) (m), facing `yaw` (rad, about z), its right wrist at
    `right_wrist` (3,) m (the scripted hand), its right elbow by `elbow_position` (bent down
    and out), its left arm hanging straight down. ValueError for non-finite input."""
    values = np.concatenate([np.asarray(place, float).reshape(-1)[:2],
                             np.asarray(right_wrist, float).reshape(-1), [yaw, height]])
    if values.size != 7 or not np.all(np.isfinite(values)):
        raise ValueError('standing_body needs a finite place (2,), right_wrist (3,), yaw and '
                         'height')
    c, s = math.cos(yaw), math.sin(yaw)
    left, up = np.array([-s, c, 0.0]), np.array([0.0, 0.0, 1.0])
    body = np.array([place[0], place[1], height], dtype=float)
    torso = body + model.trunk * up
    head = torso + model.neck * up
    shoulder_height = torso - model.shoulder_drop * up
    l_shoulder = shoulder_height + model.shoulder_half_width * left
    r_shoulder = shoulder_height - model.shoulder_half_width * left
    r_wrist = np.asarray(right_wrist, float).reshape(3)
    r_elbow = elbow_position(r_shoulder, r_wrist, model.upper_arm, model.forearm,
                             -up - 0.5 * left)  # down and out (to its right)
    l_elbow = l_shoulder - model.upper_arm * up
    l_wrist = l_elbow - model.forearm * up
    points = {'head': head, 'torso': torso, 'l_shoulder': l_shoulder, 'r_shoulder': r_shoulder,
              'l_elbow': l_elbow, 'r_elbow': r_elbow, 'l_wrist': l_wrist, 'r_wrist': r_wrist,
              'body': body}
    return np.array([points[name] for name in BODY_POINTS])
