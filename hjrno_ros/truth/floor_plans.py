"""Map-like scenes: the ``indoor`` rooms, ``windows`` of cluttered maps and ``plans``: windows of floor plans.

``plans`` is what the product model trains on (docs/training.md, "Floor plans"): a generated floor plan of
2·PLAN_HALF × 2·PLAN_HALF model units (κ_max = 1, so the turn radius at full lock is 1) in one of three styles,

=============  =====================================================================================
``rooms``      rooms split recursively (binary space partition) by walls with door gaps
``corridors``  a corridor crossing the plan with side branches, most ending in dead ends
``warehouse``  shelf rows with aisles and cross aisles inside outer walls
=============  =====================================================================================

plus clutter (boxes, disks, ellipses), unknown patches at the plan's border (obstacles to the node, which
treats unknown cells as occupied by default) and the map edge around it (everything beyond the plan is
solid, as the node's map edge is).  Wall thicknesses go down to 0.05 units: thinner than a model grid cell.
The window is the scenario's domain centred on a random free point of the plan (the robot, at least
ROBOT_CLEARANCE from everything); every shape is moved so that point is the origin, and the signed distance
comes from the whole plan, so walls cross the window's edge.  The builders take the scenario module's
``_Draw`` (sampled values from the family's declared ranges, seeded).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.geometry import Box, Shape, union_sdf
from hjrno_ros.truth.shapes import (
    DOMAIN_HI,
    DOMAIN_LO,
    ROUNDNESS,
    clutter_item,
    random_smooth_shape,
    segment_box,
    shifted,
)

if TYPE_CHECKING:
    from hjrno_ros.truth.scenarios import _Draw as Draw

DOOR_CLEARANCE = 1.0  # indoor: clutter-free distance around a door gap (beyond its half width)
CLUTTER_GAP = 0.8  # indoor: minimum free gap between clutter items and any other obstacle
WALL_END_MARGIN = 0.3  # a door gap keeps this far from the ends of its wall
WINDOW_MAP_HALF = 8.0  # m: windows family, obstacles anywhere in [-8, 8]² around the 10 m window
ROBOT_CLEARANCE = 0.3  # m: windows family, free disk around the window centre (the robot)
PLAN_HALF = 10.0  # plans: the floor plan spans [-10, 10]² around its own origin
EDGE_DEPTH = 6.0  # plans: solid beyond the plan's edge, deeper than half a window
MIN_ROOM = 2.0  # plans: no room narrower than this
PLAN_STYLES = ("rooms", "corridors", "warehouse")


def door_wall(
    rng: np.random.Generator,
    fixed: float,
    span: tuple[float, float],
    free: tuple[float, float],
    vertical: bool,
    width: float,
    thickness: float,
    keep_out: Callable[[float], bool] = lambda s: False,
) -> tuple[list[Box], float]:
    """Wall at x = fixed (vertical) or y = fixed over ``span``, split by a door gap of ``width`` whose
    centre s lies in the ``free`` stretch (between the walls it joins) WALL_END_MARGIN from its ends."""
    for _ in range(1000):
        s = float(rng.uniform(free[0] + width / 2 + WALL_END_MARGIN, free[1] - width / 2 - WALL_END_MARGIN))
        if not keep_out(s):
            break
    else:
        raise ValueError("could not place a door gap on an interior wall")
    pt = (lambda u: (fixed, u)) if vertical else (lambda u: (u, fixed))
    segments = [(span[0], s - width / 2), (s + width / 2, span[1])]
    return [segment_box(pt(a), pt(b), thickness) for a, b in segments], s




def build_indoor(draw: Draw) -> tuple[list, dict]:
    car, rng = draw.dynamics(CarParams), draw.rng
    t = draw.uniform("wall_thickness")
    n_walls, n_clutter = draw.integer("n_walls"), draw.integer("n_clutter")
    xw, yw = draw.uniform("wall_positions"), draw.uniform("wall_positions")
    widths = [draw.uniform("door_widths"), draw.uniform("door_widths")][:n_walls]
    side = DOMAIN_LO if rng.integers(2) == 0 else DOMAIN_HI
    lo, hi, ext = DOMAIN_LO, DOMAIN_HI, DOMAIN_HI + t
    # Outer walls straddle the domain edge: a band t wide inside the domain (and as much outside).
    walls: list = [
        Box((lo, 0.0), (t, ext)),
        Box((hi, 0.0), (t, ext)),
        Box((0.0, lo), (ext, t)),
        Box((0.0, hi), (ext, t)),
    ]
    roles = ["outer_wall"] * 4
    junction = (lambda y: abs(y - yw) < widths[0] / 2 + t / 2 + DOOR_CLEARANCE) if n_walls == 2 else (lambda y: False)
    more, yd = door_wall(rng, xw, (lo + t / 2, hi - t / 2), (lo + t, hi - t), True, widths[0], t, junction)
    walls, doors = walls + more, [(xw, yd)]
    if n_walls == 2:  # from the outer wall on `side` to wall 1
        span, free = (
            ((side + t / 2, xw), (side + t, xw - t / 2)) if side < xw else ((xw, side - t / 2), (xw + t / 2, side - t))
        )
        more, xd = door_wall(rng, yw, span, free, False, widths[1], t)
        walls, doors = walls + more, doors + [(xd, yw)]
    roles += ["wall"] * (len(walls) - 4)
    clutter, sizes = [], []
    for _ in range(200 * n_clutter):
        if len(clutter) == n_clutter:
            break
        s = draw.uniform("clutter_sizes")
        c = rng.uniform(lo + t + s + CLUTTER_GAP, hi - t - s - CLUTTER_GAP, 2)
        if (
            union_sdf(walls, c) >= s + CLUTTER_GAP
            and all(math.dist(c, d) >= w / 2 + DOOR_CLEARANCE + s for d, w in zip(doors, widths, strict=False))
            and all(math.dist(c, p.center) >= s + q + CLUTTER_GAP for p, q in zip(clutter, sizes, strict=False))
        ):
            clutter.append(clutter_item(rng, c, s))
            sizes.append(s)
    if len(clutter) < n_clutter:
        raise ValueError(f"could not place {n_clutter} clutter items")
    params = {
        "wall_thickness": t,
        "n_walls": n_walls,
        "n_clutter": n_clutter,
        "wall_positions": [xw, yw][:n_walls],
        "door_widths": widths,
        "doors": [[float(x), float(y)] for x, y in doors],
        "clutter_sizes": sizes,
        "shape_roles": roles + ["clutter"] * n_clutter,
        **car,
    }
    return walls + clutter, params




def build_windows(draw: Draw) -> tuple[list, dict]:
    """What brt_node feeds its model: a window cut around the robot from a cluttered map, so
    obstacles cross the window edge and may lie just outside it (they still shape l inside)."""
    car, rng = draw.dynamics(CarParams), draw.rng
    n_blobs, n_walls = draw.integer("n_blobs"), draw.integer("n_walls")
    shapes, roles, centers, radii, thick, lengths = [], [], [], [], [], []
    for _ in range(200 * n_blobs):
        if len(centers) == n_blobs:
            break
        r = draw.uniform("radius")
        c = rng.uniform(-WINDOW_MAP_HALF, WINDOW_MAP_HALF, 2)
        if math.hypot(*c) >= r + ROBOT_CLEARANCE and all(math.dist(c, o) >= r + q + 0.3
                                                           for o, q in zip(centers, radii, strict=True)):
            shapes.append(random_smooth_shape(rng, c, (ROUNDNESS * r, r)))
            centers.append(c.tolist())
            radii.append(r)
    if len(centers) < n_blobs:
        raise ValueError(f"could not place {n_blobs} obstacles")
    for _ in range(n_walls):
        t, length = draw.uniform("wall_thickness"), draw.uniform("wall_length")
        side = float(rng.choice([-1.0, 1.0]))
        fixed = side * float(rng.uniform(ROBOT_CLEARANCE + t / 2, WINDOW_MAP_HALF - 1.0))
        start = float(rng.uniform(-WINDOW_MAP_HALF, WINDOW_MAP_HALF - length))
        a, b = (start, fixed), (start + length, fixed)
        if rng.integers(2):
            a, b = a[::-1], b[::-1]
        shapes.append(segment_box(a, b, t))
        thick.append(t)
        lengths.append(length)
    roles = ["map"] * len(shapes)
    params = {"n_blobs": n_blobs, "n_walls": n_walls, "radius": radii, "centers": centers, "wall_thickness": thick,
              "wall_length": lengths, "shape_roles": roles, **car}
    return shapes, params




# ---------------------------------------------------------------------------------------------
# Floor plans.

Part = tuple[Shape, str]  # a shape and its role (wall, shelf, solid, clutter, unknown, edge)


def _rect(x0: float, x1: float, y0: float, y1: float) -> Box | None:
    """The axis-aligned box [x0, x1] × [y0, y1] (corners in any order); None when degenerate."""
    (x0, x1), (y0, y1) = sorted((x0, x1)), sorted((y0, y1))
    if x1 - x0 < 1e-6 or y1 - y0 < 1e-6:
        return None
    return Box(((x0 + x1) / 2, (y0 + y1) / 2), ((x1 - x0) / 2, (y1 - y0) / 2))


def _boxes(rects: list[tuple[float, float, float, float]], role: str) -> list[Part]:
    return [(box, role) for box in (_rect(*r) for r in rects) if box is not None]


def _outer_walls(t: float) -> list[Part]:
    """The building's outer wall along the plan's edge, t thick, inside the plan."""
    h = PLAN_HALF
    return _boxes([(-h, -h + t, -h, h), (h - t, h, -h, h), (-h, h, -h, -h + t), (-h, h, h - t, h)], "wall")


def _map_edge() -> list[Part]:
    """Everything beyond the plan is solid: the node's map edge bounds the signed distance the same way."""
    h, e = PLAN_HALF, PLAN_HALF + EDGE_DEPTH
    return _boxes([(-e, -h, -e, e), (h, e, -e, e), (-h, h, -e, -h), (-h, h, h, e)], "edge")


