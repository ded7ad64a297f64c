"""Recorded human motion: a Vicon Nexus CSV export read into a hand path in the base frame.

No ROS here. The export (data/human-motion/README.md) has a header of five lines:

    Objects
    100                                   <- frame rate, Hz
    ,,Global Angle right_hand:right_hand,,,,,,Global Angle ...   <- segment names, 6 columns each
    Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ,...
    ,,rad,rad,rad,mm,mm,mm,...

then one frame a line. TX, TY, TZ are the segment's position in the room frame in mm (Z up);
a frame where the cameras lost the segment has empty cells there, read as a NaN row.

The room-to-base transform is p_base = Rz(yaw) p_room + translation (m, rad): the hand path
as the robot's base frame sees it. `choose_placement` picks that transform for a take never
seen before, so that most of its horizontal path lies inside a planar arm's reach annulus.
"""

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SEGMENT_PREFIX = 'Global Angle '
SEGMENT_COLUMNS = ('RX', 'RY', 'RZ', 'TX', 'TY', 'TZ')
MM = 1e-3


@dataclass(frozen=True)
class Placement:
    """Room-to-base transform: p_base = Rz(yaw) p_room + translation; translation (3,) m,
    yaw rad (rotation about the room's vertical z axis)."""

    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw: float = 0.0

    def apply(self, points) -> np.ndarray:
        """Room-frame points (N, 3) m -> base-frame points (N, 3) m (NaN rows stay NaN)."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return points @ rotation.T + np.asarray(self.translation, dtype=float)

    def turned(self, turn: float) -> 'Placement':
        """This placement followed by a turn (rad) about the base's vertical axis: the person
        keeps every distance from the base and stands elsewhere round it."""
        c, s = math.cos(turn), math.sin(turn)
        x, y, z = self.translation
        return Placement((c * x - s * y, s * x + c * y, z), self.yaw + turn)


@dataclass(frozen=True)
class RecordedMotion:
    """One segment of a take: times (N,) s from the first frame (already time-scaled) and
    positions (N, 3) m in the base frame; a lost frame is a NaN row. rate_hz: the recorded
    frame rate; segment: the segment's name."""

    times: np.ndarray
    positions: np.ndarray
    rate_hz: float
    segment: str

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask (N,) of frames where the segment was seen."""
        return np.all(np.isfinite(self.positions), axis=1)


def _header_line(rows: list[list[str]], index: int, what: str, name: str) -> list[str]:
    if len(rows) <= index:
        raise ValueError(f'{name} is not a Vicon CSV export: it ends before its {what} line')
    return rows[index]


def _segment_column(names: list[str], segment: str) -> int:
    """First column of `segment` (e.g. 'right_hand') in the segment-name line."""
    wanted = f'{SEGMENT_PREFIX}{segment}:{segment}'
    present = []
    for column, cell in enumerate(names):
        cell = cell.strip()
        if cell.startswith(SEGMENT_PREFIX):
            present.append(cell[len(SEGMENT_PREFIX):].split(':')[0])
            if cell == wanted:
                return column
    raise ValueError(f"no segment '{segment}' in the file (segments: "
                     f"{', '.join(present) or 'none'})")


def read_vicon_csv(path, segment: str = 'right_hand', placement: Placement = Placement(),
                   time_scale: float = 1.0) -> RecordedMotion:
    """Read one segment's path from a Vicon Nexus CSV export.

    path: the .csv file; segment: segment name ('right_hand', 'left_hand', 'head', ...);
    placement: room-to-base transform; time_scale: recorded time multiplier (2.0 plays the
    take at half speed). Raises ValueError with a one-line reason for a file that is not such
    an export (wrong header, missing segment, no frames, non-numeric cells, bad frame rate).
    """
    return read_vicon_segments(path, (segment,), placement, time_scale)[segment]


def read_vicon_segments(path, segments, placement: Placement = Placement(),
                        time_scale: float = 1.0, optional: bool = False
                        ) -> dict[str, RecordedMotion]:
    """Read several segments' paths from one Vicon Nexus CSV export in one pass.

    segments: names as in `read_vicon_csv`; the rest as there. Returns {segment:
    RecordedMotion} sharing one times array. Raises ValueError as `read_vicon_csv` does,
    naming the first segment that is missing or never seen; with `optional`, a segment the
    file does not have is left out of the result and one never seen is all NaN rows.
    """
    if not (math.isfinite(time_scale) and time_scale > 0.0):
        raise ValueError(f'time_scale must be a positive finite number, got {time_scale}')
    segments = tuple(segments)
    if not segments:
        raise ValueError('no segment asked for')
    path = Path(path)
    try:
        with path.open(newline='', encoding='utf-8-sig') as stream:
            rows = list(csv.reader(stream))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise ValueError(f'cannot read {path.name}: {error}') from None
    if not rows or [c.strip() for c in rows[0][:1]] != ['Objects']:
        raise ValueError(f"{path.name} is not a Vicon CSV export: line 1 is not 'Objects'")
    rate_cells = [c for c in _header_line(rows, 1, 'frame-rate', path.name) if c.strip()]
    try:
        rate_hz = float(rate_cells[0])
    except (IndexError, ValueError):
        raise ValueError(f'{path.name}: line 2 must be the frame rate in Hz') from None
    if not (math.isfinite(rate_hz) and rate_hz > 0.0):
        raise ValueError(f'{path.name}: frame rate must be positive, got {rate_hz}')
    names = _header_line(rows, 2, 'segment-name', path.name)
    if optional:
        wanted = {f'{SEGMENT_PREFIX}{segment}:{segment}' for segment in segments}
        present = {cell.strip() for cell in names} & wanted
        segments = tuple(s for s in segments if f'{SEGMENT_PREFIX}{s}:{s}' in present)
        if not segments:
            raise ValueError(f'{path.name} has none of the segments {", ".join(wanted)}')
    columns = [_segment_column(names, segment) for segment in segments]
    labels = [c.strip() for c in _header_line(rows, 3, 'column-label', path.name)]
    unit_line = [c.strip() for c in _header_line(rows, 4, 'unit', path.name)]
    for segment, column in zip(segments, columns, strict=True):
        if labels[:1] != ['Frame'] or tuple(labels[column:column + 6]) != SEGMENT_COLUMNS:
            raise ValueError(f"{path.name}: line 4 must read 'Frame,Sub Frame' and "
                             f"{','.join(SEGMENT_COLUMNS)} under segment '{segment}'")
        units = unit_line[column + 3:column + 6]
        if units != ['mm'] * 3:
            raise ValueError(f"{path.name}: positions of '{segment}' must be in mm, "
                             f"got {units}")
    frames, points = [], []
    for line_number, row in enumerate(rows[5:], start=6):
        if not any(cell.strip() for cell in row):
            continue                                   # a trailing blank line
        try:
            frames.append(float(row[0]))
            frame_points = []
            for column in columns:
                cells = [c.strip() for c in row[column + 3:column + 6]]
                frame_points.append([float(c) if c else math.nan for c in cells]
                                    if len(cells) == 3 else [math.nan] * 3)
            points.append(frame_points)
        except ValueError:
            raise ValueError(f'{path.name} line {line_number}: non-numeric cell') from None
    if not frames:
        raise ValueError(f'{path.name} holds no frames')
    frames = np.asarray(frames)
    if not np.all(np.isfinite(frames)) or np.any(np.diff(frames) <= 0.0):
        raise ValueError(f'{path.name}: frame numbers must increase')
    times = (frames - frames[0]) / rate_hz * time_scale
    motions = {}
    for index, segment in enumerate(segments):
        positions = np.asarray(points)[:, index, :] * MM
        positions[~np.all(np.isfinite(positions), axis=1)] = math.nan  # partly lost = lost
        if not optional and not np.any(np.isfinite(positions[:, 0])):
            raise ValueError(f"{path.name}: segment '{segment}' is never seen")
        motions[segment] = RecordedMotion(times, placement.apply(positions), rate_hz, segment)
    return motions


# auto_place's default clearance (m) of a person's trunk from each arm's base
# (docs/design.md, "A placement a person could stand in").
BODY_CLEARANCE = {'scara': 0.40, 'panda': 0.45}


@dataclass(frozen=True)
class ReachAnnulus:
    """Where a planar arm on the base frame's origin reaches: inner..outer radius (m), a
    margin (m) kept from both edges, and the half-angle (rad) of the sector round +x the
    path is asked to stay in (a joint-1 range narrower than a full turn)."""

    inner: float
    outer: float
    margin: float = 0.03
    half_angle: float = math.radians(120.0)

    def __post_init__(self):
        if not (0.0 <= self.inner < self.outer and self.margin >= 0.0
                and self.inner + 2.0 * self.margin < self.outer
                and 0.0 < self.half_angle <= math.pi):
            raise ValueError(f'need 0 <= inner < outer with room for the margins, and '
                             f'0 < half_angle <= pi, got {self}')


def _cleaned_horizontal(positions: np.ndarray, max_step: float, width: int = 31) -> np.ndarray:
    """Seen frames' x, y (M, 2) without jumps: a frame farther than max_step (m) from the
    median of the `width` seen frames round it (a marker swap shorter than half of them) is
    dropped."""
    xy = positions[np.all(np.isfinite(positions), axis=1), :2]
    if len(xy) < width:
        return xy
    half = width // 2
    padded = np.pad(xy, ((half, half), (0, 0)), mode='edge')
    windows = np.lib.stride_tricks.sliding_window_view(padded, width, axis=0)  # (M, 2, w)
    median = np.median(windows, axis=2)
    return xy[np.linalg.norm(xy - median, axis=1) <= max_step]


def body_clearances(centres, body) -> np.ndarray:
    """The least horizontal distance (C,) m from each of `centres` (C, 2) m to any seen point
    of `body` (N, 3) m (NaN rows skipped; every seen frame counts, marker swaps included):
    how close a person's trunk comes to a robot base standing there. inf without a seen
    point."""
    from scipy.spatial import cKDTree  # only placement needs it

    body = np.asarray(body, dtype=float).reshape(-1, 3)
    xy = body[np.all(np.isfinite(body), axis=1), :2]
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    if len(xy) == 0:
        return np.full(len(centres), math.inf)
    return cKDTree(xy).query(centres)[0]


YAW_TURNS = (0.0, math.pi / 6.0, -math.pi / 6.0, math.pi / 3.0, -math.pi / 3.0)
"""rad: the turns of a path's mean bearing off +x that choose_placement tries with a rule."""


