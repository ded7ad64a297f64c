"""Topic-level tests of teaching the Panda by hand: arm_sim robot:=panda in teach mode
(gravity compensated, as a Panda in its guiding mode) pushed by the demonstrator robot:=panda
with a 3-D force, follow and avoid, to the demonstration's end."""

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy

from hri_bringup.processes import wait_for
from scara_sim.demonstrator_node import DEFAULT_REFERENCES

pytestmark = pytest.mark.integration

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
START_TIMEOUT = 20.0  # s: the Panda's model takes a second to load in each node
FAST = {'start_delay': 0.3, 'hold_time': 1.0, 'peak_speed': 0.2}
WINDOW = 20  # samples (about 20 ms) over which speeds are differences of positions


def run_panda_demonstration(nodes, probe, **params):
    """arm_sim (Panda, teach mode) and the demonstrator (Panda) to its end: the exit code,
    its log, the tool's stamps (N,) s and positions (N, 3) m, the wrenches and references."""
    sim = nodes('scara_sim', 'arm_sim', params={'robot': 'panda', 'teach_mode': True})
    tips = probe.collect('/ee_position', PointStamped, RELIABLE)
    references = probe.collect('/demo/reference', PointStamped, RELIABLE)
    wrenches = probe.collect('/human/wrench', WrenchStamped, RELIABLE)
    assert wait_for(lambda: len(tips) > 0, START_TIMEOUT), sim.log()
    demo = nodes('scara_sim', 'demonstrator', params={'robot': 'panda', **FAST, **params})
    code = demo.wait(40.0)
    assert code is not None, demo.log()
    tips = list(tips)
    stamps = np.array([t.header.stamp.sec + 1e-9 * t.header.stamp.nanosec for t in tips])
    path = np.array([[t.point.x, t.point.y, t.point.z] for t in tips])
    assert sim.stop() == 0, sim.log()
    return code, demo.log(), stamps, path, list(wrenches), list(references)


def radial_speeds(stamps, path, reference) -> tuple[np.ndarray, np.ndarray]:
    """The tool's speed (m/s) and the rate of change of its distance to x_r (m/s, > 0: away
    from x_r), each over WINDOW samples."""
    dt = stamps[WINDOW:] - stamps[:-WINDOW]
    speed = np.linalg.norm(path[WINDOW:] - path[:-WINDOW], axis=1) / dt
    distance = np.linalg.norm(path - reference, axis=1)
    return speed, (distance[WINDOW:] - distance[:-WINDOW]) / dt


@pytest.mark.parametrize(('mode', 'reference', 'final_distance', 'sign'), [
    ('follow', DEFAULT_REFERENCES['panda'], 0.041, -1.0),
    ('avoid', (0.31, 0.004, 0.49), 0.183, 1.0),  # 6 mm from the tool at home
])
def test_a_3d_demonstration_on_the_panda_follows_or_avoids_x_r(nodes, probe, mode, reference,
                                                              final_distance, sign):
    params = {'mode': mode}
    if mode == 'avoid':
        params['reference'] = list(reference)
    code, log, stamps, path, wrenches, references = run_panda_demonstration(nodes, probe,
                                                                            **params)
    assert code == 0, log
    assert 'demonstration done' in log and 'Traceback' not in log
    reference = np.array(reference)
    last = references[-1].point
    np.testing.assert_allclose([last.x, last.y, last.z], reference)
    # The tool reaches the demonstration's end and stays there once let go.
    distance = np.linalg.norm(path - reference, axis=1)
    assert distance[-1] == pytest.approx(final_distance, abs=0.004), log
    # A push in space: the hand pushed along z, and the tool's height changed with its path.
    assert max(abs(w.wrench.force.z) for w in wrenches) > 1.0
    moved = path[-1] - path[0]
    assert abs(moved[2]) > 0.2 * np.linalg.norm(moved)
    # The pattern: while the tool moves at a hand's speed it moves towards x_r (follow) or
    # away from it (avoid), the distance changing at nearly the tool's whole speed.
    speed, radial = radial_speeds(stamps, path, reference)
    print(f'\n{mode}: the tool ends {distance[-1]:.4f} m from x_r (goal {final_distance} m),'
          f' moved {np.round(moved, 3).tolist()} m, peak speed {speed.max():.3f} m/s')
    assert 0.1 <= speed.max() <= 0.3
    moving = speed > 0.05
    assert moving.sum() > 200  # samples: most of a push of about 1.5 s
    assert np.all(sign * radial[moving] > 0.0)
    assert np.median(sign * radial[moving] / speed[moving]) > 0.95
    assert wrenches[-1].wrench.force.x == wrenches[-1].wrench.force.z == 0.0


def test_a_planar_reference_on_the_panda_is_one_line_and_exit_1(nodes):
    demo = nodes('scara_sim', 'demonstrator',
                 params={'robot': 'panda', 'reference': [0.45, 0.05]})
    assert demo.wait(START_TIMEOUT) == 1
    errors = [line for line in demo.log().splitlines() if '[ERROR]' in line]
    assert len(errors) == 1 and 'panda moves in 3-D: reference must be [x, y, z]' in errors[0]
    assert 'Traceback' not in demo.log()
