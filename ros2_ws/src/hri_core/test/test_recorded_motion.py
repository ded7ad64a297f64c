"""Unit tests of hri_core.recorded_motion: Vicon CSV reading, transform, placement."""

import functools
import math
from pathlib import Path

import numpy as np
import pytest

from hri_core.recorded_motion import (
    BODY_CLEARANCE,
    Placement,
    ReachAnnulus,
    Replay,
    body_clearances,
    choose_placement,
    reach_fraction,
    read_vicon_csv,
    read_vicon_segments,
)

TAKES = sorted((Path(__file__).resolve().parents[4] / 'data' / 'human-motion').glob('*.csv'))
SCARA_REACH = ReachAnnulus(inner=0.222, outer=0.65)      # l1 0.35, l2 0.30, |q2| <= 2.46 rad
SEGMENTS = ('head', 'right_hand')


def vicon_text(rows, segments=SEGMENTS, rate='100', units='mm'):
    """A small export: rows are (frame, {segment: (x, y, z) mm or None for lost})."""
    names = ',,' + ','.join(f'Global Angle {s}:{s},,,,,' for s in segments)
    labels = 'Frame,Sub Frame,' + ','.join('RX,RY,RZ,TX,TY,TZ' for _ in segments)
    unit_line = ',,' + ','.join(f'rad,rad,rad,{units},{units},{units}' for _ in segments)
    lines = ['\ufeffObjects', rate, names, labels, unit_line]
    for frame, points in rows:
        cells = [str(frame), '0']
        for segment in segments:
            point = points.get(segment)
            cells += ['0.1', '0.2', '0.3'] if point is not None else ['', '', '']
            cells += [f'{v:.6f}' for v in point] if point is not None else ['', '', '']
        lines.append(','.join(cells))
    return '\n'.join(lines) + '\n\n'


def write(tmp_path, text, name='take.csv'):
    path = tmp_path / name
    path.write_text(text, encoding='utf-8')
    return path


def test_reads_positions_in_metres_with_lost_frames_as_nan(tmp_path):
    rows = [(31, {'head': (0, 0, 1500), 'right_hand': (100.0, -200.0, 900.0)}),
            (32, {'head': (0, 0, 1500)}),
            (33, {'head': (0, 0, 1500), 'right_hand': (110.0, -200.0, 905.0)})]
    motion = read_vicon_csv(write(tmp_path, vicon_text(rows)))
    assert motion.rate_hz == 100.0 and motion.segment == 'right_hand'
    np.testing.assert_allclose(motion.times, [0.0, 0.01, 0.02])
    np.testing.assert_allclose(motion.positions[0], [0.1, -0.2, 0.9])
    assert np.all(np.isnan(motion.positions[1]))
    assert motion.valid.tolist() == [True, False, True]
    head = read_vicon_csv(write(tmp_path, vicon_text(rows)), segment='head')
    np.testing.assert_allclose(head.positions[:, 2], 1.5)


def test_transform_and_time_scale(tmp_path):
    rows = [(1, {'right_hand': (1000.0, 0.0, 500.0)}), (2, {'right_hand': (1000.0, 10.0, 500.0)})]
    placement = Placement(translation=(0.1, 0.2, -0.5), yaw=math.pi / 2)
    motion = read_vicon_csv(write(tmp_path, vicon_text(rows)), placement=placement,
                            time_scale=4.0)
    np.testing.assert_allclose(motion.times, [0.0, 0.04])
    # Rz(90 deg) (1, 0, 0.5) = (0, 1, 0.5); + (0.1, 0.2, -0.5)
    np.testing.assert_allclose(motion.positions[0], [0.1, 1.2, 0.0], atol=1e-12)
    np.testing.assert_allclose(motion.positions[1], [0.09, 1.2, 0.0], atol=1e-12)