def choose_placement(positions, reach: ReachAnnulus, grid: float = 0.02,
                     max_points: int = 600, body=None, clearance: float = 0.0,
                     accept=None) -> Placement:
    """A room-to-base transform that puts most of a take's horizontal path inside `reach`
    while the person's trunk keeps `clearance` from the base.

    positions: (N, 3) room-frame path, m (NaN rows allowed). body: (M, 3) room-frame points
    that must stay at least `clearance` m (horizontally) from the base through the whole
    take, e.g. the hip, collar and head of every frame stacked (NaN rows allowed; None:
    no such rule). The base is placed on a grid (`grid` m) round the path; places closer
    than `clearance` to any body point are ruled out; for each remaining place, the yaw
    turns the path's circular-mean bearing onto +x, and the score is the fraction of the
    path inside the annulus (with its margin) and the sector; ties go to the path nearest
    the annulus's mid-radius and the +x axis (the least swinging round the base).
    Marker-swap frames of the path are dropped first; at most `max_points` frames are
    scored. The translation's z is 0 (heights stay as recorded). accept: a further rule on
    the placement (a function of a Placement to bool, e.g. hri_core.bodies.clear_of_arm:
    the person not inside the arm at the start); the places, each also with the path's
    bearing turned by YAW_TURNS, are tried best first until one passes. Raises ValueError
    if no frame is seen, for a negative clearance, or if no place on the grid keeps the
    clearance and passes `accept`.
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    if not (math.isfinite(clearance) and clearance >= 0.0):
        raise ValueError(f'clearance must be a finite number >= 0 m, got {clearance}')
    xy = _cleaned_horizontal(positions, max_step=0.3)
    if len(xy) == 0:
        raise ValueError('the path has no seen frame to place')
    xy = xy[np.linspace(0, len(xy) - 1, min(len(xy), max_points)).astype(int)]
    low, high = xy.min(axis=0) - reach.outer, xy.max(axis=0) + reach.outer
    gx = np.arange(low[0], high[0] + grid, grid)
    gy = np.arange(low[1], high[1] + grid, grid)
    centres = np.stack(np.meshgrid(gx, gy, indexing='ij'), axis=-1).reshape(-1, 2)
    if body is not None and clearance > 0.0:
        centres = centres[body_clearances(centres, body) >= clearance]
        if len(centres) == 0:
            raise ValueError(f'no base place within reach of the path keeps the body '
                             f'{clearance} m away')
    inner, outer = reach.inner + reach.margin, reach.outer - reach.margin
    middle = 0.5 * (inner + outer)
    # With a placement rule the path's mean bearing may also land up to 60 degrees off +x:
    # the arm's start pose lies along +x (the SCARA's link1), and turning the person off it
    # keeps more of the path in reach than moving the base away.
    turns = (0.0,) if accept is None else YAW_TURNS
    scores, bearings, places = [], [], []
    for chunk in np.array_split(centres, max(1, len(centres) // 2000)):
        if len(chunk) == 0:
            continue
        offset = xy[None, :, :] - chunk[:, None, :]           # (C, M, 2)
        radius = np.hypot(offset[..., 0], offset[..., 1])
        # The circular mean bearing from the unit vectors, without an angle per point (a
        # point on the centre adds nothing, where a division by its zero radius would
        # give NaN).
        unit = offset / np.maximum(radius, 1e-12)[..., None]
        mean_bearing = np.arctan2(unit[..., 1].sum(1), unit[..., 0].sum(1))
        # Each point's bearing off the mean, in [-pi, pi]: the angle of offset turned back
        # by the mean bearing.
        c, s = np.cos(mean_bearing)[:, None], np.sin(mean_bearing)[:, None]
        relative = np.arctan2(offset[..., 1] * c - offset[..., 0] * s,
                              offset[..., 0] * c + offset[..., 1] * s)
        ring = (radius >= inner) & (radius <= outer)
        deviation = np.mean(np.abs(radius - middle), axis=1) / (outer - inner)
        for turn in turns:
            turned = _wrapped(relative - turn)
            inside = ring & (np.abs(turned) <= reach.half_angle)
            spread = deviation + np.mean(np.abs(turned), axis=1) / math.pi
            scores.append(inside.mean(axis=1) - 1e-3 * spread)
            bearings.append(mean_bearing + turn)
            places.append(chunk)
    scores, bearings = np.concatenate(scores), np.concatenate(bearings)
    centres = np.concatenate(places)
    # Best first; a stable sort keeps the grid's order among equal scores.
    for index in np.argsort(-scores, kind='stable'):
        placement = _base_at(centres[index], float(bearings[index]))
        if accept is None or accept(placement):
            return placement
    raise ValueError('no base place within reach of the path passes the placement rule '
                     '(the person clear of the arm at the start)')


def _wrapped(angle: np.ndarray) -> np.ndarray:
    """`angle` (rad) within [-3 pi, 3 pi] brought into [-pi, pi]."""
    return np.where(angle > math.pi, angle - 2.0 * math.pi,
                    np.where(angle < -math.pi, angle + 2.0 * math.pi, angle))


def _base_at(centre, bearing: float) -> Placement:
    """The placement that puts the base at the room point `centre` (2,) m with the room
    bearing `bearing` (rad) turned onto +x."""
    yaw = -bearing
    c, s = math.cos(yaw), math.sin(yaw)
    shift = -np.array([c * centre[0] - s * centre[1], s * centre[0] + c * centre[1]])
    return Placement((float(shift[0]), float(shift[1]), 0.0), float(yaw))


def reach_fraction(positions, reach: ReachAnnulus) -> float:
    """Fraction of the seen frames of a base-frame path (N, 3) m inside `reach` (its
    radii, without the margin); NaN rows are not counted."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    xy = positions[np.all(np.isfinite(positions), axis=1), :2]
    if len(xy) == 0:
        return 0.0
    radius = np.hypot(xy[:, 0], xy[:, 1])
    return float(np.mean((radius >= reach.inner) & (radius <= reach.outer)))


