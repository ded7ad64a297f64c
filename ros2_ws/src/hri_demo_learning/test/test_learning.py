"""Unit tests of hri_demo_learning.learning on the committed fixture bags (no ROS process).

Table I's rows the simulated demonstrations reproduce: follow S=1, d1=0, d2=0.041 m; avoid
S=1, d1=0.183 m, d2=2 m (the workspace radius); follow shifted by 0.23 m combined with avoid:
[0.183, 0.271] m. Every bad input raises LearningError with a one-line reason and writes
nothing. The learner's settings are its defaults from config/learner.yaml.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from hri_core.task_file import load_task_file
from hri_demo_learning.bag_io import BagWriter, jazzy_typestore
from hri_demo_learning.learning import (
    REFERENCE_TOLERANCE,
    LearningError,
    LearningSettings,
    check_fixed_reference,
    default_task_name,
    figure_title,
    learn_from_bags,
    learn_task,
)

FIXTURES = Path(__file__).resolve().parents[4] / 'bags' / 'fixtures'
FOLLOW = str(FIXTURES / 'follow')
AVOID = str(FIXTURES / 'avoid')
CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'learner.yaml'
# The fit and reading settings of learn_task, as the learner node gets them by default.
SETTINGS = LearningSettings.from_parameters(
    yaml.safe_load(CONFIG.read_text())['learner']['ros__parameters'])
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
TYPES = jazzy_typestore()
POINT_STAMPED = 'geometry_msgs/msg/PointStamped'


def written_files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


@pytest.fixture(scope='module')
def follow(tmp_path_factory):
    """follow learned once with the defaults (task name from the bag), into its own folder."""
    return learn_task([FOLLOW], None, '', tmp_path_factory.mktemp('follow'), SETTINGS)


def test_follow_gives_table_one_and_writes_its_task_file_and_figure(follow):
    record = follow.record
    assert (record.name, record.s, record.n, record.d1) == ('follow', 1, 3, 0.0)
    assert record.d2 == pytest.approx(0.041, abs=0.002)
    assert record.a1 > 0 and record.a2 > 0 and record.iterations <= 50
    assert (follow.method, follow.converged) == ('trf', True)
    assert 0 < follow.fit_seconds < follow.total_seconds
    assert follow.task_file.name == 'follow.yaml'
    assert load_task_file(follow.task_file) == record
    assert follow.figure == follow.task_file.with_suffix('.png')
    content = follow.figure.read_bytes()
    assert content.startswith(PNG_SIGNATURE) and len(content) > 10_000
    assert written_files(follow.task_file.parent) == ['follow.png', 'follow.yaml']


def test_avoid_is_open_outward_to_the_workspace_radius(tmp_path):
    learned = learn_task([AVOID], [0.0], 'avoid', tmp_path, SETTINGS)
    assert learned.record.s == 1
    assert learned.record.d1 == pytest.approx(0.183, abs=0.002)
    assert learned.record.d2 == SETTINGS.workspace_radius


def test_follow_shifted_and_combined_with_avoid_keeps_a_safe_distance(tmp_path):
    learned = learn_task([Path(FOLLOW), Path(AVOID)], [0.23, 0], 'follow_safe',
                         tmp_path / 'new' / 'folder', SETTINGS)
    assert learned.record.s == 1
    assert learned.record.d1 == pytest.approx(0.183, abs=0.002)
    assert learned.record.d2 == pytest.approx(0.271, abs=0.002)
    assert written_files(tmp_path / 'new' / 'folder') == ['follow_safe.png',
                                                          'follow_safe.yaml']


def test_the_papers_gauss_newton_finds_the_same_region(follow):
    learned = learn_from_bags([FOLLOW], [0.0], 'follow_gn',
                              replace(SETTINGS, method='gauss_newton'))
    assert learned.method == 'gauss_newton'
    assert (learned.record.s, learned.record.d1, learned.record.d2) == \
        (follow.record.s, follow.record.d1, follow.record.d2)


def test_learn_from_bags_writes_nothing_and_matches_learn_task(follow, tmp_path,
                                                               monkeypatch):
    monkeypatch.chdir(tmp_path)
    learned = learn_from_bags([FOLLOW], [0.0], 'follow', SETTINGS)
    assert (learned.task_file, learned.figure) == (None, None)
    assert learned.record == follow.record
    assert written_files(tmp_path) == []


def point_bytes(x: float, y: float) -> bytes:
    msg = TYPES.types[POINT_STAMPED](
        header=TYPES.types['std_msgs/msg/Header'](
            stamp=TYPES.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
            frame_id='base'),
        point=TYPES.types['geometry_msgs/msg/Point'](x=x, y=y, z=0.0))
    return bytes(TYPES.serialize_cdr(msg, POINT_STAMPED))


def bag_with_a_moving_reference(bag: Path) -> str:
    """3 s at 0.1 m/s then 1 s at rest (1 kHz); x_r jumps by 5 cm after 1 s of motion."""
    t = np.arange(0.0, 3.0, 1e-3)
    path = np.column_stack([0.35 + 0.03 * t, 0.30 - 0.08 * t])
    positions = np.vstack([path, np.repeat(path[-1:], 1000, axis=0)])
    with BagWriter(bag) as writer:
        ee = writer.add_topic('/ee_position', POINT_STAMPED)
        reference = writer.add_topic('/demo/reference', POINT_STAMPED)
        writer.write(reference, 10**18, point_bytes(0.45, 0.05))
        for index, (x, y) in enumerate(positions):
            stamp = 10**18 + (index + 1) * 10**6
            if index == 1000:
                writer.write(reference, stamp, point_bytes(0.50, 0.05))
            writer.write(ee, stamp, point_bytes(x, y))
    return str(bag)


@pytest.mark.parametrize(('bags', 'shifts', 'task_name', 'reason'), [
    ([], None, 'task', 'parameter bags is required: one or more bag folders'),
    ([FOLLOW, ''], None, 'task', 'parameter bags holds an empty path'),
    ([FOLLOW, AVOID], [0.23], 'task',
     r'parameter shifts has 1 values for 2 bags: give one shift \(m\) per bag'),
    ([FOLLOW], [float('nan')], 'task', 'parameter shifts must be finite'),
    ([FOLLOW], ['0.1'], 'task', 'parameter shifts must be an array of numbers'),
    ([FOLLOW], [True], 'task', 'parameter shifts must be an array of numbers'),
    ([FOLLOW], '0', 'task', 'parameter shifts must be an array of numbers'),
    ([FOLLOW], None, '../escape', "task_name '../escape' is not a safe file name"),
    ([FOLLOW], None, '-x', 'is not a safe file name'),
    (['/no/such/bag'], None, 'task', 'bag path does not exist: /no/such/bag'),
    ([str(FIXTURES)], None, 'task', 'is not a bag'),
    ([FOLLOW], [-1.0], 'task', r"cannot learn 'task' from .*moves distances below 0"),
], ids=['no-bags', 'empty-path', 'shifts-length', 'shifts-nan', 'shifts-text',
        'shifts-bool', 'shifts-string', 'name-escape', 'name-dash', 'missing-bag',
        'not-a-bag', 'negative-distance'])
def test_bad_input_raises_one_line_and_writes_nothing(tmp_path, bags, shifts, task_name,
                                                      reason):
    with pytest.raises(LearningError, match=reason) as error:
        learn_task(bags, shifts, task_name, tmp_path / 'tasks', SETTINGS)
    assert '\n' not in str(error.value)
    assert written_files(tmp_path / 'tasks') == []


@pytest.mark.parametrize(('change', 'reason'), [
    ({'method': 'newton'}, r"^parameter method must be one of trf, gauss_newton, got 'newton'$"),
    ({'n': 2}, r'^parameter n must be an integer in \[3, 15\], got 2$'),
    ({'n': 3.0}, r'^parameter n must be an integer in \[3, 15\], got 3\.0$'),
    ({'max_iterations': True}, r'^parameter max_iterations must be an integer'),
    ({'tolerance': 0.0}, r'^parameter tolerance must be a number in \[1e-15, 0\.01\]'),
    ({'workspace_radius': float('nan')}, r'^parameter workspace_radius must be a number in'),
    ({'l1': float('inf')}, r'^parameter l1 must be a number in \[0\.01, 10\], got inf$'),
    ({'stationary_speed': '0.004'}, r"^parameter stationary_speed must be a number .*'0\.004'"),
    ({'rest_fraction': 0.6}, r'^parameter rest_fraction must be a number in \[0, 0\.5\]'),
    ({'max_cost': -1.0}, r'^parameter max_cost must be a number in \[1e-06, 2\], got -1\.0$'),
    ({'max_task_speed': 20.0}, r'^parameter max_task_speed must be a number in \[0\.001, 10\]'),
    ({'combine': 1}, r'^parameter combine must be true or false, got 1$'),
], ids=lambda value: next(iter(value)) if isinstance(value, dict) else None)
def test_settings_out_of_range_are_refused_in_one_line(change, reason):
    with pytest.raises(LearningError, match=reason):
        replace(SETTINGS, **change)


def test_settings_take_the_parameters_they_name_and_need_the_required_ones():
    values = yaml.safe_load(CONFIG.read_text())['learner']['ros__parameters']
    assert LearningSettings.from_parameters({**values, 'bags': ['x']}) == SETTINGS
    assert SETTINGS.reach == values['l1'] + values['l2']
    assert (SETTINGS.fit_options.method, SETTINGS.fit_options.tolerance,
            SETTINGS.fit_options.max_iterations) == \
        (values['method'], values['tolerance'], values['max_iterations'])
    with pytest.raises(LearningError, match=r'^settings l1, l2 are required$'):
        LearningSettings.from_parameters({k: v for k, v in values.items()
                                          if k not in ('l1', 'l2')})


def test_a_reference_moved_during_the_demonstration_is_refused(tmp_path):
    bag = bag_with_a_moving_reference(tmp_path / 'moving_reference')
    with pytest.raises(LearningError, match=r'the reference x_r moved by 0\.050 m during'):
        learn_task([bag], None, '', tmp_path / 'tasks', SETTINGS)
    assert written_files(tmp_path / 'tasks') == []


def test_an_output_it_cannot_write_is_refused(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('not a folder')
    with pytest.raises(LearningError, match=f'cannot write the task into {blocker}/tasks: '):
        learn_task([FOLLOW], None, '', blocker / 'tasks', SETTINGS)


def test_check_fixed_reference_allows_wander_within_the_tolerance():
    x_r = np.array([0.45, 0.05])
    check_fixed_reference(np.empty((0, 2)), x_r, 'bag')
    check_fixed_reference(x_r + [[0.0, 0.0], [0.9 * REFERENCE_TOLERANCE, 0.0]], x_r, 'bag')
    with pytest.raises(LearningError, match=r'^bag b: the reference x_r moved by 0\.002 m'):
        check_fixed_reference(x_r + [[0.0, 0.0], [0.0, 2 * REFERENCE_TOLERANCE]], x_r, 'b')


@pytest.mark.parametrize(('bags', 'name'), [
    (['bags/follow'], 'follow'),
    (['bags/follow/'], 'follow'),
    (['recordings/demo.mcap'], 'demo'),
    (['bags/follow', 'bags/avoid'], 'follow_avoid'),
    (['bags/my demo.v2'], 'my_demo_v2'),
    (['bags/--x'], 'x'),
    (['b' * 80], 'b' * 64),
    (['/'], 'task'),
])
def test_default_task_name_is_a_safe_name_from_the_bag_names(bags, name):
    assert default_task_name(bags) == name


def test_figure_title_names_the_bags_when_they_differ_from_the_task():
    assert figure_title('follow', ['bags/follow/']) == 'follow'
    assert figure_title('follow_safe', ['bags/follow', 'bags/avoid']) == \
        'follow_safe (follow, avoid)'
