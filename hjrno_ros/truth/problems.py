"""Fixed reference problems for ``hjrno solve``, the benchmarks and the validation tests.

Each is deterministic: dynamics, grid, target l and the solve settings that suit it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from hjrno_ros.core.dynamics import Air3DParams, CarParams
from hjrno_ros.core.geometry import Box, Disk, Shape, air3d_collision_sdf, union_sdf
from hjrno_ros.core.grids import GridSpec, air3d_grid, car_grid
from hjrno_ros.truth.systems import Air3D, DynamicDubinsCar

DEFAULT_CAR_SHAPE = (40, 40, 12, 20)
DEFAULT_AIR3D_SHAPE = (51, 40, 50)


@dataclasses.dataclass
class Problem:
    name: str
    description: str
    dynamics: object
    grid: GridSpec
    target: np.ndarray
    shapes: tuple[Shape, ...]  # obstacles in the x-y plane (Air3D: evader, pursuer in body frames)
    solve_options: dict

    def clearance(self, states: np.ndarray) -> np.ndarray:
        """Exact l(x) at car states (..., 4) from the shapes (not the grid)."""
        return union_sdf(self.shapes, np.asarray(states)[..., :2])


def disk(shape=DEFAULT_CAR_SHAPE, params: CarParams = CarParams()) -> Problem:
    grid = car_grid(shape)
    shapes = (Disk((0.0, 0.0), 1.0),)
    target = union_sdf(shapes, grid.states()[..., :2]).astype(np.float32)
    return Problem("disk", "dynamic Dubins car, disk obstacle r = 1 m at the centre of a 10 m x 10 m window",
                   DynamicDubinsCar(params), grid, target, shapes, {"criterion": "interior"})


def room(shape=DEFAULT_CAR_SHAPE, params: CarParams = CarParams()) -> Problem:
    """Converged is judged near V = 0: inside the walls V keeps sinking towards the extrapolated edge."""
    grid = car_grid(shape)
    t, h = 0.4, 5.0  # wall thickness and half the room size, m
    shapes = (
        Box((0.0, -h + t / 2), (h, t / 2)),
        Box((0.0, h - t / 2), (h, t / 2)),
        Box((-h + t / 2, 0.0), (t / 2, h)),
        Box((h - t / 2, 0.0), (t / 2, h)),
    )
    target = union_sdf(shapes, grid.states()[..., :2]).astype(np.float32)
    return Problem("room", "dynamic Dubins car in a closed 10 m x 10 m room with 0.4 m walls",
                   DynamicDubinsCar(params), grid, target, shapes, {"criterion": "band", "max_horizon": 60.0})


def air3d(shape=DEFAULT_AIR3D_SHAPE, params: Air3DParams = Air3DParams()) -> Problem:
    grid = air3d_grid(shape)
    shapes = (Disk((0.0, 0.0), 2.5), Disk((0.0, 0.0), 2.5))
    target = air3d_collision_sdf(shapes[0], shapes[1], grid)
    return Problem("air3d", "Air3D, two circular agents r = 2.5 m (collision at 5 m), speeds 5 m/s",
                   Air3D(params), grid, target, shapes, {"criterion": "band", "max_horizon": 10.0, "chunk": 0.5})


PROBLEMS: dict[str, Callable[..., Problem]] = {"disk": disk, "room": room, "air3d": air3d}


def make_problem(name: str, shape: tuple[int, ...] | None = None) -> Problem:
    if name not in PROBLEMS:
        raise ValueError(f"unknown problem {name!r}; choose from {', '.join(PROBLEMS)}")
    return PROBLEMS[name]() if shape is None else PROBLEMS[name](tuple(shape))
