"""Fixtures of the topic-level tests: a domain per test, processes ended in every case."""

import os

import pytest

from tests.common import NodeProcess, RosProbe, next_domain_id, start_node

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'


@pytest.fixture
def ros_domain() -> int:
    """A ROS_DOMAIN_ID of this test's own."""
    return next_domain_id()


@pytest.fixture
def nodes(ros_domain, tmp_path):
    """`nodes(package, executable, **kw)` starts a node; all are stopped when the test ends."""
    started: list[NodeProcess] = []

    def start(package: str, executable: str, **kwargs) -> NodeProcess:
        kwargs.setdefault('log_dir', tmp_path)
        process = start_node(package, executable, ros_domain, **kwargs)
        started.append(process)
        return process

    try:
        yield start
    finally:
        for process in started:
            process.stop()


@pytest.fixture
def probe(ros_domain):
    """An rclpy node of the test on the test's domain."""
    ros_probe = RosProbe(ros_domain)
    try:
        yield ros_probe
    finally:
        ros_probe.close()
