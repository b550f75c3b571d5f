"""Scenario families: signs, placement, reproducibility, ranges, serialisation, and one tiny solve."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import ndimage

from hjrno_ros.core.geometry import union_sdf
from hjrno_ros.core.grids import air3d_grid, car_grid
from hjrno_ros.truth.scenarios import (
    DOMAIN_HI,
    DOMAIN_LO,
    FAMILIES,
    Scenario,
    growth_radius,
    make_scenario,
    parametric_test_diagonal,
    parametric_train_grid,
    random_smooth_shape,
)
from hjrno_ros.truth.solver import solve
from hjrno_ros.truth.systems import Air3D, DynamicDubinsCar

CAR_FAMILIES = [f for f, spec in FAMILIES.items() if spec.kind == "car"]
SEEDS = (0, 1, 7)
CAR_SMALL = car_grid((51, 51, 5, 4))  # 0.2 m in x-y: a node within 0.15 m of any point (blobs are wider)
INDOOR_FINE = car_grid((101, 101, 3, 4))  # 0.1 m: a node within 0.071 m of any point (small clutter)
AIR3D_SMALL = air3d_grid((27, 21, 12))


def _grid(scen: Scenario):
    return AIR3D_SMALL if scen.is_air3d else INDOOR_FINE if scen.family == "indoor" else CAR_SMALL


def _node(grid, point) -> tuple[int, int]:
    return tuple(int(np.argmin(np.abs(grid.axis(i) - point[i]))) for i in range(2))


def _edge_points(lo: tuple[float, float], hi: tuple[float, float], n: int = 200) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    xs, ys = lo[0] + s * (hi[0] - lo[0]), lo[1] + s * (hi[1] - lo[1])
    return np.concatenate(
        [np.stack([xs, np.full(n, y)], -1) for y in lo[1:] + hi[1:]]
        + [np.stack([np.full(n, x), ys], -1) for x in (lo[0], hi[0])]
    )


def _inside_and_free_points(scen: Scenario) -> tuple[list, list]:
    """Points known to be inside an obstacle and known to be free, per family."""
    p = scen.params
    if scen.family == "air3d":
        return [(0.0, 0.0)], [(18.0, 8.0)]
    if scen.family == "indoor":
        clutter = [s.center for s, r in zip(scen.shapes, p["shape_roles"], strict=True) if r == "clutter"]
        return [(DOMAIN_LO, 0.0), (0.0, DOMAIN_HI), *clutter], [tuple(d) for d in p["doors"]]
    if scen.family == "windows":  # blob centres inside the window; the robot at the centre is free
        return [c for c in p["centers"] if max(map(abs, c)) < DOMAIN_HI - 0.2], [(0.0, 0.0)]
    if scen.family == "plans":  # box centres inside the window; the robot at the centre is free
        boxes = [s.center for s, r in zip(scen.shapes, p["shape_roles"], strict=True)
                 if r in ("wall", "shelf", "solid") and min(s.half_size) >= 0.3]  # thicker than a test-grid cell
        return [c for c in boxes if max(map(abs, c)) < DOMAIN_HI - 0.2], [(0.0, 0.0)]
    centers = p["centers"] if scen.family == "two" else [p["center"]]
    return centers, [(DOMAIN_LO, DOMAIN_LO), (DOMAIN_HI, DOMAIN_HI)]


@pytest.fixture(scope="module", params=list(FAMILIES))
def family(request) -> str:
    return request.param


def _in_range(value, bounds) -> bool:
    v = np.asarray(value, float)
    return bool(np.all((bounds[0] <= v) & (v <= bounds[1])))


# ---------------------------------------------------------------------------------------------
# Every family.


@pytest.mark.parametrize("seed", SEEDS)
def test_sign_of_target(family, seed):
    scen = make_scenario(family, seed)
    grid = _grid(scen)
    target = scen.target(grid)
    assert target.dtype == np.float32 and target.shape == grid.shape
    inside, free = _inside_and_free_points(scen)
    for pt in inside:
        assert union_sdf(scen.shapes[:1] if scen.is_air3d else scen.shapes, np.asarray(pt)) < 0
        assert np.all(target[_node(grid, pt)] < 0), f"l >= 0 at {pt}, inside an obstacle"
    for pt in free:
        assert np.all(target[_node(grid, pt)] > 0), f"l <= 0 at {pt}, in free space"


@pytest.mark.parametrize("seed", SEEDS)
def test_shapes_inside_domain(family, seed):
    scen = make_scenario(family, seed)
    grid = _grid(scen)
    edge = _edge_points(grid.lo[:2], grid.hi[:2])
    roles = scen.params.get("shape_roles", ["obstacle"] * len(scen.shapes))
    assert len(roles) == len(scen.shapes)
    if family in ("windows", "plans"):  # by design, map obstacles cross the window edge; the robot's spot is free
        assert union_sdf(scen.shapes, np.zeros(2)) >= 0.3
        assert any(shape.sdf(edge).min() <= 0 for shape in scen.shapes) or seed != 0
        return
    for shape, role in zip(scen.shapes, roles, strict=True):
        if role != "outer_wall":
            assert shape.sdf(edge).min() > 0, f"a {role} of {family} seed {seed} reaches the domain edge"
    target = scen.target(grid)
    rim = np.ones(grid.shape[:2], bool)
    rim[1:-1, 1:-1] = False
    if family == "indoor":
        assert target[rim].max() < 0  # the outer walls cover the whole edge
    else:  # grown obstacles (velocity family) included
        assert target[rim].min() > 0
    if scen.is_air3d:
        for shape, key in zip(scen.shapes, ("evader_radius", "pursuer_radius"), strict=True):
            assert shape.reach() <= scen.params[key] + 1e-9  # centred on the body origin


def test_same_seed_reproduces_exactly(family):
    a, b = make_scenario(family, 3), make_scenario(family, 3)
    assert a == b
    grid = _grid(a)
    assert np.array_equal(a.target(grid), b.target(grid))


def test_different_seeds_differ(family):
    grid = _grid(make_scenario(family, 0))
    targets = [make_scenario(family, seed).target(grid) for seed in (0, 1)]
    assert not np.array_equal(*targets)


def test_params_within_declared_ranges(family):
    spec = FAMILIES[family]
    for seed in range(12):
        p = make_scenario(family, seed).params
        checked = 0
        for key, bounds in spec.ranges.items():
            if key in p:
                assert _in_range(p[key], bounds), f"{family} seed {seed}: {key}={p[key]} outside {bounds}"
                checked += 1
        for key, options in spec.choices.items():
            assert p[key] in options
        if family == "velocity":
            for key in ("c", "k"):
                assert _in_range(p[key], spec.ranges[f"{p['law']}_{key}"])
                checked += 1
        assert checked >= 1


def test_json_round_trip(family):
    scen = make_scenario(family, 5)
    back = Scenario.from_dict(json.loads(json.dumps(scen.as_dict())))
    assert back == scen
    grid = _grid(scen)
    assert np.array_equal(back.target(grid), scen.target(grid))


def test_dynamics_and_default_grid(family):
    scen = make_scenario(family, 0)
    dyn, grid = scen.dynamics(), scen.grid()
    if scen.is_air3d:
        assert isinstance(dyn, Air3D) and grid.ndim == 3
    else:
        assert isinstance(dyn, DynamicDubinsCar)
        assert (grid.lo[:3], grid.hi[:3]) == ((-5.0, -5.0, 0.0), (5.0, 5.0, 1.0))
        assert dyn.params.a_max == scen.params["a_max"] and dyn.params.kappa_max == scen.params["kappa_max"]
    assert scen.grid(grid.shape[:-1] + (8,)).shape[-1] == 8


# ---------------------------------------------------------------------------------------------
# Family specifics.


def test_random_smooth_shape_bounds():
    rng = np.random.default_rng(0)
    for _ in range(20):
        shape = random_smooth_shape(rng, (1.0, -2.0), (0.6, 1.0))
        r = np.hypot(*(shape.boundary() - (1.0, -2.0)).T)
        assert r.max() <= 1.0 and r.min() > 0.3
        assert shape.sdf(np.array([1.0, -2.0])) < -0.3
    with pytest.raises(ValueError):
        random_smooth_shape(rng, (0.0, 0.0), (1.0, 0.5))
    with pytest.raises(ValueError):
        random_smooth_shape(rng, (0.0, 0.0), (0.5, 1.0), n_angles=4)


@pytest.mark.parametrize("law", ["exp", "log"])
def test_velocity_obstacle_grows_with_speed(law):
    scen = make_scenario("velocity", 2, law=law)
    grid = car_grid((41, 41, 6, 4))
    target = scen.target(grid)
    dl = np.diff(target, axis=2)
    assert dl.max() <= 1e-6  # never shrinks with speed
    assert dl.min() < -1e-2  # strictly grows somewhere
    base = make_scenario("single", 0)
    static = dataclasses.replace(base, shapes=scen.shapes).target(grid)
    np.testing.assert_allclose(target[:, :, 0], static[:, :, 0], atol=1e-6)  # r(0) = 0
    np.testing.assert_allclose(
        target[:, :, -1], static[:, :, -1] - growth_radius(law, scen.params["c"], scen.params["k"], 1.0), atol=1e-5
    )
    assert (target[:, :, -1] <= 0).sum() > (target[:, :, 0] <= 0).sum()


def test_two_obstacles_keep_their_separation():
    for seed in range(10):
        scen = make_scenario("two", seed)
        gap = scen.shapes[1].sdf(scen.shapes[0].boundary()).min()
        assert gap >= scen.params["separation"] - 1e-9 > 0


@pytest.mark.parametrize("n_walls", [1, 2])
def test_indoor_doors_are_passable(n_walls):
    h, car_radius = 0.1, 0.25
    x = np.arange(DOMAIN_LO + h / 2, DOMAIN_HI, h)
    eight = np.ones((3, 3), bool)
    pts = np.stack(np.meshgrid(x, x, indexing="ij"), -1)
    for seed in range(4):
        scen = make_scenario("indoor", seed, n_walls=n_walls)
        p = scen.params
        assert len(p["doors"]) == n_walls and p["shape_roles"].count("clutter") == p["n_clutter"]
        walls = [s for s, r in zip(scen.shapes, p["shape_roles"], strict=True) if r != "clutter"]
        sdf = union_sdf(scen.shapes, pts)
        for door, width in zip(p["doors"], p["door_widths"], strict=True):
            assert width >= 1.0
            assert union_sdf(scen.shapes, np.asarray(door)) >= width / 2 - 1e-9
        _, rooms = ndimage.label(union_sdf(walls, pts) > car_radius, eight)
        _, free = ndimage.label(sdf > car_radius, eight)  # every room reachable by a car of radius 0.25 m
        assert rooms == free == 1, f"seed {seed}: {free} free regions"


def test_parametric_protocol():
    train = parametric_train_grid(4)
    assert len(set(train)) == 16 and (0.5, 0.5) in train and (1.5, 1.5) in train
    assert all(0.5 <= a <= 1.5 and 0.5 <= k <= 1.5 for a, k in train)
    test = parametric_test_diagonal(20, np.random.default_rng(1), a_range=(0.5, 1.5), kappa_range=(0.2, 2.2))
    assert test == parametric_test_diagonal(20, np.random.default_rng(1), (0.5, 1.5), (0.2, 2.2))
    s = np.array([((a - 0.5) / 1.0, (k - 0.2) / 2.0) for a, k in test])
    np.testing.assert_allclose(s[:, 0], s[:, 1], atol=1e-12)
    assert s.min() >= 0 and s.max() <= 1 and len(np.unique(s[:, 0])) == 20


def test_parametric_limits_and_fixed_obstacle():
    scen = make_scenario("parametric", 4, a_max=0.7, kappa_max=1.3)
    assert (scen.dynamics().params.a_max, scen.dynamics().params.kappa_max) == (0.7, 1.3)
    other = make_scenario("parametric", 4, a_max=2.5, kappa_max=0.5)  # outside the training box is allowed
    assert other.shapes == scen.shapes  # the obstacle depends on the seed only
    assert other.params["a_max"] == 2.5
    sampled = make_scenario("parametric", 4)
    assert sampled.shapes == scen.shapes and sampled.params["a_max"] != 0.7


def test_air3d_overrides():
    scen = make_scenario("air3d", 0, evader_speed=3.0, pursuer_radius=0.8)
    assert scen.dynamics().params.evader_speed == 3.0 and scen.params["pursuer_radius"] == 0.8
    assert make_scenario("air3d", 0).shapes[0] == scen.shapes[0]


@pytest.mark.parametrize(
    ("family", "seed", "overrides", "message"),
    [
        ("forest", 0, {}, "unknown scenario family"),
        ("single", -1, {}, "non-negative integer"),
        ("single", 1.5, {}, "non-negative integer"),
        ("single", 0, {"separation": 1.0}, "unknown option"),
        ("single", 0, {"radius": 4.0}, "outside its range"),
        ("single", 0, {"radius": "big"}, "finite number"),
        ("two", 0, {"separation": -0.1}, "outside its range"),
        ("indoor", 0, {"n_walls": 3}, "integer in"),
        ("indoor", 0, {"n_clutter": 1.5}, "integer in"),
        ("indoor", 0, {"door_widths": 0.5}, "outside its range"),
        ("velocity", 0, {"law": "cubic"}, "must be one of"),
        ("velocity", 0, {"law": "log", "k": 20.0}, "outside its range"),
        ("velocity", 0, {"law": "exp", "v_max": 10.0}, "does not fit"),  # the grown obstacle no longer fits
        ("parametric", 0, {"a_max": -1.0}, "a_max must be > 0"),
        ("parametric", 0, {"kappa_max": float("nan")}, "finite number"),
        ("parametric", 0, {"a_max": True}, "finite number"),
        ("air3d", 0, {"pursuer_speed": -5.0}, "speeds must be >= 0"),
    ],
)
def test_bad_requests_raise(family, seed, overrides, message):
    with pytest.raises(ValueError, match=message):
        make_scenario(family, seed, **overrides)


def test_bad_scenarios_raise():
    scen = make_scenario("single", 0)
    with pytest.raises(ValueError):
        scen.target(air3d_grid((9, 9, 8)))
    with pytest.raises(ValueError):
        Scenario("forest", 0, scen.shapes, scen.params)
    with pytest.raises(ValueError):
        Scenario("air3d", 0, scen.shapes, {})


# ---------------------------------------------------------------------------------------------
# Why the families with several obstacles exist: V∞ is not the union of single-obstacle V∞.


def test_two_obstacle_value_is_not_union_of_singles():
    two = make_scenario("two", 0, separation=0.4)
    grid = two.grid((24, 24, 7, 12))
    dyn = two.dynamics()
    values = []
    for shapes in (two.shapes, two.shapes[:1], two.shapes[1:]):
        target = dataclasses.replace(two, shapes=shapes).target(grid)
        v, _ = solve(dyn, grid, target, accuracy="low", chunk=2.0, max_horizon=8.0, tolerance=1e-2)
        values.append(v)
    gap = np.minimum(values[1], values[2]) - values[0]
    assert gap.min() > -0.02  # an extra obstacle never makes a state safer
    assert gap.max() > 0.2  # ... and the pair is strictly worse than either alone somewhere
    ix, iy = np.unravel_index(np.argmax(gap), grid.shape)[:2]
    mid = np.mean(two.params["centers"], axis=0)
    assert math.dist((grid.axis(0)[ix], grid.axis(1)[iy]), mid) < 2.5  # near the gap between them
