"""Safety-filter settings, the twist ↔ control mappings of the ground robots, and the modes that judge V and ∇V at
the present state (no ROS).  The node's default mode, ``least_restrictive``, looks one period ahead and lives in
:mod:`hjrno_ros.core.least_restrictive`.

Given V and ∇V at the state (x, y, v, θ), three modes:

- ``switch``: pass the nominal command while V > ε; at V ≤ ε replace it by the optimal safe
  control u* = argmax_u ∇V·f (docs/design.md, "Safety filter"), mapped to a velocity command.
- ``blend``: mix nominal and safe commands linearly over V ∈ (ε, ε + blend_width] instead of
  switching, which reduces chattering.
- ``qp``: the smallest change of the nominal control u = (a, κ or ω), in units of the limits, that
  keeps dV/dt ≥ −γ (V − ε) under the worst-case disturbance (a control-barrier condition on the
  HJ value function).  ∇V·f is affine in u, so this one-constraint QP over the control box has a
  closed-form solution; where no control satisfies it, u*.  Far from the boundary it passes
  the command unchanged, near it it bends the command only as much as needed.

Commands are twists (linear m/s, angular rad/s); the base turns them into controls as
:func:`twist_to_control` says.  The model vouches only for commands inside its limits, so every
command, nominal or filtered, is first clipped to them (:func:`clip_to_limits`).  Anything
non-finite fails closed: a stop command.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from hjrno_ros.core.dynamics import (
    CAR_MODEL,
    RobotParams,
    disturbance_bound,
    feasible_acceleration,
    optimal_control,
    turn_gain,
)

TINY = 1e-12  # |∂(∇V·f)/∂z| below this is no lever: treated as zero (a subnormal one overflowed the qp's kinks)

MODES = ("least_restrictive", "switch", "blend", "qp")


@dataclasses.dataclass(frozen=True)
class FilterSettings:
    epsilon: float = 0.1  # m: intervene when V ≤ ε
    mode: str = "switch"
    blend_width: float = 0.2  # m: "blend" ramps from safe (V ≤ ε) to nominal (V ≥ ε + width)
    dt: float = 0.05  # s: control period mapping accelerations to speed commands
    decay_rate: float = 4.0  # 1/s: "qp" keeps dV/dt ≥ −decay_rate (V − ε)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"filter mode must be one of {MODES}, got {self.mode!r}")
        if not (math.isfinite(self.epsilon) and self.epsilon >= 0):
            raise ValueError(f"epsilon must be finite and >= 0, got {self.epsilon}")
        if not (self.blend_width > 0 and self.dt > 0 and self.decay_rate > 0):
            raise ValueError(f"blend_width, dt and decay_rate must be > 0, got {self.blend_width}, {self.dt}, "
                             f"{self.decay_rate}")


@dataclasses.dataclass(frozen=True)
class Decision:
    linear: float  # m/s
    angular: float  # rad/s
    intervened: bool
    value: float  # V at the state, m
    reason: str
    clipped: bool = False  # the nominal was outside the model's limits


def twist_to_control(params: RobotParams, states: np.ndarray, twist: np.ndarray, dt: float) -> np.ndarray:
    """What a base does with twists ``(n, 2)``: a = (v_cmd − v)/dt within ±a_max; the differential drive turns
    at ω within ±ω_max, the car at the curvature κ = ω / v within ±κ_max (v kept 1 mm/s away from zero with its
    sign, so reversing turns the right way)."""
    v = states[..., 2]
    accel = np.clip((twist[..., 0] - v) / dt, -params.a_max, params.a_max)
    if params.model == CAR_MODEL:
        v = np.where(np.abs(v) < 1e-3, np.where(v < 0, -1e-3, 1e-3), v)
    turn = np.clip(twist[..., 1] / turn_gain(params, v), -params.turn_max, params.turn_max)
    return np.stack([accel, turn], -1)


def control_to_twist(params: RobotParams, states: np.ndarray, control: np.ndarray, dt: float) -> np.ndarray:
    """The twists ``(n, 2)`` that make such a base apply ``control`` (a, κ or ω) over one period ``dt``."""
    v = states[..., 2]
    return np.stack([np.clip(v + control[..., 0] * dt, params.v_min, params.v_max),
                     turn_gain(params, v) * control[..., 1]], -1)


def turn_bound(params: RobotParams, states: np.ndarray, linear: np.ndarray, dt: float) -> np.ndarray:
    """The largest |angular| (rad/s) the model vouches for with the linear command ``linear`` over one period:
    ω_max for the differential drive; κ_max·max(|v|, |v′|) for the car, with v′ the speed the base can reach
    toward the command within a_max·dt (θ̇ = v·κ)."""
    if params.model != CAR_MODEL:
        return np.full(np.shape(linear), params.turn_max)
    v = states[..., 2]
    reach = np.clip(linear, v - params.a_max * dt, v + params.a_max * dt)
    return params.kappa_max * np.maximum(np.abs(v), np.abs(reach))


def clip_to_limits(params: RobotParams, states: np.ndarray, twist: np.ndarray, dt: float) -> np.ndarray:
    """Twists ``(..., 2)`` clipped to what the model vouches for over one period ``dt``: linear in
    [v_min, v_max], angular within :func:`turn_bound`."""
    linear = np.clip(twist[..., 0], params.v_min, params.v_max)
    bound = turn_bound(params, states, linear, dt)
    return np.stack([linear, np.clip(twist[..., 1], -bound, bound)], -1)


def sampling_margin(params: RobotParams, dt: float) -> float:
    """m: how far V can fall while one command holds for ``dt`` (the filter decides once per period): the robot
    and the disturbance move it at most (1 + δ)·|v| + d₀ at the top speed, and V is 1-Lipschitz in (x, y).  A
    small fast-turning robot needs it: a TurtleBot3 covers 1.1 cm per 50 ms, more than its scaled ε (0.8 cm)."""
    speed = max(abs(params.v_min), abs(params.v_max))
    return float(((1 + params.tracking_error) * speed + params.d0) * dt)


def within_nominal_speed(params: RobotParams, twist: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """For a robot that rests safely (d₀ = 0: nothing moves it at v = 0), the linear command stays between 0 and
    the nominal's: the filter brakes or turns, never adds speed or reverses against the nominal.  Its model's V
    never gains from speed (docs/design.md, "Robot models"), so this only removes what a learned V's noise adds.
    The angular command is unchanged (its curvature is ω / v at the present speed)."""
    if params.d0 > 0:
        return twist
    linear = np.clip(twist[..., 0], np.minimum(nominal[..., 0], 0.0), np.maximum(nominal[..., 0], 0.0))
    return np.stack([linear, twist[..., 1]], -1)


def safe_twist(params: RobotParams, state: np.ndarray, grad: np.ndarray, dt: float) -> np.ndarray:
    """The optimal safe control at ``state`` (``(4,)`` or ``(n, 4)``) as (linear, angular) commands."""
    state = np.asarray(state, float)
    twist = control_to_twist(params, state, optimal_control(params, state, np.asarray(grad, float)), dt)
    return stops_at_rest(params, state, twist)


def stops_at_rest(params: RobotParams, states: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """For a robot that rests safely (d₀ = 0) the safe linear command stays between 0 and the present speed: it
    brakes to rest, never through it.  Rest is the safest speed of this model (V(x, y, 0, θ) = l(x, y) ≥ V at any
    other speed), but ∂V/∂v has a kink there, and a one-sided gradient of a reversing robot's table (stopped:
    "brake" = back up) made the safe control creep backwards into a wall, one period at a time."""
    if params.d0 > 0:
        return twist
    v = states[..., 2]
    linear = np.clip(twist[..., 0], np.minimum(v, 0.0), np.maximum(v, 0.0))
    return np.stack([linear, twist[..., 1]], -1)


def nominal_weight(settings: FilterSettings, value: np.ndarray) -> np.ndarray:
    """Share of the nominal command: 1 while V > ε (+ blend width), 0 at V ≤ ε, linear in between."""
    value = np.asarray(value, float)
    if settings.mode == "switch":
        return (value > settings.epsilon).astype(float)
    return np.clip((value - settings.epsilon) / settings.blend_width, 0.0, 1.0)


def minimal_change(params: RobotParams, settings: FilterSettings, states: np.ndarray, values: np.ndarray,
                   grads: np.ndarray, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``qp`` mode on controls: (u ``(n, 2)``, changed ``(n,)``) for nominal controls ``(n, 2)``.

    In scaled units z = u / limit the constraint is g·z ≥ b; z(λ) = clip(z_nom + λ g) is the
    projection path, and g·z(λ) is piecewise linear in λ with a kink where each axis saturates.
    """
    v = states[:, 2]
    half = np.array([params.a_max, params.turn_max])
    g = np.column_stack([grads[:, 2], grads[:, 3] * turn_gain(params, v)]) * half  # ∂(∇V·f)/∂z
    at_limit = feasible_acceleration(params, v, np.sign(g[:, 0]), np) == 0  # speed limit: a cannot help
    g[:, 0] = np.where(at_limit, 0.0, g[:, 0])
    g = np.where(np.abs(g) < TINY, 0.0, g)
    drift = grads[:, 0] * v * np.cos(states[:, 3]) + grads[:, 1] * v * np.sin(states[:, 3])
    drift -= disturbance_bound(params, v) * np.linalg.norm(grads[:, :2], axis=-1)  # worst-case disturbance
    b = -settings.decay_rate * (values - settings.epsilon) - drift
    z0 = np.clip(nominal / half, -1.0, 1.0)
    safe_g = np.where(g == 0, 1.0, g)
    kinks = np.sort(np.where(g == 0, 0.0, np.maximum((np.sign(g) - z0) / safe_g, 0.0)), axis=1)
    z_at = [np.clip(z0 + lam[:, None] * g, -1.0, 1.0) for lam in (np.zeros(len(g)), kinks[:, 0], kinks[:, 1])]
    h0, h1, h2 = ((g * z).sum(-1) for z in z_at)
    lam = np.where(h1 >= b, kinks[:, 0] * (b - h0) / np.where(h1 > h0, h1 - h0, 1.0),
                   kinks[:, 0] + (kinks[:, 1] - kinks[:, 0]) * (b - h1) / np.where(h2 > h1, h2 - h1, 1.0))
    lam = np.where(h2 < b, kinks[:, 1], np.clip(lam, 0.0, kinks[:, 1]))
    changed = h0 < b
    z = np.where(changed[:, None], np.clip(z0 + lam[:, None] * g, -1.0, 1.0), z0)
    return z * half, changed


