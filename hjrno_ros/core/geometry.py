"""Signed distance l(x, y): positive outside obstacles, ≤ 0 inside, |∇l| ≈ 1 away from kinks.

Two sources: shapes (exact or densely sampled boundaries, evaluated at any points) and
rasters (occupancy grids, masks), via an exact Euclidean distance transform (the ``edt`` package where installed,
2-4 times faster than scipy's on a map, else scipy's: the same distances) with the boundary half a cell between
occupied and free cells; numpy alone otherwise, so that the node, which has ``edt``, loads no scipy (docs/node.md).
Rasters are indexed ``[ix, iy]`` (x first, docs/design.md, "Conventions"); cell (ix, iy) has its centre at
origin + (ix + ½, iy + ½)·resolution.
Points are arrays ``(..., 2)`` of (x, y) in metres.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from hjrno_ros.core.grids import GridSpec

_BOUNDARY_SAMPLES = 720  # vertices used for curved boundaries (ellipse, spline)


class Shape(Protocol):
    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance at points (..., 2)."""

    def reach(self) -> float:
        """Largest distance from the origin to a point of the shape (bounds rasters)."""

    def as_dict(self) -> dict: ...


def _finite(*values: float) -> bool:
    return all(math.isfinite(float(v)) for v in np.ravel(values))


