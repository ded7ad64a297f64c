"""Unit tests of the system YAML (hri_bringup.system): loading, checks, substitutions.

No node is started; tests/test_system.py runs the system node itself.
"""

from pathlib import Path

import pytest
import yaml

pytest.importorskip('rclpy')

from ament_index_python.packages import get_package_share_directory  # noqa: E402

from hri_bringup.processes import SYSTEM_NODES  # noqa: E402
from hri_bringup.system import (  # noqa: E402
    PARAMETERS,
    SETTINGS,
    load_config,
    system_section,
    system_settings,
    write_params_file,
)
from hri_core.node_common import StartupError  # noqa: E402

SHIPPED = Path(__file__).resolve().parents[1] / 'config' / 'system.yaml'


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / 'system.yaml'
    path.write_text(text)
    return path


def shipped_defaults() -> dict:
    return system_section(load_config(SHIPPED))


def test_the_shipped_config_holds_every_default_of_the_system_node():
    settings = shipped_defaults()
    assert set(settings) == set(PARAMETERS) | set(SETTINGS)
    assert settings['nodes'] == list(SYSTEM_NODES)
    assert settings['config'] == str(
        Path(get_package_share_directory('hri_bringup')) / 'config' / 'system.yaml')


def test_the_shipped_config_loads_table_one_with_follow_and_a_hand_that_comes_and_goes():
    sections = load_config(SHIPPED)
    manager = sections['event_manager']['ros__parameters']
    assert Path(manager['tasks_dir'], 'follow.yaml').is_file()
    assert manager['initial_task'] == 'follow'
    hand = sections['hand_sim']['ros__parameters']
    assert hand['profile'] == 'waypoints' and hand['repeat'] and hand['unseen_time'] > 1.0
    assert system_settings(shipped_defaults(), sections, 'config') == {
        'nodes': list(SYSTEM_NODES), 'log_dir': '', 'echo_output': True, 'stop_timeout': 5.0}


def test_find_pkg_share_is_replaced_in_strings_and_lists(tmp_path):
    path = write(tmp_path, 'hand_sim:\n  ros__parameters:\n    profile: hold\n'
                           'recorder:\n  ros__parameters:\n'
                           '    topics: ["$(find-pkg-share scara_sim)/x", /joint_states]\n'
                           '/**:\n  ros__parameters:\n    use_sim_time: false\n')
    sections = load_config(path)
    share = get_package_share_directory('scara_sim')
    assert sections['recorder']['ros__parameters']['topics'] == [f'{share}/x', '/joint_states']
    assert sections['/**']['ros__parameters'] == {'use_sim_time': False}


def test_a_file_may_leave_out_the_system_section(tmp_path):
    path = write(tmp_path, 'hand_sim:\n  ros__parameters:\n    profile: hold\n')
    settings = system_settings(shipped_defaults(), load_config(path), 'config')
    assert settings['nodes'] == list(SYSTEM_NODES)


def test_the_system_section_overrides_the_shipped_defaults(tmp_path):
    path = write(tmp_path, 'system:\n  ros__parameters:\n'
                           '    nodes: [hand_sim, recorder]\n    stop_timeout: 2\n')
    settings = system_settings(shipped_defaults(), load_config(path), 'config')
    assert settings['nodes'] == ['hand_sim', 'recorder']
    assert settings['stop_timeout'] == 2.0 and isinstance(settings['stop_timeout'], float)
    assert settings['echo_output'] is True


@pytest.mark.parametrize('text, reason', [
    ('system: [unclosed\n', 'not valid YAML'),
    ('', 'found none'),
    ('- a\n- b\n', 'found none'),
    ('hand_simm:\n  ros__parameters:\n    profile: hold\n', "section 'hand_simm' is no node"),
    ('hand_sim:\n  profile: hold\n', 'must hold exactly `ros__parameters:`'),
    ('hand_sim:\n  ros__parameters: 3\n', 'must hold exactly `ros__parameters:`'),
    ('event_manager:\n  ros__parameters:\n    tasks_dir: $(find-pkg-share no_such_pkg)/t\n',
     "no installed package 'no_such_pkg'"),
])
def test_a_bad_file_is_one_line_naming_the_problem(tmp_path, text, reason):
    path = write(tmp_path, text)
    with pytest.raises(StartupError) as error:
        load_config(path)
    assert reason in str(error.value) and str(path) in str(error.value)
    assert '\n' not in str(error.value)


def test_a_missing_file_is_one_line(tmp_path):
    with pytest.raises(StartupError, match='no such file'):
        load_config(tmp_path / 'missing.yaml')


@pytest.mark.parametrize('settings, reason', [
    ('nodes: [scara_sim, dance]', 'unknown node(s) dance'),
    ('nodes: []', 'nothing to start'),
    ('nodes: scara_sim', 'must be a list of node names'),
    ('stop_timeout: fast', 'must be a positive number'),
    ('stop_timeout: 0', 'must be a positive number'),
    ('echo_output: 1', 'must be true or false'),
    ('nodez: [scara_sim]', "unknown parameter 'nodez'"),
])
def test_bad_system_settings_are_one_line(tmp_path, settings, reason):
    path = write(tmp_path, f'system:\n  ros__parameters:\n    {settings}\n')
    with pytest.raises(StartupError) as error:
        system_settings(shipped_defaults(), load_config(path), f'config {path}')
    assert reason in str(error.value) and str(path) in str(error.value)


def test_the_childrens_file_is_the_config_with_substitutions_done(tmp_path):
    sections = load_config(SHIPPED)
    written = write_params_file(sections, tmp_path / 'system_params.yaml')
    text = written.read_text()
    assert '$(find-pkg-share' not in text
    assert yaml.safe_load(text) == sections