def stop(value: float, reason: str) -> Decision:
    """Fail closed: zero velocity."""
    return Decision(0.0, 0.0, True, value, reason)


def filter_command(params: RobotParams, settings: FilterSettings, state: np.ndarray, value: float, grad: np.ndarray,
                   linear: float, angular: float) -> Decision:
    """The command to send, given the nominal (linear, angular) and V, ∇V at ``state`` (x, y, v, θ)."""
    if not (np.all(np.isfinite(state)) and math.isfinite(value) and np.all(np.isfinite(grad))):
        return stop(float(value), "non-finite state or value")
    if not (math.isfinite(linear) and math.isfinite(angular)):
        return stop(float(value), "non-finite nominal command")
    state = np.asarray(state, float)
    nominal = np.array([[linear, angular]], float)
    clipped = bool(np.any(clip_to_limits(params, state[None], nominal, settings.dt) != nominal))
    out, intervened = filter_batch(params, settings, state[None], np.array([value], float),
                                   np.asarray(grad, float)[None], nominal)
    if not intervened[0]:
        if clipped:
            return Decision(float(out[0, 0]), float(out[0, 1]), False, float(value), "clipped to limits", True)
        return Decision(float(linear), float(angular), False, float(value), "pass")
    reason = "qp" if settings.mode == "qp" else "safe control" if nominal_weight(settings, value) == 0 else "blend"
    return Decision(float(out[0, 0]), float(out[0, 1]), True, float(value), reason, clipped)


