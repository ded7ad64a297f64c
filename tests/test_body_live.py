"""Topic-level: a recorded person's whole body beside a live arm (the Panda, the SCARA), the
whole-body clearance on.

hand_sim replays a take of data/human-motion with the person's body on /human/body, placed
by its auto_place with the arm's reach and body clearance; the arm's live loop (arm_sim,
event_manager, controller with `clearance` CLEARANCE, its default, given explicitly) runs
one of Table I's tasks. The probe keeps /joint_states, /target and /human/body and judges every
10 ms from SETTLE s on, as bench/bench_body_takes.py does in the pure loop:

- the trunk zone: the share of samples in which some capsule of the arm (robot_body, fitted
  from the URDF's collision meshes as the controller fits them; the SCARA's in its plane) is
  closer than clearance - 3 cm to the person's head, torso or hip capsules (the bar: 1 %);
- avoid: the share of the samples in which the tool is closer to the hand than d1 - 3 cm (5 %,
  as test_recorded_hand's);
- every command within the effort limits, at most 1 N m from the one before; no joint within
  5 degrees of a limit (the SCARA: a quarter of its 0.1 rad barrier band, where the law's
  stop damper holds the reference).

The default run: the Panda's avoid on ObjectInspection_0, a person inspecting an object held
at the chest beside the robot, and the SCARA's on the same take; with --all, the
Panda's avoid and follow_safe on a handover.
"""

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped

from hri_adaptive_controller.arm_law import ArmController
from hri_core import topics
from hri_core.bodies import capsule_distances, human_capsules, panda_package_dirs, robot_body
from hri_core.human_body import TRUNK
from hri_core.node_common import stamp_seconds
from hri_core.recorded_motion import BODY_CLEARANCE
from hri_core.robot_model import robot_model
from hri_core.task_file import load_task_file
from tests.common import PAPER_TASKS, REPO_ROOT
from tests.test_panda_loop import (
    LIMIT_MARGIN,
    RELIABLE,
    check_commands_and_limits,
    run_panda_loop,
)

pytestmark = [pytest.mark.integration, pytest.mark.exclusive]

TAKES = REPO_ROOT / 'data' / 'human-motion'
# m: where auto_place puts the hand path (scripts/demo.py's for the Panda, hand_sim's default
# for the SCARA), and the hand's dimensions on /target.
REACH = {'panda': ([0.30, 0.75], 3), 'scara': ([0.222, 0.65], 2)}
RUN = 10.0  # s after the first joint state
SETTLE = 3.0  # s: the arm comes from its home pose and the task fades in
SAMPLE = 0.01  # s between the samples judged
BODY_MAX_AGE = 0.05  # s: an older /human/body is no body at that time (a lost frame)
MARGIN = 0.03  # m: "closer than clearance - 3 cm", and avoid's d1 - 3 cm
TRUNK_BAR = 0.01  # share of the samples
AVOID_BAR = 0.05  # share of the samples
CLEARANCE = 0.1  # m, the controller's clearance here (hri_adaptive_controller.arm_law's)


def latest(times: np.ndarray, at: float) -> int:
    """Index of the last of `times` (sorted) at or before `at`, -1 if none."""
    return int(np.searchsorted(times, at, side='right')) - 1


