"""Settings every test of the repository shares.

Property tests (hypothesis) run derandomized: the same examples on every run and machine, so a
red run can be repeated, and nothing is stored between runs (no example database).
"""

import os
from pathlib import Path

from hypothesis import settings

PACKAGE_SOURCES = Path(__file__).resolve().parent / 'ros2_ws' / 'src'

settings.register_profile('repository', derandomize=True, database=None, deadline=None,
                          print_blob=True)
settings.load_profile('repository')


def pytest_ignore_collect(collection_path: Path, config) -> bool | None:
    """With HRI_TEST_SCOPE=integration (scripts/test.sh's two topic-level phases) the packages'
    unit tests are not collected: they hold no topic-level test, and collecting them (their
    imports: scipy, hypothesis and all) took each pytest process about 4 s of CPU."""
    if os.environ.get('HRI_TEST_SCOPE') == 'integration' and \
            collection_path.is_relative_to(PACKAGE_SOURCES):
        return True
    return None