def _rotate(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.stack([c * points[..., 0] - s * points[..., 1], s * points[..., 0] + c * points[..., 1]], axis=-1)


def polygon_sdf(points: np.ndarray, vertices: np.ndarray, block: int = 4096) -> np.ndarray:
    """Exact signed distance to a simple closed polygon (vertices ``(N, 2)``, either orientation)."""
    pts = np.asarray(points, float)
    flat = pts.reshape(-1, 2)
    out = np.concatenate([_polygon_sdf_flat(flat[i:i + block], np.asarray(vertices, float))
                          for i in range(0, len(flat), block)] or [np.zeros(0)])
    return out.reshape(pts.shape[:-1])


def _polygon_sdf_flat(p: np.ndarray, a: np.ndarray) -> np.ndarray:
    p = p[:, None, :]  # (M, 1, 2) against edges a → b, (N, 2)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-300), 0.0, 1.0)
    dist = np.sqrt(np.min(np.sum((p - (a + t[..., None] * ab)) ** 2, -1), axis=-1))
    py, px = p[..., 1], p[..., 0]  # even-odd rule: edges crossed by a ray in +x
    crosses = (a[:, 1] > py) != (b[:, 1] > py)
    x_at = a[:, 0] + (py - a[:, 1]) * ab[:, 0] / np.where(ab[:, 1] == 0, 1.0, ab[:, 1])
    inside = np.sum(crosses & (px < x_at), axis=-1) % 2 == 1
    return np.where(inside, -dist, dist)


@dataclasses.dataclass(frozen=True)
class Disk:
    center: tuple[float, float]
    radius: float

    def __post_init__(self):
        if not (_finite(*self.center, self.radius) and self.radius > 0):
            raise ValueError(f"disk needs a finite centre and radius > 0, got {self}")

    def sdf(self, points):
        return np.hypot(points[..., 0] - self.center[0], points[..., 1] - self.center[1]) - self.radius

    def reach(self) -> float:
        return float(np.hypot(*self.center) + self.radius)

    def as_dict(self):
        return {"type": "disk", "center": list(self.center), "radius": self.radius}


@dataclasses.dataclass(frozen=True)
class Box:
    """Rectangle with half side lengths ``half_size``, rotated by ``angle`` about its centre."""

    center: tuple[float, float]
    half_size: tuple[float, float]
    angle: float = 0.0

    def __post_init__(self):
        if not (_finite(*self.center, *self.half_size, self.angle) and min(self.half_size) > 0):
            raise ValueError(f"box needs finite values and half sizes > 0, got {self}")

    def sdf(self, points):
        local = np.abs(_rotate(np.asarray(points, float) - np.asarray(self.center), -self.angle))
        q = local - np.asarray(self.half_size)
        outside = np.hypot(np.maximum(q[..., 0], 0), np.maximum(q[..., 1], 0))
        return outside + np.minimum(np.maximum(q[..., 0], q[..., 1]), 0.0)

    def reach(self) -> float:
        return float(np.hypot(*self.center) + np.hypot(*self.half_size))

    def as_dict(self):
        return {"type": "box", "center": list(self.center), "half_size": list(self.half_size), "angle": self.angle}


@dataclasses.dataclass(frozen=True)
class Polygon:
    vertices: tuple[tuple[float, float], ...]

    def __post_init__(self):
        v = np.asarray(self.vertices, float)
        if v.ndim != 2 or v.shape[0] < 3 or v.shape[1] != 2 or not np.all(np.isfinite(v)):
            raise ValueError("polygon needs at least 3 finite (x, y) vertices")
        object.__setattr__(self, "vertices", tuple(map(tuple, v.tolist())))

    def sdf(self, points):
        return polygon_sdf(points, np.asarray(self.vertices))

    def reach(self) -> float:
        return float(np.max(np.hypot(*np.asarray(self.vertices).T)))

    def as_dict(self):
        return {"type": "polygon", "vertices": [list(v) for v in self.vertices]}


@dataclasses.dataclass(frozen=True)
class Ellipse:
    center: tuple[float, float]
    semi_axes: tuple[float, float]
    angle: float = 0.0

    def __post_init__(self):
        if not (_finite(*self.center, *self.semi_axes, self.angle) and min(self.semi_axes) > 0):
            raise ValueError(f"ellipse needs finite values and semi-axes > 0, got {self}")

    def boundary(self, n: int = _BOUNDARY_SAMPLES) -> np.ndarray:
        s = np.linspace(0, 2 * np.pi, n, endpoint=False)
        local = np.stack([self.semi_axes[0] * np.cos(s), self.semi_axes[1] * np.sin(s)], -1)
        return _rotate(local, self.angle) + np.asarray(self.center)

    def sdf(self, points):
        return polygon_sdf(points, self.boundary())

    def reach(self) -> float:
        return float(np.hypot(*self.center) + max(self.semi_axes))

    def as_dict(self):
        return {"type": "ellipse", "center": list(self.center), "semi_axes": list(self.semi_axes), "angle": self.angle}


@dataclasses.dataclass(frozen=True)
class ClosedSpline:
    """Region bounded by the periodic cubic B-spline through ``points`` (in order around it)."""

    points: tuple[tuple[float, float], ...]

    def __post_init__(self):
        v = np.asarray(self.points, float)
        if v.ndim != 2 or v.shape[0] < 4 or v.shape[1] != 2 or not np.all(np.isfinite(v)):
            raise ValueError("closed spline needs at least 4 finite (x, y) points")
        object.__setattr__(self, "points", tuple(map(tuple, v.tolist())))

    def boundary(self, n: int = _BOUNDARY_SAMPLES) -> np.ndarray:
        v = np.asarray(self.points)
        closed = np.vstack([v, v[:1]])
        from scipy import interpolate  # offline shapes only: the node never loads it

        tck, _ = interpolate.splprep([closed[:, 0], closed[:, 1]], s=0, per=1, k=3)
        x, y = interpolate.splev(np.linspace(0, 1, n, endpoint=False), tck)
        return np.stack([x, y], -1)

    def sdf(self, points):
        return polygon_sdf(points, self.boundary())

    def reach(self) -> float:
        return float(np.max(np.hypot(*self.boundary().T)))

    def as_dict(self):
        return {"type": "spline", "points": [list(p) for p in self.points]}


_SHAPES = {"disk": Disk, "box": Box, "polygon": Polygon, "ellipse": Ellipse, "spline": ClosedSpline}


def shape_from_dict(d: dict) -> Shape:
    """Inverse of ``shape.as_dict()``."""
    kind = d.get("type")
    if kind not in _SHAPES:
        raise ValueError(f"unknown shape type {kind!r}; known: {sorted(_SHAPES)}")
    args = {k: (tuple(map(tuple, v)) if k in ("vertices", "points") else tuple(v) if isinstance(v, list) else v)
            for k, v in d.items() if k != "type"}
    return _SHAPES[kind](**args)


def union_sdf(shapes: Sequence[Shape], points: np.ndarray) -> np.ndarray:
    """Signed distance to the union of shapes (min of the parts; exact outside, a bound inside overlaps)."""
    if not shapes:
        raise ValueError("need at least one shape")
    return np.minimum.reduce([s.sdf(points) for s in shapes])


def union_inside(shapes: Sequence[Shape], points: np.ndarray, block: int = 8) -> np.ndarray:
    """Whether each node of a lattice of ``points`` ``(nx, ny, 2)`` lies in the union of ``shapes`` (signed distance
    ≤ 0), as ``union_sdf(shapes, points) <= 0`` but cheaper: each shape's distance is read at the centres of blocks
    of ``block`` × ``block`` nodes first, and since it is 1-Lipschitz a block whose centre reads more than the
    block's radius lies wholly outside that shape.  A floor plan's mask then costs its shapes' areas, not every
    node against every shape."""
    pts = np.asarray(points, float)
    nx, ny = pts.shape[:2]
    padded = np.pad(pts, ((0, -nx % block), (0, -ny % block), (0, 0)), mode="edge")  # repeats real nodes
    tiles = padded.reshape(padded.shape[0] // block, block, padded.shape[1] // block, block, 2).swapaxes(1, 2)
    centres = tiles.mean((2, 3))
    radius = np.linalg.norm(tiles - centres[:, :, None, None], axis=-1).max((2, 3))
    out = np.zeros((nx, ny), bool)
    for shape in shapes:
        near = np.repeat(np.repeat(shape.sdf(centres) <= radius, block, 0), block, 1)[:nx, :ny]
        near &= ~out
        out[near] = shape.sdf(pts[near]) <= 0
    return out


# ---------------------------------------------------------------------------------------------
# Rasters.


def signed_distance_from_mask(mask: np.ndarray, spacing: float) -> np.ndarray:
    """Signed distance at cell centres of a boolean obstacle raster; boundary half a cell out."""
    mask = np.asarray(mask, bool)
    if mask.ndim != 2 or mask.size == 0:
        raise ValueError(f"need a non-empty 2-D mask, got shape {mask.shape}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"raster spacing must be finite and > 0, got {spacing}")
    big = float(np.hypot(*mask.shape) * spacing)
    if not mask.any():
        return np.full(mask.shape, big)
    if mask.all():
        return np.full(mask.shape, -big)
    outside = distance_to_false(~mask) * spacing - 0.5 * spacing
    inside = distance_to_false(mask) * spacing - 0.5 * spacing
    return np.where(mask, -inside, outside)


def distance_to_false(mask: np.ndarray) -> np.ndarray:
    """Euclidean distance (cells) from each True cell's centre to the nearest False cell's centre, 0 on False cells:
    ``edt`` where installed (the node's map path: docs/node.md, "Map to value table"), else scipy's transform."""
    try:
        import edt
    except ImportError:
        from scipy import ndimage

        return ndimage.distance_transform_edt(mask)
    return edt.edt(np.ascontiguousarray(mask), black_border=False, parallel=1).astype(np.float64)


def occupancy_to_mask(occupancy: np.ndarray, occupied_threshold: int = 50, unknown_is_obstacle: bool = True):
    """Obstacle mask of an occupancy raster ``[ix, iy]`` with values −1 (unknown) or 0..100."""
    occ = np.asarray(occupancy)
    if occ.ndim != 2 or occ.size == 0:
        raise ValueError(f"occupancy grid must be a non-empty 2-D array, got shape {occ.shape}")
    if not np.issubdtype(occ.dtype, np.integer):
        raise ValueError(f"occupancy values must be integers in -1..100, got dtype {occ.dtype}")
    if occ.min() < -1 or occ.max() > 100:
        raise ValueError(f"occupancy values must lie in -1..100, got range [{occ.min()}, {occ.max()}]")
    if not 0 <= occupied_threshold <= 100:
        raise ValueError(f"occupied_threshold must lie in 0..100, got {occupied_threshold}")
    unknown = occ < 0
    return np.where(unknown, unknown_is_obstacle, occ >= occupied_threshold)


def occupancy_signed_distance(
    occupancy: np.ndarray, resolution: float, occupied_threshold: int = 50, unknown_is_obstacle: bool = True
) -> np.ndarray:
    """Signed distance (m, float32) at the cell centres of an occupancy raster ``[ix, iy]``.

    With ``unknown_is_obstacle`` the space beyond the map is unknown, hence an obstacle: the map's outer
    edge bounds the distance (a one-cell occupied border is added before the distance transform)."""
    mask = occupancy_to_mask(occupancy, occupied_threshold, unknown_is_obstacle)
    if not unknown_is_obstacle:
        return signed_distance_from_mask(mask, resolution).astype(np.float32)
    padded = np.pad(mask, 1, constant_values=True)
    return signed_distance_from_mask(padded, resolution)[1:-1, 1:-1].astype(np.float32)


def sample_raster(raster: np.ndarray, origin: tuple[float, float], resolution: float, points: np.ndarray,
                  outside: float | None = None) -> np.ndarray:
    """Bilinear samples of a cell-centred raster ``[ix, iy]`` at ``points`` (..., 2).

    Points beyond the outermost cell centres take the nearest value, or ``outside`` when given; a NaN point gives
    NaN.  Only the
    block of cells the points touch is read, so the cost follows the points, not the raster's size.
    """
    pts = np.asarray(points, float)
    ij = (pts - np.asarray(origin, float)) / resolution - 0.5
    coords = np.moveaxis(ij, -1, 0).reshape(2, -1)
    n = np.asarray(raster.shape)
    coords = np.clip(coords, 0.0, (n - 1)[:, None])  # "nearest" beyond the outermost centres; no int overflow
    finite = np.isfinite(coords).all(0)
    if finite.any():
        lo = np.floor(coords[:, finite].min(1)).astype(int)
        hi = np.minimum(np.floor(coords[:, finite].max(1)).astype(int) + 2, n)
    else:
        lo, hi = np.zeros(2, int), np.minimum(n, 1)
    block = np.asarray(raster[lo[0]:hi[0], lo[1]:hi[1]], float)
    out = np.where(finite, _bilinear(block, np.where(finite, coords - lo[:, None], 0.0)), np.nan)
    out = out.reshape(pts.shape[:-1])
    if outside is not None:
        beyond = np.any((ij < -0.5) | (ij > n - 0.5), axis=-1)
        out = np.where(beyond, outside, out)
    return out


def _bilinear(block: np.ndarray, ij: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``block`` at fractional indices ``ij`` (2, N) inside [0, shape − 1]."""
    n = np.asarray(block.shape)[:, None]
    i0 = np.minimum(np.floor(ij).astype(int), np.maximum(n - 2, 0))
    i1 = np.minimum(i0 + 1, n - 1)
    t = ij - i0
    return ((1 - t[0]) * ((1 - t[1]) * block[i0[0], i0[1]] + t[1] * block[i0[0], i1[1]])
            + t[0] * ((1 - t[1]) * block[i1[0], i0[1]] + t[1] * block[i1[0], i1[1]]))


def sample_walled(sd: np.ndarray, origin: tuple[float, float], resolution: float, points: np.ndarray) -> np.ndarray:
    """Bilinear samples of a signed-distance raster ``sd`` ``[ix, iy]`` at ``points`` (..., 2), with everything
    beyond the map's rectangle [origin, origin + shape·resolution] a wall.

    Beyond the rectangle a point takes minus its Euclidean distance to it (lower still past an occupied edge cell,
    by that cell's depth): the signed distance of that world, where :func:`sample_raster`'s constant ``outside``
    is a plateau the operator never saw in training (docs/results.md, "The map's edge").  Between the outermost
    cell centres and the edge the value falls by the (Chebyshev) distance past the centres, to 0 on a free edge
    cell's outer side, so the join is continuous and never rises outward.  Meant for a raster that already walls
    the edge (:func:`occupancy_signed_distance` with ``unknown_is_obstacle``: ≤ ½·resolution at the outermost
    centres); for any raster the value beyond the edge is ≤ 0 and ≤ that at the edge.  Cost follows the points.
    """
    pts = np.asarray(points, float)
    half = 0.5 * resolution
    first = np.asarray(origin, float) + half
    nearest = np.clip(pts, first, first + (np.asarray(sd.shape) - 1) * resolution)  # the outermost centres' box
    past = np.abs(pts - nearest)  # per axis, beyond the outermost centres
    band = np.minimum(past, half)  # the part within the map's rectangle
    beyond = np.hypot(*np.moveaxis(past - band, -1, 0))  # the distance to the map's rectangle
    out = sample_raster(sd, origin, resolution, nearest) - band.max(-1) - beyond
    return np.where(beyond > 0, np.minimum(out, -beyond), out)


def rasterize(shape: Shape, origin: tuple[float, float], spacing: float, size: tuple[int, int]) -> np.ndarray:
    """Obstacle mask ``[ix, iy]`` of a shape on a cell-centred raster."""
    x = origin[0] + (np.arange(size[0]) + 0.5) * spacing
    y = origin[1] + (np.arange(size[1]) + 0.5) * spacing
    return shape.sdf(np.stack(np.meshgrid(x, y, indexing="ij"), -1)) <= 0


# ---------------------------------------------------------------------------------------------
# Air3D: collision of two planar agents as a function of the relative state (x, y, ψ).


def air3d_collision_sdf(evader: Shape, pursuer: Shape, grid: GridSpec, supersample: int = 4) -> np.ndarray:
    """l(x, y, ψ) on an Air3D grid: signed distance between the evader (at the origin, heading 0)
    and the pursuer (at (x, y), heading ψ), both given in their own body frames.

    The agents touch iff p ∈ E ⊕ (−R(ψ)P); l is the signed distance of p to that Minkowski sum,
    which is the separation distance outside and the penetration depth inside.  The sum is
    rasterised by convolution at ``supersample`` times the grid's finest x-y spacing, so l is
    exact up to about that raster's spacing.
    """
    if grid.ndim != 3 or grid.periodic != (2,):
        raise ValueError("air3d_collision_sdf needs an (x, y, psi) grid with psi periodic")
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    h = min(grid.spacings[:2]) / supersample
    lo = np.asarray(grid.lo[:2]) - 2 * h
    size = tuple(int(np.ceil((grid.hi[i] - grid.lo[i]) / h)) + 4 for i in range(2))
    evader_mask = rasterize(evader, tuple(lo), h, size)
    if not evader_mask.any():
        raise ValueError("the evader shape does not cover any raster cell inside the grid")
    nodes = grid.states()[:, :, 0, :2]
    out = np.empty(grid.shape, np.float32)
    for k, psi in enumerate(grid.axis(2)):
        kernel = _reflected_rotated_kernel(pursuer, psi, h)
        from scipy import signal  # Air3D targets only

        dilated = signal.fftconvolve(evader_mask.astype(float), kernel, mode="same") > 0.5
        sd = signed_distance_from_mask(dilated, h)
        out[:, :, k] = sample_raster(sd, tuple(lo), h, nodes)
    return out


def _reflected_rotated_kernel(shape: Shape, psi: float, h: float) -> np.ndarray:
    """Mask of −R(ψ)·shape on an odd-sized raster centred on the origin (cell centres at k·h)."""
    half = int(np.ceil(shape.reach() / h)) + 1
    k = np.arange(-half, half + 1) * h
    pts = np.stack(np.meshgrid(k, k, indexing="ij"), -1)
    body = _rotate(-pts, -psi)  # q with −R(ψ) q = pts  ⇔  q = −R(−ψ) pts
    return (shape.sdf(body) <= 0).astype(float)
