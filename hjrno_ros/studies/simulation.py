"""Closed-loop rollouts of many states at once, for validation, evaluation and the demo.

Feedback laws are functions of the states (batch ``(n, dims)``); control and disturbance are
held constant over each step of a classical RK4 integration.  A state has collided once its
clearance l(x) (exact geometry, not the grid) drops to ≤ 0; it is frozen from then on.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from hjrno_ros.core.dynamics import (
    RobotParams,
    disturbance_bound,
    optimal_control,
    robot_f,
    worst_disturbance,
)
from hjrno_ros.core.value_table import ValueTable

Feedback = Callable[[np.ndarray], np.ndarray]


@dataclasses.dataclass
class Rollouts:
    """Outcome per initial state."""

    collided: np.ndarray  # bool (n,)
    collision_time: np.ndarray  # s, inf where none
    min_clearance: np.ndarray  # m, the smallest l(x) seen
    final: np.ndarray  # (n, dims) last state (the collision state for collided ones)


def simulate(
    f: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    control: Feedback,
    disturbance: Feedback,
    clearance: Callable[[np.ndarray], np.ndarray],
    states: np.ndarray,
    duration: float,
    dt: float = 0.02,
    wrap: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Rollouts:
    """Integrate ẋ = f(x, control(x), disturbance(x)) for ``duration`` seconds from each state."""
    x = np.array(states, np.float64, copy=True)
    n = x.shape[0]
    alive = np.ones(n, bool)
    t_hit = np.full(n, np.inf)
    min_l = clearance(x).astype(np.float64)
    alive &= min_l > 0
    t_hit[~alive] = 0.0
    for k in range(int(round(duration / dt))):
        if not alive.any():
            break
        xa = x[alive]
        xa = rk4_step(f, xa, control(xa), disturbance(xa), dt)
        if wrap is not None:
            xa = wrap(xa)
        x[alive] = xa
        la = clearance(xa)
        idx = np.flatnonzero(alive)
        min_l[idx] = np.minimum(min_l[idx], la)
        hit = idx[la <= 0]
        t_hit[hit] = (k + 1) * dt
        alive[hit] = False
    return Rollouts(collided=np.isfinite(t_hit), collision_time=t_hit, min_clearance=min_l, final=x)


def rk4_step(f: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray], x: np.ndarray, u: np.ndarray,
             d: np.ndarray, dt: float) -> np.ndarray:
    """One classical RK4 step of ẋ = f(x, u, d) with u and d held over the step."""
    k1 = f(x, u, d)
    k2 = f(x + 0.5 * dt * k1, u, d)
    k3 = f(x + 0.5 * dt * k2, u, d)
    k4 = f(x + dt * k3, u, d)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def ball(rng: np.random.Generator, shape: tuple[int, ...], radius: float) -> np.ndarray:
    """Samples ``(*shape, 2)`` uniform in the disk of ``radius``."""
    direction = rng.normal(size=(*shape, 2))
    direction /= np.maximum(np.linalg.norm(direction, axis=-1, keepdims=True), 1e-12)
    return radius * np.sqrt(rng.uniform(size=(*shape, 1))) * direction


def wrap_car(states: np.ndarray) -> np.ndarray:
    """Wrap θ of car states to [-π, π)."""
    states = states.copy()
    states[..., 3] = (states[..., 3] + np.pi) % (2 * np.pi) - np.pi
    return states


def ball_noise(d_max: float, rng: np.random.Generator) -> Feedback:
    """Random disturbance, uniform in the disk ‖d‖ ≤ d_max, drawn anew at every step."""
    return lambda states: ball(rng, (states.shape[0],), d_max)


def random_disturbance(params: RobotParams, rng: np.random.Generator) -> Feedback:
    """The robot's random disturbance: uniform in its disk ‖d‖ ≤ δ·|v| + d₀ at each state, drawn anew at
    every step (the paper's car: ‖d‖ ≤ d₀ everywhere)."""
    return lambda states: disturbance_bound(params, states[:, 2])[:, None] * ball(rng, (states.shape[0],), 1.0)


def optimal_feedback(params: RobotParams, table: ValueTable) -> tuple[Feedback, Feedback]:
    """The safest control and the worst disturbance of the robot, both from ∇V of a value table."""
    return (
        lambda s: optimal_control(params, s, table.gradient(s)),
        lambda s: worst_disturbance(params, s, table.gradient(s)),
    )


def robot_dynamics(params: RobotParams) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    return lambda s, u, d: robot_f(params, s, u, d)