@pytest.mark.parametrize('text, reason', [
    ('', "line 1 is not 'Objects'"),
    ('Objects\n', 'ends before its frame-rate line'),
    ('Objects\nfast\n', 'frame rate in Hz'),
    ('Objects\n-100\n', 'frame rate must be positive'),
    (vicon_text([], segments=('head',)), "no segment 'right_hand'.*segments: head"),
    (vicon_text([]), 'holds no frames'),
    (vicon_text([(1, {})]), 'never seen'),
    (vicon_text([(1, {'right_hand': (1, 2, 3)})], units='cm'), 'must be in mm'),
    (vicon_text([(1, {'right_hand': (1, 2, 3)})]).replace('0.100000', '0.1')
     .replace('1.000000', 'one'), 'line 6: non-numeric cell'),
    (vicon_text([(2, {'right_hand': (1, 2, 3)}), (1, {'right_hand': (1, 2, 3)})]),
     'frame numbers must increase'),
    (vicon_text([(1, {'right_hand': (1, 2, 3)})]).replace('TX,TY,TZ\n', 'AX,AY,AZ\n'),
     "line 4 must read 'Frame,Sub Frame'"),
])
def test_a_bad_file_gives_a_one_line_reason(tmp_path, text, reason):
    with pytest.raises(ValueError, match=reason) as caught:
        read_vicon_csv(write(tmp_path, text))
    assert '\n' not in str(caught.value)


def test_missing_file_and_bad_time_scale(tmp_path):
    with pytest.raises(ValueError, match='cannot read absent.csv'):
        read_vicon_csv(tmp_path / 'absent.csv')
    rows = [(1, {'right_hand': (1, 2, 3)})]
    with pytest.raises(ValueError, match='time_scale must be a positive'):
        read_vicon_csv(write(tmp_path, vicon_text(rows)), time_scale=0.0)


def test_binary_garbage_is_a_one_line_reason(tmp_path):
    path = tmp_path / 'garbage.csv'
    path.write_bytes(np.random.default_rng(5).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match='garbage.csv'):
        read_vicon_csv(path)


@pytest.mark.parametrize('take', TAKES, ids=lambda p: p.stem)
def test_every_shipped_take_reads(take):
    motion = read_vicon_csv(take)
    assert motion.rate_hz == 100.0
    assert len(motion.times) > 600
    assert np.all(np.diff(motion.times) > 0.0)
    seen = motion.positions[motion.valid]
    assert np.all(np.abs(seen) < 5.0)                   # metres, not millimetres
    assert motion.valid.mean() > 0.9


def test_shipped_takes_are_all_present():
    assert len(TAKES) == 8
    assert (TAKES[0].parent / 'LICENSE').read_text().startswith('MIT License')


def random_walk_path(seed, length=1500, spread=1.4):
    """A hand-like room-frame path: a smooth random walk about 1.4 m across, 1-2 m from the
    room origin, with lost frames and one marker swap."""
    rng = np.random.default_rng(seed)
    steps = np.cumsum(rng.normal(0.0, 1.0, (length, 2)), axis=0)
    steps = np.apply_along_axis(lambda v: np.convolve(v, np.ones(50) / 50, 'same'), 0, steps)
    steps = (steps - steps.min(0)) / np.ptp(steps, axis=0).max() * spread
    path = np.column_stack([steps + rng.uniform(-2.0, 2.0, 2), np.full(length, 0.9)])
    path[rng.choice(length, 40, replace=False)] = np.nan
    path[700] += (3.0, -2.0, 0.0)                       # one frame metres away
    return path


@pytest.mark.parametrize('seed', [1, 2, 3, 4])
def test_placement_puts_most_of_an_unseen_path_in_reach(seed):
    path = random_walk_path(seed)
    placement = choose_placement(path, SCARA_REACH)
    placed = placement.apply(path)
    assert reach_fraction(placed, SCARA_REACH) >= 0.6
    # the path faces the arm: its circular-mean bearing is +x
    xy = placed[np.all(np.isfinite(placed), axis=1), :2]
    bearing = np.angle(np.mean(np.exp(1j * np.arctan2(xy[:, 1], xy[:, 0]))))
    assert abs(bearing) < 0.3
    np.testing.assert_allclose(placed[:, 2][np.isfinite(placed[:, 2])], 0.9)


