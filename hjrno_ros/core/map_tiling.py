"""A whole map's (x, y, v, θ) grid at a model's spacings, and its tiling by the model's windows.

Windows placed every half window along each axis have nodes on this grid's nodes, so a map-wide table can be
stitched from window predictions (:func:`hjrno_ros.truth.map_refinement.warm_start`) and refined by the solver
in the node's background process.  Axis order: V[ix, iy, iv, iθ] (docs/design.md, "Conventions").
"""

from __future__ import annotations

import math

import numpy as np

from hjrno_ros.core.grids import GridSpec


def map_grid(model_grid: GridSpec, lo: tuple[float, float], hi: tuple[float, float]) -> GridSpec:
    """The model grid's (v, θ) axes and x-y spacing over the box [lo, hi] (grown to whole steps, centred,
    at least one window): nodes of windows placed every half window coincide with this grid's nodes."""
    h = model_grid.spacings[:2]
    n = [max(model_grid.shape[i], math.ceil((hi[i] - lo[i]) / h[i] - 1e-4) + 1) for i in range(2)]  # float32 maps
    c = [(lo[i] + hi[i]) / 2 for i in range(2)]
    xy_lo = [c[i] - (n[i] - 1) * h[i] / 2 for i in range(2)]
    xy_hi = [c[i] + (n[i] - 1) * h[i] / 2 for i in range(2)]
    return GridSpec((*xy_lo, *model_grid.lo[2:]), (*xy_hi, *model_grid.hi[2:]), (*n, *model_grid.shape[2:]),
                    model_grid.periodic)


def window_starts(n: int, w: int) -> list[int]:
    """First node of each window of ``w`` nodes along an axis of ``n`` (every w//2, the last flush)."""
    return sorted({*range(0, n - w + 1, max(1, w // 2)), n - w})


def owners(n: int, w: int, starts: list[int]) -> np.ndarray:
    """Per node, the index into ``starts`` of the window whose centre is nearest."""
    centres = np.asarray(starts) + (w - 1) / 2
    return np.argmin(np.abs(np.arange(n)[:, None] - centres[None]), axis=1)
