"""A value table V on a grid, evaluated with its gradient at arbitrary states (numpy, no JAX).

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
        self._vg: Any = None  # scipy's interpolator of V and ∇V, made on first use

    def prepare_gradient(self) -> None:
        """Make the interpolator of [V, ∂V/∂x0, ...] now (milliseconds for a window's table), not at the first
        gradient lookup: one interpolator over the stacked components (linear interpolation is per component), so a
        lookup of V and ∇V costs one call, not two.  scipy.interpolate (~14 MB) is imported only here: the node's
        least-restrictive filter reads values only."""
        if self._vg is not None:
            return
        from scipy import interpolate

        grid, values = self.grid, self.values
        grads = np.stack(
            [self._unpad(np.gradient(self._padded(values, i), grid.spacings[i], axis=i), i) for i in range(grid.ndim)],
            axis=-1,
        )
        stacked = np.concatenate([values[..., None], grads], -1)
        self._vg = interpolate.RegularGridInterpolator(self._axes_closed(), self._close(stacked), bounds_error=False,
                                                       fill_value=None)

    def _padded(self, a: np.ndarray, axis: int) -> np.ndarray:
        return np.concatenate([a.take([-1], axis), a, a.take([0], axis)], axis) if axis in self.grid.periodic else a

    def _unpad(self, a: np.ndarray, axis: int) -> np.ndarray:
        n = self.grid.shape[axis]
        return a.take(range(1, n + 1), axis) if axis in self.grid.periodic else a

    def _close(self, a: np.ndarray) -> np.ndarray:
        """Append the first slice after the last along periodic axes, so interpolation wraps."""
        for ax in self.grid.periodic:
            a = np.concatenate([a, a.take([0], ax)], ax)
        return a

    def _axes_closed(self) -> tuple[np.ndarray, ...]:
        axes = []
        for i, ax in enumerate(self.grid.axes()):
            axes.append(np.append(ax, self.grid.hi[i]) if i in self.grid.periodic else ax)
        return tuple(axes)

    def _query(self, states: np.ndarray) -> np.ndarray:
        s = np.array(states, np.float64, copy=True)
        if s.shape[-1] != self.grid.ndim:
            raise ValueError(f"states need {self.grid.ndim} components in the last axis, got shape {s.shape}")
        lo, hi = np.asarray(self.grid.lo), np.asarray(self.grid.hi)
        for i in range(self.grid.ndim):
            if i in self.grid.periodic:
                s[..., i] = lo[i] + (s[..., i] - lo[i]) % (hi[i] - lo[i])
            else:
                s[..., i] = np.clip(s[..., i], lo[i], hi[i])
        return s

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
        out = self._vg(self._query(states))
        return out[..., 0], out[..., 1:]

    def value(self, states: np.ndarray) -> np.ndarray:
        """V ``(...)`` at ``states`` ``(..., ndim)`` (the same interpolation as :meth:`value_and_gradient`'s, without
        the gradient: the least-restrictive filter reads values only); one state ``(ndim,)`` gives ``(1,)``, as
        scipy's interpolator does."""
        s = np.asarray(states, np.float64)
        s = s[None] if s.ndim == 1 else s
        if s.shape[-1] != self.grid.ndim:
            raise ValueError(f"states need {self.grid.ndim} components in the last axis, got shape {s.shape}")
        return multilinear(self.values, self.grid, np.moveaxis(s, -1, 0))

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
    """Multilinear interpolation of ``values[prefix..., i0, i1, ...]`` on ``grid`` at ``coords`` (one array per grid
    axis, broadcast together; ``prefix``: index arrays of leading axes that are not interpolated, e.g. a table per
    level): periodic axes wrap, the others clamp to the grid's box, a non-finite coordinate gives NaN.  Values only,
    a few numpy operations per corner: cheaper than scipy's interpolator for the few states of a command."""
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
    corners = values[(*(np.reshape(p, -1) for p in prefix), *np.moveaxis(index, 1, 0))]
    return np.where(bad, np.nan, (weight * corners).sum(0).reshape(shape))


def value_table(grid: GridSpec, values: np.ndarray) -> ValueTable | ReversingTable:
    """``values`` on ``grid`` as a table; a whole forward-speed table (periodic θ, v from 0) also answers reversing
    states, by symmetry."""
    table = ValueTable(grid, values)
    return ReversingTable(table) if grid.periodic and grid.lo[2] == 0 else table
