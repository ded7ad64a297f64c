"""The kill test's judges (tests/fault_tools.py) on made-up streams: what counts as the
controller's gap, and what the scheduling canaries excuse. No ROS process."""

import numpy as np
import pytest

from tests.fault_tools import controller_gaps, machine_stall

START = 1_800_000_000.0  # s, a system-clock time


def sim_stream(held: slice, count: int = 100, period: float = 1e-3):
    """Joint states sent every `period` s from START; the applied effort changes every step
    except over `held`, where one command stays applied."""
    sent = START + period * np.arange(count)
    efforts = np.column_stack((0.1 + 0.001 * np.arange(count), np.full(count, -0.2)))
    efforts[held] = efforts[held.start]
    return sent, efforts


def test_a_held_command_with_no_command_sent_is_a_gap_of_its_sending_time():
    sent, efforts = sim_stream(slice(20, 51))
    commands = np.concatenate((sent[:20] + 5e-4, sent[51:] + 5e-4))
    gaps = controller_gaps(sent, efforts, commands, 0.005)
    assert len(gaps) == 1
    at, span, spacing = gaps[0]
    assert at == sent[20]
    # Times near 1.8e9 s carry about 0.2 us of float resolution.
    assert span == pytest.approx(0.030, abs=1e-6)
    assert spacing == pytest.approx(1e-3, abs=1e-6)


def test_a_command_sent_inside_the_hold_or_a_short_hold_is_no_gap():
    sent, efforts = sim_stream(slice(20, 51))
    answered = np.append(sent + 5e-4, sent[30] + 2e-4)
    assert controller_gaps(sent, efforts, answered, 0.005) == []
    sent, efforts = sim_stream(slice(20, 24))
    assert controller_gaps(sent, efforts, np.array([]), 0.005) == []


def test_steps_caught_up_at_once_are_no_gap_however_far_their_stamps_span():
    # A sim held back 30 ms sends its 30 caught-up steps, one command applied, within 0.3 ms.
    sent, efforts = sim_stream(slice(20, 51))
    sent[20:51] = sent[20] + np.linspace(0.0, 3e-4, 31)
    sent[51:] = sent[50] + 1e-3 * np.arange(1, 50)
    assert controller_gaps(sent, efforts, np.array([]), 0.005) == []


def test_a_sim_that_sent_nothing_for_longer_than_steady_or_held_zero_is_not_judged():
    sent, efforts = sim_stream(slice(20, 51))
    sent[35:] += 0.02  # the sim itself stopped for 20 ms inside the hold
    assert controller_gaps(sent, efforts, np.array([]), 0.005, steady=0.008) == []
    sent, efforts = sim_stream(slice(20, 51))
    efforts[20:51] = 0.0  # zero torque: a documented timeout, not a held command
    assert controller_gaps(sent, efforts, np.array([]), 0.005) == []
    assert controller_gaps(sent, *sim_stream(slice(20, 51))[1:], np.array([]), 0.005,
                           since=START + 1.0) == []


def test_machine_stall_is_the_longest_canary_stall_overlapping_the_stretch():
    # A stall ends at its wake-up time: (wake, lateness).
    stalls = np.array([[START + 0.010, 0.004], [START + 0.050, 0.012], [START + 0.200, 0.09]])
    assert machine_stall(stalls, START + 0.040, START + 0.060) == 0.012
    assert machine_stall(stalls, START + 0.0, START + 0.060) == 0.012
    assert machine_stall(stalls, START + 0.115, START + 0.150) == 0.09  # 0.110 to 0.200
    assert machine_stall(stalls, START + 0.060, START + 0.100) == 0.0
    assert machine_stall(np.empty((0, 2)), START, START + 1.0) == 0.0