def test_a_path_that_fits_is_placed_wholly_in_reach():
    angle = np.linspace(-1.0, 1.0, 400)
    arc = np.column_stack([0.45 * np.cos(angle) + 3.0, 0.45 * np.sin(angle) - 1.0,
                           np.zeros(400)])
    placed = choose_placement(arc, SCARA_REACH).apply(arc)
    assert reach_fraction(placed, SCARA_REACH) == 1.0


@pytest.mark.parametrize('take', TAKES, ids=lambda p: p.stem)
def test_placement_of_the_shipped_takes(take):
    motion = read_vicon_csv(take)
    placed = choose_placement(motion.positions, SCARA_REACH).apply(motion.positions)
    assert reach_fraction(placed, SCARA_REACH) >= 0.65


def test_a_turned_placement_keeps_every_distance_from_the_base_and_turns_the_points():
    rng = np.random.default_rng(4)
    points = rng.uniform(-2.0, 2.0, size=(20, 3))
    placement = Placement((0.6, -0.3, 0.1), 0.4)
    turned = placement.turned(-0.9)
    before, after = placement.apply(points), turned.apply(points)
    assert np.allclose(np.hypot(after[:, 0], after[:, 1]), np.hypot(before[:, 0], before[:, 1]))
    assert np.allclose(after[:, 2], before[:, 2])
    assert np.allclose(np.arctan2(after[:, 1], after[:, 0]),
                       np.angle(np.exp(1j * (np.arctan2(before[:, 1], before[:, 0]) - 0.9))))
    assert placement.turned(0.0) == placement


def test_placement_needs_a_seen_frame_and_a_sane_annulus():
    with pytest.raises(ValueError, match='no seen frame'):
        choose_placement(np.full((5, 3), np.nan), SCARA_REACH)
    with pytest.raises(ValueError, match='inner < outer'):
        ReachAnnulus(inner=0.7, outer=0.65)


def three_frames(tmp_path, lost_last=False):
    rows = [(1, {'right_hand': (400.0, 0.0, 0.0)}), (2, {'right_hand': (410.0, 0.0, 0.0)}),
            (3, {} if lost_last else {'right_hand': (420.0, 0.0, 0.0)})]
    return read_vicon_csv(write(tmp_path, vicon_text(rows)))


def test_replay_loops_at_the_recorded_pace(tmp_path):
    replay = Replay(three_frames(tmp_path), 'loop')
    assert replay.cycle == pytest.approx(0.03)
    assert replay.due(0.0) == (0, 0.0)
    assert replay.due(0.015) == (1, pytest.approx(0.01))
    assert replay.due(0.029) == (2, pytest.approx(0.02))
    assert replay.due(0.031) == (0, pytest.approx(0.03))       # the second pass
    assert replay.due(0.075) == (1, pytest.approx(0.07))      # the third


def test_replay_stops_or_holds_the_last_seen_frame(tmp_path):
    stop = Replay(three_frames(tmp_path), 'stop')
    assert stop.due(0.02)[0] == 2 and stop.due(0.021) is None
    hold = Replay(three_frames(tmp_path, lost_last=True), 'hold')
    assert hold.due(0.02) == (2, pytest.approx(0.02))          # the lost frame is due ...
    assert hold.due(0.5) == (1, 0.5)                           # ... then the last seen one
    with pytest.raises(ValueError, match='at_end must be one of loop, stop, hold'):
        Replay(three_frames(tmp_path), 'rewind')


def test_placement_ignores_a_long_marker_swap():
    angle = np.linspace(-1.0, 1.0, 400)
    arc = np.column_stack([0.45 * np.cos(angle) + 3.0, 0.45 * np.sin(angle) - 1.0,
                           np.zeros(400)])
    swapped = arc.copy()
    swapped[200:212] += (4.0, 3.0, 0.0)                      # 12 frames metres away
    placement = choose_placement(swapped, SCARA_REACH)
    assert reach_fraction(placement.apply(arc), SCARA_REACH) == 1.0