def _rooms(draw: Draw, t: float) -> list[Part]:
    """Binary space partition: split any room longer than ``room_size`` across its long side by a wall
    with one door gap (none if the wall is too short for it)."""
    rng, size = draw.rng, draw.uniform("room_size")
    parts = _outer_walls(t)

    def split(lo: np.ndarray, hi: np.ndarray) -> None:
        axis = int(np.argmax(hi - lo))
        if hi[axis] - lo[axis] <= max(size, 2 * MIN_ROOM + t):
            return
        at = float(rng.uniform(lo[axis] + MIN_ROOM + t / 2, hi[axis] - MIN_ROOM - t / 2))
        other = 1 - axis
        a, b = float(lo[other]), float(hi[other])
        width = draw.uniform("door_width")
        segments = [(a, b)]
        if b - a > width + 2 * WALL_END_MARGIN:
            s = float(rng.uniform(a + width / 2 + WALL_END_MARGIN, b - width / 2 - WALL_END_MARGIN))
            segments = [(a, s - width / 2), (s + width / 2, b)]
        for u0, u1 in segments:
            r = (at - t / 2, at + t / 2, u0, u1) if axis == 0 else (u0, u1, at - t / 2, at + t / 2)
            parts.extend(_boxes([r], "wall"))
        lo2, hi1 = lo.copy(), hi.copy()
        hi1[axis], lo2[axis] = at - t / 2, at + t / 2
        split(lo, hi1)
        split(lo2, hi)

    inner = PLAN_HALF - t
    split(np.array([-inner, -inner]), np.array([inner, inner]))
    return parts


