"""Topic-level tests of how a node is configured: its YAML, a user's copy, and remapping.

A node's defaults are its package's config/<node>.yaml; a copy passed with --params-file and
`-p` win over them, also for a renamed node; `--ros-args -r` moves any of its topics.
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
