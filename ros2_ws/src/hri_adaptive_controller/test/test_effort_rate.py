"""Tests of effort_rate: the torque command's rate limit after the clamp."""

import math

import numpy as np
import pytest

from hri_adaptive_controller.effort_rate import CommandEcho, EffortRateLimiter


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


def _drive_steps(applied_band: float | None, seed: int) -> float:
    """Largest change (N m) of the torque a drive applies between its 1 ms steps when the
    commands reach it in late bursts and it applies the newest (as scara_sim on a loaded
    machine), the law asking for a torque that swings by 30 N m; the limiter sees the applied
    torque of each state when applied_band is given."""
    rng = np.random.default_rng(seed)
    limiter = EffortRateLimiter(1000.0)
    applied = (0.0, 0.0)
    in_flight: list[tuple[int, tuple]] = []  # (step it arrives, command)
    largest = 0.0
    for k in range(3000):
        t = k * 1e-3
        wanted = (15.0 * np.sin(2 * np.pi * 3.0 * t), 15.0 * np.sign(np.sin(2 * np.pi * t)))
        command, _ = limiter.limit(wanted, 1e-3, None if applied_band is None else applied,
                                   math.inf if applied_band is None else applied_band)
        # Most commands arrive at the next step; bursts hold them back for up to 20 steps;
        # in order (a reliable topic).
        delay = 1 if rng.random() < 0.9 else int(rng.integers(2, 21))
        in_flight.append((max([k + delay] + [due for due, _ in in_flight[-1:]]), command))
        arrived = [c for due, c in in_flight if due <= k + 1]
        in_flight = [(due, c) for due, c in in_flight if due > k + 1]
        if arrived:
            newest = arrived[-1]
            largest = max(largest, float(np.max(np.abs(np.subtract(newest, applied)))))
            applied = newest
    return largest


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_near_the_applied_torque_a_late_burst_steps_the_drive_by_at_most_the_band(seed):
    assert _drive_steps(applied_band=2.0, seed=seed) <= 2.0 + 1e-9
    assert _drive_steps(applied_band=None, seed=seed) > 4.0  # the bursts, unguarded


def test_the_applied_band_narrows_the_step_but_never_widens_it():
    limiter = EffortRateLimiter(1000.0)
    limiter.reset((10.0, -10.0))
    # The drive reports 0 (a lag longer than the band reaches): the command walks towards the
    # band at the rate limit, never more than a step from the last command.
    tau, limited = limiter.limit((10.0, -10.0), 1e-3, applied=(0.0, 0.0), applied_band=2.0)
    assert tau == pytest.approx((9.0, -9.0)) and limited
    for _ in range(10):
        before = np.array(limiter.previous)
        tau, _ = limiter.limit((10.0, -10.0), 1e-3, applied=(0.0, 0.0), applied_band=2.0)
        assert np.abs(np.array(tau) - before).max() <= 1.0 + 1e-12
    assert tau == pytest.approx((2.0, -2.0))  # then held within the band
    # Within a step of the band, the band: the law asks 5 more, the drive applies 9.5.
    limiter.reset((10.0, 10.0))
    tau, limited = limiter.limit((15.0, 10.0), 1e-3, applied=(9.5, 10.0), applied_band=1.0)
    assert tau == pytest.approx((10.5, 10.0)) and limited
    limiter.reset((20.0, 20.0))
    tau, _ = limiter.limit((20.0, 20.0), 1e-3, applied=(20.0, 19.0), applied_band=2.0)
    assert tau == pytest.approx((20.0, 20.0))  # within the box the caller clamped to


def test_only_an_echo_of_a_sent_command_counts_as_the_applied_torque():
    echo = CommandEcho(depth=3)
    assert echo.applied((1.0, 2.0)) is None and echo.applied(None) is None
    for k in range(5):
        echo.sent((float(k), -float(k)))
    assert echo.applied((4.0, -4.0)) == (4.0, -4.0)      # the newest: a simulator's echo
    assert echo.applied((2.0, -2.0)) == (2.0, -2.0)      # three back: a late drive
    assert echo.applied((1.0, -1.0)) is None             # forgotten beyond the depth
    assert echo.applied((4.0 + 1e-9, -4.0)) is None      # a measured torque near it
    echo.sent((2.0, -2.0))                               # sent again: the newest now
    echo.sent((5.0, -5.0))
    echo.sent((6.0, -6.0))
    assert echo.applied((2.0, -2.0)) == (2.0, -2.0)
    with pytest.raises(ValueError, match='depth must be >= 1'):
        CommandEcho(depth=0)
