"""Least-restrictive safety filter for the dynamic Dubins car (no ROS).

Given V and ∇V at the state: pass the nominal command while V > ε; at V ≤ ε replace it by the
optimal safe control u* = argmax_u ∇V·f (DESIGN.md §5), mapped to a velocity command
(v_cmd = v + u1·dt, ω = v·u2).  ``mode="blend"`` mixes nominal and safe commands over
V ∈ (ε, ε + blend_width] instead of switching, which reduces chattering.  Anything non-finite
fails closed: a stop command.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .dynamics import CarParams, car_optimal_control

MODES = ("switch", "blend")


@dataclasses.dataclass(frozen=True)
class FilterSettings:
    epsilon: float = 0.1  # m: intervene when V ≤ ε
    mode: str = "switch"
    blend_width: float = 0.2  # m: "blend" ramps from safe (V ≤ ε) to nominal (V ≥ ε + width)
    dt: float = 0.05  # s: control period mapping accelerations to speed commands

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"filter mode must be one of {MODES}, got {self.mode!r}")
        if not (math.isfinite(self.epsilon) and self.epsilon >= 0):
            raise ValueError(f"epsilon must be finite and >= 0, got {self.epsilon}")
        if not (self.blend_width > 0 and self.dt > 0):
            raise ValueError(f"blend_width and dt must be > 0, got {self.blend_width}, {self.dt}")


@dataclasses.dataclass(frozen=True)
class Decision:
    linear: float  # m/s
    angular: float  # rad/s
    intervened: bool
    value: float  # V at the state, m
    reason: str


def safe_twist(params: CarParams, state: np.ndarray, grad: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The optimal safe control at ``state`` (one or a batch ``(n, 4)``) as (linear, angular) commands."""
    state = np.asarray(state, float)
    u = car_optimal_control(params, state, np.asarray(grad, float))
    v = state[..., 2]
    return np.clip(v + u[..., 0] * dt, params.v_min, params.v_max), v * u[..., 1]


def nominal_weight(settings: FilterSettings, value: np.ndarray) -> np.ndarray:
    """Share of the nominal command: 1 while V > ε (+ blend width), 0 at V ≤ ε, linear in between."""
    value = np.asarray(value, float)
    if settings.mode == "switch":
        return (value > settings.epsilon).astype(float)
    return np.clip((value - settings.epsilon) / settings.blend_width, 0.0, 1.0)


def stop(value: float, reason: str) -> Decision:
    """Fail closed: zero velocity."""
    return Decision(0.0, 0.0, True, value, reason)


def filter_command(params: CarParams, settings: FilterSettings, state: np.ndarray, value: float, grad: np.ndarray,
                   linear: float, angular: float) -> Decision:
    """The command to send, given the nominal (linear, angular) and V, ∇V at ``state`` (x, y, v, θ)."""
    if not (np.all(np.isfinite(state)) and math.isfinite(value) and np.all(np.isfinite(grad))):
        return stop(float(value), "non-finite state or value")
    if not (math.isfinite(linear) and math.isfinite(angular)):
        return stop(float(value), "non-finite nominal command")
    w = float(nominal_weight(settings, value))
    if w == 1.0:
        return Decision(float(linear), float(angular), False, float(value), "pass")
    safe_lin, safe_ang = (float(c) for c in safe_twist(params, state, grad, settings.dt))
    if w == 0.0:
        return Decision(safe_lin, safe_ang, True, float(value), "safe control")
    return Decision(w * linear + (1 - w) * safe_lin, w * angular + (1 - w) * safe_ang, True, float(value), "blend")


def filter_batch(params: CarParams, settings: FilterSettings, states: np.ndarray, values: np.ndarray,
                 grads: np.ndarray, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`filter_command` for ``n`` robots at once: commands ``(n, 2)`` and intervened ``(n,)``.

    Non-finite inputs fail closed (zero command), as in the scalar version."""
    w = nominal_weight(settings, values)
    safe = np.stack(safe_twist(params, states, grads, settings.dt), -1)
    out = w[:, None] * nominal + (1 - w[:, None]) * safe
    bad = ~(np.isfinite(states).all(-1) & np.isfinite(values) & np.isfinite(grads).all(-1)
            & np.isfinite(nominal).all(-1))
    out[bad] = 0.0
    return out, (w < 1.0) | bad