def _corridors(draw: Draw, t: float) -> list[Part]:
    """A corridor along x at a random height with branches up and down, each of random width and length:
    a branch shorter than the way to the plan's edge is a dead end.  Everything else is solid."""
    rng, h = draw.rng, PLAN_HALF
    width = draw.uniform("corridor_width")
    y0 = float(rng.uniform(-3.0, 3.0))
    rects = []
    for side in (1.0, -1.0):
        edge, far = y0 + side * width / 2, side * h
        branches: list[tuple[float, float, float]] = []  # (x0, x1, length)
        n = draw.integer("n_branches")
        for _ in range(50 * n):
            if len(branches) == n:
                break
            bw = draw.uniform("corridor_width")
            x = float(rng.uniform(-h + 0.5, h - 0.5 - bw))
            if all(x > b + 1.0 or x + bw < a - 1.0 for a, b, _ in branches):
                branches.append((x, x + bw, float(rng.uniform(2.0, 1.3 * h))))
        branches.sort()
        x_prev = -h
        for a, b, length in branches:
            rects.append((x_prev, a, edge, far))
            if length < abs(far - edge):
                rects.append((a, b, edge + side * length, far))
            x_prev = b
        rects.append((x_prev, h, edge, far))
    return _boxes(rects, "solid")


