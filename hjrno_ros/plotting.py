"""Figures of value functions: x-y slices of the BRT {V ≤ 0} with the obstacle {l ≤ 0} drawn."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .grids import GridSpec  # noqa: E402

LEGEND = "(grey: obstacle l≤0, red: BRT V∞≤0)"


def _slice_indices(n: int, count: int) -> list[int]:
    return sorted(set(np.linspace(0, n - 1, count).round().astype(int).tolist()))


def _panel(ax, grid: GridSpec, target: np.ndarray, value: np.ndarray, i: int, j: int | None) -> None:
    """One x-y slice at third-axis index i (v, or ψ for Air3D) and θ index j (car only)."""
    x, y = grid.axis(0), grid.axis(1)
    idx = (slice(None), slice(None), i) + (() if j is None else (j,))
    v, l_ = value[idx].T, target[idx].T
    if v.min() < 0:
        ax.contourf(x, y, v, levels=[v.min() - 1, 0.0], colors=["#f4a6a6"])
        ax.contour(x, y, v, levels=[0.0], colors=["#b00000"], linewidths=1.2)
    if l_.min() < 0:
        ax.contourf(x, y, l_, levels=[l_.min() - 1, 0.0], colors=["#404040"])
    label = f"{'v' if grid.ndim == 4 else 'ψ'}={grid.axis(2)[i]:.2f}"
    if j is not None:
        label += f", θ={grid.axis(3)[j]:.2f}"
    ax.set_title(label, fontsize=9)
    ax.set_xlim(x[0], x[-1])
    ax.set_ylim(y[0], y[-1])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)


def save_figure(fig, path: str | Path, title: str) -> Path:
    """Title, tighten, write the PNG (folders made as needed) and free the figure."""
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _columns(grid: GridSpec) -> list[tuple[int, int | None]]:
    """(third-axis index, θ index) of the slices shown per sample."""
    if grid.ndim == 3:
        return [(i, None) for i in _slice_indices(grid.shape[2], 4)]
    mid_v, top_v = grid.shape[2] // 2, grid.shape[2] - 1
    quarter = grid.shape[3] // 4
    return [(0, 0), (mid_v, 0), (top_v, 0), (top_v, quarter)]


def brt_slices(path: str | Path, grid: GridSpec, target: np.ndarray, value: np.ndarray, title: str = "") -> Path:
    """PNG of x-y slices: rows over the third axis (v, or ψ for Air3D), columns over θ (car only)."""
    rows = _slice_indices(grid.shape[2], 3)
    cols = list(range(0, grid.shape[3], max(1, grid.shape[3] // 4)))[:4] if grid.ndim == 4 else [None]
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.2 * len(cols), 3.0 * len(rows)), squeeze=False)
    for r, i in enumerate(rows):
        for c, j in enumerate(cols):
            _panel(axes[r][c], grid, target, value, i, j)
    return save_figure(fig, path, f"{title}  {LEGEND}")


def dataset_samples(path: str | Path, split, count: int = 4) -> Path:
    """PNG of the first ``count`` samples of a loaded split: one row each, a few (v, θ) slices."""
    count = max(1, min(count, len(split.target)))
    cols = _columns(split.grid)
    fig, axes = plt.subplots(count, len(cols), figsize=(3.0 * len(cols), 2.9 * count), squeeze=False)
    for r in range(count):
        for c, (i, j) in enumerate(cols):
            _panel(axes[r][c], split.grid, split.target[r], split.value[r], i, j)
        axes[r][0].set_ylabel(f"seed {split.scenarios[r].seed}", fontsize=9)
    return save_figure(fig, path, f"{split.config.name} ({split.attrs['split']})  {LEGEND}")
