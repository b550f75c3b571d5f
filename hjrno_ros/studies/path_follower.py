"""A Nav2-like path follower: A* on the inflated map and Regulated Pure Pursuit (numpy only).

The planner is a grid A* (8-connected) over cells whose clearance exceeds the footprint, with a cost that grows
near obstacles as Nav2's inflation layer's does, so paths keep off walls where there is room.  The controller
follows Nav2's Regulated Pure Pursuit defaults: lookahead 0.6 m; rotate in place towards the path when it is more
than 45° off (at 1.8 rad/s, within the robot's limit); speed scaled down on arcs tighter than 0.9 m and near
obstacles (cost-regulated, below 0.6 m), but not below 0.25 m/s, then on the last 0.6 m to the goal (at least
0.05 m/s); no collision checking of its own (that is the safety layer's job).  Pure pursuit cuts corners: the
carrot is 0.6 m ahead on the path and the arc towards it leaves the path on the inside of every bend.
"""

from __future__ import annotations

import dataclasses
import heapq
import math

import numpy as np
from scipy import ndimage


@dataclasses.dataclass(frozen=True)
class FollowerSettings:
    """Nav2 RPP's defaults (nav2_regulated_pure_pursuit_controller), the robot's limits given separately."""

    lookahead: float = 0.6  # m: lookahead_dist
    rotate_to_heading_min_angle: float = 0.785  # rad: rotate in place above this
    rotate_to_heading_angular_vel: float = 1.8  # rad/s
    regulated_min_radius: float = 0.9  # m: regulated_linear_scaling_min_radius (slower on tighter arcs)
    regulated_min_speed: float = 0.25  # m/s: regulated_linear_scaling_min_speed
    cost_scaling_dist: float = 0.6  # m: cost-regulated scaling below this distance to obstacles
    cost_scaling_gain: float = 1.0
    approach_velocity_scaling_dist: float = 0.6  # m
    min_approach_linear_velocity: float = 0.05  # m/s
    goal_tolerance: float = 0.25  # m: xy_goal_tolerance


@dataclasses.dataclass(frozen=True)
class Grid2D:
    """Obstacle cells ``[ix, iy]`` with their clearance (m, distance from each cell centre to the nearest
    obstacle cell's boundary)."""

    obstacles: np.ndarray
    origin: tuple[float, float]
    resolution: float

    @property
    def clearance(self) -> np.ndarray:
        return ndimage.distance_transform_edt(~self.obstacles) * self.resolution - 0.5 * self.resolution

    def cell(self, xy: np.ndarray) -> tuple[int, int]:
        i = np.floor((np.asarray(xy, float) - self.origin) / self.resolution).astype(int)
        return int(np.clip(i[0], 0, self.obstacles.shape[0] - 1)), int(np.clip(i[1], 0, self.obstacles.shape[1] - 1))

    def centre(self, ij: np.ndarray) -> np.ndarray:
        return np.asarray(self.origin) + (np.asarray(ij, float) + 0.5) * self.resolution


