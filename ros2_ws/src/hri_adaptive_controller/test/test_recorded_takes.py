"""Every shipped take of a real person's hand (data/human-motion/*.csv) in the pure closed loop.

Each take's right hand is placed by recorded_motion.choose_placement (most of its path inside
the arm's reach), sampled at its recorded 100 Hz through the controller's glitch filter and
hold (closed_loop with target_period 0.01 s: target_filter.FilteredHand), lost frames giving
nothing, with Table I's follow and avoid rows (tasks/), faded in at t = 0 as the
event_manager does; the arm stops at scara_sim's joint limits. The checks are the issue's:
efforts finite and within the limit, the applied effort changes <= 2 N m between consecutive
1 ms steps, no effort above 25 % of the limit held for more than 0.5 s; follow: median
distance <= 0.08 m over the samples where the hand is reachable and slower than the arm's
task speed (run_metrics.considered_samples); avoid: at most 5 % of those samples closer than
d1 - 3 cm. Nothing is tuned per take. To keep the unit suite quick each take is cropped to
its first CROP s (8-21 s recorded), each (take, task) a test of its own.
"""

import functools
from pathlib import Path

import numpy as np
import pytest

from hri_adaptive_controller.arm_law import SCARA_GAINS
from hri_adaptive_controller.closed_loop import LoopConditions, recorded_target, simulate
from hri_adaptive_controller.run_metrics import TakeCriteria, take_metrics
from hri_core.dynamics import ScaraParameters
from hri_core.potential import TaskShape
from hri_core.recorded_motion import ReachAnnulus, choose_placement, read_vicon_csv
from hri_core.robot_model import ScaraModel
from hri_core.task_file import load_task_file

TAKES = sorted((Path(__file__).resolve().parents[4] / 'data' / 'human-motion').glob('*.csv'))
TASKS_DIR = Path(__file__).resolve().parents[1] / 'tasks'
PARAMS = ScaraParameters()
ARM = ScaraModel(PARAMS)  # scara_sim's arm, its joint limits and its 20 N m effort limit
REACH = ReachAnnulus(ARM.folded_reach, ARM.attained_reach)
EFFORT_LIMIT = float(ARM.limits.effort.min())
CROP = 12.0  # s of each take
HAND_PERIOD = 0.01  # s, the takes' 100 Hz
MAX_EFFORT_STEP = 2.0  # N m between consecutive steps
HIGH_EFFORT_HOLD = 0.5  # s above 25 % of the limit
FOLLOW_MEDIAN = 0.08  # m
CLOSE_FRACTION = 0.05


def task(name: str) -> TaskShape:
    record = load_task_file(TASKS_DIR / f'{name}.yaml')
    return record.shape


@functools.cache
def placed_take(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The take at `path` placed within reach and cropped: (times (N,) s, hand (N, 3) m),
    once per take for its follow and avoid cases."""
    placement = choose_placement(read_vicon_csv(path).positions, REACH)
    motion = read_vicon_csv(path, placement=placement)
    keep = motion.times <= CROP
    return motion.times[keep], motion.positions[keep]


def replay(path: Path, name: str):
    """(metrics, result) of the take at `path` with the task `name`."""
    times, positions = placed_take(path)
    shape = task(name)
    result = simulate({name: shape}, [(0.0, name)], recorded_target(times, positions),
                      float(times[-1]), LoopConditions(arm=ARM, monitor=False,
                                                       target_period=HAND_PERIOD))
    index = np.clip(np.searchsorted(times, result.time, side='right') - 1, 0, len(times) - 1)
    hand = positions[index, :2]
    criteria = TakeCriteria(d1=shape.d1, effort_limit=EFFORT_LIMIT,
                            task_speed=SCARA_GAINS.max_task_speed, reach=REACH)
    return take_metrics(result.time, hand, result.position, result.tau, criteria), result


def test_every_take_is_tested():
    assert len(TAKES) >= 6, TAKES


CASES = [pytest.param(path, name, id=f'{path.stem}-{name}') for path in TAKES
         for name in ('follow', 'avoid')]


@pytest.mark.parametrize(('path', 'name'), CASES)
def test_a_recorded_hand_is_followed_or_avoided_with_small_smooth_effort(path, name):
    metrics, result = replay(path, name)
    label = f'{path.stem} {name}: {metrics}'
    assert np.all(np.isfinite(result.tau)) and not result.fault.any(), label
    assert np.max(np.abs(result.tau)) <= EFFORT_LIMIT + 1e-12, label
    assert metrics.largest_effort_step <= MAX_EFFORT_STEP, label
    assert metrics.longest_high_effort_hold <= HIGH_EFFORT_HOLD, label
    assert metrics.considered > 0.1 * len(result.time), label  # the check means something
    if name == 'follow':
        assert metrics.follow_median_distance <= FOLLOW_MEDIAN, label
    else:
        assert metrics.close_fraction <= CLOSE_FRACTION, label
    assert np.all((result.theta_hat >= ARM.theta_lower)
                  & (result.theta_hat <= ARM.theta_upper)), label
