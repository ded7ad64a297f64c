"""Unit tests of joint_limits.joint_speed_limit (the reference joint motion held within the
joint velocity limits and within what each joint can stop from before its limit) and of the
Panda in the pure closed loop on fast hand paths that stretch it out: no joint comes nearer
than STOP_MARGIN to a stop, and every torque is finite and within its effort limit."""

import math

import numpy as np
import pytest

from hri_adaptive_controller import arm_kernels
from hri_adaptive_controller.arm_law import PANDA_GAINS, SCARA_GAINS
from hri_adaptive_controller.closed_loop import LoopConditions, path_target, simulate
from hri_adaptive_controller.joint_limits import (
    STOP_SHARE,
    STOP_SOFTNESS,
    joint_speed_limit,
)
from hri_adaptive_controller.task_variable import CAP_BAND
from hri_core.potential import TaskShape
from hri_core.robot_model import robot_model

FOLLOW = TaskShape(1, 1.291, 13.66, 0.0, 0.041)  # Table I's rows
FOLLOW_SAFE = TaskShape(1, 1.576, 30.78, 0.183, 0.271)
STOP_MARGIN = 0.05  # rad: the least distance to any joint stop the closed loops keep
HAND_PERIOD = 0.01  # s: the hand through the node's hold, as hand_sim's 100 Hz /target


@pytest.fixture(scope='module')
def panda():
    return robot_model('panda')


def speeds(model, scale=1.0):
    """Where the smooth cap starts: as ArmController takes it from the velocity limits."""
    return scale * model.limits.velocity / (1.0 + CAP_BAND)


def random_cases(model, rng, count):
    """(q, dq, qdot_r, qddot_r) (n,) each: joints anywhere within the limits (a share at
    their stops' edges) and references up to 20 times the velocity limits."""
    lower, upper = model.limits.lower, model.limits.upper
    for k in range(count):
        q = rng.uniform(lower, upper)
        if k % 3 == 0:  # within a tenth of a radian of a limit
            edge = rng.integers(0, 2, q.size).astype(bool)
            q = np.where(edge, upper - rng.uniform(0, 0.1, q.size),
                         lower + rng.uniform(0, 0.1, q.size))
        dq = rng.normal(0.0, 1.0, q.size)
        qdot_r = rng.normal(0.0, 1.0, q.size) * model.limits.velocity * rng.choice([0.3, 3, 20])
        qddot_r = rng.normal(0.0, 10.0, q.size)
        yield q, dq, qdot_r, qddot_r


@pytest.mark.parametrize('name', ['panda', 'scara'])
def test_the_reference_keeps_within_the_speed_limits_and_stops_short(name, panda):
    model = panda if name == 'panda' else robot_model('scara')
    gains = PANDA_GAINS if name == 'panda' else SCARA_GAINS
    band, rate = gains.limit_band, gains.stop_rate
    lower, upper, velocity = model.limits.lower, model.limits.upper, model.limits.velocity
    rng = np.random.default_rng(1)
    held = 0
    for q, dq, qdot_r, qddot_r in random_cases(model, rng, 400):
        out, out_rate, changed = joint_speed_limit(q, dq, qdot_r, qddot_r, lower, upper,
                                                   speeds(model), rate, band)
        assert np.all(np.isfinite(out)) and np.all(np.isfinite(out_rate))
        assert np.all(np.abs(out) <= velocity + 1e-12), (q, qdot_r, out)
        # Towards a limit never more than k (d - STOP_SHARE band) + softness: zero (or away)
        # from STOP_SHARE band on, nearer than that.
        softness = STOP_SOFTNESS * rate * band
        assert np.all(out <= rate * (upper - q - STOP_SHARE * band) + softness + 1e-12)
        assert np.all(-out <= rate * (q - lower - STOP_SHARE * band) + softness + 1e-12)
        # Nothing changes a reference well within both.
        if not changed:
            assert np.array_equal(out, qdot_r) and np.array_equal(out_rate, qddot_r)
        held += changed
    assert 50 <= held < 400  # both branches taken


def test_a_reference_within_the_limits_is_left_alone(panda):
    q = panda.home.copy()
    qdot_r = 0.5 * speeds(panda) * np.sign(np.sin(np.arange(7.0) + 1.0))
    out, rate, changed = joint_speed_limit(q, np.zeros(7), qdot_r, np.ones(7),
                                           panda.limits.lower, panda.limits.upper,
                                           speeds(panda), PANDA_GAINS.stop_rate,
                                           PANDA_GAINS.limit_band)
    assert not changed and np.array_equal(out, qdot_r) and np.array_equal(rate, np.ones(7))


