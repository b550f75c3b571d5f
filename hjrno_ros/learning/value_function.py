"""A trained operator behind one call: an obstacle window + the robot state → V and ∇V.

The model was trained on windows of fixed physical size (``window``, from its card) centred on
the origin; at run time the window is centred on the robot, axis-aligned with the map frame, so
headings stay map-frame headings.  V0 is the signed distance sampled at the model's x-y nodes
(the card's grid: the FNO and TNO would take other resolutions of the window, the CNN would not).  For the
filter, the operator predicts the 2 × 2 (v, θ) slices half a grid step either side of the robot's
speed and heading (one grid cell centred on the state, as the solver's grid interpolates), and a
:class:`ValueTable` over that stencil gives V and ∇V (x, y, v, θ) at the state: central differences
over one step in v and θ.  4 slices, not the 9 of a 3 × 3 stencil: inference costs 4/9 as much.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.value_table import ValueTable
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.operators.cnn import CNN
from hjrno_ros.learning.slices import InputSpec, param_value


def channels_last_cnns(model: torch.nn.Module) -> None:
    """Store the CNN members' weights channels-last: oneDNN's faster convolution path on CPU (the bundled
    ensembles 1.2-1.4× faster, outputs equal up to float rounding: docs/results.md, channels-last study).  Only
    CNN modules: the FNO's and TNO's weights are not all 4-D convolution kernels."""
    for module in model.modules():
        if isinstance(module, CNN):
            module.to(memory_format=torch.channels_last)


class LearnedValueFunction:
    def __init__(self, stem, device: str | torch.device | None = None, threads: int | None = None):
        device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        if threads:
            torch.set_num_threads(threads)
        self.model, self.card = checkpoint.load_typed(stem, device)
        self.device = torch.device(device)
        if self.device.type == "cpu":
            channels_last_cnns(self.model)
        self.spec = InputSpec.from_dict(self.card.inputs)
        if self.spec.kind != "car":
            raise ValueError(f"{stem}: the filter needs a car model, this one is {self.spec.kind!r}")
        self.grid: GridSpec = self.card.grid
        self.params: CarParams = self.card.dynamics
        self.epsilon = self.card.epsilon  # None when uncalibrated; the filter's default: self.card.margin()

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

    @torch.no_grad()
    def predict(self, v0: np.ndarray, speeds: np.ndarray, headings: np.ndarray,
                params: np.ndarray | None = None) -> np.ndarray:
        """V slices (K, Nx, Ny) in metres for V0 (Nx, Ny) in metres at K (speed, heading) pairs."""
        v0 = np.asarray(v0, np.float32)
        if v0.ndim != 2 or not np.all(np.isfinite(v0)):
            raise ValueError(f"V0 must be a finite 2-D array, got shape {v0.shape}")
        k = len(speeds)
        x = self.spec.inputs(np.broadcast_to(v0, (k, *v0.shape)), np.asarray(speeds), np.asarray(headings), params)
        out = self.model(x.to(self.device))[:, 0].cpu().numpy() * self.spec.value_scale
        return np.minimum(out, v0[None])  # V∞ ≤ V0 holds for the true value function

    def condition(self, robot: CarParams | None = None) -> np.ndarray | None:
        """The parameter channels for ``robot`` in the card's units (default: the card's own car), (1, P)."""
        names = list(self.spec.param_ranges)
        if not names:
            return None
        values = dataclasses.asdict(robot or self.params)
        return np.array([[param_value(values, name) for name in names]], np.float32)

    def local_table(self, v0: np.ndarray, center: tuple[float, float], v: float, theta: float,
                    robot: CarParams | None = None) -> ValueTable:
        """V over the window × a 2 × 2 (v, θ) stencil (v ± dv/2, θ ± dθ/2, dv and dθ the card grid's
        steps; v kept within [v_min, v_max]): evaluate V and ∇V at the state.  ``robot``: a covered robot in
        the card's units (a conditioned model's channels).  A forward-only card answers a reversing state by
        symmetry, V(x, y, −v, θ) = V(x, y, v, θ + π) (core/similarity.py, Coverage)."""
        mirror = v < 0 and self.params.v_min >= 0
        dv, dtheta = self.grid.spacings[2], self.grid.spacings[3]
        v_mid = float(np.clip(-v if mirror else v, self.params.v_min + dv / 2, self.params.v_max - dv / 2))
        speeds = np.array([v_mid - dv / 2, v_mid + dv / 2])
        headings = np.array([theta - dtheta / 2, theta + dtheta / 2])
        vv, tt = np.meshgrid(speeds, headings + (np.pi if mirror else 0.0), indexing="ij")
        params = self.condition(robot)
        slices = self.predict(v0, vv.ravel(), tt.ravel(), None if params is None else np.repeat(params, 4, 0))
        nx, ny = v0.shape
        table = np.moveaxis(slices.reshape(2, 2, nx, ny), (0, 1), (2, 3))
        if mirror:
            speeds, table = -speeds[::-1], table[:, :, ::-1]
        grid = GridSpec((self.grid.lo[0] + center[0], self.grid.lo[1] + center[1], speeds[0], headings[0]),
                        (self.grid.hi[0] + center[0], self.grid.hi[1] + center[1], speeds[-1], headings[-1]),
                        (nx, ny, 2, 2))
        return ValueTable(grid, table)