def filter_batch(params: RobotParams, settings: FilterSettings, states: np.ndarray, values: np.ndarray,
                 grads: np.ndarray, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`filter_command` for ``n`` robots at once: commands ``(n, 2)`` and intervened ``(n,)``.

    Nominal commands are clipped to the limits first, and so is the result.  Non-finite inputs, and any
    non-finite result (a finite but huge speed overflows v·u₂), fail closed (zero command), as in the
    scalar version."""
    bad = ~(np.isfinite(states).all(-1) & np.isfinite(values) & np.isfinite(grads).all(-1)
            & np.isfinite(nominal).all(-1))
    states, values, grads, nominal = (np.where(bad[(...,) + (None,) * (a.ndim - 1)], 0.0, a)
                                      for a in (states, values, grads, nominal))
    nominal = clip_to_limits(params, states, nominal, settings.dt)
    if settings.mode == "qp":
        u, changed = minimal_change(params, settings, states, values, grads,
                                    twist_to_control(params, states, nominal, settings.dt))
        out = np.where(changed[:, None], control_to_twist(params, states, u, settings.dt), nominal)
    else:
        w = nominal_weight(settings, values)
        out = w[:, None] * nominal + (1 - w[:, None]) * safe_twist(params, states, grads, settings.dt)
        changed = w < 1.0
    out = clip_to_limits(params, states, within_nominal_speed(params, out, nominal), settings.dt)
    bad |= ~np.isfinite(out).all(-1)
    out[bad] = 0.0
    return out, changed | bad
