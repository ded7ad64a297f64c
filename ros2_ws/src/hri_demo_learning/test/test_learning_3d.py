"""Unit tests of the learning pipeline in 3-D (no ROS process).

* The fixture bags (recorded in the plane, z = 0) learn to the tasks the planar pipeline
  learned from them (test/data/fixture_tasks_planar.yaml, written by that pipeline), to 1e-9.
* A planar demonstration turned and tilted into 3-D (the same radial profile) gives the same
  S, d1, d2 (within 5 mm) and K as in the plane, for a follow, an avoid and a follow at a
  distance (eq. 4's combination); a push straight up (along z alone) too, so z is not dropped.
"""

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from hri_demo_learning.bag_io import read_demonstration
from hri_demo_learning.learning import (
    Demonstration,
    LearningSettings,
    learn_from_bags,
    learn_from_demonstrations,
)
from hri_demo_learning.synthetic_demonstration import push_path

TEST_DIR = Path(__file__).resolve().parent
FIXTURES = TEST_DIR.parents[3] / 'bags' / 'fixtures'
CONFIG = TEST_DIR.parent / 'config' / 'learner.yaml'
SETTINGS = LearningSettings.from_parameters(
    yaml.safe_load(CONFIG.read_text())['learner']['ros__parameters'])
PLANAR_TASKS = yaml.safe_load((TEST_DIR / 'data' / 'fixture_tasks_planar.yaml').read_text())
BAGS = {'follow': ['follow'], 'avoid': ['avoid'], 'follow_safe': ['follow', 'avoid']}
SHIFTS = {'follow': [0.0], 'avoid': [0.0], 'follow_safe': [0.23, 0.0]}

REFERENCE = np.array([0.45, 0.05])  # m, x_r in the plane
HEADING = np.array([-0.35, 0.94]) / np.hypot(0.35, 0.94)  # from x_r toward the start
RATE = 500.0  # Hz
NOISE = 1e-4  # m
PUSHES = {'follow': (0.30, 0.041), 'avoid': (0.05, 0.183)}  # m from x_r: start, stop


def assert_same_task(record, expected: dict) -> None:
    for name, value in expected.items():
        if isinstance(value, float):
            assert getattr(record, name) == pytest.approx(value, rel=1e-9, abs=1e-12), name
        else:
            assert getattr(record, name) == value, name


@pytest.mark.parametrize('task', ['follow', 'avoid', 'follow_safe'])
def test_the_fixture_bags_learn_to_the_tasks_of_the_planar_pipeline(task):
    learned = learn_from_bags([str(FIXTURES / bag) for bag in BAGS[task]], SHIFTS[task], task,
                              SETTINGS)
    assert_same_task(learned.record, PLANAR_TASKS[task])
    for demo_target in learned.targets:
        assert demo_target.shape == (3,) and demo_target[2] == 0.0


@pytest.mark.parametrize('task', ['follow', 'avoid'])
def test_the_fixture_joint_states_learn_as_before_through_the_scaras_kinematics(task):
    demo = read_demonstration(FIXTURES / task, position_topic='/none')
    assert (demo.position_source, demo.robot, demo.reach) == ('/joint_states', '', None)
    learned = learn_from_demonstrations(
        [Demonstration(demo.times, demo.positions, demo.references[-1], task)], [0.0], task,
        SETTINGS)
    assert_same_task(learned.record, PLANAR_TASKS[f'{task}_joint_states'])


def planar_push(behaviour: str, rng) -> Demonstration:
    """A minimum-jerk push along a ray from x_r, 1 s at rest, 3 s moving, 1.5 s at rest."""
    start, stop = PUSHES[behaviour]
    times = np.arange(0.0, 5.5, 1.0 / RATE)
    positions = push_path(times, REFERENCE + start * HEADING, REFERENCE + stop * HEADING,
                          1.0, 3.0)
    positions = positions + rng.normal(0.0, NOISE, positions.shape)
    return Demonstration(times, positions, REFERENCE.copy(), f'planar {behaviour}')


def turned(demo: Demonstration, rotation: Rotation, offset) -> Demonstration:
    """`demo` in the plane z = 0 turned by `rotation` and moved by `offset` (3,) m."""
    def place(points):
        flat = np.column_stack([points, np.zeros(len(points))])
        return rotation.apply(flat) + offset
    return Demonstration(demo.times, place(demo.positions), place(demo.reference[None])[0],
                         f'{demo.source} in 3-D')


def vertical() -> Rotation:
    """The rotation that turns the plane's heading onto +z: that push is along z alone."""
    rotation, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [[*HEADING, 0.0]])
    return rotation


ROTATIONS = {'tilted': Rotation.from_euler('xyz', [35.0, -50.0, 120.0], degrees=True),
             'vertical': vertical()}


@pytest.mark.parametrize('rotation', ROTATIONS, ids=list(ROTATIONS))
@pytest.mark.parametrize('task', ['follow', 'avoid', 'follow_safe'])
def test_a_demonstration_turned_into_3d_gives_the_planar_task(task, rotation):
    rng = np.random.default_rng(31)
    planar = [planar_push(behaviour, rng) for behaviour in BAGS[task]]
    spatial = [turned(demo, ROTATIONS[rotation], np.array([0.2, -0.1, 0.4]))
               for demo in planar]
    if rotation == 'vertical':
        moved = np.ptp(spatial[0].positions, axis=0)
        assert moved[2] > 0.1 and max(moved[:2]) < 0.01  # the push is along z
    in_plane = learn_from_demonstrations(planar, SHIFTS[task], task, SETTINGS).record
    in_space = learn_from_demonstrations(spatial, SHIFTS[task], task, SETTINGS).record
    assert in_space.s == in_plane.s
    assert in_space.d1 == pytest.approx(in_plane.d1, abs=0.005)
    assert in_space.d2 == pytest.approx(in_plane.d2, abs=0.005)
    assert in_space.k == pytest.approx(in_plane.k, rel=1e-6)  # K from the 3-D speeds
    assert (in_space.a1, in_space.a2) == pytest.approx((in_plane.a1, in_plane.a2), rel=1e-6)


def test_the_planar_tasks_are_the_papers_rows():
    # What the comparison above compares: Table I's rows, from the planar pushes.
    rng = np.random.default_rng(31)
    follow = learn_from_demonstrations([planar_push('follow', rng)], [0.0], 'follow', SETTINGS)
    assert (follow.record.s, follow.record.d1) == (1, 0.0)
    assert follow.record.d2 == pytest.approx(0.041, abs=0.002)
    avoid = learn_from_demonstrations([planar_push('avoid', rng)], [0.0], 'avoid', SETTINGS)
    assert avoid.record.s == 1 and avoid.record.d2 == SETTINGS.workspace_radius
    assert avoid.record.d1 == pytest.approx(0.183, abs=0.002)


def test_the_planar_reference_file_names_every_task_field():
    names = {field.name for field in fields(LearningSettings)}
    assert 'tool_frame' in names  # the setting the 3-D bags bring
    for task in PLANAR_TASKS.values():
        assert set(task) == {'s', 'a1', 'a2', 'd1', 'd2', 'k', 'n', 'cost', 'iterations'}
