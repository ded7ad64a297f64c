"""Unit tests of separation_cap (the controller's ISO/TS 15066 speed cap) and of the pull limit
it sets on the task term (task_variable, arm_law on the SCARA)."""

import dataclasses
import math

import numpy as np
import pytest

from hri_adaptive_controller.arm_law import SCARA_GAINS, ActiveTask, ArmController, HandState
from hri_adaptive_controller.separation_cap import (
    DROP_RATE,
    LOOKAHEAD,
    RISE_RATE,
    SEPARATION_PERIOD,
    STALE_AFTER,
    STANDOFF,
    SeparationCap,
    pull_speed_knee,
)
from hri_adaptive_controller.task_variable import CAP_BAND, radial_drive, task_drive
from hri_core.potential import TaskShape
from hri_core.robot_model import ScaraModel
from hri_core.separation import ProtectiveSeparation

SETTINGS = ProtectiveSeparation(reaction_time=0.1, stopping_time=0.3, stopping_distance=0.05,
                                intrusion_distance=0.02, human_uncertainty=0.004,
                                robot_uncertainty=0.001, near_speed=2.0, far_speed=1.6,
                                near_limit=0.5, assume_iso_speed=False)
V_MAX = 0.25
FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)
AVOID = TaskShape(1, 0.056, 25.46, 0.183, 2.0)
REACH = 0.65
THETA_HAT = [0.66, 0.19, 0.13, 1.0, 0.5, 1.75, 0.54]
Q, DQ = np.array([0.3, 1.2]), np.zeros(2)
STILL_HAND = HandState(np.array([0.1, 0.3]), np.zeros(2), np.zeros(2))  # 0.27 m from the tip


def follow_step(law, dt=1e-3):
    """One step of the law at Q, still, with the follow task at a = 1 and the still hand."""
    return law.step(Q, DQ, STILL_HAND, ActiveTask(FOLLOW, 1.0, 0.0), dt)


def test_knee_is_the_iso_limit_through_the_soft_band():
    v_h = 0.2
    still = SETTINGS.distance(v_h, 0.0)
    separation = still + STANDOFF + 0.01  # room for 0.1 m/s over T_r = 0.1 s
    knee = pull_speed_knee(separation, v_h, SETTINGS, V_MAX)
    assert knee == pytest.approx(0.1 / (1.0 + CAP_BAND))
    # At the knee's top speed (1 + CAP_BAND) knee, S_p is the separation less the standoff.
    assert SETTINGS.distance(v_h, (1.0 + CAP_BAND) * knee) == pytest.approx(
        separation - STANDOFF)
    # The arm comes to rest outside S_p, not on it.
    assert pull_speed_knee(still + STANDOFF, v_h, SETTINGS, V_MAX) == 0.0


def test_knee_is_zero_where_a_still_arm_is_too_close_and_capped_far_away():
    assert pull_speed_knee(SETTINGS.distance(0.5, 0.0) - 1e-3, 0.5, SETTINGS, V_MAX) == 0.0
    assert pull_speed_knee(5.0, 0.0, SETTINGS, V_MAX) == V_MAX
    no_reaction = ProtectiveSeparation(**{**SETTINGS.__dict__, 'reaction_time': 0.0})
    assert pull_speed_knee(1.0, 0.0, no_reaction, V_MAX) == V_MAX


@pytest.mark.parametrize('separation, speed', [(math.nan, 0.0), (0.5, math.inf),
                                               (-0.1, 0.0), (0.5, -0.1)])
def test_bad_input_gives_the_safe_knee(separation, speed):
    assert pull_speed_knee(separation, speed, SETTINGS, V_MAX) == 0.0


def test_cap_starts_at_zero_and_moves_at_its_rates():
    cap = SeparationCap(SETTINGS, V_MAX)
    assert cap.knee(0.0) == 0.0  # nothing heard: no approach
    cap.observe(0.0, 5.0, 0.0, 0.0)
    assert cap.knee(0.1) == pytest.approx(RISE_RATE * 0.1)
    assert cap.knee(10.0 * STALE_AFTER) == 0.0  # stale: falls to 0 (at DROP_RATE)

    def run(times, separation):
        knees = []
        for t in times:  # /hri/separation at 50 Hz, control at 1 kHz
            if round(t * 1000) % 20 == 0:
                cap.observe(t, separation, 0.0, 0.0)
            knees.append(cap.knee(t))
        return np.array(knees)

    knees = run(np.arange(20.0, 22.0, 0.001), 5.0)
    assert knees[-1] == V_MAX
    assert np.max(np.diff(knees)) <= RISE_RATE * 0.001 + 1e-12
    # A still arm just fits: knee 0.
    knees = run(np.arange(22.0, 22.2, 0.001), SETTINGS.distance(0.0, 0.0))
    assert knees[-1] == 0.0
    assert np.min(np.diff(knees)) >= -DROP_RATE * 0.001 - 1e-12
    assert np.all(knees >= 0.0)


def test_cap_looks_ahead_at_the_closing_speed():
    cap = SeparationCap(SETTINGS, V_MAX)
    still = SETTINGS.distance(0.0, 0.0)
    cap.observe(0.0, still + 0.01, 0.0, 0.0)
    assert cap.target(0.0) == pytest.approx(pull_speed_knee(still + 0.01, 0.0, SETTINGS,
                                                            V_MAX))
    cap.observe(0.0, still + 0.01, 0.0, 0.1 / LOOKAHEAD)  # 0.1 m/s x LOOKAHEAD closer
    assert cap.target(0.0) == 0.0
    cap.observe(0.0, still + 0.01, 0.0, -1.0)  # moving apart: no credit
    assert cap.target(0.0) == pytest.approx(pull_speed_knee(still + 0.01, 0.0, SETTINGS,
                                                            V_MAX))
    cap.observe(0.0, math.nan, 0.0, 0.0)
    assert cap.target(0.0) == 0.0


