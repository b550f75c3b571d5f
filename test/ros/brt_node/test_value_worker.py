"""The value worker's V0 and clearance at the map's edge, without DDS: a worker over a solver card's grid
(no weights, no thread) reads a map whose window reaches beyond its edge."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("nav_msgs")  # value_worker's inputs module imports the ROS message types

from hjrno_ros.core import geometry  # noqa: E402
from hjrno_ros.core.model_card import ModelCard  # noqa: E402
from hjrno_ros.ros.brt_node.config import NodeConfig  # noqa: E402
from hjrno_ros.ros.brt_node.inputs import MapData  # noqa: E402
from hjrno_ros.ros.brt_node.value_sources import SolverGrid, resolve_model  # noqa: E402
from hjrno_ros.ros.brt_node.value_worker import ValueWorker, map_distance  # noqa: E402

RES, ORIGIN, SHAPE = 0.05, (2.0, -1.0), (200, 160)  # the map [2, 12] x [-1, 7]


def map_data(unknown_is_obstacle: bool) -> MapData:
    occ = np.zeros(SHAPE, np.int8)
    occ[120:124, 40:100] = 100  # a wall inside the map
    sd = geometry.occupancy_signed_distance(occ, RES, unknown_is_obstacle=unknown_is_obstacle)
    return MapData(occ, sd, ORIGIN, RES, "map", None, 0.0, 1, 65, unknown_is_obstacle)


@pytest.fixture(scope="module")
def worker() -> ValueWorker:
    grid = SolverGrid(ModelCard.load(resolve_model("default")))  # the default's grid and window, no torch
    return ValueWorker(grid, None, None, NodeConfig, lambda *a: None, lambda *a: None)


def test_v0_beyond_the_edge_is_minus_the_distance_to_the_map(worker):
    """A window centred 1 m inside the map's lower-left corner: a quarter and more of its nodes lie beyond the
    edge; there V0 is −(distance to the map) − r, as the wall at the edge makes it (no −resolution plateau)."""
    m = map_data(True)
    points = worker.vf.window_points((ORIGIN[0] + 1.0, ORIGIN[1] + 1.0))
    lo, hi = np.asarray(ORIGIN), np.asarray(ORIGIN) + np.asarray(SHAPE) * RES
    distance = np.hypot(*np.maximum(np.maximum(lo - points, points - hi), 0).T).T
    beyond = distance > 0
    assert beyond.mean() > 0.25
    r = worker.inflation(RES)
    v0 = worker.v0(m, points)
    assert v0.dtype == np.float32 and v0.shape == points.shape[:2]
    np.testing.assert_allclose(v0[beyond], -distance[beyond] - r, atol=1e-5)
    inside = np.all((points >= lo + RES / 2) & (points <= hi - RES / 2), -1)
    np.testing.assert_allclose(v0[inside], geometry.sample_raster(m.sd, ORIGIN, RES, points)[inside] - r, atol=1e-6)
    assert len(np.unique(np.round(v0[beyond], 4))) > 100  # a distance, not a plateau
    braking = worker.clearance(m, points)  # the braking bound reads the same map, less its own margin
    np.testing.assert_allclose(braking[beyond], -distance[beyond] - worker.inflation(RES, model_grid=False),
                               atol=1e-9)


def test_without_unknown_is_obstacle_beyond_the_map_reads_the_nearest_edge_cell(worker):
    m = map_data(False)
    points = worker.vf.window_points((ORIGIN[0] + 1.0, ORIGIN[1] + 1.0))
    nearest = geometry.sample_raster(m.sd, ORIGIN, RES, points)  # outside=None: the nearest cell's value
    np.testing.assert_array_equal(map_distance(m, points), nearest)
    np.testing.assert_allclose(worker.v0(m, points), nearest - worker.inflation(RES), atol=1e-6)
    beyond = np.any(points < np.asarray(ORIGIN), -1)
    assert beyond.mean() > 0.25 and worker.v0(m, points)[beyond].min() > 0  # free space, as the free edge cells
