"""Ground robots (dynamic Dubins car, differential drive) and Air3D: one set of formulas for solver, filter and
simulator.

Every formula is written once against an array module ``xp`` (``numpy`` or ``jax.numpy``):
the dynamics f(x, u, d), the optimal (value-maximising) control and the worst
(value-minimising) disturbance given ∇V.  The ``hj_reachability`` dynamics classes in
:mod:`hjrno_ros.truth.systems` call the same functions with ``xp=jax.numpy``, so the ground
truth, the simulator and the safety filter cannot drift apart.  This module imports numpy only.

Both ground robots (docs/design.md, "Robot models") have the state (x, y, v, θ): ẋ = v cos θ + d₁,
ẏ = v sin θ + d₂, v̇ = u₁ with |u₁| ≤ a_max, v ∈ [v_min, v_max] (v_min < 0: the base reverses), a position
disturbance bounded by a tracking error that grows with speed, ‖d‖ ≤ δ·|v| + d₀, and a turn θ̇ = g(v)·u₂:

- the **car** (:class:`CarParams`): curvature control, g(v) = v, |u₂| ≤ κ_max.  Named configurations
  :meth:`CarParams.product` (δ = 0.1, d₀ = 0) and :meth:`CarParams.paper` (δ = 0, d₀ = 0.1 m/s: the HJRNO
  paper's benchmark car and ``CarParams()``'s default, kept so that the reproduction experiments, their datasets
  and ``models/v5`` / ``models/paper_cnn`` do not move; the node's car is :meth:`CarParams.product`);
- the **differential drive** (:class:`DiffDriveParams`): turn-rate control, g(v) = 1, |u₂| ≤ ω_max, so it
  turns in place: the node's default robot and ``models/default``.  Its defaults are the product robot's
  (δ = 0.1, d₀ = 0: a stopped robot stays stopped).

Arrays: a state is ``(..., n)`` with the last axis in state order, (x, y, v, θ) for the car and
(x, y, ψ) for Air3D; gradients, controls and disturbances follow the same rule.  SI units.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

Array = Any

_EDGE_TOL = 1e-6  # relative tolerance for "the speed sits on its limit"
CAR_MODEL = "dynamic_dubins_car"  # the card's dynamics.model: the equations above, curvature control
DIFF_DRIVE_MODEL = "diff_drive"  # the same with turn-rate control
# A card written before the product model: {a_max, kappa_max, d_max, v_min, v_max}, the paper's
# disturbance ‖d‖ ≤ d_max, i.e. d₀ = d_max with δ = 0 (CarParams.from_dict translates it).
LEGACY_CAR_FIELDS = ("a_max", "kappa_max", "d_max", "v_min", "v_max")


def _check(cond: bool, message: str) -> None:
    if not cond:
        raise ValueError(message)


def _concrete(values: tuple) -> bool:
    """True when every value is a plain number (not a JAX tracer used for a traced sweep)."""
    return all(isinstance(v, (int, float, np.floating, np.integer)) for v in values)


def _check_limits(params: Any, kind: str, turn: str) -> None:
    """ValueError naming the first unusable limit of a ground robot's ``params`` (``turn``: its turn limit)."""
    values = dataclasses.astuple(params)
    if not _concrete(values):
        return
    _check(all(math.isfinite(v) for v in values), f"{kind} parameters must be finite: {params}")
    _check(params.a_max > 0, f"a_max must be > 0, got {params.a_max}")
    _check(getattr(params, turn) > 0, f"{turn} must be > 0, got {getattr(params, turn)}")
    _check(params.v_max > 0, f"v_max must be > 0, got {params.v_max}")
    _check(params.v_min < params.v_max, f"need v_min < v_max, got v_min={params.v_min} v_max={params.v_max}")
    _check(params.tracking_error >= 0, f"tracking_error (δ) must be >= 0, got {params.tracking_error}")
    _check(params.d0 >= 0, f"d0 must be >= 0, got {params.d0}")


