"""The six scenario families: sign of l, shapes inside the domain, seeds, ranges, round trips."""

import json

import numpy as np
import pytest

from hjrno_ros import scenarios as sc
from hjrno_ros.solver import solve

CAR_SHAPE = (24, 24, 5, 8)
AIR3D_SHAPE = (27, 21, 12)


def small_grid(scenario):
    return scenario.grid(AIR3D_SHAPE if scenario.is_air3d else CAR_SHAPE)


@pytest.mark.parametrize("family", list(sc.FAMILIES))
def test_seeds_reproduce_and_differ(family):
    a, b, c = sc.make_scenario(family, 3), sc.make_scenario(family, 3), sc.make_scenario(family, 4)
    grid = small_grid(a)
    np.testing.assert_array_equal(a.target(grid), b.target(grid))
    assert not np.array_equal(a.target(grid), c.target(grid))


@pytest.mark.parametrize("family", list(sc.FAMILIES))
def test_sign_of_l_and_round_trip(family):
    for seed in range(3):
        s = sc.make_scenario(family, seed)
        grid = small_grid(s)
        target = s.target(grid)
        assert target.shape == grid.shape and target.dtype == np.float32 and np.isfinite(target).all()
        assert (target <= 0).any() and (target > 0).any()
        again = sc.Scenario.from_dict(json.loads(json.dumps(s.as_dict())))
        np.testing.assert_array_equal(again.target(grid), target)
        if not s.is_air3d:
            # l at a point inside each shape is negative; the shapes' union is what l measures.
            for shape in s.shapes:
                inner = getattr(shape, "center", None)
                pts = np.asarray(getattr(shape, "points", None) or [inner])
                centre = np.mean(pts, 0)[None]
                if shape.sdf(centre)[0] < 0 and family != "velocity":
                    xy = np.stack(np.meshgrid(grid.axis(0), grid.axis(1), indexing="ij"), -1)
                    assert np.min(target[..., 0, 0][np.hypot(*(xy - centre).transpose(2, 0, 1)) < 0.4]) < 0.3


@pytest.mark.parametrize("family", ["single", "two", "velocity", "parametric"])
def test_obstacles_stay_inside_the_domain(family):
    edge = np.concatenate([np.stack([np.linspace(-5, 5, 200), np.full(200, y)], -1) for y in (-5, 5)]
                          + [np.stack([np.full(200, x), np.linspace(-5, 5, 200)], -1) for x in (-5, 5)])
    for seed in range(5):
        s = sc.make_scenario(family, seed)
        for shape in s.shapes:
            assert shape.sdf(edge).min() > 0


def test_indoor_has_walls_on_the_edge_and_free_space():
    s = sc.make_scenario("indoor", 0)
    grid = s.grid(CAR_SHAPE)
    target = s.target(grid)
    assert target[0, :, 0, 0].max() <= 0 and target[-1, :, 0, 0].max() <= 0  # outer walls
    assert (target[..., 0, 0] > 0.5).mean() > 0.3  # rooms are mostly free


def test_velocity_obstacles_grow_with_speed():
    s = sc.make_scenario("velocity", 1)
    target = s.target(s.grid(CAR_SHAPE))
    assert np.all(target[:, :, -1] <= target[:, :, 0] + 1e-6)
    assert np.any(target[:, :, -1] < target[:, :, 0] - 0.05)
    assert s.params["law"] in sc.VELOCITY_LAWS


def test_parameters_lie_in_their_declared_ranges():
    for family, spec in sc.FAMILIES.items():
        for seed in range(5):
            s = sc.make_scenario(family, seed)
            for name, (lo, hi) in spec.ranges.items():
                value = s.params.get(name)
                if isinstance(value, (int, float)):
                    assert lo - 1e-9 <= value <= hi + 1e-9, (family, name, value)
                elif isinstance(value, list):
                    assert all(lo - 1e-9 <= v <= hi + 1e-9 for v in value), (family, name, value)


def test_parametric_protocol():
    lattice = sc.parametric_train_grid(10)
    assert len(lattice) == 100 and lattice[0] == (0.5, 0.5) and lattice[-1] == (1.5, 1.5)
    diag = sc.parametric_test_diagonal(50, np.random.default_rng(0))
    assert all(abs((a - 0.5) - (k - 0.5)) < 1e-12 for a, k in diag)
    s = sc.make_scenario("parametric", 0, a_max=0.7, kappa_max=1.2)
    assert s.dynamics().params.a_max == 0.7 and s.dynamics().params.kappa_max == 1.2


@pytest.mark.parametrize("args, kwargs, message", [
    (("moon", 0), {}, "unknown scenario family"),
    (("single", -1), {}, "non-negative"),
    (("single", 0), {"colour": 1}, "unknown option"),
])
def test_bad_requests_are_rejected(args, kwargs, message):
    with pytest.raises(ValueError, match=message):
        sc.make_scenario(*args, **kwargs)


def test_two_obstacles_are_not_the_union_of_single_solutions():
    """V∞ of two obstacles differs from the min of each obstacle's V∞: the gap between them matters."""
    s = sc.make_scenario("two", 2, separation=0.3)
    grid = s.grid((24, 24, 7, 12))
    both, _ = solve(s.dynamics(), grid, s.target(grid), max_horizon=20.0)
    xy = grid.states()[..., :2]
    parts = [solve(s.dynamics(), grid, shape.sdf(xy).astype(np.float32), max_horizon=20.0)[0] for shape in s.shapes]
    union = np.minimum(*parts)
    # More obstacles only shrink the safe set: the union's BRT lies inside the pair's (measured 100 %) ...
    assert np.mean(both[union <= 0] <= 0) > 0.99
    # ... and the pair's V is far below the union's somewhere (measured 0.71 m with a 0.3 m gap).
    assert np.max(union - both) > 0.3
    assert np.mean(both <= 0) > np.mean(union <= 0)
