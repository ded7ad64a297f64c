"""Topic-level: the controller checks its joint limits against scara_sim's at start-up.

The controller asks scara_sim's parameter service for joint_lower_limits and
joint_upper_limits once it is up: equal, one info line; different, one error line naming
both, and the controller keeps the range both allow.
"""

import pytest

pytestmark = pytest.mark.integration

NODES = ['scara_sim', 'controller']


def test_equal_limits_are_confirmed(live_loop):
    loop = live_loop(nodes=NODES)
    assert loop['controller'].wait_for_line("joint limits agree with scara_sim's", 20.0), \
        loop['controller'].log()


def test_a_narrower_sim_is_named_and_its_range_used(live_loop):
    loop = live_loop({'scara_sim': {'joint_upper_limits': [2.0, 2.46]}}, nodes=NODES)
    assert loop['controller'].wait_for_line('using the range both allow', 20.0), \
        loop['controller'].log()
    log = loop['controller'].log()
    assert "differ from scara_sim's" in log and '[2.0, 2.46]' in log, log
