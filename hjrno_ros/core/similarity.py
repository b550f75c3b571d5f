"""Exact similarity of the ground robots: one robot's value function is another's, rescaled.

docs/design.md, "Similarity".  With lengths x = s·x′ and times t = τ·t′ (so speeds v = (s/τ)·v′,
accelerations (s/τ²)·a′, turn rates ω′/τ, curvatures κ′/s, headings unchanged), the robot
ẋ = v cos θ + d, v̇ = u₁, θ̇ = g(v)·u₂, ‖d‖ ≤ δ·|v| + d₀ is the same robot in primed units with

    a′ = a·τ²/s,  v′ = v·τ/s (both limits),  δ′ = δ,  d₀′ = d₀·τ/s,  and
    κ′ = κ·s (the car, g(v) = v)  or  ω′ = ω·τ (the differential drive, g = 1),

and, since the target l is a length, V(x, y, v, θ) = s·V′(x/s, y/s, v·τ/s, θ).  Choosing
τ = 1/ω_top and s = v_max/ω_top with ω_top the fastest turn at top speed (κ_max·v_max for the car, ω_max for
the differential drive; :meth:`Scaling.of`) gives v′_max = 1 and κ′_max = 1 or ω′_max = 1: a robot's *model
units*.  What is left are the dimensionless numbers (:class:`Dimensionless`)

    a_max/(v_max·ω_top),  v_min/v_max,  δ,  d₀/v_max,

and two robots of the same model with equal numbers have the same V′: one solve (or one trained model, on a
window of W model units, i.e. W·s metres) serves both.  Gradients map per axis: ∂V/∂x = ∂V′/∂x′ (x, y),
∂V/∂v = τ·∂V′/∂v′, ∂V/∂θ = s·∂V′/∂θ′.  numpy only.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from hjrno_ros.core.dynamics import CAR_MODEL, ROBOT_MODELS, RobotParams
from hjrno_ros.core.grids import GridSpec


@dataclasses.dataclass(frozen=True)
class Dimensionless:
    """What a ground robot's value function depends on once length and time are scaled out."""

    accel_ratio: float  # a_max / (v_max·ω_top): the braking distance v²/(2a) against the turn radius v/ω, halved
    speed_ratio: float  # v_min / v_max (< 0: the robot reverses)
    tracking_error: float  # δ
    rest_disturbance: float  # d₀ / v_max
    model: str = CAR_MODEL  # the equations: two robot models with equal numbers are not similar

    @classmethod
    def of(cls, p: RobotParams) -> Dimensionless:
        return cls(p.a_max / (p.v_max * p.turn_rate_max), p.v_min / p.v_max, p.tracking_error, p.d0 / p.v_max,
                   p.model)

    @property
    def numbers(self) -> tuple[float, float, float, float]:
        return self.accel_ratio, self.speed_ratio, self.tracking_error, self.rest_disturbance

    def model_params(self) -> RobotParams:
        """The robot in model units: v_max = 1 and κ_max = 1 (car) or ω_max = 1 (differential drive)."""
        turn = "kappa_max" if self.model == CAR_MODEL else "omega_max"
        return ROBOT_MODELS[self.model](a_max=self.accel_ratio, d0=self.rest_disturbance, v_min=self.speed_ratio,
                                        v_max=1.0, tracking_error=self.tracking_error, **{turn: 1.0})

    def close_to(self, other: Dimensionless, rtol: float = 1e-9, atol: float = 1e-12) -> bool:
        return self.model == other.model and all(
            math.isclose(a, b, rel_tol=rtol, abs_tol=atol) for a, b in zip(self.numbers, other.numbers, strict=True))


COVER_RTOL = 1e-6  # relative tolerance on the dimensionless numbers
NUMBERS = ("a_max/(kappa_max*v_max^2)", "v_min/v_max", "tracking_error", "d0/v_max")  # the car's names
DIFF_DRIVE_NUMBERS = ("a_max/(v_max*omega_max)", "v_min/v_max", "tracking_error", "d0/v_max")


