"""Tests of effort_rate: the torque command's rate limit after the clamp."""

import numpy as np
import pytest

from hri_adaptive_controller.effort_rate import EffortRateLimiter


def test_a_step_becomes_a_ramp_at_the_rate_times_the_elapsed_time():
    limiter = EffortRateLimiter(1000.0)
    assert limiter.previous == (0.0, 0.0)
    tau, limited = limiter.limit((5.0, -0.5), 1e-3)
    assert tau == pytest.approx((1.0, -0.5)) and limited
    tau, limited = limiter.limit((5.0, -0.5), 3e-3)  # a command 3 ms later: 3 N m more
    assert tau == pytest.approx((4.0, -0.5)) and limited
    tau, limited = limiter.limit((5.0, -0.5), 1e-3)
    assert tau == pytest.approx((5.0, -0.5)) and not limited


def test_changes_within_the_rate_pass_unchanged_and_reset_restarts_from_a_value():
    limiter = EffortRateLimiter(1000.0)
    rng = np.random.default_rng(3)
    wanted = np.cumsum(rng.uniform(-0.9, 0.9, size=(200, 2)), axis=0)
    for tau in wanted:
        out, limited = limiter.limit(tuple(tau), 1e-3)
        assert not limited and out == pytest.approx(tuple(tau))
    limiter.reset()
    assert limiter.limit((20.0, -20.0), 0.0) == ((0.0, 0.0), True)


def test_limited_commands_stay_within_the_clamp_box():
    limiter = EffortRateLimiter(500.0)
    rng = np.random.default_rng(7)
    for _ in range(500):
        wanted = rng.uniform(-20.0, 20.0, size=2)
        before = np.array(limiter.previous)
        out, _ = limiter.limit(tuple(wanted), 2e-3)
        assert np.all(np.abs(out) <= 20.0)
        assert np.all(np.abs(np.array(out) - before) <= 1.0 + 1e-12)


def test_a_bad_rate_is_refused():
    with pytest.raises(ValueError, match='max_rate'):
        EffortRateLimiter(0.0)
    with pytest.raises(ValueError, match='max_rate'):
        EffortRateLimiter(float('inf'))
