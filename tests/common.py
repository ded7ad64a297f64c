"""What only the tests need: a ROS_DOMAIN_ID per test, the repository's paths.

Starting nodes, waiting for them and the rclpy probe are in hri_bringup.processes, which the
tests import directly.
"""

import itertools
import os
import time
from pathlib import Path

from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter

from hri_bringup.processes import paper_tasks_dir, wait_for

REPO_ROOT = Path(__file__).resolve().parents[1]
# Table I's task files, where the live loop's event_manager loads them from.
PAPER_TASKS = paper_tasks_dir()
_domain_counter = itertools.count()
DOMAIN_ID_FIRST, DOMAIN_ID_COUNT = 100, 130
# The xdist controller's PID is the workers' parent: one offset per session.
_session_offset = (os.getppid() if 'PYTEST_XDIST_WORKER' in os.environ else os.getpid()) * 7


def next_domain_id() -> int:
    """A ROS_DOMAIN_ID in 100..229 of this test alone.

    Under pytest-xdist, worker k of n takes the IDs 100 + k + n j, so workers never share one;
    the offset from the session's PID makes two sessions at once unlikely to meet.
    """
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    worker = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw'))
    slots = DOMAIN_ID_COUNT // workers
    slot = (_session_offset + next(_domain_counter)) % slots
    return DOMAIN_ID_FIRST + slot * workers + worker


# s: how long one handshake request of `wait_for_service` waits for its answer.
HANDSHAKE_WAIT = 1.0


def wait_for_service(client, timeout: float) -> bool:
    """True once `client`'s service answers it, within `timeout` s. rclpy's wait_for_service
    sees only the server's request reader: a response sent before the server has found the
    client's response reader is dropped (the node logs `failed to send response (timeout)`;
    seen with a node called within milliseconds of its start, beside phase 1). So an empty
    request of the service's type (a parameter service's no-op: no parameter set or read) is
    sent until one is answered."""
    deadline = time.monotonic() + timeout
    if not client.wait_for_service(timeout_sec=timeout):
        return False
    while (left := deadline - time.monotonic()) > 0.0:
        future = client.call_async(client.srv_type.Request())
        if wait_for(future.done, min(HANDSHAKE_WAIT, left)):
            return True
        client.remove_pending_request(future)
    return False


def call_service(client, request, timeout: float = 15.0):
    """The response of `client` (a probe's service client) to `request`; fails the test if
    none comes within `timeout` s. 15 s: a node's service may do seconds of work (hand_sim
    reads a take twice and searches its placement, 2 s alone; twice that and more beside
    phase 1's three workers); the deadline is for a node that never answers."""
    future = client.call_async(request)
    assert wait_for(future.done, timeout), client.srv_name
    return future.result()


def set_parameter(client, name: str, value):
    """Set one parameter through a node's `set_parameters` service `client`; its
    SetParametersResult."""
    request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return call_service(client, request).results[0]
