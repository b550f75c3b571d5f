"""The braking bound: a lower bound of a ground robot's value function from the obstacle map alone (numpy only).

Braking straight at a_max is one admissible strategy, so the value V(x, y, v, θ) (the best least clearance the
robot can keep against the worst disturbance) is at least the least clearance along that strategy's path:

    V(x, y, v, θ) ≥ min over σ ∈ [0, L] of l(p + σ·u) − R,   L = v²/(2 a_max),   R = δ·v²/(2 a_max) + d₀·|v|/a_max,

with p = (x, y), u the direction of travel (θ, or θ + π when reversing), L the braking distance and R the
farthest the disturbance ‖d‖ ≤ δ·|v| + d₀ moves the robot while it brakes (l is 1-Lipschitz; with d₀ = 0,
R = δ·L).  The minimum is
taken over ``samples`` points of the segment and lowered by half their spacing, so the bound stays a bound.
It needs no model and no calibration: exact where the learned value is least certain (at low speed, beside
walls) and the filter's fallback wherever the learned table does not reach (docs/design.md, "Safety filter").
It holds for robots that rest safely (d₀ = 0); with d₀ > 0 the disturbance moves a stopped robot forever and
there is no such bound (−∞).

Obstacles that may approach at up to u m/s (people a laser sees, :func:`braking_value`'s ``moving``) come u·|v|/a_max
nearer while the robot brakes to rest, so their clearance along the path is lowered by that much: a margin that
shrinks with the robot's speed, where the value table's V0 must take the top speed's (docs/design.md, "Moving
obstacles").  Contact after the robot is at rest is outside the avoid set (passive safety).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hjrno_ros.core.dynamics import RobotParams

Clearance = Callable[[np.ndarray], np.ndarray]  # x-y points (..., 2) -> l (...), m
SAMPLES = 5  # points along the braking path (both ends included)


def braking_value(params: RobotParams, clearance: Clearance, states: np.ndarray, samples: int = SAMPLES,
                  moving: tuple[Clearance, float] | None = None) -> np.ndarray:
    """The braking bound at ``states`` ``(..., 4)`` (x, y, v, θ), m: a lower bound of V for any map ``clearance``;
    ``moving``: the clearance of obstacles that may approach, and their speed u (m/s)."""
    states = np.asarray(states, float)
    if params.d0 > 0:
        return np.full(states.shape[:-1], -np.inf)
    v, theta = states[..., 2], states[..., 3]
    length = v * v / (2.0 * params.a_max)
    direction = np.sign(v)[..., None] * np.stack([np.cos(theta), np.sin(theta)], -1)
    sigma = np.linspace(0.0, 1.0, samples)
    points = states[..., None, :2] + (length[..., None] * sigma)[..., None] * direction[..., None, :]
    least = clearance(points).min(-1)
    if moving is not None:
        approach, speed = moving
        least = np.minimum(least, approach(points).min(-1) - speed * np.abs(v) / params.a_max)
    least = least - length / (2 * (samples - 1))
    return least - params.tracking_error * length
