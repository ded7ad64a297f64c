"""Unit tests of scara_sim.simulation: drive modes, limits, J^T f and real-time stepping."""

import numpy as np
import pytest

from hri_core.dynamics import (
    ScaraParameters,
    forward_kinematics,
    jacobian,
    kinetic_energy,
    rk4_step,
)
from scara_sim.simulation import (
    EARLY_TOLERANCE,
    STAMP_DEADBAND,
    FixedStepClock,
    RealTimeStepper,
    ScaraSimulator,
    StampSlew,
    VelocityLoop,
    clamp_to_joint_limits,
    clip_torque,
    human_joint_torque,
    joint_command_floats,
    joint_command_from_values,
)

LOWER, UPPER = np.array([-2.3, -2.5]), np.array([2.3, 2.5])


def make_simulator(q=(0.0, 1.2), **kwargs) -> ScaraSimulator:
    params = kwargs.pop('params', ScaraParameters())
    limit = kwargs.pop('effort_limit', 20.0)
    loop = VelocityLoop(kp=[80.0, 20.0], ki=[800.0, 200.0], effort_limit=limit)
    return ScaraSimulator(params=params, q=np.array(q), dq=np.zeros(2), lower=LOWER,
                          upper=UPPER, effort_limit=limit, velocity_loop=loop, **kwargs)


@pytest.mark.parametrize(('values', 'message'), [
    ([1.0], 'expected 2 values, got 1'),
    ([1.0, 2.0, 3.0], 'expected 2 values, got 3'),
    ([1.0, float('nan')], 'non-finite value'),
    ([float('-inf'), 0.0], 'non-finite value'),
])
@pytest.mark.parametrize('read', [joint_command_from_values, joint_command_floats])
def test_malformed_joint_commands_are_rejected(values, message, read):
    with pytest.raises(ValueError, match=message):
        read(values)


def test_joint_command_floats_equal_the_array_reader():
    values = (0.25, -3.5e-7)
    assert joint_command_floats(values) == tuple(joint_command_from_values(values).tolist())
    assert joint_command_floats(np.array(values)) == values


def test_clip_torque_is_symmetric_and_validates_the_limit():
    np.testing.assert_array_equal(clip_torque([30.0, -25.0], 20.0), [20.0, -20.0])
    np.testing.assert_array_equal(clip_torque([3.0, -2.5], 20.0), [3.0, -2.5])
    with pytest.raises(ValueError, match='effort_limit must be finite and > 0'):
        clip_torque([1.0, 1.0], 0.0)


def test_human_torque_does_the_same_work_as_the_force():
    rng = np.random.default_rng(0)
    q, dq = rng.uniform(-2, 2, (20, 2)), rng.uniform(-1, 1, (20, 2))
    force = rng.uniform(-10, 10, (20, 2))
    tau = human_joint_torque(q, force, 0.35, 0.30)
    tip_velocity = np.einsum('...ij,...j->...i', jacobian(q, 0.35, 0.30), dq)
    np.testing.assert_allclose(np.sum(tau * dq, -1), np.sum(force * tip_velocity, -1))


def test_clamp_to_joint_limits_stops_only_motion_into_the_limit():
    q, dq = clamp_to_joint_limits([2.4, -2.6], [1.0, -1.0], LOWER, UPPER)
    np.testing.assert_array_equal(q, [2.3, -2.5])
    np.testing.assert_array_equal(dq, [0.0, 0.0])
    q, dq = clamp_to_joint_limits([2.3, -2.5], [-1.0, 1.0], LOWER, UPPER)
    np.testing.assert_array_equal(dq, [-1.0, 1.0])
    q, dq = clamp_to_joint_limits([0.1, 0.2], [3.0, -3.0], LOWER, UPPER)
    np.testing.assert_array_equal(q, [0.1, 0.2])
    np.testing.assert_array_equal(dq, [3.0, -3.0])


def test_positive_effort_on_joint_one_turns_it_positive_and_is_clipped():
    sim = make_simulator()
    for _ in range(200):
        sim.step('effort', [50.0, 0.0], [0.0, 0.0])
    np.testing.assert_array_equal(sim.applied_effort, [20.0, 0.0])
    assert sim.q[0] > 0.0 and sim.dq[0] > 0.0


def test_idle_mode_applies_zero_torque_and_friction_stops_the_arm():
    sim = make_simulator()
    sim.dq = np.array([1.0, -1.0])
    energy0 = kinetic_energy(sim.q, sim.dq, sim.params)
    for _ in range(5000):
        sim.step('idle', None, [0.0, 0.0])
    np.testing.assert_array_equal(sim.applied_effort, [0.0, 0.0])
    assert kinetic_energy(sim.q, sim.dq, sim.params) < 1e-4 * energy0


