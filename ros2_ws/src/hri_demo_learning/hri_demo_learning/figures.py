"""Figures of a learned task, like the paper's Fig. 3 (b)-(d).

The normalised task energy P_d/||P_d|| of the demonstration samples (eq. 3, 4) is drawn
against the distance to x_r as the median of each of at most `PROFILE_BINS` distance bins
(points) with the 5-95 % band of the samples in it, the fitted potential P (eq. 2) as a line
scaled by the same ||P|| over all the samples as in eq. 7, and the desired region shaded.
Binning bounds the drawing whatever the bag's length: a million scattered points took the
learner 6-9 s to draw, the bins a fraction of a second, and they show the same profile.
Drawing uses
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
PROFILE_BINS = 300  # distance bins of the drawn demonstration (points drawn: at most this)
_BAND = (5.0, 95.0)  # percentiles of each bin's band
_MAX_LOG = 700.0  # keeps exp() finite when P at a grid point dwarfs P at the samples


def _desired_spans(shape, right):
    """(start, end) intervals in m of the desired region (P = 0) within [0, right]."""
    if shape.s == 1:
        spans = [(shape.d1, min(shape.d2, right))]
    else:
        spans = [(0.0, min(shape.d1, right)), (shape.d2, right)]
    return [(start, end) for start, end in spans if end > start]


def binned_profile(distance, values, bins: int = PROFILE_BINS):
    """The samples summarised per distance bin, for drawing.

    distance, values: (N,) finite; bins >= 1 equal bins over [min, max] of distance. Returns
    (centre, median, low, high), each (B,) with B <= bins (bins without samples left out):
    the median distance and value of each bin's samples and the _BAND percentiles of its
    values. O(N log N), one sort.
    """
    d = np.asarray(distance, dtype=float)
    v = np.asarray(values, dtype=float)
    low, high = float(np.min(d)), float(np.max(d))
    width = (high - low) / bins if high > low else 1.0
    index = np.minimum(((d - low) / width).astype(np.int64), bins - 1)
    order = np.lexsort((v, index))
    index, d_sorted, v_sorted = index[order], d[order], v[order]
    starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
    ends = np.r_[starts[1:], index.size]
    summary = np.empty((4, starts.size))
    for column, (start, end) in enumerate(zip(starts, ends, strict=True)):
        in_bin = v_sorted[start:end]  # sorted by value within the bin
        summary[:, column] = (np.median(d_sorted[start:end]), np.median(in_bin),
                              *np.percentile(in_bin, _BAND))
    return tuple(summary)


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
    """Write a PNG of the fit: P_d/||P_d|| (binned) and P/||P|| (line) against |x - x_r|.

    distance: (N,) m; energy: (N,) P_d, not all zero; shape: TaskShape of the fitted P;
    path: PNG file to write (its folder is created); title: figure title; reference: None, or
    (TaskShape, label) of another P drawn the same way (dashed), e.g. the paper's row.
    Returns the Path written. Raises ValueError for unusable input. The demonstration is
    drawn as PROFILE_BINS distance bins (median and band), however long it is; the
    normalisation uses every sample.
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
    centre, median, band_low, band_high = binned_profile(d, demonstrated)
    axes.fill_between(centre, band_low, band_high, color='tab:blue', alpha=0.25, linewidth=0,
                      label='demonstration, 5-95 % per distance bin')
    axes.scatter(centre, median, s=8, color='tab:blue',
                 label=r'demonstration $P_d/\|P_d\|$ (median per bin)')
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
