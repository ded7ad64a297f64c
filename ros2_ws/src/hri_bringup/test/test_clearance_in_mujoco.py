"""Unit tests of clearance_in_mujoco: recorded people beside the Panda in MuJoCo, judged
against ISO/TS 15066 (no ROS process)."""

from pathlib import Path

import numpy as np
import pytest

from hri_bringup.clearance_in_mujoco import contact_trace, run_take
from hri_bringup.processes import paper_tasks_dir
from hri_core.task_file import load_task_file
from scara_sim.mujoco_simulation import Contact

TAKES = Path(__file__).resolve().parents[4] / 'data' / 'human-motion'


def test_the_trace_sums_each_parts_contacts_per_step():
    touch = [(), (Contact('panda_hand', 'torso', 10.0, (0.0, 0.0, 0.0)),
                  Contact('panda_link7', 'torso', 5.0, (0.0, 0.0, 0.0)),
                  Contact('panda_hand', 'r_hand', 2.0, (0.0, 0.0, 0.0))),
             (Contact('panda_hand', 'torso', 1.0, (0.0, 0.0, 0.0)),)]
    time, part, force = contact_trace(touch, 1e-3)
    np.testing.assert_allclose(time, [2e-3, 2e-3, 3e-3])
    assert part == ['torso', 'r_hand', 'torso']
    np.testing.assert_allclose(force, [15.0, 2.0, 1.0])


def test_follow_presses_into_the_person_without_the_clearance_and_not_with_it():
    """ObjectInspection_0's first 2 s under follow (the person's inspection at the chest,
    placed by auto_place): without the whole-body clearance the Panda presses into the
    torso past Table A.2's limits (the first contact at 1.6 s); with it, no contact."""
    shape = load_task_file(paper_tasks_dir() / 'follow.yaml').shape
    take = TAKES / 'ObjectInspection_0.csv'
    off = run_take(take, 'follow', shape, clearance=False, seconds=2.0)
    assert off.contact_steps > 0 and off.trunk_touched and not off.passed
    assert off.force.shape == off.time.shape == (2000,)
    assert not all(judgement.passed for judgement in off.judgements.values())
    on = run_take(take, 'follow', shape, clearance=True, seconds=2.0)
    assert on.contact_steps == 0 and on.passed and on.judgements == {}
    assert on.least_distance > 0.0
    with pytest.raises(ValueError, match=r'seconds must be in \(0, 10\]'):
        run_take(take, 'follow', shape, clearance=True, seconds=11.0)