def _warehouse(draw: Draw, t: float) -> list[Part]:
    """Rows of shelves ``shelf_depth`` deep with aisles between them, cut by one or two cross aisles,
    inside the outer walls; rows along x or along y."""
    rng, h = draw.rng, PLAN_HALF
    aisle, depth = draw.uniform("aisle_width"), draw.uniform("shelf_depth")
    lo, hi = -h + t + aisle, h - t - aisle
    cuts = sorted(float(c) for c in rng.uniform(lo + 2.0, hi - 2.0, int(rng.integers(1, 3))))
    cross = draw.uniform("aisle_width") + 0.5
    spans, x = [], lo
    for c in cuts:
        if c - cross / 2 > x:
            spans.append((x, c - cross / 2))
        x = max(x, c + cross / 2)
    spans.append((x, hi))
    rects, y = [], lo + float(rng.uniform(0.0, aisle))
    while y + depth <= hi:
        rects += [(x0, x1, y, y + depth) for x0, x1 in spans]
        y += depth + aisle * float(rng.uniform(0.8, 1.25))
    if rng.integers(2):
        rects = [(y0, y1, x0, x1) for x0, x1, y0, y1 in rects]
    return _outer_walls(t) + _boxes(rects, "shelf")


def _clutter(draw: Draw, parts: list[Part]) -> list[Part]:
    """``n_clutter`` boxes, disks and ellipses in free space, at least 0.2 from everything else."""
    rng, h, shapes, out = draw.rng, PLAN_HALF, [s for s, _ in parts], []
    n = draw.integer("n_clutter")
    for _ in range(100 * n):
        if len(out) == n:
            break
        size = draw.uniform("clutter_size")
        c = rng.uniform(-h + size, h - size, 2)
        if union_sdf(shapes, c) >= size + 0.2:
            item = clutter_item(rng, c, size)
            shapes.append(item)
            out.append((item, "clutter"))
    return out


def _unknown(draw: Draw) -> list[Part]:
    """``n_unknown`` unexplored patches on the plan's border (up to 5 × 5 units)."""
    rng, h, out = draw.rng, PLAN_HALF, []
    for _ in range(draw.integer("n_unknown")):
        w, d = rng.uniform(1.5, 5.0, 2)
        along, side = float(rng.uniform(-h, h)), int(rng.integers(4))
        r = (along - w / 2, along + w / 2, h - d, h) if side < 2 else (h - d, h, along - w / 2, along + w / 2)
        if side % 2:  # mirror to the opposite border
            r = (r[0], r[1], -r[3], -r[2]) if side < 2 else (-r[1], -r[0], r[2], r[3])
        out += _boxes([r], "unknown")
    return out


def _robot_position(rng: np.random.Generator, shapes: list[Shape]) -> np.ndarray:
    """A uniform point of the plan at least ROBOT_CLEARANCE from every shape."""
    h = PLAN_HALF - ROBOT_CLEARANCE
    for _ in range(100):
        points = rng.uniform(-h, h, (64, 2))
        free = np.flatnonzero(union_sdf(shapes, points) >= ROBOT_CLEARANCE)
        if len(free):
            return points[free[0]]
    raise ValueError("the floor plan has no free point for the robot")


def build_plans(draw: Draw) -> tuple[list, dict]:
    """A window of a generated floor plan around a free point (the robot at the origin)."""
    car, rng = draw.dynamics(CarParams), draw.rng
    style, t = draw.choice("style"), draw.uniform("wall_thickness")
    parts = {"rooms": _rooms, "corridors": _corridors, "warehouse": _warehouse}[style](draw, t)
    parts += _clutter(draw, parts)
    parts += _unknown(draw) + _map_edge()
    robot = _robot_position(rng, [s for s, _ in parts])
    shapes = [shifted(s, tuple(-robot)) for s, _ in parts]
    params = {"style": style, "wall_thickness": t, "robot_in_plan": robot.tolist(),
              "shape_roles": [role for _, role in parts], **car}
    return shapes, params
