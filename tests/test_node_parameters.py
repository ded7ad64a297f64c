"""Topic-level tests of how a node is configured: its YAML, a user's copy, and remapping.

A node's defaults are its package's config/<node>.yaml; a copy passed with --params-file and
`-p` win over them, also for a renamed node; `--ros-args -r` moves any of its topics. What a
user gets wrong is refused at start with one line and exit 1, for every executable: a
parameter the node does not have (named with the nearest one it has), a stale key in a
params file, a params file that is missing, integers where floats are wanted.
"""

from pathlib import Path

import pytest
import yaml
from geometry_msgs.msg import PointStamped

from hri_bringup.processes import wait_for
from hri_core.node_common import defaults_file
from hri_core.topics import TARGET

pytestmark = pytest.mark.integration


def edited_copy(package: str, node_name: str, folder: Path, **changes) -> Path:
    """A copy of the node's shipped YAML in `folder` with `changes` applied."""
    document = yaml.safe_load(defaults_file(package, node_name).read_text())
    document[node_name]['ros__parameters'].update(changes)
    path = folder / f'my_{node_name}.yaml'
    path.write_text(yaml.safe_dump(document))
    return path


def held_point(messages: list[PointStamped]) -> list[float]:
    return [round(messages[-1].point.x, 6), round(messages[-1].point.y, 6)]


def test_a_node_runs_with_the_values_of_an_edited_copy_of_its_yaml(nodes, probe, tmp_path):
    targets = probe.collect(TARGET.name, PointStamped, TARGET.qos)
    my_yaml = edited_copy('scara_sim', 'hand_sim', tmp_path, start=[0.2, -0.1])
    hand = nodes('scara_sim', 'hand_sim', params_files=[my_yaml])
    assert wait_for(lambda: len(targets) > 5, 15.0), hand.log()
    assert held_point(targets) == [0.2, -0.1]
    assert 'hand profile hold (at [0.2, -0.1]' in hand.log()


def test_without_a_params_file_a_node_runs_with_its_shipped_defaults(nodes, probe):
    targets = probe.collect(TARGET.name, PointStamped, TARGET.qos)
    shipped = yaml.safe_load(defaults_file('scara_sim', 'hand_sim').read_text())
    hand = nodes('scara_sim', 'hand_sim')
    assert wait_for(lambda: len(targets) > 5, 15.0), hand.log()
    assert held_point(targets) == shipped['hand_sim']['ros__parameters']['start']


def test_a_parameter_given_with_p_wins_over_the_params_file(nodes, probe, tmp_path):
    targets = probe.collect(TARGET.name, PointStamped, TARGET.qos)
    my_yaml = edited_copy('scara_sim', 'hand_sim', tmp_path, start=[0.2, -0.1])
    hand = nodes('scara_sim', 'hand_sim', params={'start': [0.25, 0.15]},
                 params_files=[my_yaml])
    assert wait_for(lambda: len(targets) > 5, 15.0), hand.log()
    assert held_point(targets) == [0.25, 0.15]


def test_a_renamed_node_keeps_its_defaults_and_takes_its_own_section(nodes, probe, tmp_path):
    targets = probe.collect(TARGET.name, PointStamped, TARGET.qos)
    my_yaml = tmp_path / 'left_hand.yaml'
    my_yaml.write_text(yaml.safe_dump({'left_hand': {'ros__parameters': {'rate_hz': 20.0}}}))
    hand = nodes('scara_sim', 'hand_sim', remaps={'__node': 'left_hand'},
                 params_files=[my_yaml])
    assert wait_for(lambda: len(targets) > 5, 15.0), hand.log()
    shipped = yaml.safe_load(defaults_file('scara_sim', 'hand_sim').read_text())
    assert held_point(targets) == shipped['hand_sim']['ros__parameters']['start']
    assert '[left_hand]: hand profile hold' in hand.log()
    assert 'at 20 Hz' in hand.log()


def test_a_wrong_value_in_the_params_file_is_refused_in_one_line(nodes, tmp_path):
    my_yaml = edited_copy('scara_sim', 'hand_sim', tmp_path, rate_hz=-3.0)
    hand = nodes('scara_sim', 'hand_sim', params_files=[my_yaml])
    assert hand.wait(15.0) == 1, hand.log()
    assert 'bad parameter rate_hz' in hand.log()
    assert 'Traceback' not in hand.log()