# -- a placement a person could stand in ---------------------------------------------------
# Each arm's reach annulus as hand_sim gets it: the SCARA's default (hand_sim.yaml) and the
# Panda's demo (scripts/demo.py's PANDA_HAND_REACH).
ARM_REACH = {'scara': SCARA_REACH, 'panda': ReachAnnulus(0.30, 0.75)}
# Share of each take's hand path in reach with the trunk kept clear, at least: the least over
# the eight takes and both arms is 0.68 (CollaborativeHammering_1, SCARA).
MIN_IN_REACH = 0.65


@functools.cache
def recorded_body(take: Path):
    """The take's whole body (human_body.read_recorded_body), read once per test process:
    the tests below read it 40 times (0.14 s each)."""
    from hri_core.human_body import read_recorded_body

    return read_recorded_body(take)


@functools.cache
def trunk_clear_placement(take: Path, arm: str):
    """choose_placement of the take's right wrist with the arm's reach and the trunk kept
    BODY_CLEARANCE[arm] away (no further rule), found once per test process."""
    from hri_core.human_body import BODY_POINTS

    body = recorded_body(take)
    return choose_placement(body.points[:, BODY_POINTS.index('r_wrist')], ARM_REACH[arm],
                            body=body.trunk(), clearance=BODY_CLEARANCE[arm])


@pytest.mark.parametrize('arm', sorted(ARM_REACH))
@pytest.mark.parametrize('take', TAKES, ids=lambda path: path.stem)
def test_auto_place_keeps_the_trunk_clear_and_most_of_the_hand_in_reach(take, arm):
    from hri_core.human_body import BODY_POINTS

    body = recorded_body(take)
    hand = body.points[:, BODY_POINTS.index('r_wrist')]
    reach, clearance = ARM_REACH[arm], BODY_CLEARANCE[arm]
    placement = trunk_clear_placement(take, arm)
    trunk = placement.apply(body.trunk())
    trunk = trunk[np.all(np.isfinite(trunk), axis=1)]
    assert len(trunk) > 0.9 * 3 * len(body.times)
    assert np.min(np.hypot(trunk[:, 0], trunk[:, 1])) >= clearance
    assert reach_fraction(placement.apply(hand), reach) >= MIN_IN_REACH


def test_without_a_clearance_two_takes_put_the_hip_by_the_panda():
    # What the clearance is for: the placement by reach alone.
    from hri_core.human_body import BODY_POINTS

    for name, closest in (('RobotHumanHandover_1', 0.05), ('CollaborativeHammering_1', 0.3)):
        body = recorded_body(next(t for t in TAKES if t.stem == name))
        hip = body.points[:, BODY_POINTS.index('body')]
        placed = choose_placement(body.points[:, BODY_POINTS.index('r_wrist')],
                                  ARM_REACH['panda']).apply(hip)
        assert np.nanmin(np.hypot(placed[:, 0], placed[:, 1])) < closest


def test_a_clearance_no_place_keeps_is_refused_in_one_line():
    path = np.column_stack([np.linspace(0.0, 1.0, 50), np.zeros(50), np.zeros(50)])
    body = np.column_stack([np.linspace(-3.0, 3.0, 301), np.zeros(301), np.zeros(301)])
    body = np.vstack([body, body[:, [1, 0, 2]]])  # a cross 6 m wide round the path
    with pytest.raises(ValueError, match='no base place within reach of the path keeps'):
        choose_placement(path, SCARA_REACH, body=body, clearance=1.5)
    with pytest.raises(ValueError, match='clearance must be a finite number >= 0 m'):
        choose_placement(path, SCARA_REACH, body=body, clearance=-0.1)


