"""Settings every test of the repository shares: the tiers, and hypothesis's profile.

Tiers (markers, pytest.ini): `pure` (no ROS process: the packages' unit tests and the plain
ones in tests/), `topic` (starts ROS processes; `integration` is its older name and stays an
alias, so either selects the same tests), `exclusive` (a 1 kHz loop with timing checks, run
one at a time; always `topic` too) and `slow` (not in the default run). A test file marks only
what it starts (`integration` or `topic`) and `exclusive` / `slow`; the hook below adds the
rest, so a new test cannot fall outside every tier of scripts/test.sh.

Property tests (hypothesis) run derandomized: the same examples on every run and machine, so a
red run can be repeated, and nothing is stored between runs (no example database).
"""

import os
from pathlib import Path

import pytest

PACKAGE_SOURCES = Path(__file__).resolve().parent / 'ros2_ws' / 'src'
# The markers that say a test starts ROS processes (one implies the others).
TOPIC_MARKERS = ('topic', 'integration', 'exclusive')
# scripts/test.sh's topic-level phases (HRI_TEST_SCOPE, pytest_ignore_collect below).
TOPIC_SCOPE = os.environ.get('HRI_TEST_SCOPE') in ('topic', 'integration')

# Only where property tests are collected: hypothesis's import took 1.2 s of CPU in each of
# the topic-level phases' pytest processes, which hold none.
if not TOPIC_SCOPE:
    from hypothesis import settings

    settings.register_profile('repository', derandomize=True, database=None, deadline=None,
                              print_blob=True)
    settings.load_profile('repository')


def pytest_configure(config) -> None:
    """A pytest-xdist worker leads a session of its own. Linux's autogroup scheduling
    (kernel.sched_autogroup_enabled, on here) shares the CPU between sessions before
    processes, and every node a test starts has its own (hri_bringup.processes starts them
    with start_new_session): the workers, in scripts/test.sh's session, got one share among
    a dozen, and their publishing threads stalled (a stand-in arm's 200 Hz joint states
    arrived 6 times in 0.5 s). Not in a run that scripts/test.sh puts in the background
    (HRI_TEST_BACKGROUND=1): its workers stay in its low-priority session."""
    if hasattr(config, 'workerinput') and os.environ.get('HRI_TEST_BACKGROUND') != '1':
        try:
            os.setsid()
        except OSError:  # already a session or group leader: nothing to gain
            pass


def pytest_ignore_collect(collection_path: Path, config) -> bool | None:
    """With HRI_TEST_SCOPE=topic (or its older value integration: scripts/test.sh's two
    topic-level phases) the packages' unit tests are not collected: they hold no topic-level
    test, and collecting them (their imports: scipy, hypothesis and all) took each pytest
    process about 4 s of CPU."""
    if TOPIC_SCOPE and collection_path.is_relative_to(PACKAGE_SOURCES):
        return True
    return None


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Every test gets its tier: `topic` and `integration` both when it has either or is
    `exclusive`, else `pure`. tryfirst: before pytest's own hook deselects by `-m`."""
    for item in items:
        if any(item.get_closest_marker(name) for name in TOPIC_MARKERS):
            for name in ('topic', 'integration'):
                if item.get_closest_marker(name) is None:
                    item.add_marker(name)
        else:
            item.add_marker('pure')
    # The long ones first (stable): pytest-xdist hands each worker a contiguous share of the
    # list, so a long test at the front starts at once instead of running on alone at the end.
    items.sort(key=lambda item: item.get_closest_marker('first') is None)
