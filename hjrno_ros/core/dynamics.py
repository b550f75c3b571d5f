"""Dynamic Dubins car and Air3D: one set of formulas for solver, filter and simulator.

Every formula is written once against an array module ``xp`` (``numpy`` or ``jax.numpy``):
the dynamics f(x, u, d), the optimal (value-maximising) control and the worst
(value-minimising) disturbance given ∇V.  The ``hj_reachability`` dynamics classes in
:mod:`hjrno_ros.truth.systems` call the same functions with ``xp=jax.numpy``, so the ground
truth, the simulator and the safety filter cannot drift apart.  This module imports numpy only.

Arrays: a state is ``(..., n)`` with the last axis in state order, (x, y, v, θ) for the car and
(x, y, ψ) for Air3D; gradients, controls and disturbances follow the same rule.  SI units.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

Array = Any

_EDGE_TOL = 1e-6  # relative tolerance for "the speed sits on its limit"


def _check(cond: bool, message: str) -> None:
    if not cond:
        raise ValueError(message)


def _concrete(values: tuple) -> bool:
    """True when every value is a plain number (not a JAX tracer used for a traced sweep)."""
    return all(isinstance(v, (int, float, np.floating, np.integer)) for v in values)


@dataclasses.dataclass(frozen=True)
class CarParams:
    """Limits of the dynamic Dubins car (defaults: docs/design.md, "Dynamics")."""

    a_max: float = 1.0  # |u1| ≤ a_max, m/s²
    kappa_max: float = 1.0  # |u2| ≤ κ_max, 1/m
    d_max: float = 0.1  # ‖d‖ ≤ d_max, m/s
    v_min: float = 0.0  # m/s
    v_max: float = 1.0  # m/s

    def __post_init__(self) -> None:
        values = dataclasses.astuple(self)
        if not _concrete(values):
            return
        _check(all(math.isfinite(v) for v in values), f"car parameters must be finite: {self}")
        _check(self.a_max > 0, f"a_max must be > 0, got {self.a_max}")
        _check(self.kappa_max > 0, f"kappa_max must be > 0, got {self.kappa_max}")
        _check(self.d_max >= 0, f"d_max must be >= 0, got {self.d_max}")
        _check(self.v_min >= 0, f"v_min must be >= 0 (forward-driving car), got {self.v_min}")
        _check(self.v_min < self.v_max, f"need v_min < v_max, got v_min={self.v_min} v_max={self.v_max}")

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in dataclasses.asdict(self).items()}


@dataclasses.dataclass(frozen=True)
class Air3DParams:
    """Speeds and turn-rate bounds of the Air3D pursuit-evasion game (evader frame)."""

    evader_speed: float = 5.0  # m/s
    pursuer_speed: float = 5.0  # m/s
    evader_max_turn_rate: float = 1.0  # rad/s, the control
    pursuer_max_turn_rate: float = 1.0  # rad/s, the disturbance

    def __post_init__(self) -> None:
        values = dataclasses.astuple(self)
        if not _concrete(values):
            return
        _check(all(math.isfinite(v) for v in values), f"Air3D parameters must be finite: {self}")
        _check(self.evader_speed >= 0 and self.pursuer_speed >= 0, f"speeds must be >= 0: {self}")
        _check(self.evader_max_turn_rate > 0 and self.pursuer_max_turn_rate > 0, f"turn rates must be > 0: {self}")

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in dataclasses.asdict(self).items()}


# ---------------------------------------------------------------------------------------------
# Dynamic Dubins car: ẋ = v cos θ + d1, ẏ = v sin θ + d2, v̇ = u1, θ̇ = v·u2.


def feasible_acceleration(p: CarParams, v: Array, u1: Array, xp=np) -> Array:
    """Clip u1 so the speed cannot leave [v_min, v_max] (no reversing through the limit)."""
    tol = _EDGE_TOL * (p.v_max - p.v_min)
    u1 = xp.where(v >= p.v_max - tol, xp.minimum(u1, 0.0), u1)
    return xp.where(v <= p.v_min + tol, xp.maximum(u1, 0.0), u1)


def car_f(p: CarParams, state: Array, control: Array, disturbance: Array, xp=np) -> Array:
    """ẋ = f(x, u, d) of the dynamic Dubins car; u = (acceleration, curvature), d = (dx, dy)."""
    v, theta = state[..., 2], state[..., 3]
    u1 = feasible_acceleration(p, v, control[..., 0], xp)
    return xp.stack(
        [v * xp.cos(theta) + disturbance[..., 0], v * xp.sin(theta) + disturbance[..., 1], u1, v * control[..., 1]],
        axis=-1,
    )


def car_optimal_control(p: CarParams, state: Array, grad: Array, xp=np) -> Array:
    """argmax_u ∇V·f: u1 = a_max·sign(∂V/∂v) (kept feasible), u2 = κ_max·sign(v·∂V/∂θ)."""
    v = state[..., 2]
    u1 = xp.where(grad[..., 2] < 0, -p.a_max, p.a_max)
    u2 = xp.where(v * grad[..., 3] < 0, -p.kappa_max, p.kappa_max)
    return xp.stack([feasible_acceleration(p, v, u1, xp), u2], axis=-1)


def car_worst_disturbance(p: CarParams, state: Array, grad: Array, xp=np) -> Array:
    """argmin_d ∇V·f over the ball ‖d‖ ≤ d_max: d = −d_max ∇ₓᵧV / ‖∇ₓᵧV‖ (zero where ∇ₓᵧV = 0)."""
    del state
    g = grad[..., :2]
    norm = xp.sqrt(xp.sum(g * g, axis=-1, keepdims=True))
    return xp.where(norm > 0, -p.d_max * g / xp.where(norm > 0, norm, 1.0), 0.0 * g)


# ---------------------------------------------------------------------------------------------
# Air3D, relative state of the pursuer in the evader's frame:
# ẋ = −v_e + v_p cos ψ + u y,  ẏ = v_p sin ψ − u x,  ψ̇ = d − u  (u evader, d pursuer turn rate).


def air3d_f(p: Air3DParams, state: Array, control: Array, disturbance: Array, xp=np) -> Array:
    """ẋ = f(x, u, d) of Air3D; u and d are the evader's and pursuer's turn rates, shape (..., 1)."""
    x, y, psi = state[..., 0], state[..., 1], state[..., 2]
    u, d = control[..., 0], disturbance[..., 0]
    return xp.stack(
        [-p.evader_speed + p.pursuer_speed * xp.cos(psi) + u * y, p.pursuer_speed * xp.sin(psi) - u * x, d - u],
        axis=-1,
    )


def air3d_optimal_control(p: Air3DParams, state: Array, grad: Array, xp=np) -> Array:
    """The evader's turn rate maximising ∇V·f: ω_e·sign(y ∂V/∂x − x ∂V/∂y − ∂V/∂ψ)."""
    x, y = state[..., 0], state[..., 1]
    direction = y * grad[..., 0] - x * grad[..., 1] - grad[..., 2]
    return xp.where(direction < 0, -p.evader_max_turn_rate, p.evader_max_turn_rate)[..., None]


def air3d_worst_disturbance(p: Air3DParams, state: Array, grad: Array, xp=np) -> Array:
    """The pursuer's turn rate minimising ∇V·f: −ω_p·sign(∂V/∂ψ)."""
    del state
    return xp.where(-grad[..., 2] < 0, -p.pursuer_max_turn_rate, p.pursuer_max_turn_rate)[..., None]
