"""State grids: one description for solver, datasets, interpolation and plots.

Axis convention (docs/design.md, "Conventions"): a value table is ``V[i0, i1, ...]`` with axes in state order,
(x, y, v, θ) for the car and (x, y, ψ) for Air3D, exactly like ``hj_reachability``'s
``grid.states``.  Non-periodic axes include both end points; periodic axes (angles) cover
[-π, π) and exclude the end point.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """Box [lo, hi] sampled with ``shape`` nodes; ``periodic`` lists the periodic axes."""

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    shape: tuple[int, ...]
    periodic: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "lo", tuple(float(v) for v in self.lo))
            object.__setattr__(self, "hi", tuple(float(v) for v in self.hi))
            object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))
            object.__setattr__(self, "periodic", tuple(int(i) for i in self.periodic))
        except (TypeError, ValueError, OverflowError):  # e.g. a periodic axis of inf in an edited card
            raise ValueError(f"grid lo, hi need numbers, shape and periodic whole numbers, got {self.lo}, {self.hi}, "
                             f"{self.shape}, {self.periodic}") from None
        n = len(self.shape)
        if not (len(self.lo) == len(self.hi) == n) or n == 0:
            raise ValueError(f"grid lo, hi and shape need one entry per axis, got {self.lo}, {self.hi}, {self.shape}")
        if any(not (math.isfinite(a) and math.isfinite(b) and a < b) for a, b in zip(self.lo, self.hi, strict=False)):
            raise ValueError(f"grid bounds must be finite with lo < hi, got lo={self.lo} hi={self.hi}")
        if any(k < (3 if i in self.periodic else 2) for i, k in enumerate(self.shape)):
            raise ValueError(f"every grid axis needs at least 2 nodes (periodic: 3), got shape {self.shape}")
        if any(not 0 <= i < n for i in self.periodic):
            raise ValueError(f"periodic axes {self.periodic} out of range for a {n}-D grid")

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def spacings(self) -> tuple[float, ...]:
        return tuple(
            (b - a) / (k if i in self.periodic else k - 1)
            for i, (a, b, k) in enumerate(zip(self.lo, self.hi, self.shape, strict=False))
        )

    @property
    def half_cell_diagonal(self) -> float:
        """Half the diagonal of an x-y cell, m: the most by which the multilinear interpolation of a
        1-Lipschitz function of (x, y), such as the signed distance l, exceeds the function itself
        (h/√2 for square cells of side h).  Inflating by it makes a grid's target conservative."""
        return float(np.hypot(*self.spacings[:2]) / 2)

    def axis(self, i: int) -> np.ndarray:
        """Coordinates of the nodes along axis ``i``."""
        return np.linspace(self.lo[i], self.hi[i], self.shape[i], endpoint=i not in self.periodic)

    def axes(self) -> tuple[np.ndarray, ...]:
        return tuple(self.axis(i) for i in range(self.ndim))

    def states(self) -> np.ndarray:
        """All nodes as an array ``(*shape, ndim)``."""
        return np.stack(np.meshgrid(*self.axes(), indexing="ij"), axis=-1)

    def with_shape(self, shape: tuple[int, ...]) -> GridSpec:
        return dataclasses.replace(self, shape=tuple(shape))

    def as_dict(self) -> dict:
        return {"lo": list(self.lo), "hi": list(self.hi), "shape": list(self.shape), "periodic": list(self.periodic)}

    @classmethod
    def from_dict(cls, d: dict) -> GridSpec:
        return cls(tuple(d["lo"]), tuple(d["hi"]), tuple(d["shape"]), tuple(d.get("periodic", ())))


def car_grid(
    shape: tuple[int, int, int, int] = (40, 40, 12, 20),
    xy_lo: tuple[float, float] = (-5.0, -5.0),
    xy_hi: tuple[float, float] = (5.0, 5.0),
    v_range: tuple[float, float] = (0.0, 1.0),
) -> GridSpec:
    """(x, y, v, θ) grid of the car: a 10 m × 10 m window by default, θ periodic on [-π, π)."""
    if len(shape) != 4:
        raise ValueError(f"a car grid has 4 axes (x, y, v, theta), got shape {shape}")
    return GridSpec((*xy_lo, v_range[0], -math.pi), (*xy_hi, v_range[1], math.pi), tuple(shape), (3,))


def air3d_grid(
    shape: tuple[int, int, int] = (51, 40, 50),
    xy_lo: tuple[float, float] = (-6.0, -10.0),
    xy_hi: tuple[float, float] = (20.0, 10.0),
) -> GridSpec:
    """(x, y, ψ) relative grid of Air3D, ψ periodic on [-π, π) (hj_reachability's example domain)."""
    if len(shape) != 3:
        raise ValueError(f"an Air3D grid has 3 axes (x, y, psi), got shape {shape}")
    return GridSpec((*xy_lo, -math.pi), (*xy_hi, math.pi), tuple(shape), (2,))


def wrap_angle(a):
    """Wrap angles to [-π, π)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
