"""Figures of a learned task, like the paper's Fig. 3 (b)-(d).

The normalised task energy P_d/||P_d|| of the demonstration samples (eq. 3, 4) is drawn as
points, the fitted potential P (eq. 2) as a line scaled by the same ||P|| over the samples as in
eq. 7, both against the distance to x_r, with the desired region shaded. Drawing uses
matplotlib's object API on an Agg canvas (no pyplot, no display, no global backend state), so
it works headless and inside a running node.
"""

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from hri_core.potential import log_potential
from hri_demo_learning.task_energy import normalised_energy

_GRID_POINTS = 600
_MAX_DRAWN_SAMPLES = 5000
"""Samples drawn as points at most: an evenly strided subset of a longer demonstration. At 6 px
a point, 5000 of them cover the curve; drawing the 500k samples of a 1M-message bag took
matplotlib 8 s here, longer than learning from it."""
_MAX_LOG = 700.0  # keeps exp() finite when P at a grid point dwarfs P at the samples


def _desired_spans(shape, right):
    """(start, end) intervals in m of the desired region (P = 0) within [0, right]."""
    if shape.s == 1:
        spans = [(shape.d1, min(shape.d2, right))]
    else:
        spans = [(0.0, min(shape.d1, right)), (shape.d2, right)]
    return [(start, end) for start, end in spans if end > start]


def _scaled_curves(d, grid, shape):
    """P/||P|| over the samples d and on the grid, both scaled by ||P|| over the samples."""
    log_samples = log_potential(d, shape)
    if not np.any(np.isfinite(log_samples)):
        return np.zeros_like(d), np.zeros_like(grid)
    top = float(np.max(log_samples))
    log_norm = top + 0.5 * np.log(np.sum(np.exp(2.0 * (log_samples - top))))
    return (np.exp(log_samples - log_norm),
            np.exp(np.minimum(log_potential(grid, shape) - log_norm, _MAX_LOG)))


def plot_task_fit(distance, energy, shape, path, title='', reference=None):
    """Write a PNG of the fit: P_d/||P_d|| (points) and P/||P|| (line) against |x - x_r|.

    distance: (N,) m; energy: (N,) P_d, not all zero; shape: TaskShape of the fitted P;
    path: PNG file to write (its folder is created); title: figure title; reference: None, or
    (TaskShape, label) of another P drawn the same way (dashed), e.g. the paper's row.
    Returns the Path written. Raises ValueError for unusable input. At most
    _MAX_DRAWN_SAMPLES samples are drawn (evenly strided); the normalisation uses them all.
    """
    d = np.asarray(distance, dtype=float)
    e = np.asarray(energy, dtype=float)
    if d.ndim != 1 or e.shape != d.shape or d.size == 0:
        raise ValueError(f'distance and energy must be non-empty (N,) arrays, got {d.shape}, '
                         f'{e.shape}')
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(e))):
        raise ValueError('non-finite input: distance and energy must be finite')
    if np.any(d < 0.0):
        raise ValueError('distance must be >= 0')
    if not np.any(e != 0.0):
        raise ValueError('the task energy P_d is zero on every sample: nothing to draw')

    right = 1.1 * float(np.max(d)) if np.max(d) > 0.0 else 1.0
    grid = np.linspace(0.0, right, _GRID_POINTS)
    fitted_samples, fitted_grid = _scaled_curves(d, grid, shape)
    demonstrated = normalised_energy(e)

    figure = Figure(figsize=(6.4, 4.2), dpi=120)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    for index, (start, end) in enumerate(_desired_spans(shape, right)):
        axes.axvspan(start, end, color='tab:green', alpha=0.15,
                     label='desired region' if index == 0 else None)
    drawn = np.unique(np.linspace(0, d.size - 1, min(d.size, _MAX_DRAWN_SAMPLES)).astype(int))
    axes.scatter(d[drawn], demonstrated[drawn], s=6, color='tab:blue', alpha=0.6,
                 label=r'demonstration $P_d/\|P_d\|$')
    axes.plot(grid, fitted_grid, color='tab:red', linewidth=1.8,
              label=rf'fit $P/\|P\|$: S={shape.s:+d}, $a_1$={shape.a1:.4g}, '
                    rf'$a_2$={shape.a2:.4g}')
    if reference is not None:
        reference_shape, reference_label = reference
        _, reference_grid = _scaled_curves(d, grid, reference_shape)
        axes.plot(grid, reference_grid, color='tab:gray', linewidth=1.5, linestyle='--',
                  label=reference_label)
    ceiling = max(float(np.max(demonstrated)), float(np.max(fitted_samples)))
    axes.set_xlim(0.0, right)
    axes.set_ylim(-0.05 * ceiling, 1.15 * ceiling)
    axes.set_xlabel(r'distance to the reference $\|x - x_r\|$ (m)')
    axes.set_ylabel('normalised energy')
    axes.set_title(title or f'd1 = {shape.d1:.3f} m, d2 = {shape.d2:.3f} m')
    axes.grid(True, alpha=0.3)
    axes.legend(loc='best', fontsize='small')
    figure.tight_layout()

    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(target, format='png')
    return target