def test_body_clearances_is_the_least_horizontal_distance():
    body = np.array([[1.0, 0.0, 5.0], [np.nan, np.nan, np.nan], [0.0, 2.0, -1.0]])
    np.testing.assert_allclose(body_clearances([[0.0, 0.0], [1.0, 1.0]], body), [1.0, 1.0])
    assert body_clearances([[0.0, 0.0]], np.full((2, 3), np.nan))[0] == math.inf


def test_read_vicon_segments_reads_several_in_one_pass(tmp_path):
    rows = [(1, {'head': (0, 0, 1500), 'right_hand': (100.0, -200.0, 900.0)}),
            (2, {'head': (0, 0, 1510)})]
    motions = read_vicon_segments(write(tmp_path, vicon_text(rows)), ('head', 'right_hand'))
    np.testing.assert_allclose(motions['head'].positions[:, 2], [1.5, 1.51])
    assert motions['right_hand'].valid.tolist() == [True, False]
    optional = read_vicon_segments(write(tmp_path, vicon_text(rows)), ('hip', 'head'),
                                   optional=True)
    assert list(optional) == ['head']
    with pytest.raises(ValueError, match="no segment 'hip'"):
        read_vicon_segments(write(tmp_path, vicon_text(rows)), ('hip', 'head'))


@pytest.fixture(scope='module')
def arms():
    from hri_core.bodies import panda_package_dirs, robot_body
    from hri_core.robot_model import robot_model

    return {name: robot_body(robot_model(name), panda_package_dirs()) for name in ARM_REACH}


# The rule costs reach: the least share is 0.61 (CollaborativeHammering_1, SCARA; 0.70 without).
MIN_IN_REACH_OFF_THE_ARM = 0.6


def start_distance(placement, names, points, arm) -> float:
    """The least distance (m) of the placed person's capsules from the arm's at home."""
    from hri_core.bodies import capsule_distances, human_capsules

    person = human_capsules(names, placement.apply(points))
    return float(capsule_distances(arm.capsules(arm.model.home), person,
                                   arm.planar).distance.min())


@pytest.mark.parametrize('arm', sorted(ARM_REACH))
@pytest.mark.parametrize('take', TAKES, ids=lambda path: path.stem)
def test_auto_place_keeps_the_person_off_the_arm_at_its_start(take, arm, arms):
    from hri_core.bodies import clear_of_arm, human_capsules
    from hri_core.human_body import BODY_POINTS

    body = recorded_body(take)
    hand = body.points[:, BODY_POINTS.index('r_wrist')]
    names, points = body.first_frame()
    assert names, take.stem
    rule = clear_of_arm(arms[arm], human_capsules(names, points), 0.10)
    placement = choose_placement(hand, ARM_REACH[arm], body=body.trunk(),
                                 clearance=BODY_CLEARANCE[arm], accept=rule)
    assert start_distance(placement, names, points, arms[arm]) >= 0.10
    trunk = placement.apply(body.trunk())
    assert np.nanmin(np.hypot(trunk[:, 0], trunk[:, 1])) >= BODY_CLEARANCE[arm]
    assert reach_fraction(placement.apply(hand), ARM_REACH[arm]) >= MIN_IN_REACH_OFF_THE_ARM


def test_without_the_arm_rule_most_takes_start_the_person_over_the_scara(arms):
    # What the rule is for: the SCARA's home pose points along the path's mean bearing.
    inside = 0
    for take in TAKES:
        inside += start_distance(trunk_clear_placement(take, 'scara'),
                                 *recorded_body(take).first_frame(), arms['scara']) < 0.10
    assert inside >= len(TAKES) // 2


def test_a_placement_rule_no_place_passes_is_refused_in_one_line():
    path = np.column_stack([np.linspace(0.3, 0.5, 50), np.zeros(50), np.zeros(50)])
    with pytest.raises(ValueError, match='no base place within reach of the path passes'):
        choose_placement(path, SCARA_REACH, accept=lambda placement: False)