def replay_beside_the_arm(nodes, probe, robot: str, take: str, task: str) -> dict:
    """The live loop of `robot` under `task` with `take` replayed; the judged figures."""
    model = robot_model(robot)
    body = robot_body(model, panda_package_dirs())
    reach, dimension = REACH[robot]
    targets = probe.collect(topics.TARGET.name, PointStamped, topics.TARGET.qos)
    bodies = probe.collect(topics.HUMAN_BODY.name, topics.HUMAN_BODY.type, RELIABLE)
    hand = {'profile': 'recording', 'recording': str(TAKES / f'{take}.csv'),
            'auto_place': True, 'reach': reach, 'body_clearance': BODY_CLEARANCE[robot],
            'dimension': dimension, 'at_end': 'stop', 'arm': robot}
    states, efforts, _, controller = run_panda_loop(nodes, probe, task, hand, RUN,
                                                    arm={'robot': robot},
                                                    controller_only={'clearance': CLEARANCE})
    assert 'whole-body clearance and separation pairs off' not in controller.log()
    targets, bodies = list(targets), list(bodies)
    assert targets and bodies, 'no /target or /human/body from hand_sim'
    joint_times = np.array([stamp_seconds(m.header.stamp) for m in states])
    q = np.array([m.position for m in states])
    hand_times = np.array([stamp_seconds(m.header.stamp) for m in targets])
    hands = np.array([(m.point.x, m.point.y, m.point.z) for m in targets])[:, :model.task_axes]
    body_times = np.array([stamp_seconds(m.header.stamp) for m in bodies])
    trunk, tool_hand = [], []
    for at in np.arange(joint_times[0] + SETTLE, joint_times[-1], SAMPLE):
        j, b, h = latest(joint_times, at), latest(body_times, at), latest(hand_times, at)
        if b >= 0 and at - body_times[b] <= BODY_MAX_AGE:
            names = [name for name in bodies[b].names if name in TRUNK]
            points = [(p.x, p.y, p.z) for name, p in zip(bodies[b].names, bodies[b].points,
                                                         strict=True) if name in TRUNK]
            if names:
                person = human_capsules(names, np.array(points))
                trunk.append(capsule_distances(body.capsules(q[j]), person,
                                               body.planar).distance.min())
        if h >= 0 and at - hand_times[h] <= BODY_MAX_AGE:
            tool_hand.append(float(np.linalg.norm(
                model.tool_position(q[j])[:model.task_axes] - hands[h])))
    trunk, tool_hand = np.array(trunk), np.array(tool_hand)
    # The law holds a joint's reference from a quarter of its barrier band on (the stop
    # damper): the Panda's 2.1 deg, within the default 5; the SCARA's 1.4 deg (band 0.1 rad),
    # which a person pressing its elbow folded reaches 2.5 deg from joint 2's stop.
    band = ArmController(model).gains.limit_band
    step, margin = check_commands_and_limits(model, q, efforts,
                                             min(LIMIT_MARGIN, 0.25 * band))
    figures = {'robot': robot, 'take': take, 'task': task, 'samples': trunk.size,
               'trunk_close': float(np.mean(trunk < CLEARANCE - MARGIN)),
               'trunk_least': float(trunk.min()),
               'tool_hand_median': float(np.median(tool_hand)),
               'tool_hand_least': float(tool_hand.min()),
               'largest_step': step, 'nearest_limit': margin}
    print(f"{take} {task} beside the {robot}: trunk within clearance - 3 cm "
          f"{100 * figures['trunk_close']:.1f} % of {trunk.size} samples (least "
          f"{figures['trunk_least']:+.3f} m); tool-hand median {figures['tool_hand_median']:.3f}"
          f" m, least {figures['tool_hand_least']:.3f} m; largest command step {step:.3f} N m")
    # Hand and body arrive at 100 Hz: nearly every 10 ms sample has both.
    assert trunk.size > 0.8 * (RUN - SETTLE) / SAMPLE, figures
    assert tool_hand.size > 0.8 * (RUN - SETTLE) / SAMPLE, figures
    return figures | {'tool_hand': tool_hand}


# Without the clearance the pure loop puts the Panda inside the trunk zone in 34 % (avoid,
# ObjectInspection_0) and 2-5 % (HumanRobotHandover_0) of the samples, the SCARA (in its
# plane) in 90 % (avoid, ObjectInspection_0) (bench_body_takes).
CASES = [pytest.param('panda', 'ObjectInspection_0', 'avoid', id='panda-avoid-ObjectInspection_0'),
         pytest.param('scara', 'ObjectInspection_0', 'avoid', id='scara-avoid-ObjectInspection_0'),
         pytest.param('panda', 'HumanRobotHandover_0', 'avoid',
                      id='panda-avoid-HumanRobotHandover_0', marks=pytest.mark.slow),
         pytest.param('panda', 'HumanRobotHandover_0', 'follow_safe',
                      id='panda-follow_safe-HumanRobotHandover_0', marks=pytest.mark.slow)]


@pytest.mark.parametrize(('robot', 'take', 'task'), CASES)
def test_the_arm_keeps_clear_of_a_recorded_persons_trunk(nodes, probe, robot, take, task):
    figures = replay_beside_the_arm(nodes, probe, robot, take, task)
    assert figures['trunk_close'] <= TRUNK_BAR, figures
    d1 = load_task_file(PAPER_TASKS / f'{task}.yaml').d1
    assert np.mean(figures['tool_hand'] < d1 - MARGIN) <= AVOID_BAR, figures
