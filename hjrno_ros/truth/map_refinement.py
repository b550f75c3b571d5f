"""The operator's value over a whole static map, refined by the HJ solver warm-started from it.

The operator predicts V on a robot-centred window in milliseconds, but indoors its turn (the sign of
∂V/∂θ near V = 0) disagrees with the truth's on ~12 % of states, and that turn is what makes its filter
collide.  ``solve(..., initial=W)`` from the operator's prediction W corrects it in a fraction
of a cold solve's time (docs/results.md, warm-start study, 16 indoor rooms: sign agreement 0.875 → 0.919 after
16 simulated s, 8.7 s of wall time per 10 m room here against ~75 s cold; 0 and 0 collisions in 2002
closed-loop episodes against the operator's 6 and 13).  For a map that does not change, that is worth
doing once, in the background, while the operator's windows keep the filter running.

* :func:`warm_start`: the operator's prediction on a map grid (:mod:`hjrno_ros.core.map_tiling`), stitched
  from windows: each x-y node takes the window whose centre is nearest to it (windows overlap by half), at
  every (v, θ) node.
* :func:`refine`: the warm-started solve in stages of simulated time, each stage's table yielded.

The node runs this in a child process (:mod:`hjrno_ros.ros.brt_node.refinement_process`).
Axis order everywhere: V[ix, iy, iv, iθ] (docs/design.md, "Conventions").
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.map_tiling import owners, window_starts

SOLVER = {"accuracy": "high", "tolerance": 3e-3, "criterion": "band"}  # the indoor datasets' settings


def warm_start(vf, v0: np.ndarray, grid: GridSpec) -> np.ndarray:
    """The operator's V on ``grid`` (Nx, Ny, Nv, Nθ) from V0 (Nx, Ny) on its x-y nodes."""
    if v0.shape != grid.shape[:2]:
        raise ValueError(f"V0 shape {v0.shape} does not match the grid's x-y shape {grid.shape[:2]}")
    wx, wy = vf.shape
    vv, tt = np.meshgrid(grid.axis(2), grid.axis(3), indexing="ij")
    out = np.empty(grid.shape, np.float32)
    sx, sy = window_starts(grid.shape[0], wx), window_starts(grid.shape[1], wy)
    ox, oy = owners(grid.shape[0], wx, sx), owners(grid.shape[1], wy, sy)
    for a, i in enumerate(sx):
        for b, j in enumerate(sy):
            slices = vf.predict(v0[i:i + wx, j:j + wy], vv.ravel(), tt.ravel())  # (Nv·Nθ, wx, wy)
            table = np.moveaxis(slices.reshape(*vv.shape, wx, wy), (0, 1), (2, 3))
            mx, my = np.flatnonzero(ox == a), np.flatnonzero(oy == b)
            out[np.ix_(mx, my)] = table[np.ix_(mx - i, my - j)]
    return out


def broadcast_target(v0: np.ndarray, grid: GridSpec) -> np.ndarray:
    """l(x, y, v, θ) = V0(x, y): the target of a map whose obstacles do not depend on the speed."""
    return np.ascontiguousarray(np.broadcast_to(v0[:, :, None, None], grid.shape), np.float32)


def refine(dynamics, grid: GridSpec, target: np.ndarray, initial: np.ndarray, horizon: float, stage: float
           ) -> Iterator[tuple[float, np.ndarray, bool]]:
    """(simulated s so far, table, settled) after each ``stage`` s of the tube of ``target`` l from
    min(initial, l); stops at ``horizon`` or when the solver's tolerance says it settled."""
    from hjrno_ros.truth.solver import solve  # JAX: only where a solve runs

    if not (horizon > 0 and stage > 0):
        raise ValueError(f"need horizon > 0 and stage > 0, got {horizon}, {stage}")
    done, current = 0.0, initial
    while done < horizon - 1e-9:
        length = min(stage, horizon - done)
        current, report = solve(dynamics, grid, target, initial=current, chunk=min(1.0, length),
                                max_horizon=length, **SOLVER)
        done += report.horizon
        yield done, current, report.converged
        if report.converged:
            return