def test_a_topic_is_remapped_with_ros_args(nodes, probe):
    remapped = probe.collect('/person/hand', PointStamped, TARGET.qos)
    default = probe.collect(TARGET.name, PointStamped, TARGET.qos)
    hand = nodes('scara_sim', 'hand_sim', remaps={TARGET.name: '/person/hand'})
    assert wait_for(lambda: len(remapped) > 5, 15.0), hand.log()
    assert default == []
    assert 'on /person/hand' in hand.log()


# Every executable of the suite, each with a misspelling of one of its parameters and the
# parameter meant: (package, executable, misspelt, meant).
MISSPELT_PARAMETERS = [
    ('scara_sim', 'scara_sim', 'rate_hx', 'rate_hz'),
    ('scara_sim', 'arm_sim', 'robt', 'robot'),
    ('scara_sim', 'hand_sim', 'profil', 'profile'),
    ('scara_sim', 'demonstrator', 'mod', 'mode'),
    ('hri_demo_learning', 'recorder', 'topic', 'topics'),
    ('hri_demo_learning', 'learner', 'task_nam', 'task_name'),
    ('hri_adaptive_controller', 'event_manager', 'initial_tsk', 'initial_task'),
    ('hri_adaptive_controller', 'controller', 'efort_limit', 'effort_limit'),
    ('hri_adaptive_controller', 'event_detector', 'rule', 'rules'),
    ('hri_bringup', 'system', 'confg', 'config'),
    ('hri_bringup', 'live_view', 'prt', 'port'),
]
START_TIMEOUT = 40.0  # s for a refused node to exit (imports on a loaded machine)


def error_lines(log: str) -> list[str]:
    return [line for line in log.splitlines() if 'ERROR' in line or 'FATAL' in line]


def assert_refused_in_one_line(process, *fragments: str) -> str:
    """The process exited 1 with no traceback and exactly one error line holding every
    fragment; that line."""
    code = process.wait(START_TIMEOUT)
    log = process.log()
    assert code == 1, (code, log)
    assert 'Traceback' not in log, log
    errors = error_lines(log)
    assert len(errors) == 1, log
    for fragment in fragments:
        assert fragment in errors[0], (fragment, errors[0])
    return errors[0]


@pytest.mark.parametrize(('package', 'executable', 'misspelt', 'meant'), MISSPELT_PARAMETERS,
                         ids=[row[1] for row in MISSPELT_PARAMETERS])
def test_a_misspelt_parameter_is_refused_naming_the_nearest(nodes, package, executable,
                                                             misspelt, meant):
    # The value is valid for the parameter meant: only the name is wrong.
    value = {'topics': ['/joint_states'], 'port': 18765}.get(meant, 1.5)
    process = nodes(package, executable, params={misspelt: value})
    line = assert_refused_in_one_line(process, f'unknown parameter {misspelt} '
                                               f'(did you mean {meant}?)')
    print(f'{executable}: {line.split("]: ", 1)[-1]}')


def test_a_stale_key_in_a_params_file_is_refused_and_rclpys_own_are_not(nodes, tmp_path):
    # use_sim_time is rclpy's, declared on every node: given with -p it is no stranger.
    stale = edited_copy('scara_sim', 'hand_sim', tmp_path, hand_speed=0.2)
    refused = nodes('scara_sim', 'hand_sim', params_files=[stale])
    accepted = nodes('scara_sim', 'hand_sim', params={'use_sim_time': False})
    assert_refused_in_one_line(refused, 'unknown parameter hand_speed (did you mean ')
    assert accepted.wait_for_line('hand profile', START_TIMEOUT), accepted.log()
    assert error_lines(accepted.log()) == []


def test_a_missing_params_file_is_one_line(nodes, tmp_path):
    missing = tmp_path / 'no_such.yaml'
    not_yaml = tmp_path / 'broken.yaml'
    not_yaml.write_text('hand_sim: {ros__parameters: [\n')
    for path, reason in ((missing, 'No such file or directory'), (not_yaml, 'is not YAML')):
        process = nodes('scara_sim', 'hand_sim', params_files=[path])
        assert_refused_in_one_line(process, f'--params-file {path}', reason)


def test_integers_where_floats_are_wanted_get_the_decimal_point_hint(nodes):
    array = nodes('scara_sim', 'hand_sim', params={'start': [1, 2]})
    scalar = nodes('scara_sim', 'hand_sim', params={'speed': 1})
    assert_refused_in_one_line(array, 'bad parameter start',
                               'write each value with a decimal point, e.g. [1.0, 2.0]')
    assert_refused_in_one_line(scalar, 'bad parameter speed',
                               'write it with a decimal point, e.g. 1.0')
