"""A trained operator behind one call, whatever runs it (torch, onnxruntime): an obstacle window + the robot state
→ a value table around the robot.

The model was trained on windows of fixed physical size (``window``, from its card) centred on
the origin; at run time the window is centred on the robot, axis-aligned with the map frame, so
headings stay map-frame headings.  V0 is the signed distance sampled at the model's x-y nodes
(the card's grid: the FNO and TNO would take other resolutions of the window, the CNN would not).

A *table* model predicts every (v, θ) node of the card's grid in one forward pass: the node then holds the
whole table of the window, and every speed and heading the robot can reach is in it.  For a robot that rests
safely (d₀ = 0) the rest slice is not predicted but exact, V(x, y, 0, θ) = V0(x, y) (docs/design.md, "Robot
models").  A *slice* model predicts a (v, θ) stencil of slices around the robot's speed and heading: at least
one grid cell centred on the state (2 × 2 slices), widened to what the robot reaches before the next table
(:meth:`OperatorValues.local_values`).  Either way a :class:`ValueTable` gives V and ∇V (x, y, v, θ)
at any state it covers.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.model_card import ModelCard
from hjrno_ros.core.model_inputs import InputSpec, param_value
from hjrno_ros.core.value_table import ReversingTable, ValueTable, value_table

Forward = Callable[[np.ndarray], np.ndarray]
"""The operator: inputs (B, C, Nx, Ny) float32 → outputs (B, O, Nx, Ny) float32, in model units."""


class OperatorValues:
    """A card's operator as a :class:`~hjrno_ros.core.value_source.ValueSource`: V on windows centred on the robot,
    from ``forward``, the network run by torch (:class:`hjrno_ros.learning.value_function.LearnedValueFunction`) or
    by onnxruntime (:mod:`hjrno_ros.inference.onnx_operator`)."""

    def __init__(self, card: ModelCard, forward: Forward, stem: str | Path = "", runtime: str = "") -> None:
        self.card, self.forward, self.runtime = card, forward, runtime
        self.spec = InputSpec.from_dict(card.inputs)
        if self.spec.kind != "car":
            raise ValueError(f"{stem}: the filter needs a car model, this one is {self.spec.kind!r}")
        self.grid: GridSpec = card.grid
        self.params: RobotParams = card.dynamics
        self.epsilon = card.epsilon  # None when uncalibrated; the filter's default: card.margin()
        self.whole_table = self.spec.table is not None  # every (v, θ) of the window in one pass
        self.predicts = True  # a ValueSource with an operator (core/value_source.py)

    @property
    def window(self) -> tuple[float, float]:
        """Physical window size (x, y) in metres."""
        return self.card.window

    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape[0], self.grid.shape[1]

    def window_points(self, center: tuple[float, float], shape: tuple[int, int] | None = None) -> np.ndarray:
        """World (x, y) of the window's nodes, ``(Nx, Ny, 2)``, for a window centred at ``center``."""
        nx, ny = shape or self.shape
        x = np.linspace(self.grid.lo[0], self.grid.hi[0], nx) + center[0]
        y = np.linspace(self.grid.lo[1], self.grid.hi[1], ny) + center[1]
        return np.stack(np.meshgrid(x, y, indexing="ij"), -1)

    def predict(self, v0: np.ndarray, speeds: np.ndarray, headings: np.ndarray,
                params: np.ndarray | None = None) -> np.ndarray:
        """V slices (K, Nx, Ny) in metres for V0 (Nx, Ny) in metres at K (speed, heading) pairs (a slice model)."""
        v0 = self._checked(v0)
        if self.whole_table:
            raise ValueError("a table model predicts whole tables: use table()")
        k = len(speeds)
        x = self.spec.array(np.broadcast_to(v0, (k, *v0.shape)), np.asarray(speeds), np.asarray(headings), params)
        out = self.forward(x)[:, 0] * self.spec.value_scale
        return np.minimum(out, v0[None])  # V∞ ≤ V0 holds for the true value function

    @staticmethod
    def _checked(v0: np.ndarray) -> np.ndarray:
        v0 = np.asarray(v0, np.float32)
        if v0.ndim != 2 or not np.all(np.isfinite(v0)):
            raise ValueError(f"V0 must be a finite 2-D array, got shape {v0.shape}")
        return v0

    def table(self, v0: np.ndarray, robot: RobotParams | None = None) -> np.ndarray:
        """The whole table V[ix, iy, iv, iθ] in metres on the card's grid for V0 (Nx, Ny), one forward pass (a table
        model); ``robot``: a covered robot in the card's units.  V ≤ V0, and the rest slice is V0 where d₀ = 0."""
        v0 = self._checked(v0)
        params = self.condition(robot)
        out = self.forward(self.spec.array(v0[None], np.zeros(1), np.zeros(1), params))
        nv, nt = self.spec.table
        table = np.moveaxis(out[0].reshape(nv, nt, *v0.shape), (0, 1), (2, 3)) * self.spec.value_scale
        table = np.minimum(table, v0[:, :, None, None])
        if self.params.d0 == 0 and self.grid.lo[2] == 0:
            table[:, :, 0, :] = v0[:, :, None]
        return table

    def condition(self, robot: RobotParams | None = None) -> np.ndarray | None:
        """The parameter channels for ``robot`` in the card's units (default: the card's own car), (1, P)."""
        names = list(self.spec.param_ranges)
        if not names:
            return None
        values = dataclasses.asdict(robot or self.params)
        return np.array([[param_value(values, name) for name in names]], np.float32)

    def local_values(self, v0: np.ndarray, center: tuple[float, float], v: float, theta: float,
                     robot: RobotParams | None = None, reach: tuple[float, float] = (0.0, 0.0)
                     ) -> tuple[GridSpec, np.ndarray]:
        """(grid, V on it) over the window centred at ``center``: a table model's whole (v, θ) table, or a slice
        model's (v, θ) stencil around the state: v ± dv/2 and θ ± dθ/2 (dv, dθ the card grid's steps; v kept within
        [v_min, v_max]), or with a ``reach`` (speed, heading) the card grid's nodes spanning v ± reach[0] and
        θ ± reach[1], so the table holds every speed and heading the robot reaches before the next one;
        mirrored for a reversing state of a forward-only card (V(x, y, −v, θ) = V(x, y, v, θ + π);
        core/similarity.py, Coverage).  ``robot``: a covered robot in the card's units (its parameter channels)."""
        g = self.grid
        if self.whole_table:
            grid = GridSpec((g.lo[0] + center[0], g.lo[1] + center[1], *g.lo[2:]),
                            (g.hi[0] + center[0], g.hi[1] + center[1], *g.hi[2:]), g.shape, g.periodic)
            return grid, self.table(v0, robot)
        mirror = v < 0 and self.params.v_min >= 0
        dv, dtheta = g.spacings[2], g.spacings[3]
        speed = float(-v if mirror else v)
        if reach[0] <= dv / 2:  # one cell centred on the state, kept within the speed range
            speed = float(np.clip(speed, self.params.v_min + dv / 2, self.params.v_max - dv / 2))
        speeds = _levels(speed, dv, reach[0], g.lo[2], (max(g.lo[2], self.params.v_min), g.hi[2]))
        headings = _levels(theta, dtheta, reach[1], g.lo[3])
        vv, tt = np.meshgrid(speeds, headings + (np.pi if mirror else 0.0), indexing="ij")
        params = self.condition(robot)
        slices = self.predict(v0, vv.ravel(), tt.ravel(), None if params is None else np.repeat(params, vv.size, 0))
        nx, ny = v0.shape
        table = np.moveaxis(slices.reshape(*vv.shape, nx, ny), (0, 1), (2, 3))
        if mirror:
            speeds, table = -speeds[::-1], table[:, :, ::-1]
        grid = GridSpec((g.lo[0] + center[0], g.lo[1] + center[1], speeds[0], headings[0]),
                        (g.hi[0] + center[0], g.hi[1] + center[1], speeds[-1], headings[-1]), (nx, ny, *vv.shape))
        return grid, table

    def local_table(self, v0: np.ndarray, center: tuple[float, float], v: float, theta: float,
                    robot: RobotParams | None = None, reach: tuple[float, float] = (0.0, 0.0)
                    ) -> ValueTable | ReversingTable:
        """:meth:`local_values` as a table that answers V and ∇V at any state it covers (a whole forward table also
        at reversing states, by symmetry)."""
        return value_table(*self.local_values(v0, center, v, theta, robot, reach))


def _levels(centre: float, step: float, reach: float, origin: float,
            bounds: tuple[float, float] | None = None) -> np.ndarray:
    """The levels of one stencil axis: with no ``reach`` beyond half a ``step``, two levels half a step either side
    of ``centre`` (one grid cell centred on the state); else the grid's own nodes (``origin`` + k·step) from the
    one at or below centre − reach to the one at or above centre + reach, those within ``bounds``.  Grid nodes make the
    interpolation between the two nodes around the state the same whatever the reach (exact similarity)."""
    if reach <= step / 2:
        return np.array([centre - step / 2, centre + step / 2])
    k = np.arange(math.floor((centre - reach - origin) / step + 1e-9), math.ceil((centre + reach - origin) / step
                                                                                 - 1e-9) + 1)
    levels = origin + step * k
    if bounds is not None:
        levels = levels[(levels >= bounds[0] - 1e-9) & (levels <= bounds[1] + 1e-9)]
    return levels