def test_an_old_separation_is_taken_ahead_by_its_age():
    """A detector held back: the separation heard 0.2 s ago, the arm closing at 0.1 m/s,
    counts as 0.1 m/s x 0.18 s nearer than it was (the first period is the topic's own)."""
    cap = SeparationCap(SETTINGS, V_MAX)
    separation = SETTINGS.distance(0.0, 0.0) + STANDOFF + 0.03
    cap.observe(0.0, separation, 0.0, 0.1)
    fresh = pull_speed_knee(separation - LOOKAHEAD * 0.1, 0.0, SETTINGS, V_MAX)
    assert cap.target(SEPARATION_PERIOD) == pytest.approx(fresh)  # on time: as heard
    late = pull_speed_knee(separation - LOOKAHEAD * 0.1 - (0.2 - SEPARATION_PERIOD) * 0.1,
                           0.0, SETTINGS, V_MAX)
    assert cap.target(0.2) == pytest.approx(late)
    assert 0.0 < late < fresh < V_MAX
    # The cap's own speed counts where the measured closing is slower (a still arm then).
    cap.value = 0.05
    cap.observe(0.0, separation, 0.0, 0.0)
    expected = pull_speed_knee(separation - (0.2 - SEPARATION_PERIOD) * 0.05 * (1.0 + CAP_BAND),
                               0.0, SETTINGS, V_MAX)
    assert 0.0 < cap.target(0.2) == pytest.approx(expected)


def test_cap_goes_stale_after_its_timeout():
    cap = SeparationCap(SETTINGS, V_MAX)
    cap.observe(0.0, 5.0, 0.0, 0.0)
    assert not cap.stale(STALE_AFTER * 0.9)
    assert cap.stale(STALE_AFTER * 1.1)


def test_pull_limit_caps_only_speeds_towards_the_hand():
    follow = task_drive(FOLLOW, 0.0, V_MAX, REACH, approach_speed=0.1, region_margin=0.02)
    limited = dataclasses.replace(follow, pull_limit=0.05)
    radii = np.linspace(0.06, 0.6, 50)
    free = np.array([radial_drive(r, follow)[0] for r in radii])
    capped = np.array([radial_drive(r, limited)[0] for r in radii])
    assert np.max(free) > 0.2  # the follow task pulls fast far out ...
    assert np.max(capped) <= (1.0 + CAP_BAND) * 0.05 + 1e-12  # ... and slowly when limited
    avoid = task_drive(AVOID, 0.0, V_MAX, REACH)
    stopped = dataclasses.replace(avoid, pull_limit=0.0)
    inside = np.linspace(0.01, 0.18, 30)  # Q' < 0: the push out of d1 is never limited
    assert [radial_drive(r, avoid) for r in inside] == [radial_drive(r, stopped)
                                                         for r in inside]


def test_controller_applies_the_pull_limit_and_refuses_a_bad_one():
    law = ArmController(ScaraModel(), SCARA_GAINS, THETA_HAT)
    free = follow_step(law)
    law.limit_pull_speed(0.0)
    stopped = follow_step(law)
    assert math.hypot(*free.qdot_r) > 0.1
    assert stopped.qdot_r.tolist() == [0.0, 0.0]  # a still hand, no pull: no reference motion
    law.limit_pull_speed(math.inf)
    again = follow_step(law)
    assert again.qdot_r == pytest.approx(free.qdot_r)
    for bad in (-0.1, math.nan):
        with pytest.raises(ValueError, match='pull speed limit must be >= 0'):
            law.limit_pull_speed(bad)


def test_a_falling_knee_changes_the_torque_gradually():
    """The knee falling at DROP_RATE from max_task_speed to 0 under a follow task that pulls
    at full speed keeps the torque's change per 1 ms step below the continuity bar
    (max_effort_rate dt = 1 N m), which the same fall in one step breaks."""
    law = ArmController(ScaraModel(), SCARA_GAINS, THETA_HAT)
    cap = SeparationCap(SETTINGS, V_MAX)
    dt = 1e-3
    for step in range(600):  # the knee rises to max_task_speed (0.5 s at RISE_RATE)
        cap.observe(step * dt, 5.0, 0.0, 0.0)
        cap.knee(step * dt)
    assert cap.value == V_MAX
    torques, knees = [], []
    for step in range(600, 700):
        cap.observe(step * dt, SETTINGS.distance(0.0, 0.0), 0.0, 0.0)  # no room: target 0
        knees.append(cap.knee(step * dt))
        law.limit_pull_speed(knees[-1])
        torques.append(follow_step(law, dt).tau)
    assert knees[-1] == 0.0
    steps = np.max(np.abs(np.diff(np.array(torques), axis=0)))
    bar = SCARA_GAINS.max_effort_rate * dt
    law.limit_pull_speed(math.inf)
    full = follow_step(law, dt).tau
    jump = np.max(np.abs(np.array(full) - np.array(torques[-1])))
    assert 0.0 < steps < 0.5 * bar < bar < jump, (steps, jump)
