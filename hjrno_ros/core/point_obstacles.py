"""Obstacles seen as points by a live sensor (a laser scan), and their distance field.

A scan gives surface points, not occupied areas: each return is taken as the near edge of a small disk behind it
(:func:`behind`), so that the obstacles have a signed distance, and the operator's V0 takes the minimum of it and
the static map's signed distance on the window's nodes only (a KD-tree over the disks' centres, pykdtree's: the
cost follows the window and the scan, not the map; scipy's would load ~35 MB of scipy into the node).  Obstacles
that move (people) are grown by a further margin (docs/design.md, "Moving obstacles").
Poses are (x, y, yaw) in SI units; points are ``(..., 2)`` arrays of x, y.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pykdtree.kdtree import KDTree

Pose2 = tuple[float, float, float]
STATIC_MATCH = 0.15  # m: scan returns this close to a static-map obstacle are that obstacle (localisation, cells)


def scan_points(ranges: np.ndarray, angle_min: float, angle_increment: float, range_min: float,
                range_max: float) -> np.ndarray:
    """The returns of a planar scan as points (N, 2) in the sensor's frame: beams with a finite range inside
    [range_min, range_max] (an infinite or over-range beam saw nothing, a NaN one is dropped)."""
    r = np.asarray(ranges, float)
    angles = angle_min + angle_increment * np.arange(r.size)
    keep = np.isfinite(r) & (r >= range_min) & (r <= range_max)
    return np.stack([r[keep] * np.cos(angles[keep]), r[keep] * np.sin(angles[keep])], -1)


def behind(points: np.ndarray, depth: float) -> np.ndarray:
    """Each return (N, 2), in its sensor's frame, moved ``depth`` further along its beam: the centre of a disk of
    radius ``depth`` whose near edge the beam hit.  A scan sees surfaces only; as disks its returns are solid
    obstacles with a signed distance (negative inside), which the operator and the braking bound need: the
    unsigned distance to a thin arc of points rises again behind it."""
    p = np.asarray(points, float)
    r = np.linalg.norm(p, axis=-1, keepdims=True)
    return p * (1.0 + depth / np.maximum(r, 1e-9))


def transform(points: np.ndarray, pose: Pose2) -> np.ndarray:
    """``points`` (..., 2) given in a frame whose origin and heading are ``pose`` in the outer frame."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    p = np.asarray(points, float)
    return np.stack([pose[0] + c * p[..., 0] - s * p[..., 1], pose[1] + s * p[..., 0] + c * p[..., 1]], -1)


@dataclasses.dataclass(frozen=True)
class PointObstacles:
    """Disks of radius ``margin`` m centred on ``points`` (N, 2) in the map frame: ``distance`` is their signed
    distance, the clearance they leave.  ``approach``: how fast they may come nearer, m/s (0: they stand still),
    since ``received``, the monotonic time (s) their data arrived; the value table and the braking bound grow them
    by that speed over the data's age and the robot's stop (docs/design.md, "Moving obstacles")."""

    points: np.ndarray
    margin: float = 0.0
    approach: float = 0.0
    received: float = 0.0

    def __post_init__(self) -> None:
        points = np.ascontiguousarray(self.points, np.float64).reshape(-1, 2)
        object.__setattr__(self, "_tree", KDTree(points) if len(points) else None)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance from each of ``points`` (..., 2) to the nearest disk; +inf without disks."""
        p = np.asarray(points, float)
        if self._tree is None:
            return np.full(p.shape[:-1], np.inf)
        d, _ = self._tree.query(np.ascontiguousarray(p.reshape(-1, 2)))
        return d.reshape(p.shape[:-1]) - self.margin
