"""Unit tests of node_common's plain parts (no rclpy.init): the teardown bound, the unknown
parameter check, the command line's --params-file check, the hints and the summary line."""

import re
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

from hri_core.node_common import (
    SUMMARY_PREFIX,
    ParameterSpec,
    bounded_teardown,
    decimal_point_hint,
    log_summary,
    rcl_error_line,
    ros_arguments_problem,
    unknown_parameters_problem,
)

HUNG = ("import time\n"
        "from hri_core.node_common import bounded_teardown\n"
        "bounded_teardown(lambda: time.sleep(30), 'node teardown', print, 3, timeout=0.3)\n"
        "print('returned')\n")


def test_a_hung_teardown_step_ends_the_process_with_its_code_and_a_line():
    started = time.monotonic()
    result = subprocess.run([sys.executable, '-c', HUNG], capture_output=True, text=True,
                            timeout=20)
    assert time.monotonic() - started < 10.0
    assert result.returncode == 3, result.stderr
    assert 'node teardown did not return within 0.3 s' in result.stdout
    assert 'returned' not in result.stdout


def test_a_teardown_step_that_returns_leaves_the_process_running():
    said = []
    bounded_teardown(lambda: time.sleep(0.05), 'rclpy shutdown', said.append, 0, timeout=1.0)
    time.sleep(1.2)  # past the timeout: the cancelled timer never fires
    assert said == []


HAND_SIM_NAMES = ['rate_hz', 'profile', 'start', 'end', 'speed', 'period', 'radius']


def test_a_misspelt_parameter_is_named_with_the_nearest_declared_one():
    line = unknown_parameters_problem(['profil'], HAND_SIM_NAMES, 'hand_sim')
    assert line.startswith('unknown parameter profil (did you mean profile?) for hand_sim')
    assert '\n' not in line


def test_several_unknown_parameters_are_named_in_one_line():
    line = unknown_parameters_problem(['sped', 'radus', 'profile'], HAND_SIM_NAMES, 'hand_sim')
    assert 'unknown parameters radus (did you mean radius?), sped (did you mean speed?)' in line


def test_declared_and_rclpys_own_parameters_are_not_unknown():
    given = ['profile', 'use_sim_time', 'start_type_description_service',
             'qos_overrides./target.publisher.depth']
    assert unknown_parameters_problem(given, HAND_SIM_NAMES, 'hand_sim') == ''
    # rclpy's own are never offered as the nearest name of a node's own parameter.
    assert 'did you mean rate_hz?' in unknown_parameters_problem(
        ['use_sim_hz'], HAND_SIM_NAMES + ['use_sim_time'], 'hand_sim')


@pytest.mark.parametrize(('argv', 'reason'), [
    (['hand_sim', '--ros-args', '--params-file', '/no/such.yaml'],
     r'^cannot read --params-file /no/such.yaml: No such file or directory$'),
    (['hand_sim', '--ros-args', '-p', 'speed:=0.1', '--params-file'],
     r'^--params-file needs a file'),
])
def test_a_params_file_that_cannot_be_read_is_one_line(argv, reason):
    assert re.search(reason, ros_arguments_problem(argv))


def test_a_params_file_that_is_not_yaml_is_one_line(tmp_path):
    broken = tmp_path / 'broken.yaml'
    broken.write_text('hand_sim: {ros__parameters: [\n')
    good = tmp_path / 'good.yaml'
    good.write_text('hand_sim:\n  ros__parameters:\n    speed: 0.1\n')
    problem = ros_arguments_problem(['x', '--ros-args', '--params-file', str(broken)])
    assert problem.startswith(f'--params-file {broken} is not YAML: ') and '\n' not in problem
    assert ros_arguments_problem(['x', '--ros-args', '--params-file', str(good)]) == ''
    # After `--` the arguments are the program's own, not ROS's.
    assert ros_arguments_problem(['x', '--ros-args', '--', '--params-file', 'nope']) == ''


def test_rcls_error_loses_its_source_locations():
    error = RuntimeError("failed to initialize rcl: Couldn't parse parameter override rule: "
                         "'-p rate_hz'. Error: Expected lexeme type (22) not found, search "
                         'ended at index 7, at /project/src/rcl/lexer_lookahead.c:238, at '
                         '/project/src/rcl/arguments.c:1215')
    assert rcl_error_line(error) == ("failed to initialize rcl: Couldn't parse parameter "
                                     "override rule: '-p rate_hz'. Error: Expected lexeme type "
                                     '(22) not found, search ended at index 7')


@pytest.mark.parametrize(('spec_type', 'given', 'hint'), [
    (float, 1000, ' (write it with a decimal point, e.g. 1000.0)'),
    (float, None, ' (write it with a decimal point, e.g. 1000.0)'),
    (list, [20, 4], ' (write each value with a decimal point, e.g. [20.0, 4.0])'),
    (list, None, ' (write each value with a decimal point, e.g. [20.0, 4.0])'),
    (str, 3, ''),
])
def test_integers_for_floats_get_the_value_as_it_is_to_be_written(spec_type, given, hint):
    assert decimal_point_hint(ParameterSpec(spec_type, 'x', low=0, high=1), given) == hint


class FakeNode:
    """What log_summary uses of a node: its logger."""

    def __init__(self):
        self.lines = []

    def get_logger(self):
        return SimpleNamespace(info=lambda text: self.lines.append(('info', text)),
                               error=lambda text: self.lines.append(('error', text)))


def test_the_summary_line_is_the_nodes_own_or_how_long_it_ran():
    own = FakeNode()
    own.summary = lambda: '12 tasks'
    log_summary(own, 3.0)
    generic = FakeNode()
    log_summary(generic, 3.04)
    failing = FakeNode()
    failing.summary = lambda: 1 / 0
    log_summary(failing, 1.0)
    assert own.lines == [('info', f'{SUMMARY_PREFIX}12 tasks')]
    assert generic.lines == [('info', f'{SUMMARY_PREFIX}ran 3.0 s')]
    assert failing.lines == [('error', f'{SUMMARY_PREFIX}none (ZeroDivisionError: division by '
                                       'zero)')]
