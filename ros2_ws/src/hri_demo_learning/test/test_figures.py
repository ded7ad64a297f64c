"""Unit tests of hri_demo_learning.figures: the Fig. 3-style plot of a fit."""


import numpy as np
import pytest

from hri_core.potential import TaskShape
from hri_demo_learning.figures import binned_profile, plot_task_fit

PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def profile(stop, start, seed=0):
    distance = np.sort(np.random.default_rng(seed).uniform(min(start, stop), max(start, stop),
                                                           300))
    return distance, (distance - stop) ** 2


@pytest.mark.parametrize(('shape', 'data'), [
    (TaskShape(1, 27.06, 1000.0, 0.0, 0.041), profile(0.041, 0.3)),           # follow
    (TaskShape(1, 0.056, 25.46, 0.183, 2.0), profile(0.183, 0.02)),           # P(0) ~ 1e124
    (TaskShape(-1, 14.0, 19.3, 0.1, 0.25), profile(0.175, 0.1)),              # trap
])
def test_figure_is_written(tmp_path, shape, data):
    path = plot_task_fit(*data, shape, tmp_path / 'figures' / 'task.png', title='task')
    assert path == tmp_path / 'figures' / 'task.png'
    content = path.read_bytes()
    assert content.startswith(PNG_SIGNATURE) and len(content) > 10_000


def test_figure_rejects_unusable_data(tmp_path):
    shape = TaskShape(1, 1.0, 10.0, 0.0, 0.041)
    distance, energy = profile(0.041, 0.3)
    with pytest.raises(ValueError, match='nothing to draw'):
        plot_task_fit(distance, np.zeros_like(energy), shape, tmp_path / 'a.png')
    with pytest.raises(ValueError, match='non-finite input'):
        plot_task_fit(distance, np.full_like(energy, np.nan), shape, tmp_path / 'a.png')
    with pytest.raises(ValueError, match=r'non-empty \(N,\) arrays'):
        plot_task_fit(distance, energy[:-1], shape, tmp_path / 'a.png')
    assert not (tmp_path / 'a.png').exists()


def test_binned_profile_gives_each_bins_median_and_band():
    rng = np.random.default_rng(3)
    distance = rng.uniform(0.05, 0.3, 20_000)
    values = distance ** 2 + rng.normal(0.0, 1e-3, distance.size)
    centre, median, low, high = binned_profile(distance, values, bins=50)
    assert centre.size == 50  # every bin holds samples
    edges = np.linspace(distance.min(), distance.max(), 51)
    for k in (0, 17, 49):
        inside = (distance >= edges[k]) & ((distance < edges[k + 1]) if k < 49 else True)
        assert median[k] == pytest.approx(np.median(values[inside]))
        assert centre[k] == pytest.approx(np.median(distance[inside]))
        assert low[k] == pytest.approx(np.percentile(values[inside], 5.0))
        assert high[k] == pytest.approx(np.percentile(values[inside], 95.0))
    assert np.all(low <= median) and np.all(median <= high)


def test_binned_profile_leaves_out_empty_bins_and_takes_one_distance():
    centre, median, _, _ = binned_profile([0.1, 0.1, 0.3], [1.0, 3.0, 5.0], bins=10)
    np.testing.assert_allclose(centre, [0.1, 0.3])
    np.testing.assert_allclose(median, [2.0, 5.0])
    centre, median, _, _ = binned_profile([0.2, 0.2], [1.0, 2.0], bins=10)
    np.testing.assert_allclose((centre, median), ([0.2], [1.5]))