def number_names(model: str) -> tuple[str, ...]:
    """The dimensionless numbers' names for a robot model (as a card's ``coverage`` lists them)."""
    return NUMBERS if model == CAR_MODEL else DIFF_DRIVE_NUMBERS


@dataclasses.dataclass(frozen=True)
class Coverage:
    """The robots a card serves: a closed range per dimensionless number (:class:`Dimensionless` order).

    A card's own numbers are covered exactly.  A model conditioned on ``log_a_max`` covers its trained range of
    a_max/(v_max·ω_top).  A product card (d₀ = 0) trained on forward speeds v ∈ [0, v_max] covers any
    v_min/v_max in [−1, 0]: its V for v ≥ 0 does not depend on v_min (from v ≥ 0 a path through reverse passes
    v = 0, where the robot could stay: at rest nothing moves it and min-over-time of l only falls), and a reversing
    state is the forward state turned round, V(x, y, −v, θ) = V(x, y, v, θ + π) (both robots and the ball
    disturbance are symmetric).  A smaller tracking error than the card's is covered conservatively: the filter
    keeps the card's δ.  Only robots of the card's model (car or differential drive) are covered."""

    ranges: tuple[tuple[float, float], ...]
    model: str = CAR_MODEL

    @classmethod
    def of(cls, robot: RobotParams, param_ranges: dict | None = None) -> Coverage:
        own = Dimensionless.of(robot).numbers
        ranges = [(v, v) for v in own]
        if "log_a_max" in (param_ranges or {}):
            lo, hi = param_ranges["log_a_max"]
            ranges[0] = (math.exp(lo), math.exp(hi))
        if robot.d0 == 0 and robot.v_min == 0:
            ranges[1] = (-1.0, 0.0)
        if robot.tracking_error > 0:
            ranges[2] = (0.0, robot.tracking_error)
        return cls(tuple(ranges), robot.model)

    def covers(self, numbers: Dimensionless) -> bool:
        def tol(x: float) -> float:
            return COVER_RTOL * abs(x) + 1e-9

        return numbers.model == self.model and all(
            lo - tol(lo) <= v <= hi + tol(hi) for v, (lo, hi) in zip(numbers.numbers, self.ranges, strict=True))

    def describe(self) -> str:
        return f"{self.model}: " + ", ".join(f"{n} {lo:.4g}" if lo == hi else f"{n} {lo:.4g}..{hi:.4g}"
                                             for n, (lo, hi) in zip(number_names(self.model), self.ranges,
                                                                    strict=True))