@dataclasses.dataclass(frozen=True, init=False)
class CarParams:
    """Limits and disturbance bound of the dynamic Dubins car (docs/design.md, "Robot models").

    ``CarParams()`` is the paper's benchmark car (:meth:`paper`), for the reproduction experiments; :meth:`product`
    is the product car (``models/car_fno``).  The node's default robot is :class:`DiffDriveParams`.  The
    paper's name ``d_max`` is accepted as a keyword (it means d₀ with δ = 0) and readable while
    δ = 0; with a speed-dependent bound use :func:`disturbance_bound`.
    """

    a_max: float = 1.0  # |u1| ≤ a_max, m/s²
    kappa_max: float = 1.0  # |u2| ≤ κ_max, 1/m
    d0: float = 0.1  # ‖d‖ ≤ δ·|v| + d₀: the part at rest, m/s
    v_min: float = 0.0  # m/s; < 0 allowed (a base that reverses)
    v_max: float = 1.0  # m/s
    tracking_error: float = 0.0  # δ, dimensionless: the part that grows with |v|

    def __init__(self, a_max: float = 1.0, kappa_max: float = 1.0, d0: float | None = None, v_min: float = 0.0,
                 v_max: float = 1.0, tracking_error: float = 0.0, *, d_max: float | None = None):
        if d_max is not None:
            _check(d0 is None, "give d0 or the paper's d_max, not both")
            _check(tracking_error == 0, "d_max is the paper's speed-independent bound: use d0 with tracking_error")
            d0 = d_max
        values = (a_max, kappa_max, 0.1 if d0 is None else d0, v_min, v_max, tracking_error)
        for f, value in zip(dataclasses.fields(self), values, strict=True):
            object.__setattr__(self, f.name, value)
        self.__post_init__()

    def __post_init__(self) -> None:
        _check_limits(self, "car", "kappa_max")

    @classmethod
    def paper(cls, **changes: float) -> CarParams:
        """The HJRNO paper's car: a = κ = 1, v ∈ [0, 1], ‖d‖ ≤ 0.1 m/s at every speed (δ = 0, d₀ = 0.1)."""
        return dataclasses.replace(cls(), **changes)

    @classmethod
    def product(cls, **changes: float) -> CarParams:
        """The product robot: a = κ = 1, v ∈ [0, 1], ‖d‖ ≤ 0.1·|v| (δ = 0.1, d₀ = 0): at rest, no drift."""
        return dataclasses.replace(cls(tracking_error=0.1, d0=0.0), **changes)

    @property
    def preset(self) -> str | None:
        """"paper" or "product" when these are exactly that named configuration's values, else None."""
        return next((name for name, make in CAR_PRESETS.items() if make() == self), None)

    @property
    def d_max(self) -> float:
        """The paper's speed-independent bound d₀; an error while δ > 0 (the bound depends on v)."""
        _check(self.tracking_error == 0, f"the disturbance bound depends on speed (tracking_error "
               f"{self.tracking_error}): use disturbance_bound(params, v), not d_max")
        return self.d0

    model = CAR_MODEL  # the card's dynamics.model

    def disturbance_max(self) -> float:
        """The largest bound over the speed range, max_v δ·|v| + d₀, m/s."""
        return self.tracking_error * max(abs(self.v_min), abs(self.v_max)) + self.d0

    @property
    def turn_max(self) -> float:
        """The bound of the turn control u₂: κ_max, 1/m."""
        return self.kappa_max

    @property
    def turn_rate_max(self) -> float:
        """The fastest turn at top speed, κ_max·v_max, rad/s (sets the time scale of similarity)."""
        return self.kappa_max * self.v_max

    def rescaled(self, length: float, time: float) -> CarParams:
        """The same car with lengths divided by ``length`` and times by ``time`` (docs/design.md, "Similarity")."""
        speed = length / time
        return CarParams(a_max=self.a_max * time ** 2 / length, kappa_max=self.kappa_max * length,
                         d0=self.d0 / speed, v_min=self.v_min / speed, v_max=self.v_max / speed,
                         tracking_error=self.tracking_error)

    def as_dict(self) -> dict[str, Any]:
        """``{"model": "dynamic_dubins_car", a_max, kappa_max, d0, v_min, v_max, tracking_error}``: what
        a model card's ``dynamics`` holds; :meth:`from_dict` reads it back."""
        return {"model": CAR_MODEL, **{k: float(v) for k, v in dataclasses.asdict(self).items()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CarParams:
        """Inverse of :meth:`as_dict`.  A dict without ``model`` or any new field (``d0``,
        ``tracking_error``) is the paper's form {a_max, kappa_max, d_max, v_min, v_max}: d₀ = d_max, δ = 0.
        Missing fields take the paper's defaults; unknown fields and models are a ValueError."""
        d = dict(d)
        model = d.pop("model", CAR_MODEL)
        _check(model == CAR_MODEL, f"unknown car dynamics model {model!r}; known: {CAR_MODEL!r}")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names - {"d_max"})
        _check(not unknown, f"unknown car parameter(s) {unknown}; known: {sorted(names)}")
        return cls(**d)


@dataclasses.dataclass(frozen=True)
class DiffDriveParams:
    """Limits and disturbance bound of the differential drive (docs/design.md, "Robot models"): θ̇ = u₂ with
    |u₂| ≤ ω_max, so it turns in place.  The defaults are the product robot's in its own units
    (v_max = ω_max = 1, δ = 0.1, d₀ = 0: a stopped robot stays stopped, and turning in place keeps it safe)."""

    a_max: float = 1.0  # |u1| ≤ a_max, m/s²
    omega_max: float = 1.0  # |u2| ≤ ω_max, rad/s
    d0: float = 0.0  # m/s, the disturbance at rest
    v_min: float = 0.0  # m/s; < 0 allowed (a base that reverses)
    v_max: float = 1.0  # m/s
    tracking_error: float = 0.1  # δ

    model = DIFF_DRIVE_MODEL

    def __post_init__(self) -> None:
        _check_limits(self, "diff-drive", "omega_max")

    disturbance_max = CarParams.disturbance_max

    @property
    def preset(self) -> str | None:
        return "diff_drive" if self == DiffDriveParams() else None

    @property
    def turn_max(self) -> float:
        """The bound of the turn control u₂: ω_max, rad/s."""
        return self.omega_max

    @property
    def turn_rate_max(self) -> float:
        """The fastest turn, ω_max, rad/s (at every speed, rest included)."""
        return self.omega_max

    def rescaled(self, length: float, time: float) -> DiffDriveParams:
        """The same robot with lengths divided by ``length`` and times by ``time``."""
        speed = length / time
        return DiffDriveParams(a_max=self.a_max * time ** 2 / length, omega_max=self.omega_max * time,
                               d0=self.d0 / speed, v_min=self.v_min / speed, v_max=self.v_max / speed,
                               tracking_error=self.tracking_error)

    def as_dict(self) -> dict[str, Any]:
        """``{"model": "diff_drive", a_max, omega_max, d0, v_min, v_max, tracking_error}``."""
        return {"model": DIFF_DRIVE_MODEL, **{k: float(v) for k, v in dataclasses.asdict(self).items()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> DiffDriveParams:
        """Inverse of :meth:`as_dict`; missing fields take the defaults, unknown ones are a ValueError."""
        d = dict(d)
        model = d.pop("model", DIFF_DRIVE_MODEL)
        _check(model == DIFF_DRIVE_MODEL, f"not a diff-drive model: {model!r}")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        _check(not unknown, f"unknown diff-drive parameter(s) {unknown}; known: {sorted(names)}")
        return cls(**{k: float(v) for k, v in d.items()})


RobotParams = CarParams | DiffDriveParams
ROBOT_MODELS = {CAR_MODEL: CarParams, DIFF_DRIVE_MODEL: DiffDriveParams}
CAR_PRESETS = {"paper": CarParams.paper, "product": CarParams.product, "diff_drive": DiffDriveParams}


def car_preset(name: str) -> RobotParams:
    """The named robot model: ``"paper"`` or ``"product"`` (cars) or ``"diff_drive"``."""
    _check(name in CAR_PRESETS, f"unknown robot model {name!r}; choose from {', '.join(CAR_PRESETS)}")
    return CAR_PRESETS[name]()


def robot_from_dict(d: Mapping[str, Any]) -> RobotParams:
    """A card's or scenario's ``dynamics`` dict as parameters: ``model`` picks the class (none: the car)."""
    model = d.get("model", CAR_MODEL)
    _check(model in ROBOT_MODELS, f"unknown robot dynamics model {model!r}; known: {sorted(ROBOT_MODELS)}")
    return ROBOT_MODELS[model].from_dict(d)


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
# Ground robots: ẋ = v cos θ + d1, ẏ = v sin θ + d2, v̇ = u1, θ̇ = g(v)·u2, ‖d‖ ≤ δ·|v| + d₀, with
# g(v) = v for the car (curvature) and 1 for the differential drive (turn rate).


def turn_gain(p: RobotParams, v: Array, xp=np) -> Array:
    """g(v) in θ̇ = g(v)·u₂: v for the car (curvature control), 1 for the differential drive (turn rate)."""
    return v if p.model == CAR_MODEL else xp.ones_like(v)


def disturbance_bound(p: RobotParams, v: Array, xp=np) -> Array:
    """The radius of the disturbance ball at speed v: δ·|v| + d₀, m/s."""
    return p.tracking_error * xp.abs(v) + p.d0


def feasible_acceleration(p: RobotParams, v: Array, u1: Array, xp=np) -> Array:
    """Clip u1 so the speed cannot leave [v_min, v_max] (neither limit is crossed, whatever its sign)."""
    tol = _EDGE_TOL * (p.v_max - p.v_min)
    u1 = xp.where(v >= p.v_max - tol, xp.minimum(u1, 0.0), u1)
    return xp.where(v <= p.v_min + tol, xp.maximum(u1, 0.0), u1)


def robot_f(p: RobotParams, state: Array, control: Array, disturbance: Array, xp=np) -> Array:
    """ẋ = f(x, u, d); u = (acceleration, curvature or turn rate), d = (dx, dy) in m/s."""
    v, theta = state[..., 2], state[..., 3]
    u1 = feasible_acceleration(p, v, control[..., 0], xp)
    return xp.stack([v * xp.cos(theta) + disturbance[..., 0], v * xp.sin(theta) + disturbance[..., 1], u1,
                     turn_gain(p, v, xp) * control[..., 1]], axis=-1)


def optimal_control(p: RobotParams, state: Array, grad: Array, xp=np) -> Array:
    """argmax_u ∇V·f: u1 = a_max·sign(∂V/∂v) (kept feasible), u2 = u₂max·sign(g(v)·∂V/∂θ).

    Where ∂V/∂v = 0 every u1 is optimal and u1 brakes towards v = 0 (−a_max·sign(v)): the safe control
    never speeds up without a reason in V.  The car's g(v) = v matters when reversing: at v < 0 the same
    curvature turns the heading the other way, so its safe turn flips with the direction of travel."""
    v = state[..., 2]
    u1 = xp.where(grad[..., 2] < 0, -p.a_max, xp.where(grad[..., 2] > 0, p.a_max, -p.a_max * xp.sign(v)))
    u2 = xp.where(turn_gain(p, v, xp) * grad[..., 3] < 0, -p.turn_max, p.turn_max)
    return xp.stack([feasible_acceleration(p, v, u1, xp), u2], axis=-1)


def worst_direction(grad: Array, xp=np) -> Array:
    """−∇ₓᵧV / ‖∇ₓᵧV‖, the unit x-y direction that lowers V fastest (zero where ∇ₓᵧV = 0)."""
    g = grad[..., :2]
    norm = xp.sqrt(xp.sum(g * g, axis=-1, keepdims=True))
    return xp.where(norm > 0, -g / xp.where(norm > 0, norm, 1.0), 0.0 * g)


def worst_disturbance(p: RobotParams, state: Array, grad: Array, xp=np) -> Array:
    """argmin_d ∇V·f over the ball ‖d‖ ≤ δ·|v| + d₀: d = −(δ·|v| + d₀)·∇ₓᵧV / ‖∇ₓᵧV‖."""
    return disturbance_bound(p, state[..., 2], xp)[..., None] * worst_direction(grad, xp)


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
