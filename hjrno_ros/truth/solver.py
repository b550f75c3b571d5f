"""Converged value functions V∞ with ``hj_reachability``, with an honest convergence report.

``hj.step`` has no convergence test, so :func:`solve` steps the backward reachable tube in
chunks of simulated time and watches max |ΔV| per simulated second, over the interior of the
grid (open x-y edges excluded, they are extrapolated) and over the band near V = 0.  A solve that
does not settle within the horizon budget says so in its report; it is never flagged converged.

The dynamics' parameters enter the compiled step as traced values, so a new obstacle *or* a new
parameter set (a_max, κ_max, ...) reuses one compiled step per (dynamics type, grid, accuracy).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable

import hj_reachability as hj
import jax
import jax.numpy as jnp
import numpy as np

from hjrno_ros.core.grids import GridSpec
from hjrno_ros.truth.systems import hj_grid

ACCURACIES = ("low", "medium", "high", "very_high")
CRITERIA = ("interior", "band")


@dataclasses.dataclass
class SolveReport:
    """What a solve did: how far it went, how settled V is, and what it cost."""

    converged: bool
    horizon: float  # simulated seconds of backward time reached
    max_delta: float  # max |ΔV| per simulated second over the interior, last chunk
    max_delta_band: float  # the same over the band |V| < band
    tolerance: float
    criterion: str
    band: float
    wall_time: float  # s
    grid_shape: tuple[int, ...]
    accuracy: str
    history: list[tuple[float, float, float]] = dataclasses.field(default_factory=list)  # (t, delta, delta_band)

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["grid_shape"] = list(self.grid_shape)
        d["history"] = [list(h) for h in self.history]
        return d

    def summary(self) -> str:
        state = "converged" if self.converged else "NOT converged"
        return (
            f"{state} at horizon {self.horizon:.1f} s: max|dV|/s interior {self.max_delta:.2e}, "
            f"band {self.max_delta_band:.2e} (tol {self.tolerance:.1e}, {self.criterion}); "
            f"grid {'x'.join(map(str, self.grid_shape))}, {self.accuracy}, {self.wall_time:.1f} s wall"
        )


_euler = hj.time_integration.euler_step.__wrapped__
_RK_ORDER = {hj.time_integration.first_order_total_variation_diminishing_runge_kutta: 1,
             hj.time_integration.second_order_total_variation_diminishing_runge_kutta: 2,
             hj.time_integration.third_order_total_variation_diminishing_runge_kutta: 3}


def _tvd_runge_kutta(order: int) -> Callable:
    """``hj_reachability``'s TVD Runge-Kutta step of ``order`` (same arithmetic) over its *un-jitted*
    Euler step.  hj's own jits take the dynamics as a static argument, and ours holds traced
    parameters: tracers in static arguments are what JAX warns leads to leaked-tracer errors
    (jax-ml/jax#2884), so :func:`_step` traces hj's functions inline instead."""

    def integrate(settings, dynamics, grid, time, values, target_time):
        time_1, values_1 = _euler(settings, dynamics, grid, time, values, max_time_step=target_time - time)
        if order == 1:
            return time_1, settings.value_postprocessor(time_1, values_1)
        time_step = time_1 - time
        _, values_2 = _euler(settings, dynamics, grid, time_1, values_1, time_step)
        if order == 2:
            return time_1, settings.value_postprocessor(time_1, (values + values_2) / 2)
        values_0_5 = (3 / 4) * values + (1 / 4) * values_2
        _, values_1_5 = _euler(settings, dynamics, grid, time + time_step / 2, values_0_5, time_step)
        return time_1, settings.value_postprocessor(time_1, (1 / 3) * values + (2 / 3) * values_1_5)

    return integrate


@functools.cache
def _settings(accuracy: str) -> hj.SolverSettings:
    settings = hj.SolverSettings.with_accuracy(accuracy, hamiltonian_postprocessor=hj.solver.backwards_reachable_tube)
    return settings.replace(time_integrator=_tvd_runge_kutta(_RK_ORDER[settings.time_integrator]))


@functools.partial(jax.jit, static_argnames=("dynamics_type", "param_type", "accuracy"))
def _step(dynamics_type, param_type, accuracy, param_values, grid, t0, values, t1):
    """One backward chunk t0 → t1 (< t0); the dynamics' parameters are traced, not static."""
    dynamics = dynamics_type(param_type(*param_values))
    return hj.step.__wrapped__(_settings(accuracy), dynamics, grid, t0, values, t1, progress_bar=False)


def interior_mask(grid: GridSpec, open_axes: tuple[int, ...], edge_cells: int = 2) -> np.ndarray:
    """True away from the open (extrapolated) edges of ``open_axes``."""
    mask = np.ones(grid.shape, bool)
    for ax in open_axes:
        sl = [slice(None)] * grid.ndim
        sl[ax] = slice(0, edge_cells)
        mask[tuple(sl)] = False
        sl[ax] = slice(grid.shape[ax] - edge_cells, None)
        mask[tuple(sl)] = False
    return mask


def rise_with_speed(grid: GridSpec, value: np.ndarray, open_axes: tuple[int, ...] = (0, 1),
                    edge_cells: int = 2) -> np.ndarray:
    """Every step of a car table along the speed axis, as V(node with the larger |v|) − V(the other),
    flattened, over the interior (``open_axes`` edges excluded, they are extrapolated).  > 0 where the
    table calls the faster state safer.  A pair of nodes straddling v = 0 is left out (neither |v| is
    larger in the sense of braking towards 0)."""
    v = grid.axis(2)
    step = np.diff(np.asarray(value, np.float64), axis=2)  # V[i+1] − V[i]
    keep = (v[:-1] >= 0) | (v[1:] <= 0)
    outward = np.where(v[:-1] >= 0, 1.0, -1.0)[keep]  # i → i+1 raises |v| at v ≥ 0, lowers it at v ≤ 0
    inner = interior_mask(grid, open_axes, edge_cells)[:, :, 1:][:, :, keep]
    return (step[:, :, keep] * outward[None, None, :, None])[inner]


def validate_table(grid: GridSpec, table: np.ndarray, what: str = "target") -> np.ndarray:
    """``table`` (the target l or a warm start) as float32 on ``grid``, or a ValueError saying what is wrong."""
    table = np.asarray(table)
    if table.shape != grid.shape:
        raise ValueError(f"{what} shape {table.shape} does not match grid shape {grid.shape}")
    if not np.all(np.isfinite(table)):
        raise ValueError(f"{what} has {int(np.sum(~np.isfinite(table)))} NaN/Inf values")
    return table.astype(np.float32)


def validate_target(grid: GridSpec, target: np.ndarray) -> np.ndarray:
    """The target l(x) as float32 on ``grid``, or a ValueError saying what is wrong with it."""
    target = validate_table(grid, target)
    if not np.any(target > 0):
        raise ValueError("target has no safe states (l <= 0 everywhere): nothing to solve")
    return target


def solve(
    dynamics,
    grid: GridSpec,
    target: np.ndarray,
    *,
    accuracy: str = "high",
    chunk: float = 1.0,
    max_horizon: float = 40.0,
    tolerance: float = 1e-3,
    criterion: str = "interior",
    band: float | None = None,
    open_axes: tuple[int, ...] = (0, 1),
    progress: Callable[[float, float, float], None] | None = None,
    initial: np.ndarray | None = None,
) -> tuple[np.ndarray, SolveReport]:
    """V∞ = lim V(−t) of the backward reachable tube of ``target`` (l > 0 outside, ≤ 0 inside).

    Steps ``chunk`` simulated seconds at a time until max |ΔV| per second over the chosen region
    ("interior" or "band" |V| < ``band``) is below ``tolerance``, or ``max_horizon`` is reached
    (then the report says not converged).  ``progress(t, delta, delta_band)`` is called per chunk.

    ``initial`` (same grid) warm-starts the tube at min(initial, l) instead of l, e.g. from an
    operator's prediction.  The tube only lowers V and V∞ is the largest fixed point below l, so its
    limit is ≤ V∞ (conservative where the start was below V∞) and is V∞ if the start was ≥ V∞
    everywhere; a solve stopped by the tolerance lies a little above that limit (< 0.06 m near V = 0
    from V∞ + 0.3 m in ``test_an_optimistic_warm_start_comes_down_to_v_inf``).
    """
    if min(grid.shape) < 3:
        raise ValueError(f"the solver needs at least 3 nodes per grid axis, got shape {grid.shape}")
    if accuracy not in ACCURACIES:
        raise ValueError(f"accuracy must be one of {ACCURACIES}, got {accuracy!r}")
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    if not (chunk > 0 and max_horizon >= chunk and tolerance > 0):
        raise ValueError(f"need chunk > 0, max_horizon >= chunk, tolerance > 0: {chunk}, {max_horizon}, {tolerance}")
    if len(dynamics.state_names) != grid.ndim:
        raise ValueError(f"{type(dynamics).__name__} has {len(dynamics.state_names)} states, grid has {grid.ndim} axes")
    values = jnp.asarray(validate_target(grid, target))
    if initial is not None:
        values = jnp.minimum(values, jnp.asarray(validate_table(grid, initial, "initial value")))
    if band is None:
        band = 3.0 * max(grid.spacings[i] for i in open_axes) if open_axes else 0.3
    inner = interior_mask(grid, open_axes)
    params = tuple(float(v) for v in dataclasses.astuple(dynamics.params))
    grid_hj = hj_grid(grid)
    start, t, history = time.perf_counter(), 0.0, []
    delta = delta_band = math.inf
    while True:
        t_next = min(t + chunk, max_horizon)
        new = _step(type(dynamics), type(dynamics.params), accuracy, params, grid_hj, -t, values, -t_next)
        change = np.abs(np.asarray(new - values)) / (t_next - t)
        near = inner & (np.abs(np.asarray(new)) < band)
        delta = float(change[inner].max())
        delta_band = float(change[near].max()) if near.any() else 0.0
        values, t = new, t_next
        history.append((t, delta, delta_band))
        if progress is not None:
            progress(t, delta, delta_band)
        if (delta if criterion == "interior" else delta_band) < tolerance or t >= max_horizon - 1e-9:
            break
    settled = (delta if criterion == "interior" else delta_band) < tolerance
    out = np.asarray(values, dtype=np.float32)
    if not np.all(np.isfinite(out)):
        raise FloatingPointError("the solve produced NaN/Inf values (unstable parameters or grid)")
    report = SolveReport(
        converged=bool(settled),
        horizon=t,
        max_delta=delta,
        max_delta_band=delta_band,
        tolerance=tolerance,
        criterion=criterion,
        band=float(band),
        wall_time=time.perf_counter() - start,
        grid_shape=grid.shape,
        accuracy=accuracy,
        history=history,
    )
    return out, report