def test_the_held_rate_is_the_time_derivative(panda):
    # Along a smooth path of the joints and of the reference through both caps, the rate the
    # function gives is the central difference of the reference it gives.
    lower, upper = panda.limits.lower, panda.limits.upper
    band, k = PANDA_GAINS.limit_band, PANDA_GAINS.stop_rate
    rng = np.random.default_rng(2)
    for _ in range(20):
        q0 = rng.uniform(lower + 0.05, upper - 0.05)
        q0[3] = upper[3] - rng.uniform(0.0, 0.1)  # joint 4 near its upper stop
        dq = rng.normal(0.0, 0.5, 7)
        v0 = rng.normal(0.0, 3.0, 7)
        v0[3] = abs(v0[3]) + 0.2  # towards that stop
        a = rng.normal(0.0, 5.0, 7)

        def at(t, q0=q0, dq=dq, v0=v0, a=a):
            return joint_speed_limit(q0 + dq * t, dq, v0 + a * t, a, lower, upper,
                                     speeds(panda), k, band)

        h = 1e-6
        value, rate, changed = at(0.0)
        assert changed
        difference = (at(h)[0] - at(-h)[0]) / (2.0 * h)
        assert np.allclose(rate, difference, rtol=1e-5, atol=1e-5), (rate, difference)


def test_the_compiled_speed_limit_is_the_reference(panda):
    rng = np.random.default_rng(3)
    for model, gains in ((panda, PANDA_GAINS), (robot_model('scara'), SCARA_GAINS)):
        for q, dq, qdot_r, qddot_r in random_cases(model, rng, 200):
            args = (q, dq, qdot_r, qddot_r, model.limits.lower, model.limits.upper,
                    speeds(model), gains.stop_rate, gains.limit_band)
            compiled = arm_kernels.joint_speed_limit(*args)
            reference = joint_speed_limit(*args)
            assert compiled[2] == reference[2]
            for got, expected in zip(compiled[:2], reference[:2], strict=True):
                scale = max(1.0, float(np.max(np.abs(expected))))
                assert np.allclose(got, expected, rtol=0.0, atol=1e-10 * scale)


def stretching_path(model, seed: int):
    """A seeded hand path that starts at the Panda's tool and makes four fast minimum-jerk
    moves (peak 0.8-1.2 m/s) to points 0.75-1.0 m from its shoulder, at and beyond its
    0.95 m reach, in every direction above the base's height less a little: the arm
    stretches out and swings round near its stretched posture. (end of the path s, path)"""
    rng = np.random.default_rng(seed)
    start = model.tool_position(model.home)
    moves, t, point = [], 0.3, start
    for _ in range(4):
        direction = rng.normal(size=3)
        direction[2] = 0.5 * abs(direction[2])
        direction /= np.linalg.norm(direction)
        end = model.shoulder + direction * rng.uniform(0.75, 1.0)
        speed = rng.uniform(0.8, 1.2)
        moves.append((t, end, speed))
        t += 1.875 * float(np.linalg.norm(end - point)) / speed + rng.uniform(0.2, 0.6)
        point = end
    return t, path_target(start, moves)


@pytest.mark.parametrize(('seed', 'name'), [(5, 'follow'), (14, 'follow_safe')])
def test_the_panda_stretched_out_by_a_fast_hand_keeps_off_its_joint_stops(panda, seed, name):
    # Before the joint speed limit seed 5's follow drove joints 4 and 2 into their stops
    # (peak joint speed 15 rad/s); seed 14's follow_safe kept 0.56 rad off them but its
    # joints reached 10.8 rad/s (4.3 rad/s with the limit, whose reference stays within
    # 2.2: near the stretched arm the torque still saturates at times).
    shape = FOLLOW if name == 'follow' else FOLLOW_SAFE
    end, target = stretching_path(panda, seed)
    result = simulate({name: shape}, [(0.0, name)], target, end + 0.5,
                      LoopConditions(arm=panda, monitor=False, initial_task=name,
                                     target_period=HAND_PERIOD))
    lower, upper = panda.limits.lower, panda.limits.upper
    margin = np.minimum(result.q - lower, upper - result.q)
    worst = np.unravel_index(int(np.argmin(margin)), margin.shape)
    label = (f'joint {worst[1] + 1} within {margin[worst]:.3f} rad of a stop at '
             f't = {result.time[worst[0]]:.2f} s')
    assert margin.min() >= STOP_MARGIN, label
    assert not result.fault.any() and np.all(np.isfinite(result.tau))
    assert np.all(np.abs(result.tau) <= panda.limits.effort + 1e-9)
    assert math.isfinite(float(result.position.sum()))