AT_END = ('loop', 'stop', 'hold')


class Replay:
    """A take replayed at its recorded pace: which frame is due `elapsed` s after the start.

    motion: the take (already in the base frame); placement: the transform it was placed with
    (kept for the record). at_end: 'loop' (start again one frame period after the last frame),
    'stop' (nothing more), or 'hold' (the last seen frame for good, its time advancing with
    `elapsed`).
    `due(elapsed)` gives (index, time of that frame since the start in s) of the newest frame
    at or before `elapsed`, or None when none is due (after the end with 'stop'). The caller
    publishes each frame time once, and nothing for a lost frame (`motion.valid[index]`).
    """

    def __init__(self, motion: RecordedMotion, at_end: str = 'loop',
                 placement: Placement = Placement()):
        if at_end not in AT_END:
            raise ValueError(f"at_end must be one of {', '.join(AT_END)}, got {at_end!r}")
        self.motion, self.at_end, self.placement = motion, at_end, placement
        times = motion.times
        period = float(np.median(np.diff(times))) if len(times) > 1 else 1.0 / motion.rate_hz
        self.cycle = float(times[-1]) + period          # s, one pass when looping
        self._last_seen = int(np.flatnonzero(motion.valid)[-1])

    def due(self, elapsed: float) -> tuple[int, float] | None:
        times = self.motion.times
        if elapsed < 0.0:
            return None
        offset = 0.0
        if elapsed > times[-1]:
            if self.at_end == 'stop':
                return None
            if self.at_end == 'hold':
                return self._last_seen, float(elapsed)
            passes = math.floor(elapsed / self.cycle)
            offset = passes * self.cycle
            elapsed -= offset
        index = int(np.searchsorted(times, elapsed, side='right')) - 1
        return index, float(times[index] + offset)
