"""Random and map-like shapes the scenario families draw from (numpy + scipy, no solver).

Coordinates are the car families' window: [DOMAIN_LO, DOMAIN_HI]² (m, or model units for the
product scenes, docs/design.md "Similarity").
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import ConvexHull

from hjrno_ros.core.geometry import Box, ClosedSpline, Disk, Ellipse, Shape, shape_from_dict

DOMAIN_LO, DOMAIN_HI = -5.0, 5.0  # car families: the x-y window [-5, 5]²
ROUNDNESS = 0.6  # random smooth shapes: polar radii drawn in [ROUNDNESS·R, R]
N_ANGLES = 8  # polar samples of a random smooth shape


def random_smooth_shape(
    rng: np.random.Generator, center: tuple[float, float], radius_range: tuple[float, float], n_angles: int = N_ANGLES
) -> ClosedSpline:
    """Smooth random blob: radii in ``radius_range`` at evenly spaced (randomly offset) angles,
    their convex hull, and the closed cubic spline through the hull points.

    The boundary stays within ``radius_range[1]`` of ``center`` (the spline is scaled down if it
    overshoots), so a blob placed ≥ R from the domain edge is inside the domain.
    """
    lo, hi = (float(r) for r in radius_range)
    if not (0 < lo <= hi and math.isfinite(hi)):
        raise ValueError(f"radius_range must satisfy 0 < lo <= hi < inf, got {radius_range}")
    if n_angles < 5:
        raise ValueError(f"n_angles must be >= 5 (the spline needs >= 4 hull points), got {n_angles}")
    step = 2 * math.pi / n_angles
    for _ in range(100):
        angles = rng.uniform(0.0, step) + step * np.arange(n_angles)
        pts = rng.uniform(lo, hi, n_angles)[:, None] * np.stack([np.cos(angles), np.sin(angles)], -1)
        hull = ConvexHull(pts).vertices  # counter-clockwise in 2-D
        if len(hull) >= 4:
            break
    else:  # only reachable with an extreme radius ratio
        raise ValueError(f"could not draw a shape with >= 4 hull points from radius_range {radius_range}")
    pts = pts[hull]
    reach = float(np.max(np.hypot(*ClosedSpline(pts).boundary().T)))
    if reach > hi:
        pts = pts * (hi / reach * (1 - 1e-9))
    return ClosedSpline(pts + np.asarray(center, float))


def segment_box(a: tuple[float, float], b: tuple[float, float], thickness: float) -> Box:
    """Axis-aligned wall of ``thickness`` from point a to point b (same x or same y)."""
    (xa, ya), (xb, yb) = a, b
    half = (abs(xb - xa) / 2, thickness / 2) if ya == yb else (thickness / 2, abs(yb - ya) / 2)
    return Box(((xa + xb) / 2, (ya + yb) / 2), half)


def clutter_item(rng: np.random.Generator, center: np.ndarray, size: float) -> Shape:
    """A box, disk or ellipse within ``size`` of ``center``."""
    kind = ("box", "disk", "ellipse")[int(rng.integers(3))]
    u, angle = rng.uniform(0.5, 1.0, 2), float(rng.uniform(-math.pi, math.pi))
    c = tuple(center.tolist())
    if kind == "disk":
        return Disk(c, size)
    if kind == "box":
        return Box(c, tuple((size / math.sqrt(2) * u).tolist()), angle)
    return Ellipse(c, (size, size * float(u[0])), angle)


def shifted(shape: Shape, offset: tuple[float, float]) -> Shape:
    """``shape`` moved by ``offset`` (every shape stores its placement as a centre or as points)."""
    d = shape.as_dict()
    dx = np.asarray(offset, float)
    for key in ("center", "points", "vertices"):
        if key in d:
            d[key] = (np.asarray(d[key], float) + dx).tolist()
    return shape_from_dict(d)
