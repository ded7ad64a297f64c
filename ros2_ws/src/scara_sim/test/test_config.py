"""The shipped config/*.yaml hold exactly the defaults each node declares.

Imports the node modules for their parameter tables (rclpy is imported, never initialised).
"""

import dataclasses
from pathlib import Path

import pytest
import yaml

pytest.importorskip('rclpy')

from hri_core.dynamics import ScaraParameters  # noqa: E402
from scara_sim import demonstrator_node, hand_sim_node, scara_sim_node  # noqa: E402
from scara_sim.profiles import HandProfile, PushSettings  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / 'config'


@pytest.mark.parametrize('module', [scara_sim_node, hand_sim_node, demonstrator_node])
def test_config_file_matches_the_declared_defaults(module):
    document = yaml.safe_load((CONFIG / f'{module.NODE_NAME}.yaml').read_text())
    assert list(document) == [module.NODE_NAME]
    values = document[module.NODE_NAME]['ros__parameters']
    assert set(values) == set(module.PARAMETERS)
    for name, spec in module.PARAMETERS.items():
        assert type(values[name]) is type(spec.default), name
        if isinstance(spec.default, str):
            assert values[name] == spec.default, name
        else:
            assert values[name] == pytest.approx(spec.default, rel=1e-12), name


def test_arm_defaults_are_the_dynamics_defaults():
    defaults = dataclasses.asdict(ScaraParameters())
    declared = {name: spec.default for name, spec in scara_sim_node.ARM_PARAMETERS.items()}
    assert declared == defaults


def test_push_and_hand_defaults_are_the_profiles_defaults():
    push = {name: spec.default for name, spec in demonstrator_node.PUSH_SETTINGS.items()}
    assert push == dataclasses.asdict(PushSettings())
    hand = HandProfile()
    table = hand_sim_node.PARAMETERS
    assert table['profile'].default == hand.name
    assert tuple(table['start'].default) == hand.start
    assert tuple(table['end'].default) == hand.end
    for name in ('speed', 'period', 'radius', 'start_delay'):
        assert table[name].default == getattr(hand, name)


@pytest.mark.parametrize('module', [scara_sim_node, hand_sim_node, demonstrator_node])
def test_every_number_has_a_range_containing_its_default(module):
    for name, spec in module.PARAMETERS.items():
        assert spec.description, name
        if isinstance(spec.default, (int, float)) and not isinstance(spec.default, bool):
            assert spec.low <= spec.default <= spec.high, name
