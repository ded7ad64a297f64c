"""Each node's config/<node>.yaml gives a valid value to every parameter the node declares.

That file is the one source of a node's defaults (node_common.run_node reads it first), so a
value missing from it, of the wrong type, out of its declared range, or a key the node does not
declare (ROS would ignore it without a word) is caught here rather than at a robot.
Imports the node modules for their parameter tables; rclpy is imported, never initialised.
"""

import dataclasses
import math

import pytest

from hri_adaptive_controller import controller_node, event_detector_node, event_manager_node
from hri_adaptive_controller.arm_law import default_gains
from hri_bringup import live_view_node
from hri_core import topics
from hri_core.node_common import PARAMETER_TYPES, load_defaults
from hri_core.robot_model import robot_model
from hri_demo_learning import learner_node, recorder_node
from scara_sim import arm_sim_node, demonstrator_node, hand_sim_node, scara_sim_node

TABLE_NODES = [
    ('scara_sim', scara_sim_node),
    ('scara_sim', arm_sim_node),
    ('scara_sim', hand_sim_node),
    ('scara_sim', demonstrator_node),
    ('hri_adaptive_controller', controller_node),
    ('hri_adaptive_controller', event_manager_node),
    ('hri_adaptive_controller', event_detector_node),
    ('hri_demo_learning', learner_node),
    ('hri_demo_learning', recorder_node),
    ('hri_bringup', live_view_node),
]


def value_problem(spec, value) -> str:
    """Why `value` does not fit `spec` ('' if it does)."""
    if spec.type in (list, list[str]):
        item = float if spec.type is list else str
        if not (isinstance(value, list) and all(isinstance(v, item) for v in value)):
            return f'expected a list of {item.__name__}, got {value!r}'
    elif type(value) is not spec.type:
        return f'expected {spec.type.__name__}, got {value!r}'
    if spec.type in (int, float) and not spec.low <= value <= spec.high:
        return f'{value} outside [{spec.low}, {spec.high}]'
    return spec.problem(value)


@pytest.mark.parametrize(('package', 'module'), TABLE_NODES,
                         ids=[module.NODE_NAME for _, module in TABLE_NODES])
def test_yaml_holds_a_valid_value_for_every_declared_parameter(package, module):
    """Every parameter but those the user must give (required) or may leave unset."""
    values = load_defaults(package, module.NODE_NAME)
    with_default = {name: spec for name, spec in module.PARAMETERS.items()
                    if not (spec.required or spec.optional)}
    assert set(values) == set(with_default)
    for name, spec in with_default.items():
        assert spec.type in PARAMETER_TYPES, name
        assert spec.description, name
        assert value_problem(spec, values[name]) == '', name


def test_value_problem_catches_what_ros_would_refuse():
    spec = controller_node.PARAMETERS['kp']
    assert value_problem(spec, 10) == 'expected float, got 10'
    assert 'outside' in value_problem(spec, -1.0)
    mode = controller_node.PARAMETERS['mode']
    assert 'is not one of' in value_problem(mode, 'torque')
    limits = scara_sim_node.PARAMETERS['joint_lower_limits']
    assert 'expected 2 values' in value_problem(limits, [1.0])
    assert 'finite' in value_problem(controller_node.PARAMETERS['ks'], [1.0, math.nan])
    assert 'list of str' in value_problem(recorder_node.PARAMETERS['topics'], ['/a', 1.0])


def test_the_recorder_records_the_demonstration_topics_by_default():
    defaults = load_defaults('hri_demo_learning', 'recorder')
    assert defaults['topics'] == [topic.name for topic in topics.DEMONSTRATION_TOPICS]


def test_controller_yaml_runs_the_gains_the_closed_loop_tests_check():
    """The unit tests of the pure closed loop use each robot's own gains
    (arm_law.default_gains); the node must run them."""
    values = load_defaults('hri_adaptive_controller', 'controller')
    for robot in ('scara', 'panda'):
        model = robot_model(robot)
        robot_gains = default_gains(model)
        assert controller_node.gains_from({**values, 'robot': robot}, model) == \
            dataclasses.replace(robot_gains, limit_band=values['joint_limit_band'],
                                body=dataclasses.replace(robot_gains.body,
                                                         clearance=values['clearance']))
