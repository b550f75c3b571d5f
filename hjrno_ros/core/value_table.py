"""A value table V on a grid, evaluated with its gradient at arbitrary states (numpy alone).

Used wherever ground truth drives a decision: rollouts that validate the solver, the ground-truth
safety filter, evaluation.  Multilinear interpolation of V and of its central-difference
gradient (periodic axes wrap, other axes clamp to the grid's box).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hjrno_ros.core.grids import GridSpec


class ValueTable:
    """V[i0, i1, ...] on ``grid`` with ``value(states)``, ``gradient(states)`` and both at once."""

    def __init__(self, grid: GridSpec, values: np.ndarray):
        values = np.asarray(values, np.float64)
        if values.shape != grid.shape:
            raise ValueError(f"value table shape {values.shape} does not match grid shape {grid.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError("value table has NaN/Inf entries")
        self.grid = grid
        self.values = values
        self._vg: np.ndarray | None = None  # [..., (V, ∂V/∂x0, ...)], made on first use

    def prepare_gradient(self) -> None:
        """Make the central-difference gradient now (a window's table: milliseconds), not at the first gradient
        lookup: V and its partials stacked in one array, interpolated together (linear interpolation is per
        component), so a lookup of V and ∇V costs one call."""
        if self._vg is not None:
            return
        grid, values = self.grid, self.values
        grads = [self._unpad(np.gradient(self._padded(values, i), h, axis=i), i) for i, h in enumerate(grid.spacings)]
        self._vg = np.stack([values, *grads], -1)

    def _padded(self, a: np.ndarray, axis: int) -> np.ndarray:
        return np.concatenate([a.take([-1], axis), a, a.take([0], axis)], axis) if axis in self.grid.periodic else a

    def _unpad(self, a: np.ndarray, axis: int) -> np.ndarray:
        n = self.grid.shape[axis]
        return a.take(range(1, n + 1), axis) if axis in self.grid.periodic else a

    def inside(self, states: np.ndarray, axes: tuple[int, ...] | None = None) -> np.ndarray:
        """True where the states lie within the grid's box on the given (default: non-periodic) axes."""
        s = np.asarray(states)
        axes = tuple(i for i in range(self.grid.ndim) if i not in self.grid.periodic) if axes is None else axes
        ok = np.ones(s.shape[:-1], bool)
        for i in axes:
            ok &= (s[..., i] >= self.grid.lo[i]) & (s[..., i] <= self.grid.hi[i])
        return ok

    def value_and_gradient(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """V ``(...)`` and ∇V ``(..., ndim)`` at ``states`` ``(..., ndim)``."""
        self.prepare_gradient()
        out = multilinear(self._vg, self.grid, self._coords(states))
        return out[..., 0], out[..., 1:]

    def value(self, states: np.ndarray) -> np.ndarray:
        """V ``(...)`` at ``states`` ``(..., ndim)`` (the same interpolation as :meth:`value_and_gradient`'s, without
        the gradient: the least-restrictive filter reads values only)."""
        return multilinear(self.values, self.grid, self._coords(states))

    def _coords(self, states: np.ndarray) -> np.ndarray:
        """``states`` ``(..., ndim)`` as one coordinate array per axis; one state ``(ndim,)`` counts as ``(1, ndim)``,
        as in scipy's interpolators."""
        s = np.asarray(states, np.float64)
        s = s[None] if s.ndim == 1 else s
        if s.shape[-1] != self.grid.ndim:
            raise ValueError(f"states need {self.grid.ndim} components in the last axis, got shape {s.shape}")
        return np.moveaxis(s, -1, 0)

    def gradient(self, states: np.ndarray) -> np.ndarray:
        return self.value_and_gradient(states)[1]


class ReversingTable:
    """A forward-speed car table (v ∈ [0, v_max]) answered at reversing states by symmetry:
    V(x, y, v, θ) = V(x, y, −v, θ + π) for v < 0, so ∂V/∂v flips sign and the other partials carry over.
    Exact for the dynamic Dubins car with a ball disturbance (core/similarity.py, Coverage, says why a forward
    table also holds for any v_min ∈ [−v_max, 0] when d₀ = 0)."""

    def __init__(self, table: ValueTable):
        if table.grid.ndim != 4 or table.grid.lo[2] != 0:
            raise ValueError(f"a reversing table needs a car table over v >= 0, got speeds from {table.grid.lo}")
        self.table, self.grid = table, table.grid

    def _forward(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the forward states, which were reversing)."""
        s = np.array(states, np.float64, copy=True)
        back = s[..., 2] < 0
        s[..., 2] = np.abs(s[..., 2])
        s[..., 3] = np.where(back, s[..., 3] + np.pi, s[..., 3])
        return s, back

    def inside(self, states: np.ndarray, axes: tuple[int, ...] | None = None) -> np.ndarray:
        return self.table.inside(self._forward(states)[0], axes)

    def value_and_gradient(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s, back = self._forward(states)
        value, grad = self.table.value_and_gradient(s)
        grad[..., 2] = np.where(back, -grad[..., 2], grad[..., 2])
        return value, grad

    def value(self, states: np.ndarray) -> np.ndarray:
        return self.table.value(self._forward(states)[0])

    def prepare_gradient(self) -> None:
        self.table.prepare_gradient()

    def gradient(self, states: np.ndarray) -> np.ndarray:
        return self.value_and_gradient(states)[1]


def multilinear(values: np.ndarray, grid: GridSpec, coords: Any, prefix: tuple[Any, ...] = ()) -> np.ndarray:
    """Multilinear interpolation of ``values[prefix..., i0, i1, ..., channels...]`` on ``grid`` at ``coords`` (one
    array per grid axis, broadcast together; ``prefix``: index arrays of leading axes that are not interpolated, e.g.
    a table per level; trailing axes are channels, interpolated alike): periodic axes wrap, the others clamp to the
    grid's box, a non-finite coordinate gives NaN.  A few numpy operations per corner: cheaper than scipy's
    interpolator for the few states of a command."""
    coords = np.broadcast_arrays(*(np.asarray(c, np.float64) for c in coords), *prefix)
    prefix, coords = coords[len(coords) - len(prefix):], coords[:len(coords) - len(prefix)]
    shape = coords[0].shape
    bad = ~np.isfinite(coords).all(0)
    lo, n, h = np.asarray(grid.lo)[:, None], np.asarray(grid.shape)[:, None], np.asarray(grid.spacings)[:, None]
    f = (np.where(bad, 0.0, coords).reshape(len(coords), -1) - lo) / h  # (ndim, N) in index units
    periodic = np.isin(np.arange(len(coords)), list(grid.periodic))[:, None]
    f = np.where(periodic, np.mod(f, n), np.clip(f, 0.0, n - 1))
    i0 = np.minimum(np.floor(f).astype(int), np.where(periodic, n - 1, np.maximum(n - 2, 0)))
    i1 = np.where(periodic, (i0 + 1) % n, np.minimum(i0 + 1, n - 1))
    t = f - i0
    bits = (np.arange(1 << len(coords))[:, None] >> np.arange(len(coords))) & 1  # (corners, ndim)
    index = np.where(bits[:, :, None] == 1, i1, i0)  # (corners, ndim, N)
    weight = np.where(bits[:, :, None] == 1, t, 1.0 - t).prod(1)  # (corners, N)
    corners = values[(*(np.reshape(p, -1) for p in prefix), *np.moveaxis(index, 1, 0))]  # (corners, N, channels...)
    channels = corners.shape[2:]
    out = (weight.reshape(weight.shape + (1,) * len(channels)) * corners).sum(0).reshape(shape + channels)
    return np.where(bad.reshape(shape + (1,) * len(channels)), np.nan, out)


def value_table(grid: GridSpec, values: np.ndarray) -> ValueTable | ReversingTable:
    """``values`` on ``grid`` as a table; a whole forward-speed table (periodic θ, v from 0) also answers reversing
    states, by symmetry."""
    table = ValueTable(grid, values)
    return ReversingTable(table) if grid.periodic and grid.lo[2] == 0 else table