def plan(grid: Grid2D, start: np.ndarray, goal: np.ndarray, radius: float, inflation: float = 0.55,
         weight: float = 3.0, clear: np.ndarray | None = None) -> np.ndarray | None:
    """Waypoints ``(k, 2)`` from ``start`` to ``goal`` through cells with clearance > ``radius``, each step costing
    its length times 1 + weight·exp(−(clearance − radius)/inflation·3) (Nav2's inflation cost shape); None if the
    goal is unreachable.  ``clear``: the grid's clearance, if already computed."""
    clear = grid.clearance if clear is None else clear
    free = clear > radius
    cost = 1.0 + weight * np.exp(-3.0 * np.maximum(clear - radius, 0.0) / inflation)
    s, g = grid.cell(start), grid.cell(goal)
    if not free[s]:  # a robot that stopped beside an obstacle may leave it through cells short of its radius
        ij = np.stack(np.meshgrid(*(np.arange(n) for n in free.shape), indexing="ij"), -1)
        near = np.linalg.norm(ij - np.asarray(s), axis=-1) * grid.resolution <= radius + grid.resolution
        free = free | (near & (clear > 0))
    if not (free[s] and free[g]):
        return None
    steps = [(dx, dy, math.hypot(dx, dy)) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]
    best = {s: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    queue = [(0.0, s)]
    nx, ny = free.shape
    while queue:
        _, c = heapq.heappop(queue)
        if c == g:
            break
        for dx, dy, length in steps:
            n = (c[0] + dx, c[1] + dy)
            if not (0 <= n[0] < nx and 0 <= n[1] < ny) or not free[n]:
                continue
            d = best[c] + length * cost[n]
            if d < best.get(n, math.inf):
                best[n], parent[n] = d, c
                heapq.heappush(queue, (d + math.hypot(n[0] - g[0], n[1] - g[1]), n))
    if g not in best:
        return None
    path = [g]
    while path[-1] != s:
        path.append(parent[path[-1]])
    points = grid.centre(np.array(path[::-1]))
    points[0], points[-1] = start[:2], goal[:2]
    return points


class RegulatedPurePursuit:
    """Twists towards the carrot on a path for a robot with the given limits (see the module docstring)."""

    def __init__(self, path: np.ndarray, v_max: float, omega_max: float, clearance, settings=FollowerSettings()):
        self.path, self.v_max, self.omega_max, self.clearance, self.s = path, v_max, omega_max, clearance, settings
        self.progress = 0  # index of the path point nearest the robot so far (never goes back)

    def done(self, pose: np.ndarray) -> bool:
        return bool(np.linalg.norm(self.path[-1] - pose[:2]) <= self.s.goal_tolerance)

    def carrot(self, pose: np.ndarray) -> np.ndarray:
        """The first path point at least ``lookahead`` from the robot, beyond its nearest point so far."""
        window = self.path[self.progress:self.progress + 200]
        self.progress += int(np.argmin(np.linalg.norm(window - pose[:2], axis=1)))
        ahead = np.linalg.norm(self.path[self.progress:] - pose[:2], axis=1) >= self.s.lookahead
        return self.path[self.progress + int(np.argmax(ahead))] if ahead.any() else self.path[-1]

    def command(self, pose: np.ndarray) -> tuple[float, float]:
        """(linear m/s, angular rad/s) for the robot at ``pose`` (x, y, θ)."""
        if self.done(pose):
            return 0.0, 0.0
        target = self.carrot(pose)
        dx, dy = target - pose[:2]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        x, y = c * dx + s * dy, -s * dx + c * dy  # the carrot in the robot's frame
        angle = math.atan2(y, x)
        rotate = min(self.s.rotate_to_heading_angular_vel, self.omega_max)
        if abs(angle) > self.s.rotate_to_heading_min_angle:
            return 0.0, math.copysign(rotate, angle)
        curvature = 2.0 * y / max(x * x + y * y, 1e-9)
        v = self.v_max
        radius = 1.0 / max(abs(curvature), 1e-9)
        if radius < self.s.regulated_min_radius:
            v *= radius / self.s.regulated_min_radius
        clear = float(self.clearance(pose[None, :2])[0])
        if clear < self.s.cost_scaling_dist:
            v *= self.s.cost_scaling_gain * max(clear, 0.0) / self.s.cost_scaling_dist
        v = max(v, min(self.s.regulated_min_speed, self.v_max))
        remaining = float(np.linalg.norm(self.path[-1] - pose[:2]))
        if remaining < self.s.approach_velocity_scaling_dist:
            v *= remaining / self.s.approach_velocity_scaling_dist
        v = max(v, self.s.min_approach_linear_velocity)
        omega = v * curvature
        if abs(omega) > self.omega_max:  # keep the arc: slow down instead of turning less
            v *= self.omega_max / abs(omega)
            omega = math.copysign(self.omega_max, omega)
        return v, omega
