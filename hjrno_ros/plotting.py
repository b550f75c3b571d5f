"""Figures of value functions: x-y slices of the BRT {V ≤ 0} with the obstacle {l ≤ 0} drawn."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .grids import GridSpec  # noqa: E402


def _slice_indices(n: int, count: int) -> list[int]:
    return sorted(set(np.linspace(0, n - 1, count).round().astype(int).tolist()))


def brt_slices(path: str | Path, grid: GridSpec, target: np.ndarray, value: np.ndarray, title: str = "") -> Path:
    """PNG of x-y slices: rows over the third axis (v, or ψ for Air3D), columns over θ (car only)."""
    x, y = grid.axis(0), grid.axis(1)
    rows = _slice_indices(grid.shape[2], 3)
    cols = list(range(0, grid.shape[3], max(1, grid.shape[3] // 4)))[:4] if grid.ndim == 4 else [None]
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.2 * len(cols), 3.0 * len(rows)), squeeze=False)
    for r, i in enumerate(rows):
        for c, j in enumerate(cols):
            idx = (slice(None), slice(None), i) + (() if j is None else (j,))
            ax = axes[r][c]
            v, l_ = value[idx].T, target[idx].T
            ax.contourf(x, y, v, levels=[v.min() - 1, 0.0], colors=["#f4a6a6"])
            ax.contour(x, y, v, levels=[0.0], colors=["#b00000"], linewidths=1.2)
            ax.contourf(x, y, l_, levels=[l_.min() - 1, 0.0], colors=["#404040"])
            third = grid.axis(2)[i]
            label = f"{'v' if grid.ndim == 4 else 'ψ'}={third:.2f}"
            if j is not None:
                label += f", θ={grid.axis(3)[j]:.2f}"
            ax.set_title(label, fontsize=9)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
    fig.suptitle(f"{title}  (grey: obstacle l≤0, red: BRT V∞≤0)", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
