"""The ``plans`` family: windows of generated floor plans (truth/floor_plans.py) and the accel_ratio datasets."""

import json
import math

import numpy as np
import pytest

from hjrno_ros.core.geometry import union_sdf
from hjrno_ros.datasets.dataset import ExperimentConfig, load_config
from hjrno_ros.truth.floor_plans import PLAN_STYLES, ROBOT_CLEARANCE
from hjrno_ros.truth.scenarios import FAMILIES, Scenario, make_scenario

SEEDS = range(40)


@pytest.fixture(scope="module")
def plans():
    return [make_scenario("plans", seed, robot="product") for seed in SEEDS]


def test_every_style_appears_and_the_robot_stands_free_at_the_origin(plans):
    assert {p.params["style"] for p in plans} == set(PLAN_STYLES)
    for p in plans:
        assert union_sdf(p.shapes, np.zeros(2)) >= ROBOT_CLEARANCE - 1e-9
        assert len(p.params["shape_roles"]) == len(p.shapes)
        assert p.params["shape_roles"].count("edge") == 4  # the map edge around every plan


def test_plans_hold_what_real_maps_hold(plans):
    roles = {r for p in plans for r in p.params["shape_roles"]}
    assert {"wall", "solid", "shelf", "clutter", "unknown", "edge"} <= roles
    thin = [p for p in plans if p.params["wall_thickness"] < 0.15]
    assert thin, "some plans have walls thinner than 0.15 units (a model grid cell is 0.32)"
    # obstacles cross the window's edge: l changes sign along the window's border in most windows
    grid = plans[0].grid((33, 33, 3, 4))
    crossing = 0
    for p in plans:
        l_xy = p.target(grid)[:, :, 0, 0]
        border = np.concatenate([l_xy[0], l_xy[-1], l_xy[:, 0], l_xy[:, -1]])
        crossing += bool((border > 0).any() and (border <= 0).any())
    assert crossing >= 0.7 * len(plans)


def test_corridor_plans_have_dead_ends_and_widths_in_range():
    p = make_scenario("plans", 3, robot="product", style="corridors")
    assert p.params["style"] == "corridors"
    lo, hi = FAMILIES["plans"].ranges["corridor_width"]
    assert (lo, hi) == (1.0, 4.0)


def test_plans_are_reproducible_and_round_trip_through_json(plans):
    again = make_scenario("plans", 7, robot="product")
    assert again.as_dict() == plans[7].as_dict()
    back = Scenario.from_dict(json.loads(json.dumps(plans[7].as_dict())))
    grid = back.grid((16, 16, 3, 4))
    assert np.array_equal(back.target(grid), plans[7].target(grid))
    assert make_scenario("plans", 8, robot="product").as_dict() != plans[7].as_dict()


def test_accel_ratio_draws_a_max_log_uniformly_and_keeps_the_geometry():
    cfg = load_config("product_plans")
    assert cfg.accel_ratio == (0.5, 4.0)
    a = np.array([cfg.scenario("train", i).params["a_max"] for i in range(200)])
    assert a.min() >= 0.5 and a.max() <= 4.0
    assert 0.35 < np.mean(np.log(a) < math.log(math.sqrt(2.0))) < 0.65  # the log-median of [0.5, 4] is √2
    s = cfg.scenario("train", 5)
    assert (s.params["kappa_max"], s.params["v_max"], s.params["v_min"], s.params["tracking_error"]) == (1, 1, 0, .1)
    plain = make_scenario("plans", 5, robot="product")
    assert [x.as_dict() for x in s.shapes] == [x.as_dict() for x in plain.shapes]
    test = cfg.scenario("test", 0)
    assert test.seed >= 1_000_000  # held-out plans: seeds never used in training
    assert load_config("product_calib").scenario("test", 0).seed not in {cfg.scenario("test", i).seed
                                                                         for i in range(cfg.n_test)}


@pytest.mark.parametrize("bad", [[0.0, 1.0], [2.0, 1.0], [1.0], "fast", [1.0, math.inf]])
def test_a_bad_accel_ratio_is_one_clear_error(bad):
    with pytest.raises(ValueError, match="accel_ratio must be"):
        ExperimentConfig("x", "plans", (8, 8, 3, 4), 1, 0, options={"robot": "product"}, accel_ratio=bad)


def test_configs_without_accel_ratio_keep_their_digest():
    cfg = load_config("ci")
    assert "accel_ratio" not in cfg.as_dict()
