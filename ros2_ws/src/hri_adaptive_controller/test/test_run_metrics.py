"""Unit tests of run_metrics: time to region, steady distance, torque peaks."""

import numpy as np
import pytest

from hri_adaptive_controller.run_metrics import (
    in_region,
    run_metrics,
    steady_distance,
    time_to_region,
)


def approach_run(seed: int = 3):
    """A distance that decays from 0.3 m to 0.02 m (time constant 1 s) with sensor noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, 0.01)
    distance = 0.02 + 0.28 * np.exp(-t) + rng.normal(0.0, 1e-4, t.size)
    tau = np.column_stack([np.exp(-t), -0.5 * np.exp(-t)]) * 4.0
    return t, distance, tau


def test_time_to_region_is_the_last_entry():
    t, distance, _ = approach_run()
    # 0.02 + 0.28 e^-t = 0.041  ->  t = ln(0.28 / 0.021) = 2.590 s
    assert time_to_region(t, distance, 0.0, 0.041) == pytest.approx(2.59, abs=0.05)


def test_leaving_the_region_again_resets_the_entry_time():
    t = np.arange(0.0, 6.0, 0.5)
    distance = np.array([0.3, 0.1, 0.03, 0.03, 0.2, 0.2, 0.03, 0.03, 0.03, 0.03, 0.03, 0.03])
    assert time_to_region(t, distance, 0.0, 0.041) == pytest.approx(3.0)
    assert time_to_region(t, distance, 0.0, 0.041, start=1.0) == pytest.approx(2.0)


def test_never_settling_in_the_region_gives_none():
    t = np.linspace(0.0, 5.0, 51)
    assert time_to_region(t, np.full(51, 0.1), 0.183, 2.0) is None


def test_in_region_with_tolerance():
    mask = in_region([0.17, 0.18, 0.25, 0.28], 0.183, 0.271, tolerance=0.005)
    assert mask.tolist() == [False, True, True, False]


def test_run_metrics_of_an_approach():
    t, distance, tau = approach_run()
    metrics = run_metrics(t, distance, tau, 0.0, 0.041, window=2.0)
    assert metrics.in_region_at_end
    assert metrics.steady_distance == pytest.approx(0.02, abs=1e-3)
    assert metrics.peak_torque == pytest.approx(4.0, rel=1e-6)
    assert metrics.final_peak_torque < 0.01
    assert steady_distance(t, distance, 2.0) == metrics.steady_distance


def test_bad_series_are_rejected():
    with pytest.raises(ValueError, match='matching non-empty'):
        run_metrics([0.0, 1.0], [0.1], np.zeros((2, 2)), 0.0, 0.1)
    with pytest.raises(ValueError, match='finite'):
        time_to_region([0.0, 1.0], [0.1, np.nan], 0.0, 0.1)
