"""The six HJRNO scenario families (and ``windows``, for the node's model), seeded and reproducible.

A :class:`Scenario` is plain data (family, seed, shapes, params) that round-trips through JSON;
it knows its dynamics, its default grid and its target l on a grid (l > 0 outside obstacles,
≤ 0 inside; docs/design.md, "Conventions").  :func:`make_scenario` draws one from a family:

=============  ==============================================================================
``single``     one random smooth obstacle fully inside the 10 m × 10 m domain
``two``        two such obstacles a sampled ``separation`` apart (gap between bounding circles)
``indoor``     outer walls, 1–2 interior walls with door gaps, clutter (boxes, disks, ellipses)
``velocity``   one obstacle growing with speed: l(x, y, v) = sdf(x, y) − r(v), r "exp" or "log"
``parametric`` one obstacle; the car's limits (a_max, κ_max) are the sampled parameters
``air3d``      random evader and pursuer shapes in their body frames; l via the Minkowski sum
``windows``    a robot-centred 10 m window of a larger (16 m) map: random blobs and wall segments
               that cross the window edge, the window centre (the robot) ≥ 0.3 m from everything
``plans``      a robot-centred window of a generated floor plan: rooms and doors, corridors and dead
               ends, warehouse shelves, thin walls, clutter, unknown patches, the map edge
               (truth/floor_plans.py; in model units for the product model)
=============  ==============================================================================

Reproducibility: the random stream is ``np.random.default_rng([seed, family index])`` (the
family index keeps equal seeds of different families independent).  Every sampled value is
drawn even when the caller overrides it, so an override changes only what depends on it
(e.g. the same parametric seed gives the same obstacle for every (a_max, κ_max)).
Each family declares its sampling ranges once, in :data:`FAMILIES`.  Overrides of geometric
parameters must lie in those ranges; overrides of dynamics parameters (CarParams, DiffDriveParams or
Air3DParams fields) only need to be physically valid, so a model can be tested outside the
training box.  The ground-robot families take the robot model as the option ``robot`` ("paper", the default
the reproduction datasets use, "product", or "diff_drive"; docs/design.md, "Robot models"), whose values the
dynamics options then change; a scenario's ``params`` hold the resulting model (its ``as_dict``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hjrno_ros.core.dynamics import Air3DParams, CarParams, DiffDriveParams, RobotParams, car_preset, robot_from_dict
from hjrno_ros.core.geometry import ClosedSpline, air3d_collision_sdf, shape_from_dict, union_sdf
from hjrno_ros.core.grids import GridSpec, air3d_grid, car_grid
from hjrno_ros.truth.floor_plans import PLAN_STYLES, build_indoor, build_plans, build_windows
from hjrno_ros.truth.shapes import DOMAIN_HI, DOMAIN_LO, ROUNDNESS, random_smooth_shape
from hjrno_ros.truth.systems import Air3D, DynamicDubinsCar, robot_system

__all__ = ["DOMAIN_HI", "DOMAIN_LO", "FAMILIES", "Scenario", "make_scenario", "random_smooth_shape"]
EDGE_MARGIN = 0.5  # m, free band between obstacles (grown ones included) and the domain edge


def growth_radius(law: str, c: float, k: float, v) -> np.ndarray:
    """Speed-dependent inflation r(v) of the velocity family: c·(exp(k v) − 1) or c·log(1 + k v)."""
    v = np.asarray(v, float)
    if law == "exp":
        return c * np.expm1(k * v)
    if law == "log":
        return c * np.log1p(k * v)
    raise ValueError(f"unknown velocity law {law!r}; known: {VELOCITY_LAWS}")


VELOCITY_LAWS = ("exp", "log")


# ---------------------------------------------------------------------------------------------
# Scenario: plain data with its dynamics, grid and target.


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One sample: ``shapes`` are geometry shapes (Air3D: (evader, pursuer) in body frames);
    ``params`` holds the sampled parameters and the dynamics' parameters (JSON-serialisable)."""

    family: str
    seed: int
    shapes: tuple
    params: dict

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"unknown scenario family {self.family!r}; known: {sorted(FAMILIES)}")
        object.__setattr__(self, "shapes", tuple(self.shapes))
        object.__setattr__(self, "params", dict(self.params))
        if not self.shapes:
            raise ValueError("a scenario needs at least one shape")
        if self.is_air3d and len(self.shapes) != 2:
            raise ValueError(f"an air3d scenario needs exactly (evader, pursuer), got {len(self.shapes)} shapes")

    @property
    def is_air3d(self) -> bool:
        return FAMILIES[self.family].kind == "air3d"

    def dynamics_params(self) -> RobotParams | Air3DParams:
        """The dynamics' parameters (``params["model"]`` names the ground robot); a car scenario stored before the
        product model (``d_max``) is the paper's car."""
        if self.is_air3d:
            return Air3DParams(**{f.name: self.params[f.name] for f in dataclasses.fields(Air3DParams)
                                  if f.name in self.params})
        cls = DiffDriveParams if self.params.get("model") == DiffDriveParams.model else CarParams
        names = ("model", "d_max", *(f.name for f in dataclasses.fields(cls)))
        return robot_from_dict({k: self.params[k] for k in names if k in self.params})

    def dynamics(self) -> DynamicDubinsCar | Air3D:
        """The ``hj_reachability`` dynamics with this scenario's parameters."""
        p = self.dynamics_params()
        return Air3D(p) if self.is_air3d else robot_system(p)

    def grid(self, shape: tuple[int, ...] | None = None) -> GridSpec:
        """Default grid: Air3D's relative domain, or the car's [-5, 5]² × [v_min, v_max] × [-π, π)."""
        if self.is_air3d:
            return air3d_grid(shape) if shape is not None else air3d_grid()
        p = self.dynamics_params()
        kw = {"xy_lo": (DOMAIN_LO, DOMAIN_LO), "xy_hi": (DOMAIN_HI, DOMAIN_HI), "v_range": (p.v_min, p.v_max)}
        return car_grid(shape, **kw) if shape is not None else car_grid(**kw)

    def target(self, grid: GridSpec | None = None) -> np.ndarray:
        """l on ``grid`` as float32: ``l[ix, iy, iv, iθ]`` for the car, ``l[ix, iy, iψ]`` for Air3D."""
        grid = self.grid() if grid is None else grid
        if self.is_air3d:
            return air3d_collision_sdf(self.shapes[0], self.shapes[1], grid)
        if grid.ndim != 4:
            raise ValueError(f"a car scenario needs an (x, y, v, theta) grid, got {grid.ndim} axes")
        xy = np.stack(np.meshgrid(grid.axis(0), grid.axis(1), indexing="ij"), -1)
        l_xy = union_sdf(self.shapes, xy)[:, :, None]
        if self.family == "velocity":
            p = self.params
            l_xy = l_xy - growth_radius(p["law"], p["c"], p["k"], grid.axis(2))[None, None, :]
        else:
            l_xy = np.repeat(l_xy, grid.shape[2], axis=2)
        return np.ascontiguousarray(np.broadcast_to(l_xy[..., None], grid.shape), dtype=np.float32)

    def as_dict(self) -> dict:
        return {
            "family": self.family,
            "seed": int(self.seed),
            "shapes": [s.as_dict() for s in self.shapes],
            "params": self.params,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Scenario:
        """Inverse of :meth:`as_dict` (also after a JSON round trip)."""
        return cls(d["family"], int(d["seed"]), tuple(shape_from_dict(s) for s in d["shapes"]), dict(d["params"]))


# ---------------------------------------------------------------------------------------------
# Drawing with overrides.


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise ValueError(f"option {name!r} must be a finite number, got {value!r}")
    return float(value)


class _Draw:
    """Draws from the family's ranges; always consumes the stream, then applies an override."""

    def __init__(self, rng: np.random.Generator, spec: FamilySpec, overrides: Mapping[str, Any]):
        self.rng, self.spec, self.overrides = rng, spec, dict(overrides)

    def uniform(self, name: str, lo: float | None = None, hi: float | None = None, free: bool = False) -> float:
        """U(lo, hi) (default: the declared range); ``free``: an override need not lie in the range."""
        lo, hi = self.spec.ranges[name] if lo is None else (lo, hi)
        value = float(self.rng.uniform(lo, hi))
        if name not in self.overrides:
            return value
        value = _number(name, self.overrides[name])
        if not free and not lo <= value <= hi:
            raise ValueError(f"option {name}={value} lies outside its range [{lo}, {hi}]")
        return value

    def integer(self, name: str) -> int:
        lo, hi = self.spec.ranges[name]
        value = int(self.rng.integers(lo, hi + 1))
        if name not in self.overrides:
            return value
        value = self.overrides[name]
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not lo <= value <= hi:
            raise ValueError(f"option {name} must be an integer in [{lo}, {hi}], got {value!r}")
        return int(value)

    def choice(self, name: str) -> str:
        options = self.spec.choices[name]
        value = options[int(self.rng.integers(len(options)))]
        value = self.overrides.get(name, value)
        if value not in options:
            raise ValueError(f"option {name} must be one of {options}, got {value!r}")
        return value

    def dynamics(self, cls: type, **values: float) -> dict[str, Any]:
        """Fields of the ground robot's parameters / Air3DParams: given values, else overrides, else defaults
        (validated).  For a ground robot (``cls`` CarParams) the option ``robot`` names the model and its defaults
        ("paper", the default, "product" or "diff_drive")."""
        defaults = car_preset(self.overrides.get("robot", "paper")) if cls is CarParams else cls()
        cls = type(defaults)
        values = {k: v for k, v in values.items() if k in {f.name for f in dataclasses.fields(cls)}}
        fields = {}
        for f in dataclasses.fields(cls):
            raw = values.get(f.name, self.overrides.get(f.name, getattr(defaults, f.name)))
            fields[f.name] = _number(f.name, raw)
        return cls(**fields).as_dict()


# ---------------------------------------------------------------------------------------------
# Families.


def _center_bounds(reach: float) -> tuple[float, float]:
    """Bounds of a centre whose disk of radius ``reach`` keeps EDGE_MARGIN from the domain edge."""
    lo, hi = DOMAIN_LO + EDGE_MARGIN + reach, DOMAIN_HI - EDGE_MARGIN - reach
    if lo > hi:
        raise ValueError(f"an obstacle reaching {reach:.2f} m from its centre does not fit in the domain")
    return lo, hi


def _blob(draw: _Draw, radius: float, grow: float = 0.0) -> tuple[ClosedSpline, list[float]]:
    lo, hi = _center_bounds(radius + grow)
    center = draw.rng.uniform(lo, hi, 2)
    return random_smooth_shape(draw.rng, center, (ROUNDNESS * radius, radius)), center.tolist()


def _build_single(draw: _Draw) -> tuple[list, dict]:
    car = draw.dynamics(CarParams)
    radius = draw.uniform("radius")
    shape, center = _blob(draw, radius)
    return [shape], {"radius": radius, "center": center, **car}


def _build_two(draw: _Draw) -> tuple[list, dict]:
    car = draw.dynamics(CarParams)
    r1, r2, sep = draw.uniform("radius_1"), draw.uniform("radius_2"), draw.uniform("separation")
    (lo1, hi1), (lo2, hi2) = _center_bounds(r1), _center_bounds(r2)
    for _ in range(1000):  # c2 = c1 + d: c1 lies in box1 ∩ (box2 − d), a box
        direction = float(draw.rng.uniform(-math.pi, math.pi))
        d = (r1 + r2 + sep) * np.array([math.cos(direction), math.sin(direction)])
        lo, hi = np.maximum(lo1, lo2 - d), np.minimum(hi1, hi2 - d)
        if np.all(lo <= hi):
            break
    else:
        raise ValueError(f"two obstacles of radii {r1:.2f}, {r2:.2f} m {sep:.2f} m apart do not fit in the domain")
    c1 = draw.rng.uniform(lo, hi)
    c2 = c1 + d
    shapes = [random_smooth_shape(draw.rng, c, (ROUNDNESS * r, r)) for c, r in ((c1, r1), (c2, r2))]
    params = {
        "radius_1": r1,
        "radius_2": r2,
        "separation": sep,
        "direction": direction,
        "centers": [c1.tolist(), c2.tolist()],
        **car,
    }
    return shapes, params


def _build_velocity(draw: _Draw) -> tuple[list, dict]:
    car = draw.dynamics(CarParams)
    law = draw.choice("law")
    c = draw.uniform("c", *FAMILIES["velocity"].ranges[f"{law}_c"])
    k = draw.uniform("k", *FAMILIES["velocity"].ranges[f"{law}_k"])
    radius = draw.uniform("radius")
    grow = float(growth_radius(law, c, k, car["v_max"]))
    shape, center = _blob(draw, radius, grow)
    return [shape], {"law": law, "c": c, "k": k, "radius": radius, "center": center, **car}


def _build_parametric(draw: _Draw) -> tuple[list, dict]:
    a_max, kappa_max = draw.uniform("a_max", free=True), draw.uniform("kappa_max", free=True)
    car = draw.dynamics(CarParams, a_max=a_max, kappa_max=kappa_max)
    radius = draw.uniform("radius")
    shape, center = _blob(draw, radius)
    return [shape], {"radius": radius, "center": center, **car}


def _build_air3d(draw: _Draw) -> tuple[list, dict]:
    params = draw.dynamics(Air3DParams)
    r_e, r_p = draw.uniform("evader_radius"), draw.uniform("pursuer_radius")
    shapes = [random_smooth_shape(draw.rng, (0.0, 0.0), (ROUNDNESS * r, r)) for r in (r_e, r_p)]
    return shapes, {"evader_radius": r_e, "pursuer_radius": r_p, **params}


@dataclasses.dataclass(frozen=True)
class FamilySpec:
    """A family: its sampling ranges (uniform; integers inclusive), categorical choices and builder."""

    name: str
    kind: str  # "car" or "air3d"
    ranges: Mapping[str, tuple[float, float]]
    build: Callable[[_Draw], tuple[list, dict]]
    choices: Mapping[str, tuple] = dataclasses.field(default_factory=dict)
    extra_options: tuple[str, ...] = ()  # overridable names without a range of their own

    @property
    def options(self) -> tuple[str, ...]:
        """Names ``make_scenario`` accepts as overrides."""
        dyn = (Air3DParams,) if self.kind == "air3d" else (CarParams, DiffDriveParams)
        names = [k for k in self.ranges if k not in _LAW_KEYS] + ([] if self.kind == "air3d" else ["robot"])
        return tuple(sorted({*names, *self.choices, *self.extra_options,
                             *(f.name for cls in dyn for f in dataclasses.fields(cls))}))


_LAW_KEYS = {f"{law}_{c}" for law in VELOCITY_LAWS for c in "ck"}
_SINGLE_RADIUS = (0.75, 2.0)

FAMILIES: dict[str, FamilySpec] = {
    "single": FamilySpec("single", "car", {"radius": _SINGLE_RADIUS}, _build_single),
    "two": FamilySpec(
        "two", "car", {"radius_1": (0.6, 1.4), "radius_2": (0.6, 1.4), "separation": (0.2, 2.5)}, _build_two
    ),
    "indoor": FamilySpec(
        "indoor",
        "car",
        {
            "wall_thickness": (0.3, 0.5),
            "n_walls": (1, 2),
            "n_clutter": (1, 4),
            "wall_positions": (-2.0, 2.0),
            "door_widths": (1.0, 1.6),
            "clutter_sizes": (0.3, 0.7),
        },
        build_indoor,
    ),
    "velocity": FamilySpec(
        "velocity",
        "car",
        {"radius": (0.75, 1.5), "exp_c": (0.2, 0.4), "exp_k": (0.5, 1.5), "log_c": (0.2, 0.6), "log_k": (1.0, 5.0)},
        _build_velocity,
        choices={"law": VELOCITY_LAWS},
        extra_options=("c", "k"),
    ),
    "parametric": FamilySpec(
        "parametric", "car", {"a_max": (0.5, 1.5), "kappa_max": (0.5, 1.5), "radius": _SINGLE_RADIUS}, _build_parametric
    ),
    "air3d": FamilySpec("air3d", "air3d", {"evader_radius": (0.5, 1.5), "pursuer_radius": (0.5, 1.5)}, _build_air3d),
    "windows": FamilySpec(
        "windows",
        "car",
        {"n_blobs": (5, 12), "n_walls": (0, 2), "radius": (0.4, 1.2), "wall_thickness": (0.15, 0.3),
         "wall_length": (3.0, 10.0)},
        build_windows,
    ),
    "plans": FamilySpec(
        "plans",
        "car",
        {"wall_thickness": (0.05, 0.4), "room_size": (3.0, 8.0), "door_width": (1.0, 2.5),
         "corridor_width": (1.0, 4.0), "n_branches": (1, 5), "aisle_width": (1.0, 3.0), "shelf_depth": (0.5, 1.5),
         "n_clutter": (0, 8), "clutter_size": (0.15, 0.6), "n_unknown": (0, 2)},
        build_plans,
        choices={"style": PLAN_STYLES},
    ),
}
_FAMILY_INDEX = {name: i for i, name in enumerate(FAMILIES)}


def make_scenario(family: str, seed: int, **overrides: Any) -> Scenario:
    """Draw scenario ``seed`` of ``family``; ``overrides`` fix sampled or dynamics parameters by name."""
    if family not in FAMILIES:
        raise ValueError(f"unknown scenario family {family!r}; known: {sorted(FAMILIES)}")
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    spec = FAMILIES[family]
    unknown = sorted(set(overrides) - set(spec.options))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for family {family!r}; options: {list(spec.options)}")
    draw = _Draw(np.random.default_rng([int(seed), _FAMILY_INDEX[family]]), spec, overrides)
    shapes, params = spec.build(draw)
    return Scenario(family, int(seed), tuple(shapes), params)


# ---------------------------------------------------------------------------------------------
# The parametric family's train / test protocol.


def parametric_train_grid(
    n: int = 10, a_range: tuple[float, float] = (0.5, 1.5), kappa_range: tuple[float, float] = (0.5, 1.5)
) -> list[tuple[float, float]]:
    """(a_max, κ_max) on an n × n lattice over the box (end points included), a-major order."""
    if n < 2:
        raise ValueError(f"the training lattice needs n >= 2, got {n}")
    return [(float(a), float(k)) for a in np.linspace(*a_range, n) for k in np.linspace(*kappa_range, n)]


def parametric_test_diagonal(
    n: int,
    rng: np.random.Generator,
    a_range: tuple[float, float] = (0.5, 1.5),
    kappa_range: tuple[float, float] = (0.5, 1.5),
) -> list[tuple[float, float]]:
    """n values drawn uniformly along the box's diagonal from (a_lo, κ_lo) to (a_hi, κ_hi)."""
    if n < 1:
        raise ValueError(f"need n >= 1 test values, got {n}")
    (a0, a1), (k0, k1) = a_range, kappa_range
    return [(float(a0 + u * (a1 - a0)), float(k0 + u * (k1 - k0))) for u in rng.uniform(0.0, 1.0, n)]