def test_human_force_alone_moves_the_tip_along_the_force():
    sim = make_simulator()
    tip0 = forward_kinematics(sim.q, 0.35, 0.30)
    for _ in range(300):
        sim.step('idle', None, [5.0, 0.0])
    displacement = forward_kinematics(sim.q, 0.35, 0.30) - tip0
    # The tip accelerates along J M^-1 J^T f, which is within 90 degrees of f.
    assert displacement[0] > 0.01


def test_joint_limit_holds_against_a_constant_torque():
    sim = make_simulator(q=(2.2, 1.2))
    for _ in range(2000):
        sim.step('effort', [10.0, 0.0], [0.0, 0.0])
    assert sim.q[0] == pytest.approx(2.3)
    assert sim.dq[0] == 0.0


def test_step_returns_the_state_it_sets_and_follows_new_limits():
    sim = make_simulator(q=(2.2, 1.2))
    for mode, command in (('effort', (3.0, -1.0)), ('velocity', (0.2, 0.1)), ('idle', None)):
        q, dq, effort = sim.step(mode, command, (1.0, -2.0))
        assert (q, dq, effort) == (tuple(sim.q.tolist()), tuple(sim.dq.tolist()),
                                   tuple(sim.applied_effort.tolist()))
    sim.upper = np.array([2.0, 2.5])  # as the node swaps the limits on a parameter change
    q, _, _ = sim.step('effort', (10.0, 0.0), (0.0, 0.0))
    assert q[0] == 2.0


def test_velocity_loop_tracks_the_command_and_resists_the_human():
    sim = make_simulator()
    command = np.array([0.3, -0.2])
    for _ in range(1000):
        sim.step('velocity', command, [5.0, 5.0])
    # The human's J^T f changes with q: a ramp disturbance, tracked with a small lag.
    np.testing.assert_allclose(sim.dq, command, atol=5e-3)
    assert np.all(np.abs(sim.applied_effort) < 20.0)


def test_velocity_loop_integral_does_not_wind_up_in_saturation():
    loop = VelocityLoop(kp=[80.0, 20.0], ki=[800.0, 200.0], effort_limit=5.0)
    for _ in range(1000):
        tau = loop.torque([10.0, 0.0], [0.0, 0.0], 1e-3)
    assert tau[0] == 5.0
    assert loop.integral[0] == 0.0
    loop.reset()
    np.testing.assert_array_equal(loop.integral, [0.0, 0.0])


def test_simulator_rejects_an_initial_state_outside_the_limits():
    with pytest.raises(ValueError, match='outside the joint limits'):
        make_simulator(q=(2.5, 0.0))
    with pytest.raises(ValueError, match="unknown command mode 'torque'"):
        make_simulator().step('torque', [0.0, 0.0], [0.0, 0.0])


def test_fixed_step_clock_counts_late_ticks_and_bounds_catch_up():
    clock = FixedStepClock(dt=1e-3, max_catch_up=5, start=10.0)
    assert clock.steps_due(10.0) == 0
    assert clock.next_step_end == pytest.approx(10.001)
    assert clock.steps_due(10.0011) == 1          # slightly late: one step
    assert clock.steps_due(10.0019) == 0          # a tenth of a step early: not yet
    assert clock.steps_due(10.00196) == 1         # within the tolerance: its step
    assert clock.steps_due(10.0040) == 2          # a step late: a burst of two
    assert clock.late_ticks == 1
    assert clock.longest_catch_up == 2
    assert clock.steps_due(10.0058) == 1          # 0.8 ms late: one step, not two
    assert clock.late_ticks == 1
    assert clock.next_step_end == pytest.approx(10.006)
    clock.start_window()
    assert clock.steps_due(10.0155) == 5          # ten owed, five run, five dropped
    assert clock.dropped == 5
    assert clock.longest_catch_up == 10
    assert clock.integrated == 10
    assert clock.sim_time == pytest.approx(0.015)
    assert clock.steps_due(10.0156) == 0
    assert clock.idle_ticks == 3
    with pytest.raises(ValueError, match='max_catch_up must be >= 1'):
        FixedStepClock(dt=1e-3, max_catch_up=0, start=0.0)


def test_no_step_runs_before_its_time_and_ticks_late_by_less_than_a_step_run_one():
    # Ticks at the times the clock asks for, each late by a random amount below a step:
    # every tick runs exactly one step, and no step is run before it has ended.
    rng = np.random.default_rng(3)
    clock = FixedStepClock(dt=1e-3, max_catch_up=50, start=0.0)
    for _ in range(2000):
        now = clock.next_step_end + rng.uniform(0.0, 0.94e-3)
        assert clock.steps_due(now) == 1
        assert clock.sim_time <= now + EARLY_TOLERANCE * clock.dt
    assert clock.late_ticks == 0 and clock.idle_ticks == 0


