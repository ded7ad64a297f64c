"""Fixtures of the topic-level tests: a domain per test, processes ended in every case."""

import os

import pytest

from hri_bringup.processes import (
    NodeProcess,
    RosProbe,
    remove_dead_shared_memory,
    start_live_loop,
    start_node,
    stop_all,
)
from tests.common import REPO_ROOT, next_domain_id
from tests.fault_tools import close_intake
from tests.node_forker import NodeForker

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'


def pytest_sessionfinish(session, exitstatus):
    """The shared-memory segments the killed nodes left behind (the fault tests kill about
    a hundred) are removed when the session ends."""
    remove_dead_shared_memory()


@pytest.fixture
def ros_domain() -> int:
    """A ROS_DOMAIN_ID of this test's own."""
    return next_domain_id()


@pytest.fixture(scope='session')
def node_forker():
    """The nodes' parent for this pytest process (tests/node_forker.py): a node forked from
    it starts without Python's start-up, about a second of CPU less each."""
    forker = NodeForker(REPO_ROOT)
    try:
        yield forker
    finally:
        forker.close()


@pytest.fixture
def nodes(ros_domain, tmp_path, node_forker):
    """`nodes(package, executable, **kw)` starts a node (start_node's keywords), forked from
    the node forker, or as `ros2 run` itself with `ros2_run=True`; all are stopped when the
    test ends."""
    started: list[NodeProcess] = []

    def start(package: str, executable: str, ros2_run: bool = False,
              **kwargs) -> NodeProcess:
        kwargs.setdefault('log_dir', tmp_path)
        if not ros2_run:
            kwargs.setdefault('spawn', node_forker.spawn)
        process = start_node(package, executable, ros_domain, **kwargs)
        started.append(process)
        return process

    try:
        yield start
    finally:
        stop_all(started)


@pytest.fixture
def live_loop(ros_domain, tmp_path, node_forker):
    """`live_loop(overrides, **kw)` starts the live loop (hri_bringup.processes.
    start_live_loop) on the test's domain, its nodes forked from the node forker;
    {name: process}; all stopped when the test ends."""
    started: list[NodeProcess] = []

    def start(overrides: dict | None = None, **kwargs) -> dict[str, NodeProcess]:
        kwargs.setdefault('log_dir', tmp_path)
        kwargs.setdefault('spawn', node_forker.spawn)
        processes = start_live_loop(ros_domain, overrides, **kwargs)
        started.extend(processes.values())
        return processes

    try:
        yield start
    finally:
        stop_all(started)


@pytest.fixture
def probe(ros_domain):
    """An rclpy node of the test on the test's domain."""
    ros_probe = RosProbe(ros_domain)
    try:
        yield ros_probe
    finally:
        close_intake(ros_probe)
        ros_probe.close()
