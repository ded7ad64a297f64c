"""docs/parameters.md is what scripts/parameters_doc.py writes from the nodes' tables and YAML.

Imports the node modules for their parameter tables; rclpy is imported, never initialised.
"""

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / 'scripts' / 'parameters_doc.py'


def load_generator():
    spec = importlib.util.spec_from_file_location('parameters_doc', SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_parameters_reference_is_up_to_date():
    generator = load_generator()
    assert generator.DOC.read_text() == generator.document(), (
        'docs/parameters.md is out of date: run python scripts/parameters_doc.py')


def test_every_declared_parameter_is_in_the_reference():
    generator = load_generator()
    text = generator.DOC.read_text()
    for _, module in generator.NODES:
        for name in module.PARAMETERS:
            assert f'| `{name}` |' in text, (module.NODE_NAME, name)