def test_float_step_equals_the_array_functions():
    rng = np.random.default_rng(5)
    sim = make_simulator()
    for i in range(500):
        # Near and beyond the limits now and then, so that the stop is exercised too.
        q = rng.uniform(LOWER - 0.05, UPPER + 0.05) if i % 5 == 0 else rng.uniform(-2.0, 2.0, 2)
        sim.q, sim.dq = np.clip(q, LOWER, UPPER), rng.normal(0.0, 2.0, 2)
        command, force = rng.normal(0.0, 15.0, 2), rng.normal(0.0, 20.0, 2)
        mode = ('effort', 'idle')[i % 2]
        tau = clip_torque(command, sim.effort_limit) if mode == 'effort' else np.zeros(2)
        total = tau + human_joint_torque(sim.q, force, sim.params.l1, sim.params.l2)
        q_next, dq_next = rk4_step(sim.q, sim.dq, total, sim.dt, sim.params)
        q_next, dq_next = clamp_to_joint_limits(q_next, dq_next, LOWER, UPPER)
        sim.step(mode, command, force)
        np.testing.assert_allclose(sim.q, q_next, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(sim.dq, dq_next, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(sim.applied_effort, tau)


def test_stepper_returns_every_integrated_step_with_its_own_time():
    stepper = RealTimeStepper(make_simulator(), FixedStepClock(1e-3, 20, start=5.0))
    rng = np.random.default_rng(2)
    now, returned = 5.0, []
    for _ in range(400):
        # Ticks mostly on time, some late by up to 30 ms (beyond max_catch_up: dropped).
        now += 1e-3 if rng.uniform() < 0.9 else rng.uniform(1e-3, 0.03)
        before = stepper.sim.q.copy()
        states = stepper.advance(now, lambda t: ('effort', [1.0, -0.5], [0.0, 0.0]))
        returned.extend(states)
        if states:
            np.testing.assert_array_equal(states[-1].q, stepper.sim.q)
        else:
            np.testing.assert_array_equal(before, stepper.sim.q)
    clock = stepper.clock
    assert clock.late_ticks > 0 and clock.dropped > 0
    assert len(returned) == clock.integrated
    times = np.array([s.sim_time for s in returned])
    assert np.all(np.diff(times) > 0.0) and times[-1] == pytest.approx(clock.sim_time)
    # Each step stands for its own millisecond: consecutive steps 1 ms apart unless dropped.
    gaps = np.round(np.diff(times) / 1e-3).astype(int)
    assert gaps.min() == 1 and gaps.sum() - (gaps.size) == clock.dropped


def test_a_timeout_is_judged_per_step_in_a_caught_up_tick():
    # A command that expires at t = 10.5 ms, and one tick at 20 ms after a stall: the steps
    # ending before the expiry apply it, those after do not, although one tick ran them all.
    stepper = RealTimeStepper(make_simulator(), FixedStepClock(1e-3, 50, start=0.0))
    asked = []

    def inputs(t):
        asked.append(t)
        return ('effort', [2.0, -1.0], [0.0, 0.0]) if t <= 0.0105 else ('idle', None, [0.0, 0.0])

    stepper.advance(0.0, inputs)
    states = stepper.advance(0.020, inputs)
    assert len(states) == 20
    assert asked == pytest.approx([k * 1e-3 for k in range(1, 21)])
    assert [list(s.effort) for s in states[:10]] == [[2.0, -1.0]] * 10
    assert [list(s.effort) for s in states[10:]] == [[0.0, 0.0]] * 10


def test_stamps_follow_a_slewed_system_clock_one_step_apart_and_never_back():
    # The system clock runs 5 ms/s (0.5 %) off the monotonic one for 20 s, then steps back
    # by 30 ms: the stamps (start + simulated time + correction) keep up with the drift
    # within the deadband plus one tick's slew, stay 1 ms apart within 1 %, and go on
    # increasing while the step back is caught up.
    rng = np.random.default_rng(3)
    slew = StampSlew(dt_ns=1_000_000)
    stamps, lag = [], []
    drift = 0.0
    for tick in range(40_000):
        steps = 2 if rng.random() < 0.01 else 1  # a late tick now and then
        drift += 5_000.0 * steps if tick < 20_000 else 0.0
        if tick == 20_000:
            drift -= 30e6
        reading = round(drift + rng.normal(0.0, 500.0))  # two clock reads, 0.5 us apart
        correction = slew.update(reading, steps)
        stamps.append(tick * 1_000_000 + correction)
        if tick < 20_000:
            lag.append(drift - correction)
    periods = np.diff(stamps)
    assert np.all(periods > 0)
    assert np.all(np.abs(periods - np.round(periods / 1e6) * 1e6) <= 10_000)
    assert max(np.abs(lag[100:])) <= STAMP_DEADBAND + 20_000
    assert abs(drift - slew.correction) <= STAMP_DEADBAND + 20_000  # caught up again


def test_stamps_left_alone_within_the_deadband():
    slew = StampSlew(dt_ns=1_000_000)
    assert [slew.update(drift, 1) for drift in (0, 40_000, -40_000, 49_999)] == [0, 0, 0, 0]
