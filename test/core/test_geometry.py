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


def test_the_fast_distance_transform_is_scipys():
    """The map path's transform (``edt``, in the node's requirements) equals scipy's, to float32 rounding."""
    import edt  # noqa: F401  (installed: the node's maps take the fast path)
    from scipy import ndimage

    rng = np.random.default_rng(4)
    for shape, density in (((120, 90), 0.02), ((64, 64), 0.5), ((1, 50), 0.1), ((30, 1), 0.9)):
        mask = rng.random(shape) < density
        mask[0, 0], mask[-1, -1] = True, False
        ours = geo.distance_to_false(mask)
        assert ours.dtype == np.float64 and ours.shape == shape
        np.testing.assert_allclose(ours, ndimage.distance_transform_edt(mask), rtol=1e-6, atol=1e-4)
    assert not geo.distance_to_false(np.zeros((5, 5), bool)).any()


def test_raster_samples_are_scipys_bilinear_nearest_beyond_and_nan_for_nan_points():
    from scipy import ndimage

    rng = np.random.default_rng(5)
    for shape in ((40, 30), (1, 6), (6, 1), (1, 1)):
        raster = rng.normal(size=shape)
        points = rng.uniform(-1.0, 3.0, (400, 2))
        ij = np.clip(((points - (0.2, -0.1)) / 0.07 - 0.5).T, 0.0, np.array(shape)[:, None] - 1.0)
        want = ndimage.map_coordinates(raster, ij, order=1, mode="nearest")
        np.testing.assert_allclose(geo.sample_raster(raster, (0.2, -0.1), 0.07, points), want, atol=1e-12)
    out = geo.sample_raster(np.ones((5, 5)), (0.0, 0.0), 0.1, np.array([[np.nan, 0.2], [0.2, 0.2]]))
    assert np.isnan(out[0]) and out[1] == 1.0


def test_union_inside_is_the_union_distance_sign_on_a_lattice():
    shapes = [geo.Disk((0.3, 0.2), 0.4), geo.Box((-1.0, 1.0), (0.8, 0.05), 0.3),
              geo.Ellipse((1.2, -0.9), (0.5, 0.2), 1.0), geo.Polygon(((-1.5, -1.5), (-0.5, -1.2), (-1.1, -0.4))),
              geo.ClosedSpline(((0.8, 0.8), (1.6, 0.9), (1.5, 1.6), (0.9, 1.4)))]
    x, y = np.linspace(-2.0, 2.0, 123), np.linspace(-2.0, 2.0, 77)  # neither a multiple of the block
    points = np.stack(np.meshgrid(x, y, indexing="ij"), -1)
    inside = geo.union_inside(shapes, points, block=8)
    assert inside.shape == (123, 77) and inside.sum() > 500
    np.testing.assert_array_equal(inside, geo.union_sdf(shapes, points) <= 0)


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


# ------------------------------------------------------------------------------------------ beyond the map's edge
EDGE_RES, EDGE_ORIGIN, EDGE_SHAPE = 0.1, (-1.0, 0.5), (30, 20)  # the map [-1, 2] x [0.5, 2.5]
EDGE_HI = (EDGE_ORIGIN[0] + EDGE_SHAPE[0] * EDGE_RES, EDGE_ORIGIN[1] + EDGE_SHAPE[1] * EDGE_RES)


def walled(occ: np.ndarray, points) -> np.ndarray:
    sd = geo.occupancy_signed_distance(occ, EDGE_RES)  # unknown_is_obstacle: the edge is a wall
    return geo.sample_walled(sd, EDGE_ORIGIN, EDGE_RES, np.asarray(points, float))


def test_beyond_a_free_edge_the_value_is_minus_the_distance_to_the_map():
    """A free map: beyond each side the value falls linearly, −d at d from the edge; beyond a corner it is minus
    the Euclidean distance to the corner; at the edge 0 (the wall's side), from the outermost centres' ½ cell."""
    free = np.zeros(EDGE_SHAPE, np.int8)
    d = np.array([0.0, 0.01, 0.05, 0.1, 0.37, 1.0, 2.5])
    mid_y = 1.5
    left = walled(free, np.column_stack([EDGE_ORIGIN[0] - d, np.full_like(d, mid_y)]))
    top = walled(free, np.column_stack([np.full_like(d, 0.3), EDGE_HI[1] + d]))
    np.testing.assert_allclose(left, -d, atol=1e-9)
    np.testing.assert_allclose(top, -d, atol=1e-9)
    corner = np.array([[EDGE_HI[0] + 0.3, EDGE_ORIGIN[1] - 0.4], [EDGE_ORIGIN[0] - 1.2, EDGE_HI[1] + 0.5]])
    np.testing.assert_allclose(walled(free, corner), [-0.5, -1.3], atol=1e-9)
    # from the outermost centre (½ cell in, value ½ cell) down to 0 at the edge, then on down: one straight line
    x = EDGE_ORIGIN[0] + np.linspace(0.5, -1.0, 61) * EDGE_RES
    line = walled(free, np.column_stack([x, np.full_like(x, mid_y)]))
    np.testing.assert_allclose(line, x - EDGE_ORIGIN[0], atol=1e-9)


