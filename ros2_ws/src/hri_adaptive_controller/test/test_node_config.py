"""The shipped config/*.yaml hold exactly the defaults each node declares.

Imports the node modules for their parameter tables (rclpy is imported, never initialised).
"""

from pathlib import Path

import pytest
import yaml

pytest.importorskip('rclpy')

from hri_adaptive_controller import controller_node, event_manager_node  # noqa: E402
from hri_adaptive_controller.adaptive_law import DEFAULT_GAINS  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / 'config'


@pytest.mark.parametrize('module', [controller_node, event_manager_node])
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


def test_controller_defaults_are_the_library_gains():
    assert controller_node.gains_from(
        {name: spec.default for name, spec in controller_node.PARAMETERS.items()}
    ) == DEFAULT_GAINS
