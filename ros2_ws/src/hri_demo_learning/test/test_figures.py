"""Unit tests of hri_demo_learning.figures: the Fig. 3-style plot of a fit."""

import time

import numpy as np
import pytest

from hri_core.potential import TaskShape
from hri_demo_learning.figures import plot_task_fit

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


def test_a_long_demonstration_is_drawn_from_a_strided_subset_in_little_time(tmp_path):
    distance = np.linspace(0.3, 0.041, 500_000)
    started = time.perf_counter()
    plot_task_fit(distance, (distance - 0.041) ** 2, TaskShape(1, 27.06, 1000.0, 0.0, 0.041),
                  tmp_path / 'long.png')
    assert time.perf_counter() - started < 5.0  # all 500k points: 8 s here
