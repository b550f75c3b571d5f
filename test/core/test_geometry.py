"""Signed distance: sign, unit gradient, exactness against closed forms, rasters, Air3D collision sets."""

import numpy as np
import pytest

from hjrno_ros.core import geometry as geo
from hjrno_ros.core.grids import air3d_grid, car_grid

RNG = np.random.default_rng(3)
POINTS = RNG.uniform(-4, 4, (2000, 2))


def unit_gradient_fraction(shape, h=1e-4):
    """Fraction of sample points (away from kinks) where |∇l| is within 2 % of 1."""
    grad = np.stack([(shape.sdf(POINTS + h * e) - shape.sdf(POINTS - h * e)) / (2 * h) for e in np.eye(2)], -1)
    return np.mean(np.abs(np.linalg.norm(grad, axis=-1) - 1) < 0.02)


SHAPES = [
    geo.Disk((0.5, -0.3), 1.2),
    geo.Box((0.2, 0.1), (1.0, 0.5), 0.4),
    geo.Ellipse((-0.5, 0.5), (1.5, 0.7), 0.3),
    geo.Polygon(((-1.0, -1.0), (1.5, -0.5), (0.5, 1.5), (-0.8, 0.7))),
    geo.ClosedSpline(((1.0, 0.0), (0.2, 1.1), (-1.0, 0.3), (-0.7, -0.9), (0.4, -1.2))),
]


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: type(s).__name__)
def test_shapes_sign_and_unit_gradient(shape):
    inner = getattr(shape, "vertices", getattr(shape, "points", None))
    centre = np.asarray(shape.center if inner is None else np.mean(inner, 0))
    assert shape.sdf(centre[None])[0] < 0
    assert shape.sdf(np.array([[30.0, 30.0]]))[0] > 25
    assert unit_gradient_fraction(shape) > 0.97
    assert shape.reach() >= np.max(np.hypot(*POINTS[shape.sdf(POINTS) <= 0].T))
    assert geo.shape_from_dict(shape.as_dict()).sdf(POINTS[:10]).tolist() == shape.sdf(POINTS[:10]).tolist()


def test_closed_forms_agree():
    disk, circle_as_ellipse = geo.Disk((0.3, 0.2), 1.0), geo.Ellipse((0.3, 0.2), (1.0, 1.0))
    assert np.abs(disk.sdf(POINTS) - circle_as_ellipse.sdf(POINTS)).max() < 1e-4
    box = geo.Box((0.0, 0.0), (1.0, 0.5))
    square = geo.Polygon(((-1.0, -0.5), (1.0, -0.5), (1.0, 0.5), (-1.0, 0.5)))
    assert np.abs(box.sdf(POINTS) - square.sdf(POINTS)).max() < 1e-12
    ring = [(np.cos(a), np.sin(a)) for a in np.linspace(0, 2 * np.pi, 16, endpoint=False)]
    assert np.abs(geo.ClosedSpline(tuple(ring)).sdf(POINTS) - geo.Disk((0, 0), 1).sdf(POINTS)).max() < 1e-3


def test_occupancy_signed_distance_is_resolution_and_origin_aware():
    res, origin = 0.05, (-2.0, 1.0)
    occ = np.zeros((80, 60), np.int8)  # [ix, iy]: 4 m x 3 m
    occ[30:40, 20:30] = 100  # a 0.5 m square at x in [-0.5, 0), y in [2, 2.5)
    sd = geo.occupancy_signed_distance(occ, res, unknown_is_obstacle=False)  # the square alone, not the map's edge
    # A point 1 m to the right of the square's right edge is 1 m away (within a cell).
    p = np.array([[0.0 + 1.0, 2.25]])
    assert abs(geo.sample_raster(sd, origin, res, p)[0] - 1.0) < res
    assert geo.sample_raster(sd, origin, res, np.array([[-0.25, 2.25]]))[0] < -0.2
    square = geo.Box((-0.25, 2.25), (0.25, 0.25))
    cells = origin + (np.stack(np.meshgrid(np.arange(80), np.arange(60), indexing="ij"), -1) + 0.5) * res
    assert np.abs(sd - square.sdf(cells)).max() < 0.75 * res