def test_beyond_the_edge_is_the_walled_worlds_signed_distance():
    """Random obstacles, some on the edge: beyond the map the value is that of the world walled all around
    (the occupancy padded with 30 occupied cells, its own distance transform) within a cell, where the −resolution
    plateau was up to 3 m off; it is continuous across the edge, never rises outward, is ≤ 0 and ≤ its value at the
    edge, and from one cell out it is at or below the old plateau."""
    rng = np.random.default_rng(5)
    occ = np.where(rng.random(EDGE_SHAPE) < 0.15, 100, 0).astype(np.int8)
    pad = 30
    world = geo.signed_distance_from_mask(np.pad(occ >= 50, pad, constant_values=True), EDGE_RES)
    world_origin = (EDGE_ORIGIN[0] - pad * EDGE_RES, EDGE_ORIGIN[1] - pad * EDGE_RES)
    lo, hi = np.asarray(EDGE_ORIGIN), np.asarray(EDGE_HI)
    pts = rng.uniform(lo - 2.5, hi + 2.5, (20000, 2))
    outside = np.any((pts < lo) | (pts > hi), -1)
    distance = np.hypot(*np.maximum(np.maximum(lo - pts, pts - hi), 0).T)  # to the map's rectangle
    got = walled(occ, pts)
    truth = geo.sample_raster(world, world_origin, EDGE_RES, pts)
    sd = geo.occupancy_signed_distance(occ, EDGE_RES)
    plateau = geo.sample_raster(sd, EDGE_ORIGIN, EDGE_RES, pts, outside=-EDGE_RES)
    assert np.abs(got - truth)[outside].max() <= EDGE_RES
    assert np.abs(plateau - truth)[outside].max() > 2.0  # what the plateau did
    assert np.all(got[outside] <= -distance[outside] + 1e-12)
    assert np.all(got[distance >= EDGE_RES] <= plateau[distance >= EDGE_RES])
    on_edge = np.clip(pts, lo, hi)  # each point's nearest point of the map's edge (for the outside ones)
    assert np.all(got[outside] <= walled(occ, on_edge)[outside] + 1e-12)
    # along outward rays from the outermost centres across the edge: continuous, never rising
    t = np.linspace(0.0, 3.0, 301) * EDGE_RES  # 0.01 cell steps, from the centre to 2.5 cells out
    for ix, iy in [(0, 3), (0, 11), (29, 7), (29, 19), (12, 0), (5, 19)]:
        centre = lo + (np.array([ix, iy]) + 0.5) * EDGE_RES
        out = np.array([-1.0 if ix == 0 else 1.0 if ix == 29 else 0.0, -1.0 if iy == 0 else 1.0 if iy == 19 else 0.0])
        ray = walled(occ, centre + t[:, None] * out / np.linalg.norm(out))
        assert ray[0] == pytest.approx(sd[ix, iy]) and np.all(np.diff(ray) <= 1e-12), (ix, iy)
        assert np.abs(np.diff(ray)).max() <= np.sqrt(2) * (t[1] - t[0]) + 1e-12, (ix, iy)


def test_sample_walled_keeps_the_inside_and_far_points():
    """Within the outermost centres it is sample_raster; far and infinite points are far inside the wall."""
    sd = geo.occupancy_signed_distance(np.zeros(EDGE_SHAPE, np.int8), EDGE_RES)
    inner = np.asarray(EDGE_ORIGIN) + RNG.uniform(0.5, np.array(EDGE_SHAPE) - 0.5, (500, 2)) * EDGE_RES
    np.testing.assert_array_equal(geo.sample_walled(sd, EDGE_ORIGIN, EDGE_RES, inner),
                                  geo.sample_raster(sd, EDGE_ORIGIN, EDGE_RES, inner))
    far = geo.sample_walled(sd, EDGE_ORIGIN, EDGE_RES, np.array([[-1e20, 1.0], [np.inf, 1.0], [0.0, -np.inf]]))
    assert far[0] == pytest.approx(-1e20) and far[1] == far[2] == -np.inf
    huge = np.broadcast_to(np.float32(0.025), (100_000, 100_000))  # a zero-stride view: whole, it would be 80 GB
    window = np.stack(np.meshgrid(np.linspace(-5, 5, 32), np.linspace(200, 210, 32), indexing="ij"), -1)
    got = geo.sample_walled(huge, (0.0, 0.0), 0.05, window)
    np.testing.assert_allclose(got, np.minimum(0.025, window[..., 0]), atol=1e-7)
