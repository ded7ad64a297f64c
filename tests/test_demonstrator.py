"""Topic-level tests of the demonstrator pushing the simulated arm (scara_sim)."""

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy

from hri_bringup.processes import wait_for

pytestmark = pytest.mark.integration

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
START_TIMEOUT = 15.0
FAST = {'start_delay': 0.3, 'hold_time': 1.0, 'peak_speed': 0.2}


def run_demonstration(nodes, probe, reference, **params):
    """Run scara_sim and the demonstrator to its end; return (exit code, tips, wrenches)."""
    sim = nodes('scara_sim', 'scara_sim')
    tips = probe.collect('/ee_position', PointStamped, RELIABLE)
    references = probe.collect('/demo/reference', PointStamped, RELIABLE)
    wrenches = probe.collect('/human/wrench', WrenchStamped, RELIABLE)
    assert wait_for(lambda: len(tips) > 0, START_TIMEOUT), sim.log()
    demo = nodes('scara_sim', 'demonstrator',
                 params={'reference': reference, **FAST, **params})
    code = demo.wait(25.0)
    assert code is not None, demo.log()
    assert references, demo.log()
    np.testing.assert_allclose([references[-1].point.x, references[-1].point.y], reference)
    return code, demo, tips, wrenches


def path_of(tips) -> np.ndarray:
    return np.array([[t.point.x, t.point.y] for t in list(tips)])


def peak_speed(tips) -> float:
    tips = list(tips)  # a snapshot: the probe keeps appending
    stamps = np.array([t.header.stamp.sec + 1e-9 * t.header.stamp.nanosec for t in tips])
    path = path_of(tips)
    window = 20  # about 20 ms: differences over single 1 ms steps are too coarse in time
    return float(np.max(np.linalg.norm(path[window:] - path[:-window], axis=1)
                        / (stamps[window:] - stamps[:-window])))


def test_follow_demonstration_stops_at_stop_distance_and_exits_0(nodes, probe):
    reference = [0.45, 0.05]
    code, demo, tips, wrenches = run_demonstration(nodes, probe, reference, mode='follow')
    assert code == 0, demo.log()
    distance = np.linalg.norm(path_of(tips)[-1] - reference)
    assert distance == pytest.approx(0.041, abs=0.004), demo.log()
    assert 0.1 <= peak_speed(tips) <= 0.3
    assert wrenches[-1].wrench.force.x == 0.0 and wrenches[-1].wrench.force.y == 0.0
    assert 'demonstration done' in demo.log()


def test_avoid_demonstration_moves_out_to_safe_distance_and_exits_0(nodes, probe):
    reference = [0.355, 0.295]  # 7 mm from where the arm starts
    code, demo, tips, _ = run_demonstration(nodes, probe, reference, mode='avoid')
    assert code == 0, demo.log()
    path = path_of(tips)
    assert np.linalg.norm(path[0] - reference) < 0.01
    assert np.linalg.norm(path[-1] - reference) == pytest.approx(0.183, abs=0.004)


def test_demonstrator_without_the_arm_gives_up_with_one_line(nodes):
    demo = nodes('scara_sim', 'demonstrator', params={'wait_timeout': 1.5})
    assert demo.wait(20.0) == 1
    log = demo.log()
    assert 'no /ee_position within 1.5 s' in log
    assert 'Traceback' not in log