def test_unknown_cells_and_thresholds():
    occ = np.zeros((20, 20), np.int16)
    occ[5, 5] = -1
    occ[15, 15] = 40
    assert geo.occupancy_to_mask(occ)[5, 5]
    assert not geo.occupancy_to_mask(occ, unknown_is_obstacle=False)[5, 5]
    assert not geo.occupancy_to_mask(occ)[15, 15]
    assert geo.occupancy_to_mask(occ, occupied_threshold=30)[15, 15]
    assert np.all(geo.occupancy_signed_distance(np.zeros((4, 4), np.int8), 0.1) > 0)


@pytest.mark.parametrize("bad, message", [
    (np.zeros((0, 3), np.int8), "non-empty"),
    (np.zeros((3, 3, 3), np.int8), "2-D"),
    (np.full((3, 3), 120, np.int16), "-1..100"),
    (np.zeros((3, 3), np.float32), "integers"),
])
def test_bad_occupancy_is_rejected(bad, message):
    with pytest.raises(ValueError, match=message):
        geo.occupancy_signed_distance(bad, 0.05)


def test_bad_resolution_and_shapes_are_rejected():
    with pytest.raises(ValueError, match="spacing"):
        geo.occupancy_signed_distance(np.zeros((3, 3), np.int8), float("nan"))
    with pytest.raises(ValueError, match="radius > 0"):
        geo.Disk((0, 0), -1.0)
    with pytest.raises(ValueError, match="half sizes"):
        geo.Box((0, 0), (0.0, 1.0))
    with pytest.raises(ValueError, match="unknown shape"):
        geo.shape_from_dict({"type": "blob"})


def test_air3d_collision_of_circles_is_distance_minus_radii():
    grid = air3d_grid((41, 32, 24))
    l_ = geo.air3d_collision_sdf(geo.Disk((0, 0), 1.0), geo.Disk((0, 0), 1.5), grid)
    s = grid.states()
    exact = np.hypot(s[..., 0], s[..., 1]) - 2.5
    h = min(grid.spacings[:2]) / 4
    assert np.abs(l_ - exact).max() <= 1.5 * h


def test_air3d_collision_of_boxes_depends_on_heading():
    grid = air3d_grid((53, 41, 24))  # nodes at x = 2.5 m and y = 0
    rod = geo.Box((0.0, 0.0), (2.0, 0.2))
    l_ = geo.air3d_collision_sdf(rod, rod, grid)
    # Pursuer 2.5 m ahead on the x axis: parallel rods (psi = 0) overlap, crossed rods (psi = pi/2) do not.
    psi = grid.axis(2)
    i0 = np.argmin(np.abs(psi))
    i90 = np.argmin(np.abs(psi - np.pi / 2))
    ix = np.argmin(np.abs(grid.axis(0) - 2.5))
    iy = np.argmin(np.abs(grid.axis(1) - 0.0))
    assert l_[ix, iy, i0] < -0.25 and abs(l_[ix, iy, i90] - 0.3) < 0.15


def test_car_grid_axes_follow_the_convention():
    g = car_grid((10, 8, 5, 6))
    s = g.states()
    assert s.shape == (10, 8, 5, 6, 4)
    assert s[1, 0, 0, 0, 0] > s[0, 0, 0, 0, 0] and s[0, 1, 0, 0, 1] > s[0, 0, 0, 0, 1]
    assert g.axis(3)[0] == pytest.approx(-np.pi) and g.axis(3)[-1] < np.pi


def test_grid_target_minus_half_cell_diagonal_is_conservative():
    """l sampled at grid nodes and interpolated overestimates the exact clearance near a clutter box
    smaller than a cell (room indoor/3000313 on the 32 x 32 datasets' grid: V∞ came out > 0 inside it);
    since l is 1-Lipschitz, l − h/√2 interpolates below the exact clearance everywhere."""
    from hjrno_ros.core.value_table import ValueTable
    from hjrno_ros.truth.scenarios import make_scenario

    room = make_scenario("indoor", 3000313)
    grid = room.grid((32, 32, 3, 4))
    r = grid.half_cell_diagonal
    assert r == pytest.approx(max(grid.spacings[:2]) / 2 ** 0.5)  # square cells: h/√2
    xs = np.linspace(-5, 5, 301)
    pts = np.stack(np.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    states = np.column_stack([pts, np.full(len(pts), 0.5), np.zeros(len(pts))])
    exact = geo.union_sdf(room.shapes, pts)
    plain, inflated = (ValueTable(grid, room.target(grid) - np.float32(c)).value(states) - exact for c in (0.0, r))
    assert plain[exact <= 0].max() > 0.15  # free in the table, inside an obstacle in fact
    assert inflated.max() <= 1e-5