@dataclasses.dataclass(frozen=True)
class Scaling:
    """x = s·x′, t = τ·t′ between a robot's SI units and primed (model) units."""

    length: float  # s: metres per model length unit
    time: float  # τ: seconds per model time unit

    def __post_init__(self) -> None:
        if not (math.isfinite(self.length) and math.isfinite(self.time) and self.length > 0 and self.time > 0):
            raise ValueError(f"a scaling needs finite length and time > 0, got s={self.length}, tau={self.time}")

    @classmethod
    def of(cls, robot: RobotParams) -> Scaling:
        """The robot's model units: τ = 1/ω_top, s = v_max/ω_top (ω_top = κ_max·v_max for the car, ω_max for the
        differential drive), so v′_max = 1 and κ′_max = 1 or ω′_max = 1."""
        return cls(robot.v_max / robot.turn_rate_max, 1.0 / robot.turn_rate_max)

    @property
    def speed(self) -> float:
        """s/τ: m/s per model speed unit."""
        return self.length / self.time

    @property
    def acceleration(self) -> float:
        """s/τ²: m/s² per model acceleration unit."""
        return self.length / self.time ** 2

    # parameters --------------------------------------------------------------------------------
    def params_to_model(self, robot: RobotParams) -> RobotParams:
        """The robot's limits in model units."""
        return robot.rescaled(self.length, self.time)

    def params_to_robot(self, model: RobotParams) -> RobotParams:
        """Model-unit limits in the robot's SI units."""
        return model.rescaled(1.0 / self.length, 1.0 / self.time)

    # states, grids and windows ---------------------------------------------------------------------
    def _state_factors(self, ndim: int) -> np.ndarray:
        if ndim != 4:
            raise ValueError(f"car states have 4 components (x, y, v, theta), got {ndim}")
        return np.array([self.length, self.length, self.speed, 1.0])

    def states_to_model(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, float)
        return states / self._state_factors(states.shape[-1])

    def states_to_robot(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, float)
        return states * self._state_factors(states.shape[-1])

    def grid_to_model(self, grid: GridSpec) -> GridSpec:
        """A robot's (x, y, v, θ) grid in model units (same nodes, same shape)."""
        f = self._state_factors(grid.ndim)
        return dataclasses.replace(grid, lo=tuple(np.asarray(grid.lo) / f), hi=tuple(np.asarray(grid.hi) / f))

    def grid_to_robot(self, grid: GridSpec) -> GridSpec:
        f = self._state_factors(grid.ndim)
        return dataclasses.replace(grid, lo=tuple(np.asarray(grid.lo) * f), hi=tuple(np.asarray(grid.hi) * f))

    def window_to_model(self, lo: tuple[float, float], hi: tuple[float, float]) -> tuple[tuple, tuple]:
        """An x-y map window (m) in model units."""
        return tuple(float(v) / self.length for v in lo), tuple(float(v) / self.length for v in hi)

    def window_to_robot(self, lo: tuple[float, float], hi: tuple[float, float]) -> tuple[tuple, tuple]:
        return tuple(float(v) * self.length for v in lo), tuple(float(v) * self.length for v in hi)

    # values, gradients, times ---------------------------------------------------------------------
    def value_to_model(self, value):
        """V (or l, or a margin ε), m → model lengths."""
        return np.asarray(value) / self.length

    def value_to_robot(self, value):
        """V′ in model lengths → m."""
        return np.asarray(value) * self.length

    def _gradient_factors(self, ndim: int) -> np.ndarray:
        if ndim != 4:
            raise ValueError(f"car gradients have 4 components, got {ndim}")
        return np.array([1.0, 1.0, self.time, self.length])  # ∂V/∂(x, y, v, θ) = factor·∂V′/∂(x′, y′, v′, θ′)

    def gradient_to_robot(self, grad: np.ndarray) -> np.ndarray:
        grad = np.asarray(grad, float)
        return grad * self._gradient_factors(grad.shape[-1])

    def gradient_to_model(self, grad: np.ndarray) -> np.ndarray:
        grad = np.asarray(grad, float)
        return grad / self._gradient_factors(grad.shape[-1])

    def duration_to_robot(self, t: float) -> float:
        """A model-unit time (horizon, chunk) in s."""
        return float(t) * self.time

    def rate_to_robot(self, rate: float) -> float:
        """A model-unit rate of V (the solver's max |ΔV| per second) in m/s."""
        return float(rate) * self.speed


def robot_to_robot(a: RobotParams, b: RobotParams) -> Scaling:
    """The scaling that takes robot ``a``'s quantities to robot ``b``'s (x_b = s·x_a, t_b = τ·t_a): use its
    ``*_to_robot`` on ``a``'s values.  ValueError unless their dimensionless numbers agree."""
    if not Dimensionless.of(a).close_to(Dimensionless.of(b)):
        raise ValueError(f"robots of different models or dimensionless numbers are not similar: "
                         f"{Dimensionless.of(a)} vs {Dimensionless.of(b)}")
    sa, sb = Scaling.of(a), Scaling.of(b)
    return Scaling(sb.length / sa.length, sb.time / sa.time)
